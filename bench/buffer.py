"""Memory and sampling time of DomainReplayBuffer with and without frame_stack, measured side by side.

Both buffers receive the same transitions: random 84x84x3 frames stacked by SB3's VecFrameStack (k = 3) and
VecTransposeImage into 9x84x84 uint8 observations, from 4 envs with episodes of random length around 500
(terminated or truncated), stored through SB3's own OffPolicyAlgorithm._store_transition. The buffers are
filled past their capacity, so the ring has wrapped. Reported: bytes per transition (all storage over the
capacity), the projection to the paper's 500k transitions, and the median time of sample(128) for each
buffer, the calls of the two buffers interleaved.

    .venv/bin/python bench/buffer.py                        # 20k transitions (about 3 GB of RAM, 1-2 min)
    .venv/bin/python bench/buffer.py --transitions 4000     # quicker
"""

from __future__ import annotations

import argparse
import statistics
import time
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack, VecTransposeImage

from sb3_sgfd.common.buffers import DomainReplayBuffer

FRAME_SHAPE = (84, 84, 3)
PAPER_TRANSITIONS = 500_000


class NoiseFrames(gym.Env):
    """
    Random frames, episodes of 400-600 steps that end by termination or truncation at random.

    :param seed: Seed of the frames and episode lengths
    """

    def __init__(self, seed: int):
        self.observation_space = spaces.Box(0, 255, shape=FRAME_SHAPE, dtype=np.uint8)
        self.action_space = spaces.Box(-1, 1, shape=(6,), dtype=np.float32)
        self._rng = np.random.default_rng(seed)
        self._t = self._length = 0
        self._terminates = False

    def _frame(self) -> np.ndarray:
        return self._rng.integers(0, 256, size=FRAME_SHAPE, dtype=np.uint8)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self._t, self._length = 0, int(self._rng.integers(400, 601))
        self._terminates = bool(self._rng.integers(2))
        return self._frame(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._t += 1
        end = self._t >= self._length
        return self._frame(), float(self._rng.normal()), end and self._terminates, end and not self._terminates, {}


class Tee:
    """Stands for the replay buffer in _store_transition and feeds every transition to several buffers."""

    def __init__(self, *buffers: DomainReplayBuffer):
        self.buffers = buffers

    def add(self, *args: Any) -> None:
        for buffer in self.buffers:
            buffer.add(*args)


def fill(buffers: Tee, n_envs: int, n_stack: int, n_steps: int, seed: int) -> None:
    """Store n_steps VecEnv steps in the buffers, the way SB3's off-policy collection does."""
    env_fns = [lambda i=i: NoiseFrames(seed * 1000 + i) for i in range(n_envs)]
    venv = VecTransposeImage(VecFrameStack(DummyVecEnv(env_fns), n_stack))
    algo = SimpleNamespace(_vec_normalize_env=None, _last_obs=venv.reset())
    rng = np.random.default_rng(seed)
    for _ in range(n_steps):
        actions = rng.uniform(-1, 1, size=(n_envs, 6)).astype(np.float32)
        new_obs, rewards, dones, infos = venv.step(actions)
        OffPolicyAlgorithm._store_transition(algo, buffers, actions, new_obs, rewards, dones, infos)


def median_sample_seconds(buffers: list[DomainReplayBuffer], batch_size: int, n_batches: int) -> list[float]:
    """Median wall time of sample(batch_size) for each buffer, calls interleaved so both share the conditions."""
    times: list[list[float]] = [[] for _ in buffers]
    for _ in range(n_batches):
        for buffer, buffer_times in zip(buffers, times, strict=True):
            start = time.perf_counter()
            buffer.sample(batch_size)
            buffer_times.append(time.perf_counter() - start)
    return [statistics.median(buffer_times) for buffer_times in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--transitions", type=int, default=20_000, help="buffer capacity (over all envs)")
    parser.add_argument("--n-envs", type=int, default=4)
    parser.add_argument("--frame-stack", type=int, default=3)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--batches", type=int, default=200, help="timed sample() calls per buffer")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    n_stack, n_envs = args.frame_stack, args.n_envs
    obs_space = spaces.Box(0, 255, shape=(FRAME_SHAPE[2] * n_stack, *FRAME_SHAPE[:2]), dtype=np.uint8)
    action_space = spaces.Box(-1, 1, shape=(6,), dtype=np.float32)
    common = {"device": "cpu", "n_envs": n_envs}
    plain = DomainReplayBuffer(args.transitions, obs_space, action_space, **common)
    framed = DomainReplayBuffer(args.transitions, obs_space, action_space, frame_stack=n_stack, **common)
    # 5% past the capacity, so that the ring has wrapped.
    n_steps = plain.buffer_size + max(1, plain.buffer_size // 20)
    start = time.perf_counter()
    fill(Tee(plain, framed), n_envs, n_stack, n_steps, args.seed)
    fill_seconds = time.perf_counter() - start

    np.random.seed(args.seed)
    plain_time, framed_time = median_sample_seconds([plain, framed], args.batch_size, args.batches)

    capacity = plain.buffer_size * n_envs
    print(
        f"obs {obs_space.shape} {obs_space.dtype}, frame_stack={n_stack}, {n_envs} envs, capacity {capacity} "
        f"transitions, {n_steps * n_envs} stored (ring wrapped), episodes of 400-600 steps, "
        f"filled in {fill_seconds:.0f} s"
    )
    print(f"\n| buffer | bytes per transition | GB at 500k | median sample({args.batch_size}) |\n|---|---|---|---|")
    for name, buffer, seconds in (
        ("plain", plain, plain_time),
        (f"frame_stack={n_stack}", framed, framed_time),
    ):
        per_transition = buffer.storage_nbytes() / capacity
        print(
            f"| {name} | {per_transition:,.0f} | {per_transition * PAPER_TRANSITIONS / 1e9:.2f} | "
            f"{seconds * 1e3:.2f} ms |"
        )
    memory_ratio = plain.storage_nbytes() / framed.storage_nbytes()
    time_ratio = framed_time / plain_time
    print("\n| memory, plain / frame_stack | sample time, frame_stack / plain |\n|---|---|")
    print(f"| {memory_ratio:.2f}x | {time_ratio:.2f}x |")


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
