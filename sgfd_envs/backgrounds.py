"""Background sources (task-irrelevant variation) and compositing.

A source is a sequence of ``n_frames`` RGB frames (uint8, height x width x 3) read by index; the env
starts at a random index on reset and advances one frame per step, wrapping around. A still source has one frame.

- :class:`ProceduralBackground`: natural-looking (1/f noise) colour textures, deterministic per seed, from
  disjoint train and test seed banks, moving or (one frame) still. Needs no download.
- :class:`VideoBackground`: the first ``frame_budget`` frames of a video file, read with OpenCV
  (e.g. the Kinetics clips of DBC and AMBS).
- :class:`ImageBackground`: one still image (or a video stored as one image per frame).

Two ways to put a frame into the render: :func:`colour_key` (the SGFD authors' code, after DBC's: every pixel of the
whole render whose blue exceeds its red and its green takes the background's, which replaces the sky and a bluish
floor) and :func:`composite` (behind the robot by the render's coverage, floor and sky hidden). The authors' code
pastes the image as OpenCV reads it, in BGR order, into an RGB frame: :class:`ChannelsReversed`.

Which source is which domain of a split (the seed banks, a user's folder) is :mod:`sgfd_envs.background_splits`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from sgfd_envs.background_splits import (
    OVERLAY_SEEDS,
    PROCEDURAL_SEEDS,
    VIDEO_SUFFIXES,
    background_files,
    check_background_split,
    check_test_domains,
)
from sgfd_envs.limits import check_background_pixels, check_image_file

# Their home before they moved to the import-light module, kept.
from sgfd_envs.background_splits import BACKGROUND_SPLITS as BACKGROUND_SPLITS  # isort: skip
from sgfd_envs.background_splits import IMAGE_SUFFIXES as IMAGE_SUFFIXES  # isort: skip
from sgfd_envs.background_splits import n_background_domains as n_background_domains  # isort: skip

DEFAULT_FRAME_BUDGET = 1000


class BackgroundSource(Protocol):
    """A finite sequence of background frames."""

    @property
    def n_frames(self) -> int:
        """Number of frames; indices wrap around it."""
        ...

    def frame(self, index: int) -> np.ndarray:
        """Frame ``index % n_frames`` as uint8 (height, width, 3) RGB."""
        ...


def composite(rendered: np.ndarray, coverage: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Put ``background`` behind a render of the scene with its backdrop hidden: ``rendered + (1 - coverage) *
    background``, as drawing the background behind the scene would blend it into the scene's edges. Where the
    scene covers a pixel whole it stays as rendered; where nothing was drawn it is the background's.

    :param rendered: uint8 (H, W, 3) render with no floor and no skybox (colour weighted by coverage, as OpenGL's
        multisample resolve leaves it)
    :param coverage: uint8 (H, W) share of each pixel the scene covers, 0..255 (the render's alpha)
    :param background: uint8 (H, W, 3) background frame
    """
    uncovered = (255 - coverage.astype(np.uint16))[..., np.newaxis]
    blended = rendered + (uncovered * background + 127) // 255
    return np.minimum(blended, 255).astype(np.uint8)


def colour_key(rendered: np.ndarray, background: np.ndarray) -> np.ndarray:
    """The SGFD authors' background (``dmc2gym/wrappers.py``, ``_get_obs``, after DBC's): every pixel of the render
    whose blue channel exceeds its red and its green takes the background's pixel. On dm_control's scenes that is
    the sky and a bluish floor (the finger's), and any bluish part of a robot; the grey floors of the authors'
    walker and cheetah stay.

    :param rendered: uint8 (H, W, 3) RGB render of the whole scene (floor and skybox drawn)
    :param background: uint8 (H, W, 3) frame pasted under the mask, in the order given (the authors': BGR)
    """
    red, green, blue = rendered[..., 0], rendered[..., 1], rendered[..., 2]
    keyed = (blue > red) & (blue > green)
    frame = rendered.copy()
    frame[keyed] = background[keyed]
    return frame


class ChannelsReversed:
    """A source's frames with their channels reversed: an RGB frame as OpenCV's ``imread`` of its image gives it
    (BGR), which is what the SGFD authors' code pastes into the RGB render.

    :param source: the source of RGB frames
    """

    def __init__(self, source: BackgroundSource) -> None:
        self.source = source

    @property
    def n_frames(self) -> int:
        return self.source.n_frames

    def frame(self, index: int) -> np.ndarray:
        return self.source.frame(index)[..., ::-1]


def fit_frame(
    frame_bgr: np.ndarray,
    height: int,
    width: int,
    grayscale: bool = False,
    *,
    crop: bool = True,
    interpolation: int = cv2.INTER_AREA,
    halvings: int = 0,
) -> np.ndarray:
    """An OpenCV frame fitted to the observation: centre-cropped to its aspect ratio (or, with ``crop=False``, resized
    whole, as the benchmarks resize their clips), resized, made RGB, and halved ``halvings`` times (:func:`halve`).

    :param frame_bgr: uint8 (h, w, 3) BGR frame as OpenCV reads it
    :param height: output height
    :param width: output width
    :param grayscale: replicate the luma into the three channels (as DBC does)
    :param crop: centre-crop to the output's aspect ratio before resizing
    :param interpolation: OpenCV interpolation of the resize
    :param halvings: 2x2 averagings after the resize (a texture's mip level, see
        :class:`sgfd_envs.benchmarks.scene.VideoTexture`)
    """
    if crop:
        rows, cols = frame_bgr.shape[:2]
        if cols * height > rows * width:
            keep = max(1, round(rows * width / height))
            start = (cols - keep) // 2
            frame_bgr = frame_bgr[:, start : start + keep]
        else:
            keep = max(1, round(cols * height / width))
            start = (rows - keep) // 2
            frame_bgr = frame_bgr[start : start + keep]
    resized = halve(cv2.resize(frame_bgr, (width, height), interpolation=interpolation), halvings)
    if grayscale:
        return np.repeat(cv2.cvtColor(resized, cv2.COLOR_BGR2GRAY)[..., np.newaxis], 3, axis=2)
    return cv2.cvtColor(resized, cv2.COLOR_BGR2RGB)


def halve(image: np.ndarray, times: int = 1) -> np.ndarray:
    """``image`` halved ``times`` times, each pixel the average of a 2x2 block (rounded), as a GPU makes a texture's
    next mip level.

    :param image: uint8 (H, W, C) image, H and W divisible by ``2 ** times``
    :param times: how many halvings
    """
    for _ in range(times):
        image = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)
    return image


# --- built-in procedural source ------------------------------------------------------------------


def _noise_field(rng: np.random.Generator, size: int, spectral_slope: float) -> np.ndarray:
    """A tileable (periodic) noise image in [0, 1] with power spectrum 1/f**spectral_slope.

    Natural images have a slope near 2; the inverse FFT makes the field wrap seamlessly.
    """
    fy = np.fft.fftfreq(size)[:, np.newaxis]
    fx = np.fft.rfftfreq(size)[np.newaxis, :]
    radius = np.hypot(fx, fy)
    radius[0, 0] = np.inf
    amplitude = radius ** (-spectral_slope / 2)
    spectrum = amplitude * (rng.standard_normal(radius.shape) + 1j * rng.standard_normal(radius.shape))
    field = np.fft.irfft2(spectrum, s=(size, size))
    low, high = np.percentile(field, (1, 99))
    return np.clip((field - low) / (high - low), 0.0, 1.0)


def _colour_texture(rng: np.random.Generator, size: int, spectral_slope: float) -> np.ndarray:
    """A tileable uint8 RGB texture: one noise field through a random colour ramp, shaded by another."""
    anchors = rng.uniform(0, 255, size=(5, 3))
    levels = np.linspace(0.0, 1.0, len(anchors))
    ramp = np.stack([np.interp(np.linspace(0, 1, 256), levels, anchors[:, c]) for c in range(3)], axis=1)
    hue = (_noise_field(rng, size, spectral_slope) * 255).astype(np.uint8)
    shade = 0.55 + 0.45 * _noise_field(rng, size, spectral_slope + 0.5)
    return np.clip(ramp[hue] * shade[..., np.newaxis], 0, 255).astype(np.uint8)


def _lissajous_path(rng: np.random.Generator, n_frames: int, extent: int, cycles: tuple[int, int]) -> np.ndarray:
    """Integer (row, col) offsets along a smooth closed curve that returns to its start after n_frames."""
    t = np.arange(n_frames) / n_frames
    phases = rng.uniform(0, 2 * np.pi, size=2)
    rows = extent / 2 * (1 + np.sin(2 * np.pi * cycles[0] * t + phases[0]))
    cols = extent / 2 * (1 + np.sin(2 * np.pi * cycles[1] * t + phases[1]))
    return np.stack([rows, cols], axis=1).round().astype(np.int64) % extent


class ProceduralBackground:
    """Two layers of moving colour noise: a slow backdrop and faster drifting blobs in front of it.

    :param seed: texture seed; the same seed always gives the same frames
    :param height: frame height
    :param width: frame width
    :param n_frames: length of the (looping) sequence
    :param grayscale: replicate the luma into the three channels
    """

    def __init__(
        self, seed: int, height: int, width: int, n_frames: int = DEFAULT_FRAME_BUDGET, grayscale: bool = False
    ) -> None:
        self.seed, self.height, self.width, self._n_frames = seed, height, width, n_frames
        self.grayscale = grayscale
        self._layers: tuple[np.ndarray, ...] | None = None

    @property
    def n_frames(self) -> int:
        return self._n_frames

    def _build(self) -> tuple[np.ndarray, ...]:
        rng = np.random.default_rng(self.seed)
        size = 4 * max(self.height, self.width)
        backdrop = _colour_texture(rng, size, spectral_slope=2.8)
        blobs = _colour_texture(rng, size, spectral_slope=2.3)
        # Soft-edged blob mask: a smooth field pushed through a steep ramp around its mid-level.
        mask_field = _noise_field(rng, size, spectral_slope=3.0)
        blob_alpha = (np.clip((mask_field - 0.5) * 6 + 0.5, 0, 1) * 255).astype(np.uint16)
        if self.grayscale:
            backdrop, blobs = (
                np.repeat(cv2.cvtColor(t, cv2.COLOR_RGB2GRAY)[..., None], 3, axis=2) for t in (backdrop, blobs)
            )
        # Pad by one frame so any offset in [0, size) crops a contiguous window of the tiled texture.
        pad = ((0, self.height), (0, self.width))
        backdrop = np.pad(backdrop, (*pad, (0, 0)), mode="wrap").astype(np.uint16)
        blobs = np.pad(blobs, (*pad, (0, 0)), mode="wrap").astype(np.uint16)
        blob_alpha = np.pad(blob_alpha, pad, mode="wrap")[..., np.newaxis]
        backdrop_path = _lissajous_path(rng, self._n_frames, size, cycles=(1, 2))
        blobs_path = _lissajous_path(rng, self._n_frames, size, cycles=(3, 2))
        return backdrop, blobs, blob_alpha, backdrop_path, blobs_path

    def frame(self, index: int) -> np.ndarray:
        if self._layers is None:
            self._layers = self._build()
        backdrop, blobs, blob_alpha, backdrop_path, blobs_path = self._layers
        index %= self._n_frames
        (r0, c0), (r1, c1) = backdrop_path[index], blobs_path[index]
        rows0, cols0 = slice(r0, r0 + self.height), slice(c0, c0 + self.width)
        rows1, cols1 = slice(r1, r1 + self.height), slice(c1, c1 + self.width)
        alpha = blob_alpha[rows1, cols1]
        mixed = blobs[rows1, cols1] * alpha + backdrop[rows0, cols0] * (255 - alpha)
        return (mixed // 255).astype(np.uint8)


def overlay_bank(height: int, width: int, n_images: int = len(OVERLAY_SEEDS)) -> np.ndarray:
    """Still procedural images for SGQN's overlay augmentation, none of them a training or test background.

    :param height: image height
    :param width: image width
    :param n_images: how many (at most ``len(OVERLAY_SEEDS)``)
    :return: uint8 (n_images, height, width, 3)
    """
    if not 1 <= n_images <= len(OVERLAY_SEEDS):
        raise ValueError(f"n_images must be in 1..{len(OVERLAY_SEEDS)}, got {n_images!r}")
    return np.stack(
        [ProceduralBackground(seed, height, width, n_frames=1).frame(0) for seed in OVERLAY_SEEDS[:n_images]]
    )


# --- file sources ---------------------------------------------------------------------------------


class _FittedFiles:
    """Frames read from files, each fitted by :func:`fit_frame` as it is read (the parameters:
    :class:`ImageBackground`'s)."""

    def __init__(
        self, height: int, width: int, grayscale: bool, crop: bool, interpolation: int, halvings: int, argument: str
    ) -> None:
        self.height, self.width, self.grayscale = height, width, grayscale
        self._crop, self._interpolation, self._halvings = crop, interpolation, halvings
        self._argument = argument

    def _fit(self, frame_bgr: np.ndarray) -> np.ndarray:
        """A frame read from a file, fitted to this source's frames by :func:`fit_frame`."""
        return fit_frame(
            frame_bgr, self.height, self.width, self.grayscale, crop=self._crop, interpolation=self._interpolation,
            halvings=self._halvings,
        )  # fmt: skip


class VideoBackground(_FittedFiles):
    """The first ``frame_budget`` frames of a video file, each fitted by :func:`fit_frame`, decoded as they are first
    needed (the first at construction, so an unreadable file fails where it is given).

    :param path: video file readable by ``cv2.VideoCapture``
    :param height: frame height
    :param width: frame width
    :param frame_budget: most frames kept (DBC: 1000), None for all
    :param grayscale: replicate the luma into the three channels (DBC's setting)

    ``crop``, ``interpolation``, ``halvings`` and ``argument``: as :class:`ImageBackground`'s.
    """

    # The fitting keywords on one line, as ImageBackground's (documented there).
    def __init__(
        self, path: str | Path, height: int, width: int, frame_budget: int | None = DEFAULT_FRAME_BUDGET,
        grayscale: bool = False,
        *, crop: bool = True, interpolation: int = cv2.INTER_AREA, halvings: int = 0, argument: str = "background_dir",
    ) -> None:  # fmt: skip
        super().__init__(height, width, grayscale, crop, interpolation, halvings, argument)
        self.path = str(path)
        self.frame_budget = frame_budget
        self._frames: list[np.ndarray] = []
        self._capture: cv2.VideoCapture | None = cv2.VideoCapture(self.path)
        frame_size = (self._capture.get(cv2.CAP_PROP_FRAME_WIDTH), self._capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        check_background_pixels(self.path, int(frame_size[0]), int(frame_size[1]), argument)  # before decoding
        self._decode_until(0)
        if not self._frames:
            raise ValueError(f"{argument}: OpenCV could not read any frame of the video {self.path!r}")

    def _decode_until(self, index: int) -> None:
        while self._capture is not None and len(self._frames) <= index:
            ok, frame = self._capture.read()
            if ok:
                self._frames.append(self._fit(frame))
            if not ok or len(self._frames) == self.frame_budget:
                self._capture.release()
                self._capture = None

    @property
    def n_frames(self) -> int:
        self._decode_until(2**62)
        return len(self._frames)

    def frame(self, index: int) -> np.ndarray:
        self._decode_until(index)
        if index >= len(self._frames):  # past the end: the video is decoded whole, and loops
            index %= len(self._frames)
        return self._frames[index]


class ImageBackground(_FittedFiles):
    """Still images as frames, each fitted by :func:`fit_frame` and read as first needed (the first at construction):
    one image (a one-frame source), or a video stored as one image file per frame (DAVIS).

    :param paths: an image file readable by ``cv2.imread``, or the frames' files in order
    :param height: frame height
    :param width: frame width
    :param grayscale: replicate the luma into the three channels
    :param crop: centre-crop each image to the output's aspect ratio (else resize it whole)
    :param interpolation: OpenCV interpolation of the resize
    :param halvings: 2x2 averagings after it (frames of ``height >> halvings`` by ``width >> halvings``)
    :param argument: the keyword argument that gave the files, for messages
    """

    # The fitting keywords (fit_frame's, and the argument named in messages) on one line, as VideoBackground's.
    def __init__(
        self, paths: str | Path | Sequence[str | Path], height: int, width: int, grayscale: bool = False,
        *, crop: bool = True, interpolation: int = cv2.INTER_AREA, halvings: int = 0, argument: str = "background_dir",
    ) -> None:  # fmt: skip
        super().__init__(height, width, grayscale, crop, interpolation, halvings, argument)
        self.paths = (Path(paths),) if isinstance(paths, (str, Path)) else tuple(Path(p) for p in paths)
        self._frames: dict[int, np.ndarray] = {}
        self.frame(0)

    @property
    def n_frames(self) -> int:
        return len(self.paths)

    def frame(self, index: int) -> np.ndarray:
        index %= len(self.paths)
        if index not in self._frames:
            check_image_file(self.paths[index], self._argument)  # its pixels, from its header, before decoding
            image = cv2.imread(str(self.paths[index]), cv2.IMREAD_COLOR)
            if image is None:
                raise ValueError(f"{self._argument}: OpenCV could not read the image {str(self.paths[index])!r}")
            fitted = self._fit(image)
            fitted.flags.writeable = False
            self._frames[index] = fitted
        return self._frames[index]


# --- the source of a domain ---------------------------------------------------------------------


def make_background(
    split: str,
    domain: int,
    height: int,
    width: int,
    background_dir: str | Path | None = None,
    frame_budget: int = DEFAULT_FRAME_BUDGET,
    grayscale: bool = False,
    still: bool = False,
    test_domains: int | None = None,
) -> BackgroundSource:
    """The background source of one domain; frames are produced or decoded on first use.

    :param split: ``"train"`` or ``"test"``
    :param domain: index of the source within the split, in ``range(n_background_domains(split, ...))``
    :param height: frame height
    :param width: frame width
    :param background_dir: a user's folder of videos/images, or None for the built-in procedural banks
    :param frame_budget: most frames per source (DBC: 1000)
    :param grayscale: replicate the luma into the three channels (DBC's setting)
    :param still: one still image per domain, as the SGFD authors' code reads it (a procedural texture's first
        frame; a file read by ``cv2.imread`` and resized whole by ``cv2.resize``), else moving frames (a frame per
        step: a procedural texture, a video, or an image centre-cropped and resized by area)
    :param test_domains: the built-in test sources (None: the paper's one; see
        :func:`~sgfd_envs.background_splits.check_test_domains`)
    """
    if isinstance(frame_budget, bool) or not isinstance(frame_budget, (int, np.integer)) or frame_budget < 1:
        raise ValueError(f"frame_budget must be a positive int, got {frame_budget!r}")
    check_background_split(split)
    check_test_domains(test_domains, background_dir)
    if background_dir is None:
        n_frames = 1 if still else int(frame_budget)
        return ProceduralBackground(PROCEDURAL_SEEDS[split][domain], height, width, n_frames, grayscale)
    path = background_files(background_dir)[split][domain]
    if path.suffix.lower() in VIDEO_SUFFIXES:
        if still:
            raise ValueError(
                f"background_dir: {str(path)!r} is a video, and backgrounds='still' shows one image per domain: "
                "give images, or backgrounds='moving' to play videos"
            )
        return VideoBackground(path, height, width, int(frame_budget), grayscale)
    if still:
        return ImageBackground(path, height, width, grayscale, crop=False, interpolation=cv2.INTER_LINEAR)
    return ImageBackground(path, height, width, grayscale)
