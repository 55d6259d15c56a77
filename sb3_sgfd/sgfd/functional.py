"""SGFD's functions as a user calls them, each checking its arguments (one line naming a bad one): the random Fourier
features, the decorrelation loss and its gradient, the weights of one batch, the saliency and p(Z_i), and what the
weights are checked with (effective sample size, weighted Pearson correlation). The training loop calls the unchecked
engine in :mod:`sb3_sgfd.sgfd.decorrelation` and :mod:`sb3_sgfd.sgfd.weighting`, whose inputs are checked where they
enter."""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch
from torch import Tensor, nn

from sb3_sgfd.common.validation import (
    check_choice,
    check_interval,
    check_matrix,
    check_non_negative_int,
    check_optional_positive,
    check_positive,
    check_positive_int,
)
from sb3_sgfd.sgfd.checks import check_domains, check_probs, check_weights
from sb3_sgfd.sgfd.classifier import DomainClassifier, accuracy, classifier_round, saliency_probabilities
from sb3_sgfd.sgfd.decorrelation import (
    COVARIANCES,
    WeightMemory,
    covariance_matrix,
    draw_fourier,
    flat_decorrelation_loss,
    fourier_features,
    pair_weights,
    scaled_loss_gradient,
    solve_weights,
)

__all__ = [
    "classifier_accuracy",
    "decorrelation_loss",
    "effective_sample_size",
    "feature_probabilities",
    "learn_sample_weights",
    "loss_gradient",
    "random_fourier_features",
    "saliency_map",
    "train_classifier",
    "weighted_pearson",
]


def random_fourier_features(z: Tensor, n_features: int = 5, generator: torch.Generator | None = None) -> Tensor:
    """Random Fourier features of each column of ``z``: sqrt(2) cos(omega z + psi) (paper section 4.1).

    omega ~ N(0, 1) and psi ~ U(0, 2 pi) are drawn independently for every (feature, function) pair.

    :param z: features, shape (n, d)
    :param n_features: number m of random functions per feature
    :param generator: source of randomness; sampled on its device, so the global RNG is left untouched
    :return: tensor of shape (n, d, m)
    """
    check_matrix(z, "z", min_rows=2, finite=True)
    check_positive_int(n_features=n_features)
    return fourier_features(z, *draw_fourier((z.shape[1], n_features), (z.shape[1], n_features), z, generator))


def decorrelation_loss(
    rff: Tensor, weights: Tensor, feature_probs: Tensor | None = None, *, covariance: str = "weighted"
) -> Tensor:
    """Saliency-guided decorrelation loss: sum_{i<j} p_i p_j ||Sigma_{Z_i Z_j; w}||_F^2 (final SGFD loss).

    All pairs come from one (d*m) x (d*m) covariance matrix; no loop over pairs.

    :param rff: features per sample, shape (n, d, m) (``random_fourier_features``, or (n, d, 1) for raw ones)
    :param weights: sample weights, shape (n,), non-negative; differentiable
    :param feature_probs: p(Z_i), shape (d,), summing to 1; None means uniform (global decorrelation)
    :param covariance: "weighted" (covariance of the reweighted samples, see ``learn_sample_weights``)
        or "literal" (paper eq. 5 as printed: covariance of the products w_k u_k)
    :return: scalar loss
    """
    if not isinstance(rff, Tensor) or rff.dim() != 3 or rff.shape[0] < 2:
        shape = tuple(rff.shape) if isinstance(rff, Tensor) else type(rff).__name__
        raise ValueError(f"rff must be a tensor of shape (n, d, m) with n >= 2, got {shape}")
    if not torch.isfinite(rff).all():
        raise ValueError("rff contains NaN or inf values")
    check_weights(weights, rff.shape[0])
    check_probs(feature_probs, rff.shape[1])
    check_choice("covariance", covariance, COVARIANCES)
    n, d, m = rff.shape
    probs = rff.new_full((d,), 1.0 / d) if feature_probs is None else feature_probs
    return flat_decorrelation_loss(rff.reshape(n, d * m), weights.to(rff), pair_weights(probs.to(rff), m), covariance)


def loss_gradient(
    rff: Tensor, a: Tensor, feature_probs: Tensor | None = None, *, covariance: str = "weighted"
) -> Tensor:
    """Gradient of ``decorrelation_loss`` in the sample distribution a = w / sum(w), in closed form (no autograd;
    the tests compare it with autograd).

    :param rff: features per sample, shape (n, d, m)
    :param a: sample distribution, shape (n,), summing to 1
    :param feature_probs: p(Z_i), shape (d,); None = uniform
    :param covariance: "weighted" or "literal"
    :return: (n,) gradient, exact up to a term equal for every sample (see ``scaled_loss_gradient``)
    """
    n, d, m = rff.shape
    check_choice("covariance", covariance, COVARIANCES)
    check_probs(feature_probs, d)
    probs = (rff.new_full((d,), 1.0 / d) if feature_probs is None else feature_probs).to(rff)
    pairs = pair_weights(probs, m)
    return scaled_loss_gradient(rff.reshape(n, d * m), a, pairs + pairs.T, covariance)[0]


def learn_sample_weights(
    z: Tensor,
    feature_probs: Tensor | None = None,
    *,
    n_rff: int = 5,
    iters: int = 10,
    lr: float = 5.0,
    momentum: float = 0.9,
    weight_decay: float = 1e-4,
    use_rff: bool = True,
    covariance: str = "weighted",
    ess_penalty: float = 0.35,
    feature_std: float | None = 0.5,
    memory: WeightMemory | None = None,
    max_step: float | None = None,
    generator: torch.Generator | None = None,
    return_losses: bool = False,
) -> Tensor | tuple[Tensor, float, float]:
    """Sample weights that decorrelate the features of one batch (final SGFD loss; Alg. 1 lines 14-17).

    Takes ``iters`` SGD steps on logits theta, w = n softmax(theta) (so w >= 0 and sum w = n), minimising

        L(w) / L(1) + ess_penalty * (n / ESS(w) - 1),

    L = ``decorrelation_loss`` on one RFF draw of the batch. The gradient is in closed form (``loss_gradient``)
    and the loop is :func:`descend`. Why these choices (the figures behind each are in the documentation's "design
    choices" page, measured by ``bench/decorrelation.py``):

    - ``covariance="weighted"`` is the covariance of the reweighted samples. Eq. 5 as printed ("literal",
      the covariance of the products w_k u_k) also counts the spread of the weights themselves, so its
      minimum need not be a decorrelating reweighting: at a stable lr it barely decorrelates, and at a large
      one it collapses onto single samples.
    - Dividing by L(1), the loss at uniform weights, makes the step size independent of the scale of z,
      p and the RFF (the paper's lr 1e-2 then leaves the weights uniform).
    - ``ess_penalty``: n / ESS - 1 = mean(w^2) - 1, the official code's sum-of-squares penalty on the
      softmax weights, keeps the weights from collapsing onto a few samples; the strength knob.
    - ``feature_std``: features are standardised over the batch and rescaled to this std before the RFF,
      so omega ~ N(0, 1) meets the same scale on raw states as on tanh encoder features, whose spread of
      ~0.5 is what the paper's omega ~ N(0, 1) was used on. ``None`` is the paper's (z as is).
    - ``memory`` (off by default; the official code's, see :class:`WeightMemory`): the loss covers the
      current batch and the memory's features under its stored logits, and the memory is then updated.
    - ``max_step`` (off by default): a trust region, each SGD step scaled down so that no logit moves by
      more than ``max_step``; it protects the worst batches' effective sample size.

    A batch with nothing to decorrelate (loss 0 at uniform weights, e.g. d = 1) gets uniform weights.

    :param z: features of the batch, shape (n, d); detached here
    :param feature_probs: p(Z_i), shape (d,); None = uniform (global decorrelation)
    :param n_rff: random Fourier functions per feature (m)
    :param iters: SGD steps; 0 returns uniform weights
    :param lr: SGD learning rate on the logits theta
    :param momentum: SGD momentum
    :param weight_decay: SGD weight decay on theta (pulls towards uniform weights)
    :param use_rff: False decorrelates the standardised features themselves (the paper's "no RFF" ablation)
    :param covariance: "weighted" or "literal", see ``decorrelation_loss``
    :param ess_penalty: weight of the n / ESS - 1 penalty (0 disables it)
    :param feature_std: standard deviation the features are rescaled to before the RFF; None = as is
    :param memory: past batches to decorrelate against, updated in place; None = this batch only
    :param max_step: largest change of any logit in one step (a trust region); None = unbounded
    :param generator: RNG for the RFF draw; the global RNG is untouched when given
    :param return_losses: also return the loss at uniform weights and at the returned weights
    :return: weights (n,), non-negative, summing to n, without grad; with ``return_losses``
        the tuple (weights, loss_before, loss_after) of this batch alone, same RFF draw
    """
    check_matrix(z, "z", min_rows=2, finite=True)
    check_probs(feature_probs, z.shape[1])
    check_choice("covariance", covariance, COVARIANCES)
    check_positive_int(n_rff=n_rff)
    check_non_negative_int(iters=iters)
    numbers = {"lr": lr, "momentum": momentum, "weight_decay": weight_decay, "ess_penalty": ess_penalty}
    for name, value in numbers.items():
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    if feature_std is not None and (not isinstance(feature_std, (int, float)) or not feature_std > 0):
        raise ValueError(f"feature_std must be None or a number > 0, got {feature_std!r}")
    check_optional_positive("max_step", max_step)
    if memory is not None and not isinstance(memory, WeightMemory):
        raise ValueError(f"memory must be None or a WeightMemory, got {type(memory).__name__}")
    weights, loss_before, loss_after = solve_weights(
        z, feature_probs, n_rff=n_rff, iters=iters, lr=lr, momentum=momentum, weight_decay=weight_decay,
        use_rff=use_rff, covariance=covariance, ess_penalty=ess_penalty, feature_std=feature_std, memory=memory,
        max_step=max_step, generator=generator,
    )  # fmt: skip
    if not torch.isfinite(weights).all():
        raise RuntimeError("learn_sample_weights produced non-finite weights; lower lr")
    return (weights, loss_before.item(), loss_after.item()) if return_losses else weights


def saliency_map(classifier: nn.Module, z: Tensor, domains: Tensor | None = None) -> Tensor:
    """Mean absolute saliency M_i = |d f(z) / d z_i| over the batch (Simonyan et al.'s saliency map), f the logit of
    the domain the classifier predicts for each sample (or of the true one, given ``domains``). Logits, not
    probabilities: the softmax saturates once the classifier is confident (which SGFD waits for).

    :param classifier: maps (n, d) features to (n, K) logits
    :param z: features (n, d)
    :param domains: optional true domain labels (n,)
    :return: (d,) non-negative saliency, without grad
    """
    check_matrix(z, "z", finite=True)
    if domains is not None:
        check_domains(domains, z.shape[0])
        n_domains = classifier.n_domains if isinstance(classifier, DomainClassifier) else None
        if n_domains is not None and not 0 <= int(domains.min()) <= int(domains.max()) < n_domains:
            raise ValueError(f"domains must be labels in [0, {n_domains}), got {domains.unique().tolist()}")
    if isinstance(classifier, DomainClassifier):
        return classifier.input_gradient(z.detach(), domains).abs().mean(dim=0)
    # A copy that requires grad; autograd.grad w.r.t. it alone leaves the classifier's .grad untouched.
    z = z.detach().clone().requires_grad_(True)
    with torch.enable_grad():  # SAC may call this inside torch.no_grad()
        logits = classifier(z)
        if domains is not None and not 0 <= int(domains.min()) <= int(domains.max()) < logits.shape[1]:
            raise ValueError(f"domains must be labels in [0, {logits.shape[1]}), got {domains.unique().tolist()}")
        target = logits.argmax(dim=1) if domains is None else domains.to(logits.device)
        # Samples do not interact in an MLP (no batch norm), so d(sum_k f_k)/d z_k = d f_k / d z_k.
        (grad,) = torch.autograd.grad(logits.gather(1, target.long().unsqueeze(1)).sum(), z)
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
    """p(Z_i) = (1 - smoothing) softmax_i(M_i / temperature) + smoothing / d: how likely feature i is to change across
    domains (section 4.2), M the ``saliency_map``.

    Normalised (M divided by its largest entry), the most salient feature's share depends on the temperature alone
    (at 0.1 a feature at half the top saliency weighs e^-5 as much), not on how large the classifier's logits
    happen to be. ``smoothing`` mixes p with the uniform distribution: once one feature k takes nearly all the mass,
    the weight p_k p_j of a pair (k, j) is the partner's own p_j, which at temperature 0.1 varies by orders of
    magnitude between partners that are all barely salient. The paper's p = softmax(M) is ``temperature=1,
    normalize=False, smoothing=0``; the figures behind the defaults are in the documentation's "design choices".

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
    return saliency_probabilities(saliency_map(classifier, z, domains), temperature, normalize, smoothing)


def train_classifier(
    classifier: nn.Module,
    optimizer: torch.optim.Optimizer,
    batches: Iterable[tuple[Tensor, Tensor]],
    stop_accuracy: float | None = None,
) -> tuple[Tensor, int]:
    """The domain classifier trained as Algorithm 1 does, batch after batch (:func:`sb3_sgfd.sgfd.classifier.
    classifier_round` on each), stopping at the first batch that scores ``stop_accuracy`` before its step (a host
    read per batch): for analyses that train a classifier offline.

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param optimizer: optimiser of the classifier's parameters
    :param batches: (features (n, d), domain labels (n,)) pairs
    :param stop_accuracy: accuracy that ends training; None trains on every batch
    :return: the accuracy of the last batch scored (0-d), and the steps taken
    """
    scored, steps = torch.zeros(()), 0
    for z, domains in batches:
        scored, reached = classifier_round(classifier, optimizer, [(z, domains)], stop_accuracy)
        if reached:
            break
        steps += 1
    return scored, steps


def classifier_accuracy(classifier: nn.Module, z: Tensor, domains: Tensor) -> float:
    """Fraction of samples whose predicted domain is the true one (a host read).

    :param classifier: domain classifier, (n, d) -> (n, K) logits
    :param z: features (n, d)
    :param domains: true domain labels (n,)
    """
    check_matrix(z, "z", finite=True)
    check_domains(domains, z.shape[0])
    with torch.no_grad():
        return accuracy(classifier(z).argmax(dim=1), domains).item()


def effective_sample_size(weights: Tensor) -> float:
    """Kish's effective sample size (sum w)^2 / sum w^2: n for uniform weights, 1 for a single sample.

    :param weights: non-negative weights, shape (n,)
    """
    if not isinstance(weights, Tensor) or weights.dim() != 1 or weights.numel() < 1:
        raise ValueError("weights must be a 1-D tensor with at least one element")
    check_weights(weights, weights.shape[0])
    w = weights.detach().double()
    return (w.sum().square() / w.square().sum()).item()


def weighted_pearson(x: Tensor, weights: Tensor | None = None) -> Tensor:
    """Weighted Pearson correlation matrix of the columns of ``x``; columns with no weighted variance (up to
    rounding) have correlation 0 with every other column.

    :param x: samples, shape (n, d)
    :param weights: non-negative sample weights (n,); None = uniform
    :return: (d, d) matrix with 1 on the diagonal
    """
    check_matrix(x, "x", min_rows=2, finite=True)
    n = x.shape[0]
    if weights is None:
        weights = torch.ones(n, dtype=x.dtype, device=x.device)
    check_weights(weights, n)
    cov = covariance_matrix(x.detach(), weights.detach().to(x), "weighted")
    std = cov.diagonal().clamp_min(0).sqrt()
    # Centring a constant column leaves rounding noise of about eps * |x|; dividing by it would be noise too.
    varies = std > 10 * torch.finfo(x.dtype).eps * x.detach().abs().amax(dim=0)
    std = torch.where(varies, std, torch.ones_like(std))
    corr = (cov / torch.outer(std, std)).clamp(-1.0, 1.0)
    corr = torch.where(torch.outer(varies, varies), corr, torch.zeros_like(corr))
    corr.fill_diagonal_(1.0)
    return corr
