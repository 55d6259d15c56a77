"""SGFD_SAC: Soft Actor-Critic whose critic and actor losses are reweighted per sample by SGFD."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.sac import SAC
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.buffers import DomainReplayBuffer, DomainReplayBufferSamples
from sb3_sgfd.policies import CnnPolicy, MlpPolicy, SGFDPolicy
from sb3_sgfd.reweighting import effective_sample_size, learn_sample_weights
from sb3_sgfd.saliency import DomainClassifier, classifier_accuracy, feature_probabilities, train_classifier

_SINGLE_DOMAIN_WARNING = (
    "SGFD_SAC sees a single domain, so there is nothing to decorrelate; it trains as plain SAC. Give it "
    "one sub-env per domain, e.g. sgfd_envs.make_domain_vec_env(env_id, split='train')."
)


class SGFD_SAC(SAC):
    """
    Soft Actor-Critic with Saliency-Guided Features Decorrelation (SGFD).

    At every gradient step the batch's encoder features z get sample weights w (mean 1, detached)
    that decorrelate the features a domain classifier finds changing across environments from the
    other features (random Fourier features, paper eqs. 3-6); w multiplies the per-sample critic and
    actor losses (eq. 7). The domain classifier trains on (z, domain label) from replay batches once
    ``num_timesteps >= classifier_start``, while its accuracy is below ``accuracy_threshold``
    (Algorithm 1); until it first reaches the threshold, w = 1 and this is SAC.

    Defaults follow the paper's Tables 3-4. Takes the arguments of SB3's :class:`SAC`, plus:

    :param actor_update_interval: Update the actor and entropy coefficient every this many gradient steps
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
    :param saliency_temperature: Temperature of the softmax over max-normalised saliency giving p(Z_i)
    :param saliency_smoothing: Weight of the uniform distribution mixed into p(Z_i) (see
        :func:`sb3_sgfd.saliency.feature_probabilities`)
    :param use_rff: Decorrelate random Fourier features (False: the features themselves, linear only)
    :param use_saliency: Weight feature pairs by the classifier's saliency (False: uniform, global decorrelation)
    :param reweight_critic: Apply the weights to the critic loss
    :param reweight_actor: Apply the weights to the actor loss
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
        "SGFDPolicy": SGFDPolicy,
    }

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
        saliency_temperature: float = 0.1,
        saliency_smoothing: float = 0.3,
        use_rff: bool = True,
        use_saliency: bool = True,
        reweight_critic: bool = True,
        reweight_actor: bool = True,
        _init_setup_model: bool = True,
    ):
        _check_positive_int(actor_update_interval=actor_update_interval, classifier_hidden_dim=classifier_hidden_dim)
        _check_positive_int(n_rff=n_rff, classifier_interval=classifier_interval)
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
        self.actor_update_interval = actor_update_interval
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
        self.saliency_temperature = saliency_temperature
        self.saliency_smoothing = saliency_smoothing
        self.use_rff = use_rff
        self.use_saliency = use_saliency
        self.reweight_critic = reweight_critic
        self.reweight_actor = reweight_actor
        # Sticky: weights are learned from the first time the classifier reaches the threshold on.
        self.classifier_ready = False
        self.single_domain = False
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
        self.classifier_optimizer = th.optim.Adam(self.classifier.parameters(), lr=self.classifier_lr)
        # The RFF draw of update k is seeded from (rff_seed, k): reproducible, and the seed is all that
        # a checkpoint needs to continue the same sequence.
        if self.rff_seed is None:
            self.rff_seed = int(np.random.default_rng(self.seed).integers(2**31))
        self._rff_generator = th.Generator(device=self.device)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        # Switch to train mode (this affects batch norm / dropout)
        self.policy.set_training_mode(True)
        # Update optimizers learning rate
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]

        # Update learning rate according to lr schedule
        self._update_learning_rate(optimizers)

        ent_coef_losses, ent_coefs = [], []
        actor_losses, critic_losses = [], []
        self._sgfd_stats: dict[str, list[float]] = {}

        for gradient_step in range(gradient_steps):
            # Sample replay buffer
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            # For n-step replay, discount factor is gamma**n_steps (when no early termination)
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
            update_index = self._n_updates + gradient_step
            # SGFD: per-sample weights of this batch, detached, mean 1 (Algorithm 1, lines 6-17)
            weights = self._batch_weights(replay_data, batch_size, update_index)
            critic_weights = weights if self.reweight_critic else th.ones_like(weights)
            actor_weights = weights if self.reweight_actor else th.ones_like(weights)
            # SGFD: the actor and the entropy coefficient learn every `actor_update_interval` steps
            update_actor = update_index % self.actor_update_interval == 0

            # We need to sample because `log_std` may have changed between two gradient steps
            if self.use_sde:
                self.actor.reset_noise()

            if update_actor:
                # Action by the current actor for the sampled state
                actions_pi, log_prob = self.actor.action_log_prob(replay_data.observations)
                log_prob = log_prob.reshape(-1, 1)

            ent_coef_loss = None
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                # Important: detach the variable from the graph
                # so we don't change it with other losses
                # see https://github.com/rail-berkeley/softlearning/issues/60
                ent_coef = th.exp(self.log_ent_coef.detach())
                assert isinstance(self.target_entropy, float)
                if update_actor:
                    ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                    ent_coef_losses.append(ent_coef_loss.item())
            else:
                ent_coef = self.ent_coef_tensor

            ent_coefs.append(ent_coef.item())

            # Optimize entropy coefficient, also called
            # entropy temperature or alpha in the paper
            if ent_coef_loss is not None and self.ent_coef_optimizer is not None:
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()

            with th.no_grad():
                # Select action according to policy
                next_actions, next_log_prob = self.actor.action_log_prob(replay_data.next_observations)
                # Compute the next Q values: min over all critics targets
                next_q_values = th.cat(self.critic_target(replay_data.next_observations, next_actions), dim=1)
                next_q_values, _ = th.min(next_q_values, dim=1, keepdim=True)
                # add entropy term
                next_q_values = next_q_values - ent_coef * next_log_prob.reshape(-1, 1)
                # td error + entropy term
                target_q_values = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values

            # Get current Q-values estimates for each critic network
            # using action from the replay buffer
            current_q_values = self.critic(replay_data.observations, replay_data.actions)

            # SGFD: weighted critic loss, 0.5 * sum over critics of mean(w * (Q - y)^2)
            critic_loss = 0.5 * sum(
                (critic_weights * (current_q - target_q_values) ** 2).mean() for current_q in current_q_values
            )
            assert isinstance(critic_loss, th.Tensor)  # for type checker
            critic_losses.append(_finite(critic_loss.item(), "critic loss", update_index))

            # Optimize the critic
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            if update_actor:
                # Min over all critic networks
                q_values_pi = th.cat(self.critic(replay_data.observations, actions_pi), dim=1)
                min_qf_pi, _ = th.min(q_values_pi, dim=1, keepdim=True)
                # SGFD: weighted actor loss, mean(w * (alpha log pi - min Q)) (eq. 7)
                actor_loss = (actor_weights * (ent_coef * log_prob - min_qf_pi)).mean()
                actor_losses.append(_finite(actor_loss.item(), "actor loss", update_index))

                # Optimize the actor
                self.actor.optimizer.zero_grad()
                actor_loss.backward()
                self.actor.optimizer.step()

            # Update target networks
            if gradient_step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                # Copy running stats, see GH issue #996
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)

        self._n_updates += gradient_steps

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", np.mean(ent_coefs))
        if len(actor_losses) > 0:
            self.logger.record("train/actor_loss", np.mean(actor_losses))
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        if len(ent_coef_losses) > 0:
            self.logger.record("train/ent_coef_loss", np.mean(ent_coef_losses))
        for key, values in self._sgfd_stats.items():
            self.logger.record(f"sgfd/{key}", np.mean(values))

    def _batch_weights(self, replay_data: DomainReplayBufferSamples, batch_size: int, update_index: int) -> th.Tensor:
        """
        Algorithm 1, lines 6-17: train the domain classifier while it is below the accuracy threshold,
        then learn weights that decorrelate the batch's features. Returns (n, 1) weights, mean 1.
        """
        ones = th.ones((replay_data.rewards.shape[0], 1), device=self.device)
        if self.num_timesteps < self.classifier_start or self.single_domain:
            return ones
        if not self.classifier_ready and len(self.replay_buffer.stored_domains()) < 2:  # type: ignore[union-attr]
            warnings.warn(_SINGLE_DOMAIN_WARNING, stacklevel=2)
            self.single_domain = True
            return ones

        z = self.encode(replay_data.observations)
        domains = self._checked_domains(replay_data.domains)
        if self.classifier_iters > 0 and update_index % self.classifier_interval == 0:
            batches = self._classifier_batches(z, domains, batch_size)
            accuracy, _ = train_classifier(self.classifier, self.classifier_optimizer, batches, self.accuracy_threshold)
        else:
            accuracy = classifier_accuracy(self.classifier, z, domains)
        self.classifier_ready = self.classifier_ready or accuracy >= self.accuracy_threshold
        self._record("classifier_accuracy", accuracy)
        if not self.classifier_ready or not (self.reweight_critic or self.reweight_actor):
            return ones

        self._rff_generator.manual_seed(self.rff_seed + update_index)
        weights, loss_before, loss_after = self.sample_weights(z, self._rff_generator, record=True)
        self._record("weight_ess", effective_sample_size(weights) / len(weights))
        self._record("weight_min", weights.min().item())
        self._record("weight_max", weights.max().item())
        self._record("decorrelation_loss_before", loss_before)
        self._record("decorrelation_loss_after", loss_after)
        return weights.reshape(-1, 1)

    def sample_weights(
        self, z: th.Tensor, generator: th.Generator | None = None, record: bool = False
    ) -> tuple[th.Tensor, float, float]:
        """
        Algorithm 1, lines 12-17 for features ``z``: the classifier's feature probabilities (uniform in the
        no-saliency ablation), then the weights that minimise the weighted decorrelation loss.

        :param z: (n, d) encoder features
        :param generator: seeds the random Fourier features
        :param record: log the most salient feature
        :return: weights (n,) with mean 1, the decorrelation loss at uniform weights and at the weights
        """
        feature_probs = None
        if self.use_saliency:
            feature_probs = feature_probabilities(
                self.classifier, z, temperature=self.saliency_temperature, smoothing=self.saliency_smoothing
            )
            if record:
                self._record("top_saliency_feature", float(feature_probs.argmax()))
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
            generator=generator,
            return_losses=True,
        )

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """The critic's encoder features z of a batch of (preprocessed) observations, without gradient."""
        with th.no_grad():
            return self.critic.extract_features(observations, self.critic.features_extractor)

    def _classifier_batches(
        self, z: th.Tensor, domains: th.Tensor, batch_size: int
    ) -> Iterator[tuple[th.Tensor, th.Tensor]]:
        """This batch's features, then fresh replay batches: ``classifier_iters`` batches in all."""
        yield z, domains
        for _ in range(self.classifier_iters - 1):
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            yield self.encode(batch.observations), self._checked_domains(batch.domains)

    def _checked_domains(self, domains: th.Tensor | None) -> th.Tensor:
        if domains is None:
            raise ValueError("SGFD_SAC needs replay samples with domain labels (use DomainReplayBuffer)")
        if int(domains.max()) >= max(self.n_domains, 2):
            raise ValueError(
                f"a transition has domain label {int(domains.max())} but n_domains={self.n_domains}; pass "
                "n_domains= at least one more than the largest info['domain'] label"
            )
        return domains

    def _record(self, key: str, value: float) -> None:
        self._sgfd_stats.setdefault(key, []).append(value)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "classifier", "classifier_optimizer", "_rff_generator", "_sgfd_stats"]

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


def _finite(value: float, what: str, update_index: int) -> float:
    if not math.isfinite(value):
        raise RuntimeError(
            f"SGFD_SAC: non-finite {what} ({value}) at update {update_index}; stopping before it spreads"
        )
    return value


def _check_positive_int(**values: int) -> None:
    for name, value in values.items():
        if not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
