"""AMBS (Chen & Pan, ICLR 2022): a behavioural metric learnt by meta-learners on the encoder's two halves."""

from sb3_sgfd.ambs.ambs import AMBS, AMBSRepresentation
from sb3_sgfd.ambs.policies import AMBSEncoder, AMBSPolicy

__all__ = ["AMBS", "AMBSEncoder", "AMBSPolicy", "AMBSRepresentation"]
