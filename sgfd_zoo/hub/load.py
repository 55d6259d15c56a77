"""``sgfd-zoo load-from-hub``: a run pushed to the Hugging Face Hub (or a local copy of its repository) into a new
run folder of a log folder, as rl-zoo3's load_from_hub lays it out, marked finished: ``enjoy``, ``record-video`` and
``evaluate`` take it as they take a run trained here.

The YAML files are read as data before anything is copied (a tag or a value that names code is refused), and only
the metric files the zoo reads are taken out of ``train_eval_metrics.zip`` (plain names, bounded sizes). The model
zip is SB3's format, which holds pickles: it is copied, not loaded, and loading it later runs its author's code.
"""

from __future__ import annotations

import argparse
import fnmatch
import functools
import json
import shutil
import zipfile
from collections.abc import Sequence
from pathlib import Path

from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_env_id, command_parser
from sgfd_zoo.config_checks import first_line
from sgfd_zoo.hub import ARGS, CONFIG, ENV_KWARGS, METRICS, VEC_NORMALIZE, model_file, repository_id
from sgfd_zoo.hub.push import METRIC_FILES
from sgfd_zoo.runs.files import atomic_write
from sgfd_zoo.runs.folders import RunFolder, env_name, mark_finished
from sgfd_zoo.runs.locks import claim_new_run
from sgfd_zoo.runs.safe import plain_name
from sgfd_zoo.trained import saved_settings

#: The largest metric file taken out of ``train_eval_metrics.zip``, inflated (a run's logs are megabytes)
MAX_METRIC_BYTES = 256 * 2**20


def load_parser() -> ZooArgumentParser:
    """The options of ``sgfd-zoo load-from-hub``: rl-zoo3's load_from_hub's, and ``--from-dir``."""
    parser = command_parser("load-from-hub")
    parser.add_argument("--algo", default="sgfd_sac", choices=SGFD_ALGOS, metavar="ALGO", help=", ".join(SGFD_ALGOS))
    parser.add_argument("--env", required=True, metavar="ENV_ID", help="the id it trained on")
    parser.add_argument("-f", "--folder", default="logs", help="the log folder to copy it into (default: logs)")
    parser.add_argument("-orga", "--organization", help="the Hub user or organization of the repository")
    parser.add_argument("-name", "--repo-name", help="the repository's name (default: <algo>-<EnvName>)")
    parser.add_argument("--revision", help="a branch, tag or commit of the repository (default: main)")
    parser.add_argument("--from-dir", metavar="FOLDER", help="a local copy of the repository instead of the Hub")
    return parser


def main(argv: Sequence[str]) -> int:
    """``sgfd-zoo load-from-hub`` on ``argv`` (the command line after ``load-from-hub``)."""
    args = load_parser().parse_args(list(argv))
    check_env_id(args.env)
    if (args.organization is None) == (args.from_dir is None):
        raise ZooError("give the repository's -orga (and -name), or --from-dir with a local copy of it; one of them")
    name = env_name(args.env)
    model = model_file(args.algo, name)
    source = Path(args.from_dir) if args.from_dir else download(args, model)
    run = copy_run(source, model, Path(args.folder), args.algo, args.env)
    print(f"Saved to {run.path}")
    print(f"watch it: sgfd-zoo enjoy --algo {args.algo} --env {args.env} -f {args.folder} --exp-id {run.run_id}")
    return 0


def download(args: argparse.Namespace, model: str) -> Path:
    """The repository's files in huggingface_hub's cache (only those a run folder takes); their folder."""
    from huggingface_hub import snapshot_download

    repo_id = repository_id(args.organization, args.repo_name, model)
    print(f"Downloading https://huggingface.co/{repo_id}")
    patterns = [model, CONFIG, ARGS, ENV_KWARGS, VEC_NORMALIZE, METRICS]
    try:
        return Path(snapshot_download(repo_id=repo_id, revision=args.revision, allow_patterns=patterns))
    except Exception as error:  # huggingface_hub's errors: no such repository, no network, a private one
        raise ZooError(f"{repo_id}: not downloaded ({type(error).__name__}: {first_line(error)})") from None


def copy_run(source: Path, model: str, folder: Path, algo: str, env_id: str) -> RunFolder:
    """The repository's files in ``source`` as a new finished run of ``algo`` on ``env_id`` under ``folder``.

    :param source: the repository's files
    :param model: the model's file name there
    :param folder: the log folder
    :param algo: the algorithm's key
    :param env_id: the id
    """
    for required in (model, CONFIG):
        if not (source / required).is_file():
            raise ZooError(f"{source}: no {required}; a run pushed by sgfd-zoo push-to-hub has one")
    saved_settings(source / CONFIG, required=True)  # each refused before anything is copied
    saved_settings(source / ARGS, required=False)
    saved_settings(source / ENV_KWARGS, required=False)
    steps = _model_steps(source / model)
    claimed = claim_new_run(folder / algo, env_name(env_id), f"sgfd-zoo load-from-hub --algo {algo} --env {env_id}")
    try:
        run = RunFolder(claimed.path)
        run.config_dir.mkdir()
        for name in (CONFIG, ARGS, ENV_KWARGS):
            if (source / name).is_file():
                _copy(source / name, run.config_dir / name)
        if (source / VEC_NORMALIZE).is_file():
            _copy(source / VEC_NORMALIZE, run.config_dir / "vecnormalize.pkl")
        if (source / METRICS).is_file():
            _extract_metrics(source / METRICS, run.path)
        stored = _copy(source / model, run.model_path)
        mark_finished(run.path, stored, steps)
    finally:
        claimed.release()
    return run


def _copy(source: Path, target: Path):
    return atomic_write(target, lambda tmp: shutil.copyfile(source, tmp))


def _model_steps(path: Path) -> int:
    """The steps a model zip was trained for, from its ``data`` member (JSON; nothing is unpickled)."""
    try:
        with zipfile.ZipFile(path) as archive:
            if archive.getinfo("data").file_size > MAX_METRIC_BYTES:
                raise ValueError("its data member is larger than a model's")
            steps = int(json.loads(archive.read("data"))["num_timesteps"])
    except (OSError, KeyError, TypeError, ValueError, zipfile.BadZipFile) as error:
        raise ZooError(f"{path}: not a Stable-Baselines3 model zip ({type(error).__name__}: {error})") from None
    return steps


def _extract_metrics(archive_path: Path, run: Path) -> None:
    """The members of ``train_eval_metrics.zip`` that are metric files the zoo reads, as plain files of the run."""
    try:
        with zipfile.ZipFile(archive_path) as archive:
            for member in archive.infolist():
                name = plain_name(member.filename, archive_path)
                if not any(fnmatch.fnmatch(name, pattern) for pattern in METRIC_FILES) or member.is_dir():
                    continue
                if member.file_size > MAX_METRIC_BYTES:
                    raise ZooError(f"{archive_path}: {name} inflates to {member.file_size} bytes, over the limit")
                atomic_write(run / name, functools.partial(_extract, archive, member))
    except zipfile.BadZipFile as error:
        raise ZooError(f"{archive_path}: not a zip file ({error})") from None


def _extract(archive: zipfile.ZipFile, member: zipfile.ZipInfo, target: str) -> None:
    """One member into ``target``, stopped at :data:`MAX_METRIC_BYTES` whatever its header declares."""
    written = 0
    with archive.open(member) as source, open(target, "wb") as out:
        while chunk := source.read(2**20):
            written += len(chunk)
            if written > MAX_METRIC_BYTES:
                raise ZooError(f"{member.filename}: inflates past {MAX_METRIC_BYTES} bytes")
            out.write(chunk)
