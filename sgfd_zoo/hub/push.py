"""``sgfd-zoo push-to-hub``: a finished run to a Hugging Face Hub repository (:mod:`sgfd_zoo.hub`'s files), or with
``--dry-run FOLDER`` exactly those files into a folder, uploading nothing.

rl-zoo3's own ``push_to_hub`` does not start with the pinned versions (it imports a name sb3-team-hf-integration 3.2
no longer has), and huggingface_sb3's ``package_to_hub`` writes a card that names no split and drops the video
where no ffmpeg is on the PATH. This command stages the files itself and uploads them with huggingface_hub's
``HfApi``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

import sgfd_envs
from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_at_least, command_parser
from sgfd_zoo.config_checks import first_line
from sgfd_zoo.hub import (
    ARGS,
    CARD,
    CONFIG,
    ENV_KWARGS,
    METRICS,
    RESULTS,
    VEC_NORMALIZE,
    VIDEO,
    model_file,
    repository_id,
)
from sgfd_zoo.runs.safe import redact_values
from sgfd_zoo.trained import TrainedAgent, find_agent, saved_settings

#: What of a run folder goes into ``train_eval_metrics.zip`` (rl-zoo3 puts its evaluations.npz and csv files there)
METRIC_FILES = ("evaluations.npz", "evaluations_*.npz", "*.monitor.csv", "progress*.csv")


def push_parser() -> ZooArgumentParser:
    """The options of ``sgfd-zoo push-to-hub``: rl-zoo3's push_to_hub's, and ``--dry-run``."""
    parser = command_parser("push-to-hub")
    parser.add_argument("--algo", default="sgfd_sac", metavar="ALGO", help="the run's algorithm (default: sgfd_sac)")
    parser.add_argument("--env", required=True, metavar="ENV_ID", help="the id it trained on")
    parser.add_argument("-f", "--folder", default="logs", help="the log folder (default: logs)")
    parser.add_argument("--exp-id", type=int, default=0, metavar="ID", help="the run <EnvName>_<ID> (0: the newest)")
    parser.add_argument("-orga", "--organization", help="the Hub user or organization the repository belongs to")
    parser.add_argument("-name", "--repo-name", help="the repository's name (default: <algo>-<EnvName>)")
    parser.add_argument("-m", "--commit-message", default="Upload a run of sgfd-zoo", help="the commit's message")
    parser.add_argument("--n-episodes", type=int, default=10, metavar="N", help="evaluation episodes per split")
    parser.add_argument("--seed", type=int, default=0, help="the evaluation's and the video's seed (default: 0)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=1000, metavar="STEPS", help="the video's length")
    parser.add_argument("--video-split", metavar="SPLIT", help="the video's split (default: the last unseen one)")
    parser.add_argument("--no-video", action="store_true", help="no replay.mp4")
    parser.add_argument("--device", default="auto", help="torch's device (default: auto)")
    parser.add_argument(
        "--dry-run",
        metavar="FOLDER",
        help="write the repository's files into FOLDER (new or empty) and upload nothing",
    )
    return parser


def main(argv: Sequence[str]) -> int:
    """``sgfd-zoo push-to-hub`` on ``argv`` (the command line after ``push-to-hub``)."""
    args = push_parser().parse_args(list(argv))
    check_at_least("--n-episodes", args.n_episodes, 1)
    check_at_least("-n", args.n_timesteps, 1)
    if args.organization is None and args.dry_run is None:
        raise ZooError(
            "-orga is required (the Hub user or organization), unless --dry-run FOLDER writes the files only"
        )
    from sgfd_zoo.registration import register_algorithms

    register_algorithms()
    agent = find_agent(_agent_arguments(args))
    repo_id = repository_id(args.organization or "ORGANIZATION", args.repo_name, model_file(agent.algo, _name(agent)))
    if args.dry_run is not None:
        folder = _empty_folder(Path(args.dry_run))
        with tempfile.TemporaryDirectory(prefix=".sgfd-zoo-hub-", dir=folder.parent) as staging:
            files = Path(staging) / "repository"
            files.mkdir()
            written = stage(agent, files, repo_id, args)
            folder.rmdir()
            os.replace(files, folder)  # whole or not at all
        print(f"push-to-hub --dry-run: {len(written)} files for {repo_id} in {folder}: {', '.join(written)}")
        return 0
    with tempfile.TemporaryDirectory(prefix="sgfd-zoo-hub-") as staging:
        stage(agent, Path(staging), repo_id, args)
        url = upload(Path(staging), repo_id, args.commit_message)
    print(f"Pushed {agent.run.path} to {url}")
    return 0


def _agent_arguments(args: argparse.Namespace) -> argparse.Namespace:
    """What :func:`~sgfd_zoo.trained.find_agent` reads: the final model of the chosen run, its own env settings."""
    chosen = {"algo": args.algo, "env": args.env, "folder": args.folder, "exp_id": args.exp_id}
    defaults = {"load_checkpoint": None, "load_last_checkpoint": False, "load_best": False, "norm_reward": False}
    return argparse.Namespace(**chosen, **defaults, env_kwargs=None, split=None, domain=None)


def _name(agent: TrainedAgent) -> str:
    return agent.run.config_dir.name


def _empty_folder(folder: Path) -> Path:
    """``folder``, made if missing; a ZooError when it holds anything (the dry run's files would mix with it) or is
    a symbolic link."""
    if folder.is_symlink() or (folder.exists() and (not folder.is_dir() or any(folder.iterdir()))):
        raise ZooError(f"--dry-run {folder}: expected a new or empty folder (it would mix the files with others)")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def stage(agent: TrainedAgent, folder: Path, repo_id: str, args: argparse.Namespace) -> list[str]:
    """Write the repository's files for ``agent`` into ``folder``; returns their names, sorted.

    :param agent: the run's final model and settings
    :param folder: an empty folder
    :param repo_id: ``<organization>/<name>``, for the card's commands
    :param args: the command's options (episodes, seed, video)
    """
    from rl_zoo3.utils import ALGOS

    from sgfd_zoo.hub.card import evaluation_results, model_card
    from sgfd_zoo.report.evaluate import evaluate_run

    run = agent.run
    shutil.copyfile(agent.model_path, folder / model_file(agent.algo, _name(agent)))
    config = saved_settings(run.config_dir / CONFIG, required=True)
    _write_yaml(folder / CONFIG, config)
    _write_yaml(folder / ARGS, _shared_args(saved_settings(run.config_dir / ARGS, required=False)))
    _write_yaml(folder / ENV_KWARGS, agent.env_kwargs)
    if (run.config_dir / "vecnormalize.pkl").is_file():
        shutil.copyfile(run.config_dir / "vecnormalize.pkl", folder / VEC_NORMALIZE)
    _write_metrics(run.path, folder / METRICS)
    rows = evaluate_run(run, args.n_episodes, args.seed)
    results = evaluation_results(rows, agent.env_kwargs, args.n_episodes)
    (folder / RESULTS).write_text(json.dumps(results, indent=1) + "\n")
    if not args.no_video:
        _write_video(agent, folder / VIDEO, args)
    card = model_card(agent.algo, ALGOS[agent.algo].__name__, agent.env_id, repo_id, results, config, agent.env_kwargs)
    (folder / CARD).write_text(card)
    return sorted(path.name for path in folder.iterdir())


def _write_yaml(path: Path, data: dict[str, Any]) -> None:
    path.write_text(yaml.dump(redact_values(dict(data))))


def _shared_args(args: dict[str, Any]) -> dict[str, Any]:
    """rl-zoo3's ``args.yml`` as it is shared: no URL's credentials (:func:`_write_yaml`), its log folder's name."""
    if isinstance(args.get("log_folder"), str):
        args = {**args, "log_folder": Path(args["log_folder"]).name}
    return args


def _write_metrics(run: Path, archive_path: Path) -> None:
    """``train_eval_metrics.zip``: the run's :data:`METRIC_FILES` (plain files only: a link is not followed)."""
    with zipfile.ZipFile(archive_path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for pattern in METRIC_FILES:
            for path in sorted(run.glob(pattern)):
                if path.is_file() and not path.is_symlink():
                    archive.write(path, arcname=path.name)


def _write_video(agent: TrainedAgent, path: Path, args: argparse.Namespace) -> None:
    """``replay.mp4``: the agent on ``--video-split`` (default: the last unseen split), domain 0."""
    from sgfd_zoo.video import record_video

    split = args.video_split or sgfd_envs.test_splits(agent.env_id)[-1]
    if split not in sgfd_envs.splits(agent.env_id):
        raise ZooError(
            f"--video-split {split}: {agent.env_id} has the splits {', '.join(sgfd_envs.splits(agent.env_id))}"
        )
    played = TrainedAgent(agent.run, agent.model_path, agent.hyperparams, {**agent.env_kwargs, "split": split})
    record_video(played, path, args.n_timesteps, seed=args.seed, device=args.device)


def upload(folder: Path, repo_id: str, message: str) -> str:
    """``folder``'s files into the Hub repository ``repo_id`` (made if missing) in one commit; its URL."""
    from huggingface_hub import HfApi

    api = HfApi()
    try:
        url = api.create_repo(repo_id=repo_id, exist_ok=True)
        api.upload_folder(repo_id=repo_id, folder_path=folder, commit_message=message)
    except Exception as error:  # huggingface_hub's errors: no token, no network, no right to the repository
        raise ZooError(f"the Hub refused or did not answer ({type(error).__name__}: {first_line(error)})") from None
    return str(url)
