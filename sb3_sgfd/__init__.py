"""SGFD for Stable-Baselines3: saliency-guided features decorrelation by sample reweighting, and the
visual-RL agents of the paper's tables (DBC, AMBS, TED, SGQN) on one SAC training loop.

One folder per algorithm (``sgfd/``, ``ambs/``, ``dbc/``, ``ted/``, ``sgqn/``: the algorithm, its policy if it has
one, its math), and what they share in ``common/``."""

from importlib import metadata
from pathlib import Path

from sb3_sgfd import _legacy
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
from sb3_sgfd.dbc import DBC
from sb3_sgfd.sgfd import SGFD_SAC, SGFDSettings
from sb3_sgfd.sgqn import SGQN
from sb3_sgfd.ted import TED

_legacy.install()

# The installed distribution's version, which pip took from sgfd_envs/version.txt (the one file both distributions
# read), so an install and the file cannot disagree. A checkout used without installing it has no metadata: it
# reads that same file beside the package.
try:
    __version__ = metadata.version("sb3-sgfd")
except metadata.PackageNotFoundError:
    __version__ = (Path(__file__).resolve().parents[1] / "sgfd_envs" / "version.txt").read_text().strip()

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
