"""SGFD for Stable-Baselines3: saliency-guided features decorrelation by sample reweighting, and the
visual-RL agents of the paper's tables (DBC, AMBS, TED, SGQN) on one SAC training loop."""

from sb3_sgfd.ambs import AMBS
from sb3_sgfd.buffers import DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.dbc import DBC
from sb3_sgfd.encoder_sac import EncoderSAC
from sb3_sgfd.policies import (
    AMBSPolicy,
    CnnPolicy,
    EncoderMlpPolicy,
    MlpPolicy,
    PixelEncoder,
    SGFDPolicy,
)
from sb3_sgfd.sac import SGFD_SAC
from sb3_sgfd.sgqn import SGQN
from sb3_sgfd.ted import TED

__version__ = "0.1.0"

__all__ = [
    "AMBS",
    "DBC",
    "SGFD_SAC",
    "SGQN",
    "TED",
    "AMBSPolicy",
    "CnnPolicy",
    "DomainReplayBuffer",
    "DomainReplayBufferSamples",
    "EncoderMlpPolicy",
    "EncoderSAC",
    "MlpPolicy",
    "PixelEncoder",
    "SGFDPolicy",
    "__version__",
]
