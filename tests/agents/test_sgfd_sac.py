import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import KVWriter, Logger
from stable_baselines3.common.vec_env import DummyVecEnv

import sb3_sgfd
import sgfd_envs
from sb3_sgfd import SGFD_SAC, DomainReplayBuffer, MlpPolicy
from sb3_sgfd.sgfd.functional import feature_probabilities, learn_sample_weights
from sb3_sgfd.sgfd.settings import SGFDSettings
from sb3_sgfd.sgfd.weighting import SGFDWeighting, WeightingPlan, Weights

ENV_ID = "SGFD/MT-walker-walk-v0"
TINY = dict(
    learning_starts=100, batch_size=32, learning_rate=1e-3, tau=0.01, policy_kwargs=dict(net_arch=[32, 32]), seed=0
)


def state_env(n_envs: int | None = None):
    # The varied length in the state: the domain classifier can tell the domains apart within a few updates.
    return sgfd_envs.make_domain_vec_env(ENV_ID, split="train", n_envs=n_envs, obs_type="state", observe_parameter=True)


def reweighting_model(**kwargs) -> SGFD_SAC:
    # Algorithm 1's ten classifier updates per step, so that the tiny runs reach the accuracy threshold.
    settings = dict(TINY, classifier_start=200, classifier_hidden_dim=32, classifier_iters=10)
    settings.update(kwargs)
    return SGFD_SAC("MlpPolicy", state_env(), **settings)


def test_with_unit_weights_it_is_sb3_sac_exactly():
    # Before the classifier starts w = 1; with the actor updated every step SGFD_SAC must then take
    # exactly SAC's steps: same batches, same losses, same parameters to the last bit.
    # Each constructor re-seeds the global RNGs, so each model learns right after it is built.
    sac = SAC(MlpPolicy, state_env(), replay_buffer_class=DomainReplayBuffer, **TINY).learn(300)
    sgfd = SGFD_SAC("MlpPolicy", state_env(), actor_update_interval=1, classifier_start=10**9, **TINY).learn(300)
    assert sgfd._n_updates == sac._n_updates > 0
    for (name, expected), (_, got) in zip(
        sac.policy.state_dict().items(), sgfd.policy.state_dict().items(), strict=True
    ):
        assert th.equal(expected, got), name
    assert th.equal(sac.log_ent_coef, sgfd.log_ent_coef)


class FixedWeighting(SGFDWeighting):
    """The same weight for every sample from the first step; counts the batches and records their features."""

    def __init__(self, value: float, settings: SGFDSettings | None = None) -> None:
        super().__init__(1, 2, settings or SGFDSettings(), seed=0)
        self.classifier_optimizer = th.optim.Adam(self.classifier.parameters())
        self.value, self.calls, self.features = value, 0, []

    def reading_plan(self, update_index, num_timesteps, weights_wanted):
        return WeightingPlan(classifier_round=False, weights_wanted=weights_wanted)

    def forward(self, z, domains, plan, fresh=(), masked=True):
        self.calls += 1
        self.features.append(z)
        return Weights(th.full((len(z),), self.value) if plan.weights_wanted else None, {})


def weighted_by(model: SGFD_SAC, weighting: SGFDWeighting) -> SGFD_SAC:
    model.weighting = weighting
    return model


@pytest.mark.parametrize(("reweight_critic", "reweight_actor"), [(True, True), (False, True), (True, False)])
def test_weights_multiply_the_critic_and_actor_losses(reweight_critic, reweight_actor):
    # Every sample weighted 0 from the first step: a weighted loss then has zero gradient.
    model = SGFD_SAC("MlpPolicy", state_env(), reweight_critic=reweight_critic, reweight_actor=reweight_actor, **TINY)
    weighted_by(model, FixedWeighting(0.0, model.sgfd))
    critic = [p.clone() for p in model.critic.parameters()]
    actor = [p.clone() for p in model.actor.latent_pi.parameters()]
    ent_coef = model.log_ent_coef.clone()
    model.learn(200)
    critic_moved = any(not th.equal(a, b) for a, b in zip(critic, model.critic.parameters(), strict=True))
    actor_moved = any(not th.equal(a, b) for a, b in zip(actor, model.actor.latent_pi.parameters(), strict=True))
    assert model._n_updates > 0
    assert critic_moved is not reweight_critic
    assert actor_moved is not reweight_actor
    # The entropy-coefficient loss is SAC's, unweighted.
    assert not th.equal(ent_coef, model.log_ent_coef)


@pytest.mark.parametrize(("reweight_critic", "expected"), [(True, 1.0), (False, 0.5)])
def test_weights_for_the_actor_alone_are_computed_only_on_the_steps_it_learns(reweight_critic, expected):
    model = SGFD_SAC("MlpPolicy", state_env(), reweight_critic=reweight_critic, actor_update_interval=2, **TINY)
    weighting = weighted_by(model, FixedWeighting(1.0, model.sgfd)).weighting
    model.learn(400)
    assert model._n_updates >= 50
    wanted = [step for step in range(model._n_updates) if reweight_critic or step % 2 == 0]
    assert weighting.calls == model._n_updates and len(wanted) == math.ceil(expected * model._n_updates)


class EncodingForbidden(SGFD_SAC):
    """Records the replay batches; encoding a batch again during a step is an error."""

    def _setup_model(self):
        super()._setup_model()
        self.batches = []
        sample = self.replay_buffer.sample
        self.replay_buffer.sample = lambda *args, **kwargs: (
            self.batches.append(sample(*args, **kwargs)) or self.batches[-1]
        )

    def encode(self, observations):
        raise AssertionError("the step encoded a batch again instead of reusing the critic's features")


class EncodingChecked(FixedWeighting):
    """Records, at each call, whether z is the critic's current encoding of the batch just sampled."""

    def __init__(self, model: EncodingForbidden) -> None:
        super().__init__(1.0)
        self.model, self.matches = model, []

    def forward(self, z, domains, plan, fresh=(), masked=True):
        critic = self.model.critic
        with th.no_grad():
            expected = critic.extract_features(self.model.batches[-1].observations, critic.features_extractor)
        self.matches.append(th.equal(z, expected) and not z.requires_grad)
        return super().forward(z, domains, plan, fresh, masked)


def test_the_weights_reuse_the_critics_features_of_the_batch():
    # A learned encoder (MlpEncoder), so that its features are not the observations themselves.
    model = EncodingForbidden("EncoderMlpPolicy", state_env(), **TINY)
    weighting = weighted_by(model, EncodingChecked(model)).weighting
    model.learn(200)
    assert weighting.calls == model._n_updates == len(model.batches) > 0
    assert all(weighting.matches)


def test_learns_on_the_training_domains_and_its_weights_leave_one():
    model = reweighting_model()
    model.learn(600)
    stats = {key.removeprefix("sgfd/"): value for key, value in model.logger.name_to_value.items()}  # the last call's
    assert model.weighting.ready
    assert model.n_domains == 4
    assert stats["weight_min"] < 1.0 < stats["weight_max"]
    assert 0.3 < stats["weight_ess"] < 1.0
    assert stats["decorrelation_loss_after"] < stats["decorrelation_loss_before"]
    # The most salient feature is the appended length: the one that tells the domains apart.
    batch = model.replay_buffer.sample(128)
    z = model.encode(batch.observations)
    assert int(feature_probabilities(model.classifier, z).argmax()) == z.shape[1] - 1
    assert stats["top_saliency_feature"] == z.shape[1] - 1
    logged = model.logger.name_to_value
    assert {"sgfd/classifier_accuracy", "sgfd/weight_ess", "sgfd/decorrelation_loss_after"} <= set(logged)


def test_by_default_the_classifier_trains_on_the_batch_features_every_classifier_interval_steps():
    model = reweighting_model(classifier_iters=1, classifier_interval=3, accuracy_threshold=1.0)
    samples = []
    sample = model.replay_buffer.sample
    model.replay_buffer.sample = lambda *args, **kwargs: samples.append(1) or sample(*args, **kwargs)
    steps = []
    optimizer = model.weighting.classifier_optimizer
    optimizer_step = optimizer.step
    optimizer.step = lambda *args, **kwargs: steps.append(1) or optimizer_step(*args, **kwargs)
    model.learn(600)
    # one replay batch per gradient step (the SAC update's), a classifier step on every third
    updates_after_start = model._n_updates - (200 - TINY["learning_starts"]) // 4
    assert len(samples) == model._n_updates
    assert abs(len(steps) - updates_after_start / 3) <= 2 and steps


def test_sample_weights_follow_the_saliency_settings():
    # Full smoothing mixes the saliency away: the weights must then be the no-saliency ablation's.
    z = th.randn(64, 25, generator=th.Generator().manual_seed(1))

    def weights(**settings) -> th.Tensor:
        model = reweighting_model(**{"saliency_smoothing": 1.0, **settings})
        return model.sample_weights(z, th.Generator().manual_seed(2))[0]

    uniform = weights(use_saliency=False)
    assert not th.allclose(uniform, th.ones_like(uniform))
    assert th.allclose(weights(use_saliency=True), uniform)
    assert not th.allclose(weights(saliency_smoothing=0.0), uniform)


def test_reweight_max_step_reaches_the_solver():
    # What the step cap does is test_reweighting's; here, that SGFD_SAC hands it to the solver.
    z = th.randn(64, 25, generator=th.Generator().manual_seed(1))
    z[:, 1] = z[:, 0] + 0.1 * z[:, 1]  # something to decorrelate
    model = reweighting_model(use_saliency=False, reweight_iters=1, reweight_lr=50.0, reweight_max_step=0.25)
    weights = model.sample_weights(z, th.Generator().manual_seed(2))[0]

    def solver(**kwargs) -> th.Tensor:
        return learn_sample_weights(z, iters=1, lr=50.0, generator=th.Generator().manual_seed(2), **kwargs)

    assert th.equal(weights, solver(max_step=0.25))
    assert not th.allclose(weights, solver())


def test_actor_is_updated_every_actor_update_interval_steps():
    model = reweighting_model(actor_update_interval=3, classifier_start=10**9)
    model.learn(400)
    actor_steps = model.actor.optimizer.state[model.actor.optimizer.param_groups[0]["params"][0]]["step"]
    critic_steps = model.critic.optimizer.state[model.critic.optimizer.param_groups[0]["params"][0]]["step"]
    assert int(critic_steps) == model._n_updates
    assert int(actor_steps) == -(-model._n_updates // 3)


def test_save_load_keeps_classifier_and_solver_and_continues(tmp_path):
    model = reweighting_model()
    model.learn(400)
    model.save(tmp_path / "sgfd")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = SGFD_SAC.load(tmp_path / "sgfd", env=state_env())
    loaded.load_replay_buffer(tmp_path / "buffer")
    obs = model.env.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    for (name, expected), (_, got) in zip(
        model.classifier.state_dict().items(), loaded.classifier.state_dict().items(), strict=True
    ):
        assert th.equal(expected, got), name
    assert loaded.weighting.classifier_optimizer.state_dict()["state"], "classifier optimizer state was not restored"
    assert (loaded.weighting.ready, loaded.rff_seed, loaded.n_domains) == (True, model.rff_seed, 4)
    loaded.learn(300, reset_num_timesteps=False)
    assert loaded.num_timesteps == model.num_timesteps + 300
    assert "sgfd/weight_ess" in loaded.logger.name_to_value


def test_a_single_domain_warns_once_and_trains_as_sac():
    env = sgfd_envs.make_domain_vec_env(ENV_ID, split="interpolation", obs_type="state")
    with pytest.warns(UserWarning, match="single domain") as record:
        model = SGFD_SAC("MlpPolicy", env, classifier_start=150, **TINY)
        model.learn(300)
    assert len([w for w in record if "single domain" in str(w.message)]) == 1
    assert model.weighting.single_domain and not model.weighting.ready
    assert "sgfd/weight_ess" not in model.logger.name_to_value


class NaNRewardAfter(gym.Wrapper):
    def __init__(self, env, after: int):
        super().__init__(env)
        self.after, self.count = after, 0

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.count += 1
        return obs, (float("nan") if self.count > self.after else reward), terminated, truncated, info


def test_a_non_finite_reward_is_refused_where_it_enters_naming_the_env_domain_and_step():
    env = DummyVecEnv([lambda: NaNRewardAfter(gym.make(ENV_ID, obs_type="state"), after=150)])
    model = SGFD_SAC("MlpPolicy", env, n_domains=1, **TINY)
    with pytest.raises(ValueError, match=r"non-finite reward \(nan\) at add 150 \(sub-env 0, domain 0\)"):
        model.learn(400)
    stored = model.replay_buffer.rewards[: model.replay_buffer.pos]
    assert model.replay_buffer.pos == 150 and np.isfinite(stored).all()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(accuracy_threshold=1.5), "accuracy_threshold"),
        (dict(actor_update_interval=0), "actor_update_interval"),
        (dict(n_rff=0), "n_rff"),
        (dict(classifier_iters=-1), "classifier_iters"),
        (dict(replay_buffer_class=ReplayBuffer), "replay_buffer_class"),
        (dict(n_domains=0), "n_domains"),
        (dict(reweight_max_step=0.0), "reweight_max_step"),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SGFD_SAC("MlpPolicy", state_env(), **kwargs, **TINY)


def test_a_label_beyond_n_domains_is_refused():
    model = reweighting_model(n_domains=2)
    with pytest.raises(ValueError, match="n_domains"):
        model.learn(400)


class Recorded(KVWriter):
    """A logger output that keeps every dump."""

    def __init__(self) -> None:
        self.dumps: list[tuple[dict, dict]] = []

    def write(self, key_values, key_excluded, step=0) -> None:
        self.dumps.append((dict(key_values), dict(key_excluded)))

    def close(self) -> None:
        """Nothing held."""


def test_the_sample_weights_reach_the_logger_as_a_histogram_for_tensorboard_only():
    model = reweighting_model(accuracy_threshold=0.1, classifier_iters=1)
    recorded = Recorded()
    model.set_logger(Logger(None, [recorded]))
    model.learn(400)
    assert bool(model.weighting.ready)
    model.dump_logs()  # what SB3 does at an episode's end (the walker's are longer than this run)
    dumps = [(values, excluded) for values, excluded in recorded.dumps if "sgfd/weights" in values]
    assert dumps, "no histogram of the weights was logged"
    values, excluded = dumps[-1]
    weights = values["sgfd/weights"]
    assert isinstance(weights, th.Tensor) and weights.shape == (model.batch_size,)
    assert abs(float(weights.mean()) - 1.0) < 1e-4  # the weights, mean 1
    assert set(excluded["sgfd/weights"]) == {"stdout", "log", "json", "csv"}


def test_a_model_saved_by_a_newer_version_is_refused_in_one_line(tmp_path):
    import json
    import zipfile

    model = SGFD_SAC("MlpPolicy", state_env(), **TINY)
    model.save(tmp_path / "model")
    with zipfile.ZipFile(tmp_path / "model.zip") as saved:
        members = {name: saved.read(name) for name in saved.namelist()}
    data = json.loads(members["data"])
    assert data["sb3_sgfd_version"] == sb3_sgfd.__version__  # what wrote it
    data["sb3_sgfd_version"] = "99.0.0"
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(tmp_path / "newer.zip", "w") as newer:
        for name, content in members.items():
            newer.writestr(name, content)
    with pytest.raises(ValueError, match=r"written by sb3-sgfd 99\.0\.0, newer than this sb3-sgfd") as error:
        SGFD_SAC.load(tmp_path / "newer.zip")
    assert "\n" not in str(error.value)
    assert SGFD_SAC.load(tmp_path / "model.zip").sb3_sgfd_version == sb3_sgfd.__version__
