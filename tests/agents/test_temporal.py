"""TED classifier and loss (sb3_sgfd.ted.losses) against direct computations, plus a small learning check."""

from __future__ import annotations

import math

import pytest
import torch

from sb3_sgfd.ted.losses import TEDClassifier, ted_loss, temporal_pairs


def hand_made_classifier() -> TEDClassifier:
    classifier = TEDClassifier(3).double()
    with torch.no_grad():
        classifier.w.copy_(torch.tensor([[0.5, -1.0, 2.0], [1.5, 0.25, -0.5]]))
        classifier.b.copy_(torch.tensor([[0.1, -0.2, 0.3]]))
        classifier.w_bar.copy_(torch.tensor([[0.7, 0.0, -0.4]]))
        classifier.b_bar.copy_(torch.tensor([[-0.3, 0.6, 0.2]]))
        classifier.c.fill_(-0.8)
    return classifier


def direct_logit(classifier: TEDClassifier, z1: list[float], z2: list[float]) -> float:
    """The classifier's formula written out one dimension at a time."""
    w, b, w_bar, b_bar = (p.detach().tolist() for p in (classifier.w, classifier.b, classifier.w_bar, classifier.b_bar))
    total = classifier.c.item()
    for d in range(len(z1)):
        total += abs(w[0][d] * z1[d] + w[1][d] * z2[d] + b[0][d]) - (w_bar[0][d] * z1[d] + b_bar[0][d]) ** 2
    return total


Z = [[1.0, -2.0, 0.5], [0.0, 3.0, -1.5]]
NEXT_Z = [[2.0, 1.0, -1.0], [-0.5, 0.25, 4.0]]
SAME_EPISODE_Z = [[-1.0, 0.0, 2.5], [1.25, -3.0, 0.75]]


def test_logit_matches_the_formula_per_dimension():
    classifier = hand_made_classifier()
    z1, z2 = torch.tensor(Z, dtype=torch.float64), torch.tensor(NEXT_Z, dtype=torch.float64)
    logits = classifier(z1, z2)
    assert logits.shape == (2,)
    expected = [direct_logit(classifier, Z[i], NEXT_Z[i]) for i in range(2)]
    torch.testing.assert_close(logits, torch.tensor(expected, dtype=torch.float64), rtol=0, atol=1e-12)


def test_loss_is_the_mean_cross_entropy_over_the_three_kinds_of_pairs():
    classifier = hand_made_classifier()
    tensors = [torch.tensor(rows, dtype=torch.float64) for rows in (Z, NEXT_Z, SAME_EPISODE_Z)]
    loss = ted_loss(classifier, *tensors, generator=torch.Generator().manual_seed(0))
    # With n = 2 the only shift is 1: sample i is paired with the next features of sample 1 - i.
    pairs = [(Z[i], NEXT_Z[i], 1.0) for i in range(2)]
    pairs += [(Z[i], NEXT_Z[1 - i], 0.0) for i in range(2)]
    pairs += [(Z[i], SAME_EPISODE_Z[i], 0.0) for i in range(2)]
    terms = []
    for z1, z2, label in pairs:
        p = 1 / (1 + math.exp(-direct_logit(classifier, z1, z2)))
        terms.append(-(label * math.log(p) + (1 - label) * math.log(1 - p)))
    assert loss.item() == pytest.approx(sum(terms) / len(terms), abs=1e-12)


@pytest.mark.parametrize("n", [2, 3, 7, 16])
def test_other_episode_pairs_never_use_the_sample_own_next_features(n: int):
    z = torch.arange(n, dtype=torch.float32)[:, None].repeat(1, 2)
    next_z = z + 100
    generator = torch.Generator().manual_seed(n)
    for _ in range(50):
        z1, z2, labels = temporal_pairs(z, next_z, -z, generator)
        assert labels.tolist() == [1.0] * n + [0.0] * (2 * n)
        torch.testing.assert_close(z1, torch.cat([z, z, z]))
        torch.testing.assert_close(z2[:n], next_z)
        torch.testing.assert_close(z2[2 * n :], -z)
        partners = (z2[n : 2 * n, 0] - 100).long()
        assert sorted(partners.tolist()) == list(range(n))
        assert (partners != torch.arange(n)).all()


def test_gradients_reach_the_online_features_and_the_classifier_only():
    generator = torch.Generator().manual_seed(1)
    z, next_z, same = (torch.randn(8, 4, generator=generator, requires_grad=True) for _ in range(3))
    classifier = TEDClassifier(4)
    ted_loss(classifier, z, next_z, same, generator=generator).backward()
    assert z.grad is not None and z.grad.abs().sum() > 0
    assert next_z.grad is None and same.grad is None
    for name, parameter in classifier.named_parameters():
        assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name


def test_a_given_generator_leaves_the_global_rng_untouched():
    z, classifier = torch.randn(6, 3), TEDClassifier(3)  # its initialisation draws from the global RNG
    torch.manual_seed(5)
    state = torch.get_rng_state()
    ted_loss(classifier, z, z + 1, z - 1, generator=torch.Generator().manual_seed(0))
    assert torch.equal(torch.get_rng_state(), state)


def test_initialisation_is_orthogonal():
    classifier = TEDClassifier(16)
    w = classifier.w.detach()
    torch.testing.assert_close(w @ w.T, torch.eye(2), rtol=0, atol=1e-5)
    for row in (classifier.b, classifier.w_bar, classifier.b_bar):
        assert row.detach().norm().item() == pytest.approx(1.0, abs=1e-5)
    assert abs(classifier.c.item()) == pytest.approx(1.0)


def test_classifier_alone_learns_a_per_dimension_temporal_relation():
    # next_z = f(z) + small noise with f a fixed random diagonal map: the classifier has one term per dimension,
    # so it can learn a relation dimension by dimension (mixing dimensions is the encoder's part of the job).
    dim, n = 32, 256
    generator = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    scales = (torch.rand(dim, generator=generator) + 0.5) * torch.randn(dim, generator=generator).sign()

    def batch(size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        z = torch.randn(size, dim, generator=generator)
        next_z = z * scales + 0.05 * torch.randn(size, dim, generator=generator)
        # Another time of the episode: unrelated to z, distributed like next_z.
        far = torch.randn(size, dim, generator=generator) * scales + 0.05 * torch.randn(size, dim, generator=generator)
        return z, next_z, far

    classifier = TEDClassifier(dim)
    optimizer = torch.optim.Adam(classifier.parameters(), lr=0.05)
    for _ in range(300):
        loss = ted_loss(classifier, *batch(n), generator=generator)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    with torch.no_grad():
        z1, z2, labels = temporal_pairs(*batch(1024), generator=generator)
        logits = classifier(z1, z2)
        held_out_loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels).item()
        accuracy = ((logits > 0).to(labels) == labels).float().mean().item()
    assert held_out_loss < 0.5 * math.log(2)
    assert accuracy > 0.9


@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda: TEDClassifier(0), ValueError, "features_dim must be a positive integer"),
        (lambda: TEDClassifier(True), ValueError, "features_dim must be a positive integer"),
        (lambda: TEDClassifier(3)(torch.zeros(2, 4), torch.zeros(2, 4)), ValueError, r"z1 must have shape \(n, 3\)"),
        (lambda: TEDClassifier(3)(torch.zeros(2, 3), torch.zeros(3, 3)), ValueError, r"z2 must have shape \(2, 3\)"),
        (lambda: temporal_pairs(torch.zeros(1, 3), torch.zeros(1, 3), torch.zeros(1, 3)), ValueError, "at least 2"),
        (lambda: temporal_pairs(torch.zeros(4), torch.zeros(4), torch.zeros(4)), ValueError, "z must have shape"),
        (
            lambda: temporal_pairs(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(3, 3)),
            ValueError,
            "same_episode_z must have shape",
        ),
        (lambda: temporal_pairs(torch.zeros(2, 3, dtype=torch.long), *[torch.zeros(2, 3)] * 2), TypeError, "floating"),
        (lambda: ted_loss(torch.nn.Linear(3, 1), *[torch.zeros(2, 3)] * 3), TypeError, "TEDClassifier"),
        (lambda: ted_loss(TEDClassifier(3), *[torch.zeros(2, 4)] * 3), ValueError, r"z must have shape \(n, 3\)"),
    ],
)
def test_invalid_inputs_are_rejected(call, error: type[Exception], message: str):
    with pytest.raises(error, match=message):
        call()
