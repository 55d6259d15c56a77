"""SGFD for Stable-Baselines3: saliency-guided features decorrelation by sample reweighting."""

from sb3_sgfd.buffers import DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.policies import CnnPolicy, MlpPolicy, PixelEncoder, SGFDPolicy
from sb3_sgfd.sac import SGFD_SAC

__version__ = "0.1.0"

__all__ = [
    "SGFD_SAC",
    "CnnPolicy",
    "DomainReplayBuffer",
    "DomainReplayBufferSamples",
    "MlpPolicy",
    "PixelEncoder",
    "SGFDPolicy",
    "__version__",
]
