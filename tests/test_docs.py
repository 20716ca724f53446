"""Every public entry point documents its Parameters and Returns (numpydoc), so a user need not read its code."""
import importlib

import pytest

# (module, dotted name, needs a Returns section)
ENTRY_POINTS = [
    ("rcis.polyhedron", "Polyhedron", False), ("rcis.polyhedron", "Polyhedron.contains", True),
    ("rcis.polyhedron", "Polyhedron.robust_tighten", True), ("rcis.polyhedron", "Polyhedron.project", True),
    ("rcis.pwa", "PWASystem", False), ("rcis.pwa", "PWASystem.step", True), ("rcis.pwa", "PWASystem.pre", True),
    ("rcis.admissible", "AdmissibleInputs", False), ("rcis.admissible", "AdmissibleInputs.override", True),
    ("rcis.invariant", "inside_out", True), ("rcis.invariant", "outside_in", True),
    ("rcis.certify", "falsify", True), ("rcis.cache", "RegionCache.get", True),
    ("rcis.cache", "code_fingerprint", False), ("rcis.validate", "finite_vector", True),
    ("intention.library", "build_library", True), ("intention.library", "OvertakeLibrary", False),
    ("intention.library", "export_set", True), ("intention.estimator", "IntentionEstimator", False),
    ("intention.estimator", "IntentionEstimator.update", True),
    ("guardian.supervisor", "IntentionAwareGuardian", False), ("guardian.supervisor", "IntentionAwareGuardian.step", True),
    ("guardian.wrapper", "Guardian", False), ("guardian.wrapper", "Guardian.step", True),
    ("guardian.rollout", "run_episodes", False), ("guardian.rollout", "overtake_rollouts", True),
    ("guardian.rollout", "highway_rollouts", True),
    ("guardian.highd.replay", "replay", True), ("guardian.highd.reader", "read_recording", True),
    ("guardian.highd.generate", "generate", True), ("guardian.highd.convert", "to_itha", True),
    ("guardian.highd.ngsim", "convert_ngsim", True), ("guardian.service.server", "make_server", True),
    ("itha.core", "ITHA.step", True), ("itha.core", "is_self_safe", True), ("itha.core", "is_responsible", True),
    ("itha.car_following", "make_set", True), ("itha.car_following", "load_or_build", True),
    ("itha.highway_experiment", "highway_experiment", True), ("itha.processors", "processors_experiment", True),
    ("itha.idm", "idm_acceleration", True),
    ("envs.agents", "make_agent", True),
    ("envs.overtake", "OvertakeEnv", False), ("envs.wrappers", "OvertakeGuardianWrapper", False),
]


@pytest.mark.parametrize("module,name,returns", ENTRY_POINTS, ids=[f"{m}.{n}" for m, n, _ in ENTRY_POINTS])
def test_entry_point_has_numpydoc_sections(module, name, returns):
    obj = importlib.import_module(module)
    for part in name.split("."):
        obj = getattr(obj, part)
    doc = obj.__doc__ or ""
    assert "Parameters\n" in doc and "----------" in doc, f"{module}.{name}: no numpydoc Parameters section"
    if returns:
        assert "Returns\n" in doc and "-------" in doc, f"{module}.{name}: no numpydoc Returns section"
