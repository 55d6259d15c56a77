"""SGFD's entries in rl-zoo3's algorithm, hyperparameter-sampler and converter tables."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import optuna
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER, convert_offpolicy_params
from rl_zoo3.utils import ALGOS
from stable_baselines3 import SAC

from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED


@dataclass(frozen=True)
class ZooAlgo:
    """
    An algorithm key of the zoo.

    :param algo_class: The SB3 algorithm
    :param column: Its column name in the paper's tables
    :param hyperparams: The yaml file stem under zoo/hyperparams it reads
    :param overrides: Hyperparameters set on top of that file (how the ablations differ from SGFD)
    :param quick_hyperparams: The stem under zoo/hyperparams/quick, where it differs from ``hyperparams``
    """

    algo_class: type
    column: str
    hyperparams: str
    overrides: dict[str, Any] = field(default_factory=dict)
    quick_hyperparams: str | None = None


# In the paper's column order (Tables 1-2: SGFD, TED, AMBS, SGQN, DBC, DR), then SGFD's ablations.
# "sgfd_sac" is the paper's agent: SGFD's reweighting on AMBS's representation learning (appendix B); its quick
# configuration is on states, where there is no encoder to learn, so it is the reweighting on SAC there.
# "sac" is the Domain Randomisation baseline: SAC with the same policy on the same training domains.
SGFD_ALGOS: dict[str, ZooAlgo] = {
    "sgfd_sac": ZooAlgo(SGFD_SAC, "SGFD", "sgfd_sac"),
    "ted": ZooAlgo(TED, "TED", "ted"),
    "ambs": ZooAlgo(AMBS, "AMBS", "ambs"),
    "sgqn": ZooAlgo(SGQN, "SGQN", "sgqn"),
    "dbc": ZooAlgo(DBC, "DBC", "dbc"),
    "sac": ZooAlgo(SAC, "DR", "sac"),
    # SGFD on SAC's critic-trained encoder, without AMBS's objective (this package's first SGFD agent)
    "sgfd_sac_plain": ZooAlgo(SGFD_SAC, "SGFD on SAC", "sgfd_sac_plain", quick_hyperparams="sgfd_sac"),
    "sgfd_sac_no_rff": ZooAlgo(SGFD_SAC, "SGFD w/o RFF", "sgfd_sac", {"use_rff": False}),
    "sgfd_sac_no_saliency": ZooAlgo(SGFD_SAC, "SGFD w/o saliency", "sgfd_sac", {"use_saliency": False}),
    # Algorithm 1 (line 18 updates Q with the unweighted eq. 1) and the official code weight the actor only.
    "sgfd_sac_actor_only": ZooAlgo(SGFD_SAC, "SGFD actor-only", "sgfd_sac", {"reweight_critic": False}),
}


def sample_sgfd_sac_params(
    trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]
) -> dict[str, Any]:
    """SAC's search space (as rl-zoo3 samples it) plus SGFD's classifier and weight-solver settings."""
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
    return convert_sgfd_sac_params(sampled)


def convert_sgfd_sac_params(sampled_params: dict[str, Any]) -> dict[str, Any]:
    """Turn Optuna's sampled values into SGFD_SAC arguments (also used to load a stored trial)."""
    return convert_offpolicy_params(sampled_params)


def register_algorithms() -> None:
    """Add SGFD's keys to rl-zoo3's tables; idempotent. The other agents take rl-zoo3's SAC search space."""
    for key, algo in SGFD_ALGOS.items():
        ALGOS[key] = algo.algo_class
        if algo.algo_class is SGFD_SAC:
            HYPERPARAMS_SAMPLER[key] = sample_sgfd_sac_params
            HYPERPARAMS_CONVERTER[key] = convert_sgfd_sac_params
        elif key != "sac":
            HYPERPARAMS_SAMPLER[key] = HYPERPARAMS_SAMPLER["sac"]
            HYPERPARAMS_CONVERTER[key] = HYPERPARAMS_CONVERTER["sac"]


def column_name(algo: str) -> str:
    """The paper-table column of an algorithm key (the key itself when it is not one of ours)."""
    return SGFD_ALGOS[algo].column if algo in SGFD_ALGOS else algo
