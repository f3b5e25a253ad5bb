"""Fixtures of the live-view tests: the DDS domain and work folder ctest gives each test,
and the project's scripts on sys.path."""
import os
import shutil
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "scripts"))


@pytest.fixture
def domain():
    return int(os.environ.get("DEIF_TEST_DOMAIN", "150"))


@pytest.fixture
def work(tmp_path):
    path = os.environ.get("DEIF_TEST_WORK") or str(tmp_path)
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path
