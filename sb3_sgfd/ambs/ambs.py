"""AMBS (Chen & Pan, ICLR 2022): SAC whose encoder learns a behavioural metric through meta-learners."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar, cast

import torch as th
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.sac.policies import SACPolicy
from torch.nn import functional as F

from sb3_sgfd.ambs.losses import MetricLearner, ambs_metric_loss, ambs_metric_loss_code, split_halves
from sb3_sgfd.ambs.policies import AMBSEncoder, AMBSPolicy
from sb3_sgfd.common.augmentation import random_shift
from sb3_sgfd.common.dynamics import (
    DeterministicTransitionModel,
    ProbabilisticTransitionModel,
    RewardDecoder,
    gaussian_nll,
)
from sb3_sgfd.common.encoder_sac import EncoderSAC
from sb3_sgfd.common.policies import DetachedEncoderActor
from sb3_sgfd.common.representation import Agent, Batch, Representation, register, step
from sb3_sgfd.common.validation import check_choice, check_non_negative

TRANSITION_MODELS = {"probabilistic": ProbabilisticTransitionModel, "deterministic": DeterministicTransitionModel}


@register("ambs")
class AMBSRepresentation(Representation):
    """
    AMBS's encoder objective, after the critic's step: ``bisim_coef * metric + transition_coef * (transition
    NLL + reward MSE)``, one Adam step on the encoder (without its ratio, which the critic loss trains) and one
    on the transition model, reward decoder and meta-learners. Needs the policy's
    :class:`sb3_sgfd.ambs.policies.AMBSEncoder` (``policy="AMBSPolicy"``).

    The metric compares the unscaled features of two augmented views (the critic's two views with
    ``augmentation_views=2``; otherwise a fresh shift for images, the same observations for states). Its
    dynamics target comes from the transition model's detached predictions for the actor's deterministic
    actions (on-policy, as the official code); the NLL and reward MSE use the replayed actions, on the
    dynamics half, against the detached next features.

    :param metric: ``"code"``: the metric and NLL as AMBS's code computes them (the default: the published
        numbers and the coefficients come from it; :func:`sb3_sgfd.ambs.losses.ambs_metric_loss_code`, the
        NLL's residual halved); ``"paper"``: the paper's formulas (|r_i - r_j|, the W2 norm over the dynamics
        half, about sqrt(d) larger; :func:`sb3_sgfd.ambs.losses.ambs_metric_loss`, the plain Gaussian NLL)
    :param meta_learners: Measure the halves with AMBS's meta-learners d_r, d_d; False: with Huber and squared
        distances (the SGFD code's committed setting; ``metric="code"`` only)
    :param transition: ``"probabilistic"`` (AMBS) or ``"deterministic"`` (the SGFD code's committed setting)
    :param adaptive_ratio: Let the critic loss learn the ratio c of the halves (AMBS); False: c stays 0.5
    :param bisim_coef: Weight of the metric loss (AMBS: 0.5)
    :param transition_coef: Weight of the transition NLL plus the reward MSE (AMBS: 0.01)
    :param hidden_dim: Width of the transition model and reward decoder (512)
    :param metric_hidden_dim: Width of the meta-learners d_r, d_d (50)
    :param encoder_lr: Adam learning rate of the encoder's auxiliary step
    :param decoder_lr: Adam learning rate of the transition model, reward decoder and meta-learners
    :param decoder_weight_decay: Their weight decay (AMBS: 0)
    """

    policy_aliases: ClassVar[dict[str, type[SACPolicy]]] = {
        "AMBSPolicy": AMBSPolicy,
        "CnnPolicy": AMBSPolicy,
        "MlpPolicy": AMBSPolicy,
    }

    def __init__(
        self,
        metric: str = "code",
        meta_learners: bool = True,
        transition: str = "probabilistic",
        adaptive_ratio: bool = True,
        bisim_coef: float = 0.5,
        transition_coef: float = 0.01,
        hidden_dim: int = 512,
        metric_hidden_dim: int = 50,
        encoder_lr: float = 1e-3,
        decoder_lr: float = 1e-3,
        decoder_weight_decay: float = 0.0,
    ) -> None:
        super().__init__()
        check_choice("metric", metric, ("code", "paper"))
        check_choice("transition", transition, TRANSITION_MODELS)
        if not meta_learners and metric != "code":
            raise ValueError("meta_learners=False is the code's form: it needs metric='code', got metric='paper'")
        check_non_negative(bisim_coef=bisim_coef, transition_coef=transition_coef)
        self.metric, self.meta_learners, self.transition_kind = metric, bool(meta_learners), transition
        self.adaptive_ratio = bool(adaptive_ratio)
        self.bisim_coef, self.transition_coef = bisim_coef, transition_coef
        self.hidden_dim, self.metric_hidden_dim = hidden_dim, metric_hidden_dim
        self.encoder_lr, self.decoder_lr, self.decoder_weight_decay = encoder_lr, decoder_lr, decoder_weight_decay

    def setup(self, model: Agent) -> None:
        encoder = model.critic.features_extractor
        if not isinstance(encoder, AMBSEncoder):
            raise ValueError(
                f"the 'ambs' representation needs the AMBSEncoder (policy='AMBSPolicy'), got {type(encoder).__name__}"
            )
        if not self.adaptive_ratio:
            encoder.ratio.requires_grad_(False)
        reward_dim, dynamics_dim = encoder.reward_dim, encoder.features_dim - encoder.reward_dim
        action_dim = get_action_dim(model.action_space)
        self.transition = TRANSITION_MODELS[self.transition_kind](dynamics_dim, action_dim, self.hidden_dim)
        self.reward_decoder = RewardDecoder(dynamics_dim, self.hidden_dim)
        decoders: list[th.nn.Module] = [self.transition, self.reward_decoder]
        self.reward_learner: MetricLearner | None = None
        self.dynamics_learner: MetricLearner | None = None
        if self.meta_learners:
            self.reward_learner = MetricLearner(reward_dim, self.metric_hidden_dim)
            self.dynamics_learner = MetricLearner(dynamics_dim, self.metric_hidden_dim)
            decoders += [self.reward_learner, self.dynamics_learner]
        self.encoder_optimizer = th.optim.Adam(encoder.trunk.parameters(), lr=self.encoder_lr)
        self.decoder_optimizer = th.optim.Adam(
            [param for module in decoders for param in module.parameters()],
            lr=self.decoder_lr,
            weight_decay=self.decoder_weight_decay,
        )

    def update(self, model: Agent, batch: Batch) -> dict[str, th.Tensor]:
        encoder: AMBSEncoder = model.critic.features_extractor  # type: ignore[assignment]
        data = batch.replay_data
        observations = batch.observations[0]
        if len(batch.observations) > 1:
            second_view = batch.observations[1]
        elif model.augmentation_views == 0 and observations.dim() == 4:
            second_view = random_shift(observations, model.augmentation_pad, self.generator)
        else:
            second_view = observations
        h = encoder.embed(model.preprocess(observations))
        aug_h = encoder.embed(model.preprocess(second_view))
        with th.no_grad():
            next_h = encoder.embed(model.preprocess(batch.next_observations[0]))
            # the actor reads these features (scaled by the ratio): no second pass of the encoder; it is a
            # SharedEncoderPolicy's, as EncoderSAC requires with an objective
            actor = cast(DetachedEncoderActor, model.actor)
            actor_actions = actor.action_of_features(encoder.scaled(h), deterministic=True)
            h_dynamics = split_halves(h, encoder.reward_dim)[1]
            predicted = self.transition(h_dynamics, actor_actions)
        perm = th.randperm(len(h), generator=self.generator, device=self.generator.device).to(h.device)
        # Callable[...]: the paper's form takes the meta-learners as not None (__init__ ensures it for that form)
        metric_loss: Callable[..., th.Tensor] = ambs_metric_loss_code if self.metric == "code" else ambs_metric_loss
        metric = metric_loss(
            h,
            aug_h,
            data.rewards,
            *predicted,
            perm,
            encoder.reward_weight().detach(),
            self.reward_learner,
            self.dynamics_learner,
            model.gamma,
            encoder.reward_dim,
        )
        dynamics = split_halves(h, encoder.reward_dim)[1]
        mu, sigma = self.transition(dynamics, data.actions)
        # AMBS's code halves the NLL's residual, ((0.5 mu - 0.5 target) / sigma)^2
        residual_scale = 0.5 if self.metric == "code" else 1.0
        nll = gaussian_nll(mu, sigma, split_halves(next_h, encoder.reward_dim)[1], residual_scale)
        next_sample = self.transition.sample(dynamics, data.actions, self.generator)
        reward_loss = F.mse_loss(self.reward_decoder(next_sample), data.rewards)
        loss = self.bisim_coef * metric + self.transition_coef * (nll + reward_loss)
        step(loss, self.encoder_optimizer, self.decoder_optimizer)
        return {
            "metric_loss": metric.detach(),
            "transition_nll": nll.detach(),
            "reward_loss": reward_loss.detach(),
            "reward_weight": encoder.reward_weight().detach(),
        }


class AMBS(EncoderSAC):
    """
    AMBS: SAC with the ratio-scaled :class:`sb3_sgfd.ambs.policies.AMBSEncoder` (``policy="AMBSPolicy"``) trained
    by the critic and by AMBS's behavioural metric (:class:`AMBSRepresentation`); two random-shift views with
    the critic loss and target averaged over them, encoder tau 0.05, gradient norms clipped at 40, actor every
    2 steps. Takes the arguments of :class:`sb3_sgfd.common.encoder_sac.EncoderSAC` (``representation`` is
    ``"ambs"``; its hyperparameters go in ``representation_kwargs``). ``SGFD_SAC`` with the same arguments is
    the SGFD paper's agent.
    """

    fixed_representation: ClassVar[str | None] = "ambs"

    #: AMBS's values of EncoderSAC's arguments, where the caller gives none
    defaults: ClassVar[dict[str, Any]] = {
        "encoder_tau": 0.05,
        "actor_update_interval": 2,
        "augmentation_views": 2,
        "max_grad_norm": 40.0,
    }

    def __init__(self, policy: Any, env: Any, **kwargs: Any) -> None:
        super().__init__(policy, env, **{**self.defaults, **kwargs})
