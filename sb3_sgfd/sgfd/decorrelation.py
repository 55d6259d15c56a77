"""Sample reweighting for feature decorrelation (SGFD paper, sections 4.1-4.2, eqs. 3-7).

Pure torch, no Stable-Baselines3 import. Read top to bottom next to the paper:

1. ``random_fourier_features``: u(z_i) = sqrt(2) cos(omega z_i + psi), m functions per feature (eq. 4).
2. ``decorrelation_loss``: sum_{i<j} p_i p_j ||Sigma_{Z_i Z_j; w}||_F^2 (eqs. 5-7; eq. 7 is the final loss).
3. ``learn_sample_weights``: a few SGD steps on the weights w (sum w = n, w >= 0), Algorithm 1 lines 14-17.
4. ``effective_sample_size`` and ``weighted_pearson``: what we check the weights with.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from sb3_sgfd.common.tensor_state import TensorStateModule
from sb3_sgfd.common.validation import (
    check_choice,
    check_interval,
    check_matrix,
    check_non_negative_int,
    check_optional_positive,
    check_positive_int,
)
from sb3_sgfd.sgfd.checks import check_probs, check_weights

COVARIANCES = ("weighted", "literal")


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
    return _fourier_features(z, n_features, generator)


def _fourier_features(z: Tensor, n_features: int, generator: torch.Generator | None) -> Tensor:
    d = z.shape[1]
    # Sample where the generator lives (a CPU generator cannot fill a CUDA tensor), then move.
    device = generator.device if generator is not None else z.device
    omega = torch.randn(d, n_features, generator=generator, device=device).to(z)
    psi = 2 * math.pi * torch.rand(d, n_features, generator=generator, device=device).to(z)
    return math.sqrt(2.0) * torch.cos(z.unsqueeze(-1) * omega + psi)


def _covariance(u: Tensor, weights: Tensor, covariance: str) -> Tensor:
    """Covariance matrix (D, D) of the columns of u (n, D) under the sample weights."""
    if covariance == "weighted":
        # Covariance of the reweighted distribution: sum_k w_k (u_k - mu_w)(u_k - mu_w)^T / sum_k w_k.
        w = weights / weights.sum()
        centred = u - w @ u
        return centred.T @ (w.unsqueeze(1) * centred)
    # Paper eq. 5 as printed: the plain covariance of the products w_k u_k.
    wu = weights.unsqueeze(1) * u
    centred = wu - wu.mean(dim=0)
    return centred.T @ centred / (u.shape[0] - 1)


def _pair_weights(feature_probs: Tensor, m: int) -> Tensor:
    """(d*m, d*m) weight of each covariance entry: p_i p_j inside the (m x m) block of a pair i < j, else 0."""
    d = len(feature_probs)
    pairs = torch.triu(torch.outer(feature_probs, feature_probs), diagonal=1)
    return pairs[:, None, :, None].expand(d, m, d, m).reshape(d * m, d * m)


def _decorrelation_loss(features: Tensor, weights: Tensor, pair_weights: Tensor, covariance: str) -> Tensor:
    """sum_{i<j} p_i p_j ||Sigma_ij||_F^2 from one covariance of the flattened (n, d*m) features."""
    cov = _covariance(features, weights, covariance)
    # Block (i, j) of cov is Sigma_{Z_i Z_j; w}; the weights pick the blocks above the diagonal.
    return (pair_weights * cov.square()).sum()


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
    pair_weights = _pair_weights(probs.to(rff), m)
    return _decorrelation_loss(rff.reshape(n, d * m), weights.to(rff), pair_weights, covariance)


class WeightMemory(TensorStateModule):
    """Features and weight logits of past batches, which the solver decorrelates the current batch against.

    The official SGFD code (after StableNet) keeps one batch-sized memory: the loss is taken over the current
    batch and the memory together (its logits fixed), then the memory moves towards the current batch,
    ``memory = momentum * memory + (1 - momentum) * current`` (a running mean for its first
    ``1 / (1 - momentum)`` updates). The paper does not mention it; ``bench/decorrelation.py`` measures it.
    Its state (the remembered features and logits, the update count) is saved in its state dict as tensors.

    :param momentum: Weight of the memory in its update, in [0, 1)
    """

    def __init__(self, momentum: float = 0.9) -> None:
        super().__init__()
        check_interval("memory momentum", momentum, 0.0, 1.0, high_open=True)
        self.momentum = float(momentum)
        self.features: Tensor | None = None
        self.logits: Tensor | None = None
        self.updates = 0

    def remembers(self, features: Tensor) -> bool:
        """Whether the memory holds rows of the shape of ``features`` (a batch of another size starts afresh)."""
        return self.features is not None and self.features.shape == features.shape

    def update(self, features: Tensor, logits: Tensor) -> None:
        """Move the memory towards one solved batch.

        :param features: the batch's features as the solver saw them (n, d)
        :param logits: the solver's logits theta for it (n,)
        """
        features, logits = features.detach(), logits.detach()
        if not self.remembers(features):
            self.features, self.logits, self.updates = features.clone(), logits.clone(), 0
        else:
            assert self.features is not None and self.logits is not None  # remembers() says so
            # A running mean first, so that the start does not linger.
            keep = min(self.momentum, self.updates / (self.updates + 1))
            self.features = keep * self.features + (1 - keep) * features
            self.logits = keep * self.logits + (1 - keep) * logits
        self.updates += 1

    def state_tensors(self) -> dict[str, Tensor]:
        if self.features is None or self.logits is None:
            return {}
        return {"features": self.features, "logits": self.logits, "updates": torch.tensor(float(self.updates))}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        self.features, self.logits = tensors.get("features"), tensors.get("logits")
        self.updates = int(tensors["updates"]) if "updates" in tensors else 0

    def load_legacy_state(self, state: dict[str, Any]) -> None:
        self.features, self.logits, self.updates = state["features"], state["logits"], int(state["updates"])

    def _apply(self, fn, recurse=True):  # type: ignore[no-untyped-def]
        # .to(device) moves the remembered tensors, which are not parameters or buffers.
        self.features = None if self.features is None else fn(self.features)
        self.logits = None if self.logits is None else fn(self.logits)
        return super()._apply(fn, recurse)


def _scaled_loss_gradient(features: Tensor, a: Tensor, doubled_pairs: Tensor, covariance: str) -> tuple[Tensor, Tensor]:
    """dL/da for the flattened features (n, D) at the distribution a, given P + P^T (times any scale), and the
    covariance C it was taken at (so that the solver's first step also gives it the loss at uniform weights).

    With S = (P + P^T) / 2 and C the covariance, L = sum S * C^2 and dL/dC = G = (P + P^T) * C;

    - "weighted": C = sum_k a_k (u_k - mu)(u_k - mu)^T with mu = sum_k a_k u_k, so
      dL/da_k = (u_k - mu)^T G (u_k - mu) (mu moves with a, but L is stationary in mu at the weighted mean);
    - "literal" (eq. 5 as printed): C = Vc^T Vc / (n - 1) with V = diag(n a) U centred, so
      dL/da_k = 2 n / (n - 1) (Vc G)_k . u_k.

    Each is exact up to a term equal for every sample, which the solver's softmax cancels.
    """
    if covariance == "weighted":
        centred = features - a @ features
        cov = centred.T @ (a.unsqueeze(1) * centred)
        return ((centred @ (doubled_pairs * cov)) * centred).sum(dim=1), cov
    n = features.shape[0]
    products = n * a.unsqueeze(1) * features
    centred = products - products.mean(dim=0)
    cov = centred.T @ centred / (n - 1)
    return 2 * n / (n - 1) * ((centred @ (doubled_pairs * cov)) * features).sum(dim=1), cov


def loss_gradient(
    rff: Tensor, a: Tensor, feature_probs: Tensor | None = None, *, covariance: str = "weighted"
) -> Tensor:
    """Gradient of ``decorrelation_loss`` in the sample distribution a = w / sum(w), in closed form: the
    solver's inner loop, two (n x D) by (D x D) products and no autograd (the tests compare it with autograd).

    :param rff: features per sample, shape (n, d, m)
    :param a: sample distribution, shape (n,), summing to 1
    :param feature_probs: p(Z_i), shape (d,); None = uniform
    :param covariance: "weighted" or "literal"
    :return: (n,) gradient, exact up to a term equal for every sample (see ``_scaled_loss_gradient``)
    """
    n, d, m = rff.shape
    check_choice("covariance", covariance, COVARIANCES)
    check_probs(feature_probs, d)
    probs = (rff.new_full((d,), 1.0 / d) if feature_probs is None else feature_probs).to(rff)
    pair_weights = _pair_weights(probs, m)
    return _scaled_loss_gradient(rff.reshape(n, d * m), a, pair_weights + pair_weights.T, covariance)[0]


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

    L = ``decorrelation_loss`` on one RFF draw of the batch. The gradient is in closed form
    (``loss_gradient``) and the SGD step (momentum, weight decay) is torch's, written out: no autograd and
    no host-device synchronisation inside the loop. Why these choices (the figures behind each are in the
    documentation's "design choices" page, measured by ``bench/decorrelation.py``):

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
        z,
        feature_probs,
        n_rff=n_rff,
        iters=iters,
        lr=lr,
        momentum=momentum,
        weight_decay=weight_decay,
        use_rff=use_rff,
        covariance=covariance,
        ess_penalty=ess_penalty,
        feature_std=feature_std,
        memory=memory,
        max_step=max_step,
        generator=generator,
    )
    if not torch.isfinite(weights).all():
        raise RuntimeError("learn_sample_weights produced non-finite weights; lower lr")
    return (weights, loss_before.item(), loss_after.item()) if return_losses else weights


def solve_weights(
    z: Tensor,
    feature_probs: Tensor | None,
    *,
    n_rff: int,
    iters: int,
    lr: float,
    momentum: float,
    weight_decay: float,
    use_rff: bool = True,
    covariance: str = "weighted",
    ess_penalty: float,
    feature_std: float | None = 0.5,
    memory: WeightMemory | None = None,
    update_memory: bool = True,
    max_step: float | None = None,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """``learn_sample_weights`` without its argument checks and with the losses as 0-d tensors: what SGFD_SAC
    runs at every step, with no host read (its inputs are checked where they enter).

    :param update_memory: move ``memory`` towards this batch afterwards (False: only read it)
    :return: weights (n,), the loss at uniform weights and at the weights (this batch alone, same RFF draw)
    """
    n, d = z.shape

    dtype = torch.float64 if z.dtype == torch.float64 else torch.float32
    z = z.detach().to(dtype)
    if feature_std is not None:
        # Constant features become 0 and so drop out of the loss.
        z = feature_std * (z - z.mean(dim=0)) / z.std(dim=0).clamp_min(1e-8)
    remembered = memory is not None and memory.remembers(z)
    every_z = torch.cat([z, memory.features.to(z)]) if remembered else z  # type: ignore[union-attr]
    features = _fourier_features(every_z, n_rff, generator) if use_rff else every_z.unsqueeze(-1)
    m = features.shape[2]
    features = features.reshape(len(every_z), d * m)
    probs = z.new_full((d,), 1.0 / d) if feature_probs is None else feature_probs.detach()

    fixed_logits = memory.logits.to(z) if remembered else None  # type: ignore[union-attr]

    def distribution(theta: Tensor) -> Tensor:
        return torch.softmax(theta if fixed_logits is None else torch.cat([theta, fixed_logits]), dim=0)

    pair_weights = _pair_weights(probs.to(z), m)
    doubled_pairs = pair_weights + pair_weights.T
    theta = z.new_zeros(n)
    a = distribution(theta)
    # The first step's gradient, at the starting weights, comes with the covariance there and so the loss.
    grad_a, cov = _scaled_loss_gradient(features, a, doubled_pairs, covariance)
    loss_start = (pair_weights * cov.square()).sum()
    # The loss divided by its starting value, and the factor 2 of dL/dC, folded into the pair weights once.
    # A loss of 0 (nothing to decorrelate) leaves only the penalty, whose gradient at uniform weights is
    # zero: theta stays 0 without a data-dependent branch (no host-device synchronisation in the loop).
    scale = torch.where(loss_start > 0, 1 / loss_start, 0.0)
    scaled_pairs = doubled_pairs * scale
    grad_a = grad_a * scale
    penalty = 2 * ess_penalty * n
    velocity = torch.zeros_like(theta)
    for step in range(iters):
        if step > 0:
            a = distribution(theta)
            grad_a = _scaled_loss_gradient(features, a, scaled_pairs, covariance)[0]
        # d/da of loss + ess_penalty * (n sum(a^2) - 1); the penalty counts this batch only.
        # Through the softmax: a * (g - a . g) for each softmax (the memory's logits are constants).
        if fixed_logits is None:  # one softmax for both terms: n sum(a^2) has gradient 2 n a
            grad_a = torch.add(grad_a, a, alpha=penalty)
            grad = a * (grad_a - a @ grad_a)
        else:
            own = torch.softmax(theta, dim=0)
            grad = (a * (grad_a - a @ grad_a))[:n] + penalty * own * (own - own @ own)
        grad = torch.add(grad, theta, alpha=weight_decay)
        velocity = grad if step == 0 else torch.add(grad, velocity, alpha=momentum)
        if max_step is None:
            theta = torch.add(theta, velocity, alpha=-lr)
        else:  # scaled as a tensor, not by a Python branch on its size: no host-device synchronisation
            change = lr * velocity
            theta = theta - change * (max_step / change.abs().max()).clamp(max=1.0)
    weights = n * torch.softmax(theta, dim=0)
    if memory is not None and update_memory:
        memory.update(z, theta)
    # The losses of this batch alone (without the memory), on the same draw.
    own_features = features[:n]
    if fixed_logits is None:
        loss_before = loss_start
    else:
        loss_before = _decorrelation_loss(own_features, torch.ones_like(weights), pair_weights, covariance)
    return weights, loss_before, _decorrelation_loss(own_features, weights, pair_weights, covariance)


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
    """Weighted Pearson correlation matrix of the columns of ``x``.

    Columns with no weighted variance (up to rounding) have correlation 0 with every other column.

    :param x: samples, shape (n, d)
    :param weights: non-negative sample weights (n,); None = uniform
    :return: (d, d) matrix with 1 on the diagonal
    """
    check_matrix(x, "x", min_rows=2, finite=True)
    n = x.shape[0]
    if weights is None:
        weights = torch.ones(n, dtype=x.dtype, device=x.device)
    check_weights(weights, n)
    cov = _covariance(x.detach(), weights.detach().to(x), "weighted")
    std = cov.diagonal().clamp_min(0).sqrt()
    # Centring a constant column leaves rounding noise of about eps * |x|; dividing by it would be noise too.
    varies = std > 10 * torch.finfo(x.dtype).eps * x.detach().abs().amax(dim=0)
    std = torch.where(varies, std, torch.ones_like(std))
    corr = (cov / torch.outer(std, std)).clamp(-1.0, 1.0)
    corr = torch.where(torch.outer(varies, varies), corr, torch.zeros_like(corr))
    corr.fill_diagonal_(1.0)
    return corr
