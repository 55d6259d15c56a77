"""rl-zoo3's ExperimentManager, taught to train on SGFD's multi-domain envs and to resume."""

from __future__ import annotations

import difflib
import inspect
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import optuna
from gymnasium import spaces
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER, convert_offpolicy_params
from rl_zoo3.utils import ALGOS, get_class_by_name
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import ProgressBarCallback
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.torch_layers import FlattenExtractor, NatureCNN
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecNormalize, VecTransposeImage

import sgfd_envs
from sb3_sgfd import SGFD_SAC
from sb3_sgfd.policies import MlpEncoder, PixelEncoder
from sgfd_envs.backgrounds import overlay_bank
from zoo.algos import SGFD_ALGOS
from zoo.arguments import ZooError
from zoo.callbacks import CSVLogCallback, MultiSplitEvalCallback, ProgressCallback, ResumableCheckpointCallback
from zoo.runs import RunFolder, runs_by_id

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


class SGFDExperimentManager(ExperimentManager):
    """
    rl-zoo3's ExperimentManager with SGFD's conventions:

    - hyperparameters from ``zoo/hyperparams/<algo>.yml`` unless ``-conf`` names another file;
    - the training VecEnv has one sub-env per training domain (``n_envs`` defaults to their number);
    - evaluation envs get the same env kwargs as training (rl-zoo3 drops yaml ``env_kwargs`` there),
      and evaluation covers every split: training domains and the unseen ones;
    - checkpoints (model + replay buffer) every ``save_freq`` steps, and ``resume=True`` continues the
      newest run of this algo and env from its last checkpoint;
    - a progress bar by default when the output is a terminal, and progress reports to ``progress_reporter``;
    - a policy that cannot read the observations is refused, naming the flags that fit, before anything is
      built.

    Takes rl-zoo3's arguments, plus:

    :param quick: Use the quick configuration (``zoo/hyperparams/quick``) when no ``-conf`` is given
    :param resume: Continue the newest run from its last checkpoint instead of starting a new one
    :param progress: Show a progress bar; None: when stdout is a terminal
    :param run_id: Write to (and resume) the run folder ``<EnvName>_<run_id>``; None: rl-zoo3's newest id + 1
    :param progress_reporter: Called every few seconds with a dict of the run's progress (``sgfd-zoo sweep``)
    :param check_only: Only read and check the configuration (``setup_experiment`` then builds nothing)
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
        self.checkpoint: dict | None = None
        if resume and not check_only:
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
        check_policy_fits(self.algo, processed, observes_pixels(self.env_kwargs))
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
        if self.progress_reporter is not None:
            evaluation = next((c for c in self.callbacks if isinstance(c, MultiSplitEvalCallback)), None)
            latest = None if evaluation is None else evaluation.latest_returns
            self.callbacks.append(ProgressCallback(self.progress_reporter, self.n_timesteps, latest))

    # -- resuming --------------------------------------------------------------------------------

    def _point_at_run_to_resume(self) -> None:
        if self.run_id is not None:
            runs = [RunFolder(Path(self.save_path))]
        else:
            runs = list(runs_by_id(Path(self.log_path).parent, self.algo, self.env_name.gym_id).values())
        runs = [run for run in runs if run.checkpoint is not None]
        if not runs:
            raise ZooError(
                f"--resume: no checkpoint of {self.algo} on {self.env_name.gym_id} under {self.log_path} "
                "(checkpoints are written every --save-freq steps)"
            )
        run = runs[-1]
        self.save_path = str(run.path)
        self.params_path = str(run.config_dir)
        self.checkpoint = run.checkpoint

    def setup_experiment(self):
        if self.check_only:
            unprocessed, saved_hyperparams = self.read_hyperparameters()
            self._preprocess_hyperparams(unprocessed)
            return None, saved_hyperparams
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
    policy_class = ALGOS[algo].policy_aliases.get(policy) if isinstance(policy, str) else policy
    if policy_class is None and isinstance(policy, str) and "." in policy:
        policy_class = get_class_by_name(policy)
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


def default_extractor(policy_class: type | None) -> type | None:
    """The features extractor a policy class uses when none is given; None when it follows the observations."""
    if policy_class is None:
        return None
    if hasattr(policy_class, "default_features_extractor_class"):
        return policy_class.default_features_extractor_class
    default = inspect.signature(policy_class.__init__).parameters.get("features_extractor_class")
    return default.default if default is not None and isinstance(default.default, type) else None


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
