"""Fixtures of the network tests (several network-namespace hosts; root only): the DDS
domain ctest gives each test (its address range 10.211.<domain>.0/24 follows from it), its
work folder, and the project's scripts on sys.path."""
import os
import shutil
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "scripts"))


@pytest.fixture
def domain():
    return int(os.environ.get("DEIF_TEST_DOMAIN", "180"))


@pytest.fixture
def work(tmp_path):
    path = os.environ.get("DEIF_TEST_WORK") or str(tmp_path)
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path


@pytest.fixture(autouse=True)
def no_namespaces_left():
    """Every test leaves no network namespace of its own behind, on every path."""
    yield
    import subprocess
    left = [l.split()[0] for l in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                                   text=True).stdout.splitlines()
            if l.startswith(f"deif{os.getpid()}")]
    assert not left, f"namespaces left behind: {left}"
