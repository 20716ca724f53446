"""The LP intention estimator (Section 6.4.2, rule (6.9))."""
import numpy as np
import pytest

from intention import estimator as est_mod
from intention.estimator import IntentionEstimator
from intention.models import aggressive, cautious
from intention.params import OvertakeParams

P = OvertakeParams()
MODELS = {"aggressive": aggressive(P), "cautious": cautious(P)}
W_LO = np.array([-.15, -.09, -.05, -.1])
W_HI = -W_LO


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


def test_an_update_reuses_the_lp_models(monkeypatch):
    built = []
    original = est_mod._SlidingFeasibilityLP.__init__

    def counting(self, *a, **k):
        built.append(1)
        original(self, *a, **k)

    monkeypatch.setattr(est_mod._SlidingFeasibilityLP, "__init__", counting)
    est = IntentionEstimator(MODELS, horizon=10)
    assert len(built) == 2
    rng = np.random.default_rng(0)
    for x, u, nxt in trajectory(MODELS["aggressive"], rng, 50):
        est.update(x, u, nxt)
    est.reset()
    for x, u, nxt in trajectory(MODELS["aggressive"], rng, 20):
        est.update(x, u, nxt)
    assert len(built) == 2


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
