"""Every third-party module the shipped packages import is a declared dependency of the wheel.

The test extra pulls in much more than ``dependencies`` (pydantic came in through openapi-core), so a
module missing from ``dependencies`` passed the suite and crashed ``guardian serve`` on a clean install.
This test reads the imports themselves: every ``import x`` / ``from x import ...`` of every ``.py`` file
of the packages the wheel ships (at any depth, inside functions too; docstrings and comments do not
count), less the standard library and the project's own packages, mapped to the distribution that
provides it, must be in ``[project] dependencies``. An extra's modules (``rl``: stable-baselines3, torch;
``sumo``: eclipse-sumo, libsumo; ``commonroad``: commonroad-io) may be imported only inside a ``try`` whose ``except ImportError`` raises an
error naming ``pip install 'guardian[EXTRA]'``.
"""
import ast
import importlib.metadata
import re
import sys
import tomllib

import pytest
from project import ROOT

PACKAGES = ("guardian", "envs", "rcis", "intention", "itha")  # setup.py's find_packages(include=...)
EXTRAS = {"rl": {"stable-baselines3", "torch"}, "sumo": {"eclipse-sumo", "libsumo", "traci"},
          "commonroad": {"commonroad-io"}}  # extra -> its distributions


def _dist_name(requirement: str) -> str:
    """The normalised distribution name of a requirement (``dask[distributed]>=2024.1`` -> ``dask``)."""
    name = re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", requirement.strip()).group(0)
    return re.sub(r"[-_.]+", "-", name).lower()


def _declared(requirements: list) -> set:
    """The distributions ``requirements`` name, and those their extras bring (``dask[distributed]``:
    dask, and distributed as dask's metadata lists it for the extra ``distributed``)."""
    out = set()
    for requirement in requirements:
        name = _dist_name(requirement)
        out.add(name)
        extras = re.match(r"[^\[;<>=!~ ]*\[([^\]]*)\]", requirement.strip())
        for extra in (e.strip() for e in (extras.group(1).split(",") if extras else ())):
            for r in importlib.metadata.requires(name) or ():
                if re.search(rf"""extra\s*==\s*["']{re.escape(extra)}["']""", r):
                    out.add(_dist_name(r))
    return out


def _pyproject() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]


def _sources():
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if "__pycache__" not in path.parts:
                yield path


def _imports(tree: ast.AST):
    """``(top-level module name, node)`` of every absolute import in ``tree``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name.split(".")[0], node
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module.split(".")[0], node


def _third_party_imports() -> dict:
    """{top-level module: [(file, node, tree)]} for the imports outside the standard library and the project."""
    own = set(PACKAGES)
    found = {}
    for path in _sources():
        tree = ast.parse(path.read_text(), filename=str(path))
        for name, node in _imports(tree):
            if name in sys.stdlib_module_names or name in own:
                continue
            found.setdefault(name, []).append((path.relative_to(ROOT), node, tree))
    return found


def _distributions(module: str) -> set:
    dists = importlib.metadata.packages_distributions().get(module)
    assert dists, f"{module} is imported by the shipped packages but no installed distribution provides it"
    return {_dist_name(d) for d in dists}


def test_every_imported_distribution_is_declared():
    project = _pyproject()
    declared = _declared(project["dependencies"])
    extras = set().union(*(_declared(project["optional-dependencies"][e]) for e in EXTRAS))
    missing = {}
    for module, places in sorted(_third_party_imports().items()):
        dists = _distributions(module)
        if dists & declared:
            continue
        if dists & extras:
            continue  # checked by the test below: imported only behind a clear error
        missing[module] = (sorted(dists), sorted({str(p) for p, _, _ in places}))
    assert missing == {}, f"imported but not in pyproject's dependencies: {missing}"


def _parents(tree: ast.AST) -> dict:
    return {child: parent for parent in ast.walk(tree) for child in ast.iter_child_nodes(parent)}


def _catches_import_error(handler: ast.ExceptHandler) -> bool:
    types = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    return any(isinstance(t, ast.Name) and t.id in ("ImportError", "ModuleNotFoundError") for t in types)


def _module_strings(tree: ast.Module) -> dict:
    """Module-level ``NAME = "text"`` constants (a handler may name the hint through one)."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    out[target.id] = node.value.value
    return out


def _raises_the_hint(handler: ast.ExceptHandler, constants: dict, hint: str) -> bool:
    raises = [n for n in ast.walk(handler) if isinstance(n, ast.Raise) and n.exc is not None]
    texts = [n.value for r in raises for n in ast.walk(r) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    texts += [constants.get(n.id, "") for r in raises for n in ast.walk(r) if isinstance(n, ast.Name)]
    return any(hint in t for t in texts)


def _guarded(node: ast.AST, tree: ast.Module, hint: str) -> bool:
    """Whether ``node`` sits in the body of a ``try`` whose ImportError handler raises ``hint``."""
    parents, constants = _parents(tree), _module_strings(tree)
    child, parent = node, parents.get(node)
    while parent is not None:
        if isinstance(parent, ast.Try) and child in parent.body:
            if any(_catches_import_error(h) and _raises_the_hint(h, constants, hint) for h in parent.handlers):
                return True
        child, parent = parent, parents.get(parent)
    return False


@pytest.mark.parametrize("extra", sorted(EXTRAS))
def test_an_extra_is_imported_only_behind_a_clear_error(extra):
    project = _pyproject()
    declared = _declared(project["dependencies"])
    only = {_dist_name(r) for r in project["optional-dependencies"][extra]} - declared
    assert only == EXTRAS[extra]
    hint, seen, bare = f"guardian[{extra}]", [], []
    for module, places in sorted(_third_party_imports().items()):
        if not _distributions(module) & only:
            continue
        for path, node, tree in places:
            seen.append(f"{path}:{node.lineno}")
            if not _guarded(node, tree, hint):
                bare.append(f"{path}:{node.lineno} imports {module}")
    assert seen, f"no import of the {extra} extra found: the check above would pass vacuously"
    assert bare == [], f"the {extra} extra imported without an ImportError naming {hint!r}: {bare}"


def test_an_extra_of_a_dependency_declares_what_it_brings():
    declared = _declared(["dask[distributed]>=2024.1", "numpy>=1.26"])
    assert {"dask", "distributed", "numpy"} <= declared and "pandas" not in _declared(["dask>=2024.1"])


def test_the_check_sees_imports_inside_functions_and_not_in_docstrings():
    tree = ast.parse('"""import numpy"""\ndef f():\n    if True:\n        from pydantic import BaseModel\n'
                     "# import scipy\n")
    assert [name for name, _ in _imports(tree)] == ["pydantic"]
