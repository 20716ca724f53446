"""The intention estimator (Section 6.4.2, rule (6.9)): per-slot interval decisions against the window LP.

The referee is HiGHS: ``WindowLPEstimator`` below is the estimator as it was before the interval test
(one HiGHS model per intention and estimator, the whole window re-solved at every update, warm).
"""
import numpy as np
import pytest

from intention import estimator as est_mod
from intention.estimator import LP_BAND, IntentionEstimator, _SlidingFeasibilityLP
from intention.models import aggressive, cautious
from intention.params import OvertakeParams
from rcis.pwa import PWAPiece, PWASystem

P = OvertakeParams()
MODELS = {"aggressive": aggressive(P), "cautious": cautious(P)}
W_LO = np.array([-.15, -.09, -.05, -.1])
W_HI = -W_LO


class WindowLPEstimator:
    """The estimator before the interval test, verbatim in what it decides: each update writes the new
    slot's residual into a per-estimator HiGHS model of the whole window and re-solves it (warm)."""

    def __init__(self, models, horizon=10, tol=est_mod.OBSERVATION_TOL):
        self.models, self.horizon, self.tol = models, horizon, tol
        self._lps = {}
        for name, model in models.items():
            piece = model.system.pieces[0]
            lo, hi = (np.asarray(v) for v in piece.W._box)
            self._lps[name] = _SlidingFeasibilityLP(piece.E, lo, hi, horizon, tol)
        self.reset()

    def reset(self):
        self.valid = list(self.models)
        self.steps = 0
        self.identified_at = None
        for lp in self._lps.values():
            lp.clear()

    def update(self, x, u_e, x_next):
        x, u_e, x_next = (np.asarray(v, dtype=float) for v in (x, u_e, x_next))
        slot = self.steps % self.horizon
        self.steps += 1
        invalidated = []
        for name in list(self.valid):
            system = self.models[name].system
            piece = system.pieces[system.piece_index(x)]
            self._lps[name].write_slot(slot, x_next - piece.image(x, u_e))
            if not self._lps[name].feasible():
                invalidated.append(name)
        self.valid = [n for n in self.valid if n not in invalidated]
        if len(self.valid) == 1 and self.identified_at is None:
            self.identified_at = self.steps
        return est_mod.EstimatorUpdate(tuple(self.valid), tuple(invalidated),
                                       self.valid[0] if len(self.valid) == 1 else None)


def trajectory(model, rng, steps, adversarial=False):
    x = np.array([rng.uniform(18, 30), rng.uniform(-0.5, 2.5), rng.uniform(-70, 70), rng.uniform(5, 30)])
    for _ in range(steps):
        u = rng.uniform([-3, -1.8], [3, 1.8])
        w = np.where(rng.random(4) < 0.5, W_LO, W_HI) if adversarial else rng.uniform(W_LO, W_HI)
        nxt = model.system.step(x, u, w)
        yield x, u, nxt
        x = nxt


@pytest.mark.parametrize("true", ["aggressive", "cautious"])
@pytest.mark.parametrize("adversarial", [False, True])
def test_true_intention_is_never_invalidated_and_the_set_never_grows(true, adversarial):
    rng = np.random.default_rng(11)
    identified = 0
    for _ in range(40):
        est = IntentionEstimator(MODELS, horizon=8)
        previous = set(est.valid)
        for x, u, nxt in trajectory(MODELS[true], rng, 80, adversarial):
            est.update(x, u, nxt)
            assert true in est.valid
            assert set(est.valid) <= previous
            previous = set(est.valid)
        identified += est.valid == [true]
    assert identified >= 30  # in the reaction zone the two policies soon disagree


def test_identification_is_recorded_once():
    rng = np.random.default_rng(3)
    est = IntentionEstimator(MODELS, horizon=5)
    for x, u, nxt in trajectory(MODELS["cautious"], rng, 100):
        est.update(x, u, nxt)
    assert est.valid == ["cautious"] and 1 <= est.identified_at <= 100


def test_no_estimator_owns_a_solver(monkeypatch):
    """The overtake models are separable: thousands of estimators and updates build no HiGHS model."""
    built = []
    original = est_mod._SlidingFeasibilityLP.__init__

    def counting(self, *a, **k):
        built.append(1)
        original(self, *a, **k)

    monkeypatch.setattr(est_mod._SlidingFeasibilityLP, "__init__", counting)
    rng = np.random.default_rng(0)
    estimators = [IntentionEstimator(MODELS, horizon=10) for _ in range(1000)]
    for est in estimators[:50]:
        for x, u, nxt in trajectory(MODELS["aggressive"], rng, 30):
            est.update(x, u, nxt)
        est.reset()
    assert built == [] and all(e.lp_solves == 0 for e in estimators)


def test_a_lead_that_fits_no_model_empties_the_valid_set():
    est = IntentionEstimator(MODELS, horizon=5)
    x = np.array([25.0, 0.0, 20.0, 20.0])
    u = np.zeros(2)
    nxt = MODELS["cautious"].system.step(x, u, np.zeros(4))
    nxt[3] += 2.0  # the lead jumps 2 m/s in 0.1 s: no intention allows it
    assert est.update(x, u, nxt).valid == ()


def test_bad_input_names_the_field():
    est = IntentionEstimator(MODELS)
    with pytest.raises(ValueError, match="x_next"):
        est.update([25, 0, 20, 20], [0, 0], [np.nan, 0, 20, 20])
    with pytest.raises(ValueError, match="horizon"):
        IntentionEstimator(MODELS, horizon=0)


# ---- the boundary: HiGHS' tolerance and the band ----------------------------------------------------

def _row_bounds(model):
    piece = model.system.pieces[0]
    lo, hi = (np.asarray(v) for v in piece.W._box)
    E = piece.E
    return E, lo, hi, np.minimum(E * lo, E * hi).sum(axis=1), np.maximum(E * lo, E * hi).sum(axis=1)


def _slot_residual(model, row, side, distance, rng):
    """A residual inside every row's interval except ``row``, which lies ``distance`` outside
    ``[r - tol, r + tol]``'s meeting point with the interval on ``side`` (+1 above, -1 below)."""
    _, _, _, lower, upper = _row_bounds(model)
    r = rng.uniform(lower, upper)
    tol = est_mod.OBSERVATION_TOL
    r[row] = upper[row] + tol + distance if side > 0 else lower[row] - tol - distance
    return r


def _highs_accepts(model, residual, warm_lp=None, slot=0):
    E, lo, hi, _, _ = _row_bounds(model)
    lp = warm_lp or _SlidingFeasibilityLP(E, lo, hi, 10, est_mod.OBSERVATION_TOL)
    lp.clear()
    lp.write_slot(slot, residual)
    return lp.feasible()


@pytest.mark.parametrize("name", ["aggressive", "cautious"])
def test_highs_tolerance_lies_inside_the_band(name):
    """HiGHS accepts a slot exactly on the boundary and rejects it ``LP_BAND`` outside, fresh or warm, on
    every row and side; its own threshold (between) is what the band hands to the LP. If a HiGHS
    release widened its tolerance past the band, this fails (and the interval test would disagree)."""
    model = MODELS[name]
    rng = np.random.default_rng(5)
    warm = _SlidingFeasibilityLP(*_row_bounds(model)[:3], 10, est_mod.OBSERVATION_TOL)
    thresholds = []
    for row in range(4):
        for side in (1, -1):
            for lp in (None, warm):
                assert _highs_accepts(model, _slot_residual(model, row, side, 0.0, rng), lp)
                assert not _highs_accepts(model, _slot_residual(model, row, side, LP_BAND, rng), lp)
                lo_d, hi_d = 0.0, LP_BAND  # bisect HiGHS' threshold on this row and side
                for _ in range(40):
                    mid = (lo_d + hi_d) / 2
                    if _highs_accepts(model, _slot_residual(model, row, side, mid, rng), lp):
                        lo_d = mid
                    else:
                        hi_d = mid
                thresholds.append(hi_d)
    assert max(thresholds) < LP_BAND / 4, thresholds  # the band has room beyond HiGHS' tolerance


BOUNDARY_DISTANCES = [-1e-3, -1e-9, -1e-12, 0.0, 1e-15, 1e-12, 1e-10, 5e-9, 1e-8, 1.1e-8, 1.2e-8, 5e-8, 1e-7,
                      1.1e-7, 1.2e-7, 5e-7, LP_BAND, 1.01 * LP_BAND, 2e-6, 1e-5, 1e-3]


@pytest.mark.parametrize("name", ["aggressive", "cautious"])
def test_boundary_cases_are_decided_as_the_lp_decides_them(name):
    """A transition whose residual lies at each distance from the interval, on each row and side: the
    estimator's decision equals HiGHS' on a fresh window LP everywhere, and the warm window LP's
    everywhere outside the band (inside it, HiGHS' own answer depends on its warm start)."""
    model = MODELS[name]
    rng = np.random.default_rng(9)
    x = np.array([25.0, 0.3, 30.0, 22.0])
    u = np.array([0.4, -0.2])
    piece = model.system.pieces[model.system.piece_index(x)]
    band_cases = 0
    for row in range(4):
        for side in (1, -1):
            for d in BOUNDARY_DISTANCES:
                r = _slot_residual(model, row, side, d, rng)
                x_next = piece.image(x, u) + r
                est = IntentionEstimator({name: model}, horizon=10)
                ref = WindowLPEstimator({name: model}, horizon=10)
                for _ in range(3):  # a window of identical transitions, then the boundary one
                    clean = piece.image(x, u) + rng.uniform(*_row_bounds(model)[3:]) * 0.5
                    est.update(x, u, clean)
                    ref.update(x, u, clean)
                got = est.update(x, u, x_next).valid
                realised = x_next - piece.image(x, u)  # r up to the rounding of adding and subtracting x
                fresh = _highs_accepts(model, realised)
                assert got == ((name,) if fresh else ()), (row, side, d)
                excess = est._candidates[name].excess(realised)
                assert abs(excess - d) < 1e-13 or d < 0
                if excess <= 0 or excess > LP_BAND:
                    assert got == ref.update(x, u, x_next).valid, (row, side, d)
                    assert est.lp_solves == 0
                else:
                    band_cases += 1
                    assert est.lp_solves == 1
    assert band_cases > 0


def test_a_slot_decided_in_the_band_keeps_the_window_lp_until_it_leaves_the_window():
    model = MODELS["cautious"]
    rng = np.random.default_rng(2)
    x = np.array([25.0, 0.3, 30.0, 22.0])
    u = np.zeros(2)
    piece = model.system.pieces[model.system.piece_index(x)]
    est = IntentionEstimator({"cautious": model}, horizon=4)
    # 2e-9 outside the V row: inside every HiGHS threshold, so the LP accepts it
    est.update(x, u, piece.image(x, u) + _slot_residual(model, 0, 1, 2e-9, rng))
    assert est.valid == ["cautious"] and est.lp_solves == 1
    for k in range(6):
        est.update(x, u, piece.image(x, u) + rng.uniform(*_row_bounds(model)[3:]) * 0.5)
        assert est.lp_solves == min(1 + k + 1, 4), k  # three more window LPs, then intervals again


def test_a_non_separable_disturbance_is_decided_by_the_window_lp():
    """An E whose first column enters two rows: no interval test; every update solves the window LP
    (a shared one), and the decisions equal the per-estimator LP's."""
    base = MODELS["cautious"].system
    E = base.pieces[0].E.copy()
    E[2, 0] = 0.05  # w_ex also moves the headway
    pieces = [PWAPiece(p.domain, p.A, p.B, p.c, E, p.W, p.strict, p.label) for p in base.pieces]
    system = PWASystem(pieces, base.input_set, base.state_set, base.successor_box, "coupled")
    model = type(MODELS["cautious"])("coupled", P, system, MODELS["cautious"].policy)
    rng = np.random.default_rng(4)
    for _ in range(10):
        est, ref = IntentionEstimator({"coupled": model}, horizon=6), WindowLPEstimator({"coupled": model}, horizon=6)
        for x, u, nxt in trajectory(MODELS["cautious"], rng, 25, adversarial=bool(rng.integers(2))):
            assert est.update(x, u, nxt).valid == ref.update(x, u, nxt).valid
    assert est.lp_solves > 0


# ---- the corpora: rollouts of every driver, both intentions, both disturbances ----------------------

class RecordingWindowLPEstimator(WindowLPEstimator):
    """The referee, recording each transition it is fed and the valid set after it (per instance:
    without intentions the guardian's and the tally's estimators run side by side)."""

    instances: list = []

    def __init__(self, *a, **k):
        self.log = []
        RecordingWindowLPEstimator.instances.append(self)
        super().__init__(*a, **k)

    def update(self, x, u_e, x_next):
        out = super().update(x, u_e, x_next)
        self.log.append((np.array(x, float), np.array(u_e, float), np.array(x_next, float), self.steps,
                         tuple(self.valid)))
        return out

    def reset(self):
        super().reset()
        self.log.append(None)  # an episode boundary


def _rollouts(library):
    from envs.agents import BASELINES
    from guardian.config import GuardianConfig
    from guardian.evaluation.rollouts import TWO_CARS_ENV, Rollout, highway_rollouts

    out = []
    for intention in ("aggressive", "cautious"):
        for disturbance in ("random", "adversarial"):
            for driver in BASELINES:
                for use_intention in (True, False):
                    r = Rollout(TWO_CARS_ENV, driver, library=library, intention=intention, disturbance=disturbance,
                                env_config={"duration": 10}, config=GuardianConfig(use_intention=use_intention))
                    out.append(highway_rollouts(r, 2, 7))
    return out


@pytest.mark.slow
def test_rollouts_and_their_replay_are_unchanged(library, monkeypatch):
    """Rollouts of the four drivers x both intentions x random and adversarial disturbance x the guardian
    with and without intentions: the same results with the interval estimator as with the window LP;
    and every recorded transition, replayed in order, gives the same valid set after every update."""
    import guardian.decide.lead
    import guardian.evaluation.tally

    new = _rollouts(library)
    RecordingWindowLPEstimator.instances = []
    monkeypatch.setattr(guardian.decide.lead, "IntentionEstimator", RecordingWindowLPEstimator)
    monkeypatch.setattr(guardian.evaluation.tally, "IntentionEstimator", RecordingWindowLPEstimator)
    monkeypatch.setattr(est_mod, "IntentionEstimator", RecordingWindowLPEstimator)
    reference = _rollouts(library)
    monkeypatch.undo()
    assert new == reference
    models = {n: library.models[n] for n in ("aggressive", "cautious")}
    updates, invalidations, log = 0, 0, []
    for referee in RecordingWindowLPEstimator.instances:
        est = IntentionEstimator(models, horizon=referee.horizon)
        for entry in referee.log:
            log.append(entry)
            if entry is None:
                est.reset()
                continue
            x, u, x_next, steps, valid = entry
            before = len(est.valid)
            est.update(x, u, x_next)
            assert est.steps == steps and tuple(est.valid) == valid, (steps, est.valid, valid)
            updates += 1
            invalidations += before - len(est.valid)
    assert updates > 9_000 and invalidations > 50
    # and each transition's own slot, against each model (the wrong one too), fresh LP vs interval test
    lps = {n: _SlidingFeasibilityLP(*_row_bounds(m)[:3], 1, est_mod.OBSERVATION_TOL) for n, m in models.items()}
    disagreements, decided = [], 0
    for entry in log[::7]:
        if entry is None:
            continue
        x, u, x_next, *_ = entry
        for name, model in models.items():
            one = IntentionEstimator({name: model}, horizon=1)
            got = bool(one.update(x, u, x_next).valid)
            lps[name].clear()
            lps[name].write_slot(0, x_next - model.system.pieces[model.system.piece_index(x)].image(x, u))
            decided += 1
            if got != lps[name].feasible(fresh=True):
                disagreements.append((name, x, u, x_next))
    assert decided > 2000 and disagreements == []
