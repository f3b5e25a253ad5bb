"""Fixtures of the interoperability tests: the DDS domain and work folder ctest gives each test, and
the project's scripts on sys.path (tests/support/process_fixtures.py)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "support"))
from process_fixtures import domain, no_crash_unless_asked, work  # noqa: E402,F401
