"""The sweep's plan: which (algorithm, env, seed) runs are still to train, the run folder each trains in, and how
many runs share a GPU (:func:`packing`). Pure: it reads the log folder and starts nothing (no Ray, no torch)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import sgfd_envs
from sgfd_zoo.algos import hyperparams_entry
from sgfd_zoo.arguments import ZooError, has_flag
from sgfd_zoo.runs.folders import RunFolder, find_runs, runs_by_id
from sgfd_zoo.runs.locks import RunLocked, live_holder


@dataclass(frozen=True)
class Job:
    """
    One run of the sweep.

    :param algo: Algorithm key
    :param env_id: SGFD env id
    :param seed: Training seed
    :param run_id: The run folder is ``<folder>/<algo>/<EnvName>_<run_id>``
    :param folder: The sweep's log folder (absolute)
    """

    algo: str
    env_id: str
    seed: int
    run_id: int
    folder: Path

    @property
    def run(self) -> RunFolder:
        return RunFolder.at(self.folder, self.algo, self.env_id, self.run_id)

    @property
    def run_dir(self) -> Path:
        return self.run.path

    @property
    def log_file(self) -> Path:
        return self.run.log_file

    def __str__(self) -> str:
        return f"{self.algo} on {self.env_id} seed {self.seed}"

    @property
    def name(self) -> str:
        """Short, for the progress lines."""
        return f"{self.algo} {self.env_id.split('/')[-1].removesuffix('-v0')} seed {self.seed}"


def plan(
    folder: Path,
    algos: Sequence[str],
    env_ids: Sequence[str],
    seeds: Sequence[int],
    recorded: Collection[tuple[str, str, int | None]] = (),
) -> tuple[list[Job], list[tuple[str, str, int]], list[str]]:
    """
    The runs still to train (new or to resume), the (algo, env, seed) already finished in ``folder`` or
    ``recorded``, and
    one line per unreadable file of a run folder (such a folder is read as if that file were absent: a run
    whose args are unreadable has no known seed, one whose checkpoint index is unreadable resumes from the
    checkpoint files it has).

    :param folder: Log folder (absolute)
    :param algos: Algorithm keys
    :param env_ids: SGFD env ids
    :param seeds: Training seeds
    :param recorded: (algo, env, seed) finished elsewhere (a study's records, from an earlier session)
    """
    problems = [problem for run in find_runs(folder, algos, env_ids, finished=False) for problem in run.problems]
    finished = {(run.algo, run.env_id, run.seed) for run in find_runs(folder, algos, env_ids)} | set(recorded)
    jobs, done = [], []
    assigned: dict[tuple[str, str], set[int]] = {}
    # Seed by seed: the first runs to finish fill a whole table for one seed, not many seeds of one cell.
    for seed in seeds:
        for env_id in env_ids:
            for algo in algos:
                if (algo, env_id, seed) in finished:
                    done.append((algo, env_id, seed))
                    continue
                taken = assigned.setdefault((algo, env_id), set())
                run_id = choose_run_id(folder, algo, env_id, seed, [*(s + 1 for s in seeds), *taken])
                taken.add(run_id)
                jobs.append(Job(algo, env_id, seed, run_id, folder))
    return jobs, done, problems


def choose_run_id(folder: Path, algo: str, env_id: str, seed: int, reserved: Sequence[int]) -> int:
    """
    The run id of an unfinished ``seed``, decided here (in one process) because rl-zoo3's own choice,
    newest id + 1, races when runs start together. In order of preference:

    1. the unfinished run of this seed with the furthest checkpoint (it will be resumed);
    2. an unfinished run of this seed without a checkpoint (restarted there, so that failed attempts do
       not pile up as folders; it has no model to lose), the one with id ``seed + 1`` first;
    3. ``seed + 1`` (rl-zoo3 numbers runs from 1; ``enjoy --exp-id 0`` means the newest), unless that
       folder holds another seed's run (from ``sgfd-zoo train``, say);
    4. one more than any id in the folder and any of ``reserved`` (the sweep's ids, ids already given).

    :param folder: the sweep's log folder
    :param algo: algorithm key
    :param env_id: SGFD env id
    :param seed: Training seed
    :param reserved: Ids a new id must not take
    """
    existing = runs_by_id(folder, algo, env_id)
    mine = {run_id: run for run_id, run in existing.items() if run.seed == seed}
    checkpoints = {run_id: run.checkpoint for run_id, run in mine.items()}
    resumable = [(checkpoint.num_timesteps, run_id) for run_id, checkpoint in checkpoints.items() if checkpoint]
    if resumable:
        return max(resumable)[1]
    preferred = seed + 1
    if mine:
        return preferred if preferred in mine else max(mine)
    if preferred not in existing or existing[preferred].seed is None:
        return preferred
    return max([*existing, *reserved, preferred]) + 1


def locked_runs(jobs: Sequence[Job]) -> list[tuple[Job, str]]:
    """The jobs whose run folder another live process writes now (a ``sgfd-zoo train --resume`` of it, another
    sweep), each with one line naming that process: the sweep leaves them alone.

    :param jobs: the planned runs
    """
    locked = []
    for job in jobs:
        if (holder := live_holder(job.run_dir)) is not None:
            locked.append((job, f"refused: {RunLocked.being_written(job.run_dir, holder)} (one writer at a time)"))
    return locked


# -- runs on a GPU ----------------------------------------------------------------------------------------------
# The packing rule's constants, in one place: bench/device_check.py measures 1, 4 and 8 concurrent paper-scale runs
# on one GPU; tune these from its table (sgfd_zoo/sweep/device_rates.csv).

#: Env processes one core keeps up with. A paper-scale env process renders and steps for about 2 ms per agent step
#: (EGL on the GPU), while its run's learner spends tens of milliseconds per update: each env process idles most of
#: the time, and four share a core.
ENV_PROCESSES_PER_CORE = 4
#: The most runs one GPU holds: 8 is the most measured at once (2026-12-04, H200 with 16 cores: 8 runs 74.4 updates/s
#: in all, 4 runs 66.5, 1 run 18.4).
MAX_RUNS_PER_GPU = 8
#: torch's CPU threads of a run whose networks are on a GPU: its CPU side is Python, kernel launches and the replay
#: buffer's numpy indexing, which more threads do not speed up; they would only spin beside the env processes.
TORCH_THREADS_WITH_GPU = 1
#: Ray counts resources in steps of 1e-4: a GPU fraction is rounded down to it, so that k runs fit one GPU.
RAY_RESOURCE_STEP = 1e-4
#: What a replay buffer stores per transition beside its observations (action, reward, done, timeout, domain label,
#: episode id: about 40 bytes for a 6-d action), rounded up.
TRANSITION_EXTRA_BYTES = 64
#: A state observation's bytes, at most (float32; the MT states have 24 to 25 values, the benchmarks' fewer).
STATE_OBSERVATION_BYTES = 4 * 64
#: The side of a pixel observation where a run's env kwargs give no ``image_size`` (every id's default).
DEFAULT_IMAGE_SIZE = 84
#: The share of a GPU's part of its node's memory (Ray's ``memory`` resource) that its runs' replay buffers may fill:
#: the rest holds the runs' processes, their env processes and their networks.
REPLAY_MEMORY_SHARE = 0.75


@dataclass(frozen=True)
class Packing:
    """
    How runs share a node's GPUs and cores.

    :param gpus_per_run: Ray's ``num_gpus`` of each run (0.125: 8 runs on a GPU)
    :param cpus_per_run: Ray's ``num_cpus`` of each run: the GPU's share of the node's cores
    :param env_processes: subprocess envs per run (0: its envs step in the run's own process)
    :param torch_threads: torch's CPU threads per run
    :param replay_bytes: the memory each run's full replay buffer takes (0: not counted)
    """

    gpus_per_run: float
    cpus_per_run: float
    env_processes: int
    torch_threads: int
    replay_bytes: int = 0

    @property
    def runs_per_gpu(self) -> int:
        """How many runs one GPU holds at once."""
        if self.gpus_per_run >= 1:
            return 1
        return int(1 / self.gpus_per_run + 1e-6) if self.gpus_per_run > 0 else 0

    def __str__(self) -> str:
        envs = f"{self.env_processes} env processes" if self.env_processes else "its envs in its own process"
        threads = f"{self.torch_threads} torch thread{'s' if self.torch_threads > 1 else ''}"
        share = f"{self.runs_per_gpu} run{'s' if self.runs_per_gpu > 1 else ''} per GPU"
        if self.gpus_per_run > 1:
            share = f"{self.gpus_per_run:g} GPUs per run"
        replay = f", a replay buffer of {self.replay_bytes / 1e9:.1f} GB" if self.replay_bytes else ""
        return (
            f"{share} (--gpus-per-run {self.gpus_per_run:g}); each {self.cpus_per_run:g} CPUs, {threads} and {envs}"
            f"{replay}"
        )


def packing(
    cores_per_gpu: float,
    envs_per_run: int,
    gpus_per_run: float | None = None,
    memory_per_gpu: float | None = None,
    replay_bytes: int = 0,
) -> Packing:
    """
    How paper-scale runs share a GPU node (the rule the sweep follows when its runs have a GPU):

    - a run needs one core for its learner and one for every :data:`ENV_PROCESSES_PER_CORE` of its env processes
      (each training domain an env process: 4 at paper scale, so 2 cores a run);
    - a GPU holds as many runs as its share of the node's cores feeds, at most :data:`MAX_RUNS_PER_GPU`
      (16 cores a GPU: 8 runs; 8 cores: 4), and as many full replay buffers as :data:`REPLAY_MEMORY_SHARE` of its
      share of the node's memory holds (the paper's pixel buffer: 21.2 GB a run, 4 runs in 128 GiB);
    - each run reserves the GPU's cores divided among its runs, and takes :data:`TORCH_THREADS_WITH_GPU` torch
      threads.

    :param cores_per_gpu: the node's CPU cores divided by its GPUs
    :param envs_per_run: training envs of a run (its training domains: ``n_envs``)
    :param gpus_per_run: the GPU fraction asked for (``--gpus-per-run``); None: the rule's
    :param memory_per_gpu: the node's memory for tasks (bytes) divided by its GPUs; None: not known (not counted)
    :param replay_bytes: a run's full replay buffer (:func:`replay_bytes`); 0: not counted
    """
    env_processes = envs_per_run if envs_per_run > 1 else 0
    if gpus_per_run is None:
        cores_per_run = 1 + math.ceil(env_processes / ENV_PROCESSES_PER_CORE)
        runs = min(max(int(cores_per_gpu // cores_per_run), 1), MAX_RUNS_PER_GPU)
        if memory_per_gpu and replay_bytes:
            runs = min(runs, max(int(memory_per_gpu * REPLAY_MEMORY_SHARE // replay_bytes), 1))
        gpus_per_run = math.floor(1 / runs / RAY_RESOURCE_STEP) * RAY_RESOURCE_STEP
    return Packing(
        gpus_per_run=gpus_per_run,
        cpus_per_run=round(cores_per_gpu * gpus_per_run, 4),
        env_processes=env_processes,
        torch_threads=TORCH_THREADS_WITH_GPU,
        replay_bytes=replay_bytes,
    )


def gpu_fraction(text: str | None) -> float | None:
    """The ``--gpus-per-run`` value: a fraction of a GPU up to 1 (Ray packs ``1 / fraction`` runs on one), a whole
    number of GPUs, or 0 (none); None when not given. Anything else is refused in one line.

    :param text: the flag's value as given
    """
    if text is None:
        return None
    expected = "expected a fraction of a GPU such as 0.25 (4 runs on one GPU), a whole number of GPUs, or 0"
    try:
        value = float(text)
    except ValueError:
        raise ZooError(f"--gpus-per-run {text!r}: {expected}") from None
    if not math.isfinite(value) or value < 0:
        raise ZooError(f"--gpus-per-run {text}: {expected}")
    if value > 1 and not value.is_integer():
        raise ZooError(f"--gpus-per-run {text}: Ray gives a run more than one GPU only whole; {expected}")
    if 0 < value < RAY_RESOURCE_STEP:
        raise ZooError(f"--gpus-per-run {text}: Ray counts GPUs in steps of {RAY_RESOURCE_STEP:g}; {expected}")
    return value


def envs_per_run(algos: Sequence[str], env_ids: Sequence[str], quick: bool = False) -> int:
    """The most training envs a run of these (algorithm, env) pairs has: its yaml's ``n_envs``, else one per training
    domain (as the zoo builds it).

    :param algos: algorithm keys
    :param env_ids: env ids
    :param quick: the quick configuration's yaml
    """
    counts = [
        int(hyperparams_entry(algo, env_id, quick).get("n_envs") or sgfd_envs.n_domains(env_id, "train"))
        for algo in algos
        for env_id in env_ids
    ]
    return max(counts, default=1)


def replay_bytes(algos: Sequence[str], env_ids: Sequence[str], quick: bool = False) -> int:
    """The memory the largest full replay buffer of these runs takes, from their yaml entries: ``buffer_size``
    transitions of their observations (pixels: one frame each where the buffer stores each frame once, its
    ``replay_buffer_kwargs`` naming ``frame_stack``; else both stacks), plus :data:`TRANSITION_EXTRA_BYTES` each.

    :param algos: algorithm keys
    :param env_ids: env ids
    :param quick: the quick configuration's yaml
    """
    largest = 0
    for algo in algos:
        for env_id in env_ids:
            entry = hyperparams_entry(algo, env_id, quick)
            given = entry.get("env_kwargs")
            env_kwargs: dict[str, Any] = given if isinstance(given, dict) else {}
            if env_kwargs.get("obs_type", "pixels") == "state":
                observation = 2 * STATE_OBSERVATION_BYTES
            else:
                frame = 3 * int(env_kwargs.get("image_size", DEFAULT_IMAGE_SIZE)) ** 2
                stored_once = "frame_stack" in str(entry.get("replay_buffer_kwargs") or "")
                observation = frame if stored_once else 2 * int(entry.get("frame_stack") or 1) * frame
            transitions = int(entry.get("buffer_size", 1_000_000))  # SB3's default where the yaml gives none
            largest = max(largest, transitions * (observation + TRANSITION_EXTRA_BYTES))
    return largest


def run_resources(
    args: argparse.Namespace, train_args: list[str], cores_per_gpu: float | None, memory_per_gpu: float | None = None
) -> tuple[list[str], Packing | None]:
    """Set ``args.cpus_per_run`` and ``args.gpus_per_run`` (Ray's reservation of each run) once the cluster is known,
    and return the train flags with each run's torch threads and, on a GPU, its env processes (flags the user gave
    are kept), with the packing on a GPU (None without). Without a GPU a run reserves 1 CPU and takes as many torch
    threads as CPUs, as before GPUs were packed; with one, the packing rule (:func:`packing`) decides what the user
    left open.

    :param args: the sweep's options (``gpus_per_run`` None: not given; ``envs_per_run``, ``replay_bytes``)
    :param train_args: the flags of each run's ``sgfd-zoo train``
    :param cores_per_gpu: the CPU cores per GPU of the cluster's GPU nodes (the fewest); None: it has no GPU
    :param memory_per_gpu: their memory for tasks (Ray's ``memory``, bytes) per GPU, the least; None: not known
    """
    rule = None
    if cores_per_gpu is None and args.gpus_per_run:
        raise ZooError(f"--gpus-per-run {args.gpus_per_run:g}: the Ray cluster has no GPU")
    if cores_per_gpu is None or args.gpus_per_run == 0:
        args.gpus_per_run = 0.0
        args.cpus_per_run = args.cpus_per_run or 1.0
        added = ["--num-threads", str(max(math.floor(args.cpus_per_run), 1))]
    else:
        if memory_per_gpu is not None and args.replay_bytes > memory_per_gpu:
            raise ZooError(
                f"a run's replay buffer takes {args.replay_bytes / 1e9:.1f} GB, more than the "
                f"{memory_per_gpu / 1e9:.1f} GB of memory per GPU of the cluster's GPU nodes: lower it "
                "(-params buffer_size:N) or use nodes with more memory"
            )
        rule = packing(cores_per_gpu, args.envs_per_run, args.gpus_per_run, memory_per_gpu, args.replay_bytes)
        args.gpus_per_run = rule.gpus_per_run
        args.cpus_per_run = args.cpus_per_run or max(rule.cpus_per_run, 1.0)
        added = ["--num-threads", str(rule.torch_threads)]
        if rule.env_processes and not has_flag(train_args, "--vec-env"):
            added += ["--vec-env", "subproc"]
    if has_flag(train_args, "--num-threads"):
        added = added[2:]
    return [*train_args, *added], rule
