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


#: Each test below runs on the CPU in CI and, marked ``cuda``, on a GPU where there is one: its logic is proven on
#: the CPU before a GPU runs it (``bench/device_check.py`` runs the ``cuda`` ones on a GPU).
DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.cuda)]


@pytest.mark.parametrize("device", DEVICES)
def test_a_batch_arrives_in_one_transfer_and_equals_the_cpu_batch(device):
    buffer, cpu = filled_buffer(device), filled_buffer("cpu")
    on_device, on_cpu = samples_of(buffer, 3), samples_of(cpu, 3)
    assert on_device.observations.dtype == th.uint8 and on_device.observations.device.type == device
    for name in ("observations", "actions", "next_observations", "dones", "rewards", "domains"):
        assert th.equal(getattr(on_device, name).cpu(), getattr(on_cpu, name)), name
    again = samples_of(buffer, 4)  # on a GPU the staging buffer is reused once the previous copy is done
    assert th.equal(again.observations.cpu(), samples_of(cpu, 4).observations)
    staging = buffer._batch_transfer._staging
    assert (staging is not None and staging.is_pinned()) == (device == "cuda")  # pinned where a copy is async


def state_env():
    return sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter=True)


TINY = dict(learning_starts=50, batch_size=16, seed=0, policy_kwargs=dict(net_arch=[16, 16]))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("reading", ["paper", "official"])
@pytest.mark.slow
def test_a_model_trained_on_a_device_loads_on_the_cpu_and_back(device, reading, tmp_path):
    # its update captured on CUDA (on the CPU the same path without graphs), then eager on the CPU, then captured
    # again: saved from either way, it trains on in the other
    model = SGFD_SAC(
        "MlpPolicy", state_env(), reading=reading, classifier_start=0, device=device, compile_update=True,
        reweight_iters=3, **TINY,
    )  # fmt: skip
    model.learn(200)
    model.save(tmp_path / "first")
    on_cpu = SGFD_SAC.load(tmp_path / "first", env=state_env(), device="cpu")
    assert all(p.device.type == "cpu" for p in on_cpu.weighting.parameters())
    if on_cpu.weighting.memory is not None:
        assert on_cpu.weighting.memory.features.device.type == "cpu"
    on_cpu.compile_update = False
    on_cpu.learn(100, reset_num_timesteps=False)
    on_cpu.save(tmp_path / "cpu")
    back = SGFD_SAC.load(tmp_path / "cpu", env=state_env(), device=device)
    back.compile_update = True
    assert next(back.policy.parameters()).device.type == device
    back.learn(100, reset_num_timesteps=False)
    assert back._update.capture == (device == "cuda")


def tensors_of(model) -> dict[str, th.Tensor]:
    """Every tensor a training step touches: parameters, optimiser states, the weighting's and objective's state,
    the figures."""
    found = {f"policy.{k}": v for k, v in model.policy.state_dict().items()}
    found |= {f"weighting.{k}": v for k, v in model.weighting.state_dict().items()}
    found |= {f"objective.{k}": v for k, v in model.representation_model.state_dict().items()}
    optimizers = [*model._update_optimizers()]
    for index, optimizer in enumerate(optimizers):
        for state in optimizer.state.values():
            found |= {f"optimizer {index}.{k}": v for k, v in state.items() if th.is_tensor(v) and k != "step"}
    found |= {"figures.update": model._update.figures.update, "weighting.ready": model.weighting.ready}
    return found


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.slow
def test_the_papers_agent_trains_with_every_tensor_on_its_device(device):
    from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

    env = VecTransposeImage(
        VecFrameStack(sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", image_size=24, render="fast"), 2)
    )
    # the weighting starts within the run: its classifier from the first update, and a threshold just above chance
    # (4 domains: 0.25): a 16-sample batch scores >= 0.3 (5 right) by chance with p ~ 0.37, so some of the ~48
    # rounds reach it whatever the device's arithmetic (0.5 is reached on some seeds only: issue 38)
    settings = dict(classifier_start=0, accuracy_threshold=0.3, reweight_iters=3)
    kwargs = dict(representation_kwargs=dict(hidden_dim=16), device=device, compile_update=True, **TINY)
    model = SGFD_SAC(AMBSPolicy, env, representation="ambs", augmentation_views=2, **settings, **kwargs)
    model.learn(240)
    assert bool(model.weighting.ready), "the weights never started"
    model._update.log_figures(model.logger)
    assert 0 < model.logger.name_to_value["sgfd/weight_ess"] <= 1
    wrong = {name: str(t.device) for name, t in tensors_of(model).items() if t.device.type != device}
    assert not wrong, wrong
    assert model.replay_buffer._batch_transfer.device.type == device
    assert bool(model._update.pieces.graphs) == (device == "cuda")  # the step replayed as graphs on CUDA
    baseline = AMBS(AMBSPolicy, env, **kwargs)
    baseline.learn(120)
    assert bool(baseline._update.pieces.graphs) == (device == "cuda")
