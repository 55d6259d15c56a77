"""A study's compact records of finished runs, kept next to its spec, with no model:

<study>/runs/<algo>/<EnvName>_<id>/         the same name as the run folder it was exported from
    config.yml, args.yml, versions.txt      the run's hyperparameters, arguments and what trained it (no URL's
                                            credentials; args.yml's log_folder only the folder's name)
    source.txt                              the run it was exported from: <algo>/<run> and a digest of its log
                                            folder's path (records of earlier versions: the absolute path)
    evaluations_<split>.npz                 as in the run folder
    diagnostics.csv                         the logged figures the study reads, one row per logged step
    final_evaluation.csv                    the final model's evaluation, one row per split (written last)

Records are committed and shared: a record is made of plain files (a link in the run or in the record is refused,
never followed), and reading one never follows a link either.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

import sgfd_envs
from sgfd_zoo.runs.bounded import RefusedFile, csv_rows, read_text
from sgfd_zoo.runs.fields import finite_number, result_row, safe_name, whole_number
from sgfd_zoo.runs.folders import FileInFolder, NamedRun, RunFolder, read_evaluations, run_paths
from sgfd_zoo.runs.safe import copy_file, load_yaml, make_folder, redact, refuse_links_inside, write_file, write_text

FINAL_EVALUATION_FIELDS = ("algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes")
# Kept when present: whether the split played on a built-in stand-in of a benchmark's data (older records lack it).
OPTIONAL_EVALUATION_FIELDS = ("stand_in",)
#: source.txt: the run, and a digest of its log folder's absolute path (which names people and machines).
_SOURCE = re.compile(r"(?P<run>[^/\s]+/[^/\s]+) in log folder (?P<digest>sha256:[0-9a-f]{16})")


def _folder_digest(folder: Path) -> str:
    return "sha256:" + hashlib.sha256(str(Path(folder).resolve()).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class RunRecord(NamedRun):
    """A finished run as a study keeps it next to its spec: ``<study>/runs/<algo>/<EnvName>_<id>``. What the
    study's tables and figures read, so that a later session, on a machine without the log folder, continues
    the study without training these runs again.

    :param path: the record's folder
    """

    final_evaluation = FileInFolder(
        "final_evaluation.csv", "The final model's evaluation, a row per split (written last)."
    )
    diagnostics = FileInFolder("diagnostics.csv", "The logged figures the study reads, a row per logged step.")
    source_file = FileInFolder(
        "source.txt", "The run it was exported from: ``<algo>/<run>`` and its log folder's digest."
    )

    def made_from(self, run: RunFolder) -> bool | None:
        """Whether this record was made from the log run ``run``; None for a record written before records named
        their run. Reads the absolute paths that records of earlier versions hold too."""
        if not self.source_file.exists():
            return None
        source = read_text(self.source_file).strip()
        match = _SOURCE.fullmatch(source)
        if match is None:
            return Path(source) == run.path.resolve()
        return match["run"] == f"{run.algo}/{run.path.name}" and match["digest"] == _folder_digest(run.root)

    @functools.cached_property
    def final_rows(self) -> list[dict[str, Any]]:
        """The final model's evaluation, one row per split ([] when the record has none), as ``sgfd-zoo
        evaluate`` gives it, ``run`` being the record's folder: each field checked (:func:`~sgfd_zoo.runs.fields.
        result_row`: this record's algorithm and env, one of its splits, finite returns), read within the limits
        of :mod:`~sgfd_zoo.runs.bounded`."""
        if not self.final_evaluation.exists():
            return []
        rows = [
            {**result_row(row, self.final_evaluation, self.algo, self.env_id), "run": str(self.path)}
            for row in csv_rows(self.final_evaluation)
        ]
        seeds = {row["seed"] for row in rows}
        if len(seeds) > 1:
            where = self.final_evaluation
            raise RefusedFile(f"{where}: refused: it holds the rows of seeds {sorted(seeds)}, not one run's")
        return rows

    @property
    def seed(self) -> int | None:
        return self.final_rows[0]["seed"] if self.final_rows else None

    @property
    def complete(self) -> bool:
        """Whether the record has the final model's evaluation on every split of its env."""
        return {row["split"] for row in self.final_rows} >= set(sgfd_envs.splits(self.env_id))

    def log(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(timesteps, values) of one logged figure kept in ``diagnostics.csv`` (empty when it was not kept): whole
        steps and finite values, or a refusal naming the file."""
        steps, values = [], []
        if self.diagnostics.exists():
            for row in csv_rows(self.diagnostics):
                if row.get(key):
                    steps.append(whole_number(row.get("timesteps"), "timesteps", self.diagnostics))
                    values.append(finite_number(row[key], key, self.diagnostics))
        return np.array(steps, dtype=np.int64), np.array(values, dtype=np.float64)

    def write(self, run: RunFolder, final_rows: list[dict[str, Any]], diagnostics: Callable[[Path], object]) -> None:
        """This record of the finished ``run``: its files, then its final evaluation (last: a record with
        one is whole).

        :param run: the run folder
        :param final_rows: its final model's evaluation (``sgfd-zoo evaluate``'s rows)
        :param diagnostics: writes the logged figures to the path it is given
        """
        root = self.root
        run.refuse_links()  # a linked versions.txt would copy whatever it points to into a committed record
        make_folder(root, self.path)
        refuse_links_inside(self.path, root)
        self.final_evaluation.unlink(missing_ok=True)
        write_text(root, self.source_file, f"{run.algo}/{run.path.name} in log folder {_folder_digest(run.root)}\n")
        for npz in sorted(run.path.glob("evaluations_*.npz")):
            safe_name(npz.name, "file", run.path)
            read_evaluations(npz)  # data only: an UnreadableFile otherwise
            copy_file(run.root, npz, root, self.path / npz.name, limit="MAX_NPZ_FILE_BYTES")
        for name, limit in (("config.yml", "MAX_YAML_BYTES"), ("args.yml", "MAX_YAML_BYTES"), ("versions.txt", None)):
            if (run.config_dir / name).exists():
                change = functools.partial(_shared_args, source=run.config_dir / name) if name == "args.yml" else redact
                copy_file(run.root, run.config_dir / name, root, self.path / name, change, limit or "MAX_TEXT_BYTES")
        write_file(root, self.diagnostics, lambda tmp: diagnostics(Path(tmp)))

        def write_rows(tmp: str) -> None:
            with open(tmp, "w", newline="") as handle:
                fields = FINAL_EVALUATION_FIELDS + OPTIONAL_EVALUATION_FIELDS
                writer = csv.DictWriter(handle, fields, extrasaction="ignore")
                writer.writeheader()
                writer.writerows(final_rows)

        write_file(root, self.final_evaluation, write_rows)
        self.__dict__.pop("final_rows", None)


def _shared_args(text: str, source: Path) -> str:
    """rl-zoo3's ``args.yml`` as a record keeps it: no URL's credentials, and of its log folder only the name."""
    args = load_yaml(text, source)
    if isinstance(args, dict) and isinstance(args.get("log_folder"), str):
        args["log_folder"] = Path(args["log_folder"]).name
        return redact(yaml.dump(args))
    return redact(text)


def find_records(
    folder: Path, algos: Iterable[str] | None = None, env_ids: Iterable[str] | None = None
) -> list[RunRecord]:
    """The run records under a study's ``runs`` folder, sorted by algo, env and id (whole or not: see
    :attr:`RunRecord.complete`).

    :param folder: the study's ``runs`` folder
    :param algos: only these algorithm keys
    :param env_ids: only these env ids
    """
    paths = run_paths(folder, algos, env_ids)
    for path in paths:  # committed files: a link would read (and show in the tables) what it points to
        refuse_links_inside(path, folder, "read")
    records = [RunRecord(path) for path in paths]
    return sorted(records, key=lambda record: (record.algo, record.env_id, record.run_id))
