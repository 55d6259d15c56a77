"""rl-zoo3's ExperimentManager, taught to train on SGFD's multi-domain envs, to stop at a checkpoint and to
resume from one."""

from __future__ import annotations

import contextlib
import difflib
import errno
import inspect
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import optuna
import rl_zoo3.exp_manager
from gymnasium import spaces
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER, convert_offpolicy_params
from rl_zoo3.utils import ALGOS, get_class_by_name
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import ProgressBarCallback
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.torch_layers import FlattenExtractor, NatureCNN
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import SGFD_SAC
from sb3_sgfd.common.policies import MlpEncoder, PixelEncoder
from sb3_sgfd.common.representation import REPRESENTATIONS
from sb3_sgfd.common.validation import RefusedTransition
from sgfd_envs.backgrounds import overlay_bank
from sgfd_zoo import provenance, training_state
from sgfd_zoo.algos import SGFD_ALGOS, classifier_start_warning, is_sgfd
from sgfd_zoo.arguments import TrainingStopped, ZooError, check_keywords, train_command
from sgfd_zoo.callbacks import (
    CHECKPOINT_PARTS,
    CSVLogCallback,
    MultiSplitEvalCallback,
    ProgressCallback,
    ResumableCheckpointCallback,
    StopRequest,
    interrupts_deferred,
)
from sgfd_zoo.runs import (
    CHECKPOINT_INDEX,
    KEPT_CHECKPOINTS,
    Checkpoint,
    FileWriteError,
    NoUsableCheckpoint,
    RunFolder,
    UnreadableFile,
    atomic_write,
    describe_checkpoint,
    mark_finished,
    read_index,
    remove_checkpoint_files,
    runs_by_id,
    write_failure,
    write_index,
    write_json,
)
from sgfd_zoo.training_state import RestoreTrainingState

HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"
# Keys rl-zoo3 consumes itself before the rest goes to the algorithm's constructor.
ZOO_KEYS = {
    "n_timesteps",
    "n_envs",
    "env_kwargs",
    "frame_stack",
    "normalize",
    "env_wrapper",
    "vec_env_wrapper",
    "callback",
    "monitor_kwargs",
    "noise_type",
    "noise_std",
}
# Hyperparameters that hold keyword arguments; a string is a Python expression, as rl-zoo3 reads policy_kwargs.
KWARGS_KEYS = ("policy_kwargs", "replay_buffer_kwargs", "representation_kwargs")
# What SB3 passes a replay buffer itself, besides replay_buffer_kwargs.
BUFFER_ARGUMENTS = {"buffer_size", "observation_space", "action_space", "device", "n_envs", "optimize_memory_usage"}
# Errors of a write that a full disk (or quota, or file size limit) causes.
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def hyperparams_file(algo: str, quick: bool = False) -> Path:
    """The zoo's yaml for ``algo``: paper scale, or the quick configuration for a laptop-size run."""
    if algo not in SGFD_ALGOS:
        return HYPERPARAMS_DIR / ("quick" if quick else "") / f"{algo}.yml"
    entry = SGFD_ALGOS[algo]
    if quick:
        return HYPERPARAMS_DIR / "quick" / f"{entry.quick_hyperparams or entry.hyperparams}.yml"
    return HYPERPARAMS_DIR / f"{entry.hyperparams}.yml"


def sample_sgfd_sac_params(
    trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]
) -> dict[str, Any]:
    """SAC's search space (as rl-zoo3 samples it) plus SGFD's classifier and weight-solver settings."""
    sampled = {
        "one_minus_gamma": trial.suggest_float("one_minus_gamma", 0.0001, 0.03, log=True),
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 3e-3, log=True),
        "batch_size_pow": trial.suggest_int("batch_size_pow", 6, 9),
        "tau": trial.suggest_float("tau", 0.002, 0.05, log=True),
        "net_arch": trial.suggest_categorical("net_arch", ["medium", "big"]),
        "accuracy_threshold": trial.suggest_float("accuracy_threshold", 0.7, 0.98),
        "n_rff": trial.suggest_int("n_rff", 1, 10),
        "reweight_iters": trial.suggest_int("reweight_iters", 5, 30),
        "reweight_lr": trial.suggest_float("reweight_lr", 1e-2, 10.0, log=True),
        "saliency_temperature": trial.suggest_float("saliency_temperature", 0.05, 2.0, log=True),
        "saliency_smoothing": trial.suggest_float("saliency_smoothing", 0.0, 0.7),
    }
    return convert_sgfd_sac_params(sampled)


def convert_sgfd_sac_params(sampled_params: dict[str, Any]) -> dict[str, Any]:
    """Turn Optuna's sampled values into SGFD_SAC arguments (also used to load a stored trial)."""
    return convert_offpolicy_params(sampled_params)


def register_algorithms() -> None:
    """Add SGFD's keys to rl-zoo3's tables; idempotent. The other agents take rl-zoo3's SAC search space."""
    for key, algo in SGFD_ALGOS.items():
        ALGOS[key] = algo.algo_class
        if algo.algo_class is SGFD_SAC:
            HYPERPARAMS_SAMPLER[key] = sample_sgfd_sac_params
            HYPERPARAMS_CONVERTER[key] = convert_sgfd_sac_params
        elif key != "sac":
            HYPERPARAMS_SAMPLER[key] = HYPERPARAMS_SAMPLER["sac"]
            HYPERPARAMS_CONVERTER[key] = HYPERPARAMS_CONVERTER["sac"]


#: The most env steps between two checkpoints when ``--save-freq`` is not given.
LONGEST_CHECKPOINT_INTERVAL = 100_000
#: Without ``--save-freq``, a run checkpoints at least this many times: a kill costs at most 1/5 of a short run.
CHECKPOINTS_PER_RUN = 5


def default_checkpoint_interval(n_timesteps: int) -> int:
    """Env steps between checkpoints when ``--save-freq`` is not given: a fifth of the run, at most 100k steps
    (a paper-scale pixel checkpoint writes a 10.6 GB buffer)."""
    return max(min(LONGEST_CHECKPOINT_INTERVAL, n_timesteps // CHECKPOINTS_PER_RUN), 1)


class SGFDExperimentManager(ExperimentManager):
    """
    rl-zoo3's ExperimentManager with SGFD's conventions:

    - hyperparameters from ``sgfd_zoo/hyperparams/<algo>.yml`` unless ``-conf`` names another file;
    - the training VecEnv has one sub-env per training domain (``n_envs`` defaults to their number);
    - evaluation envs get the same env kwargs as training (rl-zoo3 drops yaml ``env_kwargs`` there),
      and evaluation covers every split: training domains and the unseen ones;
    - checkpoints (model + replay buffer) every ``save_freq`` steps, each file written whole and checked
      (:class:`~sgfd_zoo.callbacks.ResumableCheckpointCallback`); ``resume=True`` continues the newest run of this
      algo and env from its newest checkpoint that verifies, the one before when the newest does not;
    - Ctrl-C stops training at a checkpoint and a full disk stops it cleanly: a :class:`TrainingStopped`
      says how to continue, and the run is not finished; the final model is followed by ``finished.json``;
    - a progress bar by default when the output is a terminal, and progress reports to ``progress_reporter``;
    - a policy that cannot read the observations, and unknown keys in the kwargs hyperparameters (policy,
      features extractor, representation, replay buffer), are refused in one line, naming what fits, before
      anything is built.

    Takes rl-zoo3's arguments, plus:

    :param quick: Use the quick configuration (``sgfd_zoo/hyperparams/quick``) when no ``-conf`` is given
    :param resume: Continue the newest run from its last checkpoint instead of starting a new one
    :param progress: Show a progress bar; None: when stdout is a terminal
    :param run_id: Write to (and resume) the run folder ``<EnvName>_<run_id>``; None: rl-zoo3's newest id + 1
    :param progress_reporter: Called every few seconds with a dict of the run's progress (``sgfd-zoo sweep``)
    :param check_only: Only check the configuration: ``setup_experiment`` builds the model on the env with a
        tiny replay buffer, writes nothing and returns no model
    :param command: The ``sgfd-zoo train`` flags of this run, to print the command that continues it
    :param default_save_freq: No ``--save-freq`` was given: checkpoint every :func:`default_checkpoint_interval`
        steps of this run
    :param classifier_start: ``classifier_start`` of an SGFD algorithm (``--classifier-start``); the others have
        no classifier and ignore it, so that a sweep may mix them
    """

    def __init__(
        self,
        *args: Any,
        quick: bool = False,
        resume: bool = False,
        progress: bool | None = None,
        run_id: int | None = None,
        progress_reporter: Callable[[dict[str, Any]], None] | None = None,
        check_only: bool = False,
        command: Sequence[str] | None = None,
        default_save_freq: bool = False,
        classifier_start: int | None = None,
        **kwargs,
    ):
        algo = args[1] if len(args) > 1 else kwargs["algo"]
        if not kwargs.get("config"):
            kwargs["config"] = str(hyperparams_file(algo, quick))
        if progress is None:
            progress = kwargs.get("show_progress") or sys.stdout.isatty()
        kwargs["show_progress"] = progress
        super().__init__(*args, **kwargs)
        if run_id is not None:
            # Runs started together (sgfd-zoo sweep) would race for rl-zoo3's "newest id + 1".
            self.save_path = str(Path(self.log_path) / f"{self.env_name}_{run_id}")
            self.params_path = f"{self.save_path}/{self.env_name}"
        self.run_id = run_id
        self.progress_reporter = progress_reporter
        self.check_only = check_only
        self.resume = resume
        self.command = None if command is None else list(command)
        self.default_save_freq = default_save_freq
        self.classifier_start = classifier_start
        self.stop = StopRequest()
        self.checkpoint: Checkpoint | None = None
        self.checkpointer: ResumableCheckpointCallback | None = None
        self.training_state: dict[str, Any] | None = None
        if resume and not check_only:
            self._point_at_run_to_resume()

    def train_command(self, resume: bool) -> str:
        """The command that continues this run from its checkpoint (``resume``) or starts it again."""
        run = RunFolder.parse(Path(self.save_path))
        argv = self.command
        if argv is None:
            argv = ["--algo", self.algo, "--env", self.env_name.gym_id, "-f", self.log_folder, "--seed", str(self.seed)]
        return train_command(argv, None if run is None else run.run_id, resume)

    # -- configuration ---------------------------------------------------------------------------

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        hyperparams, saved = super().read_hyperparameters()
        if self.algo in SGFD_ALGOS:
            # The ablations are the SGFD entries with one part switched off; the saved config shows it.
            overrides = {**SGFD_ALGOS[self.algo].overrides, **(self.custom_hyperparams or {})}
            if self.classifier_start is not None and is_sgfd(self.algo):
                if "classifier_start" in (self.custom_hyperparams or {}):
                    raise ZooError("--classifier-start and --hyperparams classifier_start:... both set; give one")
                overrides["classifier_start"] = self.classifier_start
            hyperparams.update(overrides)
            saved.update(overrides)
        return hyperparams, saved

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]):
        explicit_n_envs = "n_envs" in hyperparams
        for key in KWARGS_KEYS:
            if key in hyperparams:
                hyperparams[key] = kwargs_value(key, hyperparams[key])
        # rl-zoo3 eval()s a string replay_buffer_class; a dotted path names a class to import instead.
        if isinstance(hyperparams.get("replay_buffer_class"), str) and "." in hyperparams["replay_buffer_class"]:
            hyperparams["replay_buffer_class"] = get_class_by_name(hyperparams["replay_buffer_class"])
        processed, env_wrapper, callbacks, vec_env_wrapper = super()._preprocess_hyperparams(hyperparams)
        if self._eval_env_kwargs_args is None:
            self.eval_env_kwargs = dict(self.env_kwargs)
        if not explicit_n_envs:
            with env_kwargs_checked(self.env_kwargs):
                self.n_envs = sgfd_envs.n_domains(self.env_name.gym_id, "train", **self.env_kwargs)
        check_algo_kwargs(self.algo, processed)
        check_policy_fits(self.algo, processed, observes_pixels(self.env_kwargs))
        check_nested_kwargs(self.algo, processed)
        self._add_overlay_images(processed)
        # After the checks: a configuration that is refused gets its one line only.
        warning = classifier_start_warning(self.algo, processed, self.n_timesteps)
        if warning is not None:
            print(f"warning: {warning}", file=sys.stderr)
        return processed, env_wrapper, callbacks, vec_env_wrapper

    def _add_overlay_images(self, hyperparams: dict[str, Any]) -> None:
        """SGQN's overlay images, unless the yaml names some: sgfd_envs' procedural overlay bank."""
        representation = hyperparams.get("representation", getattr(ALGOS[self.algo], "fixed_representation", None))
        kwargs = dict(hyperparams.get("representation_kwargs") or {})
        if representation != "sgqn" or "overlay_images" in kwargs or "overlay_dir" in kwargs:
            return
        size = self.env_kwargs.get("image_size", 84)
        kwargs["overlay_images"] = overlay_bank(size, size)
        hyperparams["representation_kwargs"] = kwargs

    # -- environments ----------------------------------------------------------------------------

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        # rl-zoo3 asks for an eval env only on its Optuna path: score trials on every training domain.
        return self.create_split_env("train", n_envs=None if eval_env else n_envs, eval_env=eval_env)

    def create_split_env(self, split: str, n_envs: int | None = None, eval_env: bool = True) -> VecEnv:
        """A VecEnv over the domains of ``split``, wrapped the way training wraps it (frame stack, transpose)."""
        env_kwargs = self.eval_env_kwargs if eval_env else self.env_kwargs
        with env_kwargs_checked(env_kwargs):
            env = sgfd_envs.make_domain_vec_env(
                self.env_name.gym_id,
                split=split,
                n_envs=n_envs,
                seed=self.seed + (10_000 if eval_env else 0),
                vec_env_cls=self.vec_env_class,
                **env_kwargs,
            )
        return wrap_like_training(env, self.frame_stack, self._maybe_normalize if self.normalize else None, eval_env)

    # -- callbacks -------------------------------------------------------------------------------

    def create_callbacks(self) -> None:
        if self.show_progress:
            self.callbacks.append(ProgressBarCallback())
        log_name = "progress.csv" if self.checkpoint is None else f"progress_from_{self.checkpoint.num_timesteps}.csv"
        self.callbacks.append(CSVLogCallback(Path(self.save_path) / log_name))
        if self.default_save_freq:
            self.save_freq = default_checkpoint_interval(self.n_timesteps)
        # Always there: with --save-freq <= 0 it still saves the checkpoint a Ctrl-C stops at.
        save_freq = max(self.save_freq // self.n_envs, 1) if self.save_freq > 0 else None
        self.checkpointer = ResumableCheckpointCallback(save_freq, self.save_path, self.stop, verbose=self.verbose)
        self.callbacks.append(self.checkpointer)
        if self.eval_freq > 0 and not self.optimize_hyperparameters:
            splits = sgfd_envs.splits(self.env_name.gym_id)
            self.callbacks.append(
                MultiSplitEvalCallback(
                    {split: self.create_split_env(split) for split in splits},
                    eval_freq=max(self.eval_freq // self.n_envs, 1),
                    n_eval_episodes=self.n_eval_episodes,
                    log_path=self.save_path,
                    deterministic=self.deterministic_eval,
                    verbose=self.verbose,
                )
            )
        if self.progress_reporter is not None:
            evaluation = next((c for c in self.callbacks if isinstance(c, MultiSplitEvalCallback)), None)
            latest = None if evaluation is None else evaluation.latest_returns
            progress = ProgressCallback(self.progress_reporter, self.n_timesteps, latest)
            if evaluation is not None:
                evaluation.on_split = progress.evaluating
            self.callbacks.append(progress)
        if self.training_state is not None:  # last: after every other callback has started
            self.callbacks.append(RestoreTrainingState(self.training_state))

    # -- setting up, resuming -------------------------------------------------------------------

    def _point_at_run_to_resume(self) -> None:
        if self.run_id is not None:
            runs = [RunFolder(Path(self.save_path))]
        else:
            runs = list(runs_by_id(Path(self.log_path).parent, self.algo, self.env_name.gym_id).values())
        runs = [run for run in runs if run.checkpoints()]
        if not runs:
            raise ZooError(
                f"--resume: no checkpoint of {self.algo} on {self.env_name.gym_id} under {self.log_path} "
                "(checkpoints are written every --save-freq steps)"
            )
        run = runs[-1]
        self.save_path = str(run.path)
        self.params_path = str(run.config_dir)
        checkpoint, problems = run.usable_checkpoint()
        try:
            read_index(run.path)
        except UnreadableFile as error:
            problems = [str(error), *problems]
        if checkpoint is None:
            raise NoUsableCheckpoint(
                f"--resume: no usable checkpoint in {run.path}: {'; '.join(problems)}; start the run again with: "
                f"{self.train_command(resume=False)}"
            )
        if problems:
            print(
                f"warning: {'; '.join(problems)}: resuming from the checkpoint at {checkpoint.num_timesteps} steps",
                file=sys.stderr,
            )
        self.checkpoint = checkpoint

    def setup_experiment(self):
        if self.check_only:
            return self._check_configuration()
        if self.optimize_hyperparameters or self.continue_training:
            return super().setup_experiment()
        # rl-zoo3's steps in another order: the model (or the checkpoint) first, so that a configuration that
        # does not build leaves no run folder behind.
        unprocessed, saved_hyperparams = self.read_hyperparameters()
        hyperparams, self.env_wrapper, self.callbacks, self.vec_env_wrapper = self._preprocess_hyperparams(unprocessed)
        if self.checkpoint is None:
            self._claim_run_folder()
        env = self.create_envs(self.n_envs)
        self._hyperparams = self._preprocess_action_noise(hyperparams, saved_hyperparams, env)
        model = self._build_model(env, self._hyperparams) if self.checkpoint is None else self._load_checkpoint(env)
        self.create_log_folder()
        self.create_callbacks()
        self._save_config(saved_hyperparams)
        return model, saved_hyperparams

    def _save_config(self, saved_hyperparams: dict[str, Any]) -> None:
        super()._save_config(saved_hyperparams)
        if self.command is not None:  # what `sgfd-zoo evaluate` prints to continue an unfinished run
            write_json(RunFolder(Path(self.save_path)).command_file, self.command)
        # Appended, not replaced: a resumed run's later steps may come from other code.
        versions = RunFolder(Path(self.save_path)).versions_file
        start = 0 if self.checkpoint is None else self.checkpoint.num_timesteps
        block = f"=== from step {start}, {time.strftime('%Y-%m-%d %H:%M:%S')}\n{provenance.versions()}"
        earlier = versions.read_text() if versions.exists() else ""
        atomic_write(versions, lambda tmp: Path(tmp).write_text(earlier + block))

    def _check_configuration(self) -> tuple[None, dict[str, Any]]:
        """The configuration read, checked and built into a model on the env with a tiny replay buffer: what
        fails here fails once (the sweep checks every configuration before it starts any run)."""
        unprocessed, saved_hyperparams = self.read_hyperparameters()
        hyperparams = self._preprocess_hyperparams(unprocessed)[0]
        env = self.create_envs(self.n_envs)
        try:
            hyperparams = self._preprocess_action_noise(hyperparams, saved_hyperparams, env)
            model = self._build_model(env, {**hyperparams, "buffer_size": 64 * self.n_envs})
            del model
        finally:
            env.close()
        return None, saved_hyperparams

    def _build_model(self, env: VecEnv, hyperparams: dict[str, Any]) -> BaseAlgorithm:
        try:
            return ALGOS[self.algo](
                env=env,
                tensorboard_log=self.tensorboard_log,
                seed=self.seed,
                verbose=self.verbose,
                device=self.device,
                **hyperparams,
            )
        except (TypeError, ValueError) as error:
            env.close()
            raise ZooError(
                f"{self.algo} on {self.env_name.gym_id} cannot be built from this configuration: "
                f"{type(error).__name__}: {_first_line(error)}"
            ) from error

    def _claim_run_folder(self) -> None:
        """Refuse to start afresh over a finished run or a usable checkpoint; discard checkpoints that are
        unusable (the run starts again from step 0 there, as the message of ``--resume`` says)."""
        run = RunFolder.parse(Path(self.save_path))
        if run is None or not run.path.exists():
            return
        if run.finished:
            raise ZooError(f"--run-id {run.run_id}: {run.path} is a finished run; choose another --run-id")
        if not run.checkpoints():
            return
        checkpoint, problems = run.usable_checkpoint()
        if checkpoint is not None:
            raise ZooError(
                f"--run-id {run.run_id}: {run.path} has a checkpoint at {checkpoint.num_timesteps} steps; continue "
                f"it with: {self.train_command(resume=True)} (or delete the folder to start it again)"
            )
        removed = remove_checkpoint_files(run.path, [])
        (run.path / CHECKPOINT_INDEX).unlink(missing_ok=True)
        print(
            f"Starting {run.path} again from step 0: no checkpoint of it is usable ({'; '.join(problems)}); "
            f"removed {', '.join([*removed, CHECKPOINT_INDEX])}",
            file=sys.stderr,
        )

    def _load_checkpoint(self, env: VecEnv) -> BaseAlgorithm:
        """The model of ``self.checkpoint`` with the parts it saved; the index then lists it (and what is older)
        and nothing else: the unusable newer checkpoints and what interrupted saves left are deleted."""
        run = RunFolder(Path(self.save_path))
        checkpoint = self.checkpoint
        assert checkpoint is not None
        exact = "training_state" in checkpoint.files
        try:
            model = ALGOS[self.algo].load(
                run.path / checkpoint.files["model"].name,
                env=env,
                tensorboard_log=self.tensorboard_log,
                verbose=self.verbose,
                device=self.device,
                # with the envs' state restored, the checkpoint's last observation is the envs' own
                force_reset=not exact,
            )
            for part in CHECKPOINT_PARTS:
                if part.restore is not None and part.name in checkpoint.files:
                    part.restore(model, str(run.path / checkpoint.files[part.name].name))
            if exact:  # put back when the resumed training starts, after everything that builds the run
                self.training_state = training_state.load(run.path / checkpoint.files["training_state"].name)
        except Exception as error:
            env.close()
            raise ZooError(
                f"--resume: {run.path / checkpoint.files['model'].name} (the checkpoint at {checkpoint.num_timesteps} "
                f"steps) passes its checks but does not load ({type(error).__name__}: {_first_line(error)}); if "
                "another version of the code wrote it, resume with that version, or delete the folder to start again"
            ) from error
        older = [c for c in run.checkpoints() if c.num_timesteps < checkpoint.num_timesteps]
        kept = [describe_checkpoint(run.path, checkpoint), *older][:KEPT_CHECKPOINTS]
        write_index(run.path, kept)
        remove_checkpoint_files(run.path, kept)
        print(f"Resuming {run.path} from {model.num_timesteps} steps")
        return model

    # -- training and its end ----------------------------------------------------------------------

    def _warn_if_inexact(self, model: BaseAlgorithm) -> None:
        reason = training_state.unavailable(model)
        if reason is not None:
            print(
                f"warning: this run's checkpoints hold no env state ({reason}): a resume continues from the model, "
                "replay buffer and optimisers with the envs started afresh, not bit for bit",
                file=sys.stderr,
            )

    def learn(self, model: BaseAlgorithm) -> None:
        """Train to ``n_timesteps`` (the rest of them when resumed). Ctrl-C stops at a checkpoint, a full disk
        stops cleanly; either raises :class:`TrainingStopped`, so that no final model is saved."""
        remaining = self.n_timesteps - (model.num_timesteps if self.checkpoint is not None else 0)
        if remaining <= 0:
            print(f"Nothing to resume: the checkpoint already has {model.num_timesteps} of {self.n_timesteps} steps")
            return None
        self._warn_if_inexact(model)
        kwargs: dict[str, Any] = {"reset_num_timesteps": self.checkpoint is None}
        if self.log_interval > -1:
            kwargs["log_interval"] = self.log_interval
        elif self.log_interval < -1:
            kwargs["log_interval"] = None
        if self.callbacks:
            kwargs["callback"] = self.callbacks
        try:
            with interrupts_deferred(self.stop):
                model.learn(remaining, **kwargs)
        except KeyboardInterrupt:
            raise TrainingStopped(
                f"Ctrl-C twice: stopped at once at {model.num_timesteps} steps, {self._kept()}; the run is not "
                f"finished; {self._next_command()}",
                exit_code=130,
            ) from None
        except RefusedTransition as error:
            # Nothing of the bad step was stored; the newest checkpoint is from before it.
            raise TrainingStopped(
                f"{error}; training stopped at {model.num_timesteps} steps; {self._kept()}; the run is not "
                f"finished; once the env is fixed, {self._next_command()}"
            ) from None
        except (FileWriteError, OSError) as error:
            if not isinstance(error, FileWriteError) and error.errno not in NO_ROOM:
                raise
            if not isinstance(error, FileWriteError):  # a log file, say
                path = Path(error.filename) if error.filename else Path(self.save_path) / "(a log file)"
                error = FileWriteError(path, error.strerror or str(error), error)
            what = f"{error.path.name} (at {model.num_timesteps} steps)"
            raise TrainingStopped(
                f"{write_failure(what, error.path.parent, error, None, self._kept())}; free space, then "
                f"{self._next_command()}"
            ) from None
        finally:
            if model.env is not None:
                model.env.close()
        assert self.checkpointer is not None
        if self.checkpointer.failure is not None:
            raise TrainingStopped(f"{self.checkpointer.failure}; free space, then {self._next_command()}")
        # The checkpointer stops between two env steps; the step SB3 took after it is dropped, not trained on.
        stopped_at = self.checkpointer.stopped if self.checkpointer.stopped is not None else model.num_timesteps
        if self.stop and stopped_at < self.n_timesteps:
            raise TrainingStopped(
                f"{self.stop.reason} at {stopped_at} steps: {self._kept()}; the run is not finished; "
                f"{self._next_command()}",
                exit_code=130,
            )
        return None

    def _next_command(self) -> str:
        """What goes on with the run: ``--resume`` from its newest checkpoint, or, without one, the same flags."""
        if self.checkpointer is not None and self.checkpointer.newest() is not None:
            return f"continue it with: {self.train_command(resume=True)}"
        return f"start it again with: {self.train_command(resume=False)}"

    def _kept(self) -> str:
        newest = self.checkpointer.newest() if self.checkpointer is not None else None
        if newest is None:
            return f"no checkpoint in {self.save_path}"
        return f"its checkpoint at {newest.num_timesteps} steps is in {self.save_path}"

    def save_trained_model(self, model: BaseAlgorithm) -> None:
        """rl-zoo3's files of a trained agent, each written whole, the model last, then ``finished.json``."""
        if self.optimize_hyperparameters:
            return super().save_trained_model(model)
        folder = Path(self.save_path)
        print(f"Saving to {folder}")
        newest = self.checkpointer.newest() if self.checkpointer is not None else None
        # A Ctrl-C now waits for the end of the save: the run is then finished.
        with interrupts_deferred(StopRequest()):
            try:
                if hasattr(model, "save_replay_buffer") and self.save_replay_buffer:
                    atomic_write(folder / "replay_buffer.pkl", model.save_replay_buffer)
                if self.normalize:
                    vec_normalize = model.get_vec_normalize_env()
                    assert vec_normalize is not None
                    atomic_write(Path(self.params_path) / "vecnormalize.pkl", vec_normalize.save)
                stored = atomic_write(folder / f"{self.env_name}.zip", model.save)
                mark_finished(folder, stored, model.num_timesteps)
            except FileWriteError as error:
                size = None if newest is None else newest.files["model"].size
                raise TrainingStopped(
                    f"{write_failure('the final model', folder, error, size, self._kept())}; the run is not finished; "
                    f"free space, then {self._next_command()}"
                ) from None
        return None


@contextlib.contextmanager
def env_kwargs_checked(env_kwargs: dict[str, Any]) -> Iterator[None]:
    """The ValueError or TypeError of an env built with ``env_kwargs`` (sgfd_envs names the kwarg and those the
    id takes) as a one-line ZooError."""
    try:
        yield
    except (ValueError, TypeError) as error:
        raise ZooError(f"env_kwargs {env_kwargs}: {_first_line(error)}") from error


def wrap_like_training(env: VecEnv, frame_stack: int | None, normalize=None, eval_env: bool = True) -> VecEnv:
    """Frame stacking and channel-first transposition, as rl-zoo3 wraps its training envs."""
    if normalize is not None:
        env = normalize(env, eval_env)
    if frame_stack:
        env = VecFrameStack(env, frame_stack)
    space = env.observation_space
    if isinstance(space, spaces.Box) and is_image_space(space) and not is_image_space_channels_first(space):
        env = VecTransposeImage(env)
    return env


def constructor_arguments(algo_class: type) -> set[str]:
    """The keyword arguments ``algo_class`` takes, following ``**kwargs`` up to the base class that has them."""
    names: set[str] = set()
    for cls in algo_class.__mro__:
        if "__init__" not in vars(cls):
            continue
        parameters = inspect.signature(cls.__init__).parameters
        names |= {name for name, p in parameters.items() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
        if not any(p.kind == p.VAR_KEYWORD for p in parameters.values()):
            break
    return names - {"self", "env"}


def observes_pixels(env_kwargs: dict[str, Any]) -> bool:
    """Whether the SGFD ids give image observations with these env kwargs (their default: pixels)."""
    return env_kwargs.get("obs_type", "pixels") == "pixels"


def check_policy_fits(algo: str, hyperparams: dict[str, Any], pixels: bool) -> None:
    """A ZooError, naming the flags that fit, when the configuration's policy cannot read the observations:
    an image encoder on states, a flattening policy on pixels, encoder arguments for a policy that has none,
    or image augmentation on states.

    :param algo: algorithm key
    :param hyperparams: the processed hyperparameters (policy, policy_kwargs, ...)
    :param pixels: whether the env gives images
    """
    policy = hyperparams.get("policy")
    policy_class = policy_class_of(algo, policy)
    name = policy if isinstance(policy, str) else getattr(policy, "__name__", str(policy))
    kwargs = hyperparams.get("policy_kwargs") or {}
    extractor = kwargs.get("features_extractor_class") or default_extractor(policy_class)
    seen = "pixel" if pixels else "state"
    fixes = (
        "use --quick (the state configuration) or leave out obs_type:'state'"
        if not pixels
        else "use the paper-scale configuration (no --quick) or --env-kwargs obs_type:'state'"
    )
    if extractor is not None and issubclass(extractor, (PixelEncoder, NatureCNN)) and not pixels:
        raise ZooError(f"policy {name!r} of {algo} encodes images, but the env gives {seen} observations: {fixes}")
    if extractor is not None and issubclass(extractor, (FlattenExtractor, MlpEncoder)) and pixels:
        raise ZooError(f"policy {name!r} of {algo} reads flat states, but the env gives {seen} observations: {fixes}")
    if extractor is FlattenExtractor and kwargs.get("features_extractor_kwargs"):
        raise ZooError(
            f"policy {name!r} of {algo} flattens the observations and takes no features_extractor_kwargs "
            f"({kwargs['features_extractor_kwargs']}): use --quick, or policy 'EncoderMlpPolicy' for a learned encoder"
        )
    if hyperparams.get("augmentation_views") and not pixels:
        raise ZooError(f"{algo} shifts images (augmentation_views), but the env gives state observations: {fixes}")


def policy_class_of(algo: str, policy: str | type | None) -> type | None:
    """The policy class a ``policy`` hyperparameter names: an alias of the algorithm, a dotted path, or a class."""
    if not isinstance(policy, str):
        return policy
    policy_class = ALGOS[algo].policy_aliases.get(policy)
    if policy_class is None and "." in policy:
        policy_class = get_class_by_name(policy)
    return policy_class


def default_extractor(policy_class: type | None) -> type | None:
    """The features extractor a policy class uses when none is given; None when it follows the observations."""
    if policy_class is None:
        return None
    if hasattr(policy_class, "default_features_extractor_class"):
        return policy_class.default_features_extractor_class
    default = inspect.signature(policy_class.__init__).parameters.get("features_extractor_class")
    return default.default if default is not None and isinstance(default.default, type) else None


def kwargs_value(key: str, value: Any) -> dict[str, Any] | None:
    """A kwargs hyperparameter as a dict: a string is evaluated as rl-zoo3 evaluates ``policy_kwargs`` (with
    the names its module sees: ``nn``, ``th``, ...); anything else but a dict or None is refused, by name.

    :param key: the hyperparameter, e.g. ``representation_kwargs``
    :param value: its value in the yaml or ``-params``
    """
    if isinstance(value, str):
        try:
            value = eval(value, dict(vars(rl_zoo3.exp_manager)))
        except Exception as error:
            reason = f"{type(error).__name__}: {error}"
            raise ZooError(f"{key}: {value!r} is not a Python dict expression ({reason})") from None
    if value is not None and not isinstance(value, dict):
        raise ZooError(f"{key} must be a dict, or a string such as \"dict(key=value)\", got {value!r}")
    return value


def keyword_arguments(cls: type, filled: set[str] = frozenset(), follow_var_keyword: bool = True) -> set[str] | None:
    """The keyword arguments a user may give ``cls`` (less those its caller ``filled`` itself), following
    ``**kwargs`` up the base classes (SB3's policies hand theirs to their base); None when ``cls`` takes
    ``**kwargs`` it does not hand up (``follow_var_keyword=False``), so that its keys cannot be known.

    :param cls: a class
    :param filled: arguments its caller passes itself
    :param follow_var_keyword: follow ``**kwargs`` up the MRO
    """
    if not follow_var_keyword:
        parameters = inspect.signature(cls.__init__).parameters
        if any(p.kind == p.VAR_KEYWORD for p in parameters.values()):
            return None
    return constructor_arguments(cls) - filled - {"self"}


def default_argument(cls: type, name: str) -> Any:
    """The default of ``cls``'s constructor argument ``name``, from the first class of its MRO that has it."""
    for base in cls.__mro__:
        if "__init__" in vars(base):
            parameter = inspect.signature(base.__init__).parameters.get(name)
            if parameter is not None:
                return parameter.default
    return None


def check_nested_kwargs(algo: str, hyperparams: dict[str, Any]) -> None:
    """Refuse unknown keys inside ``policy_kwargs`` (and its ``features_extractor_kwargs``),
    ``representation_kwargs`` and ``replay_buffer_kwargs``, naming each and the keys that class takes.

    :param algo: algorithm key
    :param hyperparams: the processed hyperparameters
    """
    algo_class = ALGOS[algo]
    policy_class = policy_class_of(algo, hyperparams.get("policy"))
    policy_kwargs = hyperparams.get("policy_kwargs") or {}
    if policy_class is not None:
        valid = keyword_arguments(policy_class, {"observation_space", "action_space", "lr_schedule"}) or set()
        check_keywords(f"policy_kwargs of {algo} ({policy_class.__name__})", policy_kwargs, valid)
    extractor = policy_kwargs.get("features_extractor_class") or default_extractor(policy_class)
    if isinstance(extractor, type) and policy_kwargs.get("features_extractor_kwargs"):
        valid = keyword_arguments(extractor, {"observation_space"}, follow_var_keyword=False)
        if valid is not None:  # one that hands **kwargs on (AMBSEncoder to its trunk) is checked when built
            where = f"features_extractor_kwargs of {algo} ({extractor.__name__})"
            check_keywords(where, policy_kwargs["features_extractor_kwargs"], valid)
    representation = hyperparams.get("representation", getattr(algo_class, "fixed_representation", None))
    if hyperparams.get("representation_kwargs") and representation in REPRESENTATIONS:
        representation_class = REPRESENTATIONS[representation]
        valid = keyword_arguments(representation_class) or set()
        where = f"representation_kwargs of {algo} ({representation!r}: {representation_class.__name__})"
        check_keywords(where, hyperparams["representation_kwargs"], valid)
    buffer_class = hyperparams.get("replay_buffer_class") or default_argument(algo_class, "replay_buffer_class")
    buffer_class = buffer_class or ReplayBuffer
    if hyperparams.get("replay_buffer_kwargs") and isinstance(buffer_class, type):
        valid = keyword_arguments(buffer_class, BUFFER_ARGUMENTS) or set()
        where = f"replay_buffer_kwargs of {algo} ({buffer_class.__name__})"
        check_keywords(where, hyperparams["replay_buffer_kwargs"], valid)


def _first_line(error: BaseException) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[0] if lines else "(no message)"


def check_algo_kwargs(algo: str, hyperparams: dict[str, Any]) -> None:
    """Refuse yaml keys that neither rl-zoo3 nor the algorithm's constructor knows, naming close matches."""
    known = constructor_arguments(ALGOS[algo])
    unknown = sorted(set(hyperparams) - known - ZOO_KEYS)
    if unknown:
        hints = []
        for key in unknown:
            close = difflib.get_close_matches(key, known | ZOO_KEYS, n=1)
            hints.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise ZooError(f"unknown hyperparameter(s) for {algo}: {', '.join(hints)}")
