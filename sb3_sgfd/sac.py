"""SGFD_SAC: SAC, on any encoder objective of EncoderSAC, with its losses reweighted per sample by SGFD."""

from __future__ import annotations

import warnings
from typing import Any

import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.buffers import DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.encoder_sac import EncoderSAC
from sb3_sgfd.reweighting import WeightMemory, check_max_step
from sb3_sgfd.validation import check_non_negative_int, check_positive_int
from sb3_sgfd.weighting import SampleWeighting, Step
from sb3_sgfd.weighting_official import OfficialWeighting
from sb3_sgfd.weighting_paper import PaperWeighting

#: SGFD's readings (``SGFD_SAC(reading=...)``): the paper's text, and what the authors' code computes.
READINGS: dict[str, type[SampleWeighting]] = {"paper": PaperWeighting, "official": OfficialWeighting}

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
    :class:`sb3_sgfd.weighting.SampleWeighting`:

    - ``"paper"`` (:class:`sb3_sgfd.weighting_paper.PaperWeighting`): Algorithm 1 as printed, with this
      package's measured choices; the classifier trains from ``classifier_start`` while its accuracy is below
      ``accuracy_threshold``, and the weights start the first time it reaches it (until then this is SAC);
    - ``"official"`` (:class:`sb3_sgfd.weighting_official.OfficialWeighting`): what the authors' code computes,
      which produced the published numbers: weights on the actor loss only from the first update, a memory of
      past batches, guided-backprop saliency, and an objective that keeps the weights close to uniform.

    The arguments below marked *reading* default to ``None``: the reading's value (``READINGS[reading].defaults``;
    paper / official given as p / o), each overridable.

    The weights combine with any encoder objective of :class:`sb3_sgfd.encoder_sac.EncoderSAC`:
    ``representation="ambs"`` (with ``policy="AMBSPolicy"``, two augmented views, ``encoder_tau=0.05``,
    ``max_grad_norm=40``) is the paper's agent, AMBS plus the reweighting (appendix B); without one the encoder
    learns from the critic loss alone.

    Takes the arguments of :class:`EncoderSAC` (SB3's SAC's, the encoder's and the objective's), plus:

    :param reading: ``"paper"`` or ``"official"``
    :param n_domains: Number of domain labels; ``None``: the envs' ``n_domains`` attribute or, if they have
        none, the number of sub-envs
    :param classifier_start: Env steps before the domain classifier starts training
    :param classifier_iters: *reading* (p 1, o 10) Classifier updates per classifier round (paper: at most, the
        first on this batch's features, the others on fresh replay batches, Algorithm 1's 10; official: steps on
        fresh batches of 5 x ``batch_size``)
    :param classifier_interval: *reading* (p 1, o 4) A classifier round every this many gradient steps
    :param accuracy_threshold: *reading* (p 0.9, o 0.8) Classifier accuracy below which it trains (paper: and at
        which reweighting starts)
    :param classifier_hidden_dim: Width of the classifier's two hidden layers
    :param classifier_lr: *reading* (p 1e-3 Adam, o 0.01 SGD) Learning rate of the classifier
    :param n_rff: Random Fourier functions per latent feature
    :param reweight_iters: *reading* (p 10, o 20) Steps of the weight solver per batch
    :param reweight_lr: *reading* (p 5, o 1 then 0.1) Learning rate of the weight solver (the paper's table
        prints 1e-2, its classifier's; see :func:`sb3_sgfd.reweighting.learn_sample_weights`)
    :param reweight_momentum: Momentum of the weight solver
    :param reweight_weight_decay: *reading* (p 1e-4, o 0) Weight decay of the weight solver
    :param reweight_ess_penalty: *reading* (p 0.35, o 5) How strongly the weights are kept near uniform: the
        strength knob (paper: penalty on n / ESS - 1; official: weight of log sum w^2). Higher is weaker
    :param reweight_memory: *reading* (p off, o 0.9) Momentum of a memory of past batches the solver also
        decorrelates against (see :class:`sb3_sgfd.reweighting.WeightMemory`); ``False``: no memory
    :param reweight_max_step: Largest change of any weight logit in one solver step, a trust region (see
        :func:`sb3_sgfd.reweighting.learn_sample_weights`); None: unbounded, as in the paper and the code
    :param saliency_temperature: *reading* (p 0.1 of the max-normalised saliency, o 1 of the raw one) Softmax
        temperature giving p(Z_i)
    :param saliency_smoothing: *reading* (p 0.3, o 0) Weight of the uniform distribution mixed into p(Z_i) (see
        :func:`sb3_sgfd.saliency.feature_probabilities`)
    :param use_rff: Decorrelate random Fourier features (False: the features themselves, linear only)
    :param use_saliency: Weight feature pairs by the classifier's saliency (False: uniform, global decorrelation)
    :param reweight_critic: *reading* (p True, o False) Apply the weights to the critic loss
    :param reweight_actor: Apply the weights to the actor loss
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
        reading: str = "paper",
        n_domains: int | None = None,
        classifier_start: int = 100_000,
        classifier_iters: int | None = None,
        classifier_interval: int | None = None,
        accuracy_threshold: float | None = None,
        classifier_hidden_dim: int = 128,
        classifier_lr: float | None = None,
        n_rff: int = 5,
        reweight_iters: int | None = None,
        reweight_lr: float | None = None,
        reweight_momentum: float = 0.9,
        reweight_weight_decay: float | None = None,
        reweight_ess_penalty: float | None = None,
        reweight_memory: float | bool | None = None,
        reweight_max_step: float | None = None,
        saliency_temperature: float | None = None,
        saliency_smoothing: float | None = None,
        use_rff: bool = True,
        use_saliency: bool = True,
        reweight_critic: bool | None = None,
        reweight_actor: bool = True,
        _init_setup_model: bool = True,
    ):
        if reading not in READINGS:
            raise ValueError(f"reading must be one of {sorted(READINGS)}, got {reading!r}")
        given = {
            "classifier_iters": classifier_iters,
            "classifier_interval": classifier_interval,
            "accuracy_threshold": accuracy_threshold,
            "classifier_lr": classifier_lr,
            "reweight_iters": reweight_iters,
            "reweight_lr": reweight_lr,
            "reweight_weight_decay": reweight_weight_decay,
            "reweight_ess_penalty": reweight_ess_penalty,
            "reweight_memory": reweight_memory,
            "saliency_temperature": saliency_temperature,
            "saliency_smoothing": saliency_smoothing,
            "reweight_critic": reweight_critic,
        }
        settings = {name: READINGS[reading].defaults[name] if value is None else value for name, value in given.items()}
        if settings["reweight_memory"] is False:
            settings["reweight_memory"] = None
        check_positive_int(
            classifier_hidden_dim=classifier_hidden_dim,
            n_rff=n_rff,
            classifier_interval=settings["classifier_interval"],
        )
        check_non_negative_int(
            classifier_start=classifier_start,
            classifier_iters=settings["classifier_iters"],
            reweight_iters=settings["reweight_iters"],
        )
        if not 0.0 < settings["accuracy_threshold"] <= 1.0:
            raise ValueError(f"accuracy_threshold must be in (0, 1], got {settings['accuracy_threshold']}")
        if replay_buffer_class is None or not issubclass(replay_buffer_class, DomainReplayBuffer):
            raise ValueError(
                "replay_buffer_class must be DomainReplayBuffer or a subclass (SGFD needs the domain "
                f"label of every transition), got {replay_buffer_class}"
            )
        if settings["reweight_memory"] is not None:
            WeightMemory(settings["reweight_memory"])  # checks it
        check_max_step(reweight_max_step, "reweight_max_step")
        self.reading = reading
        self.n_domains = n_domains
        self.classifier_start = classifier_start
        self.classifier_hidden_dim = classifier_hidden_dim
        self.n_rff = n_rff
        self.reweight_momentum = reweight_momentum
        self.reweight_max_step = reweight_max_step
        self.use_rff = use_rff
        self.use_saliency = use_saliency
        self.reweight_actor = reweight_actor
        self.classifier_iters: int = settings["classifier_iters"]
        self.classifier_interval: int = settings["classifier_interval"]
        self.accuracy_threshold: float = settings["accuracy_threshold"]
        self.classifier_lr: float = settings["classifier_lr"]
        self.reweight_iters: int = settings["reweight_iters"]
        self.reweight_lr: float = settings["reweight_lr"]
        self.reweight_weight_decay: float = settings["reweight_weight_decay"]
        self.reweight_ess_penalty: float = settings["reweight_ess_penalty"]
        self.reweight_memory: float | None = settings["reweight_memory"]
        self.saliency_temperature: float = settings["saliency_temperature"]
        self.saliency_smoothing: float = settings["saliency_smoothing"]
        self.reweight_critic: bool = settings["reweight_critic"]
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
            _init_setup_model=_init_setup_model,
        )

    def _setup_model(self) -> None:
        if self.n_domains is None:
            self.n_domains = self._domain_count() if self.env is not None else None
        if self.n_domains is None or self.n_domains < 1:
            raise ValueError(f"n_domains must be a positive integer, got {self.n_domains}")
        super()._setup_model()
        if self.n_domains == 1 and not self.single_domain:
            warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
            self.single_domain = True
        # The RFF draw of update k is seeded from (rff_seed, k): reproducible, and the seed is all that
        # a checkpoint needs to continue the same sequence.
        if self.rff_seed is None:
            self.rff_seed = self._derived_seeds()["reweighting"]
        # A forked RNG: SGFD's additions must not shift the random streams SAC draws from, so that with
        # w = 1 this is SAC to the last bit under the same seed.
        with th.random.fork_rng(devices=[]):
            self.weighting = READINGS[self.reading](
                self.critic.features_extractor.features_dim,
                self.n_domains,
                classifier_start=self.classifier_start,
                classifier_iters=self.classifier_iters,
                classifier_interval=self.classifier_interval,
                accuracy_threshold=self.accuracy_threshold,
                classifier_hidden_dim=self.classifier_hidden_dim,
                classifier_lr=self.classifier_lr,
                n_rff=self.n_rff,
                reweight_iters=self.reweight_iters,
                reweight_lr=self.reweight_lr,
                reweight_momentum=self.reweight_momentum,
                reweight_weight_decay=self.reweight_weight_decay,
                reweight_ess_penalty=self.reweight_ess_penalty,
                reweight_memory=self.reweight_memory,
                reweight_max_step=self.reweight_max_step,
                saliency_temperature=self.saliency_temperature,
                saliency_smoothing=self.saliency_smoothing,
                use_rff=self.use_rff,
                use_saliency=self.use_saliency,
                seed=self.rff_seed,
                device=self.device,
            )

    @property
    def classifier(self) -> th.nn.Module:
        """The weighting's domain classifier."""
        return self.weighting.classifier

    def _batch_weights(
        self,
        replay_data: DomainReplayBufferSamples,
        z: th.Tensor,
        batch_size: int,
        update_index: int,
        update_actor: bool,
    ) -> tuple[th.Tensor | None, th.Tensor | None]:
        """
        The reading's weights of this batch (:class:`sb3_sgfd.weighting.SampleWeighting`), as (n, 1) weights of
        the critic and of the actor (None where that loss is not reweighted or the reading gives none; weights
        for the actor alone are not computed on the steps it does not learn).
        """
        if self.single_domain or not self.weighting.active(self.num_timesteps):
            return None, None
        if not self._domains_checked:
            # Once, when the weighting starts: stored_domains() reads the whole buffer.
            self._domains_checked = True
            if len(self.replay_buffer.stored_domains()) < 2:  # type: ignore[union-attr]
                warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
                self.single_domain = True
                return None, None
        weights_wanted = self.reweight_critic or (self.reweight_actor and update_actor)
        step = Step(update_index, self.num_timesteps, weights_wanted, self._fresh_features)
        weights, figures = self.weighting(z, self._checked_domains(replay_data.domains), step)
        for key, value in figures.items():
            self.record(f"sgfd/{key}", value)
        if weights is None:
            return None, None
        weights = weights.reshape(-1, 1)
        return (weights if self.reweight_critic else None), (weights if self.reweight_actor else None)

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

    def _fresh_features(self, n_samples: int, augmented: bool) -> tuple[th.Tensor, th.Tensor]:
        """A fresh replay batch of ``n_samples``, encoded (of its first augmented view with ``augmented``), and
        its domain labels: the classifier's extra batches."""
        batch = self.replay_buffer.sample(n_samples, env=self._vec_normalize_env)  # type: ignore[union-attr]
        observations = self.augment(batch.observations)[0] if augmented else batch.observations
        return self.encode(observations), self._checked_domains(batch.domains)

    def _domain_count(self) -> int:
        return self.n_domains if self.n_domains is not None else super()._domain_count()

    def _checked_domains(self, domains: th.Tensor | None) -> th.Tensor:
        # Their values were checked where they entered (DomainReplayBuffer.add refuses a label >= n_domains).
        if domains is None:
            raise ValueError("SGFD_SAC needs replay samples with domain labels (use DomainReplayBuffer)")
        return domains

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "weighting"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, saved_pytorch_variables = super()._get_torch_save_params()
        return [*state_dicts, "weighting", "weighting.classifier_optimizer"], saved_pytorch_variables
