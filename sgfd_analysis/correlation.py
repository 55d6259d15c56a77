"""
``sgfd-zoo correlation-study``: does SGFD decorrelate the feature that changes across domains from the others?

The paper's case study (section 5.3, Fig. 4; appendix C.1): states with physical meaning from the training
domains, plus the parameter that differs between them (Causal World's object mass, s10), compared under
three weightings of each batch of 128:

(a) raw: uniform weights;
(b) global: ``learn_sample_weights`` with uniform feature probabilities (decorrelate every pair);
(c) SGFD: ``learn_sample_weights`` with ``feature_probabilities`` of a ``DomainClassifier`` trained on
    (state features, domain label), as Algorithm 1 trains it.

Everything uses the package's own functions with their defaults. The weights of a batch are learned on
that batch and the correlation is measured on the same batch, as the paper's figure does: the question
is how much of the batch's correlation the weights remove, not whether they generalise to other batches.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch
from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global figure state
from matplotlib.patches import Rectangle

import sgfd_envs
from sb3_sgfd.sgfd.classifier import DomainClassifier
from sb3_sgfd.sgfd.functional import (
    classifier_accuracy,
    effective_sample_size,
    feature_probabilities,
    learn_sample_weights,
    train_classifier,
    weighted_pearson,
)
from sgfd_zoo.arguments import ZooArgumentParser, ZooError

WEIGHTINGS = ("raw", "global", "sgfd")
TITLES = {"raw": "(a) raw data", "global": "(b) global decorrelation", "sgfd": "(c) SGFD (saliency-guided)"}
# The paper's figure shows s1..s10: nine state features and the changed one.
DEFAULT_N_STATE_FEATURES = 9
# Causal World's state starts with the time left and 27 joint entries; the paper's s1..s9 are "the coordinates
# of the object or the angle of the manipulator". Nine such: the first fingertip's and the block's position and
# the block's velocity. Left out: constants and the block/goal sizes, which are copies of the pushing parameter.
CAUSAL_WORLD_FEATURES = [
    *(f"end_effector_positions[{i}]" for i in range(3)),
    *(f"tool_block_cartesian_position[{i}]" for i in range(3)),
    *(f"tool_block_linear_velocity[{i}]" for i in range(3)),
]
DEFAULT_STEPS_PER_DOMAIN = 1000
DEFAULT_BATCH_SIZE = 128
# SGFD_SAC's defaults for the classifier (Algorithm 1): Adam at 1e-3, trained until a batch is 90% right.
CLASSIFIER_LR = 1e-3
ACCURACY_THRESHOLD = 0.9
MAX_CLASSIFIER_STEPS = 5000
# The goals: SGFD below global below raw, SGFD at most 0.65 of raw, ESS at least half the batch.
GOAL_RATIO = 0.65
GOAL_ESS = 0.5


@dataclass
class StateSample:
    """States collected from the training domains, with the changed parameter appended as the last column.

    :param features: (N, d) states; column ``changed`` is the parameter that differs between domains
    :param domains: (N,) domain label of each state
    :param names: d feature names (dm_control observation names, then the parameter's name)
    :param changed: column of the changed feature
    """

    features: np.ndarray
    domains: np.ndarray
    names: list[str]
    changed: int


@dataclass
class StudyResult:
    """What :func:`correlation_study` measured.

    :param names: feature names, in matrix order
    :param changed: index of the changed feature
    :param matrices: weighting -> (d, d) mean over batches of |weighted Pearson correlation|
    :param mean_abs_corr: weighting -> mean over batches and over the other features of |r(changed, other)|
    :param ess: weighting -> mean over batches of the effective sample size as a fraction of the batch
    :param classifier_accuracy: accuracy of the domain classifier on all states
    :param n_batches: number of batches averaged
    :param batch_size: states per batch
    """

    names: list[str]
    changed: int
    matrices: dict[str, np.ndarray]
    mean_abs_corr: dict[str, float]
    ess: dict[str, float]
    classifier_accuracy: float
    n_batches: int
    batch_size: int
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def goals(self) -> dict[str, bool]:
        """The issue's goals, each met or not."""
        corr = self.mean_abs_corr
        return {
            "sgfd_below_global_below_raw": bool(corr["sgfd"] < corr["global"] < corr["raw"]),
            f"sgfd_at_most_{GOAL_RATIO}_of_raw": bool(corr["sgfd"] <= GOAL_RATIO * corr["raw"]),
            f"sgfd_ess_at_least_{GOAL_ESS}_n": bool(self.ess["sgfd"] >= GOAL_ESS),
        }


def state_names(env: gym.Env, env_id: str) -> list[str]:
    """Names of the entries of a state observation: ``key`` or ``key[i]`` of the task's observation dict.

    :param env: an env of ``env_id`` made with ``obs_type="state"``
    :param env_id: its id
    """
    names = getattr(env.unwrapped, "state_names", None)
    if names is not None:
        return list(names)
    from sgfd_envs import domains
    from sgfd_envs.registry import task_entry

    entry = task_entry(env_id)
    # The dm_control task of the env, unmodified: its observation spec names and sizes the entries.
    dm_env = domains.load(entry.robot, entry.task)
    try:
        spec = dm_env.observation_spec()
    finally:
        dm_env.physics.free()
    names = []
    for key, value in spec.items():
        size = int(np.prod(value.shape))
        names += [key] if size == 1 and value.shape == () else [f"{key}[{i}]" for i in range(size)]
    return names


def changed_parameter(env: gym.Env) -> tuple[str, float]:
    """Name and value of the parameter that changes across the domains of an env.

    :param env: an MT env (morphology) or a Causal World env (object property)
    """
    unwrapped = env.unwrapped
    for prefix in ("morphology", "varied"):
        name = getattr(unwrapped, f"{prefix}_parameter", None)
        value = getattr(unwrapped, f"{prefix}_value", None)
        if name is not None and value is not None:
            return str(name), float(value)
    raise ZooError(
        f"{env.spec.id if env.spec else env}: no changed parameter; use an MT id or a Causal World id, one of "
        f"{', '.join(study_env_ids())}"
    )


def study_env_ids() -> tuple[str, ...]:
    """The ids whose domains differ in a named parameter: the MT ids, and the Causal World ids."""
    mt_ids = tuple(env_id for env_id in sgfd_envs.SGFD_IDS if "/MT-" in env_id)
    return mt_ids + tuple(getattr(sgfd_envs, "CAUSAL_WORLD_IDS", ()))


def collect_states(
    env_id: str,
    steps_per_domain: int = DEFAULT_STEPS_PER_DOMAIN,
    seed: int = 0,
    features: list[str] | None = None,
    n_state_features: int | None = None,
    split: str = "train",
) -> StateSample:
    """Roll out uniformly random actions in every domain of a split and keep the chosen state features.

    Random actions: the study is about correlations the domains themselves induce, not about a policy.

    :param env_id: an id of :func:`study_env_ids`
    :param steps_per_domain: states recorded per domain (the reset state and the state after each step)
    :param seed: seeds the env of domain i (reset and action space) with ``seed + i``
    :param features: state features by name (see :func:`state_names`); None: the first ``n_state_features``
    :param n_state_features: how many leading state entries to keep when ``features`` is None; None: 9, or
        for Causal World ids :data:`CAUSAL_WORLD_FEATURES`
    :param split: the split whose domains are collected
    """
    if features is None and n_state_features is None:
        cw_ids = getattr(sgfd_envs, "CAUSAL_WORLD_IDS", ())
        features = CAUSAL_WORLD_FEATURES if env_id in cw_ids else None
        n_state_features = DEFAULT_N_STATE_FEATURES
    if env_id not in study_env_ids():
        raise ZooError(f"--env {env_id!r} has no per-domain parameter; choose from {', '.join(study_env_ids())}")
    if steps_per_domain < 2:
        raise ZooError(f"--steps-per-domain must be >= 2, got {steps_per_domain}")
    n_domains = sgfd_envs.n_domains(env_id, split)
    if n_domains < 2:
        raise ZooError(f"split {split!r} of {env_id} has {n_domains} domain; the study needs at least 2")
    rows, labels = [], []
    names: list[str] = []
    columns: list[int] = []
    parameter = ""
    for domain in range(n_domains):
        env = gym.make(env_id, split=split, domain=domain, obs_type="state")
        try:
            if domain == 0:
                names = state_names(env, env_id)
                columns = _select_columns(names, features, n_state_features)
            parameter, value = changed_parameter(env)
            env.action_space.seed(seed + domain)
            obs, _ = env.reset(seed=seed + domain)
            states = [obs]
            while len(states) < steps_per_domain:
                obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
                states.append(obs)
                if terminated or truncated:
                    obs, _ = env.reset()
                    states.append(obs)
        finally:
            env.close()
        block = np.asarray(states[:steps_per_domain], dtype=np.float64)[:, columns]
        rows.append(np.column_stack([block, np.full(len(block), value)]))
        labels.append(np.full(len(block), domain, dtype=np.int64))
    chosen = [names[column] for column in columns]
    return StateSample(np.concatenate(rows), np.concatenate(labels), [*chosen, parameter], len(chosen))


def _select_columns(names: list[str], features: list[str] | None, n_state_features: int | None) -> list[int]:
    if features is None:
        if n_state_features is None or not 1 <= n_state_features <= len(names):
            raise ZooError(f"--n-state-features must be in 1..{len(names)} for this env, got {n_state_features}")
        return list(range(n_state_features))
    unknown = [name for name in features if name not in names]
    if unknown or not features:
        raise ZooError(f"--features: unknown {unknown or 'empty list'}; choose from {', '.join(names)}")
    if len(set(features)) != len(features):
        raise ZooError(f"--features repeats a name: {features}")
    return [names.index(name) for name in features]


def train_domain_classifier(
    z: torch.Tensor, domains: torch.Tensor, n_domains: int, batch_size: int, generator: torch.Generator
) -> tuple[DomainClassifier, int]:
    """A ``DomainClassifier`` trained as Algorithm 1 does (``sb3_sgfd.sgfd.functional.train_classifier``):
    cross-entropy on random batches, until a batch is classified with accuracy >= 0.9 (``SGFD_SAC``'s threshold),
    at most ``MAX_CLASSIFIER_STEPS`` steps.

    :param z: (N, d) standardised features
    :param domains: (N,) labels
    :param n_domains: number of classes
    :param batch_size: states per update
    :param generator: draws the initial weights and the batches
    :return: the classifier and the number of updates it took
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(torch.randint(2**31, (1,), generator=generator)))
        classifier = DomainClassifier(z.shape[1], max(n_domains, 2))
    optimizer = torch.optim.Adam(classifier.parameters(), lr=CLASSIFIER_LR)

    def batches() -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        for _ in range(MAX_CLASSIFIER_STEPS):
            batch = torch.randint(len(z), (batch_size,), generator=generator)
            yield z[batch], domains[batch]

    _, steps = train_classifier(classifier, optimizer, batches(), stop_accuracy=ACCURACY_THRESHOLD)
    return classifier, steps


def standardised_sample(sample: StateSample) -> tuple[torch.Tensor, torch.Tensor]:
    """The sample's features standardised over the whole sample (float32, constant features left at 0) and
    its domain labels: what the domain classifier and the weights of :func:`correlation_study` see.

    :param sample: states from :func:`collect_states`
    """
    spread = sample.features.std(axis=0)
    if spread[sample.changed] == 0:
        raise ZooError(f"the changed feature {sample.names[sample.changed]!r} has the same value in every domain")
    standardised = (sample.features - sample.features.mean(axis=0)) / np.where(spread > 0, spread, 1.0)
    return torch.as_tensor(standardised, dtype=torch.float32), torch.as_tensor(sample.domains)


def correlation_study(sample: StateSample, batch_size: int = DEFAULT_BATCH_SIZE, seed: int = 0) -> StudyResult:
    """Mean |Pearson correlation| under raw, global and SGFD weights, over random batches of the sample.

    Features are standardised over the whole sample first. Pearson correlation and the weight solver
    (which standardises each batch itself) do not care, but the classifier's saliency |d logit / d z_i|
    does: it scales as 1 / std_i, so a parameter that varies by a centimetre would look salient for its
    units alone, trained classifier or not.

    :param sample: states from :func:`collect_states`
    :param batch_size: states per batch (SGFD's batch: 128)
    :param seed: seeds the classifier, the batches and the random Fourier features
    """
    n, d = sample.features.shape
    if not 2 <= batch_size <= n:
        raise ZooError(f"--batch-size must be in 2..{n} (the number of states), got {batch_size}")
    z_all, domains = standardised_sample(sample)
    n_domains = int(domains.max()) + 1

    generator = torch.Generator().manual_seed(seed)
    classifier, classifier_steps = train_domain_classifier(z_all, domains, n_domains, batch_size, generator)
    accuracy = classifier_accuracy(classifier, z_all, domains)

    order = np.random.default_rng(seed).permutation(n)
    n_batches = n // batch_size
    abs_corr: dict[str, list[np.ndarray]] = {key: [] for key in WEIGHTINGS}
    ess: dict[str, list[float]] = {key: [] for key in WEIGHTINGS}
    changed_prob: list[float] = []
    rff = torch.Generator()
    for index in range(n_batches):
        z = z_all[order[index * batch_size : (index + 1) * batch_size]]
        probs = feature_probabilities(classifier, z)
        changed_prob.append(probs[sample.changed].item())
        weights: dict[str, torch.Tensor] = {"raw": torch.ones(batch_size)}
        # The same RFF draw for both weightings: they differ only in the feature probabilities.
        for key, feature_probs in (("global", None), ("sgfd", probs)):
            rff.manual_seed(seed * 1_000_003 + index)
            weights[key] = cast(torch.Tensor, learn_sample_weights(z, feature_probs, generator=rff))  # no losses
        for key in WEIGHTINGS:
            abs_corr[key].append(weighted_pearson(z, weights[key]).abs().numpy())
            ess[key].append(effective_sample_size(weights[key]) / batch_size)

    others = [column for column in range(d) if column != sample.changed]
    matrices = {key: np.mean(abs_corr[key], axis=0) for key in WEIGHTINGS}
    return StudyResult(
        names=sample.names,
        changed=sample.changed,
        matrices=matrices,
        mean_abs_corr={key: float(matrices[key][sample.changed, others].mean()) for key in WEIGHTINGS},
        ess={key: float(np.mean(ess[key])) for key in WEIGHTINGS},
        classifier_accuracy=accuracy,
        n_batches=n_batches,
        batch_size=batch_size,
        extra={"classifier_steps": classifier_steps, "mean_changed_feature_probability": float(np.mean(changed_prob))},
    )


def labels(names: list[str]) -> list[str]:
    """Axis labels ``s1 name`` ... ``sd name`` (the paper numbers the features s1..s10)."""
    return [f"s{index + 1} {name}" for index, name in enumerate(names)]


def plot_correlation(result: StudyResult, path: Path, title: str) -> Path:
    """Three heat maps side by side (raw, global, SGFD) of the mean |correlation|, features labelled.

    :param result: what :func:`correlation_study` measured
    :param path: PNG file to write
    :param title: figure title
    """
    d = len(result.names)
    size = 1.6 + 0.38 * d
    fig = Figure(figsize=(3 * size + 1.2, size + 1.4), layout="constrained")
    axes = fig.subplots(1, 3)
    ticks = labels(result.names)
    for ax, key in zip(axes, WEIGHTINGS, strict=True):
        matrix = result.matrices[key]
        image = ax.imshow(matrix, vmin=0.0, vmax=1.0, cmap="Blues")
        for i in range(d):
            for j in range(d):
                ax.text(
                    j,
                    i,
                    f"{matrix[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=6,
                    color="white" if matrix[i, j] > 0.6 else "black",
                )
        # Frame the changed feature's row and column: the correlations the study is about.
        c = result.changed
        ax.add_patch(Rectangle((-0.5, c - 0.5), d, 1, fill=False, edgecolor="red", linewidth=1.2))
        ax.add_patch(Rectangle((c - 0.5, -0.5), 1, d, fill=False, edgecolor="red", linewidth=1.2))
        ax.set_xticks(range(d), ticks, rotation=90, fontsize=7)
        ax.set_yticks(range(d), ticks if key == "raw" else [f"s{i + 1}" for i in range(d)], fontsize=7)
        ess = f", ESS {result.ess[key]:.2f} n" if key != "raw" else ""
        ax.set_title(f"{TITLES[key]}\nmean |r(s{c + 1}, others)| = {result.mean_abs_corr[key]:.3f}{ess}", fontsize=9)
    fig.colorbar(image, ax=list(axes), shrink=0.8, label="|Pearson r|, mean over batches")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=100)
    return path


def result_json(result: StudyResult, config: dict[str, Any]) -> dict[str, Any]:
    """The JSON document of a study: per weighting the mean |r| of the changed feature and the mean ESS."""
    document: dict[str, Any] = {
        key: {"mean_abs_corr": result.mean_abs_corr[key], "ess": result.ess[key]} for key in WEIGHTINGS
    }
    document.update(
        {
            "sgfd_over_raw": result.mean_abs_corr["sgfd"] / result.mean_abs_corr["raw"],
            "goals": result.goals,
            "features": labels(result.names),
            "changed_feature": labels(result.names)[result.changed],
            "classifier_accuracy": result.classifier_accuracy,
            "n_batches": result.n_batches,
            "batch_size": result.batch_size,
            "matrices": {key: np.round(result.matrices[key], 6).tolist() for key in WEIGHTINGS},
            **result.extra,
            **config,
        }
    )
    return document


def report(result: StudyResult) -> str:
    """The figures and goals as printed lines."""
    c = f"s{result.changed + 1} ({result.names[result.changed]})"
    corr, ess = result.mean_abs_corr, result.ess
    lines = [
        f"mean |correlation| between the changed feature {c} and the {len(result.names) - 1} others, "
        f"over {result.n_batches} batches of {result.batch_size}:"
    ]
    for key in WEIGHTINGS:
        lines.append(f"  {key:<6}  {corr[key]:.4f}   ESS {ess[key]:.3f} n")
    lines.append(
        f"  sgfd / raw = {corr['sgfd'] / corr['raw']:.3f};  classifier accuracy {result.classifier_accuracy:.3f}"
    )
    ratio = corr["sgfd"] / corr["raw"]
    checks = [
        (
            f"sgfd < global < raw ({corr['sgfd']:.4f} < {corr['global']:.4f} < {corr['raw']:.4f})",
            "sgfd_below_global_below_raw",
        ),
        (f"sgfd <= {GOAL_RATIO} x raw (ratio {ratio:.3f})", f"sgfd_at_most_{GOAL_RATIO}_of_raw"),
        (f"SGFD's ESS >= {GOAL_ESS} n ({ess['sgfd']:.3f} n)", f"sgfd_ess_at_least_{GOAL_ESS}_n"),
    ]
    goals = result.goals
    lines += [f"goal {text}: {'met' if goals[key] else 'NOT MET'}" for text, key in checks]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    parser = ZooArgumentParser(
        prog="sgfd-zoo correlation-study", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", required=True, help=f"one of {', '.join(study_env_ids())}")
    parser.add_argument("--out", required=True, type=Path, help="folder for correlation.png and correlation.json")
    parser.add_argument("--seed", type=int, default=0, help="seeds the envs, the classifier, batches and RFFs")
    parser.add_argument(
        "--steps-per-domain",
        type=int,
        default=DEFAULT_STEPS_PER_DOMAIN,
        help="states collected per training domain (random actions)",
    )
    parser.add_argument("--batch-size", type=int, default=DEFAULT_BATCH_SIZE, help="states per batch")
    parser.add_argument(
        "--n-state-features",
        type=int,
        help=f"keep the first N entries of the state (default {DEFAULT_N_STATE_FEATURES}; for "
        f"Causal World ids: {', '.join(CAUSAL_WORLD_FEATURES)})",
    )
    parser.add_argument("--features", help="comma-separated state feature names instead, e.g. 'height,velocity[0]'")
    args = parser.parse_args(argv)
    features = [name.strip() for name in args.features.split(",")] if args.features is not None else None
    print(f"Collecting {args.steps_per_domain} states per training domain of {args.env} (random actions)...")
    sample = collect_states(args.env, args.steps_per_domain, args.seed, features, args.n_state_features)
    result = correlation_study(sample, args.batch_size, args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    config = {
        "env_id": args.env,
        "seed": args.seed,
        "steps_per_domain": args.steps_per_domain,
        "n_domains": int(sample.domains.max()) + 1,
    }
    json_path = args.out / "correlation.json"
    json_path.write_text(json.dumps(result_json(result, config), indent=2))
    png_path = plot_correlation(
        result, args.out / "correlation.png", f"{args.env}: Pearson correlation, seed {args.seed}"
    )
    print(report(result))
    print(f"Wrote {png_path} and {json_path}")
    return 0
