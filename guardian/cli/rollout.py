"""``guardian rollout``: supervised rollouts (the overtake env, or a highway-env environment with --env)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from guardian.cli.common import emit, load_library, progress_bar, combine_runs, intention_name, add_library_options


def cmd_rollout_highway_env(args) -> int:
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the environments
    from envs.agents import AGENTS
    from envs.mpc import STYLES
    from envs.highway_overtake import ConfigError
    from guardian.rollout import OVERTAKE_ENV, highway_rollouts

    if args.env not in gym.registry:
        known = sorted(k for k in gym.registry if k.startswith(("highway", "merge", "roundabout", "guardian/")))
        print(f"guardian rollout: unknown environment {args.env!r}; ids: {', '.join(known)}", file=sys.stderr)
        return 2
    if args.agent not in AGENTS:
        print(f"guardian rollout: unknown agent {args.agent!r}; choose from {', '.join(AGENTS)}", file=sys.stderr)
        return 2
    overtake = args.env == OVERTAKE_ENV
    if args.agent in STYLES and not (overtake and args.action in (None, "continuous")):
        print(f"guardian rollout: the {args.agent} driver drives {OVERTAKE_ENV} with --action continuous",
              file=sys.stderr)
        return 2
    if args.traffic is not None and args.traffic < 0:
        print(f"guardian rollout: --traffic must be >= 0, got {args.traffic}", file=sys.stderr)
        return 2
    if overtake and args.ego_speed_min is None and args.traffic != 0:
        args.ego_speed_min = 0.0  # among traffic the ego must be able to wait behind the lead
    try:
        env_config = env_config_option(args.env, args.env_config or [])
    except ValueError as exc:
        print(f"guardian rollout: {exc}", file=sys.stderr)
        return 2
    library = load_library(args) if overtake else None  # initial states are drawn inside C_bnd, guarded or not
    intentions = (("aggressive", "cautious") if args.intention == "all" else (args.intention,)) if overtake else (None,)
    from guardian.wrapper import GuardianConfig

    gcfg = GuardianConfig(use_intention=not args.no_intention)
    runs = []
    for k, intention in enumerate(intentions):
        label = f"rollout {args.env}" + (f" {intention}" if intention else "")
        try:
            r = highway_rollouts(args.env, args.agent, args.episodes, args.seed, action=args.action,
                                 guardian=not args.no_guardian, library=library, intention=intention,
                                 disturbance=args.disturbance, traffic=args.traffic, guardian_config=gcfg,
                                 safe_start=args.safe_start, env_config=env_config,
                                 progress=progress_bar(label), rerun_path=args.rerun if k == 0 else None,
                                 video_dir=(args.video / (intention or "all")) if args.video else None)
        except ConfigError as exc:
            print(f"guardian rollout: {exc}", file=sys.stderr)
            return 2
        r.update({"env": args.env, "agent": args.agent, "action": args.action or "default",
                  "guardian": not args.no_guardian, "intention_aware": not args.no_guardian and not args.no_intention,
                  "disturbance": args.disturbance})
        if intention:
            r["intention"] = intention
        runs.append(r)
    result = runs[0] if len(runs) == 1 else combine_runs(runs)
    text = "\n".join(_summary(args, r) for r in runs)
    emit(result, args.json, text)
    return 0


def env_config_option(env_id: str, pairs: list) -> dict:
    """``KEY=VALUE`` pairs as the env's config (values read as JSON, else as text); a key the env
    does not have is refused with its name."""
    known = set(_env_class(env_id).default_config())
    out = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--env-config takes KEY=VALUE, got {pair!r}")
        if key not in known:
            raise ValueError(f"--env-config: {env_id} has no config key {key!r}")
        try:
            out[key] = json.loads(text)
        except json.JSONDecodeError:
            out[key] = text
    return out


def _env_class(env_id: str):
    import importlib

    import gymnasium as gym

    entry = gym.spec(env_id).entry_point
    if callable(entry):
        return entry
    module, _, name = entry.partition(":")
    return getattr(importlib.import_module(module), name)


def _summary(args, r: dict) -> str:
    head = f"{args.env} {r.get('intention', '')} {args.agent} guardian={'on' if r['guardian'] else 'off'}".replace("  ", " ")
    skip = {"env", "agent", "action", "guardian", "intention_aware", "disturbance", "intention", "crashes", "runs"}
    fields = [f"{k}={v:.1f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items() if k not in skip]
    crashes = [f"  crash: episode {c['episode']} step {c['step']} fault={c['fault']} ({c['rule']}) "
               f"start_inside={c['start_inside']}" for c in r.get("crashes", [])]
    return "\n".join([head, "  " + " ".join(fields), *crashes])


def cmd_rollout(args) -> int:
    from envs.agents import AGENTS, BASELINES
    from guardian.rollout import overtake_rollouts

    if args.episodes < 1:
        print("guardian rollout: --episodes must be at least 1", file=sys.stderr)
        return 2
    if args.env is not None:
        if args.scenario is not None:
            print("guardian rollout: --env and --scenario exclude each other", file=sys.stderr)
            return 2
        return cmd_rollout_highway_env(args)
    if args.driver not in (*AGENTS, "all"):
        print(f"guardian rollout: unknown driver {args.driver!r}; choose from {', '.join(AGENTS)} or all",
              file=sys.stderr)
        return 2
    lib = load_library(args)
    intentions = ("aggressive", "cautious") if args.intention == "all" else (args.intention,)
    drivers = BASELINES if args.driver == "all" else (args.driver,)
    runs = [overtake_rollouts(lib, i, d, args.episodes, args.seed, guardian=not args.no_guardian,
                              use_intention=not args.no_intention, disturbance=args.disturbance,
                              max_steps=args.max_steps, horizon=args.horizon,
                              rerun_path=args.rerun if len(intentions) * len(drivers) == 1 else None,
                              progress=progress_bar(f"rollout {i}/{d}"))
            for i in intentions for d in drivers]
    result = runs[0] if len(runs) == 1 else combine_runs(runs)
    text = "\n".join(f"{r['intention']:10s} {r['driver']:8s} episodes={r['episodes']} steps={r['steps']} "
                     f"violations={r['safety_violations']} overrides={r['override_steps']} "
                     f"identified={r['identified_fraction']:.2f} "
                     f"mean_steps_to_identify={r['mean_steps_to_identify_intention']}" for r in runs)
    emit(result, args.json, text)
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("rollout", help="supervised rollouts of the overtake scenario")
    p.add_argument("--scenario", choices=["overtake"], default=None,
                   help="the overtake scenario (the default when --env is not given)")
    p.add_argument("--env", default=None,
                   help="a highway-env id: guardian/HighwayOvertake-v0 (lead part + ITHA), highway-v0, "
                        "highway-fast-v0, ... (ITHA)")
    p.add_argument("--agent", default="random",
                   help="with --env: random | reckless | idle | mpc | bad | careful (the MPC drivers: "
                        "HighwayOvertake, continuous)")
    p.add_argument("--action", choices=["continuous", "meta"], default=None,
                   help="with --env: the agent's action type (default: the env's own)")
    p.add_argument("--traffic", type=int, default=None, help="with --env: number of other cars")
    p.add_argument("--video", type=Path, default=None, help="with --env: write each episode as MP4 into this folder")
    p.add_argument("--env-config", action="append", metavar="KEY=VALUE", default=None,
                   help="with --env: a config key of the env (value read as JSON), repeatable")
    p.add_argument("--safe-start", action="store_true",
                   help="with --env and the guardian: draw each start again until it lies in the guardian's sets")
    p.add_argument("--intention", type=intention_name, default="cautious",
                   help="aggressive | cautious | all (C_a, C_c accepted)")
    p.add_argument("--driver", default="mpc",
                   help="the overtake scenario's driver: mpc | bad | careful | random | reckless | idle, or all "
                        "(the four of Section 6.5.3: mpc, bad, careful, random)")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--disturbance", choices=["random", "adversarial"], default="random")
    p.add_argument("--max-steps", type=int, default=300, help="steps per episode (dt = 0.1 s)")
    p.add_argument("--horizon", type=int, default=10, help="intention estimator horizon N")
    p.add_argument("--no-guardian", action="store_true", help="drive without supervision")
    p.add_argument("--no-intention", action="store_true",
                   help="keep the guardian but pin it to the bounded-velocity set")
    p.add_argument("--rerun", type=Path, default=None, help="write a rerun recording (.rrd)")
    add_library_options(p)
    p.set_defaults(func=cmd_rollout)
