"""The sweep's plan: which (algorithm, env, seed) runs are still to train, and the run folder each trains in.
Pure: it reads the log folder and starts nothing (no Ray)."""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

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
