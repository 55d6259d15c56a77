"""SGFD's weights as the authors' public code computes them (SiliHuang-ai/SGFD, the code behind the published
numbers), read from its behaviour and written here from those facts.

Pure torch, no Stable-Baselines3 import. Per gradient step on which the actor learns (the code weights the actor
loss only):

1. the classifier (MLP d-128-128-K, orthogonal init, softmax output) scores the batch; every
   ``classifier_interval`` steps, once ``num_timesteps > classifier_start``, while that accuracy is below
   ``accuracy_threshold`` (0.8), it takes ``classifier_iters`` (10) SGD steps (lr 0.01, momentum 0.9, weight
   decay 1e-4) on fresh, unaugmented replay batches of 5 x the batch size, with cross-entropy applied to its
   softmax output (a double softmax), and the batch is scored again. Nothing is sticky;
2. p(Z_i) = softmax_i(mean_k |GBP_i(z_k)|): guided backpropagation of the classifier's softmax probabilities,
   averaged over the classes, no temperature, no smoothing (on real features nearly uniform);
3. the weights, whenever the batch's accuracy is above 0 (in practice from the first update): 20 epochs of SGD
   (momentum 0.9, no weight decay; lr 1.0 for the first half, 0.1 for the second) on logits theta (from 1) of
   w = softmax(theta), minimising L / L.detach() + 5 P / P.detach() (the gradient of log L + 5 log P), P = sum
   w^2, L = sum over channels c and pairs i != j of p_i p_j Cov_c(u_i, u_j)^2 under the softmax weights of the
   batch and a memory of past batches together; the random Fourier features are drawn anew every epoch:
   ``u_i = sqrt(2 / m) [cos, sin](s_i)``, s_i = x_i omega_f + psi_if min-max scaled over the features (per sample
   and function) to [0, pi/2], one omega_f per function shared by every feature, so 2 m channels;
4. the memory (features and logits, batch-sized) is a running mean of the solved batches for its first 10
   updates, then an exponential average with momentum 0.9; its rows enter the loss with their logits fixed.

The code's very first solve also counts the memory's zero-initialised rows; here the first solve sees the batch
alone (one solve of a run). Gradients are in closed form (the tests compare them with autograd).
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from sb3_sgfd.sgfd.decorrelation import WeightMemory
from sb3_sgfd.sgfd.saliency import _accuracy, _probabilities
from sb3_sgfd.sgfd.settings import SGFDSettings
from sb3_sgfd.sgfd.weighting import SampleWeighting, Step, Weights, weight_figures

#: The code's classifier batches are this many replay batches' worth of samples (640 at batch 128).
CLASSIFIER_BATCHES = 5


class OfficialClassifier(nn.Module):
    """The code's domain classifier: Linear(d, hidden) -> ReLU -> Linear(hidden, hidden) -> ReLU -> Linear(K),
    weights orthogonal and biases zero at the start. ``forward`` returns logits; the code's softmax output is
    ``probabilities``.

    :param n_features: dimension d of the features
    :param n_domains: number K of domains
    :param hidden_dim: width of the hidden layers (128)
    """

    def __init__(self, n_features: int, n_domains: int, hidden_dim: int = 128) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(n_features, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, n_domains),
        )
        for layer in self.net:
            if isinstance(layer, nn.Linear):
                nn.init.orthogonal_(layer.weight)
                nn.init.zeros_(layer.bias)

    def forward(self, z: Tensor) -> Tensor:
        """:param z: features (n, d)
        :return: domain logits (n, K)"""
        return self.net(z)

    def probabilities(self, z: Tensor) -> Tensor:
        """The code's classifier output: softmax probabilities (n, K)."""
        return torch.softmax(self(z), dim=1)

    def guided_saliency(self, z: Tensor) -> Tensor:
        """Guided backpropagation of each class's probability to z, averaged over the classes: (n, d), without
        grad. Through a ReLU the gradient passes where the unit was active and the gradient is positive (Springenberg
        et al.); in closed form for this network (the tests compare it with autograd through guided ReLUs)."""
        first, second, last = (cast(nn.Linear, self.net[index]) for index in (0, 2, 4))
        with torch.no_grad():
            pre1 = first(z)
            pre2 = second(pre1.clamp_min(0))
            probs = torch.softmax(last(pre2.clamp_min(0)), dim=1)
            n_classes = probs.shape[1]
            # d probs_t / d logits = probs_t (e_t - probs), for every target class t: (K, n, K)
            eye = torch.eye(n_classes, dtype=probs.dtype, device=probs.device)
            upstream = probs.T.unsqueeze(2) * (eye.unsqueeze(1) - probs.unsqueeze(0))
            hidden2 = (upstream @ last.weight).clamp_min(0) * (pre2 > 0)
            hidden1 = (hidden2 @ second.weight).clamp_min(0) * (pre1 > 0)
            return (hidden1 @ first.weight).mean(dim=0)


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
    d = x.shape[1]
    device = generator.device if generator is not None else x.device
    omega = torch.randn(draws, 1, 1, n_rff, generator=generator, device=device).to(x)
    psi = 2 * math.pi * torch.rand(draws, 1, d, n_rff, generator=generator, device=device).to(x)
    # Laid out (draws, m, n, d), so that the scaling over the features reduces the last, contiguous axis;
    # cos and sin written in place of a concatenation. Six passes over the draws in all.
    s = x * omega.permute(0, 3, 1, 2) + psi.permute(0, 3, 1, 2)
    low, high = torch.aminmax(s, dim=3, keepdim=True)
    scale = (math.pi / 2) / (high - low).clamp_min(torch.finfo(s.dtype).tiny)
    s = torch.addcmul(-low * scale, s, scale)
    u = s.new_empty(draws, 2 * n_rff, *x.shape)
    torch.cos(s, out=u[:, :n_rff])
    torch.sin(s, out=u[:, n_rff:])
    return u.mul_(math.sqrt(2.0 / n_rff))


def official_loss_and_gradient(u: Tensor, a: Tensor, pairs: Tensor) -> tuple[Tensor, Tensor]:
    """L = sum_c sum_{i != j} pairs_ij Cov_c(i, j)^2 for channels u (C, N, d) under the distribution a (N,), and
    dL/da (N,) up to a term equal for every sample (which the softmax cancels).

    Cov_c = sum_k a_k (u_ck - mu_c)(u_ck - mu_c)^T with mu_c = sum_k a_k u_ck (the code's sum_k a_k u u^T - mu
    mu^T), so dL/da_k = sum_c (u_ck - mu_c)^T (2 pairs * Cov_c) (u_ck - mu_c) - (a term equal for every k).

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
) -> tuple[Tensor, Tensor, Tensor]:
    """The code's weight solver (point 3 of the module docstring), closed form, no host read.

    :param z: features of the batch (n, d), as they are (no standardisation)
    :param probs: p(Z_i) (d,)
    :param n_rff: functions m per RFF draw (2 m channels)
    :param iters: SGD epochs, one RFF draw each; the learning rate is divided by 10 for the second half
    :param lr: the first half's learning rate
    :param momentum: SGD momentum
    :param weight_decay: SGD weight decay on the logits (the code: none)
    :param ess_penalty: the weight of P / P.detach() (the code: 5)
    :param use_rff: False: the features themselves, one channel (the no-RFF ablation)
    :param memory: past batches decorrelated against (their logits fixed); None: this batch alone
    :param update_memory: move the memory towards this batch afterwards
    :param max_step: largest change of a logit in one step (a trust region, off in the code); None: unbounded
    :param generator: source of the RFF draws
    :return: weights (n,) with mean 1, and the loss of this batch alone at uniform weights and at the weights
        (on the first epoch's draw)
    """
    n = z.shape[0]
    z = z.detach().to(torch.float64 if z.dtype == torch.float64 else torch.float32)
    remembered = memory is not None and memory.remembers(z)
    every_z = torch.cat([z, memory.features.to(z)]) if remembered else z  # type: ignore[union-attr]
    fixed_logits = memory.logits.to(z) if remembered else None  # type: ignore[union-attr]
    draws = max(iters, 1)
    if use_rff:
        channels = official_fourier_features(every_z, n_rff, draws, generator)
    else:
        channels = every_z.expand(draws, 1, *every_z.shape)
    pairs = torch.outer(probs, probs).to(z)
    pairs = pairs - torch.diag(pairs.diagonal())
    theta = z.new_ones(n)
    velocity = torch.zeros_like(theta)
    for epoch in range(iters):
        a = torch.softmax(theta if fixed_logits is None else torch.cat([theta, fixed_logits]), dim=0)
        loss, grad_a = official_loss_and_gradient(channels[epoch], a, pairs)
        own = torch.softmax(theta, dim=0)
        concentration = own.square().sum()
        # grad of log L + penalty log P through the softmaxes (the memory's logits are constants)
        grad = (a * (grad_a - a @ grad_a))[:n] * torch.where(loss > 0, 1 / loss, 0.0)
        grad = grad + ess_penalty * 2 * own * (own - concentration) / concentration
        grad = torch.add(grad, theta, alpha=weight_decay)
        velocity = grad if epoch == 0 else torch.add(grad, velocity, alpha=momentum)
        step_lr = lr * 0.1 ** math.floor(epoch / (iters * 0.5))
        change = step_lr * velocity
        if max_step is not None:
            change = change * (max_step / change.abs().max()).clamp(max=1.0)
        theta = theta - change
    weights = n * torch.softmax(theta, dim=0)
    if memory is not None and update_memory:
        memory.update(z, theta)
    first = channels[0, :, :n]
    uniform = z.new_full((n,), 1.0 / n)
    before = official_loss(first, uniform, pairs)
    after = official_loss(first, weights / n, pairs)
    return weights, before, after


class OfficialWeighting(SampleWeighting):
    """
    The authors' code's reading of SGFD's weights (``SGFD_SAC(reading="official")``). Its settings'
    defaults are :meth:`sb3_sgfd.sgfd.settings.SGFDSettings.official`.

    :param n_features: dimension d of the features z
    :param n_domains: number of domain labels (the classifier's classes)
    :param settings: SGFD's settings (:class:`sb3_sgfd.sgfd.settings.SGFDSettings`)
    :param seed: seeds the RFF draws of each update (``seed + update_index``)
    :param device: where the classifier and the generators live
    """

    classifier: OfficialClassifier

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
        self.classifier = OfficialClassifier(n_features, max(n_domains, 2), settings.classifier_hidden_dim).to(device)
        self.classifier_optimizer = torch.optim.SGD(
            self.classifier.parameters(), lr=settings.classifier_lr, momentum=0.9, weight_decay=1e-4
        )
        self.memory = None if settings.reweight_memory is None else WeightMemory(settings.reweight_memory)
        self.rff_generator = torch.Generator(device=device)

    def forward(self, z: Tensor, domains: Tensor, step: Step) -> Weights:
        with torch.no_grad():
            accuracy = _accuracy(self.classifier(z).argmax(dim=1), domains)
        classifier_round = (
            step.weights_wanted
            and self.settings.classifier_iters > 0
            and step.num_timesteps > self.settings.classifier_start
            and step.update_index % self.settings.classifier_interval == 0
        )
        if classifier_round and bool(accuracy < self.settings.accuracy_threshold):
            for _ in range(self.settings.classifier_iters):
                fresh_z, fresh_domains = step.fresh_features(CLASSIFIER_BATCHES * len(z), False)
                loss = F.cross_entropy(self.classifier.probabilities(fresh_z), fresh_domains)
                self.classifier_optimizer.zero_grad()
                loss.backward()
                self.classifier_optimizer.step()
            with torch.no_grad():
                accuracy = _accuracy(self.classifier(z).argmax(dim=1), domains)
        figures = {"classifier_accuracy": accuracy}
        if not step.weights_wanted:
            return Weights(None, figures)
        self.rff_generator.manual_seed(self.seed + step.update_index)
        weights, before, after, probs = self._weights(z, self.rff_generator, update_memory=True)
        # The code reweights whenever the batch's accuracy is above 0 (a tensor choice: no host read).
        weights = torch.where(accuracy > 0, weights, torch.ones_like(weights))
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)})

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        weights, before, after, _ = self._weights(z, generator, update_memory=False)
        return weights, before, after

    def feature_probabilities(self, z: Tensor) -> Tensor:
        """p(Z_i) from the guided-backprop saliency of the batch (uniform without saliency): (d,)."""
        if not self.settings.use_saliency:
            return z.new_full((z.shape[1],), 1.0 / z.shape[1])
        saliency = self.classifier.guided_saliency(z).abs().mean(dim=0)
        return _probabilities(
            saliency, self.settings.saliency_temperature, normalize=False, smoothing=self.settings.saliency_smoothing
        )

    def _weights(
        self, z: Tensor, generator: torch.Generator | None, update_memory: bool
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        probs = self.feature_probabilities(z)
        weights, before, after = solve_official_weights(
            z, probs, memory=self.memory, update_memory=update_memory, generator=generator, **self.solver_settings
        )
        return weights, before, after, (probs if self.settings.use_saliency else None)
