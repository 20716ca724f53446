"""rcis is a generic engine: it builds an RCIS for a system that is not ours (that it imports no scenario is
an import contract, tests/house/test_imports.py)."""
import runpy
from project import ROOT



def test_the_double_integrator_example_builds_a_certified_rcis(capsys):
    runpy.run_path(str(ROOT / "examples" / "double_integrator.py"), run_name="__main__")
    out = capsys.readouterr().out
    assert "converged=True" in out and "counterexamples=0" in out
    assert "(0.9, 0.5) in C: True" in out and "(0.95, 0.9) in C: False" in out
