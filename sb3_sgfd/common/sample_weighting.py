"""What a per-sample weighting of the losses adds to SAC (SGFD's), as a part of the training loop, the way a
representation objective is one (:mod:`sb3_sgfd.common.representation`).

``EncoderSAC`` holds at most one :class:`SampleWeighting` (``model.weighting``) and calls it at three points of each
gradient step, so that any weighting combines with any encoder objective without a copy of the loop:

- ``plan``: its decisions for the step that need the host (a captured step replays one graph per plan);
- ``before_step``: its work that needs the host before the step (fresh batches, a decision read from the device);
- ``loss_weights``: the weights (n, 1) of the critic's and of the actor's per-sample losses, from the critic's
  (detached) features of the batch; the step multiplies the losses by them.

Both calls get the step's :class:`~sb3_sgfd.common.update_runner.UpdateRunner`: pieces to run as captured work, and
whether a decision inside the step must be a tensor (captured steps) or may be a Python branch.

The weighting owns its models, optimisers, generators and state, all saved with the model; it sees the algorithm
through :class:`WeightingAgent`, the part of it that it may use.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import torch as th
from torch import Tensor

from sb3_sgfd.common.tensor_state import TensorStateModule
from sb3_sgfd.common.update_runner import UpdateRunner


class LossWeights(NamedTuple):
    """The weights of one batch's per-sample losses, (n, 1) each; None: that loss is unweighted (SAC's).

    :param critic: weights of the critic's loss
    :param actor: weights of the actor's loss
    """

    critic: Tensor | None = None
    actor: Tensor | None = None


class WeightingAgent(Protocol):
    """What a sample weighting may use of the algorithm it weights (``EncoderSAC`` is one)."""

    num_timesteps: int
    #: the replay buffer (a domain buffer: ``sample``, ``stored_domains``)
    replay_buffer: Any

    def encode(self, observations: Tensor) -> Tensor:
        """The critic's encoder features of a batch of observations, without gradient."""
        ...

    def augment(self, observations: Tensor) -> list[Tensor]:
        """The algorithm's random-shift views of a batch (the batch itself without augmentation)."""
        ...

    def fresh_batch(self, name: str, n_samples: int) -> Any:
        """Another replay batch of ``n_samples`` (through the static inputs ``name`` when captured)."""
        ...

    def record(
        self, key: str, value: float | Tensor, check_finite: str | None = None, when: Tensor | None = None
    ) -> None:
        """Log a figure of this gradient step (``when``: only where that 0-d bool tensor is true)."""
        ...


class SampleWeighting(TensorStateModule):
    """Base class of the sample weightings; a subclass overrides what it adds (here: nothing, SAC's unweighted
    losses). Its ``state_dict`` (modules, and the tensors of ``state_tensors``) is saved with the model."""

    def plan(self, agent: WeightingAgent, update_index: int, update_actor: bool) -> tuple:
        """The decisions for the update ``update_index`` that the weighting's Python code branches on (empty: it does
        nothing at this step).

        :param agent: the algorithm
        :param update_index: index of the gradient step over the whole run
        :param update_actor: whether the actor learns at this step
        """
        return ()

    def before_step(
        self, agent: WeightingAgent, runner: UpdateRunner, replay_data: Any, observations: list[Tensor], plan: tuple
    ) -> None:
        """What the weighting does before the step where it needs the host.

        :param agent: the algorithm
        :param runner: the runner of the step (pieces to run as captured work, whether decisions must be masks)
        :param replay_data: the step's replay batch
        :param observations: its augmented views (the first is the one the weights are computed on)
        :param plan: what :meth:`plan` returned for this step
        """

    def loss_weights(
        self, agent: WeightingAgent, runner: UpdateRunner, replay_data: Any, z: Tensor, plan: tuple
    ) -> LossWeights:
        """The weights of this batch's critic and actor losses (inside the step: on a captured step, what this
        computes is part of the step's graph).

        :param agent: the algorithm
        :param runner: the runner of the step (whether decisions must be masks: :attr:`UpdateRunner.masked`)
        :param replay_data: the step's replay batch (with its domain labels)
        :param z: the critic's detached encoder features of the first view, (n, d)
        :param plan: what :meth:`plan` returned for this step
        """
        return LossWeights()

    def optimizer_names(self) -> list[str]:
        """Attributes holding this weighting's optimisers (saved and loaded with the model)."""
        return [name for name, value in vars(self).items() if isinstance(value, th.optim.Optimizer)]

    def generators(self) -> dict[str, th.Generator]:
        """The generators it draws from, by name (a checkpoint saves their states)."""
        return {}

    def state_tensors(self) -> dict[str, Tensor]:
        return {}

    def load_state_tensors(self, tensors: dict[str, Tensor]) -> None:
        """Nothing beyond the modules' own state here."""
