"""Shared pytest setup."""

import os

import pytest
import torch

# The tests' Ray instances are local: Ray binds them to loopback when multi-node clusters are off, a switch it reads
# when it is imported. `sgfd-zoo sweep` sets it itself before it imports Ray; test modules import Ray first.
# (test_a_local_sweeps_ray_listens_on_loopback_only checks the zoo's own setting, in a process without this one.)
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")

# sgfd_envs picks MuJoCo's headless OpenGL backend (EGL) unless MUJOCO_GL is set; that must happen
# before any test module imports dm_control, so import it before collection.
import sgfd_envs  # noqa: F401

# The networks in these tests are tiny: torch's intra-op threads only fight each other (and the
# renderer) for the CPU. One thread makes the suite several times faster on 2 cores.
torch.set_num_threads(1)


@pytest.hookimpl(tryfirst=True)  # before xdist's, which reads the groups
def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` skip, with the reason said, where no CUDA device is there; tests marked ``ray`` run
    on one xdist worker, one after another (two local Ray instances at once would compete for the cores and
    their ports), and first."""
    for item in items:
        if item.get_closest_marker("ray") is not None:
            item.add_marker(pytest.mark.xdist_group("ray"))
    # The Ray tests first: their worker works through them while the others share out the rest, the slow ones
    # first, so that the run does not end on one long test while the other worker idles.
    items.sort(key=lambda item: (item.get_closest_marker("ray") is None, item.get_closest_marker("slow") is None))
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device (none here)")
    for item in items:
        if "cuda" in item.keywords:
            item.add_marker(skip)
