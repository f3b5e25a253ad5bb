"""Fixtures shared by the Python unit tests.

Environment (set by tests/python/CMakeLists.txt for ctest; optional by hand):
  DEIF_SIM_EXE    the deif_sim to run (default: $DEIF_BUILD_DIR/bin/deif_sim)
  DEIF_BUILD_DIR  the build folder whose bin/ holds deif_config and deif_sim (default build/)
  DEIF_TEST_WORK  keep every test's files under this folder (default: pytest's tmp_path)
"""
import os
import re
import shutil

import pytest

from deif import paths

ROOT = paths.ROOT


@pytest.fixture(scope="session")
def deif_sim():
    """Path of deif_sim; also exported as DEIF_SIM_EXE for the code under test."""
    exe = os.environ.get("DEIF_SIM_EXE") or os.path.join(paths.build_dir(), "bin", "deif_sim")
    if not os.path.exists(exe):
        pytest.fail(f"deif_sim not found at {exe}; build it (scripts/build) or set DEIF_SIM_EXE")
    if not os.path.exists(os.path.join(paths.build_dir(), "bin", "deif_config")):
        pytest.fail(f"deif_config not found in {paths.build_dir()}/bin; build it (scripts/build) "
                    "or set DEIF_BUILD_DIR")
    os.environ["DEIF_SIM_EXE"] = exe
    return exe


def _work(base, name):
    path = os.path.join(base, re.sub(r"[^A-Za-z0-9_.-]+", "_", name))
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path


@pytest.fixture
def work_dir(request, tmp_path):
    """An empty folder for one test (under DEIF_TEST_WORK when set, to look at afterwards)."""
    base = os.environ.get("DEIF_TEST_WORK")
    return _work(base, request.node.name) if base else str(tmp_path)


@pytest.fixture(scope="module")
def module_work_dir(request, tmp_path_factory):
    """An empty folder shared by the tests of one module."""
    base = os.environ.get("DEIF_TEST_WORK")
    name = request.module.__name__.rsplit(".", 1)[-1]
    return _work(base, name) if base else str(tmp_path_factory.mktemp(name))
