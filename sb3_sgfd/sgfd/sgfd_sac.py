"""SGFD_SAC: SAC, on any encoder objective of EncoderSAC, with its losses reweighted per sample by SGFD.

Read beside the paper's Algorithm 1: the training loop is :class:`~sb3_sgfd.common.encoder_sac.EncoderSAC`'s (a marked
twin of SB3's ``SAC.train``); SGFD is its sample weighting, ``model.weighting`` (:mod:`sb3_sgfd.sgfd.weighting`), which
each gradient step asks for the weights of the batch. The critic's loss (line 18) and the actor's (line 19, eq. 8)
take them in ``EncoderSAC._gradient_step``: ``weighted_mean((current_q - target_q_values) ** 2, weights.critic)`` and
``weighted_mean(ent_coef * log_prob - min_qf_pi, weights.actor)``. The weights come from the domain classifier and its
saliency (lines 6-13, :mod:`sb3_sgfd.sgfd.classifier`) and the decorrelation solver (lines 14-17,
:mod:`sb3_sgfd.sgfd.decorrelation`).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.common import buffer_setup
from sb3_sgfd.common.buffers import DomainReplayBuffer
from sb3_sgfd.common.encoder_sac import EncoderSAC
from sb3_sgfd.common.observations import user_stacklevel
from sb3_sgfd.common.utils import derived_seeds
from sb3_sgfd.common.validation import check_positive_int
from sb3_sgfd.sgfd.saved_files import upgrade_saved_attributes, upgrade_saved_parameters
from sb3_sgfd.sgfd.settings import SGFDSettings, setting_names
from sb3_sgfd.sgfd.weighting import READINGS, SINGLE_DOMAIN_WARNING, SGFDWeighting


class SGFD_SAC(EncoderSAC):
    """
    Soft Actor-Critic with Saliency-Guided Features Decorrelation (SGFD).

    At every gradient step the batch's encoder features z get sample weights w (mean 1, detached)
    that decorrelate the features a domain classifier finds changing across environments from the
    other features (random Fourier features, paper eqs. 3-7); w multiplies the per-sample critic and/or
    actor losses. How the weights are computed is one of two readings (``reading``), each a
    :class:`sb3_sgfd.sgfd.weighting.SGFDWeighting`:

    - ``"paper"`` (:class:`sb3_sgfd.sgfd.weighting.PaperWeighting`): Algorithm 1 as printed, with this
      package's measured choices; the classifier trains from ``classifier_start`` while its accuracy is below
      ``accuracy_threshold``, and the weights start the first time it reaches it (until then this is SAC);
    - ``"official"`` (:class:`sb3_sgfd.sgfd.weighting.OfficialWeighting`): what the authors' code
      computes, which produced the published numbers: weights on the actor loss only from the first update, a
      memory of past batches, guided-backprop saliency, and an objective that keeps the weights close to uniform.

    SGFD's settings (``reading`` and the keywords of :class:`sb3_sgfd.sgfd.settings.SGFDSettings`, which documents
    each: ``classifier_start``, ``reweight_lr``, ...) are gathered in one ``SGFDSettings``, ``model.sgfd``. Each
    defaults to the reading's value (``SGFDSettings.paper()``, ``SGFDSettings.official()``); ``sgfd=`` gives them as
    one object instead.

    The weights combine with any encoder objective of :class:`sb3_sgfd.common.encoder_sac.EncoderSAC`:
    ``representation="ambs"`` (with ``policy="AMBSPolicy"``, two augmented views, ``encoder_tau=0.05``,
    ``max_grad_norm=40``) is the paper's agent, AMBS plus the reweighting (appendix B); without one the encoder
    learns from the critic loss alone.

    :param policy: the policy (``"MlpPolicy"``, ``"CnnPolicy"``, ...), as EncoderSAC's
    :param env: the envs, one sub-env per training domain (``sgfd_envs.make_domain_vec_env``)
    :param reading: ``"paper"`` or ``"official"``
    :param n_domains: Number of domain labels; ``None``: the envs' ``n_domains`` attribute or, if they have
        none, the number of sub-envs
    :param sgfd: All of SGFD's settings as one object (then no setting may be given as a keyword)
    :param actor_update_interval: Update the actor every this many gradient steps (SGFD's code: 2)
    :param kwargs: SGFD's settings as keywords, and the arguments of :class:`EncoderSAC` (SB3's SAC's, the
        encoder's and the objective's)
    """

    #: Keywords taken through ``**kwargs`` beside EncoderSAC's: SGFD's settings (the fields of SGFDSettings)
    settings_keywords: ClassVar[frozenset[str]] = frozenset(setting_names())

    weighting: SGFDWeighting

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        reading: str | None = None,
        n_domains: int | None = None,
        sgfd: SGFDSettings | None = None,
        actor_update_interval: int = 2,
        **kwargs: Any,
    ) -> None:
        self.sgfd = SGFDSettings.taken_from(reading, sgfd, kwargs)  # what remains in kwargs is EncoderSAC's
        buffer_class = kwargs.get("replay_buffer_class", DomainReplayBuffer)
        if buffer_class is None or not issubclass(buffer_class, buffer_setup.DOMAIN_BUFFERS):
            raise ValueError(
                "replay_buffer_class must be DomainReplayBuffer or a subclass (SGFD needs the domain label of every "
                f"transition), got {buffer_class}"
            )
        self.n_domains = n_domains
        # given: a promise about the labels (none beyond it); else counted from the envs, and recounted on load
        self._n_domains_given = n_domains is not None
        self.rff_seed: int | None = None
        super().__init__(policy, env, actor_update_interval=actor_update_interval, **kwargs)

    @classmethod
    def check_arguments(cls, arguments: Mapping[str, Any]) -> None:
        """:meth:`EncoderSAC.check_arguments`, and SGFD's settings among ``arguments`` as :class:`SGFDSettings`
        checks them (each refused in one line naming it)."""
        super().check_arguments(arguments)
        SGFDSettings.taken_from(arguments.get("reading"), None, dict(arguments))

    def _setup_model(self) -> None:
        upgrade_saved_attributes(self)  # a model saved by an earlier version: its attributes as today's
        if self.n_domains is None:
            self.n_domains = self._domain_count() if self.env is not None else None
        check_positive_int(n_domains=self.n_domains)  # type: ignore[arg-type]
        super()._setup_model()

    def _make_weighting(self) -> SGFDWeighting:
        """The reading's weighting, with a fresh classifier for ``n_domains`` labels; its RFF draws from a generator
        seeded once from ``rff_seed`` (a checkpoint saves its state)."""
        if self.rff_seed is None:
            self.rff_seed = derived_seeds(self.seed)["weighting"]
        if self.n_domains == 1:
            warnings.warn(SINGLE_DOMAIN_WARNING, stacklevel=user_stacklevel())
        features = self.critic.features_extractor.features_dim
        reading = READINGS[self.sgfd.reading]
        # The solver compiled where a step is captured (CUDA); on the CPU its compilation does not pay back within a
        # quick run (measured: bench/update_overhead.py's row of the solver compiled), so it runs eager there.
        compile_solver = self.compile_update and self.device.type == "cuda"
        return reading(features, self.n_domains, self.sgfd, self.rff_seed, self.device, compile_solver)  # type: ignore[arg-type]

    @property
    def classifier(self) -> th.nn.Module:
        """The weighting's domain classifier."""
        return self.weighting.classifier

    def sample_weights(
        self, z: th.Tensor, generator: th.Generator | None = None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """The reading's weights of features ``z`` with the classifier as it is now, leaving the weighting's
        state (memory, classifier) as it is: for figures and benchmarks.

        :param z: (n, d) encoder features
        :param generator: seeds the random Fourier features
        :return: weights (n,) with mean 1, the decorrelation loss at uniform weights and at the weights
        """
        return self.weighting.solve(z, generator)

    def set_parameters(
        self, load_path_or_dict: str | dict[str, Any], exact_match: bool = True, device: th.device | str = "auto"
    ) -> None:
        if isinstance(load_path_or_dict, dict):
            load_path_or_dict = upgrade_saved_parameters(load_path_or_dict)  # a weighting saved by 0.1.0
            if self.__dict__.pop("_saved_weighting_replaced", False):
                # loaded onto more domains than its untrained classifier had classes: the fresh weighting stays
                load_path_or_dict = {k: v for k, v in load_path_or_dict.items() if not k.startswith("weighting")}
                exact_match = False
        super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)

    def _domain_count(self) -> int:
        return self.n_domains if self.n_domains is not None else super()._domain_count()

    def _adopt_env_domains(self) -> None:
        """Envs with more domain labels than this model was built for (a model loaded onto more sub-envs of a plain
        env, labelled by their index) are taken while its classifier has a class for each, or has never trained
        (single domain, or before ``classifier_start``: SGFD then starts afresh on the new labels); refused in one
        line otherwise. An ``n_domains`` given when the model was made stays: the buffer refuses a label beyond it."""
        count = buffer_setup.env_domain_count(self.env) if self.env is not None else 0
        if self.n_domains is not None and count > self.n_domains and not self._n_domains_given:
            single = self.n_domains == 1 or (self.weighting is not None and self.weighting.single_domain)
            untrained = single or self.num_timesteps < self.sgfd.classifier_start
            fresh = count > max(self.n_domains, 2)
            if fresh and not untrained:
                raise ValueError(
                    f"the envs give {count} domain labels, but this SGFD_SAC's domain classifier was trained on "
                    f"n_domains={self.n_domains}: load it onto envs with at most {max(self.n_domains, 2)}, or "
                    "train a new model"
                )
            self.n_domains = count
            if fresh and self.weighting is not None:
                self.weighting = self._new_weighting()  # type: ignore[assignment]  # this class's _make_weighting's
            elif fresh:
                self._saved_weighting_replaced = True  # load: set_parameters skips the saved one
            elif self.weighting is not None:
                self.weighting.recheck_domains()
        super()._adopt_env_domains()
