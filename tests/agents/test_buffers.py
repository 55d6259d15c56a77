import io
import pickle

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_sgfd.common.buffers import DomainDictReplayBuffer, DomainReplayBuffer, DomainReplayBufferSamples

OBS_SPACE = spaces.Box(-1e6, 1e6, shape=(3,), dtype=np.float32)
ACTION_SPACE = spaces.Box(-1, 1, shape=(2,), dtype=np.float32)


def fill(buffer: ReplayBuffer, n_steps: int, labels_of_step) -> None:
    """Transitions whose observation encodes (step, env, domain), so a sample can be checked."""
    n_envs = buffer.n_envs
    for step in range(n_steps):
        labels = labels_of_step(step)
        obs = np.array([[step, env, labels[env]] for env in range(n_envs)], dtype=np.float32)
        infos = [{"domain": int(label)} for label in labels]
        buffer.add(obs, obs + 1, np.zeros((n_envs, 2)), np.ones(n_envs), np.zeros(n_envs), infos)


def test_domain_labels_round_trip_with_their_transitions():
    buffer = DomainReplayBuffer(64, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=4)
    # Labels differ from the env index so that a mix-up would show.
    fill(buffer, 40, lambda step: [(env + step) % 3 for env in range(4)])
    np.random.seed(0)
    batch = buffer.sample(256)
    assert isinstance(batch, DomainReplayBufferSamples)
    assert batch.domains.dtype == th.int64
    assert th.equal(batch.domains, batch.observations[:, 2].long())
    assert th.equal(batch.next_observations, batch.observations + 1)
    assert set(batch.domains.tolist()) == {0, 1, 2}


def test_sub_env_index_is_the_label_when_info_has_none():
    buffer = DomainReplayBuffer(16, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=3)
    obs = np.zeros((3, 3), dtype=np.float32)
    for _ in range(5):
        buffer.add(obs, obs, np.zeros((3, 2)), np.zeros(3), np.zeros(3), [{}, {}, {}])
    assert buffer.domains[:5].tolist() == [[0, 1, 2]] * 5
    assert buffer.stored_domains().tolist() == [0, 1, 2]


def test_a_buffer_pickled_under_the_module_path_before_the_package_split_loads(monkeypatch: pytest.MonkeyPatch):
    # Buffers pickled while the class lived in sb3_sgfd/buffers.py name it sb3_sgfd.buffers.DomainReplayBuffer, as
    # the zoo's yaml does; pickle.dumps already refuses a name that does not lead back to the class.
    buffer = DomainReplayBuffer(16, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=2)
    fill(buffer, 5, lambda step: [1, 0])
    with monkeypatch.context() as patch:
        patch.setattr(DomainReplayBuffer, "__module__", "sb3_sgfd.buffers")
        pickled = pickle.dumps(buffer)
    assert b"sb3_sgfd.buffers" in pickled and b"sb3_sgfd.buffers.replay" not in pickled
    loaded = pickle.loads(pickled)
    assert type(loaded) is DomainReplayBuffer
    assert np.array_equal(loaded.observations, buffer.observations) and loaded.stored_domains().tolist() == [0, 1]


def modules_named(pickled: bytes) -> set[str]:
    """The project's modules a pickle names (where its classes are looked up on load), found by loading it."""
    named = set()

    class Recording(pickle.Unpickler):
        def find_class(self, module: str, name: str) -> object:
            named.add(module)
            return super().find_class(module, name)

    Recording(io.BytesIO(pickled)).load()
    return {module for module in named if module.split(".")[0] == "sb3_sgfd"}


def test_a_saved_buffer_names_only_modules_that_stay():
    # Saved buffers name their class by module path: these modules stay where they are; the parts the buffer holds
    # (frame store, episode index) are pickled as their attributes, so that they name none.
    images = spaces.Box(0, 255, shape=(6, 4, 4), dtype=np.uint8)
    framed = DomainReplayBuffer(8, images, ACTION_SPACE, device="cpu", frame_stack=2, same_episode_negatives=True)
    obs = np.zeros((1, 6, 4, 4), dtype=np.uint8)
    for _ in range(4):
        framed.add(obs, obs, np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    framed.sample(2)  # its batch transfer is made, and pickled
    flat = DomainDictReplayBuffer(8, spaces.Dict({"state": OBS_SPACE}), ACTION_SPACE, device="cpu")
    named = modules_named(pickle.dumps(framed)) | modules_named(pickle.dumps(flat))
    stay = {"sb3_sgfd.common.buffers.replay", "sb3_sgfd.common.buffers.dict_replay", "sb3_sgfd.common.transfer"}
    assert "sb3_sgfd.common.buffers.replay" in named and named <= stay
    loaded = pickle.loads(pickle.dumps(framed))
    assert type(loaded.frame_store).__name__ == "FrameStore" and type(loaded.episode_index).__name__ == "EpisodeIndex"


@pytest.mark.parametrize("bad", [-1, 1.5, "a"])
def test_invalid_domain_label_is_rejected(bad):
    buffer = DomainReplayBuffer(16, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=1)
    obs = np.zeros((1, 3), dtype=np.float32)
    with pytest.raises(ValueError, match=r"info\['domain'\]"):
        buffer.add(obs, obs, np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{"domain": bad}])


def test_samples_match_sb3_replay_buffer_under_the_same_seed():
    plain = ReplayBuffer(32, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=2)
    ours = DomainReplayBuffer(32, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=2)
    for buffer in (plain, ours):
        fill(buffer, 50, lambda step: [0, 1])  # wraps around
    np.random.seed(3)
    expected = plain.sample(64)
    np.random.seed(3)
    got = ours.sample(64)
    for name in ("observations", "actions", "next_observations", "dones", "rewards"):
        assert th.equal(getattr(expected, name), getattr(got, name)), name


@pytest.mark.parametrize(
    ("field", "match"),
    [
        ("obs", r"non-finite observation \(nan\) at add 3 \(sub-env 1, domain 2\)"),
        ("next_obs", r"non-finite next observation \(inf\) at add 3 \(sub-env 1, domain 2\)"),
        ("action", r"non-finite action \(nan\) at add 3 \(sub-env 1, domain 2\)"),
        ("reward", r"non-finite reward \(-inf\) at add 3 \(sub-env 1, domain 2\)"),
        ("label", r"domain label 5 from info\['domain'\] at add 3 \(sub-env 1, domain 5\).*n_domains=4"),
    ],
)
@pytest.mark.parametrize("frame_stack", [None, 1])
def test_bad_data_is_refused_at_add_and_nothing_of_it_is_stored(field, match, frame_stack):
    buffer = DomainReplayBuffer(
        16, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=2, n_domains=4, frame_stack=frame_stack
    )
    fill(buffer, 3, lambda step: [0, 2])
    obs, next_obs = np.zeros((2, 3), dtype=np.float32), np.zeros((2, 3), dtype=np.float32)
    action, reward, labels = np.zeros((2, 2), dtype=np.float32), np.zeros(2, dtype=np.float32), [0, 2]
    value = {"obs": np.nan, "next_obs": np.inf, "action": np.nan, "reward": -np.inf}.get(field)
    target = {"obs": obs, "next_obs": next_obs, "action": action}.get(field)
    if target is not None:
        target[1, 0] = value
    elif field == "reward":
        reward[1] = value
    else:
        labels = [0, 5]
    before = (buffer.pos, buffer.rewards.copy(), buffer.domains.copy())
    with pytest.raises(ValueError, match=match):
        buffer.add(obs, next_obs, action, reward, np.zeros(2), [{"domain": label} for label in labels])
    assert buffer.pos == before[0] and np.array_equal(buffer.rewards, before[1])
    assert np.array_equal(buffer.domains, before[2])


@pytest.mark.parametrize(
    ("field", "match"),
    [
        ("velocity", r"non-finite observation \(nan\) at add 3 \(sub-env 1, domain 2\)"),
        ("next_velocity", r"non-finite next observation \(inf\) at add 3 \(sub-env 1, domain 2\)"),
        ("action", r"non-finite action \(nan\) at add 3 \(sub-env 1, domain 2\)"),
        ("reward", r"non-finite reward \(-inf\) at add 3 \(sub-env 1, domain 2\)"),
        ("label", r"domain label 5 from info\['domain'\] at add 3 \(sub-env 1, domain 5\).*n_domains=4"),
    ],
)
def test_dict_buffer_refuses_bad_data_in_any_key_at_add_and_stores_nothing_of_it(field, match):
    space = spaces.Dict({"pixels": spaces.Box(0, 255, (2, 2), np.uint8), "position": OBS_SPACE, "velocity": OBS_SPACE})
    buffer = DomainDictReplayBuffer(16, space, ACTION_SPACE, device="cpu", n_envs=2, n_domains=4)

    def observation():
        return {key: np.zeros((2, *part.shape), dtype=part.dtype) for key, part in space.spaces.items()}

    def add(obs, next_obs, action, reward, labels):
        buffer.add(obs, next_obs, action, reward, np.zeros(2), [{"domain": label} for label in labels])

    for _ in range(3):
        add(observation(), observation(), np.zeros((2, 2), np.float32), np.zeros(2, np.float32), [0, 2])
    obs, next_obs = observation(), observation()
    action, reward, labels = np.zeros((2, 2), dtype=np.float32), np.zeros(2, dtype=np.float32), [0, 2]
    if field == "velocity":
        obs["velocity"][1, 2] = np.nan
    elif field == "next_velocity":
        next_obs["velocity"][1, 0] = np.inf
    elif field == "action":
        action[1, 1] = np.nan
    elif field == "reward":
        reward[1] = -np.inf
    else:
        labels = [0, 5]
    before = (buffer.pos, buffer.rewards.copy(), buffer.domains.copy())
    with pytest.raises(ValueError, match=match):
        add(obs, next_obs, action, reward, labels)
    assert buffer.pos == before[0] and np.array_equal(buffer.rewards, before[1])
    assert np.array_equal(buffer.domains, before[2])
