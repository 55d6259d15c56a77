"""What a sweep costs before it starts: its runs, the updates and env steps each takes, and the GPU-hours and wall time
they take at the rates the latest device check measured (:data:`RATES_FILE`), packed on the GPUs by the sweep's rule
(:func:`sgfd_zoo.sweep.plan.packing`). It reads yaml and csv only: no torch, no Ray, nothing trained.

A run's time is its gradient updates at the learner's update rate plus its env steps (transitions: the physics and
the render of every sub-env step) at the env-step rate: at the paper's cadence (one update per 5 transitions) the env
steps are no longer a small part of it. The rate table holds one row per measurement of the device check
(``bench/device_check.py``): its date and machine, what ran and on which observations, how many runs shared the GPU,
and either an agent's updates per second in all during a learning run (with the env steps each update's share of the
run took inside it: ``env_steps_per_update``), or, on an ``envs`` row, env steps per second in all of a run's env
processes. The learner's own update rate is the learning run's with those env steps taken out. What the latest check
did not measure has no rate: the plan says so and leaves its runs out of the totals, rather than guess one.
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
RATE_COLUMNS += ("runs_at_once", "updates_per_s", "env_steps_per_update", "env_steps_per_s", "update", "note")
#: The ``algo`` of a row that measured env steps alone (a run's env processes, no agent).
ENVS = "envs"
#: ``sgfd-zoo train``'s evaluation during training where a spec leaves it open (its --eval-freq, --eval-episodes).
TRAIN_EVAL_FREQ, TRAIN_EVAL_EPISODES = 25_000, 5
#: The callback that adds the authors' burst of updates (sb3_sgfd.common.update_burst), and its default size.
UPDATE_BURST, UPDATE_BURST_DEFAULT = "sb3_sgfd.common.update_burst.UpdateBurst", 1000


@dataclass(frozen=True)
class Rate:
    """One measurement of the device check: ``runs_at_once`` runs shared one GPU of ``machine``; an agent's row gives
    their ``updates_per_s`` in all, with ``env_steps_per_update`` env steps inside each update's time; an
    :data:`ENVS` row gives their env processes' ``env_steps_per_s`` in all."""

    date: str
    machine: str
    cores: int
    gpus: int
    algo: str
    observations: str
    env_id: str
    runs_at_once: int
    updates_per_s: float | None
    env_steps_per_update: float | None
    env_steps_per_s: float | None
    update: str
    note: str


def _optional_float(text: str | None) -> float | None:
    return None if text is None or text.strip() == "" else float(text)


def _rate_of(row: dict[str, str]) -> Rate:
    return Rate(
        date=row["date"],
        machine=row["machine"],
        cores=int(row["cores"]),
        gpus=int(row["gpus"]),
        algo=row["algo"],
        observations=row["observations"],
        env_id=row["env_id"],
        runs_at_once=int(row["runs_at_once"]),
        updates_per_s=_optional_float(row["updates_per_s"]),
        env_steps_per_update=_optional_float(row["env_steps_per_update"]),
        env_steps_per_s=_optional_float(row["env_steps_per_s"]),
        update=row["update"],
        note=row["note"],
    )


def _problem(rate: Rate) -> str | None:
    """What makes a parsed row no rate, or None."""
    if min(rate.cores, rate.gpus, rate.runs_at_once) < 1:
        return "cores, gpus and runs_at_once must be positive"
    if rate.algo == ENVS:
        return None if (rate.env_steps_per_s or 0) > 0 else f"an {ENVS} row needs env_steps_per_s > 0"
    if not (rate.updates_per_s or 0) > 0 or (rate.env_steps_per_update or 0) < 0:
        return "an agent's row needs updates_per_s > 0 and env_steps_per_update >= 0"
    return None


def read_rates(path: Path = RATES_FILE) -> list[Rate]:
    """The rows of the rate table at ``path``, checked (a ZooError naming the file and the line otherwise)."""
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        if tuple(reader.fieldnames or ()) != RATE_COLUMNS:
            raise ZooError(f"{path}: expected the columns {', '.join(RATE_COLUMNS)}, got {reader.fieldnames}")
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                rate = _rate_of(row)
            except (TypeError, ValueError) as error:
                raise ZooError(f"{path}, line {line}: not a rate ({error})") from None
            if (problem := _problem(rate)) is not None:
                raise ZooError(f"{path}, line {line}: {problem}")
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
    """What one run of the sweep trains: ``updates`` gradient updates (None: not computable from its settings) and
    ``env_steps`` transitions on ``observations``; and the episodes it is evaluated on, during training and at the
    end (every split)."""

    algo: str
    env_id: str
    seed: int
    updates: int | None
    observations: str
    eval_episodes: int
    final_episodes: int
    env_steps: int = 0


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
            kwargs = {**(entry.get("env_kwargs") or {}), **env_kwargs}
            n_envs = int(entry.get("n_envs") or sgfd_envs.n_domains(env_id, "train", **kwargs))
            evaluations = steps // eval_freq if eval_freq > 0 else 0
            episodes = evaluations * eval_episodes * len(sgfd_envs.splits(env_id))
            final = n_episodes * len(sgfd_envs.evaluation_modes(env_id))
            observations = str(kwargs.get("obs_type", "pixels"))
            cells[algo, env_id] = (_updates(entry, steps, n_envs), observations, episodes, final, steps)
    return [RunPlan(algo, env_id, seed, *cells[algo, env_id]) for seed in seeds for env_id in env_ids for algo in algos]


def _updates(entry: dict[str, Any], steps: int, n_envs: int) -> int | None:
    """Gradient updates of a run of ``steps`` env steps: one per transition after ``learning_starts`` with
    ``gradient_steps: -1`` (as many as the vec env collected), else ``gradient_steps`` per ``train_freq`` vec steps;
    plus the burst of :data:`UPDATE_BURST` where the entry's callbacks hold it; None for a train frequency counted in
    episodes."""
    learning_starts, train_freq = int(entry.get("learning_starts", 100)), entry.get("train_freq", 1)  # SB3's defaults
    gradient_steps = int(entry.get("gradient_steps", 1))
    if not isinstance(train_freq, int):
        return None
    collected = max(steps - learning_starts, 0)
    regular = collected if gradient_steps < 0 else collected * gradient_steps // (train_freq * n_envs)
    return regular + (_burst_updates(entry.get("callback")) if collected > 0 else 0)


def _burst_updates(callback: Any) -> int:
    """The updates of the :data:`UPDATE_BURST` among rl-zoo3's callbacks (a name, a ``{name: kwargs}``, or a list of
    them), 0 without one."""
    entries = callback if isinstance(callback, list) else [callback]
    for entry in entries:
        if entry == UPDATE_BURST:
            return UPDATE_BURST_DEFAULT
        if isinstance(entry, dict) and UPDATE_BURST in entry:
            return int((entry[UPDATE_BURST] or {}).get("updates", UPDATE_BURST_DEFAULT))
    return 0


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
    """Updates per second of one run of ``algo`` while ``at_once`` runs share its GPU, as its learning run measured
    them (env steps inside), and how it was had: measured, or this algorithm's own one-run rate scaled by another
    algorithm's measured ``at_once``-run / one-run ratio on the same machine (marked with ``~``). None (with why)
    when the check measured neither.

    :param check: the rows of one device check
    :param algo: algorithm key
    :param observations: ``pixels`` or ``state``
    :param at_once: runs sharing the GPU
    """
    rows = {
        (rate.algo, rate.runs_at_once): rate.updates_per_s
        for rate in check
        if rate.observations == observations and rate.updates_per_s is not None
    }
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


def _env_steps_inside(check: Sequence[Rate], algo: str, observations: str, at_once: int) -> float:
    """The env steps inside each update of ``algo``'s learning run at ``at_once`` (its one-run row where that was not
    measured)."""
    rows = {(r.algo, r.runs_at_once): r for r in check if r.observations == observations and r.updates_per_s}
    row = rows.get((algo, at_once)) or rows[algo, 1]
    return row.env_steps_per_update or 0.0


def per_run_env_rate(
    check: Sequence[Rate], observations: str, at_once: int, sharing: float
) -> tuple[float | None, str]:
    """Env steps per second of one run's env processes while ``at_once`` runs share the machine: measured, or the
    one-run rate slowed as the learning runs are (``sharing``: an agent's ``at_once``-run / one-run rate per run),
    marked ``~``. None (with why) when the check measured no env steps on ``observations``.

    :param check: the rows of one device check
    :param observations: ``pixels`` or ``state``
    :param at_once: runs sharing the machine
    :param sharing: the factor by which sharing slows a run's learning
    """
    rows = {
        rate.runs_at_once: rate.env_steps_per_s
        for rate in check
        if rate.algo == ENVS and rate.observations == observations and rate.env_steps_per_s
    }
    if at_once in rows:
        return rows[at_once] / at_once, "measured"
    if 1 not in rows:
        return None, f"no measured env-step rate on {observations}"
    return rows[1] * sharing, f"the 1-run env-step rate x the learning runs' {at_once}-run slowdown {sharing:.2f}"


@dataclass(frozen=True)
class RunSpeed:
    """How fast one run goes while ``at_once`` runs share its GPU: seconds per gradient update of its learner (its
    env steps taken out) and per env step; ``how`` says what was not measured as it stands (empty: all was)."""

    at_once: int
    update_seconds: float
    env_step_seconds: float
    how: str = ""

    def hours(self, run: RunPlan) -> float:
        """Hours of ``run`` at this speed: its updates and its env steps."""
        return ((run.updates or 0) * self.update_seconds + run.env_steps * self.env_step_seconds) / 3600


def run_speed(check: Sequence[Rate], algo: str, observations: str, at_once: int) -> tuple[RunSpeed | None, str]:
    """:class:`RunSpeed` of a run of ``algo`` from one device check, or None and why not.

    :param check: the rows of one device check
    :param algo: algorithm key
    :param observations: ``pixels`` or ``state``
    :param at_once: runs sharing the GPU
    """
    measured, how = per_run_rate(check, algo, observations, at_once)
    if measured is None:
        return None, how
    alone = per_run_rate(check, algo, observations, 1)[0] or measured
    env_rate, env_how = per_run_env_rate(check, observations, at_once, measured / alone)
    if env_rate is None:
        return None, env_how
    update_seconds = 1 / measured - _env_steps_inside(check, algo, observations, at_once) / env_rate
    if update_seconds <= 0:
        return None, f"its measured updates/s leave no time for its env steps at {env_rate:.0f} env steps/s"
    hows = [text for text in (how, env_how) if text != "measured"]
    return RunSpeed(at_once, update_seconds, 1 / env_rate, "; ".join(hows)), ""


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


def _header(check: Sequence[Rate], rule: Any, at_once: int, runs: Sequence[RunPlan], rates_file: Path) -> list[str]:
    """The lines above the plan's table: the check, the packing, the updates and env steps per run, the columns."""
    first = check[0]
    updates = sorted({run.updates for run in runs}, key=lambda n: -1 if n is None else n)
    lines = [
        f"rates: the device check of {first.date} on {first.machine} ({first.gpus} GPU, {first.cores} cores), "
        f"{' and '.join(sorted({rate.update for rate in check if rate.algo != ENVS}))} update ({rates_file.name})",
        f"packing on that machine: {rule}",
    ]
    if at_once < rule.runs_per_gpu:
        most = f"{at_once} run{'s' if at_once > 1 else ''}"
        lines.append(f"(the check measured at most {most} at once on a GPU: the plan packs {most} per GPU)")
    return [
        *lines,
        f"updates per run: {', '.join('not computable' if n is None else f'{n:,}' for n in updates)}",
        f"env steps per run (physics and render): {', '.join(f'{n:,}' for n in sorted({r.env_steps for r in runs}))}",
        "",
        f"| algo | runs | updates/s, 1 run alone | env steps/s, 1 run alone | GPU-hours, 1 run per GPU | "
        f"updates/s each, {at_once} per GPU | env steps/s each | GPU-hours, {at_once} per GPU |",
        "|---|---|---|---|---|---|---|---|",
    ]


def _group_speeds(check: Sequence[Rate], group: Sequence[RunPlan], at_once: int) -> tuple[RunSpeed, RunSpeed] | str:
    """The speeds of one algorithm's runs, alone and packed, or why there are none."""
    kinds = {run.observations for run in group}
    if len(kinds) > 1:
        return "pixels and states mixed"
    if any(run.updates is None for run in group):
        return "updates not computable"
    alone, why = run_speed(check, group[0].algo, group[0].observations, 1)
    packed, packed_why = run_speed(check, group[0].algo, group[0].observations, at_once) if alone else (None, why)
    return (alone, packed) if alone is not None and packed is not None else packed_why


def _row(name: str, group: Sequence[RunPlan], alone: RunSpeed, packed: RunSpeed) -> str:
    mark = "~" if packed.how else ""
    hours_alone = sum(alone.hours(run) for run in group)
    hours_packed = sum(packed.hours(run) for run in group) / packed.at_once
    return (
        f"| {name} | {len(group)} | {1 / alone.update_seconds:.1f} | {1 / alone.env_step_seconds:.0f} | "
        f"{hours_alone:.1f} | {mark}{1 / packed.update_seconds:.1f} | {mark}{1 / packed.env_step_seconds:.0f} | "
        f"{mark}{hours_packed:.1f} |"
    )


def _footer(
    runs: Sequence[RunPlan], rated: dict[str, RunSpeed], totals: tuple[float, float], gpus: int, cores: int
) -> list[str]:
    """The totals, the wall time on ``gpus`` GPUs of ``cores`` cores each, and what the totals leave out."""
    at_once = next(iter(rated.values())).at_once if rated else 1
    with_rate = [run for run in runs if run.algo in rated]
    wall = wall_hours([rated[run.algo].hours(run) for run in with_rate], gpus * at_once)
    lines = [
        "",
        f"total, the {len(with_rate)} of {len(runs)} runs with a rate: {totals[0]:.1f} GPU-hours one run per GPU, "
        f"{totals[1]:.1f} at {at_once} per GPU",
        f"wall time of those {len(with_rate)} runs on {gpus} such GPU{'s' if gpus > 1 else ''} ({cores} cores each), "
        f"{at_once} runs on each: {wall:.1f} h ({wall / 24:.1f} days)",
    ]
    unrated = [algo for algo in dict.fromkeys(run.algo for run in runs) if algo not in rated]
    if unrated:
        lines.append(
            f"not in the totals: {', '.join(unrated)} ({len(runs) - len(with_rate)} runs): no rate in that check "
            "(bench/device_check.py measures one)"
        )
    if runs:
        during, final = max(run.eval_episodes for run in runs), max(run.final_episodes for run in runs)
        lines.append(
            f"not in the rates: evaluation, up to {during} episodes per run during training and {final} at the end "
            "(inference and rendering only)"
        )
    return lines


def _measured_lines(check: Sequence[Rate], rated: dict[str, RunSpeed], at_once: int) -> list[str]:
    """How the rates were had: what was scaled, and every row of the check the plan used."""
    lines = [f"~ {algo}: {speed.how}" for algo, speed in rated.items() if speed.how]
    lines.append(
        "updates/s alone: the learning run's updates/s with the env steps inside each update (its "
        "env_steps_per_update) taken out at the env-step rate"
    )
    used = [rate for rate in check if rate.algo in (*rated, ENVS) and rate.runs_at_once in (1, at_once)]
    for rate in used:
        if rate.algo == ENVS:
            figure = f"{rate.env_steps_per_s:g} env steps/s in all"
        else:
            inside = rate.env_steps_per_update or 0
            figure = (
                f"{rate.updates_per_s:g} updates/s in all, {inside:g} env step{'' if inside == 1 else 's'} per update"
            )
        lines.append(f"measured: {rate.algo}, {rate.runs_at_once} at once: {figure} ({rate.note})")
    return lines


def cost_lines(
    runs: Sequence[RunPlan], gpus: int, gpus_per_run: float | None, rates_file: Path = RATES_FILE
) -> list[str]:
    """The plan's cost, in markdown lines: per algorithm its runs, rates and GPU-hours (updates and env steps), alone
    and packed by the sweep's rule on the latest device check's machine; the totals, the wall time on ``gpus`` GPUs,
    and the measurements used.

    :param runs: the runs still to train, in start order (:func:`plan_runs`)
    :param gpus: GPUs of that machine's kind the sweep runs on
    :param gpus_per_run: ``--gpus-per-run``; None: the packing rule's
    :param rates_file: the rate table
    """
    check = latest_check(read_rates(rates_file), rates_file)
    first = check[0]
    envs = max((sgfd_envs.n_domains(run.env_id, "train") for run in runs), default=1)
    rule = packing(first.cores / first.gpus, envs, gpus_per_run)
    agents = [rate for rate in check if rate.algo != ENVS]
    at_once = max([rate.runs_at_once for rate in agents if rate.runs_at_once <= rule.runs_per_gpu], default=1)
    lines = _header(check, rule, at_once, runs, rates_file)
    rated: dict[str, RunSpeed] = {}
    totals = (0.0, 0.0)
    for algo in dict.fromkeys(run.algo for run in runs):
        group = [run for run in runs if run.algo == algo]
        speeds = _group_speeds(check, group, at_once)
        name = f"{column_name(algo)} ({algo})"
        if isinstance(speeds, str):
            lines.append(f"| {name} | {len(group)} | {speeds} | – | – | – | – | – |")
            continue
        alone, packed = speeds
        lines.append(_row(name, group, alone, packed))
        totals = (
            totals[0] + sum(alone.hours(run) for run in group),
            totals[1] + sum(packed.hours(run) for run in group) / at_once,
        )
        rated[algo] = packed
    footer = _footer(runs, rated, totals, gpus, first.cores // first.gpus)
    return [*lines, *footer, *_measured_lines(check, rated, at_once)]
