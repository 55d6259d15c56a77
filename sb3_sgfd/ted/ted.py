"""TED (Dunion et al., ICLR 2023): SAC whose encoder learns to tell consecutive steps from other pairs."""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.common.encoder_sac import EncoderSAC
from sb3_sgfd.common.policies import EncoderMlpPolicy
from sb3_sgfd.common.representation import Agent, Batch, Representation, register, step
from sb3_sgfd.common.validation import check_non_negative
from sb3_sgfd.ted.losses import TEDClassifier, ted_loss


@register("ted")
class TEDRepresentation(Representation):
    """
    TED's objective, after the critic's step: ``ted_coef * ted_loss`` on the online features of o_t and the
    target encoder's features of o_t+1 (positives), of another sample's next observation and of a
    non-adjacent observation of the same episode (negatives), one Adam step on the classifier and the
    encoder. The replay buffer samples the same-episode observations (``same_episode_negatives``, set here);
    with augmentation each gets its own random shift, as the official code's RAD base does.

    :param ted_coef: Weight of the TED loss (TED: 1)
    :param ted_lr: Adam learning rate of the classifier and the encoder's TED step (TED: 1e-3)
    """

    needs_same_episode: ClassVar[bool] = True

    # on states, a learned MLP encoder: the objective trains it
    policy_aliases: ClassVar[dict[str, type[SACPolicy]]] = {"MlpPolicy": EncoderMlpPolicy}

    def __init__(self, ted_coef: float = 1.0, ted_lr: float = 1e-3) -> None:
        super().__init__()
        check_non_negative(ted_coef=ted_coef, ted_lr=ted_lr)
        self.ted_coef, self.ted_lr = ted_coef, ted_lr

    def setup(self, model: Agent) -> None:
        encoder = model.critic.features_extractor
        self.classifier = TEDClassifier(encoder.features_dim)
        self.optimizer = th.optim.Adam([*self.classifier.parameters(), *encoder.parameters()], lr=self.ted_lr)

    def update(self, model: Agent, batch: Batch) -> dict[str, th.Tensor]:
        critic, target = model.critic, model.critic_target
        same_episode = batch.replay_data.same_episode_observations
        if same_episode is None:
            raise RuntimeError("TED needs the replay buffer's same_episode_observations (DomainReplayBuffer)")
        z = critic.extract_features(batch.observations[0], critic.features_extractor)
        with th.no_grad():
            next_z = target.extract_features(batch.next_observations[0], target.features_extractor)
            same_z = target.extract_features(model.augment(same_episode)[0], target.features_extractor)
        loss = ted_loss(self.classifier, z, next_z, same_z, self.generator)
        step(self.ted_coef * loss, self.optimizer)
        return {"ted_loss": loss.detach()}


class TED(EncoderSAC):
    """
    TED: SAC (with RAD's random shift: one augmented view) whose encoder is trained by the critic and by the
    temporal-disentanglement classifier (:class:`TEDRepresentation`); critic and encoder tau 0.01, actor every
    2 steps. TED's fine-tuning phase on the test environment is not part of it. Takes the arguments of
    :class:`sb3_sgfd.common.encoder_sac.EncoderSAC` (``representation`` is ``"ted"``; its hyperparameters go in
    ``representation_kwargs``).
    """

    fixed_representation: ClassVar[str | None] = "ted"

    #: TED's values of EncoderSAC's arguments, where the caller gives none
    defaults: ClassVar[dict[str, Any]] = {"actor_update_interval": 2, "augmentation_views": 1}

    def __init__(self, policy: Any, env: Any, **kwargs: Any) -> None:
        super().__init__(policy, env, **{**self.defaults, **kwargs})
