"""The zoo's algorithms in rl-zoo3's tables: each key's class and its Optuna search space for ``sgfd-zoo
optimize`` (SGFD's agents: a narrower SAC space plus SGFD's own settings, :func:`sample_sgfd_sac_params`; the
others: rl-zoo3's SAC space)."""

from __future__ import annotations

from typing import Any

import optuna
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER, convert_offpolicy_params
from rl_zoo3.utils import ALGOS

from sb3_sgfd import SGFD_SAC
from sgfd_zoo.algos import SGFD_ALGOS


def register_algorithms() -> None:
    """Add SGFD's keys to rl-zoo3's tables; idempotent. The other agents take rl-zoo3's SAC search space."""
    for key, algo in SGFD_ALGOS.items():
        ALGOS[key] = algo.algo_class
        if algo.algo_class is SGFD_SAC:
            HYPERPARAMS_SAMPLER[key] = sample_sgfd_sac_params
            HYPERPARAMS_CONVERTER[key] = convert_offpolicy_params  # also loads a stored trial
        elif key != "sac":
            HYPERPARAMS_SAMPLER[key] = HYPERPARAMS_SAMPLER["sac"]
            HYPERPARAMS_CONVERTER[key] = HYPERPARAMS_CONVERTER["sac"]


def sample_sgfd_sac_params(
    trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]
) -> dict[str, Any]:
    """
    A SAC search space in rl-zoo3's parameter names, turned into arguments by rl-zoo3's off-policy conversion,
    plus SGFD's classifier and weight-solver settings. Not rl-zoo3's ``sample_sac_params``: its ranges (below)
    are narrower, and it samples no ``train_freq``, so the yaml's train_freq and gradient_steps stay.
    """
    sampled = {
        "one_minus_gamma": trial.suggest_float("one_minus_gamma", 0.0001, 0.03, log=True),
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 3e-3, log=True),
        "batch_size_pow": trial.suggest_int("batch_size_pow", 6, 9),
        "tau": trial.suggest_float("tau", 0.002, 0.05, log=True),
        "net_arch": trial.suggest_categorical("net_arch", ["medium", "big"]),
        "accuracy_threshold": trial.suggest_float("accuracy_threshold", 0.7, 0.98),
        "n_rff": trial.suggest_int("n_rff", 1, 10),
        "reweight_iters": trial.suggest_int("reweight_iters", 5, 30),
        "reweight_lr": trial.suggest_float("reweight_lr", 1e-2, 10.0, log=True),
        "saliency_temperature": trial.suggest_float("saliency_temperature", 0.05, 2.0, log=True),
        "saliency_smoothing": trial.suggest_float("saliency_smoothing", 0.0, 0.7),
    }
    return convert_offpolicy_params(sampled)
