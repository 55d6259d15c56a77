"""Tests for sb3_sgfd.common.augmentation: DrQ's random shift."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import Tensor

from sb3_sgfd.common.augmentation import random_shift


def seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def crops_of_padded(image: Tensor, pad: int) -> dict[tuple[int, int], Tensor]:
    """Every (H, W) crop of the edge-replicated pad of one (C, H, W) image, by offset (dy, dx)."""
    _, h, w = image.shape
    padded = F.pad(image.double().unsqueeze(0), (pad, pad, pad, pad), mode="replicate")[0]
    return {(dy, dx): padded[:, dy : dy + h, dx : dx + w] for dy in range(2 * pad + 1) for dx in range(2 * pad + 1)}


def offsets_of(images: Tensor, shifted: Tensor, pad: int) -> list[tuple[int, int]]:
    """The offset each output was cropped at; fails if an output is no crop of its padded input."""
    found = []
    for image, out in zip(images, shifted, strict=True):
        matches = [offset for offset, crop in crops_of_padded(image, pad).items() if torch.equal(crop, out.double())]
        assert matches, "output is not an integer crop of the padded input"
        found.append(matches[0])
    return found


def distinct_images(n: int, c: int, h: int, w: int) -> Tensor:
    """Images whose pixels are all different, so that a crop determines its offset (up to the replicated edge)."""
    return torch.arange(n * c * h * w, dtype=torch.float32).reshape(n, c, h, w)


def test_outputs_are_crops_of_the_replicated_pad():
    images = distinct_images(6, 2, 7, 9)
    shifted = random_shift(images, pad=2, generator=seeded(0))
    assert shifted.shape == images.shape and shifted.dtype == images.dtype
    offsets = offsets_of(images, shifted, pad=2)
    # Samples are shifted independently: six draws from 25 offsets are not all the same.
    assert len(set(offsets)) > 1


def test_every_offset_is_reached():
    images = distinct_images(64, 1, 5, 5)
    offsets = offsets_of(images, random_shift(images, pad=1, generator=seeded(1)), pad=1)
    assert set(offsets) == {(dy, dx) for dy in range(3) for dx in range(3)}


def test_pad_zero_is_identity():
    images = torch.rand(3, 2, 5, 4)
    out = random_shift(images, pad=0, generator=seeded(0))
    assert torch.equal(out, images)


def test_uint8_preserved():
    images = torch.randint(0, 256, (4, 3, 10, 10), dtype=torch.uint8, generator=seeded(2))
    shifted = random_shift(images, pad=4, generator=seeded(3))
    assert shifted.dtype == torch.uint8 and shifted.shape == images.shape
    # Same crops as the float path with the same generator seed.
    assert torch.equal(shifted.float(), random_shift(images.float(), pad=4, generator=seeded(3)))


def test_reproducible_and_seed_dependent():
    images = distinct_images(8, 1, 12, 12)
    a = random_shift(images, pad=4, generator=seeded(5))
    b = random_shift(images, pad=4, generator=seeded(5))
    c = random_shift(images, pad=4, generator=seeded(6))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_global_rng_untouched():
    state = torch.get_rng_state()
    random_shift(torch.rand(2, 1, 6, 6, generator=seeded(0)), pad=2, generator=seeded(1))
    assert torch.equal(state, torch.get_rng_state())


def test_non_contiguous_input():
    images = distinct_images(3, 4, 6, 6).permute(0, 1, 3, 2)
    offsets_of(images, random_shift(images, pad=1, generator=seeded(0)), pad=1)


def test_drq_sized_batch_runs():
    images = torch.randint(0, 256, (128, 9, 84, 84), dtype=torch.uint8, generator=seeded(0))
    shifted = random_shift(images, pad=4, generator=seeded(1))
    assert shifted.shape == images.shape and shifted.dtype == torch.uint8


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"images": torch.zeros(2, 5, 5)}, "images"),
        ({"images": torch.zeros(2, 1, 5, 5), "pad": -1}, "pad"),
        ({"images": torch.zeros(2, 1, 5, 5), "pad": 1.5}, "pad"),
        ({"images": torch.zeros(2, 1, 5, 5), "pad": True}, "pad"),
    ],
)
def test_argument_checks(kwargs, message):
    with pytest.raises(ValueError, match=message):
        random_shift(**kwargs)
