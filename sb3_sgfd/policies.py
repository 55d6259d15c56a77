"""The policies by the path yaml files and saved models name (``policy: sb3_sgfd.policies.CnnPolicy``); they live in
:mod:`sb3_sgfd.common.policies` and, AMBS's, :mod:`sb3_sgfd.ambs.policies`."""

from sb3_sgfd.ambs.policies import AMBSEncoder, AMBSPolicy
from sb3_sgfd.common.policies import (
    CnnPolicy,
    DetachedEncoderActor,
    EncoderMlpPolicy,
    MlpEncoder,
    MlpPolicy,
    MultiInputPolicy,
    PixelEncoder,
    SGFDPolicy,
    SharedEncoderPolicy,
)

__all__ = [
    "AMBSEncoder",
    "AMBSPolicy",
    "CnnPolicy",
    "DetachedEncoderActor",
    "EncoderMlpPolicy",
    "MlpEncoder",
    "MlpPolicy",
    "MultiInputPolicy",
    "PixelEncoder",
    "SGFDPolicy",
    "SharedEncoderPolicy",
]
