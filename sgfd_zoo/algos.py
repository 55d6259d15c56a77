"""The zoo's algorithm keys: which SB3 algorithm each is, its column in the paper's tables and its yaml.

No heavy import: reporting reads this table; the classes are imported when a key is trained or loaded.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"


@dataclass(frozen=True)
class ZooAlgo:
    """
    An algorithm key of the zoo.

    :param class_path: The SB3 algorithm, ``package:Class`` (the package sb3_sgfd or stable_baselines3)
    :param column: Its column name in the paper's tables
    :param hyperparams: The yaml file stem under sgfd_zoo/hyperparams it reads
    :param overrides: Hyperparameters set on top of that file (how the ablations differ from SGFD)
    :param quick_hyperparams: The stem under sgfd_zoo/hyperparams/quick, where it differs from ``hyperparams``
    """

    class_path: str
    column: str
    hyperparams: str
    overrides: dict[str, Any] = field(default_factory=dict)
    quick_hyperparams: str | None = None

    @property
    def algo_class(self) -> type:
        import stable_baselines3  # here: reading this table imports no agent

        import sb3_sgfd

        package, _, name = self.class_path.partition(":")
        return getattr({"sb3_sgfd": sb3_sgfd, "stable_baselines3": stable_baselines3}[package], name)


SGFD, SAC = "sb3_sgfd:SGFD_SAC", "stable_baselines3:SAC"
# In the paper's column order (Tables 1-2: SGFD, TED, AMBS, SGQN, DBC, DR), then SGFD's ablations.
# "sgfd_sac" is the paper's agent: SGFD's reweighting on AMBS's representation learning (appendix B); its quick
# configuration is on states, where there is no encoder to learn, so it is the reweighting on SAC there.
# "sac" is the Domain Randomisation baseline: SAC with the same policy on the same training domains.
SGFD_ALGOS: dict[str, ZooAlgo] = {
    "sgfd_sac": ZooAlgo(SGFD, "SGFD", "sgfd_sac"),
    "ted": ZooAlgo("sb3_sgfd:TED", "TED", "ted"),
    "ambs": ZooAlgo("sb3_sgfd:AMBS", "AMBS", "ambs"),
    "sgqn": ZooAlgo("sb3_sgfd:SGQN", "SGQN", "sgqn"),
    "dbc": ZooAlgo("sb3_sgfd:DBC", "DBC", "dbc"),
    "sac": ZooAlgo(SAC, "DR", "sac"),
    # SGFD as the authors' code computes it (reading="official": weights on the actor only from the first update,
    # near uniform); at paper scale on the code's committed encoder objective (sgfd_sac_official.yml)
    "sgfd_sac_official": ZooAlgo(
        SGFD, "SGFD (code)", "sgfd_sac_official", {"reading": "official"}, quick_hyperparams="sgfd_sac"
    ),
    # The paper reading at a strength between the two: ESS about 0.85 n on real MT states (bench/decorrelation.py)
    "sgfd_sac_moderate": ZooAlgo(
        SGFD, "SGFD moderate", "sgfd_sac", {"reweight_ess_penalty": 1.5, "reweight_max_step": 1.0}
    ),
    # SGFD on SAC's critic-trained encoder, without AMBS's objective (this package's first SGFD agent)
    "sgfd_sac_plain": ZooAlgo(SGFD, "SGFD on SAC", "sgfd_sac_plain", quick_hyperparams="sgfd_sac"),
    "sgfd_sac_no_rff": ZooAlgo(SGFD, "SGFD w/o RFF", "sgfd_sac", {"use_rff": False}),
    "sgfd_sac_no_saliency": ZooAlgo(SGFD, "SGFD w/o saliency", "sgfd_sac", {"use_saliency": False}),
    # Algorithm 1 (line 18 updates Q with the unweighted eq. 1) and the official code weight the actor only.
    # Both switches are set, so that each variant stays itself whatever the yaml's defaults are.
    "sgfd_sac_actor_only": ZooAlgo(
        SGFD, "SGFD actor-only", "sgfd_sac", {"reweight_critic": False, "reweight_actor": True}
    ),
    "sgfd_sac_critic_only": ZooAlgo(
        SGFD, "SGFD critic-only", "sgfd_sac", {"reweight_critic": True, "reweight_actor": False}
    ),
    # Both losses weighted (Algorithm 1 as the design reads it; SGFD_SAC's own default).
    "sgfd_sac_both": ZooAlgo(SGFD, "SGFD both", "sgfd_sac", {"reweight_critic": True, "reweight_actor": True}),
}
# Order of the tables' columns: the keys above, then any other in name order.
ALGO_ORDER = list(SGFD_ALGOS)


def hyperparams_file(algo: str, quick: bool = False) -> Path:
    """The zoo's yaml for ``algo``: paper scale, or the quick configuration for a laptop-size run."""
    if algo not in SGFD_ALGOS:
        return HYPERPARAMS_DIR / ("quick" if quick else "") / f"{algo}.yml"
    entry = SGFD_ALGOS[algo]
    if quick:
        return HYPERPARAMS_DIR / "quick" / f"{entry.quick_hyperparams or entry.hyperparams}.yml"
    return HYPERPARAMS_DIR / f"{entry.hyperparams}.yml"


def hyperparams_entry(algo: str, env_id: str, quick: bool = False) -> dict[str, Any]:
    """
    The entry of ``algo``'s yaml that a run on ``env_id`` reads, as rl-zoo3's ExperimentManager picks it: the env
    id's own entry, else ``default``; empty when the file has neither (rl-zoo3 then stops).

    :param algo: algorithm key
    :param env_id: the env id
    :param quick: the quick configuration's yaml instead of the paper-scale one
    """
    import yaml  # here: the tables above are read without parsing any yaml

    entries = yaml.safe_load(hyperparams_file(algo, quick).read_text()) or {}
    return dict(entries.get(env_id, entries.get("default", {})))


def column_name(algo: str) -> str:
    """The paper-table column of an algorithm key (the key itself when it is not one of ours)."""
    return SGFD_ALGOS[algo].column if algo in SGFD_ALGOS else algo


def algo_sort_key(algo: str) -> tuple[int, str]:
    """Sort key putting algorithm keys in the paper's column order."""
    return (ALGO_ORDER.index(algo) if algo in ALGO_ORDER else len(ALGO_ORDER), algo)


def is_sgfd(algo: str) -> bool:
    """Whether ``algo`` is one of the SGFD agents (SGFD_SAC with a domain classifier and ``classifier_start``)."""
    return algo in SGFD_ALGOS and SGFD_ALGOS[algo].class_path == SGFD


def classifier_start_warning(algo: str, hyperparams: dict[str, Any], n_timesteps: int) -> str | None:
    """
    One line when ``algo`` is an SGFD agent whose domain classifier would not train within the run (its
    ``classifier_start`` is at or past the run's last step), saying what the run then is; None otherwise.

    :param algo: algorithm key
    :param hyperparams: the run's hyperparameters (``classifier_start`` and ``reading`` where set)
    :param n_timesteps: env steps the run trains for
    """
    if not is_sgfd(algo):
        return None
    start = hyperparams.get("classifier_start")
    if start is None:
        from sb3_sgfd.sgfd.settings import SGFDSettings  # here: reading this table imports no agent

        start = SGFDSettings().classifier_start
    if start < n_timesteps:
        return None
    # The official reading weights from the first update with whatever the classifier scores; the paper's
    # reweights only once its classifier has trained.
    what = (
        "its weights come from a classifier that never trains"
        if hyperparams.get("reading") == "official"
        else "it trains as plain SAC (no sample weights)"
    )
    return (
        f"{algo}: the run is {n_timesteps} steps and SGFD's domain classifier starts at step {start} "
        f"(classifier_start), so {what}; start it within the run with --classifier-start STEPS"
    )
