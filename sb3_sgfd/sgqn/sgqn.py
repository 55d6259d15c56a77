"""SGQN (Bertoin et al., NeurIPS 2022): SAC whose critic keeps its value on its own salient pixels."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
import torch as th
from stable_baselines3.common.preprocessing import get_action_dim

from sb3_sgfd.common.encoder_sac import EncoderSAC
from sb3_sgfd.common.representation import Agent, Batch, Representation, register, step
from sb3_sgfd.common.utils import image_shape
from sb3_sgfd.common.validation import check_non_negative
from sb3_sgfd.sgqn.attribution import (
    AttributionDecoder,
    attribution_loss,
    attribution_mask,
    consistency_loss,
    guided_backprop,
    mask_observations,
    overlay,
)
from sgfd_envs.limits import check_image_file

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")


@register("sgqn")
class SGQNRepresentation(Representation):
    """
    SGQN's two additions to SAC on pixels:

    - in the critic loss, the consistency term ``consistency_coef * 0.5 * sum_k MSE(Q_k(s, a), Q_k(s * M, a))``,
      M the top-(1 - ``quantile``) guided-backprop attribution of Q1 before the critic's step;
    - after the critic's step (every ``aux_update_interval`` steps), the attribution predictor: a decoder on the
      critic encoder's features of an overlaid observation, trained with the encoder by binary cross-entropy
      to predict the mask of the updated critic.

    The overlay images (Places365 in the official code, which cannot be downloaded here) come from
    ``overlay_images`` or ``overlay_dir``; the zoo passes ``sgfd_envs``' procedural overlay bank.

    :param quantile: Attribution quantile of the mask (SGQN: 0.9 by default, 0.98 in its scripts)
    :param consistency_coef: Weight of the consistency term (SGQN: 1, with its 0.5 inside)
    :param attribution_coef: Weight of the predictor's loss (SGQN: 1)
    :param aux_lr: Adam learning rate of the predictor and the encoder's predictor step (SGQN: 3e-4)
    :param aux_update_interval: Train the predictor every this many gradient steps (SGQN: 2)
    :param overlay_alpha: Weight of the overlay image (SGQN: 0.5)
    :param overlay_images: (N, H, W, 3) uint8 images, resized to the observations if needed
    :param overlay_dir: A folder of images, used when ``overlay_images`` is None
    """

    #: The overlay images, (N, 3, H, W) uint8 on the model's device (a buffer, not saved)
    bank: th.Tensor

    def __init__(
        self,
        quantile: float = 0.9,
        consistency_coef: float = 1.0,
        attribution_coef: float = 1.0,
        aux_lr: float = 3e-4,
        aux_update_interval: int = 2,
        overlay_alpha: float = 0.5,
        overlay_images: np.ndarray | None = None,
        overlay_dir: str | None = None,
    ) -> None:
        super().__init__()
        if not 0 < quantile < 1:
            raise ValueError(f"quantile must be in (0, 1), got {quantile!r}")
        check_non_negative(consistency_coef=consistency_coef, attribution_coef=attribution_coef, aux_lr=aux_lr)
        if isinstance(aux_update_interval, bool) or not isinstance(aux_update_interval, int) or aux_update_interval < 1:
            raise ValueError(f"aux_update_interval must be a positive int, got {aux_update_interval!r}")
        if overlay_images is None and overlay_dir is None:
            raise ValueError(
                "SGQN needs overlay images: representation_kwargs overlay_images=(N, H, W, 3) uint8 array or "
                "overlay_dir=a folder of images (sgfd-zoo passes sgfd_envs.backgrounds.overlay_bank)"
            )
        self.quantile, self.consistency_coef, self.attribution_coef = quantile, consistency_coef, attribution_coef
        self.aux_lr, self.aux_update_interval, self.overlay_alpha = aux_lr, aux_update_interval, overlay_alpha
        self.overlay_images, self.overlay_dir = overlay_images, overlay_dir

    def setup(self, model: Agent) -> None:
        channels, height, width = image_shape(model.observation_space)
        if channels % 3 != 0:
            raise ValueError(f"SGQN expects stacked RGB frames (channels a multiple of 3), got {channels} channels")
        encoder = model.critic.features_extractor
        action_dim = get_action_dim(model.action_space)
        self.decoder = AttributionDecoder(encoder.features_dim, action_dim, (channels, height, width))
        self.optimizer = th.optim.Adam([*self.decoder.parameters(), *encoder.parameters()], lr=self.aux_lr)
        if self.overlay_images is not None:
            images = self.overlay_images
        else:
            assert self.overlay_dir is not None  # __init__ requires one of the two
            images = read_images(Path(self.overlay_dir))
        self.register_buffer("bank", image_bank(images, height, width), persistent=False)

    def attribution_mask(self, model: Agent, observations: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """M: the top-(1 - quantile) pixels of each frame by guided backprop of Q1 (the critic as it is now)."""
        attribution = guided_backprop(lambda obs: model.critic(obs, actions)[0], observations, model.critic)
        return attribution_mask(attribution, channels_per_frame=3, quantile=self.quantile)

    def critic_loss(
        self, model: Agent, observations: th.Tensor, actions: th.Tensor, q_values: tuple[th.Tensor, ...]
    ) -> th.Tensor | None:
        mask = self.attribution_mask(model, observations, actions)
        masked_q_values = model.critic(mask_observations(observations, mask, self.generator), actions)
        loss = consistency_loss(q_values, masked_q_values)
        model.record("sgqn/consistency_loss", loss.detach())
        return self.consistency_coef * loss

    def plan(self, update_index: int) -> tuple:
        # whether the attribution predictor learns at this step
        return (update_index % self.aux_update_interval == 0,)

    def update(self, model: Agent, batch: Batch) -> dict[str, th.Tensor]:
        (predictor_learns,) = batch.plan
        if not predictor_learns:
            return {}
        observations, actions = batch.observations[0], batch.replay_data.actions
        mask = self.attribution_mask(model, observations, actions)
        overlaid = overlay(observations, self.bank, self.overlay_alpha, generator=self.generator)
        critic = model.critic
        logits = self.decoder(critic.extract_features(overlaid, critic.features_extractor), actions)
        loss = attribution_loss(logits, mask)
        step(self.attribution_coef * loss, self.optimizer)
        return {"attribution_loss": loss.detach(), "salient_fraction": mask.float().mean()}


def read_images(folder: Path) -> np.ndarray:
    """Every image of ``folder`` (sorted), as (N, H, W, 3) uint8 RGB at the size of the first; each at most
    ``sgfd_envs.limits.MAX_BACKGROUND_PIXELS`` pixels (refused in one line).

    :param folder: a folder of images
    """
    if not folder.is_dir():
        raise ValueError(f"overlay_dir {str(folder)!r} is not a folder")
    files = sorted(path for path in folder.iterdir() if path.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"overlay_dir {str(folder)!r} holds no image ({', '.join(IMAGE_SUFFIXES)})")
    images: list[np.ndarray] = []
    for path in files:
        check_image_file(path, "overlay_dir")  # its pixels bounded from its header, before OpenCV decodes it
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"overlay_dir: cannot read {path}")
        if images:
            bgr = cv2.resize(bgr, (images[0].shape[1], images[0].shape[0]), interpolation=cv2.INTER_AREA)
        images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    return np.stack(images)


def image_bank(images: np.ndarray, height: int, width: int) -> th.Tensor:
    """(N, H, W, 3) uint8 images as a (N, 3, height, width) uint8 tensor, resized where needed.

    :param images: the overlay images
    :param height: observation height
    :param width: observation width
    """
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8 or len(images) == 0:
        raise ValueError(f"overlay_images must be a (N, H, W, 3) uint8 array, got {images.dtype} {images.shape}")
    if images.shape[1:3] != (height, width):
        images = np.stack([cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA) for image in images])
    return th.as_tensor(images).permute(0, 3, 1, 2).contiguous()


class SGQN(EncoderSAC):
    """
    SGQN: SAC on pixels (random shift: one augmented view) with SGQN's consistency term and attribution
    predictor (:class:`SGQNRepresentation`); encoder tau 0.05, actor every 2 steps. Takes the arguments of
    :class:`sb3_sgfd.common.encoder_sac.EncoderSAC` (``representation`` is ``"sgqn"``; its hyperparameters, and the
    overlay images, go in ``representation_kwargs``).
    """

    fixed_representation: ClassVar[str | None] = "sgqn"

    #: SGQN's values of EncoderSAC's arguments, where the caller gives none
    defaults: ClassVar[dict[str, Any]] = {"encoder_tau": 0.05, "actor_update_interval": 2, "augmentation_views": 1}

    def __init__(self, policy: Any, env: Any, **kwargs: Any) -> None:
        super().__init__(policy, env, **{**self.defaults, **kwargs})
