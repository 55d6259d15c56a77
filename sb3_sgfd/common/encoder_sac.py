"""EncoderSAC: SB3's SAC with what every visual-RL agent of the SGFD paper's tables shares (the class docstring says
what), and two slots an algorithm fills: an encoder objective (:mod:`sb3_sgfd.common.representation`: DBC, AMBS,
TED, SGQN) and a sample weighting of the critic's and the actor's losses (:mod:`sb3_sgfd.common.sample_weighting`:
SGFD's).

``EncoderSAC.train`` (with ``_gradient_step``, its loop's body) is a twin of ``SAC.train``: the lines marked ``# +``
are what it adds. With its defaults it takes SB3 SAC's steps bit for bit (tested). It holds the
:class:`~sb3_sgfd.common.update_runner.UpdateRunner` that runs the steps (captured with ``compile_update``) and sums
their figures.
"""

from __future__ import annotations

import inspect
import io
import pathlib
import warnings
from collections.abc import Mapping
from typing import Any, ClassVar, TypeVar, cast

import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.sac import SAC
from stable_baselines3.sac.policies import SACPolicy

from sb3_sgfd.common import buffer_setup, policies
from sb3_sgfd.common import representation as objectives
from sb3_sgfd.common.augmentation import random_shift
from sb3_sgfd.common.buffers import DomainReplayBuffer
from sb3_sgfd.common.observations import warn_if_flattening_images
from sb3_sgfd.common.optimizers import set_learning_rate
from sb3_sgfd.common.sample_weighting import LossWeights, SampleWeighting
from sb3_sgfd.common.update_runner import StepPlan, UpdateRunner
from sb3_sgfd.common.utils import derived_seeds, polyak_pairs, target_pairs, weighted_mean
from sb3_sgfd.common.validation import check_encoder_sac_arguments, check_fixed_representation, check_sac_arguments
from sb3_sgfd.common.version import __version__, check_saved_version

SelfEncoderSAC = TypeVar("SelfEncoderSAC", bound="EncoderSAC")
#: What a saved model does not hold as attributes (the objective's and the weighting's state go in as state dicts)
UNSAVED = ("representation_model", "weighting", "_augment_generator", "_encoder_pairs", "_head_pairs", "_update")
#: The arguments EncoderSAC hands to SB3's SAC, as they are
SAC_ARGUMENTS = [name for name in inspect.signature(SAC.__init__).parameters if name not in ("self", "policy", "env")]

__all__ = ["EncoderSAC", "StepPlan"]


class EncoderSAC(SAC):
    """
    SAC with an encoder shared by actor and critic and trained by the critic (``SharedEncoderPolicy``), the critic
    target's encoder at its own rate, random-shift augmentation (DrQ), a delayed actor, clipped gradients, an encoder
    objective (``representation``) and a sample weighting (``weighting``, set by a subclass such as SGFD_SAC). Takes
    the arguments of SB3's :class:`SAC` (with the SGFD paper's lr 1e-3, batch 128, tau 0.01), plus:

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
        "ted", "sgqn"), or None (a subclass with an objective of its own: that one)
    :param representation_kwargs: Its hyperparameters
    :param actor_reuses_features: The actor's Q on the critic's encoder features of the step, detached (no second
        encoder pass, as the authors' codes detach the encoder); False: SB3's, the batch encoded again after the
        critic's step (the same values on states, where the features are the observations)
    :param compile_update: Run each gradient step as captured work (:mod:`sb3_sgfd.common.capture`): on CUDA one
        CUDA-graph replay per step plan with fused optimisers, the figures read once per log interval, what fuses
        compiled (SGFD's solver); on the CPU, the optimisers stepping fused (nothing compiled). Off by default
        until a GPU has measured it (``bench/device_check.py``)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = policies.POLICY_ALIASES
    #: The objective subclasses train; None: any (or none).
    fixed_representation: ClassVar[str | None] = None

    representation_model: objectives.Representation | None

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
        representation = self.fixed_representation if representation is None else representation
        check_fixed_representation(type(self).__name__, self.fixed_representation, representation)
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
        self.weighting: SampleWeighting | None = None
        self._update = self._new_runner(th.device("cpu"))  # for the model's device at the first train call
        super().__init__(policy, env, **{name: arguments[name] for name in SAC_ARGUMENTS})

    @classmethod
    def check_arguments(cls, arguments: Mapping[str, Any]) -> None:
        """Refuse, in one line naming it, a bad value of any constructor argument among ``arguments`` (any subset):
        SAC's, this loop's and the objective's ``representation_kwargs``, before anything is built."""
        check_sac_arguments(arguments)
        check_encoder_sac_arguments(arguments)
        if "representation" in arguments or "representation_kwargs" in arguments:
            representation = arguments.get("representation", cls.fixed_representation)
            objectives.make_representation(representation, arguments.get("representation_kwargs"))

    def _get_policy_from_name(self, policy_name: str) -> type[BasePolicy]:
        # The objective's policies first: AMBS("CnnPolicy", env) is AMBSPolicy, DBC("MlpPolicy", env) a trainable MLP
        objective = objectives.REPRESENTATIONS.get(self.representation or "")
        aliases = objective.policy_aliases if objective is not None else {}
        return aliases.get(policy_name) or super()._get_policy_from_name(policy_name)

    def _setup_model(self) -> None:
        check_saved_version(vars(self).get("sb3_sgfd_version"), f"this {type(self).__name__} model")  # SB3's load
        # SB3 builds the replay buffer in super()._setup_model(): the objective's needs go in first.
        representation_model = objectives.make_representation(self.representation, self.representation_kwargs)
        buffer_setup.prepare_replay_buffer(
            self, representation_model, self._domain_count() if self.env is not None else 1
        )
        with warnings.catch_warnings():
            if buffer_setup.buffer_takes_n_steps(self):
                warnings.filterwarnings("ignore", message=buffer_setup.N_STEPS_IGNORED_WARNING, category=UserWarning)
            super()._setup_model()
        warn_if_flattening_images(self.policy)
        if self.ent_coef_optimizer is not None and (self.ent_coef_lr is not None or self.ent_coef_beta != 0.9):
            lr, betas = (
                self.lr_schedule(1) if self.ent_coef_lr is None else self.ent_coef_lr,
                (self.ent_coef_beta, 0.999),
            )
            self.ent_coef_optimizer = th.optim.Adam([self.log_ent_coef], lr=lr, betas=betas)  # type: ignore[arg-type]
        policies.check_encoder_setup(self, representation_model is not None)
        # Augmentation and the objectives draw from generators of their own: SAC's random streams stay SB3's SAC's.
        seeds = derived_seeds(self.seed)
        self._augment_generator = th.Generator(device=self.device).manual_seed(seeds["augmentation"])
        self.representation_model = representation_model
        if representation_model is not None:
            objectives.set_up_representation(representation_model, self, seeds["representation"])
        self._encoder_pairs, self._head_pairs = target_pairs(self.critic, self.critic_target)
        self._adopt_env_domains()
        self.weighting = self._new_weighting()

    def _new_weighting(self) -> SampleWeighting | None:
        with th.random.fork_rng(devices=[]):  # wherever a weighting is made, SAC's random streams stay SB3's
            return self._make_weighting()

    def _make_weighting(self) -> SampleWeighting | None:
        """The sample weighting of the losses (made once the SAC model exists); none here: SAC's losses."""
        return None

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        # Switch to train mode (this affects batch norm / dropout)
        self.policy.set_training_mode(True)
        # Update optimizers learning rate
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None and self.ent_coef_lr is None:  # + unless its rate is its own
            optimizers += [self.ent_coef_optimizer]

        # Update learning rate according to lr schedule
        self._update_learning_rate(optimizers)
        update = self._prepare_update()  # + the runner of the eager or captured update

        for gradient_step in range(gradient_steps):
            # Sample replay buffer (+ copied into the captured graphs' static inputs)
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            replay_data = update.inputs("batch", replay_data)  # +
            # + the host's decisions for this step (which parts learn): one captured graph per plan
            plan = self._plan(self._n_updates + gradient_step, gradient_step)
            # + views of the observations for the critic (the first also the actor's), of the next ones for its target
            # (without augmentation, the batch itself: nothing to capture)
            views = update.run if self.augmentation_views else lambda _, piece, *args: piece(*args)
            observations, next_observations = views("views", self._views, replay_data)
            # + what the sample weighting needs the host for before the step (SGFD: fresh batches, a classifier round)
            if self.weighting is not None:
                self.weighting.before_step(self, update, replay_data, observations, plan.weighting)
            update.run(plan, self._gradient_step, replay_data, observations, next_observations, plan)  # +

        self._n_updates += gradient_steps

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        update.finish(self.logger, self._n_updates)  # + the figures read (captured: once per log interval), finiteness

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
        critic_outputs = [policies.critic_and_features(self.critic, obs, replay_data.actions) for obs in observations]
        current_q_values = [q_values for q_values, _ in critic_outputs]
        z = critic_outputs[0][1].detach()  # +

        # We need to sample because `log_std` may have changed between two gradient steps
        if self.use_sde:
            self.actor.reset_noise()

        if plan.update_actor:
            # Action by the current actor for the sampled state
            actions_pi, log_prob = policies.actor_action_log_prob(self.policy, observations[0], z)
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

        # + the sample weighting's weights (n, 1) of the critic's and the actor's losses from the first view's features
        # (SGFD's; None: unweighted, SAC's)
        weighting, update = self.weighting, self._update
        weights = (
            LossWeights() if weighting is None else weighting.loss_weights(self, update, replay_data, z, plan.weighting)
        )

        # Compute critic loss  (+ mean over views, weighted per sample)
        critic_loss = sum(
            0.5 * sum(weighted_mean((current_q - target_q_values) ** 2, weights.critic) for current_q in view)
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
            batch = objectives.Batch(replay_data, observations, next_observations, plan.objective)
            for key, value in self.representation_model.update(self, batch).items():
                self.record(f"{self.representation}/{key}", value)

        if plan.update_actor:
            # Min over all critic networks (+ on this step's features of the batch: no second encoder pass)
            q_pi = policies.actor_q_values(self.policy, observations[0], z, actions_pi, self.actor_reuses_features)
            q_values_pi = th.cat(q_pi, dim=1)
            min_qf_pi, _ = th.min(q_values_pi, dim=1, keepdim=True)
            actor_loss = weighted_mean(ent_coef * log_prob - min_qf_pi, weights.actor)  # + weighted
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
        self._update.end_step()  # +

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
        """``augment`` of a batch's observations, and of its next observations."""
        return self.augment(replay_data.observations), self.augment(replay_data.next_observations)

    def augment(self, observations: th.Tensor) -> list[th.Tensor]:
        """``augmentation_views`` random shifts of a batch of (n, C, H, W) images as the replay buffer returns them,
        or the batch itself without augmentation."""
        pad, generator = self.augmentation_pad, self._augment_generator
        views = [random_shift(observations, pad, generator) for _ in range(self.augmentation_views)]
        return views or [observations]

    def _plan(self, update_index: int, gradient_step: int) -> StepPlan:
        """What the host decides for the step (its index over the run, and in this ``train`` call, which SAC's target
        updates count): each part whose Python code branches on the update says so here, so that one captured graph
        per plan replays exactly what the eager step would run."""
        objective = () if self.representation_model is None else self.representation_model.plan(update_index)
        update_actor = update_index % self.actor_update_interval == 0
        return StepPlan(
            update_actor=update_actor,
            update_target=gradient_step % self.target_update_interval == 0,
            objective=objective,
            weighting=() if self.weighting is None else self.weighting.plan(self, update_index, update_actor),
        )

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
        """The generators it draws from beside the global ones, by name (a checkpoint saves their states)."""
        generators = {"augmentation": self._augment_generator}
        if self.representation_model is not None:
            generators["representation"] = self.representation_model.generator
        if self.weighting is not None:
            generators.update(self.weighting.generators())
        return generators

    def _update_optimizers(self) -> list[th.optim.Optimizer]:
        """Every optimiser a gradient step steps."""
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        for part in (self.representation_model, self.weighting):
            if part is not None:
                optimizers += [getattr(part, name) for name in part.optimizer_names()]
        return optimizers

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), *UNSAVED]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, saved_pytorch_variables = super()._get_torch_save_params()
        for name in ("representation_model", "weighting"):
            part = getattr(self, name)
            if part is not None:
                state_dicts = [*state_dicts, name, *(f"{name}.{optimizer}" for optimizer in part.optimizer_names())]
        return state_dicts, saved_pytorch_variables

    # --- The update's runner, figures and logs (UpdateRunner), SB3's save and load kept ---

    def _prepare_update(self) -> UpdateRunner:
        """The update's runner for this ``train`` call (made afresh for another device or ``compile_update``)."""
        if not self._update.fits(self.device, self.compile_update):
            self._update = self._new_runner(self.device, self._n_updates)
        self._update.start(self._update_optimizers, self._n_updates)
        return self._update

    def _new_runner(self, device: th.device, n_updates: int = 0) -> UpdateRunner:
        return UpdateRunner(device, self.compile_update, lambda: self.generators().values(), n_updates)

    def record(
        self, key: str, value: float | th.Tensor, check_finite: str | None = None, when: th.Tensor | None = None
    ) -> None:
        """Log a figure of this gradient step (:meth:`UpdateRunner.record`)."""
        self._update.record(key, value, check_finite, when)

    def fresh_batch(self, name: str, n_samples: int) -> Any:
        """Another replay batch of ``n_samples``, through the static inputs ``name`` when captured."""
        batch = self.replay_buffer.sample(n_samples, env=self._vec_normalize_env)  # type: ignore[union-attr]
        return self._update.inputs(name, batch)

    def _update_learning_rate(self, optimizers: list[th.optim.Optimizer] | th.optim.Optimizer) -> None:
        # SB3's, with the rate set in place where it is a tensor (a captured graph reads it there)
        self.logger.record("train/learning_rate", self.lr_schedule(self._current_progress_remaining))
        for optimizer in optimizers if isinstance(optimizers, list) else [optimizers]:
            set_learning_rate(optimizer, self.lr_schedule(self._current_progress_remaining))

    def learn(  # type: ignore[override]
        self: SelfEncoderSAC,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfEncoderSAC:
        """SB3's ``learn``; its TensorBoard runs are named after the algorithm (``SGFD_SAC_1``, ``DBC_1``, ...) unless
        ``tb_log_name`` says otherwise."""
        name = type(self).__name__ if tb_log_name is None else tb_log_name
        return super().learn(total_timesteps, callback, log_interval, name, reset_num_timesteps, progress_bar)

    def dump_logs(self) -> None:
        self._update.flush(self.logger)  # + a captured update's figures, once per log interval
        super().dump_logs()

    def set_parameters(
        self, load_path_or_dict: str | dict[str, Any], exact_match: bool = True, device: th.device | str = "auto"
    ) -> None:
        super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)
        self._update.forget()

    def save(self, *args: Any, **kwargs: Any) -> None:
        self._update.figures.raise_if_not_finite()  # nothing non-finite is saved
        self.sb3_sgfd_version = __version__  # a later load refuses a file newer than its code, in one line
        super().save(*args, **kwargs)

    # --- The envs' domains and the domain replay buffer (sb3_sgfd.common.buffer_setup) ---

    def _domain_count(self) -> int:
        """The number of domain labels the model takes from its envs (SGFD_SAC's ``n_domains`` overrides it)."""
        return buffer_setup.env_domain_count(self.env)  # type: ignore[arg-type]

    def _adopt_env_domains(self) -> None:
        """Let the replay buffer take every label of the envs attached now."""
        if self.env is not None:
            buffer_setup.adopt_env_domains(self, self._domain_count())

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)
        self._adopt_env_domains()

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        self._adopt_env_domains()
