"""SGFD's domain classifier (Algorithm 1, lines 6-13): the network, its accuracy, the feature probabilities p(Z_i) from
its saliency (section 4.2), and a classifier round: train while below the accuracy threshold, stop at it.

A round's decisions are Python branches in an eager step (:func:`classifier_round`: it stops at the first batch at
the threshold, as Algorithm 1 reads), and tensors in a captured one (:func:`masked_classifier_round`: every
batch is scored and stepped, the steps after the threshold masked off by :func:`masked_step`): the same training,
the second without a host read. Pure torch, no Stable-Baselines3 import.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from sb3_sgfd.common.validation import check_matrix
from sb3_sgfd.sgfd.checks import check_domains


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
    known_below: int = 0,
) -> tuple[Tensor, bool]:
    """The paper's classifier round (Algorithm 1, lines 7-13), decided on the host: each batch is scored first, and
    training stops at the first one classified with accuracy >= ``stop_accuracy``; otherwise a cross-entropy step on
    it. Scoring before the step makes the accuracy a held-out estimate.

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param optimizer: optimiser of the classifier's parameters
    :param batches: (features (n, d), domain labels (n,)) pairs, e.g. detached encoder features
    :param stop_accuracy: accuracy that ends training; None trains on every batch
    :param known_below: the first batches already scored below ``stop_accuracy`` by the caller (no host read again)
    :return: the last batch's accuracy (0-d), and whether the threshold was reached
    """
    if not batches:
        raise ValueError("a classifier round needs at least one batch")
    for index, (z, domains) in enumerate(batches):
        check_matrix(z, "z")
        check_domains(domains, z.shape[0])
        logits = classifier(z)  # one forward pass scores the batch and, below the threshold, trains on it
        scored = accuracy(logits.detach().argmax(dim=1), domains)
        if stop_accuracy is not None and index >= known_below and float(scored) >= stop_accuracy:
            return scored, True
        optimizer.zero_grad()
        F.cross_entropy(logits, domains).backward()
        optimizer.step()
    return scored, False


def masked_classifier_round(
    classifier: nn.Module,
    optimizer: torch.optim.Optimizer,
    batches: Sequence[tuple[Tensor, Tensor]],
    stop_accuracy: float | None = None,
) -> Tensor:
    """:func:`classifier_round` decided on the device, for a captured step: every batch is scored and
    stepped, each step from the first batch at the threshold on masked off (:func:`masked_step`). The same training,
    no host read.

    :return: whether the threshold was reached (0-d bool)
    """
    training = None
    for z, domains in batches:
        check_matrix(z, "z")
        check_domains(domains, z.shape[0])
        logits = classifier(z)
        scored = accuracy(logits.detach().argmax(dim=1), domains)
        below = scored < stop_accuracy if stop_accuracy is not None else scored.new_ones((), dtype=torch.bool)
        training = below if training is None else training & below
        optimizer.zero_grad()
        F.cross_entropy(logits, domains).backward()
        masked_step(optimizer, training)
    if training is None:
        raise ValueError("a classifier round needs at least one batch")
    return ~training


def masked_step(optimizer: torch.optim.Optimizer, take: Tensor) -> None:
    """``optimizer.step()`` where the 0-d bool ``take`` is true; where it is false, parameters and optimiser state stay
    as they were (a state the step made for the first time stays at zeros, which is how Adam's and SGD's momentum
    start): the decision stays on the device, no host read.

    :param optimizer: an optimiser whose state starts at zero (Adam; SGD with momentum and no dampening)
    :param take: whether the step happens
    """
    params = [param for group in optimizer.param_groups for param in group["params"] if param.grad is not None]
    before = {
        param: (
            param.detach().clone(),
            {
                name: value.clone()
                for name, value in optimizer.state.get(param, {}).items()
                if isinstance(value, Tensor)
            },
        )
        for param in params
    }
    optimizer.step()
    with torch.no_grad():
        for param, (value, state) in before.items():
            param.copy_(torch.where(take, param, value))
            for name, now in optimizer.state[param].items():
                if isinstance(now, Tensor):
                    old = state.get(name)
                    now.copy_(torch.where(take, now, torch.zeros_like(now) if old is None else old))
