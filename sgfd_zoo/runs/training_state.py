"""What a checkpoint needs beyond the model and its replay buffer for a resumed run to continue bit for bit: the
random generators (torch's, numpy's and Python's global ones, the action space's, the model's own), the envs'
state (each sub-env and its wrappers, :class:`sgfd_envs.state.ResumableState`) and the frame stacks of the
VecEnv wrappers. Taken between two env steps (the checkpoint callback's ``on_rollout_start``), put back when the
resumed run's training starts (:class:`RestoreTrainingState`), after everything that builds the run.

On disk it is data, not a pickle (a checkpoint may come from someone else's folder): an ``.npz`` of its arrays,
read with ``allow_pickle=False``, and the structure around them as JSON (:func:`save`, :func:`load`). The pickles of
earlier versions are read by an unpickler that builds only tensors, arrays and containers (:func:`load`).
"""

from __future__ import annotations

import io
import json
import pickle
import random
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecFrameStack

from sgfd_zoo.runs.bounded import UnreadableFile, load_json, load_npz

_NUMPY_CORES = ("numpy.core.multiarray", "numpy._core.multiarray")  # numpy 1's name, numpy 2's


def _vec_layers(env: VecEnv) -> list[VecEnv]:
    layers = [env]
    while isinstance(layers[-1], VecEnvWrapper):
        layers.append(layers[-1].venv)
    return layers


def _generators(model: BaseAlgorithm) -> dict[str, th.Generator]:
    """The model's own generators (EncoderSAC's augmentation, objective and weights), by name."""
    return model.generators() if hasattr(model, "generators") else {}


def unavailable(model: BaseAlgorithm) -> str | None:
    """Why the training state of ``model``'s envs cannot be taken (the first sub-env's reason), or None."""
    env = model.get_env()
    if env is None:
        return None
    try:
        reasons = _vec_layers(env)[-1].env_method("training_state_unavailable")
    except AttributeError:
        return "its envs are not sgfd_envs' (no ResumableState wrapper)"
    return next((reason for reason in reasons if reason is not None), None)


STRUCTURE = "structure.json"  # the member of the .npz holding the JSON around the arrays


def save(model: BaseAlgorithm, path: str) -> None:
    """Write :func:`capture`'s state of ``model`` to ``path`` (an ``.npz``, see the module docstring)."""
    arrays: dict[str, Any] = {}
    structure = json.dumps(_encode(capture(model), arrays))
    arrays[STRUCTURE] = np.frombuffer(structure.encode(), dtype=np.uint8)
    with open(path, "wb") as handle:
        np.savez(handle, allow_pickle=False, **arrays)


def load(path: str | Path) -> dict[str, Any]:
    """The state :func:`save` wrote to ``path``; one an earlier version pickled (``.pkl``) is read by
    :class:`_DataUnpickler`, which builds nothing but tensors, arrays and containers. A ValueError (or an
    UnpicklingError) when the file is not such a state."""
    if Path(path).suffix == ".pkl":
        with open(path, "rb") as handle:
            state = _DataUnpickler(handle).load()
        if not isinstance(state, dict):
            raise ValueError(f"{Path(path).name} is not a training state")
        return state
    try:
        arrays = load_npz(Path(path))  # within the limits of sgfd_zoo.runs.bounded
    except UnreadableFile as error:
        raise ValueError(str(error)) from None
    if STRUCTURE not in arrays:
        raise ValueError(f"{Path(path).name} has no {STRUCTURE}")
    try:
        state = _decode(load_json(arrays.pop(STRUCTURE).tobytes(), f"{path} ({STRUCTURE})"), arrays)
    except TypeError as error:  # e.g. a list as a dict's key
        raise ValueError(f"{Path(path).name} is not a training state ({error})") from None
    if not isinstance(state, dict):
        raise ValueError(f"{Path(path).name} is not a training state")
    return state


# The tree of a state as JSON: each list, tuple and dict a one-key object saying which it is (JSON has no tuple,
# and only strings as keys), each array, tensor and numpy scalar a reference to an array of the .npz.
def _encode(value: Any, arrays: dict[str, Any]) -> Any:
    # (a numpy float64 is a Python float too: it is kept as a numpy scalar, to come back as one)
    if value is None or (isinstance(value, bool | int | float | str) and not isinstance(value, np.generic)):
        return value
    if isinstance(value, list | tuple):
        return {type(value).__name__: [_encode(item, arrays) for item in value]}
    if isinstance(value, dict):
        return {"dict": [[_encode(key, arrays), _encode(item, arrays)] for key, item in value.items()]}
    for kind, array in (
        ("tensor", value.cpu().numpy() if isinstance(value, th.Tensor) else None),
        ("array", value if isinstance(value, np.ndarray) else None),
        ("scalar", np.asarray(value) if isinstance(value, np.generic) else None),
    ):
        if array is not None:
            if array.dtype.hasobject:
                raise TypeError(f"an array of Python objects in a training state: {array!r}")
            name = f"a{len(arrays)}"
            arrays[name] = array
            return {kind: name}
    raise TypeError(f"{type(value).__name__} in a training state (it holds numbers, arrays and containers)")


def _decode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if not isinstance(value, dict) or len(value) != 1:
        raise ValueError(f"not a training state's structure: {str(value)[:80]}")
    ((kind, content),) = value.items()
    if kind in ("list", "tuple"):
        items = [_decode(item, arrays) for item in content]
        return items if kind == "list" else tuple(items)
    if kind == "dict":
        return {_decode(key, arrays): _decode(item, arrays) for key, item in content}
    if kind in ("tensor", "array", "scalar") and isinstance(content, str) and content in arrays:
        array = arrays[content]
        return th.from_numpy(array.copy()) if kind == "tensor" else array[()] if kind == "scalar" else array
    raise ValueError(f"not a training state's structure: {kind!r}")


def _tensor_storage(data: bytes) -> Any:
    """A tensor's storage as an earlier version's pickle holds it (torch's own format), loaded as data only."""
    return th.load(io.BytesIO(data), weights_only=True)


# The classes and functions a pickled training state of an earlier version names, each bound to what builds it here.
_PICKLED_DATA: dict[tuple[str, str], Any] = {
    ("torch._utils", "_rebuild_tensor_v2"): th._utils._rebuild_tensor_v2,
    ("torch.storage", "_load_from_bytes"): _tensor_storage,
    ("collections", "OrderedDict"): OrderedDict,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    # an array and a numpy scalar pickle through these two (numpy 1 and 2 name their module differently)
    **{(module, "_reconstruct"): np.ndarray(0).__reduce__()[0] for module in _NUMPY_CORES},
    **{(module, "scalar"): np.float64(0).__reduce__()[0] for module in _NUMPY_CORES},
}


class _DataUnpickler(pickle.Unpickler):
    """Reads the training states earlier versions pickled: it builds torch tensors, numpy arrays and the
    containers around them, and refuses every other class or function a pickle names (which could run code)."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in _PICKLED_DATA:
            raise pickle.UnpicklingError(f"it names {module}.{name}, which a training state does not hold")
        return _PICKLED_DATA[(module, name)]


def capture(model: BaseAlgorithm) -> dict[str, Any]:
    """The training state of ``model`` and its envs now (see the module docstring).

    :raises NotImplementedError: when a sub-env cannot give its state (its message says which)
    """
    env = model.get_env()
    state: dict[str, Any] = {
        "torch": th.get_rng_state(),
        "cuda": th.cuda.get_rng_state_all() if th.cuda.is_available() else [],
        "numpy": np.random.get_state(),
        "random": random.getstate(),
        "action_space": model.action_space.np_random.bit_generator.state,
        "generators": {name: generator.get_state() for name, generator in _generators(model).items()},
        "envs": None,
        "frame_stacks": [],
    }
    if env is not None:
        layers = _vec_layers(env)
        state["frame_stacks"] = [
            layer.stacked_obs.stacked_obs.copy() for layer in layers if isinstance(layer, VecFrameStack)
        ]
        state["envs"] = layers[-1].env_method("get_training_state")
    return state


def restore(model: BaseAlgorithm, state: dict[str, Any]) -> None:
    """Put ``capture``'s state back into ``model`` and its envs (made with the same arguments)."""
    th.set_rng_state(state["torch"])
    if state["cuda"] and th.cuda.is_available():
        th.cuda.set_rng_state_all(state["cuda"])
    np.random.set_state(state["numpy"])
    random.setstate(state["random"])
    model.action_space.np_random.bit_generator.state = state["action_space"]
    generators = _generators(model)
    for name, generator_state in state["generators"].items():
        generators[name].set_state(generator_state)
    env = model.get_env()
    if env is None or state["envs"] is None:
        return
    layers = _vec_layers(env)
    stacks = [layer for layer in layers if isinstance(layer, VecFrameStack)]
    for layer, stacked in zip(stacks, state["frame_stacks"], strict=True):
        layer.stacked_obs.stacked_obs[...] = stacked
    for index, env_state in enumerate(state["envs"]):
        layers[-1].env_method("set_training_state", env_state, indices=[index])


class RestoreTrainingState(BaseCallback):
    """Puts a checkpoint's training state back when the resumed run's training starts: after the model, the
    envs, the callbacks and every seed are set up, right before the first env step.

    :param state: what :func:`capture` took at the checkpoint
    """

    def __init__(self, state: dict[str, Any]) -> None:
        super().__init__()
        self.state = state

    def _on_training_start(self) -> None:
        restore(self.model, self.state)

    def _on_step(self) -> bool:
        return True
