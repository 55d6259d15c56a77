"""EncoderSAC: SB3's SAC with the machinery every visual-RL agent of the SGFD paper's tables shares.

- the encoder is shared by actor and critic and trained by the critic (``SharedEncoderPolicy``), and the critic
  target's encoder has its own soft-update rate (``encoder_tau``, DBC/AMBS: 0.05);
- random-shift augmentation of the critic's inputs (DrQ): one view (RAD, SGQN, TED), or two with the target
  and the critic loss averaged over them (DrQ, AMBS);
- the actor and the entropy coefficient learn every ``actor_update_interval`` steps, gradient norms are
  clipped (``max_grad_norm``, AMBS: 40);
- an optional representation objective (``representation=``: DBC, AMBS, TED or SGQN, see
  :mod:`sb3_sgfd.common.representation`), and per-sample weights of the critic and actor losses (``_batch_weights``,
  which a sample weighting overrides).

``EncoderSAC.train`` (with ``_gradient_step``, its loop's body) is a twin of ``SAC.train``: the lines marked ``# +``
are what it adds. With its defaults (no augmentation, no objective, ``encoder_tau = tau``, actor every step, no
clipping) it takes SB3 SAC's steps bit for bit (tested). With ``compile_update`` the same body is captured
(:mod:`sb3_sgfd.common.captured`).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any, ClassVar, cast

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.sac import SAC
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.common.augmentation import random_shift
from sb3_sgfd.common.buffer_setup import N_STEPS_IGNORED_WARNING, DomainBufferMixin
from sb3_sgfd.common.buffers import DomainReplayBuffer
from sb3_sgfd.common.captured import CapturedUpdateMixin, StepPlan
from sb3_sgfd.common.observations import warn_if_flattening_images
from sb3_sgfd.common.policies import (
    CnnPolicy,
    EncoderMlpPolicy,
    MlpPolicy,
    MultiInputPolicy,
    SGFDPolicy,
    SharedEncoderPolicy,
    check_encoder_setup,
    critic_and_features,
)
from sb3_sgfd.common.representation import REPRESENTATIONS, Batch, Representation, make_representation
from sb3_sgfd.common.utils import polyak_pairs, weighted_mean
from sb3_sgfd.common.validation import check_encoder_sac_arguments, check_sac_arguments


class EncoderSAC(CapturedUpdateMixin, DomainBufferMixin, SAC):
    """
    SAC with a critic-trained shared encoder, augmentation, an encoder target, and the hooks an encoder
    objective (``representation``) and a sample weighting need. Takes the arguments of SB3's :class:`SAC`
    (with the SGFD paper's lr 1e-3, batch 128, tau 0.01), plus:

    :param actor_update_interval: Update the actor and entropy coefficient every this many gradient steps
    :param encoder_tau: Soft-update rate of the critic target's encoder; None: ``tau``
    :param augmentation_views: Random-shift views of each batch's observations (images only): 0 none, 1 the
        critic, target and actor see one shifted view (RAD), 2 the critic loss and its target are averaged
        over two (DrQ, AMBS; the actor sees the first)
    :param augmentation_pad: Pixels of edge-replicating padding before the random crop (DrQ: 4)
    :param max_grad_norm: Clip the gradient norm of the critic and of the actor to this; None: no clipping
    :param ent_coef_lr: Adam learning rate of the entropy coefficient, fixed; None: ``learning_rate`` (SAC)
        (DBC, AMBS, SGQN: 1e-4)
    :param ent_coef_beta: Adam's first beta for the entropy coefficient (SAC: 0.9; DBC, AMBS, SGQN: 0.5)
    :param representation: An encoder objective registered in :mod:`sb3_sgfd.common.representation` ("dbc", "ambs",
        "ted", "sgqn"), or None
    :param representation_kwargs: Its hyperparameters
    :param actor_reuses_features: The actor's Q on the critic's encoder features of the step, detached (no second
        encoder pass, as the authors' codes detach the encoder); False: SB3's, the batch encoded again after the
        critic's step (the same values on states, where the features are the observations)
    :param compile_update: Run each gradient step as captured work (:mod:`sb3_sgfd.common.captured`): on CUDA one
        CUDA-graph replay per step plan with fused optimisers, the figures read once per log interval, what fuses
        compiled; on the CPU the same path without graphs. Off by default until a GPU has measured it
        (``bench/device_check.py``)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
        "SharedEncoderPolicy": SharedEncoderPolicy,
        "SGFDPolicy": SGFDPolicy,
        "EncoderMlpPolicy": EncoderMlpPolicy,
        "MultiInputPolicy": MultiInputPolicy,
    }
    #: The objective subclasses train; None: any (or none).
    fixed_representation: ClassVar[str | None] = None

    representation_model: Representation | None

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
        actor_update_interval: int = 1,
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
        _init_setup_model: bool = True,
    ):
        # the objective checks its own arguments when it is built (in _setup_model: SB3's load builds no objective here)
        arguments = {name: value for name, value in locals().items() if name not in ("self", "policy", "env")}
        EncoderSAC.check_arguments({k: v for k, v in arguments.items() if not k.startswith("representation")})
        if self.fixed_representation is not None and representation != self.fixed_representation:
            raise ValueError(
                f"{type(self).__name__} trains the {self.fixed_representation!r} representation, got "
                f"representation={representation!r} (EncoderSAC takes any)"
            )
        self.actor_update_interval = actor_update_interval
        self.encoder_tau = encoder_tau
        self.augmentation_views = augmentation_views
        self.augmentation_pad = augmentation_pad
        self.max_grad_norm = max_grad_norm
        self.ent_coef_lr = ent_coef_lr
        self.ent_coef_beta = ent_coef_beta
        self.representation = representation
        self.representation_kwargs = dict(representation_kwargs or {})
        self.actor_reuses_features = actor_reuses_features
        self.compile_update = compile_update
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
            _init_setup_model=_init_setup_model,
        )

    @classmethod
    def check_arguments(cls, arguments: Mapping[str, Any]) -> None:
        """Refuse, in one line naming it, a bad value of any constructor argument among ``arguments`` (any subset):
        SAC's, this loop's and the objective's ``representation_kwargs``, before anything is built."""
        check_sac_arguments(arguments)
        check_encoder_sac_arguments(arguments)
        if "representation" in arguments or "representation_kwargs" in arguments:
            representation = arguments.get("representation", cls.fixed_representation)
            make_representation(representation, arguments.get("representation_kwargs"))

    def _get_policy_from_name(self, policy_name: str) -> type[BasePolicy]:
        # The objective's policies first: AMBS("CnnPolicy", env) is AMBS's AMBSPolicy, DBC("MlpPolicy", env) an MLP
        # encoder it can train.
        objective = REPRESENTATIONS.get(self.representation) if self.representation is not None else None
        if objective is not None and policy_name in objective.policy_aliases:
            return objective.policy_aliases[policy_name]
        return super()._get_policy_from_name(policy_name)

    def _setup_model(self) -> None:
        # SB3 builds the replay buffer in super()._setup_model(): the objective's needs go in first.
        representation_model = make_representation(self.representation, self.representation_kwargs)
        self._prepare_replay_buffer(representation_model)
        with warnings.catch_warnings():
            if self._buffer_takes_n_steps():
                warnings.filterwarnings("ignore", message=N_STEPS_IGNORED_WARNING, category=UserWarning)
            super()._setup_model()
        warn_if_flattening_images(self.policy)
        if self.ent_coef_optimizer is not None and (self.ent_coef_lr is not None or self.ent_coef_beta != 0.9):
            lr = self.lr_schedule(1) if self.ent_coef_lr is None else self.ent_coef_lr
            self.ent_coef_optimizer = th.optim.Adam([self.log_ent_coef], lr=lr, betas=(self.ent_coef_beta, 0.999))  # type: ignore[arg-type]  # not None with the optimizer
        check_encoder_setup(self, representation_model is not None)
        # Augmentation and the objectives draw from generators of their own, seeded from the model's seed:
        # SAC's random streams stay those of SB3's SAC.
        seeds = self._derived_seeds()
        self._augment_generator = th.Generator(device=self.device).manual_seed(seeds["augmentation"])
        self.representation_model = representation_model
        if representation_model is not None:
            representation_model.generator = th.Generator(device=self.device).manual_seed(seeds["representation"])
            with th.random.fork_rng(devices=[]):
                # the CPU generator: CUDA streams stay SAC's
                th.random.default_generator.manual_seed(seeds["representation"])
                representation_model.setup(self)
            representation_model.to(self.device)
        self._encoder_pairs, self._head_pairs = self._target_pairs()
        self._adopt_env_domains()

    def _derived_seeds(self) -> dict[str, int]:
        """Seeds of the generators the additions to SAC draw from, all from the model's seed: one stream,
        so that a subclass's additions do not move its siblings' draws."""
        draws = np.random.default_rng(self.seed).integers(2**31, size=3)
        return {"reweighting": int(draws[0]), "augmentation": int(draws[1]), "representation": int(draws[2])}

    def _target_pairs(self) -> tuple[list[tuple[th.Tensor, th.Tensor]], list[tuple[th.Tensor, th.Tensor]]]:
        """(online, target) parameters of the critic's encoder and of its heads, for the soft updates."""
        targets = dict(self.critic_target.named_parameters())
        encoder, heads = [], []  # type: list[tuple[th.Tensor, th.Tensor]], list[tuple[th.Tensor, th.Tensor]]
        for name, param in self.critic.named_parameters():
            (encoder if name.startswith("features_extractor.") else heads).append((param, targets[name]))
        return encoder, heads

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        # Switch to train mode (this affects batch norm / dropout)
        self.policy.set_training_mode(True)
        # Update optimizers learning rate
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None and self.ent_coef_lr is None:  # + unless its rate is its own
            optimizers += [self.ent_coef_optimizer]

        # Update learning rate according to lr schedule
        self._update_learning_rate(optimizers)
        self._prepare_update()  # + the optimisers and figures of the eager or captured update

        for gradient_step in range(gradient_steps):
            # Sample replay buffer (+ copied into the captured graphs' static inputs)
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            replay_data = self._update.inputs("batch", replay_data)  # +
            # + the host's decisions for this step (which parts learn): one captured graph per plan
            plan = self._plan(self._n_updates + gradient_step, gradient_step)
            # + views of the observations for the critic (the first also the actor's), of the next ones for its target
            # (without augmentation, the batch itself: nothing to capture)
            views = self._update.run if self.augmentation_views else lambda _, piece, *args: piece(*args)
            observations, next_observations = views("views", self._views, replay_data)
            # + what the weighting needs the host for before the step (SGFD's code reading: its classifier's round)
            self._before_gradient_step(replay_data, observations, plan)
            self._update.run(plan, self._gradient_step, replay_data, observations, next_observations, plan)  # +

        self._n_updates += gradient_steps

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self._after_train()  # + the figures read (once per log interval when captured) and the finiteness check

    def _gradient_step(
        self, replay_data: Any, observations: list[th.Tensor], next_observations: list[th.Tensor], plan: StepPlan
    ) -> None:
        """One gradient step: the body of ``SAC.train``'s loop, with the lines marked ``# +`` added (its figures go to
        the device, the host's decisions come in ``plan``); captured, this is one CUDA graph per plan."""
        # For n-step replay, discount factor is gamma**n_steps (when no early termination)
        discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma

        # Get current Q-values estimates for each critic network
        # using action from the replay buffer (+ per view, each with the encoder features it came from; + first,
        # so that the actor reads the critic's features of the batch instead of encoding it again)
        critic_outputs = [critic_and_features(self.critic, obs, replay_data.actions) for obs in observations]
        current_q_values = [q_values for q_values, _ in critic_outputs]
        z = critic_outputs[0][1].detach()  # +

        # We need to sample because `log_std` may have changed between two gradient steps
        if self.use_sde:
            self.actor.reset_noise()

        if plan.update_actor:
            # Action by the current actor for the sampled state
            actions_pi, log_prob = self._actor_action_log_prob(observations[0], z)
            log_prob = log_prob.reshape(-1, 1)

        ent_coef_loss = None
        if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
            # Important: detach the variable from the graph
            # so we don't change it with other losses
            # see https://github.com/rail-berkeley/softlearning/issues/60
            ent_coef = th.exp(self.log_ent_coef.detach())
            assert isinstance(self.target_entropy, float)
            if plan.update_actor:
                ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                self.record("train/ent_coef_loss", ent_coef_loss)
        else:
            ent_coef = self.ent_coef_tensor

        self.record("train/ent_coef", ent_coef)

        # Optimize entropy coefficient, also called
        # entropy temperature or alpha in the paper
        if ent_coef_loss is not None and self.ent_coef_optimizer is not None:
            self.ent_coef_optimizer.zero_grad()
            ent_coef_loss.backward()
            self.ent_coef_optimizer.step()

        with th.no_grad():
            # + the target averaged over the views of the next observation (one view: SAC's target)
            target_q_values = sum(
                self._target_q_values(next_obs, replay_data, ent_coef, discounts) for next_obs in next_observations
            ) / len(next_observations)

        # + per-sample weights of the critic and actor losses (SGFD) from the first view's features; None = SAC
        critic_weights, actor_weights = self._batch_weights(replay_data, z, plan)

        # Compute critic loss  (+ mean over views, weighted per sample)
        critic_loss = sum(
            0.5 * sum(weighted_mean((current_q - target_q_values) ** 2, critic_weights) for current_q in view)
            for view in current_q_values
        ) / len(current_q_values)
        # + the objective's term of the critic loss (SGQN's consistency)
        if self.representation_model is not None:
            extra = self.representation_model.critic_loss(
                self, observations[0], replay_data.actions, current_q_values[0]
            )
            critic_loss = critic_loss if extra is None else critic_loss + extra
        assert isinstance(critic_loss, th.Tensor)  # for type checker
        self.record("train/critic_loss", critic_loss, check_finite="critic loss")

        # Optimize the critic
        self.critic.optimizer.zero_grad()
        critic_loss.backward()
        self._clip_grad_norm(self.critic.optimizer)  # +
        self.critic.optimizer.step()

        # + the representation objective's own step (DBC, AMBS, TED, SGQN)
        if self.representation_model is not None:
            batch = Batch(replay_data, observations, next_observations, plan.objective)
            for key, value in self.representation_model.update(self, batch).items():
                self.record(f"{self.representation}/{key}", value)

        if plan.update_actor:
            # Min over all critic networks (+ on this step's features of the batch: no second encoder pass)
            q_values_pi = th.cat(self._actor_q_values(observations[0], z, actions_pi), dim=1)
            min_qf_pi, _ = th.min(q_values_pi, dim=1, keepdim=True)
            actor_loss = weighted_mean(ent_coef * log_prob - min_qf_pi, actor_weights)  # + weighted
            self.record("train/actor_loss", actor_loss, check_finite="actor loss")

            # Optimize the actor
            self.actor.optimizer.zero_grad()
            actor_loss.backward()
            self._clip_grad_norm(self.actor.optimizer)  # +
            self.actor.optimizer.step()

        # Update target networks
        if plan.update_target:
            # + the encoder at its own rate
            polyak_pairs(self._head_pairs, self.tau)
            polyak_pairs(self._encoder_pairs, self.tau if self.encoder_tau is None else self.encoder_tau)
            # Copy running stats, see GH issue #996
            polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)
        self._figures.end_update()  # +

    def _target_q_values(
        self, next_observations: th.Tensor, replay_data: Any, ent_coef: th.Tensor, discounts: th.Tensor | float
    ) -> th.Tensor:
        """SAC's soft TD target of one view of the next observations."""
        # Select action according to policy
        next_actions, next_log_prob = self.actor.action_log_prob(next_observations)
        # Compute the next Q values: min over all critics targets
        next_q_values = th.cat(self.critic_target(next_observations, next_actions), dim=1)
        next_q_values, _ = th.min(next_q_values, dim=1, keepdim=True)
        # add entropy term
        next_q_values = next_q_values - ent_coef * next_log_prob.reshape(-1, 1)
        # td error + entropy term
        return replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values

    def _views(self, replay_data: Any) -> tuple[list[th.Tensor], list[th.Tensor]]:
        """The augmented views of a batch's observations and of its next observations (``augment`` of each)."""
        return self.augment(replay_data.observations), self.augment(replay_data.next_observations)

    def augment(self, observations: th.Tensor) -> list[th.Tensor]:
        """``augmentation_views`` random shifts of a batch of (n, C, H, W) images as the replay buffer returns them,
        or the batch itself without augmentation."""
        if not self.augmentation_views:
            return [observations]
        return [
            random_shift(observations, self.augmentation_pad, self._augment_generator)
            for _ in range(self.augmentation_views)
        ]

    def _batch_weights(
        self, replay_data: Any, z: th.Tensor, plan: StepPlan
    ) -> tuple[th.Tensor | None, th.Tensor | None]:
        """Per-sample weights (n, 1) of the critic and actor losses from the critic's (detached) features ``z`` of
        the first view; None: unweighted (SAC). A sample weighting overrides it."""
        return None, None

    def _before_gradient_step(self, replay_data: Any, observations: list[th.Tensor], plan: StepPlan) -> None:
        """What a sample weighting does before the step where it needs the host (a decision, fresh batches), given
        the batch and its views. Nothing here."""

    def _plan(self, update_index: int, gradient_step: int) -> StepPlan:
        """What the host decides for the step (its index over the run, and in this ``train`` call, which SAC's target
        updates count): each part whose Python code branches on the update says so here, so that one captured graph
        per plan replays exactly what the eager step would run."""
        objective = () if self.representation_model is None else self.representation_model.plan(update_index)
        return StepPlan(
            update_actor=update_index % self.actor_update_interval == 0,
            update_target=gradient_step % self.target_update_interval == 0,
            objective=objective,
            weighting=self._weighting_plan(update_index, update_index % self.actor_update_interval == 0),
        )

    def _weighting_plan(self, update_index: int, update_actor: bool) -> tuple:
        """A sample weighting's share of the plan (none here)."""
        return ()

    def _actor_action_log_prob(self, observations: th.Tensor, z: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """The actor's actions and their log-probabilities for the batch, from the critic's features z of it when
        the actor reads the critic's encoder (the same values SB3's actor computes, without a second pass)."""
        if self._actor_reads_critic_features:
            return cast(SharedEncoderPolicy, self.policy).actor.action_log_prob_of_features(z)
        return self.actor.action_log_prob(observations)

    def _actor_q_values(self, observations: th.Tensor, z: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        """The critic's Q of the actor's actions: with ``actor_reuses_features`` on the critic's (detached) features of
        this step, as the authors' codes (the encoder detached); else SB3's, the batch encoded again."""
        if self.actor_reuses_features and self._actor_reads_critic_features:
            q_input = th.cat([z, actions], dim=1)
            return tuple(q_net(q_input) for q_net in self.critic.q_networks)
        return self.critic(observations, actions)

    @property
    def _actor_reads_critic_features(self) -> bool:
        # one encoder, the critic's, which the actor reads detached (SB3's own SAC policies: not so)
        return isinstance(self.policy, SharedEncoderPolicy)

    def _clip_grad_norm(self, optimizer: th.optim.Optimizer) -> None:
        """Clip the gradient norm of the parameters ``optimizer`` steps (the actor's exclude the shared encoder)."""
        if self.max_grad_norm is not None:
            parameters = [param for group in optimizer.param_groups for param in group["params"]]
            th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)

    def preprocess(self, observations: th.Tensor) -> th.Tensor:
        """Observations as the buffer returns them, as the encoder takes them (SB3's ``preprocess_obs``)."""
        return cast(th.Tensor, preprocess_obs(observations, self.observation_space, self.policy.normalize_images))

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """The critic's encoder features z of a batch of observations (as the buffer returns them), without gradient."""
        with th.no_grad():
            return self.critic.extract_features(observations, self.critic.features_extractor)

    def generators(self) -> dict[str, th.Generator]:
        """The generators this algorithm draws from beside the global ones, by name: what a checkpoint saves so
        that a resumed run continues their streams."""
        generators = {"augmentation": self._augment_generator}
        if self.representation_model is not None:
            generators["representation"] = self.representation_model.generator
        return generators

    def _update_optimizers(self) -> list[th.optim.Optimizer]:
        """Every optimiser a gradient step steps (a sample weighting adds its own)."""
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        if self.representation_model is not None:
            optimizers += [
                getattr(self.representation_model, name) for name in self.representation_model.optimizer_names()
            ]
        return optimizers

    def _excluded_save_params(self) -> list[str]:
        excluded = ["representation_model", "_augment_generator", "_encoder_pairs", "_head_pairs"]
        return [*super()._excluded_save_params(), *excluded]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, saved_pytorch_variables = super()._get_torch_save_params()
        if self.representation_model is not None:
            names = ["representation_model"]
            names += [f"representation_model.{name}" for name in self.representation_model.optimizer_names()]
            state_dicts = [*state_dicts, *names]
        return state_dicts, saved_pytorch_variables
