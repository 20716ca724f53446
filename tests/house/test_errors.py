"""Every exception a user can meet is importable from guardian.errors; each subclasses a builtin; the
engine keeps its own in rcis.errors (it imports nothing from the product); no other module defines one."""
import ast
import builtins

import pytest

import guardian.errors
import rcis.errors
from project import ROOT

PACKAGES = ("rcis", "intention", "itha", "envs", "guardian")
ERROR_MODULES = {ROOT / "rcis" / "errors.py", ROOT / "guardian" / "errors.py"}
BUILTIN_EXCEPTIONS = {v for v in vars(builtins).values() if isinstance(v, type) and issubclass(v, BaseException)}


def test_every_error_is_importable_from_guardian_errors():
    from guardian.errors import ConfigError, HighDFormatError, LPError, ServiceError, StaleCacheError

    assert all(issubclass(c, BaseException) for c in (ConfigError, HighDFormatError, LPError, ServiceError,
                                                       StaleCacheError))
    assert set(guardian.errors.__all__) == {"ConfigClash", "ConfigError", "HighDFormatError", "LPError",
                                            "SchedulerError", "ServiceError", "StaleCacheError", "Terminated"}
    for name in rcis.errors.__all__:
        assert getattr(guardian.errors, name) is getattr(rcis.errors, name)


@pytest.mark.parametrize("name", guardian.errors.__all__)
def test_each_error_subclasses_a_builtin(name):
    """Directly, or through another of these (``ConfigClash`` is a ``ConfigError``)."""
    cls = getattr(guardian.errors, name)
    base = cls.__bases__[0]
    assert base in BUILTIN_EXCEPTIONS or base.__name__ in guardian.errors.__all__, f"{name} derives from {cls.__bases__}"


def test_bad_inputs_raise_the_shared_types():
    """The classes the product raises are the ones in guardian.errors (not look-alikes elsewhere)."""
    from envs.highway_overtake import HighwayOvertakeEnv
    from guardian.highd.reader import read_recording
    from guardian.service.sessions import SessionStore

    with pytest.raises(guardian.errors.ConfigError):
        HighwayOvertakeEnv(config={"intention": "reckless"})
    with pytest.raises(ValueError):  # a user catching the builtin still catches it
        HighwayOvertakeEnv(config={"lanes_count": 1})
    with pytest.raises(guardian.errors.HighDFormatError):
        read_recording(ROOT / "tests", 1)
    err = guardian.errors.ServiceError(404, "no such session", session="x")
    assert (err.status, str(err), err.body()) == (404, "no such session", {"error": "no such session", "session": "x"})
    assert SessionStore  # the service's module imports the shared class
    from guardian.service import sessions
    assert sessions.ServiceError is guardian.errors.ServiceError


def test_no_other_module_defines_an_exception_class():
    """Public exception classes live in the two errors modules only (private control-flow ones may stay)."""
    offenders = []
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            if path in ERROR_MODULES:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                    bases = {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases}
                    if any(b.endswith(("Error", "Exception")) for b in bases):
                        offenders.append(f"{path.relative_to(ROOT)}: {node.name}")
    assert offenders == []


def test_the_engine_errors_module_imports_nothing_from_the_product():
    tree = ast.parse((ROOT / "rcis" / "errors.py").read_text())
    mods = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)} | \
           {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not {m.split(".")[0] for m in mods if m} & {"guardian", "intention", "itha", "envs"}
