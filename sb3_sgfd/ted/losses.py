"""Temporal disentanglement (TED) auxiliary loss (Dunion et al., ICLR 2023, section 4).

Pure torch, no Stable-Baselines3 import. Read top to bottom next to the paper:

1. ``TEDClassifier``: the paper's classifier chi(z_t, z~), a sum over feature dimensions k of
   |w_k1 z_t,k + w_k2 z~_k + b_k| - (w̄_k z_t,k + b̄_k)^2, plus c: one term per dimension, so the loss can only
   be lowered by features whose dimensions each carry their own temporal structure (the disentanglement).
2. ``temporal_pairs``: the three batches of pairs the classifier tells apart: temporal (o_t, o_t+1), label 1;
   non-temporal from other episodes (o_t, o_t' of another sample), label 0; non-temporal from the same episode
   (o_t, o_t'' with |t'' - t| >= 2), label 0. The first element is encoded by the online encoder, the second
   by the target encoder, whose gradient is stopped.
3. ``ted_loss``: binary cross-entropy of chi over all 3n pairs (its mean), the TED loss the encoder and the
   classifier minimise; the caller scales it by its coefficient and adds it to the critic loss.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from sb3_sgfd.common.validation import check_matrix, check_positive_int


class TEDClassifier(nn.Module):
    """Tells temporal pairs (z_t, z_t+1) from non-temporal ones, one independent term per feature dimension.

    logit(z1, z2) = sum_d [ |w[0]_d z1_d + w[1]_d z2_d + b_d| - (w_bar_d z1_d + b_bar_d)^2 ] + c

    All parameters start from orthogonal initialisation, as in the official code: ``w`` gets two orthonormal
    rows, each (1, D) row a random unit vector, and ``c`` is +1 or -1.

    :param features_dim: Dimension D of the features
    """

    def __init__(self, features_dim: int) -> None:
        check_positive_int(features_dim=features_dim)
        super().__init__()
        self.features_dim = features_dim
        # w[0] weighs z1 and w[1] weighs z2 inside the absolute value; w_bar and b_bar make the quadratic term of z1.
        self.w = nn.Parameter(torch.empty(2, features_dim))
        self.b = nn.Parameter(torch.empty(1, features_dim))
        self.w_bar = nn.Parameter(torch.empty(1, features_dim))
        self.b_bar = nn.Parameter(torch.empty(1, features_dim))
        self.c = nn.Parameter(torch.empty(1, 1))
        for parameter in self.parameters():
            nn.init.orthogonal_(parameter)

    def forward(self, z1: Tensor, z2: Tensor) -> Tensor:
        """Logit that (z1, z2) is a temporal pair.

        :param z1: features of the first observations, shape (n, D) (online encoder)
        :param z2: features of the second observations, shape (n, D) (target encoder)
        :return: logits, shape (n,)
        """
        check_matrix(z1, "z1", cols=self.features_dim)
        check_matrix(z2, "z2", rows=z1.shape[0], cols=self.features_dim)
        pair_term = (self.w[0] * z1 + self.w[1] * z2 + self.b).abs()
        own_term = (self.w_bar * z1 + self.b_bar).square()
        return (pair_term - own_term).sum(dim=1) + self.c[0, 0]


def temporal_pairs(
    z: Tensor, next_z: Tensor, same_episode_z: Tensor, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """The 3n pairs of a batch of n transitions and their labels (1: temporal, 0: not).

    Rows 0..n-1: (z_t, next_z) positives. Rows n..2n-1: (z_t, next_z[perm]) negatives from other samples, with
    perm = (arange(n) + s) % n for one shift s drawn uniformly in 1..n-1, so no sample is paired with its own
    next observation (the official code draws a plain permutation, which has fixed points: positives labelled 0).
    These are other transitions of the batch, almost always of other episodes. Rows 2n..3n-1: (z_t,
    same_episode_z) negatives. ``next_z`` and ``same_episode_z`` are detached: they are target features.

    :param z: online features of o_t, shape (n, D), n >= 2
    :param next_z: target features of o_t+1, shape (n, D)
    :param same_episode_z: target features of an observation of the same episode at least 2 steps from o_t, (n, D)
    :param generator: source of the shift; sampled on its device, so the global RNG is left untouched
    :return: z1 (3n, D), z2 (3n, D) and labels (3n,) in z's dtype
    """
    check_matrix(z, "z")
    n, d = z.shape
    if n < 2:
        raise ValueError(f"z must hold at least 2 samples, to pair each with another's next features; got {n}")
    check_matrix(next_z, "next_z", rows=n, cols=d)
    check_matrix(same_episode_z, "same_episode_z", rows=n, cols=d)
    # Sample where the generator lives (a CPU generator cannot fill a CUDA tensor), then move.
    device = generator.device if generator is not None else z.device
    shift = torch.randint(1, n, (1,), generator=generator, device=device).to(z.device)
    perm = (torch.arange(n, device=z.device) + shift) % n
    target = next_z.detach()
    z1 = torch.cat([z, z, z])
    z2 = torch.cat([target, target[perm], same_episode_z.detach()])
    labels = torch.cat(
        [torch.ones(n, dtype=z.dtype, device=z.device), torch.zeros(2 * n, dtype=z.dtype, device=z.device)]
    )
    return z1, z2, labels


def ted_loss(
    classifier: TEDClassifier,
    z: Tensor,
    next_z: Tensor,
    same_episode_z: Tensor,
    generator: torch.Generator | None = None,
) -> Tensor:
    """TED loss: mean binary cross-entropy of the classifier over the 3n pairs of ``temporal_pairs``.

    Not scaled: the caller multiplies it by its TED coefficient (so one loss value can be logged as is).

    :param classifier: the TED classifier
    :param z: online features of o_t, shape (n, D), n >= 2; gradients reach the encoder through it
    :param next_z: target features of o_t+1, shape (n, D); detached
    :param same_episode_z: target features of a same-episode observation at least 2 steps away, (n, D); detached
    :param generator: source of the other-episode pairing; None uses torch's global RNG
    :return: scalar loss
    """
    if not isinstance(classifier, TEDClassifier):
        raise TypeError(f"classifier must be a TEDClassifier, got {type(classifier).__name__}")
    check_matrix(z, "z", cols=classifier.features_dim)
    z1, z2, labels = temporal_pairs(z, next_z, same_episode_z, generator)
    return nn.functional.binary_cross_entropy_with_logits(classifier(z1, z2), labels)
