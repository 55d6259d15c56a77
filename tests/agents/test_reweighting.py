"""Tests for sb3_sgfd.sgfd.decorrelation: RFF, the decorrelation loss, the weight solver and the check metrics."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor

from sb3_sgfd.sgfd.decorrelation import WeightMemory
from sb3_sgfd.sgfd.functional import (
    decorrelation_loss,
    effective_sample_size,
    learn_sample_weights,
    loss_gradient,
    random_fourier_features,
    weighted_pearson,
)
from sgfd_analysis.synthetic import DomainBatch, make_domain_batch


def seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def top_probs(batch: DomainBatch) -> Tensor:
    """p from a saliency map where only the domain feature is salient (max-normalised, temperature 0.1)."""
    saliency = torch.zeros(batch.z.shape[1])
    saliency[batch.top] = 1.0
    return torch.softmax(saliency / 0.1, dim=0)


def tied_correlation(batch: DomainBatch, weights: Tensor | None = None) -> float:
    return weighted_pearson(batch.z, weights)[batch.top, batch.tied].abs().mean().item()


def reference_loss(rff: Tensor, weights: Tensor, probs: Tensor, covariance: str) -> float:
    """The final SGFD loss with an explicit loop over feature pairs, straight from the paper's formulas."""
    n, d, _ = rff.shape
    u, w = rff.double(), weights.double()
    total = 0.0
    for i in range(d):
        for j in range(i + 1, d):
            if covariance == "weighted":
                mu_i, mu_j = (w @ u[:, i]) / w.sum(), (w @ u[:, j]) / w.sum()
                block = sum(w[k] * torch.outer(u[k, i] - mu_i, u[k, j] - mu_j) for k in range(n)) / w.sum()
            else:
                a, b = w[:, None] * u[:, i], w[:, None] * u[:, j]
                block = sum(torch.outer(a[k] - a.mean(0), b[k] - b.mean(0)) for k in range(n)) / (n - 1)
            total += probs[i].item() * probs[j].item() * block.square().sum().item()
    return total


# --- random_fourier_features ---


def test_rff_shape_range_and_reproducibility():
    z = torch.randn(16, 3, generator=seeded(0))
    rff = random_fourier_features(z, 7, generator=seeded(1))
    assert rff.shape == (16, 3, 7)
    assert rff.abs().max() <= math.sqrt(2) + 1e-6
    assert torch.equal(rff, random_fourier_features(z, 7, generator=seeded(1)))
    assert not torch.allclose(rff, random_fourier_features(z, 7, generator=seeded(2)))


def test_rff_approximates_the_gaussian_kernel():
    # With omega ~ N(0, 1) and psi ~ U(0, 2 pi), E[u(x) u(y)] = exp(-(x - y)^2 / 2): checks both draws and sqrt(2).
    for delta in (0.0, 0.5, 1.0, 2.0):
        z = torch.tensor([[0.0], [delta]]).expand(2, 4000).contiguous()
        rff = random_fourier_features(z, 5, generator=seeded(3))
        estimate = (rff[0] * rff[1]).mean().item()
        assert estimate == pytest.approx(math.exp(-(delta**2) / 2), abs=0.03)


def test_rff_leaves_global_rng_alone_when_given_a_generator():
    state = torch.get_rng_state()
    random_fourier_features(torch.randn(4, 2, generator=seeded(0)), generator=seeded(1))
    assert torch.equal(state, torch.get_rng_state())


@pytest.mark.parametrize(
    ("z", "n_features", "match"),
    [
        (torch.zeros(5), 5, "z must have shape"),
        (torch.zeros(1, 3), 5, "z must have shape"),
        (torch.zeros(4, 3, dtype=torch.long), 5, "floating-point"),
        (torch.tensor([[0.0, float("nan")], [1.0, 2.0]]), 5, "NaN or inf"),
        (torch.zeros(4, 3), 0, "n_features"),
        (torch.zeros(4, 3), 2.0, "n_features"),
    ],
)
def test_rff_rejects_bad_input(z, n_features, match):
    with pytest.raises((ValueError, TypeError), match=match):
        random_fourier_features(z, n_features)


# --- decorrelation_loss ---


@pytest.mark.parametrize("covariance", ["weighted", "literal"])
def test_loss_matches_explicit_pair_loop(covariance):
    rff = torch.randn(9, 4, 3, generator=seeded(0))
    weights = torch.rand(9, generator=seeded(1)) * 2
    probs = torch.softmax(torch.randn(4, generator=seeded(2)), dim=0)
    loss = decorrelation_loss(rff, weights, probs, covariance=covariance)
    assert loss.item() == pytest.approx(reference_loss(rff, weights, probs, covariance), rel=1e-4)


def test_uniform_weights_give_the_plain_cross_covariance():
    # At w = 1 both forms are eq. 3 up to the normaliser (1/n for "weighted", 1/(n-1) for "literal").
    rff = torch.randn(12, 5, 2, generator=seeded(0))
    ones = torch.ones(12)
    weighted = decorrelation_loss(rff, ones).item()
    literal = decorrelation_loss(rff, ones, covariance="literal").item()
    assert weighted == pytest.approx(literal * (11 / 12) ** 2, rel=1e-5)


def test_loss_defaults_to_uniform_probs_and_ignores_pairs_with_zero_probability():
    rff = torch.randn(10, 6, 2, generator=seeded(0))
    weights = torch.rand(10, generator=seeded(1))
    uniform = torch.full((6,), 1 / 6)
    assert decorrelation_loss(rff, weights).item() == pytest.approx(decorrelation_loss(rff, weights, uniform).item())
    one_hot = torch.zeros(6)
    one_hot[2] = 1.0
    assert decorrelation_loss(rff, weights, one_hot).item() == 0.0


def test_weighted_loss_is_invariant_to_weight_scale_and_sample_order():
    rff = torch.randn(10, 4, 3, generator=seeded(0))
    weights = torch.rand(10, generator=seeded(1))
    perm = torch.randperm(10, generator=seeded(2))
    base = decorrelation_loss(rff, weights).item()
    assert decorrelation_loss(rff, 3 * weights).item() == pytest.approx(base, rel=1e-5)
    assert decorrelation_loss(rff[perm], weights[perm]).item() == pytest.approx(base, rel=1e-5)


def test_loss_is_differentiable_in_the_weights():
    rff = torch.randn(10, 4, 3, generator=seeded(0))
    weights = torch.ones(10, requires_grad=True)
    decorrelation_loss(rff, weights).backward()
    assert weights.grad is not None and torch.isfinite(weights.grad).all() and weights.grad.abs().sum() > 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rff": torch.zeros(4, 3)}, "rff must be"),
        ({"rff": torch.full((4, 3, 2), float("inf"))}, "rff contains"),
        ({"weights": torch.ones(5)}, r"weights must be a tensor of shape \(4,\)"),
        ({"weights": -torch.ones(4)}, "non-negative"),
        ({"weights": torch.tensor([1.0, float("nan"), 1.0, 1.0])}, "weights contains"),
        ({"feature_probs": torch.full((3,), 0.5)}, "sum to 1"),
        ({"feature_probs": torch.full((2,), 0.5)}, r"feature_probs must be a tensor of shape \(3,\)"),
        ({"feature_probs": torch.tensor([1.5, -0.5, 0.0])}, "non-negative"),
        ({"covariance": "pearson"}, "covariance must be one of"),
    ],
)
def test_loss_rejects_bad_input(kwargs, match):
    args = {"rff": torch.randn(4, 3, 2, generator=seeded(0)), "weights": torch.ones(4), "feature_probs": None}
    covariance = kwargs.pop("covariance", "weighted")
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        decorrelation_loss(args["rff"], args["weights"], args["feature_probs"], covariance=covariance)


# --- learn_sample_weights ---


def test_weights_are_normalised_non_negative_and_detached():
    batch = make_domain_batch(d=10, seed=0)
    z = batch.z.clone().requires_grad_(True)
    weights = learn_sample_weights(z, top_probs(batch), generator=seeded(0))
    assert weights.shape == (128,) and weights.dtype == torch.float32
    assert (weights >= 0).all()
    assert weights.sum().item() == pytest.approx(128, rel=1e-5)
    assert not weights.requires_grad and z.grad is None
    assert not torch.allclose(weights, torch.ones(128))


def test_weights_lower_the_loss_and_report_it_on_the_same_draw():
    for seed in range(3):
        batch = make_domain_batch(d=20, seed=seed)
        weights, before, after = learn_sample_weights(
            batch.z, top_probs(batch), generator=seeded(seed), return_losses=True
        )
        assert 0 < after < before
        # the reported losses come from the same RFF draw (and the same defaults) as the weights
        z = 0.5 * (batch.z - batch.z.mean(0)) / batch.z.std(0)
        rff = random_fourier_features(z, 5, generator=seeded(seed))
        assert decorrelation_loss(rff, torch.ones(128), top_probs(batch)).item() == pytest.approx(before, rel=1e-4)
        assert decorrelation_loss(rff, weights, top_probs(batch)).item() == pytest.approx(after, rel=1e-4)


@pytest.mark.parametrize("d", [10, 50])
def test_default_weights_meet_the_decorrelation_targets(d):
    # Targets of issue 3 for the defaults (10 iterations, batch 128), averaged over 10 seeded batches.
    guided, uniform = [], []
    for seed in range(10):
        batch = make_domain_batch(d=d, seed=seed)
        before = tied_correlation(batch)
        weights = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(seed))
        global_weights = learn_sample_weights(batch.z, None, generator=seeded(seed))
        assert effective_sample_size(weights) >= 0.5 * 128
        guided.append(1 - tied_correlation(batch, weights) / before)
        uniform.append(1 - tied_correlation(batch, global_weights) / before)
    assert sum(guided) / 10 >= 0.35
    assert sum(guided) > sum(uniform)


def test_weighted_covariance_decorrelates_far_more_than_the_literal_form():
    batch = make_domain_batch(d=20, seed=1)
    before = tied_correlation(batch)
    weighted = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(0))
    # 0.1 is the literal form's largest stable lr; it diverges at the default
    literal = learn_sample_weights(batch.z, top_probs(batch), covariance="literal", lr=0.1, generator=seeded(0))
    assert 1 - tied_correlation(batch, weighted) / before > 0.3
    assert 1 - tied_correlation(batch, literal) / before < 0.1


def test_ess_penalty_keeps_more_samples():
    batch = make_domain_batch(d=20, seed=2)
    with_penalty = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(0))
    without = learn_sample_weights(batch.z, top_probs(batch), ess_penalty=0.0, generator=seeded(0))
    assert effective_sample_size(with_penalty) > effective_sample_size(without) + 10


def test_weights_do_not_depend_on_feature_scale():
    batch = make_domain_batch(d=10, seed=3)
    small = learn_sample_weights(batch.z, generator=seeded(0))
    large = learn_sample_weights(100 * batch.z + 7, generator=seeded(0))
    assert torch.allclose(small, large, atol=1e-3)


def test_no_rff_ablation_and_float64_input():
    batch = make_domain_batch(d=10, seed=4)
    weights, before, after = learn_sample_weights(
        batch.z.double(), top_probs(batch).double(), use_rff=False, return_losses=True
    )
    assert weights.dtype == torch.float64 and after < before


def test_solver_is_reproducible_and_leaves_global_rng_alone():
    batch = make_domain_batch(d=10, seed=5)
    state = torch.get_rng_state()
    first = learn_sample_weights(batch.z, generator=seeded(9))
    assert torch.equal(state, torch.get_rng_state())
    assert torch.equal(first, learn_sample_weights(batch.z, generator=seeded(9)))


def test_solver_runs_inside_no_grad():
    batch = make_domain_batch(d=10, seed=6)
    with torch.no_grad():
        weights = learn_sample_weights(batch.z, generator=seeded(0))
    assert effective_sample_size(weights) < 127  # the weights moved


def test_nothing_to_decorrelate_gives_uniform_weights():
    z = torch.randn(32, 1, generator=seeded(0))
    assert torch.equal(learn_sample_weights(z, generator=seeded(0)), torch.ones(32))
    constant = torch.ones(32, 4)
    assert torch.equal(learn_sample_weights(constant, generator=seeded(0)), torch.ones(32))
    batch = make_domain_batch(d=10, seed=0)
    assert torch.equal(learn_sample_weights(batch.z, iters=0), torch.ones(128))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"z": torch.zeros(8)}, "z must have shape"),
        ({"z": torch.zeros(1, 4)}, "z must have shape"),
        ({"z": torch.tensor([[0.0, float("inf")], [1.0, 2.0]])}, "NaN or inf"),
        ({"feature_probs": torch.ones(4)}, "feature_probs"),
        ({"n_rff": 0}, "n_rff"),
        ({"iters": -1}, "iters"),
        ({"iters": 2.5}, "iters"),
        ({"lr": float("nan")}, "lr"),
        ({"momentum": -0.1}, "momentum"),
        ({"ess_penalty": -1.0}, "ess_penalty"),
        ({"feature_std": 0.0}, "feature_std"),
        ({"covariance": "cov"}, "covariance"),
        ({"max_step": 0.0}, "max_step"),
        ({"max_step": float("inf")}, "max_step"),
        ({"max_step": True}, "max_step"),
    ],
)
def test_solver_rejects_bad_input(kwargs, match):
    z = kwargs.pop("z", torch.randn(8, 4, generator=seeded(0)))
    with pytest.raises(ValueError, match=match):
        learn_sample_weights(z, **kwargs)


def test_max_step_bounds_how_far_each_step_moves_the_logits():
    batch = make_domain_batch(d=10, seed=0)

    def largest_logit_step(**kwargs) -> float:
        weights = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(0), iters=1, lr=50.0, **kwargs)
        return (weights.log() - weights.log().mean()).abs().max().item()

    # One step from uniform weights, whose logits' changes sum to 0: log w - mean(log w) is that step.
    assert largest_logit_step() > 1.0
    assert largest_logit_step(max_step=0.25) == pytest.approx(0.25, abs=1e-4)
    # A trust region the steps never reach leaves the default solver's weights as they are.
    unbounded = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(0))
    bounded = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(0), max_step=1e6)
    torch.testing.assert_close(bounded, unbounded)


# --- the closed-form gradient, and the solver against an autograd reference ---


def softmax_projection(gradient: Tensor, a: Tensor) -> Tensor:
    """What the solver uses of a gradient in a: a * (g - a . g), blind to terms equal for every sample."""
    return a * (gradient - a @ gradient)


@pytest.mark.parametrize("covariance", ["weighted", "literal"])
def test_closed_form_gradient_matches_autograd(covariance):
    rff = torch.randn(12, 4, 3, generator=seeded(0), dtype=torch.float64)
    probs = torch.softmax(torch.randn(4, generator=seeded(1), dtype=torch.float64), dim=0)
    a = torch.softmax(torch.randn(12, generator=seeded(2), dtype=torch.float64), dim=0).requires_grad_(True)
    # decorrelation_loss takes weights w = n a
    decorrelation_loss(rff, 12 * a, probs, covariance=covariance).backward()
    closed = loss_gradient(rff, a.detach(), probs, covariance=covariance)
    torch.testing.assert_close(softmax_projection(closed, a.detach()), softmax_projection(a.grad, a.detach()))
    # and it is not blind: a different distribution gives a different projected gradient
    other = loss_gradient(rff, torch.full((12,), 1 / 12, dtype=torch.float64), probs, covariance=covariance)
    assert not torch.allclose(softmax_projection(other, a.detach()), softmax_projection(closed, a.detach()))


def reference_solver(z: Tensor, probs: Tensor | None, seed: int, memory: tuple[Tensor, Tensor] | None = None, **kw):
    """The solver written with autograd and torch's SGD: standardise, RFF, then SGD on the logits of
    loss / loss(start) + ess_penalty * (n sum(a^2) - 1) over the batch and the memory's rows."""
    n, d = z.shape
    lr, iters, penalty = kw.get("lr", 5.0), kw.get("iters", 10), kw.get("ess_penalty", 0.35)
    zs = 0.5 * (z - z.mean(0)) / z.std(0)
    memory_z, memory_logits = memory if memory is not None else (z[:0], z.new_zeros(0))
    rff = random_fourier_features(torch.cat([zs, memory_z]), 5, generator=seeded(seed))
    probs = torch.full((d,), 1 / d) if probs is None else probs
    theta = torch.zeros(n, requires_grad=True)
    optimizer = torch.optim.SGD([theta], lr=lr, momentum=0.9, weight_decay=1e-4)
    n_all = len(rff)

    def loss(t: Tensor) -> Tensor:
        return decorrelation_loss(rff, n_all * torch.softmax(torch.cat([t, memory_logits]), dim=0), probs)

    start = loss(theta).detach()
    for _ in range(iters):
        own = torch.softmax(theta, dim=0)
        objective = loss(theta) / start + penalty * (n * own.square().sum() - 1)
        optimizer.zero_grad()
        objective.backward()
        optimizer.step()
    return n * torch.softmax(theta.detach(), dim=0)


@pytest.mark.parametrize("kwargs", [{}, {"lr": 1.0, "iters": 20}, {"ess_penalty": 0.0}])
def test_solver_takes_the_steps_of_autograd_and_torch_sgd(kwargs):
    batch = make_domain_batch(d=8, seed=7)
    weights = learn_sample_weights(batch.z, top_probs(batch), generator=seeded(3), **kwargs)
    expected = reference_solver(batch.z, top_probs(batch), seed=3, **kwargs)
    torch.testing.assert_close(weights, expected, rtol=1e-4, atol=1e-4)
    assert not torch.allclose(weights, torch.ones(128), atol=1e-2)


def test_memory_joins_the_loss_with_fixed_logits_and_then_moves_towards_the_batch():
    first, second = make_domain_batch(d=8, seed=1), make_domain_batch(d=8, seed=2)
    memory = WeightMemory(momentum=0.9)
    learn_sample_weights(first.z, top_probs(first), generator=seeded(0), memory=memory)
    assert memory.updates == 1
    stored_z, stored_logits = memory.features.clone(), memory.logits.clone()
    torch.testing.assert_close(stored_z, 0.5 * (first.z - first.z.mean(0)) / first.z.std(0))
    # the second solve decorrelates against the first batch's features under their logits
    weights = learn_sample_weights(second.z, top_probs(second), generator=seeded(1), memory=memory)
    expected = reference_solver(second.z, top_probs(second), seed=1, memory=(stored_z, stored_logits))
    torch.testing.assert_close(weights, expected, rtol=1e-4, atol=1e-4)
    without = learn_sample_weights(second.z, top_probs(second), generator=seeded(1))
    assert not torch.allclose(weights, without, atol=1e-3)
    # a running mean for the first updates (here: the mean of the two batches), then momentum 0.9
    second_z = 0.5 * (second.z - second.z.mean(0)) / second.z.std(0)
    torch.testing.assert_close(memory.features, (stored_z + second_z) / 2)
    for seed in range(3, 15):
        learn_sample_weights(second.z, top_probs(second), generator=seeded(seed), memory=memory)
    before = memory.features.clone()
    learn_sample_weights(first.z, top_probs(first), generator=seeded(99), memory=memory)
    first_z = 0.5 * (first.z - first.z.mean(0)) / first.z.std(0)
    torch.testing.assert_close(memory.features, 0.9 * before + 0.1 * first_z)
    # a batch of another size starts the memory afresh; the state round-trips
    learn_sample_weights(first.z[:64], generator=seeded(0), memory=memory)
    assert memory.updates == 1 and memory.features.shape == (64, 8)
    copy = WeightMemory()
    copy.load_state_dict(memory.state_dict())
    assert copy.updates == 1 and torch.equal(copy.logits, memory.logits)
    with pytest.raises(ValueError, match="memory momentum must be a number in"):
        WeightMemory(1.0)


# --- effective_sample_size and weighted_pearson ---


def test_effective_sample_size():
    assert effective_sample_size(torch.ones(50)) == pytest.approx(50)
    assert effective_sample_size(torch.tensor([0.0, 0.0, 5.0])) == pytest.approx(1)
    weights = torch.rand(20, generator=seeded(0))
    assert effective_sample_size(weights) == pytest.approx(effective_sample_size(7 * weights))
    assert 1 < effective_sample_size(weights) < 20
    with pytest.raises(ValueError, match="weights"):
        effective_sample_size(torch.zeros(3))
    with pytest.raises(ValueError, match="weights"):
        effective_sample_size(torch.ones(2, 2))


def test_weighted_pearson_matches_corrcoef_and_repeated_rows():
    x = torch.randn(30, 4, generator=seeded(0), dtype=torch.float64)
    assert torch.allclose(weighted_pearson(x), torch.corrcoef(x.T))
    counts = torch.randint(0, 4, (30,), generator=seeded(1))
    repeated = x.repeat_interleave(counts, dim=0)
    assert torch.allclose(weighted_pearson(x, counts.double()), torch.corrcoef(repeated.T))


def test_weighted_pearson_on_a_constant_column():
    x = torch.randn(20, 3, generator=seeded(0))
    x[:, 1] = 2.0
    corr = weighted_pearson(x)
    assert torch.equal(corr[1], torch.tensor([0.0, 1.0, 0.0]))
    assert torch.isfinite(corr).all()
    with pytest.raises(ValueError, match="weights"):
        weighted_pearson(x, torch.ones(19))
