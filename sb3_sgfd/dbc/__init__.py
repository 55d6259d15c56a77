"""DBC (Zhang et al., ICLR 2021): the encoder's distances made a bisimulation metric."""

from sb3_sgfd.dbc.dbc import DBC, DBCRepresentation

__all__ = ["DBC", "DBCRepresentation"]
