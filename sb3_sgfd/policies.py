"""The policies by the path yaml files and saved models name (``policy: sb3_sgfd.policies.CnnPolicy``); they live in
:mod:`sb3_sgfd.common.policies` (its ``__all__``) and, AMBS's, :mod:`sb3_sgfd.ambs.policies`."""

from sb3_sgfd.ambs.policies import AMBSEncoder, AMBSPolicy
from sb3_sgfd.common.policies import *  # noqa: F403 (a re-export: the names of its __all__)
from sb3_sgfd.common.policies import __all__ as _COMMON_NAMES

__all__ = ["AMBSEncoder", "AMBSPolicy", *_COMMON_NAMES]
