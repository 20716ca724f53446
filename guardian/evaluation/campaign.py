"""The falsification campaign: many seeded episodes of adversarial and random agents, one table.

A campaign is a list of ``Cell`` (an environment configuration and an agent) run for some episodes
each. Every episode is one ``guardian rollout --episodes 1 --seed S`` (``Cell.replay`` gives its options), so
any failure the table reports can be replayed alone. Episodes are spread over local processes or a
Dask cluster (``scheduler``), as the HighD replay does; results do not depend on how they are spread.

The matrix (``matrix``):

* ``guardian/HighwayOvertake-v0``: every agent of ``envs.agents`` that drives a road (the MPC drivers
  with continuous actions only) x both action types x both intentions x both disturbance modes x four
  traffic settings: none (the two cars of Section 6.5, the dissertation's parameters), 4 cars on 2
  lanes, 8 cars on 3 lanes with 4 from behind, 12 fast cars (30-38 m/s) on 3 lanes with 6 from behind;
* ``highway-v0`` and ``highway-fast-v0``: the same agents x both action types x six settings: the
  env's own, density 2.5, 2 lanes at density 1.5, one lane at density 2.5, policy frequency 5, and
  policy frequency 15 (``highway-fast-v0`` then simulates at 15 Hz too).

The campaign's agents read the simulator, not the observation, so the overtake cells observe the
overtake state (highway-env's Kinematics table costs 60 % of their step) and ``highway-v0``'s episodes
last 15 s instead of 40 (its 50 cars at 15 Hz make it five times slower than ``highway-fast-v0``); both
are part of each cell's config, so the replay command reproduces them.

``only="roads"`` (``guardian falsify --only roads``; not part of the default matrix)
runs the roads beyond one straight segment: ``merge-v0``, ``merge-generic-v0`` (meta; highway-env's merge
envs fail with continuous actions), ``guardian/Merge-v0`` with merge-v0's traffic (both action types),
``exit-v0`` (both), each with ``ROAD_AGENTS`` and the ``merge`` agent; and several guarded cars on
``guardian/Merge-v0`` (``MULTI_SETTINGS``: 2 and 4 controlled cars in the merging reference's easy and hard
traffic, 20 s at 5 Hz) for both over-approximations, with random, reckless and merge agents and both
action types.

The counts are ``guardian.evaluation.tally.HighwayTally``'s (each by a written rule; the fault judge is
``guardian.evaluation.judge``); ``exceptions`` counts episodes that raised.
"""
from __future__ import annotations

import json
import math
import time
import traceback
from dataclasses import dataclass, field

from guardian.config import GuardianConfig
from rcis.parallel import Jobs
from guardian.evaluation.rollouts import Rollout, highway_rollouts

OVERTAKE_ENV = "guardian/HighwayOvertake-v0"
ROAD_AGENTS = ("random", "reckless", "seek", "brake_check", "oscillate", "hold", "trap")
MPC_AGENTS = ("mpc", "bad")
OVERTAKE_TRAFFIC = (
    ("two cars", 0, {}),
    ("4 cars, 2 lanes", 4, {}),
    ("8 cars, 3 lanes", 8, {"lanes_count": 3, "traffic_from_behind": 4}),
    ("12 fast cars, 3 lanes", 12, {"lanes_count": 3, "traffic_from_behind": 6, "traffic_speed_range": [30.0, 38.0]}),
)
HIGHWAY_SETTINGS = (
    ("own config", {}),
    ("density 2.5", {"vehicles_density": 2.5}),
    ("2 lanes, density 1.5", {"lanes_count": 2, "vehicles_density": 1.5}),
    ("1 lane, density 2.5", {"lanes_count": 1, "vehicles_density": 2.5}),
    ("policy 5 Hz", {"policy_frequency": 5}),
    ("policy 15 Hz", {"policy_frequency": 15, "simulation_frequency": 15}),
)
ROADS = (("merge-v0", ("meta",), {}), ("merge-generic-v0", ("meta",), {}),
         ("guardian/Merge-v0", ("continuous", "meta"), {}), ("exit-v0", ("continuous", "meta"), {}))
MULTI_SETTINGS = tuple((f"{n} guarded, {traffic}", n, {"traffic": traffic, "duration": 20, "policy_frequency": 5})
                       for n in (2, 4) for traffic in ("easy", "hard"))
MULTI_AGENTS = ("random", "reckless", "merge")
COUNTED = ("collisions", "ego_at_fault_collisions", "starts_outside", "collisions_after_outside_starts",
           "ego_at_fault_after_outside_starts", "safety_violations", "failsafe_steps", "conflict_steps",
           "unchecked_entries", "reversing_steps", "unsupervised_steps", "traffic_reversing_uncovered_steps",
           "override_steps", "steps", "episodes_cut", "actuator_clipped_steps")


@dataclass(frozen=True)
class Cell:
    """One configuration of the matrix."""

    env: str
    agent: str
    action: str
    setting: str
    intention: str | None = None
    disturbance: str = "random"
    traffic: int | None = None
    env_config: tuple = ()          # sorted (key, json value) pairs
    guardian: bool = True
    controlled: int | None = None   # several controlled cars (MultiAgentAction)
    overapprox: str = "trivial"
    jerk: float | None = None       # the controlled cars' actuator's jerk bound (envs.actuator.Actuated)
    lag: float | None = None        # and its first-order lag's time constant [s]

    @property
    def config(self) -> dict:
        return {k: json.loads(v) for k, v in self.env_config}

    def replay(self, seed: int) -> dict:
        """The ``guardian rollout`` options (by their argparse names) that replay episode ``seed`` of this cell
        alone; ``guardian.cli.rollout.replay_command`` writes them as a command line."""
        out = {"env": self.env, "agent": self.agent, "action": self.action}
        if self.env == OVERTAKE_ENV:
            out.update({"intention": self.intention, "disturbance": self.disturbance, "traffic": self.traffic})
        out["env_config"] = self.config
        if self.controlled is not None:
            out["controlled"] = self.controlled
        if self.overapprox != "trivial":
            out["overapprox"] = self.overapprox
        if self.jerk is not None:
            out["jerk"] = self.jerk
        if self.lag is not None:
            out["lag"] = self.lag
        if not self.guardian:
            out["no_guardian"] = True
        out.update({"episodes": 1, "seed": seed})
        return out

    def rollout(self, library=None) -> Rollout:
        """The cell as a rollout setting (``library``: the overtake sets its env needs)."""
        return Rollout(self.env, self.agent, action=self.action, guarded=self.guardian,
                       config=GuardianConfig(overapprox=self.overapprox), library=library, intention=self.intention,
                       disturbance=self.disturbance, traffic=self.traffic, controlled=self.controlled,
                       env_config=self.config, jerk=self.jerk, lag=self.lag)


def _cell(env, agent, action, setting, config, guardian, **kw) -> Cell:
    return Cell(env, agent, action, setting, env_config=tuple(sorted((k, json.dumps(v)) for k, v in config.items())),
                guardian=guardian, **kw)


def matrix(guardian: bool = True, only: str | None = None, jerk: float | None = None,
           lag: float | None = None) -> list[Cell]:
    """The campaign's cells (``only``: ``overtake``, ``highway`` or ``roads``; by default the first two); ``jerk``,
    ``lag``: the controlled cars behind an actuator with that jerk bound and lag (highway-env's roads only)."""
    if jerk is not None or lag is not None:
        if only not in ("highway", "roads"):
            raise ValueError("an actuator (jerk limit, lag) applies to highway-env's roads: choose only='highway' or "
                             "'roads'")
        import dataclasses

        from itha.actuator import Actuator

        Actuator(jerk=math.inf if jerk is None else float(jerk), lag=0.0 if lag is None else float(lag),
                 profile="hold")   # refuses what no actuator is, before any cell runs
        return [dataclasses.replace(c, jerk=None if jerk is None else float(jerk), lag=None if lag is None else
                                    float(lag)) for c in matrix(guardian, only)]
    cells = []
    if only == "roads":
        for env, actions, config in ROADS:
            for action in actions:
                for agent in ROAD_AGENTS + ("merge",):
                    cells.append(_cell(env, agent, action, "own config", config, guardian))
        for setting, n, config in MULTI_SETTINGS:
            for action in ("continuous", "meta"):
                for agent in MULTI_AGENTS:
                    for overapprox in (("trivial", "ordered") if guardian else ("trivial",)):
                        cells.append(_cell("guardian/Merge-v0", agent, action, setting, config, guardian,
                                           controlled=n, overapprox=overapprox))
        return cells
    if only in (None, "overtake"):
        for setting, traffic, config in OVERTAKE_TRAFFIC:
            for action in ("continuous", "meta"):
                agents = ROAD_AGENTS + (MPC_AGENTS if action == "continuous" else ())
                for agent in agents:
                    for intention in ("aggressive", "cautious"):
                        for disturbance in ("random", "adversarial"):
                            cells.append(_cell(OVERTAKE_ENV, agent, action, setting,
                                               {**config, "observation": {"type": "OvertakeState"}}, guardian,
                                               intention=intention, disturbance=disturbance, traffic=traffic))
    if only in (None, "highway"):
        for env in ("highway-v0", "highway-fast-v0"):
            for setting, config in HIGHWAY_SETTINGS:
                for action in ("continuous", "meta"):
                    for agent in ROAD_AGENTS:
                        short = {"duration": 15} if env == "highway-v0" else {}
                        cells.append(_cell(env, agent, action, setting, {**config, **short}, guardian))
    return cells


# ---- running --------------------------------------------------------------------------------------------
_LIBRARIES: dict = {}


def _library(traffic: int, cache_dir):
    """The overtake library a HighwayOvertake cell needs, built or loaded once per process."""
    from intention.library import build_library
    from intention.params import OvertakeParams

    params = OvertakeParams() if traffic == 0 else OvertakeParams.among_traffic()
    if params not in _LIBRARIES:
        _LIBRARIES[params] = build_library(params=params, cache_dir=cache_dir, quiet=True, workers=1)
    return _LIBRARIES[params]


def run_episode(cell: Cell, seed: int, cache_dir=None) -> dict:
    """One episode of ``cell``: the tally's counts, or the exception it raised."""
    try:
        library = _library(cell.traffic, cache_dir) if cell.env == OVERTAKE_ENV else None
        return highway_rollouts(cell.rollout(library), 1, seed)
    except Exception:  # noqa: BLE001 - an episode that raises is a finding, counted and kept
        return {"exception": traceback.format_exc(limit=6)}


def _chunk(cell: Cell, seeds: list, cache_dir) -> list:
    return [(seed, run_episode(cell, seed, cache_dir)) for seed in seeds]


@dataclass
class Campaign:
    """The accumulated counts of a campaign (``add`` each episode's result)."""

    rows: dict = field(default_factory=dict)
    failures: list = field(default_factory=list)
    episodes: int = 0
    started: float | None = None   # time.perf_counter() when the run began

    def add(self, cell: Cell, seed: int, r: dict) -> None:
        self.episodes += 1
        for key in self._keys(cell):
            row = self.rows.setdefault(key, {k: 0 for k in ("episodes", *COUNTED, "exceptions")})
            row["episodes"] += 1
            if "exception" in r:
                row["exceptions"] += 1
                continue
            for k in COUNTED:
                row[k] += r.get(k) or 0
        if "exception" in r:
            self.failures.append({"kind": "exception", "cell": cell.setting, "replay": cell.replay(seed),
                                  "detail": r["exception"].strip().splitlines()[-1]})
            return
        for crash in r["crashes"]:
            blamed = crash["fault"] == "ego" or crash.get("partner_car") is not None   # a guarded car at fault
            if blamed or not crash["start_inside"]:
                self.failures.append({"kind": "at-fault collision" if crash["start_inside"] and blamed
                                      else "collision after a start outside", "fault": crash["fault"],
                                      "rule": crash["rule"], "cell": cell.setting, "replay": cell.replay(seed)})
        for k in ("unchecked_entries", "reversing_steps", "unsupervised_steps", "episodes_cut", "actuator_clipped_steps"):
            if r.get(k):
                self.failures.append({"kind": k, "count": r[k], "cell": cell.setting, "replay": cell.replay(seed)})
        if cell.env == OVERTAKE_ENV and r.get("safety_violations"):
            kind = "safe-set exit after a start outside" if r.get("starts_outside") else "safe-set exit"
            self.failures.append({"kind": kind, "cell": cell.setting, "replay": cell.replay(seed)})

    @staticmethod
    def _keys(cell: Cell) -> list:
        family = "HighwayOvertake" if cell.env == OVERTAKE_ENV else cell.env
        if cell.controlled is not None:
            family = f"{cell.env} x{cell.controlled} {cell.overapprox}"
        return [("all",), ("env", family, cell.action), ("agent", cell.agent), ("setting", family, cell.setting)]

    def table(self, kind: str) -> list:
        return [{"group": " ".join(key[1:]) if kind != "all" else "all", **row}
                for key, row in sorted(self.rows.items()) if key[0] == kind]


def run_campaign(cells: list, episodes: int, seed: int = 0, workers: int | None = 1, scheduler: str | None = None,
                 cache_dir=None, progress=None, camp: Campaign | None = None) -> dict:
    """Run ``episodes`` episodes of every cell; cell ``k`` episode ``i`` has seed ``seed + 1000 k + i``.

    Parameters
    ----------
    cells : list of Cell
    episodes : int
        Episodes per cell.
    seed : int
    workers : int
        Local processes (1: in this process); unused (None in the result) with ``scheduler``.
    scheduler : str, optional
        A Dask scheduler's address instead of local processes; connected to before any work (the sets
        included), ``guardian.errors.SchedulerError`` if no scheduler answers there.
    cache_dir : path, optional
        The set cache the workers load the overtake libraries from.
    progress : callable, optional
        ``progress(done, total)`` after each chunk of episodes.
    camp : Campaign, optional
        Where the episodes are counted as they finish (a fresh one by default): after an interruption it holds
        the finished episodes, for ``campaign_result``.

    Returns
    -------
    dict
        ``episodes, seconds, workers, totals`` (the counts summed), ``by_env`` (per environment and
        action type), ``by_agent``, ``by_setting``, and ``failures`` (each with the rollout options replaying it, ``replay``).
    """
    jobs = [(cell, [seed + 1000 * k + i for i in range(start, min(start + CHUNK, episodes))])
            for k, cell in enumerate(cells) for start in range(0, episodes, CHUNK)]
    total = sum(len(s) for _, s in jobs)
    cache = str(cache_dir) if cache_dir else None
    with Jobs(workers or 1, scheduler) as pool:  # connected first: an unreachable scheduler is refused at once
        if any(c.env == OVERTAKE_ENV for c in cells):  # build the sets once, before the workers need them
            for traffic in {c.traffic for c in cells if c.env == OVERTAKE_ENV}:
                _library(traffic, cache)
        camp, done, t0 = Campaign() if camp is None else camp, 0, time.perf_counter()
        camp.started = t0
        running = {k: pool.submit(_chunk, cell, seeds, cache) for k, (cell, seeds) in enumerate(jobs)}
        for k, results in pool.as_completed(running):
            cell = jobs[k][0]
            for s, r in results:
                camp.add(cell, s, r)
            done += len(results)
            if progress:
                progress(done, total)
    return campaign_result(camp, cells, episodes, workers, scheduler)


def campaign_result(camp: Campaign, cells: list, episodes: int, workers, scheduler, interrupted: bool = False) -> dict:
    """The campaign's record from what ``camp`` counted (``interrupted``: the episodes that finished before a
    signal stopped the run; the cells it did not reach are absent from the tables)."""
    seconds = round(time.perf_counter() - camp.started, 1) if camp.started is not None else 0.0
    return {"episodes": camp.episodes, "seconds": seconds, "workers": workers,
            "scheduler": scheduler, "cells": len(cells), "episodes_per_cell": episodes,
            "totals": camp.table("all")[0] if camp.episodes else {}, "by_env": camp.table("env"),
            "by_agent": camp.table("agent"), "by_setting": camp.table("setting"),
            "failures": sorted(camp.failures, key=lambda f: (f["kind"], json.dumps(f["replay"], sort_keys=True))),
            **({"interrupted": True} if interrupted else {})}


CHUNK = 5  # episodes per job: few enough to balance the workers, many enough to reuse a loaded library
