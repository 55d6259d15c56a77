import base64
import json
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.utils import ConstantSchedule

import sb3_sgfd
from sb3_sgfd import EncoderSAC
from sb3_sgfd.common.policies import CnnPolicy, MlpPolicy, PixelEncoder, SharedEncoderPolicy

IMAGE_SPACE = spaces.Box(0, 255, shape=(9, 32, 32), dtype=np.uint8)
ACTION_SPACE = spaces.Box(-1, 1, shape=(3,), dtype=np.float32)


def make_policy(**kwargs) -> SharedEncoderPolicy:
    kwargs.setdefault("net_arch", [32, 32])
    return CnnPolicy(IMAGE_SPACE, ACTION_SPACE, ConstantSchedule(1e-3), **kwargs)


def test_pixel_encoder_is_the_papers_architecture():
    encoder = PixelEncoder(spaces.Box(0, 255, shape=(9, 84, 84), dtype=np.uint8))
    convs = [layer for layer in encoder.convs if isinstance(layer, th.nn.Conv2d)]
    assert [conv.stride for conv in convs] == [(2, 2), (1, 1), (1, 1), (1, 1)]
    assert {conv.kernel_size for conv in convs} == {(3, 3)}
    assert {conv.out_channels for conv in convs} == {32}
    assert isinstance(encoder.trunk[1], th.nn.LayerNorm) and isinstance(encoder.trunk[2], th.nn.Tanh)
    z = encoder(th.rand(5, 9, 84, 84))
    assert z.shape == (5, 50)
    assert z.abs().max() < 1


def test_encoder_is_shared_and_trained_by_the_critic_only():
    policy = make_policy()
    assert policy.actor.features_extractor is policy.critic.features_extractor
    assert policy.critic_target.features_extractor is not policy.critic.features_extractor
    encoder_params = {id(p) for p in policy.critic.features_extractor.parameters()}
    actor_opt = {id(p) for group in policy.actor.optimizer.param_groups for p in group["params"]}
    critic_opt = {id(p) for group in policy.critic.optimizer.param_groups for p in group["params"]}
    assert encoder_params <= critic_opt
    assert not encoder_params & actor_opt

    obs = th.randint(0, 256, (4, *IMAGE_SPACE.shape)).float() / 255
    actions, log_prob = policy.actor.action_log_prob(obs)
    (log_prob.sum() + actions.sum()).backward()
    assert all(p.grad is None for p in policy.critic.features_extractor.parameters())
    assert any(p.grad is not None for p in policy.actor.latent_pi.parameters())

    q1, _ = policy.critic(obs, actions.detach())
    q1.sum().backward()
    grads = [p.grad for p in policy.critic.features_extractor.parameters()]
    assert all(g is not None for g in grads) and any(g.abs().sum() > 0 for g in grads)


def test_default_features_extractor_follows_the_observation_space():
    state_space = spaces.Box(-np.inf, np.inf, shape=(7,), dtype=np.float32)
    lr = ConstantSchedule(1e-3)
    assert isinstance(
        SharedEncoderPolicy(IMAGE_SPACE, ACTION_SPACE, lr, net_arch=[8]).actor.features_extractor, PixelEncoder
    )
    assert not isinstance(
        SharedEncoderPolicy(state_space, ACTION_SPACE, lr, net_arch=[8]).actor.features_extractor, PixelEncoder
    )
    assert not isinstance(MlpPolicy(state_space, ACTION_SPACE, lr, net_arch=[8]).actor.features_extractor, PixelEncoder)
    assert SharedEncoderPolicy(state_space, ACTION_SPACE, lr).net_args["net_arch"] == [1024, 1024]


def test_the_former_name_sgfd_policy_still_names_the_shared_encoder_policy(tmp_path):
    # yaml files and code name it "SGFDPolicy", and models saved before the rename name its class by that path
    assert sb3_sgfd.SGFDPolicy is sb3_sgfd.SharedEncoderPolicy is SharedEncoderPolicy
    for name in ("SGFDPolicy", "SharedEncoderPolicy"):
        assert EncoderSAC.policy_aliases[name] is SharedEncoderPolicy
    model = EncoderSAC("SGFDPolicy", "Pendulum-v1", buffer_size=100, policy_kwargs={"net_arch": [8]}, seed=0)
    SharedEncoderPolicy.__qualname__ = "SGFDPolicy"  # saved as before the rename: the class named by its former path
    try:
        model.save(tmp_path / "model.zip")
    finally:
        SharedEncoderPolicy.__qualname__ = "SharedEncoderPolicy"
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        policy_class = json.loads(archive.read("data"))["policy_class"][":serialized:"]
    assert b"sb3_sgfd.common.policies" in base64.b64decode(policy_class)
    assert b"SGFDPolicy" in base64.b64decode(policy_class)
    assert type(EncoderSAC.load(tmp_path / "model.zip").policy) is SharedEncoderPolicy


def test_separate_encoders_are_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="share_features_extractor"):
        make_policy(share_features_extractor=False)


def test_plain_sac_trains_and_reloads_with_the_sgfd_policy(tmp_path):
    model = SAC(MlpPolicy, "Pendulum-v1", learning_starts=20, batch_size=16, policy_kwargs={"net_arch": [16]}, seed=0)
    model.learn(60)
    assert isinstance(model.policy, MlpPolicy)
    obs = model.env.observation_space.sample()[None]
    model.save(tmp_path / "sac")
    loaded = SAC.load(tmp_path / "sac")
    assert isinstance(loaded.policy, MlpPolicy)
    assert loaded.policy.actor.features_extractor is loaded.policy.critic.features_extractor
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])


def test_an_mlp_policy_on_images_warns_once_in_one_line_at_the_users_line():
    import sgfd_envs
    from sb3_sgfd import SGFD_SAC
    from sb3_sgfd.common.observations import FlattenedImagesWarning

    pixels = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", split="train", image_size=16)
    small = dict(buffer_size=64, policy_kwargs=dict(net_arch=[8]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        SGFD_SAC("MlpPolicy", pixels, **small)
        SGFD_SAC("CnnPolicy", pixels, **small)  # convolutions: no warning
    flattened = [warning for warning in caught if issubclass(warning.category, FlattenedImagesWarning)]
    assert len(flattened) == 1, [str(warning.message) for warning in caught]
    message = str(flattened[0].message)
    assert "\n" not in message and "'CnnPolicy'" in message and "Box(shape=(3, 16, 16), dtype=uint8)" in message
    assert Path(flattened[0].filename).resolve() == Path(__file__).resolve()
    pixels.close()


def test_a_cnn_policy_on_states_is_refused_in_one_line():
    import sgfd_envs
    from sb3_sgfd import SGFD_SAC

    states = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter=True)
    with pytest.raises(ValueError, match=r"got Box\(shape=\(25,\), dtype=float32\); for states use MlpPolicy") as error:
        SGFD_SAC("CnnPolicy", states, buffer_size=64)
    assert "\n" not in str(error.value)
    states.close()
