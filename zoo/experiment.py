"""rl-zoo3's ExperimentManager, taught to train on SGFD's multi-domain envs and to resume."""

from __future__ import annotations

import difflib
import inspect
import sys
from pathlib import Path
from typing import Any

from gymnasium import spaces
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.utils import ALGOS, get_class_by_name
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import ProgressBarCallback
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecNormalize, VecTransposeImage

import sgfd_envs
from sgfd_envs.backgrounds import overlay_bank
from zoo.algos import SGFD_ALGOS
from zoo.callbacks import CSVLogCallback, MultiSplitEvalCallback, ResumableCheckpointCallback, read_checkpoint

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


class ZooError(Exception):
    """A mistake in what the user asked for; the CLI prints it as one line and exits non-zero."""


def hyperparams_file(algo: str, quick: bool = False) -> Path:
    """The zoo's yaml for ``algo``: paper scale, or the quick configuration for a laptop-size run."""
    if algo not in SGFD_ALGOS:
        return HYPERPARAMS_DIR / ("quick" if quick else "") / f"{algo}.yml"
    entry = SGFD_ALGOS[algo]
    if quick:
        return HYPERPARAMS_DIR / "quick" / f"{entry.quick_hyperparams or entry.hyperparams}.yml"
    return HYPERPARAMS_DIR / f"{entry.hyperparams}.yml"


class SGFDExperimentManager(ExperimentManager):
    """
    rl-zoo3's ExperimentManager with SGFD's conventions:

    - hyperparameters from ``zoo/hyperparams/<algo>.yml`` unless ``-conf`` names another file;
    - the training VecEnv has one sub-env per training domain (``n_envs`` defaults to their number);
    - evaluation envs get the same env kwargs as training (rl-zoo3 drops yaml ``env_kwargs`` there),
      and evaluation covers every split: training domains and the unseen ones;
    - checkpoints (model + replay buffer) every ``save_freq`` steps, and ``resume=True`` continues the
      newest run of this algo and env from its last checkpoint;
    - a progress bar by default when the output is a terminal.

    Takes rl-zoo3's arguments, plus:

    :param quick: Use the quick configuration (``zoo/hyperparams/quick``) when no ``-conf`` is given
    :param resume: Continue the newest run from its last checkpoint instead of starting a new one
    :param progress: Show a progress bar; None: when stdout is a terminal
    :param run_id: Write to (and resume) the run folder ``<EnvName>_<run_id>``; None: rl-zoo3's newest id + 1
    """

    def __init__(
        self,
        *args: Any,
        quick: bool = False,
        resume: bool = False,
        progress: bool | None = None,
        run_id: int | None = None,
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
        self.resume = resume
        self.checkpoint: dict | None = None
        if resume:
            self._point_at_run_to_resume()

    # -- configuration ---------------------------------------------------------------------------

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        hyperparams, saved = super().read_hyperparameters()
        if self.algo in SGFD_ALGOS:
            # The ablations are the SGFD entries with one part switched off; the saved config shows it.
            overrides = {**SGFD_ALGOS[self.algo].overrides, **(self.custom_hyperparams or {})}
            hyperparams.update(overrides)
            saved.update(overrides)
        return hyperparams, saved

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]):
        explicit_n_envs = "n_envs" in hyperparams
        # rl-zoo3 eval()s a string replay_buffer_class; a dotted path names a class to import instead.
        if isinstance(hyperparams.get("replay_buffer_class"), str) and "." in hyperparams["replay_buffer_class"]:
            hyperparams["replay_buffer_class"] = get_class_by_name(hyperparams["replay_buffer_class"])
        processed, env_wrapper, callbacks, vec_env_wrapper = super()._preprocess_hyperparams(hyperparams)
        if self._eval_env_kwargs_args is None:
            self.eval_env_kwargs = dict(self.env_kwargs)
        if not explicit_n_envs:
            self.n_envs = sgfd_envs.n_domains(self.env_name.gym_id, "train", **self.env_kwargs)
        check_algo_kwargs(self.algo, processed)
        self._add_overlay_images(processed)
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
        log_name = (
            "progress.csv" if self.checkpoint is None else f"progress_from_{self.checkpoint['num_timesteps']}.csv"
        )
        self.callbacks.append(CSVLogCallback(Path(self.save_path) / log_name))
        if self.save_freq > 0:
            self.callbacks.append(ResumableCheckpointCallback(max(self.save_freq // self.n_envs, 1), self.save_path))
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

    # -- resuming --------------------------------------------------------------------------------

    def _point_at_run_to_resume(self) -> None:
        if self.run_id is not None:
            runs = [Path(self.save_path)]
        else:
            runs = sorted(
                Path(self.log_path).glob(f"{self.env_name}_*"),
                key=lambda path: int(path.name.rsplit("_", 1)[1]) if path.name.rsplit("_", 1)[1].isdigit() else -1,
            )
        runs = [run for run in runs if read_checkpoint(run) is not None]
        if not runs:
            raise ZooError(
                f"--resume: no checkpoint of {self.algo} on {self.env_name.gym_id} under {self.log_path} "
                "(checkpoints are written every --save-freq steps)"
            )
        run = runs[-1]
        self.save_path = str(run)
        self.params_path = str(run / str(self.env_name))
        self.checkpoint = read_checkpoint(run)

    def setup_experiment(self):
        if self.checkpoint is None:
            return super().setup_experiment()
        # Same steps as rl-zoo3's setup, but the model and its replay buffer come from the checkpoint.
        unprocessed, saved_hyperparams = self.read_hyperparameters()
        hyperparams, self.env_wrapper, self.callbacks, self.vec_env_wrapper = self._preprocess_hyperparams(unprocessed)
        self.create_log_folder()
        self.create_callbacks()
        env = self.create_envs(self.n_envs)
        self._hyperparams = self._preprocess_action_noise(hyperparams, saved_hyperparams, env)
        run = Path(self.save_path)
        model = ALGOS[self.algo].load(
            run / self.checkpoint["model"],
            env=env,
            tensorboard_log=self.tensorboard_log,
            verbose=self.verbose,
            device=self.device,
        )
        if "replay_buffer" in self.checkpoint:
            model.load_replay_buffer(run / self.checkpoint["replay_buffer"])
        if "vecnormalize" in self.checkpoint and isinstance(model.get_vec_normalize_env(), VecNormalize):
            model.set_env(VecNormalize.load(str(run / self.checkpoint["vecnormalize"]), env))
        print(f"Resuming {run} from {model.num_timesteps} steps")
        self._save_config(saved_hyperparams)
        return model, saved_hyperparams

    def learn(self, model: BaseAlgorithm) -> None:
        if self.checkpoint is None:
            return super().learn(model)
        remaining = self.n_timesteps - model.num_timesteps
        if remaining <= 0:
            print(f"Nothing to resume: the checkpoint already has {model.num_timesteps} of {self.n_timesteps} steps")
            return None
        kwargs: dict[str, Any] = {"reset_num_timesteps": False}
        if self.callbacks:
            kwargs["callback"] = self.callbacks
        try:
            model.learn(remaining, **kwargs)
        finally:
            if model.env is not None:
                model.env.close()
        return None


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
