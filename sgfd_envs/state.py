"""The state of an env and its wrappers, so that a run stopped at a checkpoint continues bit for bit.

:class:`ResumableState` is the outermost wrapper of every sub-env of ``make_domain_vec_env``: through SB3's
``env_method`` (in-process or in a subprocess alike) it hands over and takes back the state of each layer below
it. The base env gives its own (:meth:`sgfd_envs.dmc.DMCEnv.get_state`); a wrapper's state is its plain data
(counters, flags, the episode's rewards: numbers, strings, arrays and containers of them), which is all that
gymnasium's and SB3's wrappers keep (TimeLimit's elapsed steps, Monitor's episode figures).
"""

from __future__ import annotations

import copy
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

_PLAIN = (bool, int, float, str, type(None), np.ndarray, np.generic)


@runtime_checkable
class HasState(Protocol):
    """What hands over its state and takes it back: a base env (:meth:`sgfd_envs.dmc.DMCEnv.get_state`) or a
    benchmark's distraction with a state of its own."""

    def get_state(self) -> Any:
        """The state: plain data (numbers, strings, arrays and containers of them)."""
        ...

    def set_state(self, state: Any) -> None:
        """Continue from ``get_state``'s state, on an object made with the same arguments."""
        ...


def _plain(value: Any) -> bool:
    if isinstance(value, _PLAIN):
        return True
    if isinstance(value, (list, tuple)):
        return all(_plain(item) for item in value)
    if isinstance(value, dict):
        return all(isinstance(key, str) and _plain(item) for key, item in value.items())
    return False


def _layers(env: gym.Env) -> list[gym.Env]:
    layers = [env]
    while isinstance(layers[-1], gym.Wrapper):
        layers.append(layers[-1].env)
    return layers


class ResumableState(gym.Wrapper):
    """Gives and takes the state of the env below it, layer by layer (see the module docstring)."""

    def training_state_unavailable(self) -> str | None:
        """Why ``get_training_state`` cannot give this env's state, or None when it can."""
        base = _layers(self.env)[-1]
        if not isinstance(base, HasState):
            return f"{type(base).__name__} has no get_state and set_state"
        return getattr(base, "state_unavailable", None)

    def get_training_state(self) -> list[dict[str, Any]]:
        """One entry per layer below this wrapper, outermost first; the base env's own ``get_state``."""
        states = []
        for layer in _layers(self.env):
            if not isinstance(layer, gym.Wrapper):
                states.append({"env": layer.get_state()} if isinstance(layer, HasState) else {})
                continue
            fields = {name: value for name, value in vars(layer).items() if name != "env" and _plain(value)}
            states.append({"fields": copy.deepcopy(fields)})
        return states

    def set_training_state(self, states: list[dict[str, Any]]) -> None:
        """Continue from ``get_training_state``'s states, on an env made with the same arguments."""
        layers = _layers(self.env)
        if len(states) != len(layers):
            raise ValueError(f"a state of {len(states)} env layers given to an env of {len(layers)}")
        for layer, state in zip(layers, states, strict=True):
            if "env" in state:
                if not isinstance(layer, HasState):
                    raise ValueError(f"a state of a base env given to {type(layer).__name__}, which has no set_state")
                layer.set_state(state["env"])
            for name, value in state.get("fields", {}).items():
                setattr(layer, name, copy.deepcopy(value))
