"""
Cost of one gradient step of SGFD_SAC and the paper's agents next to SB3's SAC, eager and compiled
(``compile_update=True``: on CUDA one CUDA-graph replay per step plan, SGFD's weight solver compiled by torch.compile;
on the CPU the optimisers stepping fused), with the same policy, batch and replay data. On the CPU a row of SB3's SAC
with fused Adam (``optimizer_kwargs=dict(fused=True)``) shows what the fused optimisers alone give, and with
``--solver-row`` a row of the steady phase with its solver compiled as on CUDA what torch.compile would add there (and
when it would pay back).

Two policies, and the agents:

- ``mlp``: MlpPolicy [256, 256] on SGFD/MT-walker-walk-v0 states with ``observe_parameter=True`` (25-d);
- ``cnn``: CnnPolicy (the paper's encoder, 1024-wide heads) on 9x84x84 observations (3 stacked 84x84 frames
  of SGFD/walker-walk-v0);
- ``agents``: DBC, AMBS, SGFD on AMBS (the paper's agent, steady phase), TED and SGQN on the same pixels, each with
  its objective and augmentation as in sgfd_zoo/hyperparams.

SGFD is timed in three phases: ``steady`` (weights on, the classifier above its threshold: its round is scored and
skipped on the host, or masked off in a captured step), ``classifier`` (the classifier training at every step,
weights not yet on: the start of a run; no solver, where the host decides) and ``mixed`` (weights on and the
classifier training). A compiled row's one-off cost (compilation, captures) is printed under its ratio, with the
updates after which it pays back. Every model updates its actor at every step, so the ratio to SAC is
the additions' own cost. Each timed round is ``--round-steps`` gradient steps of every model in turn, so all see the
same machine load; the table gives the median over rounds of the time per step and of the ratio within a round.

For the MLP on the CPU, the steady eager step's additions are also timed part by part, each alone in every round:
the weights (the classifier's pass and the solver), the classifier's pass alone, and the solver's products alone
(``2 x reweight_iters`` of them at the shapes of the batch's random Fourier features: the covariance form's compute),
each as a share of SAC's step, beside what the goal of at most 1.2x leaves for them.

Beside the time, the operator dispatches per update (a dispatch-mode counter; on a GPU each is a kernel launch of
about 25 us): SB3's eager SAC, each eager update, and each compiled update as the host runs it once captured, i.e.
everything outside its captured pieces plus one replay per piece (on the CPU, where nothing is captured, the counter
pauses inside the pieces where CUDA replays a graph) and, apart, the operators inside them (what a replay runs on the
device without the host). Goal: the compiled update's host dispatches at most a tenth of SB3's eager SAC's.

    python bench/update_overhead.py                                  # mlp and cnn
    python bench/update_overhead.py --policies mlp --rounds 30 --solver-row
    python bench/update_overhead.py --policies agents --rounds 5     # DBC, AMBS, SGFD on AMBS, TED, SGQN
    python bench/update_overhead.py --policies mlp --compiled-only   # SAC, and the compiled rows alone
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecTransposeImage
from torch.utils._python_dispatch import TorchDispatchMode

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, AMBSPolicy, CnnPolicy, DomainReplayBuffer, MlpPolicy
from sgfd_envs.backgrounds import overlay_bank

PHASES = ("steady", "classifier", "mixed")
#: The CPU's row of the steady phase compiled with SGFD's solver compiled as on CUDA (on the CPU it runs eager)
SOLVER_COMPILED = "SGFD steady compiled with its solver"
#: Issue 47's goal for the steady eager step: at most this many times SAC's step (the parts' table says what it leaves)
STEADY_GOAL = 1.2
IMAGE_SIZE = [84]  # --image-size (the paper's 84; smaller only for a smoke run)


def state_env() -> VecEnv:
    return sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter=True)


def pixel_env() -> VecEnv:
    # The fast render: this bench times gradient steps on the batches it collects, not the render.
    env = sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", image_size=IMAGE_SIZE[0], render="fast")
    return VecTransposeImage(VecFrameStack(env, 3))


POLICIES: dict[str, tuple[type, Callable[[], VecEnv], dict]] = {
    "mlp": (MlpPolicy, state_env, {"net_arch": [256, 256]}),
    "cnn": (CnnPolicy, pixel_env, {}),
    "agents": (CnnPolicy, pixel_env, {}),
}

#: Each phase held through SGFD's own settings (and the weighting's ``ready``: whether the weights have started).
#: Steady: every accuracy above 0 reaches the least threshold, so a round trains nothing (skipped on the host; in a
#: captured step masked off, at the cost of a step). Classifier and mixed: a classifier whose learning rate leaves its
#: parameters as they are never reaches an accuracy of 1, so it takes its step on every round.
PHASE_SETTINGS: dict[str, dict[str, Any]] = {
    "steady": {"accuracy_threshold": 1e-6},
    "classifier": {"accuracy_threshold": 1.0, "classifier_lr": 1e-12},
    "mixed": {"accuracy_threshold": 1.0, "classifier_lr": 1e-12},
}


def fill(model: BaseAlgorithm, n_steps: int, seed: int) -> None:
    """Random-action transitions of every domain, stored as SB3 stores them."""
    env = model.get_env()
    rng = np.random.default_rng(seed)
    obs = env.reset()
    for _ in range(n_steps):
        actions = rng.uniform(-1, 1, size=(env.num_envs, *env.action_space.shape)).astype(np.float32)
        next_obs, rewards, dones, infos = env.step(actions)
        model._last_obs = obs
        model._store_transition(model.replay_buffer, actions, next_obs, rewards, dones, infos)
        obs = next_obs


def sgfd_in_phase(phase: str, policy: type, env: VecEnv, **common: Any) -> SGFD_SAC:
    """SGFD_SAC held in one phase (:data:`PHASE_SETTINGS`): whether it trains its classifier and weights its losses."""
    model = SGFD_SAC(policy, env, actor_update_interval=1, classifier_start=0, **PHASE_SETTINGS[phase], **common)
    model.weighting.ready.fill_(phase in ("steady", "mixed"))
    return model


def models_of(name: str, args: argparse.Namespace, device: th.device) -> dict[str, BaseAlgorithm]:
    """SB3's SAC, then each compared model eager and compiled (``--compiled-only``: compiled alone)."""
    policy, make_env, policy_kwargs = POLICIES[name]
    common: dict[str, Any] = dict(
        buffer_size=10_000, batch_size=args.batch_size, learning_rate=1e-3, tau=0.01, seed=0, device=device
    )
    common["policy_kwargs"] = policy_kwargs
    if policy is CnnPolicy:  # the paper's frame-deduplicating buffer keeps several pixel models in memory
        common["replay_buffer_kwargs"] = dict(frame_stack=3)
    models: dict[str, BaseAlgorithm] = {
        "SAC": SAC(policy, make_env(), replay_buffer_class=DomainReplayBuffer, **common)
    }
    ways = [("compiled", True)] if args.compiled_only else [("eager", False), ("compiled", True)]
    if device.type == "cpu" and name != "agents":
        # SB3's SAC with the fused Adam that a compiled update steps with on the CPU: how much of the compiled rows'
        # gain is the optimiser's alone
        fused = dict(common, policy_kwargs=dict(policy_kwargs, optimizer_kwargs=dict(fused=True)))
        models["SAC fused Adam"] = SAC(policy, make_env(), replay_buffer_class=DomainReplayBuffer, **fused)
    for way, compiled in ways:
        each = dict(common, compile_update=compiled)
        if name == "agents":
            ambs = dict(augmentation_views=2, encoder_tau=0.05, max_grad_norm=40.0, representation="ambs")
            sgqn = dict(quantile=0.98, overlay_images=overlay_bank(IMAGE_SIZE[0], IMAGE_SIZE[0]))
            models[f"DBC {way}"] = DBC(CnnPolicy, make_env(), actor_update_interval=1, **each)
            models[f"AMBS {way}"] = AMBS(AMBSPolicy, make_env(), actor_update_interval=1, **each)
            models[f"SGFD on AMBS {way}"] = sgfd_in_phase("steady", AMBSPolicy, make_env(), **ambs, **each)
            models[f"TED {way}"] = TED(CnnPolicy, make_env(), actor_update_interval=1, **each)
            models[f"SGQN {way}"] = SGQN(
                CnnPolicy, make_env(), actor_update_interval=1, representation_kwargs=sgqn, **each
            )
        else:
            for phase in PHASES:
                models[f"SGFD {phase} {way}"] = sgfd_in_phase(phase, policy, make_env(), **each)
            if compiled and device.type == "cpu" and args.solver_row:
                # the steady phase compiled with its solver compiled too (as on CUDA): what torch.compile adds alone
                model = sgfd_in_phase("steady", policy, make_env(), **each)
                model.weighting.compile_solver()
                models[SOLVER_COMPILED] = model
    return models


def classifier_steps(model: SGFD_SAC) -> int:
    """The optimiser steps the paper reading's classifier has taken (Adam counts them; a skipped or masked one not)."""
    state = model.weighting.classifier_optimizer.state.get(next(model.classifier.parameters()), {})
    return int(state.get("step", 0))


def check_phase(key: str, model: SGFD_SAC, first_update: int, steps_before: int) -> None:
    """That the classifier trained on every update since ``first_update`` (classifier and mixed phases; in the steady
    one it trains only on a batch it gets wholly wrong), and the weights were on (classifier phase: off)."""
    phase = next((phase for phase in PHASES if f" {phase} " in f" {key} "), "steady")
    taken, updates = classifier_steps(model) - steps_before, model._n_updates - first_update
    if phase != "steady":  # steady: a batch no domain of which the classifier gets right (accuracy 0) still trains it
        assert taken == updates, f"{key}: the classifier took {taken} steps where the phase holds {updates}"
    model._update.log_figures(model.logger)  # what the device still holds, into the logger
    weighted = "sgfd/weight_ess" in model.logger.name_to_value
    assert weighted == (phase != "classifier"), f"{key}: the weights were {'on' if weighted else 'off'}"


def steady_parts(model: SGFD_SAC, batch_size: int) -> dict[str, Callable[[], object]]:
    """What SGFD's steady step adds, as calls timed alone on one batch of the model's replay data: its weights (the
    classifier's pass and the solver, ``weighting.solve``), the classifier's pass alone (predictions and saliency), and
    the products the solver is made of alone (``2 x reweight_iters`` of them at the shapes of the batch's random
    Fourier features: the compute of the covariance form, which SGFD_SAC runs)."""
    weighting, settings = model.weighting, model.sgfd
    z = model.encode(model.replay_buffer.sample(batch_size).observations)  # type: ignore[union-attr]
    generator = th.Generator(device=z.device).manual_seed(0)
    n, width = z.shape[0], z.shape[1] * settings.n_rff
    features = th.randn(n, width, generator=generator, device=z.device)
    uniform = th.full((n, 1), 1.0 / n, device=z.device)
    pairs = th.randn(width, width, generator=generator, device=z.device)

    def products() -> None:
        for _ in range(settings.reweight_iters):
            features.T @ (uniform * features)  # the covariance under the weights
            features @ pairs  # its gradient's product

    products_key = f"the solver's {2 * settings.reweight_iters} products alone ({n} x {width} features)"
    return {
        "the weights: classifier pass and solver": lambda: weighting.solve(z, generator),
        "the classifier's pass (predictions, saliency)": lambda: weighting.classifier.predictions_and_input_gradient(z),
        products_key: products,
    }


def time_call(call: Callable[[], object], repeats: int) -> float:
    """Seconds per call over ``repeats`` calls (on the CPU: nothing to synchronise)."""
    start = time.perf_counter()
    for _ in range(repeats):
        call()
    return (time.perf_counter() - start) / repeats


def print_steady_parts(parts: dict[str, list[float]], times: dict[str, list[float]]) -> None:
    """The steady eager step's additions over SAC's step, and each part timed alone, as ms and as a share of SAC's
    step in the same round; beside them, what the goal (:data:`STEADY_GOAL`) leaves for all of SGFD's additions."""
    added = [steady - sac for steady, sac in zip(times["SGFD steady eager"], times["SAC"], strict=True)]
    rows = {"SGFD steady eager minus SAC": added, **parts}
    print("\nSGFD steady eager, what it adds, each part timed alone (medians over rounds; share of SAC's step)\n")
    width = max(len(key) for key in rows)
    print(f"| {'part':<{width}} | {'ms per step':>11} | {'of SAC':>6} |")
    print(f"|{'-' * (width + 2)}|{'-' * 13}|{'-' * 8}|")
    for key, values in rows.items():
        share = statistics.median(value / sac for value, sac in zip(values, times["SAC"], strict=True))
        print(f"| {key:<{width}} | {1e3 * statistics.median(values):>11.2f} | {share:>6.2f} |")
    left = f"{STEADY_GOAL - 1:.2f} of SAC's step"
    print(f"at most {STEADY_GOAL}x leaves {left} for everything SGFD adds in the steady phase")


def synchronize(device: th.device) -> None:
    if device.type == "cuda":
        th.cuda.synchronize(device)


def time_round(model: BaseAlgorithm, steps: int, batch_size: int, device: th.device) -> float:
    """Seconds per gradient step over ``steps`` steps."""
    synchronize(device)
    start = time.perf_counter()
    model.train(gradient_steps=steps, batch_size=batch_size)
    synchronize(device)
    return (time.perf_counter() - start) / steps


class Dispatches(TorchDispatchMode):
    """Counts operator dispatches; paused inside a compiled model's captured pieces, each of which counts as one
    replay, while the operators inside are counted apart."""

    def __init__(self) -> None:
        super().__init__()
        self.host, self.inside, self.paused = 0, 0, False

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
        if self.paused:
            self.inside += 1
        else:
            self.host += 1
        return func(*args, **(kwargs or {}))


def dispatches_per_update(model: BaseAlgorithm, batch_size: int, steps: int = 4) -> tuple[float, float]:
    """Host dispatches per update, and (compiled) the dispatches inside its captured pieces per update."""
    counter = Dispatches()
    runner = getattr(model, "_update", None)
    replays = runner is not None and runner.capture
    if replays:
        run = runner.run

        def replayed(key, piece, *args, **kwargs):  # type: ignore[no-untyped-def]
            counter.host += 1  # the replay
            counter.paused = True
            try:
                return run(key, piece, *args, **kwargs)
            finally:
                counter.paused = False

        runner.run = replayed
    try:
        with counter:
            model.train(gradient_steps=steps, batch_size=batch_size)
    finally:
        if replays:
            runner.run = run
    return counter.host / steps, counter.inside / steps


def timed_rounds(
    models: dict[str, BaseAlgorithm],
    parts: dict[str, Callable[[], object]],
    rounds: int,
    steps: int,
    batch_size: int,
    device: th.device,
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Seconds per step of each model and per call of each part, in each round: all of them in turn, so that all see
    the same machine load, in an order rotated by one place each round, so that each takes every place in turn (a
    slower stretch of the machine falls on none of them more than on the others)."""
    times: dict[str, list[float]] = {key: [] for key in models}
    part_times: dict[str, list[float]] = {key: [] for key in parts}
    timed: list[tuple[list[float], Callable[[], float]]] = [
        *(
            (times[key], lambda model=model: time_round(model, steps, batch_size, device))
            for key, model in models.items()
        ),
        *((part_times[key], lambda call=call: time_call(call, steps)) for key, call in parts.items()),
    ]
    for index in range(rounds):
        shift = index % len(timed)
        for seconds, measure in timed[shift:] + timed[:shift]:
            seconds.append(measure())
    return times, part_times


def bench_policy(name: str, args: argparse.Namespace, device: th.device) -> dict[str, float]:
    models = models_of(name, args, device)
    gpu = device.type == "cuda"
    warmup_seconds: dict[str, float] = {}
    for key, model in models.items():
        model._setup_learn(10**6)
        fill(model, args.fill, seed=0)
        # warm-up: the allocator, the first classifier steps, compilation and captures (on a GPU cuDNN's kernels)
        warmup = args.warmup or (20 if gpu else 3)
        warmup_seconds[key] = warmup * time_round(model, warmup, args.batch_size, device)
    dispatches = {key: dispatches_per_update(model, args.batch_size) for key, model in models.items()}
    steps = args.round_steps or ((200 if gpu else 20) if name == "mlp" else (50 if gpu else 2))
    sgfd_models = {key: model for key, model in models.items() if isinstance(model, SGFD_SAC)}
    start = {key: (model._n_updates, classifier_steps(model)) for key, model in sgfd_models.items()}
    steady = models.get("SGFD steady eager")
    # the steady step's parts, alone (the MLP on the CPU, where the goal is set)
    timed_alone = name == "mlp" and isinstance(steady, SGFD_SAC) and not gpu
    parts = steady_parts(steady, args.batch_size) if timed_alone else {}  # type: ignore[arg-type]
    times, part_times = timed_rounds(models, parts, args.rounds, steps, args.batch_size, device)
    for key, model in sgfd_models.items():
        check_phase(key, model, *start[key])

    shape = models["SAC"].observation_space.shape
    print(f"\n## {name}: obs {shape}, batch {args.batch_size}, {args.rounds} rounds of {steps} steps\n")
    width = max(len(key) for key in times)
    header = f"| {'update':<{width}} | {'ms per step':>11} | {'vs SAC':>6} | {'dispatches':>10} | {'in graphs':>9} |"
    header += " vs SAC, quartiles over rounds |"
    print(header)
    print(f"|{'-' * (width + 2)}|{'-' * 13}|{'-' * 8}|{'-' * 12}|{'-' * 11}|{'-' * 31}|")
    medians = {key: 1e3 * statistics.median(values) for key, values in times.items()}
    for key in times:
        host, inside = dispatches[key]
        ratio = round_ratio(times, key, "SAC")
        low, high = round_quartiles(times, key, "SAC")
        row = f"| {key:<{width}} | {medians[key]:>11.2f} | {ratio:>5.2f}x | {host:>10.0f} | {inside:>9.0f} |"
        print(f"{row} {f'{low:.2f}-{high:.2f}x':>29} |")
    if parts:
        print_steady_parts(part_times, times)
    sac_dispatches = dispatches["SAC"][0]
    compiled = [key for key in times if key.endswith("compiled")]
    if gpu and compiled:  # what a captured update saves: the host's dispatches (on the CPU nothing is captured)
        worst = max(dispatches[key][0] for key in compiled)
        print(f"compiled host dispatches / SB3 SAC's: at most {worst / sac_dispatches:.3f} (goal <= 0.1)")
    for key in compiled:
        eager = key.removesuffix("compiled") + "eager"
        if eager in times:
            print(f"{key.removesuffix(' compiled')}: compiled / eager {round_ratio(times, key, eager):.2f}x")
            print_compile_time(key, eager, warmup_seconds, times, args.warmup or (20 if gpu else 3))
        if "SAC fused Adam" in times:
            ratio = round_ratio(times, key, "SAC fused Adam")
            print(f"  compiled / SAC with fused Adam {ratio:.2f}x (the additions' cost, both stepping fused)")
    if SOLVER_COMPILED in times:
        ratio = round_ratio(times, SOLVER_COMPILED, "SGFD steady compiled")
        print(f"SGFD steady: the solver compiled / left eager, both stepping fused {ratio:.2f}x")
        print_compile_time(SOLVER_COMPILED, "SGFD steady compiled", warmup_seconds, times, args.warmup or 3)
    if name == "agents":
        for way in ("eager", "compiled"):
            if f"AMBS {way}" in times:
                ratio = round_ratio(times, f"SGFD on AMBS {way}", f"AMBS {way}")
                print(f"SGFD on AMBS / AMBS, {way}: {ratio:.2f}x (what the reweighting adds to the paper's agent)")
    return medians


def print_compile_time(
    compiled: str, eager: str, warmup_seconds: dict[str, float], times: dict[str, list[float]], steps: int
) -> None:
    """The compiled update's one-off cost (its warm-up over the eager one's: compilation, captures) and the updates
    after which its saving per update (from the ratio within rounds) pays it back."""
    cost = warmup_seconds[compiled] - warmup_seconds[eager]
    saving_ms = 1e3 * statistics.median(times[eager]) * (1 - round_ratio(times, compiled, eager))
    if cost < 0.1:  # within the warm-ups' noise: nothing compiled or captured beyond what the eager one does
        print(f"  no one-off cost over {steps} warm-up steps")
        return
    payback = f"paid back after {1e3 * cost / saving_ms:,.0f} updates" if saving_ms > 0 else "never paid back"
    print(f"  compile and capture {cost:.1f} s over {steps} warm-up steps; {payback}")


def round_ratios(times: dict[str, list[float]], key: str, base: str) -> list[float]:
    """The time of ``key`` over that of ``base`` in each round: the machine's speed drifts between rounds, and a
    ratio within one round cancels most of it."""
    return [value / reference for value, reference in zip(times[key], times[base], strict=True)]


def round_ratio(times: dict[str, list[float]], key: str, base: str) -> float:
    """The median over rounds of :func:`round_ratios`."""
    return statistics.median(round_ratios(times, key, base))


def round_quartiles(times: dict[str, list[float]], key: str, base: str) -> tuple[float, float]:
    """The first and third quartiles over rounds of :func:`round_ratios`: how far the machine moved the ratio within
    one run."""
    ratios = round_ratios(times, key, base)
    if len(ratios) < 2:
        return ratios[0], ratios[0]
    low, _, high = statistics.quantiles(ratios, n=4, method="inclusive")
    return low, high


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", nargs="+", choices=list(POLICIES), default=["mlp", "cnn"])
    parser.add_argument("--rounds", type=int, default=15, help="timed rounds per model")
    parser.add_argument(
        "--round-steps", type=int, help="gradient steps per round (default: mlp 20, pixels 2; on a GPU 200 and 50)"
    )
    parser.add_argument("--warmup", type=int, help="untimed gradient steps per model first (default 3; GPU 20)")
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--fill", type=int, default=300, help="vec-env steps of data (x4 domains)")
    parser.add_argument("--compiled-only", action="store_true", help="SAC and the compiled models only")
    parser.add_argument(
        "--solver-row",
        action="store_true",
        help="on the CPU, also the steady phase with its solver compiled as on CUDA (seconds of compiling per policy)",
    )
    parser.add_argument("--device", default="auto", help="cpu, cuda, or auto (cuda when available)")
    parser.add_argument("--image-size", type=int, default=84, help="pixel side of the cnn and agents rows")
    args = parser.parse_args()
    IMAGE_SIZE[0] = args.image_size
    device = th.device(
        "cuda" if args.device == "auto" and th.cuda.is_available() else args.device.replace("auto", "cpu")
    )
    name = th.cuda.get_device_name(device) if device.type == "cuda" else f"CPU, {th.get_num_threads()} torch threads"
    print(f"device: {device} ({name})")
    for policy in args.policies:
        bench_policy(policy, args, device)


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
