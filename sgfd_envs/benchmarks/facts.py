"""What the id table knows of each benchmark: its name (the ids' prefix), its tasks with their action repeats, and
its splits (the undistracted ``train`` first, then the test modes). Import-light (no simulator, no OpenCV), so that
``import sgfd_envs`` and ``gym.spec`` load neither. Each benchmark's module (:mod:`~sgfd_envs.benchmarks.dmcgb`,
:mod:`~sgfd_envs.benchmarks.dmcgb2`, :mod:`~sgfd_envs.benchmarks.dcs`) describes these facts, holds the rest and
its distraction, and gives these under its own names (``dcs.TASKS``, ``dmcgb.MODES``).
"""

from __future__ import annotations

from collections.abc import Sequence

# --- DMC-GB ----------------------------------------------------------------------------------------------------

DMCGB = "DMCGB"
DMCGB_MODES = ("train", "color_easy", "color_hard", "video_easy", "video_hard")
# (domain, task) -> action repeat, DMC-GB's defaults: 4, but 2 on finger spin.
DMCGB_TASKS: dict[tuple[str, str], int] = {
    **dict.fromkeys([("walker", "walk"), ("walker", "stand"), ("cartpole", "swingup"), ("ball_in_cup", "catch")], 4),
    ("finger", "spin"): 2,
}
# DMC-GB's distracting_cs mode (DMC-GB2 tests on it too), a split with a parameter, its intensity.
DISTRACTING_CS = "distracting_cs"
# distracting_cs: intensity -> how many of DAVIS's training videos the background draws from (None: all 60).
DISTRACTING_CS_VIDEOS: dict[float, int | None] = {
    0.025: 2, 0.05: 2, 0.1: 4, 0.15: 6, 0.2: 8, 0.3: None, 0.4: None, 0.5: None
}  # fmt: skip
INTENSITIES = tuple(DISTRACTING_CS_VIDEOS)

# --- DMC-GB2 ---------------------------------------------------------------------------------------------------

DMCGB2 = "DMCGB2"
GEOMETRIC_MODES = ("rotate_easy", "rotate_hard", "shift_easy", "shift_hard", "rotate_shift_easy", "rotate_shift_hard")
PHOTOMETRIC_MODES = ("color_easy", "color_hard", "video_easy", "video_hard", "color_video_easy", "color_video_hard")
DMCGB2_MODES = ("train", *GEOMETRIC_MODES, *PHOTOMETRIC_MODES)
# (domain, task) -> action repeat: 2 on every task.
DMCGB2_TASKS: dict[tuple[str, str], int] = dict.fromkeys(
    [("walker", "walk"), ("walker", "stand"), ("cheetah", "run"), ("finger", "spin"), ("cartpole", "swingup"),
     ("ball_in_cup", "catch")],
    2,
)  # fmt: skip

# --- the Distracting Control Suite ---------------------------------------------------------------------------

DCS = "DCS"
DCS_SPLITS = ("train", "easy", "medium", "hard")
DIFFICULTY_SCALE = {"easy": 0.1, "medium": 0.2, "hard": 0.3}
DIFFICULTY_VIDEOS = {"easy": 4, "medium": 8, "hard": None}
# DCS's difficulty -> (scale, videos of the list); None: all of them.
DIFFICULTIES: dict[str, tuple[float, int | None]] = {
    name: (DIFFICULTY_SCALE[name], DIFFICULTY_VIDEOS[name]) for name in DIFFICULTY_SCALE
}
DISTRACTIONS = ("background", "camera", "colour")
VIDEO_SPLITS = ("train", "validation")
# (domain, task) -> action repeat. DCS's code fixes none; these are PlaNet's per-task values, which pixel-based
# agents (CURL, RAD, DrQ) use on these six tasks.
DCS_TASKS: dict[tuple[str, str], int] = {
    ("ball_in_cup", "catch"): 4,
    ("cartpole", "swingup"): 8,
    ("cheetah", "run"): 4,
    ("finger", "spin"): 2,
    ("reacher", "easy"): 4,
    ("walker", "walk"): 2,
}


def check_distractions(distractions: Sequence[str]) -> tuple[str, ...]:
    """``distractions`` as a tuple if it is a non-empty subset of :data:`DISTRACTIONS`, else a ValueError."""
    if isinstance(distractions, str):
        distractions = (distractions,)
    chosen = tuple(dict.fromkeys(distractions))
    unknown = [d for d in chosen if d not in DISTRACTIONS]
    if not chosen or unknown:
        raise ValueError(f"distractions must be a non-empty subset of {DISTRACTIONS}, got {tuple(distractions)!r}")
    return chosen
