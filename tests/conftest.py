import importlib.util
import pathlib

import pytest


@pytest.fixture(scope="session")
def benchmark_module():
    """``benchmark_module(name)``: the script ``benchmarks/<name>.py`` as a module (benchmarks are not a package)."""
    def load(name: str):
        path = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("rcis-cache")


@pytest.fixture(scope="session")
def library(cache_dir):
    """The full overtake library, built once per test session into a private cache."""
    from intention.library import build_library

    return build_library(cache_dir=cache_dir, quiet=True, workers=2)


@pytest.fixture(scope="session")
def traffic_library(cache_dir):
    """The overtake library among traffic (the ego may wait behind the lead: v_ex >= 0), with three
    inside-out iterations for the intention sets (every iterate is an RCIS; the tests need no more)."""
    from intention.library import LibrarySettings, build_library
    from intention.params import OvertakeParams

    return build_library(params=OvertakeParams.among_traffic(), settings=LibrarySettings(intention_max_iterations=3),
                         cache_dir=cache_dir, quiet=True, workers=2)
