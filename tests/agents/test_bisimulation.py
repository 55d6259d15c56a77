"""The DBC and AMBS losses, their latent dynamics (sb3_sgfd.common.dynamics) and a small learning check."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch
from torch import Tensor, nn

from sb3_sgfd.ambs.losses import MetricLearner, ambs_distance, ambs_metric_loss, ambs_metric_loss_code, split_halves
from sb3_sgfd.common.dynamics import (
    DeterministicTransitionModel,
    ProbabilisticTransitionModel,
    RewardDecoder,
    gaussian_nll,
    wasserstein2,
)
from sb3_sgfd.dbc.losses import bisimulation_loss, bisimulation_loss_code


def seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def seeded_learner(half_dim: int, seed: int) -> MetricLearner:
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return MetricLearner(half_dim, hidden_dim=5).double()


# A hand-made batch of 4: encodings, rewards, transition predictions and a pairing with no fixed point.
Z = [[0.5, -1.0, 2.0, 0.0], [1.5, 0.25, -0.5, 1.0], [-2.0, 0.0, 1.0, -1.0], [0.0, 3.0, -1.0, 0.5]]
AUG_Z = [[0.25, -1.0, 1.5, 0.5], [1.0, 0.0, -0.5, 1.5], [-1.5, 0.5, 1.0, -0.5], [0.5, 2.5, -1.0, 0.0]]
REWARDS = [1.0, -0.5, 0.25, 2.0]
MU = [[0.1, 0.2], [-0.3, 0.4], [1.0, -1.0], [0.0, 0.5]]
SIGMA = [[0.5, 1.0], [0.25, 2.0], [1.0, 1.0], [3.0, 0.1]]
PERM = [2, 0, 3, 1]


def w2_by_hand(i: int, j: int) -> float:
    """W2 from the general Gaussian formula ||mu1 - mu2||^2 + tr(S1 + S2 - 2 (S1 S2)^(1/2)), diagonal S."""
    squared = sum((a - b) ** 2 for a, b in zip(MU[i], MU[j], strict=True))
    squared += sum(s**2 + t**2 - 2 * math.sqrt(s**2 * t**2) for s, t in zip(SIGMA[i], SIGMA[j], strict=True))
    return math.sqrt(squared)


def t64(values: list) -> Tensor:
    return torch.tensor(values, dtype=torch.float64)


# --- models ---


def test_transition_model_shapes_and_sigma_bounds():
    with torch.random.fork_rng():
        torch.manual_seed(0)
        model = ProbabilisticTransitionModel(3, 2, hidden_dim=16, min_sigma=0.1, max_sigma=2.0)
    z, action = torch.randn(5, 3, generator=seeded(1)), torch.randn(5, 2, generator=seeded(2))
    mu, sigma = model(z, action)
    assert mu.shape == sigma.shape == (5, 3)
    assert (sigma >= 0.1).all() and (sigma <= 2.0).all()
    # The layer norm undoes any input scale; a huge bias on the sigma head saturates its sigmoid instead.
    with torch.no_grad():
        for bias, bound in ((-1e3, 0.1), (1e3, 2.0)):
            model.sigma.bias.fill_(bias)
            assert torch.allclose(model(z, action)[1], torch.full((5, 3), bound))


def test_transition_sample_uses_only_its_generator():
    with torch.random.fork_rng():
        torch.manual_seed(0)
        model = ProbabilisticTransitionModel(3, 2, hidden_dim=16)
    z, action = torch.randn(4, 3, generator=seeded(1)), torch.randn(4, 2, generator=seeded(2))
    state = torch.get_rng_state()
    sample = model.sample(z, action, generator=seeded(7))
    assert torch.equal(state, torch.get_rng_state())
    mu, sigma = model(z, action)
    assert torch.allclose(sample, mu + sigma * torch.randn(4, 3, generator=seeded(7)))
    assert torch.equal(sample, model.sample(z, action, generator=seeded(7)))
    assert not torch.equal(sample, model.sample(z, action, generator=seeded(8)))


def test_reward_decoder_shape():
    decoder = RewardDecoder(3, hidden_dim=8)
    assert decoder(torch.zeros(6, 3)).shape == (6, 1)


def test_model_argument_checks():
    with pytest.raises(ValueError, match="features_dim"):
        ProbabilisticTransitionModel(0, 2)
    with pytest.raises(ValueError, match="min_sigma"):
        ProbabilisticTransitionModel(3, 2, min_sigma=0.0)
    with pytest.raises(ValueError, match="max_sigma"):
        ProbabilisticTransitionModel(3, 2, min_sigma=1.0, max_sigma=0.5)
    with pytest.raises(ValueError, match="action"):
        ProbabilisticTransitionModel(3, 2, hidden_dim=4)(torch.zeros(2, 3), torch.zeros(2, 3))
    with pytest.raises(ValueError, match="hidden_dim"):
        RewardDecoder(3, hidden_dim=0)


# --- gaussian_nll and wasserstein2 ---


def test_gaussian_nll_is_the_normal_log_likelihood():
    g = seeded(0)
    mu, target = torch.randn(6, 3, generator=g, dtype=torch.float64), torch.randn(6, 3, generator=g).double()
    sigma = 0.1 + torch.rand(6, 3, generator=g, dtype=torch.float64)
    log_prob = torch.distributions.Normal(mu, sigma).log_prob(target)
    expected = -log_prob.mean() - 0.5 * math.log(2 * math.pi)
    assert torch.allclose(gaussian_nll(mu, sigma, target), expected)


def test_gaussian_nll_with_ambs_codes_halved_residual_and_for_a_deterministic_model():
    g = seeded(1)
    mu, target = torch.randn(6, 3, generator=g, dtype=torch.float64), torch.randn(6, 3, generator=g).double()
    sigma = 0.1 + torch.rand(6, 3, generator=g, dtype=torch.float64)
    # AMBS's code: mean(0.5 ((0.5 mu - 0.5 target) / sigma)^2 + log sigma)
    expected = (0.5 * ((0.5 * mu - 0.5 * target) / sigma) ** 2 + sigma.log()).mean()
    assert torch.allclose(gaussian_nll(mu, sigma, target, residual_scale=0.5), expected)
    # a deterministic model: sigma 1
    assert torch.allclose(gaussian_nll(mu, None, target, 0.5), (0.5 * (0.5 * mu - 0.5 * target) ** 2).mean())
    model = DeterministicTransitionModel(3, 2, hidden_dim=8)
    prediction, spread = model(mu.float(), torch.zeros(6, 2))
    assert prediction.shape == (6, 3) and spread is None
    assert torch.equal(model.sample(mu.float(), torch.zeros(6, 2)), prediction)


def test_wasserstein2_by_hand():
    distances = wasserstein2(t64(MU), t64(SIGMA), t64(MU)[PERM], t64(SIGMA)[PERM])
    expected = [w2_by_hand(i, PERM[i]) for i in range(4)]
    assert torch.allclose(distances, t64(expected))
    # A simple case: sqrt(1^2 + 2^2 + 0.5^2).
    simple = wasserstein2(t64([[1.0, 2.0]]), t64([[0.5, 1.0]]), t64([[0.0, 0.0]]), t64([[1.0, 1.0]]))
    assert simple.item() == pytest.approx(math.sqrt(5.25))


def test_wasserstein2_zero_for_identical_and_symmetric():
    g = seeded(3)
    mu1, mu2 = torch.randn(5, 4, generator=g), torch.randn(5, 4, generator=g)
    s1, s2 = torch.rand(5, 4, generator=g) + 0.1, torch.rand(5, 4, generator=g) + 0.1
    mu1.requires_grad_(True)
    same = wasserstein2(mu1, s1, mu1.detach().clone(), s1)
    assert torch.equal(same, torch.zeros(5))
    same.sum().backward()
    assert torch.isfinite(mu1.grad).all()
    assert torch.allclose(wasserstein2(mu1, s1, mu2, s2), wasserstein2(mu2, s2, mu1, s1))


# --- bisimulation_loss (DBC) ---


def test_bisimulation_loss_by_hand():
    gamma = 0.9
    total = 0.0
    for i, j in enumerate(PERM):
        z_dist = sum(abs(a - b) for a, b in zip(Z[i], Z[j], strict=True))
        target = abs(REWARDS[i] - REWARDS[j]) + gamma * w2_by_hand(i, j)
        total += (z_dist - target) ** 2
    loss = bisimulation_loss(t64(Z), t64(REWARDS), t64(MU), t64(SIGMA), torch.tensor(PERM), gamma)
    assert loss.item() == pytest.approx(total / 4, rel=1e-12)
    # Rewards as an (n, 1) column give the same loss.
    column = bisimulation_loss(t64(Z), t64(REWARDS)[:, None], t64(MU), t64(SIGMA), torch.tensor(PERM), gamma)
    assert column.item() == pytest.approx(total / 4, rel=1e-12)


def huber(x: float) -> float:
    """The Huber function with delta 1 (torch's smooth L1)."""
    return 0.5 * x * x if abs(x) < 1 else abs(x) - 0.5


# Predictions of the whole latent (4 dimensions), for DBC's code form, which measures z and them per dimension.
MU4 = [[0.1, 0.2, -0.5, 1.0], [-0.3, 0.4, 0.0, 2.0], [1.0, -1.0, 0.5, 0.5], [0.0, 0.5, 1.5, -1.0]]
SIGMA4 = [[0.5, 1.0, 0.2, 0.3], [0.25, 2.0, 0.1, 1.0], [1.0, 1.0, 0.5, 0.5], [3.0, 0.1, 1.0, 2.0]]


def test_bisimulation_loss_code_by_hand():
    # DBC's code: the mean over pairs and dimensions of (H(z_ik - z_jk) - H(r_i - r_j) - gamma W2_ijk)^2.
    gamma, errors = 0.9, []
    for i, j in enumerate(PERM):
        for k in range(4):
            w2 = math.sqrt((MU4[i][k] - MU4[j][k]) ** 2 + (SIGMA4[i][k] - SIGMA4[j][k]) ** 2)
            errors.append((huber(Z[i][k] - Z[j][k]) - huber(REWARDS[i] - REWARDS[j]) - gamma * w2) ** 2)
    loss = bisimulation_loss_code(t64(Z), t64(REWARDS), t64(MU4), t64(SIGMA4), torch.tensor(PERM), gamma)
    assert loss.item() == pytest.approx(sum(errors) / len(errors), rel=1e-12)
    # At the paper's 50 features the paper's form (sums over the features) is three orders of magnitude larger.
    g = seeded(7)
    z, mu = torch.tanh(torch.randn(128, 50, generator=g)).double(), torch.randn(128, 50, generator=g).double()
    sigma, rewards = torch.rand(128, 50, generator=g).double(), torch.rand(128, generator=g).double()
    perm = torch.randperm(128, generator=g)
    ratio = bisimulation_loss(z, rewards, mu, sigma, perm, 0.99) / bisimulation_loss_code(
        z, rewards, mu, sigma, perm, 0.99
    )
    assert ratio > 300, ratio


def test_ambs_metric_loss_code_by_hand():
    reward_learner, dynamics_learner = seeded_learner(2, 0), seeded_learner(2, 1)
    c, gamma = 0.3, 0.9

    def learned(learner: MetricLearner, a: list[float], b: list[float]) -> float:
        return learner(t64([a]), t64([b])).item()

    def by_hand(meta: bool, deterministic: bool) -> float:
        reward_errors, dynamics_errors = [], []
        for pair_set in ("batch", "augmented"):
            for i, j in enumerate(PERM):
                first, second = (Z[i], Z[j]) if pair_set == "batch" else (Z[j], AUG_Z[i])
                if meta:
                    rew = c * learned(reward_learner, first[:2], second[:2])
                    dyn = (1 - c) * learned(dynamics_learner, first[2:], second[2:])
                else:
                    rew = c * sum(huber(a - b) for a, b in zip(first[:2], second[:2], strict=True)) / 2
                    dyn = sum(((1 - c) * (a - b)) ** 2 for a, b in zip(first[2:], second[2:], strict=True)) / 2
                reward_errors.append((rew - c * huber(REWARDS[i] - REWARDS[j])) ** 2)
                if deterministic:  # per dimension: the Huber distance of the predicted means
                    dynamics_errors += [(dyn - gamma * (1 - c) * huber(MU[i][k] - MU[j][k])) ** 2 for k in range(2)]
                else:  # W2 per dimension, averaged over the dimensions
                    w2 = [math.sqrt((MU[i][k] - MU[j][k]) ** 2 + (SIGMA[i][k] - SIGMA[j][k]) ** 2) for k in range(2)]
                    dynamics_errors.append((dyn - gamma * (1 - c) * sum(w2) / 2) ** 2)
        return 0.5 * sum(reward_errors) / len(reward_errors) + 0.5 * sum(dynamics_errors) / len(dynamics_errors)

    args = (t64(Z), t64(AUG_Z), t64(REWARDS), t64(MU))
    learners = (reward_learner, dynamics_learner)
    cases = [
        (True, False, t64(SIGMA), learners),
        (False, False, t64(SIGMA), (None, None)),
        (False, True, None, (None, None)),
    ]
    for meta, deterministic, sigma, pair in cases:
        loss = ambs_metric_loss_code(*args, sigma, torch.tensor(PERM), c, *pair, gamma, 2)
        assert loss.item() == pytest.approx(by_hand(meta, deterministic), rel=1e-12), (meta, deterministic)
    with pytest.raises(ValueError, match="both"):
        ambs_metric_loss_code(*args, t64(SIGMA), torch.tensor(PERM), c, reward_learner, None, gamma, 2)


def test_bisimulation_loss_gradients_reach_only_z():
    z = t64(Z).requires_grad_(True)
    mu, sigma = t64(MU).requires_grad_(True), t64(SIGMA).requires_grad_(True)
    bisimulation_loss(z, t64(REWARDS), mu.detach(), sigma.detach(), torch.tensor(PERM), 0.9).backward()
    assert z.grad is not None and z.grad.abs().sum() > 0
    assert mu.grad is None and sigma.grad is None
    # The target is a constant even when the predictions are passed with grad.
    bisimulation_loss(z, t64(REWARDS), mu, sigma, torch.tensor(PERM), 0.9).backward()
    assert mu.grad is None and sigma.grad is None


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"perm": torch.tensor([0, 1, 2])}, "perm"),
        ({"perm": torch.tensor([0.0, 1.0, 2.0, 3.0])}, "perm"),
        ({"gamma": 1.0}, "gamma"),
        ({"gamma": -0.1}, "gamma"),
        ({"rewards": torch.zeros(4, 2)}, "rewards"),
        ({"rewards": torch.zeros(3)}, "rewards"),
        ({"mu": torch.zeros(3, 2)}, "mu"),
        ({"sigma": torch.ones(4, 3)}, "sigma"),
        ({"z": torch.zeros(4)}, "z"),
    ],
)
def test_bisimulation_loss_argument_checks(change, message):
    kwargs = {
        "z": torch.zeros(4, 3),
        "rewards": torch.zeros(4),
        "mu": torch.zeros(4, 2),
        "sigma": torch.ones(4, 2),
        "perm": torch.tensor(PERM),
        "gamma": 0.5,
    }
    with pytest.raises(ValueError, match=message):
        bisimulation_loss(**{**kwargs, **change})


# --- AMBS: meta-learners, halves, metric loss ---


def test_metric_learner_formula_non_negative_and_ordered():
    learner = seeded_learner(2, 0)
    g = seeded(1)
    a, b = torch.randn(16, 2, generator=g, dtype=torch.float64), torch.randn(16, 2, generator=g).double()
    first, second = learner.net[0], learner.net[2]
    by_hand = (torch.relu(torch.cat([a, b], 1) @ first.weight.T + first.bias) @ second.weight.T + second.bias) ** 2
    assert torch.allclose(learner(a, b), by_hand.squeeze(1))
    assert (learner(a, b) >= 0).all()
    assert not torch.allclose(learner(a, b), learner(b, a))


def test_split_halves():
    z = torch.arange(12.0).reshape(2, 6)
    reward_part, dynamics_part = split_halves(z, 2)
    assert torch.equal(reward_part, z[:, :2]) and torch.equal(dynamics_part, z[:, 2:])
    for bad in (0, 6, 2.0):
        with pytest.raises(ValueError, match="reward_dim"):
            split_halves(z, bad)


def ambs_by_hand(c: float, gamma: float, reward_learner: MetricLearner, dynamics_learner: MetricLearner) -> float:
    """AMBS's metric loss from its formula, one pair at a time: batch pairs (i, j) and augmented pairs (j, i')."""

    def learned(learner: MetricLearner, a: list[float], b: list[float]) -> float:
        return learner(t64([a]), t64([b])).item()

    reward_errors, dynamics_errors = [], []
    for pair_set in ("batch", "augmented"):
        for i, j in enumerate(PERM):
            first, second = (Z[i], Z[j]) if pair_set == "batch" else (Z[j], AUG_Z[i])
            reward_target = c * abs(REWARDS[i] - REWARDS[j])
            dynamics_target = (1 - c) * gamma * w2_by_hand(i, j)
            reward_errors.append((c * learned(reward_learner, first[:2], second[:2]) - reward_target) ** 2)
            dynamics_errors.append(((1 - c) * learned(dynamics_learner, first[2:], second[2:]) - dynamics_target) ** 2)
    return 0.5 * sum(reward_errors) / len(reward_errors) + 0.5 * sum(dynamics_errors) / len(dynamics_errors)


def test_ambs_metric_loss_by_hand():
    reward_learner, dynamics_learner = seeded_learner(2, 0), seeded_learner(2, 1)
    c, gamma = 0.3, 0.9
    expected = ambs_by_hand(c, gamma, reward_learner, dynamics_learner)
    args = (t64(Z), t64(AUG_Z), t64(REWARDS), t64(MU), t64(SIGMA), torch.tensor(PERM))
    loss = ambs_metric_loss(*args, c, reward_learner, dynamics_learner, gamma, 2)
    assert loss.item() == pytest.approx(expected, rel=1e-12)
    # The softmax ratio as a 0-d tensor gives the same loss.
    as_tensor = ambs_metric_loss(
        *args, torch.tensor(c, dtype=torch.float64), reward_learner, dynamics_learner, gamma, 2
    )
    assert as_tensor.item() == pytest.approx(expected, rel=1e-12)


def test_ambs_metric_loss_gradients():
    reward_learner, dynamics_learner = seeded_learner(2, 0), seeded_learner(2, 1)
    h, aug_h = t64(Z).requires_grad_(True), t64(AUG_Z).requires_grad_(True)
    mu = t64(MU).requires_grad_(True)
    ratio = torch.tensor([0.2, -0.1], dtype=torch.float64, requires_grad=True)
    c = torch.softmax(ratio, dim=0)[0]
    batch = (h, aug_h, t64(REWARDS), mu, t64(SIGMA), torch.tensor(PERM))
    ambs_metric_loss(*batch, c, reward_learner, dynamics_learner, 0.9, 2).backward()
    assert h.grad.abs().sum() > 0 and aug_h.grad.abs().sum() > 0
    for learner in (reward_learner, dynamics_learner):
        assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in learner.parameters())
    # The target and the balance are constants.
    assert mu.grad is None and ratio.grad is None


def test_ambs_distance_by_hand():
    reward_learner, dynamics_learner = seeded_learner(2, 0), seeded_learner(1, 1)
    a, b = t64(Z)[:, :3], t64(AUG_Z)[:, :3]
    distance = ambs_distance(a, b, 0.25, reward_learner, dynamics_learner, 2)
    expected = 0.25 * reward_learner(a[:, :2], b[:, :2]) + 0.75 * dynamics_learner(a[:, 2:], b[:, 2:])
    assert distance.shape == (4,) and torch.allclose(distance, expected)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"reward_weight": 1.5}, "reward_weight"),
        ({"reward_weight": -0.1}, "reward_weight"),
        ({"reward_weight": torch.tensor([0.5, 0.5])}, "reward_weight"),
        ({"gamma": 1.0}, "gamma"),
        ({"perm": torch.tensor([1, 2, 3])}, "perm"),
        ({"aug_h": torch.zeros(4, 3)}, "aug_h"),
        ({"mu": torch.zeros(4, 4)}, "mu"),
        ({"reward_dim": 4}, "reward_dim"),
        ({"reward_learner": MetricLearner(3)}, "reward_learner"),
        ({"dynamics_learner": nn.Linear(4, 1)}, "dynamics_learner"),
        ({"rewards": torch.zeros(5)}, "rewards"),
    ],
)
def test_ambs_metric_loss_argument_checks(change, message):
    kwargs = {
        "h": torch.zeros(4, 4),
        "aug_h": torch.zeros(4, 4),
        "rewards": torch.zeros(4),
        "mu": torch.zeros(4, 2),
        "sigma": torch.ones(4, 2),
        "perm": torch.tensor(PERM),
        "reward_weight": 0.5,
        "reward_learner": MetricLearner(2),
        "dynamics_learner": MetricLearner(2),
        "gamma": 0.5,
        "reward_dim": 2,
    }
    with pytest.raises(ValueError, match=message):
        ambs_metric_loss(**{**kwargs, **change})


# --- learning: a task with a reward-irrelevant distractor ---
#
# o = [x, y]: the reward r = -||x|| and the next x = 0.9 x + 0.1 a depend on x in [-1, 1]^2 only; y in R^6 is a
# distractor, N(0, I) afresh every step, or (predictable) rolled by one place, which a dynamics model can
# follow. The encoder o -> 8 features is trained with a metric loss plus 0.01 * (transition NLL + reward MSE)
# (AMBS's weighting). The check compares the learned distance between observations that differ only in y and
# observations that differ only in x, each part redrawn from its own distribution (the y change is the larger
# in norm: about 3.4 against 1.0).

X_DIM, Y_DIM, ACTION_DIM, FEATURES_DIM = 2, 6, 2, 8
BATCH, GAMMA, LR = 64, 0.5, 1e-2


def transitions(n: int, g: torch.Generator, predictable: bool = False) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(observations, actions, rewards, next observations) of n independent steps."""
    x = 2 * torch.rand(n, X_DIM, generator=g) - 1
    y = torch.randn(n, Y_DIM, generator=g)
    actions = 2 * torch.rand(n, ACTION_DIM, generator=g) - 1
    next_y = y.roll(1, dims=1) if predictable else torch.randn(n, Y_DIM, generator=g)
    return torch.cat([x, y], 1), actions, -x.norm(dim=1), torch.cat([0.9 * x + 0.1 * actions, next_y], 1)


class Tanh(nn.Module):
    def forward(self, x: Tensor) -> Tensor:
        return torch.tanh(x)


def train(method: str, steps: int, coef: float, predictable: bool = False) -> Callable[[Tensor, Tensor], Tensor]:
    """Train encoder, transition model, reward decoder (and AMBS's meta-learners); return the learned distance."""
    ambs = method == "ambs"
    half = FEATURES_DIM // 2
    model_dim = half if ambs else FEATURES_DIM
    with torch.random.fork_rng():
        torch.manual_seed(0)
        encoder = nn.Sequential(nn.Linear(X_DIM + Y_DIM, 64), nn.ReLU(), nn.Linear(64, FEATURES_DIM), Tanh())
        transition = ProbabilisticTransitionModel(model_dim, ACTION_DIM, hidden_dim=32)
        decoder = RewardDecoder(model_dim, hidden_dim=32)
        learners = (MetricLearner(half, 32), MetricLearner(half, 32)) if ambs else ()
    modules = [encoder, transition, decoder, *learners]
    optimizer = torch.optim.Adam([p for module in modules for p in module.parameters()], lr=LR)
    g = seeded(1)
    for _ in range(steps):
        obs, actions, rewards, next_obs = transitions(BATCH, g, predictable)
        perm = torch.randperm(BATCH, generator=g)
        if ambs:
            # The second view: a little noise on the distractor.
            noisy = obs + torch.cat([torch.zeros(BATCH, X_DIM), 0.1 * torch.randn(BATCH, Y_DIM, generator=g)], 1)
            h, aug_h, next_h = encoder(torch.cat([obs, noisy, next_obs])).split(BATCH)
            z, next_z = split_halves(h, half)[1], split_halves(next_h, half)[1]
        else:
            h, next_h = encoder(torch.cat([obs, next_obs])).split(BATCH)
            z, next_z = h, next_h
        mu, sigma = transition(z, actions)
        if ambs:
            metric = ambs_metric_loss(h, aug_h, rewards, mu.detach(), sigma.detach(), perm, 0.5, *learners, GAMMA, half)
        else:
            metric = bisimulation_loss(h, rewards, mu.detach(), sigma.detach(), perm, GAMMA)
        predicted_rewards = decoder(mu + sigma * torch.randn(mu.shape, generator=g)).squeeze(1)
        model_loss = gaussian_nll(mu, sigma, next_z.detach()) + (predicted_rewards - rewards).square().mean()
        optimizer.zero_grad()
        (coef * metric + 0.01 * model_loss).backward()
        optimizer.step()
    if ambs:
        return lambda a, b: ambs_distance(encoder(a), encoder(b), 0.5, *learners, half)
    return lambda a, b: (encoder(a) - encoder(b)).abs().sum(dim=1)


def mean_distances(distance: Callable[[Tensor, Tensor], Tensor]) -> dict[str, float]:
    """Mean learned distance of 256 observations to themselves, with y redrawn, and with x redrawn."""
    g = seeded(100)
    obs, *_ = transitions(256, g)
    other, *_ = transitions(256, g)
    new_y = torch.cat([obs[:, :X_DIM], other[:, X_DIM:]], 1)
    new_x = torch.cat([other[:, :X_DIM], obs[:, X_DIM:]], 1)
    with torch.no_grad():
        return {
            name: distance(obs, changed).mean().item() for name, changed in [("self", obs), ("y", new_y), ("x", new_x)]
        }


def measured(method: str, steps: int, coef: float, predictable: bool = False) -> dict[str, float]:
    """``mean_distances`` of a training run, in float64: float32 rounding, which differs between CPUs (AVX2 or
    not, thread counts), grows over the run into other outcomes of these toys (measured: the random distractor
    without the metric ended at y / x = 2.8 on one CPU and 0.28 on another); in float64 both agree to 10%."""
    default = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        return mean_distances(train(method, steps, coef, predictable))
    finally:
        torch.set_default_dtype(default)


# Margins from float64 runs with ATEN_CPU_CAPABILITY=default and avx2 on one thread, as conftest.py runs the suite
# (the largest y / x):
# DBC 0.115 (random), 0.085 (predictable); without the metric, predictable 6.4; AMBS 0.26, (y - self) / (x - self)
# 0.053; AMBS without the metric 1.00.


@pytest.mark.slow
@pytest.mark.parametrize("predictable", [False, True], ids=["random-distractor", "predictable-distractor"])
def test_dbc_ignores_the_distractor(predictable):
    d = measured("dbc", 1000 if predictable else 600, coef=1.0, predictable=predictable)
    assert d["y"] < 0.3 * d["x"], d


@pytest.mark.slow
def test_dbc_fails_without_the_metric_on_a_predictable_distractor():
    # Without the bisimulation loss (300 steps) a distractor the dynamics model can follow stays encoded (y / x
    # 6.4). An unpredictable one the transition NLL drops by itself (y / x 0.08 in float64), so that case shows
    # nothing about the metric.
    d = measured("dbc", 300, coef=0.0, predictable=True)
    assert d["y"] > 2 * d["x"], d


@pytest.mark.slow
def test_ambs_ignores_the_distractor():
    d = measured("ambs", 800, coef=1.0)
    assert d["y"] < 0.4 * d["x"], d
    # Most of what is left is the meta-learners' distance of a representation to itself, which nothing trains to
    # 0 (d(a, a) = f([a, a])^2); above it, the distractor adds next to nothing.
    assert d["y"] - d["self"] < 0.2 * (d["x"] - d["self"]), d


def test_ambs_without_metric_learns_no_distance():
    # At coefficient 0 the meta-learners get no gradient: their distance does not tell x from y (a short run suffices).
    d = measured("ambs", 200, coef=0.0)
    assert d["y"] > 0.8 * d["x"], d
