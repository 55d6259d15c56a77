"""SGFD_SAC: SAC, on any encoder objective of EncoderSAC, with its losses reweighted per sample by SGFD."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.common.buffer_setup import DOMAIN_BUFFERS
from sb3_sgfd.common.buffers import DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.common.encoder_sac import EncoderSAC, StepPlan
from sb3_sgfd.common.validation import check_positive_int
from sb3_sgfd.sgfd.settings import SGFDSettings, setting_names
from sb3_sgfd.sgfd.weighting import CLASSIFIER_BATCHES, READINGS, OfficialWeighting, SampleWeighting, WeightingPlan

#: The figures of the weights themselves, logged over the steps where the weights are in use.
WEIGHT_FIGURES = ("weight_ess", "weight_min", "weight_max", "decorrelation_loss_before", "decorrelation_loss_after")

_SINGLE_DOMAIN_WARNING = (
    "SGFD_SAC sees a single domain, so there is nothing to decorrelate; it trains as plain SAC. Give it "
    "one sub-env per domain, e.g. sgfd_envs.make_domain_vec_env(env_id, split='train')."
)


class SGFD_SAC(EncoderSAC):
    """
    Soft Actor-Critic with Saliency-Guided Features Decorrelation (SGFD).

    At every gradient step the batch's encoder features z get sample weights w (mean 1, detached)
    that decorrelate the features a domain classifier finds changing across environments from the
    other features (random Fourier features, paper eqs. 3-7); w multiplies the per-sample critic and/or
    actor losses. How the weights are computed is one of two readings (``reading``), each a
    :class:`sb3_sgfd.sgfd.weighting.SampleWeighting`:

    - ``"paper"`` (:class:`sb3_sgfd.sgfd.weighting.PaperWeighting`): Algorithm 1 as printed, with this
      package's measured choices; the classifier trains from ``classifier_start`` while its accuracy is below
      ``accuracy_threshold``, and the weights start the first time it reaches it (until then this is SAC);
    - ``"official"`` (:class:`sb3_sgfd.sgfd.weighting.OfficialWeighting`): what the authors' code
      computes, which produced the published numbers: weights on the actor loss only from the first update, a
      memory of past batches, guided-backprop saliency, and an objective that keeps the weights close to uniform.

    SGFD's settings (``reading`` and every keyword from ``classifier_start`` to ``reweight_actor``) are gathered
    in one :class:`sb3_sgfd.sgfd.settings.SGFDSettings`, ``model.sgfd``, which documents each. Each defaults to
    ``None``: the reading's value (``SGFDSettings.paper()``, ``SGFDSettings.official()``); ``sgfd=`` gives
    them as one object instead.

    The weights combine with any encoder objective of :class:`sb3_sgfd.common.encoder_sac.EncoderSAC`:
    ``representation="ambs"`` (with ``policy="AMBSPolicy"``, two augmented views, ``encoder_tau=0.05``,
    ``max_grad_norm=40``) is the paper's agent, AMBS plus the reweighting (appendix B); without one the encoder
    learns from the critic loss alone.

    Takes the arguments of :class:`EncoderSAC` (SB3's SAC's, the encoder's and the objective's), plus:

    :param reading: ``"paper"`` or ``"official"``
    :param n_domains: Number of domain labels; ``None``: the envs' ``n_domains`` attribute or, if they have
        none, the number of sub-envs
    :param sgfd: All of SGFD's settings as one object (then none of the keywords below may be given)
    :param classifier_start: and the keywords after it: :class:`sb3_sgfd.sgfd.settings.SGFDSettings`
    """

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 1_000_000,
        learning_starts: int = 1000,
        batch_size: int = 128,
        tau: float = 0.01,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = DomainReplayBuffer,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        ent_coef: str | float = "auto",
        target_update_interval: int = 1,
        target_entropy: str | float = "auto",
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        use_sde_at_warmup: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        actor_update_interval: int = 2,
        encoder_tau: float | None = None,
        augmentation_views: int = 0,
        augmentation_pad: int = 4,
        max_grad_norm: float | None = None,
        ent_coef_lr: float | None = None,
        ent_coef_beta: float = 0.9,
        representation: str | None = None,
        representation_kwargs: dict[str, Any] | None = None,
        actor_reuses_features: bool = True,
        compile_update: bool = False,
        reading: str | None = None,
        n_domains: int | None = None,
        sgfd: SGFDSettings | None = None,
        classifier_start: int | None = None,
        classifier_iters: int | None = None,
        classifier_interval: int | None = None,
        accuracy_threshold: float | None = None,
        classifier_hidden_dim: int | None = None,
        classifier_lr: float | None = None,
        n_rff: int | None = None,
        reweight_iters: int | None = None,
        reweight_lr: float | None = None,
        reweight_momentum: float | None = None,
        reweight_weight_decay: float | None = None,
        reweight_ess_penalty: float | None = None,
        reweight_memory: float | bool | None = None,
        reweight_max_step: float | None = None,
        saliency_temperature: float | None = None,
        saliency_smoothing: float | None = None,
        use_rff: bool | None = None,
        use_saliency: bool | None = None,
        reweight_critic: bool | None = None,
        reweight_actor: bool | None = None,
        _init_setup_model: bool = True,
    ):
        # SGFD's settings: the keywords of this signature that SGFDSettings holds, the reading's value where None
        given = {name: value for name, value in locals().items() if name in SGFD_KEYWORDS}
        if sgfd is not None:
            if not isinstance(sgfd, SGFDSettings):
                raise ValueError(f"sgfd must be an SGFDSettings, got {type(sgfd).__name__}")
            clashing = sorted(name for name, value in given.items() if value is not None and name != "reading")
            if clashing or reading not in (None, sgfd.reading):
                raise ValueError(
                    f"give SGFD's settings either as sgfd= or as keywords, not both: {clashing or 'reading'}"
                )
            self.sgfd = sgfd
        else:
            self.sgfd = SGFDSettings.of_reading(
                reading or "paper", **{k: v for k, v in given.items() if k != "reading"}
            )
        if replay_buffer_class is None or not issubclass(replay_buffer_class, DOMAIN_BUFFERS):
            raise ValueError(
                "replay_buffer_class must be DomainReplayBuffer or a subclass (SGFD needs the domain "
                f"label of every transition), got {replay_buffer_class}"
            )
        self.n_domains = n_domains
        # given: a promise about the labels (none beyond it); else counted from the envs, and recounted on load
        self._n_domains_given = n_domains is not None
        self.single_domain = False
        self._domains_checked = False
        self.rff_seed: int | None = None
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            n_steps=n_steps,
            ent_coef=ent_coef,
            target_update_interval=target_update_interval,
            target_entropy=target_entropy,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            use_sde_at_warmup=use_sde_at_warmup,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            actor_update_interval=actor_update_interval,
            encoder_tau=encoder_tau,
            augmentation_views=augmentation_views,
            augmentation_pad=augmentation_pad,
            max_grad_norm=max_grad_norm,
            ent_coef_lr=ent_coef_lr,
            ent_coef_beta=ent_coef_beta,
            representation=representation,
            representation_kwargs=representation_kwargs,
            actor_reuses_features=actor_reuses_features,
            compile_update=compile_update,
            _init_setup_model=_init_setup_model,
        )

    @classmethod
    def check_arguments(cls, arguments: Mapping[str, Any]) -> None:
        """:meth:`EncoderSAC.check_arguments`, and SGFD's settings among ``arguments`` as :class:`SGFDSettings`
        checks them (each refused in one line naming it)."""
        super().check_arguments(arguments)
        settings = {name: value for name, value in arguments.items() if name in SGFD_KEYWORDS and name != "reading"}
        SGFDSettings.of_reading(arguments.get("reading") or "paper", **settings)

    def _setup_model(self) -> None:
        self._adopt_saved_settings()
        if self.n_domains is None:
            self.n_domains = self._env_domain_count() if self.env is not None else None
        check_positive_int(n_domains=self.n_domains)  # type: ignore[arg-type]
        self._adopt_env_domains()
        super()._setup_model()
        if self.n_domains == 1 and not self.single_domain:
            warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
            self.single_domain = True
        # The RFF draws come from a generator seeded once from rff_seed (a checkpoint saves its state).
        if self.rff_seed is None:
            self.rff_seed = self._derived_seeds()["reweighting"]
        self.weighting = self._new_weighting()

    def _new_weighting(self) -> SampleWeighting:
        """The reading's weighting with a fresh classifier for ``n_domains`` labels."""
        # A forked RNG: SGFD's additions must not shift the random streams SAC draws from, so that with
        # w = 1 this is SAC to the last bit under the same seed.
        with th.random.fork_rng(devices=[]):
            return READINGS[self.sgfd.reading](
                self.critic.features_extractor.features_dim,
                self.n_domains,  # type: ignore[arg-type]
                self.sgfd,
                seed=self.rff_seed,  # type: ignore[arg-type]
                device=self.device,
                compile_solver=self._captures_update(),
            )

    def set_parameters(
        self, load_path_or_dict: str | dict[str, Any], exact_match: bool = True, device: th.device | str = "auto"
    ) -> None:
        if getattr(self, "_saved_weighting_replaced", False) and isinstance(load_path_or_dict, dict):
            # loaded onto more domains than its untrained classifier had classes: the fresh weighting stays
            self._saved_weighting_replaced = False
            load_path_or_dict = {k: v for k, v in load_path_or_dict.items() if not k.startswith("weighting")}
            exact_match = False
        super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)

    def _adopt_saved_settings(self) -> None:
        """A model saved by version 0.1.0 holds SGFD's settings as attributes of their own: gather them into
        ``self.sgfd`` (SB3's ``load`` puts a saved model's attributes back before it sets the model up)."""
        saved = {name: self.__dict__.pop(name) for name in list(self.__dict__) if name in SGFD_KEYWORDS}
        if saved:
            self.sgfd = SGFDSettings.of_reading(saved.pop("reading", "paper"), **saved)

    @property
    def classifier(self) -> th.nn.Module:
        """The weighting's domain classifier."""
        return self.weighting.classifier

    def _weighting_plan(self, update_index: int, update_actor: bool) -> tuple:
        """The weighting's decisions for the update (empty: it does nothing, and this step is SAC's)."""
        if self.single_domain or not self.weighting.active(self.num_timesteps):
            return ()
        if not self._domains_checked:
            # Once, when the weighting starts: stored_domains() reads the whole buffer.
            self._domains_checked = True
            if len(self.replay_buffer.stored_domains()) < 2:  # type: ignore[union-attr]
                warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
                self.single_domain = True
                return ()
        weights_wanted = self.sgfd.reweight_critic or (self.sgfd.reweight_actor and update_actor)
        return tuple(self.weighting.plan(update_index, self.num_timesteps, weights_wanted))

    def _before_gradient_step(
        self, replay_data: DomainReplayBufferSamples, observations: list[th.Tensor], plan: StepPlan
    ) -> None:
        """Where a classifier round needs the host: the paper reading's further batches are sampled (the step encodes
        them); the code reading's round scores the batch, and if it is below the threshold (the round's one host
        read) trains on fresh batches before the step."""
        self._fresh_batches: list[DomainReplayBufferSamples] = []
        if not plan.weighting or not WeightingPlan(*plan.weighting).classifier_round:
            return
        n, iters = len(replay_data.actions), self.sgfd.classifier_iters
        if not isinstance(self.weighting, OfficialWeighting):
            self._fresh_batches = [self._fresh_batch(f"sgfd fresh {i}", n) for i in range(iters - 1)]
            return
        score = self._update.run("sgfd score", self._score, observations[0], self._checked_domains(replay_data.domains))
        if bool(score < self.sgfd.accuracy_threshold):
            batches = [self._fresh_batch(f"sgfd round {i}", CLASSIFIER_BATCHES * n) for i in range(iters)]
            self._update.run("sgfd round", self._official_round, batches)

    def _fresh_batch(self, name: str, n_samples: int) -> DomainReplayBufferSamples:
        """A fresh replay batch for the classifier, in the static inputs ``name`` when captured."""
        batch = self.replay_buffer.sample(n_samples, env=self._vec_normalize_env)  # type: ignore[union-attr]
        return self._update.inputs(name, batch)

    def _score(self, observations: th.Tensor, domains: th.Tensor) -> th.Tensor:
        return self.weighting.score(self.encode(observations), domains)  # type: ignore[operator]

    def _official_round(self, batches: list[DomainReplayBufferSamples]) -> None:
        encoded = [(self.encode(batch.observations), self._checked_domains(batch.domains)) for batch in batches]
        self.weighting.train_round(encoded)  # type: ignore[operator]

    def _batch_weights(
        self, replay_data: DomainReplayBufferSamples, z: th.Tensor, plan: StepPlan
    ) -> tuple[th.Tensor | None, th.Tensor | None]:
        """
        The reading's weights of this batch (:class:`sb3_sgfd.sgfd.weighting.SampleWeighting`), as (n, 1) weights of
        the critic and of the actor (None where that loss is not reweighted or the reading gives none; weights
        for the actor alone are not computed on the steps it does not learn).
        """
        if not plan.weighting:
            return None, None
        fresh = [
            (self.encode(self.augment(batch.observations)[0]), self._checked_domains(batch.domains))
            for batch in self._fresh_batches
        ]
        domains = self._checked_domains(replay_data.domains)
        weights, figures, weighted = self.weighting(z, domains, WeightingPlan(*plan.weighting), fresh)
        for key, value in figures.items():
            self.record(f"sgfd/{key}", value, when=weighted if key in WEIGHT_FIGURES else None)
        if weights is None:
            return None, None
        weights = weights.reshape(-1, 1)
        return (weights if self.sgfd.reweight_critic else None), (weights if self.sgfd.reweight_actor else None)

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

    def generators(self) -> dict[str, th.Generator]:
        # the RFF generator is seeded anew at every update, but its state between updates is part of a resume too
        return {**super().generators(), "weights": self.weighting.rff_generator}

    def _update_optimizers(self) -> list[th.optim.Optimizer]:
        return [*super()._update_optimizers(), self.weighting.classifier_optimizer]

    def _domain_count(self) -> int:
        return self.n_domains if self.n_domains is not None else super()._domain_count()

    def _adopt_env_domains(self) -> None:
        """Envs with more domain labels than this model was built for (a model loaded onto more sub-envs of a plain
        env, labelled by their index) are taken while its classifier has a class for each, or has never trained
        (single domain, or before ``classifier_start``: SGFD then starts afresh on the new labels); refused in one
        line otherwise. An ``n_domains`` given when the model was made stays: the buffer refuses a label beyond it."""
        count = self._env_domain_count() if self.env is not None else 0
        given = getattr(self, "_n_domains_given", False)  # a model saved by 0.1.0 counted them
        if self.n_domains is not None and count > self.n_domains and not given:
            untrained = self.single_domain or self.num_timesteps < self.sgfd.classifier_start
            fresh = count > max(self.n_domains, 2)
            if fresh and not untrained:
                raise ValueError(
                    f"the envs give {count} domain labels, but this SGFD_SAC's domain classifier was trained on "
                    f"n_domains={self.n_domains}: load it onto envs with at most {max(self.n_domains, 2)}, or "
                    "train a new model"
                )
            self.n_domains, self.single_domain, self._domains_checked = count, False, False
            if fresh and hasattr(self, "weighting"):
                self.weighting = self._new_weighting()
            elif fresh:
                self._saved_weighting_replaced = True  # load: set_parameters skips the saved one
        super()._adopt_env_domains()

    def _checked_domains(self, domains: th.Tensor | None) -> th.Tensor:
        # Their values were checked where they entered (DomainReplayBuffer.add refuses a label >= n_domains).
        if domains is None:
            raise ValueError("SGFD_SAC needs replay samples with domain labels (use DomainReplayBuffer)")
        return domains

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "weighting", "_saved_weighting_replaced", "_fresh_batches"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, saved_pytorch_variables = super()._get_torch_save_params()
        return [*state_dicts, "weighting", "weighting.classifier_optimizer"], saved_pytorch_variables


#: SGFD_SAC's keywords that are SGFD's settings (``reading`` and the fields of SGFDSettings)
SGFD_KEYWORDS = frozenset(["reading", *setting_names()])
