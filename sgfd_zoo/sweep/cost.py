"""What a sweep costs before it starts: its runs, the updates each trains, and the GPU-hours and wall time they take
at the rates the latest device check measured (:data:`RATES_FILE`), packed on the GPUs by the sweep's rule
(:func:`sgfd_zoo.sweep.plan.packing`). It reads yaml and csv only: no torch, no Ray, nothing trained.

The rate table holds one row per measurement: the date and machine of the device check (``bench/device_check.py``),
the algorithm and observations, how many runs shared the GPU and their updates per second in all, and which update
(``eager``, or the captured one). An algorithm the latest check did not measure has no rate: the plan says so and
leaves its runs out of the totals, rather than guess one.
"""

from __future__ import annotations

import ast
import csv
import heapq
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import sgfd_envs
from sgfd_zoo.algos import column_name, hyperparams_entry
from sgfd_zoo.arguments import ZooError, flag_value, has_flag
from sgfd_zoo.sweep.plan import packing

RATES_FILE = Path(__file__).with_name("device_rates.csv")
RATE_COLUMNS: tuple[str, ...] = ("date", "machine", "cores", "gpus", "algo", "observations", "env_id")
RATE_COLUMNS += ("runs_at_once", "updates_per_s", "update", "note")
#: ``sgfd-zoo train``'s evaluation during training where a spec leaves it open (its --eval-freq, --eval-episodes).
TRAIN_EVAL_FREQ, TRAIN_EVAL_EPISODES = 25_000, 5


@dataclass(frozen=True)
class Rate:
    """One measurement of the device check: ``runs_at_once`` runs of ``algo`` shared one GPU of ``machine`` and made
    ``updates_per_s`` updates a second in all."""

    date: str
    machine: str
    cores: int
    gpus: int
    algo: str
    observations: str
    env_id: str
    runs_at_once: int
    updates_per_s: float
    update: str
    note: str


def read_rates(path: Path = RATES_FILE) -> list[Rate]:
    """The rows of the rate table at ``path``, checked (a ZooError naming the file and the line otherwise)."""
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        if tuple(reader.fieldnames or ()) != RATE_COLUMNS:
            raise ZooError(f"{path}: expected the columns {', '.join(RATE_COLUMNS)}, got {reader.fieldnames}")
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                rate = Rate(
                    date=row["date"],
                    machine=row["machine"],
                    cores=int(row["cores"]),
                    gpus=int(row["gpus"]),
                    algo=row["algo"],
                    observations=row["observations"],
                    env_id=row["env_id"],
                    runs_at_once=int(row["runs_at_once"]),
                    updates_per_s=float(row["updates_per_s"]),
                    update=row["update"],
                    note=row["note"],
                )
            except (TypeError, ValueError) as error:
                raise ZooError(f"{path}, line {line}: not a rate ({error})") from None
            if min(rate.cores, rate.gpus, rate.runs_at_once) < 1 or not rate.updates_per_s > 0:
                raise ZooError(f"{path}, line {line}: cores, gpus, runs_at_once and updates_per_s must be positive")
            rows.append(rate)
    return rows


def latest_check(rates: Sequence[Rate], path: Path = RATES_FILE) -> list[Rate]:
    """The rows of the newest device check (the newest date; one machine a date)."""
    if not rates:
        raise ZooError(f"{path}: no rate measured yet (bench/device_check.py measures them)")
    newest = max(rate.date for rate in rates)
    rows = [rate for rate in rates if rate.date == newest]
    machines = sorted({(rate.machine, rate.cores, rate.gpus) for rate in rows})
    if len(machines) > 1:
        raise ZooError(f"{path}: the check of {newest} names several machines {machines}; one machine a date")
    return rows


@dataclass(frozen=True)
class RunPlan:
    """What one run of the sweep trains: ``updates`` gradient updates (None: not computable from its settings) on
    ``observations``; and the episodes it is evaluated on, during training and at the end (every split)."""

    algo: str
    env_id: str
    seed: int
    updates: int | None
    observations: str
    eval_episodes: int
    final_episodes: int


def plan_runs(
    algos: Sequence[str], env_ids: Sequence[str], seeds: Sequence[int], train: Sequence[str], n_episodes: int
) -> list[RunPlan]:
    """The runs of a sweep in the order it starts them (seed by seed), each with what it trains.

    :param algos: algorithm keys
    :param env_ids: env ids
    :param seeds: training seeds
    :param train: the flags of every run's ``sgfd-zoo train``
    :param n_episodes: final evaluation episodes per split (``sgfd-zoo evaluate --n-episodes``)
    """
    quick = has_flag(train, "--quick")
    overrides = _key_values(train, ("-params", "--hyperparams"))
    env_kwargs = _key_values(train, ("--env-kwargs",))
    eval_freq = int(flag_value(train, "--eval-freq") or TRAIN_EVAL_FREQ)
    eval_episodes = int(flag_value(train, "--eval-episodes") or TRAIN_EVAL_EPISODES)
    cells = {}
    for algo in algos:
        for env_id in env_ids:
            entry = {**hyperparams_entry(algo, env_id, quick), **overrides}
            steps = int(float(flag_value(train, "-n") or flag_value(train, "--n-timesteps") or entry["n_timesteps"]))
            n_envs = int(entry.get("n_envs") or sgfd_envs.n_domains(env_id, "train"))
            kwargs = {**(entry.get("env_kwargs") or {}), **env_kwargs}
            evaluations = steps // eval_freq if eval_freq > 0 else 0
            episodes = evaluations * eval_episodes * len(sgfd_envs.splits(env_id))
            final = n_episodes * len(sgfd_envs.evaluation_modes(env_id))
            observations = str(kwargs.get("obs_type", "pixels"))
            cells[algo, env_id] = (_updates(entry, steps, n_envs), observations, episodes, final)
    return [RunPlan(algo, env_id, seed, *cells[algo, env_id]) for seed in seeds for env_id in env_ids for algo in algos]


def _updates(entry: dict[str, Any], steps: int, n_envs: int) -> int | None:
    """Gradient updates of a run of ``steps`` env steps: one per transition after ``learning_starts`` with
    ``gradient_steps: -1`` (as many as the vec env collected), else ``gradient_steps`` per ``train_freq`` vec steps;
    None for a train frequency counted in episodes."""
    learning_starts, train_freq = int(entry.get("learning_starts", 100)), entry.get("train_freq", 1)  # SB3's defaults
    gradient_steps = int(entry.get("gradient_steps", 1))
    if not isinstance(train_freq, int):
        return None
    collected = max(steps - learning_starts, 0)
    return collected if gradient_steps < 0 else collected * gradient_steps // (train_freq * n_envs)


def _key_values(argv: Sequence[str], flags: Sequence[str]) -> dict[str, Any]:
    """The ``key:value`` words after any of ``flags`` (up to the next flag), their values read as Python literals
    where they are one (else kept as text)."""
    values: dict[str, Any] = {}
    taking = False
    for word in argv:
        if word.startswith("-") and not _is_number(word):
            taking = word in flags
        elif taking and ":" in word:
            key, _, text = word.partition(":")
            try:
                values[key] = ast.literal_eval(text)
            except (ValueError, SyntaxError):
                values[key] = text
    return values


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def per_run_rate(check: Sequence[Rate], algo: str, observations: str, at_once: int) -> tuple[float | None, str]:
    """Updates per second of one run of ``algo`` while ``at_once`` runs share its GPU, and how it was had: measured,
    or this algorithm's own one-run rate scaled by another algorithm's measured ``at_once``-run / one-run ratio on
    the same machine (marked with ``~``). None (with why) when the check measured neither.

    :param check: the rows of one device check
    :param algo: algorithm key
    :param observations: ``pixels`` or ``state``
    :param at_once: runs sharing the GPU
    """
    rows = {(rate.algo, rate.runs_at_once): rate.updates_per_s for rate in check if rate.observations == observations}
    if (algo, at_once) in rows:
        return rows[algo, at_once] / at_once, "measured"
    if (algo, 1) not in rows:
        return None, f"no measured rate on {observations}"
    for other, runs in sorted(rows):
        if runs == at_once and (other, 1) in rows:
            ratio = rows[other, at_once] / rows[other, 1]
            how = f"{algo}'s 1-run rate x {other}'s {at_once}-run / 1-run ratio {ratio:.2f}"
            return rows[algo, 1] * ratio / at_once, how
    return None, f"its {at_once}-runs-at-once rate is not measured"


def wall_hours(durations: Sequence[float], slots: int) -> float:
    """Hours until the last run ends when runs of ``durations`` (hours, in start order) take the first free of
    ``slots`` places (runs per GPU x GPUs), each at its packed rate throughout: an upper bound, since the last runs
    share their GPU with fewer."""
    free = [0.0] * max(slots, 1)
    ends = [0.0]
    for duration in durations:
        start = heapq.heappop(free)
        ends.append(start + duration)
        heapq.heappush(free, start + duration)
    return max(ends)


def cost_lines(
    runs: Sequence[RunPlan], gpus: int, gpus_per_run: float | None, rates_file: Path = RATES_FILE
) -> list[str]:
    """The plan's cost, in markdown lines: per algorithm its runs, rates and GPU-hours, alone and packed by the
    sweep's rule on the latest device check's machine; the totals, the wall time on ``gpus`` GPUs, and the
    measurements used.

    :param runs: the runs still to train, in start order (:func:`plan_runs`)
    :param gpus: GPUs of that machine's kind the sweep runs on
    :param gpus_per_run: ``--gpus-per-run``; None: the packing rule's
    :param rates_file: the rate table
    """
    check = latest_check(read_rates(rates_file), rates_file)
    first = check[0]
    envs = max((sgfd_envs.n_domains(run.env_id, "train") for run in runs), default=1)
    rule = packing(first.cores / first.gpus, envs, gpus_per_run)
    at_once = max([rate.runs_at_once for rate in check if rate.runs_at_once <= rule.runs_per_gpu], default=1)
    updates = sorted({run.updates for run in runs}, key=lambda n: -1 if n is None else n)
    lines = [
        f"rates: the device check of {first.date} on {first.machine} ({first.gpus} GPU, {first.cores} cores), "
        f"{' and '.join(sorted({rate.update for rate in check}))} update ({rates_file.name})",
        f"packing on that machine: {rule}",
    ]
    if at_once < rule.runs_per_gpu:
        most = f"{at_once} run{'s' if at_once > 1 else ''}"
        lines.append(f"(the check measured at most {most} at once on a GPU: the plan packs {most} per GPU)")
    lines += [
        f"updates per run: {', '.join('not computable' if n is None else f'{n:,}' for n in updates)}",
        "",
        f"| algo | runs | updates/s, 1 run alone | GPU-hours, 1 run per GPU | updates/s each, {at_once} per GPU | "
        f"GPU-hours, {at_once} per GPU |",
        "|---|---|---|---|---|---|",
    ]
    packed_rate: dict[str, float] = {}
    scaled: list[str] = []
    alone_total = packed_total = 0.0
    for algo in dict.fromkeys(run.algo for run in runs):
        group = [run for run in runs if run.algo == algo]
        kinds = {run.observations for run in group}
        one, why = per_run_rate(check, algo, group[0].observations, 1)
        each, how = per_run_rate(check, algo, group[0].observations, at_once) if one else (None, why)
        if len(kinds) > 1 or any(run.updates is None for run in group):
            each, how = None, "updates not computable" if len(kinds) == 1 else "pixels and states mixed"
        name = f"{column_name(algo)} ({algo})"
        if one is None or each is None:
            lines.append(f"| {name} | {len(group)} | {how} | – | – | – |")
            continue
        updates_of_group = sum(run.updates or 0 for run in group)
        alone, packed = updates_of_group / one / 3600, updates_of_group / each / 3600 / at_once
        mark = "" if how == "measured" else "~"
        scaled += [f"~ {how} ({algo} not measured at {at_once} at once)"] if mark else []
        lines.append(f"| {name} | {len(group)} | {one:.1f} | {alone:.1f} | {mark}{each:.1f} | {mark}{packed:.1f} |")
        alone_total, packed_total = alone_total + alone, packed_total + packed
        packed_rate[algo] = each
    rated = [run for run in runs if run.algo in packed_rate]
    wall = wall_hours([(run.updates or 0) / packed_rate[run.algo] / 3600 for run in rated], gpus * at_once)
    lines += [
        "",
        f"total, the {len(rated)} of {len(runs)} runs with a rate: {alone_total:.1f} GPU-hours one run per GPU, "
        f"{packed_total:.1f} at {at_once} per GPU",
        f"wall time of those {len(rated)} runs on {gpus} such GPU{'s' if gpus > 1 else ''} "
        f"({first.cores // first.gpus} cores each), {at_once} runs on each: {wall:.1f} h "
        f"({wall / 24:.1f} days)",
    ]
    unrated = [algo for algo in dict.fromkeys(run.algo for run in runs) if algo not in packed_rate]
    if unrated:
        lines.append(
            f"not in the totals: {', '.join(unrated)} ({len(runs) - len(rated)} runs): no rate in that check "
            "(bench/device_check.py measures one)"
        )
    if runs:
        during, final = max(run.eval_episodes for run in runs), max(run.final_episodes for run in runs)
        lines.append(
            f"not in the rates: evaluation, up to {during} episodes per run during training and {final} at the end "
            "(inference and rendering only)"
        )
    lines += scaled
    used = [rate for rate in check if rate.algo in packed_rate and rate.runs_at_once in (1, at_once)]
    lines += [
        f"measured: {rate.algo}, {rate.runs_at_once} at once: {rate.updates_per_s:g} updates/s in all ({rate.note})"
        for rate in used
    ]
    return lines
