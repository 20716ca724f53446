"""F_R^M, following the lead with the intentions not ruled out (guardian.decide.lead_following), as falsifiers.

States are drawn in the set, the lead drives by one of the models (the closed-loop PWA system of
intention.models, its disturbance at random or at its box's corners), the guardian chooses the ego's
input for a proposal that pushes towards the lead: every successor must be in the set again and never
closer than h_min. The same falsifier with a lead that brakes as its physical bound allows but no
model does must find counterexamples (the set trusts the intention, and the test can fail).
"""
import numpy as np
import pytest

from guardian.config import GuardianConfig
from guardian.decide.lead_following import LeadFollowing
from guardian.decide.overtake import PointMassGuardian
from guardian.model.scene import Car, Scene
from intention.lead_bounds import next_lead_speed_bounds

HALF = 0.875 / 2


def _guard(lib, **config) -> PointMassGuardian:
    return PointMassGuardian(lib, 2, HALF, traffic=True, config=GuardianConfig(**config))


def _scene(x) -> Scene:
    return Scene(Car(102.5, float(x[0]), frozenset(), 5.0, "ego"), (), 2)


def _successor(lib, model, x, u, rng, corners: bool):
    piece = lib.models[model].system.pieces[lib.models[model].system.piece_index(x)]
    W, _ = piece.W.generators()
    w = W[rng.integers(len(W))] if corners else rng.dirichlet(np.ones(len(W))) @ W
    nxt = lib.models[model].system.step(x, u, w)
    nxt[0] = max(nxt[0], 0.0)  # guardian/HighwayOvertake-v0 holds the ego at standstill
    return nxt


def _draw(g: PointMassGuardian, rng, models, outside_plain: bool):
    """A right-lane state in F_R^M (and outside F_R when ``outside_plain``)."""
    while True:
        x = np.array([rng.uniform(5, 34), rng.uniform(-0.5, 0.4), rng.uniform(10, 70), rng.uniform(0, 33)])
        if g.following.contains(x, models) and not (outside_plain and g.following.contains(x, ())):
            return x


@pytest.mark.parametrize("model", ["aggressive", "cautious"])
def test_the_lead_speed_bounds_hold_every_successor_of_the_model(traffic_library, model):
    lib, rng = traffic_library, np.random.default_rng(10)
    m = lib.models[model]
    for _ in range(400):
        centre = np.array([rng.uniform(0, 36), rng.uniform(-0.9, 2.7), rng.uniform(-90, 90), rng.uniform(0, 33.5)])
        width = rng.uniform(0, [2, 0.5, 8, 2])
        lo, hi = np.clip(centre - width, [0, -0.9, -np.inf, 0], [36, 2.7, np.inf, 33.5]), \
            np.clip(centre + width, [0, -0.9, -np.inf, 0], [36, 2.7, np.inf, 33.5])
        b_lo, b_hi = next_lead_speed_bounds(m, lo, hi)
        for _ in range(10):
            x = rng.uniform(lo, hi)
            vL = _successor(lib, model, x, np.zeros(2), rng, corners=bool(rng.integers(2)))[3]
            assert b_lo[0] - 1e-9 <= vL <= b_hi[0] + 1e-9, (lo, hi, x, vL)


@pytest.mark.parametrize("model", ["aggressive", "cautious"])
def test_the_intention_aware_follow_set_is_invariant_under_the_lead_of_its_intentions(traffic_library, model):
    """States of F_R^{a,c} outside F_R (20 episodes of 40 steps), the guardian on a proposal of full throttle, the lead of ``model``
    with its disturbance at random or at the box's corners: always back in the set, never below h_min."""
    lib, rng = traffic_library, np.random.default_rng(11)
    p = lib.params
    g = _guard(lib)
    for episode in range(20):
        g.reset()
        x = _draw(g, rng, ("aggressive", "cautious"), outside_plain=True)
        corners = bool(episode % 2)
        for t in range(40):
            proposal = [p.a_ex_bounds[1] if t % 3 else rng.uniform(*p.a_ex_bounds), float(-x[1] / p.dt)]
            applied, d = g.step(x, _scene(x), np.clip(proposal, [-3, -1.8], [3, 1.8]))
            assert d.level == "composed" and d.lead_target == "follow", (episode, t, x, d.reasons)
            x = _successor(lib, model, x, applied, rng, corners)
            assert x[2] >= p.h_min, (episode, t, x)
            assert g.in_follow_set(x), f"episode {episode} step {t}: left F_R^M at {x} ({g.intentions()})"
        assert model in g.intentions()


def test_the_falsifier_finds_the_lead_that_brakes_harder_than_its_intention(traffic_library):
    """The same loop with a lead that brakes at a_L^min, which its bounds allow and no intention does:
    the intention-aware set is left (the set trusts the intention; the falsifier above can fail)."""
    lib, rng = traffic_library, np.random.default_rng(12)
    p = lib.params
    g = _guard(lib)
    failures = 0
    for _ in range(40):
        x = _draw(g, rng, ("aggressive", "cautious"), outside_plain=True)
        models = ("aggressive", "cautious")
        for _ in range(60):
            v_next = g.following.next_speeds(x, models, wanted=p.a_ex_bounds[1])
            a = max(lo for lo, _ in g.kin.accel_for_speeds(x[0], v_next)) if v_next else p.a_ex_bounds[0]
            v = max((1 - p.b_e * p.dt) * x[0] + p.dt * (a + p.w_ex_bounds[1]), 0.0)
            h = x[2] + p.dt * (x[3] - x[0])
            vL = max((1 - p.b_L * p.dt) * x[3] + p.dt * p.a_L_bounds[0], 0.0)
            x = np.array([v, 0.0, h, vL])
            if h < p.h_min or not g.following.contains(x, models):
                failures += 1
                break
    assert failures > 0


def test_behind_a_slower_lead_the_intention_lets_the_ego_close_in_and_no_intention_does_not(traffic_library):
    """24 m/s, 30 m behind a lead at 19 m/s: both intentions speed the lead up there, so holding the
    speed is safe with the intention; without it the lead may brake at a_L^min and F_R refuses."""
    x = np.array([24.0, 0.0, 30.0, 19.0])
    with_intention, without = _guard(traffic_library), _guard(traffic_library, use_intention=False)
    assert with_intention.in_follow_set(x) and not without.in_follow_set(x)
    applied, d = with_intention.step(x, _scene(x), [0.0, 0.0])
    assert d.changed == "none" and applied[0] == 0.0
    applied, d = without.step(x, _scene(x), [0.0, 0.0])
    assert applied[0] < 0.0 and d.changed != "none"  # outside F_R: the hardest braking


def test_without_intentions_the_next_speeds_are_the_physical_follow_sets(traffic_library):
    p = traffic_library.params
    g = _guard(traffic_library)
    rng = np.random.default_rng(13)
    S = g.follow
    for _ in range(200):
        v, h, vL = rng.uniform(0, 34), rng.uniform(10, 80), rng.uniform(0, 33)
        expected = S.speed_intervals(h + p.dt * (vL - v), float(S.params.worst_lead_speed(vL)))
        assert g.following.next_speeds([v, 0.0, h, vL], (), wanted=3.0) == expected
        assert g.following.contains([v, 0.0, h, vL], ()) == bool(S.contains([[v, h, vL]])[0])


def test_a_lane_the_ego_cannot_be_held_in_is_refused(traffic_library):
    with pytest.raises(ValueError, match="cannot be held"):
        LeadFollowing(traffic_library.params, traffic_library.models, (0.0, 0.005), 0.0)
