"""A study's compact records of finished runs, kept next to its spec, with no model:

<study>/runs/<algo>/<EnvName>_<id>/         the same name as the run folder it was exported from
    config.yml, args.yml, versions.txt      the run's hyperparameters, arguments and what trained it
    source.txt                              the run folder it was exported from
    evaluations_<split>.npz                 as in the run folder
    diagnostics.csv                         the logged figures the study reads, one row per logged step
    final_evaluation.csv                    the final model's evaluation, one row per split (written last)
"""

from __future__ import annotations

import csv
import functools
import shutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import sgfd_envs
from sgfd_zoo.runs.files import UnreadableFile, atomic_write
from sgfd_zoo.runs.folders import NamedRun, RunFolder, run_paths

FINAL_EVALUATION_FIELDS = ("algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes")
# Kept when present: whether the split played on a built-in stand-in of a benchmark's data (older records lack it).
OPTIONAL_EVALUATION_FIELDS = ("stand_in",)


@dataclass(frozen=True)
class RunRecord(NamedRun):
    """A finished run as a study keeps it next to its spec: ``<study>/runs/<algo>/<EnvName>_<id>``. What the
    study's tables and figures read, so that a later session, on a machine without the log folder, continues
    the study without training these runs again.

    :param path: the record's folder
    """

    @property
    def final_evaluation(self) -> Path:
        return self.path / "final_evaluation.csv"

    @property
    def diagnostics(self) -> Path:
        return self.path / "diagnostics.csv"

    @property
    def source_file(self) -> Path:
        return self.path / "source.txt"

    @property
    def source(self) -> Path | None:
        """The log run this record was made from (None for a record written before records named it)."""
        return Path(self.source_file.read_text().strip()) if self.source_file.exists() else None

    @functools.cached_property
    def final_rows(self) -> list[dict[str, Any]]:
        """The final model's evaluation, one row per split ([] when the record has none), as ``sgfd-zoo
        evaluate`` gives it, ``run`` being the record's folder."""
        if not self.final_evaluation.exists():
            return []
        with self.final_evaluation.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
        types = {"seed": int, "mean_reward": float, "std_reward": float, "n_episodes": int}
        try:
            return [
                {
                    **{key: types.get(key, str)(row[key]) for key in FINAL_EVALUATION_FIELDS},
                    **{key: row[key] for key in OPTIONAL_EVALUATION_FIELDS if row.get(key)},
                    "run": str(self.path),
                }
                for row in rows
            ]
        except (KeyError, TypeError, ValueError) as error:
            raise UnreadableFile(f"{self.final_evaluation} is unreadable ({type(error).__name__}: {error})") from None

    @property
    def seed(self) -> int | None:
        return self.final_rows[0]["seed"] if self.final_rows else None

    @property
    def complete(self) -> bool:
        """Whether the record has the final model's evaluation on every split of its env."""
        return {row["split"] for row in self.final_rows} >= set(sgfd_envs.splits(self.env_id))

    def log(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(timesteps, values) of one logged figure kept in ``diagnostics.csv`` (empty when it was not kept)."""
        steps, values = [], []
        if self.diagnostics.exists():
            with self.diagnostics.open(newline="") as handle:
                for row in csv.DictReader(handle):
                    if row.get(key):
                        steps.append(int(row["timesteps"]))
                        values.append(float(row[key]))
        return np.array(steps, dtype=np.int64), np.array(values, dtype=np.float64)

    def write(self, run: RunFolder, final_rows: list[dict[str, Any]], diagnostics: Callable[[Path], object]) -> None:
        """This record of the finished ``run``: its files, then its final evaluation (last: a record with
        one is whole).

        :param run: the run folder
        :param final_rows: its final model's evaluation (``sgfd-zoo evaluate``'s rows)
        :param diagnostics: writes the logged figures to the path it is given
        """
        self.path.mkdir(parents=True, exist_ok=True)
        self.final_evaluation.unlink(missing_ok=True)
        atomic_write(self.source_file, lambda tmp: Path(tmp).write_text(f"{run.path.resolve()}\n"))
        for npz in sorted(run.path.glob("evaluations_*.npz")):
            atomic_write(self.path / npz.name, functools.partial(shutil.copyfile, npz))
        for name in ("config.yml", "args.yml", run.versions_file.name):
            if (run.config_dir / name).exists():
                atomic_write(self.path / name, functools.partial(shutil.copyfile, run.config_dir / name))
        atomic_write(self.diagnostics, lambda tmp: diagnostics(Path(tmp)))

        def write_rows(tmp: str) -> None:
            with open(tmp, "w", newline="") as handle:
                fields = FINAL_EVALUATION_FIELDS + OPTIONAL_EVALUATION_FIELDS
                writer = csv.DictWriter(handle, fields, extrasaction="ignore")
                writer.writeheader()
                writer.writerows(final_rows)

        atomic_write(self.final_evaluation, write_rows)
        self.__dict__.pop("final_rows", None)


def find_records(
    folder: Path, algos: Iterable[str] | None = None, env_ids: Iterable[str] | None = None
) -> list[RunRecord]:
    """The run records under a study's ``runs`` folder, sorted by algo, env and id (whole or not: see
    :attr:`RunRecord.complete`).

    :param folder: the study's ``runs`` folder
    :param algos: only these algorithm keys
    :param env_ids: only these env ids
    """
    records = [RunRecord(path) for path in run_paths(folder, algos, env_ids)]
    return sorted(records, key=lambda record: (record.algo, record.env_id, record.run_id))
