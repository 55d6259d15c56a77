"""How well SGFD's sample weights decorrelate, and how fast they are computed.

Synthetic batches (sgfd_analysis/synthetic.py): n = 128 samples from 4 domains, one domain feature tied to 4
others, the rest noise, all tanh-squashed. For each seed a DomainClassifier is trained on 8192 other samples
of the same distribution (300 Adam steps on minibatches of 256; held-out accuracy ~0.98, above SGFD's 0.9
threshold), then feature_probabilities and learn_sample_weights run on the batch. Reported: mean |weighted
Pearson r| between the domain feature and its tied features before and after reweighting, its relative
reduction, the effective sample size ESS / n, and loss_after / loss_before.

Then the same solver on real states of the MT ids (``state_table``), where the synthetic batches' verdict on a
setting need not hold: there, the worst batch matters as much as the mean.

The strength curve (``strength_table``, synthetic and real states): how much of the domain feature's
correlation each reading's weights remove against how many samples they keep (ESS), for the paper reading
at ESS penalties from its default 0.35 up (SGFD_SAC's ``reweight_ess_penalty``, the strength knob; inside a
trust region above 1, where its steps otherwise collapse on real states), and for the official reading (the
authors' code, its memory filled by earlier batches) at its penalty 5 and below; the same p for every row, and
one row with the official reading's own p (guided backprop of its classifier, no temperature).

    .venv/bin/python bench/decorrelation.py            # 20 seeds, d = 10 and 50, 3 MT ids (about 2 minutes)
    .venv/bin/python bench/decorrelation.py --seeds 5  # quicker
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Iterator

import gymnasium as gym
import torch
from torch import Tensor, nn

from sb3_sgfd.sgfd.classifier import DomainClassifier
from sb3_sgfd.sgfd.decorrelation import WeightMemory, solve_official_weights, solve_weights
from sb3_sgfd.sgfd.functional import (
    classifier_accuracy,
    effective_sample_size,
    feature_probabilities,
    learn_sample_weights,
    saliency_map,
    train_classifier,
    weighted_pearson,
)
from sb3_sgfd.sgfd.settings import SGFDSettings
from sgfd_analysis.correlation import collect_states, standardised_sample, state_names
from sgfd_analysis.correlation import train_domain_classifier as correlation_classifier
from sgfd_analysis.synthetic import DomainBatch, ScaledLogits, make_domain_batch

N_BATCH, N_TRAIN, N_DOMAINS = 128, 8192, 4  # the memory rows use 40 of the training batches
# Each reading's solver settings, as SGFD_SAC runs them (solve_weights has no defaults of its own).
PAPER_SOLVER = SGFDSettings.paper().solver_settings()
OFFICIAL_SOLVER = SGFDSettings.official().solver_settings()


def train_domain_classifier(
    z: Tensor, domains: Tensor, steps: int, seed: int, stop_accuracy: float | None = None
) -> DomainClassifier:
    """Adam on minibatches of 256 (sb3_sgfd.sgfd.functional.train_classifier, SGFD's loop); with ``stop_accuracy``, it
    stops at the first minibatch classified that well, as SGFD_SAC's classifier does at its threshold."""
    torch.manual_seed(seed)
    classifier = DomainClassifier(z.shape[1], N_DOMAINS)
    optimizer = torch.optim.Adam(classifier.parameters(), lr=1e-3)

    def batches() -> Iterator[tuple[Tensor, Tensor]]:
        for _ in range(steps):
            index = torch.randint(0, len(z), (256,))
            yield z[index], domains[index]

    train_classifier(classifier, optimizer, batches(), stop_accuracy)
    return classifier


def tied_correlation(batch: DomainBatch, weights: Tensor | None = None) -> float:
    return weighted_pearson(batch.z, weights)[batch.top, batch.tied].abs().mean().item()


class Case:
    """One seed: the evaluation batch and a classifier trained on other samples."""

    def __init__(self, d: int, seed: int, tie_noise: float) -> None:
        full = make_domain_batch(n=N_TRAIN + N_BATCH, d=d, n_domains=N_DOMAINS, tie_noise=tie_noise, seed=seed)
        self.seed = seed
        self.train_z, self.train_domains = full.z[:N_TRAIN], full.domains[:N_TRAIN]
        self.batch = full._replace(z=full.z[N_TRAIN:], domains=full.domains[N_TRAIN:])
        self.classifier = train_domain_classifier(self.train_z, self.train_domains, steps=300, seed=seed)
        self.probs = feature_probabilities(self.classifier, self.batch.z)
        literal = {"temperature": 1.0, "normalize": False, "smoothing": 0.0}
        self.literal_probs = feature_probabilities(self.classifier, self.batch.z, **literal)
        # the same classifier, less confident: same decisions, logits 10x smaller
        quiet = ScaledLogits(self.classifier, 0.1)
        self.quiet_literal_probs = feature_probabilities(quiet, self.batch.z, **literal)


def remembered(case: Case, momentum: float, n_earlier: int) -> WeightMemory:
    """A memory that has solved ``n_earlier`` batches of the case's training samples, as a run's would have."""
    memory = WeightMemory(momentum)
    generator = torch.Generator().manual_seed(20_000 + case.seed)
    for index in range(n_earlier):
        z = case.train_z[index * N_BATCH : (index + 1) * N_BATCH]
        learn_sample_weights(z, feature_probabilities(case.classifier, z), generator=generator, memory=memory)
    return memory


def evaluate(
    cases: list[Case],
    probs: Callable[[Case], Tensor | None],
    scale: float = 1.0,
    memory: tuple[float, int] | None = None,
    **kwargs,
) -> list[str]:
    before, after, reductions, ess, loss_ratio = [], [], [], [], []
    for case in cases:
        generator = torch.Generator().manual_seed(10_000 + case.seed)
        if memory is not None:
            kwargs["memory"] = remembered(case, *memory)
        weights, loss_before, loss_after = learn_sample_weights(
            case.batch.z * scale, probs(case), generator=generator, return_losses=True, **kwargs
        )
        r0, r1 = tied_correlation(case.batch), tied_correlation(case.batch, weights)
        before.append(r0)
        after.append(r1)
        reductions.append(1 - r1 / r0)
        ess.append(effective_sample_size(weights) / len(weights))
        loss_ratio.append(loss_after / loss_before)
    mean = statistics.fmean
    return [
        f"{mean(before):.3f}",
        f"{mean(after):.3f}",
        f"{mean(reductions):.1%} ({min(reductions):.1%})",
        f"{mean(ess):.2f} ({min(ess):.2f})",
        f"{mean(loss_ratio):.2f}",
    ]


def print_table(header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(len(header))]
    for row in [header, ["-" * w for w in widths], *rows]:
        print("| " + " | ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)) + " |")


def decorrelation_table(cases: list[Case]) -> None:
    saliency = lambda case: case.probs  # noqa: E731
    settings: list[tuple[str, Callable[[Case], Tensor | None], dict]] = [
        ("default (saliency p)", saliency, {}),
        ("uniform p (global)", lambda case: None, {}),
        ("paper saliency p (raw, T=1)", lambda case: case.literal_probs, {}),
        ("paper saliency p, logits x 0.1", lambda case: case.quiet_literal_probs, {}),
        ("literal covariance (eq. 5), lr 5", saliency, {"covariance": "literal"}),
        ("literal covariance, lr 0.1", saliency, {"covariance": "literal", "lr": 0.1}),
        ("literal covariance, lr 0.1, 50 iters", saliency, {"covariance": "literal", "lr": 0.1, "iters": 50}),
        ("weighted covariance, 50 iters", saliency, {"iters": 50}),
        ("max_step 1 (a trust region)", saliency, {"max_step": 1.0}),
        ("5 iters, lr 10, max_step 1", saliency, {"iters": 5, "lr": 10.0, "max_step": 1.0}),
        ("paper lr 1e-2", saliency, {"lr": 1e-2}),
        ("lr 1e-2, ess_penalty 0", saliency, {"lr": 1e-2, "ess_penalty": 0.0}),
        ("ess_penalty 0", saliency, {"ess_penalty": 0.0}),
        ("ess_penalty 0.2", saliency, {"ess_penalty": 0.2}),
        ("feature_std None (raw z)", saliency, {"feature_std": None}),
        ("feature_std 1 (unit variance)", saliency, {"feature_std": 1.0}),
        ("no RFF (linear)", saliency, {"use_rff": False}),
    ]
    rows = [[name, *evaluate(cases, probs, **kwargs)] for name, probs, kwargs in settings]
    # The official code's memory of past batches (momentum 0.9), after 10 and 40 earlier batches of the run.
    for n_earlier in (10, 40):
        rows.append([f"memory 0.9, {n_earlier} earlier batches", *evaluate(cases, saliency, memory=(0.9, n_earlier))])
    # Raw states are not squashed; Pearson is scale-free, so only the RFF input changes.
    rows.append(["z x 10 (raw-state scale)", *evaluate(cases, saliency, scale=10.0)])
    rows.append(["z x 10, feature_std None", *evaluate(cases, saliency, scale=10.0, feature_std=None)])
    head = ["setting", r"\|r\| before", r"\|r\| after", "reduction mean (min)", "ESS/n mean (min)", "loss after/before"]
    print_table(head, rows)


def saliency_table(cases: list[Case], d: int) -> None:
    """Where feature_probabilities puts the mass, for classifiers of different confidence."""
    # SGFD starts reweighting as soon as the classifier's accuracy passes 0.9.
    early = {
        case.seed: train_domain_classifier(
            case.train_z, case.train_domains, steps=300, seed=case.seed, stop_accuracy=0.9
        )
        for case in cases
    }
    classifiers: list[tuple[str, Callable[[Case], nn.Module]]] = [
        ("trained (300 steps)", lambda case: case.classifier),
        ("trained, logits x 0.1", lambda case: ScaledLogits(case.classifier, 0.1)),
        ("early (stopped at accuracy 0.9)", lambda case: early[case.seed]),
    ]
    rows = []
    for label, get_classifier in classifiers:
        for name, kwargs in (
            ("default", {}),
            ("paper (raw, T=1)", {"temperature": 1.0, "normalize": False, "smoothing": 0.0}),
        ):
            top_first, p_top, p_tied, accuracy, max_saliency = [], [], [], [], []
            for case in cases:
                batch, classifier = case.batch, get_classifier(case)
                probs = feature_probabilities(classifier, batch.z, **kwargs)
                accuracy.append(classifier_accuracy(classifier, batch.z, batch.domains))
                max_saliency.append(saliency_map(classifier, batch.z).max().item())
                top_first.append(float(int(probs.argmax()) == batch.top))
                p_top.append(probs[batch.top].item())
                p_tied.append(probs[batch.tied].mean().item())
            rows.append(
                [
                    label,
                    f"{statistics.fmean(accuracy):.2f}",
                    f"{statistics.fmean(max_saliency):.2f}",
                    name,
                    f"{statistics.fmean(top_first):.0%}",
                    f"{statistics.fmean(p_top):.3f}",
                    f"{statistics.fmean(p_tied):.3f}",
                    f"{1 / d:.3f}",
                ]
            )
    header = ["classifier", "accuracy", "max saliency", "p", "top ranked 1st", "p_top", "p_tied", "uniform 1/d"]
    print_table(header, rows)


# The solver's default next to fewer, longer steps (one matches the default on the synthetic batches above),
# with and without a trust region on the logits (max_step).
STATE_SETTINGS: list[tuple[str, dict]] = [
    ("default (10 iterations, lr 5)", {}),
    ("4 iterations, lr 17, ess_penalty 0.42", {"iters": 4, "lr": 17.0, "ess_penalty": 0.42}),
    ("5 iterations, lr 8", {"iters": 5, "lr": 8.0}),
    ("default, max_step 1", {"max_step": 1.0}),
    ("5 iterations, lr 10, max_step 1", {"iters": 5, "lr": 10.0, "max_step": 1.0}),
    ("6 iterations, lr 8, max_step 1", {"iters": 6, "lr": 8.0, "max_step": 1.0}),
]


def real_states(env_id: str, steps_per_domain: int):
    """Random-action states of the id's training domains with the varied parameter appended (sgfd-zoo
    correlation-study's sample), standardised; a DomainClassifier trained to the 0.9 threshold on them; the columns
    other than the parameter's; and a shuffled order of the rows (batches of 128 are taken in it)."""
    with gym.make(env_id, obs_type="state") as env:
        n_state = len(state_names(env, env_id))
    sample = collect_states(env_id, steps_per_domain=steps_per_domain, n_state_features=n_state)
    z_all, domains = standardised_sample(sample)
    generator = torch.Generator().manual_seed(0)
    classifier, _ = correlation_classifier(z_all, domains, int(domains.max()) + 1, N_BATCH, generator)
    others = [column for column in range(z_all.shape[1]) if column != sample.changed]
    return sample, z_all, classifier, others, torch.randperm(len(z_all), generator=generator)


def state_table(env_id: str, steps_per_domain: int = 1000) -> None:
    """The same solver on real states: random-action states of the id's training domains with the varied
    parameter appended (sgfd-zoo correlation-study's sample, every state entry), a DomainClassifier trained
    to the 0.9 threshold on them, then the weights of each batch of 128. Reported: the mean |r| between the
    parameter and the other features, its reduction, and ESS / n, over the batches (mean and worst)."""
    sample, z_all, classifier, others, order = real_states(env_id, steps_per_domain)
    rows = []
    for name, kwargs in STATE_SETTINGS:
        before, reductions, ess = [], [], []
        for index in range(len(z_all) // N_BATCH):
            z = z_all[order[index * N_BATCH : (index + 1) * N_BATCH]]
            weights = learn_sample_weights(
                z, feature_probabilities(classifier, z), generator=torch.Generator().manual_seed(index), **kwargs
            )
            r0 = weighted_pearson(z)[sample.changed, others].abs().mean().item()
            r1 = weighted_pearson(z, weights)[sample.changed, others].abs().mean().item()
            before.append(r0)
            reductions.append(1 - r1 / r0)
            ess.append(effective_sample_size(weights) / N_BATCH)
        rows.append(
            [
                name,
                f"{statistics.fmean(before):.3f}",
                f"{statistics.fmean(reductions):.1%} ({min(reductions):.1%})",
                f"{statistics.fmean(ess):.2f} ({min(ess):.3f})",
            ]
        )
    print(f"\n## {env_id}: {len(z_all) // N_BATCH} batches of real states, d = {z_all.shape[1]}\n")
    print_table(["setting", r"\|r\| before", "reduction mean (worst)", "ESS/n mean (worst)"], rows)


# (label, reading, solver settings): the paper reading from its default towards uniform weights, then the
# official reading from its default towards stronger weights.
STRENGTHS: list[tuple[str, str, dict]] = [
    ("paper, ess_penalty 0.35 (default)", "paper", {}),
    ("paper, ess_penalty 0.7", "paper", {"ess_penalty": 0.7}),
    ("paper, ess_penalty 1.5, max_step 1 (sgfd_sac_moderate)", "paper", {"ess_penalty": 1.5, "max_step": 1.0}),
    ("paper, ess_penalty 3, max_step 1", "paper", {"ess_penalty": 3.0, "max_step": 1.0}),
    ("paper, ess_penalty 6, max_step 1", "paper", {"ess_penalty": 6.0, "max_step": 1.0}),
    ("official, penalty 5 (default)", "official", {}),
    ("official, penalty 1", "official", {"ess_penalty": 1.0}),
    ("official, penalty 0.2", "official", {"ess_penalty": 0.2}),
]
N_EARLIER = 10  # batches the official reading's memory has seen before the measured one


def strength_weights(reading: str, z: Tensor, probs: Tensor, earlier: list[Tensor], seed: int, **settings) -> Tensor:
    """One reading's weights of the batch z, given p; the official reading's memory first solves ``earlier``."""
    generator = torch.Generator().manual_seed(10_000 + seed)
    if reading == "paper":
        return learn_sample_weights(z, probs, generator=generator, **settings)
    memory = WeightMemory(0.9)
    for index, batch in enumerate(earlier):
        solve_official_weights(batch, probs, memory=memory, generator=torch.Generator().manual_seed(index), **settings)
    return solve_official_weights(z, probs, memory=memory, generator=generator, **settings)[0]


def official_probs(train_z: Tensor, train_domains: Tensor, z: Tensor, seed: int, rounds: int = 100) -> Tensor:
    """p from the official reading's own classifier, trained its way (SGD 0.01 on the cross-entropy of its softmax
    output, rounds of 10 steps on 640 samples while a batch's accuracy is below 0.8): guided backprop, T = 1."""
    torch.manual_seed(seed)
    classifier = DomainClassifier(z.shape[1], N_DOMAINS, orthogonal=True)
    optimizer = torch.optim.SGD(classifier.parameters(), lr=0.01, momentum=0.9, weight_decay=1e-4)
    generator = torch.Generator().manual_seed(seed)
    for _ in range(rounds):
        index = torch.randint(len(train_z), (N_BATCH,), generator=generator)
        if classifier_accuracy(classifier, train_z[index], train_domains[index]) >= 0.8:
            break
        for _ in range(10):
            index = torch.randint(len(train_z), (5 * N_BATCH,), generator=generator)
            loss = torch.nn.functional.cross_entropy(classifier.probabilities(train_z[index]), train_domains[index])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    return torch.softmax(classifier.guided_saliency(z).abs().mean(dim=0), dim=0)


def strength_rows(batches: list[tuple[Tensor, Tensor, list[Tensor], Callable[[Tensor], float]]]) -> list[list[str]]:
    """The curve's rows over ``batches`` of (z, p, earlier batches, |r| of the domain feature under weights)."""
    rows = []
    for label, reading, settings in STRENGTHS:
        cuts, ess, largest = [], [], []
        for seed, (z, probs, earlier, correlation) in enumerate(batches):
            weights = strength_weights(reading, z, probs, earlier, seed, **settings)
            cuts.append(1 - correlation(weights) / correlation(torch.ones(len(z))))
            ess.append(effective_sample_size(weights) / len(weights))
            largest.append(weights.max().item())
        mean = statistics.fmean
        rows.append(
            [
                label,
                f"{mean(cuts):.1%} ({min(cuts):.1%})",
                f"{mean(ess):.2f} ({min(ess):.2f})",
                f"{mean(largest):.2f}",
            ]
        )
    return rows


STRENGTH_HEADER = ["reading, setting", r"\|r\| cut mean (worst)", "ESS/n mean (min)", "largest weight"]


def strength_table(cases: list[Case]) -> None:
    """The strength curve on the synthetic batches (each case's p), and the official reading with its own p."""
    batches = [
        (
            case.batch.z,
            case.probs,
            [case.train_z[i * N_BATCH : (i + 1) * N_BATCH] for i in range(N_EARLIER)],
            lambda weights, case=case: tied_correlation(case.batch, weights),
        )
        for case in cases
    ]
    rows = strength_rows(batches)
    cuts, ess = [], []
    for seed, case in enumerate(cases):
        probs = official_probs(case.train_z, case.train_domains, case.batch.z, case.seed)
        earlier = batches[seed][2]
        weights = strength_weights("official", case.batch.z, probs, earlier, seed)
        cuts.append(1 - tied_correlation(case.batch, weights) / tied_correlation(case.batch))
        ess.append(effective_sample_size(weights) / N_BATCH)
    mean = statistics.fmean
    rows.append(
        ["official, its own p (guided backprop)", f"{mean(cuts):.1%} ({min(cuts):.1%})", f"{mean(ess):.2f}", ""]
    )
    print_table(STRENGTH_HEADER, rows)


def strength_state_table(env_id: str, steps_per_domain: int = 1000, n_batches: int = 12) -> None:
    """The strength curve on real states (as ``state_table``: random-action states of the training domains, the
    varied parameter's |r| with the other features), the first ``n_batches`` batches of 128."""
    sample, z_all, classifier, others, order = real_states(env_id, steps_per_domain)
    chunks = [z_all[order[i * N_BATCH : (i + 1) * N_BATCH]] for i in range(len(z_all) // N_BATCH)]

    def correlation_of(z: Tensor) -> Callable[[Tensor], float]:
        return lambda weights: weighted_pearson(z, weights)[sample.changed, others].abs().mean().item()

    batches = [
        (z, feature_probabilities(classifier, z), chunks[index + 1 : index + 1 + N_EARLIER], correlation_of(z))
        for index, z in enumerate(chunks[:n_batches])
    ]
    print(f"\n## strength on {env_id}: {n_batches} batches of real states, d = {z_all.shape[1]}\n")
    print_table(STRENGTH_HEADER, strength_rows(batches))


def median_ms(fn: Callable[[], object], repeats: int = 50) -> float:
    for _ in range(5):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def product_multiply_adds(rows: int, channels: int, block: int, steps: int) -> int:
    """Multiply-adds of a solve's matrix products: per step one covariance and one gradient, each rows x D^2,
    for ``channels`` separate covariances of D = ``block`` columns."""
    return steps * 2 * channels * rows * block**2


def timing_table() -> None:
    d = 50
    # The paper reading: one (d m x d m) covariance of the batch per step; the official one: 2 m separate (d x d)
    # covariances of the batch and its batch-sized memory per epoch, m the RFF functions of the calls timed below.
    # Exact solvers cannot do less, so this ratio is a floor.
    paper_macs = product_multiply_adds(N_BATCH, 1, d * PAPER_SOLVER["n_rff"], PAPER_SOLVER["iters"])
    official_macs = product_multiply_adds(2 * N_BATCH, 2 * OFFICIAL_SOLVER["n_rff"], d, OFFICIAL_SOLVER["iters"])
    z = torch.tanh(torch.randn(N_BATCH, d, generator=torch.Generator().manual_seed(0)))
    classifier = DomainClassifier(d, N_DOMAINS)
    probs = feature_probabilities(classifier, z)
    generator = torch.Generator().manual_seed(0)
    memory = WeightMemory(0.9)
    solve_official_weights(z, probs, memory=memory, generator=generator)
    default_threads = torch.get_num_threads()
    rows = []
    for threads in sorted({1, default_threads}):
        torch.set_num_threads(threads)
        rows.append(
            [
                "learn_sample_weights(n=128, d=50, m=5, iters=10)",
                str(threads),
                f"{median_ms(lambda: learn_sample_weights(z, probs, generator=generator)):.2f}",
            ]
        )
        rows.append(
            [
                "feature_probabilities(n=128, d=50)",
                str(threads),
                f"{median_ms(lambda: feature_probabilities(classifier, z)):.2f}",
            ]
        )
        paper_ms = median_ms(lambda: solve_weights(z, probs, generator=generator, **PAPER_SOLVER))
        official_ms = median_ms(
            lambda: solve_official_weights(
                z, probs, memory=memory, update_memory=False, generator=generator, **OFFICIAL_SOLVER
            )
        )
        rows.append(["the paper reading's solve (its defaults, as SGFD_SAC runs it)", str(threads), f"{paper_ms:.2f}"])
        rows.append(
            [
                f"the official reading's solve (20 epochs, batch and memory): {official_ms / paper_ms:.2f}x",
                str(threads),
                f"{official_ms:.2f}",
            ]
        )
    torch.set_num_threads(default_threads)
    print_table(["call (CPU)", "threads", "median ms"], rows)
    print(
        f"\nmultiply-adds of the solves' matrix products: paper {paper_macs / 1e6:.0f}M, official "
        f"{official_macs / 1e6:.0f}M ({official_macs / paper_macs:.2f}x, the least any exact official solve costs "
        "at equal arithmetic speed)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--dims", type=int, nargs="+", default=[10, 50])
    parser.add_argument("--tie-noise", type=float, default=0.8)
    parser.add_argument(
        "--state-ids",
        nargs="*",
        default=["SGFD/MT-walker-walk-v0", "SGFD/MT-cheetah-run-v0", "SGFD/MT-finger-spin-v0"],
        help="ids whose real states the solver settings also run on (none: skip)",
    )
    parser.add_argument("--only-strength", action="store_true", help="only the strength curve and the timing")
    args = parser.parse_args()
    for d in args.dims:
        cases = [Case(d, seed, args.tie_noise) for seed in range(args.seeds)]
        print(f"\n## d = {d}, n = {N_BATCH}, {args.seeds} seeds, tie noise {args.tie_noise}\n")
        if not args.only_strength:
            decorrelation_table(cases)
            print()
            saliency_table(cases, d)
            print()
        print(f"### strength: cut against ESS, both readings (d = {d})\n")
        strength_table(cases)
    for env_id in args.state_ids:
        if not args.only_strength:
            state_table(env_id)
        strength_state_table(env_id)
    print("\n## timing\n")
    timing_table()


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
