"""rcis is a generic engine: it imports no scenario, and builds an RCIS for a system that is not ours."""
import ast
import runpy
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("intention", "itha", "envs", "guardian")


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_rcis_imports_no_scenario_package():
    offenders = {f"{p.name}: {m}" for p in (ROOT / "rcis").glob("*.py") for m in _imports(p)
                 if m.split(".")[0] in SCENARIOS}
    assert offenders == set()


def test_importing_every_rcis_module_loads_no_scenario_package():
    code = ("import importlib, pkgutil, sys, rcis\n"
            "for m in pkgutil.iter_modules(rcis.__path__): importlib.import_module('rcis.' + m.name)\n"
            f"print(sorted({{n.split('.')[0] for n in sys.modules}} & set({SCENARIOS!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert out.strip() == "[]"


def test_the_double_integrator_example_builds_a_certified_rcis(capsys):
    runpy.run_path(str(ROOT / "examples" / "double_integrator.py"), run_name="__main__")
    out = capsys.readouterr().out
    assert "converged=True" in out and "counterexamples=0" in out
    assert "(0.9, 0.5) in C: True" in out and "(0.95, 0.9) in C: False" in out
