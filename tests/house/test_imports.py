"""The house's import rules (pyproject.toml, ``[tool.importlinter]``) hold, and a module that breaks one is
caught: import-linter reads every import statement, those inside functions too."""
import shutil
import subprocess
import sys
from pathlib import Path
from project import ROOT

PACKAGES = ("guardian", "rcis", "intention", "itha", "envs")


def _lint(root: Path) -> subprocess.CompletedProcess:
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run([sys.executable, "-c", code, "--no-cache", str(root / "pyproject.toml")],
                          capture_output=True, text=True, cwd=root, env={"PYTHONPATH": str(root), "PATH": ""})


def _copy(tmp_path: Path) -> Path:
    for name in PACKAGES:
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__", "*.csv"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    return tmp_path


def test_the_import_contracts_are_kept():
    done = _lint(ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "broken" not in done.stdout.replace("0 broken", "")


def test_a_module_that_breaks_a_contract_is_caught(tmp_path):
    root = _copy(tmp_path)
    assert _lint(root).returncode == 0
    (root / "guardian" / "decide" / "offender.py").write_text("def f():\n    import highway_env\n")
    (root / "guardian" / "model" / "upstairs.py").write_text("from guardian.wrappers import cars\n")
    (root / "rcis" / "scenario.py").write_text("import intention.models\n")
    done = _lint(root)
    assert done.returncode != 0
    broken = [line for line in done.stdout.splitlines() if line.rstrip().endswith("BROKEN")]
    assert len(broken) == 3, done.stdout
    out = " ".join(done.stdout.split())
    assert "guardian.decide.offender -> highway_env" in out
    assert "guardian.model.upstairs -> guardian.wrappers.cars" in out
    assert "rcis.scenario -> intention.models" in out
