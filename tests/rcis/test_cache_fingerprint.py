"""The set cache's code fingerprint covers every file that shapes a set: editing any of them changes the key.

Before, the fingerprint hashed a hand list of five engine files and the model file, so an edit of
``rcis/tolerances.py`` (or a kernel, or the parameters) loaded sets computed by other code.
"""
import os
import shutil
import subprocess
import sys

import pytest

from intention.library import LibrarySettings, _payload
from intention.params import OvertakeParams
from rcis import cache
from rcis.cache import code_fingerprint, source_closure
from project import ROOT

ENGINE = {"rcis.invariant", "rcis.pwa", "rcis.polyhedron", "rcis.region", "rcis.lp", "rcis.tolerances",
          "rcis._kernels"}
SETS = {  # the model module each cached set passes, and what must shape it
    "intention.library": ENGINE | {"intention.library", "intention.models", "intention.params"},
    "itha.car_following": ENGINE | {"itha.car_following", "itha._kernels"},
}


@pytest.mark.parametrize("model", SETS)
def test_the_closure_holds_the_engine_the_model_and_the_parameters(model):
    assert SETS[model] <= set(source_closure(*cache.ENGINE_MODULES, model))


@pytest.mark.parametrize("model,module", [(m, x) for m, xs in SETS.items() for x in sorted(xs)])
def test_editing_any_shaping_module_changes_the_fingerprint(model, module, monkeypatch):
    before = code_fingerprint(model)
    read = cache._source
    monkeypatch.setattr(cache, "_source", lambda name: read(name) + (b"\n# edited\n" if name == module else b""))
    assert code_fingerprint(model) != before


def test_the_library_payload_changes_when_a_tolerance_changes(monkeypatch):
    """The key the library's cache actually uses (not only the helper) follows an edit of rcis/tolerances.py."""
    args = ("aggressive", OvertakeParams(), LibrarySettings(), "seed")
    before = _payload(*args)
    read = cache._source
    monkeypatch.setattr(cache, "_source", lambda name: read(name).replace(b"1e-6", b"2e-6")
                        if name == "rcis.tolerances" else read(name))
    after = _payload(*args)
    assert after["code"] != before["code"] and {k for k in before if before[k] != after[k]} == {"code"}


def test_a_real_edit_of_the_tolerances_file_in_a_copy_changes_the_key(tmp_path):
    """No monkeypatching: copy the packages, edit rcis/tolerances.py on disk, ask a fresh process."""
    for pkg in ("rcis", "itha"):
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    code = "from rcis.cache import code_fingerprint; import itha; print(itha.__file__, code_fingerprint('itha.car_following'))"
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}

    def ask():
        out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, check=True, capture_output=True,
                             text=True).stdout.split()
        assert out[0].startswith(str(tmp_path))
        return out[1]

    before = ask()
    with open(tmp_path / "rcis" / "tolerances.py", "a") as fh:
        fh.write("\n# a tolerance edited\n")
    assert ask() != before
