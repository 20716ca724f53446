"""A scene session's bodies from the guardian's own model objects (``guardian.model``): a driving stack that reads
its simulator into an ``EgoState`` and a ``Scene`` built by ``guardian.model.sensing.scene_of`` (whose ``sensed``
are the readings) sends them as they are; ``vehicle_body`` and ``guardian_body`` give the session's creation
from a bicycle kinematics and a ``GuardianConfig``. Lanes on the wire are slots (0 the leftmost)."""
from __future__ import annotations

import math


def _f(v) -> float:
    return float(v)


def ego_body(ego, scene, road, length: float, actuated: bool = False) -> dict:
    """``EgoSpec`` of ``ego`` (``guardian.model.scene.EgoState``) in ``scene``; ``x`` is the centre along the
    road (``ego.x`` on a ``RoadMap``, ``front - length / 2`` on one straight road); ``actuated``: the vehicle
    declares ``max_jerk``, and the body carries the acceleration its actuator applied over the last step."""
    from guardian.model.roads import RoadMap

    x = ego.x if isinstance(road, RoadMap) else ego.front - length / 2
    body = {"x": _f(x), "y": _f(ego.y), "heading": _f(ego.heading), "speed": _f(ego.speed), "front": _f(ego.front),
            "lane": int(ego.lane), "target_lane": int(ego.target_lane), "announces": bool(scene.ego.announces)}
    if actuated:
        body["acceleration"] = _f(ego.acceleration)
    return body


def car_body(s, road) -> dict:
    """``CarSpec`` of one reading (``guardian.model.sensing.Sensed``): its lanes as slots, as the wire has them."""
    body = {"id": s.name, "x": _f(s.x), "y": _f(s.y), "heading": _f(s.heading), "speed": _f(s.speed),
            "length": _f(s.length), "width": _f(s.width), "front": _f(s.front), "own": int(s.own),
            "lanes": sorted(int(k) for k in s.lanes), "beside": sorted(int(k) for k in s.beside),
            "swings": bool(s.swings), "announced": sorted(road.numbering.slot_set(s.announced))}
    for flag in ("announces", "crashed", "blind", "fixed"):
        if getattr(s, flag):
            body[flag] = True
    return body


def step_body(ego, scene, proposed, road, length: float, actuated: bool = False) -> dict:
    """A scene step's body (without ``seq``) from the objects a ``BicycleGuardian.step`` takes; ``scene`` must
    carry its readings (``scene.sensed``, as ``scene_of`` builds it)."""
    if not scene.sensed and scene.others:
        raise ValueError("the scene carries no readings (scene.sensed): build it with guardian.model.sensing.scene_of")
    return {"ego": ego_body(ego, scene, road, length, actuated), "cars": [car_body(s, road) for s in scene.sensed],
            "input": [_f(proposed[0]), _f(proposed[1])]}


def vehicle_body(kin, meta: bool, actuator=None) -> dict:
    """The ``vehicle`` of a scene session for a bicycle kinematics (``guardian.decide.kinematics.BicycleEgo``) and,
    when its acceleration cannot jump, its actuator (``itha.actuator.Actuator``, profile "hold": a jerk bound, a
    lag or both)."""
    body = {"model": "bicycle", "length": _f(kin.length), "width": _f(kin.width), "dt": _f(kin.dt),
            "max_steering": _f(kin.max_steering), "max_acceleration": _f(kin.accel), "meta": bool(meta)}
    if actuator is not None and not math.isinf(actuator.jerk):
        body["max_jerk"] = _f(actuator.jerk)
    if actuator is not None and actuator.lag:
        body["lag"] = _f(actuator.lag)
    return body


def guardian_body(config) -> dict:
    """The ``guardian`` options of a scene session from a ``guardian.config.GuardianConfig``."""
    return {"overapprox": config.overapprox, "h_min": _f(config.h_min), "v_max": _f(config.v_max),
            "traffic_accel": _f(config.traffic_accel), "wreck_margin": _f(config.wreck_margin),
            "reverse_reach": _f(config.reverse_reach), "reverse_horizon": _f(config.reverse_horizon)}
