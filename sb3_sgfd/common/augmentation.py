"""Image augmentation for pixel observations (DrQ, Kostrikov et al. 2021, section 3.1).

Pure torch, no Stable-Baselines3 import. Read next to the paper:

1. ``random_shift``: pad each side of the image by ``pad`` pixels, repeating the boundary pixels, then take a
   random (H, W) crop, independently for every sample ("image shift", DrQ's augmentation with pad 4 on 84 x 84).
"""

from __future__ import annotations

import torch
from torch import Tensor


def random_shift(images: Tensor, pad: int = 4, generator: torch.Generator | None = None) -> Tensor:
    """DrQ's random shift: an edge-replicating pad by ``pad``, then a random integer crop of size (H, W) per sample.

    The pad is never materialised: a crop at offset (dy, dx) of the padded image reads the input at
    (clamp(y + dy - pad, 0, H - 1), clamp(x + dx - pad, 0, W - 1)), which is exactly what edge replication
    puts there. One gather for the whole batch, no loop over samples; the dtype (uint8 or float) is kept.

    :param images: batch of images, shape (n, C, H, W), any dtype
    :param pad: pixels added on every side; the offsets dy, dx are uniform in 0..2 * pad; 0 is the identity
    :param generator: source of the offsets, sampled on its device and then moved, so the global RNG is left
        untouched; None draws them from the global RNG
    :return: shifted images, same shape, dtype and device as ``images``
    """
    if not isinstance(images, Tensor):
        raise TypeError(f"images must be a torch.Tensor, got {type(images).__name__}")
    if images.dim() != 4:
        raise ValueError(f"images must have shape (n, C, H, W), got {tuple(images.shape)}")
    if isinstance(pad, bool) or not isinstance(pad, int) or pad < 0:
        raise ValueError(f"pad must be an int >= 0, got {pad!r}")
    if pad == 0 or images.numel() == 0:
        return images.clone()
    n, c, h, w = images.shape
    device = generator.device if generator is not None else images.device
    offsets = torch.randint(0, 2 * pad + 1, (n, 2), generator=generator, device=device).to(images.device)
    # Source row / column of every output row / column, per sample: (n, H) and (n, W).
    rows = (torch.arange(h, device=images.device) + offsets[:, :1] - pad).clamp_(0, h - 1)
    cols = (torch.arange(w, device=images.device) + offsets[:, 1:] - pad).clamp_(0, w - 1)
    flat_index = (rows.unsqueeze(2) * w + cols.unsqueeze(1)).reshape(n, 1, h * w).expand(n, c, h * w)
    return images.reshape(n, c, h * w).gather(2, flat_index).reshape(n, c, h, w)
