"""DomainReplayBuffer(frame_stack=k) against the plain DomainReplayBuffer fed the same transitions.

Transitions come from SB3's own VecFrameStack and VecTransposeImage over a tiny env of random frames, and
are stored through SB3's own OffPolicyAlgorithm._store_transition (next_obs with the terminal observation
of done envs), so the frame buffer sees exactly what it sees in training.
"""

from __future__ import annotations

import pickle
import warnings
from copy import deepcopy
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import stable_baselines3.common.buffers as sb3_buffers
import torch as th
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st
from stable_baselines3 import SAC
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecFrameStack, VecTransposeImage

import sb3_sgfd.common.buffers.replay as buffer_replay
from sb3_sgfd.common.buffers import DomainReplayBuffer

# Larger than any k * c stacked here, so that SB3 sees the stacks as channel-last images; not square, so
# that a mixed-up axis would show.
HEIGHT, WIDTH = 13, 14
ACTION_SPACE = spaces.Box(-1, 1, shape=(2,), dtype=np.float32)
FIELDS = ("observations", "actions", "next_observations", "dones", "rewards", "domains")


class RandomFrames(gym.Env):
    """
    Random HxWxc uint8 frames, episodes of planned lengths ending by termination or truncation.

    :param channels: Channels per frame
    :param plan: (length, terminates) of the successive episodes, cycled
    :param seed: Seed of the frames and rewards
    :param low: Smallest pixel value
    :param high: Largest pixel value
    :param flat: Frames of a single random grey level (so that equal frames are common)
    :param domain: Base of the domain label put in info
    """

    def __init__(
        self,
        channels: int,
        plan: list[tuple[int, bool]],
        seed: int,
        low: int = 0,
        high: int = 255,
        flat: bool = False,
        domain: int = 0,
    ):
        self.observation_space = spaces.Box(0, 255, shape=(HEIGHT, WIDTH, channels), dtype=np.uint8)
        self.action_space = ACTION_SPACE
        self._plan, self._low, self._high, self._flat, self._domain = plan, low, high, flat, domain
        self._rng = np.random.default_rng(seed)
        self._episode = self._t = self._length = 0
        self._terminates = False

    def _frame(self) -> np.ndarray:
        size = 1 if self._flat else self.observation_space.shape
        values = self._rng.integers(self._low, self._high, size=size, endpoint=True, dtype=np.uint8)
        return np.broadcast_to(values, self.observation_space.shape).copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self._length, self._terminates = self._plan[self._episode % len(self._plan)]
        self._episode += 1
        self._t = 0
        return self._frame(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._t += 1
        end = self._t >= self._length
        info = {"domain": self._domain + self._episode % 3}
        return self._frame(), float(self._rng.normal()), end and self._terminates, end and not self._terminates, info


def stacked_venv(n_envs: int, n_stack: int, channels: int, plans: list, seed: int, **frames: Any) -> VecEnv:
    """SB3's stacking of an image env for a CNN policy: VecFrameStack, then VecTransposeImage."""
    env_fns = [
        (lambda i=i: RandomFrames(channels, plans[i], seed * 7919 + i, domain=3 * i, **frames)) for i in range(n_envs)
    ]
    return VecTransposeImage(VecFrameStack(DummyVecEnv(env_fns), n_stack, channels_order="last"))


class Tee:
    """Stands for the replay buffer in _store_transition and feeds every transition to several buffers."""

    def __init__(self, *buffers: DomainReplayBuffer):
        self.buffers = buffers

    def add(self, *args: Any) -> None:
        for buffer in self.buffers:
            buffer.add(*deepcopy(args))


def drive(
    plain: DomainReplayBuffer,
    framed: DomainReplayBuffer,
    make_venv: Any,
    n_steps: int,
    cuts: frozenset[int] = frozenset(),
) -> tuple[DomainReplayBuffer, DomainReplayBuffer, np.ndarray]:
    """
    Store n_steps steps of ``make_venv(0)`` in both buffers through SB3's _store_transition. Before each
    step in ``cuts`` both buffers go through pickle and the run goes on with a fresh VecEnv ``make_venv(step)``,
    as a run resumed from a saved replay buffer does.

    :return: The buffers and, for each step and env, how many steps its obs is into its episode
    """
    venv = make_venv(0)
    algo = SimpleNamespace(_vec_normalize_env=None, _last_obs=venv.reset())
    n_envs = venv.num_envs
    since, steps = np.zeros((n_steps, n_envs), dtype=np.int64), np.zeros(n_envs, dtype=np.int64)
    for step in range(n_steps):
        if step in cuts:
            plain, framed = pickle.loads(pickle.dumps(plain)), pickle.loads(pickle.dumps(framed))
            venv = make_venv(step)
            algo._last_obs = venv.reset()
            steps[:] = 0
        since[step] = steps
        # Actions name the step and env, so that a sampled transition can be traced back.
        actions = np.array([[step, env] for env in range(n_envs)], dtype=np.float32)
        new_obs, rewards, dones, infos = venv.step(actions)
        OffPolicyAlgorithm._store_transition(algo, Tee(plain, framed), actions, new_obs, rewards, dones, infos)
        steps = np.where(dones, 0, steps + 1)
    return plain, framed, since


def stored_pairs(buffer: DomainReplayBuffer, n_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step, slot and env of every transition still stored after n_steps adds to an empty buffer."""
    steps = np.arange(max(0, n_steps - buffer.buffer_size), n_steps)
    step_idx = np.repeat(steps, buffer.n_envs)
    return step_idx, step_idx % buffer.buffer_size, np.tile(np.arange(buffer.n_envs), len(steps))


def assert_same_samples(expected: Any, got: Any) -> None:
    for name in FIELDS:
        assert th.equal(getattr(expected, name), getattr(got, name)), name
    assert (expected.discounts is None) == (got.discounts is None)
    if expected.discounts is not None:
        assert th.equal(expected.discounts, got.discounts), "discounts"


def make_pair(
    slots: int, n_envs: int, n_stack: int, channels: int, returns: int = 1
) -> tuple[DomainReplayBuffer, DomainReplayBuffer]:
    """A plain buffer and a frame buffer of ``slots`` slots per env for HxW frames of ``channels`` channels, with
    ``returns``-step returns."""
    space = spaces.Box(0, 255, shape=(n_stack * channels, HEIGHT, WIDTH), dtype=np.uint8)
    common = dict(device="cpu", n_envs=n_envs, n_steps=returns, gamma=0.9)
    plain = DomainReplayBuffer(slots * n_envs, space, ACTION_SPACE, **common)
    framed = DomainReplayBuffer(slots * n_envs, space, ACTION_SPACE, frame_stack=n_stack, **common)
    return plain, framed


@st.composite
def scenarios(draw: st.DrawFn) -> dict[str, Any]:
    n_envs = draw(st.integers(1, 3))
    n_steps = draw(st.integers(1, 40))
    low = draw(st.sampled_from([0, 1]))
    return {
        "n_envs": n_envs,
        "n_stack": draw(st.integers(1, 4)),
        "channels": draw(st.sampled_from([1, 3])),
        # One slot per env (the newest transition overwrites the previous one) gets its own chance.
        "slots": draw(st.one_of(st.just(1), st.integers(1, 12))),
        "n_steps": n_steps,
        # n-step returns (SAC's n_steps): the next observation is the last one of the return's
        "returns": draw(st.sampled_from([1, 3])),
        "plans": [
            draw(st.lists(st.tuples(st.integers(1, 12), st.booleans()), min_size=1, max_size=4)) for _ in range(n_envs)
        ],
        "frames": {"low": low, "high": draw(st.sampled_from([1, 2, 255])), "flat": draw(st.booleans())},
        "cuts": frozenset(draw(st.sets(st.integers(1, 39), max_size=2))),
        "seed": draw(st.integers(0, 2**16)),
    }


@settings(max_examples=150, deadline=None)
@given(scenarios())
def test_frame_buffer_rebuilds_what_the_plain_buffer_stores(case: dict[str, Any]) -> None:
    n_envs, n_stack = case["n_envs"], case["n_stack"]
    plain, framed = make_pair(case["slots"], n_envs, n_stack, case["channels"], case["returns"])
    plans, seed, frames = case["plans"], case["seed"], case["frames"]
    plain, framed, since = drive(
        plain,
        framed,
        lambda offset: stacked_venv(n_envs, n_stack, case["channels"], plans, seed + offset, **frames),
        case["n_steps"],
        case["cuts"],
    )

    # A stored transition can be rebuilt iff the frames of its obs since its episode's start (at most
    # k - 1 before the newest) are still stored.
    step_idx, slot_idx, env_idx = stored_pairs(framed, case["n_steps"])
    older_stored = step_idx - step_idx[0]
    rebuildable = older_stored >= np.minimum(since[step_idx, env_idx], n_stack - 1)
    sampleable = framed.is_sampleable(slot_idx, env_idx)
    if frames["low"] > 0:
        np.testing.assert_array_equal(sampleable, rebuildable)
    else:
        # With all-zero frames a fresh env's reset stack can equal the previous next_obs: it then counts as a
        # continuation (still rebuilt exactly), whose zero "older" frames must stay stored.
        assert not (sampleable & ~rebuildable).any()
    for env in range(n_envs):
        assert (~sampleable[env_idx == env]).sum() <= n_stack - 1

    if not sampleable.any():
        with pytest.raises(ValueError, match="can be sampled"):
            framed.sample(8)
        return
    slots, envs = slot_idx[sampleable], env_idx[sampleable]
    assert_same_samples(plain._get_samples(slots, env_indices=envs), framed._get_samples(slots, env_indices=envs))
    if not sampleable.all():
        first_bad = np.flatnonzero(~sampleable)[:1]
        with pytest.raises(ValueError, match="no sampleable transition"):
            framed._get_samples(slot_idx[first_bad], env_indices=env_idx[first_bad])

    # sample() only returns sampleable transitions, each the plain buffer's one...
    np.random.seed(seed)
    batch = framed.sample(32)
    steps_of_rows, envs_of_rows = batch.actions[:, 0].long().numpy(), batch.actions[:, 1].long().numpy()
    assert framed.is_sampleable(steps_of_rows % framed.buffer_size, envs_of_rows).all()
    assert_same_samples(
        plain._get_samples(steps_of_rows % framed.buffer_size, env_indices=envs_of_rows),
        batch,
    )
    # ... and, with nothing to redraw, draws the same batch as the plain buffer under the same seed.
    if sampleable.all():
        np.random.seed(seed)
        expected = plain.sample(32)
        np.random.seed(seed)
        assert_same_samples(expected, framed.sample(32))


def test_sac_collection_fills_the_frame_buffer_exactly():
    class TwinnedFrameBuffer(DomainReplayBuffer):
        """Frame buffer that also stores every transition in a plain twin."""

        def __init__(self, *args: Any, **kwargs: Any):
            super().__init__(*args, **kwargs)
            self.twin = DomainReplayBuffer(*args, **{**kwargs, "frame_stack": None})

        def add(self, *args: Any) -> None:
            self.twin.add(*deepcopy(args))
            super().add(*args)

    plans = [[(7, True), (5, False)], [(4, False), (9, True)]]
    venv = VecFrameStack(
        DummyVecEnv([lambda i=i: RandomFrames(3, plans[i], seed=i, domain=i) for i in range(2)]), 3, "last"
    )
    model = SAC(
        "MlpPolicy",
        venv,
        buffer_size=40,
        learning_starts=1000,
        replay_buffer_class=TwinnedFrameBuffer,
        replay_buffer_kwargs={"frame_stack": 3},
        policy_kwargs={"net_arch": [8]},
        device="cpu",
        seed=0,
    )
    assert isinstance(model.get_env(), VecTransposeImage)
    model.learn(total_timesteps=60)
    framed = model.replay_buffer
    assert isinstance(framed, TwinnedFrameBuffer) and framed.full and framed.frame_store.side_frames

    _, slot_idx, env_idx = stored_pairs(framed, 30)
    sampleable = framed.is_sampleable(slot_idx, env_idx)
    assert sampleable.sum() >= len(slot_idx) - 2 * 2
    slots, envs = slot_idx[sampleable], env_idx[sampleable]
    assert_same_samples(framed.twin._get_samples(slots, env_indices=envs), framed._get_samples(slots, env_indices=envs))


def test_pickled_frame_buffer_samples_and_continues_identically():
    plain, framed = make_pair(slots=10, n_envs=2, n_stack=3, channels=3)
    venv = stacked_venv(2, 3, 3, [[(6, True)], [(4, False), (20, True)]], seed=5)
    algo = SimpleNamespace(_vec_normalize_env=None, _last_obs=venv.reset())

    def store(buffers: tuple[DomainReplayBuffer, ...], n_steps: int) -> None:
        for _ in range(n_steps):
            actions = np.zeros((2, 2), dtype=np.float32)
            new_obs, rewards, dones, infos = venv.step(actions)
            OffPolicyAlgorithm._store_transition(algo, Tee(*buffers), actions, new_obs, rewards, dones, infos)

    store((plain, framed), 13)
    loaded = pickle.loads(pickle.dumps(framed))
    np.random.seed(1)
    expected = framed.sample(64)
    np.random.seed(1)
    assert_same_samples(expected, loaded.sample(64))

    # The same env goes on: the loaded buffer sees a continuation, not a new episode.
    side_before = set(loaded.frame_store.side_frames)
    store((plain, loaded), 1)
    assert set(loaded.frame_store.side_frames) - side_before == set()
    store((plain, loaded), 12)
    _, slot_idx, env_idx = stored_pairs(loaded, 26)
    sampleable = loaded.is_sampleable(slot_idx, env_idx)
    slots, envs = slot_idx[sampleable], env_idx[sampleable]
    assert_same_samples(plain._get_samples(slots, env_indices=envs), loaded._get_samples(slots, env_indices=envs))


def test_resuming_with_a_fresh_env_mid_episode_stays_exact():
    plain, framed = make_pair(slots=16, n_envs=2, n_stack=3, channels=1)
    plans = [[(50, False)], [(50, True)]]
    plain, framed, _ = drive(
        plain, framed, lambda offset: stacked_venv(2, 3, 1, plans, seed=offset), n_steps=12, cuts=frozenset({7})
    )
    # Both episodes were cut after the transition in slot 6: its next frames went to the side store.
    assert set(framed.frame_store.side_frames) == {(6, 0), (6, 1)}
    assert framed.frame_store.history[7].tolist() == [0, 0]
    _, slot_idx, env_idx = stored_pairs(framed, 12)
    assert framed.is_sampleable(slot_idx, env_idx).all()
    assert_same_samples(
        plain._get_samples(slot_idx, env_indices=env_idx), framed._get_samples(slot_idx, env_indices=env_idx)
    )


def test_reset_mid_episode_keeps_continuity_and_drops_lost_frames():
    plain, framed = make_pair(slots=8, n_envs=1, n_stack=4, channels=1)
    venv = stacked_venv(1, 4, 1, [[(30, True)]], seed=2, low=1)
    algo = SimpleNamespace(_vec_normalize_env=None, _last_obs=venv.reset())
    for step in range(10):
        if step == 5:
            plain.reset()
            framed.reset()
        actions = np.zeros((1, 2), dtype=np.float32)
        new_obs, rewards, dones, infos = venv.step(actions)
        OffPolicyAlgorithm._store_transition(algo, Tee(plain, framed), actions, new_obs, rewards, dones, infos)
    # After the reset, slots 0-4 hold steps 5-9, whose stacks reach 3 frames back: slots 0-2 miss some.
    assert framed.is_sampleable(np.arange(5), np.zeros(5, dtype=int)).tolist() == [False] * 3 + [True] * 2
    slots, envs = np.array([3, 4]), np.zeros(2, dtype=int)
    assert_same_samples(plain._get_samples(slots, env_indices=envs), framed._get_samples(slots, env_indices=envs))


@pytest.mark.parametrize("n_stack", [1, 3])
def test_samples_do_not_share_memory_with_the_buffer(n_stack: int):
    plain, framed = make_pair(slots=6, n_envs=1, n_stack=n_stack, channels=1)
    plain, framed, _ = drive(plain, framed, lambda offset: stacked_venv(1, n_stack, 1, [[(3, True)]], 9), 6)
    slots, envs = np.arange(6), np.zeros(6, dtype=int)
    first = framed._get_samples(slots, env_indices=envs)
    first.observations.add_(1)
    first.next_observations.add_(1)
    assert_same_samples(plain._get_samples(slots, env_indices=envs), framed._get_samples(slots, env_indices=envs))


def test_frame_storage_fits_the_paper_budget():
    space = spaces.Box(0, 255, shape=(9, 84, 84), dtype=np.uint8)
    actions = spaces.Box(-1, 1, shape=(6,), dtype=np.float32)
    framed = DomainReplayBuffer(256, space, actions, device="cpu", n_envs=4, frame_stack=3)
    plain = DomainReplayBuffer(256, space, actions, device="cpu", n_envs=4)
    capacity = framed.buffer_size * framed.n_envs
    assert framed.storage_nbytes() / capacity <= 25_000
    # The same measure counts both stacks of the plain buffer.
    assert plain.storage_nbytes() / capacity >= 2 * 9 * 84 * 84
    assert framed.observations.nbytes == 0 and framed.next_observations.nbytes == 0


def test_single_slot_buffer_stays_exact_across_episode_ends():
    plain, framed = make_pair(slots=1, n_envs=2, n_stack=2, channels=1)
    venv = stacked_venv(2, 2, 1, [[(2, True)], [(3, False)]], seed=4)
    algo = SimpleNamespace(_vec_normalize_env=None, _last_obs=venv.reset())
    slot, envs = np.zeros(2, dtype=int), np.arange(2)
    checked = 0
    for _ in range(12):
        actions = np.zeros((2, 2), dtype=np.float32)
        new_obs, rewards, dones, infos = venv.step(actions)
        OffPolicyAlgorithm._store_transition(algo, Tee(plain, framed), actions, new_obs, rewards, dones, infos)
        # Only a transition that starts its episode has its whole stack in a one-slot buffer.
        sampleable = framed.is_sampleable(slot, envs)
        np.testing.assert_array_equal(sampleable, framed.frame_store.history[0] == 0)
        if sampleable.any():
            checked += int(sampleable.sum())
            assert_same_samples(
                plain._get_samples(slot[sampleable], env_indices=envs[sampleable]),
                framed._get_samples(slot[sampleable], env_indices=envs[sampleable]),
            )
    assert checked >= 4


def test_episode_start_equal_to_the_previous_next_obs_is_still_an_episode_start():
    space = spaces.Box(0, 255, (2, 4, 4), np.uint8)
    buffer = DomainReplayBuffer(2, space, ACTION_SPACE, device="cpu", frame_stack=2)
    no_action, no_reward, info = np.zeros((1, 2)), np.zeros(1), [{}]
    buffer.add(stack(0, 0), stack(0, 7), no_action, no_reward, np.ones(1), info)
    # The reset stack happens to equal the terminal next_obs above, but follows a done transition.
    buffer.add(stack(0, 7), stack(7, 8), no_action, no_reward, np.zeros(1), info)
    buffer.add(stack(7, 8), stack(8, 9), no_action, no_reward, np.zeros(1), info)
    # Slot 0 was overwritten; the episode started in slot 1 needs nothing from it.
    assert buffer.is_sampleable(np.array([1, 0]), np.zeros(2, dtype=int)).tolist() == [True, True]
    batch = buffer._get_samples(np.array([1]), env_indices=np.zeros(1, dtype=int))
    assert th.equal(batch.observations, th.as_tensor(stack(0, 7)))
    assert th.equal(batch.next_observations, th.as_tensor(stack(7, 8)))


def test_each_episode_end_costs_one_stored_frame():
    _, framed = make_pair(slots=10, n_envs=1, n_stack=2, channels=3)
    venv = stacked_venv(1, 2, 3, [[(2, True)]], seed=0)
    algo = SimpleNamespace(_vec_normalize_env=None, _last_obs=venv.reset())
    frame_bytes = 3 * HEIGHT * WIDTH
    sizes = []
    for _ in range(4):
        sizes.append(framed.storage_nbytes())
        actions = np.zeros((1, 2), dtype=np.float32)
        new_obs, rewards, dones, infos = venv.step(actions)
        OffPolicyAlgorithm._store_transition(algo, framed, actions, new_obs, rewards, dones, infos)
    sizes.append(framed.storage_nbytes())
    # Steps 0-3: the episode ends at steps 1 and 3; the terminal frame is moved aside at the next add.
    assert np.diff(sizes).tolist() == [0, 0, frame_bytes, 0]


def test_memory_warning_counts_frames_not_stacks(monkeypatch: pytest.MonkeyPatch):
    space = spaces.Box(0, 255, shape=(9, 84, 84), dtype=np.uint8)
    framed_bytes = DomainReplayBuffer(1000, space, ACTION_SPACE, device="cpu", frame_stack=3).storage_nbytes()

    def build_with_available(available: int, frame_stack: int | None) -> list[warnings.WarningMessage]:
        fake = SimpleNamespace(virtual_memory=lambda: SimpleNamespace(available=available))
        monkeypatch.setattr(sb3_buffers, "psutil", fake)
        monkeypatch.setattr(buffer_replay, "psutil", fake)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            DomainReplayBuffer(1000, space, ACTION_SPACE, device="cpu", frame_stack=frame_stack)
        return [w for w in caught if "enough memory" in str(w.message)]

    enough_for_frames = framed_bytes + 1
    assert build_with_available(enough_for_frames, frame_stack=3) == []
    assert len(build_with_available(enough_for_frames, frame_stack=None)) == 1
    assert len(build_with_available(framed_bytes - 1, frame_stack=3)) == 1


@pytest.mark.parametrize(
    ("space", "frame_stack", "kwargs", "message"),
    [
        (spaces.Box(0, 255, (6, 4, 4), np.uint8), 0, {}, "frame_stack must be None or a positive integer"),
        (spaces.Box(0, 255, (6, 4, 4), np.uint8), 1.5, {}, "frame_stack must be None or a positive integer"),
        (spaces.Box(0, 255, (6, 4, 4), np.uint8), True, {}, "frame_stack must be None or a positive integer"),
        (spaces.Box(0, 255, (8, 4, 4), np.uint8), 3, {}, "must divide the first"),
        (spaces.Discrete(4), 2, {}, "Box observation space"),
        (
            spaces.Box(0, 255, (6, 4, 4), np.uint8),
            2,
            {"optimize_memory_usage": True, "handle_timeout_termination": False},
            "optimize_memory_usage",
        ),
    ],
)
def test_invalid_configuration_is_rejected(space: spaces.Space, frame_stack: Any, kwargs: dict, message: str):
    with pytest.raises(ValueError, match=message):
        DomainReplayBuffer(16, space, ACTION_SPACE, device="cpu", frame_stack=frame_stack, **kwargs)


def frame(value: int) -> np.ndarray:
    return np.full((1, 4, 4), value, dtype=np.uint8)


def stack(*values: int) -> np.ndarray:
    """One env's stack of flat frames, oldest first, as a batch of one env."""
    return np.concatenate([frame(value) for value in values])[None]


@pytest.mark.parametrize(
    ("obs", "next_obs", "message"),
    [
        # Older frames not zero at the start: not stacked by VecFrameStack.
        (stack(3, 4, 5), stack(4, 5, 6), "nor starts an episode"),
        (stack(0, 0, 5), stack(0, 6, 7), "shifted by one frame"),
        (stack(0, 0, 5)[:, :2], stack(0, 5, 6)[:, :2], "obs must have shape"),
    ],
)
def test_observations_not_stacked_by_vec_frame_stack_are_rejected(obs: np.ndarray, next_obs: np.ndarray, message: str):
    space = spaces.Box(0, 255, (3, 4, 4), np.uint8)
    buffer = DomainReplayBuffer(8, space, ACTION_SPACE, device="cpu", frame_stack=3)
    with pytest.raises(ValueError, match=message):
        buffer.add(obs, next_obs, np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    assert buffer.pos == 0 and not buffer.full


def test_jump_inside_an_episode_is_rejected_and_leaves_the_buffer_unchanged():
    space = spaces.Box(0, 255, (3, 4, 4), np.uint8)
    buffer = DomainReplayBuffer(8, space, ACTION_SPACE, device="cpu", frame_stack=3)
    buffer.add(stack(0, 0, 5), stack(0, 5, 6), np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    # Not the previous next_obs (0, 5, 6), and not a fresh episode either.
    with pytest.raises(ValueError, match="neither continues"):
        buffer.add(stack(0, 5, 7), stack(5, 7, 8), np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    assert buffer.pos == 1 and buffer.frame_store.side_frames == {}
    buffer.add(stack(0, 5, 6), stack(5, 6, 7), np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    batch = buffer._get_samples(np.array([0, 1]), env_indices=np.array([0, 0]))
    assert th.equal(batch.observations, th.as_tensor(np.concatenate([stack(0, 0, 5), stack(0, 5, 6)])))
    assert th.equal(batch.next_observations, th.as_tensor(np.concatenate([stack(0, 5, 6), stack(5, 6, 7)])))
