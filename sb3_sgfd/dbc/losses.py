"""DBC's encoder objective (Zhang et al., ICLR 2021, "Learning Invariant Representations for Reinforcement
Learning without Reconstruction"), in the paper's form and in its authors' code's form.

Pure torch, no Stable-Baselines3 import. ``bisimulation_loss`` is the paper's
J(phi) = (||z_i - z_j||_1 - |r_i - r_j| - gamma W2(P^(. | z_i, a_i), P^(. | z_j, a_j)))^2,
the on-policy bisimulation metric d(s_i, s_j) = |r_i - r_j| + gamma W2(...) made the L1 distance of the
encodings, over pairs (i, perm(i)) of one batch. ``bisimulation_loss_code`` is what deep_bisim4control computes,
which produced the published numbers: per-dimension Huber (smooth L1) distances of z and r and a per-dimension
W2, the squared error averaged over every element (the scale its ``bisim_coef`` 0.5 was set for). The latent
dynamics both use are in :mod:`sb3_sgfd.common.dynamics`.
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor

from sb3_sgfd.common.dynamics import dimension_distances, dynamics_distance
from sb3_sgfd.common.validation import check_gamma, check_matrix, check_perm, check_rewards, check_same_shape


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
    check_matrix(z, "z")
    n = z.shape[0]
    r = check_rewards(rewards, n).to(z)
    check_matrix(mu, "mu", rows=n)
    check_same_shape(sigma, "sigma", mu, "mu")
    check_perm(perm, n)
    check_gamma(gamma)
    perm = perm.to(z.device)
    z_dist = (z - z[perm]).abs().sum(dim=1)
    target = (r - r[perm]).abs() + gamma * dynamics_distance(mu.to(z), sigma.to(z), perm)
    return (z_dist - target).square().mean()


def bisimulation_loss_code(
    z: Tensor, rewards: Tensor, mu: Tensor, sigma: Tensor | None, perm: Tensor, gamma: float
) -> Tensor:
    """DBC's encoder loss as its authors' code computes it: the mean over the pairs (i, j = perm(i)) and the
    dimensions k of (H(z_ik - z_jk) - H(r_i - r_j) - gamma W2_ijk)^2, H the Huber function (smooth L1, delta 1)
    and W2_ijk that of dimension k (``dimension_distances``). The paper's form is ``bisimulation_loss``.

    :param z: encodings of a batch, shape (n, d), with grad
    :param rewards: rewards of the batch, shape (n,) or (n, 1)
    :param mu: predicted next-latent means, shape (n, d) (the transition model predicts the whole latent)
    :param sigma: their standard deviations, shape (n, d); None: a deterministic model
    :param perm: sample i is paired with perm[i] (a permutation of range(n))
    :param gamma: discount of the bisimulation metric, in [0, 1)
    :return: scalar loss
    """
    check_matrix(z, "z")
    n = z.shape[0]
    r = check_rewards(rewards, n).to(z)
    check_same_shape(mu, "mu", z, "z")
    if sigma is not None:
        check_same_shape(sigma, "sigma", mu, "mu")
    check_perm(perm, n)
    check_gamma(gamma)
    perm = perm.to(z.device)
    z_dist = F.smooth_l1_loss(z, z[perm], reduction="none")
    r_dist = F.smooth_l1_loss(r, r[perm], reduction="none").unsqueeze(1)
    target = r_dist + gamma * dimension_distances(mu.to(z), None if sigma is None else sigma.to(z), perm)
    return (z_dist - target).square().mean()
