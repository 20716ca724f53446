"""highway-env's road network read as the guardian's roads (``guardian.model.roads``).

One straight multi-lane road along x is a ``Road`` (the ``highway-v0`` family); any other road highway-env
builds from straight, sine and circular lanes of one width, one-way along ``+x``, is read as a ``RoadMap``
(``merge-v0``, ``merge-generic-v0``, ``exit-v0``) when it is a corridor of straight lanes with on-ramps and
exits chained to it; every other road is refused with the reason (``read_road``).
"""
from __future__ import annotations

import math

from highway_env.road.lane import CircularLane, SineLane, StraightLane

from guardian.errors import ConfigError
from guardian.model.roads import Road, RoadMap, Strip

JOIN = 1e-6  # [m] lane ends closer than this are joined

def read_road(base):
    """The env's road: a ``Road`` when it is one straight multi-lane road along x with equal lanes, lane 0
    at ``y = 0`` (the ``highway-v0`` family); else a ``guardian.model.roads.RoadMap`` (``read_road_map``); a
    road the guardian cannot reason about raises a ConfigError with the reason."""
    graph = base.road.network.graph
    lanes = [lane for _from in graph.values() for group in _from.values() for lane in group]
    ok = bool(lanes) and all(isinstance(lane, StraightLane) and abs(lane.heading) < 1e-9 for lane in lanes)
    if ok:
        ys = sorted(float(lane.start[1]) for lane in lanes)
        widths = {round(lane.width, 9) for lane in lanes}
        gaps = {round(b - a, 9) for a, b in zip(ys, ys[1:])}
        ok = len(graph) == 1 and len(widths) == 1 and (len(ys) == 1 or gaps == widths) and abs(ys[0]) < 1e-9
    if ok:
        return Road(len(lanes), float(lanes[0].width))
    return read_road_map(base.road.network)


def _refuse(why: str):
    raise ConfigError(f"Guardian: cannot reason about this env's road: {why}. It reads one-way roads along +x "
                      "of equal lanes: straight lanes on parallel slots, with on-ramps and exits (straight, sine or "
                      "circular lanes) chained to one slot (highway-v0, merge-v0, merge-generic-v0, exit-v0)")


def _close(a, b) -> bool:
    return math.hypot(float(a[0]) - float(b[0]), float(a[1]) - float(b[1])) < JOIN


def read_road_map(network) -> RoadMap:
    """highway-env's ``RoadNetwork`` as a corridor with branches (``guardian.model.roads``), or a ConfigError
    saying why the guardian cannot reason about it."""
    graph = network.graph
    lanes = [((f, t, i), lane) for f, tos in graph.items() for t, group in tos.items() for i, lane in enumerate(group)]
    if not lanes:
        _refuse("it has no lanes")
    for index, lane in lanes:
        if type(lane) not in (StraightLane, SineLane, CircularLane):
            _refuse(f"lane {index} is a {type(lane).__name__}")
    widths = {round(float(lane.width), 9) for _, lane in lanes}
    if len(widths) != 1:
        _refuse(f"its lanes have different widths {sorted(widths)} m")
    w = widths.pop()
    starts = {index: lane.position(0.0, 0.0) for index, lane in lanes}
    ends = {index: lane.position(lane.length, 0.0) for index, lane in lanes}
    for index, lane in lanes:
        if math.cos(float(lane.heading_at(0.0))) < 0 or math.cos(float(lane.heading_at(lane.length))) < 0:
            _refuse(f"lane {index} runs against the direction of travel (towards -x)")
    along = [(index, lane) for index, lane in lanes if type(lane) is StraightLane
             and abs(float(lane.direction[1])) < 1e-9 and float(lane.direction[0]) > 0]
    if not along:
        _refuse("no lane runs straight along +x")

    def on_grid(y, y_ref):
        q = (y - y_ref) / w
        return abs(q - round(q)) < 1e-6

    # the grid of slots: the one holding most straight lanes along x (ties: the leftmost)
    ys = sorted({round(float(lane.start[1]), 9) for _, lane in along})
    y_ref = max(ys, key=lambda y: (sum(on_grid(float(lane.start[1]), y) for _, lane in along), -y))
    corridor = {index: lane for index, lane in along if on_grid(float(lane.start[1]), y_ref)}
    y0 = min(float(lane.start[1]) for lane in corridor.values())
    slot = {index: int(round((float(lane.start[1]) - y0) / w)) for index, lane in corridor.items()}
    n_lanes = max(slot.values()) + 1
    incoming = {t for tos in graph.values() for t in tos}
    sources = {f for f in graph if f not in incoming}
    sinks = {t for t in incoming if not graph.get(t)}

    def successors(index):
        return [j for j, _ in lanes if j != index and _close(ends[index], starts[j])]

    def predecessors(index):
        return [j for j, _ in lanes if j != index and _close(ends[j], starts[index])]

    # branches: chains of the other lanes, each joined to one corridor lane at one end
    branches, table, done = [], {index: (slot[index], -1) for index in corridor}, set()
    continued_after, continued_before = set(), set()   # corridor lanes a branch continues / leads into
    for index, _ in lanes:
        if index in corridor or index in done:
            continue
        chain = [index]
        while True:  # walk back to the chain's first lane
            back = [j for j in predecessors(chain[0]) if j not in corridor]
            if len(back) > 1:
                _refuse(f"lanes {back} both lead into lane {chain[0]}")
            if not back or back[0] in chain:
                break
            chain.insert(0, back[0])
        while True:  # and on to its last
            fwd = [j for j in successors(chain[-1]) if j not in corridor]
            if len(fwd) > 1:
                _refuse(f"lane {chain[-1]} forks into {fwd}")
            if not fwd or fwd[0] in chain:
                break
            chain.append(fwd[0])
        done.update(chain)
        into = [j for j in successors(chain[-1]) if j in corridor]
        out_of = [j for j in predecessors(chain[0]) if j in corridor]
        if into and out_of:
            _refuse(f"lanes {chain} leave the straight lanes and join them again")
        if not into and not out_of:
            _refuse(f"lanes {chain} are not chained to the straight lanes along x")
        if len(into) > 1 or len(out_of) > 1:
            _refuse(f"lanes {chain} join more than one straight lane")
        joint = (into or out_of)[0]
        k = slot[joint]
        if into:  # an on-ramp: its chain ends where the slot's lane begins
            continued_before.add(joint)
            s = float(starts[joint][0])
            coords = []
            for j in reversed(chain):
                s -= float(_lane(lanes, j).length)
                coords.insert(0, s)
        else:  # an exit: its chain begins where the slot's lane ends
            continued_after.add(joint)
            s, coords = float(ends[joint][0]), []
            for j in chain:
                coords.append(s)
                s += float(_lane(lanes, j).length)
        for n, (j, s0) in enumerate(zip(chain, coords)):
            lane = _lane(lanes, j)
            first, last = n == 0, n == len(chain) - 1
            branches.append(_strip(lane, w, k, s0, open_before=first and not out_of and j[0] in sources,
                                   open_after=last and not into and j[1] in sinks))
            table[j] = (k, len(branches) - 1)
    # the corridor's spans per slot, open at the road's own ends; dead ends where a slot stops
    spans, dead = [], []
    for k in range(n_lanes):
        pieces = sorted((float(lane.start[0]), float(lane.end[0]), index) for index, lane in corridor.items()
                        if slot[index] == k)
        merged = []
        for lo, hi, index in pieces:
            if merged and lo <= merged[-1][1] + JOIN:
                if lo < merged[-1][1] - JOIN:
                    _refuse(f"straight lanes overlap on slot {k} around x = {lo:g}")
                merged[-1] = [merged[-1][0], max(hi, merged[-1][1]), merged[-1][2], index]
            else:
                merged.append([lo, hi, index, index])
        out = []
        for lo, hi, first, last in merged:
            if first[0] in sources and first not in continued_before:
                lo = -math.inf
            if last[1] in sinks and last not in continued_after:
                hi = math.inf
            elif last not in continued_after:
                dead.append((k, hi))
            out.append((lo, hi))
        spans.append(tuple(out))
    if set(table) != {index for index, _ in lanes}:
        _refuse("some lanes could not be placed")
    return RoadMap(float(w), n_lanes, y0, tuple(spans), tuple(branches),
                   tuple((index, k, b) for index, (k, b) in sorted(table.items())), tuple(dead))


def _lane(lanes, index):
    return next(lane for j, lane in lanes if j == index)


def _strip(lane, w: float, slot: int, s0: float, open_before: bool, open_after: bool) -> Strip:
    if isinstance(lane, CircularLane):
        return Strip("arc", (float(lane.center[0]), float(lane.center[1])), (0.0, 0.0), w, float(lane.length), slot,
                     s0, radius=float(lane.radius), start_phase=float(lane.start_phase), direction=int(lane.direction),
                     open_before=open_before, open_after=open_after)
    start, end = (float(lane.start[0]), float(lane.start[1])), (float(lane.end[0]), float(lane.end[1]))
    if isinstance(lane, SineLane):
        return Strip("sine", start, end, w, float(lane.length), slot, s0, amplitude=float(lane.amplitude),
                     pulsation=float(lane.pulsation), phase=float(lane.phase), open_before=open_before,
                     open_after=open_after)
    return Strip("straight", start, end, w, float(lane.length), slot, s0, open_before=open_before, open_after=open_after)

