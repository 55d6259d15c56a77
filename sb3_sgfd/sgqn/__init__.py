"""SGQN (Bertoin et al., NeurIPS 2022): Q made consistent on its own salient pixels."""

from sb3_sgfd.sgqn.sgqn import SGQN, SGQNRepresentation

__all__ = ["SGQN", "SGQNRepresentation"]
