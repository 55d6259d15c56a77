"""``sgfd-zoo enjoy``: watch or roll out a trained agent, as rl-zoo3's enjoy does, on any split and domain.

The zoo reads the command line and the run's saved settings itself (as data: :mod:`sgfd_zoo.trained`), then does
what ``rl_zoo3.enjoy.enjoy`` does with rl-zoo3's and SB3's public pieces: it makes the env (``create_test_env``),
loads the model and steps it, printing each episode's return and length. Without ``--no-render`` the env is shown
in a window (gymnasium's human rendering, drawn with pygame); a machine without a display is told in one line what
to use instead.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence

import numpy as np

from sgfd_zoo.arguments import (
    ZooArgumentParser,
    ZooError,
    check_env_id,
    check_key_values,
    command_parser,
    import_gym_packages,
)
from sgfd_zoo.trained import TrainedAgent, add_agent_options, display_available, find_agent, load_model, make_env


def enjoy_parser() -> ZooArgumentParser:
    """The options of ``sgfd-zoo enjoy``: rl-zoo3's enjoy's, and ``--split``, ``--domain``."""
    parser = command_parser("enjoy")
    add_agent_options(parser)
    rollout = parser.add_argument_group("the rollout")
    rollout.add_argument("-n", "--n-timesteps", type=int, default=1000, metavar="STEPS", help="steps (default: 1000)")
    rollout.add_argument("--n-envs", type=int, default=1, metavar="N", help="envs stepped together (default: 1)")
    rollout.add_argument("--no-render", action="store_true", help="no window (a machine without a display)")
    rollout.add_argument("--reward-log", default="", metavar="FOLDER", help="SB3's monitor files of the rollout")
    rollout.add_argument("-P", "--progress", action="store_true", help="a progress bar")
    return parser


def main(argv: Sequence[str]) -> int:
    """``sgfd-zoo enjoy`` on ``argv`` (the command line after ``enjoy``)."""
    args = enjoy_parser().parse_args(list(argv))
    if args.n_timesteps < 1 or args.n_envs < 1:
        raise ZooError(f"-n and --n-envs must be >= 1, got -n {args.n_timesteps} --n-envs {args.n_envs}")
    check_env_id(args.env)
    check_key_values("--env-kwargs", args.env_kwargs)  # the arguments first: then what this machine can show
    if not args.no_render:
        check_window()
    import_gym_packages(args.gym_packages)
    from sgfd_zoo.registration import register_algorithms

    register_algorithms()
    agent = find_agent(args)
    _set_up_torch(args.seed, args.num_threads)
    env = make_env(agent, args.seed, None if args.no_render else "human", args.n_envs, args.reward_log or None)
    try:
        model = load_model(agent, env, args.device, args.seed)
        rollout(agent, model, env, args)
    finally:
        env.close()
    return 0


def check_window() -> None:
    """A ZooError, in one line saying what to use instead, where no window can be shown: no display, or no pygame
    (what gymnasium's human rendering draws with)."""
    if not display_available():
        raise ZooError(
            "no display to show the agent on (DISPLAY is unset): add --no-render to roll it out without a window, "
            "or write a video with sgfd-zoo record-video (the same options)"
        )
    if importlib.util.find_spec("pygame") is None:
        raise ZooError(
            "a window needs pygame, which the human extra brings: pip install -e './sgfd_envs[human]' -c "
            "constraints.txt; or add --no-render, or write a video with sgfd-zoo record-video"
        )


def _set_up_torch(seed: int, num_threads: int) -> None:
    import torch as th
    from stable_baselines3.common.utils import set_random_seed

    set_random_seed(seed)
    if num_threads > 0:
        th.set_num_threads(num_threads)


def rollout(agent: TrainedAgent, model, env, args) -> None:
    """rl-zoo3's enjoy loop: ``-n`` steps, each episode's return and length printed (one env), their means at the
    end; Ctrl-C ends it early with the summary."""
    deterministic = not args.stochastic
    obs = env.reset()
    state = None
    episode_start = np.ones((env.num_envs,), dtype=bool)
    episode_return, episode_length = 0.0, 0
    returns: list[float] = []
    lengths: list[int] = []
    steps = range(args.n_timesteps)
    if args.progress:
        from tqdm.rich import tqdm

        steps = tqdm(steps)
    try:
        for _ in steps:
            action, state = model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
            obs, reward, done, _infos = env.step(action)
            episode_start = done
            episode_return += float(reward[0])
            episode_length += 1
            if args.n_envs == 1 and done[0]:
                if args.verbose > 0:
                    print(f"Episode Reward: {episode_return:.2f}")
                    print("Episode Length", episode_length)
                returns.append(episode_return)
                lengths.append(episode_length)
                episode_return, episode_length = 0.0, 0
    except KeyboardInterrupt:
        pass
    if args.verbose > 0 and returns:
        print(f"{len(returns)} Episodes ({agent.algo} on {agent.env_id}, env settings {agent.env_kwargs})")
        print(f"Mean reward: {np.mean(returns):.2f} +/- {np.std(returns):.2f}")
        print(f"Mean episode length: {np.mean(lengths):.2f} +/- {np.std(lengths):.2f}")
