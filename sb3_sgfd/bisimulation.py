"""Bisimulation-metric representation losses: DBC (Zhang et al., ICLR 2021) and AMBS (Chen & Pan, ICLR 2022).

Pure torch, no Stable-Baselines3 import. Read top to bottom next to the papers:

1. ``ProbabilisticTransitionModel``: the latent dynamics P^(z' | z, a) = N(mu(z, a), diag sigma(z, a)^2), sigma
   squashed into [min_sigma, max_sigma] (DBC section 4, "a probabilistic dynamics model"; AMBS runs it on the
   dynamics half of the representation).
2. ``RewardDecoder``: the reward model R^(z) (DBC section 4; AMBS: on a sample of the predicted next dynamics
   representation).
3. ``gaussian_nll``: the dynamics model's loss, -log N(target; mu, sigma) up to the constant 0.5 log(2 pi).
4. ``wasserstein2``: W2 between two diagonal Gaussians, sqrt(||mu1 - mu2||^2 + ||sigma1 - sigma2||^2), in closed
   form (DBC section 4).
5. ``bisimulation_loss``: DBC's encoder objective
   J(phi) = (||z_i - z_j||_1 - |r_i - r_j| - gamma W2(P^(. | z_i, a_i), P^(. | z_j, a_j)))^2,
   the on-policy bisimulation metric d(s_i, s_j) = |r_i - r_j| + gamma W2(...) made the L1 distance of the
   encodings, over pairs (i, perm(i)) of one batch.
6. ``MetricLearner`` and ``split_halves``: AMBS's decomposition phi(s) = [phi_r(s), phi_d(s)] (reward and
   dynamics representations) and its meta-learners d_r, d_d, small networks measuring each half.
7. ``ambs_metric_loss``: AMBS's objective, each meta-learner matched to its own term of the bisimulation
   metric, weighted by the balance c (the encoder's softmax ratio):
   (c d_r(phi_r(s_i), phi_r(s_j)) - c |r_i - r_j|)^2 + ((1 - c) d_d(phi_d(s_i), phi_d(s_j)) - (1 - c) gamma W2)^2,
   over the batch pairs and augmented pairs of the official code, each term halved as there; the official
   auxiliary loss is 0.5 * this + 0.01 * (transition NLL + reward MSE).
8. ``ambs_distance``: the learned behavioural distance c d_r + (1 - c) d_d between two representations.

The authors' code computes both metrics differently from their papers, and the published numbers came from the
code; each has its own function here, the default of the objectives (``metric="code"``):

- ``bisimulation_loss_code`` (deep_bisim4control): per-dimension Huber (smooth L1) distances of z and r and a
  per-dimension W2, the squared error averaged over every element; on the same tensors about 1000x smaller than
  the paper's ``bisimulation_loss`` at d = 50, the scale its ``bisim_coef`` 0.5 was set for;
- ``ambs_metric_loss_code`` (AMBS): the reward target a Huber distance of the rewards, the dynamics target W2 per
  dimension averaged over the dimensions; without meta-learners (the SGFD code's committed setting) Huber and
  squared distances of the halves, and with a deterministic transition model a per-dimension Huber distance of
  the predicted means; AMBS's code also halves the transition NLL's residual (``gaussian_nll``'s
  ``residual_scale=0.5``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def _check_positive_int(value: object, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be an int >= 1, got {value!r}")


def _check_matrix(x: Tensor, name: str, rows: int | None = None, cols: int | None = None) -> None:
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {x.dtype}")
    wrong_rows = rows is not None and x.dim() == 2 and x.shape[0] != rows
    wrong_cols = cols is not None and x.dim() == 2 and x.shape[1] != cols
    if x.dim() != 2 or x.shape[1] < 1 or wrong_rows or wrong_cols:
        expected = f"({'n' if rows is None else rows}, {'d' if cols is None else cols})"
        raise ValueError(f"{name} must have shape {expected}, got {tuple(x.shape)}")


def _check_same_shape(x: Tensor, name: str, like: Tensor, like_name: str) -> None:
    _check_matrix(x, name)
    if x.shape != like.shape:
        raise ValueError(f"{name} must have the shape of {like_name} {tuple(like.shape)}, got {tuple(x.shape)}")


def _check_rewards(rewards: Tensor, n: int) -> Tensor:
    """Rewards (n,) or (n, 1) as a (n,) tensor."""
    if not isinstance(rewards, Tensor) or rewards.shape not in ((n,), (n, 1)):
        shape = tuple(rewards.shape) if isinstance(rewards, Tensor) else type(rewards).__name__
        raise ValueError(f"rewards must be a tensor of shape ({n},) or ({n}, 1), got {shape}")
    return rewards.reshape(n)


def _check_perm(perm: Tensor, n: int) -> None:
    # Shape and dtype only: whether it is a permutation would be a host read on every gradient step (the
    # objectives draw it with randperm), and any pairing of the rows is a well-defined loss.
    if not isinstance(perm, Tensor) or perm.shape != (n,) or perm.dtype not in (torch.int32, torch.int64):
        shape = f"{tuple(perm.shape)} {perm.dtype}" if isinstance(perm, Tensor) else type(perm).__name__
        raise ValueError(f"perm must be an integer tensor of shape ({n},), got {shape}")


def _check_gamma(gamma: float) -> None:
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not 0 <= gamma < 1:
        raise ValueError(f"gamma must be a number in [0, 1), got {gamma!r}")


def _check_reward_weight(reward_weight: float | Tensor) -> Tensor | float:
    """The balance c as given: a float in [0, 1], or a 0-d float tensor, detached (a softmax ratio, in [0, 1] by
    construction: its value is not read, which would be a host read on every gradient step)."""
    if isinstance(reward_weight, Tensor):
        if reward_weight.dim() != 0 or not reward_weight.is_floating_point():
            raise ValueError(f"reward_weight must be a float or a 0-d float tensor, got shape {reward_weight.shape}")
        return reward_weight.detach()
    if not isinstance(reward_weight, (int, float)) or isinstance(reward_weight, bool):
        raise ValueError(f"reward_weight must be a float or a 0-d float tensor, got {type(reward_weight).__name__}")
    if not 0 <= reward_weight <= 1:
        raise ValueError(f"reward_weight must be in [0, 1], got {reward_weight!r}")
    return float(reward_weight)


def _check_reward_dim(reward_dim: int, d: int) -> None:
    if isinstance(reward_dim, bool) or not isinstance(reward_dim, int) or not 0 < reward_dim < d:
        raise ValueError(f"reward_dim must be an int in [1, {d - 1}] for {d} features, got {reward_dim!r}")


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
        _check_positive_int(features_dim, "features_dim")
        _check_positive_int(action_dim, "action_dim")
        _check_positive_int(hidden_dim, "hidden_dim")
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
        _check_matrix(z, "z", cols=self.features_dim)
        _check_matrix(action, "action", rows=z.shape[0], cols=self.action_dim)
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
        _check_positive_int(features_dim, "features_dim")
        _check_positive_int(action_dim, "action_dim")
        _check_positive_int(hidden_dim, "hidden_dim")
        self.features_dim, self.action_dim = features_dim, action_dim
        self.trunk = nn.Sequential(
            nn.Linear(features_dim + action_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.ReLU()
        )
        self.mu = nn.Linear(hidden_dim, features_dim)

    def forward(self, z: Tensor, action: Tensor) -> tuple[Tensor, None]:
        """The predicted next latent and no standard deviation: (mu (n, features_dim), None)."""
        _check_matrix(z, "z", cols=self.features_dim)
        _check_matrix(action, "action", rows=z.shape[0], cols=self.action_dim)
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
        _check_positive_int(features_dim, "features_dim")
        _check_positive_int(hidden_dim, "hidden_dim")
        self.features_dim = features_dim
        self.net = nn.Sequential(
            nn.Linear(features_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, 1)
        )

    def forward(self, z: Tensor) -> Tensor:
        """Predicted reward.

        :param z: latents, shape (n, features_dim)
        :return: (n, 1)
        """
        _check_matrix(z, "z", cols=self.features_dim)
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
    _check_matrix(mu, "mu")
    _check_same_shape(target, "target", mu, "mu")
    if sigma is None:
        return (0.5 * (residual_scale * (mu - target)).square()).mean()
    _check_same_shape(sigma, "sigma", mu, "mu")
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
    _check_matrix(mu1, "mu1")
    _check_same_shape(sigma1, "sigma1", mu1, "mu1")
    _check_same_shape(mu2, "mu2", mu1, "mu1")
    _check_same_shape(sigma2, "sigma2", mu1, "mu1")
    return torch.linalg.vector_norm(torch.cat([mu1 - mu2, sigma1 - sigma2], dim=1), dim=1)


def _dynamics_distance(mu: Tensor, sigma: Tensor, perm: Tensor) -> Tensor:
    """W2 between the predicted next-latent distributions of i and perm(i), as a constant: (n,)."""
    mu, sigma = mu.detach(), sigma.detach()
    return wasserstein2(mu, sigma, mu[perm], sigma[perm])


def bisimulation_loss(z: Tensor, rewards: Tensor, mu: Tensor, sigma: Tensor, perm: Tensor, gamma: float) -> Tensor:
    """DBC's encoder loss: mean over the pairs (i, perm(i)) of (||z_i - z_j||_1 - |r_i - r_j| - gamma W2_ij)^2.

    W2_ij = ``wasserstein2`` between the transition model's predictions for i and j. The target
    |r_i - r_j| + gamma W2_ij is a constant: ``mu`` and ``sigma`` should come from the model under
    ``torch.no_grad`` on the current latents and actions (the official code's), and are detached here as well,
    so only ``z`` gets gradients (the stop-gradient on z in the paper's W2 term). The official code measures
    z and r with a Huber distance per dimension and W2 per dimension, averaging the squared errors over the
    dimensions; this is the paper's objective, with the L1 norm summed over the features.

    :param z: encodings of a batch, shape (n, d), with grad
    :param rewards: rewards of the batch, shape (n,) or (n, 1)
    :param mu: predicted next-latent means for each sample, shape (n, k)
    :param sigma: predicted next-latent standard deviations, shape (n, k)
    :param perm: a permutation of range(n); sample i is paired with perm[i]
    :param gamma: discount of the bisimulation metric, in [0, 1)
    :return: scalar loss
    """
    _check_matrix(z, "z")
    n = z.shape[0]
    r = _check_rewards(rewards, n).to(z)
    _check_matrix(mu, "mu", rows=n)
    _check_same_shape(sigma, "sigma", mu, "mu")
    _check_perm(perm, n)
    _check_gamma(gamma)
    perm = perm.to(z.device)
    z_dist = (z - z[perm]).abs().sum(dim=1)
    target = (r - r[perm]).abs() + gamma * _dynamics_distance(mu.to(z), sigma.to(z), perm)
    return (z_dist - target).square().mean()


def _dimension_distances(mu: Tensor, sigma: Tensor | None, perm: Tensor) -> Tensor:
    """The code's per-dimension distance between the predictions for i and perm(i), as a constant: (n, k). W2 of
    each dimension's Gaussians, sqrt((mu_i - mu_j)^2 + (sigma_i - sigma_j)^2); for a deterministic model (sigma
    None) the Huber distance of the means."""
    mu = mu.detach()
    if sigma is None:
        return F.smooth_l1_loss(mu, mu[perm], reduction="none")
    sigma = sigma.detach()
    return torch.sqrt((mu - mu[perm]).square() + (sigma - sigma[perm]).square())


def bisimulation_loss_code(
    z: Tensor, rewards: Tensor, mu: Tensor, sigma: Tensor | None, perm: Tensor, gamma: float
) -> Tensor:
    """DBC's encoder loss as its authors' code computes it: the mean over the pairs (i, j = perm(i)) and the
    dimensions k of (H(z_ik - z_jk) - H(r_i - r_j) - gamma W2_ijk)^2, H the Huber function (smooth L1, delta 1)
    and W2_ijk that of dimension k (``_dimension_distances``). The paper's form is ``bisimulation_loss``.

    :param z: encodings of a batch, shape (n, d), with grad
    :param rewards: rewards of the batch, shape (n,) or (n, 1)
    :param mu: predicted next-latent means, shape (n, d) (the transition model predicts the whole latent)
    :param sigma: their standard deviations, shape (n, d); None: a deterministic model
    :param perm: sample i is paired with perm[i] (a permutation of range(n))
    :param gamma: discount of the bisimulation metric, in [0, 1)
    :return: scalar loss
    """
    _check_matrix(z, "z")
    n = z.shape[0]
    r = _check_rewards(rewards, n).to(z)
    _check_same_shape(mu, "mu", z, "z")
    if sigma is not None:
        _check_same_shape(sigma, "sigma", mu, "mu")
    _check_perm(perm, n)
    _check_gamma(gamma)
    perm = perm.to(z.device)
    z_dist = F.smooth_l1_loss(z, z[perm], reduction="none")
    r_dist = F.smooth_l1_loss(r, r[perm], reduction="none").unsqueeze(1)
    target = r_dist + gamma * _dimension_distances(mu.to(z), None if sigma is None else sigma.to(z), perm)
    return (z_dist - target).square().mean()


class MetricLearner(nn.Module):
    """AMBS's meta-learner d(a, b) = f([a, b])^2, f: Linear(2 * half_dim, hidden) -> ReLU -> Linear(1).

    The concatenation is ordered, as in AMBS, so d(a, b) and d(b, a) differ in general; squaring keeps d >= 0.
    Nothing trains d(a, a) to 0 either: on the test task the self-distance stays near a quarter of the distance
    between observations that differ in their task-relevant part.

    :param half_dim: size of each of the two inputs (one half of the representation)
    :param hidden_dim: width of the hidden layer (50 in AMBS)
    """

    def __init__(self, half_dim: int, hidden_dim: int = 50) -> None:
        super().__init__()
        _check_positive_int(half_dim, "half_dim")
        _check_positive_int(hidden_dim, "hidden_dim")
        self.half_dim = half_dim
        self.net = nn.Sequential(nn.Linear(2 * half_dim, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, 1))

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        """Learned distance of each row of ``a`` to the same row of ``b``.

        :param a: first representations, shape (n, half_dim)
        :param b: second representations, shape (n, half_dim)
        :return: (n,) non-negative distances
        """
        _check_matrix(a, "a", cols=self.half_dim)
        _check_same_shape(b, "b", a, "a")
        return self.net(torch.cat([a, b], dim=1)).squeeze(1).square()


def split_halves(z: Tensor, reward_dim: int) -> tuple[Tensor, Tensor]:
    """AMBS's decomposition of a representation: the first ``reward_dim`` features phi_r, the rest phi_d.

    :param z: representations, shape (n, d)
    :param reward_dim: size of the reward part, in [1, d - 1] (AMBS: round(d / 2))
    :return: (reward part (n, reward_dim), dynamics part (n, d - reward_dim)), views of ``z``
    """
    _check_matrix(z, "z")
    _check_reward_dim(reward_dim, z.shape[1])
    return z[:, :reward_dim], z[:, reward_dim:]


def _check_learner(learner: object, name: str, half_dim: int) -> None:
    if not isinstance(learner, MetricLearner) or learner.half_dim != half_dim:
        got = f"half_dim {learner.half_dim}" if isinstance(learner, MetricLearner) else type(learner).__name__
        raise ValueError(f"{name} must be a MetricLearner with half_dim {half_dim}, got {got}")


def ambs_distance(
    h_a: Tensor,
    h_b: Tensor,
    reward_weight: float | Tensor,
    reward_learner: MetricLearner,
    dynamics_learner: MetricLearner,
    reward_dim: int,
) -> Tensor:
    """AMBS's learned behavioural distance c d_r(a_r, b_r) + (1 - c) d_d(a_d, b_d) between representations.

    :param h_a: first representations (pre-ratio encoder features), shape (n, d)
    :param h_b: second representations, shape (n, d)
    :param reward_weight: the balance c in [0, 1] (the softmax ratio of the reward half); detached here
    :param reward_learner: meta-learner d_r on the reward halves
    :param dynamics_learner: meta-learner d_d on the dynamics halves
    :param reward_dim: size of the reward half
    :return: (n,) distances
    """
    _check_matrix(h_a, "h_a")
    _check_same_shape(h_b, "h_b", h_a, "h_a")
    c = _check_reward_weight(reward_weight)
    _check_reward_dim(reward_dim, h_a.shape[1])
    _check_learner(reward_learner, "reward_learner", reward_dim)
    _check_learner(dynamics_learner, "dynamics_learner", h_a.shape[1] - reward_dim)
    a_rew, a_dyn = split_halves(h_a, reward_dim)
    b_rew, b_dyn = split_halves(h_b, reward_dim)
    return c * reward_learner(a_rew, b_rew) + (1 - c) * dynamics_learner(a_dyn, b_dyn)


def ambs_metric_loss(
    h: Tensor,
    aug_h: Tensor,
    rewards: Tensor,
    mu: Tensor,
    sigma: Tensor | None,
    perm: Tensor,
    reward_weight: float | Tensor,
    reward_learner: MetricLearner,
    dynamics_learner: MetricLearner,
    gamma: float,
    reward_dim: int,
) -> Tensor:
    """AMBS's metric loss: each meta-learner regressed onto its own term of the bisimulation metric.

    With c = ``reward_weight``, j = perm(i), and every pair (A, B) in {(h_i, h_j), (h_j, aug_h_i)} (the official
    code's batch pairs and augmented pairs, both with the target of (i, j)):

        0.5 mean (c d_r(A_r, B_r) - c |r_i - r_j|)^2 + 0.5 mean ((1 - c) d_d(A_d, B_d) - (1 - c) gamma W2_ij)^2,

    W2_ij = ``wasserstein2`` between the transition model's predictions for i and j on the dynamics half
    (constant, detached here as well). The 0.5 on each half is the official code's, whose auxiliary loss is then
    ``0.5 * ambs_metric_loss + 0.01 * (gaussian_nll + reward MSE)`` (bisim_coef 0.5, the 1e-2 hard-coded).
    The official code measures rewards with a Huber distance (smooth L1) and W2 per dimension averaged over the
    dimensions (``ambs_metric_loss_code``); here |r_i - r_j| and the exact W2, as in the paper.

    :param h: pre-ratio encoder features of one augmented view of the batch, shape (n, d), with grad
    :param aug_h: pre-ratio features of a second augmented view of the same observations, shape (n, d)
    :param rewards: rewards of the batch, shape (n,) or (n, 1)
    :param mu: predicted next dynamics-half means for each sample, shape (n, d - reward_dim)
    :param sigma: predicted next dynamics-half standard deviations, shape (n, d - reward_dim); None: a
        deterministic model (W2 between point masses, the distance of the means)
    :param perm: a permutation of range(n); sample i is paired with perm[i]
    :param reward_weight: the balance c in [0, 1], a float or a 0-d tensor (softmax ratio); detached here
    :param reward_learner: meta-learner d_r on the reward halves (trained by this loss too)
    :param dynamics_learner: meta-learner d_d on the dynamics halves (trained by this loss too)
    :param gamma: discount of the bisimulation metric, in [0, 1)
    :param reward_dim: size of the reward half, in [1, d - 1]
    :return: scalar loss
    """
    _check_matrix(h, "h")
    _check_same_shape(aug_h, "aug_h", h, "h")
    n, d = h.shape
    r = _check_rewards(rewards, n).to(h)
    _check_reward_dim(reward_dim, d)
    _check_matrix(mu, "mu", rows=n, cols=d - reward_dim)
    sigma = torch.zeros_like(mu) if sigma is None else sigma
    _check_same_shape(sigma, "sigma", mu, "mu")
    _check_perm(perm, n)
    _check_gamma(gamma)
    c = _check_reward_weight(reward_weight)
    _check_learner(reward_learner, "reward_learner", reward_dim)
    _check_learner(dynamics_learner, "dynamics_learner", d - reward_dim)
    perm = perm.to(h.device)

    first = torch.cat([h, h[perm]])
    second = torch.cat([h[perm], aug_h])
    first_rew, first_dyn = split_halves(first, reward_dim)
    second_rew, second_dyn = split_halves(second, reward_dim)
    rew_dist = c * reward_learner(first_rew, second_rew)
    dyn_dist = (1 - c) * dynamics_learner(first_dyn, second_dyn)
    rew_target = (c * (r - r[perm]).abs()).repeat(2)
    dyn_target = ((1 - c) * gamma * _dynamics_distance(mu.to(h), sigma.to(h), perm)).repeat(2)
    return 0.5 * F.mse_loss(rew_dist, rew_target) + 0.5 * F.mse_loss(dyn_dist, dyn_target)


def ambs_metric_loss_code(
    h: Tensor,
    aug_h: Tensor,
    rewards: Tensor,
    mu: Tensor,
    sigma: Tensor | None,
    perm: Tensor,
    reward_weight: float | Tensor,
    reward_learner: MetricLearner | None,
    dynamics_learner: MetricLearner | None,
    gamma: float,
    reward_dim: int,
) -> Tensor:
    """AMBS's metric loss as its authors' code computes it (the paper's form is ``ambs_metric_loss``).

    With c = ``reward_weight``, j = perm(i), and the pairs (A, B) in {(h_i, h_j), (h_j, aug_h_i)} of
    ``ambs_metric_loss``:

        0.5 mean (D_r(A_r, B_r) - c H(r_i - r_j))^2 + 0.5 mean (D_d(A_d, B_d) - gamma T_ij)^2,

    H the Huber function (smooth L1), T_ij = (1 - c) times the mean over the dimensions of each dimension's W2
    between the predictions for i and j; with a deterministic transition model (``sigma`` None), (1 - c) times the
    per-dimension Huber distance of the predicted means, the squared error then averaged over the dimensions too.
    With the meta-learners, D_r = c d_r and D_d = (1 - c) d_d (AMBS); without them (``reward_learner`` and
    ``dynamics_learner`` None, the SGFD code's committed setting), D_r = c mean_k H(A_rk - B_rk) and D_d =
    mean_k ((1 - c) (A_dk - B_dk))^2.

    :param h: pre-ratio encoder features of one augmented view of the batch, shape (n, d), with grad
    :param aug_h: pre-ratio features of a second augmented view of the same observations, shape (n, d)
    :param rewards: rewards of the batch, shape (n,) or (n, 1)
    :param mu: predicted next dynamics-half means, shape (n, d - reward_dim)
    :param sigma: their standard deviations, the same shape; None: a deterministic model
    :param perm: sample i is paired with perm[i] (a permutation of range(n))
    :param reward_weight: the balance c in [0, 1], a float or a 0-d tensor (softmax ratio); detached here
    :param reward_learner: meta-learner d_r on the reward halves, or None (both or neither)
    :param dynamics_learner: meta-learner d_d on the dynamics halves, or None
    :param gamma: discount of the bisimulation metric, in [0, 1)
    :param reward_dim: size of the reward half, in [1, d - 1]
    :return: scalar loss
    """
    _check_matrix(h, "h")
    _check_same_shape(aug_h, "aug_h", h, "h")
    n, d = h.shape
    r = _check_rewards(rewards, n).to(h)
    _check_reward_dim(reward_dim, d)
    _check_matrix(mu, "mu", rows=n, cols=d - reward_dim)
    if sigma is not None:
        _check_same_shape(sigma, "sigma", mu, "mu")
    _check_perm(perm, n)
    _check_gamma(gamma)
    c = _check_reward_weight(reward_weight)
    if (reward_learner is None) != (dynamics_learner is None):
        raise ValueError("reward_learner and dynamics_learner must both be MetricLearners or both be None")
    if reward_learner is not None:
        _check_learner(reward_learner, "reward_learner", reward_dim)
        _check_learner(dynamics_learner, "dynamics_learner", d - reward_dim)
    perm = perm.to(h.device)

    first_rew, first_dyn = split_halves(torch.cat([h, h[perm]]), reward_dim)
    second_rew, second_dyn = split_halves(torch.cat([h[perm], aug_h]), reward_dim)
    if reward_learner is not None:
        rew_dist = c * reward_learner(first_rew, second_rew)
        dyn_dist = (1 - c) * dynamics_learner(first_dyn, second_dyn)  # type: ignore[misc]
    else:
        rew_dist = c * F.smooth_l1_loss(first_rew, second_rew, reduction="none").mean(dim=1)
        dyn_dist = ((1 - c) * (first_dyn - second_dyn)).square().mean(dim=1)
    rew_target = (c * F.smooth_l1_loss(r, r[perm], reduction="none")).repeat(2)
    per_dimension = (1 - c) * _dimension_distances(mu.to(h), None if sigma is None else sigma.to(h), perm)
    if sigma is None:  # per dimension, against the pair's one learned distance
        dyn_error = dyn_dist.unsqueeze(1) - gamma * per_dimension.repeat(2, 1)
    else:
        dyn_error = dyn_dist - gamma * per_dimension.mean(dim=1).repeat(2)
    return 0.5 * (rew_dist - rew_target).square().mean() + 0.5 * dyn_error.square().mean()
