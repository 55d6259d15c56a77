"""SGFD's settings in one typed object: what ``SGFD_SAC``'s keyword arguments (the zoo's yaml) set, checked once
where they enter, and read by the weightings.

Two readings give the defaults: the paper's (:meth:`SGFDSettings.paper`, Algorithm 1 and eqs. 3-7 with this
package's measured choices) and the authors' code's (:meth:`SGFDSettings.official`, what produced the published
numbers). A new setting is a field here (with its line in the docstring) and a keyword of ``SGFD_SAC``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, TypedDict

from sb3_sgfd.common.validation import (
    check_bool,
    check_choice,
    check_interval,
    check_non_negative,
    check_non_negative_int,
    check_optional_positive,
    check_positive,
    check_positive_int,
)

READINGS = ("paper", "official")

#: Where the code's reading differs from the paper's; every other setting is the same in both.
_OFFICIAL: dict[str, Any] = {
    "classifier_iters": 10,
    # the code trains its classifier every 20 env steps at one update per 5 env steps: every 4th update
    "classifier_interval": 4,
    "accuracy_threshold": 0.8,
    "classifier_lr": 0.01,
    "reweight_iters": 20,
    "reweight_lr": 1.0,
    "reweight_weight_decay": 0.0,
    "reweight_ess_penalty": 5.0,
    "reweight_memory": 0.9,
    "saliency_temperature": 1.0,
    "saliency_smoothing": 0.0,
    "reweight_critic": False,
}


@dataclass(frozen=True)
class SGFDSettings:
    """
    The settings of SGFD's sample weights. The defaults are the paper reading's; :meth:`official` gives the
    code's (marked o below where they differ), :meth:`of_reading` a reading's with some settings changed.

    :param reading: ``"paper"`` (:class:`sb3_sgfd.sgfd.weighting.PaperWeighting`) or ``"official"``
        (:class:`sb3_sgfd.sgfd.weighting.OfficialWeighting`)
    :param classifier_start: Env steps before the domain classifier starts training
    :param classifier_iters: (o 10) Classifier updates per classifier round (paper: at most, the first on this
        batch's features, the others on fresh replay batches, Algorithm 1's 10; official: steps on fresh
        batches of 5 x ``batch_size``)
    :param classifier_interval: (o 4) A classifier round every this many gradient steps
    :param accuracy_threshold: (o 0.8) Classifier accuracy below which it trains (paper: and at which the weights
        start)
    :param classifier_hidden_dim: Width of the classifier's two hidden layers
    :param classifier_lr: (o 0.01 SGD) Learning rate of the classifier (paper reading: Adam)
    :param n_rff: Random Fourier functions per latent feature
    :param reweight_iters: (o 20) Steps of the weight solver per batch
    :param reweight_lr: (o 1 then 0.1) Learning rate of the weight solver (the paper's table prints 1e-2, its
        classifier's; see :func:`sb3_sgfd.sgfd.decorrelation.learn_sample_weights`)
    :param reweight_momentum: Momentum of the weight solver
    :param reweight_weight_decay: (o 0) Weight decay of the weight solver
    :param reweight_ess_penalty: (o 5) How strongly the weights are kept near uniform, the strength knob (paper:
        penalty on n / ESS - 1; official: weight of log sum w^2); higher is weaker
    :param reweight_memory: (o 0.9) Momentum of a memory of past batches the solver also decorrelates against
        (:class:`sb3_sgfd.sgfd.decorrelation.WeightMemory`); None: no memory
    :param reweight_max_step: Largest change of any weight logit in one solver step, a trust region; None:
        unbounded, as in the paper and the code
    :param saliency_temperature: (o 1 of the raw saliency) Softmax temperature giving p(Z_i) (paper reading: of
        the max-normalised saliency)
    :param saliency_smoothing: (o 0) Weight of the uniform distribution mixed into p(Z_i)
        (:func:`sb3_sgfd.sgfd.functional.feature_probabilities`)
    :param use_rff: Decorrelate random Fourier features (False: the features themselves, linear only)
    :param use_saliency: Weight feature pairs by the classifier's saliency (False: uniform, global decorrelation)
    :param reweight_critic: (o False) Apply the weights to the critic loss
    :param reweight_actor: Apply the weights to the actor loss
    """

    reading: str = "paper"
    classifier_start: int = 100_000
    classifier_iters: int = 1
    classifier_interval: int = 1
    accuracy_threshold: float = 0.9
    classifier_hidden_dim: int = 128
    classifier_lr: float = 1e-3
    n_rff: int = 5
    reweight_iters: int = 10
    reweight_lr: float = 5.0
    reweight_momentum: float = 0.9
    reweight_weight_decay: float = 1e-4
    reweight_ess_penalty: float = 0.35
    reweight_memory: float | None = None
    reweight_max_step: float | None = None
    saliency_temperature: float = 0.1
    saliency_smoothing: float = 0.3
    use_rff: bool = True
    use_saliency: bool = True
    reweight_critic: bool = True
    reweight_actor: bool = True

    def __post_init__(self) -> None:
        check_choice("reading", self.reading, READINGS)
        check_positive_int(
            classifier_hidden_dim=self.classifier_hidden_dim,
            n_rff=self.n_rff,
            classifier_interval=self.classifier_interval,
        )
        check_non_negative_int(
            classifier_start=self.classifier_start,
            classifier_iters=self.classifier_iters,
            reweight_iters=self.reweight_iters,
        )
        check_interval("accuracy_threshold", self.accuracy_threshold, 0.0, 1.0, low_open=True)
        check_positive(
            classifier_lr=self.classifier_lr,
            reweight_lr=self.reweight_lr,
            saliency_temperature=self.saliency_temperature,
        )
        check_non_negative(
            reweight_weight_decay=self.reweight_weight_decay, reweight_ess_penalty=self.reweight_ess_penalty
        )
        check_interval("reweight_momentum", self.reweight_momentum, 0.0, 1.0, high_open=True)
        check_interval("saliency_smoothing", self.saliency_smoothing, 0.0, 1.0)
        if self.reweight_memory is not None:
            check_interval("reweight_memory", self.reweight_memory, 0.0, 1.0, high_open=True, also="False")
        check_optional_positive("reweight_max_step", self.reweight_max_step)
        check_bool(
            use_rff=self.use_rff,
            use_saliency=self.use_saliency,
            reweight_critic=self.reweight_critic,
            reweight_actor=self.reweight_actor,
        )

    @classmethod
    def paper(cls, **settings: Any) -> SGFDSettings:
        """The paper reading's settings, with ``settings`` over them."""
        return cls.of_reading("paper", **settings)

    @classmethod
    def official(cls, **settings: Any) -> SGFDSettings:
        """The authors' code's settings, with ``settings`` over them."""
        return cls.of_reading("official", **settings)

    @classmethod
    def of_reading(cls, reading: str = "paper", **settings: Any) -> SGFDSettings:
        """The settings of ``reading`` with ``settings`` over them: a value of None stands for the reading's own,
        and ``reweight_memory=False`` for no memory (as ``SGFD_SAC``'s keywords take them).

        :param reading: ``"paper"`` or ``"official"``
        :param settings: any fields of :class:`SGFDSettings` but ``reading``
        """
        check_choice("reading", reading, READINGS)
        names = setting_names()
        unknown = sorted(set(settings) - set(names))
        if unknown:
            raise ValueError(f"unknown SGFD setting(s) {unknown}; the settings are {names}")
        given = {name: value for name, value in settings.items() if value is not None}
        if given.get("reweight_memory") is False:
            given["reweight_memory"] = None
        defaults = _OFFICIAL if reading == "official" else {}
        return cls(reading=reading, **{**defaults, **given})

    @classmethod
    def taken_from(cls, reading: str | None, sgfd: SGFDSettings | None, keywords: dict[str, Any]) -> SGFDSettings:
        """The settings an ``SGFD_SAC`` is given: ``sgfd`` whole, or the reading's with the settings among
        ``keywords`` over it. The settings are taken out of ``keywords`` (what remains is EncoderSAC's).

        :param reading: ``"paper"`` or ``"official"``; None: ``sgfd``'s, else the paper's
        :param sgfd: all the settings as one object (then no setting may be among ``keywords``)
        :param keywords: keyword arguments, some of them settings (each a field of :class:`SGFDSettings`)
        """
        given = {name: keywords.pop(name) for name in setting_names() if name in keywords}
        if sgfd is None:
            return cls.of_reading(reading or "paper", **given)
        if not isinstance(sgfd, SGFDSettings):
            raise ValueError(f"sgfd must be an SGFDSettings, got {type(sgfd).__name__}")
        clashing = sorted(name for name, value in given.items() if value is not None)
        if clashing or reading not in (None, sgfd.reading):
            raise ValueError(f"give SGFD's settings either as sgfd= or as keywords, not both: {clashing or 'reading'}")
        return sgfd

    def solver_settings(self) -> SolverSettings:
        """The weight solver's keywords (both readings' solvers take them), in a new dict."""
        return {
            "n_rff": self.n_rff,
            "iters": self.reweight_iters,
            "lr": self.reweight_lr,
            "momentum": self.reweight_momentum,
            "weight_decay": self.reweight_weight_decay,
            "ess_penalty": self.reweight_ess_penalty,
            "max_step": self.reweight_max_step,
            "use_rff": self.use_rff,
        }


class SolverSettings(TypedDict):
    """The keywords of the readings' weight solvers that the settings give (:meth:`SGFDSettings.solver_settings`)."""

    # In alphabetical order, as a TypedDict's keys have none of their own.
    ess_penalty: float
    iters: int
    lr: float
    max_step: float | None
    momentum: float
    n_rff: int
    use_rff: bool
    weight_decay: float


def setting_names() -> list[str]:
    """The names of the settings a reading's defaults can be overridden by (every field but ``reading``)."""
    return [field.name for field in fields(SGFDSettings) if field.name != "reading"]
