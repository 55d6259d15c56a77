"""How an agent sets up its domain replay buffer and keeps it fitting its envs: the buffer class for its
observations (flat, images or Dict), what its objective needs, SAC's n-step returns, and the envs' number of
domain labels, kept up to date when the model is given other envs (SB3's ``load(path, env=...)``, ``set_env``) or
another replay buffer (``load_replay_buffer``). :class:`~sb3_sgfd.common.encoder_sac.EncoderSAC` calls these.

Plain envs (without an ``n_domains`` attribute) label each sub-env by its index, so a model loaded onto more
sub-envs sees more labels: the replay buffer must take them."""

from __future__ import annotations

from typing import Any

from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from sb3_sgfd.common.buffers import DomainDictReplayBuffer, DomainReplayBuffer
from sb3_sgfd.common.representation import Representation

#: SB3 warns that a custom buffer class does not take ``n_steps``: the domain buffers do (:func:`domain_buffer_kwargs`),
#: so the warning is silenced for them only (:func:`buffer_takes_n_steps`)
N_STEPS_IGNORED_WARNING = "`n_steps="
#: the replay buffers that store domain labels
DOMAIN_BUFFERS = (DomainReplayBuffer, DomainDictReplayBuffer)


def prepare_replay_buffer(model: Any, representation_model: Representation | None, domain_count: int) -> None:
    """Set the model's buffer class and kwargs before SB3 builds the buffer: the Dict variant for Dict observations
    (which no encoder objective reads), same-episode negatives for an objective that needs them (TED), the envs'
    label count and the n-step returns.

    :param model: the algorithm (SB3's ``observation_space``, ``replay_buffer_class`` and kwargs, ``n_steps``,
        ``gamma``, ``env``; EncoderSAC's ``representation`` and ``augmentation_views``)
    :param representation_model: its encoder objective, or None
    :param domain_count: the number of domain labels of its envs
    """
    buffer_class = model.replay_buffer_class
    domain_buffer = buffer_class is not None and issubclass(buffer_class, DOMAIN_BUFFERS)
    if isinstance(model.observation_space, spaces.Dict):
        if representation_model is not None or model.augmentation_views:
            what = f"the {model.representation!r} representation" if representation_model else "augmentation"
            raise ValueError(
                f"{what} reads image or flat observations, not Dict ones; train without it "
                "(representation=None, augmentation_views=0) or flatten the observations"
            )
        if buffer_class is DomainReplayBuffer:
            model.replay_buffer_class = DomainDictReplayBuffer
    if representation_model is not None and representation_model.needs_same_episode:
        if not domain_buffer:
            raise ValueError(f"the {model.representation!r} representation needs a DomainReplayBuffer")
        model.replay_buffer_kwargs = {**model.replay_buffer_kwargs, "same_episode_negatives": True}
    if domain_buffer:
        model.replay_buffer_kwargs = {**model.replay_buffer_kwargs, **domain_buffer_kwargs(model, domain_count)}


def buffer_takes_n_steps(model: Any) -> bool:
    """Whether SAC's ``n_steps`` > 1 go to the buffer class set up (a domain buffer takes them), so that SB3's
    warning that a custom buffer class ignores them would be wrong; any other class does ignore them."""
    buffer_class = model.replay_buffer_class
    return model.n_steps > 1 and buffer_class is not None and issubclass(buffer_class, DOMAIN_BUFFERS)


def domain_buffer_kwargs(model: Any, domain_count: int) -> dict[str, Any]:
    """What the domain replay buffer needs from the model: the envs' label count (it refuses a label outside
    it) and SAC's n-step returns (SB3 sets them up for its own buffers only)."""
    kwargs: dict[str, Any] = {}
    if model.env is not None:
        kwargs["n_domains"] = max(model.replay_buffer_kwargs.get("n_domains") or 1, domain_count)
    if model.n_steps > 1:
        kwargs.update(n_steps=model.n_steps, gamma=model.gamma)
    return kwargs


def env_domain_count(env: VecEnv) -> int:
    """The envs' number of domain labels: their largest ``n_domains`` attribute, or the number of sub-envs if they
    have none."""
    # has_attr first: a SubprocVecEnv's worker dies on a missing attribute instead of raising it here
    if not env.has_attr("n_domains"):
        return int(env.num_envs)
    return max(int(count) for count in env.get_attr("n_domains"))


def adopt_env_domains(model: Any, domain_count: int) -> None:
    """Let the model's replay buffer take every label of the envs attached now (it refuses a label outside
    [0, n_domains) where it enters): a model saved with fewer domains or sub-envs learns on with more.

    :param model: the algorithm (its ``env``, ``replay_buffer`` and ``replay_buffer_kwargs``)
    :param domain_count: the number of domain labels the model takes from its envs
    """
    buffer = model.replay_buffer
    if model.env is None or not isinstance(buffer, DOMAIN_BUFFERS) or buffer.n_domains is None:
        return
    buffer.n_domains = max(buffer.n_domains, domain_count)
    model.replay_buffer_kwargs["n_domains"] = buffer.n_domains
