"""A run's data files read as data (docs/trust.md): its YAML, its evaluations during training, the step counts of its
final model, and the values of its configuration the zoo uses itself, each within the limits of
:mod:`sgfd_zoo.runs.bounded` and checked (:mod:`sgfd_zoo.runs.fields`) before it is used. Runs and records alike
(:mod:`sgfd_zoo.runs.folders`, :mod:`sgfd_zoo.runs.records`) read through these functions.
"""

from __future__ import annotations

import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sgfd_zoo.runs.bounded import RefusedFile, UnreadableFile, load_json, load_npz, read_text, zip_member
from sgfd_zoo.runs.fields import finite_number, whole_number
from sgfd_zoo.runs.safe import load_yaml


def read_yaml(path: Path) -> tuple[dict[str, Any], str | None]:
    """The mapping in a yaml file ({} when absent) and, when it cannot be read, why; a
    :class:`~sgfd_zoo.runs.bounded.RefusedFile` when it holds a tag that names Python code (it is data only) or is
    over a limit (:func:`~sgfd_zoo.runs.bounded.check_yaml`)."""
    if not path.exists():
        return {}, None
    try:
        loaded = load_yaml(read_text(path, "MAX_YAML_BYTES"), path)
        # rl-zoo3 writes an OrderedDict, or a list of (key, value) pairs
        return (dict(loaded) if loaded else {}), None
    except (RefusedFile, UnreadableFile):
        raise
    except (OSError, ValueError, TypeError, yaml.YAMLError) as error:
        return {}, f"{path} is unreadable ({type(error).__name__}: {str(error).splitlines()[0]})"


def read_evaluations(path: Path) -> dict[str, np.ndarray] | None:
    """``timesteps`` (n evaluations), ``results`` (n x episodes) and what else an ``evaluations_<split>.npz``
    holds, or None without one; an :class:`UnreadableFile` when it is not such a file (arrays of Python objects
    included: they would be pickles, which are never loaded), refused over a limit
    (:func:`~sgfd_zoo.runs.bounded.load_npz`) or when it holds a return that is not finite or a step that is not a
    whole number."""
    if not path.exists():
        return None
    arrays = load_npz(path)
    steps, results = arrays.get("timesteps"), arrays.get("results")
    if (
        steps is None
        or results is None
        or steps.dtype.kind not in "iuf"
        or results.dtype.kind not in "iuf"
        or steps.ndim != 1
        or results.shape[:1] != steps.shape
        or results.ndim != 2
    ):
        held = ", ".join(f"{key} {array.dtype} {array.shape}" for key, array in arrays.items()) or "nothing"
        raise UnreadableFile(
            f"{path} is not an evaluations file (expected numbers: timesteps (n) and results (n x episodes); it "
            f"holds {held})"
        )
    if not np.isfinite(results).all():
        raise RefusedFile(f"{path}: refused: its results hold {results[~np.isfinite(results)][0]}, not a finite return")
    if steps.size and not (np.isfinite(steps).all() and (steps >= 0).all() and (steps == np.round(steps)).all()):
        raise RefusedFile(f"{path}: refused: its timesteps are not all whole numbers >= 0")
    return arrays


def final_model_steps(path: Path) -> int | None:
    """The step count of a whole final model that reached the total it was trained for, else None. Reads its
    ``data`` member only, within :data:`~sgfd_zoo.runs.bounded.MAX_ZIP_MEMBER_BYTES` (it loads no model)."""
    try:
        data = load_json(zip_member(path, "data"), f"{path} (member data)")
        steps, total = int(data["num_timesteps"]), int(data["_total_timesteps"])
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, RuntimeError, UnreadableFile):
        return None
    return steps if 0 < total <= steps else None


def config_value(config: Mapping[str, Any], key: str, source: Path, kind: str) -> Any:
    """``config[key]`` (None when absent) when it is of ``kind``, else refused naming the file:

    - ``"fraction"``: a finite number in [0, 1] (``accuracy_threshold``);
    - ``"name"``: a string (``reading``);
    - ``"seed"``: a whole number >= 0;
    - ``"frames"``: a whole number >= 0, or false (``frame_stack``);
    - ``"mapping"``: a dict of settings with string keys (``env_kwargs``).
    """
    value = config.get(key)
    if value is None:
        return None
    where = f"{source} {key}"
    if kind == "fraction":
        number = finite_number(value, "the value", where, low=0.0)
        if number > 1:
            raise UnreadableFile(f"{where} is unreadable ({value!r} is not a fraction in [0, 1])")
        return number
    if kind == "seed":
        return whole_number(value, "the value", where, 0, 2**32 - 1)
    if kind == "frames":
        return value if value is False else whole_number(value, "the value", where)
    if kind == "mapping" and isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return value
    if kind == "name" and isinstance(value, str):
        return value
    raise UnreadableFile(f"{where} is unreadable ({value!r} is not {'a string' if kind == 'name' else 'a mapping'})")
