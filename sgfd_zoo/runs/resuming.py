"""Where a run starts from: the run ``--resume`` continues and the checkpoint it continues from, a run folder
started again from step 0, and a checkpoint loaded into a model. Each function is one decision of
:class:`sgfd_zoo.experiment.SGFDExperimentManager`; the caller holds the run's lock (:mod:`sgfd_zoo.runs.locks`)
before it changes anything in the folder."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sgfd_envs.families import env_kwargs_as_trained
from sgfd_zoo.arguments import ZooError
from sgfd_zoo.config_checks import first_line
from sgfd_zoo.runs import training_state
from sgfd_zoo.runs.checkpoint_callback import CHECKPOINT_PARTS
from sgfd_zoo.runs.checkpoints import (
    CHECKPOINT_INDEX,
    KEPT_CHECKPOINTS,
    Checkpoint,
    describe_checkpoint,
    read_index,
    remove_checkpoint_files,
    write_index,
)
from sgfd_zoo.runs.files import UnreadableFile
from sgfd_zoo.runs.folders import NoUsableCheckpoint, RunFolder, runs_by_id


def run_to_resume(log_folder: Path, algo: str, env_id: str, run_path: Path | None) -> RunFolder:
    """The run ``--resume`` continues: ``run_path`` (``--run-id``), else the newest run of ``algo`` on ``env_id``
    that has a checkpoint; a ZooError when there is none.

    :param log_folder: the log folder (``-f``)
    :param algo: algorithm key
    :param env_id: env id
    :param run_path: the run folder ``--run-id`` names, or None
    """
    runs = [RunFolder(run_path)] if run_path is not None else list(runs_by_id(log_folder, algo, env_id).values())
    runs = [run for run in runs if run.checkpoints()]
    if not runs:
        raise ZooError(
            f"--resume: no checkpoint of {algo} on {env_id} under {Path(log_folder) / algo} "
            "(checkpoints are written every --save-freq steps)"
        )
    return runs[-1]


def choose_checkpoint(run: RunFolder, restart_command: str) -> Checkpoint:
    """The newest checkpoint of ``run`` that verifies, warning in one line about newer ones that do not (and an
    unreadable index); a :class:`NoUsableCheckpoint` naming each problem when none does.

    :param run: the run folder
    :param restart_command: the command that starts the run again from step 0
    """
    checkpoint, problems = run.usable_checkpoint()
    try:
        read_index(run.path)
    except UnreadableFile as error:
        problems = [str(error), *problems]
    if checkpoint is None:
        raise NoUsableCheckpoint(
            f"--resume: no usable checkpoint in {run.path}: {'; '.join(problems)}; start the run again with: "
            f"{restart_command}"
        )
    if problems:
        print(
            f"warning: {'; '.join(problems)}: resuming from the checkpoint at {checkpoint.num_timesteps} steps",
            file=sys.stderr,
        )
    return checkpoint


def envs_as_trained(run: RunFolder, env_id: str, *env_kwargs: dict[str, Any]) -> list[dict[str, Any]]:
    """The env kwargs (of training, of evaluation) a resumed run goes on with: those given, and for a run recorded
    before the SGFD ids' families of envs (no ``env_family`` in its readable ``args.yml``), the family it trained on
    where they name none (:func:`sgfd_envs.families.env_kwargs_as_trained`).

    :param run: the run folder
    :param env_id: its id
    :param env_kwargs: the env kwargs given, each
    """
    if not run.args or "env_family" in run.args:
        return [dict(kwargs) for kwargs in env_kwargs]
    return [env_kwargs_as_trained(env_id, kwargs, None) for kwargs in env_kwargs]


def prepare_restart(run: RunFolder, resume_command: str) -> None:
    """Before a run starts from step 0 in an existing folder (``--run-id``): refuse a finished run or one with a
    usable checkpoint; delete checkpoints that are unusable (the message of ``--resume`` says it starts again).

    :param run: the run folder
    :param resume_command: the command that continues it from its checkpoint
    """
    if run.finished:
        raise ZooError(f"--run-id {run.run_id}: {run.path} is a finished run; choose another --run-id")
    if not run.checkpoints():
        return
    checkpoint, problems = run.usable_checkpoint()
    if checkpoint is not None:
        raise ZooError(
            f"--run-id {run.run_id}: {run.path} has a checkpoint at {checkpoint.num_timesteps} steps; continue "
            f"it with: {resume_command} (or delete the folder to start it again)"
        )
    removed = remove_checkpoint_files(run.path, [])
    (run.path / CHECKPOINT_INDEX).unlink(missing_ok=True)
    print(
        f"Starting {run.path} again from step 0: no checkpoint of it is usable ({'; '.join(problems)}); "
        f"removed {', '.join([*removed, CHECKPOINT_INDEX])}",
        file=sys.stderr,
    )


def load_checkpoint(
    algo_class: type[BaseAlgorithm], run: RunFolder, checkpoint: Checkpoint, env: VecEnv, **load_kwargs: Any
) -> tuple[BaseAlgorithm, dict[str, Any] | None]:
    """The model of ``checkpoint`` with the parts it saved, and its training state (None when it has none); the
    index then lists it (and what is older) and nothing else: the unusable newer checkpoints and what
    interrupted saves left are deleted. A checkpoint that verifies but does not load is a one-line ZooError.

    :param algo_class: the algorithm
    :param run: the run folder
    :param checkpoint: a checkpoint of it that verifies
    :param env: the env to load it on (closed when it does not load)
    :param load_kwargs: for ``algo_class.load``
    """
    exact = "training_state" in checkpoint.files
    state = None
    try:
        # Read first: it is data (the model and the buffer are SB3's pickles, trusted as the run's own), and put
        # back when the resumed training starts, after everything that builds the run.
        if exact:
            state = training_state.load(run.path / checkpoint.files["training_state"].name)
        # with the envs' state restored, the checkpoint's last observation is the envs' own
        model = algo_class.load(
            run.path / checkpoint.files["model"].name, env=env, force_reset=not exact, **load_kwargs
        )
        for part in CHECKPOINT_PARTS:
            if part.restore is not None and part.name in checkpoint.files:
                part.restore(model, str(run.path / checkpoint.files[part.name].name))
    except Exception as error:
        env.close()
        raise ZooError(
            f"--resume: {run.path / checkpoint.files['model'].name} (the checkpoint at {checkpoint.num_timesteps} "
            f"steps) passes its checks but does not load ({type(error).__name__}: {first_line(error)}); if "
            "another version of the code wrote it, resume with that version, or delete the folder to start again"
        ) from error
    older = [c for c in run.checkpoints() if c.num_timesteps < checkpoint.num_timesteps]
    kept = [describe_checkpoint(run.path, checkpoint), *older][:KEPT_CHECKPOINTS]
    write_index(run.path, kept)
    remove_checkpoint_files(run.path, kept)
    print(f"Resuming {run.path} from {model.num_timesteps} steps")
    return model, state
