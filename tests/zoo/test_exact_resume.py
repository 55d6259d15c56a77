"""Resume is exact: N steps, save everything a checkpoint holds, build the run again, restore, N more steps: the
same parameters as 2N steps straight, bit for bit (on the CPU)."""

from __future__ import annotations

import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import AMBS, SGFD_SAC, AMBSPolicy, DomainReplayBuffer, MlpPolicy
from sgfd_zoo.runs import training_state
from sgfd_zoo.runs.training_state import RestoreTrainingState

ENV_ID = "SGFD/MT-walker-walk-v0"
TINY = dict(learning_starts=60, batch_size=16, buffer_size=1000, seed=3, policy_kwargs=dict(net_arch=[16, 16]))
PIXELS = dict(
    TINY, policy_kwargs=dict(net_arch=[16, 16], features_extractor_kwargs=dict(features_dim=8, n_filters=4, n_layers=2))
)


def state_env():
    return sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state", observe_parameter=True, seed=3)


def pixel_env():
    return VecTransposeImage(
        VecFrameStack(sgfd_envs.make_domain_vec_env(ENV_ID, image_size=24, seed=3, render="fast"), 2)
    )


AGENTS = {
    "SAC": (SAC, lambda: SAC(MlpPolicy, state_env(), replay_buffer_class=DomainReplayBuffer, **TINY)),
    "SGFD_SAC": (
        SGFD_SAC,
        lambda: SGFD_SAC("MlpPolicy", state_env(), classifier_start=80, classifier_iters=3, **TINY),
    ),
    "SGFD_SAC official": (
        SGFD_SAC,
        lambda: SGFD_SAC("MlpPolicy", state_env(), reading="official", classifier_start=80, **TINY),
    ),
    "AMBS": (AMBS, lambda: AMBS(AMBSPolicy, pixel_env(), representation_kwargs=dict(hidden_dim=16), **PIXELS)),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(AGENTS))
def test_n_steps_saved_and_resumed_then_n_more_are_2n_steps_straight(name, tmp_path):
    algo, make = AGENTS[name]
    straight = make().learn(240)
    first = make().learn(120)
    # what a checkpoint holds: the model, the replay buffer and the training state (data: an .npz), taken between
    # two steps
    training_state.save(first, str(tmp_path / "state.npz"))
    first.save(tmp_path / "model")
    first.save_replay_buffer(tmp_path / "buffer")
    env = first.get_env()
    del first
    # a new process would build the envs again from the same arguments
    # force_reset=False: the envs continue from their restored state, so the saved last observation stands
    resumed = algo.load(tmp_path / "model", env=pixel_env() if name == "AMBS" else state_env(), force_reset=False)
    resumed.load_replay_buffer(tmp_path / "buffer")
    restore = RestoreTrainingState(training_state.load(tmp_path / "state.npz"))
    resumed.learn(120, reset_num_timesteps=False, callback=restore)
    env.close()
    assert resumed.num_timesteps == straight.num_timesteps and resumed._n_updates == straight._n_updates
    for (key, expected), (_, got) in zip(
        straight.policy.state_dict().items(), resumed.policy.state_dict().items(), strict=True
    ):
        assert th.equal(expected, got), key
    assert th.equal(straight.log_ent_coef, resumed.log_ent_coef)
    if isinstance(straight, SGFD_SAC):
        for (key, expected), (_, got) in zip(
            straight.weighting.state_dict().items(), resumed.weighting.state_dict().items(), strict=True
        ):
            assert same(expected, got), key


def same(a, b) -> bool:
    """Equal to the last bit: tensors, and the dicts of extra state that hold them."""
    if isinstance(a, th.Tensor):
        return isinstance(b, th.Tensor) and th.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    return a == b
