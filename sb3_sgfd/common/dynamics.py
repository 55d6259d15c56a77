"""The latent dynamics DBC and AMBS learn beside their metrics, and the distances between its predictions.

Pure torch, no Stable-Baselines3 import. Read next to DBC (Zhang et al., ICLR 2021, section 4) and AMBS (Chen &
Pan, ICLR 2022):

1. ``ProbabilisticTransitionModel``: the latent dynamics P^(z' | z, a) = N(mu(z, a), diag sigma(z, a)^2), sigma
   squashed into [min_sigma, max_sigma] (DBC section 4, "a probabilistic dynamics model"; AMBS runs it on the
   dynamics half of the representation); ``DeterministicTransitionModel`` predicts mu alone.
2. ``RewardDecoder``: the reward model R^(z) (DBC section 4; AMBS: on a sample of the predicted next dynamics
   representation).
3. ``gaussian_nll``: the dynamics model's loss, -log N(target; mu, sigma) up to the constant 0.5 log(2 pi).
4. ``wasserstein2``: W2 between two diagonal Gaussians, sqrt(||mu1 - mu2||^2 + ||sigma1 - sigma2||^2), in closed
   form (DBC section 4); ``dynamics_distance`` and ``dimension_distances``: the paper's and the codes' distances
   between the predictions for the two samples of each pair, the targets of the metrics in
   :mod:`sb3_sgfd.dbc.losses` and :mod:`sb3_sgfd.ambs.losses`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sb3_sgfd.common.validation import check_matrix, check_positive_int, check_same_shape


class ProbabilisticTransitionModel(nn.Module):
    """Latent dynamics N(mu(z, a), diag sigma(z, a)^2): [z, a] -> Linear -> LayerNorm -> ReLU -> (mu, sigma).

    sigma = min_sigma + (max_sigma - min_sigma) * sigmoid(head), so it lies in [min_sigma, max_sigma]
    (DBC's official bounds 1e-4 and 10).

    :param features_dim: size of the latent z (and of the predicted next latent)
    :param action_dim: size of the action
    :param hidden_dim: width of the hidden layer (512 in DBC and AMBS)
    :param min_sigma: smallest standard deviation, > 0
    :param max_sigma: largest standard deviation, >= min_sigma
    """

    def __init__(
        self,
        features_dim: int,
        action_dim: int,
        hidden_dim: int = 512,
        min_sigma: float = 1e-4,
        max_sigma: float = 10.0,
    ) -> None:
        super().__init__()
        check_positive_int(features_dim=features_dim)
        check_positive_int(action_dim=action_dim)
        check_positive_int(hidden_dim=hidden_dim)
        if not isinstance(min_sigma, (int, float)) or not math.isfinite(min_sigma) or min_sigma <= 0:
            raise ValueError(f"min_sigma must be a finite number > 0, got {min_sigma!r}")
        if not isinstance(max_sigma, (int, float)) or not math.isfinite(max_sigma) or max_sigma < min_sigma:
            raise ValueError(f"max_sigma must be a finite number >= min_sigma ({min_sigma}), got {max_sigma!r}")
        self.features_dim, self.action_dim = features_dim, action_dim
        self.min_sigma, self.max_sigma = float(min_sigma), float(max_sigma)
        self.trunk = nn.Sequential(
            nn.Linear(features_dim + action_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.ReLU()
        )
        self.mu = nn.Linear(hidden_dim, features_dim)
        self.sigma = nn.Linear(hidden_dim, features_dim)

    def forward(self, z: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and standard deviation of the next latent.

        :param z: latents, shape (n, features_dim)
        :param action: actions, shape (n, action_dim)
        :return: (mu, sigma), each (n, features_dim)
        """
        check_matrix(z, "z", cols=self.features_dim)
        check_matrix(action, "action", rows=z.shape[0], cols=self.action_dim)
        hidden = self.trunk(torch.cat([z, action], dim=1))
        sigma = self.min_sigma + (self.max_sigma - self.min_sigma) * torch.sigmoid(self.sigma(hidden))
        return self.mu(hidden), sigma

    def sample(self, z: Tensor, action: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """One reparametrised draw mu + sigma * eps, eps ~ N(0, I), of the next latent.

        :param z: latents, shape (n, features_dim)
        :param action: actions, shape (n, action_dim)
        :param generator: source of eps, sampled on its device and then moved, so the global RNG is left
            untouched; None draws from the global RNG
        :return: (n, features_dim), differentiable through mu and sigma
        """
        mu, sigma = self(z, action)
        device = generator.device if generator is not None else sigma.device
        eps = torch.randn(sigma.shape, generator=generator, device=device, dtype=sigma.dtype).to(sigma.device)
        return mu + sigma * eps


class DeterministicTransitionModel(nn.Module):
    """Latent dynamics mu(z, a), no spread: [z, a] -> Linear -> LayerNorm -> ReLU -> mu (the code's '' model,
    which the SGFD code's committed run uses).

    :param features_dim: size of the latent z (and of the predicted next latent)
    :param action_dim: size of the action
    :param hidden_dim: width of the hidden layer (512)
    """

    def __init__(self, features_dim: int, action_dim: int, hidden_dim: int = 512) -> None:
        super().__init__()
        check_positive_int(features_dim=features_dim)
        check_positive_int(action_dim=action_dim)
        check_positive_int(hidden_dim=hidden_dim)
        self.features_dim, self.action_dim = features_dim, action_dim
        self.trunk = nn.Sequential(
            nn.Linear(features_dim + action_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.ReLU()
        )
        self.mu = nn.Linear(hidden_dim, features_dim)

    def forward(self, z: Tensor, action: Tensor) -> tuple[Tensor, None]:
        """The predicted next latent and no standard deviation: (mu (n, features_dim), None)."""
        check_matrix(z, "z", cols=self.features_dim)
        check_matrix(action, "action", rows=z.shape[0], cols=self.action_dim)
        return self.mu(self.trunk(torch.cat([z, action], dim=1))), None

    def sample(self, z: Tensor, action: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """The prediction itself (a point mass)."""
        return self(z, action)[0]


class RewardDecoder(nn.Module):
    """Reward model z -> Linear -> LayerNorm -> ReLU -> Linear(1).

    :param features_dim: size of the latent z
    :param hidden_dim: width of the hidden layer (512 in DBC and AMBS)
    """

    def __init__(self, features_dim: int, hidden_dim: int = 512) -> None:
        super().__init__()
        check_positive_int(features_dim=features_dim)
        check_positive_int(hidden_dim=hidden_dim)
        self.features_dim = features_dim
        self.net = nn.Sequential(
            nn.Linear(features_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, 1)
        )

    def forward(self, z: Tensor) -> Tensor:
        """Predicted reward.

        :param z: latents, shape (n, features_dim)
        :return: (n, 1)
        """
        check_matrix(z, "z", cols=self.features_dim)
        return self.net(z)


def gaussian_nll(mu: Tensor, sigma: Tensor | None, target: Tensor, residual_scale: float = 1.0) -> Tensor:
    """Mean over all elements of 0.5 (s (mu - target) / sigma)^2 + log sigma; with s = 1, -log N(target; mu,
    sigma) - 0.5 log 2 pi.

    The transition model's loss in DBC and AMBS. ``target`` (the encoding of the next observation) should be
    detached by the caller, as in the official code: only the model and the encoder of the current observation
    learn from it. AMBS's code halves the residual (s = 0.5: its optimal sigma is half the spread of the
    residual); DBC's and the paper's is s = 1.

    :param mu: predicted means, shape (n, d)
    :param sigma: predicted standard deviations, shape (n, d), > 0; None: 1 (a deterministic model)
    :param target: observed next latents, shape (n, d)
    :param residual_scale: s, the factor on the residual
    :return: scalar loss
    """
    check_matrix(mu, "mu")
    check_same_shape(target, "target", mu, "mu")
    if sigma is None:
        return (0.5 * (residual_scale * (mu - target)).square()).mean()
    check_same_shape(sigma, "sigma", mu, "mu")
    return (0.5 * (residual_scale * (mu - target) / sigma).square() + torch.log(sigma)).mean()


def wasserstein2(mu1: Tensor, sigma1: Tensor, mu2: Tensor, sigma2: Tensor) -> Tensor:
    """2-Wasserstein distance between N(mu1, diag sigma1^2) and N(mu2, diag sigma2^2), one per row.

    For diagonal Gaussians W2^2 = ||mu1 - mu2||^2 + ||sigma1 - sigma2||^2 (the Frobenius term of the closed form
    for commuting covariances). DBC's official code takes sqrt((mu1 - mu2)^2 + (sigma1 - sigma2)^2) per
    dimension and never sums (the loss then averages over dimensions, as AMBS's does); this is the distance of
    the paper. The gradient is finite (zero) where the two Gaussians coincide.

    :param mu1: means of the first distributions, shape (n, d)
    :param sigma1: standard deviations of the first distributions, shape (n, d)
    :param mu2: means of the second distributions, shape (n, d)
    :param sigma2: standard deviations of the second distributions, shape (n, d)
    :return: (n,) distances
    """
    check_matrix(mu1, "mu1")
    check_same_shape(sigma1, "sigma1", mu1, "mu1")
    check_same_shape(mu2, "mu2", mu1, "mu1")
    check_same_shape(sigma2, "sigma2", mu1, "mu1")
    return torch.linalg.vector_norm(torch.cat([mu1 - mu2, sigma1 - sigma2], dim=1), dim=1)


def dynamics_distance(mu: Tensor, sigma: Tensor, perm: Tensor) -> Tensor:
    """The paper's target: W2 between the predicted next-latent distributions of i and perm(i), as a constant: (n,)."""
    mu, sigma = mu.detach(), sigma.detach()
    return wasserstein2(mu, sigma, mu[perm], sigma[perm])


def dimension_distances(mu: Tensor, sigma: Tensor | None, perm: Tensor) -> Tensor:
    """The code's per-dimension distance between the predictions for i and perm(i), as a constant: (n, k). W2 of
    each dimension's Gaussians, sqrt((mu_i - mu_j)^2 + (sigma_i - sigma_j)^2); for a deterministic model (sigma
    None) the Huber distance of the means."""
    mu = mu.detach()
    if sigma is None:
        return F.smooth_l1_loss(mu, mu[perm], reduction="none")
    sigma = sigma.detach()
    return torch.sqrt((mu - mu[perm]).square() + (sigma - sigma[perm]).square())
