"""The wheel a user installs holds every package and the shipped sample, and works outside the source tree.

Built with the stock ``pip wheel`` (an isolated build, as an index would build it), unpacked with
``pip install --target`` into a temporary folder, and run from another folder with only that folder
ahead of the installed dependencies (the source tree is not on the path). ``.ci/run`` does the same in a
fresh virtual environment and runs ``guardian rcis build`` and ``guardian replay`` there.
"""
import os
import shutil
import subprocess
import sys
import zipfile

import pytest
from project import ROOT

PACKAGES = ("rcis", "intention", "itha", "envs", "guardian")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """Built from a copy of the tracked sources (a ``build/`` folder left in the tree would leak into it)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src, out = tmp / "src", tmp / "dist"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns("build", "dist", "*.egg-info", "__pycache__", ".venv*",
                                                             ".git", ".pytest_cache"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(out), str(src)],
                   check=True, capture_output=True, text=True)
    (path,) = out.glob("guardian-*.whl")
    return path


def test_the_wheel_holds_every_module_and_the_sample(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    sources = {str(p.relative_to(ROOT)) for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
               if "__pycache__" not in p.parts}
    assert sources - names == set()
    sample = {f"guardian/data/highd_sample/{p.name}" for p in (ROOT / "data" / "highd_sample").glob("*.csv")}
    assert len(sample) == 3 and sample <= names
    assert not any(n.startswith(("tests/", "benchmarks/", "data/")) for n in names)


def test_the_installed_wheel_runs_from_another_folder(wheel, tmp_path):
    target, elsewhere = tmp_path / "site", tmp_path / "elsewhere"
    elsewhere.mkdir()
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(target),
                    str(wheel)], check=True, capture_output=True, text=True)
    env = {**os.environ, "PYTHONPATH": str(target), "GUARDIAN_CACHE_DIR": str(tmp_path / "cache")}
    code = ("import guardian, guardian.cli, guardian.service, guardian.highd.replay as r\n"
            "print(guardian.__file__); print(r.default_sample())\n"
            "print(sorted(p.name for p in r.default_sample().iterdir()))")
    out = subprocess.run([sys.executable, "-c", code], cwd=elsewhere, env=env, check=True, capture_output=True,
                         text=True).stdout.splitlines()
    assert out[0].startswith(str(target)) and out[1].startswith(str(target))
    assert out[2] == "['01_recordingMeta.csv', '01_tracks.csv', '01_tracksMeta.csv']"
    help_ = subprocess.run([sys.executable, "-m", "guardian.cli", "--help"], cwd=elsewhere, env=env,
                           capture_output=True, text=True)
    assert help_.returncode == 0 and "rcis" in help_.stdout and "replay" in help_.stdout
