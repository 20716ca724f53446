"""Inter-triggering hybrid automata (Definitions 17-22) as a general structure.

An ITHA is a collection of agents ``H_i = <Σ_i, T_i, R_i>`` and a resolution
function ``ρ``. At each step every agent picks an input ``u_i`` and a triggering
action ``τ_i``; agent i then evolves by its own dynamics ``f_i(x_i, u_i, D_i)``
when ``ρ_i = ∅`` and by its reset ``R_i(t, x_i, u_i, ρ_i)`` otherwise (7.1c).

This module is exact for agents whose inputs, disturbances and triggering
actions are finite (sets are enumerated); it is the reference that the fast,
structure-exploiting instances (``itha.processors``, ``itha.road`` with ``itha.responsibility``) are
tested against. It provides

* ``ITHA.step``: one execution step (Definition 18),
* ``trivial_overapproximation``: ``ρ̂`` of (7.6), by enumerating every other
  agent's triggering action,
* ``ordered_actions``: Algorithm 1 for any total order (a permutation),
* ``is_self_safe`` (Definition 20, (7.4)) and ``is_responsible``
  (Definition 22, (7.5)) against per-agent invariant sets.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Callable, Hashable, Sequence

State = Any
Input = Any
Trigger = Hashable
Context = dict  # {"states": [...], "inputs": [...], "triggers": [...]}: what resets may look at


@dataclass(frozen=True)
class Agent:
    """One hybrid agent ``H_i = <Σ_i, T_i, R_i>`` with an invariant set ``X_{i,c}``.

    * ``inputs(x)``: the finite input set ``U_i`` (usable at x),
    * ``successors(t, x, u)``: ``f_i(x, u, D_i)`` as a finite set,
    * ``triggers(t, x)``: ``T_i``, which contains ``null`` (the ε action),
    * ``reset(t, i, x, u, S, ctx)``: ``R_i(t, x, u, S)`` as a finite set; ``ctx``
      holds every agent's state and triggering action (the reset may read the
      agents in S, footnote 1 of Definition 17); other agents' inputs are
      unknown to the reset and must be covered by the returned set,
    * ``invariant(x)``: membership of ``X_{i,c}``.
    """

    name: str
    inputs: Callable[[State], Sequence[Input]]
    successors: Callable[[int, State, Input], Sequence[State]]
    triggers: Callable[[int, State], Sequence[Trigger]]
    null: Trigger
    reset: Callable[[int, int, State, Input, frozenset, Context], Sequence[State]]
    invariant: Callable[[State], bool]


Resolution = Callable[[int, Sequence[State], Sequence[Trigger]], list]  # -> [frozenset per agent]


@dataclass
class ITHA:
    """A collection of agents and a resolution function (Definition 17)."""

    agents: list[Agent]
    resolution: Resolution

    def __len__(self) -> int:
        return len(self.agents)

    def resolve(self, t: int, states, triggers) -> list[frozenset]:
        rho = [frozenset(s) for s in self.resolution(t, states, triggers)]
        for j, tau in enumerate(triggers):  # Assumption 2: null actions trigger nobody
            if tau == self.agents[j].null and any(j in s for s in rho):
                raise ValueError(f"resolution violates Assumption 2: agent {j} has the null "
                                 f"action but appears in ρ")
        return rho

    def step(self, t: int, states, inputs, triggers, choose: Callable[[Sequence[State]], State]):
        """One step of (7.1c).

        Parameters
        ----------
        t : int
            The time step.
        states, inputs, triggers : sequence
            Each agent's state, input and trigger (``τ_i`` in ``T_i``, else ``ValueError``).
        choose : callable
            Picks the successor from each agent's finite set of successors (or of reset states).

        Returns
        -------
        (list, list of frozenset)
            The next states and the resolution ``ρ`` the triggers produced.
        """
        for i, (a, x, tau) in enumerate(zip(self.agents, states, triggers)):
            if tau not in a.triggers(t, x):
                raise ValueError(f"agent {i} ({a.name}): trigger {tau!r} is not in T_i")
        rho = self.resolve(t, states, triggers)
        ctx = {"states": list(states), "inputs": list(inputs), "triggers": list(triggers)}
        nxt = []
        for i, a in enumerate(self.agents):
            if rho[i]:
                options = a.reset(t, i, states[i], inputs[i], rho[i], ctx)
            else:
                options = a.successors(t, states[i], inputs[i])
            nxt.append(choose(list(options)))
        return nxt, rho


# ---- resolution over-approximations ----------------------------------------------
def _profiles(itha: ITHA, t: int, states, fixed: dict[int, Trigger]):
    """Every joint triggering profile that agrees with ``fixed``."""
    choices = [[fixed[k]] if k in fixed else list(a.triggers(t, states[k]))
               for k, a in enumerate(itha.agents)]
    return itertools.product(*choices)


def trivial_overapproximation(itha: ITHA, t: int, states, actor: int, tau: Trigger) -> list[set]:
    """``ρ̂^{(actor)}`` of (7.6): for each agent j, every ``ρ_j`` some choice of the others gives."""
    out = [set() for _ in itha.agents]
    for profile in _profiles(itha, t, states, {actor: tau}):
        for j, s in enumerate(itha.resolve(t, states, profile)):
            out[j].add(s)
    return out


def _resets_safe(itha: ITHA, t: int, states, j: int, u_j, S_of, ctx, check_self: bool) -> bool:
    """Lines 6-11 of Algorithm 1 / the conditions of (7.5) for one resolution profile."""
    for i, a in enumerate(itha.agents):
        S = S_of[i]
        if not S or j not in S:
            continue
        if i == j:
            if check_self and not all(a.invariant(y) for y in a.reset(t, i, states[i], u_j, S, ctx)):
                return False
        elif not all(a.invariant(y) for u in a.inputs(states[i])
                     for y in a.reset(t, i, states[i], u, S, ctx)):
            return False
    return True


def ordered_actions(itha: ITHA, t: int, states, j: int, decided: dict[int, Trigger],
                    order: Sequence[int]):
    """Algorithm 1 for agent j: its feasible triggers and ``ρ̂^{(j)}(t, τ_j)`` for each.

    ``order`` is the total order at time t (highest first); ``decided`` holds the
    triggers already chosen by the agents before j. Returns ``{τ_j: (ρ̂, inputs)}``
    where ρ̂ lists, per agent, the resolutions kept and ``inputs`` are j's inputs
    that keep j safe under every kept resolution. Triggers with no kept
    resolution are infeasible and absent.
    """
    pos = {k: n for n, k in enumerate(order)}
    earlier = {k for k in decided if pos[k] < pos[j]}
    if earlier != {k for k in order[:pos[j]]}:
        raise ValueError(f"agent {j}: decisions of {sorted(set(order[:pos[j]]) - earlier)} are missing")
    a = itha.agents[j]
    out = {}
    for tau in a.triggers(t, states[j]):
        fixed = {k: decided[k] for k in earlier} | {j: tau}
        kept = [set() for _ in itha.agents]
        good_inputs = set(range(len(a.inputs(states[j]))))
        for profile in _profiles(itha, t, states, fixed):
            S_of = itha.resolve(t, states, profile)
            ctx = {"states": list(states), "triggers": list(profile)}
            ok_u = {n for n, u in enumerate(a.inputs(states[j]))
                    if not S_of[j] or all(a.invariant(y) for y in a.reset(t, j, states[j], u, S_of[j], ctx))}
            if not ok_u:
                continue  # line 6: no input keeps j safe under this profile
            if not _resets_safe(itha, t, states, j, None, S_of, ctx, check_self=False):
                continue  # line 9: some other agent would be reset outside its set
            for i, s in enumerate(S_of):
                kept[i].add(s)
            good_inputs &= ok_u
        if any(kept):
            us = [u for n, u in enumerate(a.inputs(states[j])) if n in good_inputs]
            out[tau] = (kept, us)
    return out


# ---- responsibility-sensitive safety -----------------------------------------------
def is_self_safe(agent: Agent, t: int, x, u) -> bool:
    """(7.4): ``f_i(x, u, D_i) ⊆ X_{i,c}``.

    Parameters
    ----------
    agent : Agent
    t : int
    x, u
        The agent's state and input.

    Returns
    -------
    bool
        Every successor under every disturbance lies in the agent's invariant set.
    """
    return all(agent.invariant(y) for y in agent.successors(t, x, u))


def is_responsible(itha: ITHA, t: int, states, j: int, tau_j, u_j, rho_hat: list[set],
                   triggers=None) -> bool:
    """(7.5) for agent j with ``ρ̂`` (a list of sets of resolutions, one per agent).

    Only binding when ``τ_j ≠ ε`` and every agent is in its set.

    Parameters
    ----------
    itha : ITHA
    t : int
    states : sequence
        Every agent's state.
    j : int
        The agent whose trigger is judged.
    tau_j, u_j
        Its trigger and input.
    rho_hat : list of set
        The over-approximation ``ρ̂`` of the resolution, one set per agent.
    triggers : sequence, optional
        The context the resets read; by default j's trigger with everyone else null.

    Returns
    -------
    bool
        Every agent that ``τ_j`` may reset is reset into its invariant set.
    """
    if tau_j == itha.agents[j].null:
        return True
    if not all(a.invariant(x) for a, x in zip(itha.agents, states)):
        return True
    if triggers is None:
        triggers = [a.null for a in itha.agents]
        triggers[j] = tau_j
    ctx = {"states": list(states), "triggers": list(triggers)}
    for i, a in enumerate(itha.agents):
        for S in rho_hat[i]:
            if j not in S:
                continue
            inputs = [u_j] if i == j else a.inputs(states[i])
            if not all(a.invariant(y) for u in inputs for y in a.reset(t, i, states[i], u, S, ctx)):
                return False
    return True
