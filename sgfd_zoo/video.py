"""``sgfd-zoo record-video``: an mp4 of a trained agent on any split and domain, as rl-zoo3's record_video makes
one for its own algorithms.

The frames are the env's own (``render_mode="rgb_array"``: the camera image with the domain's background,
colours or morphology, as the agent sees it), scaled up without smoothing, and encoded with imageio's ffmpeg
(imageio-ffmpeg ships the binary: no ffmpeg on the PATH is needed).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_at_least, command_parser, import_gym_packages
from sgfd_zoo.runs.safe import make_folder, write_file
from sgfd_zoo.trained import TrainedAgent, add_agent_options, find_agent, load_model, make_env


def video_parser() -> ZooArgumentParser:
    """The options of ``sgfd-zoo record-video``: enjoy's choice of agent and env, and the video's."""
    parser = command_parser("record-video")
    add_agent_options(parser)
    video = parser.add_argument_group("the video")
    video.add_argument("-n", "--n-timesteps", type=int, default=1000, metavar="STEPS", help="its length in env steps")
    video.add_argument(
        "-o", "--output-folder", metavar="FOLDER", help="where it goes (default: the run's videos/ folder)"
    )
    video.add_argument("--scale", type=int, default=4, help="each pixel as SCALE x SCALE (default: 4: 84 px -> 336)")
    video.add_argument("--fps", type=int, help="frames per second (default: the env's real time)")
    return parser


def main(argv: Sequence[str]) -> int:
    """``sgfd-zoo record-video`` on ``argv`` (the command line after ``record-video``)."""
    args = video_parser().parse_args(list(argv))
    check_at_least("-n", args.n_timesteps, 1)
    check_at_least("--scale", args.scale, 1)
    check_at_least("--fps", args.fps, 1)
    import_gym_packages(args.gym_packages)
    from sgfd_zoo.registration import register_algorithms

    register_algorithms()
    agent = find_agent(args)
    folder = Path(args.output_folder) if args.output_folder else agent.run.path / "videos"
    path = folder / f"{video_name(agent)}-step-0-to-step-{args.n_timesteps}.mp4"
    shown = {"seed": args.seed, "device": args.device, "deterministic": not args.stochastic, "scale": args.scale}
    root = None if args.output_folder else agent.run.root  # inside the log folder: no link followed on the way
    print(f"Saved {record_video(agent, path, args.n_timesteps, fps=args.fps, root=root, **shown)}")
    return 0


def video_name(agent: TrainedAgent) -> str:
    """``final-model-<algo>-<EnvName>-<split>-domain<d>`` (rl-zoo3 names its videos ``final-model-<algo>-<EnvName>``);
    a checkpoint's ``checkpoint-<steps>-...``."""
    stem = agent.model_path.stem
    model = "final-model" if stem == agent.run.model_path.stem else stem.replace("_steps", "").replace("_", "-")
    split = agent.env_kwargs.get("split", "train")
    domain = agent.env_kwargs.get("domain", 0)
    return f"{model}-{agent.algo}-{agent.run.config_dir.name}-{split}-domain{domain}"


def record_video(
    agent: TrainedAgent,
    path: Path,
    n_steps: int,
    seed: int = 0,
    device: str = "auto",
    deterministic: bool = True,
    scale: int = 4,
    fps: int | None = None,
    root: Path | None = None,
) -> Path:
    """Roll ``agent`` out for ``n_steps`` on its env and write the frames to ``path`` (an mp4), whole or not at all.

    :param agent: the agent and the env it plays
    :param path: the mp4 to write (its folder is made)
    :param n_steps: env steps (frames after the first)
    :param seed: the env's and actions' seed
    :param device: torch's device
    :param deterministic: deterministic actions
    :param scale: each pixel as ``scale`` x ``scale`` pixels
    :param fps: frames per second; None: the env's real time (its ``render_fps``)
    :param root: a folder the video goes inside with no symbolic link on the way (a log folder); None: the user's
    """
    env = make_env(agent, seed, "rgb_array")
    try:
        model = load_model(agent, env, device, seed)
        if fps is None:
            fps = int(env.get_attr("metadata", [0])[0].get("render_fps", 25))
        if root is None:  # the user's own path
            path.parent.mkdir(parents=True, exist_ok=True)
        make_folder(root or path.parent, path.parent)
        frames = played_frames(model, env, n_steps, deterministic, scale)
        write_file(root or path.parent, path, lambda tmp: write_mp4(tmp, frames, fps))
    finally:
        env.close()
    return path


def played_frames(model: Any, env: Any, n_steps: int, deterministic: bool, scale: int) -> Iterator[np.ndarray]:
    """The env's frame after reset and after each of ``n_steps`` steps of ``model``'s actions, scaled up."""
    obs = env.reset()
    state = None
    episode_start = np.ones((env.num_envs,), dtype=bool)
    yield _scaled(env.get_images()[0], scale)
    for _ in range(n_steps):
        action, state = model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        obs, _reward, episode_start, _infos = env.step(action)
        yield _scaled(env.get_images()[0], scale)


def _scaled(frame: np.ndarray | None, scale: int) -> np.ndarray:
    if frame is None:
        raise ZooError("the env gives no frame to record (its render_mode is not rgb_array)")
    return np.repeat(np.repeat(np.asarray(frame, dtype=np.uint8), scale, axis=0), scale, axis=1)


def write_mp4(path: str, frames: Iterator[np.ndarray], fps: int) -> None:
    """``frames`` (RGB, uint8, all of one size) as an H.264 mp4 at ``path``, with imageio-ffmpeg's own ffmpeg."""
    import imageio_ffmpeg

    frames = iter(frames)
    first = next(frames)
    height, width = first.shape[:2]
    # macro_block_size 2: H.264's 4:2:0 needs even sides only (the default, 16, would resize 84 px frames)
    writer = imageio_ffmpeg.write_frames(
        path, (width, height), fps=fps, codec="libx264", macro_block_size=2, output_params=["-f", "mp4"]
    )
    writer.send(None)  # starts ffmpeg
    try:
        for frame in itertools.chain([first], frames):
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()
