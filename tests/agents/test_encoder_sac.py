"""EncoderSAC and the agents on it (DBC, AMBS, TED, SGQN, SGFD on AMBS): SAC's steps when their additions are
switched off, their objectives at work when on, and save/load."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, AMBSPolicy, CnnPolicy, DomainReplayBuffer, EncoderSAC, MlpPolicy
from sb3_sgfd.common.utils import polyak_pairs

ENV_ID = "SGFD/MT-walker-walk-v0"
ENCODER = dict(features_dim=8, n_filters=8, n_layers=2)
TINY = dict(learning_starts=100, batch_size=16, learning_rate=1e-3, tau=0.01, seed=0)
OVERLAYS = np.random.default_rng(0).integers(0, 256, size=(4, 24, 24, 3), dtype=np.uint8)


def pixel_env():
    """4 training domains, 24x24 pixels, 2 stacked frames (6 channels), channel first."""
    return VecTransposeImage(VecFrameStack(sgfd_envs.make_domain_vec_env(ENV_ID, image_size=24, render="fast"), 2))


def state_env():
    return sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state", observe_parameter=True)


# algorithm, policy, objective's hyperparameters, the same with every coefficient 0
AGENTS = {
    "dbc": (DBC, CnnPolicy, dict(hidden_dim=16), dict(bisim_coef=0.0, transition_coef=0.0)),
    "ambs": (AMBS, AMBSPolicy, dict(hidden_dim=16, metric_hidden_dim=8), dict(bisim_coef=0.0, transition_coef=0.0)),
    "ted": (TED, CnnPolicy, {}, dict(ted_coef=0.0)),
    "sgqn": (
        SGQN,
        CnnPolicy,
        dict(overlay_images=OVERLAYS),
        dict(overlay_images=OVERLAYS, consistency_coef=0.0, attribution_coef=0.0),
    ),
}
# What each adds to SAC's loop, switched off: then only the objective differs from SAC. (SB3's SAC evaluates the
# actor's Q on the batch encoded again after the critic's step; the agents, by default, on the step's features.)
AS_SAC = dict(
    augmentation_views=0, encoder_tau=None, max_grad_norm=None, actor_update_interval=1, actor_reuses_features=False
)


def policy_kwargs(policy) -> dict:
    return dict(net_arch=[16, 16], features_extractor_kwargs=ENCODER)


def assert_same_parameters(a: th.nn.Module, b: th.nn.Module) -> None:
    for (name, expected), (_, got) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert th.equal(expected, got), name


def test_encoder_sac_with_its_defaults_is_sb3_sac_exactly():
    sac = SAC(MlpPolicy, state_env(), replay_buffer_class=DomainReplayBuffer, **TINY).learn(300)
    encoder_sac = EncoderSAC("MlpPolicy", state_env(), **TINY).learn(300)
    assert encoder_sac._n_updates == sac._n_updates > 0
    assert_same_parameters(sac.policy, encoder_sac.policy)
    assert th.equal(sac.log_ent_coef, encoder_sac.log_ent_coef)


@pytest.mark.parametrize("name", list(AGENTS))
@pytest.mark.slow
def test_with_every_coefficient_zero_each_agent_takes_sacs_steps_bit_for_bit(name):
    algo, policy, _, zero = AGENTS[name]
    buffer_kwargs = {"same_episode_negatives": True} if name == "ted" else {}
    common = dict(TINY, policy_kwargs=policy_kwargs(policy), replay_buffer_kwargs=buffer_kwargs)
    sac = SAC(policy, pixel_env(), replay_buffer_class=DomainReplayBuffer, **common).learn(240)
    agent = algo(policy, pixel_env(), representation_kwargs=zero, **AS_SAC, **common).learn(240)
    assert agent._n_updates == sac._n_updates > 0
    assert agent.representation_model is not None and any(key.startswith(name) for key in agent.logger.name_to_value)
    assert_same_parameters(sac.policy, agent.policy)
    assert th.equal(sac.log_ent_coef, agent.log_ent_coef)


@pytest.mark.parametrize("name", list(AGENTS))
@pytest.mark.slow
def test_each_objective_trains_the_encoder_and_logs_its_losses(name):
    algo, policy, kwargs, _ = AGENTS[name]
    common = dict(TINY, policy_kwargs=policy_kwargs(policy))
    agent = algo(policy, pixel_env(), representation_kwargs=kwargs, **common)
    # the same agent with the objective's own step made a no-op: its encoder must end elsewhere
    frozen = algo(policy, pixel_env(), representation_kwargs=kwargs, **common)
    frozen.representation_model.update = lambda model, batch: {}
    frozen.representation_model.critic_loss = lambda *args: None
    agent.learn(240)
    frozen.learn(240)
    logged = agent.logger.name_to_value
    assert any(key.startswith(f"{name}/") for key in logged), logged.keys()
    assert all(np.isfinite(value) for key, value in logged.items() if key.startswith(f"{name}/"))
    moved = [
        not th.equal(a, b)
        for a, b in zip(
            agent.critic.features_extractor.parameters(), frozen.critic.features_extractor.parameters(), strict=True
        )
    ]
    assert any(moved)


def test_ambs_trains_its_ratio_through_the_critic_and_keeps_the_encoder_target_at_its_own_rate():
    agent = AMBS(
        AMBSPolicy,
        pixel_env(),
        representation_kwargs=dict(hidden_dim=16, metric_hidden_dim=8),
        **TINY,
        policy_kwargs=policy_kwargs(AMBSPolicy),
    )
    agent.learn(240)
    assert not th.equal(agent.critic.features_extractor.ratio, th.zeros(2))
    # the critic target's ratio follows at encoder_tau (0.05), never the actor's optimiser
    assert not th.equal(agent.critic_target.features_extractor.ratio, agent.critic.features_extractor.ratio)
    assert agent.logger.name_to_value["ambs/reward_weight"] != 0.5


@pytest.mark.parametrize("metric", ["code", "paper"])
def test_dbc_and_ambs_train_with_either_form_of_their_metric(metric):
    for algo, policy, kwargs, _ in (AGENTS["dbc"], AGENTS["ambs"]):
        agent = algo(policy, pixel_env(), representation_kwargs={**kwargs, "metric": metric}, **TINY)
        assert agent.representation_model.metric == metric
    default = DBC(CnnPolicy, pixel_env(), representation_kwargs=AGENTS["dbc"][2], **TINY)
    assert default.representation_model.metric == "code"  # the authors' code's form, by default
    agent = AMBS(
        AMBSPolicy,
        pixel_env(),
        representation_kwargs={**AGENTS["ambs"][2], "metric": metric},
        **TINY,
        policy_kwargs=policy_kwargs(AMBSPolicy),
    ).learn(200)
    logged = agent.logger.name_to_value
    assert np.isfinite(logged["ambs/metric_loss"]) and np.isfinite(logged["ambs/transition_nll"])


def test_ambs_as_the_sgfd_code_ran_it_keeps_its_ratio_and_measures_without_meta_learners():
    # The SGFD code's committed objective: no meta-learners, the ratio fixed at 0.5, a deterministic transition.
    kwargs = dict(hidden_dim=16, meta_learners=False, transition="deterministic", adaptive_ratio=False)
    agent = AMBS(AMBSPolicy, pixel_env(), representation_kwargs=kwargs, **TINY, policy_kwargs=policy_kwargs(AMBSPolicy))
    objective = agent.representation_model
    assert objective.reward_learner is None and objective.dynamics_learner is None
    assert type(objective.transition).__name__ == "DeterministicTransitionModel"
    encoder_start = [p.clone() for p in agent.critic.features_extractor.trunk.parameters()]
    agent.learn(240)
    assert th.equal(agent.critic.features_extractor.ratio, th.zeros(2))
    assert agent.logger.name_to_value["ambs/reward_weight"] == 0.5
    assert any(
        not th.equal(a, b)
        for a, b in zip(encoder_start, agent.critic.features_extractor.trunk.parameters(), strict=True)
    )


def test_polyak_pairs_is_sb3s_soft_update():
    online, target = th.nn.Linear(3, 2), th.nn.Linear(3, 2)
    expected = [
        (1 - 0.05) * t.detach() + 0.05 * o.detach()
        for o, t in zip(online.parameters(), target.parameters(), strict=True)
    ]
    polyak_pairs(list(zip(online.parameters(), target.parameters(), strict=True)), 0.05)
    for got, want in zip(target.parameters(), expected, strict=True):
        assert th.allclose(got, want)


def test_the_papers_agent_is_sgfd_on_ambs_and_reweights(tmp_path):
    agent = SGFD_SAC(
        AMBSPolicy,
        pixel_env(),
        representation="ambs",
        representation_kwargs=dict(hidden_dim=16, metric_hidden_dim=8),
        augmentation_views=2,
        encoder_tau=0.05,
        max_grad_norm=40.0,
        classifier_start=150,
        classifier_iters=10,
        policy_kwargs=policy_kwargs(AMBSPolicy),
        **TINY,
    )
    agent.learn(400)
    logged = agent.logger.name_to_value
    assert "ambs/metric_loss" in logged and "sgfd/classifier_accuracy" in logged
    agent.save(tmp_path / "agent")
    loaded = SGFD_SAC.load(tmp_path / "agent", env=pixel_env())
    assert loaded.representation == "ambs" and loaded.representation_model is not None
    assert_same_parameters(agent.representation_model, loaded.representation_model)


@pytest.mark.parametrize("name", list(AGENTS))
def test_save_load_predicts_identically_and_keeps_the_objective_and_its_optimisers(name, tmp_path):
    algo, policy, kwargs, _ = AGENTS[name]
    agent = algo(policy, pixel_env(), representation_kwargs=kwargs, policy_kwargs=policy_kwargs(policy), **TINY)
    agent.learn(200)
    agent.save(tmp_path / name)
    loaded = algo.load(tmp_path / name, env=pixel_env())
    obs = agent.env.reset()
    np.testing.assert_array_equal(agent.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    assert_same_parameters(agent.representation_model, loaded.representation_model)
    names = agent.representation_model.optimizer_names()
    assert names
    for optimizer_name in names:
        saved = getattr(agent.representation_model, optimizer_name).state_dict()["state"]
        restored = getattr(loaded.representation_model, optimizer_name).state_dict()["state"]
        assert saved and saved.keys() == restored.keys(), optimizer_name
        assert all(th.equal(saved[key]["exp_avg"], restored[key]["exp_avg"]) for key in saved)
    loaded.learn(40, reset_num_timesteps=False)
    assert loaded.num_timesteps == agent.num_timesteps + 40


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(augmentation_views=3), "augmentation_views must be 0, 1 or 2"),
        (dict(encoder_tau=0.0), "encoder_tau must be a number in"),
        (dict(max_grad_norm=-1), "max_grad_norm must be a finite number > 0"),
        (dict(representation="simclr"), r"representation must be None or one of \['ambs', 'dbc', 'sgqn', 'ted'\]"),
        (dict(representation="dbc", representation_kwargs=dict(bisim=1)), "representation_kwargs for 'dbc'"),
        (dict(representation_kwargs=dict(bisim_coef=1)), "given without a representation"),
        (dict(augmentation_views=1), "augmentation_views=1 shifts images"),
        (
            dict(representation="dbc", policy_kwargs=dict(features_extractor_class=FlattenExtractor)),
            "trains the encoder, but FlattenExtractor has no parameters",
        ),
        (dict(representation="dbc", representation_kwargs=dict(metric="papr")), "metric must be one of"),
        (dict(representation="ambs", representation_kwargs=dict(transition="ensemble")), "transition must be one of"),
        (dict(representation="ambs", representation_kwargs=dict(metric="paper", meta_learners=False)), "code's form"),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EncoderSAC("MlpPolicy", state_env(), **kwargs)


def test_a_representation_needs_a_critic_trained_shared_encoder():
    # SB3's own SAC policy: its actor trains the shared encoder, or actor and critic have one each
    with pytest.raises(ValueError, match="needs a policy whose encoder the critic trains"):
        EncoderSAC(SAC.policy_aliases["MlpPolicy"], state_env(), representation="dbc")


def test_an_agent_refuses_another_objective():
    with pytest.raises(ValueError, match="AMBS trains the 'ambs' representation, got representation='dbc'"):
        AMBS(AMBSPolicy, pixel_env(), representation="dbc")
    with pytest.raises(ValueError, match="needs the AMBSEncoder"):
        EncoderSAC(CnnPolicy, pixel_env(), representation="ambs", policy_kwargs=policy_kwargs(CnnPolicy))


def encoder_passes_per_update(agent: EncoderSAC, steps: int) -> float:
    """Forward passes of the critic's encoder inside ``train``, per gradient step, over ``steps`` env steps."""
    passes, training = [], [False]
    agent.critic.features_extractor.register_forward_hook(lambda *args: passes.append(1) if training[0] else None)
    train = agent.train

    def counted(*args, **kwargs):
        training[0] = True
        try:
            return train(*args, **kwargs)
        finally:
            training[0] = False

    agent.train = counted
    agent.learn(steps)
    return len(passes) / agent._n_updates


@pytest.mark.parametrize("name", [*AGENTS, "sgfd_on_ambs"])
def test_the_actor_loss_reads_the_critics_features_instead_of_encoding_the_batch_again(name):
    passes = {}
    for reuse in (True, False):
        if name == "sgfd_on_ambs":
            kwargs = dict(representation="ambs", representation_kwargs=AGENTS["ambs"][2], classifier_start=0)
            agent = SGFD_SAC(AMBSPolicy, pixel_env(), **kwargs, **TINY, policy_kwargs=policy_kwargs(AMBSPolicy))
        else:
            algo, policy, kwargs, _ = AGENTS[name]
            agent = algo(policy, pixel_env(), representation_kwargs=kwargs, **TINY, policy_kwargs=policy_kwargs(policy))
        agent.actor_update_interval, agent.actor_reuses_features = 1, reuse
        passes[reuse] = encoder_passes_per_update(agent, 140)
    # one pass less per step: the actor's Q comes from the features the critic's loss computed
    assert passes[False] - passes[True] == pytest.approx(1.0), passes


def test_gradient_clipping_counts_only_the_parameters_each_optimiser_steps(monkeypatch):
    clipped = []
    clip = th.nn.utils.clip_grad_norm_
    monkeypatch.setattr(
        th.nn.utils,
        "clip_grad_norm_",
        lambda params, norm, **kw: clipped.append(list(params)) or clip(clipped[-1], norm),
    )
    agent = AMBS(AMBSPolicy, pixel_env(), representation_kwargs=AGENTS["ambs"][2], **TINY)
    agent.learn(120)
    groups = {
        "actor": {id(p) for group in agent.actor.optimizer.param_groups for p in group["params"]},
        "critic": {id(p) for group in agent.critic.optimizer.param_groups for p in group["params"]},
    }
    seen = [{id(p) for p in params} for params in clipped]
    assert seen and all(ids in groups.values() for ids in seen)
    assert groups["actor"] in seen
    # the actor's clip leaves out the shared encoder, which its optimiser does not step
    assert not groups["actor"] & {id(p) for p in agent.critic.features_extractor.parameters()}


def test_each_agent_maps_the_usual_policy_names_to_its_own_policies():
    from sb3_sgfd import EncoderMlpPolicy
    from sb3_sgfd.ambs.policies import AMBSEncoder
    from sb3_sgfd.common.policies import MlpEncoder

    assert type(AMBS("CnnPolicy", pixel_env(), **TINY).policy) is AMBSPolicy
    on_states = AMBS("MlpPolicy", state_env(), augmentation_views=0, **TINY)
    assert type(on_states.policy) is AMBSPolicy and isinstance(on_states.critic.features_extractor, AMBSEncoder)
    assert isinstance(on_states.critic.features_extractor.trunk, MlpEncoder)
    for algo in (DBC, TED):
        assert type(algo("MlpPolicy", state_env(), augmentation_views=0, **TINY).policy) is EncoderMlpPolicy
    assert type(DBC("CnnPolicy", pixel_env(), **TINY).policy) is CnnPolicy
    sgfd_on_ambs = SGFD_SAC("CnnPolicy", pixel_env(), representation="ambs", **TINY)
    assert type(sgfd_on_ambs.policy) is AMBSPolicy
    assert type(SGFD_SAC("MlpPolicy", state_env(), **TINY).policy) is MlpPolicy
