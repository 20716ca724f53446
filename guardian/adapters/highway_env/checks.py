"""What the guardian accepts of a highway-env environment's configuration, said once.

Two kinds of limits, each refused with a ``ConfigError`` that names the key and the value:

* **values** (``check_config``): a config key must have the kind of value its class's default has (a
  number where the default is a number, ``true``/``false`` where it is a boolean, text, a list, an
  object); the keys whose range matters to a run must lie in it (frequencies and durations positive, a
  policy step no shorter than a simulation step, car and lane counts whole and not negative). highway-env
  checks none of this: ``policy_frequency=0`` divides by zero in the guardian, a negative one never ends
  an episode, and ``"abc"`` fails deep in the first step;
* **what the env can do** (``merge_limits``): highway-env's ``MergeEnv`` family (``merge-v0/v1``,
  ``merge-generic-v0``) computes its reward from a discrete action (``action in [0, 2]``) and spawns one
  ego, so it cannot take continuous actions nor several controlled cars; ``guardian/Merge-v0`` is its
  road and traffic for both.

The command line (``--env-config``, ``--action``, ``--controlled``) and the ``Guardian`` wrapper (the
env's config when it is wrapped) ask the same functions.
"""
from __future__ import annotations

import difflib
import math
from numbers import Real

import numpy as np

from guardian.errors import ConfigError

POSITIVE = ("simulation_frequency", "policy_frequency", "duration", "vehicles_density")
WHOLE = {"vehicles_count": 0, "controlled_vehicles": 1, "lanes_count": 1, "traffic_count": 0,
         "traffic_from_behind": 0}  # key: the least whole number it may be

MERGE_NOTE = ("highway-env's {env} {what} (MergeEnv: its reward reads a discrete action, `action in [0, 2]`, "
              "and it spawns one ego); guardian/Merge-v0 is merge-v0's road and traffic for both action types and "
              "several controlled cars (env config traffic=easy|medium|hard for the merging reference's modes)")


def _kind(value) -> str | None:
    """The kind of a config value a default fixes, or None where any value may do."""
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, Real):
        return "a number"
    if isinstance(value, str):
        return "text"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return None


def _is(value, kind: str) -> bool:
    if kind == "a number":
        return isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)
    return _kind(value) == kind


def check_config(defaults: dict, config: dict, where: str) -> None:
    """Refuse a value of ``config`` that is not of its default's kind or out of its range (module docstring).

    ``defaults`` is the env class's ``default_config()``; keys it lacks are ``check_keys``' business;
    ``where`` names the env in the message.
    """
    for key, value in config.items():
        if key not in defaults:
            continue
        kind = _kind(defaults[key])
        if kind is not None and not _is(value, kind):
            raise ConfigError(f"{where}: config {key!r} must be {kind}, got {value!r}")
        if key in POSITIVE and value is not None and not (_is(value, "a number") and value > 0):
            raise ConfigError(f"{where}: config {key!r} must be a positive number, got {value!r}")
        if key in WHOLE and value is not None and not (isinstance(value, int) and not isinstance(value, bool)
                                                       and value >= WHOLE[key]):
            raise ConfigError(f"{where}: config {key!r} must be a whole number >= {WHOLE[key]}, got {value!r}")
    merged = {**defaults, **config}
    sim, policy = merged.get("simulation_frequency"), merged.get("policy_frequency")
    if _is(sim, "a number") and _is(policy, "a number") and sim > 0 and policy > sim:
        raise ConfigError(f"{where}: config 'policy_frequency' {policy!r} is above 'simulation_frequency' {sim!r}: "
                          "a policy step would simulate nothing")


def env_class(env_id: str):
    """The class a registered env id makes (its entry point), without making one."""
    import importlib

    import gymnasium as gym

    entry = gym.spec(env_id).entry_point
    if callable(entry):
        return entry
    module, _, name = entry.partition(":")
    return getattr(importlib.import_module(module), name)


def action_types(env_id: str, config: dict) -> tuple:
    """The action type a config gives the env (its own default when the config has none) and, under
    ``MultiAgentAction``, each car's inner type (else the same type twice)."""
    action = config.get("action") or env_class(env_id).default_config()["action"]
    kind = action.get("type")
    inner = (action.get("action_config") or {}).get("type") if kind == "MultiAgentAction" else kind
    return kind, inner


def _merge_env_class():
    from highway_env.envs.merge_env import MergeEnv

    return MergeEnv


def discrete_reward(env_class) -> bool:
    """Whether the env reads its reward from a discrete action: MergeEnv's own ``_rewards``."""
    merge = _merge_env_class()
    return issubclass(env_class, merge) and env_class._rewards is merge._rewards


def one_ego(env_class) -> bool:
    """Whether the env spawns one controlled car whatever its config: MergeEnv's own ``_make_vehicles``."""
    from highway_env.envs.merge_env import MergeGenericEnv

    merge = _merge_env_class()
    return issubclass(env_class, merge) and env_class._make_vehicles in (merge._make_vehicles,
                                                                         MergeGenericEnv._make_vehicles)


def merge_limits(env_class, env_name: str, continuous: bool, multi_agent: bool) -> None:
    """Refuse continuous actions or ``MultiAgentAction`` on an env of MergeEnv's family that cannot take
    them (module docstring; its reward would read a tuple as no lane change), pointing to ``guardian/Merge-v0``."""
    if continuous and discrete_reward(env_class):
        raise ConfigError(MERGE_NOTE.format(env=env_name, what="fails with ContinuousAction"))
    if multi_agent and (one_ego(env_class) or discrete_reward(env_class)):
        raise ConfigError(MERGE_NOTE.format(env=env_name, what="has one controlled car"))


# ---- an env's action type, as the guardian supervises it -----------------------------------------------------
ACTION_TYPES = ("ContinuousAction", "DiscreteAction", "DiscreteMetaAction")
META_ACTIONS = ["LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER"]


def multi_agent(base) -> bool:
    """Does the env control several cars (highway-env's ``MultiAgentAction``)?"""
    return type(getattr(base, "action_type", None)).__name__ == "MultiAgentAction"


def controlled_action_types(base) -> list:
    """The action type of each supervised car (one, or each agent's of a ``MultiAgentAction``)."""
    if multi_agent(base):
        return list(base.action_type.agents_action_types)
    return [base.action_type]


def controlled_vehicles(base) -> list:
    """The guarded cars: highway-env's controlled cars under ``MultiAgentAction``, else the ego."""
    return list(base.controlled_vehicles) if multi_agent(base) else [base.vehicle]


def action_kind(base) -> str:
    """``DiscreteMetaAction`` or ``ContinuousAction`` (highway-env's ``DiscreteAction`` is a grid of the
    latter; either may control one axis only, the env then holds the other at 0); a ConfigError for an
    action type the guardian cannot supervise."""
    kinds = set()
    for at in controlled_action_types(base):
        kind = type(at).__name__
        if kind not in ACTION_TYPES:
            raise ConfigError(f"Guardian: config 'action.type' {kind!r} cannot be supervised; use one of {ACTION_TYPES}"
                              " (or MultiAgentAction of one of them)")
        if kind == "DiscreteMetaAction" and list(at.actions.values()) != META_ACTIONS:
            raise ConfigError("Guardian: config 'action' must offer all five meta actions "
                              "('longitudinal' and 'lateral' true)")
        if getattr(at, "dynamical", False):
            raise ConfigError("Guardian: config 'action.dynamical' true (highway-env's dynamic bicycle, with tyre "
                              "slip and yaw inertia) cannot be supervised: the guardian's ego model is the kinematic "
                              "bicycle; leave 'dynamical' false")
        kinds.add("DiscreteMetaAction" if kind == "DiscreteMetaAction" else "ContinuousAction")
    if len(kinds) != 1:
        raise ConfigError("Guardian: every controlled car must have the same action type")
    return kinds.pop()


def check_keys(defaults: dict, config: dict, where: str) -> None:
    """Refuse a key of ``config`` its env class's ``default_config()`` lacks: highway-env takes a misspelt key
    (``lanes_cout``) without a word and runs with the default."""
    unknown = sorted(set(config) - set(defaults))
    if unknown:
        near = {k: difflib.get_close_matches(k, list(defaults), n=1) for k in unknown}
        said = ", ".join(f"{k!r}" + (f" (did you mean {near[k][0]!r}?)" if near[k] else "") for k in unknown)
        raise ConfigError(f"{where}: the env has no config key {said}")


def check_env(base) -> str:
    """Refuse an env the guardian cannot supervise (its config, its action type); the action kind."""
    kind = action_kind(base)
    name = base.spec.id if base.spec is not None else type(base).__name__
    merge_limits(type(base), name, kind == "ContinuousAction", multi_agent(base))   # the env's own words first
    check_keys(type(base).default_config(), base.config, f"Guardian: {name}")
    check_config(type(base).default_config(), base.config, f"Guardian: {name}")
    return kind


def check_action(space, action) -> None:
    """Refuse an action outside the env's action space in one line naming it: a discrete action must be one
    of the space's; a continuous one must have the space's shape and finite values (values beyond the
    bounds are clipped to them, as highway-env does); a tuple (several controlled cars) one per car."""
    from gymnasium import spaces

    where = f"Guardian.step: action {action!r}"
    if isinstance(space, spaces.Tuple):
        if not isinstance(action, (tuple, list)) or len(action) != len(space.spaces):
            raise ValueError(f"{where} is not a tuple of {len(space.spaces)} actions, one per controlled car")
        for sub, a in zip(space.spaces, action):
            check_action(sub, a)
        return
    if isinstance(space, spaces.Box):
        try:
            values = np.asarray(action, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{where} is not a vector of numbers for {space}") from None
        if values.shape != space.shape or not np.all(np.isfinite(values)):
            raise ValueError(f"{where} is not {space.shape[0] if space.shape else 1} finite number(s) for {space}")
        return
    if not space.contains(action):
        raise ValueError(f"{where} is not in the env's action space {space}")
