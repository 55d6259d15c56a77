"""The domain classifier and the feature probabilities from its saliency (sb3_sgfd.sgfd.weighting, .functional)."""

from __future__ import annotations

from functools import cache

import pytest
import torch
from torch import nn
from torch.nn import functional as F

from sb3_sgfd.sgfd.classifier import DomainClassifier, accuracy, saliency_probabilities
from sb3_sgfd.sgfd.functional import (
    classifier_accuracy,
    effective_sample_size,
    feature_probabilities,
    learn_sample_weights,
    saliency_map,
    weighted_pearson,
)
from sgfd_analysis.synthetic import DomainBatch, ScaledLogits, make_domain_batch

N_TRAIN = 4096


@cache
def trained_classifier(d: int, n_tied: int, seed: int) -> tuple[DomainClassifier, DomainBatch]:
    """A classifier trained on other samples of the batch's distribution, and a held-out batch of 128."""
    full = make_domain_batch(n=N_TRAIN + 128, d=d, n_tied=n_tied, seed=seed)
    torch.manual_seed(seed)
    classifier = DomainClassifier(d, 4)
    optimizer = torch.optim.Adam(classifier.parameters(), lr=1e-3)
    index_generator = torch.Generator().manual_seed(seed)
    for _ in range(200):
        index = torch.randint(0, N_TRAIN, (256,), generator=index_generator)
        loss = F.cross_entropy(classifier(full.z[index]), full.domains[index])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return classifier, full._replace(z=full.z[N_TRAIN:], domains=full.domains[N_TRAIN:])


def linear_classifier() -> nn.Linear:
    """Two domains, three features: logit_0 = z_0 - 2 z_1, logit_1 = 3 z_2."""
    layer = nn.Linear(3, 2, bias=False)
    with torch.no_grad():
        layer.weight.copy_(torch.tensor([[1.0, -2.0, 0.0], [0.0, 0.0, 3.0]]))
    return layer


# --- DomainClassifier ---


def test_classifier_architecture_and_output():
    classifier = DomainClassifier(50, 4)
    layers = list(classifier.net)
    assert [type(layer) for layer in layers] == [nn.Linear, nn.ReLU, nn.Linear, nn.ReLU, nn.Linear]
    assert [(layer.in_features, layer.out_features) for layer in layers[::2]] == [(50, 128), (128, 128), (128, 4)]
    assert classifier(torch.zeros(7, 50)).shape == (7, 4)
    assert DomainClassifier(10, 3, hidden_dim=16).net[0].out_features == 16


@pytest.mark.parametrize(
    ("args", "match"),
    [((0, 4), "n_features"), ((5, 1), "n_domains"), ((5, 4, 0), "hidden_dim"), ((5.0, 4), "n_features")],
)
def test_classifier_rejects_bad_sizes(args, match):
    with pytest.raises(ValueError, match=match):
        DomainClassifier(*args)


def test_classifier_rejects_wrong_feature_count():
    with pytest.raises(ValueError, match=r"z must have shape \(n, 5\)"):
        DomainClassifier(5, 2)(torch.zeros(3, 4))


# --- saliency_map and feature_probabilities ---


def test_saliency_is_the_gradient_of_the_chosen_logit():
    z = torch.tensor([[5.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])  # predicted domains 0, 1, 1
    classifier = linear_classifier()
    # mean over samples of |row of the weight matrix for the predicted (or given) domain|
    assert torch.allclose(saliency_map(classifier, z), torch.tensor([1 / 3, 2 / 3, 2.0]))
    assert torch.allclose(saliency_map(classifier, z, torch.tensor([1, 1, 1])), torch.tensor([0.0, 0.0, 3.0]))
    assert torch.allclose(saliency_map(classifier, z, torch.tensor([0, 0, 0])), torch.tensor([1.0, 2.0, 0.0]))


@pytest.mark.parametrize("given", [False, True])
def test_the_classifiers_closed_form_input_gradient_is_autograds(given):
    torch.manual_seed(0)
    classifier = DomainClassifier(6, 4, hidden_dim=16)
    z = torch.randn(32, 6)
    domains = torch.randint(0, 4, (32,)) if given else None
    target = classifier(z).argmax(dim=1) if domains is None else domains
    x = z.clone().requires_grad_(True)
    (expected,) = torch.autograd.grad(classifier(x).gather(1, target.unsqueeze(1)).sum(), x)
    closed = classifier.input_gradient(z, domains)
    torch.testing.assert_close(closed, expected)
    assert not closed.requires_grad and all(param.grad is None for param in classifier.parameters())
    # saliency_map takes that path for a DomainClassifier, and autograd for any other module
    wrapped = torch.nn.Sequential(classifier)
    torch.testing.assert_close(saliency_map(classifier, z, domains), saliency_map(wrapped, z, domains))


def test_paper_form_is_softmax_of_raw_saliency_and_default_is_scale_free():
    z = torch.tensor([[5.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    classifier = linear_classifier()
    saliency = torch.tensor([1 / 3, 2 / 3, 2.0])
    literal = feature_probabilities(classifier, z, temperature=1.0, normalize=False, smoothing=0.0)
    assert torch.allclose(literal, torch.softmax(saliency, dim=0))
    default = feature_probabilities(classifier, z)
    assert torch.allclose(default, 0.7 * torch.softmax(saliency / 2.0 / 0.1, dim=0) + 0.3 / 3)
    # Less confident logits flatten the paper's p but leave the normalised one unchanged.
    quiet = ScaledLogits(classifier, 0.1)
    assert torch.allclose(feature_probabilities(quiet, z), default)
    assert feature_probabilities(quiet, z, temperature=1.0, normalize=False, smoothing=0.0).max() < literal.max()


def test_smoothing_gives_every_partner_a_floor_and_keeps_the_order():
    classifier, batch = trained_classifier(d=20, n_tied=4, seed=1)
    sharp = feature_probabilities(classifier, batch.z, smoothing=0.0)
    smooth = feature_probabilities(classifier, batch.z, smoothing=0.3)
    assert torch.allclose(smooth, 0.7 * sharp + 0.3 / 20)
    assert smooth.min() >= 0.3 / 20 > sharp.min()
    assert torch.equal(smooth.argsort(), sharp.argsort()) and int(smooth.argmax()) == batch.top
    assert smooth.sum().item() == pytest.approx(1.0, abs=1e-6)


def test_lower_temperature_concentrates_probability():
    z = torch.randn(16, 3, generator=torch.Generator().manual_seed(0))
    classifier = linear_classifier()
    maxima = [feature_probabilities(classifier, z, temperature=t).max().item() for t in (1.0, 0.3, 0.1)]
    assert maxima[0] < maxima[1] < maxima[2]


def test_probabilities_leave_no_grad_anywhere_and_work_under_no_grad():
    classifier = DomainClassifier(6, 3)
    z = torch.randn(10, 6, generator=torch.Generator().manual_seed(0)).requires_grad_(True)
    with torch.no_grad():
        probs = feature_probabilities(classifier, z)
    assert probs.shape == (6,) and probs.sum().item() == pytest.approx(1.0, abs=1e-6)
    assert (probs >= 0).all() and not probs.requires_grad
    assert z.grad is None
    assert all(parameter.grad is None for parameter in classifier.parameters())


def test_the_only_domain_feature_gets_the_largest_probability():
    classifier, batch = trained_classifier(d=20, n_tied=0, seed=0)
    probs = feature_probabilities(classifier, batch.z)
    assert int(probs.argmax()) == batch.top
    literal = feature_probabilities(classifier, batch.z, temperature=1.0, normalize=False, smoothing=0.0)
    assert int(literal.argmax()) == batch.top


def test_domain_feature_ranks_first_among_correlated_features():
    classifier, batch = trained_classifier(d=50, n_tied=4, seed=2)
    assert classifier_accuracy(classifier, batch.z, batch.domains) > 0.9
    probs = feature_probabilities(classifier, batch.z)
    assert int(probs.argmax()) == batch.top
    assert int(feature_probabilities(classifier, batch.z, domains=batch.domains).argmax()) == batch.top


def test_saliency_guided_weights_beat_global_ones_end_to_end():
    # classifier -> p -> weights, as SGFD_SAC does, against uniform p (global decorrelation)
    guided, uniform = [], []
    for seed in range(3):
        classifier, batch = trained_classifier(d=50, n_tied=4, seed=seed)
        before = weighted_pearson(batch.z)[batch.top, batch.tied].abs().mean()
        probs = feature_probabilities(classifier, batch.z)
        for p, results in ((probs, guided), (None, uniform)):
            weights = learn_sample_weights(batch.z, p, generator=torch.Generator().manual_seed(seed))
            after = weighted_pearson(batch.z, weights)[batch.top, batch.tied].abs().mean()
            results.append((1 - after / before).item())
            assert effective_sample_size(weights) >= 64
    assert sum(guided) / 3 > 0.3
    assert sum(guided) / 3 > sum(uniform) / 3 + 0.15


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"temperature": 0.0}, ValueError, "temperature"),
        ({"temperature": float("inf")}, ValueError, "temperature"),
        ({"temperature": True}, ValueError, "temperature"),
        ({"smoothing": -0.1}, ValueError, "smoothing"),
        ({"smoothing": 1.5}, ValueError, "smoothing"),
        ({"z": torch.zeros(3)}, ValueError, "z must have shape"),
        ({"z": torch.full((2, 3), float("nan"))}, ValueError, "NaN or inf"),
        ({"z": torch.zeros(2, 3, dtype=torch.int64)}, TypeError, "floating-point"),
        ({"domains": torch.tensor([0, 1, 1])}, ValueError, r"domains must be a tensor of shape \(2,\)"),
        ({"domains": torch.tensor([0.0, 1.0])}, TypeError, "integer"),
        ({"domains": torch.tensor([0, 2])}, ValueError, r"labels in \[0, 2\)"),
    ],
)
def test_feature_probabilities_rejects_bad_input(kwargs, error, match):
    z = kwargs.pop("z", torch.zeros(2, 3))
    with pytest.raises(error, match=match):
        feature_probabilities(linear_classifier(), z, **kwargs)


# --- classifier_accuracy ---


def test_classifier_accuracy():
    z = torch.tensor([[5.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [1.0, 0.0, 0.0]])  # predicts 0, 1, 1, 0
    classifier = linear_classifier()
    assert classifier_accuracy(classifier, z, torch.tensor([0, 1, 1, 0])) == 1.0
    assert classifier_accuracy(classifier, z, torch.tensor([0, 1, 0, 1])) == 0.5
    with pytest.raises(ValueError, match="domains"):
        classifier_accuracy(classifier, z, torch.tensor([0, 1]))


def test_one_closed_form_pass_gives_the_probabilities_and_the_accuracy_of_two():
    # what the paper reading computes of the classifier at every step, from one pass
    classifier, batch = trained_classifier(d=10, n_tied=4, seed=0)
    # labels that are partly wrong, so that the accuracy is neither 0 nor 1
    domains = torch.where(torch.arange(128) % 3 == 0, (batch.domains + 1) % 4, batch.domains)
    predicted, gradient = classifier.predictions_and_input_gradient(batch.z)
    probs = saliency_probabilities(gradient.abs().mean(dim=0), temperature=0.2, normalize=True, smoothing=0.1)
    torch.testing.assert_close(probs, feature_probabilities(classifier, batch.z, temperature=0.2, smoothing=0.1))
    score = accuracy(predicted, domains)
    assert score == classifier_accuracy(classifier, batch.z, domains)
    assert 0.5 < score < 0.75
