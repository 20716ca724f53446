"""Vehicles whose motion is exactly the model the guardian's sets were computed for.

highway-env's own vehicles follow a kinematic bicycle model; the overtake sets
assume (6.3)-(6.4) and the car-following sets assume (7.3). These classes keep
highway-env's interfaces (``act``, ``step``, lanes, rendering, IDM/MOBIL
decisions) and replace only the motion:

* ``OvertakeEgo``: the ego of Chapter 6, a point mass with input
  ``u_e = [a_ex, v_ey]`` (longitudinal acceleration, lateral velocity in units of
  ``y_e`` per second). Its next state is staged by the environment from the
  intention model's own ``PWASystem.step`` and applied in ``step``.
* ``IntentionLead``: the lead car, moved the same way (its acceleration is the
  intention model's (6.5)/(6.7)).
* ``PointMassIDM``: traffic deciding with highway-env's IDM and MOBIL, moving as
  (7.3): ``x+ = x + dt v``, ``v+ = min(max(v + dt a, 0), MAX_SPEED)`` with
  ``a in [-ACC_MAX, ACC_MAX]``; a lane change slides sideways at ``LATERAL_SPEED``.

All of them keep heading 0: the models have no yaw, and a yawed body would
reach further sideways than the safe set (6.8) accounts for. A collision is two
bodies overlapping now (``BodyContact``); highway-env's own check also flags
bodies that would overlap if the current velocities were held for one more step,
which for these vehicles is a prediction the model does not make.

Cars are ``WIDTH = 1.75`` m wide: the safe set (6.8) separates the two cars'
centre lines by at least ``0.9`` units of ``y_e`` (1.8 m at the default
``lateral_scale``), and bodies that touch count as colliding.
"""

from __future__ import annotations

import numpy as np
from highway_env import utils
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.graphics import VehicleGraphics
from highway_env.vehicle.kinematics import Vehicle

from intention.params import OvertakeParams

CAR_LENGTH = 5.0   # [m]
CAR_WIDTH = 1.75   # [m]


# [RGB] in videos (highway-env's palette); the panel's legend uses the same (guardian.wrappers.panel)
COLOURS = {"ego": VehicleGraphics.EGO_COLOR, "lead": VehicleGraphics.PURPLE, "traffic": VehicleGraphics.BLUE,
           "crashed": VehicleGraphics.RED}


class BodyContact:
    """Collision = the bodies overlap at this instant (no extrapolation, no impact shift).

    Also each kind's colour in the video (``ROLE``), red once crashed.
    """

    ROLE = "traffic"

    @property
    def color(self):
        return getattr(self, "_colour", None) or COLOURS["crashed" if self.crashed else self.ROLE]

    @color.setter
    def color(self, value):
        self._colour = value

    def _is_colliding(self, other, dt):
        if np.linalg.norm(other.position - self.position) > (self.diagonal + other.diagonal) / 2:
            return False, False, np.zeros(2)
        intersecting, _, _ = utils.are_polygons_intersecting(self.polygon(), other.polygon(), np.zeros(2),
                                                             np.zeros(2))
        return intersecting, False, np.zeros(2)



class OvertakeEgo(BodyContact, Vehicle):
    """The overtake ego: a point mass following (6.3).

    Accepted actions: a dict ``{"acceleration": a_ex, "steering": v_ey}`` (a
    ``ContinuousAction`` whose ranges are ``U_e``: for this point mass the second
    channel is the lateral velocity of (6.3), not a wheel angle), or a meta action
    (``"LANE_LEFT"``, ``"IDLE"``, ``"LANE_RIGHT"``, ``"FASTER"``, ``"SLOWER"``)
    tracked by a proportional controller on ``(v_ex, y_e)``. ``act(None)`` (the
    per-simulation-step call) recomputes the command from the last action.
    """

    ROLE = "ego"
    LENGTH = CAR_LENGTH
    WIDTH = CAR_WIDTH
    SPEED_GAIN = 1.0      # [1/s] meta actions: speed tracking
    route = None          # one straight road, no route to plan (highway-env's observations read it)
    LATERAL_GAIN = 2.0    # [1/s] meta actions: lateral tracking

    def __init__(self, road, position, speed: float, params: OvertakeParams, y_origin: float,
                 lateral_scale: float, target_speeds):
        super().__init__(road, position, heading=0.0, speed=speed)
        self.params = params
        self.y_origin = float(y_origin)        # simulator y of the right-lane centre (y_e = 0)
        self.lateral_scale = float(lateral_scale)  # metres per unit of y_e (simulator y grows to the right)
        self.target_speeds = np.asarray(target_speeds, dtype=float)
        self.target_speed_index = self.speed_to_index(speed)
        self.target_y = 0.0
        self.meta = None          # the last meta action, or None for continuous commands
        self.command = np.zeros(2)  # the decoded (a_ex, v_ey) before any supervision
        self.lateral_velocity = 0.0
        self._staged = None

    # ---- the model's coordinates -------------------------------------------------------
    @property
    def y_e(self) -> float:
        return (self.y_origin - float(self.position[1])) / self.lateral_scale

    def y_of(self, y_e: float) -> float:
        return self.y_origin - self.lateral_scale * y_e

    @property
    def velocity(self) -> np.ndarray:
        return np.array([self.speed, -self.lateral_scale * self.lateral_velocity])

    @property
    def input(self) -> np.ndarray:
        """The input ``u_e = [a_ex, v_ey]`` this step will apply (after any supervision)."""
        return np.array([float(self.action["acceleration"]), float(self.action["steering"])])

    # ---- the target speeds as highway-env's MDPVehicle offers them (observations read them) ----------------
    @property
    def speed_index(self) -> int:
        """The index in ``target_speeds`` the ego tracks: the meta actions' target, or, under continuous
        commands, the target speed nearest to the present speed (``TimeToCollision`` reads it)."""
        return self.target_speed_index if self.meta is not None else self.speed_to_index(self.speed)

    def index_to_speed(self, index: int) -> float:
        """[m/s] the target speed of ``index``."""
        return float(self.target_speeds[index])

    def speed_to_index(self, speed: float) -> int:
        """The index of the target speed nearest to ``speed`` (the rule the meta actions start from)."""
        return int(np.argmin(np.abs(self.target_speeds - speed)))

    # ---- actions ---------------------------------------------------------------------------
    def act(self, action=None) -> None:
        if isinstance(action, dict):
            self.meta = None
            self.command = np.array([float(action["acceleration"]), float(action["steering"])])
        elif isinstance(action, str):
            self._meta_action(action)
        elif action is not None:
            raise ValueError(f"OvertakeEgo.act: unknown action {action!r}")
        if self.meta is not None:
            self.command = self._track()
        self.action = {"acceleration": float(self.command[0]), "steering": float(self.command[1])}

    def _meta_action(self, name: str) -> None:
        p = self.params
        lanes = (0.0, 2 * p.left_lane_y)  # right and left lane centres in y_e
        if name == "FASTER":
            self.target_speed_index = min(self.target_speed_index + 1, len(self.target_speeds) - 1)
        elif name == "SLOWER":
            self.target_speed_index = max(self.target_speed_index - 1, 0)
        elif name == "LANE_LEFT":
            self.target_y = lanes[1]
        elif name == "LANE_RIGHT":
            self.target_y = lanes[0]
        elif name != "IDLE":
            raise ValueError(f"OvertakeEgo.act: unknown meta action {name!r}")
        self.meta = name

    def keep_lane(self) -> None:
        """Abandon a lane change: track the centre of the lane the ego is nearest to."""
        self.target_y = 0.0 if self.y_e < self.params.left_lane_y else 2 * self.params.left_lane_y

    def _track(self) -> np.ndarray:
        p = self.params
        v_ref = self.target_speeds[self.target_speed_index]
        a = self.SPEED_GAIN * (v_ref - self.speed) + p.b_e * self.speed  # cancels the drag of (6.3)
        vy = self.LATERAL_GAIN * (self.target_y - self.y_e)
        return np.array([np.clip(a, *p.a_ex_bounds), np.clip(vy, *p.v_ey_bounds)])

    # ---- motion -------------------------------------------------------------------------------
    def stage(self, v_next: float, y_next: float) -> None:
        """The model's next ``v_ex`` and ``y_e`` (computed by the environment with ``PWASystem.step``)."""
        self._staged = (float(v_next), float(y_next))

    def step(self, dt: float) -> None:
        if self._staged is None:
            raise RuntimeError("OvertakeEgo.step without a staged model transition")
        v_next, y_next = self._staged
        self._staged = None
        self.lateral_velocity = (y_next - self.y_e) / dt
        self.position = np.array([self.position[0] + dt * self.speed, self.y_of(y_next)])  # (6.4)
        if self.impact is not None:
            self.position += self.impact
            self.crashed, self.impact = True, None
        self.speed = v_next
        self.on_state_update()


class IntentionLead(BodyContact, Vehicle):
    """The lead car, driven by an intention model; its next speed is staged by the environment."""

    ROLE = "lead"
    LENGTH = CAR_LENGTH
    WIDTH = CAR_WIDTH

    def __init__(self, road, position, speed: float):
        super().__init__(road, position, heading=0.0, speed=speed)
        self._staged = None

    def stage(self, v_next: float) -> None:
        self._staged = float(v_next)

    def act(self, action=None) -> None:
        pass  # the environment applies the intention model

    def step(self, dt: float) -> None:
        if self._staged is None:
            raise RuntimeError("IntentionLead.step without a staged model transition")
        self.position = np.array([self.position[0] + dt * self.speed, self.position[1]])  # (6.4)
        if self.impact is not None:
            self.position += self.impact
            self.crashed, self.impact = True, None
        self.speed, self._staged = self._staged, None
        self.on_state_update()


class PointMassIDM(BodyContact, IDMVehicle):
    """IDM/MOBIL traffic moving as the car-following model (7.3)."""

    LENGTH = CAR_LENGTH
    WIDTH = CAR_WIDTH
    MAX_SPEED = 40.0        # [m/s] the car-following sets' v_max
    LATERAL_SPEED = 1.5     # [m/s] sideways speed during a lane change
    forbidden_lanes: frozenset = frozenset()  # lane ids MOBIL may not choose (the scenario's right lane)

    def mobil(self, lane_index) -> bool:
        if lane_index[2] in self.forbidden_lanes:
            return False
        return super().mobil(lane_index)

    def step(self, dt: float) -> None:
        self.timer += dt
        a = float(self.action["acceleration"])
        if self.crashed:
            a = -self.speed / dt if self.speed > 0 else 0.0  # stops: a model violation, and counted as one
        y_target = self.road.network.get_lane(self.target_lane_index).position(self.position[0], 0)[1]
        dy = float(np.clip(y_target - self.position[1], -self.LATERAL_SPEED * dt, self.LATERAL_SPEED * dt))
        self.position = np.array([self.position[0] + dt * self.speed, self.position[1] + dy])
        if self.impact is not None:
            self.position += self.impact
            self.crashed, self.impact = True, None
        self.heading = 0.0
        self.speed = float(min(max(self.speed + dt * a, 0.0), self.MAX_SPEED))
        self.on_state_update()


class LineHuggingIDM(IDMVehicle):
    """highway-env's IDM car that keeps its centre ``OFFSET`` metres off its lane's centre line: with a 4 m lane
    and a 2 m wide body its body lies over the line by 0.6 m while its centre (and its lane index) stay in its
    lane. The adversarial traffic for a guardian that reads lanes from lane indices alone (tests, campaigns:
    ``other_vehicles_type="envs.vehicles.LineHuggingIDM"``)."""

    OFFSET = 1.6  # [m] towards the right of the direction of travel (highway-env's +y); negative: the left

    def steering_control(self, target_lane_index) -> float:
        lane = self.road.network.get_lane(target_lane_index)
        s, r = lane.local_coordinates(self.position)
        heading_ahead = lane.heading_at(s + self.speed * self.TAU_PURSUIT)
        lateral_speed = -self.KP_LATERAL * (r - self.OFFSET)
        heading_ref = heading_ahead + np.clip(np.arcsin(np.clip(lateral_speed / utils.not_zero(self.speed), -1, 1)),
                                              -np.pi / 4, np.pi / 4)
        heading_rate = self.KP_HEADING * utils.wrap_to_pi(heading_ref - self.heading)
        slip = np.arcsin(np.clip(self.LENGTH / 2 / utils.not_zero(self.speed) * heading_rate, -1, 1))
        return float(np.clip(np.arctan(2 * np.tan(slip)), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE))


class LineHuggingLeftIDM(LineHuggingIDM):
    """``LineHuggingIDM`` over the line on its left (highway-env's -y)."""

    OFFSET = -1.6
