"""A replay batch's numpy arrays to torch tensors on the model's device, in one copy.

SB3's ``ReplayBuffer.to_torch`` copies each array on its own: on a GPU six or seven blocking copies from pageable
memory per batch. Here the arrays are packed into one pinned staging buffer and sent with one non-blocking copy;
pixel observations stay uint8 until they are on the device. On the CPU the arrays (new ones, made by the batch's
gathers) become tensors without a copy.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch as th

# Each array starts at a multiple of this many bytes in the staging buffer, so that its view has any dtype.
_ALIGNMENT = 64


class BatchTransfer:
    """Moves the arrays of one batch to ``device`` together.

    :param device: the model's device
    """

    def __init__(self, device: th.device | str) -> None:
        self.device = th.device(device)
        self._staging: th.Tensor | None = None
        self._copied: th.cuda.Event | None = None

    def __call__(self, arrays: Sequence[np.ndarray]) -> list[th.Tensor]:
        """The arrays as tensors on the device, each of its array's dtype and shape.

        :param arrays: arrays that nothing else will write to (the batch's own gathers)
        """
        arrays = [np.ascontiguousarray(array) for array in arrays]
        if self.device.type != "cuda":
            return [th.from_numpy(array).to(self.device) for array in arrays]
        offsets, total = [], 0
        for array in arrays:
            offsets.append(total)
            total += -(-array.nbytes // _ALIGNMENT) * _ALIGNMENT
        if self._staging is None or self._staging.numel() < total:
            self._staging = th.empty(total, dtype=th.uint8, pin_memory=True)
        elif self._copied is not None:
            self._copied.synchronize()  # the previous batch's copy has left the staging buffer
        staging = self._staging.numpy()
        for array, offset in zip(arrays, offsets, strict=True):
            staging[offset : offset + array.nbytes] = array.reshape(-1).view(np.uint8)
        on_device = self._staging[:total].to(self.device, non_blocking=True)
        self._copied = th.cuda.Event()
        self._copied.record()
        return [
            on_device[offset : offset + array.nbytes].view(_torch_dtype(array.dtype)).reshape(array.shape)
            for array, offset in zip(arrays, offsets, strict=True)
        ]

    def __getstate__(self) -> dict[str, object]:
        # The staging buffer and the event are this process's; a copy (a pickled replay buffer) makes its own.
        return {"device": self.device, "_staging": None, "_copied": None}


def _torch_dtype(dtype: np.dtype) -> th.dtype:
    return th.from_numpy(np.zeros(0, dtype=dtype)).dtype
