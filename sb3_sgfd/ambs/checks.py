"""AMBS's own checks of its arguments: the balance c, the reward half of the features and the meta-learners. The
generic checks (shapes, rewards, pairings, the discount) are in :mod:`sb3_sgfd.common.validation`."""

from __future__ import annotations

from torch import Tensor, nn


def check_reward_weight(reward_weight: object) -> Tensor | float:
    """AMBS's balance c as given: a float in [0, 1], or a 0-d float tensor, detached (a softmax ratio, in [0, 1] by
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


def check_reward_dim(reward_dim: object, d: int) -> None:
    """Refuse a reward half of a d-feature representation that is not an int in [1, d - 1]."""
    if isinstance(reward_dim, bool) or not isinstance(reward_dim, int) or not 0 < reward_dim < d:
        raise ValueError(f"reward_dim must be an int in [1, {d - 1}] for {d} features, got {reward_dim!r}")


def check_metric_learner(learner: object, name: str, half_dim: int) -> None:
    """Refuse an AMBS meta-learner (a module with a ``half_dim``) that does not measure halves of ``half_dim``."""
    learner_dim = getattr(learner, "half_dim", None)
    if not isinstance(learner, nn.Module) or learner_dim != half_dim:
        got = f"half_dim {learner_dim}" if learner_dim is not None else type(learner).__name__
        raise ValueError(f"{name} must be a MetricLearner with half_dim {half_dim}, got {got}")
