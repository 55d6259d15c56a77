"""Which background source is each domain of the background ids' splits: a seed of the built-in procedural banks,
or a file of a user's folder (``background_dir``). A user's folder either has ``train/`` and ``test/`` subfolders,
one source per file, or is flat: its sorted files give the first four training sources and the rest the test ones
(five images: the SGFD authors' setup, four training backgrounds and one unseen test background).

The keywords that choose how the backgrounds are shown (:data:`BACKGROUND_KEYWORDS`), with the paper's setup as
their defaults: ``backgrounds`` (``"still"``: one still image per domain, the paper's; ``"moving"``: a moving
texture or video, a frame per agent step), ``compositing`` (``"colour_key"``: the authors' mask of blue-dominant
pixels of the whole render; ``"matte"``: the background behind the robot by the render's coverage, floor and sky
hidden), ``test_domains`` (the built-in test backgrounds: 1, the paper's, to 4), ``background_channels`` (the
channel order pasted: None, the compositing's own) and ``robots`` (``"hipbmdp"``: the local unmodified robot files
the authors' code renders; ``"dm_control"``: dm_control's own).

Import-light (no OpenCV): the id table counts domains with it; :mod:`sgfd_envs.backgrounds` makes the sources.
"""

from __future__ import annotations

from pathlib import Path

BACKGROUND_SPLITS = ("train", "test")
# Disjoint seed banks: a test texture is never a training one.
PROCEDURAL_SEEDS: dict[str, tuple[int, ...]] = {"train": (0, 1, 2, 3), "test": (1000, 1001, 1002, 1003)}
# The paper's test split: one unseen background (the built-in stand-in's first test seed).
PAPER_TEST_DOMAINS = 1
STILL, MOVING = "still", "moving"
BACKGROUND_MOTIONS = (STILL, MOVING)
COLOUR_KEY, MATTE = "colour_key", "matte"
COMPOSITINGS = (COLOUR_KEY, MATTE)
BGR, RGB = "bgr", "rgb"
CHANNEL_ORDERS = (BGR, RGB)
# Each compositing's channel order (background_channels=None): the authors' code pastes OpenCV's BGR.
CHANNELS_OF_COMPOSITING = {COLOUR_KEY: BGR, MATTE: RGB}
HIPBMDP_ROBOTS, DM_CONTROL_ROBOTS = "hipbmdp", "dm_control"
BACKGROUND_ROBOTS = (HIPBMDP_ROBOTS, DM_CONTROL_ROBOTS)
# The keywords of the background ids that choose the family, with their defaults (the paper's setup).
BACKGROUND_KEYWORDS = {
    "robots": HIPBMDP_ROBOTS,
    "backgrounds": STILL,
    "compositing": COLOUR_KEY,
    "test_domains": None,
    "background_channels": None,
}
# SGQN's overlay images (Places365 in its paper): a third bank, disjoint from the training and test backgrounds.
OVERLAY_SEEDS = tuple(range(2000, 2032))
TRAIN_SOURCES_IN_FLAT_FOLDER = 4

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp", ".tif", ".tiff")


def check_background_split(split: str) -> str:
    """Return ``split`` if it is a background split, else raise.

    :param split: ``"train"`` or ``"test"``
    """
    if split not in BACKGROUND_SPLITS:
        raise ValueError(f"split must be one of {BACKGROUND_SPLITS} for background ids, got {split!r}")
    return split


def _media_files(folder: Path) -> tuple[Path, ...]:
    return tuple(
        sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES + IMAGE_SUFFIXES)
    )


def existing_folder(folder: str | Path, argument: str, give: str | None = None) -> Path:
    """``folder`` as a Path (``~`` expanded) if it is an existing folder, else a FileNotFoundError naming it.

    :param folder: the folder a user gave
    :param argument: the keyword argument that gave it, for the message
    :param give: what to give instead, said in the message (None: nothing)
    """
    path = Path(folder).expanduser()
    if not path.is_dir():
        hint = "" if give is None else f" ({give})"
        raise FileNotFoundError(f"{argument} {str(path)!r} is not an existing folder{hint}")
    return path


def background_files(background_dir: str | Path) -> dict[str, tuple[Path, ...]]:
    """The source files of each split in a user's folder.

    :param background_dir: folder with ``train/`` and ``test/`` subfolders, or a flat folder of at
        least five videos/images (the first four, sorted by name, are the training sources)
    """
    folder = existing_folder(background_dir, "background_dir")
    suffixes = ", ".join(VIDEO_SUFFIXES + IMAGE_SUFFIXES)
    subfolders = {split: folder / split for split in BACKGROUND_SPLITS}
    present = [split for split, sub in subfolders.items() if sub.is_dir()]
    if present:
        if len(present) != len(BACKGROUND_SPLITS):
            raise ValueError(
                f"background_dir {str(folder)!r} has {present[0]}/ but no "
                f"{({*BACKGROUND_SPLITS} - {*present}).pop()}/: give both or neither"
            )
        files = {split: _media_files(sub) for split, sub in subfolders.items()}
        for split, found in files.items():
            if not found:
                raise ValueError(f"background_dir {str(subfolders[split])!r} holds no video or image ({suffixes})")
        return files
    found = _media_files(folder)
    if len(found) <= TRAIN_SOURCES_IN_FLAT_FOLDER:
        raise ValueError(
            f"background_dir {str(folder)!r} holds {len(found)} videos/images ({suffixes}); a flat folder "
            f"needs at least {TRAIN_SOURCES_IN_FLAT_FOLDER + 1} ({TRAIN_SOURCES_IN_FLAT_FOLDER} training, "
            "the rest for testing), or use train/ and test/ subfolders"
        )
    return {"train": found[:TRAIN_SOURCES_IN_FLAT_FOLDER], "test": found[TRAIN_SOURCES_IN_FLAT_FOLDER:]}


def check_choice(keyword: str, value: object, allowed: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``allowed``, else raise naming the keyword and the allowed values."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{keyword} must be one of {allowed} for background ids, got {value!r}")
    return value


def check_test_domains(test_domains: int | None, background_dir: str | Path | None = None) -> int:
    """The number of test backgrounds: ``test_domains`` of the built-in bank (None: the paper's one), which a user's
    folder decides instead (then ``test_domains`` must be None).

    :param test_domains: None or an int in 1..4
    :param background_dir: a user's folder, or None for the built-in bank
    """
    if background_dir is not None:
        if test_domains is not None:
            raise ValueError(f"test_domains must be None with background_dir (its files decide), got {test_domains!r}")
        return len(background_files(background_dir)["test"])
    if test_domains is None:
        return PAPER_TEST_DOMAINS
    bank = len(PROCEDURAL_SEEDS["test"])
    if isinstance(test_domains, bool) or not isinstance(test_domains, int) or not 1 <= test_domains <= bank:
        raise ValueError(f"test_domains must be None or an int in 1..{bank}, got {test_domains!r}")
    return test_domains


def n_background_domains(split: str, background_dir: str | Path | None = None, test_domains: int | None = None) -> int:
    """Number of background sources (domains) in a split.

    :param split: ``"train"`` or ``"test"``
    :param background_dir: a user's folder, or None for the built-in procedural banks
    :param test_domains: the built-in test backgrounds (None: the paper's one; see :func:`check_test_domains`)
    """
    check_background_split(split)
    if split == "test":
        return check_test_domains(test_domains, background_dir)
    if background_dir is None:
        return len(PROCEDURAL_SEEDS[split])
    return len(background_files(background_dir)[split])
