"""Package discovery; everything else is in pyproject.toml.

The Python packages are found automatically. The repository's top-level ``data/`` folder is
installed as ``guardian.data`` (package data, read through ``importlib.resources``), which a
``pyproject.toml`` table cannot express together with automatic discovery.
"""
from setuptools import find_packages, setup

setup(packages=find_packages(include=["rcis", "rcis.*", "intention", "intention.*", "itha", "itha.*",
                                      "envs", "envs.*", "guardian", "guardian.*"])
      + ["guardian.data", "guardian.data.highd_sample"],
      package_dir={"guardian.data": "data"})
