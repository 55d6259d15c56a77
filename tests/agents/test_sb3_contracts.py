"""What SB3 promises of an algorithm holds for every agent here: a saved model loads onto envs with another number
of sub-envs and learns on; get_parameters / set_parameters round trip with tensors only; images that are already
scaled need normalize_images=False, as SB3's CnnPolicy says; SAC's n_steps gives n-step returns; Dict observations
train with MultiInputPolicy where the agent reads them, and are refused in one line where it does not."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, DomainReplayBuffer, EncoderSAC, MlpPolicy
from sb3_sgfd.common.buffers import DomainDictReplayBuffer

TINY = dict(learning_starts=30, batch_size=8, buffer_size=300, seed=0)
SMALL_NET = dict(net_arch=[8, 8])
PIXELS = dict(net_arch=[8, 8], features_extractor_kwargs=dict(features_dim=4, n_filters=4, n_layers=2))
OVERLAYS = np.random.default_rng(0).integers(0, 256, size=(2, 24, 24, 3), dtype=np.uint8)


def pendulum(n_envs: int):
    """A plain env (no domain labels): each sub-env is labelled by its index."""
    return make_vec_env("Pendulum-v1", n_envs=n_envs, seed=0)


def pixels(n_envs: int):
    """Plain pixel envs: a background id's first domain in every sub-env, so no env gives n_domains."""
    make = [lambda: gym.make("SGFD/walker-walk-v0", image_size=24, render="fast") for _ in range(n_envs)]
    return VecTransposeImage(VecFrameStack(DummyVecEnv(make), 2))


AGENTS = {
    "SGFD_SAC": lambda env: SGFD_SAC("MlpPolicy", env, classifier_start=40, policy_kwargs=SMALL_NET, **TINY),
    "SGFD_SAC official": lambda env: SGFD_SAC(
        "MlpPolicy", env, reading="official", classifier_start=40, policy_kwargs=SMALL_NET, **TINY
    ),
    "DBC": lambda env: DBC("MlpPolicy", env, representation_kwargs=dict(hidden_dim=8), policy_kwargs=SMALL_NET, **TINY),
    "TED": lambda env: TED("MlpPolicy", env, augmentation_views=0, policy_kwargs=SMALL_NET, **TINY),
    "AMBS": lambda env: AMBS(
        "MlpPolicy",
        env,
        augmentation_views=0,
        representation_kwargs=dict(hidden_dim=8),
        policy_kwargs=SMALL_NET,
        **TINY,
    ),
}


@pytest.mark.parametrize("name", list(AGENTS))
def test_a_model_loaded_onto_more_sub_envs_learns_on(name, tmp_path):
    model = AGENTS[name](pendulum(1)).learn(60)
    model.save(tmp_path / "model")
    loaded = type(model).load(tmp_path / "model", env=pendulum(3))
    loaded.learn(60, reset_num_timesteps=False)
    assert loaded.num_timesteps >= 120
    assert set(loaded.replay_buffer.stored_domains().tolist()) == {0, 1, 2}


def test_sgfd_refuses_in_one_line_more_domains_than_its_classifier_has_classes(tmp_path):
    model = SGFD_SAC("MlpPolicy", pendulum(2), classifier_start=40, policy_kwargs=SMALL_NET, **TINY).learn(40)
    model.save(tmp_path / "model")
    with pytest.raises(ValueError, match=r"give 3 domain labels.*trained on n_domains=2.*at most 2"):
        SGFD_SAC.load(tmp_path / "model", env=pendulum(3))


def test_sgfd_given_envs_of_more_domains_makes_its_new_classifier_off_sacs_random_stream():
    # Before its classifier trains, envs with more domains give it a new classifier (and weighting), drawn from a
    # fork of the CPU generator as at construction: SAC's random stream is where SB3's SAC would have it.
    model = SGFD_SAC("MlpPolicy", pendulum(2), policy_kwargs=SMALL_NET, **TINY)
    before = model.weighting
    state = th.get_rng_state()
    model.env = pendulum(3)  # what set_env or load_replay_buffer hand it, then check
    model._adopt_env_domains()
    assert model.weighting is not before and model.n_domains == 3
    assert th.equal(th.get_rng_state(), state)


@pytest.mark.parametrize("name", list(AGENTS))
def test_get_and_set_parameters_round_trip_with_tensors_only(name):
    model = AGENTS[name](pendulum(2)).learn(80)
    parameters = model.get_parameters()
    for part, state in parameters.items():
        if part.endswith("optimizer"):
            continue  # an optimiser's state dict is SB3's own mix of numbers and tensors
        assert all(isinstance(value, th.Tensor) for value in state.values()), (part, state.keys())
    changed = {part: state if part.endswith("optimizer") else randomised(state) for part, state in parameters.items()}
    model.set_parameters(changed, exact_match=True)
    again = model.get_parameters()
    for part, state in changed.items():
        if not part.endswith("optimizer"):
            for key, value in state.items():
                assert th.equal(again[part][key], value), (part, key)


def randomised(state: dict[str, th.Tensor]) -> dict[str, th.Tensor]:
    """Every floating-point tensor of a state dict replaced by random values (the flag and count kept); keys of one
    shared tensor (the encoder the actor and critic share) get the same values."""
    drawn: dict[int, th.Tensor] = {}
    counts = ("ready", "updates")  # the weighting's flag and its memory's count, as floats: kept as they are
    for key, value in state.items():
        if value.is_floating_point() and not key.endswith(counts):
            drawn.setdefault(value.data_ptr(), th.rand_like(value))
    return {key: drawn.get(value.data_ptr(), value) for key, value in state.items()}


def test_the_weighting_state_survives_the_round_trip():
    model = AGENTS["SGFD_SAC official"](pendulum(2)).learn(100)
    memory = model.weighting.memory
    assert memory.features is not None and memory.updates > 0
    state = model.get_parameters()
    fresh = AGENTS["SGFD_SAC official"](pendulum(2))
    fresh.set_parameters(state)
    assert fresh.weighting.memory.updates == memory.updates
    assert th.equal(fresh.weighting.memory.features, memory.features)


def test_images_already_scaled_need_normalize_images_false_as_sb3_says():
    scaled = spaces.Box(0.0, 1.0, shape=(3, 24, 24), dtype=np.float32)

    class Scaled(gym.Env):
        observation_space, action_space = scaled, spaces.Box(-1, 1, (1,), np.float32)

        def reset(self, *, seed=None, options=None):
            return self.observation_space.sample(), {}

        def step(self, action):
            return self.observation_space.sample(), 0.0, False, False, {}

    for algo in (SGFD_SAC, AMBS):
        with pytest.raises(ValueError, match="normalize_images=False"):
            algo("CnnPolicy", Scaled(), **TINY)
        model = algo("CnnPolicy", Scaled(), policy_kwargs=dict(PIXELS, normalize_images=False), **TINY)
        assert model.policy.normalize_images is False
        model.learn(40)


def n_step_batches(buffer_class, n_steps: int, gamma: float):
    """The same stream of transitions (episodes of 5 and 7 steps, the second episode of env 1 ended by its time
    limit at step 13) in a buffer, then one batch of it."""
    obs_space, action_space = spaces.Box(-10, 10, (2,), np.float32), spaces.Box(-1, 1, (1,), np.float32)
    buffer = buffer_class(64, obs_space, action_space, device="cpu", n_envs=2, n_steps=n_steps, gamma=gamma)
    rng = np.random.default_rng(1)
    for step in range(23):
        obs, next_obs = rng.normal(size=(2, 2)), rng.normal(size=(2, 2))
        done = np.array([step % 5 == 4, step % 7 == 6])
        infos = [{}, {"TimeLimit.truncated": bool(step == 13)}]
        buffer.add(obs, next_obs, rng.normal(size=(2, 1)), rng.normal(size=2), done, infos)
    np.random.seed(5)
    return buffer.sample(32)


def test_n_steps_gives_sb3s_n_step_returns():
    ours, sb3 = n_step_batches(DomainReplayBuffer, 3, 0.9), n_step_batches(NStepReplayBuffer, 3, 0.9)
    for name in ("observations", "actions", "next_observations", "dones", "rewards", "discounts"):
        assert th.equal(getattr(ours, name), getattr(sb3, name).to(getattr(ours, name).dtype)), name
    # some returns stop early, at an episode's end or the newest transition
    discounts = ours.discounts.numpy().astype(np.float64).round(4)
    assert np.isin(discounts, [0.9, 0.81, 0.729]).all() and (discounts > 0.8).any()


def test_n_steps_takes_the_same_steps_as_sb3_sac_with_n_steps_bit_for_bit():
    # episodes of 20 steps, so that some returns stop at an episode's end
    def env():
        return make_vec_env("Pendulum-v1", n_envs=2, seed=0, env_kwargs=dict(max_episode_steps=20))

    common = dict(TINY, policy_kwargs=SMALL_NET, learning_rate=1e-3, tau=0.01)  # EncoderSAC's lr and tau
    sac = SAC(MlpPolicy, env(), n_steps=3, **common).learn(150)
    ours = EncoderSAC("MlpPolicy", env(), n_steps=3, **common).learn(150)
    assert isinstance(sac.replay_buffer, NStepReplayBuffer) and ours.replay_buffer.n_steps == 3
    assert ours._n_updates == sac._n_updates > 0
    for (name, expected), (_, got) in zip(
        sac.policy.state_dict().items(), ours.policy.state_dict().items(), strict=True
    ):
        assert th.equal(expected, got), name
    assert th.equal(sac.log_ent_coef, ours.log_ent_coef)


def test_n_steps_with_a_buffer_class_that_ignores_them_warns_as_sb3_does():
    with pytest.warns(UserWarning, match=r"`n_steps=3` is ignored because a custom `replay_buffer_class`"):
        model = EncoderSAC("MlpPolicy", pendulum(1), replay_buffer_class=ReplayBuffer, n_steps=3, **TINY)
    assert type(model.replay_buffer) is ReplayBuffer
    # the domain buffer takes them: no such warning
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message="`n_steps=")
        assert EncoderSAC("MlpPolicy", pendulum(1), n_steps=3, **TINY).replay_buffer.n_steps == 3


def test_sgfd_sac_with_n_steps_learns_on_n_step_returns():
    env = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter=True)
    model = SGFD_SAC("MlpPolicy", env, n_steps=3, classifier_start=40, policy_kwargs=SMALL_NET, **TINY)
    assert model.replay_buffer.n_steps == 3 and model.replay_buffer.gamma == model.gamma
    model.learn(80)
    assert model.replay_buffer.sample(8).discounts is not None


class DictEnv(gym.Env):
    """States split into a Dict, as goal-conditioned envs give them."""

    observation_space = spaces.Dict(
        {"position": spaces.Box(-5, 5, (2,), np.float32), "velocity": spaces.Box(-5, 5, (3,), np.float32)}
    )
    action_space = spaces.Box(-1, 1, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), float(action.sum()), False, self.np_random.random() < 0.05, {}


def test_sgfd_sac_trains_on_dict_observations_with_multi_input_policy():
    env = make_vec_env(DictEnv, n_envs=2, seed=0)
    model = SGFD_SAC("MultiInputPolicy", env, classifier_start=40, policy_kwargs=SMALL_NET, **TINY).learn(120)
    assert isinstance(model.replay_buffer, DomainDictReplayBuffer)
    assert set(model.replay_buffer.stored_domains().tolist()) == {0, 1}
    assert "sgfd/classifier_accuracy" in model.logger.name_to_value
    action, _ = model.predict(env.reset(), deterministic=True)
    assert action.shape == (2, 2)


@pytest.mark.parametrize("algo", [AMBS, DBC, TED, SGQN])
def test_agents_that_read_images_or_states_refuse_dict_observations_in_one_line(algo):
    kwargs = dict(representation_kwargs=dict(overlay_images=OVERLAYS)) if algo is SGQN else {}
    with pytest.raises(ValueError, match="reads image or flat observations, not Dict ones") as error:
        algo("MultiInputPolicy", make_vec_env(DictEnv, n_envs=1), augmentation_views=0, **kwargs, **TINY)
    assert "\n" not in str(error.value)


def test_sgfd_counts_the_domains_of_a_subprocess_vec_env_of_plain_envs():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    env = make_vec_env("Pendulum-v1", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    try:
        model = SGFD_SAC("MlpPolicy", env, classifier_start=40, policy_kwargs=SMALL_NET, **TINY).learn(60)
        assert model.n_domains == 2 and set(model.replay_buffer.stored_domains().tolist()) == {0, 1}
    finally:
        env.close()
