"""The zoo's checks of a configuration, before anything is built: every key known, every value one its
taker accepts, the policy able to read the observations, the env settings the env takes. Each refusal is a
one-line :class:`~sgfd_zoo.arguments.ZooError` naming the key, the value and what fits."""

from __future__ import annotations

import contextlib
import difflib
import inspect
from collections.abc import Iterator
from typing import Any

import rl_zoo3.exp_manager
from rl_zoo3.utils import ALGOS, get_class_by_name
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.torch_layers import FlattenExtractor, NatureCNN

from sb3_sgfd.policies import MlpEncoder, PixelEncoder
from sb3_sgfd.representation import REPRESENTATIONS
from sgfd_zoo.arguments import ZooError, check_keywords

# Keys rl-zoo3 consumes itself before the rest goes to the algorithm's constructor.
ZOO_KEYS = {
    "n_timesteps",
    "n_envs",
    "env_kwargs",
    "frame_stack",
    "normalize",
    "env_wrapper",
    "vec_env_wrapper",
    "callback",
    "monitor_kwargs",
    "noise_type",
    "noise_std",
}
# Hyperparameters that hold keyword arguments; a string is a Python expression, as rl-zoo3 reads policy_kwargs.
KWARGS_KEYS = ("policy_kwargs", "replay_buffer_kwargs", "representation_kwargs")
# What SB3 passes a replay buffer itself, besides replay_buffer_kwargs.
BUFFER_ARGUMENTS = {"buffer_size", "observation_space", "action_space", "device", "n_envs", "optimize_memory_usage"}


@contextlib.contextmanager
def env_kwargs_checked(env_kwargs: dict[str, Any]) -> Iterator[None]:
    """The ValueError or TypeError of an env built with ``env_kwargs`` (sgfd_envs names the kwarg and those the
    id takes) as a one-line ZooError."""
    try:
        yield
    except (ValueError, TypeError) as error:
        raise ZooError(f"env_kwargs {env_kwargs}: {first_line(error)}") from error


def constructor_arguments(algo_class: type) -> set[str]:
    """The keyword arguments ``algo_class`` takes, following ``**kwargs`` up to the base class that has them."""
    names: set[str] = set()
    for cls in algo_class.__mro__:
        if "__init__" not in vars(cls):
            continue
        parameters = inspect.signature(cls.__init__).parameters
        names |= {name for name, p in parameters.items() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
        if not any(p.kind == p.VAR_KEYWORD for p in parameters.values()):
            break
    return names - {"self", "env"}


def observes_pixels(env_kwargs: dict[str, Any]) -> bool:
    """Whether the SGFD ids give image observations with these env kwargs (their default: pixels)."""
    return env_kwargs.get("obs_type", "pixels") == "pixels"


def check_policy_fits(algo: str, hyperparams: dict[str, Any], pixels: bool) -> None:
    """A ZooError, naming the flags that fit, when the configuration's policy cannot read the observations:
    an image encoder on states, a flattening policy on pixels, encoder arguments for a policy that has none,
    or image augmentation on states.

    :param algo: algorithm key
    :param hyperparams: the processed hyperparameters (policy, policy_kwargs, ...)
    :param pixels: whether the env gives images
    """
    policy = hyperparams.get("policy")
    policy_class = policy_class_of(algo, policy)
    name = policy if isinstance(policy, str) else getattr(policy, "__name__", str(policy))
    kwargs = hyperparams.get("policy_kwargs") or {}
    extractor = kwargs.get("features_extractor_class") or default_extractor(policy_class)
    seen = "pixel" if pixels else "state"
    fixes = (
        "use --quick (the state configuration) or leave out obs_type:'state'"
        if not pixels
        else "use the paper-scale configuration (no --quick) or --env-kwargs obs_type:'state'"
    )
    if extractor is not None and issubclass(extractor, (PixelEncoder, NatureCNN)) and not pixels:
        raise ZooError(f"policy {name!r} of {algo} encodes images, but the env gives {seen} observations: {fixes}")
    if extractor is not None and issubclass(extractor, (FlattenExtractor, MlpEncoder)) and pixels:
        raise ZooError(f"policy {name!r} of {algo} reads flat states, but the env gives {seen} observations: {fixes}")
    if extractor is FlattenExtractor and kwargs.get("features_extractor_kwargs"):
        raise ZooError(
            f"policy {name!r} of {algo} flattens the observations and takes no features_extractor_kwargs "
            f"({kwargs['features_extractor_kwargs']}): use --quick, or policy 'EncoderMlpPolicy' for a learned encoder"
        )
    if hyperparams.get("augmentation_views") and not pixels:
        raise ZooError(f"{algo} shifts images (augmentation_views), but the env gives state observations: {fixes}")


def policy_class_of(algo: str, policy: str | type | None) -> type | None:
    """The policy class a ``policy`` hyperparameter names: an alias of the algorithm, a dotted path, or a class."""
    if not isinstance(policy, str):
        return policy
    policy_class = ALGOS[algo].policy_aliases.get(policy)
    if policy_class is None and "." in policy:
        policy_class = get_class_by_name(policy)
    return policy_class


def default_extractor(policy_class: type | None) -> type | None:
    """The features extractor a policy class uses when none is given; None when it follows the observations."""
    if policy_class is None:
        return None
    if hasattr(policy_class, "default_features_extractor_class"):
        return policy_class.default_features_extractor_class
    default = inspect.signature(policy_class.__init__).parameters.get("features_extractor_class")
    return default.default if default is not None and isinstance(default.default, type) else None


def kwargs_value(key: str, value: Any) -> dict[str, Any] | None:
    """A kwargs hyperparameter as a dict: a string is evaluated as rl-zoo3 evaluates ``policy_kwargs`` (with
    the names its module sees: ``nn``, ``th``, ...); anything else but a dict or None is refused, by name.

    :param key: the hyperparameter, e.g. ``representation_kwargs``
    :param value: its value in the yaml or ``-params``
    """
    if isinstance(value, str):
        try:
            value = eval(value, dict(vars(rl_zoo3.exp_manager)))
        except Exception as error:
            reason = f"{type(error).__name__}: {error}"
            raise ZooError(f"{key}: {value!r} is not a Python dict expression ({reason})") from None
    if value is not None and not isinstance(value, dict):
        raise ZooError(f'{key} must be a dict, or a string such as "dict(key=value)", got {value!r}')
    return value


def keyword_arguments(cls: type, filled: set[str] = frozenset(), follow_var_keyword: bool = True) -> set[str] | None:
    """The keyword arguments a user may give ``cls`` (less those its caller ``filled`` itself), following
    ``**kwargs`` up the base classes (SB3's policies hand theirs to their base); None when ``cls`` takes
    ``**kwargs`` it does not hand up (``follow_var_keyword=False``), so that its keys cannot be known.

    :param cls: a class
    :param filled: arguments its caller passes itself
    :param follow_var_keyword: follow ``**kwargs`` up the MRO
    """
    if not follow_var_keyword:
        parameters = inspect.signature(cls.__init__).parameters
        if any(p.kind == p.VAR_KEYWORD for p in parameters.values()):
            return None
    return constructor_arguments(cls) - filled - {"self"}


def default_argument(cls: type, name: str) -> Any:
    """The default of ``cls``'s constructor argument ``name``, from the first class of its MRO that has it."""
    for base in cls.__mro__:
        if "__init__" in vars(base):
            parameter = inspect.signature(base.__init__).parameters.get(name)
            if parameter is not None:
                return parameter.default
    return None


def check_nested_kwargs(algo: str, hyperparams: dict[str, Any]) -> None:
    """Refuse unknown keys inside ``policy_kwargs`` (and its ``features_extractor_kwargs``),
    ``representation_kwargs`` and ``replay_buffer_kwargs``, naming each and the keys that class takes.

    :param algo: algorithm key
    :param hyperparams: the processed hyperparameters
    """
    algo_class = ALGOS[algo]
    policy_class = policy_class_of(algo, hyperparams.get("policy"))
    policy_kwargs = hyperparams.get("policy_kwargs") or {}
    if policy_class is not None:
        valid = keyword_arguments(policy_class, {"observation_space", "action_space", "lr_schedule"}) or set()
        check_keywords(f"policy_kwargs of {algo} ({policy_class.__name__})", policy_kwargs, valid)
    extractor = policy_kwargs.get("features_extractor_class") or default_extractor(policy_class)
    if isinstance(extractor, type) and policy_kwargs.get("features_extractor_kwargs"):
        valid = keyword_arguments(extractor, {"observation_space"}, follow_var_keyword=False)
        if valid is not None:  # one that hands **kwargs on (AMBSEncoder to its trunk) is checked when built
            where = f"features_extractor_kwargs of {algo} ({extractor.__name__})"
            check_keywords(where, policy_kwargs["features_extractor_kwargs"], valid)
    representation = hyperparams.get("representation", getattr(algo_class, "fixed_representation", None))
    if hyperparams.get("representation_kwargs") and representation in REPRESENTATIONS:
        representation_class = REPRESENTATIONS[representation]
        valid = keyword_arguments(representation_class) or set()
        where = f"representation_kwargs of {algo} ({representation!r}: {representation_class.__name__})"
        check_keywords(where, hyperparams["representation_kwargs"], valid)
    buffer_class = hyperparams.get("replay_buffer_class") or default_argument(algo_class, "replay_buffer_class")
    buffer_class = buffer_class or ReplayBuffer
    if hyperparams.get("replay_buffer_kwargs") and isinstance(buffer_class, type):
        valid = keyword_arguments(buffer_class, BUFFER_ARGUMENTS) or set()
        where = f"replay_buffer_kwargs of {algo} ({buffer_class.__name__})"
        check_keywords(where, hyperparams["replay_buffer_kwargs"], valid)


def first_line(error: BaseException) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[0] if lines else "(no message)"


def check_algo_kwargs(algo: str, hyperparams: dict[str, Any]) -> None:
    """Refuse yaml keys that neither rl-zoo3 nor the algorithm's constructor knows, naming close matches."""
    known = constructor_arguments(ALGOS[algo])
    unknown = sorted(set(hyperparams) - known - ZOO_KEYS)
    if unknown:
        hints = []
        for key in unknown:
            close = difflib.get_close_matches(key, known | ZOO_KEYS, n=1)
            hints.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise ZooError(f"unknown hyperparameter(s) for {algo}: {', '.join(hints)}")
