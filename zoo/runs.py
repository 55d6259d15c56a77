"""The run folders sgfd-zoo writes and reads, in one place (rl-zoo3's layout plus the zoo's files):

    <log folder>/<algo>/<EnvName>_<id>/        a run (:class:`RunFolder`); EnvName is the id with "/" -> "-"
        <EnvName>.zip                           the final model
        <EnvName>/args.yml, config.yml          rl-zoo3's saved arguments and hyperparameters
        evaluations_<split>.npz                 evaluations during training, per split
        progress.csv, progress_from_<n>.csv     everything logged (a resumed run continues in a new file)
        checkpoint.json (+ the files it names)  the newest checkpoint
        final_evaluation.json                   sgfd-zoo evaluate's result for the final model (reused while it fits)
    <log folder>/<algo>/<EnvName>_<id>.log      a sweep run's output, beside its folder

Light on imports: plotting and the sweep's planning read runs without torch; ``load_model`` imports it.
"""

from __future__ import annotations

import csv
import functools
import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

import sgfd_envs
from zoo.arguments import ZooError, check_env_id

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

CHECKPOINT_INDEX = "checkpoint.json"
STEPS_KEY = "time/total_timesteps"


def env_name(env_id: str) -> str:
    """rl-zoo3's name of an env id in paths: ``SGFD/MT-walker-walk-v0`` -> ``SGFD-MT-walker-walk-v0``."""
    return env_id.replace("/", "-")


ENV_IDS_BY_NAME = {env_name(env_id): env_id for env_id in sgfd_envs.SGFD_IDS}


@dataclass(frozen=True)
class RunFolder:
    """One run: ``<log folder>/<algo>/<EnvName>_<id>``.

    :param path: the run's folder
    """

    path: Path

    @classmethod
    def at(cls, folder: Path, algo: str, env_id: str, run_id: int) -> RunFolder:
        """The folder of run ``run_id`` of ``algo`` on ``env_id`` under the log folder ``folder``."""
        return cls(Path(folder) / algo / f"{env_name(env_id)}_{run_id}")

    @classmethod
    def parse(cls, path: Path) -> RunFolder | None:
        """``path`` as a run folder, or None if its name is not ``<EnvName>_<id>`` of an SGFD id."""
        name, _, run_id = Path(path).name.rpartition("_")
        return cls(Path(path)) if name in ENV_IDS_BY_NAME and run_id.isdigit() else None

    @property
    def algo(self) -> str:
        return self.path.parent.name

    @property
    def env_id(self) -> str:
        return ENV_IDS_BY_NAME[self.path.name.rpartition("_")[0]]

    @property
    def run_id(self) -> int:
        return int(self.path.name.rpartition("_")[2])

    @property
    def log_file(self) -> Path:
        """A sweep run's output: next to the folder, so a run that fails early leaves no half-made folder."""
        return self.path.with_name(f"{self.path.name}.log")

    @property
    def model_path(self) -> Path:
        return self.path / f"{env_name(self.env_id)}.zip"

    @property
    def final_evaluation(self) -> Path:
        """Where ``sgfd-zoo evaluate`` keeps the final model's evaluation, to reuse it."""
        return self.path / "final_evaluation.json"

    @property
    def config_dir(self) -> Path:
        return self.path / env_name(self.env_id)

    @functools.cached_property
    def args(self) -> dict[str, Any]:
        """rl-zoo3's saved command-line arguments ({} before the run wrote them)."""
        return _read_yaml(self.config_dir / "args.yml")

    @functools.cached_property
    def config(self) -> dict[str, Any]:
        """The hyperparameters the run trained with ({} before the run wrote them)."""
        return _read_yaml(self.config_dir / "config.yml")

    @property
    def seed(self) -> int | None:
        seed = self.args.get("seed")
        return None if seed is None else int(seed)

    @property
    def env_kwargs(self) -> dict[str, Any]:
        return dict(self.args.get("env_kwargs") or self.config.get("env_kwargs") or {})

    @property
    def frame_stack(self) -> int | None:
        return self.config.get("frame_stack")

    @property
    def finished(self) -> bool:
        """Whether training ended and saved the final model (else: running, or crashed and resumable)."""
        return self.model_path.exists() and (self.config_dir / "args.yml").exists()

    @property
    def checkpoint(self) -> dict[str, Any] | None:
        """The newest complete checkpoint recorded in the folder, or None."""
        return read_checkpoint(self.path)

    def evaluations(self, split: str) -> dict[str, np.ndarray] | None:
        """``timesteps``, ``results`` (evaluations x episodes) and ``ep_lengths`` of a split, or None."""
        path = self.path / f"evaluations_{split}.npz"
        if not path.exists():
            return None
        with np.load(path) as data:
            return {key: data[key] for key in data.files}

    def log(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(timesteps, values) of one logged figure over the whole run, sorted by timesteps.

        A resumed run continues in ``progress_from_<steps>.csv``; where files overlap, the later file wins
        (the resumed run replaced what the crashed one logged after its checkpoint).

        :param key: a logged name, e.g. ``sgfd/classifier_accuracy``
        """
        points: dict[int, float] = {}
        for path in sorted(self.path.glob("progress*.csv"), key=_resume_step):
            with path.open(newline="") as handle:
                reader = csv.DictReader(handle)
                if reader.fieldnames is None or key not in reader.fieldnames or STEPS_KEY not in reader.fieldnames:
                    continue
                rows = [(row[STEPS_KEY], row[key]) for row in reader]
            resumed_at = _resume_step(path)
            points = {step: value for step, value in points.items() if step <= resumed_at}
            for steps, value in rows:
                if steps and value:
                    points[int(float(steps))] = float(value)
        steps = np.array(sorted(points), dtype=np.int64)
        return steps, np.array([points[step] for step in steps], dtype=np.float64)

    def load_model(self, device: str = "cpu") -> BaseAlgorithm:
        """The final model, without allocating its replay buffer."""
        from rl_zoo3.utils import ALGOS

        from zoo.experiment import register_algorithms

        register_algorithms()
        if self.algo not in ALGOS:
            raise ZooError(f"{self.path}: unknown algorithm {self.algo!r}")
        return ALGOS[self.algo].load(self.model_path, custom_objects={"buffer_size": 1}, device=device)


def find_runs(
    folder: Path, algos: Iterable[str] | None = None, env_ids: Iterable[str] | None = None, finished: bool = True
) -> list[RunFolder]:
    """The runs under a log folder, sorted by algo, env and id; optionally only some algos and env ids.

    :param folder: the log folder
    :param algos: only these algorithm keys
    :param env_ids: only these env ids
    :param finished: only finished runs (else every run folder)
    """
    algos, env_ids = set(algos or ()), set(env_ids or ())
    runs = []
    if not Path(folder).is_dir():
        return runs
    for algo_dir in sorted(path for path in Path(folder).iterdir() if path.is_dir()):
        if algos and algo_dir.name not in algos:
            continue
        for path in algo_dir.iterdir():
            run = RunFolder.parse(path) if path.is_dir() else None
            if run is None or (env_ids and run.env_id not in env_ids) or (finished and not run.finished):
                continue
            runs.append(run)
    return sorted(runs, key=lambda run: (run.algo, run.env_id, run.run_id))


def runs_by_id(folder: Path, algo: str, env_id: str) -> dict[int, RunFolder]:
    """Every run folder (finished or not) of ``algo`` on ``env_id``, by run id."""
    return {run.run_id: run for run in find_runs(folder, [algo], [env_id], finished=False)}


def select_run(folder: Path, env_id: str, algo: str, run_id: int | None = None) -> RunFolder:
    """The finished run ``run_id`` of ``algo`` on ``env_id``, or the newest one; a ZooError naming the choices.

    :param folder: the log folder
    :param env_id: an SGFD id
    :param algo: algorithm key
    :param run_id: the run's number (the ``_<id>`` suffix); None: the highest
    """
    if not Path(folder).is_dir():
        raise ZooError(f"--folder {folder} does not exist (train first: sgfd-zoo train -f {folder} ...)")
    check_env_id(env_id)
    runs = {run.run_id: run for run in find_runs(folder, [algo], [env_id])}
    if not runs:
        raise ZooError(f"no finished {algo} run of {env_id} under {folder} (expected {algo}/<EnvName>_<id>/)")
    if run_id is None:
        return runs[max(runs)]
    if run_id not in runs:
        raise ZooError(f"--exp-id {run_id}: no such run of {algo} on {env_id}; choose from {sorted(runs)}")
    return runs[run_id]


def read_checkpoint(folder: str | Path) -> dict[str, Any] | None:
    """The newest complete checkpoint recorded in ``folder``, or None."""
    index = Path(folder) / CHECKPOINT_INDEX
    if not index.exists():
        return None
    return json.loads(index.read_text())


def _read_yaml(path: Path) -> dict[str, Any]:
    if not path.exists():
        return {}
    loaded = yaml.load(path.read_text(), Loader=yaml.UnsafeLoader)
    # rl-zoo3 writes an OrderedDict, or a list of (key, value) pairs
    return dict(loaded) if loaded else {}


def _resume_step(path: Path) -> int:
    suffix = path.stem.removeprefix("progress").removeprefix("_from_")
    return int(suffix) if suffix.isdigit() else -1
