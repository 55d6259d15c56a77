"""TED (Dunion et al., ICLR 2023): temporal disentanglement by a classifier of temporal pairs."""

from sb3_sgfd.ted.ted import TED, TEDRepresentation

__all__ = ["TED", "TEDRepresentation"]
