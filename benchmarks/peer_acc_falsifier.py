"""A peer's falsifier against our car-following guardian: CommonRoad's safety-falsification-acc, run from its own copy.

The peer (M. Koschi, C. Pek, S. Maierhofer, M. Althoff: "Computationally Efficient Safety Falsification of
Adaptive Cruise Control Systems", ITSC 2019; public repository CommonRoad/safety-falsification-acc, last commit
dfbbf9b) searches for lead-vehicle behaviours that drive an ACC into a collision. Its code is imported from the
path given by ``--peer`` (a checkout or ``git archive`` of that repository) and never copied here. Used of it:

* the vehicles: a kinematic single-track model (CommonRoad vehicle 2, l = 4.508 m, v_max = 50.8 m/s) driven
  straight and integrated by ``odeint``, the acceleration HELD over each 0.1 s step (it jumps at the step's
  start); ``check_feasibility`` limits the step-to-step change to ``j dt`` = 1 m/s^2, the acceleration to
  [-8, 1.5], and where a braking step would pass standstill it brakes at ``-v/dt`` instead, stopping exactly at
  the step's end. Both cars alike.
* the searches (``lead_search``): ``forward`` (an RRT over the lead's inputs, grown from random starts the
  peer calls safe, stopping at the first node it calls unsafe; nodes with gap <= 0 are dropped as invalid, but
  they are counted here), ``backward`` (an RRT grown backwards from unsafe states; every candidate start is
  re-simulated forwards with the ACC, and the search succeeds at a safe start whose re-simulation ends unsafe)
  and ``monte_carlo`` (the lead's inputs drawn from a beta distribution, stopping at the first collision).
* the proposers (``acc``): ``pi``, ``extended_pi``, ``idm`` and ``collision_avoidance`` with the peer's
  parameters (``config.yaml``), behind the peer's interface ``AccFactory.acc_control(v_lead, v_acc, s_x_lead,
  s_x_acc, a_acc) -> a``. The repository has no provably safe ACC ("safe-acc"): none in any of its commits; that
  is CommonRoad/safe-acc, a repository of its own (``--safe-acc``, below).
* its verdicts: a start is safe when the gap exceeds ``safe_distance`` (both cars brake as hard as their jerk
  allows from their accelerations now; ACC reaction time 0); a state is unsafe when the gap is at most
  ``unsafe_distance`` (that braking of both meets at some step's end; ``v_col`` = 0); a collision is a gap <= 0
  at a step's end.

The guardians are plugged in through the peer's interface (``AccFactory.create`` returns the proposer wrapped):
the proposer proposes (already jerk-limited by its own ``check_feasibility``), the guardian clips the proposal
into its admissible interval (none: the hardest braking, ``u_min``), and the peer's ``check_feasibility`` then
does what the vehicle can (jerk, bounds, standstill), as for every ACC of the peer.

* ``plain``: the proposer alone.
* ``unaware``: ``MaximalSet`` with exact integration, state ``(v, h, v_L)``, ``admissible_inputs``: as if the
  acceleration could jump.
* ``actuated``: ``ActuatedSet`` with ``Actuator(jerk=10, profile="hold")`` (the peer's held, rate-limited
  acceleration), state ``(v, h, v_L, a)``, ``admissible_commands``.
* ``safe_acc``: CommonRoad/safe-acc's ``SafeACC.execute`` (Althoff, Maierhofer, Pek, IEEE T-IV 2020; imported from
  the path given by ``--safe-acc``, never copied here): its inevitable-collision test, its safety layer (the
  proposal kept when its safe distance holds a step on) and its emergency profile, on the peer's vehicle, its
  standstill distance set to ``--h-min`` (``SafeAccGuard``). Its emergency under way is carried along each
  trajectory on the peer's nodes. Its own nominal ACC (a QP) is the proposer ``safe_acc_nominal`` (behind
  ``safe_acc`` only); its starts are those beyond its safe distance.

Both sets use the peer's vehicle: dt 0.1, U = [-8, 1.5], D = [d_min, d_max] = [-8, 1.5] (the lead's bounds in
config.yaml; our lead may brake at -8 at once, the peer's ramps at -10 m/s^3, so ours is the stronger lead),
v_max 50.8 (vehicle 2), h_min = 0.1 m by default (``--h-min``; the peer has no margin: its verdicts are at gap
0). h is the peer's ``delta_s`` (lead rear minus ACC front).

How the peer's vehicle differs from ``ActuatedSet``'s model: its standstill rule brakes at ``-v/dt`` where the
command would stop the car within the step, up to ~1 cm further than the set's car (which stops and stays).
Near the set's boundary that carries the state out of it (``exits``) and the guardian brakes; ``h_min`` must
cover that centimetre. (Runs before ``profile="hold"`` existed modelled the peer's held acceleration as a ramp:
up to (c - a) dt^2 / 3 further, and many more exits.)

Starts. A search draws its starts as the peer does and keeps those the controller's own criterion accepts: the
peer's (gap > safe_distance) for ``plain``; the peer's and the guardian's set for ``unaware`` and ``actuated``
(``--starts actuated``: every controller, plain too, from starts inside the actuated set). In the backward
search that criterion decides which re-simulated candidate counts as a found start ("valid initial node").
NB the peer's backward search never moves the ACC backwards (it keeps ``state_acc[0]``, the later state, for the
earlier node), so its candidates run into the ACC as they go back and almost none is a safe start: it finds
nothing under any budget tried here.

Counted per search over every state that the peer moved forwards (``RRT.forward_simulation``) from an accepted
start: collisions (states with gap <= 0; a search with one is a collided search), the least gap, the steps
from a state inside the guardian's set to one outside (``exits``; the first is reported with the set's own
prediction), and the peer's own verdict (``falsified``: the forward search reached an unsafe node, the backward
search found a safe start that ends unsafe, Monte Carlo collided). What the guardian costs, over the
controller's calls on those states: overrides (the command differs from the proposal), ``outside`` (calls with
no admissible command: the state outside the set, hardest braking; safe-acc: its emergency profile or its
inevitable-collision braking), the mean time gap h/v (v > 1 m/s) and the
mean |jerk| |a+ - a|/dt. Beside it: the share of the peer's own start distribution (ACC at 0 m/s^2, speeds
0-50.8 m/s, gap up to 50 m) that each criterion accepts. The searches stop at their first falsification, so the
costs of different rows are over different trees.

Runs (the peer's default budgets, 250 nodes x 10000 steps and 1500 s per backward step, are far too long here;
each run below takes ~25 min, ~7 min, ~3 min on a loaded 2-core machine):

    cd /tmp && python /work/main/benchmarks/peer_acc_falsifier.py --peer /tmp/peer/src --seeds 3 \\
        --nodes 50 --steps 300 --backward-nodes 20 --backward-steps 60 --backward-seconds 20
    cd /tmp && python /work/main/benchmarks/peer_acc_falsifier.py --peer /tmp/peer/src --seeds 3 \\
        --guardians plain --starts actuated --nodes 50 --steps 300 --backward-nodes 20 --backward-steps 60 \\
        --backward-seconds 20
    cd /tmp && python /work/main/benchmarks/peer_acc_falsifier.py --peer /tmp/peer/src --seeds 3 \\
        --kinds monte_carlo forward --proposers pi extended_pi --guardians actuated --h-min 0.001
    cd /tmp && python /work/main/benchmarks/peer_acc_falsifier.py --peer /tmp/peer/src --safe-acc /tmp/safe-acc \\
        --guardians safe_acc actuated plain --kinds forward monte_carlo --seeds 7 --seed0 100

    options: [--safe-acc DIR] [--seeds N] [--seed0 S] [--kinds ...] [--proposers ...] [--guardians ...]
             [--nodes N] [--steps N]
             [--backward-nodes N] [--backward-steps N] [--backward-seconds S] [--starts own|actuated]
             [--h-min M] [--share-samples N] [--json] [--save FILE]

The peer's copy: ``git --git-dir=<mirror> archive HEAD | tar -x -C /tmp/peer/src`` (safe-acc's likewise; it needs
qpsolvers and quadprog, and its recapturing controllers' data, absent from its mirror, is not used: the searches
have one lead and no cut-in). Needs numpy, scipy,
commonroad-vehicle-models (the peer imports the 2019 module names ``parameters_vehicle2``, ``init_KS``,
``vehicleDynamics_KS`` and ``vehicleParameters``; they are mapped onto the package ``vehiclemodels``, the same
functions renamed) and ruamel.yaml (imported by the peer; ``config.yaml`` is read with ruamel's current API,
the peer's ``round_trip_load`` is gone from ruamel.yaml >= 0.18). The peer's ``output.storage`` (CommonRoad
scenario files, 2019 commonroad-io API) is not needed: its ``store_results`` is replaced by a hook that keeps
the end node, and where it does not import (current commonroad-io has no ``commonroad.geometry.shape``) a stub
stands in. Under numpy 2 the forward RRT's lead input (a 1-element array) is passed on as its float.
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import io
import json
import math
import os
import sys
import time
import types

import numpy as np

from itha.actuator import ActuatedSet, Actuator
from itha.car_following import CarFollowingParams, MaximalSet, admissible_inputs

KINDS = ("forward", "backward", "monte_carlo")
PROPOSERS = ("pi", "extended_pi", "idm", "collision_avoidance", "safe_acc_nominal")
GUARDIANS = ("plain", "unaware", "actuated", "safe_acc")
H_MIN = 0.1
OVERRIDE_TOL = 1e-9
STALL_FACTOR = 3   # a search that moves more than this many times its budget of states is stopped as stalled


class Stalled(Exception):
    """The peer's forward RRT resamples until it has ``number_nodes`` children with a positive gap; where every
    child of every node collides it never gets them (seen with plain proposers from the actuated set's starts)."""


# ---- the peer ------------------------------------------------------------------------------------------
def load_peer(path: str) -> types.SimpleNamespace:
    """Import the peer's modules from ``path``; its 2019 names of the CommonRoad vehicle models are mapped onto
    the ``vehiclemodels`` package (the same functions, renamed)."""
    from vehiclemodels import (
        init_ks,
        parameters_vehicle1,
        parameters_vehicle2,
        parameters_vehicle3,
        vehicle_dynamics_ks,
        vehicle_parameters,
    )
    aliases = {"parameters_vehicle1": {"parameters_vehicle1": parameters_vehicle1.parameters_vehicle1},
               "parameters_vehicle2": {"parameters_vehicle2": parameters_vehicle2.parameters_vehicle2},
               "parameters_vehicle3": {"parameters_vehicle3": parameters_vehicle3.parameters_vehicle3},
               "init_KS": {"init_KS": init_ks.init_ks},
               "vehicleDynamics_KS": {"vehicleDynamics_KS": vehicle_dynamics_ks.vehicle_dynamics_ks},
               "vehicleParameters": {"VehicleParameters": vehicle_parameters.VehicleParameters}}
    for name, attrs in aliases.items():
        if name not in sys.modules:
            mod = types.ModuleType(name)
            mod.__dict__.update(attrs)
            sys.modules[name] = mod
    path = os.path.abspath(path)
    if not os.path.isfile(os.path.join(path, "lead_search", "forward_search.py")):
        raise SystemExit(f"--peer {path}: not a copy of CommonRoad/safety-falsification-acc (no lead_search/)")
    sys.path.insert(0, path)
    try:
        import output.storage
    except ImportError as e:
        # It writes CommonRoad scenario files with the 2019 commonroad-io API (commonroad.geometry.shape ...),
        # gone from current commonroad-io; the searches only call store_results, replaced below anyway.
        print(f"peer's output.storage does not import ({e}); its store_results is replaced", file=sys.stderr)
        import output
        stub = types.ModuleType("output.storage")
        stub.store_results = None
        sys.modules["output.storage"] = output.storage = stub
    import lead_search.backward_search as backward
    import lead_search.forward_search as forward
    import lead_search.monte_carlo_simulation as monte_carlo
    from acc import acc_interface
    from common import configuration, node, utility_fcts
    from lead_search import rrt, utility_search
    from ruamel.yaml import YAML
    with open(os.path.join(path, "config.yaml")) as f:
        config = YAML(typ="safe").load(f)
    return types.SimpleNamespace(path=path, config=config, acc_interface=acc_interface, configuration=configuration,
                                 node=node, utility_fcts=utility_fcts, backward=backward, forward=forward,
                                 monte_carlo=monte_carlo, rrt=rrt, utility_search=utility_search,
                                 searches={"forward": forward, "backward": backward, "monte_carlo": monte_carlo},
                                 originals={}, h_min=H_MIN)


def load_safe_acc(path: str, peer) -> types.SimpleNamespace:
    """Import CommonRoad/safe-acc's ``SafeACC`` and its configuration from ``path``. Both repositories name their
    packages ``acc`` and ``common`` (namespace packages): safe-acc's are imported with the peer's path and modules
    out of the way, and the peer's are put back. Its ``common.vehicle`` (typing only here; it imports the 2020
    commonroad-io ``commonroad.geometry.shape``/``trajectory.State``) is stubbed: the vehicles are ``_SafeAccCar``."""
    path = os.path.abspath(path)
    if not os.path.isfile(os.path.join(path, "acc", "safe_acc.py")):
        raise SystemExit(f"--safe-acc {path}: not a copy of CommonRoad/safe-acc (no acc/safe_acc.py)")

    def mine(name: str) -> bool:
        return name in ("acc", "common") or name.startswith(("acc.", "common."))

    saved = {k: v for k, v in sys.modules.items() if mine(k)}
    saved_path = list(sys.path)
    for k in saved:
        del sys.modules[k]
    sys.path[:] = [path] + [p for p in sys.path if os.path.abspath(p or ".") != peer.path]
    try:
        import common
        stub = types.ModuleType("common.vehicle")
        stub.Vehicle = object
        sys.modules["common.vehicle"] = common.vehicle = stub
        from acc.nominal_acc import NominalACC
        from acc.safe_acc import SafeACC
        from acc.safety_layer import SafetyLayer
        from common import configuration, util_motion
    finally:
        sys.path[:] = saved_path
        for k in [k for k in sys.modules if mine(k)]:
            del sys.modules[k]
        sys.modules.update(saved)
    from ruamel.yaml import YAML
    with open(os.path.join(path, "config.yaml")) as f:
        config = YAML(typ="safe").load(f)
    return types.SimpleNamespace(path=path, SafeACC=SafeACC, SafetyLayer=SafetyLayer, NominalACC=NominalACC,
                                 configuration=configuration, util_motion=util_motion, config=config)


class _SafeAccCar:
    """The one vehicle safe-acc's ``SafeACC.execute`` reads, at its time step 0: longitudinal state, front and rear."""

    id = 1

    def __init__(self, front: float, rear: float, v: float, a: float):
        self.states_lon = {0: types.SimpleNamespace(s=front, v=v, a=a)}
        self._front, self._rear = front, rear
        self.safe_distance_list = {0: 0.0}   # read only by its nominal ACC's QP, which the proposer replaces

    def front_position(self, time_step: int) -> float:
        return self._front

    def rear_position(self, time_step: int) -> float:
        return self._rear


class _Proposal:
    """safe-acc's nominal controller slot (``calculate_input``), filled by the proposer: safe-acc's design
    exchanges the nominal ACC freely, its safety layer and fail-safe carry the guarantee. None: the nominal found no
    input (safe-acc's own QP), which its safety layer answers with the emergency profile."""

    value: float | None = 0.0

    def calculate_input(self, *args) -> float:
        return self.value


def _numpy2_nominal(NominalACC):
    """safe-acc's ``NominalACC`` with its jerk weight handed to its QP as a number: its ``motion_equations`` returns
    it as a 1-element array, which numpy >= 2 refuses to store in a matrix cell (``rr[i, i] = r``); and an infeasible
    QP answered None as safe-acc's code meant: qpsolvers >= 2 returns None where the qpsolvers of 2020 raised, and
    its ``except`` turned that into None, while today it indexes the None (a TypeError). Nothing else differs."""
    class Nominal(NominalACC):
        @staticmethod
        def motion_equations(*args):
            a_d, b_d, q, r = NominalACC.motion_equations(*args)
            return a_d, b_d, q, float(np.asarray(r).reshape(-1)[0])

        def calculate_input(self, *args):
            try:
                return super().calculate_input(*args)
            except TypeError:
                return None
    return Nominal


class SafeAccGuard:
    """CommonRoad/safe-acc's provably safe ACC over a proposer: its own code (``SafeACC.execute``: the test for an
    inevitable collision state, the safety layer's check of the proposal against its safe distance at the next
    step, the emergency profile that gradually engages full braking), on the peer's vehicle.

    Parameters: the peer's ACC bounds (a in [-8, 1.5], jerk +-10, v_max of vehicle 2, no reaction time, no
    acceleration error ``a_corr``), the lead's (a_min -8, speeds 0 to vehicle 2's v_max), safe-acc's own emergency
    profile (config.yaml: ten comfortable jerk steps, then ``num_steps_fb`` steps of ``j_min``), and its standstill
    distance ``const_dist_offset`` set to this run's ``h_min`` (safe-acc's default is 0.5 m; ours 0.1 m), so both
    guardians keep the same least gap. One deviation: an emergency that lasts beyond its profile's 200 steps holds
    the profile's last acceleration (safe-acc would index past the end)."""

    def __init__(self, sa, peer, h_min: float):
        cfg = peer.config
        acc, lead = cfg["acc_vehicle_param"], cfg["lead_vehicle_param"]
        c = peer.configuration
        v_max = float(c.create_acc_vehicle_param(dict(acc))["dynamics_param"].longitudinal.v_max)
        v_max_lead = float(c.create_lead_vehicle_param(dict(lead))["dynamics_param"].longitudinal.v_max)
        self.dt = float(cfg["simulation_param"]["dt"])
        self.ego = {"a_min": float(acc["a_min"]), "a_max": float(acc["a_max"]), "a_corr": 0.0,
                    "j_max": float(acc["j_max"]), "j_min": float(acc["j_min"]), "t_react": 0.0, "v_min": 0.0,
                    "v_max": v_max}
        self.other = {"a_min": float(lead["a_min"]), "a_max": float(lead["a_max"]), "v_min": 0.0, "v_max": v_max_lead,
                      "j_min": float(lead["j_min"]), "j_max": float(lead["j_max"])}
        own = sa.config["acc_param"]
        acc_param = sa.configuration.create_acc_param(
            {"common": dict(own["common"], const_dist_offset=h_min),
             "emergency": {"emergency_profile": list(own["emergency"]["emergency_profile"]),
                           "num_steps_fb": own["emergency"]["num_steps_fb"]}}, self.ego["j_min"])
        sim = {"dt": self.dt, "verbose_mode": False}
        self.profile = acc_param["emergency"]["emergency_profile"]
        self.h_min, self.util = h_min, sa.util_motion
        self.nominal = _Proposal()
        self.layer = sa.SafetyLayer(self.nominal, sim, self.ego, acc_param, self.other)
        self.safe_acc = sa.SafeACC(None, self.layer, None, None, sim, self.ego, acc_param, self.other)
        self.own_nominal = _numpy2_nominal(sa.NominalACC)(sim, own["nominal_acc"], dict(self.ego, fov=math.inf))

    def nominal_acceleration(self, x) -> float | None:
        """safe-acc's own nominal ACC (its QP over a 6 s horizon keeping the safe distance), None where it finds no
        solution."""
        v, h, vL, a = x
        return self.own_nominal.calculate_input(a, v, vL, 0.0, h, self.safe_distance(v, a, vL))

    def safe_distance(self, v: float, a: float, vL: float) -> float:
        """safe-acc's safe distance (ego executing its emergency profile, the lead braking at ``a_min``)."""
        e, o = self.ego, self.other
        return self.util.safe_distance_profile_based(0.0, v, a, 0.0, vL, self.dt, e["t_react"], e["a_min"], e["a_max"],
                                                     e["j_max"], e["v_min"], e["v_max"], o["a_min"], o["v_min"],
                                                     o["v_max"], e["a_corr"], self.h_min, self.profile, 0)

    def accepts(self, x) -> bool:
        v, h, vL, a = x
        return h > self.safe_distance(v, a, vL)

    def decide(self, proposal: float, x, emergency) -> tuple[float, tuple]:
        """safe-acc's acceleration at state ``x = (v, h, v_L, a)`` given the proposal and the emergency under way
        (``(steps so far, its acceleration profile)``); returns it with the emergency after this step."""
        v, h, vL, a = x
        layer = self.layer
        if proposal is not None and math.isnan(proposal):
            proposal = None
        layer.emergency_step_counter, layer.activated_emergency_acc_profile = emergency or (0, None)
        profile = layer.activated_emergency_acc_profile
        if profile is not None and layer.emergency_step_counter >= len(profile):
            profile = layer.activated_emergency_acc_profile = profile + [profile[-1]] * (
                layer.emergency_step_counter - len(profile) + 1)
        self.nominal.value = proposal
        sa = self.safe_acc
        sa.strategy_list, sa.emergency_maneuver_activity = [], [0]   # its logs, kept short
        sa.num_vehicles.clear()
        out = sa.execute([_SafeAccCar(h, h, vL, 0.0)], [], _SafeAccCar(0.0, 0.0, v, a), 0)
        return float(out), (layer.emergency_step_counter, layer.activated_emergency_acc_profile)


def peer_params(peer, kind: str, proposer: str, budget: dict) -> dict:
    """The peer's parameter dictionaries (config.yaml, through its own ``create_*``), with this run's budget."""
    cfg = copy.deepcopy(peer.config)
    c = peer.configuration
    sim = dict(cfg["simulation_param"], search_type=kind, verbose_mode=False, store_results=False)
    rrt_param = dict(cfg["rrt_param"])
    if kind == "backward":
        sim.update(num_iterations=budget["backward_steps"], max_comp_time_backward=budget["backward_seconds"])
        rrt_param["number_nodes"] = budget["backward_nodes"]
    else:
        sim["num_iterations"] = budget["steps"]
        rrt_param["number_nodes"] = budget["nodes"]
    acc_vehicle = c.create_acc_vehicle_param(dict(cfg["acc_vehicle_param"], controller=proposer))
    return {"simulation_param": c.create_sim_param(sim), "rrt_param": c.create_rrt_param(rrt_param),
            "lead_vehicle_param": c.create_lead_vehicle_param(dict(cfg["lead_vehicle_param"])),
            "acc_vehicle_param": acc_vehicle,
            "acc_param": c.create_acc_param(cfg["acc_param"], acc_vehicle["controller"]),
            "acc_param_all_controllers": cfg["acc_param"]}


def guardian_sets(peer) -> tuple[ActuatedSet, MaximalSet, CarFollowingParams]:
    """Both sets on the peer's vehicle (see the module docstring)."""
    cfg = peer.config
    acc, lead = cfg["acc_vehicle_param"], cfg["lead_vehicle_param"]
    c = peer.configuration
    v_max = c.create_acc_vehicle_param(dict(acc))["dynamics_param"].longitudinal.v_max
    p = CarFollowingParams(dt=float(cfg["simulation_param"]["dt"]), v_max=float(v_max), h_min=peer.h_min,
                           u_min=float(acc["a_min"]), u_max=float(acc["a_max"]), d_min=float(lead["a_min"]),
                           d_max=float(lead["a_max"]), integration="exact")
    if not (acc["j_max"] == -acc["j_min"]):
        raise SystemExit("the ACC's jerk bounds are not symmetric: Actuator has one bound")
    return ActuatedSet(p, Actuator(jerk=float(acc["j_max"]), profile="hold")), MaximalSet(p), p


# ---- one run's bookkeeping ---------------------------------------------------------------------------
class Run:
    """What one search did: the states the peer moved forwards from accepted starts, the controller's calls."""

    def __init__(self, guardian: str, starts: str, A: ActuatedSet, S: MaximalSet, cap: float = math.inf,
                 guard: "SafeAccGuard | None" = None):
        self.guardian, self.starts, self.A, self.S, self.cap, self.guard = guardian, starts, A, S, cap, guard
        self.emergency = None           # safe-acc's emergency under way where no node carries it (backward search)
        self.recording = False          # a trajectory from an accepted start is being simulated
        self.root = None                # its start node (backward: where the re-simulation begins)
        self.states = 0
        self.least_gap = math.inf
        self.collisions = 0
        self.first_collision = None
        self.exits = 0                  # steps from a state inside the guardian's set to one outside
        self.first_exit = None
        self.offered = self.accepted = 0
        self.calls = self.overrides = self.outside = 0
        self.time_gaps, self.jerks = [], []
        self.end_node = None

    # the start criterion
    def accepts(self, node) -> bool:
        """The peer's criterion (gap > safe_distance), and the guardian's set unless plain (safe-acc: its safe
        distance)."""
        if not node.delta_s > node.safe_distance:
            return False
        which = self.guardian if self.starts == "own" else "actuated"
        if which == "plain":
            return True
        x = state_of(node)
        if which == "safe_acc":
            return self.guard.accepts(x)
        if which == "actuated":
            return self.A.contains(x)
        return bool(self.S.contains(x[:3])[0])

    def inside(self, node) -> bool:
        """The node's state is in the guardian's set (kept on the node: a parent is asked once per child)."""
        known = getattr(node, "_guardian_inside", None)
        if known is None:
            x = state_of(node)
            known = self.A.contains(x) if self.guardian == "actuated" else bool(self.S.contains(x[:3])[0])
            node._guardian_inside = known
        return known

    def record(self, node):
        if not self.recording:
            return
        self.states += 1
        if self.states > self.cap:
            raise Stalled
        if self.guardian in ("unaware", "actuated") and node.parent is not None and self.inside(node.parent) \
                and not self.inside(node):
            self.exits += 1
            if self.first_exit is None:
                self.first_exit = self.exit_report(node)
        gap = float(node.delta_s)
        self.least_gap = min(self.least_gap, gap)
        if gap <= 0.0:
            self.collisions += 1
            if self.first_collision is None:
                self.first_collision = trace(node, self.root)

    def exit_report(self, node) -> dict:
        """A step that left the guardian's set: the state before, the command, the lead's input, the state the
        peer's vehicles reached and the state the set's own model predicts."""
        x, y = state_of(node.parent), state_of(node)
        c, aL = y[3], float(node.lead_state.acceleration)
        out = {"before": x, "command": c, "lead_accel": aL, "after": y}
        if self.guardian == "actuated":
            out.update(predicted=self.A.next_state(x, c, aL), floor_before=self.A.floor(x), floor_after=self.A.floor(y),
                       floor_predicted=self.A.floor(self.A.next_state(x, c, aL)),
                       admissible_before=self.A.admissible_commands(x))
        else:
            out.update(admissible_before=admissible_inputs(self.S, x[:3]))
        return out


def state_of(node) -> tuple:
    """``(v, h, v_L, a)`` of a peer node (speeds clipped at 0 against odeint's rounding)."""
    return (max(float(node.acc_state.velocity), 0.0), float(node.delta_s), max(float(node.lead_state.velocity), 0.0),
            float(node.acc_state.acceleration))


def trace(node, root) -> list:
    """The states from the start to ``node``: time step, ego speed/acceleration, gap, lead speed/acceleration."""
    out = []
    while node is not None:
        out.append({"k": len(out), "v": float(node.acc_state.velocity), "a": float(node.acc_state.acceleration),
                    "h": float(node.delta_s), "vL": float(node.lead_state.velocity),
                    "aL": float(node.lead_state.acceleration)})
        if node is root:
            break
        node = node.parent
    out.reverse()
    for k, row in enumerate(out):
        row["k"] = k
    return out


class Guarded:
    """A proposer of the peer behind a guardian, with the peer's ``acc_control`` interface."""

    def __init__(self, inner, run: Run, peer, acc_vehicle_param: dict, dt: float):
        self.inner, self.run, self.peer, self.dt = inner, run, peer, dt
        self.limits = (acc_vehicle_param["a_min"], acc_vehicle_param["a_max"], dt,
                       acc_vehicle_param["dynamics_param"].longitudinal.v_max, acc_vehicle_param["j_min"],
                       acc_vehicle_param["j_max"])

    def acc_control(self, v_lead, v_acc, s_x_lead, s_x_acc, a_acc):
        run = self.run
        x = (max(float(v_acc), 0.0), float(s_x_lead - s_x_acc), max(float(v_lead), 0.0), float(a_acc))
        if self.inner is None:   # safe-acc's own nominal ACC (no answer: NaN, for its safety layer)
            nominal = run.guard.nominal_acceleration(x)
            proposal = math.nan if nominal is None else float(nominal)
        else:
            proposal = float(self.inner.acc_control(v_lead, v_acc, s_x_lead, s_x_acc, a_acc))
        out = proposal
        if run.guardian == "safe_acc":
            out = self.safe_acc(proposal, x)
        elif run.guardian != "plain":
            if run.guardian == "actuated":
                allowed = run.A.admissible_commands(x)
            else:
                allowed = admissible_inputs(run.S, x[:3])
            if allowed:
                command = min(max(proposal, allowed[0][0]), allowed[-1][1])
            else:
                command = run.A.params.u_min
                run.outside += run.recording
            a_min, a_max, dt, v_max, j_min, j_max = self.limits
            out = float(self.peer.utility_fcts.check_feasibility(command, v_acc, a_min, a_max, dt, v_max, a_acc,
                                                                 j_min, j_max))
            run.overrides += run.recording and abs(out - proposal) > OVERRIDE_TOL
        if not run.recording:      # the backward tree's own steps (its ACC states are placeholders): not counted
            return out
        run.calls += 1
        if x[0] > 1.0:
            run.time_gaps.append(x[1] / x[0])
        run.jerks.append(abs(out - x[3]) / self.dt)
        return out

    def safe_acc(self, proposal: float, x) -> float:
        """safe-acc decides; its emergency under way rides on the peer's nodes (a tree search steps many
        trajectories in turn: the emergency a node's state inherits is the one its parent's step left)."""
        run, node = self.run, self.peer.current_node
        incoming = run.emergency if node is None else getattr(node.parent, "_safe_acc_emergency", None)
        command, emergency = run.guard.decide(proposal, x, incoming)
        if node is None:
            run.emergency = emergency
        else:
            node._safe_acc_emergency = emergency
        run.outside += run.recording and (emergency[0] > 0 or command == run.guard.ego["a_min"])
        a_min, a_max, dt, v_max, j_min, j_max = self.limits
        out = float(self.peer.utility_fcts.check_feasibility(command, x[0], a_min, a_max, dt, v_max, x[3], j_min,
                                                             j_max))
        run.overrides += run.recording and abs(out - proposal) > OVERRIDE_TOL
        return out


# ---- hooks into the peer's searches --------------------------------------------------------------------
def install_hooks(peer):
    """Wrap the peer's controller factory, forward simulation, start sampler, backward validation and result
    storage; the wrappers read the current ``Run`` from ``peer.current``."""
    o = peer.originals
    if o:
        return
    o["create"] = peer.acc_interface.AccFactory.create.__func__
    o["forward_simulation"] = peer.rrt.RRT.forward_simulation
    o["init_nodes_forward"] = peer.utility_search.init_nodes_forward
    o["check_backward"] = peer.backward.check_unsafe_node_reached
    o["acc_input_forward"] = peer.utility_fcts.acc_input_forward
    peer.current_node = None

    def create(cls, simulation_param, acc_vehicle_param, acc_param):
        inner = None if peer.current.proposer == "safe_acc_nominal" else \
            o["create"](cls, simulation_param, acc_vehicle_param, acc_param)
        return Guarded(inner, peer.current, peer, acc_vehicle_param, simulation_param["dt"])

    def forward_simulation(self, steering_velocity, acceleration, *args, **kw):
        # The forward RRT hands the lead's input over as a pseudo-inverse's 1-element row; numpy 2 turns that
        # into a float neither by float() nor inside odeint's right-hand side: the value itself is passed on.
        acceleration = float(np.asarray(acceleration).reshape(-1)[0])
        node = o["forward_simulation"](self, steering_velocity, acceleration, *args, **kw)
        peer.current.record(node)
        return node

    def init_nodes_forward(rrt_param, acc_vehicle_param, simulation_param, lead_vehicle_param):
        """The peer's sampler (starts it calls safe), kept when the run's criterion accepts them."""
        run, want, kept = peer.current, rrt_param["number_nodes"], []
        while len(kept) < want:
            for node in o["init_nodes_forward"](rrt_param, acc_vehicle_param, simulation_param, lead_vehicle_param):
                if len(kept) == want:
                    break
                run.offered += 1
                if run.accepts(node):
                    run.accepted += 1
                    kept.append(node)
            if run.offered > 200 * want and not kept:
                raise RuntimeError("the start criterion accepts none of the peer's starts")
        return kept

    def check_backward(node, *args, **kw):
        """The peer's re-simulation of a candidate start; the start counts when the run's criterion accepts it."""
        run = peer.current
        run.offered += 1
        ok = run.accepts(node)
        run.accepted += ok
        run.recording, run.root = ok, node
        try:
            unsafe, _peer_safe = o["check_backward"](node, *args, **kw)
        finally:
            run.recording, run.root = False, None
        return unsafe, ok

    def store_results(end_node, *args, **kw):
        peer.current.end_node = end_node

    def acc_input_forward(acc_planner, node, *args, **kw):
        """The peer's ACC step from ``node``, with the node known to a controller that keeps a state (safe-acc)."""
        peer.current_node = node
        try:
            return o["acc_input_forward"](acc_planner, node, *args, **kw)
        finally:
            peer.current_node = None

    peer.acc_interface.AccFactory.create = classmethod(create)
    peer.rrt.RRT.forward_simulation = forward_simulation
    for mod in (peer.forward, peer.monte_carlo):
        mod.init_nodes_forward = init_nodes_forward
    peer.backward.check_unsafe_node_reached = check_backward
    for mod in peer.searches.values():
        mod.store_results = store_results
        mod.acc_input_forward = acc_input_forward


def search(peer, kind: str, proposer: str, guardian: str, seed: int, budget: dict, starts: str) -> dict:
    """One of the peer's searches, seeded, with ``proposer`` behind ``guardian``."""
    A, S, _ = guardian_sets(peer)
    cap = STALL_FACTOR * (budget["nodes"] * budget["steps"] if kind != "backward"
                          else budget["backward_nodes"] * budget["backward_steps"] ** 2)
    guard = getattr(peer, "safe_acc_guard", None)
    if guardian == "safe_acc" and guard is None:
        raise SystemExit("--guardians safe_acc needs --safe-acc DIR (a copy of CommonRoad/safe-acc)")
    if proposer == "safe_acc_nominal" and guardian != "safe_acc":
        raise SystemExit("--proposers safe_acc_nominal (safe-acc's own nominal ACC, which may find no input) runs "
                         "behind --guardians safe_acc only")
    run = Run(guardian, starts, A, S, cap, guard)
    run.proposer = proposer
    peer.current = run
    prm = peer_params(peer, kind, "pi" if proposer == "safe_acc_nominal" else proposer, budget)
    np.random.seed(seed)
    run.recording = kind != "backward"
    t0 = time.perf_counter()
    stalled, result = False, None
    with contextlib.redirect_stdout(io.StringIO()) as out:
        try:
            result = peer.searches[kind].search(prm["rrt_param"], prm["acc_vehicle_param"],
                                                prm["simulation_param"], prm["lead_vehicle_param"], prm["acc_param"],
                                                prm["acc_param_all_controllers"])
        except Stalled:
            stalled = True
    seconds = time.perf_counter() - t0
    printed = out.getvalue()
    if kind == "forward":
        falsified = "unsafe node" in printed
    elif kind == "backward":
        falsified = bool(result)
    else:
        falsified = "collision" in printed
    falsifying = None
    if falsified and run.end_node is not None:
        falsifying = trace(run.end_node, None)
        if kind == "backward":   # the backward tree's end node is the found start: re-simulated in the trace below
            falsifying = falsifying[-1:]
    return {"kind": kind, "proposer": proposer, "guardian": guardian, "seed": seed, "falsified": falsified,
            "stalled": stalled,
            "states": run.states, "collisions": run.collisions, "least_gap": run.least_gap,
            "starts_offered": run.offered, "starts_accepted": run.accepted, "calls": run.calls,
            "overrides": run.overrides, "outside": run.outside, "exits": run.exits, "first_exit": run.first_exit,
            "time_gap_mean": float(np.mean(run.time_gaps)) if run.time_gaps else math.nan,
            "jerk_mean": float(np.mean(run.jerks)) if run.jerks else math.nan,
            "first_collision": run.first_collision, "falsifying_end": falsifying, "seconds": seconds}


# ---- what each accepts as a safe start ------------------------------------------------------------------
def accepted_share(peer, samples: int, seed: int) -> dict:
    """Over the peer's start distribution (``init_nodes_forward`` before its own test: ACC at 0 m/s^2, speeds
    uniform in [0, v_max], the lead's centre uniform as the peer draws it): the share each criterion accepts."""
    A, S, _ = guardian_sets(peer)
    guard = getattr(peer, "safe_acc_guard", None)
    prm = peer_params(peer, "forward", "pi", {"nodes": 1, "steps": 1})
    acc, lead, sim = prm["acc_vehicle_param"], prm["lead_vehicle_param"], prm["simulation_param"]
    State, Node = peer.node.State, peer.node.Node
    rng = np.random.default_rng(seed)
    l_acc, l_lead = acc["dynamics_param"].l, lead["dynamics_param"].l
    n = {"peer (gap > safe_distance)": 0, "unaware set": 0, "actuated set": 0, "peer and actuated set": 0}
    for _ in range(samples):
        a_state = State(acc["s_init"], 1.75, 0, rng.uniform(sim["v_col"], acc["dynamics_param"].longitudinal.v_max),
                        0, 0, 0, 0)
        l_state = State(rng.uniform(acc["s_init"] + l_acc / 2 + sim["delta_s_init_min"],
                                    acc["s_init"] + l_acc / 2 + l_lead / 2 + sim["delta_s_init_max"]), 1.75, 0,
                        rng.uniform(0, lead["dynamics_param"].longitudinal.v_max), 0, 0, 0, 0)
        node = Node(None, l_state, a_state, lead, acc, sim)
        x = state_of(node)
        peer_ok = node.delta_s > node.safe_distance
        act = A.contains(x)
        n["peer (gap > safe_distance)"] += peer_ok
        n["unaware set"] += bool(S.contains(x[:3])[0])
        n["actuated set"] += act
        n["peer and actuated set"] += peer_ok and act
        if guard is not None:
            n["safe-acc (gap > its safe distance)"] = n.get("safe-acc (gap > its safe distance)", 0) + guard.accepts(x)
    return {k: v / samples for k, v in n.items()}


# ---- the table ---------------------------------------------------------------------------------------------
def aggregate(rows: list) -> list:
    groups = {}
    for r in rows:
        groups.setdefault((r["kind"], r["proposer"], r["guardian"]), []).append(r)
    out = []
    for (kind, proposer, guardian), rs in groups.items():
        calls = sum(r["calls"] for r in rs)
        tg = [r["time_gap_mean"] for r in rs if not math.isnan(r["time_gap_mean"])]
        jk = [r["jerk_mean"] for r in rs if not math.isnan(r["jerk_mean"])]
        out.append({"kind": kind, "proposer": proposer, "guardian": guardian, "searches": len(rs),
                    "falsified": sum(r["falsified"] for r in rs), "stalled": sum(r["stalled"] for r in rs),
                    "collided_searches": sum(r["collisions"] > 0 for r in rs),
                    "collision_states": sum(r["collisions"] for r in rs),
                    "least_gap": min(r["least_gap"] for r in rs), "states": sum(r["states"] for r in rs),
                    "starts_accepted": sum(r["starts_accepted"] for r in rs),
                    "starts_offered": sum(r["starts_offered"] for r in rs),
                    "override_share": sum(r["overrides"] for r in rs) / calls if calls else math.nan,
                    "outside_steps": sum(r["outside"] for r in rs), "exits": sum(r["exits"] for r in rs),
                    "time_gap_mean": float(np.mean(tg)) if tg else math.nan,
                    "jerk_mean": float(np.mean(jk)) if jk else math.nan,
                    "seconds": sum(r["seconds"] for r in rs)})
    return out


def print_table(groups: list, share: dict, budget: dict, starts: str, h_min: float):
    print(f"budget: forward/monte_carlo {budget['nodes']} nodes x {budget['steps']} steps; backward "
          f"{budget['backward_nodes']} nodes x {budget['backward_steps']} steps, <= {budget['backward_seconds']} s "
          f"a step; starts: {starts}; h_min {h_min} m")
    head = (f"{'search':11} {'proposer':19} {'guardian':8} {'runs':>4} {'falsif':>6} {'stall':>5} {'collided':>8} "
            f"{'least gap':>9} {'states':>7} {'starts acc/off':>14} {'overr':>6} {'outside':>7} {'exits':>5} "
            f"{'gap [s]':>7} {'|jerk|':>6} {'sec':>5}")
    print(head)
    for g in groups:
        print(f"{g['kind']:11} {g['proposer']:19} {g['guardian']:8} {g['searches']:>4} {g['falsified']:>6} "
              f"{g['stalled']:>5} "
              f"{g['collided_searches']:>8} {g['least_gap']:>9.3f} {g['states']:>7} "
              f"{str(g['starts_accepted']) + '/' + str(g['starts_offered']):>14} {g['override_share']:>6.1%} "
              f"{g['outside_steps']:>7} {g['exits']:>5} {g['time_gap_mean']:>7.2f} {g['jerk_mean']:>6.2f} "
              f"{g['seconds']:>5.0f}")
    print("share of the peer's start distribution accepted: " + ", ".join(f"{k} {v:.1%}" for k, v in share.items()))


def fmt(x) -> str:
    return "(" + ", ".join(f"{c:.6f}" for c in x) + ")"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", required=True, help="a copy of CommonRoad/safety-falsification-acc")
    ap.add_argument("--safe-acc", help="a copy of CommonRoad/safe-acc (needed by --guardians safe_acc)")
    ap.add_argument("--seeds", type=int, default=2, help="searches per search kind x proposer x guardian")
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    ap.add_argument("--proposers", nargs="+", choices=PROPOSERS, default=list(PROPOSERS))
    ap.add_argument("--guardians", nargs="+", choices=GUARDIANS, default=list(GUARDIANS[:3]))
    ap.add_argument("--nodes", type=int, default=10, help="forward and Monte Carlo: nodes per step")
    ap.add_argument("--steps", type=int, default=100, help="forward and Monte Carlo: steps (0.1 s each)")
    ap.add_argument("--backward-nodes", type=int, default=5)
    ap.add_argument("--backward-steps", type=int, default=20)
    ap.add_argument("--backward-seconds", type=float, default=10.0, help="backward: time limit of one step")
    ap.add_argument("--starts", choices=("own", "actuated"), default="own",
                    help="own: each controller's criterion; actuated: every controller from the actuated set")
    ap.add_argument("--h-min", type=float, default=H_MIN, help="the sets' least gap [m]")
    ap.add_argument("--share-samples", type=int, default=2000)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--save", help="also write the JSON report to this file")
    args = ap.parse_args(argv)
    budget = {"nodes": args.nodes, "steps": args.steps, "backward_nodes": args.backward_nodes,
              "backward_steps": args.backward_steps, "backward_seconds": args.backward_seconds}
    peer = load_peer(args.peer)
    peer.h_min = args.h_min
    install_hooks(peer)
    if args.safe_acc:
        peer.safe_acc_guard = SafeAccGuard(load_safe_acc(args.safe_acc, peer), peer, args.h_min)
    elif "safe_acc" in args.guardians:
        ap.error("--guardians safe_acc needs --safe-acc DIR (a copy of CommonRoad/safe-acc)")
    rows = []
    for kind in args.kinds:
        for proposer in args.proposers:
            for guardian in args.guardians:
                for seed in range(args.seed0, args.seed0 + args.seeds):
                    r = search(peer, kind, proposer, guardian, seed, budget, args.starts)
                    rows.append(r)
                    print(f"{kind} {proposer} {guardian} seed {seed}: falsified {r['falsified']}, "
                          f"stalled {r['stalled']}, "
                          f"collisions {r['collisions']}, least gap {r['least_gap']:.3f}, "
                          f"{r['seconds']:.0f} s", file=sys.stderr)
    share = accepted_share(peer, args.share_samples, args.seed0)
    groups = aggregate(rows)
    report = json.dumps({"budget": budget, "starts": args.starts, "h_min": args.h_min, "groups": groups, "rows": rows,
                         "accepted_share": share}, indent=1, default=float)
    if args.save:
        with open(args.save, "w") as f:
            f.write(report)
    if args.json:
        print(report)
        return 0
    print_table(groups, share, budget, args.starts, args.h_min)
    for r in rows:
        if r["guardian"] != "plain" and r["collisions"]:
            print(f"\n{r['kind']} {r['proposer']} {r['guardian']} seed {r['seed']}: collision from an accepted "
                  f"start; trace (k, v, a, h, vL, aL):")
            shown = r["first_collision"]
            for i, s in enumerate(shown):
                if len(shown) <= 25 or i < 2 or i >= len(shown) - 20:
                    print(f"  {s['k']:3} {s['v']:8.4f} {s['a']:7.3f} {s['h']:9.4f} {s['vL']:8.4f} {s['aL']:7.3f}")
                elif i == 2:
                    print(f"  ... ({len(shown) - 22} steps)")
    exits = [r for r in rows if r["guardian"] == "actuated" and r["first_exit"]]
    if exits:
        r, e = exits[0], exits[0]["first_exit"]
        print(f"\nfirst step out of the actuated set ({r['kind']} {r['proposer']} seed {r['seed']}):"
              f" (v, h, vL, a) {fmt(e['before'])}, command {e['command']:.6f}, lead {e['lead_accel']:.4f};"
              f" reached {fmt(e['after'])}, the set's model predicts {fmt(e['predicted'])};"
              f" floor {e['floor_before']:.6f} -> {e['floor_after']:.6f} (predicted {e['floor_predicted']:.6f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
