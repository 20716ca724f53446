"""ITHA core and the parallel processors: Theorem 5 as a property, Table 7.1's shape."""
import numpy as np
import pytest

from itha.core import is_responsible, is_self_safe, ordered_actions, trivial_overapproximation
from itha.processors import ProcessorParams, as_itha, decide, processors_experiment, random_graph

P = ProcessorParams()


def _small_world(seed, n=4):
    rng = np.random.default_rng(seed)
    nbrs = random_graph(n, 0.3, rng)
    x = [int(v) for v in rng.integers(0, P.n_overflow, size=n)]
    return rng, nbrs, x


def _safe_responsible_choices(itha, t, x, j, rho_hat_of):
    a = itha.agents[j]
    out = []
    for tau in a.triggers(t, x[j]):
        rho_hat = rho_hat_of(tau)
        for u in a.inputs(x[j]):
            if is_self_safe(a, t, x[j], u) and is_responsible(itha, t, x, j, tau, u, rho_hat):
                out.append((u, tau))
    return out


def _under(itha, t, x, j, tau):
    """ρ̂ that assumes nobody else triggers: an under-approximation of ρ."""
    n = len(itha)
    rho = [set() for _ in range(n)]
    for i in range(n):
        s = frozenset(({j} if i in tau else set()) | ({j} if i == j and tau else set()))
        rho[i].add(s)
    return rho


@pytest.mark.parametrize("seed", range(12))
def test_theorem5_self_safe_and_trivially_responsible_agents_never_leave_their_sets(seed):
    rng, nbrs, x = _small_world(seed)
    itha = as_itha(P, nbrs)
    for t in range(25):
        choices = []
        for j in range(len(itha)):
            options = _safe_responsible_choices(
                itha, t, x, j, lambda tau, j=j: trivial_overapproximation(itha, t, x, j, tau))
            assert options, "Theorem 5 (1): a self-safe, responsible choice always exists"
            choices.append(options[rng.integers(len(options))])
        x, _ = itha.step(t, x, [u for u, _ in choices], [tau for _, tau in choices],
                         lambda opts: opts[rng.integers(len(opts))])
        assert all(P.in_invariant(v) for v in x), f"left the invariant set at t={t}: {x}"


def test_an_under_approximation_can_leave_the_sets():
    """The same random executions with ρ̂ that ignores the other recruiters do overflow."""
    for seed in range(200):
        rng, _, x = _small_world(seed)
        nbrs = [set(range(4)) - {i} for i in range(4)]  # complete graph: many recruiters per target
        itha = as_itha(P, nbrs)
        for t in range(25):
            choices = []
            for j in range(4):
                options = _safe_responsible_choices(itha, t, x, j, lambda tau, j=j: _under(itha, t, x, j, tau))
                recruit = [o for o in options if o[1]]
                pick = recruit if recruit and rng.uniform() < 0.8 else options
                choices.append(pick[rng.integers(len(pick))])
            x, _ = itha.step(t, x, [u for u, _ in choices], [tau for _, tau in choices], max)
            if not all(P.in_invariant(v) for v in x):
                return
    pytest.fail("an under-approximation of ρ never led out of the invariant sets")


def test_trivial_overapproximation_matches_example_6_shape():
    """Agent 1's ρ̂_1 lists every subset of its in-neighbours that may recruit it (Example 6)."""
    nbrs = [{1, 3}, {0}, set(), {0}]
    itha = as_itha(P, nbrs)
    x = [0, 0, 0, 0]
    rho = trivial_overapproximation(itha, 0, x, 1, frozenset())
    # agent 3 may recruit agent 0 or not; agent 0 resets itself when it recruits (module docstring)
    assert rho[0] == {frozenset(), frozenset({3}), frozenset({0}), frozenset({0, 3})}
    assert rho[1] == {frozenset(), frozenset({0})}
    rho4 = trivial_overapproximation(itha, 0, x, 3, frozenset({0}))
    assert all(3 in S for S in rho4[0]), "with τ_4 = {1}, every resolution of agent 1 contains 4"


def test_ordered_actions_needs_the_earlier_decisions():
    itha = as_itha(P, [{1}, {0}])
    with pytest.raises(ValueError, match="missing"):
        ordered_actions(itha, 0, [0, 0], 1, {}, order=[0, 1])


@pytest.mark.parametrize("seed", range(6))
def test_ordered_actions_triggers_keep_everyone_safe(seed):
    rng, nbrs, x = _small_world(seed, n=3)
    itha = as_itha(P, nbrs)
    order, decided = [0, 1, 2], {}
    for j in order:
        feasible = ordered_actions(itha, 0, x, j, decided, order)
        assert itha.agents[j].null in feasible, "the null action is always feasible"
        decided[j] = list(feasible)[rng.integers(len(feasible))]
    for profile_ok in [decided]:
        rho = itha.resolve(0, x, [profile_ok[k] for k in range(3)])
        ctx = {"states": x, "triggers": [profile_ok[k] for k in range(3)]}
        for i, S in enumerate(rho):
            if S:
                worst = itha.agents[i].reset(0, i, x[i], 0, S, ctx)
                assert all(P.in_invariant(y) for y in worst)


@pytest.mark.parametrize("seed", range(20))
def test_fast_trivial_decisions_are_responsible_by_the_general_definition(seed):
    rng, nbrs, x = _small_world(seed)
    itha = as_itha(P, nbrs)
    for i in range(4):
        d = int(rng.integers(0, 3))
        u, tau = decide(P, i, x, d, nbrs, "trivial")
        rho = trivial_overapproximation(itha, 0, x, i, tau)
        assert is_responsible(itha, 0, x, i, tau, u, rho)


def test_table_7_1_shape():
    r = processors_experiment(runs=25, steps=50, seed=0)
    assert r["trivial"]["violations_mean"] == 0 and r["ordered"]["violations_mean"] == 0
    assert r["under"]["violations_mean"] > 0
    assert r["ordered"]["accepted_jobs_mean"] > r["trivial"]["accepted_jobs_mean"]
    assert r["ordered"]["accepted_jobs_mean"] > r["under"]["accepted_jobs_mean"]


def test_processor_params_are_validated():
    with pytest.raises(ValueError, match="n_throttle"):
        ProcessorParams(n_throttle=6)
    with pytest.raises(ValueError, match="initial"):
        ProcessorParams(initial_max=5)
