import fcntl
import importlib.util
import pathlib
from contextlib import contextmanager

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
def cache_dir(tmp_path_factory, worker_id):
    """The session's set cache, one folder shared by the xdist workers: each set is built once (under a lock,
    ``built_once``) and loaded by the others. A test that alters an entry works on a copy."""
    if worker_id == "master":
        return tmp_path_factory.mktemp("rcis-cache")
    folder = tmp_path_factory.getbasetemp().parent / "rcis-cache"
    folder.mkdir(exist_ok=True)
    return folder


@contextmanager
def built_once(folder):
    """Hold the cache folder's lock: the first worker builds, the others then find the sets in the cache."""
    with open(folder / ".build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def library(cache_dir):
    """The full overtake library, built once per test session into a private cache."""
    from intention.library import build_library

    with built_once(cache_dir):
        return build_library(cache_dir=cache_dir, quiet=True, workers=2)


@pytest.fixture(scope="session")
def traffic_library(cache_dir):
    """The overtake library among traffic (the ego may wait behind the lead: v_ex >= 0), with three
    inside-out iterations for the intention sets (every iterate is an RCIS; the tests need no more)."""
    from intention.library import LibrarySettings, build_library
    from intention.params import OvertakeParams

    with built_once(cache_dir):
        return build_library(params=OvertakeParams.among_traffic(),
                             settings=LibrarySettings(intention_max_iterations=3), cache_dir=cache_dir, quiet=True,
                             workers=2)
