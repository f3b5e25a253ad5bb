"""Fixtures of the network tests (several network-namespace hosts; root only): the DDS
domain ctest gives each test (its address range 10.211.<domain>.0/24 follows from it), its
work folder, and the project's scripts on sys.path (tests/support/process_fixtures.py)."""
import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "support"))
from process_fixtures import domain, no_crash_unless_asked, work  # noqa: E402,F401


@pytest.fixture(autouse=True)
def no_namespaces_left():
    """Every test leaves no network namespace of its own behind, on every path."""
    yield
    import subprocess
    left = [l.split()[0] for l in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                                   text=True).stdout.splitlines()
            if l.startswith(f"deif{os.getpid()}")]
    assert not left, f"namespaces left behind: {left}"
