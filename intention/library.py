"""The RCIS library of the overtake scenario (dissertation Section 6.4.1).

``C_bnd``: inside-out for the bounded-velocity model from ``C_left`` (Prop. 20);
``C_a``, ``C_c``: inside-out for the aggressive and cautious models from
``C_bnd`` (Prop. 21), so ``C_left ⊆ C_bnd ⊆ C_a, C_c`` (Prop. 22). Each set
induces a supervisor ``S_I(x)`` (``admissible``). Sets are cached on disk.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from intention.models import IntentionModel, intention_models, left_lane, safe_set
from intention.params import OvertakeParams
from rcis.admissible import AdmissibleInputs
from rcis.cache import RegionCache, code_fingerprint, payload_key
from rcis.invariant import COVER_BUDGET, inside_out, stderr_progress
from rcis.parallel import Jobs
from rcis.region import Region

SET_NAMES = ("bounded_velocity", "aggressive", "cautious")
PAPER_NAMES = {"bounded_velocity": "C_bnd", "aggressive": "C_a", "cautious": "C_c"}  # Section 6.4.1
_BY_ANY_NAME = {**{n: n for n in SET_NAMES}, **{v: k for k, v in PAPER_NAMES.items()}}


def set_name(name: str) -> str:
    """The library's name of a set given either name (``C_c`` or ``cautious``); ValueError names both."""
    try:
        return _BY_ANY_NAME[name]
    except KeyError:
        choices = ", ".join(f"{PAPER_NAMES[n]} ({n})" for n in SET_NAMES)
        raise ValueError(f"unknown set {name!r}; choose from {choices}") from None


SEED_OF = {"bounded_velocity": "left_lane", "aggressive": "bounded_velocity", "cautious": "bounded_velocity"}


@dataclass(frozen=True)
class LibrarySettings:
    bounded_max_iterations: int = 50   # the dissertation reports convergence in 12
    intention_max_iterations: int = 5  # the dissertation shows C_c after 5 iterations
    merge: bool = True
    cover_budget: int = COVER_BUDGET

    def max_iterations(self, name: str) -> int:
        return self.bounded_max_iterations if name == "bounded_velocity" else self.intention_max_iterations


@dataclass
class InvariantSet:
    name: str
    region: Region
    iterations: int
    converged: bool
    seconds: float
    from_cache: bool
    key: str
    payload: dict

    def summary(self) -> dict:
        return {"iterations": self.iterations, "converged": self.converged, "pieces": len(self.region),
                "seconds": round(self.seconds, 3), "from_cache": self.from_cache}


class OvertakeLibrary:
    """``{C_bnd, C_a, C_c}`` with their models and supervisors; built by ``build_library``.

    Parameters
    ----------
    params : OvertakeParams
        The scenario's parameters the sets were computed for.
    sets : dict of str to InvariantSet
        ``bounded_velocity``, ``aggressive``, ``cautious``.
    models : dict of str to IntentionModel
        The PWA model of each set.
    """

    def __init__(self, params: OvertakeParams, sets: dict, models: dict):
        self.params = params
        self.sets: dict[str, InvariantSet] = sets
        self.models: dict[str, IntentionModel] = models
        self._admissible: dict[str, AdmissibleInputs] = {}

    def region(self, name: str) -> Region:
        """The set ``name`` (``C_bnd``/``C_a``/``C_c`` or the long names) as a union of polyhedra."""
        return self.sets[set_name(name)].region

    def admissible(self, name: str) -> AdmissibleInputs:
        """The supervisor ``S_I`` of set ``name`` (Definition 15)."""
        name = set_name(name)
        if name not in self._admissible:
            self._admissible[name] = AdmissibleInputs(self.models[name].system, self.region(name))
        return self._admissible[name]

    def containment(self) -> dict:
        """The inclusions of Prop. 22 checked on the computed sets, and a strictness witness."""
        left = left_lane(self.params)
        bnd, agg, cau = (self.region(n) for n in SET_NAMES)
        witness = cau.witness_outside(bnd)
        return {"C_left ⊆ C_bnd": left.is_subset_of(bnd),
                "C_bnd ⊆ C_a": bnd.is_subset_of(agg),
                "C_bnd ⊆ C_c": bnd.is_subset_of(cau),
                "C_c ⊄ C_bnd (strictly larger)": witness is not None,
                "witness in C_c \\ C_bnd": None if witness is None else [round(float(v), 4) for v in witness]}


def _payload(name: str, params: OvertakeParams, settings: LibrarySettings, seed_key: str) -> dict:
    return {"set": name, "params": params.as_dict(), "max_iterations": settings.max_iterations(name),
            "merge": settings.merge, "cover_budget": settings.cover_budget, "seed": SEED_OF[name],
            "seed_key": seed_key, "code": code_fingerprint(__name__)}


def _compute(name: str, params: OvertakeParams, settings: LibrarySettings, seed: Region, quiet: bool):
    model = intention_models(params)[name]
    result = inside_out(model.system, seed, safe_set(params), settings.max_iterations(name),
                        merge=settings.merge, cover_budget=settings.cover_budget,
                        progress=None if quiet else stderr_progress(f"rcis {name}"))
    return result.region, {"iterations": result.iterations, "converged": result.converged,
                           "seconds": result.seconds, "history": result.history}


def build_library(params: OvertakeParams = OvertakeParams(), settings: LibrarySettings = LibrarySettings(),
                  cache_dir: Path | None = None, use_cache: bool = True, workers: int = 2,
                  quiet: bool = False) -> OvertakeLibrary:
    """Load every set of the overtake library from the cache, or compute it (Section 6.4.1).

    Parameters
    ----------
    params : OvertakeParams
        The scenario (Table 6.1 by default); every field is part of the cache key.
    settings : LibrarySettings
        Iteration counts, merging and the coverage budget; also part of the key.
    cache_dir : path, optional
        Default ``$GUARDIAN_CACHE_DIR`` or ``~/.cache/guardian``.
    use_cache : bool
        False recomputes every set and replaces the entries.
    workers : int
        Processes for ``C_a`` and ``C_c`` (computed in parallel when 2).
    quiet : bool
        No per-iteration progress on stderr.

    Returns
    -------
    OvertakeLibrary
        ``C_bnd``, ``C_a``, ``C_c`` with their models and supervisors ``S_I(x)``.
    """
    cache = RegionCache(cache_dir, use_cache=use_cache)
    models = intention_models(params)
    sets: dict[str, InvariantSet] = {}

    def remember(name, region, info, payload, from_cache):
        sets[name] = InvariantSet(name, region, info["iterations"], info["converged"], info["seconds"],
                                  from_cache, payload_key(payload), payload)

    bnd_payload = _payload("bounded_velocity", params, settings, "C_left")
    region, info, from_cache = cache.get(
        "bounded_velocity", bnd_payload, lambda: _compute("bounded_velocity", params, settings, left_lane(params), quiet))
    remember("bounded_velocity", region, info, bnd_payload, from_cache)
    bnd = sets["bounded_velocity"]

    todo = []
    for name in ("aggressive", "cautious"):
        payload = _payload(name, params, settings, bnd.key)
        hit = cache.load(name, payload)
        if hit is None:
            todo.append((name, payload))
        else:
            remember(name, hit[0], hit[1], payload, True)
    # Each set is stored as soon as it is computed: an interrupt keeps every finished set.
    if workers > 1 and len(todo) > 1:
        payloads = dict(todo)
        with Jobs(min(workers, len(todo))) as pool:
            running = {n: pool.submit(_compute, n, params, settings, bnd.region, quiet) for n, _ in todo}
            for name, (region, info) in pool.as_completed(running):
                cache.store(name, payloads[name], region, info)
                remember(name, region, info, payloads[name], False)
    else:
        for name, payload in todo:
            region, info = _compute(name, params, settings, bnd.region, quiet)
            cache.store(name, payload, region, info)
            remember(name, region, info, payload, False)
    return OvertakeLibrary(params, {n: sets[n] for n in SET_NAMES}, models)


def export_set(library: OvertakeLibrary, name: str) -> dict:
    """The set as JSON: x is in it iff ``A x <= b`` for some piece.

    Parameters
    ----------
    library : OvertakeLibrary
    name : str
        ``C_bnd``, ``C_a``, ``C_c`` or the long names.

    Returns
    -------
    dict
        ``name, paper_name, state`` (the coordinates' names), the pieces' ``A`` and ``b``, and how
        the set was computed (iterations, converged, parameters).
    """
    from intention.params import STATE_NAMES

    name = set_name(name)
    s = library.sets[name]
    return {"name": name, "paper_name": PAPER_NAMES[name], "state": list(STATE_NAMES),
            "pieces": [{"A": P.A.tolist(), "b": P.b.tolist()} for P in s.region.pieces],
            "params": {**library.params.as_dict(), "iterations": s.iterations, "converged": s.converged,
                       "cache_key": s.key, "settings": {k: v for k, v in s.payload.items() if k != "params"}}}


def replace_settings(settings: LibrarySettings, **changes) -> LibrarySettings:
    return dataclasses.replace(settings, **{k: v for k, v in changes.items() if v is not None})
