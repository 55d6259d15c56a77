"""
SAC policies of the SGFD paper: one encoder shared by actor and critic, trained by the critic loss.

SB3's ``share_features_extractor=True`` trains a shared encoder through the actor loss only. The
paper (following SAC-AE, DrQ and AMBS) does the opposite: the critic loss trains the encoder and
the actor reads detached features. These policies are plain ``SACPolicy`` subclasses, so SB3's
``SAC`` can use them too (the Domain Randomisation baseline and the overhead benchmark do).
"""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import SquashedDiagGaussianDistribution
from stable_baselines3.common.policies import BasePolicy, ContinuousCritic
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, CombinedExtractor, FlattenExtractor
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.sac.policies import LOG_STD_MAX, LOG_STD_MIN, Actor, SACPolicy
from torch import nn
from torch.distributions import Normal

from sb3_sgfd.common.observations import describe_space

#: The policies and encoders a yaml file or a saved model names by ``sb3_sgfd.policies.<name>``
__all__ = [
    "CnnPolicy",
    "DetachedEncoderActor",
    "EncoderMlpPolicy",
    "MlpEncoder",
    "MlpPolicy",
    "MultiInputPolicy",
    "PixelEncoder",
    "SGFDPolicy",
    "SharedEncoderPolicy",
]


class PixelEncoder(BaseFeaturesExtractor):
    """
    The paper's image encoder (Table 3, after SAC-AE/AMBS): 3x3 convolutions with ``n_filters``
    channels, stride 2 for the first and 1 for the others, ReLU in between, then
    Linear -> LayerNorm -> tanh down to ``features_dim`` features.

    :param observation_space: Channel-first image space (SB3 transposes HWC images for us)
    :param features_dim: Size of the latent vector z (paper: 50)
    :param n_layers: Number of convolutional layers (paper: 4)
    :param n_filters: Channels of every convolutional layer (paper: 32)
    :param normalized_image: The images are already scaled (floats, e.g. after ``VecNormalize``): the policy's
        ``normalize_images=False`` sets it, as SB3's for its ``NatureCNN``
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        features_dim: int = 50,
        n_layers: int = 4,
        n_filters: int = 32,
        normalized_image: bool = False,
    ) -> None:
        super().__init__(observation_space, features_dim)
        if not is_image_space(observation_space, check_channels=False, normalized_image=normalized_image):
            raise ValueError(
                f"PixelEncoder reads channel-first uint8 images in [0, 255], got {describe_space(observation_space)}; "
                "for states use "
                "MlpPolicy, for Dict observations MultiInputPolicy, and for images already scaled (floats, e.g. "
                "after VecNormalize) pass policy_kwargs=dict(normalize_images=False)"
            )
        if n_layers < 1:
            raise ValueError(f"n_layers must be >= 1, got {n_layers}")
        n_channels = observation_space.shape[0]
        layers: list[nn.Module] = [nn.Conv2d(n_channels, n_filters, 3, stride=2), nn.ReLU()]
        for _ in range(n_layers - 1):
            layers += [nn.Conv2d(n_filters, n_filters, 3, stride=1), nn.ReLU()]
        self.convs = nn.Sequential(*layers, nn.Flatten())
        with th.no_grad():
            n_flatten = self.convs(th.zeros(1, *observation_space.shape)).shape[1]
        self.trunk = nn.Sequential(nn.Linear(n_flatten, features_dim), nn.LayerNorm(features_dim), nn.Tanh())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.trunk(self.convs(observations))


class MlpEncoder(BaseFeaturesExtractor):
    """
    An encoder of flat (state) observations for the representation objectives, shaped like the pixel
    encoder's trunk: Linear -> ReLU -> Linear -> LayerNorm -> tanh.

    :param observation_space: Flat observation space
    :param features_dim: Size of the latent vector z
    :param hidden_dim: Width of the hidden layer
    """

    def __init__(self, observation_space: spaces.Box, features_dim: int = 50, hidden_dim: int = 256) -> None:
        super().__init__(observation_space, features_dim)
        n_inputs = int(np.prod(observation_space.shape))
        self.net = nn.Sequential(
            nn.Flatten(),
            nn.Linear(n_inputs, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, features_dim),
            nn.LayerNorm(features_dim),
            nn.Tanh(),
        )

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.net(observations)


class SquashedGaussian(SquashedDiagGaussianDistribution):
    """SB3's tanh-squashed diagonal Gaussian without torch.distributions' argument validation, whose checks of the
    mean, the std and each sample are a host read apiece (six per SAC gradient step on a GPU); the parameters
    come from the actor's own layers, and non-finite losses are caught where SAC logs them. Same values."""

    def proba_distribution(self, mean_actions: th.Tensor, log_std: th.Tensor) -> SquashedGaussian:
        self.distribution = Normal(mean_actions, th.ones_like(mean_actions) * log_std.exp(), validate_args=False)
        return self


class DetachedEncoderActor(Actor):
    """SB3's SAC actor, reading the shared encoder's features without backpropagating into it. Its distribution
    can also be taken from features already computed (``*_of_features``): the critic's encoding of the batch
    serves the actor too, instead of a second pass of the encoder."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not self.use_sde:
            self.action_dist = SquashedGaussian(self.action_dist.action_dim)  # type: ignore[assignment]

    def extract_features(  # type: ignore[override]
        self, obs: PyTorchObs, features_extractor: BaseFeaturesExtractor
    ) -> th.Tensor:
        with th.no_grad():
            return super().extract_features(obs, features_extractor)

    def get_action_dist_params(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor, dict[str, th.Tensor]]:
        return self.dist_params_of_features(self.extract_features(obs, self.features_extractor))

    def dist_params_of_features(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor, dict[str, th.Tensor]]:
        """SB3's ``get_action_dist_params`` after the encoder: mean, log std and keyword arguments."""
        latent_pi = self.latent_pi(features)
        mean_actions = self.mu(latent_pi)
        if self.use_sde:
            return mean_actions, self.log_std, dict(latent_sde=latent_pi)
        log_std = th.clamp(self.log_std(latent_pi), LOG_STD_MIN, LOG_STD_MAX)  # type: ignore[operator]
        return mean_actions, log_std, {}

    def action_log_prob_of_features(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``action_log_prob`` of observations whose encoder features are ``features`` (detached)."""
        mean_actions, log_std, kwargs = self.dist_params_of_features(features.detach())
        return self.action_dist.log_prob_from_params(mean_actions, log_std, **kwargs)

    def action_of_features(self, features: th.Tensor, deterministic: bool = False) -> th.Tensor:
        """``forward`` of observations whose encoder features are ``features`` (detached)."""
        mean_actions, log_std, kwargs = self.dist_params_of_features(features.detach())
        return self.action_dist.actions_from_params(mean_actions, log_std, deterministic=deterministic, **kwargs)


class SharedEncoderPolicy(SACPolicy):
    """
    SAC policy with one features extractor shared by actor and critic and trained by the critic loss: the policy
    of every agent of this package. ``SGFDPolicy`` is its former name, kept as an alias.

    The features extractor defaults to :class:`PixelEncoder` for image observations and to a
    flatten layer otherwise; actor and critic MLPs default to two hidden layers of 1024 (paper).
    The critic target keeps its own copy of the encoder, soft-updated with the critic.

    Takes the arguments of :class:`stable_baselines3.sac.policies.SACPolicy`, except
    ``share_features_extractor`` which is always true here (with the meaning above).
    """

    default_features_extractor_class: type[BaseFeaturesExtractor] | None = None
    actor: DetachedEncoderActor

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        features_extractor_class: type[BaseFeaturesExtractor] | None = None,
        **kwargs: Any,
    ) -> None:
        if kwargs.pop("share_features_extractor", True) is not True:
            raise ValueError(
                "share_features_extractor must be True for SharedEncoderPolicy (the encoder is shared and "
                "trained by the critic); use SB3's SACPolicy for separate encoders"
            )
        if features_extractor_class is None:
            features_extractor_class = self.default_features_extractor_class or (
                PixelEncoder if is_image_space(observation_space) else FlattenExtractor
            )
        extractor_kwargs = kwargs.get("features_extractor_kwargs") or {}
        if kwargs.get("normalize_images", True) is False and reads_images(features_extractor_class):
            # as SB3 does for its NatureCNN: the encoder then takes images that are already scaled
            kwargs["features_extractor_kwargs"] = {**extractor_kwargs, "normalized_image": True}
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=[1024, 1024] if net_arch is None else net_arch,
            features_extractor_class=features_extractor_class,
            share_features_extractor=True,
            **kwargs,
        )

    def _build(self, lr_schedule: Schedule) -> None:
        # The critic owns the encoder and its optimizer trains it; gradients must flow through it.
        self.critic_kwargs["share_features_extractor"] = False
        self.critic = self.make_critic(features_extractor=None)
        self.critic.optimizer = self.optimizer_class(
            self.critic.parameters(),
            lr=lr_schedule(1),  # type: ignore[call-arg]
            **self.optimizer_kwargs,
        )
        self.actor = self.make_actor(features_extractor=self.critic.features_extractor)
        actor_parameters = [
            param for name, param in self.actor.named_parameters() if not name.startswith("features_extractor.")
        ]
        self.actor.optimizer = self.optimizer_class(
            actor_parameters,
            lr=lr_schedule(1),  # type: ignore[call-arg]
            **self.optimizer_kwargs,
        )
        self.critic_target = self.make_critic(features_extractor=None)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic_target.set_training_mode(False)

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None) -> DetachedEncoderActor:
        actor_kwargs = self._update_features_extractor(self.actor_kwargs, features_extractor)
        return DetachedEncoderActor(**actor_kwargs).to(self.device)


#: The former name of :class:`SharedEncoderPolicy` (yaml files, code and models saved before the rename use it)
SGFDPolicy = SharedEncoderPolicy


class CnnPolicy(SharedEncoderPolicy):
    """:class:`SharedEncoderPolicy` with the paper's :class:`PixelEncoder`."""

    default_features_extractor_class = PixelEncoder


class MlpPolicy(SharedEncoderPolicy):
    """:class:`SharedEncoderPolicy` on flat (state) observations."""

    default_features_extractor_class = FlattenExtractor


class MultiInputPolicy(SharedEncoderPolicy):
    """:class:`SharedEncoderPolicy` on Dict observations through SB3's ``CombinedExtractor`` (its images through
    NatureCNN, the rest flattened)."""

    default_features_extractor_class = CombinedExtractor


class EncoderMlpPolicy(SharedEncoderPolicy):
    """:class:`SharedEncoderPolicy` on flat observations through a learned :class:`MlpEncoder` (for the objectives)."""

    default_features_extractor_class = MlpEncoder


#: The policies of EncoderSAC and its agents by name (``SGFD_SAC("CnnPolicy", env)``)
POLICY_ALIASES: dict[str, type[BasePolicy]] = {
    "MlpPolicy": MlpPolicy,
    "CnnPolicy": CnnPolicy,
    "SharedEncoderPolicy": SharedEncoderPolicy,
    "SGFDPolicy": SGFDPolicy,
    "EncoderMlpPolicy": EncoderMlpPolicy,
    "MultiInputPolicy": MultiInputPolicy,
}


def reads_images(extractor_class: type[BaseFeaturesExtractor]) -> bool:
    """Whether an encoder class takes SB3's ``normalized_image`` (it reads images, and checks that they are)."""
    return "normalized_image" in inspect.signature(extractor_class.__init__).parameters


def critic_and_features(
    critic: ContinuousCritic, observations: th.Tensor, actions: th.Tensor
) -> tuple[tuple[th.Tensor, ...], th.Tensor]:
    """``critic(observations, actions)``, as SB3's ContinuousCritic computes it (its encoder learning through it),
    and the encoder features it computed: a sample weighting and the actor reuse them instead of encoding the batch a
    second time (on pixels, the encoder is a large part of a step)."""
    with th.set_grad_enabled(not critic.share_features_extractor):
        features = critic.extract_features(observations, critic.features_extractor)
    q_input = th.cat([features, actions], dim=1)
    return tuple(q_net(q_input) for q_net in critic.q_networks), features


def actor_action_log_prob(policy: SACPolicy, observations: th.Tensor, z: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The actor's actions and their log-probabilities for a batch: from the critic's features z of it when the actor
    reads the critic's encoder (a :class:`SharedEncoderPolicy`: the same values, without a second pass), else as SB3's
    actor computes them from the observations."""
    if isinstance(policy, SharedEncoderPolicy):
        return policy.actor.action_log_prob_of_features(z)
    return policy.actor.action_log_prob(observations)  # type: ignore[union-attr, operator]


def actor_q_values(
    policy: SACPolicy, observations: th.Tensor, z: th.Tensor, actions: th.Tensor, reuse_features: bool
) -> tuple[th.Tensor, ...]:
    """The critic's Q of the actor's actions: with ``reuse_features`` and a :class:`SharedEncoderPolicy`, on the
    critic's (detached) features z of this step, as the authors' codes (the encoder detached); else SB3's, the batch
    encoded again."""
    critic = policy.critic  # type: ignore[union-attr]
    if reuse_features and isinstance(policy, SharedEncoderPolicy):
        q_input = th.cat([z, actions], dim=1)
        return tuple(q_net(q_input) for q_net in critic.q_networks)
    return critic(observations, actions)


def check_encoder_setup(model: Any, trains_encoder: bool) -> None:
    """Refuse, in one line, settings the model's policy cannot take: augmentation on observations that are not
    images, augmentation or an encoder objective without an encoder the critic trains, an objective for an encoder
    without parameters.

    :param model: the algorithm (its policy, observation space, ``augmentation_views`` and ``representation``)
    :param trains_encoder: whether an encoder objective trains the encoder
    """
    scaled = not model.policy.normalize_images
    if model.augmentation_views and not is_image_space(model.observation_space, normalized_image=scaled):
        raise ValueError(
            f"augmentation_views={model.augmentation_views} shifts images, but the observations are "
            f"{model.observation_space}; use augmentation_views=0 on states"
        )
    if (trains_encoder or model.augmentation_views) and not isinstance(model.policy, SharedEncoderPolicy):
        raise ValueError(
            f"{type(model).__name__} with a representation or augmentation needs a policy whose encoder the critic "
            "trains (sb3_sgfd.common.policies.SharedEncoderPolicy and its subclasses), got "
            f"{type(model.policy).__name__}"
        )
    encoder = model.critic.features_extractor
    if trains_encoder and not any(True for _ in encoder.parameters()):
        raise ValueError(
            f"the {model.representation!r} representation trains the encoder, but {type(encoder).__name__} has no "
            "parameters: use policy='EncoderMlpPolicy' (states) or 'CnnPolicy' (pixels)"
        )
