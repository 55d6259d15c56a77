"""How an agent sets up its domain replay buffer and keeps it fitting its envs: the buffer class for its
observations (flat, images or Dict), what its objective needs, SAC's n-step returns, and the envs' number of
domain labels, kept up to date when the model is given other envs (SB3's ``load(path, env=...)``, ``set_env``) or
another replay buffer (``load_replay_buffer``).

Plain envs (without an ``n_domains`` attribute) label each sub-env by its index, so a model loaded onto more
sub-envs sees more labels: the replay buffer must take them."""

from __future__ import annotations

import io
import pathlib
from typing import Any

from gymnasium import spaces
from stable_baselines3.common.type_aliases import GymEnv

from sb3_sgfd.common.buffers import DomainDictReplayBuffer, DomainReplayBuffer
from sb3_sgfd.common.representation import Representation

#: SB3 warns that a custom buffer class does not take ``n_steps``: the domain buffers do (``_domain_buffer_kwargs``),
#: so the warning is silenced for them only (:meth:`DomainBufferMixin._buffer_takes_n_steps`)
N_STEPS_IGNORED_WARNING = "`n_steps="
#: the replay buffers that store domain labels
DOMAIN_BUFFERS = (DomainReplayBuffer, DomainDictReplayBuffer)


class DomainBufferMixin:
    """Mixed into :class:`~sb3_sgfd.common.encoder_sac.EncoderSAC` (before SB3's ``SAC``); needs SB3's ``env``,
    ``observation_space``, ``replay_buffer`` and its class and kwargs, ``n_steps`` and ``gamma``."""

    env: Any
    observation_space: spaces.Space
    replay_buffer: Any
    replay_buffer_class: Any
    replay_buffer_kwargs: dict[str, Any]
    n_steps: int
    gamma: float
    representation: str | None
    augmentation_views: int

    def _prepare_replay_buffer(self, representation_model: Representation | None) -> None:
        """Set the buffer class and kwargs before SB3 builds the buffer: the Dict variant for Dict observations
        (which no encoder objective reads), same-episode negatives for an objective that needs them (TED), the
        envs' label count and the n-step returns."""
        buffer_class = self.replay_buffer_class
        domain_buffer = buffer_class is not None and issubclass(buffer_class, DOMAIN_BUFFERS)
        if isinstance(self.observation_space, spaces.Dict):
            if representation_model is not None or self.augmentation_views:
                what = f"the {self.representation!r} representation" if representation_model else "augmentation"
                raise ValueError(
                    f"{what} reads image or flat observations, not Dict ones; train without it "
                    "(representation=None, augmentation_views=0) or flatten the observations"
                )
            if buffer_class is DomainReplayBuffer:
                self.replay_buffer_class = DomainDictReplayBuffer
        if representation_model is not None and representation_model.needs_same_episode:
            if not domain_buffer:
                raise ValueError(f"the {self.representation!r} representation needs a DomainReplayBuffer")
            self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, "same_episode_negatives": True}
        if domain_buffer:
            self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, **self._domain_buffer_kwargs()}

    def _buffer_takes_n_steps(self) -> bool:
        """Whether SAC's ``n_steps`` > 1 go to the buffer class set up (a domain buffer takes them), so that SB3's
        warning that a custom buffer class ignores them would be wrong; any other class does ignore them."""
        buffer_class = self.replay_buffer_class
        return self.n_steps > 1 and buffer_class is not None and issubclass(buffer_class, DOMAIN_BUFFERS)

    def _domain_buffer_kwargs(self) -> dict[str, Any]:
        """What the domain replay buffer needs from the model: the envs' label count (it refuses a label outside
        it) and SAC's n-step returns (SB3 sets them up for its own buffers only)."""
        kwargs: dict[str, Any] = {}
        if self.env is not None:
            kwargs["n_domains"] = max(self.replay_buffer_kwargs.get("n_domains") or 1, self._domain_count())
        if self.n_steps > 1:
            kwargs.update(n_steps=self.n_steps, gamma=self.gamma)
        return kwargs

    def _domain_count(self) -> int:
        """The number of domain labels of the envs: their largest ``n_domains`` attribute, or the number of
        sub-envs if they have none (SGFD_SAC's ``n_domains`` overrides it)."""
        return self._env_domain_count()

    def _env_domain_count(self) -> int:
        """The envs' own number of domain labels (see :meth:`_domain_count`)."""
        # has_attr first: a SubprocVecEnv's worker dies on a missing attribute instead of raising it here
        if not self.env.has_attr("n_domains"):
            return int(self.env.num_envs)
        return max(int(count) for count in self.env.get_attr("n_domains"))

    def _adopt_env_domains(self) -> None:
        """Let the replay buffer take every label of the envs attached now (it refuses a label outside
        [0, n_domains) where it enters): a model saved with fewer domains or sub-envs learns on with more."""
        buffer = self.replay_buffer
        domain_buffer = isinstance(buffer, DOMAIN_BUFFERS)
        if self.env is None or not domain_buffer or buffer.n_domains is None:
            return
        buffer.n_domains = max(buffer.n_domains, self._domain_count())
        self.replay_buffer_kwargs["n_domains"] = buffer.n_domains

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)  # type: ignore[misc]
        self._adopt_env_domains()

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)  # type: ignore[misc]
        self._adopt_env_domains()
