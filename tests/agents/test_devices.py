"""The package on any device: replay batches reach it in one transfer, models save on one device and load on
another. The tests marked ``cuda`` run where a CUDA device is (``bench/device_check.py`` runs them on a GPU)."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

import sgfd_envs
from sb3_sgfd import AMBS, SGFD_SAC, AMBSPolicy, DomainReplayBuffer
from sb3_sgfd.common.transfer import BatchTransfer

IMAGES = spaces.Box(0, 255, shape=(6, 12, 12), dtype=np.uint8)
ACTIONS = spaces.Box(-1, 1, shape=(2,), dtype=np.float32)


def filled_buffer(device: str) -> DomainReplayBuffer:
    buffer = DomainReplayBuffer(64, IMAGES, ACTIONS, device=device, n_envs=2, frame_stack=2)
    rng = np.random.default_rng(0)
    obs = np.zeros((2, 6, 12, 12), dtype=np.uint8)
    for _ in range(40):
        frame = rng.integers(0, 256, size=(2, 3, 12, 12), dtype=np.uint8)
        next_obs = np.concatenate([obs[:, 3:], frame], axis=1)
        reward = rng.standard_normal(2).astype(np.float32)
        buffer.add(obs, next_obs, rng.uniform(-1, 1, (2, 2)), reward, np.zeros(2), [{"domain": 1}, {"domain": 0}])
        obs = next_obs
    return buffer


def test_on_the_cpu_a_batch_becomes_tensors_without_a_copy():
    arrays = [np.arange(12, dtype=np.uint8).reshape(3, 4), np.ones((3, 1), dtype=np.float32), np.arange(3)]
    tensors = BatchTransfer("cpu")(arrays)
    for array, tensor in zip(arrays, tensors, strict=True):
        assert tensor.dtype == th.from_numpy(array).dtype and tensor.shape == array.shape
        assert tensor.data_ptr() == array.ctypes.data  # the array itself
        assert np.array_equal(tensor.numpy(), array)


def test_a_loaded_buffer_sends_its_batches_to_the_models_device(tmp_path):
    buffer = filled_buffer("cpu")
    assert samples_of(buffer, 0).observations.device.type == "cpu"
    buffer.device = th.device("meta")  # what SB3's load_replay_buffer does with another device
    assert buffer._batch_transfer.device == th.device("meta")


def samples_of(buffer: DomainReplayBuffer, seed: int):
    np.random.seed(seed)
    return buffer.sample(16)


@pytest.mark.cuda
def test_on_a_gpu_a_batch_arrives_in_one_pinned_transfer_and_equals_the_cpu_batch():
    gpu, cpu = filled_buffer("cuda"), filled_buffer("cpu")
    on_gpu, on_cpu = samples_of(gpu, 3), samples_of(cpu, 3)
    assert gpu._batch_transfer._staging.is_pinned()
    assert on_gpu.observations.dtype == th.uint8 and on_gpu.observations.device.type == "cuda"
    for name in ("observations", "actions", "next_observations", "dones", "rewards", "domains"):
        assert th.equal(getattr(on_gpu, name).cpu(), getattr(on_cpu, name)), name
    again = samples_of(gpu, 4)  # the staging buffer is reused once the previous copy is done
    assert th.equal(again.observations.cpu(), samples_of(cpu, 4).observations)


def state_env():
    return sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter=True)


TINY = dict(learning_starts=50, batch_size=16, seed=0, policy_kwargs=dict(net_arch=[16, 16]))


@pytest.mark.cuda
@pytest.mark.parametrize("reading", ["paper", "official"])
def test_a_model_trained_on_a_gpu_loads_on_the_cpu_and_back(reading, tmp_path):
    model = SGFD_SAC("MlpPolicy", state_env(), reading=reading, classifier_start=0, device="cuda", **TINY)
    model.learn(200)
    model.save(tmp_path / "gpu")
    on_cpu = SGFD_SAC.load(tmp_path / "gpu", env=state_env(), device="cpu")
    assert all(p.device.type == "cpu" for p in on_cpu.weighting.parameters())
    if on_cpu.weighting.memory is not None:
        assert on_cpu.weighting.memory.features.device.type == "cpu"
    on_cpu.learn(100, reset_num_timesteps=False)
    on_cpu.save(tmp_path / "cpu")
    back = SGFD_SAC.load(tmp_path / "cpu", env=state_env(), device="cuda")
    assert next(back.policy.parameters()).device.type == "cuda"
    back.learn(100, reset_num_timesteps=False)


@pytest.mark.cuda
def test_the_papers_agent_trains_on_a_gpu_with_every_tensor_there():
    from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

    env = VecTransposeImage(
        VecFrameStack(sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", image_size=24, render="fast"), 2)
    )
    kwargs = dict(representation_kwargs=dict(hidden_dim=16), classifier_start=0, device="cuda", **TINY)
    model = SGFD_SAC(AMBSPolicy, env, representation="ambs", augmentation_views=2, **kwargs)
    model.learn(120)
    assert model.logger.name_to_value["sgfd/weight_ess"] > 0
    baseline = AMBS(AMBSPolicy, env, device="cuda", representation_kwargs=dict(hidden_dim=16), **TINY)
    baseline.learn(120)
