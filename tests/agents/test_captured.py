"""The update as captured work (``compile_update=True``) on the CPU, the twin of what a GPU replays: the same training
as the eager update for every agent, one plan per distinct step, the figures on the device; and the compiled solver's
step as the eager one computes it."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import Logger
from torch.utils._python_dispatch import TorchDispatchMode

from sb3_sgfd import EncoderSAC
from sb3_sgfd.common.capture import WARMUP_CALLS
from sb3_sgfd.common.device_figures import DeviceFigures
from sb3_sgfd.common.optimizers import prepare_optimizers, set_learning_rate
from sb3_sgfd.sgfd.classifier import masked_step
from sb3_sgfd.sgfd.decorrelation import paper_solution
from tests.agents.tiny import AGENTS, COMMON, state_env

STEPS = 45


def trained(
    name: str,
    compile_update: bool,
    steps: int = STEPS,
    masked: bool | None = None,
    ready: bool = False,
    fused: bool = False,
    compile_solver: bool = False,
):
    """The agent after its buffer is filled and ``steps`` gradient steps from the same random streams.

    :param masked: decide with tensors inside the steps, as a captured step does on a GPU (None: as the runner does)
    :param ready: SGFD's paper reading with its weights on from the first step (its solver runs at once)
    :param fused: the optimisers step fused, as ``compile_update`` has them (an eager model's are as SB3 makes them)
    :param compile_solver: SGFD's solver compiled, as ``compile_update`` compiles it on CUDA
    """
    model = AGENTS[name](compile_update=compile_update)
    model.learn(model.learning_starts)  # fills the buffer; no gradient step yet
    model.num_timesteps = 10**6  # past SGFD's classifier_start
    model._prepare_update()
    if fused:
        prepare_optimizers(model._update_optimizers(), captured=False, fused=True)
    if compile_solver:
        model.weighting.compile_solver()
    if masked is not None:
        model._update.masked = masked
    if ready:
        model.weighting.ready.fill_(True)
    th.manual_seed(1)
    np.random.seed(1)
    model.train(gradient_steps=steps, batch_size=model.batch_size)
    return model


def compared_parts(a, b) -> list[tuple[str, th.nn.Module, th.nn.Module]]:
    parts = [("policy", a.policy, b.policy)]
    if a.representation_model is not None:
        parts.append(("objective", a.representation_model, b.representation_model))
    if a.weighting is not None:
        parts.append(("weighting", a.weighting, b.weighting))
    return parts


@pytest.mark.slow
@pytest.mark.parametrize("name", list(AGENTS))
def test_the_captured_logic_trains_as_the_eager_one(name):
    # What a GPU captures, run on the CPU (the CPU twin of the captured step): every decision inside a step a tensor
    # (a masked classifier step, weights taken where they are on) instead of a Python branch. With torch.compile's
    # code generation switched off (what it would compile runs as written) and the eager model's optimisers fused as
    # the compiled model's are, both run the same arithmetic: the same training, to the last bit, whatever the machine.
    eager = trained(name, False, fused=True)
    with th._dynamo.config.patch(disable=True):
        captured = trained(name, True, masked=True)
    assert eager._n_updates == captured._n_updates == STEPS
    for attribute in ("actions", "observations", "rewards"):
        assert np.array_equal(getattr(eager.replay_buffer, attribute), getattr(captured.replay_buffer, attribute))
    for part, a, b in compared_parts(eager, captured):
        for (key, expected), (_, got) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
            assert th.equal(expected, got), (part, key)
    # every part moved: the comparison is not between two untrained models
    fresh = AGENTS[name](compile_update=False)
    assert any(not th.equal(p, q) for p, q in zip(fresh.policy.parameters(), captured.policy.parameters(), strict=True))
    if name.startswith("SGFD") and "official" not in name:
        assert bool(eager.weighting.ready) and bool(captured.weighting.ready), "the weights never started"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["SGFD paper", "SGFD official"])
def test_a_compiled_step_computes_what_the_eager_step_computes(name):
    # The solver compiled as compile_update compiles it on CUDA (on the CPU it stays eager: it does not pay there).
    # torch.compile's code (the weight solver's) orders its float32 arithmetic otherwise than the eager operators do,
    # so the two differ by rounding: over one step (before training compounds it) within float32's reach, relative
    # 1e-5 of each tensor, on any machine. Over many steps the runs drift apart as any two float32 orders do; that
    # they train alike is the test above.
    eager = trained(name, False, steps=1, ready=True)
    th._dynamo.reset()  # no compiled code cached from an earlier test: the compiled run must make its own
    graphs = th._dynamo.utils.counters["stats"]["unique_graphs"]
    compiled = trained(name, True, steps=1, ready=True, compile_solver=True)
    assert th._dynamo.utils.counters["stats"]["unique_graphs"] > graphs, "the solver ran uncompiled"
    for part, a, b in compared_parts(eager, compiled):
        for (key, expected), (_, got) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
            gap = (got.double() - expected.double()).norm() / expected.double().norm().clamp_min(1e-12)
            assert gap <= 1e-5, (part, key, float(gap))
    moved = AGENTS[name](compile_update=False).policy.parameters()
    assert any(not th.equal(p, q) for p, q in zip(moved, compiled.policy.parameters(), strict=True))


class OpSequence(TorchDispatchMode):
    """The operators a piece of a step dispatches, in order."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.ops.append(str(func))
        return func(*args, **(kwargs or {}))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["SGFD paper", "SGFD official", "SGQN", "AMBS"])
def test_each_plan_is_one_sequence_of_operators(name):
    # A captured graph replays what its first capture ran: every step with the same plan must run the same
    # operators, or a decision taken in Python is missing from the plan.
    model = AGENTS[name](compile_update=True, actor_update_interval=2)
    model.learn(model.learning_starts)
    model.num_timesteps = 10**6
    model._prepare_update()
    model._update.masked = True  # what a GPU captures
    runner_run = None
    sequences: dict = {}

    calls: dict = {}

    def recorded(key, piece, *args, **kwargs):
        with OpSequence() as ops:
            result = runner_run(key, piece, *args, **kwargs)
        calls[key] = calls.get(key, 0) + 1
        if calls[key] > WARMUP_CALLS:  # what a GPU captures: the calls after the eager warm-up
            sequences.setdefault(key, set()).add(tuple(ops.ops))
        return result

    runner_run, model._update.run = model._update.run, recorded
    model.train(gradient_steps=16, batch_size=model.batch_size)
    assert len(sequences) >= 2  # at least two plans: the actor learns every other step
    for key, seen in sequences.items():
        assert len(seen) == 1, f"plan {key} ran {len(seen)} different sequences of operators"


def test_device_figures_sum_on_the_device_and_stop_at_the_first_non_finite_value():
    figures = DeviceFigures("cpu")
    figures.start(10)
    for value in (1.0, 2.0, 4.0):
        figures.add("loss", th.tensor(value))
        figures.add("only when", th.tensor(value), when=th.tensor(value > 1.5))
        figures.check("loss", th.tensor(value))
        figures.end_update()
    assert figures.read() == {"loss": 7.0 / 3, "only when": 3.0}
    assert figures.read() == {}  # cleared by the read
    figures.check("critic loss", th.tensor(float("nan")))
    figures.end_update()
    figures.check("critic loss", th.tensor(float("inf")))
    with pytest.raises(RuntimeError, match=r"non-finite critic loss at update 13"):
        figures.raise_if_not_finite()


@pytest.mark.parametrize("take", [True, False])
def test_a_masked_step_is_the_step_or_nothing(take):
    th.manual_seed(0)
    layer = th.nn.Linear(3, 2)
    reference = th.nn.Linear(3, 2)
    reference.load_state_dict(layer.state_dict())
    optimizers = [th.optim.Adam(module.parameters(), lr=0.1) for module in (layer, reference)]
    for _ in range(3):  # the first step makes the state, the next ones use it
        for module, optimizer in zip((layer, reference), optimizers, strict=True):
            optimizer.zero_grad()
            module(th.ones(4, 3)).square().sum().backward()
        masked_step(optimizers[0], th.tensor(take))
        if take:
            optimizers[1].step()
    for got, expected in zip(layer.parameters(), reference.parameters(), strict=True):
        assert th.equal(got, expected)
    state = optimizers[0].state[layer.weight]
    assert take or (float(state["step"]) == 0 and not state["exp_avg"].any())


@pytest.mark.slow
def test_save_load_and_set_parameters_keep_the_compiled_update(tmp_path):
    model = trained("SGFD official", compile_update=True, steps=10)
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = type(model).load(tmp_path / "model", env=model.env)
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert loaded.compile_update is True  # saved with the model
    loaded.num_timesteps = model.num_timesteps
    loaded.set_logger(Logger(None, []))  # train() outside learn() logs somewhere, as SB3's SAC needs
    loaded.train(gradient_steps=5, batch_size=loaded.batch_size)
    assert loaded._update.compiled
    assert loaded._n_updates == 15 and all(th.isfinite(p).all() for p in loaded.policy.parameters())
    # new parameters: the runner forgets its graphs, the optimisers are set up again, training goes on from them
    given = {key: value.clone() for key, value in model.policy.state_dict().items()}
    loaded.set_parameters(model.get_parameters())
    assert not loaded._update.optimizers_prepared and not loaded._update.pieces.graphs
    assert all(th.equal(value, given[key]) for key, value in loaded.policy.state_dict().items())
    loaded.train(gradient_steps=5, batch_size=loaded.batch_size)
    assert loaded._update.optimizers_prepared and all(th.isfinite(p).all() for p in loaded.policy.parameters())


def test_optimisers_set_up_for_a_captured_update_step_as_before_and_back():
    # what a captured update does to the optimisers (on CUDA also capturable), and back to SB3's when eager
    th.manual_seed(0)
    layers = [th.nn.Linear(3, 2) for _ in range(2)]
    layers[1].load_state_dict(layers[0].state_dict())
    optimizers = [th.optim.Adam(layer.parameters(), lr=0.1) for layer in layers]
    extra = th.optim.SGD(th.nn.Linear(2, 1).parameters(), lr=0.1, momentum=0.9)

    def step(index: int) -> None:
        optimizers[index].zero_grad()
        layers[index](th.ones(4, 3)).square().sum().backward()
        optimizers[index].step()

    step(0), step(1)
    prepare_optimizers([optimizers[1], extra], captured=True)
    group = optimizers[1].param_groups[0]
    assert group["fused"] and th.is_tensor(group["lr"]) and th.is_tensor(optimizers[1].state[layers[1].weight]["step"])
    assert extra.param_groups[0]["fused"] and not th.is_tensor(extra.param_groups[0]["lr"])
    set_learning_rate(optimizers[1], 0.05)
    set_learning_rate(optimizers[0], 0.05)
    assert th.is_tensor(group["lr"]) and abs(float(group["lr"]) - 0.05) < 1e-8  # filled in place, where a graph reads
    step(0), step(1)
    for a, b in zip(layers[0].parameters(), layers[1].parameters(), strict=True):
        th.testing.assert_close(a, b)  # fused or not, the same Adam
    prepare_optimizers([optimizers[1]], captured=False)
    assert group["fused"] is None and abs(group["lr"] - 0.05) < 1e-8 and not group["capturable"]
    step(1)


def test_fused_optimisers_step_as_before_and_eager_keeps_the_way_each_was_made():
    # compile_update on the CPU steps fused without capturing: the rate and counters stay as SB3 keeps them; eager
    # gives each optimiser back the way it was made (SB3's loop, or a fused one the user asked for)
    th.manual_seed(0)
    layers = [th.nn.Linear(3, 2) for _ in range(3)]
    for layer in layers[1:]:
        layer.load_state_dict(layers[0].state_dict())
    made_fused = th.optim.Adam(layers[0].parameters(), lr=0.1, fused=True)
    made_plain = th.optim.Adam(layers[1].parameters(), lr=0.1)
    sb3s_loop = th.optim.Adam(layers[2].parameters(), lr=0.1)  # left as made: the reference
    start = [parameter.detach().clone() for parameter in layers[0].parameters()]
    prepare_optimizers([made_fused, made_plain], captured=False, fused=True)
    for optimizer in (made_fused, made_plain):
        group = optimizer.param_groups[0]
        assert group["fused"] and not group["foreach"] and not group["capturable"] and not th.is_tensor(group["lr"])
    for _ in range(3):
        for optimizer, layer in zip((made_fused, made_plain, sb3s_loop), layers, strict=True):
            optimizer.zero_grad()
            layer(th.ones(4, 3)).square().sum().backward()
            optimizer.step()
    for fused_a, fused_b, loop, before in zip(*(layer.parameters() for layer in layers), start, strict=True):
        assert th.equal(fused_a, fused_b) and not th.equal(loop, before)  # the steps moved the parameters
        th.testing.assert_close(fused_a, loop)  # the same Adam as SB3's loop, rounded otherwise
    prepare_optimizers([made_fused, made_plain], captured=False)
    assert made_fused.param_groups[0]["fused"] and made_plain.param_groups[0]["fused"] is None


def test_a_model_steps_fused_with_compile_update_on_the_cpu_and_as_asked_without():
    compiled = AGENTS["SGFD paper"](compile_update=True)
    asked = dict(COMMON, policy_kwargs=dict(net_arch=[16, 16], optimizer_kwargs=dict(fused=True)))
    eager = EncoderSAC("MlpPolicy", state_env(), **asked)
    plain = AGENTS["EncoderSAC"]()
    for model in (compiled, eager, plain):
        model.learn(model.learning_starts + 2)
    assert all(group["fused"] for o in compiled._update_optimizers() for group in o.param_groups)
    assert compiled.weighting.core is paper_solution  # the solver's compilation does not pay on the CPU
    # the policy's optimisers as its optimizer_kwargs made them (SB3 makes the entropy coefficient's without them)
    assert all(group["fused"] for o in (eager.actor.optimizer, eager.critic.optimizer) for group in o.param_groups)
    assert plain.critic.optimizer.param_groups[0]["fused"] is None  # SB3's own
