"""Fixtures shared by every test group that starts the project's processes (multiprocess,
network, live, interop, cli): the DDS domain and the work folder ctest gives each test (so
two tests never see each other; docs/TESTING.md), and the project's scripts on sys.path.
A group's conftest.py imports them."""
import os
import shutil
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "scripts"))


@pytest.fixture
def domain():
    """This test's DDS domain (ctest sets DEIF_TEST_DOMAIN; by hand: 150)."""
    return int(os.environ.get("DEIF_TEST_DOMAIN", "150"))


@pytest.fixture
def work(tmp_path):
    """This test's work folder, emptied (ctest sets DEIF_TEST_WORK; by hand: a temporary one)."""
    path = os.environ.get("DEIF_TEST_WORK") or str(tmp_path)
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path
