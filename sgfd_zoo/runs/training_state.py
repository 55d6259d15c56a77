"""What a checkpoint needs beyond the model and its replay buffer for a resumed run to continue bit for bit: the
random generators (torch's, numpy's and Python's global ones, the action space's, the model's own), the envs'
state (each sub-env and its wrappers, :class:`sgfd_envs.state.ResumableState`) and the frame stacks of the
VecEnv wrappers. Taken between two env steps (the checkpoint callback's ``on_rollout_start``), put back when the
resumed run's training starts (:class:`RestoreTrainingState`), after everything that builds the run.
"""

from __future__ import annotations

import pickle
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecFrameStack


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


def save(model: BaseAlgorithm, path: str) -> None:
    """Write :func:`capture`'s state of ``model`` to ``path`` (a pickle)."""
    with open(path, "wb") as handle:
        pickle.dump(capture(model), handle)


def load(path: str | Path) -> dict[str, Any]:
    """The state :func:`save` wrote to ``path``."""
    with open(path, "rb") as handle:
        return pickle.load(handle)


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
