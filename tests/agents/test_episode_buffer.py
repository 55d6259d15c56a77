"""Episode tracking of DomainReplayBuffer and its same-episode negatives for TED.

Every stored frame encodes (env + 1, episode + 1, step + 1), so each returned observation names the transition
it was stored with; an oracle built from the schedule of adds alone says what the buffer may return.
"""

from __future__ import annotations

import pickle
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st

from sb3_sgfd.common.buffers import DomainReplayBuffer

ACTION_SPACE = spaces.Box(-1, 1, shape=(1,), dtype=np.float32)
# Values per frame: env + 1, episode + 1, step + 1 (no zero, so that padding frames show)
CHANNELS = 3


def make_buffer(
    slots: int, n_envs: int, frame_stack: int | None = None, optimize: bool = False, negatives: bool = True
) -> DomainReplayBuffer:
    space = spaces.Box(0, 1e6, shape=((frame_stack or 1) * CHANNELS,), dtype=np.float32)
    return DomainReplayBuffer(
        slots * n_envs,
        space,
        ACTION_SPACE,
        device="cpu",
        n_envs=n_envs,
        optimize_memory_usage=optimize,
        handle_timeout_termination=not optimize,
        frame_stack=frame_stack,
        same_episode_negatives=negatives,
    )


def stack(env: int, episode: int, step: int, n_frames: int) -> np.ndarray:
    """Observation at ``step`` of an episode: its last n_frames frames, oldest first, zeros before the start."""
    steps = np.arange(step - n_frames + 1, step + 1)
    frames = np.stack([np.full_like(steps, env + 1), np.full_like(steps, episode + 1), steps + 1], axis=1)
    frames[steps < 0] = 0
    return frames.reshape(-1).astype(np.float32)


class Schedule:
    """
    Feeds a buffer episodes of planned lengths (per env, cycled) and remembers what each add stored.

    :param buffer: The buffer fed
    :param plans: Episode lengths of each env
    """

    def __init__(self, buffer: DomainReplayBuffer, plans: list[list[int]]):
        self.buffer, self.plans = buffer, plans
        self.n_envs, self.n_frames = buffer.n_envs, buffer.frame_stack or 1
        self.episode = np.zeros(self.n_envs, dtype=np.int64)
        self.step = np.zeros(self.n_envs, dtype=np.int64)
        # (episode, step) of each env's transition, per add; adds since the last reset()
        self.added: list[np.ndarray] = []
        self.since_reset = 0

    def add(self, n_adds: int = 1) -> None:
        for _ in range(n_adds):
            envs = range(self.n_envs)
            obs = np.stack([stack(env, self.episode[env], self.step[env], self.n_frames) for env in envs])
            next_obs = np.stack([stack(env, self.episode[env], self.step[env] + 1, self.n_frames) for env in envs])
            lengths = [self.plans[env][self.episode[env] % len(self.plans[env])] for env in envs]
            done = self.step + 1 >= np.array(lengths)
            self.buffer.add(obs, next_obs, np.zeros((self.n_envs, 1)), np.zeros(self.n_envs), done, [{}] * self.n_envs)
            self.added.append(np.stack([self.episode, self.step], axis=1))
            self.since_reset += 1
            self.episode = np.where(done, self.episode + 1, self.episode)
            self.step = np.where(done, 0, self.step + 1)

    def reset(self) -> None:
        self.buffer.reset()
        self.since_reset = 0

    def stored(self) -> dict[tuple[int, int, int], tuple[int, int, bool]]:
        """(env, episode, step) -> (slot, env, sampleable) of every stored transition, from the schedule alone."""
        size, k = self.buffer.buffer_size, self.n_frames
        n_stored = min(self.since_reset, size)
        first = len(self.added) - n_stored
        full = self.since_reset >= size
        table = {}
        for age, add in enumerate(range(first, len(self.added))):
            slot = (self.since_reset - n_stored + age) % size
            for env in range(self.n_envs):
                episode, step = self.added[add][env]
                # The oldest k - 1 may miss frames; with optimize_memory_usage, the oldest lost its obs once full.
                sampleable = age >= min(step, k - 1) and not (self.buffer.optimize_memory_usage and full and age == 0)
                table[(env, int(episode), int(step))] = (slot, env, sampleable)
        return table


def decode(observations: th.Tensor, n_frames: int) -> list[tuple[int, int, int]]:
    """(env, episode, step) named by the newest frame of each observation; checks the whole stack too."""
    rows = observations.numpy()
    names = []
    for row in rows:
        env, episode, step = (int(value) - 1 for value in row[-CHANNELS:])
        np.testing.assert_array_equal(row, stack(env, episode, step, n_frames))
        names.append((env, episode, step))
    return names


def check_negatives(schedule: Schedule, samples: Any) -> int:
    """Check every same-episode observation of ``samples`` against the oracle; return how many fell back."""
    table = schedule.stored()
    sampleable = {name for name, (_, _, ok) in table.items() if ok}
    n_fallbacks = 0
    k = schedule.n_frames
    for (env, episode, step), other in zip(
        decode(samples.observations, k), decode(samples.same_episode_observations, k), strict=True
    ):
        assert other in sampleable
        allowed = {name for name in sampleable if name[:2] == (env, episode) and abs(name[2] - step) >= 2}
        if allowed:
            assert other in allowed
        else:
            assert other[:2] != (env, episode)
            n_fallbacks += 1
    return n_fallbacks


@st.composite
def scenarios(draw: st.DrawFn) -> dict[str, Any]:
    n_envs = draw(st.integers(1, 3))
    frame_stack = draw(st.sampled_from([None, 1, 2, 3]))
    n_steps = draw(st.integers(1, 40))
    return {
        "n_envs": n_envs,
        "frame_stack": frame_stack,
        "optimize": frame_stack is None and draw(st.booleans()),
        "slots": draw(st.integers(1, 14)),
        "n_steps": n_steps,
        "plans": [draw(st.lists(st.integers(1, 9), min_size=1, max_size=4)) for _ in range(n_envs)],
        "pickle_at": draw(st.sets(st.integers(1, 39), max_size=2)),
        "reset_at": draw(st.one_of(st.none(), st.integers(1, 39))),
        "seed": draw(st.integers(0, 2**16)),
    }


@settings(max_examples=150, deadline=None)
@given(scenarios())
def test_same_episode_observations_are_stored_non_adjacent_and_of_the_same_episode(case: dict[str, Any]):
    np.random.seed(case["seed"])
    buffer = make_buffer(case["slots"], case["n_envs"], case["frame_stack"], case["optimize"])
    schedule = Schedule(buffer, case["plans"])
    for step in range(case["n_steps"]):
        if step in case["pickle_at"]:
            schedule.buffer = buffer = pickle.loads(pickle.dumps(buffer))
        if step == case["reset_at"]:
            schedule.reset()
        schedule.add()

    table = schedule.stored()
    # Episode ids: two stored transitions share one iff they share (env, episode).
    names = list(table)
    slots, envs = (np.array([table[name][i] for name in names], dtype=np.int64) for i in (0, 1))
    if names:
        ids = buffer.episode_ids(slots, envs)
        assert len(set(ids.tolist())) == len({name[:2] for name in names})
        assert len(set(zip(ids.tolist(), (name[:2] for name in names), strict=True))) == len(set(ids.tolist()))

    ok = np.array([table[name][2] for name in names], dtype=bool)
    np.testing.assert_array_equal(buffer.is_sampleable(slots, envs), ok)
    if not ok.any():
        return
    sampleable_names = [name for name, good in zip(names, ok, strict=True) if good]
    # A sample has no valid negative iff its episode holds nothing 2 steps away and no other episode is sampleable.
    has_other = {name[:2] for name in sampleable_names}
    impossible = np.array(
        [
            len(has_other - {name[:2]}) == 0
            and not any(other[:2] == name[:2] and abs(other[2] - name[2]) >= 2 for other in sampleable_names)
            for name in sampleable_names
        ]
    )
    slots, envs = slots[ok], envs[ok]
    if impossible.any():
        with pytest.raises(ValueError, match="no sampleable transition of another episode"):
            buffer._get_samples(slots[impossible][:1], env_indices=envs[impossible][:1])
    if impossible.all():
        return
    # Every possible sample, several times over, then batches drawn by sample() when all are possible.
    repeats = 4
    possible_slots, possible_envs = np.tile(slots[~impossible], repeats), np.tile(envs[~impossible], repeats)
    check_negatives(schedule, buffer._get_samples(possible_slots, env_indices=possible_envs))
    if not impossible.any():
        check_negatives(schedule, buffer.sample(64))


def test_every_allowed_observation_is_drawn_about_equally_often():
    buffer = make_buffer(slots=32, n_envs=2)
    schedule = Schedule(buffer, [[8, 20], [3, 100]])
    schedule.add(10)
    # Env 0, episode 0: steps 0-7 in slots 0-7. For step 3 the allowed steps are 0, 1, 5, 6, 7.
    n_draws = 5000
    samples = buffer._get_samples(np.full(n_draws, 3), env_indices=np.zeros(n_draws, dtype=int))
    steps = [name[2] for name in decode(samples.same_episode_observations, 1)]
    counts = np.bincount(steps, minlength=8)
    assert set(np.flatnonzero(counts).tolist()) == {0, 1, 5, 6, 7}
    expected = n_draws / 5
    # About 20 standard deviations apart from anything but uniform, yet far from flaky.
    assert (np.abs(counts[[0, 1, 5, 6, 7]] - expected) < 0.15 * expected).all()
    # At the episode's start and end only one neighbour is excluded.
    first = buffer._get_samples(np.full(2000, 0), env_indices=np.zeros(2000, dtype=int))
    assert {name[2] for name in decode(first.same_episode_observations, 1)} == set(range(2, 8))
    last = buffer._get_samples(np.full(2000, 7), env_indices=np.zeros(2000, dtype=int))
    assert {name[2] for name in decode(last.same_episode_observations, 1)} == set(range(6))


def test_short_episode_falls_back_to_any_other_episode_uniformly():
    buffer = make_buffer(slots=8, n_envs=2)
    schedule = Schedule(buffer, [[3, 100], [100]])
    schedule.add(5)
    # Env 0 episode 0 is steps 0-2: step 1 has no allowed slot. The other sampleable transitions are env 0's
    # episode 1 (2 steps) and env 1's episode 0 (5 steps).
    samples = buffer._get_samples(np.full(3000, 1), env_indices=np.zeros(3000, dtype=int))
    assert check_negatives(schedule, samples) == 3000
    drawn = set(decode(samples.same_episode_observations, 1))
    assert drawn == {(0, 1, 0), (0, 1, 1)} | {(1, 0, step) for step in range(5)}


def test_overwritten_start_of_an_episode_is_never_returned_with_frame_stack():
    buffer = make_buffer(slots=6, n_envs=1, frame_stack=3)
    schedule = Schedule(buffer, [[50]])
    schedule.add(11)
    # Steps 5-10 stored; steps 5 and 6 miss frames of their stacks, so step 10 may only get 7 or 8.
    samples = buffer._get_samples(np.full(500, 10 % 6), env_indices=np.zeros(500, dtype=int))
    assert {name[2] for name in decode(samples.same_episode_observations, 3)} == {7, 8}
    check_negatives(schedule, samples)


def test_large_buffer_samples_without_scanning_it():
    # 100_000 slots (2_000 per env), wrapped, with episodes from 1 to 3_000 steps: a scan per sample would take
    # hours; the vectorised draw takes milliseconds.
    n_envs, slots, n_adds = 50, 2_000, 2_600
    buffer = DomainReplayBuffer(
        slots * n_envs,
        spaces.Box(0, 1e6, shape=(CHANNELS,), dtype=np.float32),
        ACTION_SPACE,
        device="cpu",
        n_envs=n_envs,
        same_episode_negatives=True,
    )
    rng = np.random.default_rng(0)
    lengths = rng.integers(1, 3_000, size=(n_envs, 8))
    episode, step = np.zeros(n_envs, dtype=np.int64), np.zeros(n_envs, dtype=np.int64)
    env_column = np.arange(n_envs)
    for _ in range(n_adds):
        obs = np.stack([env_column + 1, episode + 1, step + 1], axis=1).astype(np.float32)
        done = step + 1 >= lengths[env_column, episode % 8]
        buffer.add(obs, obs, np.zeros((n_envs, 1)), np.zeros(n_envs), done, [{}] * n_envs)
        episode, step = np.where(done, episode + 1, episode), np.where(done, 0, step + 1)
    assert buffer.full and buffer.buffer_size * buffer.n_envs == 100_000

    np.random.seed(0)
    for _ in range(5):
        samples = buffer.sample(4096)
        names, others = samples.observations.long() - 1, samples.same_episode_observations.long() - 1
        same = (names[:, :2] == others[:, :2]).all(dim=1)
        # Long episodes dominate: nearly all get a same-episode negative, never an adjacent one.
        assert same.float().mean() > 0.9
        assert ((names[same, 2] - others[same, 2]).abs() >= 2).all()
        # Whatever falls back is from another episode by construction; it must still be a stored one.
        assert (others[:, 2] >= 0).all()


def test_flag_off_gives_none_and_flag_on_keeps_the_batches():
    batches = {}
    for negatives in (False, True):
        buffer = make_buffer(slots=16, n_envs=2, negatives=negatives)
        Schedule(buffer, [[5], [7]]).add(20)
        np.random.seed(4)
        batches[negatives] = buffer.sample(32)
    assert batches[False].same_episode_observations is None
    assert batches[True].same_episode_observations.shape == batches[True].observations.shape
    for name in ("observations", "actions", "next_observations", "dones", "rewards", "domains"):
        assert th.equal(getattr(batches[False], name), getattr(batches[True], name)), name


def test_negatives_do_not_touch_the_global_rng_after_construction():
    buffer = make_buffer(slots=16, n_envs=1)
    Schedule(buffer, [[6]]).add(16)
    np.random.seed(1)
    buffer._get_samples(np.arange(16), env_indices=np.zeros(16, dtype=int))
    after = np.random.randint(1_000_000)
    np.random.seed(1)
    assert np.random.randint(1_000_000) == after


def test_same_episode_observations_are_normalized_like_observations():
    buffer = make_buffer(slots=8, n_envs=1, frame_stack=2)
    Schedule(buffer, [[8]]).add(8)
    raw = buffer._get_samples(np.arange(8), env_indices=np.zeros(8, dtype=int))
    buffer.episode_index.rng = np.random.default_rng(0)
    fake = SimpleNamespace(normalize_obs=lambda obs: obs * 2 - 1, normalize_reward=lambda reward: reward)
    normalized = buffer._get_samples(np.arange(8), env=fake, env_indices=np.zeros(8, dtype=int))
    assert th.equal(normalized.observations, raw.observations * 2 - 1)
    # Same draw again, so the same observations, normalized.
    buffer.episode_index.rng = np.random.default_rng(0)
    again = buffer._get_samples(np.arange(8), env_indices=np.zeros(8, dtype=int))
    assert th.equal(normalized.same_episode_observations, again.same_episode_observations * 2 - 1)


@pytest.mark.parametrize("frame_stack", [None, 2])
def test_pickle_round_trip_keeps_episodes_and_draws(frame_stack: int | None):
    buffer = make_buffer(slots=6, n_envs=2, frame_stack=frame_stack)
    schedule = Schedule(buffer, [[4, 9], [20]])
    schedule.add(9)
    loaded = pickle.loads(pickle.dumps(buffer))
    for name in ("episodes", "first", "last", "current", "open"):
        np.testing.assert_array_equal(
            getattr(loaded.episode_index, name), getattr(buffer.episode_index, name), err_msg=name
        )
    index, loaded_index = buffer.episode_index, loaded.episode_index
    assert (loaded_index.n_adds, loaded_index.n_episodes) == (index.n_adds, index.n_episodes)
    np.random.seed(2)
    expected = buffer.sample(32)
    np.random.seed(2)
    assert th.equal(loaded.sample(32).same_episode_observations, expected.same_episode_observations)
    # Adds after loading continue the open episodes.
    schedule.buffer = loaded
    schedule.add(1)
    newest, before = loaded.pos - 1, loaded.pos - 2
    ids = loaded.episode_ids(np.array([newest, before]), np.array([1, 1]))
    assert ids[0] == ids[1]
    check_negatives(schedule, loaded.sample(64))


def test_invalid_arguments_are_rejected():
    with pytest.raises(ValueError, match="same_episode_negatives must be a bool"):
        make_buffer(slots=4, n_envs=1, negatives="yes")  # type: ignore[arg-type]
    buffer = make_buffer(slots=4, n_envs=2, frame_stack=2)
    Schedule(buffer, [[9], [9]]).add(5)
    with pytest.raises(ValueError, match="hold no stored transition"):
        buffer.episode_ids(np.array([0, 4]), np.array([0, 0]))
    with pytest.raises(ValueError, match="shape"):
        buffer.episode_ids(np.array([0, 1]), np.array([0]))
    # Slot 1 holds step 1 of each episode, whose older frame (step 0, slot 0) was overwritten by step 4.
    with pytest.raises(ValueError, match="no sampleable transition"):
        buffer.observations_at(np.array([1]), np.array([0]))
    np.testing.assert_array_equal(buffer.observations_at(np.array([2]), np.array([1])), stack(1, 0, 2, 2)[None])
    with pytest.raises(ValueError, match="done must hold one flag per env"):
        obs = np.zeros((2, 2 * CHANNELS), dtype=np.float32)
        buffer.add(obs, obs, np.zeros((2, 1)), np.zeros(2), np.zeros(3), [{}, {}])
