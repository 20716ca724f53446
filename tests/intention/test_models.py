"""The PWA intention models against the closed-form policies (6.5)-(6.7)."""
import numpy as np
import pytest

from intention.models import aggressive, bounded_velocity, cautious, intention_models
from intention.params import OvertakeParams

P = OvertakeParams()


def closed_form_acceleration(x, kind, p=P):
    v, y, h, vl = x
    keep = 1 - p.b_L * p.dt
    a1 = min(p.a_L_bounds[1], (p.v_Lx_bounds[1] - keep * vl) / p.dt) - p.w_delta_bounds[1] - p.w_Lx_bounds[1]
    a2 = max(p.a_L_bounds[0], (p.v_Lx_bounds[0] - keep * vl) / p.dt) - p.w_delta_bounds[0] - p.w_Lx_bounds[0]
    if abs(h) <= p.h_r:
        phi = np.dot(p.K_A, x) if kind == "aggressive" else np.dot(p.K_C, x) + p.k_c * p.v_L_des
    else:
        phi = p.K_des * (p.v_L_des - vl)
    return max(min(phi, a1), a2)


def random_states(rng, n):
    return np.column_stack([rng.uniform(0, 40, n), rng.uniform(-1, 3, n),
                            rng.choice([rng.uniform(-150, 150, n), rng.choice([-60.0, 60.0], n)]) ,
                            rng.choice([rng.uniform(0, 33.5, n), rng.uniform(0, 0.4, n)])])


@pytest.mark.parametrize("factory", [aggressive, cautious])
def test_pwa_policy_equals_closed_form(factory):
    model = factory(P)
    rng = np.random.default_rng(0)
    for x in random_states(rng, 3000):
        assert model.nominal_lead_acceleration(x) == pytest.approx(closed_form_acceleration(x, model.name),
                                                                   abs=1e-9)


@pytest.mark.parametrize("factory", [aggressive, cautious])
def test_closed_loop_step_is_6_3_and_6_4(factory):
    model = factory(P)
    rng = np.random.default_rng(1)
    dt = P.dt
    for x in random_states(rng, 500):
        u = rng.uniform([-3, -1.8], [3, 1.8])
        w = rng.uniform([-.15, -.09, -.05, -.1], [.15, .09, .05, .1])
        a_l = closed_form_acceleration(x, model.name) + w[3]
        expected = [x[0] + (u[0] - P.b_e * x[0]) * dt + w[0] * dt,
                    x[1] + u[1] * dt + w[1] * dt,
                    x[2] + (x[3] - x[0]) * dt,
                    x[3] + (a_l - P.b_L * x[3]) * dt + w[2] * dt]
        assert np.allclose(model.system.step(x, u, w), expected, atol=1e-9)


def test_lead_speed_stays_in_bounds_for_every_model():
    for model in intention_models(P).values():
        assert model.system.check_successor_box() == []


def test_successor_box_check_detects_a_false_claim():
    model = aggressive(P)
    model.system.pieces[0].c[3] += 0.1  # the lead may now exceed v_L^max by up to 0.065 m/s
    assert any("coordinate 3" in msg for msg in model.system.check_successor_box())


def test_reaction_zone_boundary_belongs_to_the_zone():
    model = cautious(P)
    x = np.array([25.0, 0.0, P.h_r, 20.0])
    assert model.system.pieces[model.system.piece_index(x)].label.startswith("zone")
    x[2] = P.h_r + 1e-6
    assert model.system.pieces[model.system.piece_index(x)].label.startswith("ahead")


def test_bounded_velocity_allows_any_next_lead_speed():
    model = bounded_velocity(P)
    lo, hi = model.lead_acceleration_interval(np.array([25.0, 0.0, 30.0, 20.0]))
    nxt = lambda a: 20.0 + (a - P.b_L * 20.0) * P.dt
    assert nxt(lo) == pytest.approx(0.0) and nxt(hi) == pytest.approx(33.5)


def test_piece_index_is_the_first_piece_that_holds_the_state():
    """The stacked one-product piece_index agrees with PWAPiece.holds, on the switching surfaces too."""
    from intention.models import intention_models

    rng = np.random.default_rng(5)
    for model in intention_models().values():
        system = model.system
        X = rng.uniform([15, -1, -120, -1], [36, 3, 120, 35], size=(3000, 4))
        X[::3, 2] = np.round(X[::3, 2])  # on integer headways, where zone boundaries sit
        for x in X:
            holders = [j for j, p in enumerate(system.pieces) if p.holds(x)]
            if holders:
                assert system.piece_index(x) == holders[0]
            else:
                with pytest.raises(ValueError):
                    system.piece_index(x)
        with pytest.raises(ValueError):
            system.piece_index(np.array([20.0, 0.0, np.nan, 20.0]))
