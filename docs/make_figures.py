"""Draw every picture of the docs site and the README from the environments themselves.

Run from the repository root after a change to the rendering, then commit the PNGs it rewrites:

    python docs/make_figures.py            # every figure
    python docs/make_figures.py --only dmcgb dcs

Each tile is the pixel observation an agent gets (84x84) after a few random actions, from a fixed seed, so the
pictures change only when the environments do. The studies' aggregate figures are copied from ``studies/``
(``sgfd-zoo study`` draws them).
"""

from __future__ import annotations

import argparse
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import sgfd_envs
from sgfd_envs.demo import benchmark_observations, rollout
from sgfd_envs.families import EARLIER_FAMILY
from sgfd_envs.morphology import DEFAULT_MT_ROBOTS
from sgfd_envs.registry import BACKGROUND, MORPHOLOGY

DOCS = Path(__file__).resolve().parent
STUDIES = DOCS.parent / "studies"
TILE = 112  # pixels per observation in the pictures (observations are 84x84; nearest-neighbour upscaling)
LABEL_HEIGHT = 30
STEPS = 30  # random agent steps after reset, so the robot is in motion
SEED = 0


def observation(env_id: str, **env_kwargs: Any) -> np.ndarray:
    """The uint8 (84, 84, 3) observation of ``env_id`` after :data:`STEPS` seeded random actions (the demo's).

    :param env_id: a registered id
    :param env_kwargs: passed to ``gym.make`` (split, domain, setting, ...)
    """
    return rollout(env_id, STEPS, SEED, **env_kwargs)[0]


def tile(pixels: np.ndarray, *lines: str, size: int = TILE) -> np.ndarray:
    """An observation resized to ``size`` pixels square, with up to two caption lines above it."""
    image = cv2.resize(pixels, (size, size), interpolation=cv2.INTER_NEAREST)
    label = np.full((LABEL_HEIGHT, size, 3), 255, dtype=np.uint8)
    for row, line in enumerate(lines[:2]):
        cv2.putText(label, line, (3, 12 + 14 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([label, image])


def grid(rows: list[list[np.ndarray]]) -> np.ndarray:
    """Tiles in rows (each row padded with white to the longest), with a 2-pixel white gap between tiles."""
    width = max(len(row) for row in rows)
    blank = np.full_like(rows[0][0], 255)
    gap = np.full((rows[0][0].shape[0], 2, 3), 255, dtype=np.uint8)
    lines = []
    for row in rows:
        padded = row + [blank] * (width - len(row))
        lines.append(np.hstack([part for t in padded for part in (t, gap)][:-1]))
    return np.vstack(lines)


# The families drawn: the paper's (the defaults) and the one before version 0.3.0 (sgfd_envs.families' table).
BACKGROUND_FAMILIES: dict[str, dict[str, Any]] = {"paper": {}, "earlier": EARLIER_FAMILY[BACKGROUND]}
ROBOT_FAMILIES = (DEFAULT_MT_ROBOTS, EARLIER_FAMILY[MORPHOLOGY]["robots"])


def backgrounds() -> np.ndarray:
    """SGFD background ids: the training domains and the unseen test domains of two tasks, in the paper's setup
    (one still image per domain under the authors' colour key, one test domain) and in the earlier family (moving
    textures behind dm_control's robots by coverage, four test domains).

    At the observations' own size: the moving textures do not compress, and this keeps the file small.
    """
    rows = []
    for task in ("walker-walk", "finger-spin"):
        env_id = f"SGFD/{task}-v0"
        for family, kwargs in BACKGROUND_FAMILIES.items():
            row = []
            for split in ("train", "test"):
                for domain in range(sgfd_envs.n_domains(env_id, split, **kwargs)):
                    pixels = observation(env_id, split=split, domain=domain, **kwargs)
                    row.append(tile(pixels, f"{task.split('-')[0]} {family}", f"{split} {domain}", size=84))
            rows.append(row)
    return grid(rows)


def morphology() -> np.ndarray:
    """SGFD/MT ids: every domain of every split (train, interpolation, extrapolation), with its setting, for
    HiP-BMDP's robot files (the default) and this package's scaled robots."""
    rows = []
    for task in ("walker-walk", "cheetah-run", "finger-spin"):
        env_id = f"SGFD/MT-{task}-v0"
        for robots in ROBOT_FAMILIES:
            row = []
            for split in sgfd_envs.splits(env_id):
                for domain in range(sgfd_envs.n_domains(env_id, split, robots=robots)):
                    pixels, label = rollout(env_id, STEPS, SEED, split=split, domain=domain, robots=robots)
                    caption = f"{split[:6]} s{label.setting} {label.morphology_value:.3g} m"
                    row.append(tile(pixels, f"{task} {robots}", caption))
            rows.append(row)
    return grid(rows)


def benchmark(name: str, tasks: tuple[str, ...]) -> Callable[[], np.ndarray]:
    """A function drawing a benchmark: one row per task, one column per split (train, then each test mode).

    :param name: ``"DMCGB"``, ``"DMCGB2"`` or ``"DCS"``
    :param tasks: task names as in the ids (``"walker-walk"``)
    """

    def draw() -> np.ndarray:
        rows = benchmark_observations(name, STEPS, SEED, tasks=tasks)
        return grid([[tile(pixels, task, split) for task, split, pixels in row] for row in rows])

    return draw


def overview() -> np.ndarray:
    """The README's picture: one training domain and the unseen domains of each family, in one row."""
    shown: list[tuple[str, dict[str, Any], str, str]] = [
        ("SGFD/walker-walk-v0", dict(split="train", domain=0), "backgrounds", "train 0"),
        ("SGFD/walker-walk-v0", dict(split="test", domain=0), "backgrounds", "test 0 (unseen)"),
        ("SGFD/MT-walker-walk-v0", dict(split="train", domain=0), "morphology", "train s2"),
        ("SGFD/MT-walker-walk-v0", dict(split="extrapolation"), "morphology", "extrap. s10 (unseen)"),
        ("DMCGB/walker-walk-v0", dict(split="video_hard"), "DMC-GB", "video_hard"),
        ("DMCGB2/walker-walk-v0", dict(split="rotate_shift_hard"), "DMC-GB2", "rotate_shift_hard"),
        ("DCS/walker-walk-v0", dict(split="hard"), "DCS", "hard"),
    ]
    return grid([[tile(observation(env_id, **kwargs), family, caption) for env_id, kwargs, family, caption in shown]])


FIGURES: dict[str, tuple[str, Callable[[], np.ndarray]]] = {
    "overview": ("envs-overview.png", overview),
    "backgrounds": ("envs-backgrounds.png", backgrounds),
    "morphology": ("envs-morphology.png", morphology),
    "dmcgb": ("benchmark-dmcgb.png", benchmark("DMCGB", ("walker-walk", "cartpole-swingup", "finger-spin"))),
    "dmcgb2": ("benchmark-dmcgb2.png", benchmark("DMCGB2", ("walker-walk", "cheetah-run"))),
    "dcs": ("benchmark-dcs.png", benchmark("DCS", ("walker-walk", "cheetah-run", "reacher-easy"))),
}
# The studies' aggregate figures (interval estimates of the IQM on extrapolation), copied as they are.
STUDY_FIGURES = {
    "study-mt-state-extrapolation.png": STUDIES / "mt-state" / "plots" / "aggregate_extrapolation.png",
    "study-sgfd-strength-extrapolation.png": STUDIES / "sgfd-strength" / "plots" / "aggregate_extrapolation.png",
}


def main(argv: list[str] | None = None) -> None:
    """Draw the chosen figures (default: all) into docs/ and copy the studies' figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=(*FIGURES, "studies"), help="draw only these figures")
    parser.add_argument("--out", type=Path, default=DOCS, help="folder to write into (default: docs/)")
    args = parser.parse_args(argv)
    chosen = args.only or [*FIGURES, "studies"]
    args.out.mkdir(parents=True, exist_ok=True)
    for key in chosen:
        if key == "studies":
            for name, source in STUDY_FIGURES.items():
                shutil.copyfile(source, args.out / name)
                print(f"copied {source.relative_to(DOCS.parent)} -> {args.out / name}")
            continue
        name, draw = FIGURES[key]
        start = time.perf_counter()
        image = draw()
        path = args.out / name
        # PNG compression 9: the pictures are flat-coloured tiles, so this keeps them small.
        if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9]):
            raise OSError(f"could not write {str(path)!r}")
        size_kb, seconds = path.stat().st_size / 1024, time.perf_counter() - start
        print(f"wrote {path} ({image.shape[1]}x{image.shape[0]}, {size_kb:.0f} KB, {seconds:.0f} s)")


if __name__ == "__main__":
    main()
