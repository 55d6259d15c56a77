"""The zoo's checks of a configuration, before anything is built: every key known, every value one its
taker accepts, the policy able to read the observations, the env settings the env takes. Each refusal is a
one-line :class:`~sgfd_zoo.arguments.ZooError` naming the key, the value and what fits."""

from __future__ import annotations

import contextlib
import inspect
from collections.abc import Iterator
from collections.abc import Set as AbstractSet
from typing import Any

import rl_zoo3.exp_manager
from rl_zoo3.utils import ALGOS, get_class_by_name
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.torch_layers import FlattenExtractor, NatureCNN

from sb3_sgfd.common.policies import MlpEncoder, PixelEncoder
from sb3_sgfd.common.representation import REPRESENTATIONS
from sb3_sgfd.common.validation import check_hyperparameters, check_non_negative_int, check_positive_int
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
def zoo_error() -> Iterator[None]:
    """A check's ValueError (one naming the value and what fits) as the zoo's one-line ZooError."""
    try:
        yield
    except ValueError as error:
        raise ZooError(first_line(error)) from None


@contextlib.contextmanager
def env_kwargs_checked(env_kwargs: dict[str, Any]) -> Iterator[None]:
    """The ValueError or TypeError of an env built with ``env_kwargs`` (sgfd_envs names the kwarg and those the
    id takes) as a one-line ZooError."""
    try:
        yield
    except (ValueError, TypeError) as error:
        raise ZooError(f"env_kwargs {env_kwargs}: {first_line(error)}") from error


# Env settings the zoo sets itself, per sub-env and per split, and why a configuration may not.
ZOO_ENV_KWARGS = {
    "split": "the zoo sets split itself: it trains on 'train' and evaluates on every split of the id ({splits})",
    "domain": "the zoo gives each sub-env its own domain (sub-env i: domain i % the split's number of domains)",
}


def merged_env_kwargs(configured: dict[str, Any] | None, given: dict[str, Any] | None) -> dict[str, Any]:
    """The env settings of a run: the configuration's, with those given on the command line (``--env-kwargs``)
    in their place, key by key (rl-zoo3 would replace the whole dict).

    :param configured: the yaml's ``env_kwargs``
    :param given: ``--env-kwargs``
    """
    if configured is not None and not isinstance(configured, dict):
        raise ZooError(f"env_kwargs must be a dict of env settings, got {configured!r}")
    return {**(configured or {}), **(given or {})}


def check_env_kwargs(env_id: str, env_kwargs: dict[str, Any], where: str = "env_kwargs") -> None:
    """Refuse, in one line, an env setting the id does not take (naming a close match and those it takes) and
    those the zoo sets itself (``split``, ``domain``), before any env is built.

    :param env_id: the env id
    :param env_kwargs: its settings
    :param where: how the message names them, e.g. ``--eval-env-kwargs``
    """
    import sgfd_envs
    from sgfd_envs.builders import env_kwargs_of

    for key, why in ZOO_ENV_KWARGS.items():
        if key in env_kwargs:
            splits = ", ".join(sgfd_envs.splits(env_id))
            raise ZooError(f"{where} {key}:{env_kwargs[key]!r}: {why.format(splits=splits)}; leave it out")
    allowed = [key for key in env_kwargs_of(env_id) if key not in ZOO_ENV_KWARGS]
    check_keywords(f"{where}: {env_id}", env_kwargs, allowed, "{where} does not take {keys}; it takes {valid}")


def rl_zoo3_schedule_start(key: str, value: Any) -> Any:
    """The value a hyperparameter starts at, where rl-zoo3 reads a string as a schedule (``lin_0.001``: linear
    from 0.001 to 0), read by rl-zoo3's own parser; a ZooError for a string it cannot read. Other values are
    returned as they are.

    :param key: a key rl-zoo3 reads schedules of, e.g. ``learning_rate``
    :param value: its value in the configuration
    """
    if not isinstance(value, str):
        return value
    try:
        schedule = rl_zoo3.exp_manager.ExperimentManager._preprocess_schedules({key: value})[key]
        return schedule.initial_value
    except (ValueError, AttributeError):  # AttributeError: a key rl-zoo3 reads no schedule of
        raise ZooError(
            f"{key} must be a number, or a schedule 'lin_<start>' (linear from <start> to 0), got {value!r}"
        ) from None


def check_zoo_values(hyperparams: dict[str, Any], steps_given: bool) -> None:
    """Refuse bad values of the keys rl-zoo3 consumes itself (the algorithm checks the rest): ``n_timesteps``
    (unless ``-n`` replaces it), ``n_envs``, ``frame_stack``.

    :param hyperparams: the configuration
    :param steps_given: ``-n`` was given
    """
    values = {}
    if not steps_given:
        steps = hyperparams.get("n_timesteps")
        if steps is None:
            raise ZooError("n_timesteps: the configuration has none; give the steps to train with -n")
        # a whole float too (yaml's 5e5), as rl-zoo3 reads it with int()
        values["n_timesteps"] = int(steps) if isinstance(steps, float) and steps.is_integer() else steps
    if hyperparams.get("n_envs") is not None:
        values["n_envs"] = hyperparams["n_envs"]
    frames = hyperparams.get("frame_stack")
    with zoo_error():
        check_positive_int(**values)
        if frames not in (None, False):  # 0 or false: no stacking
            check_non_negative_int(frame_stack=frames)


def interval_warnings(n_timesteps: int, eval_freq: int | None, save_freq: int | None) -> list[str]:
    """A warning for each interval longer than the run: what it was given for never comes.

    :param n_timesteps: the run's steps
    :param eval_freq: ``--eval-freq``, None when not given
    :param save_freq: ``--save-freq``, None when not given
    """
    intervals = []
    if eval_freq is not None:
        intervals.append(("--eval-freq", eval_freq, "it is not evaluated during training"))
    if save_freq is not None:
        intervals.append(("--save-freq", save_freq, "it has no periodic checkpoint (a Ctrl-C still saves one)"))
    return [
        f"warning: {flag} {steps} is more than the run's {n_timesteps} steps: {meaning}"
        for flag, steps, meaning in intervals
        if steps > n_timesteps
    ]


def check_algorithm_values(algo_class: type, hyperparams: dict[str, Any]) -> None:
    """The values the algorithm's constructor takes, checked before anything is built, on the configuration's
    values (before rl-zoo3 turns a learning rate into a schedule object): a schedule string rl-zoo3 cannot read
    is refused here, the rest by the algorithm's own check (:func:`sb3_sgfd.common.validation.check_hyperparameters`:
    SAC's arguments, the agent's own, SGFD's settings, the objective's ``representation_kwargs``); its ValueError
    becomes the zoo's one line.

    :param algo_class: the algorithm
    :param hyperparams: the configuration (kwargs hyperparameters already dicts)
    """
    values = {key: value for key, value in hyperparams.items() if key not in ZOO_KEYS}
    if "learning_rate" in values:
        values["learning_rate"] = rl_zoo3_schedule_start("learning_rate", values["learning_rate"])
    with zoo_error():
        check_hyperparameters(algo_class, values)


def constructor_arguments(algo_class: type) -> set[str]:
    """The keyword arguments ``algo_class`` takes, following ``**kwargs`` up to the base class that has them, and
    the settings it takes through them (``SGFD_SAC.settings_keywords``)."""
    names: set[str] = set(getattr(algo_class, "settings_keywords", ()))
    for cls in algo_class.__mro__:
        if "__init__" not in vars(cls):
            continue
        parameters = inspect.signature(vars(cls)["__init__"]).parameters
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
    default = inspect.signature(policy_class).parameters.get("features_extractor_class")
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


def keyword_arguments(
    cls: type, filled: AbstractSet[str] = frozenset(), follow_var_keyword: bool = True
) -> set[str] | None:
    """The keyword arguments a user may give ``cls`` (less those its caller ``filled`` itself), following
    ``**kwargs`` up the base classes (SB3's policies hand theirs to their base); None when ``cls`` takes
    ``**kwargs`` it does not hand up (``follow_var_keyword=False``), so that its keys cannot be known.

    :param cls: a class
    :param filled: arguments its caller passes itself
    :param follow_var_keyword: follow ``**kwargs`` up the MRO
    """
    if not follow_var_keyword:
        parameters = inspect.signature(cls).parameters
        if any(p.kind == p.VAR_KEYWORD for p in parameters.values()):
            return None
    return constructor_arguments(cls) - filled - {"self"}


def default_argument(cls: type, name: str) -> Any:
    """The default of ``cls``'s constructor argument ``name``, from the first class of its MRO that has it."""
    for base in cls.__mro__:
        if "__init__" in vars(base):
            parameter = inspect.signature(vars(base)["__init__"]).parameters.get(name)
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
        taken = keyword_arguments(extractor, {"observation_space"}, follow_var_keyword=False)
        if taken is not None:  # one that hands **kwargs on (AMBSEncoder to its trunk) is checked when built
            where = f"features_extractor_kwargs of {algo} ({extractor.__name__})"
            check_keywords(where, policy_kwargs["features_extractor_kwargs"], taken)
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
    """The first non-blank line of ``error``'s message: the zoo's errors are one line."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[0] if lines else "(no message)"


def check_algo_kwargs(algo: str, hyperparams: dict[str, Any]) -> None:
    """Refuse yaml keys that neither rl-zoo3 nor the algorithm's constructor knows, naming close matches."""
    known = constructor_arguments(ALGOS[algo]) | ZOO_KEYS
    check_keywords(algo, sorted(hyperparams), known, "unknown hyperparameter(s) for {where}: {keys}")


def changed_settings(printed: dict[str, Any], final: dict[str, Any], n_timesteps: int) -> str | None:
    """One line naming the settings a run uses that differ from those rl-zoo3 printed (the yaml's, with
    ``-params``): what the zoo set after it (``--classifier-start``, an ablation's switch, merged ``--env-kwargs``)
    and ``-n``. None when there are none.

    :param printed: the hyperparameters rl-zoo3 printed
    :param final: those the run uses
    :param n_timesteps: ``-n`` (0 or less: the yaml's)
    """
    changed = {key: value for key, value in final.items() if key not in printed or printed[key] != value}
    if n_timesteps > 0 and final.get("n_timesteps") != n_timesteps:
        changed["n_timesteps"] = n_timesteps
    if not changed:
        return None
    return "this run's settings where they differ from those above: " + ", ".join(
        f"{key} {value!r}" for key, value in sorted(changed.items())
    )
