"""
Cost of one gradient step of SGFD_SAC next to SB3's SAC, with the same policy, batch and replay data.

Two policies:

- ``mlp``: MlpPolicy [256, 256] on SGFD/MT-walker-walk-v0 states with ``observe_parameter=True`` (25-d: the
  domain is visible in the observation, as the quick configuration and the CPU study train it);
- ``cnn``: CnnPolicy (the paper's encoder, 1024-wide heads) on 9x84x84 observations (3 stacked 84x84 frames
  of SGFD/walker-walk-v0).

With ``agents``, the paper's other agents on the same pixels and CnnPolicy encoder (AMBS with its
ratio-scaled one): DBC, AMBS, SGFD on AMBS (the paper's agent, steady phase), TED and SGQN, each with its
objective and augmentation as in sgfd_zoo/hyperparams, next to SAC; each twice: as it trains (the actor's Q on
the critic's features of the step) and "before", with ``actor_reuses_features=False`` (the batch encoded
again for the actor's Q, as SB3 does and as this package did before).

SGFD is timed in three phases: ``steady`` (weights on, the classifier above its threshold, so not training),
``classifier`` (the classifier training every step, weights off: the start of a run) and ``mixed`` (weights
on and the classifier training: whenever a batch's accuracy dips below the threshold, which in the quick job
was most of a run). Both algorithms update the actor every step, so the ratio is SGFD's own cost. Each
timed round is ``--round-steps`` gradient steps of every model in turn (SAC, SGFD steady, ...), so all see
the same machine load; the script prints the median over rounds of the time per step, and the median and
quartiles over rounds of the ratio to SAC within each round.

Runs on CUDA when it is available (``--device``), and prints the device.

    python bench/update_overhead.py                       # mlp and cnn (CNN: about 3 min on 2 CPU cores)
    python bench/update_overhead.py --policies mlp --rounds 30
    python bench/update_overhead.py --policies agents --rounds 5   # DBC, AMBS, SGFD on AMBS, TED, SGQN
    python bench/update_overhead.py --policies mlp --rounds 30 --classifier-interval 20   # the official schedule
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

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, AMBSPolicy, CnnPolicy, DomainReplayBuffer, MlpPolicy
from sb3_sgfd.sgfd.saliency import classifier_accuracy, feature_probabilities
from sgfd_envs.backgrounds import overlay_bank

PHASES = ("steady", "classifier", "mixed")


def state_env() -> VecEnv:
    return sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter=True)


IMAGE_SIZE = [84]  # --image-size (the paper's 84; smaller only for a smoke run)


def pixel_env() -> VecEnv:
    # The fast render: this bench times gradient steps on the batches it collects, not the render.
    env = sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", image_size=IMAGE_SIZE[0], render="fast")
    return VecTransposeImage(VecFrameStack(env, 3))


POLICIES: dict[str, tuple[type, Callable[[], VecEnv], dict]] = {
    "mlp": (MlpPolicy, state_env, {"net_arch": [256, 256]}),
    "cnn": (CnnPolicy, pixel_env, {}),
    "agents": (CnnPolicy, pixel_env, {}),
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


AGENT_NAMES = ("DBC", "AMBS", "SGFD on AMBS", "TED", "SGQN")


def agents(env_factory: Callable[[], VecEnv], **common) -> dict[str, BaseAlgorithm]:
    """The paper's other agents, with their objectives and augmentation (sgfd_zoo/hyperparams), actor every step, each
    as it trains and "before" (the actor's Q on the batch encoded again, ``actor_reuses_features=False``)."""
    ambs = dict(augmentation_views=2, encoder_tau=0.05, max_grad_norm=40.0, representation="ambs")
    sgqn = dict(quantile=0.98, overlay_images=overlay_bank(IMAGE_SIZE[0], IMAGE_SIZE[0]))
    models: dict[str, BaseAlgorithm] = {}
    for suffix, reuse in (("", True), (" (before)", False)):
        each = dict(common, actor_reuses_features=reuse)
        models[f"DBC{suffix}"] = DBC(CnnPolicy, env_factory(), actor_update_interval=1, **each)
        models[f"AMBS{suffix}"] = AMBS(AMBSPolicy, env_factory(), actor_update_interval=1, **each)
        models[f"SGFD on AMBS{suffix}"] = sgfd_in_phase("steady", AMBSPolicy, env_factory(), **ambs, **each)
        models[f"TED{suffix}"] = TED(CnnPolicy, env_factory(), actor_update_interval=1, **each)
        models[f"SGQN{suffix}"] = SGQN(
            CnnPolicy, env_factory(), actor_update_interval=1, representation_kwargs=sgqn, **each
        )
    return models


#: Each phase held through SGFD's own settings (and the weighting's state ``ready``: whether the weights have
#: started). Steady: every accuracy above 0 reaches the least threshold, so the classifier scores each batch and
#: does not train. Classifier and mixed: a classifier whose learning rate leaves its parameters as they are never
#: reaches an accuracy of 1, so it trains on every round at its full cost (forward, backward, Adam step).
PHASE_SETTINGS: dict[str, dict[str, Any]] = {
    "steady": {"accuracy_threshold": 1e-6},
    "classifier": {"accuracy_threshold": 1.0, "classifier_lr": 1e-12},
    "mixed": {"accuracy_threshold": 1.0, "classifier_lr": 1e-12},
}


def sgfd_in_phase(phase: str, policy: type, env: VecEnv, classifier_interval: int = 1, **common) -> SGFD_SAC:
    """SGFD_SAC held in one phase (:data:`PHASE_SETTINGS`): whether the classifier trains (on the steps
    ``classifier_interval`` allows) and whether the weights are on."""
    model = SGFD_SAC(
        policy,
        env,
        actor_update_interval=1,
        classifier_start=0,
        classifier_interval=classifier_interval,
        **PHASE_SETTINGS[phase],
        **common,
    )
    model.weighting.ready = phase in ("steady", "mixed")
    return model


def classifier_steps(model: SGFD_SAC) -> int:
    """The optimiser steps the paper reading's classifier has taken (Adam counts them)."""
    state = model.weighting.classifier_optimizer.state.get(next(model.classifier.parameters()), {})
    return int(state.get("step", 0))


def check_phase(phase: str, model: SGFD_SAC, first_update: int, steps_before: int) -> None:
    """That the classifier trained on every round its interval allows since ``first_update`` (steady: never)."""
    interval = model.sgfd.classifier_interval
    rounds = sum(1 for index in range(first_update, model._n_updates) if index % interval == 0)
    taken, wanted = classifier_steps(model) - steps_before, 0 if phase == "steady" else rounds
    assert taken == wanted, f"SGFD {phase}: the classifier took {taken} steps where the phase holds {wanted}"


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


def bench_policy(name: str, args: argparse.Namespace, device: th.device) -> None:
    policy, make_env, policy_kwargs = POLICIES[name]
    common = dict(
        buffer_size=10_000,
        batch_size=args.batch_size,
        learning_rate=1e-3,
        tau=0.01,
        seed=0,
        device=device,
        policy_kwargs=policy_kwargs,
    )
    if policy is CnnPolicy:  # the paper's frame-deduplicating buffer keeps several pixel models in memory
        common["replay_buffer_kwargs"] = dict(frame_stack=3)
    models: dict[str, BaseAlgorithm] = {
        "SAC": SAC(policy, make_env(), replay_buffer_class=DomainReplayBuffer, **common)
    }
    if name == "agents":
        models.update(agents(make_env, **common))
    else:
        for phase in PHASES:
            models[f"SGFD {phase}"] = sgfd_in_phase(phase, policy, make_env(), args.classifier_interval, **common)
    gpu = device.type == "cuda"
    for model in models.values():
        model._setup_learn(10**6)
        fill(model, args.fill, seed=0)
        # warm-up: the allocator, the first classifier steps (and on a GPU, cuDNN's choice of kernels)
        time_round(model, args.warmup or (20 if gpu else 2), args.batch_size, device)
    steps = args.round_steps or ((200 if gpu else 20) if name == "mlp" else (50 if gpu else 2))
    times: dict[str, list[float]] = {key: [] for key in models}
    # each SGFD model's phase (the agents' SGFD on AMBS: steady), checked after the timed rounds
    sgfd_models = {key: model for key, model in models.items() if isinstance(model, SGFD_SAC)}
    start = {key: (model._n_updates, classifier_steps(model)) for key, model in sgfd_models.items()}
    for _ in range(args.rounds):
        for key, model in models.items():
            times[key].append(time_round(model, steps, args.batch_size, device))
    for key, model in sgfd_models.items():
        phase = key.removeprefix("SGFD ")
        check_phase(phase if phase in PHASES else "steady", model, *start[key])
    steady = models["SGFD on AMBS" if name == "agents" else "SGFD steady"]
    assert isinstance(steady, SGFD_SAC) and "sgfd/weight_ess" in steady._stats, "SGFD did not reweight"
    if name != "agents":
        assert "sgfd/weight_ess" not in models["SGFD classifier"]._stats, "the classifier phase reweighted"

    shape = models["SAC"].observation_space.shape
    schedule = "" if name == "agents" else f", SGFD's classifier_interval {args.classifier_interval}"
    print(f"\n## {name}: obs {shape}, batch {args.batch_size}, {args.rounds} rounds of {steps} steps{schedule}\n")
    width = max(len(key) for key in times)
    print(f"| {'update':<{width}} | {'ms per step':>11} | {'vs SAC':>6} | {'per-round quartiles':>19} |")
    print(f"|{'-' * (width + 2)}|{'-' * 13}|{'-' * 8}|{'-' * 21}|")
    for key, values in times.items():
        low, mid, high = round_ratio_quartiles(times, key, "SAC")
        row = (
            f"| {key:<{width}} | {1e3 * statistics.median(values):>11.2f} | {mid:>5.2f}x | {low:>8.2f} - {high:.2f}x |"
        )
        print(row)
    if name == "agents":
        ratio = round_ratio_quartiles(times, "SGFD on AMBS", "AMBS")[1]
        print(f"SGFD on AMBS / AMBS: {ratio:.2f}x (what the reweighting adds to the paper's agent)")
        for agent in AGENT_NAMES:
            low, mid, high = round_ratio_quartiles(times, agent, f"{agent} (before)")
            print(f"{agent} / before: {mid:.2f}x ({low:.2f} - {high:.2f}) (the actor's Q on the step's features)")
    else:
        medians = {phase: round_ratio_quartiles(times, f"SGFD {phase}", "SAC")[1] for phase in PHASES}
        ratios = ", ".join(f"{phase} {ratio:.2f}x" for phase, ratio in medians.items())
        print(f"SGFD / SAC ({name}): {ratios} (goal <= 1.2x)")
        print_components(steady, args.batch_size, device)


def round_ratio_quartiles(times: dict[str, list[float]], key: str, base: str) -> tuple[float, float, float]:
    """Quartiles over rounds of the time of ``key`` over that of ``base`` in the same round: the machine's
    speed drifts between rounds (other tenants, clocks), and a ratio within one round cancels most of it."""
    ratios = [value / reference for value, reference in zip(times[key], times[base], strict=True)]
    low, mid, high = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else (ratios[0],) * 3
    return low, mid, high


def print_components(model: SGFD_SAC, batch_size: int, device: th.device, repeats: int = 50) -> None:
    """Where SGFD's steady-state time goes: its parts on one replay batch, each timed alone (median)."""
    batch = model.replay_buffer.sample(batch_size)
    z = model.encode(batch.observations)
    generator = th.Generator(device=device).manual_seed(0)
    parts = {
        "classifier accuracy": lambda: classifier_accuracy(model.classifier, z, batch.domains),
        "saliency p(Z_i)": lambda: feature_probabilities(model.classifier, z),
        f"weights: saliency + solver ({model.sgfd.reweight_iters} iterations, d = {z.shape[1]})": lambda: (
            model.sample_weights(z, generator)
        ),
    }
    print("| SGFD part, alone | ms |\n|---|---|")
    for label, part in parts.items():
        for _ in range(5):
            part()
        times = []
        for _ in range(repeats):
            synchronize(device)
            start = time.perf_counter()
            part()
            synchronize(device)
            times.append(time.perf_counter() - start)
        print(f"| {label} | {1e3 * statistics.median(times):.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", nargs="+", choices=list(POLICIES), default=["mlp", "cnn"])
    parser.add_argument("--rounds", type=int, default=15, help="timed rounds per model")
    parser.add_argument(
        "--round-steps", type=int, help="gradient steps per round (default: mlp 20, pixels 2; on a GPU 200 and 50)"
    )
    parser.add_argument("--warmup", type=int, help="untimed gradient steps per model first (default 2; GPU 20)")
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--fill", type=int, default=300, help="vec-env steps of data (x4 domains)")
    parser.add_argument(
        "--classifier-interval",
        type=int,
        default=1,
        help="SGFD's classifier_interval in the mlp and cnn rows (default 1, SGFD_SAC's; the official code: 20)",
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
