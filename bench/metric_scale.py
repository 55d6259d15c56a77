"""How large the paper's and the authors' code's forms of DBC's and AMBS's metric losses are on the same batch.

Both forms of each loss are evaluated on one batch of random encodings (n = 128, standard normal features),
rewards in [0, 1), transition-model predictions (standard normal means, standard deviations in [0.5, 1.5)) and a
random pairing, for each seed; AMBS's with fresh meta-learners, the reward weight 0.5 and the features split in
halves (reward, dynamics) as AMBS's encoder does by default. Printed: the median over seeds of each form and of
paper / code, per feature count. The scale matters because each form's ``bisim_coef`` was set for it.

    python bench/metric_scale.py                       # d = 50, 20 seeds
    python bench/metric_scale.py --dims 20 50 100
"""

from __future__ import annotations

import argparse
import statistics

import torch as th

from sb3_sgfd.ambs.losses import MetricLearner, ambs_metric_loss, ambs_metric_loss_code
from sb3_sgfd.dbc.losses import bisimulation_loss, bisimulation_loss_code

N_BATCH, GAMMA, REWARD_WEIGHT = 128, 0.99, 0.5


def losses(d: int, seed: int) -> dict[str, tuple[float, float]]:
    """(paper form, code form) of each loss on one seeded batch of ``d`` features."""
    generator = th.Generator().manual_seed(seed)
    th.manual_seed(seed)

    def normal(*shape: int) -> th.Tensor:
        return th.randn(*shape, generator=generator)

    z, aug_z = normal(N_BATCH, d), normal(N_BATCH, d)
    rewards = th.rand(N_BATCH, generator=generator)
    perm = th.randperm(N_BATCH, generator=generator)
    mu = normal(N_BATCH, d)
    sigma = 0.5 + th.rand(N_BATCH, d, generator=generator)
    reward_dim = d // 2
    half_mu, half_sigma = mu[:, reward_dim:], sigma[:, reward_dim:]
    learners = (MetricLearner(reward_dim), MetricLearner(d - reward_dim))
    ambs_args = (z, aug_z, rewards, half_mu, half_sigma, perm, REWARD_WEIGHT)
    with th.no_grad():
        return {
            "DBC": (
                float(bisimulation_loss(z, rewards, mu, sigma, perm, GAMMA)),
                float(bisimulation_loss_code(z, rewards, mu, sigma, perm, GAMMA)),
            ),
            "AMBS": (
                float(ambs_metric_loss(*ambs_args, *learners, GAMMA, reward_dim)),
                float(ambs_metric_loss_code(*ambs_args, *learners, GAMMA, reward_dim)),
            ),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dims", type=int, nargs="+", default=[50])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    print("| loss | d | paper form | code form | paper / code |")
    print("|---|---|---|---|---|")
    for d in args.dims:
        runs = [losses(d, seed) for seed in range(args.seeds)]
        for name in ("DBC", "AMBS"):
            paper = statistics.median(run[name][0] for run in runs)
            code = statistics.median(run[name][1] for run in runs)
            ratio = statistics.median(run[name][0] / run[name][1] for run in runs)
            print(f"| {name} | {d} | {paper:.4g} | {code:.4g} | {ratio:.3g}x |")


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
