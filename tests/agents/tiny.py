"""Tiny versions of every agent on tiny envs, for tests that run each of them: SGFD_SAC in both readings (on states),
SGFD on AMBS, AMBS, DBC, TED and SGQN (on 24x24 pixels), and EncoderSAC."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, AMBSPolicy, CnnPolicy, EncoderSAC

ENV_ID = "SGFD/MT-walker-walk-v0"
COMMON = dict(learning_starts=64, batch_size=16, buffer_size=4000, seed=0, policy_kwargs=dict(net_arch=[16, 16]))
PIXELS = dict(
    COMMON,
    policy_kwargs=dict(net_arch=[16, 16], features_extractor_kwargs=dict(features_dim=8, n_filters=4, n_layers=2)),
)
OVERLAYS = np.random.default_rng(0).integers(0, 256, size=(4, 24, 24, 3), dtype=np.uint8)


def state_env() -> VecEnv:
    """4 training domains, the state with the varied length (the domains are told apart at once)."""
    return sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state", observe_parameter=True)


def pixel_env() -> VecEnv:
    """4 training domains, 24x24 pixels, 2 stacked frames, channel first."""
    return VecTransposeImage(VecFrameStack(sgfd_envs.make_domain_vec_env(ENV_ID, image_size=24, render="fast"), 2))


# Each agent with what makes every part of its step run within a few dozen updates: SGFD's classifier from the
# first update; the paper reading's threshold low enough that its weights start within the run; a short solver (what
# torch.compile compiles is the same code, in less time).
AGENTS: dict[str, Callable[..., Any]] = {
    "EncoderSAC": lambda **kw: EncoderSAC("MlpPolicy", state_env(), **COMMON, **kw),
    "SGFD paper": lambda **kw: SGFD_SAC(
        "MlpPolicy", state_env(), classifier_start=0, accuracy_threshold=0.5, reweight_iters=3, **COMMON, **kw
    ),
    "SGFD official": lambda **kw: SGFD_SAC(
        "MlpPolicy",
        state_env(),
        reading="official",
        classifier_start=0,
        classifier_interval=2,
        reweight_iters=4,
        **COMMON,
        **kw,
    ),
    "SGFD on AMBS": lambda **kw: SGFD_SAC(
        AMBSPolicy,
        pixel_env(),
        representation="ambs",
        classifier_start=0,
        accuracy_threshold=0.5,
        reweight_iters=3,
        **PIXELS,
        **kw,
    ),
    "AMBS": lambda **kw: AMBS(AMBSPolicy, pixel_env(), **PIXELS, **kw),
    "DBC": lambda **kw: DBC(CnnPolicy, pixel_env(), representation_kwargs=dict(hidden_dim=16), **PIXELS, **kw),
    "TED": lambda **kw: TED(CnnPolicy, pixel_env(), **PIXELS, **kw),
    "SGQN": lambda **kw: SGQN(
        CnnPolicy, pixel_env(), representation_kwargs=dict(overlay_images=OVERLAYS), **PIXELS, **kw
    ),
}
