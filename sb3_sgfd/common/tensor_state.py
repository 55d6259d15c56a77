"""A torch module whose state lives in plain attributes (a flag read on every step without a host read, tensors
whose shape changes), saved in its ``state_dict`` as floating-point tensors only, so that SB3's ``get_parameters`` and
``set_parameters`` round trip (SB3's tools treat every entry as a float tensor) and ``map_location`` moves it."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn


class TensorStateModule(nn.Module):
    """Subclasses name their state's tensors in ``state_tensors`` and take them back in ``load_state_tensors``."""

    def state_tensors(self) -> dict[str, Tensor]:
        """The state to save, by name (absent entries are not saved: e.g. an empty memory)."""
        raise NotImplementedError

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        """Take back what ``state_tensors`` gave (possibly from another device or an empty state)."""
        raise NotImplementedError

    def _save_to_state_dict(self, destination: dict[str, Any], prefix: str, keep_vars: bool) -> None:
        super()._save_to_state_dict(destination, prefix, keep_vars)
        for name, tensor in self.state_tensors().items():
            destination[prefix + name] = tensor if keep_vars else tensor.detach()

    def _load_from_state_dict(
        self,
        state_dict: dict[str, Any],
        prefix: str,
        local_metadata: dict[str, Any],
        strict: bool,
        missing_keys: list[str],
        unexpected_keys: list[str],
        error_msgs: list[str],
    ) -> None:
        super()._load_from_state_dict(
            state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs
        )
        own = {
            key: value
            for key, value in state_dict.items()
            if key.startswith(prefix)
            and "." not in key[len(prefix) :]
            and key[len(prefix) :] not in self._parameters
            and key[len(prefix) :] not in self._buffers
        }
        for key in own:
            if key in unexpected_keys:
                unexpected_keys.remove(key)
        self.load_state_tensors({key[len(prefix) :]: torch.as_tensor(value) for key, value in own.items()})
