"""SGFD_SAC: SAC, on any encoder objective of EncoderSAC, with its losses reweighted per sample by SGFD."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from typing import Any

import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.buffers import DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.encoder_sac import EncoderSAC, check_positive_int
from sb3_sgfd.reweighting import WeightMemory, check_max_step, learn_sample_weights
from sb3_sgfd.saliency import (
    DomainClassifier,
    classifier_accuracy,
    feature_probabilities,
    scored_feature_probabilities,
    train_classifier,
)

_SINGLE_DOMAIN_WARNING = (
    "SGFD_SAC sees a single domain, so there is nothing to decorrelate; it trains as plain SAC. Give it "
    "one sub-env per domain, e.g. sgfd_envs.make_domain_vec_env(env_id, split='train')."
)


class SGFD_SAC(EncoderSAC):
    """
    Soft Actor-Critic with Saliency-Guided Features Decorrelation (SGFD).

    At every gradient step the batch's encoder features z get sample weights w (mean 1, detached)
    that decorrelate the features a domain classifier finds changing across environments from the
    other features (random Fourier features, paper eqs. 3-6); w multiplies the per-sample critic and
    actor losses (eq. 7). The domain classifier trains on (z, domain label) once
    ``num_timesteps >= classifier_start``, while its accuracy is below ``accuracy_threshold``
    (Algorithm 1); until it first reaches the threshold, w = 1 and this is SAC.

    The weights combine with any encoder objective of :class:`sb3_sgfd.encoder_sac.EncoderSAC`:
    ``representation="ambs"`` (with ``policy="AMBSPolicy"``, two augmented views, ``encoder_tau=0.05``,
    ``max_grad_norm=40``) is the paper's agent, AMBS plus the reweighting (appendix B); without one the encoder
    learns from the critic loss alone.

    Defaults follow the paper's Tables 3-4. Takes the arguments of :class:`EncoderSAC` (SB3's SAC's, the
    encoder's and the objective's), plus:

    :param n_domains: Number of domain labels; ``None``: the envs' ``n_domains`` attribute or, if they have
        none, the number of sub-envs
    :param classifier_start: Env steps before the domain classifier starts training
    :param classifier_iters: Most classifier updates per classifier round: the first on this batch's features
        (already computed for the weights), the others on fresh replay batches (Algorithm 1: 10, every step)
    :param classifier_interval: A classifier round every this many gradient steps (official code: every 20)
    :param accuracy_threshold: Classifier accuracy at which its training pauses and reweighting starts
    :param classifier_hidden_dim: Width of the classifier's two hidden layers
    :param classifier_lr: Adam learning rate of the classifier
    :param n_rff: Random Fourier features per latent feature
    :param reweight_iters: SGD iterations of the weight solver per batch
    :param reweight_lr: Learning rate of the weight solver (paper: 1e-2 on an unnormalised loss, where the
        weights barely move; ours normalises the loss, see :func:`sb3_sgfd.reweighting.learn_sample_weights`)
    :param reweight_momentum: Momentum of the weight solver
    :param reweight_weight_decay: Weight decay of the weight solver
    :param reweight_ess_penalty: Penalty on n / ESS - 1 that keeps the weights from collapsing on few samples
    :param reweight_memory: Momentum of a memory of past batches the solver also decorrelates against (the
        official code's 0.9, see :class:`sb3_sgfd.reweighting.WeightMemory`); None: this batch only
    :param reweight_max_step: Largest change of any weight logit in one solver step, a trust region (see
        :func:`sb3_sgfd.reweighting.learn_sample_weights`); None: unbounded, as in the paper
    :param saliency_temperature: Temperature of the softmax over max-normalised saliency giving p(Z_i)
    :param saliency_smoothing: Weight of the uniform distribution mixed into p(Z_i) (see
        :func:`sb3_sgfd.saliency.feature_probabilities`)
    :param use_rff: Decorrelate random Fourier features (False: the features themselves, linear only)
    :param use_saliency: Weight feature pairs by the classifier's saliency (False: uniform, global decorrelation)
    :param reweight_critic: Apply the weights to the critic loss
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
        n_domains: int | None = None,
        classifier_start: int = 100_000,
        classifier_iters: int = 1,
        classifier_interval: int = 1,
        accuracy_threshold: float = 0.9,
        classifier_hidden_dim: int = 128,
        classifier_lr: float = 1e-3,
        n_rff: int = 5,
        reweight_iters: int = 10,
        reweight_lr: float = 5.0,
        reweight_momentum: float = 0.9,
        reweight_weight_decay: float = 1e-4,
        reweight_ess_penalty: float = 0.35,
        reweight_memory: float | None = None,
        reweight_max_step: float | None = None,
        saliency_temperature: float = 0.1,
        saliency_smoothing: float = 0.3,
        use_rff: bool = True,
        use_saliency: bool = True,
        reweight_critic: bool = True,
        reweight_actor: bool = True,
        _init_setup_model: bool = True,
    ):
        check_positive_int(
            classifier_hidden_dim=classifier_hidden_dim, n_rff=n_rff, classifier_interval=classifier_interval
        )
        if classifier_start < 0 or classifier_iters < 0 or reweight_iters < 0:
            raise ValueError(
                "classifier_start, classifier_iters and reweight_iters must be >= 0, got "
                f"{classifier_start}, {classifier_iters}, {reweight_iters}"
            )
        if not 0.0 < accuracy_threshold <= 1.0:
            raise ValueError(f"accuracy_threshold must be in (0, 1], got {accuracy_threshold}")
        if replay_buffer_class is None or not issubclass(replay_buffer_class, DomainReplayBuffer):
            raise ValueError(
                "replay_buffer_class must be DomainReplayBuffer or a subclass (SGFD needs the domain "
                f"label of every transition), got {replay_buffer_class}"
            )
        if reweight_memory is not None:
            WeightMemory(reweight_memory)  # checks it
        check_max_step(reweight_max_step, "reweight_max_step")
        self.n_domains = n_domains
        self.classifier_start = classifier_start
        self.classifier_iters = classifier_iters
        self.classifier_interval = classifier_interval
        self.accuracy_threshold = accuracy_threshold
        self.classifier_hidden_dim = classifier_hidden_dim
        self.classifier_lr = classifier_lr
        self.n_rff = n_rff
        self.reweight_iters = reweight_iters
        self.reweight_lr = reweight_lr
        self.reweight_momentum = reweight_momentum
        self.reweight_weight_decay = reweight_weight_decay
        self.reweight_ess_penalty = reweight_ess_penalty
        self.reweight_memory = reweight_memory
        self.reweight_max_step = reweight_max_step
        self.saliency_temperature = saliency_temperature
        self.saliency_smoothing = saliency_smoothing
        self.use_rff = use_rff
        self.use_saliency = use_saliency
        self.reweight_critic = reweight_critic
        self.reweight_actor = reweight_actor
        # Sticky: weights are learned from the first time the classifier reaches the threshold on.
        self.classifier_ready = False
        self.single_domain = False
        self._domains_checked = False
        self.rff_seed: int | None = None
        self.weight_memory: WeightMemory | None = None
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
            _init_setup_model=_init_setup_model,
        )

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.n_domains is None:
            self.n_domains = _infer_n_domains(self.env) if self.env is not None else None
        if self.n_domains is None or self.n_domains < 1:
            raise ValueError(f"n_domains must be a positive integer, got {self.n_domains}")
        if self.n_domains == 1 and not self.single_domain:
            warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
            self.single_domain = True
        n_features = self.critic.features_extractor.features_dim
        # A forked RNG: SGFD's additions must not shift the random streams SAC draws from, so that with
        # w = 1 this is SAC to the last bit under the same seed.
        with th.random.fork_rng(devices=[]):
            self.classifier = DomainClassifier(n_features, max(self.n_domains, 2), self.classifier_hidden_dim)
        self.classifier.to(self.device)
        # Fused: one kernel for all six parameters instead of a dozen small ops each (a fifth of a classifier step).
        self.classifier_optimizer = th.optim.Adam(self.classifier.parameters(), lr=self.classifier_lr, fused=True)
        # The RFF draw of update k is seeded from (rff_seed, k): reproducible, and the seed is all that
        # a checkpoint needs to continue the same sequence.
        if self.rff_seed is None:
            self.rff_seed = self._derived_seeds()["reweighting"]
        self._rff_generator = th.Generator(device=self.device)
        if self.reweight_memory is not None and self.weight_memory is None:
            self.weight_memory = WeightMemory(self.reweight_memory)

    def _batch_weights(
        self,
        replay_data: DomainReplayBufferSamples,
        z: th.Tensor,
        batch_size: int,
        update_index: int,
        update_actor: bool,
    ) -> tuple[th.Tensor | None, th.Tensor | None]:
        """
        Algorithm 1, lines 6-17: train the domain classifier while it is below the accuracy threshold,
        then learn weights that decorrelate the batch's features. Returns the (n, 1) weights, mean 1, of the
        critic and of the actor (None where that loss is not reweighted, or before the classifier is ready;
        weights for the actor alone are not computed on the steps it does not learn).

        Once the classifier is ready, one pass of it scores the batch and gives the saliency p(Z_i); if the
        score is below the threshold the classifier then takes its step, and the weights use the p(Z_i) of
        that pass (Algorithm 1 would take p after the step: one Adam step apart, for one classifier pass less).
        """
        if self.num_timesteps < self.classifier_start or self.single_domain:
            return None, None
        if not self.classifier_ready and not self._domains_checked:
            # Once, when the classifier starts: stored_domains() reads the whole buffer.
            self._domains_checked = True
            if len(self.replay_buffer.stored_domains()) < 2:  # type: ignore[union-attr]
                warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
                self.single_domain = True
                return None, None

        domains = self._checked_domains(replay_data.domains)
        weights_wanted = self.reweight_critic or (self.reweight_actor and update_actor)
        feature_probs, accuracy = None, None
        if self.classifier_ready and weights_wanted and self.use_saliency:
            feature_probs, accuracy = scored_feature_probabilities(
                self.classifier, z, domains, temperature=self.saliency_temperature, smoothing=self.saliency_smoothing
            )
        classifier_round = self.classifier_iters > 0 and update_index % self.classifier_interval == 0
        if classifier_round and (accuracy is None or accuracy < self.accuracy_threshold):
            batches = self._classifier_batches(z, domains, batch_size)
            accuracy, _ = train_classifier(self.classifier, self.classifier_optimizer, batches, self.accuracy_threshold)
        elif accuracy is None:
            accuracy = classifier_accuracy(self.classifier, z, domains)
        self.classifier_ready = self.classifier_ready or accuracy >= self.accuracy_threshold
        self.record("sgfd/classifier_accuracy", accuracy)
        if not self.classifier_ready or not weights_wanted:
            return None, None

        self._rff_generator.manual_seed(self.rff_seed + update_index)
        weights, loss_before, loss_after = self.sample_weights(z, self._rff_generator, True, feature_probs)
        # Kish's effective sample size over n, as a tensor: figures stay on the device until train() logs them.
        self.record("sgfd/weight_ess", weights.sum().square() / weights.square().sum() / len(weights))
        self.record("sgfd/weight_min", weights.min())
        self.record("sgfd/weight_max", weights.max())
        self.record("sgfd/decorrelation_loss_before", loss_before)
        self.record("sgfd/decorrelation_loss_after", loss_after)
        weights = weights.reshape(-1, 1)
        return (weights if self.reweight_critic else None), (weights if self.reweight_actor else None)

    def sample_weights(
        self,
        z: th.Tensor,
        generator: th.Generator | None = None,
        record: bool = False,
        feature_probs: th.Tensor | None = None,
    ) -> tuple[th.Tensor, float, float]:
        """
        Algorithm 1, lines 12-17 for features ``z``: the classifier's feature probabilities (uniform in the
        no-saliency ablation), then the weights that minimise the weighted decorrelation loss.

        :param z: (n, d) encoder features
        :param generator: seeds the random Fourier features
        :param record: log the most salient feature (and update the memory of past batches, if any)
        :param feature_probs: p(Z_i) if already computed for ``z``; None: from the classifier here
        :return: weights (n,) with mean 1, the decorrelation loss at uniform weights and at the weights
        """
        if not self.use_saliency:
            feature_probs = None
        elif feature_probs is None:
            feature_probs = feature_probabilities(
                self.classifier, z, temperature=self.saliency_temperature, smoothing=self.saliency_smoothing
            )
        if feature_probs is not None and record:
            self.record("sgfd/top_saliency_feature", feature_probs.argmax())
        return learn_sample_weights(
            z,
            feature_probs,
            n_rff=self.n_rff,
            iters=self.reweight_iters,
            lr=self.reweight_lr,
            momentum=self.reweight_momentum,
            weight_decay=self.reweight_weight_decay,
            ess_penalty=self.reweight_ess_penalty,
            use_rff=self.use_rff,
            memory=self.weight_memory if record else None,
            max_step=self.reweight_max_step,
            generator=generator,
            return_losses=True,
        )

    def _classifier_batches(
        self, z: th.Tensor, domains: th.Tensor, batch_size: int
    ) -> Iterator[tuple[th.Tensor, th.Tensor]]:
        """This batch's features, then fresh replay batches: ``classifier_iters`` batches in all."""
        yield z, domains
        for _ in range(self.classifier_iters - 1):
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            yield self.encode(self.augment(batch.observations)[0]), self._checked_domains(batch.domains)

    def _checked_domains(self, domains: th.Tensor | None) -> th.Tensor:
        if domains is None:
            raise ValueError("SGFD_SAC needs replay samples with domain labels (use DomainReplayBuffer)")
        if int(domains.max()) >= max(self.n_domains, 2):
            raise ValueError(
                f"a transition has domain label {int(domains.max())} but n_domains={self.n_domains}; pass "
                "n_domains= at least one more than the largest info['domain'] label"
            )
        return domains

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "classifier", "classifier_optimizer", "_rff_generator"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, saved_pytorch_variables = super()._get_torch_save_params()
        return [*state_dicts, "classifier", "classifier_optimizer"], saved_pytorch_variables


def _infer_n_domains(env: Any) -> int:
    """The largest ``n_domains`` attribute of the sub-envs, or the number of sub-envs if they have none."""
    try:
        counts = env.get_attr("n_domains")
    except AttributeError:
        return env.num_envs
    return max(int(count) for count in counts)
