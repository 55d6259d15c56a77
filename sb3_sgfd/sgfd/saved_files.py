"""SGFD_SAC models saved by earlier versions of this package, read as today's where SB3's ``load`` puts them back:
their attributes (:func:`upgrade_saved_attributes`) and their weighting's state (:func:`upgrade_saved_parameters`).
The files themselves are not changed; what is saved from a loaded model is today's format."""

from __future__ import annotations

from typing import Any

import torch

from sb3_sgfd.sgfd.settings import SGFDSettings, setting_names

#: Attributes earlier versions saved on the model that the weighting now holds and recomputes (the buffer's domains
#: are looked at again when SGFD starts)
DROPPED_ATTRIBUTES = ("single_domain", "_domains_checked", "_fresh_batches")


def upgrade_saved_attributes(model: Any) -> None:
    """Version 0.1.0 saved each of SGFD's settings as an attribute of its own (``reading``, ``n_rff``, ...): gathered
    into ``model.sgfd``; attributes that are the weighting's now are dropped. A model of today is left as it is.

    :param model: an SGFD_SAC whose attributes SB3's ``load`` has just put back
    """
    state = vars(model)
    names = {"reading", *setting_names()}
    saved = {name: state.pop(name) for name in list(state) if name in names}
    if saved:
        model.sgfd = SGFDSettings.of_reading(saved.pop("reading", "paper"), **saved)
    for name in DROPPED_ATTRIBUTES:
        state.pop(name, None)


def upgrade_saved_parameters(parameters: dict[str, Any]) -> dict[str, Any]:
    """Version 0.1.0 saved the weighting's own state as ``_extra_state`` entries (the paper reading's ``ready`` flag,
    the memory's features, logits and update count): the same values under today's names. Today's parameters are
    returned as they are.

    :param parameters: the state dicts SB3's ``load`` hands ``set_parameters``, by attribute
    """
    weighting = parameters.get("weighting")
    if not isinstance(weighting, dict) or not any(key.endswith("_extra_state") for key in weighting):
        return parameters
    weighting = dict(weighting)
    flags = weighting.pop("_extra_state", None)
    if flags is not None and "ready" in flags:
        weighting["ready"] = torch.tensor(float(flags["ready"]))
    memory = weighting.pop("memory._extra_state", None)
    if memory is not None:
        weighting["memory.features"], weighting["memory.logits"] = memory["features"], memory["logits"]
        weighting["memory.updates"] = torch.tensor(float(memory["updates"]))
    return {**parameters, "weighting": weighting}
