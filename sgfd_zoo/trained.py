"""A trained agent of a run folder, as ``enjoy``, ``record-video`` and ``push-to-hub`` use it: which model file,
the run's saved settings read as data, the env it plays (rl-zoo3's ``create_test_env``) and the model loaded.

rl-zoo3's own enjoy reads a run's ``config.yml`` and ``args.yml`` with PyYAML's unsafe loader and evaluates a
``normalize`` string. Here the zoo reads both with its data loader (:mod:`sgfd_zoo.runs.safe`) and hands rl-zoo3 the
values it read: rl-zoo3's loader never sees them. A file the data loader cannot read is refused, never skipped
(docs/trust.md). The model zip and ``vecnormalize.pkl`` are SB3's pickles: code by their format, loaded because the
user asked for this run's agent.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import ZooError, check_key_values
from sgfd_zoo.config_checks import first_line
from sgfd_zoo.runs.folders import RunFolder, read_yaml, runs_by_id, select_run
from sgfd_zoo.runs.safe import RefusedFile, hyperparameter_problem, literal_expression

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.vec_env import VecEnv


def add_agent_options(parser: argparse.ArgumentParser, default_folder: str = "logs") -> None:
    """The options that choose a trained agent and the env it plays, as rl-zoo3's enjoy names them, plus
    ``--split`` and ``--domain``.

    :param parser: the command's parser
    :param default_folder: the log folder when ``-f`` is not given
    """
    agent = parser.add_argument_group("the agent (rl-zoo3's options)")
    agent.add_argument("--algo", default="sgfd_sac", choices=SGFD_ALGOS, metavar="ALGO", help=", ".join(SGFD_ALGOS))
    agent.add_argument("--env", required=True, metavar="ENV_ID", help="the id it was trained on")
    agent.add_argument("-f", "--folder", default=default_folder, help=f"the log folder (default: {default_folder})")
    agent.add_argument(
        "--exp-id", type=int, default=0, metavar="ID", help="the run <EnvName>_<ID> (default 0: the newest finished)"
    )
    agent.add_argument(
        "--load-checkpoint", type=int, metavar="STEPS", help="the checkpoint at STEPS, not the final model"
    )
    agent.add_argument("--load-last-checkpoint", action="store_true", help="the newest checkpoint, not the final model")
    agent.add_argument("--load-best", action="store_true", help="rl-zoo3's best model: the zoo keeps none (refused)")
    agent.add_argument("--device", default="auto", help="torch's device (default: auto)")
    agent.add_argument("--num-threads", type=int, default=-1, metavar="N", help="torch's CPU threads (-1: torch's)")
    agent.add_argument("--seed", type=int, default=0, help="the env's and actions' seed (default: 0)")
    agent.add_argument("--deterministic", action="store_true", help="deterministic actions (the default)")
    agent.add_argument("--stochastic", action="store_true", help="sampled actions")
    agent.add_argument(
        "--norm-reward", action="store_true", help="normalised rewards (a run trained with VecNormalize)"
    )
    agent.add_argument("--custom-objects", action="store_true", help="rl-zoo3's; the zoo always loads with them")
    agent.add_argument("--gym-packages", nargs="+", default=[], metavar="MODULE", help="modules to import first")
    agent.add_argument("--verbose", type=int, default=1, metavar="LEVEL", help="0: quiet, 1: episodes (default)")
    played = parser.add_argument_group("the env it plays")
    played.add_argument("--split", help="the split whose domains it plays (default: the env's, train)")
    played.add_argument("--domain", type=int, help="the domain of the split (default: 0)")
    played.add_argument("--env-kwargs", nargs="+", metavar="KEY:VALUE", help="env settings, e.g. image_size:64")


@dataclass(frozen=True)
class TrainedAgent:
    """A model of a run, with the settings it was trained with, read as data.

    :param run: its run folder
    :param model_path: the model zip (the final model, or a checkpoint's)
    :param hyperparams: the run's ``config.yml``, with ``normalize_kwargs`` as rl-zoo3's ``get_saved_hyperparams``
        adds them
    :param env_kwargs: the env settings it trained with (``config.yml``'s, then ``args.yml``'s), updated by the
        command line's
    """

    run: RunFolder
    model_path: Path
    hyperparams: dict[str, Any]
    env_kwargs: dict[str, Any]

    @property
    def algo(self) -> str:
        return self.run.algo

    @property
    def env_id(self) -> str:
        return self.run.env_id


def find_agent(args: argparse.Namespace) -> TrainedAgent:
    """The agent ``args`` (see :func:`add_agent_options`) choose, its settings read and checked as data."""
    from sgfd_zoo.arguments import check_env_id

    check_env_id(args.env)
    check_key_values("--env-kwargs", args.env_kwargs)
    if args.load_best:
        raise ZooError("--load-best: the zoo keeps no best model (it evaluates every split); use --load-checkpoint")
    if args.exp_id < 0:
        raise ZooError(f"--exp-id {args.exp_id}: the zoo's runs are <EnvName>_<id> folders; give an id >= 1, or 0")
    run, model_path = _chosen_model(args)
    hyperparams = saved_settings(run.config_dir / "config.yml", required=True)
    saved_settings(run.config_dir / "args.yml", required=False)  # refused here if it cannot be read as data
    hyperparams = with_normalize_kwargs(hyperparams, args.norm_reward, run.config_dir / "config.yml")
    hyperparams.pop("env_kwargs", None)
    # What the run trained on, as the run folder reads it (its family among them: an earlier run plays its own
    # envs, as evaluate does), then the command line's
    env_kwargs = {**run.env_kwargs, **_command_line_env_kwargs(args)}
    return TrainedAgent(run, model_path, hyperparams, env_kwargs)


def _chosen_model(args: argparse.Namespace) -> tuple[RunFolder, Path]:
    """The run and the model file ``--exp-id`` and the ``--load-*`` options name."""
    folder = Path(args.folder)
    if args.load_checkpoint is None and not args.load_last_checkpoint:
        run = select_run(folder, args.env, args.algo, args.exp_id or None)
        print(f"Loading {run.model_path}")
        return run, run.model_path
    runs = runs_by_id(folder, args.algo, args.env)
    if not runs or (args.exp_id and args.exp_id not in runs):
        raise ZooError(f"--exp-id {args.exp_id}: no {args.algo} run of {args.env} under {folder}; runs: {sorted(runs)}")
    run = runs[args.exp_id or max(runs)]
    checkpoints = [c for c in run.checkpoints() if c.problem(run.path, full=False) is None]
    if args.load_checkpoint is not None:
        checkpoints = [c for c in checkpoints if c.num_timesteps == args.load_checkpoint]
    if not checkpoints:
        steps = sorted(c.num_timesteps for c in run.checkpoints())
        raise ZooError(f"{run.path}: no whole checkpoint{_at(args.load_checkpoint)}; its checkpoints: {steps}")
    model = run.path / checkpoints[0].files["model"].name
    print(f"Loading {model}")
    return run, model


def _at(steps: int | None) -> str:
    return "" if steps is None else f" at {steps} steps"


def saved_settings(path: Path, required: bool) -> dict[str, Any]:
    """The mapping of a run's ``config.yml`` or ``args.yml``, read as data; a :class:`RefusedFile` when it cannot
    be read that way (a tag that names code, a malformed ``OrderedDict``, a file that does not parse) or when a
    value would make rl-zoo3 run code (:func:`~sgfd_zoo.runs.safe.hyperparameter_problem`): never skipped.

    :param path: the file
    :param required: refuse a missing file (``config.yml``: every zoo run writes one)
    """
    if required and not path.is_file():
        raise RefusedFile(f"{path}: missing; a run the zoo trained has one (was it copied whole?)")
    saved, problem = read_yaml(path)
    if problem is not None:
        raise RefusedFile(f"refused: {problem}; the zoo reads it as data only, and does not go on without it")
    for key, value in saved.items():
        if (found := hyperparameter_problem(str(key), value)) is not None:
            raise RefusedFile(f"{path}: refused: {found}")
    return saved


def with_normalize_kwargs(hyperparams: dict[str, Any], norm_reward: bool, path: Path) -> dict[str, Any]:
    """``hyperparams`` with ``normalize`` and ``normalize_kwargs`` as rl-zoo3's ``get_saved_hyperparams`` gives them
    for testing, a ``normalize`` string read as a literal (rl-zoo3 would evaluate it)."""
    hyperparams = {**hyperparams, "normalize": hyperparams.get("normalize", False)}
    normalize = hyperparams["normalize"]
    if not normalize:
        return hyperparams
    if isinstance(normalize, str):
        try:
            kwargs = dict(literal_expression(normalize))
        except (TypeError, ValueError) as error:
            raise RefusedFile(f"{path}: refused: normalize: {error}") from None
        kwargs["norm_reward"] = norm_reward
    elif isinstance(normalize, dict):
        kwargs = dict(normalize)
    else:
        kwargs = {"norm_obs": normalize, "norm_reward": norm_reward}
    return {**hyperparams, "normalize_kwargs": kwargs}


def _command_line_env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """``--env-kwargs`` (evaluated as rl-zoo3 does, after the check), then ``--split`` and ``--domain``."""
    from sgfd_zoo.training import key_values

    given = key_values("--env-kwargs", args.env_kwargs) or {}
    for name in ("split", "domain"):
        value = getattr(args, name)
        if value is not None:
            if name in given and given[name] != value:
                raise ZooError(f"--{name} {value} and --env-kwargs {name}:{given[name]!r} disagree; give one")
            given[name] = value
    return given


def make_env(agent: TrainedAgent, seed: int, render_mode: str | None, n_envs: int = 1, log_dir: str | None = None):
    """The env the agent plays, as rl-zoo3's enjoy makes it (``create_test_env``: its wrappers, frame stack and
    normalisation statistics), from the settings read as data.

    :param agent: the agent
    :param seed: the env's seed
    :param render_mode: None, ``"human"`` (a window) or ``"rgb_array"`` (frames for a video)
    :param n_envs: sub-envs (in one process)
    :param log_dir: where rl-zoo3's enjoy logs the rewards (``--reward-log``), or None
    """
    from rl_zoo3.utils import create_test_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    env_kwargs = dict(agent.env_kwargs)
    if render_mode is not None:
        env_kwargs["render_mode"] = render_mode
    stats = agent.run.config_dir
    try:
        return create_test_env(
            agent.env_id,
            n_envs=n_envs,
            stats_path=str(stats) if stats.is_dir() else None,
            seed=seed,
            log_dir=log_dir,
            should_render=False,  # the render mode is in env_kwargs
            hyperparams=dict(agent.hyperparams),
            env_kwargs=env_kwargs,
            vec_env_cls=DummyVecEnv,
        )
    except (TypeError, ValueError) as error:  # what the env refuses: a kwarg the id does not take, a bad value
        raise ZooError(f"{agent.env_id} with {env_kwargs}: {first_line(error)}") from None


def load_model(agent: TrainedAgent, env: VecEnv, device: str, seed: int) -> BaseAlgorithm:
    """The agent's model on ``env``, as rl-zoo3's enjoy loads it (its learning rates and schedules replaced),
    without the memory of a replay buffer. SB3 checks the env against the model as it loads: an env that does not
    give the observations it was trained on is refused in one line."""
    from rl_zoo3.utils import ALGOS
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    custom_objects: dict[str, Any] = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    kwargs: dict[str, Any] = {"seed": seed}
    if issubclass(ALGOS[agent.algo], OffPolicyAlgorithm):
        kwargs["buffer_size"] = 1
        if "optimize_memory_usage" in agent.hyperparams:
            kwargs["optimize_memory_usage"] = False
    try:
        return ALGOS[agent.algo].load(agent.model_path, env, device, custom_objects=custom_objects, **kwargs)
    except ValueError as error:
        if "spaces do not match" in str(error):  # SB3's check_for_correct_spaces
            raise _mismatch(error) from None
        raise _unloadable(agent, error) from None
    except Exception as error:  # SB3 raises what the zip's contents make it raise
        raise _unloadable(agent, error) from None


def _unloadable(agent: TrainedAgent, error: Exception) -> ZooError:
    return ZooError(f"{agent.model_path}: the model does not load ({type(error).__name__}: {first_line(error)})")


def _mismatch(error: Exception) -> ZooError:
    return ZooError(
        "the env does not give the observations the agent was trained on (leave out --env-kwargs that change "
        f"obs_type, image_size or observe_parameter; split and domain are fine): {first_line(error)}"
    )


def display_available() -> bool:
    """Whether a window can be shown: a desktop (macOS, Windows), an X or Wayland display, or an SDL video driver
    named (``SDL_VIDEODRIVER``, e.g. ``dummy``), which pygame draws the window with."""
    if sys.platform in ("darwin", "win32"):
        return True
    return any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"))
