"""The data the benchmarks ship, read from a user's folder, and the built-in procedural stand-ins with the same
geometry (the same number of sources, frames per source, keys and value ranges), used when no folder is given.

- DMC-GB's colour sets (``color_easy.pt``, ``color_hard.pt``: 100 dicts of ``grid_rgb1``, ``grid_rgb2``,
  ``self_rgb``, ``skybox_rgb``) and its clips (``video_easy/video{0..9}.mp4``, ``video_hard/video{0..99}.mp4``),
  the layout of its ``src/env/data`` folder (and of DMC-GB2's ``envs/dmcgb/data``, which holds the same files).
- DAVIS 2017 (the Distracting Control Suite's backgrounds): one folder of JPEG frames per video, as in
  ``DAVIS/JPEGImages/480p``.

Every clip here is a :class:`~sgfd_envs.backgrounds.BackgroundSource` of square frames, decoded on first use.
"""

from __future__ import annotations

import io
import pickle
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np
from dm_control.suite import common

from sgfd_envs.background_splits import IMAGE_SUFFIXES, existing_folder
from sgfd_envs.backgrounds import (
    BackgroundSource,
    ImageBackground,
    ProceduralBackground,
    VideoBackground,
)
from sgfd_envs.benchmarks.scene import suite_texture_attributes
from sgfd_envs.limits import check_data_file_bytes

COLOUR_KEYS = ("grid_rgb1", "grid_rgb2", "self_rgb", "skybox_rgb")
COLOUR_SET_SIZE = 100
# Measured on DMC-GB's shipped sets: every colour is dm_control's default plus independent Gaussian noise per
# channel (kurtosis 3.0), clipped to [0, 1]: std 0.10 in color_easy, 0.20 in color_hard (0.17-0.19 once the
# clipped values are left out); grid_rgb2 is always grid_rgb1 + 0.1.
COLOUR_NOISE_STD = {"easy": 0.1, "hard": 0.2}
GRID_CHECKER_OFFSET = 0.1
# Seed banks of the stand-ins, disjoint from each other and from sgfd_envs.backgrounds' banks (0-3, 1000-1003,
# 2000-2031).
PROCEDURAL_COLOUR_SEEDS = {"easy": 5000, "hard": 5001}
DMCGB_CLIP_COUNTS = {"video_easy": 10, "video_hard": 100}
# DMC-GB's clips: video_easy 497-828 frames (about 750), video_hard 500 frames each.
DMCGB_CLIP_FRAMES = {"video_easy": 750, "video_hard": 500}
DMCGB_CLIP_SEEDS = {"video_easy": 3000, "video_hard": 3100}
DAVIS_SEEDS = {"train": 4000, "validation": 4100}
# DAVIS 2017's clips are 25-104 frames long; the stand-ins draw their length from about that range.
DAVIS_FRAMES_RANGE = (50, 100)
# The stand-ins are drawn at most this large and resized (bilinear) to a bigger texture: a procedural frame costs
# FFTs of 4x its side, and a stand-in's detail is no benchmark's anyway.
STAND_IN_MAX_SIDE = 256


# --- colour sets -----------------------------------------------------------------------------------------


class _ArrayUnpickler(pickle.Unpickler):
    """Unpickles only lists, dicts, floats and numpy arrays (what DMC-GB's colour files hold): a file cannot
    run code while it is read."""

    _ALLOWED: ClassVar[set[tuple[str, str]]] = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
        ("_codecs", "encode"),
        ("collections", "OrderedDict"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"{module}.{name} is not allowed in a colour file")
        return super().find_class(module, name)


def _unpickle_torch_file(path: Path) -> object:
    """The object of a file written by ``torch.save`` holding no tensors (legacy or zip format)."""
    check_data_file_bytes(path, path.stat().st_size)
    raw = path.read_bytes()
    if zipfile.is_zipfile(io.BytesIO(raw)):
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            name = next((n for n in archive.namelist() if n.endswith("data.pkl")), None)
            if name is None:
                raise ValueError(f"data_dir: {str(path)!r} is a zip file without data.pkl, not a torch.save file")
            check_data_file_bytes(path, archive.getinfo(name).file_size, f"{name}'s inflated size")
            return _ArrayUnpickler(io.BytesIO(archive.read(name))).load()
    handle = io.BytesIO(raw)
    # The legacy format: a magic number, the protocol version and system info, then the object.
    for _ in range(3):
        _ArrayUnpickler(handle).load()
    return _ArrayUnpickler(handle).load()


def read_colour_set(path: str | Path) -> list[dict[str, np.ndarray]]:
    """One of DMC-GB's colour files: a list of at least 100 dicts of RGB triples in [0, 1].

    :param path: ``color_easy.pt`` or ``color_hard.pt``
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"data_dir: no colour file {str(path)!r} (DMC-GB's src/env/data/{path.name})")
    try:
        entries = _unpickle_torch_file(path)
    except (pickle.UnpicklingError, EOFError, ValueError) as error:
        raise ValueError(f"data_dir: {str(path)!r} is not one of DMC-GB's colour files: {error}") from error
    if not isinstance(entries, list) or len(entries) < COLOUR_SET_SIZE:
        raise ValueError(f"data_dir: {str(path)!r} must hold a list of at least {COLOUR_SET_SIZE} colour dicts")
    colours = []
    for index, entry in enumerate(entries):
        if not isinstance(entry, dict) or set(entry) != set(COLOUR_KEYS):
            raise ValueError(f"data_dir: entry {index} of {str(path)!r} must have exactly the keys {COLOUR_KEYS}")
        values = {key: np.asarray(entry[key], dtype=np.float64).reshape(-1) for key in COLOUR_KEYS}
        if any(v.shape != (3,) or not np.all((v >= 0) & (v <= 1)) for v in values.values()):
            raise ValueError(f"data_dir: entry {index} of {str(path)!r} must hold RGB triples in [0, 1]")
        colours.append(values)
    return colours


def _rgb(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split()[:3]])


def default_colours() -> dict[str, np.ndarray]:
    """dm_control's own colours of the four keys (the centre DMC-GB's sets are drawn around)."""
    grid = suite_texture_attributes("grid")
    materials = ET.fromstring(common.ASSETS["./common/materials.xml"])
    self_rgba = next(m for m in materials.iter("material") if m.get("name") == "self").get("rgba")
    if self_rgba is None:
        raise KeyError("dm_control's materials.xml gives its 'self' material no rgba")
    return {
        "grid_rgb1": _rgb(grid["rgb1"]),
        "grid_rgb2": _rgb(grid["rgb2"]),
        "self_rgb": _rgb(self_rgba),
        "skybox_rgb": _rgb(suite_texture_attributes("skybox")["rgb1"]),
    }


def procedural_colour_set(difficulty: str, size: int = COLOUR_SET_SIZE) -> list[dict[str, np.ndarray]]:
    """A stand-in for DMC-GB's ``color_<difficulty>.pt``, drawn the way the shipped sets are distributed.

    :param difficulty: ``"easy"`` or ``"hard"``
    :param size: number of entries
    """
    if difficulty not in COLOUR_NOISE_STD:
        raise ValueError(f"difficulty must be one of {tuple(COLOUR_NOISE_STD)}, got {difficulty!r}")
    rng = np.random.default_rng(PROCEDURAL_COLOUR_SEEDS[difficulty])
    centre = default_colours()
    colours = []
    for _ in range(size):
        entry = {
            key: np.clip(centre[key] + rng.normal(0.0, COLOUR_NOISE_STD[difficulty], 3), 0.0, 1.0)
            for key in ("grid_rgb1", "self_rgb", "skybox_rgb")
        }
        entry["grid_rgb2"] = entry["grid_rgb1"] + GRID_CHECKER_OFFSET
        colours.append(entry)
    return colours


def colour_set(difficulty: str, data_dir: str | Path | None) -> list[dict[str, np.ndarray]]:
    """DMC-GB's colour set of a difficulty: from ``data_dir`` or the procedural stand-in.

    :param difficulty: ``"easy"`` or ``"hard"``
    :param data_dir: DMC-GB's data folder, or None
    """
    if data_dir is None:
        return procedural_colour_set(difficulty)
    return read_colour_set(check_data_dir(data_dir) / f"color_{difficulty}.pt")


def check_data_dir(data_dir: str | Path) -> Path:
    """``data_dir`` as a Path if it is an existing folder, else a FileNotFoundError naming it."""
    return existing_folder(
        data_dir,
        "data_dir",
        "give DMC-GB's src/env/data, which holds color_easy.pt, color_hard.pt, video_easy/ and video_hard/",
    )


# --- clips -----------------------------------------------------------------------------------------------


class ResizedSource:
    """A source's frames resized (bilinear) to size x size, each once.

    :param source: the frames
    :param size: frame height and width
    """

    def __init__(self, source: BackgroundSource, size: int) -> None:
        self._source = source
        self.size = size
        self._cache: dict[int, np.ndarray] = {}

    @property
    def n_frames(self) -> int:
        return self._source.n_frames

    def frame(self, index: int) -> np.ndarray:
        index %= self.n_frames
        if index not in self._cache:
            frame = self._source.frame(index)
            self._cache[index] = cv2.resize(frame, (self.size, self.size), interpolation=cv2.INTER_LINEAR)
        return self._cache[index]


def procedural_clip(seed: int, size: int, n_frames: int) -> BackgroundSource:
    """A procedural stand-in clip of size x size frames (drawn at most :data:`STAND_IN_MAX_SIDE` large)."""
    drawn = ProceduralBackground(seed, min(size, STAND_IN_MAX_SIDE), min(size, STAND_IN_MAX_SIDE), n_frames=n_frames)
    return drawn if size <= STAND_IN_MAX_SIDE else ResizedSource(drawn, size)


class ClipBank:
    """The clips of one mode or split, opened one at a time (only the current clip's frames stay in memory).

    :param names: one name per clip, for messages
    :param open_clip: opens clip i
    """

    def __init__(self, names: Sequence[str], open_clip: Callable[[int], BackgroundSource]) -> None:
        self.names = tuple(names)
        self._open = open_clip
        self._index: int | None = None
        self._clip: BackgroundSource | None = None

    def __len__(self) -> int:
        return len(self.names)

    def clip(self, index: int) -> BackgroundSource:
        """Clip ``index`` (the previous one is released)."""
        if self._clip is None or index != self._index:
            self._clip = self._open(index)
            self._index = index
        return self._clip


def dmcgb_clips(
    mode: str, size: int, data_dir: str | Path | None, interpolation: int = cv2.INTER_LINEAR, halvings: int = 0
) -> ClipBank:
    """DMC-GB's clips of ``video_easy`` (10) or ``video_hard`` (100), from ``data_dir`` or procedural.

    :param mode: ``"video_easy"`` or ``"video_hard"``
    :param size: the side each frame is resized to
    :param data_dir: DMC-GB's data folder, or None for the stand-ins
    :param interpolation: OpenCV interpolation of the resize
    :param halvings: 2x2 averagings after it (frames of side ``size >> halvings``; the stand-ins are drawn so)
    """
    count = DMCGB_CLIP_COUNTS[mode]
    if data_dir is None:
        seeds = [DMCGB_CLIP_SEEDS[mode] + i for i in range(count)]
        return ClipBank(
            [f"procedural {seed}" for seed in seeds],
            lambda i: procedural_clip(seeds[i], size >> halvings, DMCGB_CLIP_FRAMES[mode]),
        )
    folder = check_data_dir(data_dir) / mode
    paths = [folder / f"video{i}.mp4" for i in range(count)]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(
            f"data_dir: {str(folder)!r} lacks {len(missing)} of DMC-GB's {count} clips ({', '.join(missing[:5])}"
            f"{', ...' if len(missing) > 5 else ''})"
        )

    def open_clip(i: int) -> BackgroundSource:
        return VideoBackground(
            paths[i], size, size, None, crop=False, interpolation=interpolation, halvings=halvings, argument="data_dir"
        )

    return ClipBank([str(p) for p in paths], open_clip)


def davis_clips(
    videos: Sequence[str],
    split: str,
    size: int,
    background_dir: str | Path | None,
    interpolation: int = cv2.INTER_AREA,
    halvings: int = 0,
) -> ClipBank:
    """DAVIS videos by name (the Distracting Control Suite's lists), from ``background_dir`` or procedural.

    :param videos: the video names, in order
    :param split: ``"train"`` or ``"validation"`` (picks the stand-ins' seed bank)
    :param size: the side each frame is resized to
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder (or the DAVIS folder above it), or None
    :param interpolation: OpenCV interpolation of the resize of DAVIS's frames
    :param halvings: 2x2 averagings after it (frames of side ``size >> halvings``; the stand-ins are drawn so)
    """
    if background_dir is None:
        seeds = [DAVIS_SEEDS[split] + i for i in range(len(videos))]

        def procedural(i: int) -> BackgroundSource:
            length = int(np.random.default_rng(seeds[i]).integers(DAVIS_FRAMES_RANGE[0], DAVIS_FRAMES_RANGE[1] + 1))
            return procedural_clip(seeds[i], size >> halvings, length)

        return ClipBank([f"procedural {seed}" for seed in seeds], procedural)
    folder = davis_folder(background_dir)
    missing = [name for name in videos if not (folder / name).is_dir()]
    if missing:
        raise FileNotFoundError(
            f"background_dir: {str(folder)!r} lacks {len(missing)} of the {len(videos)} DAVIS {split} videos this "
            f"split uses ({', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''})"
        )
    return ClipBank(list(videos), lambda i: davis_video(folder / videos[i], size, interpolation, halvings))


def davis_video(folder: Path, size: int, interpolation: int, halvings: int = 0) -> BackgroundSource:
    """A DAVIS video: its folder's images in name order (``00000.jpg``, ...), each resized whole to size x size.

    :param folder: the video's folder
    :param size: the side each frame is resized to
    :param interpolation: OpenCV interpolation of the resize
    :param halvings: 2x2 averagings after it
    """
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"background_dir: the video folder {str(folder)!r} holds no image")
    return ImageBackground(files, size, size, crop=False, interpolation=interpolation, halvings=halvings)


def davis_folder(background_dir: str | Path) -> Path:
    """The folder of DAVIS's video folders: ``background_dir`` itself or its ``JPEGImages/480p``."""
    folder = existing_folder(
        background_dir, "background_dir", "give DAVIS's JPEGImages/480p, which holds one folder of frames per video"
    )
    nested = folder / "JPEGImages" / "480p"
    return nested if nested.is_dir() else folder
