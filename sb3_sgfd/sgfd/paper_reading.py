"""SGFD's weights as the paper reads (Algorithm 1, eqs. 3-7), with this package's measured choices.

Pure torch, no Stable-Baselines3 import. Per gradient step, once ``num_timesteps >= classifier_start``:

1. lines 6-13: while its accuracy is below ``accuracy_threshold``, the domain classifier (an MLP on z) takes a
   step on the batch's features (and on up to ``classifier_iters - 1`` fresh replay batches); the first time it
   reaches the threshold the weights start, and stay on (sticky);
2. line 12: p(Z_i) from the classifier's saliency (``sb3_sgfd.sgfd.saliency.feature_probabilities``: the input
   gradient of the predicted domain's logit, max-normalised, temperature 0.1, mixed with uniform);
3. lines 14-17: the weights minimising the saliency-weighted decorrelation of random Fourier features
   (``sb3_sgfd.sgfd.decorrelation.learn_sample_weights``: SGD on the logits of w = n softmax(theta), the loss divided
   by its value at uniform weights, an ESS penalty).

Where this departs from the printed algorithm, and by how much, is measured in ``bench/decorrelation.py`` and
listed in the README ("the papers and the code").
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import torch
from torch import Tensor

from sb3_sgfd.sgfd.decorrelation import WeightMemory, solve_weights
from sb3_sgfd.sgfd.saliency import (
    DomainClassifier,
    _accuracy,
    feature_probabilities,
    scored_feature_probabilities,
    train_classifier,
)
from sb3_sgfd.sgfd.settings import SGFDSettings
from sb3_sgfd.sgfd.weighting import FreshFeatures, SampleWeighting, Step, Weights, weight_figures


class PaperWeighting(SampleWeighting):
    """
    The paper's reading of SGFD's weights (``SGFD_SAC(reading="paper")``, the default). Its settings'
    defaults are :meth:`sb3_sgfd.sgfd.settings.SGFDSettings.paper`.

    :param n_features: dimension d of the features z
    :param n_domains: number of domain labels (the classifier's classes)
    :param settings: SGFD's settings (:class:`sb3_sgfd.sgfd.settings.SGFDSettings`)
    :param seed: seeds the RFF draw of each update (``seed + update_index``), so a resumed run continues it
    :param device: where the classifier and the generators live
    """

    classifier: DomainClassifier

    def __init__(
        self,
        n_features: int,
        n_domains: int,
        settings: SGFDSettings,
        seed: int,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(n_features, n_domains)
        self.settings = settings
        self.solver_settings = settings.solver_settings()
        self.seed = seed
        self.classifier = DomainClassifier(n_features, max(n_domains, 2), settings.classifier_hidden_dim).to(device)
        # Fused: one kernel for all six parameters instead of a dozen small ops each.
        self.classifier_optimizer = torch.optim.Adam(
            self.classifier.parameters(), lr=settings.classifier_lr, fused=True
        )
        self.memory = None if settings.reweight_memory is None else WeightMemory(settings.reweight_memory)
        self.rff_generator = torch.Generator(device=device)
        # Sticky: the weights are learned from the first time the classifier reaches the threshold on.
        self.ready = False

    def active(self, num_timesteps: int) -> bool:
        return num_timesteps >= self.settings.classifier_start

    def forward(self, z: Tensor, domains: Tensor, step: Step) -> Weights:
        # Once ready, one pass of the classifier scores the batch and gives p(Z_i); on a step where the
        # classifier then also trains, the weights use that p (Algorithm 1 takes it after the classifier's step).
        probs, accuracy = None, None
        if self.ready and step.weights_wanted and self.settings.use_saliency:
            probs, accuracy = scored_feature_probabilities(
                self.classifier,
                z,
                domains,
                temperature=self.settings.saliency_temperature,
                smoothing=self.settings.saliency_smoothing,
            )
        if self.settings.classifier_iters > 0 and step.update_index % self.settings.classifier_interval == 0:
            # one host read per round: whether this batch's score is below the threshold
            below = accuracy is not None and bool(accuracy < self.settings.accuracy_threshold)
            if accuracy is None or below:
                batches = self._classifier_batches(z, domains, len(z), step.fresh_features)
                accuracy, steps = train_classifier(
                    self.classifier,
                    self.classifier_optimizer,
                    batches,
                    self.settings.accuracy_threshold,
                    first_below=below,
                )
                # a batch scored at the threshold stops the loop before its step
                self.ready = self.ready or steps < self.settings.classifier_iters
        elif accuracy is None:
            with torch.no_grad():
                accuracy = _accuracy(self.classifier(z).argmax(dim=1), domains)
        figures = {"classifier_accuracy": accuracy}
        if not self.ready or not step.weights_wanted:
            return Weights(None, figures)
        self.rff_generator.manual_seed(self.seed + step.update_index)
        weights, before, after, probs = self._weights(z, probs, self.rff_generator, update_memory=True)
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)})

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        weights, before, after, _ = self._weights(z, None, generator, update_memory=False)
        return weights, before, after

    def _weights(
        self, z: Tensor, probs: Tensor | None, generator: torch.Generator | None, update_memory: bool
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """Lines 12-17: p(Z_i) (uniform in the no-saliency ablation; ``probs`` if already scored), then the
        weights; returns them, the losses before and after, and p."""
        if not self.settings.use_saliency:
            probs = None
        elif probs is None:
            probs = feature_probabilities(
                self.classifier,
                z,
                temperature=self.settings.saliency_temperature,
                smoothing=self.settings.saliency_smoothing,
            )
        weights, before, after = solve_weights(
            z, probs, memory=self.memory, update_memory=update_memory, generator=generator, **self.solver_settings
        )
        return weights, before, after, probs

    def _classifier_batches(
        self, z: Tensor, domains: Tensor, batch_size: int, fresh_features: FreshFeatures
    ) -> Iterator[tuple[Tensor, Tensor]]:
        """This batch's features, then fresh (augmented) replay batches: ``classifier_iters`` batches in all."""
        yield z, domains
        for _ in range(self.settings.classifier_iters - 1):
            yield fresh_features(batch_size, True)

    def state_tensors(self) -> dict[str, Tensor]:
        return {"ready": torch.tensor(float(self.ready))}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        self.ready = bool(tensors["ready"])

    def load_legacy_state(self, state: dict[str, Any]) -> None:
        self.ready = bool(state["ready"])
