"""Domain classifier and the feature probabilities p(Z_i) from its saliency (SGFD paper, section 4.2)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import cast

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from sb3_sgfd.common.validation import check_interval, check_matrix, check_positive
from sb3_sgfd.sgfd.checks import check_domains


class DomainClassifier(nn.Module):
    """MLP that predicts the training domain of a feature vector (paper Table 3: 2 hidden layers of 128, ReLU).

    :param n_features: dimension d of the features (50 for the paper's encoder)
    :param n_domains: number K of training domains
    :param hidden_dim: width of the two hidden layers
    """

    def __init__(self, n_features: int, n_domains: int, hidden_dim: int = 128) -> None:
        super().__init__()
        sizes = (("n_features", n_features, 1), ("n_domains", n_domains, 2), ("hidden_dim", hidden_dim, 1))
        for name, value, low in sizes:
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
        self.n_features = n_features
        self.n_domains = n_domains
        self.net = nn.Sequential(
            nn.Linear(n_features, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, n_domains),
        )

    def forward(self, z: Tensor) -> Tensor:
        """:param z: features (n, n_features)
        :return: domain logits (n, n_domains)"""
        if z.dim() != 2 or z.shape[1] != self.n_features:
            raise ValueError(f"z must have shape (n, {self.n_features}), got {tuple(z.shape)}")
        return self.net(z)

    def input_gradient(self, z: Tensor, domains: Tensor | None = None) -> Tensor:
        """d f_k(z_k) / d z_k for each sample, f_k the logit of its predicted (or given) domain, in closed form:
        through the ReLU network that is W1^T [h1 > 0] W2^T [h2 > 0] w3_k, one forward pass and three small
        products, without autograd (the tests compare it with autograd).

        :param z: features (n, n_features)
        :param domains: the domain whose logit to differentiate per sample; None: the predicted one
        :return: (n, n_features), without grad
        """
        return self.predictions_and_input_gradient(z, domains)[1]

    def predictions_and_input_gradient(self, z: Tensor, domains: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """The predicted domains (n,) and ``input_gradient``, from one forward pass."""
        first, second, last = (cast(nn.Linear, self.net[index]) for index in (0, 2, 4))
        with torch.no_grad():
            h1 = first(z).clamp_min(0)
            h2 = second(h1).clamp_min(0)
            predicted = last(h2).argmax(dim=1)
            target = predicted if domains is None else domains.to(z.device).long()
            g2 = last.weight[target] * (h2 > 0)
            g1 = (g2 @ second.weight) * (h1 > 0)
            return predicted, g1 @ first.weight


def saliency_map(classifier: nn.Module, z: Tensor, domains: Tensor | None = None) -> Tensor:
    """Mean absolute saliency M_i = |d f(z) / d z_i| over the batch (Simonyan et al.'s saliency map).

    f is the logit of the domain the classifier predicts for each sample, or of the true domain when
    ``domains`` is given. Logits, not probabilities: the softmax saturates once the classifier is
    confident (which SGFD waits for) and would leave no gradient.

    :param classifier: maps (n, d) features to (n, K) logits
    :param z: features (n, d)
    :param domains: optional true domain labels (n,)
    :return: (d,) non-negative saliency, without grad
    """
    check_matrix(z, "z", finite=True)
    if domains is not None:
        check_domains(domains, z.shape[0])
    if isinstance(classifier, DomainClassifier):
        if domains is not None and not 0 <= int(domains.min()) <= int(domains.max()) < classifier.n_domains:
            raise ValueError(f"domains must be labels in [0, {classifier.n_domains}), got {domains.unique().tolist()}")
        return classifier.input_gradient(z.detach(), domains).abs().mean(dim=0)
    # A copy that requires grad; autograd.grad w.r.t. it alone leaves the classifier's .grad untouched.
    z = z.detach().clone().requires_grad_(True)
    with torch.enable_grad():  # SAC may call this inside torch.no_grad()
        logits = classifier(z)
        if domains is not None and not 0 <= int(domains.min()) <= int(domains.max()) < logits.shape[1]:
            raise ValueError(f"domains must be labels in [0, {logits.shape[1]}), got {domains.unique().tolist()}")
        target = logits.argmax(dim=1) if domains is None else domains.to(logits.device)
        # Samples do not interact in an MLP (no batch norm), so d(sum_k f_k)/d z_k = d f_k / d z_k.
        score = logits.gather(1, target.long().unsqueeze(1)).sum()
        (grad,) = torch.autograd.grad(score, z)
    return grad.abs().mean(dim=0)


def feature_probabilities(
    classifier: nn.Module,
    z: Tensor,
    *,
    temperature: float = 0.1,
    normalize: bool = True,
    smoothing: float = 0.3,
    domains: Tensor | None = None,
) -> Tensor:
    """p(Z_i) = (1 - smoothing) softmax_i(M_i / temperature) + smoothing / d: how likely feature i is to
    change across domains (section 4.2).

    M is ``saliency_map`` (mean |d logit / d z_i| over the batch), divided by its largest entry when
    ``normalize`` is on. The paper's p = softmax(M) on the raw saliency depends on how large the classifier's
    logits happen to be, so the same classifier, its logits scaled, guides the weights differently;
    normalised, the most salient feature's share depends on the temperature alone (at 0.1 a feature at half
    the top saliency weighs e^-5 as much).

    ``smoothing`` mixes p with the uniform distribution. Once one feature k takes nearly all the mass, the
    weight p_k p_j of a pair (k, j) in the loss is the partner's own p_j, and at temperature 0.1 that varies
    by orders of magnitude between partners that are all barely salient: without the mixing the solver works
    on whichever partner happens to be a little salient, not on the partners correlated with k. The figures
    behind both choices are in the documentation's "design choices" page (``bench/decorrelation.py`` and
    ``sgfd-zoo correlation-study``).

    The paper's p = softmax(M) is ``temperature=1, normalize=False, smoothing=0``.

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param z: features (n, d)
    :param temperature: softmax temperature (> 0); smaller puts more weight on the most salient features
    :param normalize: divide the saliency by its maximum over features first (scale-free p)
    :param smoothing: weight in [0, 1] of the uniform distribution mixed into p
    :param domains: optional true labels; the saliency is then taken on the true domain's logit
    :return: (d,) probabilities summing to 1, without grad
    """
    check_positive(temperature=temperature)
    check_interval("smoothing", smoothing, 0.0, 1.0)
    return _probabilities(saliency_map(classifier, z, domains), temperature, normalize, smoothing)


def scored_feature_probabilities(
    classifier: DomainClassifier,
    z: Tensor,
    domains: Tensor,
    *,
    temperature: float = 0.1,
    normalize: bool = True,
    smoothing: float = 0.3,
) -> tuple[Tensor, Tensor]:
    """``feature_probabilities`` (on each sample's predicted domain) and ``classifier_accuracy`` on ``domains``,
    from one pass of the classifier: all SGFD needs of it on a step that learns weights. No host read: the
    features' values are checked where they enter (the replay buffer), the accuracy is a 0-d tensor.

    :param classifier: the domain classifier
    :param z: features (n, d)
    :param domains: true domain labels (n,), for the accuracy
    :return: p(Z_i) (d,) without grad, and the fraction of samples whose domain is predicted right
    """
    check_positive(temperature=temperature)
    check_interval("smoothing", smoothing, 0.0, 1.0)
    check_matrix(z, "z")
    check_domains(domains, z.shape[0])
    predicted, gradient = classifier.predictions_and_input_gradient(z.detach())
    accuracy = _accuracy(predicted, domains)
    return _probabilities(gradient.abs().mean(dim=0), temperature, normalize, smoothing), accuracy


def _probabilities(m: Tensor, temperature: float, normalize: bool, smoothing: float) -> Tensor:
    """p(Z_i) from the saliency M (d,), as ``feature_probabilities`` describes."""
    if normalize:
        m = m / m.max().clamp_min(torch.finfo(m.dtype).tiny)
    probs = torch.softmax(m / temperature, dim=0)
    return ((1 - smoothing) * probs + smoothing / probs.numel()).detach()


def train_classifier(
    classifier: nn.Module,
    optimizer: torch.optim.Optimizer,
    batches: Iterable[tuple[Tensor, Tensor]],
    stop_accuracy: float | None = None,
    first_below: bool = False,
) -> tuple[Tensor, int]:
    """The domain classifier's training loop (Algorithm 1, lines 7-13): each batch is scored first, and the
    loop stops at the first one classified with accuracy >= ``stop_accuracy``; otherwise one cross-entropy
    step on it. Scoring before the step makes the accuracy a held-out estimate. Deciding whether to stop is a
    host read per batch; with ``stop_accuracy=None`` there is none.

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param optimizer: optimiser of the classifier's parameters
    :param batches: (features (n, d), domain labels (n,)) pairs, e.g. detached encoder features
    :param stop_accuracy: accuracy that ends training; None trains on every batch
    :param first_below: the first batch is known to score below ``stop_accuracy`` (no host read to check it)
    :return: the accuracy of the last batch scored (a 0-d tensor; 0 if there was none) and the steps taken; with
        ``stop_accuracy``, fewer steps than batches means it was reached
    """
    accuracy, steps = torch.zeros(()), 0
    for index, (z, domains) in enumerate(batches):
        check_matrix(z, "z")
        check_domains(domains, z.shape[0])
        logits = classifier(z)  # one forward pass scores the batch and, below the threshold, trains on it
        accuracy = _accuracy(logits.detach().argmax(dim=1), domains)
        known_below = first_below and index == 0
        if stop_accuracy is not None and not known_below and bool(accuracy >= stop_accuracy):
            break
        loss = F.cross_entropy(logits, domains)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        steps += 1
    return accuracy, steps


def classifier_accuracy(classifier: nn.Module, z: Tensor, domains: Tensor) -> float:
    """Fraction of samples whose predicted domain is the true one (SGFD trains the classifier until > 0.9).

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param z: features (n, d)
    :param domains: true domain labels (n,)
    """
    check_matrix(z, "z", finite=True)
    check_domains(domains, z.shape[0])
    with torch.no_grad():
        predicted = classifier(z).argmax(dim=1)
    return _accuracy(predicted, domains).item()


def _accuracy(predicted: Tensor, domains: Tensor) -> Tensor:
    """Fraction of the predicted domains (n,) that are the true ones (n,), as a 0-d tensor on their device."""
    return (predicted == domains.to(predicted.device)).float().mean()
