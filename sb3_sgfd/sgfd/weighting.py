"""SGFD's sample weights, Algorithm 1 lines 6-17, as the sample weighting of the training loop
(:class:`sb3_sgfd.common.sample_weighting.SampleWeighting`): the domain classifier and its rounds
(:mod:`sb3_sgfd.sgfd.classifier`), the feature probabilities p(Z_i) from its saliency (section 4.2), and the weights
(:mod:`sb3_sgfd.sgfd.decorrelation`), as two readings:

- :class:`PaperWeighting` (``reading="paper"``): Algorithm 1 as printed, with this package's measured choices: from
  ``classifier_start``, a classifier round on every ``classifier_interval``-th update scores the batch and, while
  its accuracy is below ``accuracy_threshold``, trains on it (and on fresh batches); the weights start the first
  time a batch scores at the threshold, and stay on;
- :class:`OfficialWeighting` (``reading="official"``): what the authors' public code computes (SiliHuang-ai/SGFD),
  which produced the published numbers: weights on the actor loss from the first update, its classifier rounds on
  fresh unaugmented batches, guided-backprop saliency, a memory of past batches, an objective that keeps the
  weights near uniform.

Each step: :meth:`SGFDWeighting.plan` (on the host: is SGFD on, is a round due, which loss wants weights),
``before_step`` (the reading's host work: fresh batches; the code reading's round), then
:meth:`SGFDWeighting.loss_weights` inside the step: the reading's ``forward`` gives the weights w (n,), mean 1,
detached, and the critic's loss (Algorithm 1 line 18, reweighted here as the design asks: ``reweight_critic``) and the
actor's (line 19, eq. 8: ``reweight_actor``) take w as :class:`LossWeights`. A step decides on the host (the round
only while below the threshold, the solver only once the weights are on; one host read), except a captured one
(``compile_update`` on CUDA), which keeps every decision a tensor (masks): the same training without a host read.
Pure torch, no Stable-Baselines3 import.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import torch
from torch import Tensor
from torch.nn import functional as F

from sb3_sgfd.common.observations import user_stacklevel
from sb3_sgfd.common.sample_weighting import LossWeights, SampleWeighting, WeightingAgent
from sb3_sgfd.common.update_runner import UpdateRunner
from sb3_sgfd.sgfd.classifier import (
    DomainClassifier,
    accuracy,
    classifier_round,
    masked_classifier_round,
    saliency_probabilities,
)
from sb3_sgfd.sgfd.decorrelation import (
    WeightMemory,
    draw_fourier,
    official_solution,
    paper_solution,
    solve_official_weights,
    solve_weights,
)
from sb3_sgfd.sgfd.settings import SGFDSettings

#: The official reading's classifier batches are this many replay batches' worth of samples (640 at batch 128).
CLASSIFIER_BATCHES = 5
#: The figures of the weights themselves, logged over the steps where the weights are in use.
WEIGHT_FIGURES = ("weight_ess", "weight_min", "weight_max", "decorrelation_loss_before", "decorrelation_loss_after")
SINGLE_DOMAIN_WARNING = (
    "SGFD_SAC sees a single domain, so there is nothing to decorrelate; it trains as plain SAC. Give it "
    "one sub-env per domain, e.g. sgfd_envs.make_domain_vec_env(env_id, split='train')."
)


#: A classifier round's further batches: (features (n, d), domain labels (n,)) pairs
Fresh = Sequence[tuple[Tensor, Tensor]]


class WeightingPlan(NamedTuple):
    """SGFD's decisions for one gradient step (its share of the step's plan).

    :param classifier_round: a classifier round is due
    :param weights_wanted: a loss is weighted at this step (else only the classifier's work is done)
    """

    classifier_round: bool
    weights_wanted: bool


class Weights(NamedTuple):
    """A reading's answer for one batch.

    :param weights: (n,) non-negative weights with mean 1, without grad; None: unweighted at this step
    :param figures: diagnostics to log, 0-d tensors on the device
    :param weighted: 0-d bool, whether the weights are in use (the weight figures count only then); None: in use
    """

    weights: Tensor | None
    figures: dict[str, Tensor]
    weighted: Tensor | None = None


def weight_figures(weights: Tensor, loss_before: Tensor, loss_after: Tensor, probs: Tensor | None) -> dict[str, Tensor]:
    """The figures SGFD logs of a batch's weights, as 0-d tensors."""
    figures = {
        "weight_ess": weights.sum().square() / weights.square().sum() / len(weights),  # Kish's ESS over n
        "weight_min": weights.min(),
        "weight_max": weights.max(),
        "decorrelation_loss_before": loss_before,
        "decorrelation_loss_after": loss_after,
    }
    if probs is not None:
        figures["top_saliency_feature"] = probs.argmax()
    return figures


class SGFDWeighting(SampleWeighting):
    """What the two readings share: settings, classifier, optimiser, memory, the RFF generator, the compiled solver,
    and the slot's calls. A reading implements ``reading_plan``, ``before_step``, ``forward`` and ``solve``.

    :param n_features: dimension d of the features z
    :param n_domains: number of domain labels (the classifier's classes; one: nothing to decorrelate)
    :param settings: SGFD's settings (:class:`sb3_sgfd.sgfd.settings.SGFDSettings`)
    :param seed: seeds the RFF generator once (a checkpoint saves its state)
    :param device: where the classifier and the generator live
    :param compile_solver: run the solver's arithmetic compiled (``torch.compile``: it fuses)
    """

    official: bool = False
    classifier_optimizer: torch.optim.Optimizer

    def __init__(
        self,
        n_features: int,
        n_domains: int,
        settings: SGFDSettings,
        seed: int,
        device: torch.device | str = "cpu",
        compile_solver: bool = False,
    ) -> None:
        super().__init__()
        self.n_features, self.n_domains = n_features, n_domains
        self.settings = settings
        self.solver_settings = settings.solver_settings()
        self.seed = seed
        hidden = settings.classifier_hidden_dim
        self.classifier = DomainClassifier(n_features, max(n_domains, 2), hidden, orthogonal=self.official).to(device)
        self.memory = None if settings.reweight_memory is None else WeightMemory(settings.reweight_memory)
        self.rff_generator = torch.Generator(device=device).manual_seed(seed)
        #: The solver's arithmetic (:func:`paper_solution` or :func:`official_solution`), compiled by
        #: :meth:`compile_solver`.
        self.core: Callable[..., Any] = official_solution if self.official else paper_solution
        if compile_solver:
            self.compile_solver()
        #: Whether the weights are on (the paper's reading waits for its classifier; sticky), a 0-d bool tensor.
        self.ready = torch.tensor(self.official, device=device)
        #: One domain (given, or all the buffer holds when SGFD starts): nothing to decorrelate, SAC's steps.
        self.single_domain = n_domains == 1
        self._domains_checked = False
        #: The paper reading's further classifier batches of this step (sampled before it, encoded inside it).
        self._fresh: list[Any] = []

    def compile_solver(self) -> None:
        """Run the solver's arithmetic through ``torch.compile`` (it fuses; what a captured step on CUDA uses)."""
        self.core = torch.compile(self.core, dynamic=False)

    def active(self, num_timesteps: int) -> bool:
        """Whether the weighting does anything yet (before that, SGFD_SAC is SAC)."""
        return True

    def recheck_domains(self) -> None:
        """The envs give more domain labels now: look at the buffer's again when SGFD next starts."""
        self.single_domain, self._domains_checked = False, False

    def reading_plan(self, update_index: int, num_timesteps: int, weights_wanted: bool) -> WeightingPlan:
        """The reading's decisions for the update ``update_index``."""
        raise NotImplementedError

    def plan(self, agent: WeightingAgent, update_index: int, update_actor: bool) -> tuple:
        """SGFD's decisions for the step; empty (SAC's step) before it starts or with a single domain."""
        if self.single_domain or not self.active(agent.num_timesteps):
            return ()
        if not self._domains_checked:
            # Once, when the weighting starts: stored_domains() reads the whole buffer.
            self._domains_checked = True
            if len(agent.replay_buffer.stored_domains()) < 2:
                warnings.warn(SINGLE_DOMAIN_WARNING, stacklevel=user_stacklevel())
                self.single_domain = True
                return ()
        settings = self.settings
        weights_wanted = settings.reweight_critic or (settings.reweight_actor and update_actor)
        return self.reading_plan(update_index, agent.num_timesteps, weights_wanted)

    def loss_weights(
        self, agent: WeightingAgent, runner: UpdateRunner, replay_data: Any, z: Tensor, plan: tuple
    ) -> LossWeights:
        """The reading's weights of this batch as (n, 1) weights of the critic's and of the actor's losses (None where
        that loss is not reweighted or no weights are in use; the actor's alone are not computed on the steps it
        does not learn), its figures recorded."""
        if not plan:
            return LossWeights()
        fresh = [(agent.encode(agent.augment(batch.observations)[0]), checked(batch.domains)) for batch in self._fresh]
        weights, figures, weighted = self(z, checked(replay_data.domains), plan, fresh, masked=runner.masked)
        for key, value in figures.items():
            agent.record(f"sgfd/{key}", value, when=weighted if key in WEIGHT_FIGURES else None)
        if weights is None:
            return LossWeights()
        runner.figures.keep("sgfd/weights", weights, when=weighted)  # the weights' histogram (TensorBoard)
        weights = weights.reshape(-1, 1)
        settings = self.settings
        return LossWeights(weights if settings.reweight_critic else None, weights if settings.reweight_actor else None)

    def forward(
        self, z: Tensor, domains: Tensor, plan: WeightingPlan, fresh: Fresh = (), masked: bool = True
    ) -> Weights:
        """The weights of one batch, and the classifier's work of this step.

        :param z: the critic's (detached) encoder features of the batch, (n, d)
        :param domains: the batch's domain labels, (n,)
        :param plan: the decisions for this step
        :param fresh: the paper reading's further classifier batches (features, labels)
        :param masked: decide on the device (captured steps); False: Python branches
        """
        raise NotImplementedError

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The reading's weights for features ``z`` with its classifier as it is now, leaving every state as it is
        (the memory is read, not updated): for figures and benchmarks. Returns the weights (n,) with mean 1, and the
        decorrelation loss at uniform weights and at the weights."""
        raise NotImplementedError

    def generators(self) -> dict[str, torch.Generator]:
        return {"weights": self.rff_generator}

    def state_tensors(self) -> dict[str, Tensor]:
        return {} if self.official else {"ready": self.ready.float()}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        if "ready" in tensors:
            self.ready = tensors["ready"].to(self.ready.device) > 0.5

    def _apply(self, fn, recurse=True):  # type: ignore[no-untyped-def]
        self.ready = fn(self.ready)
        return super()._apply(fn, recurse)


def fused_where_supported(classifier: torch.nn.Module) -> bool | None:
    """Whether the classifier's optimiser steps fused (one kernel per step instead of a dozen operators per parameter:
    the same Adam or SGD, rounded otherwise): on the devices whose fused kernels torch has for both (CPU, CUDA); None
    (torch's default) elsewhere."""
    return True if next(classifier.parameters()).device.type in ("cpu", "cuda") else None


def checked(domains: Tensor | None) -> Tensor:
    """A batch's domain labels (their values were checked where they entered: the buffer refuses a label out of
    range)."""
    if domains is None:
        raise ValueError("SGFD_SAC needs replay samples with domain labels (use DomainReplayBuffer)")
    return domains


class PaperWeighting(SGFDWeighting):
    """The paper's reading of SGFD's weights (``SGFD_SAC(reading="paper")``, the default); its settings' defaults
    are :meth:`sb3_sgfd.sgfd.settings.SGFDSettings.paper`. The classifier steps with Adam."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.classifier_optimizer = torch.optim.Adam(
            self.classifier.parameters(),
            lr=self.settings.classifier_lr,
            fused=fused_where_supported(self.classifier),
        )

    def active(self, num_timesteps: int) -> bool:
        return num_timesteps >= self.settings.classifier_start

    def reading_plan(self, update_index: int, num_timesteps: int, weights_wanted: bool) -> WeightingPlan:
        settings = self.settings
        classifier_round = settings.classifier_iters > 0 and update_index % settings.classifier_interval == 0
        return WeightingPlan(classifier_round, weights_wanted)

    def before_step(
        self, agent: WeightingAgent, runner: UpdateRunner, replay_data: Any, observations: list[Tensor], plan: tuple
    ) -> None:
        """A round's further batches (Algorithm 1's up to ``classifier_iters`` updates), sampled for the step to
        encode: sampled whether or not the round trains, so that both ways of deciding draw the same batches."""
        due = bool(plan) and WeightingPlan(*plan).classifier_round
        n = len(replay_data.actions)
        self._fresh = (
            [agent.fresh_batch(f"sgfd fresh {i}", n) for i in range(self.settings.classifier_iters - 1)] if due else []
        )

    def forward(
        self, z: Tensor, domains: Tensor, plan: WeightingPlan, fresh: Fresh = (), masked: bool = True
    ) -> Weights:
        # Line 12's p(Z_i) and the batch's accuracy from one pass of the classifier as it was before this step
        predicted, gradient = self.classifier.predictions_and_input_gradient(z)
        figures = {"classifier_accuracy": accuracy(predicted, domains)}
        if masked:
            return self._masked_forward(z, domains, plan, fresh, gradient, figures)
        # The step's one host read: the batch's accuracy (at the threshold, the round has nothing to train) and whether
        # the weights are on
        batch_accuracy, ready_before = torch.stack([figures["classifier_accuracy"], self.ready.float()]).tolist()
        was_ready = ready = ready_before > 0.5
        threshold = self.settings.accuracy_threshold
        if plan.classifier_round:  # lines 6-13: train while below the threshold; the first time at it, ready
            batches = [(z, domains), *fresh]
            reached = batch_accuracy >= threshold
            if not reached:
                reached = classifier_round(self.classifier, self.classifier_optimizer, batches, threshold, 1)[1]
            if reached and not ready:
                self.ready.fill_(True)
                ready = True
        if not plan.weights_wanted:
            return Weights(None, figures)
        if not ready:
            self._skip_draws(z)  # the draws a masked step would make: the same random stream either way
            return Weights(None, figures)
        probs = None
        if self.settings.use_saliency:  # ready before this step: its p; ready now: the classifier's after the round
            probs = self._probabilities(gradient if was_ready else self.classifier.input_gradient(z))
        weights, before, after = self._solve(z, probs, self.rff_generator, update_memory=True, take=None)
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)})

    def _masked_forward(
        self,
        z: Tensor,
        domains: Tensor,
        plan: WeightingPlan,
        fresh: Fresh,
        gradient: Tensor,
        figures: dict[str, Tensor],
    ) -> Weights:
        """:meth:`forward` with every decision a tensor: the round's steps masked, the solver always run and its
        weights taken where the weights are on."""
        was_ready = self.ready.clone()
        if plan.classifier_round:
            batches = [(z, domains), *fresh]
            reached = masked_classifier_round(
                self.classifier, self.classifier_optimizer, batches, self.settings.accuracy_threshold
            )
            self.ready.copy_(self.ready | reached)  # in place: a captured graph reads and writes it there
        if not plan.weights_wanted:
            return Weights(None, figures)
        probs = None
        if self.settings.use_saliency:
            probs = self._probabilities(gradient)
            if plan.classifier_round:
                probs = torch.where(was_ready, probs, self._probabilities(self.classifier.input_gradient(z)))
        weights, before, after = self._solve(z, probs, self.rff_generator, update_memory=True, take=self.ready)
        weights = torch.where(self.ready, weights, torch.ones_like(weights))  # lines 14-17 once ready
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)}, self.ready)

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        probs = self._probabilities(self.classifier.input_gradient(z)) if self.settings.use_saliency else None
        return self._solve(z, probs, generator, update_memory=False, take=None)

    def _probabilities(self, gradient: Tensor) -> Tensor:
        settings = self.settings
        return saliency_probabilities(
            gradient.abs().mean(dim=0), settings.saliency_temperature, True, settings.saliency_smoothing
        )

    def _skip_draws(self, z: Tensor) -> None:
        if self.settings.use_rff:
            shape = (z.shape[1], self.settings.n_rff)
            draw_fourier(shape, shape, z, self.rff_generator)

    def _solve(
        self,
        z: Tensor,
        probs: Tensor | None,
        generator: torch.Generator | None,
        update_memory: bool,
        take: Tensor | None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        return solve_weights(
            z,
            probs,
            memory=self.memory,
            update_memory=update_memory,
            generator=generator,
            take=take,
            core=self.core,
            **self.solver_settings,
        )


class OfficialWeighting(SGFDWeighting):
    """The authors' code's reading of SGFD's weights (``SGFD_SAC(reading="official")``); its settings' defaults are
    :meth:`sb3_sgfd.sgfd.settings.SGFDSettings.official`. The classifier (orthogonal start) steps with SGD (momentum
    0.9, weight decay 1e-4) on the cross-entropy of its softmax output (a double softmax, as the code)."""

    official = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.classifier_optimizer = torch.optim.SGD(
            self.classifier.parameters(),
            lr=self.settings.classifier_lr,
            momentum=0.9,
            weight_decay=1e-4,
            fused=fused_where_supported(self.classifier),
        )

    def reading_plan(self, update_index: int, num_timesteps: int, weights_wanted: bool) -> WeightingPlan:
        settings = self.settings
        classifier_round = (
            weights_wanted
            and settings.classifier_iters > 0
            and num_timesteps > settings.classifier_start
            and update_index % settings.classifier_interval == 0
        )
        return WeightingPlan(classifier_round, weights_wanted)

    def before_step(
        self, agent: WeightingAgent, runner: UpdateRunner, replay_data: Any, observations: list[Tensor], plan: tuple
    ) -> None:
        """The code's round, before the step: the batch is scored, and below the threshold (the round's one host read)
        the classifier trains on ``classifier_iters`` fresh unaugmented batches of ``CLASSIFIER_BATCHES`` x n."""
        if not plan or not WeightingPlan(*plan).classifier_round:
            return
        domains = checked(replay_data.domains)
        score = runner.run("sgfd score", lambda obs: self.score(agent.encode(obs), domains), observations[0])
        if bool(score < self.settings.accuracy_threshold):
            n = CLASSIFIER_BATCHES * len(replay_data.actions)
            batches = [agent.fresh_batch(f"sgfd round {i}", n) for i in range(self.settings.classifier_iters)]
            runner.run("sgfd round", self.train_round_on, agent, batches)

    def train_round_on(self, agent: WeightingAgent, batches: Sequence[Any]) -> None:
        """:meth:`train_round` on replay batches, encoded by the critic's encoder."""
        self.train_round([(agent.encode(batch.observations), checked(batch.domains)) for batch in batches])

    def score(self, z: Tensor, domains: Tensor) -> Tensor:
        """The classifier's accuracy on a batch (0-d): below the threshold, a round trains it (the host decides)."""
        with torch.no_grad():
            return accuracy(self.classifier(z).argmax(dim=1), domains)

    def train_round(self, batches: Sequence[tuple[Tensor, Tensor]]) -> None:
        """A round's SGD steps, one per fresh batch (features of ``CLASSIFIER_BATCHES`` x the batch size, labels)."""
        for fresh_z, fresh_domains in batches:
            loss = F.cross_entropy(self.classifier.probabilities(fresh_z), fresh_domains)
            self.classifier_optimizer.zero_grad()
            loss.backward()
            self.classifier_optimizer.step()

    def forward(
        self, z: Tensor, domains: Tensor, plan: WeightingPlan, fresh: Fresh = (), masked: bool = True
    ) -> Weights:
        accuracy_now = self.score(z, domains)  # after this step's round, if one trained
        figures = {"classifier_accuracy": accuracy_now}
        if not plan.weights_wanted:
            return Weights(None, figures)
        # the solver runs whatever the accuracy: its memory moves at every step, as the code's
        weights, before, after, probs = self._weights(z, self.rff_generator, update_memory=True)
        # The code reweights whenever the batch's accuracy is above 0 (a tensor choice either way: one where)
        weighted = accuracy_now > 0
        weights = torch.where(weighted, weights, torch.ones_like(weights))
        return Weights(weights, {**figures, **weight_figures(weights, before, after, probs)}, weighted)

    def solve(self, z: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
        weights, before, after, _ = self._weights(z, generator, update_memory=False)
        return weights, before, after

    def feature_probabilities(self, z: Tensor) -> Tensor:
        """p(Z_i) from the guided-backprop saliency of the batch (uniform without saliency): (d,)."""
        if not self.settings.use_saliency:
            return z.new_full((z.shape[1],), 1.0 / z.shape[1])
        saliency = self.classifier.guided_saliency(z).abs().mean(dim=0)
        return saliency_probabilities(
            saliency, self.settings.saliency_temperature, False, self.settings.saliency_smoothing
        )

    def _weights(
        self, z: Tensor, generator: torch.Generator | None, update_memory: bool
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        probs = self.feature_probabilities(z)
        weights, before, after = solve_official_weights(
            z,
            probs,
            memory=self.memory,
            update_memory=update_memory,
            generator=generator,
            core=self.core,
            **self.solver_settings,
        )
        return weights, before, after, (probs if self.settings.use_saliency else None)


#: The weighting of each reading (``SGFDSettings.reading``).
READINGS: dict[str, type[SGFDWeighting]] = {"paper": PaperWeighting, "official": OfficialWeighting}
