"""What an env setting or a user's file may cost, bounded in one place (docs/trust.md, "Limits"): the size of the
rendered observation, and the pixels of a background image or video frame, checked from its header before it is
decoded. Each refusal is one ValueError line naming the setting or the file, the limit and the value.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

#: ``image_size``: the side of the rendered (square) observation. 1024 x 1024 x 3 bytes per frame.
MAX_IMAGE_SIZE = 1024
#: The pixels of one background image or video frame (4096 x 4096), read from its header before it is decoded.
MAX_BACKGROUND_PIXELS = 4096 * 4096
#: A benchmark's data file read whole (DMC-GB's colour sets, about 20 kB), on disk and, zipped, inflated.
MAX_DATA_FILE_BYTES = 16 * 2**20


def check_image_size_limit(image_size: int) -> int:
    """``image_size`` when it is at most :data:`MAX_IMAGE_SIZE`, else a ValueError naming the limit."""
    if image_size > MAX_IMAGE_SIZE:
        raise ValueError(f"image_size {image_size} is over the limit MAX_IMAGE_SIZE = {MAX_IMAGE_SIZE} (docs/trust.md)")
    return image_size


def check_background_pixels(path: str | Path, width: int, height: int, argument: str) -> None:
    """A ValueError when a ``width`` x ``height`` background (of file ``path``) is over :data:`MAX_BACKGROUND_PIXELS`.

    :param argument: the keyword argument that gave the file, for the message
    """
    if width * height > MAX_BACKGROUND_PIXELS:
        raise ValueError(
            f"{argument}: {str(path)!r} is {width} x {height} = {width * height} pixels, over the limit "
            f"MAX_BACKGROUND_PIXELS = {MAX_BACKGROUND_PIXELS} (docs/trust.md)"
        )


def check_image_file(path: str | Path, argument: str) -> None:
    """A ValueError when the image file ``path`` has more pixels than :data:`MAX_BACKGROUND_PIXELS`, read from its
    header by Pillow (which decodes nothing until asked); a file Pillow cannot identify is left to OpenCV, which
    reads what it can.

    :param argument: the keyword argument that gave the file, for the message
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # refused below, by a lower limit
            with Image.open(path) as image:
                width, height = image.size
    except Image.DecompressionBombError as error:  # Pillow's own limit, far above ours, met while opening
        pixels = re.search(r"\((\d+) pixels\)", str(error))
        value = pixels.group(1) if pixels else "more than Pillow allows"
        raise ValueError(
            f"{argument}: {str(path)!r} is {value} pixels, over the limit MAX_BACKGROUND_PIXELS = "
            f"{MAX_BACKGROUND_PIXELS} (docs/trust.md)"
        ) from None
    except (UnidentifiedImageError, OSError):
        return
    check_background_pixels(path, width, height, argument)


def check_data_file_bytes(path: str | Path, size: int, what: str = "size in bytes") -> None:
    """A ValueError when a benchmark's data file ``path`` (or its member) holds more than :data:`MAX_DATA_FILE_BYTES`.

    :param size: its size, or the inflated size its zip member declares
    :param what: what ``size`` measures, for the message
    """
    if size > MAX_DATA_FILE_BYTES:
        raise ValueError(
            f"data_dir: {str(path)!r}: its {what} is {size}, over the limit MAX_DATA_FILE_BYTES = "
            f"{MAX_DATA_FILE_BYTES} (docs/trust.md)"
        )
