"""No host read that SGFD or an objective adds: at most one per gradient step beyond SB3 SAC's own, counted with
a torch function mode on the CPU (each is a synchronisation on a GPU)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage
from torch.utils._python_dispatch import TorchDispatchMode

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, AMBSPolicy, CnnPolicy, DomainReplayBuffer, MlpPolicy
from tests.agents.host_reads import HostReads

ENV_ID = "SGFD/MT-walker-walk-v0"
COMMON = dict(learning_starts=64, batch_size=16, seed=0, policy_kwargs=dict(net_arch=[16, 16]))
PIXELS = dict(
    COMMON,
    policy_kwargs=dict(net_arch=[16, 16], features_extractor_kwargs=dict(features_dim=8, n_filters=4, n_layers=2)),
)
OVERLAYS = np.random.default_rng(0).integers(0, 256, size=(4, 24, 24, 3), dtype=np.uint8)


def state_env():
    return sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state", observe_parameter=True)


def pixel_env():
    return VecTransposeImage(VecFrameStack(sgfd_envs.make_domain_vec_env(ENV_ID, image_size=24, render="fast"), 2))


def reads(model, gradient_steps: int) -> int:
    with HostReads() as counter:
        model.train(gradient_steps=gradient_steps, batch_size=model.batch_size)
    return counter.count


def per_step_and_per_call(model) -> tuple[float, float]:
    """Host reads of ``train`` per gradient step and per call (the slope and intercept over 4 and 12 steps)."""
    model.learn(model.learning_starts)  # fills the buffer; no gradient step yet
    model.num_timesteps = 10**6  # past every start (SGFD's classifier_start)
    reads(model, 2)  # warm-up: lazy set-up, the first classifier round
    few, many = reads(model, 4), reads(model, 12)
    per_step = (many - few) / 8
    return per_step, few - 4 * per_step


# The phase held through SGFD's settings, as bench/update_overhead.py holds it: a classifier that cannot learn
# (learning rate 1e-12) never reaches an accuracy of 1 and trains on every round; any accuracy above 0 reaches
# the least threshold, and the classifier stays idle.
PHASES: dict[str, dict[str, Any]] = {
    "classifier": dict(accuracy_threshold=1.0, classifier_lr=1e-12),
    "mixed": dict(accuracy_threshold=1.0, classifier_lr=1e-12),
    "steady": dict(accuracy_threshold=1e-6),
}


def sgfd(reading: str = "paper", phase: str = "steady", **kwargs) -> SGFD_SAC:
    model = SGFD_SAC(
        "MlpPolicy",
        state_env(),
        reading=reading,
        classifier_start=0,
        actor_update_interval=1,
        **PHASES[phase],
        **kwargs,
        **COMMON,
    )
    if reading == "paper":  # whether the weights have started (the official reading's are always on)
        model.weighting.ready.fill_(phase in ("steady", "mixed"))
    return model


def classifier_steps(model, gradient_steps: int) -> int:
    """The steps SGFD's classifier takes in ``gradient_steps`` gradient steps: the paper reading's Adam counts them
    (a round skipped on the host, or its step masked off on the device, counts none), the code reading's SGD steps
    only when the host says."""
    optimizer = model.weighting.classifier_optimizer
    if isinstance(optimizer, torch.optim.Adam):
        parameter = next(model.classifier.parameters())
        before = int(optimizer.state.get(parameter, {}).get("step", 0))
        model.train(gradient_steps=gradient_steps, batch_size=model.batch_size)
        return int(optimizer.state.get(parameter, {}).get("step", 0)) - before
    steps: list[int] = []
    handle = optimizer.register_step_post_hook(lambda *_: steps.append(1))
    try:
        model.train(gradient_steps=gradient_steps, batch_size=model.batch_size)
    finally:
        handle.remove()
    return len(steps)


AGENTS = {
    "SGFD, classifier training": lambda: sgfd(phase="classifier"),
    "SGFD, steady": lambda: sgfd(phase="steady"),
    "SGFD, mixed": lambda: sgfd(phase="mixed"),
    "SGFD official, classifier training": lambda: sgfd("official", phase="mixed", classifier_interval=2),
    "SGFD official, steady": lambda: sgfd("official", phase="steady"),
    "SGFD on AMBS": lambda: SGFD_SAC(
        AMBSPolicy, pixel_env(), representation="ambs", classifier_start=0, actor_update_interval=1, **PIXELS
    ),
    "AMBS": lambda: AMBS(AMBSPolicy, pixel_env(), actor_update_interval=1, **PIXELS),
    "DBC": lambda: DBC(
        CnnPolicy, pixel_env(), actor_update_interval=1, representation_kwargs=dict(hidden_dim=16), **PIXELS
    ),
    "TED": lambda: TED(CnnPolicy, pixel_env(), actor_update_interval=1, **PIXELS),
    "SGQN": lambda: SGQN(
        CnnPolicy, pixel_env(), actor_update_interval=1, representation_kwargs=dict(overlay_images=OVERLAYS), **PIXELS
    ),
}


@pytest.fixture(scope="module")
def sac_reads() -> dict[str, tuple[float, float]]:
    """SB3 SAC's own host reads on the same policies (4 per gradient step: its logged losses and coefficient)."""
    states = SAC(MlpPolicy, state_env(), replay_buffer_class=DomainReplayBuffer, **COMMON)
    pixels = SAC(CnnPolicy, pixel_env(), replay_buffer_class=DomainReplayBuffer, **PIXELS)
    return {"states": per_step_and_per_call(states), "pixels": per_step_and_per_call(pixels)}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(AGENTS))
def test_at_most_one_host_read_per_gradient_step_beyond_sacs_own(name, sac_reads):
    model = AGENTS[name]()
    per_step, per_call = per_step_and_per_call(model)
    if name.startswith("SGFD,") or "official" in name:  # the phase held: the classifier trains, or it does not
        assert (classifier_steps(model, 4) > 0) == ("steady" not in name), name
    sac_step, sac_call = sac_reads["states" if name.startswith("SGFD,") or "official" in name else "pixels"]
    # SB3's own: its 4 logged figures (our policies' action distributions skip torch's argument validation)
    assert sac_step == 4, sac_step
    # per gradient step: at most one (a classifier round's decision); per train() call: the logged figures, once
    assert per_step - sac_step <= 1, (name, per_step, sac_step)
    assert per_call - sac_call <= 1, (name, per_call, sac_call)


class Dispatches(TorchDispatchMode):
    """Counts the operators a piece of code dispatches."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
        self.count += 1
        return func(*args, **(kwargs or {}))


def dispatches_per_step(model, steps: int = 4) -> float:
    model.learn(model.learning_starts)
    model.num_timesteps = 10**6
    model.train(gradient_steps=2, batch_size=model.batch_size)  # warm-up
    with Dispatches() as counter:
        model.train(gradient_steps=steps, batch_size=model.batch_size)
    return counter.count / steps


def test_an_eager_step_skips_the_work_of_the_phases_it_is_not_in():
    # The host decides: the steady phase (classifier at its threshold) runs no classifier step, the classifier phase
    # (weights not on) no weight solver; the mixed phase runs both. A mask would run both in every phase.
    counts = {phase: dispatches_per_step(sgfd(phase=phase)) for phase in ("steady", "classifier", "mixed")}
    sac = dispatches_per_step(SAC(MlpPolicy, state_env(), replay_buffer_class=DomainReplayBuffer, **COMMON))
    assert counts["steady"] < counts["mixed"] and counts["classifier"] < counts["mixed"], counts
    assert sac < counts["classifier"] < counts["steady"], (sac, counts)
