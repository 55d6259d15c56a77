"""AMBS's policy: the shared encoder of :class:`sb3_sgfd.common.policies.SharedEncoderPolicy` with its features
split into a reward half and a dynamics half, scaled by a learned ratio."""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from sb3_sgfd.ambs.checks import check_reward_dim
from sb3_sgfd.common.policies import MlpEncoder, PixelEncoder, SharedEncoderPolicy


class AMBSEncoder(BaseFeaturesExtractor):
    """
    AMBS's encoder (Chen & Pan, 2022): features split into a reward part (the first ``reward_dim``) and a
    dynamics part, scaled by a learned ratio (c, 1 - c) = softmax(ratio) before the Q heads. The critic loss
    trains the ratio; the behavioural metric measures the unscaled features (``embed``).

    :param observation_space: Image (channel-first) or flat observation space
    :param features_dim: Size of the latent vector z
    :param reward_dim: Features of the reward part (AMBS: half of them)
    :param normalized_image: The images are already scaled (the policy's ``normalize_images=False`` sets it)
    :param encoder_kwargs: Arguments of the trunk, :class:`PixelEncoder` for images, :class:`MlpEncoder` else
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        features_dim: int = 50,
        reward_dim: int | None = None,
        normalized_image: bool = False,
        **encoder_kwargs: Any,
    ) -> None:
        super().__init__(observation_space, features_dim)
        reward_dim = features_dim // 2 if reward_dim is None else reward_dim
        check_reward_dim(reward_dim, features_dim)
        self.reward_dim = reward_dim
        if len(observation_space.shape) == 3:  # images (PixelEncoder checks that they are)
            self.trunk: nn.Module = PixelEncoder(
                observation_space, features_dim, normalized_image=normalized_image, **encoder_kwargs
            )
        else:
            self.trunk = MlpEncoder(observation_space, features_dim, **encoder_kwargs)
        # (0, 0): c = 1 - c = 0.5 at the start, as AMBS
        self.ratio = nn.Parameter(th.zeros(2))

    def embed(self, observations: th.Tensor) -> th.Tensor:
        """The unscaled features of (preprocessed) observations."""
        return self.trunk(observations)

    def reward_weight(self) -> th.Tensor:
        """c, the weight of the reward part."""
        return th.softmax(self.ratio, dim=0)[0]

    def scaled(self, features: th.Tensor) -> th.Tensor:
        """Unscaled features (``embed``'s) scaled by the ratio: what ``forward`` returns for them."""
        c = th.softmax(self.ratio, dim=0)
        scale = th.cat([c[:1].expand(self.reward_dim), c[1:].expand(self.features_dim - self.reward_dim)])
        return features * scale

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.scaled(self.embed(observations))


class AMBSPolicy(SharedEncoderPolicy):
    """:class:`SharedEncoderPolicy` with AMBS's ratio-scaled :class:`AMBSEncoder` (pixel or state trunk)."""

    default_features_extractor_class = AMBSEncoder
