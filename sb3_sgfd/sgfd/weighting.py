"""SGFD's sample weights, Algorithm 1 lines 6-17 in one place: the domain classifier and its rounds, the feature
probabilities p(Z_i) from its saliency (section 4.2), and the weights (:mod:`sb3_sgfd.sgfd.decorrelation`), as two
readings, each one entry point that ``SGFD_SAC`` calls once per gradient step:

- :class:`PaperWeighting` (``reading="paper"``): Algorithm 1 as printed, with this package's measured choices: from
  ``classifier_start``, a classifier round on every ``classifier_interval``-th update scores the batch and, while
  its accuracy is below ``accuracy_threshold``, trains on it (and on fresh batches); the weights start the first
  time a batch scores at the threshold, and stay on;
- :class:`OfficialWeighting` (``reading="official"``): what the authors' public code computes (SiliHuang-ai/SGFD),
  which produced the published numbers: weights on the actor loss from the first update, its classifier rounds on
  fresh unaugmented batches, guided-backprop saliency, a memory of past batches, an objective that keeps the
  weights near uniform.

Pure torch, no Stable-Baselines3 import. Every decision of a step is a tensor (the paper's whether-to-train and
whether-ready are masks, :func:`sb3_sgfd.common.captured.masked_step`), except the official round's, which the
algorithm takes on the host before the step (one read per round). Each weighting owns its classifier, optimiser and
state, all in its ``state_dict``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple, cast

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from sb3_sgfd.common.captured import masked_step
from sb3_sgfd.common.tensor_state import TensorStateModule
from sb3_sgfd.common.validation import check_matrix
from sb3_sgfd.sgfd.checks import check_domains
from sb3_sgfd.sgfd.decorrelation import (
    WeightMemory,
    official_solution,
    paper_solution,
    solve_official_weights,
    solve_weights,
)
from sb3_sgfd.sgfd.settings import SGFDSettings

#: The official reading's classifier batches are this many replay batches' worth of samples (640 at batch 128).
CLASSIFIER_BATCHES = 5


class DomainClassifier(nn.Module):
    """MLP that predicts the training domain of a feature vector (paper Table 3: 2 hidden layers of 128, ReLU); the
    official code's starts with orthogonal weights and zero biases.

    :param n_features: dimension d of the features (50 for the paper's encoder)
    :param n_domains: number K of training domains
    :param hidden_dim: width of the two hidden layers
    :param orthogonal: the code's initialisation
    """

    def __init__(self, n_features: int, n_domains: int, hidden_dim: int = 128, orthogonal: bool = False) -> None:
        super().__init__()
        sizes = (("n_features", n_features, 1), ("n_domains", n_domains, 2), ("hidden_dim", hidden_dim, 1))
        for name, value, low in sizes:
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
        self.n_features, self.n_domains = n_features, n_domains
        self.net = nn.Sequential(
            nn.Linear(n_features, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, n_domains),
        )
        if orthogonal:
            for layer in self.net:
                if isinstance(layer, nn.Linear):
                    nn.init.orthogonal_(layer.weight)
                    nn.init.zeros_(layer.bias)

    def forward(self, z: Tensor) -> Tensor:
        """:param z: features (n, n_features)
        :return: domain logits (n, n_domains)"""
        if z.dim() != 2 or z.shape[1] != self.n_features:
            raise ValueError(f"z must have shape (n, {self.n_features}), got {tuple(z.shape)}")
        return self.net(z)

    def probabilities(self, z: Tensor) -> Tensor:
        """The code's classifier output: softmax probabilities (n, K)."""
        return torch.softmax(self(z), dim=1)

    def _layers(self) -> tuple[nn.Linear, nn.Linear, nn.Linear]:
        return cast(tuple[nn.Linear, nn.Linear, nn.Linear], tuple(self.net[index] for index in (0, 2, 4)))

    def input_gradient(self, z: Tensor, domains: Tensor | None = None) -> Tensor:
        """d f_k(z_k) / d z_k for each sample, f_k the logit of its predicted (or given) domain (n, d), without grad.

        :param z: features (n, n_features)
        :param domains: the domain whose logit to differentiate per sample; None: the predicted one
        """
        return self.predictions_and_input_gradient(z, domains)[1]

    def predictions_and_input_gradient(self, z: Tensor, domains: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """The predicted domains (n,) and ``input_gradient`` from one forward pass, in closed form: through the ReLU
        network the gradient is W1^T [h1 > 0] W2^T [h2 > 0] w3_k (the tests compare it with autograd)."""
        first, second, last = self._layers()
        with torch.no_grad():
            h1 = first(z).clamp_min(0)
            h2 = second(h1).clamp_min(0)
            predicted = last(h2).argmax(dim=1)
            target = predicted if domains is None else domains.to(z.device).long()
            g2 = last.weight[target] * (h2 > 0)
            g1 = (g2 @ second.weight) * (h1 > 0)
            return predicted, g1 @ first.weight

    def guided_saliency(self, z: Tensor) -> Tensor:
        """Guided backpropagation of each class's probability to z, averaged over the classes: (n, d), without
        grad. Through a ReLU the gradient passes where the unit was active and the gradient is positive (Springenberg
        et al.); in closed form for this network (the tests compare it with autograd through guided ReLUs)."""
        first, second, last = self._layers()
        with torch.no_grad():
            pre1 = first(z)
            pre2 = second(pre1.clamp_min(0))
            probs = torch.softmax(last(pre2.clamp_min(0)), dim=1)
            eye = torch.eye(probs.shape[1], dtype=probs.dtype, device=probs.device)
            # d probs_t / d logits = probs_t (e_t - probs), for every target class t: (K, n, K)
            upstream = probs.T.unsqueeze(2) * (eye.unsqueeze(1) - probs.unsqueeze(0))
            hidden2 = (upstream @ last.weight).clamp_min(0) * (pre2 > 0)
            hidden1 = (hidden2 @ second.weight).clamp_min(0) * (pre1 > 0)
            return (hidden1 @ first.weight).mean(dim=0)


def accuracy(predicted: Tensor, domains: Tensor) -> Tensor:
    """Fraction of the predicted domains (n,) that are the true ones (n,), as a 0-d tensor on their device."""
    return (predicted == domains.to(predicted.device)).float().mean()


def saliency_probabilities(saliency: Tensor, temperature: float, normalize: bool, smoothing: float) -> Tensor:
    """p(Z_i) = (1 - smoothing) softmax_i(M_i / temperature) + smoothing / d from the saliency M (d,), divided by its
    largest entry first when ``normalize`` is on (see :func:`feature_probabilities`); without grad."""
    if normalize:
        saliency = saliency / saliency.max().clamp_min(torch.finfo(saliency.dtype).tiny)
    probs = torch.softmax(saliency / temperature, dim=0)
    return ((1 - smoothing) * probs + smoothing / probs.numel()).detach()


def classifier_round(
    classifier: nn.Module,
    optimizer: torch.optim.Optimizer,
    batches: Sequence[tuple[Tensor, Tensor]],
    stop_accuracy: float | None = None,
) -> tuple[Tensor, Tensor]:
    """The paper's classifier round (Algorithm 1, lines 7-13), decided on the device: each batch is scored first, and
    training stops at the first one classified with accuracy >= ``stop_accuracy`` (its step and the later ones are
    masked off); otherwise a cross-entropy step on it. Scoring before the step makes the accuracy a held-out
    estimate.

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param optimizer: optimiser of the classifier's parameters
    :param batches: (features (n, d), domain labels (n,)) pairs, e.g. detached encoder features
    :param stop_accuracy: accuracy that ends training; None trains on every batch
    :return: the last batch's accuracy (0-d), and whether the threshold was reached (0-d bool)
    """
    training, scored = None, None
    for z, domains in batches:
        check_matrix(z, "z")
        check_domains(domains, z.shape[0])
        logits = classifier(z)  # one forward pass scores the batch and, below the threshold, trains on it
        scored = accuracy(logits.detach().argmax(dim=1), domains)
        below = scored < stop_accuracy if stop_accuracy is not None else scored.new_ones((), dtype=torch.bool)
        training = below if training is None else training & below
        optimizer.zero_grad()
        F.cross_entropy(logits, domains).backward()
        masked_step(optimizer, training)
    if scored is None or training is None:
        raise ValueError("a classifier round needs at least one batch")
    return scored, ~training


class WeightingPlan(NamedTuple):
    """The host's decisions of a weighting for one gradient step (part of the step's plan).

    :param classifier_round: a classifier round is due
    :param weights_wanted: a loss is weighted at this step (else only the classifier's work is done)
    """

    classifier_round: bool
    weights_wanted: bool


class Weights(NamedTuple):
    """A weighting's answer for one batch.

    :param weights: (n,) non-negative weights with mean 1, without grad; None: unweighted at this step
    :param figures: diagnostics to log, 0-d tensors on the device
    :param weighted: 0-d bool, whether the weights are in use (the weight figures are logged only then)
    """

    weights: Tensor | None
    figures: dict[str, Tensor]
    weighted: Tensor | None = None


def weight_figures(weights: Tensor, loss_before: Tensor, loss_after: Tensor, probs: Tensor | None) -> dict[str, Tensor]:
    """The figures SGFD_SAC logs of a batch's weights, as 0-d tensors."""
    figures = {
        "weight_ess": weights.sum().square() / weights.square().sum() / len(weights),  # Kish's ESS over n
        "weight_min": weights.min(),
        "weight_max": weights.max(),
        "decorrelation_loss_before": loss_before,
        "decorrelation_loss_after": loss_after,
    }
    if probs is not None:
        figures["top_saliency_feature"] = probs.argmax()
    return figures


class SampleWeighting(TensorStateModule):
    """What the two readings share: settings, classifier, optimiser, memory, the RFF generator, the compiled
    solver. A reading implements ``forward`` and ``solve``.

    :param n_features: dimension d of the features z
    :param n_domains: number of domain labels (the classifier's classes)
    :param settings: SGFD's settings (:class:`sb3_sgfd.sgfd.settings.SGFDSettings`)
    :param seed: seeds the RFF generator once (a checkpoint saves its state)
    :param device: where the classifier and the generator live
    :param compile_solver: run the solver's arithmetic compiled (``torch.compile``: it fuses)
    """

    official: bool = False
    classifier_optimizer: torch.optim.Optimizer

    def __init__(
        self,
        n_features: int,
        n_domains: int,
        settings: SGFDSettings,
        seed: int,
        device: torch.device | str = "cpu",
        compile_solver: bool = False,
    ) -> None:
        super().__init__()
        self.n_features, self.n_domains = n_features, n_domains
        self.settings = settings
        self.solver_settings = settings.solver_settings()
        self.seed = seed
        hidden = settings.classifier_hidden_dim
        self.classifier = DomainClassifier(n_features, max(n_domains, 2), hidden, orthogonal=self.official).to(device)
        self.memory = None if settings.reweight_memory is None else WeightMemory(settings.reweight_memory)
        self.rff_generator = torch.Generator(device=device).manual_seed(seed)
        core = official_solution if self.official else paper_solution
        self.core = torch.compile(core, dynamic=False) if compile_solver else core
        #: Whether the weights are on (the paper's reading waits for its classifier; sticky), a 0-d bool tensor.
        self.ready = torch.tensor(self.official, device=device)

    def active(self, num_timesteps: int) -> bool:
        """Whether the weighting does anything yet (before that, SGFD_SAC is SAC)."""
        return True

    def plan(self, update_index: int, num_timesteps: int, weights_wanted: bool) -> WeightingPlan:
        """The host's decisions for the update ``update_index``."""
        raise NotImplementedError

    def forward(
        self, z: Tensor, domains: Tensor, plan: WeightingPlan, fresh: Sequence[tuple[Tensor, Tensor]] = ()
    ) -> Weights:
        """The weights of one batch, and the classifier's work of this step, without a host read.

        :param z: the critic's (detached) encoder features of the batch, (n, d)
        :param domains: the batch's domain labels, (n,)
        :param plan: the host's decisions for this step
        :param fresh: the paper reading's further classifier batches (features, labels)
        """
        raise NotImplementedError

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The reading's weights for features ``z`` with its classifier as it is now, leaving every state as it is
        (the memory is read, not updated): for figures and benchmarks. Returns the weights (n,) with mean 1, and the
        decorrelation loss at uniform weights and at the weights."""
        raise NotImplementedError

    def state_tensors(self) -> dict[str, Tensor]:
        return {} if self.official else {"ready": self.ready.float()}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        if "ready" in tensors:
            self.ready = tensors["ready"].to(self.ready.device) > 0.5

    def load_legacy_state(self, state: dict[str, Any]) -> None:
        self.ready = torch.tensor(bool(state["ready"]), device=self.ready.device)

    def _apply(self, fn, recurse=True):  # type: ignore[no-untyped-def]
        self.ready = fn(self.ready)
        return super()._apply(fn, recurse)


class PaperWeighting(SampleWeighting):
    """The paper's reading of SGFD's weights (``SGFD_SAC(reading="paper")``, the default); its settings' defaults
    are :meth:`sb3_sgfd.sgfd.settings.SGFDSettings.paper`. The classifier steps with Adam."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.classifier_optimizer = torch.optim.Adam(self.classifier.parameters(), lr=self.settings.classifier_lr)

    def active(self, num_timesteps: int) -> bool:
        return num_timesteps >= self.settings.classifier_start

    def plan(self, update_index: int, num_timesteps: int, weights_wanted: bool) -> WeightingPlan:
        settings = self.settings
        classifier_round = settings.classifier_iters > 0 and update_index % settings.classifier_interval == 0
        return WeightingPlan(classifier_round, weights_wanted)

    def forward(
        self, z: Tensor, domains: Tensor, plan: WeightingPlan, fresh: Sequence[tuple[Tensor, Tensor]] = ()
    ) -> Weights:
        # Line 12's p(Z_i) and the batch's accuracy from one pass of the classifier as it was before this step
        predicted, gradient = self.classifier.predictions_and_input_gradient(z)
        figures = {"classifier_accuracy": accuracy(predicted, domains)}
        was_ready = self.ready.clone()
        if plan.classifier_round:  # lines 6-13: train while below the threshold; the first time at it, ready
            reached = classifier_round(
                self.classifier, self.classifier_optimizer, [(z, domains), *fresh], self.settings.accuracy_threshold
            )[1]
            self.ready.copy_(self.ready | reached)  # in place: a captured graph reads and writes it there
        if not plan.weights_wanted:
            return Weights(None, figures)
        probs = None
        if self.settings.use_saliency:  # ready before this step: its p; ready now: the classifier's after the round
            probs = self._probabilities(gradient)
            if plan.classifier_round:
                probs = torch.where(was_ready, probs, self._probabilities(self.classifier.input_gradient(z)))
        weights, before, after = self._solve(z, probs, self.rff_generator, update_memory=True)
        weights = torch.where(self.ready, weights, torch.ones_like(weights))  # lines 14-17 once ready
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)}, self.ready)

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        probs = self._probabilities(self.classifier.input_gradient(z)) if self.settings.use_saliency else None
        return self._solve(z, probs, generator, update_memory=False)

    def _probabilities(self, gradient: Tensor) -> Tensor:
        settings = self.settings
        return saliency_probabilities(
            gradient.abs().mean(dim=0), settings.saliency_temperature, True, settings.saliency_smoothing
        )

    def _solve(
        self, z: Tensor, probs: Tensor | None, generator: torch.Generator | None, update_memory: bool
    ) -> tuple[Tensor, Tensor, Tensor]:
        return solve_weights(
            z,
            probs,
            memory=self.memory,
            update_memory=update_memory,
            generator=generator,
            take=self.ready,
            core=self.core,
            **self.solver_settings,
        )


class OfficialWeighting(SampleWeighting):
    """The authors' code's reading of SGFD's weights (``SGFD_SAC(reading="official")``); its settings' defaults are
    :meth:`sb3_sgfd.sgfd.settings.SGFDSettings.official`. The classifier (orthogonal start) steps with SGD (momentum
    0.9, weight decay 1e-4) on the cross-entropy of its softmax output (a double softmax, as the code)."""

    official = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.classifier_optimizer = torch.optim.SGD(
            self.classifier.parameters(), lr=self.settings.classifier_lr, momentum=0.9, weight_decay=1e-4
        )

    def plan(self, update_index: int, num_timesteps: int, weights_wanted: bool) -> WeightingPlan:
        settings = self.settings
        classifier_round = (
            weights_wanted
            and settings.classifier_iters > 0
            and num_timesteps > settings.classifier_start
            and update_index % settings.classifier_interval == 0
        )
        return WeightingPlan(classifier_round, weights_wanted)

    def score(self, z: Tensor, domains: Tensor) -> Tensor:
        """The classifier's accuracy on a batch (0-d): below the threshold, a round trains it (the host decides)."""
        with torch.no_grad():
            return accuracy(self.classifier(z).argmax(dim=1), domains)

    def train_round(self, batches: Sequence[tuple[Tensor, Tensor]]) -> None:
        """A round's SGD steps, one per fresh batch (features of ``CLASSIFIER_BATCHES`` x the batch size, labels)."""
        for fresh_z, fresh_domains in batches:
            loss = F.cross_entropy(self.classifier.probabilities(fresh_z), fresh_domains)
            self.classifier_optimizer.zero_grad()
            loss.backward()
            self.classifier_optimizer.step()

    def forward(
        self, z: Tensor, domains: Tensor, plan: WeightingPlan, fresh: Sequence[tuple[Tensor, Tensor]] = ()
    ) -> Weights:
        accuracy_now = self.score(z, domains)  # after this step's round, if one trained
        figures = {"classifier_accuracy": accuracy_now}
        if not plan.weights_wanted:
            return Weights(None, figures)
        weights, before, after, probs = self._weights(z, self.rff_generator, update_memory=True)
        # The code reweights whenever the batch's accuracy is above 0 (a tensor choice: no host read).
        weighted = accuracy_now > 0
        weights = torch.where(weighted, weights, torch.ones_like(weights))
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)}, weighted)

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        weights, before, after, _ = self._weights(z, generator, update_memory=False)
        return weights, before, after

    def feature_probabilities(self, z: Tensor) -> Tensor:
        """p(Z_i) from the guided-backprop saliency of the batch (uniform without saliency): (d,)."""
        if not self.settings.use_saliency:
            return z.new_full((z.shape[1],), 1.0 / z.shape[1])
        saliency = self.classifier.guided_saliency(z).abs().mean(dim=0)
        return saliency_probabilities(
            saliency, self.settings.saliency_temperature, False, self.settings.saliency_smoothing
        )

    def _weights(
        self, z: Tensor, generator: torch.Generator | None, update_memory: bool
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        probs = self.feature_probabilities(z)
        weights, before, after = solve_official_weights(
            z,
            probs,
            memory=self.memory,
            update_memory=update_memory,
            generator=generator,
            core=self.core,
            **self.solver_settings,
        )
        return weights, before, after, (probs if self.settings.use_saliency else None)


#: The weighting of each reading (``SGFDSettings.reading``).
READINGS: dict[str, type[SampleWeighting]] = {"paper": PaperWeighting, "official": OfficialWeighting}
