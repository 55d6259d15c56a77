"""SGFD (saliency-guided features decorrelation): SAC whose losses are reweighted per sample, its settings, and
its two readings of the weights (the paper's and the authors' code's)."""

from sb3_sgfd.sgfd.settings import SGFDSettings
from sb3_sgfd.sgfd.sgfd_sac import SGFD_SAC

__all__ = ["SGFD_SAC", "SGFDSettings"]
