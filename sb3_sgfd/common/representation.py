"""What an encoder objective (DBC, AMBS, TED, SGQN) adds to SAC, as a part that ``Agent`` runs.

A representation objective owns its models (a dynamics model, a temporal classifier, an attribution decoder)
and their optimisers. ``Agent.train`` calls it at two points, so that any objective combines with any
sample weighting (SGFD) without a copy of the training loop:

- ``critic_loss``: a term added to the critic's loss (SGQN's consistency);
- ``update``: its own optimisation step, right after the critic's (DBC, AMBS, TED, SGQN's predictor).

Objectives register under a name (``@register("ambs")``), the value of ``Agent(representation=...)``.
They see the algorithm through :class:`Agent`, the part of it they may use, as SB3's policies never import
their algorithm.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple, Protocol

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.sac.policies import Actor, SACPolicy
from torch import nn


class Agent(Protocol):
    """What an objective may use of the algorithm it trains with (``Agent`` is one)."""

    #: the critic: its encoder (``features_extractor``, shared with the actor) and Q heads
    critic: ContinuousCritic
    critic_target: ContinuousCritic
    #: the actor: a DetachedEncoderActor whenever an objective runs (EncoderSAC then requires a SharedEncoderPolicy)
    actor: Actor
    observation_space: spaces.Space
    action_space: spaces.Space
    gamma: float
    augmentation_views: int
    augmentation_pad: int

    def preprocess(self, observations: th.Tensor) -> th.Tensor:
        """Observations as the buffer returns them, as the encoder takes them (images scaled to [0, 1])."""
        ...

    def augment(self, observations: th.Tensor) -> list[th.Tensor]:
        """The algorithm's random-shift views of a batch (the batch itself without augmentation)."""
        ...

    def record(self, key: str, value: float | th.Tensor) -> None:
        """Log a figure of this gradient step."""
        ...


REPRESENTATIONS: dict[str, type[Representation]] = {}


class Batch(NamedTuple):
    """One gradient step's data as the objectives see it.

    :param replay_data: the replay samples (``DomainReplayBufferSamples``)
    :param observations: the observation views the critic trained on (augmented; the first is the actor's)
    :param next_observations: the next-observation views of the critic's target
    :param plan: the objective's own decisions for this step (what :meth:`Representation.plan` returned)
    """

    replay_data: Any
    observations: list[th.Tensor]
    next_observations: list[th.Tensor]
    plan: tuple = ()


class Representation(nn.Module):
    """Base class of the encoder objectives; subclasses take their hyperparameters as keyword arguments and
    override what they add."""

    name: ClassVar[str] = ""
    #: The objective needs the replay buffer to return ``same_episode_observations`` (TED).
    needs_same_episode: ClassVar[bool] = False
    #: The usual policy names mapped to the policies this objective trains (``AMBS("CnnPolicy", env)``).
    policy_aliases: ClassVar[dict[str, type[SACPolicy]]] = {}
    #: The objective's own random stream, seeded from the model's seed by ``EncoderSAC`` before ``setup``.
    generator: th.Generator

    def setup(self, model: Agent) -> None:
        """Build the models and optimisers once the SAC model exists.

        :param model: the algorithm (its policy, action space and device are set)
        """

    def plan(self, update_index: int) -> tuple:
        """The objective's decisions for the update ``update_index`` that its Python code branches on (e.g. whether
        a part learns at this step): a captured update replays one graph per distinct plan, so every such branch
        must read its decision from ``Batch.plan``, not from the update's index.

        :param update_index: index of the gradient step over the whole run
        """
        return ()

    def critic_loss(
        self, model: Agent, observations: th.Tensor, actions: th.Tensor, q_values: tuple[th.Tensor, ...]
    ) -> th.Tensor | None:
        """A term added to the critic's loss, or None.

        :param model: the algorithm
        :param observations: the critic's (first) observation view
        :param actions: the replay actions
        :param q_values: the critic's Q-values of that view, one tensor per head
        """
        return None

    def update(self, model: Agent, batch: Batch) -> dict[str, th.Tensor]:
        """The objective's own step, after the critic's; returns figures to log (scalars, kept on device).

        :param model: the algorithm
        :param batch: this step's data
        """
        return {}

    def optimizer_names(self) -> list[str]:
        """Attributes holding this objective's optimisers (saved and loaded with the model)."""
        return [name for name, value in vars(self).items() if isinstance(value, th.optim.Optimizer)]


def register(name: str) -> Callable[[type[Representation]], type[Representation]]:
    """Class decorator: make an objective available as ``Agent(representation=name)``.

    :param name: the objective's name, e.g. ``"ambs"``
    """

    def decorate(cls: type[Representation]) -> type[Representation]:
        if name in REPRESENTATIONS and REPRESENTATIONS[name] is not cls:
            raise ValueError(f"representation {name!r} is registered twice")
        cls.name = name
        REPRESENTATIONS[name] = cls
        return cls

    return decorate


def make_representation(name: str | None, kwargs: dict[str, Any] | None) -> Representation | None:
    """The objective registered as ``name`` with its hyperparameters; None for no objective.

    :param name: a registered name, or None
    :param kwargs: its hyperparameters
    """
    if name is None:
        if kwargs:
            raise ValueError(f"representation_kwargs {kwargs} given without a representation")
        return None
    if name not in REPRESENTATIONS:
        raise ValueError(f"representation must be None or one of {sorted(REPRESENTATIONS)}, got {name!r}")
    try:
        return REPRESENTATIONS[name](**(kwargs or {}))
    except TypeError as error:
        raise ValueError(f"representation_kwargs for {name!r}: {error}") from None


def set_up_representation(objective: Representation, model: Agent, seed: int) -> None:
    """Build ``objective``'s models for ``model`` (:meth:`Representation.setup`) from a generator of its own seeded
    by ``seed``, as is its random stream afterwards: SAC's random streams stay those of SB3's SAC.

    :param objective: the objective, made by :func:`make_representation`
    :param model: the algorithm (its policy, action space and device are set)
    :param seed: the objective's seed, derived from the model's
    """
    device = next(model.critic.parameters()).device
    objective.generator = th.Generator(device=device).manual_seed(seed)
    with th.random.fork_rng(devices=[]):  # the CPU generator: CUDA streams stay SAC's
        th.random.default_generator.manual_seed(seed)
        objective.setup(model)
    objective.to(device)


def step(loss: th.Tensor, *optimizers: th.optim.Optimizer) -> None:
    """One backward pass of ``loss`` and a step of each optimiser.

    :param loss: the objective's loss
    :param optimizers: the optimisers of every parameter it trains
    """
    for optimizer in optimizers:
        optimizer.zero_grad()
    loss.backward()
    for optimizer in optimizers:
        optimizer.step()
