"""``guardian rollout``: supervised rollouts of any supported environment (one loop, one tally).

``--env`` is ``guardian/Overtake-v0`` (the default: Section 6.5.3's two cars), ``guardian/HighwayOvertake-v0``
(the overtake among traffic), a ``highway-v0``-family id, ``merge-v0``, ``merge-generic-v0``, ``exit-v0`` or
``guardian/Merge-v0`` (merge-v0's road for both action types and several controlled cars). ``--controlled N``
gives N controlled cars (highway-env's ``MultiAgentAction``), each with its own agent and guardian;
``--overapprox ordered`` lets the guarded cars announce their lane changes to each other (Example 8's
order), ``trivial`` assumes nothing; the JSON then has the counts summed over the cars and per car
(``agents``). ``--agent`` names a driver of the agent
registry, ``all`` (Section 6.5.3's four: mpc, bad, careful, random) or is replaced by ``--policy``, a
stable-baselines3 policy file. Options that do not apply to the environment are refused.
"""
from __future__ import annotations

import json
import shlex
from dataclasses import replace
from pathlib import Path

from guardian.cli.common import (Parser, count, emit, intention_name, json_option, library_options, load_library,
                                 lag_seconds, output_file, output_folder, positive_number, progress_bar, usage_error)
from guardian.evaluation import MAX_SECONDS

OVERTAKE_ONLY = ("intention", "disturbance", "no_intention", "horizon")


def cmd_rollout(args) -> int:
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/Overtake-v0 and guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the highway-env environments
    from envs.agents import AGENTS, BASELINES
    from envs.mpc import STYLES
    from guardian.config import GuardianConfig
    from guardian.errors import ConfigClash, ConfigError
    from guardian.evaluation.rollouts import (OVERTAKE_ENV, OVERTAKE_ENVS, TWO_CARS_ENV, Rollout, combine_runs,
                                              highway_env_config, highway_rollouts, refuse_set_keys)

    if args.env not in gym.registry:
        known = sorted(k for k in gym.registry if k.startswith(("highway", "merge", "exit", "guardian/")))
        return usage_error(args, f"unknown environment {args.env!r}; ids: {', '.join(known)}")
    if not _is_highway_env(args.env):
        return usage_error(args, f"{args.env} is not a highway-env environment; the guardian drives highway-env's "
                                 f"roads and its own scenarios")
    overtake = args.env in OVERTAKE_ENVS
    refused = _inapplicable(args, overtake)
    if refused:
        return usage_error(args, refused)
    if args.policy is not None:
        agents = (f"policy:{args.policy}",)
    else:
        if args.agent not in (*AGENTS, "all"):
            return usage_error(args, f"unknown agent {args.agent!r}; choose from {', '.join(AGENTS)} or all")
        agents = BASELINES if args.agent == "all" else (args.agent,)
        if any(a in STYLES for a in agents) and not (overtake and args.action in (None, "continuous")):
            return usage_error(args, f"the MPC drivers ({', '.join(STYLES)}) drive {TWO_CARS_ENV} or "
                                     f"{OVERTAKE_ENV} with continuous actions")
    intentions = (("aggressive", "cautious") if args.intention == "all" else (args.intention,)) if overtake else (None,)
    if args.rerun is not None and len(agents) * len(intentions) > 1:
        return usage_error(args, "--rerun records one run; choose one --agent and one --intention")
    try:
        env_config = env_config_option(args.env, args.env_config or [])
    except ValueError as exc:
        return usage_error(args, str(exc))
    refused = _conflicts(args, env_config) or _needs_cars(args, env_config, overtake)
    if refused:
        return usage_error(args, refused)
    gcfg = GuardianConfig(use_intention=not args.no_intention, horizon=args.horizon, overapprox=args.overapprox,
                          resample_unsafe_start=args.safe_start)
    spec = Rollout(args.env, "", action=args.action, guarded=not args.no_guardian, config=gcfg,
                   intention=intentions[0], disturbance=args.disturbance, traffic=args.traffic,
                   controlled=args.controlled, env_config=env_config, policy_algo=args.algo,
                   max_seconds=args.max_seconds, jerk=args.jerk, lag=args.lag)
    try:  # every key the rollout sets itself, checked before the sets are loaded
        highway_env_config(spec)
        if overtake:
            refuse_set_keys(args.env, env_config, ("initial_region", "params"))
    except ConfigClash as exc:
        return usage_error(args, clash_message(exc))
    except ValueError as exc:
        return usage_error(args, str(exc))
    among_traffic = args.env == OVERTAKE_ENV and args.traffic != 0 and env_config.get("traffic_count", 1) != 0
    if among_traffic and args.ego_speed_min is None:
        args.ego_speed_min = 0.0  # among traffic the ego must be able to wait behind the lead
    elif among_traffic and args.ego_speed_min > 0:
        return usage_error(args, f"--ego-speed-min {args.ego_speed_min:g}: among traffic the ego must be able to "
                                 f"wait behind the lead; {OVERTAKE_ENV} with traffic takes --ego-speed-min 0 "
                                 f"(its default there; leave the option out)")
    library = load_library(args) if overtake else None  # initial states are drawn inside C_bnd, guarded or not
    runs = []
    for agent in agents:
        for intention in intentions:
            label = " ".join(x for x in (f"rollout {args.env}", intention, agent.split("/")[-1]) if x)
            video = (args.video / "-".join(x for x in (intention, agent.split("/")[-1]) if x)) if args.video else None
            run = replace(spec, agent=agent, intention=intention, library=library)
            try:
                r = highway_rollouts(run, args.episodes, args.seed, args.first_episode, progress_bar(label),
                                     rerun_path=args.rerun, video_dir=video)
            except ConfigClash as exc:
                return usage_error(args, clash_message(exc))
            except (ConfigError, ValueError) as exc:
                return usage_error(args, str(exc))
            r.update({"env": args.env, "agent": agent, "action": action_name(args.env, args.action, env_config),
                      "guardian": not args.no_guardian, "controlled": args.controlled or 1,
                      "overapprox": args.overapprox, "jerk": args.jerk, "lag": args.lag,
                      "intention_aware": overtake and not args.no_guardian and not args.no_intention})
            if overtake:
                r.update({"intention": intention, "disturbance": args.disturbance})
            runs.append(r)
    result = runs[0] if len(runs) == 1 else combine_runs(runs)
    emit(result, args.json, "\n".join(_summary(args, r) for r in runs))
    return 0


LIBRARY_SETS = {"initial_region": "the set library (starts are drawn in its C_bnd)",
                "params": "the set library's parameters (--ego-speed-min)"}


def _rollout_parser():
    """The ``guardian rollout`` sub-command's parser, as the command line builds it."""
    sub = Parser(prog="guardian").add_commands("command")
    add_commands(sub)
    return sub.choices["rollout"]


def option_of(dest: str) -> str:
    """The ``guardian rollout`` option that sets ``dest`` (its long form)."""
    for action in _rollout_parser()._actions:
        if action.dest == dest and action.option_strings:
            return action.option_strings[-1]
    raise KeyError(f"guardian rollout has no option for {dest!r}")


def clash_message(exc) -> str:
    """A ``ConfigClash`` in the command line's words: the option that sets the key, not the field."""
    setting = LIBRARY_SETS[exc.key] if exc.setting == "library" else option_of(exc.setting)
    return f"{exc.env_id}: config key {exc.key!r} is set by {setting}; give it there, not in the env config"


def replay_command(replay: dict) -> str:
    """The ``guardian rollout`` command line of ``replay`` (``{option dest: value}``, as
    ``guardian.evaluation.campaign.Cell.replay`` gives it): a flag for ``True``, one ``--env-config
    KEY=VALUE`` per key of ``env_config``, ``--json`` last."""
    parts = ["guardian rollout"]
    for dest, value in replay.items():
        option = option_of(dest)
        if value is True:
            parts.append(option)
        elif dest == "env_config":
            parts += [f"{option} {shlex.quote(k + '=' + json.dumps(v).replace(' ', ''))}" for k, v in value.items()]
        elif value is not None and value is not False:
            parts.append(f"{option} {shlex.quote(str(value))}")
    return " ".join(parts + [option_of("json")])


def _inapplicable(args, overtake: bool) -> str | None:
    """Why an option given does not apply to this environment (None when all apply)."""
    from guardian.evaluation.rollouts import OVERTAKE_ENV

    defaults = {"intention": "cautious", "disturbance": "random", "no_intention": False, "horizon": 10}
    if not overtake:
        given = [k for k in OVERTAKE_ONLY if getattr(args, k) != defaults[k]]
        if given or args.ego_speed_min is not None:
            names = [f"--{k.replace('_', '-')}" for k in given] + (["--ego-speed-min"] if args.ego_speed_min is not None
                                                                   else [])
            verb = "applies" if len(names) == 1 else "apply"
            return f"{', '.join(names)} {verb} to the overtake scenarios, not to {args.env}"
    actuator = [name for name, given in (("--jerk", args.jerk is not None), ("--lag", args.lag is not None)) if given]
    if actuator and overtake:
        return (f"{' and '.join(actuator)} {'applies' if len(actuator) == 1 else 'apply'} to highway-env's roads; the "
                f"overtake scenarios' sets let the ego's acceleration jump ({args.env})")
    if args.traffic is not None and args.env != OVERTAKE_ENV and overtake:
        return f"--traffic applies to {OVERTAKE_ENV} and the highway-v0 family; {args.env} has the two cars alone"
    if not overtake:
        library = [name for name, given in (("--iterations", args.iterations is not None), ("--rebuild", args.rebuild),
                                            ("--cache-dir", args.cache_dir is not None),
                                            ("--workers", args.workers != 2)) if given]
        if library:
            verb = "applies" if len(library) == 1 else "apply"
            return (f"{', '.join(library)} {verb} to the overtake scenarios' set library; {args.env} uses none "
                    f"(its guardian reads the road)")
    if args.no_guardian and (args.no_intention or args.safe_start):
        names = [n for n, given in (("--no-intention", args.no_intention), ("--safe-start", args.safe_start)) if given]
        verb = "changes" if len(names) == 1 else "change"
        return f"{' and '.join(names)} {verb} the guardian; {'it does' if len(names) == 1 else 'they do'} not apply " \
               f"with --no-guardian"
    if args.policy is not None and args.agent != "random":
        return "--policy replaces --agent; give one of them"
    if args.algo is not None and args.policy is None:
        return "--algo names the algorithm of a --policy file"
    if args.controlled is not None and args.policy is not None:
        return "--policy drives one car; it does not apply with --controlled"
    if args.overapprox != "trivial" and (args.no_guardian or overtake):
        return "--overapprox chooses how guarded cars on highway-env's roads over-approximate each other's lane changes"
    return None


def _is_highway_env(env_id: str) -> bool:
    from highway_env.envs.common.abstract import AbstractEnv

    from guardian.adapters.highway_env.checks import env_class

    try:
        cls = env_class(env_id)
    except Exception:  # noqa: BLE001 - an entry point that cannot be imported is not one we can drive
        return False
    return isinstance(cls, type) and issubclass(cls, AbstractEnv)


ACTION_NAMES = {"DiscreteMetaAction": "meta", "ContinuousAction": "continuous", "DiscreteAction": "discrete"}


def action_name(env_id: str, action: str | None, env_config: dict) -> str:
    """The action type the rollout ran: ``--action``, else the config's, else the env's own (the inner type
    under ``MultiAgentAction``)."""
    from guardian.adapters.highway_env.checks import action_types

    if action is not None:
        return action
    inner = action_types(env_id, env_config)[1]
    return ACTION_NAMES.get(inner, inner or "default")


def env_config_option(env_id: str, pairs: list) -> dict:
    """``KEY=VALUE`` pairs (values read as JSON, else as text) or JSON objects as the env's config, later
    ones overriding earlier ones; a key the env does not have, or a value not of its kind or out of its
    range (``guardian.adapters.highway_env.checks.check_config``), is refused with its name."""
    from guardian.adapters.highway_env.checks import check_config, check_keys, env_class

    defaults = env_class(env_id).default_config()
    out = {}
    for pair in pairs:
        if pair.lstrip().startswith("{"):
            try:
                given = json.loads(pair)
            except json.JSONDecodeError as exc:
                raise ValueError(f"--env-config: {pair!r} is not a JSON object ({exc})") from None
            if not isinstance(given, dict):
                raise ValueError(f"--env-config: {pair!r} is not a JSON object")
        else:
            key, sep, text = pair.partition("=")
            if not sep or not key:
                raise ValueError(f"--env-config takes KEY=VALUE or a JSON object, got {pair!r}")
            try:
                given = {key: json.loads(text)}
            except json.JSONDecodeError:
                given = {key: text}
        out.update(given)
    check_keys(defaults, out, f"--env-config: {env_id}")
    check_config(defaults, out, f"--env-config: {env_id}")
    return out


def _conflicts(args, env_config: dict) -> str | None:
    """``--controlled`` beside a config action (each car's action is ``--action``'s). An option and the config
    key it sets are refused by ``guardian.evaluation.rollouts.highway_env_config``."""
    if args.controlled is not None and "action" in env_config:
        return "--controlled sets the action (MultiAgentAction of --action); --env-config action does not apply with it"
    return None


def _needs_cars(args, env_config: dict, overtake: bool) -> str | None:
    """``--traffic`` on an env without a car count, ``--overapprox`` with one guarded car."""
    from guardian.adapters.highway_env.checks import env_class

    if args.traffic is not None and not overtake and "vehicles_count" not in env_class(args.env).default_config():
        return f"--traffic sets the config vehicles_count; {args.env} has none (its traffic is its own)"
    cars = args.controlled if args.controlled is not None else env_config.get("controlled_vehicles") or 1
    if args.overapprox != "trivial" and not overtake and cars < 2:
        return ("--overapprox chooses how several guarded cars over-approximate each other's lane changes; "
                "with one guarded car it does not apply (give --controlled N, N >= 2)")
    return None


def _value(v) -> str:
    if v is None:
        return "-"
    return f"{v:.1f}" if isinstance(v, float) else str(v)


def _fields(record: dict, skip=()) -> str:
    """``key=value`` for every scalar of a record; an object's entries as ``key.entry=value``."""
    out = []
    for k, v in record.items():
        if k in skip or isinstance(v, list):
            continue
        if isinstance(v, dict):
            out += [f"{k}.{e}={x:g}" if isinstance(x, float) else f"{k}.{e}={_value(x)}" for e, x in v.items()]
        else:
            out.append(f"{k}={_value(v)}")
    return " ".join(out)


def _crash(c: dict) -> str:
    who = f"car {c['car']} " if c.get("car") is not None else ""
    partner = c.get("partner") or "-"
    if c.get("partner_car") is not None:
        partner += f" (guarded car {c['partner_car']})"
    blind = c.get("steps_since_traffic_blind")
    reasons = c.get("reasons") or []
    return (f"  crash: episode {c['episode']} step {c['step']} {who}fault={c['fault']} ({c['rule']}) "
            f"partner={partner} start_inside={c['start_inside']} level={c.get('level') or '-'}"
            + (f" steps_since_traffic_blind={blind}" if blind is not None else "")
            + (f" reason: {reasons[0]}" + (f" (+{len(reasons) - 1} more)" if len(reasons) > 1 else "")
               if reasons else ""))


def _summary(args, r: dict) -> str:
    overtake = "disturbance" in r
    head = " ".join(x for x in (args.env, r.get("intention"), r["agent"], f"action={r['action']}",
                                f"guardian={'on' if r['guardian'] else 'off'}",
                                f"disturbance={r['disturbance']}" if overtake else None,
                                f"intention_aware={'yes' if r['intention_aware'] else 'no'}" if overtake else None)
                    if x)
    skip = {"env", "agent", "action", "guardian", "intention_aware", "disturbance", "intention"}
    cars = [f"  car {i}: {_fields(a)}" for i, a in enumerate(r.get("agents") or [])]
    crashes = [_crash(c) for c in r.get("crashes", [])]
    return "\n".join([head, "  " + _fields(r, skip), *cars, *crashes])


def add_commands(sub) -> None:
    p = sub.add_parser("rollout", help="supervised rollouts: the overtake scenarios or a highway-env environment",
                       parents=[library_options(), json_option()])
    p.add_argument("--env", default="guardian/Overtake-v0",
                   help="guardian/Overtake-v0 (default: the two cars of Section 6.5), guardian/HighwayOvertake-v0 "
                        "(the overtake among traffic), highway-v0, highway-fast-v0, ..., merge-v0, merge-v1, "
                        "merge-generic-v0, merge-generic-v1, exit-v0, exit-v1, guardian/Merge-v0 (v1: traffic sees across lane "
                        "segments)")
    p.add_argument("--agent", default="random",
                   help="random | reckless | idle | merge | mpc | bad | careful | seek | brake_check | oscillate | hold | "
                        "trap | line, or all (Section 6.5.3's mpc, bad, careful, random)")
    p.add_argument("--policy", type=Path, default=None, metavar="PATH.zip",
                   help="drive with a stable-baselines3 policy file instead of --agent")
    p.add_argument("--algo", default=None, help="the --policy file's algorithm (DQN, PPO, ...; default: read from it)")
    p.add_argument("--action", choices=["continuous", "meta"], default=None,
                   help="the agent's action type (default: the env's own)")
    p.add_argument("--traffic", type=count(0), default=None,
                   help="other cars (guardian/HighwayOvertake-v0, the highway-v0 family)")
    p.add_argument("--controlled", type=count(1), default=None, metavar="N",
                   help="N controlled cars (MultiAgentAction), each with its own agent and guardian; highway-env roads")
    p.add_argument("--overapprox", choices=["trivial", "ordered"], default="trivial",
                   help="ordered: guarded cars announce their lane changes to each other (Example 8); trivial: none")
    p.add_argument("--env-config", action="append", metavar="KEY=VALUE", default=None,
                   help="a config key of the env (the value read as JSON), or a JSON object of them; repeatable")
    p.add_argument("--safe-start", action="store_true",
                   help="draw each start again until it lies in the guardian's invariant sets")
    p.add_argument("--intention", type=intention_name, default="cautious",
                   help="the lead's intention: aggressive | cautious | all (C_a, C_c accepted); overtake scenarios")
    p.add_argument("--disturbance", choices=["random", "adversarial"], default="random",
                   help="overtake scenarios")
    p.add_argument("--horizon", type=count(1), default=10, help="intention estimator horizon N; overtake scenarios")
    p.add_argument("--episodes", type=count(1), default=10, help="episodes per agent and intention (default 10)")
    p.add_argument("--seed", type=count(0), default=0,
                   help="episode i resets the env with seed SEED+i, the agent with rng [SEED, i] (default 0)")
    p.add_argument("--first-episode", type=count(0), default=0, metavar="I",
                   help="start at episode I of the seeding rule (env seed SEED+I, agent rng [SEED, I]): "
                        "replays episode I of a longer run alone")
    p.add_argument("--max-seconds", type=positive_number, default=MAX_SECONDS, metavar="S",
                   help=f"stop an episode the env has not ended after S simulated seconds and count it as cut "
                        f"(episodes_cut; merge-v0 never ends one itself; default {MAX_SECONDS:g})")
    p.add_argument("--jerk", type=positive_number, default=None, metavar="J",
                   help="the controlled cars' actuator changes their acceleration by at most J m/s^3 (guarded or "
                        "not; the guardian's sets then carry the acceleration); highway-env's roads")
    p.add_argument("--lag", type=lag_seconds, default=None, metavar="TAU",
                   help="the controlled cars' actuator follows a command as a first-order lag of time constant TAU "
                        "seconds (sampled each simulation step; with --jerk, within its bound too); highway-env's "
                        "roads")
    p.add_argument("--no-guardian", action="store_true", help="drive without supervision")
    p.add_argument("--no-intention", action="store_true",
                   help="keep the guardian but pin it to the bounded-velocity set; overtake scenarios")
    p.add_argument("--rerun", type=output_file, default=None, help="write a rerun recording (.rrd) of one run")
    p.add_argument("--video", type=output_folder, default=None, help="write each episode as MP4 into this folder")
    p.set_defaults(func=cmd_rollout)
