"""Sample weights that decorrelate features (SGFD paper, sections 4.1-4.2, eqs. 3-7), as the paper reads and as the
authors' code computes them.

Pure torch, no Stable-Baselines3 import. Read top to bottom next to the paper:

1. random Fourier features: u(z_i) = sqrt(2) cos(omega z_i + psi), m functions per feature (eq. 4); the code's
   variant (one omega per function, min-max scaled, cos and sin);
2. the saliency-guided decorrelation loss sum_{i<j} p_i p_j ||Sigma_{Z_i Z_j; w}||_F^2 (eqs. 5-7) and its gradient
   in the sample distribution, in closed form; the code's per-channel form;
3. one solver loop (:func:`descend`: SGD with momentum on the logits theta of w = n softmax(theta)) and each
   reading's objective on it (:func:`solve_weights`, :func:`solve_official_weights`; Algorithm 1, lines 14-17), and
   a memory of past batches (:class:`WeightMemory`).

These take their inputs as checked where they entered; :mod:`sb3_sgfd.sgfd.functional` has the same functions for
a user, each checking its arguments (``learn_sample_weights``, ``decorrelation_loss``, ...).

The solvers make no host read: their random draws come first, then the arithmetic (``core``: what
``torch.compile`` fuses), then the memory's in-place update.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import Tensor

from sb3_sgfd.common.tensor_state import TensorStateModule
from sb3_sgfd.common.validation import (
    check_interval,
)

COVARIANCES = ("weighted", "literal")


# --- 1. Random Fourier features ---


def draw_fourier(
    omega_shape: tuple[int, ...], psi_shape: tuple[int, ...], like: Tensor, generator: torch.Generator | None
):
    """omega ~ N(0, 1) and psi ~ U(0, 2 pi) of the given shapes, drawn where the generator lives, as ``like``."""
    device = generator.device if generator is not None else like.device
    omega = torch.randn(omega_shape, generator=generator, device=device).to(like)
    psi = 2 * math.pi * torch.rand(psi_shape, generator=generator, device=device).to(like)
    return omega, psi


def fourier_features(z: Tensor, omega: Tensor, psi: Tensor) -> Tensor:
    return torch.cos(torch.addcmul(psi, z.unsqueeze(-1), omega)).mul_(math.sqrt(2.0))


def official_fourier_features(
    x: Tensor, n_rff: int, draws: int = 1, generator: torch.Generator | None = None
) -> Tensor:
    """``draws`` independent draws of the code's random Fourier features of x: (draws, 2 m, n, d), channel-first.

    For each draw, omega_f ~ N(0, 1) per function (shared by the features) and psi_if ~ U(0, 2 pi) per (feature,
    function); s = x omega + psi is min-max scaled over the features of each sample and function to [0, pi/2];
    the channels are sqrt(2 / m) cos(s) for each function, then sqrt(2 / m) sin(s).

    :param x: features (n, d)
    :param n_rff: functions m per draw
    :param draws: independent draws (the solver's epochs)
    :param generator: source of omega and psi (on its device)
    """
    return _official_features(x, *draw_fourier((draws, 1, 1, n_rff), (draws, 1, x.shape[1], n_rff), x, generator))


def _official_features(x: Tensor, omega: Tensor, psi: Tensor) -> Tensor:
    n_rff = omega.shape[-1]
    # Laid out (draws, m, n, d), so that the scaling over the features reduces the last, contiguous axis.
    s = x * omega.permute(0, 3, 1, 2) + psi.permute(0, 3, 1, 2)
    low, high = torch.aminmax(s, dim=3, keepdim=True)
    scale = (math.pi / 2) / (high - low).clamp_min(torch.finfo(s.dtype).tiny)
    s = torch.addcmul(-low * scale, s, scale)
    return torch.cat([torch.cos(s), torch.sin(s)], dim=1) * math.sqrt(2.0 / n_rff)


# --- 2. The decorrelation loss and its gradient ---


def weighted_centred_covariance(u: Tensor, a: Tensor) -> tuple[Tensor, Tensor]:
    """The rows of u (n, D) centred on their mean under the distribution a (n,), and their covariance (D, D) under it,
    sum_k a_k (u_k - mu)(u_k - mu)^T. As sum_k a_k (u_k - mu) = 0, the covariance is sum_k (u_k - mu) a_k u_k^T: the
    weighted rows give both mu and the covariance."""
    weighted = a.unsqueeze(1) * u
    centred = u - weighted.sum(dim=0)
    return centred, centred.T @ weighted


def covariance_matrix(u: Tensor, weights: Tensor, covariance: str) -> Tensor:
    """Covariance matrix (D, D) of the columns of u (n, D) under the sample weights."""
    if covariance == "weighted":
        # Covariance of the reweighted distribution: sum_k w_k (u_k - mu_w)(u_k - mu_w)^T / sum_k w_k.
        return weighted_centred_covariance(u, weights / weights.sum())[1]
    # Paper eq. 5 as printed: the plain covariance of the products w_k u_k.
    wu = weights.unsqueeze(1) * u
    centred = wu - wu.mean(dim=0)
    return centred.T @ centred / (u.shape[0] - 1)


def pair_weights(feature_probs: Tensor, m: int) -> Tensor:
    """(d*m, d*m) weight of each covariance entry: p_i p_j inside the (m x m) block of a pair i < j, else 0."""
    d = len(feature_probs)
    pairs = torch.triu(torch.outer(feature_probs, feature_probs), diagonal=1)
    return pairs[:, None, :, None].expand(d, m, d, m).reshape(d * m, d * m)


def flat_decorrelation_loss(features: Tensor, weights: Tensor, pairs: Tensor, covariance: str) -> Tensor:
    """sum_{i<j} p_i p_j ||Sigma_ij||_F^2 from one covariance of the flattened (n, d*m) features."""
    return (pairs * covariance_matrix(features, weights, covariance).square()).sum()


def scaled_loss_gradient(features: Tensor, a: Tensor, doubled_pairs: Tensor, covariance: str) -> tuple[Tensor, Tensor]:
    """dL/da for the flattened features (n, D) at the distribution a, given P + P^T (times any scale), and the
    covariance C it was taken at.

    With S = (P + P^T) / 2 and C the covariance, L = sum S * C^2 and dL/dC = G = (P + P^T) * C;

    - "weighted": C = sum_k a_k (u_k - mu)(u_k - mu)^T with mu = sum_k a_k u_k, so
      dL/da_k = (u_k - mu)^T G (u_k - mu) (mu moves with a, but L is stationary in mu at the weighted mean);
    - "literal" (eq. 5 as printed): C = Vc^T Vc / (n - 1) with V = diag(n a) U centred, so
      dL/da_k = 2 n / (n - 1) (Vc G)_k . u_k.

    Each is exact up to a term equal for every sample, which the solver's softmax cancels.
    """
    if covariance == "weighted":
        centred, cov = weighted_centred_covariance(features, a)
        return ((centred @ (doubled_pairs * cov)) * centred).sum(dim=1), cov
    n = features.shape[0]
    products = n * a.unsqueeze(1) * features
    centred = products - products.mean(dim=0)
    cov = centred.T @ centred / (n - 1)
    return 2 * n / (n - 1) * ((centred @ (doubled_pairs * cov)) * features).sum(dim=1), cov


def official_loss_and_gradient(u: Tensor, a: Tensor, pairs: Tensor) -> tuple[Tensor, Tensor]:
    """The code's L = sum_c sum_{i != j} pairs_ij Cov_c(i, j)^2 for channels u (C, N, d) under the distribution a
    (N,), and dL/da (N,) up to a term equal for every sample (which the softmax cancels).

    Cov_c = sum_k a_k (u_ck - mu_c)(u_ck - mu_c)^T with mu_c = sum_k a_k u_ck, so dL/da_k = sum_c (u_ck - mu_c)^T
    (2 pairs * Cov_c) (u_ck - mu_c) - (a term equal for every k).

    :param pairs: (d, d) symmetric pair weights p_i p_j, zero on the diagonal
    """
    centred, cov = _centred_covariance(u, a)
    grad = ((centred @ (2 * pairs * cov)) * centred).sum(dim=(0, 2))
    return (pairs * cov.square()).sum(), grad


def official_loss(u: Tensor, a: Tensor, pairs: Tensor) -> Tensor:
    """The loss of :func:`official_loss_and_gradient` alone, the same value, without the gradient's work."""
    return (pairs * _centred_covariance(u, a)[1].square()).sum()


def _centred_covariance(u: Tensor, a: Tensor) -> tuple[Tensor, Tensor]:
    """Channels u (C, N, d) centred under the distribution a (N,), and their covariances (C, d, d)."""
    centred = u - torch.einsum("n,cnd->cd", a, u).unsqueeze(1)
    return centred, centred.transpose(1, 2) @ (a.unsqueeze(1) * centred)


# --- 3. The solver ---


def descend(
    theta: Tensor, gradient: Callable[[int, Tensor], Tensor], steps: SolverSteps, lr: Callable[[int], float]
) -> Tensor:
    """``steps.iters`` steps of SGD with momentum and weight decay on the logits theta (torch's SGD, written out: no
    optimiser state, no host read), both readings' solver loop.

    :param theta: the starting logits (n,)
    :param gradient: (step, theta) -> the objective's gradient in theta
    :param steps: the steps' settings (``lr`` is read from the schedule below)
    :param lr: step -> learning rate
    """
    momentum, weight_decay, max_step = steps.momentum, steps.weight_decay, steps.max_step
    velocity = torch.zeros_like(theta)
    for step in range(steps.iters):
        grad = torch.add(gradient(step, theta), theta, alpha=weight_decay)
        velocity = grad if step == 0 else torch.add(grad, velocity, alpha=momentum)
        if max_step is None:
            theta = torch.add(theta, velocity, alpha=-lr(step))
        else:  # scaled as a tensor, not by a Python branch on its size: no host-device synchronisation
            change = lr(step) * velocity
            theta = theta - change * (max_step / change.abs().max()).clamp(max=1.0)
    return theta


Solution = tuple[Tensor, Tensor, Tensor, Tensor]  # weights (n,), logits (n,), loss before, loss after


class SolverInputs(NamedTuple):
    """What a solver core reads of one batch, drawn and gathered before its arithmetic (so that the core makes no
    random draw and no host read: what ``torch.compile`` fuses).

    :param z: the batch's features (n, d), as the reading prepares them
    :param probs: p(Z_i) (d,)
    :param omega: the RFF frequencies (None: the features themselves)
    :param psi: the RFF phases
    :param remembered: the memory's features (None: no memory)
    :param fixed_logits: the memory's weight logits, constants of the solve
    """

    z: Tensor
    probs: Tensor
    omega: Tensor | None
    psi: Tensor | None
    remembered: Tensor | None
    fixed_logits: Tensor | None


class SolverSteps(NamedTuple):
    """How a solver core descends (:func:`descend`) and how strongly it keeps the weights near uniform.

    :param iters: steps (the code's reading: epochs, each on its own RFF draw)
    :param lr: learning rate (the code's reading: divided by 10 for the second half)
    :param momentum: SGD momentum
    :param weight_decay: SGD weight decay on the logits
    :param ess_penalty: weight of the term that keeps the weights near uniform
    :param max_step: largest change of a logit in one step; None: unbounded
    """

    iters: int
    lr: float
    momentum: float
    weight_decay: float
    ess_penalty: float
    max_step: float | None


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
    take: Tensor | None = None,
    core: Callable[..., Solution] | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """The paper reading's weights (:func:`sb3_sgfd.sgfd.functional.learn_sample_weights` without its checks, the
    losses as 0-d tensors): what
    SGFD_SAC runs at every step, with no host read.

    :param update_memory: move ``memory`` towards this batch afterwards (False: only read it)
    :param take: a 0-d bool: the memory moves only where it is true (the weights are in use)
    :param core: the arithmetic (:func:`paper_solution`, or its compiled form)
    :return: weights (n,), the loss at uniform weights and at the weights (this batch alone, same RFF draw)
    """
    d = z.shape[1]
    z = z.detach().to(torch.float64 if z.dtype == torch.float64 else torch.float32)
    if feature_std is not None:
        # Constant features become 0 and so drop out of the loss.
        std, mean = torch.std_mean(z, dim=0)
        z = feature_std * (z - mean) / std.clamp_min(1e-8)
    omega, psi = draw_fourier((d, n_rff), (d, n_rff), z, generator) if use_rff else (None, None)
    probs = z.new_full((d,), 1.0 / d) if feature_probs is None else feature_probs.detach().to(z)
    remembered, fixed_logits = (None, None) if memory is None else memory.rows(z)
    inputs = SolverInputs(z, probs, omega, psi, remembered, fixed_logits)
    steps = SolverSteps(iters, lr, momentum, weight_decay, ess_penalty, max_step)
    weights, theta, before, after = (core or paper_solution)(inputs, steps, covariance)
    if memory is not None and update_memory:
        memory.update(z, theta, take)
    return weights, before, after


def paper_solution(inputs: SolverInputs, steps: SolverSteps, covariance: str) -> Solution:
    """The paper reading's objective, L(w) / L(1) + ess_penalty * (n / ESS(w) - 1) on one RFF draw, minimised by
    :func:`descend` from uniform weights (see ``learn_sample_weights`` for why each choice)."""
    z, probs, omega, psi, remembered, fixed_logits = inputs
    n, d = z.shape
    rows = z if remembered is None else torch.cat([z, remembered])
    features = fourier_features(rows, omega, psi) if omega is not None and psi is not None else rows.unsqueeze(-1)
    m = features.shape[2]
    features = features.reshape(len(rows), d * m)
    pairs = pair_weights(probs, m)
    doubled_pairs = pairs + pairs.T

    def distribution(theta: Tensor) -> Tensor:
        return torch.softmax(theta if fixed_logits is None else torch.cat([theta, fixed_logits]), dim=0)

    # The loss at the start scales the objective, so that the step size is independent of the scale of z, p and
    # the RFF; a loss of 0 (nothing to decorrelate) leaves only the penalty, whose gradient at uniform weights is 0.
    grad_start, cov = scaled_loss_gradient(features, distribution(z.new_zeros(n)), doubled_pairs, covariance)
    loss_start = (pairs * cov.square()).sum()
    scale = torch.where(loss_start > 0, 1 / loss_start, 0.0)
    scaled_pairs = doubled_pairs * scale
    penalty = 2 * steps.ess_penalty * n

    def gradient(step: int, theta: Tensor) -> Tensor:
        a = distribution(theta)
        grad_a = grad_start * scale if step == 0 else scaled_loss_gradient(features, a, scaled_pairs, covariance)[0]
        # d/da of loss + ess_penalty * (n sum(a^2) - 1); the penalty counts this batch only. Through the softmax:
        # a * (g - a . g) for each softmax (the memory's logits are constants).
        if fixed_logits is None:
            grad_a = torch.add(grad_a, a, alpha=penalty)
            return a * (grad_a - a @ grad_a)
        own = torch.softmax(theta, dim=0)
        return (a * (grad_a - a @ grad_a))[:n] + penalty * own * (own - own @ own)

    theta = descend(z.new_zeros(n), gradient, steps, lr=lambda _: steps.lr)
    weights = n * torch.softmax(theta, dim=0)
    own_features = features[:n]
    before = (
        loss_start
        if remembered is None
        else flat_decorrelation_loss(own_features, torch.ones_like(weights), pairs, covariance)
    )
    return weights, theta, before, flat_decorrelation_loss(own_features, weights, pairs, covariance)


def solve_official_weights(
    z: Tensor,
    probs: Tensor,
    *,
    n_rff: int = 5,
    iters: int = 20,
    lr: float = 1.0,
    momentum: float = 0.9,
    weight_decay: float = 0.0,
    ess_penalty: float = 5.0,
    use_rff: bool = True,
    memory: WeightMemory | None = None,
    update_memory: bool = True,
    max_step: float | None = None,
    generator: torch.Generator | None = None,
    core: Callable[..., Solution] | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """The code's weight solver, closed form, no host read: ``iters`` epochs of SGD (lr divided by 10 for the second
    half) on logits theta (from 1) of w = softmax(theta), minimising L / L.detach() + ess_penalty P / P.detach() (the
    gradient of log L + ess_penalty log P), P = sum w^2, L the per-channel loss under the softmax weights of the batch
    and the memory together, on a fresh RFF draw each epoch.

    :param z: features of the batch (n, d), as they are (no standardisation)
    :param probs: p(Z_i) (d,)
    :param memory: past batches decorrelated against (their logits fixed); None: this batch alone
    :param update_memory: move the memory towards this batch afterwards
    :param generator: source of the RFF draws
    :param core: the arithmetic (:func:`official_solution`, or its compiled form)
    :return: weights (n,) with mean 1, and the loss of this batch alone at uniform weights and at the weights (on the
        first epoch's draw)
    """
    d = z.shape[1]
    z = z.detach().to(torch.float64 if z.dtype == torch.float64 else torch.float32)
    draws = max(iters, 1)
    omega, psi = draw_fourier((draws, 1, 1, n_rff), (draws, 1, d, n_rff), z, generator) if use_rff else (None, None)
    remembered, fixed_logits = (None, None) if memory is None else memory.rows(z)
    inputs = SolverInputs(z, probs.to(z), omega, psi, remembered, fixed_logits)
    steps = SolverSteps(iters, lr, momentum, weight_decay, ess_penalty, max_step)
    weights, theta, before, after = (core or official_solution)(inputs, steps)
    if memory is not None and update_memory:
        memory.update(z, theta)
    return weights, before, after


def official_solution(inputs: SolverInputs, steps: SolverSteps) -> Solution:
    """The code's objective on :func:`descend` (see :func:`solve_official_weights`)."""
    z, probs, omega, psi, remembered, fixed_logits = inputs
    n, iters, ess_penalty = z.shape[0], steps.iters, steps.ess_penalty
    rows = z if remembered is None else torch.cat([z, remembered])
    draws = max(iters, 1)
    if omega is not None and psi is not None:
        channels = _official_features(rows, omega, psi)
    else:
        channels = rows.expand(draws, 1, *rows.shape)
    pairs = torch.outer(probs, probs)
    pairs = pairs - torch.diag(pairs.diagonal())

    def gradient(epoch: int, theta: Tensor) -> Tensor:
        a = torch.softmax(theta if fixed_logits is None else torch.cat([theta, fixed_logits]), dim=0)
        loss, grad_a = official_loss_and_gradient(channels[epoch], a, pairs)
        own = torch.softmax(theta, dim=0)
        concentration = own.square().sum()
        # grad of log L + penalty log P through the softmaxes (the memory's logits are constants)
        grad = (a * (grad_a - a @ grad_a))[:n] * torch.where(loss > 0, 1 / loss, 0.0)
        return grad + ess_penalty * 2 * own * (own - concentration) / concentration

    theta = descend(
        z.new_ones(n), gradient, steps, lr=lambda epoch: steps.lr * 0.1 ** math.floor(epoch / (iters * 0.5))
    )
    weights = n * torch.softmax(theta, dim=0)
    first = channels[0, :, :n]
    before = official_loss(first, z.new_full((n,), 1.0 / n), pairs)
    return weights, theta, before, official_loss(first, weights / n, pairs)


class WeightMemory(TensorStateModule):
    """Features and weight logits of past batches, which the solver decorrelates the current batch against.

    The official SGFD code (after StableNet) keeps one batch-sized memory: the loss is taken over the current
    batch and the memory together (its logits fixed), then the memory moves towards the current batch,
    ``memory = momentum * memory + (1 - momentum) * current`` (a running mean for its first
    ``1 / (1 - momentum)`` updates). The paper does not mention it; ``bench/decorrelation.py`` measures it.
    Its tensors are made at the first batch and updated in place (a captured graph reads them where they are);
    until an update has filled it the memory's rows carry no weight, so the first batch is solved alone.

    :param momentum: Weight of the memory in its update, in [0, 1)
    """

    def __init__(self, momentum: float = 0.9) -> None:
        super().__init__()
        check_interval("memory momentum", momentum, 0.0, 1.0, high_open=True)
        self.momentum = float(momentum)
        self.features: Tensor | None = None
        self.logits: Tensor | None = None
        self.count: Tensor | None = None  # updates so far, a 0-d float tensor

    @property
    def updates(self) -> int:
        """The updates so far (a host read)."""
        return 0 if self.count is None else int(self.count)

    def rows(self, features: Tensor) -> tuple[Tensor, Tensor]:
        """The remembered features for a batch like ``features`` and their logits, -inf while the memory is empty
        (no weight in a softmax); made at the first call, and afresh for a batch of another shape."""
        if self.features is None or self.features.shape != features.shape:
            self.features = torch.zeros_like(features)
            self.logits = features.new_zeros(len(features))
            self.count = features.new_zeros(())
        assert self.logits is not None and self.count is not None
        empty = torch.full_like(self.logits, -math.inf)
        return self.features.to(features), torch.where(self.count > 0, self.logits.to(features), empty)

    def update(self, features: Tensor, logits: Tensor, take: Tensor | None = None) -> None:
        """Move the memory towards one solved batch, in place (a running mean first, so that the start does not
        linger); with ``take`` (0-d bool), only where it is true.

        :param features: the batch's features as the solver saw them (n, d)
        :param logits: the solver's logits theta for it (n,)
        :param take: whether the batch's weights are in use
        """
        self.rows(features)  # made if need be
        assert self.features is not None and self.logits is not None and self.count is not None
        with torch.no_grad():
            keep = torch.clamp(self.count / (self.count + 1), max=self.momentum)
            moved_features = keep * self.features + (1 - keep) * features.detach()
            moved_logits = keep * self.logits + (1 - keep) * logits.detach()
            if take is None:
                self.features.copy_(moved_features), self.logits.copy_(moved_logits), self.count.add_(1)
            else:
                self.features.copy_(torch.where(take, moved_features, self.features))
                self.logits.copy_(torch.where(take, moved_logits, self.logits))
                self.count.add_(take.to(self.count.dtype))

    def state_tensors(self) -> dict[str, Tensor]:
        if self.features is None or self.logits is None or self.count is None:
            return {}
        return {"features": self.features, "logits": self.logits, "updates": self.count}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        self.features, self.logits = tensors.get("features"), tensors.get("logits")
        count = tensors.get("updates")
        self.count = (
            None if self.features is None else torch.as_tensor(0.0 if count is None else count).to(self.features)
        )

    def _apply(self, fn, recurse=True):  # type: ignore[no-untyped-def]
        # .to(device) moves the remembered tensors, which are not parameters or buffers.
        self.features = None if self.features is None else fn(self.features)
        self.logits = None if self.logits is None else fn(self.logits)
        self.count = None if self.count is None else fn(self.count)
        return super()._apply(fn, recurse)
