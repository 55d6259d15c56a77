"""SGFD for Stable-Baselines3: saliency-guided features decorrelation by sample reweighting, and the
visual-RL agents of the paper's tables (DBC, AMBS, TED, SGQN) on one SAC training loop.

One folder per algorithm (``sgfd/``, ``ambs/``, ``dbc/``, ``ted/``, ``sgqn/``: the algorithm, its policy if it has
one, its math), and what they share in ``common/``."""

from sb3_sgfd.ambs import AMBS, AMBSPolicy
from sb3_sgfd.common.buffers import DomainDictReplayBuffer, DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.common.encoder_sac import EncoderSAC
from sb3_sgfd.common.policies import (
    CnnPolicy,
    EncoderMlpPolicy,
    MlpPolicy,
    MultiInputPolicy,
    PixelEncoder,
    SGFDPolicy,
    SharedEncoderPolicy,
)
from sb3_sgfd.common.version import __version__
from sb3_sgfd.dbc import DBC
from sb3_sgfd.sgfd import SGFD_SAC, SGFDSettings
from sb3_sgfd.sgqn import SGQN
from sb3_sgfd.ted import TED

__all__ = [
    "AMBS",
    "DBC",
    "SGFD_SAC",
    "SGQN",
    "TED",
    "AMBSPolicy",
    "CnnPolicy",
    "DomainDictReplayBuffer",
    "DomainReplayBuffer",
    "DomainReplayBufferSamples",
    "EncoderMlpPolicy",
    "EncoderSAC",
    "MlpPolicy",
    "MultiInputPolicy",
    "PixelEncoder",
    "SGFDPolicy",
    "SGFDSettings",
    "SharedEncoderPolicy",
    "__version__",
]
