"""Fixtures shared by every test group that starts the project's processes (multiprocess,
network, live, interop, cli): the DDS domain and the work folder ctest gives each test (so
two tests never see each other; docs/TESTING.md), the project's scripts on sys.path, and
the in-process simulation a run is compared with. A group's conftest.py imports the
fixtures; its tests import `oracle`. `no_crash_unless_asked` (autouse where imported) fails
a test in which a process of a run crashed and started again in place (docs/RUNNING.md, "A
crash") while the test had not asked for it with DEIF_FAULT_CRASH, or was caught in Fast
DDS's reader loop (docs/FASTDDS_NOTES.md, "A reader that hands out one sample for ever")
while it had not asked for it with DEIF_FAULT_READER_LOOP: a restart in place keeps a run
going, and must not hide a crash from a test."""
import json
import os
import shutil
import subprocess
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


@pytest.fixture(autouse=True)
def no_crash_unless_asked(monkeypatch):
    """Every run this test finishes through the launcher has no crash it did not ask for."""
    from deif import launcher
    crashed = []
    finish = launcher.Launcher.finish

    def checked_finish(self):
        res = finish(self)
        if "DEIF_FAULT_CRASH" not in os.environ:
            crashed.extend(f"{p['name']} ({p['crashes']} crash(es), log {p['log']})"
                           for p in res.summary.get("processes", []) if p.get("crashes"))
        if "DEIF_FAULT_READER_LOOP" not in os.environ:
            crashed.extend(f"{p['name']} ({p['reader_loops']} reader loop(s) of Fast DDS, log {p['log']})"
                           for p in res.summary.get("processes", []) if p.get("reader_loops"))
        return res

    monkeypatch.setattr(launcher.Launcher, "finish", checked_finish)
    yield
    assert not crashed, f"a process crashed (or was caught in a reader's loop) and started again in place: {crashed}"


def oracle(run_dir, work=None):
    """The in-process simulation (all to all, no network) of the run's own config (faults
    included), written beside the run; returns its folder. A run stopped before its last
    step (a test that runs "steps: 100000" until it has seen enough) is simulated only as
    far as its target went: a step's rows do not depend on the steps after it."""
    from deif import artefacts, paths
    out = run_dir + "-oracle"
    argv = [paths.executable("deif_sim"), "--config", os.path.join(run_dir, "config.yaml"),
            "--out", out, "--quiet"]
    last = artefacts.last_row(os.path.join(run_dir, "target.csv"))
    try:
        with open(os.path.join(run_dir, "summary.json")) as f:
            steps = json.load(f)["config"]["scenario"]["steps"]
    except (OSError, KeyError, ValueError):
        steps = None
    if last and steps and int(last["step"]) < steps:
        argv += ["--steps", last["step"]]
    subprocess.run(argv, check=True)
    return out
