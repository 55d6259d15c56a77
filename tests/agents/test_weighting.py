"""SGFD's two readings (sb3_sgfd.sgfd.weighting: PaperWeighting, OfficialWeighting) and their switch on SGFD_SAC."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor, nn
from torch.nn import functional as F

import sgfd_envs
from sb3_sgfd import SGFD_SAC
from sb3_sgfd.sgfd.classifier import DomainClassifier
from sb3_sgfd.sgfd.decorrelation import (
    WeightMemory,
    official_fourier_features,
    official_loss,
    official_loss_and_gradient,
    solve_official_weights,
)
from sb3_sgfd.sgfd.functional import effective_sample_size, learn_sample_weights
from sb3_sgfd.sgfd.settings import SGFDSettings
from sb3_sgfd.sgfd.weighting import OfficialWeighting, PaperWeighting, WeightingPlan
from sgfd_analysis.synthetic import make_domain_batch
from tests.agents.test_reweighting import seeded, tied_correlation, top_probs

TINY = dict(learning_starts=100, batch_size=32, policy_kwargs=dict(net_arch=[32, 32]), seed=0)


def state_env():
    return sgfd_envs.make_domain_vec_env(
        "SGFD/MT-walker-walk-v0", split="train", obs_type="state", observe_parameter=True
    )


# --- the official reading's math, each against a direct computation ---


def test_official_rff_follow_the_codes_construction():
    x = torch.randn(6, 4, generator=seeded(0), dtype=torch.float64)
    u = official_fourier_features(x, 3, draws=2, generator=seeded(1))
    assert u.shape == (2, 6, 6, 4)  # (draws, 2 m channels, n, d)
    g = seeded(1)
    omega = torch.randn(2, 1, 1, 3, generator=g).double()
    psi = 2 * math.pi * torch.rand(2, 1, 4, 3, generator=g).double()
    for draw in range(2):
        for k in range(6):
            for f in range(3):
                s = x[k] * omega[draw, 0, 0, f] + psi[draw, 0, :, f]  # one omega per function, a phase per feature
                s = (s - s.min()) / (s.max() - s.min()) * math.pi / 2  # over the features of this sample
                torch.testing.assert_close(u[draw, f, k], math.sqrt(2 / 3) * torch.cos(s))
                torch.testing.assert_close(u[draw, 3 + f, k], math.sqrt(2 / 3) * torch.sin(s))


def test_official_loss_is_the_sum_over_channels_and_off_diagonal_pairs_and_its_gradient_is_exact():
    g = seeded(2)
    u = torch.randn(3, 20, 5, generator=g, dtype=torch.float64)
    probs = torch.softmax(torch.randn(5, generator=g, dtype=torch.float64), dim=0)
    pairs = torch.outer(probs, probs)
    pairs = pairs - torch.diag(pairs.diagonal())
    logits = torch.randn(20, generator=g, dtype=torch.float64, requires_grad=True)
    a = torch.softmax(logits, dim=0)
    expected = 0.0
    for c in range(3):
        # the code's weighted covariance: sum_k a_k u u^T - mu mu^T
        mu = a @ u[c]
        cov = (a[:, None] * u[c]).T @ u[c] - torch.outer(mu, mu)
        expected = expected + sum(pairs[i, j] * cov[i, j] ** 2 for i in range(5) for j in range(5) if i != j)
    loss, grad_a = official_loss_and_gradient(u, a.detach(), pairs)
    torch.testing.assert_close(loss, expected.detach())
    assert torch.equal(official_loss(u, a.detach(), pairs), loss)  # the logged losses' path: the same value
    (autograd_theta,) = torch.autograd.grad(expected, logits)
    a = a.detach()
    torch.testing.assert_close(a * (grad_a - a @ grad_a), autograd_theta)


def reference_official_solver(z: Tensor, probs: Tensor, seed: int, memory: tuple[Tensor, Tensor] | None) -> Tensor:
    """The code's solver with autograd and torch's SGD: L / L.detach() + 5 P / P.detach(), lr 1 then 0.1."""
    every_z = z if memory is None else torch.cat([z, memory[0]])
    channels = official_fourier_features(every_z, 5, draws=20, generator=seeded(seed))
    pairs = torch.outer(probs, probs)
    pairs = pairs - torch.diag(pairs.diagonal())
    theta = torch.ones(len(z), requires_grad=True)
    optimizer = torch.optim.SGD([theta], lr=1.0, momentum=0.9)
    for epoch in range(20):
        for group in optimizer.param_groups:
            group["lr"] = 1.0 if epoch < 10 else 0.1
        logits = theta if memory is None else torch.cat([theta, memory[1]])
        a = torch.softmax(logits, dim=0)
        loss = 0.0
        for c in range(channels.shape[1]):
            centred = channels[epoch, c] - a @ channels[epoch, c]
            loss = loss + (pairs * (centred.T @ (a[:, None] * centred)).square()).sum()
        concentration = torch.softmax(theta, dim=0).square().sum()
        objective = loss / loss.detach() + 5 * concentration / concentration.detach()
        optimizer.zero_grad()
        objective.backward()
        optimizer.step()
    return len(z) * torch.softmax(theta.detach(), dim=0)


def test_official_solver_is_the_codes_sgd_with_and_without_memory():
    batch, earlier = make_domain_batch(d=8, seed=3), make_domain_batch(d=8, seed=4)
    probs = top_probs(batch)
    weights, before, after = solve_official_weights(batch.z, probs, generator=seeded(5))
    torch.testing.assert_close(weights, reference_official_solver(batch.z, probs, 5, None), rtol=1e-4, atol=1e-5)
    assert after < before and not torch.allclose(weights, torch.ones(128), atol=1e-3)
    memory = WeightMemory(0.9)
    solve_official_weights(earlier.z, top_probs(earlier), memory=memory, generator=seeded(6))
    stored = (memory.features.clone(), memory.logits.clone())
    torch.testing.assert_close(stored[0], earlier.z)  # raw features: the code does not standardise
    remembered = solve_official_weights(batch.z, probs, memory=memory, update_memory=False, generator=seeded(5))[0]
    expected = reference_official_solver(batch.z, probs, 5, stored)
    torch.testing.assert_close(remembered, expected, rtol=1e-4, atol=1e-5)
    assert memory.updates == 1 and torch.equal(memory.features, stored[0])  # read, not updated


def test_official_reading_barely_reweights_and_the_paper_reading_keeps_its_figures():
    # The authors' code on these batches (given the same p): ESS 0.96-1.00 n, |r| cut by 1-4%.
    official_cuts, official_ess, paper_cuts = [], [], []
    for seed in range(6):
        memory = WeightMemory(0.9)
        for k in range(10):  # a memory as a run holds it: earlier batches of the same distribution
            earlier = make_domain_batch(d=10, seed=1000 + 100 * seed + k)
            solve_official_weights(earlier.z, top_probs(earlier), memory=memory, generator=seeded(k))
        batch = make_domain_batch(d=10, seed=seed)
        official = solve_official_weights(batch.z, top_probs(batch), memory=memory, generator=seeded(seed))[0]
        paper = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(seed))
        before = tied_correlation(batch)
        official_cuts.append(1 - tied_correlation(batch, official) / before)
        official_ess.append(effective_sample_size(official) / 128)
        paper_cuts.append(1 - tied_correlation(batch, paper) / before)
    assert sum(official_ess) / 6 >= 0.95 and min(official_ess) > 0.9
    assert 0 < sum(official_cuts) / 6 <= 0.10
    assert sum(paper_cuts) / 6 >= 0.35  # the paper reading's figure (test_reweighting's target)


class GuidedReLU(nn.Module):
    """ReLU whose backward passes only positive gradients where the input was positive (guided backprop)."""

    def forward(self, x: Tensor) -> Tensor:
        return GuidedReLUFunction.apply(x)


class GuidedReLUFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return x.clamp_min(0)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return grad.clamp_min(0) * (x > 0)


def test_guided_saliency_is_guided_backprop_of_the_probabilities_averaged_over_classes():
    torch.manual_seed(0)
    classifier = DomainClassifier(6, 3, hidden_dim=16, orthogonal=True)
    first, _, second, _, last = classifier.net
    guided = nn.Sequential(first, GuidedReLU(), second, GuidedReLU(), last)
    z = torch.randn(10, 6, requires_grad=True)
    expected = torch.zeros(10, 6)
    for target in range(3):
        (grad,) = torch.autograd.grad(torch.softmax(guided(z), dim=1)[:, target].sum(), z)
        expected += grad / 3
    torch.testing.assert_close(classifier.guided_saliency(z.detach()), expected)
    # orthogonal weights, zero biases at the start (the code's weight_init)
    assert all(layer.bias.abs().sum() == 0 for layer in (first, second, last))
    torch.testing.assert_close(first.weight.T @ first.weight, torch.eye(6), atol=1e-5, rtol=0)


# --- the switch on SGFD_SAC ---


def test_reading_sets_the_defaults_and_each_stays_overridable():
    official = SGFD_SAC("MlpPolicy", state_env(), reading="official", **TINY)
    assert official.sgfd == SGFDSettings.official(classifier_start=official.sgfd.classifier_start)
    assert official.sgfd.reweight_critic is False and official.sgfd.reweight_actor is True
    assert isinstance(official.weighting.classifier_optimizer, torch.optim.SGD)
    assert official.weighting.memory is not None and official.weighting.memory.momentum == 0.9
    overridden = SGFD_SAC("MlpPolicy", state_env(), reading="official", reweight_memory=False, reweight_lr=0.5, **TINY)
    assert overridden.weighting.memory is None and overridden.weighting.solver_settings["lr"] == 0.5
    paper = SGFD_SAC("MlpPolicy", state_env(), **TINY)
    assert isinstance(paper.weighting, PaperWeighting) and paper.sgfd.reweight_lr == 5.0 and paper.sgfd.reweight_critic
    with pytest.raises(ValueError, match="reading must be one of"):
        SGFD_SAC("MlpPolicy", state_env(), reading="offical", **TINY)


@pytest.mark.parametrize("reading", ["paper", "official"])
def test_the_classifiers_optimiser_steps_fused_and_stays_so_through_an_eager_step(reading):
    # its own optimiser, made fused where torch has the kernels (the CPU here): one kernel per step, the same Adam or
    # SGD; an eager step gives each optimiser back the way it was made, so it stays fused
    model = SGFD_SAC("MlpPolicy", state_env(), reading=reading, classifier_start=0, **dict(TINY, learning_starts=40))
    optimizer = model.weighting.classifier_optimizer
    assert optimizer.defaults["fused"] is True
    model.learn(48)
    assert all(group["fused"] is True for group in optimizer.param_groups)
    assert not any(group["foreach"] for group in optimizer.param_groups)


@pytest.mark.slow
def test_official_reading_weights_the_actor_from_the_first_update_and_trains_its_classifier_with_sgd(tmp_path):
    model = SGFD_SAC("MlpPolicy", state_env(), reading="official", classifier_start=300, classifier_interval=2, **TINY)
    start = [p.clone() for p in model.classifier.parameters()]
    samples = []
    sample = model.replay_buffer.sample
    model.replay_buffer.sample = lambda n, env=None: samples.append(n) or sample(n, env=env)
    ess = []
    record = model.record
    model.record = lambda key, value, **kwargs: (
        (ess.append(float(value)) if key == "sgfd/weight_ess" else None) or record(key, value, **kwargs)
    )
    model.learn(500)
    # weights at every actor update (every 2nd step), never on the critic
    assert len(ess) == math.ceil(model._n_updates / 2) > 0
    assert 0.9 < sum(ess) / len(ess) < 1.0
    # its classifier trained after classifier_start only, on fresh batches of 5 x 32 samples
    assert 5 * 32 in samples and all(n in (32, 160) for n in samples)
    assert any(not torch.equal(a, b) for a, b in zip(start, model.classifier.parameters(), strict=True))
    model.save(tmp_path / "official")
    loaded = SGFD_SAC.load(tmp_path / "official", env=state_env())
    assert loaded.sgfd.reading == "official" and loaded.weighting.memory.updates == model.weighting.memory.updates
    torch.testing.assert_close(loaded.weighting.memory.features, model.weighting.memory.features)
    assert loaded.weighting.classifier_optimizer.state_dict()["state"]


def test_a_classifier_round_of_the_official_reading_is_sgd_on_cross_entropy_of_its_softmax_output():
    # The code feeds the softmax probabilities to CrossEntropyLoss (a second softmax), with SGD 0.01 / 0.9 / 1e-4.
    settings = SGFDSettings.official(
        classifier_iters=1, classifier_interval=1, accuracy_threshold=1.0, classifier_start=0, classifier_hidden_dim=16
    )
    torch.manual_seed(1)
    weighting = OfficialWeighting(4, 2, settings, seed=0)
    reference = DomainClassifier(4, 2, hidden_dim=16, orthogonal=True)
    reference.load_state_dict(weighting.classifier.state_dict())
    fresh_z, fresh_labels = torch.randn(160, 4), torch.arange(160) % 2
    z, labels = torch.randn(32, 4), torch.arange(32) % 2
    weighting.train_round([(fresh_z, fresh_labels)])  # the round SGFD_SAC runs before the step, below the threshold
    weights, figures, _ = weighting(z, labels, WeightingPlan(classifier_round=True, weights_wanted=True))
    optimizer = torch.optim.SGD(reference.parameters(), lr=0.01, momentum=0.9, weight_decay=1e-4)
    F.cross_entropy(torch.softmax(reference(fresh_z), dim=1), fresh_labels).backward()
    optimizer.step()
    for got, expected in zip(weighting.classifier.parameters(), reference.parameters(), strict=True):
        torch.testing.assert_close(got, expected)
    assert weights.shape == (32,) and float(figures["classifier_accuracy"]) <= 1.0
