"""SGFD's sample weights behind one entry: a batch's features z and domain labels in, weights and figures out.

Pure torch, no Stable-Baselines3 import. ``SGFD_SAC`` calls a :class:`SampleWeighting` once per gradient step;
two readings implement it, each readable whole next to its source:

- :class:`sb3_sgfd.sgfd.paper_reading.PaperWeighting` (``reading="paper"``): Algorithm 1 and eqs. 3-7 of the
  SGFD paper, with this package's measured choices (:mod:`sb3_sgfd.sgfd.decorrelation`, :mod:`sb3_sgfd.sgfd.saliency`);
- :class:`sb3_sgfd.sgfd.official_reading.OfficialWeighting` (``reading="official"``): what the authors' public
  code computes (SiliHuang-ai/SGFD), which produced the published numbers and reweights far less.

A weighting owns its domain classifier, the classifier's optimiser and whatever state the reading keeps (a
memory of past batches, whether the classifier is ready), all in its ``state_dict`` so that a saved model moves
across devices with ``map_location``. Everything it returns stays on the device: no host read inside a step
beyond the one a classifier round needs to decide whether to train.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import torch
from torch import Tensor, nn

from sb3_sgfd.common.tensor_state import TensorStateModule

if TYPE_CHECKING:
    from sb3_sgfd.sgfd.settings import SGFDSettings

#: (number of samples, augmented) -> (features (n, d), domain labels (n,)) of a fresh replay batch.
FreshFeatures = Callable[[int, bool], tuple[Tensor, Tensor]]


class Step(NamedTuple):
    """What a weighting needs to know of the gradient step it is called at.

    :param update_index: index of this gradient step over the run (seeds the RFF draw, times classifier rounds)
    :param num_timesteps: environment steps so far (the classifier starts at ``classifier_start``)
    :param weights_wanted: whether a loss will be weighted at this step (else only the classifier's work is done)
    :param fresh_features: samples and encodes fresh replay batches for the classifier
    """

    update_index: int
    num_timesteps: int
    weights_wanted: bool
    fresh_features: FreshFeatures


class Weights(NamedTuple):
    """A weighting's answer for one batch.

    :param weights: (n,) non-negative weights with mean 1, without grad; None: unweighted at this step
    :param figures: diagnostics to log (0-d tensors, on the device)
    """

    weights: Tensor | None
    figures: dict[str, Tensor]


class SampleWeighting(TensorStateModule):
    """The interface of SGFD's readings (see the module docstring). Subclasses take the settings
    (:class:`sb3_sgfd.sgfd.settings.SGFDSettings`), build their classifier and optimiser in ``__init__``, and
    implement ``forward`` and ``solve``.

    :param n_features: dimension d of the features z
    :param n_domains: number of domain labels
    """

    #: Whether the weights are on once the weighting is active (the paper's reading waits for its classifier).
    ready: bool = True
    classifier: nn.Module
    classifier_optimizer: torch.optim.Optimizer
    #: Draws the random Fourier features (a checkpoint saves its state with the model's other generators).
    rff_generator: torch.Generator

    def __init__(self, n_features: int, n_domains: int) -> None:
        super().__init__()
        self.n_features, self.n_domains = n_features, n_domains

    def active(self, num_timesteps: int) -> bool:
        """Whether the weighting does anything yet (before that, SGFD_SAC is SAC)."""
        return True

    def state_tensors(self) -> dict[str, Tensor]:
        """The reading's own state beyond its classifier and memory (none unless a reading keeps one)."""
        return {}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        """Take back :meth:`state_tensors`."""

    def load_legacy_state(self, state: dict[str, Any]) -> None:
        """Take back a version 0.1.0 reading's extra state (none unless a reading kept one)."""

    def forward(self, z: Tensor, domains: Tensor, step: Step) -> Weights:
        """The weights of one batch, and the classifier's work of this step.

        :param z: the critic's (detached) encoder features of the batch, (n, d)
        :param domains: the batch's domain labels, (n,)
        :param step: this gradient step
        """
        raise NotImplementedError

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The reading's weights for features ``z`` with its classifier as it is now, leaving every state as it
        is (the memory is read, not updated): for figures and benchmarks.

        :param z: features (n, d)
        :param generator: seeds the random Fourier features
        :return: weights (n,) with mean 1, and the decorrelation loss at uniform weights and at the weights
        """
        raise NotImplementedError


class WeightingFactory(Protocol):
    """How ``SGFD_SAC`` builds a reading's weighting: the constructor every reading's class has."""

    def __call__(
        self, n_features: int, n_domains: int, settings: SGFDSettings, seed: int, device: torch.device | str = ...
    ) -> SampleWeighting: ...


def weight_figures(weights: Tensor, loss_before: Tensor, loss_after: Tensor, probs: Tensor | None) -> dict[str, Tensor]:
    """The figures SGFD_SAC logs of a batch's weights, as 0-d tensors (read once per ``train()`` call)."""
    figures = {
        # Kish's effective sample size over n.
        "weight_ess": weights.sum().square() / weights.square().sum() / len(weights),
        "weight_min": weights.min(),
        "weight_max": weights.max(),
        "decorrelation_loss_before": loss_before,
        "decorrelation_loss_after": loss_after,
    }
    if probs is not None:
        figures["top_saliency_feature"] = probs.argmax()
    return figures
