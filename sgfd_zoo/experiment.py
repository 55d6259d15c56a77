"""rl-zoo3's ExperimentManager, taught to train on SGFD's multi-domain envs, to claim its run folder and hold it
while it trains, to stop at a checkpoint and to resume from one."""

from __future__ import annotations

import errno
import sys
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast

from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.utils import ALGOS, get_class_by_name
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import ProgressBarCallback
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

import sgfd_envs
from sb3_sgfd.common.validation import RefusedTransition
from sgfd_envs.backgrounds import overlay_bank
from sgfd_zoo.algos import SGFD_ALGOS, classifier_start_warning, hyperparams_file, is_sgfd
from sgfd_zoo.arguments import TrainingStopped, ZooError, train_command
from sgfd_zoo.callbacks import CSVLogCallback, MultiSplitEvalCallback, ProgressCallback
from sgfd_zoo.config_checks import (
    KWARGS_KEYS,
    changed_settings,
    check_algo_kwargs,
    check_algorithm_values,
    check_env_kwargs,
    check_nested_kwargs,
    check_policy_fits,
    check_zoo_values,
    env_kwargs_checked,
    first_line,
    interval_warnings,
    kwargs_value,
    merged_env_kwargs,
    observes_pixels,
)
from sgfd_zoo.registration import register_algorithms
from sgfd_zoo.runs import training_state
from sgfd_zoo.runs.checkpoint_callback import (
    ResumableCheckpointCallback,
    StopRequest,
    default_checkpoint_interval,
    interrupts_deferred,
)
from sgfd_zoo.runs.checkpoints import Checkpoint
from sgfd_zoo.runs.files import FileWriteError, atomic_write, write_failure
from sgfd_zoo.runs.folders import RunFolder, mark_finished
from sgfd_zoo.runs.locks import ClaimedRun, claim_new_run, claim_run
from sgfd_zoo.runs.resuming import choose_checkpoint, envs_as_trained, load_checkpoint, prepare_restart, run_to_resume
from sgfd_zoo.runs.safe import refuse_links
from sgfd_zoo.runs.training_state import RestoreTrainingState
from sgfd_zoo.vec_wrappers import wrap_like_training

# Errors of a write that a full disk (or quota, or file size limit) causes.
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


class SGFDExperimentManager(ExperimentManager):
    """
    rl-zoo3's ExperimentManager with SGFD's conventions:

    - hyperparameters from ``sgfd_zoo/hyperparams/<algo>.yml`` unless ``-conf`` names another file;
    - the training VecEnv has one sub-env per training domain (``n_envs`` defaults to their number);
    - evaluation envs get the same env kwargs as training (rl-zoo3 drops yaml ``env_kwargs`` there),
      and evaluation covers every split: training domains and the unseen ones;
    - one run, one folder, one writer: a new run claims its folder before anything is built (runs started
      together each get their own), and the run's lock is held while it trains (:mod:`sgfd_zoo.runs.locks`);
    - checkpoints (model + replay buffer) every ``save_freq`` steps, each file written whole and checked; ``resume``
      continues the newest run, on the envs it trained on, from its newest checkpoint that verifies (the one before
      when the newest does not);
    - Ctrl-C (or SIGTERM) stops training at a checkpoint, a full disk cleanly (a :class:`TrainingStopped` says how
      to continue); the final model is followed by ``finished.json``;
    - a progress bar by default on a terminal, progress reports to ``progress_reporter``, rl-zoo3's monitor files;
    - a policy that cannot read the observations, and unknown keys in the kwargs hyperparameters, are refused
      in one line, naming what fits, before anything is built.

    Takes rl-zoo3's arguments, plus:

    :param quick: the quick configuration (``sgfd_zoo/hyperparams/quick``) when no ``-conf`` is given
    :param resume: continue the newest run from its last checkpoint
    :param progress: a progress bar; None: when stdout is a terminal
    :param run_id: write to (and resume) ``<EnvName>_<run_id>``; None: a new folder, claimed
    :param progress_reporter: called every few seconds with the run's progress (``sgfd-zoo sweep``)
    :param check_only: ``setup_experiment`` builds the model with a tiny buffer, writes nothing, returns no model
    :param command: the ``sgfd-zoo train`` flags of this run, to print the command that continues it
    :param default_save_freq: no ``--save-freq``: checkpoint every :func:`default_checkpoint_interval` steps
    :param default_eval_freq: no ``--eval-freq``: no warning when rl-zoo3's default is longer than the run
    :param classifier_start: the SGFD algorithms' ``classifier_start``; the others ignore it (a sweep may mix them)
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
        default_eval_freq: bool = False,
        classifier_start: int | None = None,
        **kwargs,
    ):
        register_algorithms()
        algo = args[1] if len(args) > 1 else kwargs["algo"]
        if not kwargs.get("config"):
            kwargs["config"] = str(hyperparams_file(algo, quick))
        if progress is None:
            progress = kwargs.get("show_progress") or sys.stdout.isatty()
        kwargs["show_progress"] = progress
        super().__init__(*args, **kwargs)
        # rl-zoo3's "newest id + 1" is only a guess until the folder is claimed (setup_experiment).
        if run_id is not None:
            self._set_run_path(Path(self.log_path) / f"{self.env_name}_{run_id}")
        self.run_id = run_id
        self.progress_reporter = progress_reporter
        self.check_only = check_only
        self.resume = resume
        self.command = None if command is None else list(command)
        self.default_save_freq, self.default_eval_freq = default_save_freq, default_eval_freq
        self.classifier_start = classifier_start
        self.stop = StopRequest()
        self.checkpoint: Checkpoint | None = None
        self.checkpointer: ResumableCheckpointCallback | None = None
        self.training_state: dict[str, Any] | None = None
        self.claimed: ClaimedRun | None = None
        if resume and not check_only:
            named = Path(self.save_path) if run_id is not None else None
            self._set_run_path(run_to_resume(Path(self.log_folder), self.algo, self.env_name.gym_id, named).path)

    def _set_run_path(self, path: Path) -> None:
        self.save_path = str(path)
        self.params_path = f"{self.save_path}/{self.env_name}"

    def train_command(self, resume: bool) -> str:
        """The command that continues this run from its checkpoint (``resume``) or starts it again."""
        run = RunFolder.parse(Path(self.save_path))
        argv = self.command
        if argv is None:
            argv = ["--algo", self.algo, "--env", self.env_name.gym_id, "-f", self.log_folder, "--seed", str(self.seed)]
        return train_command(argv, None if run is None else run.run_id, resume)

    # -- configuration ---------------------------------------------------------------------------

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        # --env-kwargs are merged into the configuration's env settings (rl-zoo3 replaces them): hidden from
        # rl-zoo3 while it reads the yaml.
        given, self.env_kwargs = self.env_kwargs, {}
        hyperparams, saved = super().read_hyperparameters()
        printed = dict(saved)  # rl-zoo3 printed these (the yaml's and -params); what changes below is said below
        if given or "env_kwargs" in hyperparams:
            hyperparams["env_kwargs"] = saved["env_kwargs"] = merged_env_kwargs(hyperparams.get("env_kwargs"), given)
        self.env_kwargs = dict(hyperparams.get("env_kwargs") or {})
        if self.algo in SGFD_ALGOS:
            # The ablations are the SGFD entries with one part switched off; the saved config shows it.
            overrides = {**SGFD_ALGOS[self.algo].overrides, **(self.custom_hyperparams or {})}
            if self.classifier_start is not None and is_sgfd(self.algo):
                if "classifier_start" in (self.custom_hyperparams or {}):
                    raise ZooError("--classifier-start and --hyperparams classifier_start:... both set; give one")
                overrides["classifier_start"] = self.classifier_start
            hyperparams.update(overrides)
            saved.update(overrides)
        if (changed := changed_settings(printed, saved, self.n_timesteps)) is not None:
            print(changed)
        return hyperparams, saved

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]):
        """rl-zoo3's preprocessing, after every key and value is checked (nothing is built here)."""
        explicit_n_envs = "n_envs" in hyperparams
        for key in KWARGS_KEYS:
            if key in hyperparams:
                hyperparams[key] = kwargs_value(key, hyperparams[key])
        # rl-zoo3 eval()s a string replay_buffer_class; a dotted path names a class to import instead.
        if isinstance(hyperparams.get("replay_buffer_class"), str) and "." in hyperparams["replay_buffer_class"]:
            hyperparams["replay_buffer_class"] = get_class_by_name(hyperparams["replay_buffer_class"])
        # Keys first (a typo is named with what fits), then values; SGQN's overlay images are part of its values.
        check_algo_kwargs(self.algo, hyperparams)
        check_policy_fits(self.algo, hyperparams, observes_pixels(self.env_kwargs))
        check_nested_kwargs(self.algo, hyperparams)
        check_zoo_values(hyperparams, steps_given=self.n_timesteps > 0)
        self._add_overlay_images(hyperparams)
        check_algorithm_values(ALGOS[self.algo], hyperparams)
        processed, env_wrapper, callbacks, vec_env_wrapper = super()._preprocess_hyperparams(hyperparams)
        self.eval_env_kwargs = {**self.env_kwargs, **(self._eval_env_kwargs_args or {})}
        check_env_kwargs(self.env_name.gym_id, self.env_kwargs)
        check_env_kwargs(self.env_name.gym_id, self.eval_env_kwargs, "evaluation env_kwargs")
        if not explicit_n_envs:
            with env_kwargs_checked(self.env_kwargs):
                self.n_envs = sgfd_envs.n_domains(self.env_name.gym_id, "train", **self.env_kwargs)
        if not self.optimize_hyperparameters:
            save_freq = None if self.default_save_freq else self.save_freq
            eval_freq = None if self.default_eval_freq else self.eval_freq
            for warning in interval_warnings(self.n_timesteps, eval_freq, save_freq):
                print(warning, file=sys.stderr)
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
        # Optuna's trials ask for an eval env (scored on every training domain); a run's own log monitor files.
        monitor_dir = None if eval_env or no_log or self.check_only else self.save_path
        return self.create_split_env("train", None if eval_env else n_envs, eval_env, monitor_dir)

    def create_split_env(
        self, split: str, n_envs: int | None = None, eval_env: bool = True, monitor_dir: str | None = None
    ) -> VecEnv:
        """A VecEnv over the domains of ``split``, wrapped the way training wraps it (frame stack, transpose)."""
        env_kwargs = self.eval_env_kwargs if eval_env else self.env_kwargs
        with env_kwargs_checked(env_kwargs):
            env = sgfd_envs.make_domain_vec_env(
                self.env_name.gym_id,
                split=split,
                n_envs=n_envs,
                seed=self.seed + (10_000 if eval_env else 0),
                vec_env_cls=cast(type[DummyVecEnv] | type[SubprocVecEnv], self.vec_env_class),
                monitor_dir=monitor_dir,
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
        lock = None if self.claimed is None else self.claimed.lock
        self.checkpointer = ResumableCheckpointCallback(
            save_freq, self.save_path, self.stop, lock, verbose=self.verbose
        )
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

    def setup_experiment(self):
        if self.check_only:
            return self._check_configuration()
        if self.optimize_hyperparameters:
            return super().setup_experiment()
        # rl-zoo3's steps in another order: everything read and checked first, then the run folder claimed, then
        # the model built (or the checkpoint loaded): a configuration that does not fit leaves no run folder.
        unprocessed, saved_hyperparams = self.read_hyperparameters()
        hyperparams, self.env_wrapper, self.callbacks, self.vec_env_wrapper = self._preprocess_hyperparams(unprocessed)
        self._claim_run_folder()
        # Once the run is sure to start: a configuration or folder that is refused gets its one line only.
        if (too_short := classifier_start_warning(self.algo, hyperparams, self.n_timesteps)) is not None:
            print(f"warning: {too_short}", file=sys.stderr)
        if self.continue_training:
            return super().setup_experiment()
        if self.checkpoint is None:
            self._forget_monitor_files()
        env = self.create_envs(self.n_envs)
        self._hyperparams = self._preprocess_action_noise(hyperparams, saved_hyperparams, env)
        if self.checkpoint is None:
            model = self._build_model(env, self._hyperparams)
        else:
            load = {"tensorboard_log": self.tensorboard_log, "device": self.device, "verbose": self.verbose}
            run = RunFolder(Path(self.save_path))
            model, self.training_state = load_checkpoint(ALGOS[self.algo], run, self.checkpoint, env, **load)
        self.create_log_folder()
        self.create_callbacks()
        self._save_config(saved_hyperparams)
        return model, saved_hyperparams

    def _claim_run_folder(self) -> None:
        """This process's run folder, before anything is built: a new one claimed (processes started together each
        get their own), or the one ``--run-id`` or ``--resume`` names, locked (one writer at a time); then the
        checkpoint to resume from, or the folder readied to start again from step 0."""
        holder = f"sgfd-zoo train --algo {self.algo} --env {self.env_name.gym_id} --seed {self.seed}"
        # A link in the run's place would take its lock, checkpoints and logs out of the log folder (a shared one).
        refuse_links(Path(self.log_folder), Path(self.log_path), "train in")
        if (self.resume or self.run_id is not None) and Path(self.save_path).exists():
            RunFolder(Path(self.save_path)).refuse_links()
        try:
            if self.resume or self.run_id is not None:
                what = "--resume" if self.resume else f"--run-id {self.run_id}"
                self.claimed = claim_run(Path(self.save_path), holder, what)
            else:
                self.claimed = claim_new_run(Path(self.log_path), str(self.env_name), holder)
        except OSError as error:
            where = error.filename or self.save_path
            raise ZooError(
                f"-f {self.log_folder}: cannot write a run folder there ({where}: {error.strerror})"
            ) from None
        self._set_run_path(self.claimed.path)
        run = RunFolder(self.claimed.path)
        if self.resume:
            self.checkpoint = choose_checkpoint(run, self.train_command(resume=False))
            kwargs = envs_as_trained(run, self.env_name.gym_id, self.env_kwargs, self.eval_env_kwargs)
            self.env_kwargs, self.eval_env_kwargs = kwargs
        elif self.run_id is not None:
            prepare_restart(run, self.train_command(resume=True))

    def _forget_monitor_files(self) -> None:
        """A run that starts from step 0 logs its episodes afresh (a resumed one continues its monitor files)."""
        for path in Path(self.save_path).glob("*.monitor.csv"):
            path.unlink()

    def release_run_folder(self) -> None:
        """Give the run's lock back; a folder claimed for a run that wrote nothing goes too."""
        if self.claimed is not None:
            self.claimed.release(remove_if_empty=True)
            self.claimed = None

    def _save_config(self, saved_hyperparams: dict[str, Any]) -> None:
        """Written whole, instead of rl-zoo3's files: :meth:`sgfd_zoo.runs.folders.RunFolder.record_start`."""
        args = OrderedDict([(key, vars(self.args)[key]) for key in sorted(vars(self.args))])
        if self.env_kwargs != (saved_hyperparams.get("env_kwargs") or {}):  # a resumed run's family added
            saved_hyperparams["env_kwargs"] = dict(self.env_kwargs)
        start = 0 if self.checkpoint is None else self.checkpoint.num_timesteps
        RunFolder(Path(self.save_path)).record_start(saved_hyperparams, args, self.command, start)
        print(f"Log path: {self.save_path}")

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
            self._forget_monitor_files()  # the run has not started: its folder goes again
            raise ZooError(
                f"{self.algo} on {self.env_name.gym_id} cannot be built from this configuration: "
                f"{type(error).__name__}: {first_line(error)}"
            ) from error

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
                f"{self.stop.reason or 'Ctrl-C'} twice: stopped at once at {model.num_timesteps} steps, "
                f"{self._kept()}; the run is not finished; {self._next_command()}",
                exit_code=self.stop.exit_code,
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
        if self.checkpointer.taken_over is not None:
            raise TrainingStopped(
                f"{self.checkpointer.taken_over}; this process stopped at {model.num_timesteps} steps"
            )
        if self.checkpointer.failure is not None:
            raise TrainingStopped(f"{self.checkpointer.failure}; free space, then {self._next_command()}")
        # The checkpointer stops between two env steps; the step SB3 took after it is dropped, not trained on.
        stopped_at = self.checkpointer.stopped if self.checkpointer.stopped is not None else model.num_timesteps
        if self.stop and stopped_at < self.n_timesteps:
            raise TrainingStopped(
                f"{self.stop.reason} at {stopped_at} steps: {self._kept()}; the run is not finished; "
                f"{self._next_command()}",
                exit_code=self.stop.exit_code,
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
        if self.claimed is not None and self.claimed.lock.lost is not None:
            raise TrainingStopped(f"{self.claimed.lock.lost}; this process saved no final model")
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
