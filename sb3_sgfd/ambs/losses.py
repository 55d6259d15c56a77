"""AMBS's metric (Chen & Pan, ICLR 2022, "Learning Generalizable Representations for Reinforcement Learning
via Adaptive Meta-learner of Behavioral Similarities"), in the paper's form and in its authors' code's form.

Pure torch, no Stable-Baselines3 import. Read top to bottom next to the paper:

1. ``MetricLearner`` and ``split_halves``: AMBS's decomposition phi(s) = [phi_r(s), phi_d(s)] (reward and
   dynamics representations) and its meta-learners d_r, d_d, small networks measuring each half.
2. ``ambs_distance``: the learned behavioural distance c d_r + (1 - c) d_d between two representations.
3. ``ambs_metric_loss``: AMBS's objective, each meta-learner matched to its own term of the bisimulation
   metric, weighted by the balance c (the encoder's softmax ratio):
   (c d_r(phi_r(s_i), phi_r(s_j)) - c |r_i - r_j|)^2 + ((1 - c) d_d(phi_d(s_i), phi_d(s_j)) - (1 - c) gamma W2)^2,
   over the batch pairs and augmented pairs of the official code, each term halved as there; the official
   auxiliary loss is 0.5 * this + 0.01 * (transition NLL + reward MSE).
4. ``ambs_metric_loss_code``: what AMBS's code computes, which produced the published numbers: the reward target a
   Huber distance of the rewards, the dynamics target W2 per dimension averaged over the dimensions; without
   meta-learners (the SGFD code's committed setting) Huber and squared distances of the halves, and with a
   deterministic transition model a per-dimension Huber distance of the predicted means. AMBS's code also halves
   the transition NLL's residual (:func:`sb3_sgfd.common.dynamics.gaussian_nll`'s ``residual_scale=0.5``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sb3_sgfd.ambs.checks import check_metric_learner, check_reward_dim, check_reward_weight
from sb3_sgfd.common.dynamics import dimension_distances, dynamics_distance
from sb3_sgfd.common.validation import (
    check_gamma,
    check_matrix,
    check_perm,
    check_positive_int,
    check_rewards,
    check_same_shape,
)


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
        check_positive_int(half_dim=half_dim)
        check_positive_int(hidden_dim=hidden_dim)
        self.half_dim = half_dim
        self.net = nn.Sequential(nn.Linear(2 * half_dim, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, 1))

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        """Learned distance of each row of ``a`` to the same row of ``b``.

        :param a: first representations, shape (n, half_dim)
        :param b: second representations, shape (n, half_dim)
        :return: (n,) non-negative distances
        """
        check_matrix(a, "a", cols=self.half_dim)
        check_same_shape(b, "b", a, "a")
        return self.net(torch.cat([a, b], dim=1)).squeeze(1).square()


def split_halves(z: Tensor, reward_dim: int) -> tuple[Tensor, Tensor]:
    """AMBS's decomposition of a representation: the first ``reward_dim`` features phi_r, the rest phi_d.

    :param z: representations, shape (n, d)
    :param reward_dim: size of the reward part, in [1, d - 1] (AMBS: round(d / 2))
    :return: (reward part (n, reward_dim), dynamics part (n, d - reward_dim)), views of ``z``
    """
    check_matrix(z, "z")
    check_reward_dim(reward_dim, z.shape[1])
    return z[:, :reward_dim], z[:, reward_dim:]


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
    check_matrix(h_a, "h_a")
    check_same_shape(h_b, "h_b", h_a, "h_a")
    c = check_reward_weight(reward_weight)
    check_reward_dim(reward_dim, h_a.shape[1])
    check_metric_learner(reward_learner, "reward_learner", reward_dim)
    check_metric_learner(dynamics_learner, "dynamics_learner", h_a.shape[1] - reward_dim)
    a_rew, a_dyn = split_halves(h_a, reward_dim)
    b_rew, b_dyn = split_halves(h_b, reward_dim)
    return c * reward_learner(a_rew, b_rew) + (1 - c) * dynamics_learner(a_dyn, b_dyn)


def checked_metric_inputs(
    h: Tensor,
    aug_h: Tensor,
    rewards: Tensor,
    mu: Tensor,
    sigma: Tensor | None,
    perm: Tensor,
    reward_weight: float | Tensor,
    gamma: float,
    reward_dim: int,
) -> tuple[Tensor, float | Tensor]:
    """The metric losses' inputs checked, each refused in one line naming it (their parameters are theirs); returns
    the rewards as an (n,) tensor like ``h`` and the balance c."""
    check_matrix(h, "h")
    check_same_shape(aug_h, "aug_h", h, "h")
    n, d = h.shape
    r = check_rewards(rewards, n).to(h)
    check_reward_dim(reward_dim, d)
    check_matrix(mu, "mu", rows=n, cols=d - reward_dim)
    if sigma is not None:
        check_same_shape(sigma, "sigma", mu, "mu")
    check_perm(perm, n)
    check_gamma(gamma)
    return r, check_reward_weight(reward_weight)


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
    r, c = checked_metric_inputs(h, aug_h, rewards, mu, sigma, perm, reward_weight, gamma, reward_dim)
    d = h.shape[1]
    sigma = torch.zeros_like(mu) if sigma is None else sigma
    check_metric_learner(reward_learner, "reward_learner", reward_dim)
    check_metric_learner(dynamics_learner, "dynamics_learner", d - reward_dim)
    perm = perm.to(h.device)

    first = torch.cat([h, h[perm]])
    second = torch.cat([h[perm], aug_h])
    first_rew, first_dyn = split_halves(first, reward_dim)
    second_rew, second_dyn = split_halves(second, reward_dim)
    rew_dist = c * reward_learner(first_rew, second_rew)
    dyn_dist = (1 - c) * dynamics_learner(first_dyn, second_dyn)
    rew_target = (c * (r - r[perm]).abs()).repeat(2)
    dyn_target = ((1 - c) * gamma * dynamics_distance(mu.to(h), sigma.to(h), perm)).repeat(2)
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
    r, c = checked_metric_inputs(h, aug_h, rewards, mu, sigma, perm, reward_weight, gamma, reward_dim)
    d = h.shape[1]
    if (reward_learner is None) != (dynamics_learner is None):
        raise ValueError("reward_learner and dynamics_learner must both be MetricLearners or both be None")
    if reward_learner is not None:
        check_metric_learner(reward_learner, "reward_learner", reward_dim)
        check_metric_learner(dynamics_learner, "dynamics_learner", d - reward_dim)
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
    per_dimension = (1 - c) * dimension_distances(mu.to(h), None if sigma is None else sigma.to(h), perm)
    if sigma is None:  # per dimension, against the pair's one learned distance
        dyn_error = dyn_dist.unsqueeze(1) - gamma * per_dimension.repeat(2, 1)
    else:
        dyn_error = dyn_dist - gamma * per_dimension.mean(dim=1).repeat(2)
    return 0.5 * (rew_dist - rew_target).square().mean() + 0.5 * dyn_error.square().mean()
