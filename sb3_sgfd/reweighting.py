"""SGFD's weights as functions of tensors (random Fourier features, the decorrelation loss, the weight solver), by
the path earlier code imports them from; they live in :mod:`sb3_sgfd.sgfd.functional`, whose public names (its
``__all__``) this module gives."""

from sb3_sgfd.sgfd.functional import *  # noqa: F403 (a re-export: the names of its __all__)
from sb3_sgfd.sgfd.functional import __all__ as __all__
