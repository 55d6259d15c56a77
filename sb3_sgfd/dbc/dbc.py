"""DBC (Zhang et al., ICLR 2021): SAC whose encoder also learns the bisimulation metric."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.sac.policies import SACPolicy
from torch.nn import functional as F

from sb3_sgfd.common.dynamics import ProbabilisticTransitionModel, RewardDecoder, gaussian_nll
from sb3_sgfd.common.encoder_sac import EncoderSAC
from sb3_sgfd.common.policies import EncoderMlpPolicy
from sb3_sgfd.common.representation import Agent, Batch, Representation, register, step
from sb3_sgfd.common.validation import check_choice, check_non_negative
from sb3_sgfd.dbc.losses import bisimulation_loss, bisimulation_loss_code

#: DBC's metric forms (``DBCRepresentation(metric=...)``): its authors' code's, and its paper's.
DBC_METRICS: dict[str, Callable[[th.Tensor, th.Tensor, th.Tensor, th.Tensor, th.Tensor, float], th.Tensor]] = {
    "code": bisimulation_loss_code,
    "paper": bisimulation_loss,
}


@register("dbc")
class DBCRepresentation(Representation):
    """
    DBC's encoder objective, after the critic's step:
    ``bisim_coef * bisimulation_loss + transition_coef * (transition NLL + reward MSE)``, one Adam step on the
    encoder (the critic's, which its loss trains too) and one on the transition model and reward decoder.
    The bisimulation target uses the transition model's (detached) predictions for the replayed actions; the
    NLL is taken against the online encoder's detached next features, as the official code does.

    :param metric: ``"code"``: the loss as DBC's code computes it (per-dimension Huber distances and W2, the
        default: the published numbers and ``bisim_coef`` 0.5 come from it); ``"paper"``: the paper's formula
        (L1 norm of the encodings, the W2 norm over the latent; about 1000x larger at 50 features, see
        :func:`sb3_sgfd.dbc.losses.bisimulation_loss_code`)
    :param bisim_coef: Weight of the bisimulation loss (DBC: 0.5)
    :param transition_coef: Weight of the transition NLL plus the reward MSE (DBC: 1)
    :param hidden_dim: Width of the transition model and reward decoder (DBC: 512)
    :param encoder_lr: Adam learning rate of the encoder's auxiliary step
    :param decoder_lr: Adam learning rate of the transition model and reward decoder
    :param decoder_weight_decay: Their weight decay (DBC's scripts: 1e-7)
    """

    # on states, a learned MLP encoder: the objective trains it
    policy_aliases: ClassVar[dict[str, type[SACPolicy]]] = {"MlpPolicy": EncoderMlpPolicy}

    def __init__(
        self,
        metric: str = "code",
        bisim_coef: float = 0.5,
        transition_coef: float = 1.0,
        hidden_dim: int = 512,
        encoder_lr: float = 1e-3,
        decoder_lr: float = 1e-3,
        decoder_weight_decay: float = 1e-7,
    ) -> None:
        super().__init__()
        check_choice("metric", metric, DBC_METRICS)
        check_non_negative(bisim_coef=bisim_coef, transition_coef=transition_coef)
        self.metric = metric
        self.bisim_coef, self.transition_coef = bisim_coef, transition_coef
        self.hidden_dim = hidden_dim
        self.encoder_lr, self.decoder_lr, self.decoder_weight_decay = encoder_lr, decoder_lr, decoder_weight_decay

    def setup(self, model: Agent) -> None:
        features_dim = model.critic.features_extractor.features_dim
        action_dim = get_action_dim(model.action_space)
        self.transition = ProbabilisticTransitionModel(features_dim, action_dim, self.hidden_dim)
        self.reward_decoder = RewardDecoder(features_dim, self.hidden_dim)
        self.encoder_optimizer = th.optim.Adam(model.critic.features_extractor.parameters(), lr=self.encoder_lr)
        self.decoder_optimizer = th.optim.Adam(
            [*self.transition.parameters(), *self.reward_decoder.parameters()],
            lr=self.decoder_lr,
            weight_decay=self.decoder_weight_decay,
        )

    def update(self, model: Agent, batch: Batch) -> dict[str, th.Tensor]:
        critic = model.critic
        data = batch.replay_data
        z = critic.extract_features(batch.observations[0], critic.features_extractor)
        with th.no_grad():
            next_z = critic.extract_features(batch.next_observations[0], critic.features_extractor)
            predicted: tuple[th.Tensor, th.Tensor] = self.transition(z, data.actions)
        perm = th.randperm(len(z), generator=self.generator, device=self.generator.device).to(z.device)
        bisim = DBC_METRICS[self.metric](z, data.rewards, *predicted, perm, model.gamma)
        mu, sigma = self.transition(z, data.actions)
        nll = gaussian_nll(mu, sigma, next_z)
        next_sample = self.transition.sample(z, data.actions, self.generator)
        reward_loss = F.mse_loss(self.reward_decoder(next_sample), data.rewards)
        loss = self.bisim_coef * bisim + self.transition_coef * (nll + reward_loss)
        step(loss, self.encoder_optimizer, self.decoder_optimizer)
        return {"bisim_loss": bisim.detach(), "transition_nll": nll.detach(), "reward_loss": reward_loss.detach()}


class DBC(EncoderSAC):
    """
    Deep Bisimulation for Control: SAC with the paper's encoder trained by the critic and by DBC's
    bisimulation objective (:class:`DBCRepresentation`), critic target tau 0.01 and encoder tau 0.05, actor
    every 2 steps. Takes the arguments of :class:`sb3_sgfd.common.encoder_sac.EncoderSAC` (``representation`` is
    ``"dbc"``; its hyperparameters go in ``representation_kwargs``).
    """

    fixed_representation: ClassVar[str | None] = "dbc"

    #: DBC's values of EncoderSAC's arguments, where the caller gives none
    defaults: ClassVar[dict[str, Any]] = {"encoder_tau": 0.05, "actor_update_interval": 2}

    def __init__(self, policy: Any, env: Any, **kwargs: Any) -> None:
        super().__init__(policy, env, **{**self.defaults, **kwargs})
