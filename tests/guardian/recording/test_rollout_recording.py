"""Rollout recordings a user opens: the file wherever asked, the view on the action."""
import gymnasium as gym
import numpy as np
import highway_env  # noqa: F401


def test_a_recording_into_a_folder_not_yet_made_makes_it(tmp_path):
    from guardian.recording.rerun import GuardianRecorder

    path = tmp_path / "new" / "deeper" / "run.rrd"
    recorder = GuardianRecorder(path)
    recorder.close()
    assert path.is_file()


def test_a_rollout_recording_follows_the_ego_not_kilometres_of_road(tmp_path):
    """The viewer fits all it is given: HighwayOvertake's lanes run 20 km and no car was visible on opening; a view
    fixed on the ego's start lost the ego by the time the viewer opened (at the file's last step). The road is seen
    from ``road/follow``, a frame at the ego's x every step, over ``ROLLOUT_VIEW`` m around it; each unit has its
    own plot, and the inputs' series are named one by one (rerun's filters take no ``*`` inside a path: the
    proposed and applied inputs were in no plot)."""
    from guardian.cli import main
    from guardian.recording.rerun import ROLLOUT_VIEW, read_entities, rollout_blueprint

    env = gym.make("highway-fast-v0")
    env.reset(seed=0)
    base = env.unwrapped
    left, side = rollout_blueprint(base, overtake=False).root_container.contents
    road_view, slice_view = left.contents
    assert str(road_view.origin) == "/road/follow" and str(slice_view.origin) == "/slice"
    (bounds,) = road_view.properties["VisualBounds2D"].range.as_arrow_array().to_pylist()
    x0, x1 = bounds["x_range"]
    assert x0 < 0 < x1 and x1 - x0 == ROLLOUT_VIEW
    plots = {str(v.name): [str(c) for c in v.contents] for v in side.contents}
    throttle = next(c for n, c in plots.items() if "acceleration" in n)
    assert {"/inputs/proposed/throttle", "/inputs/applied/throttle"} <= set(throttle)
    assert not any("*" in c.rstrip("*") for cs in plots.values() for c in cs)
    rrd = tmp_path / "run.rrd"
    assert main(["rollout", "--env", "highway-fast-v0", "--episodes", "1", "--rerun", str(rrd)]) == 0
    entities = read_entities(rrd)
    assert entities["/road/follow"] == entities["/road/ego"] == entities["/road/follow/labels"] > 1
    labels = label_points(rrd)   # in the followed frame (the viewer ignores the transform when it places a label)
    assert all(by_name["ego"][0] == 0.0 for by_name in labels)


def label_points(rrd) -> list[dict]:
    """Each step's ``road/follow/labels``: ``{name: (x, y)}``."""
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.entity_path == "/road/follow/labels":
            batch = chunk.to_record_batch()
            for points, names in zip(batch.column("Points2D:positions").to_pylist(),
                                     batch.column("Points2D:labels").to_pylist()):
                out.append({n: tuple(p) for n, p in zip(names, points)})
    return out


def test_the_override_events_are_the_counted_overrides_and_read_as_a_person_reads_them(tmp_path, capsys):
    """merge-v0 once showed 29 override events against override_steps 27: clips to the model's bounds were logged
    as overrides. Now each safety override is one event (a clip is a model_clip event), numbers are rounded, a
    reason repeated over a step's simulation steps appears once with its count, and the text names the timeline's
    step."""
    import json
    import re

    from guardian.cli import main
    from guardian.recording.rerun import read_texts

    rrd = tmp_path / "merge.rrd"
    assert main(["rollout", "--env", "merge-v0", "--agent", "reckless", "--episodes", "2", "--rerun", str(rrd),
                 "--json"]) == 0
    counts = json.loads(capsys.readouterr().out)
    events = read_texts(rrd, "/events/override")
    assert len(events) == counts["override_steps"] > 0
    assert not any(re.search(r"\d\.\d{4,}", e) for e in events), events
    assert all(e.count(r) == 1 for e in events for r in e.split("; ")[1:]), events
    assert events[0].startswith("step 0 (episode 0, its step 1;")
    from guardian.recording.rerun import FAILSAFE, GUARDED, OVERRIDDEN
    colours = [c for step in entity_column(rrd, "/road/ego", "Boxes2D:colors") for c in step]
    packed = {name: (r << 24) | (g << 16) | (b << 8) | 255 for name, (r, g, b) in
              {"guarded": GUARDED, "overridden": OVERRIDDEN, "failsafe": FAILSAFE}.items()}
    assert set(colours) <= set(packed.values())
    assert sum(c != packed["guarded"] for c in colours) == len(events)      # each override marked on the road
    assert colours.count(packed["failsafe"]) == sum("failsafe" in e for e in events)


def entity_column(rrd, entity: str, column: str) -> list:
    """Each logged row's ``column`` of ``entity`` in a recording."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.entity_path == entity:
            rows.extend(r for r in chunk.to_record_batch().column(column).to_pylist() if r is not None)
    return rows


def test_a_highd_recording_opens_on_the_vehicles_the_events_name_not_on_every_vehicle():
    """One plot of every vehicle's series (931 on the sample) reads as nothing: the layout opens on a plot per
    vehicle the events name first, at most ``HIGHD_SHOWN``."""
    from guardian.recording.rerun import HIGHD_SHOWN, highd_blueprint

    _, side = highd_blueprint([5, 7, 9, 11, 13, 15]).root_container.contents
    tabs = [c for c in side.contents if type(c).__name__ == "Tabs"]
    assert [str(t.contents[0].origin) for t in tabs] == [f"/vehicles/{v}" for v in (5, 7, 9, 11)][:HIGHD_SHOWN]
    first = [[str(c) for c in view.contents] for view in tabs[0].contents]   # one plot per unit, the input first
    assert first == [["/vehicles/5/input", "/vehicles/5/admissible/**"], ["/vehicles/5/speed"], ["/vehicles/5/gap"]]


def test_a_recording_of_several_guarded_cars_shows_each_car_and_whose_override_it_was(tmp_path, capsys):
    """``--rerun`` with ``--controlled N``: the guarded cars are drawn and labelled, the view follows car 0, each car
    has its own inputs and admissible bands (tabs of one plot per unit), and each override event names its car:
    as many events per car as that car's counted overrides."""
    import json
    import re

    from guardian.cli import main
    from guardian.recording.rerun import read_entities, read_texts, rollout_blueprint

    rrd = tmp_path / "fleet.rrd"
    assert main(["rollout", "--env", "highway-v0", "--controlled", "2", "--agent", "reckless", "--episodes", "1",
                 "--rerun", str(rrd), "--json"]) == 0
    counts = json.loads(capsys.readouterr().out)
    entities = read_entities(rrd)
    assert entities["/road/guarded"] == entities["/road/follow"] > 1 and "/road/ego" not in entities
    assert all(set(step) == {"car 0", "car 1"} and step["car 0"][0] == 0.0 for step in label_points(rrd))
    for k in (0, 1):
        assert entities[f"/cars/car_{k}/inputs/applied/throttle"] == entities["/road/guarded"] + 1   # + its style
        assert f"/cars/car_{k}/admissible/acceleration/low" in entities
    events = read_texts(rrd, "/events/override")
    per_car = [sum(bool(re.match(rf"step \d+ \(car {k}, ", e)) for e in events) for k in (0, 1)]
    assert per_car == [c["override_steps"] for c in counts["agents"]] and sum(per_car) == len(events) > 0
    env = gym.make("highway-v0", config={"controlled_vehicles": 3})
    env.reset(seed=0)
    _, side = rollout_blueprint(env.unwrapped, overtake=False, cars=3).root_container.contents
    tabs = [c for c in side.contents if type(c).__name__ == "Tabs"]
    assert [[str(c) for c in tab.contents[0].contents][0] for tab in tabs] == \
        [f"/cars/car_{k}/inputs/proposed/throttle" for k in range(3)]


def slice_chunks(rrd, entity: str, ending=(":positions", ":strips")) -> list:
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            name = next(c for c in batch.schema.names if c.endswith(ending))
            out += batch.column(name).to_pylist()
    return out


def test_the_recording_draws_the_invariant_sets_slice_at_the_state_now(tmp_path):
    """Below the road: the car-following set's edge behind the nearest car ahead (the highest speed it allows at
    each gap) and the ego's point, inside it on every step the guardian kept the car in its set; with a jerk-limited
    actuator the edge is the rate-limited set's at the ego's acceleration, and lies below (7.3)'s."""
    from guardian.config import GuardianConfig
    from guardian.decide.bicycle import BicycleGuardian
    from guardian.decide.kinematics import BicycleEgo
    from guardian.evaluation.rollouts import Rollout, highway_rollouts
    from guardian.model.scene import Car, EgoState
    from guardian.recording.rerun import slice_of
    from itha.actuator import Actuator

    rrd = tmp_path / "slice.rrd"
    r = highway_rollouts(Rollout("highway-fast-v0", "seek", action="continuous"), 1, 0, rerun_path=rrd)
    points, edges = slice_chunks(rrd, "/slice/ego"), slice_chunks(rrd, "/slice/edge")
    assert len(points) == len(edges) > 0 and r["starts_outside"] == 0
    green = slice_chunks(rrd, "/slice/ego", (":colors",))
    assert {c for (c,) in green} == {0x28B43CFF}   # GUARDED: inside on every step (a point outside is red)
    for (point,), (edge,) in zip(points, edges):
        h, minus_v = point
        above = [-y for x, y in edge if x >= h]
        assert not above or -minus_v <= above[0] + 1e-6   # under the edge at the next gap drawn
    kin = BicycleEgo(1 / 15, 5.0, 5.0, 2.0, 4.0, 3, 0.785)
    ego = EgoState(100.0, 4.0, 0.0, 25.0, 1, 1, 0.0, 2.0)
    lead = Car(140.0, 20.0, frozenset({2}), 5.0, "car 1")
    plain = slice_of(BicycleGuardian(kin, GuardianConfig(), False), ego, [lead])
    jerky = slice_of(BicycleGuardian(kin, GuardianConfig(), False, Actuator(jerk=5.0, profile="hold")), ego, [lead])
    assert plain["gap"] == jerky["gap"] == 35.0 and plain["lead"] == "car 1"
    assert all(vj <= vp for (_, vp), (_, vj) in zip(plain["edge"], jerky["edge"]))
    assert any(vj < vp - 1.0 for (_, vp), (_, vj) in zip(plain["edge"], jerky["edge"]))
    assert slice_of(BicycleGuardian(kin, GuardianConfig(), False), ego, []) is None


def test_the_recording_draws_the_lanes_held_and_the_entries_refused():
    """On a straight road: each step the lanes the guarded car holds (``road/follow/held``) and the lane whose
    entry the guardian refused (``road/follow/refused``: a meta lane change asked into dense traffic), as the
    step's record and the car say."""
    from guardian.evaluation.rollouts import Rollout, make_env
    from guardian.recording.rerun import GuardianRecorder

    env = make_env(Rollout("highway-fast-v0", "random", action="meta", env_config={"vehicles_density": 2.5}))
    recorder = GuardianRecorder.__new__(GuardianRecorder)   # its _lanes alone, into a list instead of a file
    logged = {}
    recorder.rec = type("Rec", (), {"log": lambda self, path, value, **kw: logged.setdefault(path, []).append(value)})()
    road, refused_steps = None, 0
    left = env.unwrapped.action_type.actions_indexes["LANE_LEFT"]
    for episode in range(3):
        env.reset(seed=episode)
        road = env.get_wrapper_attr("supervision").road
        for _ in range(20):
            _, _, term, trunc, info = env.step(left)
            g, car = info["guardian"], env.get_wrapper_attr("cars")[0]
            recorder._lanes(env, g)
            held = logged["road/follow/held"][-1].centers.as_arrow_array().to_pylist()
            assert sorted(y for _, y in held) == sorted(road.numbering.slot(k) * road.lane_width for k in g["lanes"])
            refused = logged["road/follow/refused"][-1].centers.as_arrow_array().to_pylist()
            if g["refused_lane_change"] and car.refused_lane is not None:
                assert [y for _, y in refused] == [road.numbering.slot(car.refused_lane) * road.lane_width]
                refused_steps += 1
            if term or trunc:
                break
    assert refused_steps > 0


def test_an_overtake_recording_draws_the_active_sets_slice_with_the_state_in_it(tmp_path):
    """Two cars (Section 6.5): every step the active set sliced at the lateral position and the lead's speed now,
    one polygon per piece that holds them, and the state inside it (green) as the guardian keeps it (Theorem 4); the
    point lies in a drawn polygon exactly when the set holds it."""
    from matplotlib.path import Path as Polygon

    from guardian.evaluation.rollouts import Rollout, highway_rollouts

    rrd = tmp_path / "overtake.rrd"
    r = highway_rollouts(Rollout("guardian/Overtake-v0", "random", env_config={"duration": 4}), 1, 0, rerun_path=rrd)
    points, sets = slice_chunks(rrd, "/slice/ego"), slice_chunks(rrd, "/slice/set")
    colours = slice_chunks(rrd, "/slice/ego", (":colors",))
    assert len(points) == len(sets) == r["steps"] > 0 and r["starts_outside"] == 0
    assert {c for (c,) in colours} == {0x28B43CFF}
    for (point,), polygons in zip(points, sets):
        assert polygons and any(Polygon(np.array(poly)).contains_point(point, radius=1e-6) for poly in polygons)


def _documented_entities() -> set:
    """The entity paths docs/guardian.md ("Watch it") says rollout recordings hold, braces expanded; paths with a
    placeholder (``car_K``, ``...``) left out."""
    import itertools
    import re

    from project import ROOT

    text = (ROOT / "docs" / "guardian.md").read_text()
    text = text[text.index("`guardian rollout ... --rerun run.rrd` writes"):]
    text = text[:text.index("A test reads the file")]
    out = set()
    for name in re.findall(r"`((?:road|slice|inputs|admissible|intention|events|guardian|cars)/[^`]*)`", text):
        if "..." in name or "_K" in name:
            continue
        parts = [p.split(",") for p in re.split(r"\{([^}]*)\}", name)]
        out |= {"/" + "".join(choice).rstrip("/") for choice in itertools.product(*parts)}
    return out


def test_every_entity_the_docs_name_is_in_the_recordings(tmp_path):
    """docs/guardian.md against the files: a highway-env road (meta, dense: lane changes refused, clips to the model),
    two guarded cars, and the two-car overtake each recorded; every entity the docs name is in one of them."""
    from guardian.evaluation.rollouts import Rollout, highway_rollouts
    from guardian.recording.rerun import read_entities

    runs = {"road": Rollout("highway-fast-v0", "random", action="meta", env_config={"vehicles_density": 2.5}),
            "fleet": Rollout("highway-fast-v0", "random", action="meta", controlled=2),
            "overtake": Rollout("guardian/Overtake-v0", "random", env_config={"duration": 4})}
    seen = set()
    for name, run in runs.items():
        highway_rollouts(run, 2, 0, rerun_path=tmp_path / f"{name}.rrd")
        seen |= set(read_entities(tmp_path / f"{name}.rrd"))
    documented = _documented_entities()
    assert len(documented) > 20
    assert documented - seen == set()
