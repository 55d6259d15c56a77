"""DeepMind Control generalisation benchmark tasks as gymnasium ids.

``import sgfd_envs`` registers every id of :data:`ENV_IDS`:

- :data:`SGFD_IDS`, the paper's ten: ``SGFD/{walker-walk,cheetah-run,finger-spin,walker-run,finger-turn}-v0``,
  distracting backgrounds (splits ``train``, ``test``), and ``SGFD/MT-...-v0``, modified morphology (splits
  ``train``, ``interpolation``, ``extrapolation``); by default the paper's tasks as its authors' code built them
  (one still image per domain under their colour key; HiP-BMDP's robot files), the earlier envs a keyword away
  (:mod:`sgfd_envs.families`);
- ``SGFD/CW-{picking,pushing}-v0`` (:data:`CAUSAL_WORLD_IDS`): Causal World with the block's mass or size
  per domain, the MT splits; making them needs ``pip install -e ".[causalworld]"``;
- :data:`BENCHMARK_IDS`: the benchmarks of the field on dm_control's own tasks, ``DMCGB/<task>-v0``,
  ``DMCGB2/<task>-v0`` and ``DCS/<task>-v0`` (:mod:`sgfd_envs.benchmarks`), the split being the test mode.
"""

import os
import sys
import warnings

# dm_control picks its OpenGL backend when it is first imported (here: when the first env is made, since importing
# sgfd_envs and gym.spec load no simulator); EGL renders with no display and no GPU (Mesa llvmpipe). A value the
# user set wins.
if sys.platform.startswith("linux") and "MUJOCO_GL" not in os.environ:
    if "dm_control._render" in sys.modules:
        warnings.warn(
            "dm_control was imported before sgfd_envs with MUJOCO_GL unset, so it chose its OpenGL backend "
            "itself (GLFW needs a display). Import sgfd_envs first or set MUJOCO_GL=egl.",
            stacklevel=2,
        )
    os.environ["MUJOCO_GL"] = "egl"

from sgfd_envs.registry import (
    BENCHMARK_IDS,
    CAUSAL_WORLD_IDS,
    ENV_IDS,
    SGFD_IDS,
    evaluation_modes,
    n_domains,
    register_envs,
    splits,
    stand_in,
    test_splits,
)
from sgfd_envs.vec_env import make_domain_vec_env

register_envs()

__all__ = [
    "BENCHMARK_IDS",
    "CAUSAL_WORLD_IDS",
    "ENV_IDS",
    "SGFD_IDS",
    "evaluation_modes",
    "make_domain_vec_env",
    "n_domains",
    "splits",
    "stand_in",
    "test_splits",
]
