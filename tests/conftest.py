import pytest


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("rcis-cache")


@pytest.fixture(scope="session")
def library(cache_dir):
    """The full overtake library, built once per test session into a private cache."""
    from intention.library import build_library

    return build_library(cache_dir=cache_dir, quiet=True, workers=2)
