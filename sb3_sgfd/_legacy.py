"""The module paths of version 0.1.0, before each algorithm got its folder: models, replay buffers and yaml files
saved then name classes by those paths (``sb3_sgfd.policies.MlpPolicy``, ``sb3_sgfd.buffers.replay``), and
code written then imports from them (``sb3_sgfd.reweighting.learn_sample_weights``). Each old path is a module
whose names are looked up in the modules that now hold them, so all of that keeps loading and importing; the
classes keep their new paths, so whatever is saved from now on names those. The buffer modules of the 0.2.0
development versions that were folded into others are kept the same way (saved buffers name only ``replay`` and
``dict_replay``, which stay)."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import Any

#: old module -> the modules its names now live in, searched in this order
MOVED: dict[str, tuple[str, ...]] = {
    "sb3_sgfd.sac": ("sb3_sgfd.sgfd.sgfd_sac",),
    "sb3_sgfd.weighting": ("sb3_sgfd.sgfd.weighting",),
    "sb3_sgfd.weighting_paper": ("sb3_sgfd.sgfd.weighting", "sb3_sgfd.sgfd.decorrelation"),
    "sb3_sgfd.weighting_official": ("sb3_sgfd.sgfd.weighting", "sb3_sgfd.sgfd.decorrelation"),
    "sb3_sgfd.reweighting": (
        "sb3_sgfd.sgfd.functional",
        "sb3_sgfd.sgfd.decorrelation",
        "sb3_sgfd.sgfd.checks",
        "sb3_sgfd.common.validation",
    ),
    "sb3_sgfd.saliency": ("sb3_sgfd.sgfd.weighting", "sb3_sgfd.sgfd.functional"),
    # 0.1.x's sgfd/ files before the weighting was gathered in one module
    "sb3_sgfd.sgfd.saliency": ("sb3_sgfd.sgfd.weighting", "sb3_sgfd.sgfd.functional"),
    "sb3_sgfd.sgfd.paper_reading": ("sb3_sgfd.sgfd.weighting", "sb3_sgfd.sgfd.functional"),
    "sb3_sgfd.sgfd.official_reading": ("sb3_sgfd.sgfd.weighting", "sb3_sgfd.sgfd.decorrelation"),
    "sb3_sgfd.bisimulation": ("sb3_sgfd.common.dynamics", "sb3_sgfd.dbc.losses", "sb3_sgfd.ambs.losses"),
    "sb3_sgfd.temporal": ("sb3_sgfd.ted.losses",),
    "sb3_sgfd.attribution": ("sb3_sgfd.sgqn.attribution",),
    "sb3_sgfd.policies": ("sb3_sgfd.common.policies", "sb3_sgfd.ambs.policies"),
    "sb3_sgfd.encoder_sac": ("sb3_sgfd.common.encoder_sac", "sb3_sgfd.common.utils"),
    "sb3_sgfd.representation": ("sb3_sgfd.common.representation",),
    "sb3_sgfd.augmentation": ("sb3_sgfd.common.augmentation",),
    "sb3_sgfd.transfer": ("sb3_sgfd.common.transfer",),
    "sb3_sgfd.validation": ("sb3_sgfd.common.validation",),
    "sb3_sgfd.buffers": ("sb3_sgfd.common.buffers",),
    "sb3_sgfd.buffers.replay": ("sb3_sgfd.common.buffers.replay",),
    "sb3_sgfd.buffers.domains": ("sb3_sgfd.common.buffers.replay",),
    "sb3_sgfd.buffers.episodes": ("sb3_sgfd.common.buffers.storage",),
    "sb3_sgfd.buffers.frames": ("sb3_sgfd.common.buffers.storage",),
    "sb3_sgfd.buffers.slots": ("sb3_sgfd.common.buffers.storage",),
    # the buffer modules of the 0.2.0 development versions, folded into replay.py and storage.py
    "sb3_sgfd.common.buffers.domains": ("sb3_sgfd.common.buffers.replay",),
    "sb3_sgfd.common.buffers.nstep": ("sb3_sgfd.common.buffers.replay",),
    "sb3_sgfd.common.buffers.episodes": ("sb3_sgfd.common.buffers.storage",),
    "sb3_sgfd.common.buffers.frames": ("sb3_sgfd.common.buffers.storage",),
    "sb3_sgfd.common.buffers.slots": ("sb3_sgfd.common.buffers.storage",),
}


class _MovedModule(ModuleType):
    """An old path: attribute lookups go to the modules that now hold its names."""

    def __init__(self, name: str, targets: Sequence[str]) -> None:
        super().__init__(name, f"Moved: {name} is now {', '.join(targets)}.")
        self._targets = tuple(targets)
        if any(other.startswith(f"{name}.") for other in MOVED):
            self.__path__: list[str] = []  # a package of old submodules

    def __getattr__(self, attribute: str) -> Any:
        if attribute.startswith("__"):
            raise AttributeError(attribute)
        for target in self._targets:
            module = importlib.import_module(target)
            if hasattr(module, attribute):
                return getattr(module, attribute)
        raise AttributeError(
            f"module {self.__name__!r} (now {', '.join(self._targets)}) has no attribute {attribute!r}"
        )

    def __dir__(self) -> list[str]:
        return sorted({name for target in self._targets for name in dir(importlib.import_module(target))})


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old paths of :data:`MOVED`, after every other finder (a real module of that name wins)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return _MovedModule(spec.name, MOVED[spec.name])

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the names are looked up when asked for."""


def install() -> None:
    """Make the old paths importable (once per process)."""
    if not any(isinstance(finder, _MovedModules) for finder in sys.meta_path):
        sys.meta_path.append(_MovedModules())
