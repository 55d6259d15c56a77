"""
The paper's interpretability figures from trained agents and their logs.

- ``sgfd-zoo saliency-maps``: |d action / d pixel| of a trained pixel agent next to its observation, on
  training and unseen domains (appendix C.4).
- ``sgfd-zoo weighted-samples``: a batch from two training domains, frames sorted by the weight SGFD
  gives them (Fig. 5).
- ``sgfd-zoo classifier-accuracy``: the domain classifier's accuracy over training, mean and band over
  seeds, with the threshold (appendix C.3).
"""

from __future__ import annotations

import argparse
import json
import math
import textwrap
from collections import defaultdict
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global figure state
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.preprocessing import is_image_space, preprocess_obs
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv
from stable_baselines3.sac import SAC

import sgfd_envs
from sb3_sgfd.sgfd.functional import classifier_accuracy, effective_sample_size
from sgfd_zoo.algos import column_name
from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_env_id
from sgfd_zoo.report.plot import mean_and_band
from sgfd_zoo.runs.folders import RunFolder, env_name, find_runs, select_run
from sgfd_zoo.runs.safe import make_folder, save_figure, write_text
from sgfd_zoo.vec_wrappers import wrap_like_training

# Inches per image panel; the figures are grids of these.
PANEL = 1.3
DPI = 100
ACCURACY_KEY = "sgfd/classifier_accuracy"


# --- runs and models -------------------------------------------------------------------------------------


def require_pixels(model: BaseAlgorithm, run: RunFolder, command: str) -> None:
    """Refuse agents that do not see images: the figures show frames."""
    if not is_image_space(model.observation_space):
        raise ZooError(
            f"{command} needs a pixel agent (CnnPolicy, obs_type 'pixels'); {run.path} observes "
            f"{model.observation_space}"
        )


def domain_env(run: RunFolder, split: str, domains: list[int], seed: int) -> VecEnv:
    """One sub-env per listed domain of a split, with the run's env kwargs, wrapped as in training.

    :param run: the run whose env kwargs and frame stack are used
    :param split: a split of the run's env
    :param domains: domain indices within the split
    :param seed: sub-env i is reset with ``seed + i``
    """

    def factory(domain: int) -> gym.Env:
        return gym.make(run.env_id, split=split, domain=domain, **run.env_kwargs)

    env = DummyVecEnv([partial(factory, domain) for domain in domains])
    env.seed(seed)
    return wrap_like_training(env, run.frame_stack)


def rollout(model: BaseAlgorithm, env: VecEnv, steps: list[int], deterministic: bool = True) -> np.ndarray:
    """Observations of every sub-env at the given step numbers of the agent's own rollout.

    :param model: the agent that acts
    :param env: the wrapped VecEnv
    :param steps: step numbers to keep (0 = the reset observation), increasing
    :param deterministic: act with the mean action
    :return: array (len(steps), n_envs, *observation shape)
    """
    kept = []
    obs = env.reset()
    for step in range(max(steps) + 1):
        if step in steps:
            kept.append(np.array(obs))
        if step < max(steps):
            action, _ = model.predict(obs, deterministic=deterministic)  # type: ignore[arg-type]  # as SB3's evaluate_policy
            obs, _, _, _ = env.step(action)
    return np.stack(kept)


def newest_frame(observation: np.ndarray) -> np.ndarray:
    """The latest RGB frame (H, W, 3) of a channel-first stacked observation (C, H, W); newest channels last."""
    return np.transpose(observation[-3:], (1, 2, 0))


# --- saliency maps ---------------------------------------------------------------------------------------


def action_saliency(model: SAC, observations: np.ndarray) -> np.ndarray:
    """|d action / d pixel|: per pixel, the sum over action dimensions and channels of the absolute gradient
    of the deterministic action tanh(mu(s)) with respect to the raw pixel values.

    The SGFD actor reads its encoder's features under ``no_grad`` (the critic trains the encoder), so the
    path is rebuilt here with gradients: preprocessing, the shared encoder, the actor's MLP and mean.

    :param model: a SAC-family agent with a pixel policy
    :param observations: (n, C, H, W) observations as the policy sees them (uint8, channel first)
    :return: (n, H, W) non-negative saliency, in action units per pixel-value unit
    """
    actor = model.actor
    pixels = torch.as_tensor(observations, dtype=torch.float32, device=model.device).requires_grad_(True)
    with torch.enable_grad():
        preprocessed = preprocess_obs(pixels, actor.observation_space, normalize_images=actor.normalize_images)
        actions = torch.tanh(actor.mu(actor.latent_pi(actor.features_extractor(preprocessed))))
        saliency = torch.zeros(pixels.shape[0], *pixels.shape[2:], device=pixels.device)
        for k in range(actions.shape[1]):
            # Samples do not interact, so the gradient of the batch sum is each sample's own gradient.
            (grad,) = torch.autograd.grad(actions[:, k].sum(), pixels, retain_graph=k + 1 < actions.shape[1])
            saliency += grad.abs().sum(dim=1)
    return saliency.cpu().numpy()


def saliency_rows(run: RunFolder, max_domains: int) -> list[tuple[str, int]]:
    """(split, domain) of each figure row: up to ``max_domains`` domains of every split, training first."""
    return [
        (split, domain)
        for split in sgfd_envs.splits(run.env_id)
        for domain in range(min(max_domains, sgfd_envs.n_domains(run.env_id, split, **run.env_kwargs)))
    ]


def saliency_figure(
    frames: np.ndarray, maps: np.ndarray, row_labels: list[str], steps: list[int], title: str
) -> Figure:
    """Rows of (observation, saliency) pairs, one pair per step; one brightness scale for the whole figure.

    :param frames: (rows, steps, H, W, 3) uint8 frames
    :param maps: (rows, steps, H, W) saliency
    :param row_labels: one label per row
    :param steps: step number of each column pair
    :param title: figure title
    """
    n_rows, n_steps = maps.shape[:2]
    # A shared scale, so that a dimmer map means less influence on the action, across domains too.
    scale = float(np.quantile(maps, 0.995)) or 1.0
    fig = Figure(figsize=(2 * n_steps * PANEL, n_rows * PANEL + 0.6), layout="constrained")
    axes = fig.subplots(n_rows, 2 * n_steps, squeeze=False)
    for row in range(n_rows):
        for column in range(n_steps):
            ax_obs, ax_map = axes[row, 2 * column], axes[row, 2 * column + 1]
            ax_obs.imshow(frames[row, column], interpolation="nearest")
            ax_map.imshow(
                np.clip(maps[row, column] / scale, 0, 1), cmap="gray", vmin=0, vmax=1, interpolation="nearest"
            )
            if row == 0:
                ax_obs.set_title(f"step {steps[column]}", fontsize=8)
                ax_map.set_title("|d a / d pixel|", fontsize=8)
        axes[row, 0].set_ylabel(row_labels[row], fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    return _titled(fig, title)


def saliency_maps_main(argv: list[str]) -> int:
    parser = _run_parser("sgfd-zoo saliency-maps", "gradient of the action w.r.t. the input pixels, train and test")
    parser.add_argument("--steps", default="10,30", help="comma-separated rollout steps to show (0 = reset)")
    parser.add_argument("--max-domains", type=int, default=4, help="most domains shown per split")
    args = parser.parse_args(argv)
    steps = _steps(args.steps)
    if args.max_domains < 1:
        raise ZooError(f"--max-domains must be >= 1, got {args.max_domains}")
    run, model = _pixel_agent(args, "saliency-maps")
    if not isinstance(model, SAC):
        raise ZooError(f"saliency-maps needs a SAC-family agent (the actor's mean action); {run.path} holds {run.algo}")
    rows = saliency_rows(run, args.max_domains)
    frames, maps, observations = [], [], []
    for split in dict.fromkeys(split for split, _ in rows):
        domains = [domain for s, domain in rows if s == split]
        env = domain_env(run, split, domains, args.seed)
        try:
            obs = rollout(model, env, steps)  # (steps, domains, C, H, W)
        finally:
            env.close()
        obs = obs.transpose(1, 0, 2, 3, 4)  # (domains, steps, ...)
        flat = obs.reshape(-1, *obs.shape[2:])
        maps.append(action_saliency(model, flat).reshape(*obs.shape[:2], *obs.shape[3:]))
        frames.append(np.stack([[newest_frame(o) for o in per_domain] for per_domain in obs]))
        observations.append(obs)
    frames_all, maps_all = np.concatenate(frames), np.concatenate(maps)
    row_labels = [f"{split} {domain}" for split, domain in rows]
    title = (
        f"{run.env_id}, {column_name(run.algo)} (seed {run.seed}): brightness = sum over action dims and "
        "channels of |d action / d pixel|, one scale for all maps"
    )
    out = _out_dir(args)
    stem = f"saliency_maps_{env_name(run.env_id)}"
    png = out / f"{stem}.png"
    save_figure(saliency_figure(frames_all, maps_all, row_labels, steps, title), out, png, dpi=DPI)
    npz = out / f"{stem}.npz"
    np.savez_compressed(
        npz,
        observations=np.concatenate(observations),
        saliency=maps_all,
        rows=np.array(row_labels),
        steps=np.array(steps),
    )
    for label, per_row in zip(row_labels, maps_all, strict=True):
        print(f"{label:<16} mean saliency {per_row.mean():.3g}")
    print(f"Wrote {png} and {npz}")
    return 0


# --- weighted samples ------------------------------------------------------------------------------------


def sgfd_weights(model: Any, observations: np.ndarray, domains: np.ndarray, seed: int) -> dict[str, Any]:
    """SGFD's weights for one batch, as ``SGFD_SAC`` computes them in training: the model's encoder features,
    its classifier's feature probabilities (unless it is the no-saliency ablation), its solver settings.

    :param model: a trained ``SGFD_SAC``
    :param observations: (n, C, H, W) batch as the policy sees it
    :param domains: (n,) training-domain labels
    :param seed: seeds the random Fourier features
    :return: weights (n,), the classifier's accuracy on the batch, whether it ever reached its threshold, ESS
    """
    obs = torch.as_tensor(observations, device=model.device)
    z = model.encode(obs)
    labels = torch.as_tensor(domains, device=model.device)
    generator = torch.Generator(device=model.device).manual_seed(seed)
    weights, _, _ = model.sample_weights(z, generator)
    return {
        "weights": weights.cpu().numpy(),
        "classifier_accuracy": classifier_accuracy(model.classifier, z, labels),
        "classifier_ready": bool(model.weighting.ready),
        "accuracy_threshold": float(model.sgfd.accuracy_threshold),
        "ess": effective_sample_size(weights) / len(weights),
    }


def weighted_samples_figure(
    frames: np.ndarray, weights: np.ndarray, domains: np.ndarray, names: list[str], columns: int, title: str
) -> Figure:
    """Per domain, its frames sorted by weight (heaviest first), each captioned with its weight.

    :param frames: (n, H, W, 3) uint8
    :param weights: (n,) weights
    :param domains: (n,) domain of each frame
    :param names: label of each domain, in order of ``np.unique(domains)``
    :param columns: frames per row
    :param title: figure title
    """
    groups = [np.flatnonzero(domains == domain) for domain in np.unique(domains)]
    rows_per_group = [math.ceil(len(group) / columns) for group in groups]
    n_rows = sum(rows_per_group)
    fig = Figure(figsize=(columns * PANEL * 0.8, n_rows * PANEL * 0.9 + 0.4 * len(groups) + 0.6), layout="constrained")
    subfigs = fig.subfigures(len(groups), 1, height_ratios=rows_per_group, squeeze=False)[:, 0]
    for subfig, group, name, n_group_rows in zip(subfigs, groups, names, rows_per_group, strict=True):
        order = group[np.argsort(-weights[group], kind="stable")]
        axes = subfig.subplots(n_group_rows, columns, squeeze=False)
        for ax in axes.flat:
            ax.axis("off")
        for ax, index in zip(axes.flat, order, strict=False):
            ax.imshow(frames[index], interpolation="nearest")
            ax.set_title(f"w={weights[index]:.2f}", fontsize=7)
        subfig.suptitle(f"{name}: {len(group)} frames, mean weight {weights[group].mean():.3f}", fontsize=9)
    return _titled(fig, title)


def weighted_samples_main(argv: list[str]) -> int:
    parser = _run_parser("sgfd-zoo weighted-samples", "a batch from two domains, frames sorted by SGFD's weight")
    parser.add_argument("--domains", default="0,1", help="two training domains, comma-separated")
    parser.add_argument("--batch-size", type=int, default=128, help="batch size, split evenly between the domains")
    parser.add_argument("--rollout-steps", type=int, default=200, help="agent steps per domain to sample from")
    parser.add_argument("--columns", type=int, default=16, help="frames per row of the figure")
    args = parser.parse_args(argv)
    run, model = _pixel_agent(args, "weighted-samples")
    if not hasattr(model, "classifier"):
        raise ZooError(f"weighted-samples needs an SGFD_SAC agent; {run.path} is {type(model).__name__}")
    domains = _domains(args.domains, sgfd_envs.n_domains(run.env_id, "train", **run.env_kwargs))
    if args.batch_size < 4 or args.batch_size % 2:
        raise ZooError(f"--batch-size must be an even number >= 4, got {args.batch_size}")
    if args.rollout_steps < args.batch_size // 2:
        raise ZooError(f"--rollout-steps must be >= batch size / 2 = {args.batch_size // 2}, got {args.rollout_steps}")
    if args.columns < 1:
        raise ZooError(f"--columns must be >= 1, got {args.columns}")

    env = domain_env(run, "train", domains, args.seed)
    try:
        # Stochastic actions, as in training: the batch looks like what the replay buffer holds.
        obs = rollout(model, env, list(range(args.rollout_steps)), deterministic=False)  # (steps, 2, C, H, W)
    finally:
        env.close()
    rng = np.random.default_rng(args.seed)
    per_domain = args.batch_size // 2
    picks = [np.sort(rng.choice(args.rollout_steps, per_domain, replace=False)) for _ in domains]
    batch = np.concatenate([obs[pick, column] for column, pick in enumerate(picks)])
    labels = np.repeat(np.array(domains), per_domain)
    result = sgfd_weights(model, batch, labels, args.seed)
    weights = result["weights"]

    status = (
        f"classifier reached its {result['accuracy_threshold']} threshold in training"
        if result["classifier_ready"]
        else f"classifier NEVER reached its {result['accuracy_threshold']} threshold in training: weights from "
        "its current saliency"
    )
    title = (
        f"{run.env_id}, {column_name(run.algo)} (seed {run.seed}): SGFD weights of a batch of "
        f"{len(weights)}, ESS {result['ess']:.2f} n; {status}; accuracy on this batch "
        f"{result['classifier_accuracy']:.2f}"
    )
    names = [f"train domain {domain}" for domain in domains]
    out = _out_dir(args)
    stem = f"weighted_samples_{env_name(run.env_id)}"
    png = out / f"{stem}.png"
    frames = np.stack([newest_frame(o) for o in batch])
    save_figure(weighted_samples_figure(frames, weights, labels, names, args.columns, title), out, png, dpi=DPI)
    document = {
        "env_id": run.env_id,
        "run": str(run.path),
        "domains": labels.tolist(),
        "weights": weights.tolist(),
        "rollout_steps": [int(step) for pick in picks for step in pick],
        "mean_weight_per_domain": {str(d): float(weights[labels == d].mean()) for d in domains},
        **{key: value for key, value in result.items() if key != "weights"},
    }
    write_text(out, out / f"{stem}.json", json.dumps(document, indent=2))
    print(status)
    for domain in domains:
        chosen = weights[labels == domain]
        print(
            f"train domain {domain}: mean weight {chosen.mean():.3f} (min {chosen.min():.3f}, max {chosen.max():.3f})"
        )
    print(f"ESS {result['ess']:.3f} n; classifier accuracy on the batch {result['classifier_accuracy']:.3f}")
    print(f"Wrote {png} and {out / f'{stem}.json'}")
    return 0


# --- classifier accuracy ---------------------------------------------------------------------------------


def load_accuracy_curves(folder: Path, env_ids: list[str] | None = None) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """env id -> algo -> one curve per run that logged the classifier's accuracy (resumed runs merged).

    Each curve is a dict with ``steps``, ``accuracy``, ``threshold`` and ``start`` (from the run's config).

    :param folder: log folder of ``sgfd-zoo train``
    :param env_ids: only these env ids
    """
    curves: dict[str, dict[str, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for run in find_runs(folder, env_ids=env_ids, finished=False):
        steps, accuracy = run.log(ACCURACY_KEY)
        if len(steps) == 0:
            continue
        curves[run.env_id][run.algo].append(
            {
                "steps": steps,
                "accuracy": accuracy,
                "threshold": run.accuracy_threshold,
                "start": run.config.get("classifier_start"),
                "run": run.path,
            }
        )
    return curves


def mean_band(curves: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and one standard deviation of the accuracy over runs (:func:`sgfd_zoo.report.plot.mean_and_band`)."""
    return mean_and_band([(curve["steps"], curve["accuracy"]) for curve in curves])


def accuracy_figure(env_id: str, by_algo: dict[str, list[dict[str, Any]]]) -> Figure:
    """Classifier accuracy vs environment steps: per algorithm the mean and band over seeds, the threshold.

    :param env_id: the env the runs trained on
    :param by_algo: algo -> curves
    """
    fig = Figure(figsize=(6, 3.8), layout="constrained")
    ax = fig.add_subplot()
    thresholds, starts = set(), set()
    for algo, curves in sorted(by_algo.items()):
        grid, mean, std = mean_band(curves)
        label = f"{column_name(algo)} ({len(curves)} seed{'s' if len(curves) > 1 else ''})"
        (line,) = ax.plot(grid, mean, label=label)
        ax.fill_between(grid, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        thresholds |= {curve["threshold"] for curve in curves}
        starts |= {curve["start"] for curve in curves if curve["start"] is not None}
    for threshold in sorted(thresholds):
        ax.axhline(threshold, color="red", linestyle="--", linewidth=1, label=f"threshold {threshold:g}")
    for start in sorted(starts):
        ax.axvline(float(start), color="gray", linestyle=":", linewidth=1)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("domain classifier accuracy")
    ax.set_ylim(0.0, 1.02)
    ax.set_title(f"{env_id}: classifier accuracy during training", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    return fig


def classifier_accuracy_main(argv: list[str]) -> int:
    parser = ZooArgumentParser(
        prog="sgfd-zoo classifier-accuracy", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("-f", "--folder", required=True, type=Path, help="log folder of sgfd-zoo train")
    parser.add_argument("--env", nargs="+", help="only these env ids")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: <folder>/figures)")
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        raise ZooError(f"--folder {args.folder} does not exist (train first: sgfd-zoo train -f {args.folder} ...)")
    for env_id in args.env or []:
        check_env_id(env_id)
    curves = load_accuracy_curves(args.folder, args.env)
    if not curves:
        raise ZooError(
            f"no run under {args.folder}/<algo>/<EnvName>_<id>/ logged {ACCURACY_KEY} in progress*.csv (the classifier "
            "trains from classifier_start on; train an SGFD algorithm past it)"
        )
    out = _out_dir(args)
    for env_id, by_algo in sorted(curves.items()):
        png = out / f"classifier_accuracy_{env_name(env_id)}.png"
        save_figure(accuracy_figure(env_id, by_algo), out, png, dpi=DPI)
        for algo, runs in sorted(by_algo.items()):
            grid, mean, _ = mean_band(runs)
            threshold = runs[0]["threshold"]
            reached = grid[np.argmax(mean >= threshold)] if (mean >= threshold).any() else None
            when = (
                f"mean first >= {threshold:g} at step {reached:.0f}"
                if reached is not None
                else (f"mean never reached {threshold:g}")
            )
            print(f"{env_id} {algo}: {len(runs)} run(s), final mean accuracy {mean[-1]:.3f}, {when}")
        print(f"Wrote {png}")
    return 0


# --- shared command-line pieces ---------------------------------------------------------------------------


def _run_parser(prog: str, description: str) -> argparse.ArgumentParser:
    parser = ZooArgumentParser(prog=prog, description=description)
    parser.add_argument("-f", "--folder", required=True, type=Path, help="log folder of sgfd-zoo train")
    parser.add_argument("--env", required=True, help="the SGFD id the agent trained on")
    parser.add_argument("--algo", default="sgfd_sac", help="algorithm key of the run (default sgfd_sac)")
    parser.add_argument("--exp-id", type=int, help="run number (the _<id> of its folder); default: the newest")
    parser.add_argument("--seed", type=int, default=0, help="seeds the envs and the weights' random features")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: <folder>/figures)")
    return parser


def _pixel_agent(args: argparse.Namespace, command: str) -> tuple[RunFolder, BaseAlgorithm]:
    """The run and model :func:`_run_parser`'s options choose; a model without pixels is refused for ``command``."""
    run = select_run(args.folder, args.env, args.algo, args.exp_id)
    model = run.load_model()
    require_pixels(model, run, command)
    return run, model


def _titled(fig: Figure, title: str) -> Figure:
    """``fig`` with ``title`` above it, in lines that fit its width (about 0.07 inch per character at 9 pt)."""
    fig.suptitle(textwrap.fill(title, width=max(20, int(fig.get_figwidth() / 0.07))), fontsize=9)
    return fig


def _out_dir(args: argparse.Namespace) -> Path:
    """``-o``, else ``<folder>/figures``: made there, never through a link inside the log folder."""
    if args.out is not None:
        return make_folder(args.out, args.out)
    return make_folder(args.folder, args.folder / "figures")


def _steps(text: str) -> list[int]:
    try:
        steps = sorted({int(step) for step in text.split(",")})
    except ValueError:
        raise ZooError(f"--steps must be comma-separated integers >= 0, got {text!r}") from None
    if not steps or steps[0] < 0:
        raise ZooError(f"--steps must be comma-separated integers >= 0, got {text!r}")
    return steps


def _domains(text: str, n_domains: int) -> list[int]:
    try:
        domains = [int(domain) for domain in text.split(",")]
    except ValueError:
        domains = []
    if len(domains) != 2 or len(set(domains)) != 2 or not all(0 <= d < n_domains for d in domains):
        raise ZooError(f"--domains must be two different training domains in 0..{n_domains - 1}, got {text!r}")
    return domains
