"""Misuse of the command-line tools (docs/TESTING.md, "CLI tests"): signals to the launcher,
arguments that must be refused with exit status 2 and one line, and nothing started.

Environment (set by tests/cli/CMakeLists.txt, one ctest test per function):
  DEIF_BUILD_DIR    the build folder whose bin/ holds the executables
  DEIF_TEST_DOMAIN  the DDS domain of this test (180..199), so no other run is disturbed
  DEIF_TEST_WORK    this test's work folder
"""
import json
import os
import shutil
import signal
import subprocess
import time

import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
sys.path.insert(0, os.path.join(ROOT, "tests", "support"))
from deif import artefacts  # noqa: E402  (the project's reader of run artefacts)
from deif import launcher as deif_launcher  # noqa: E402  (its shared-memory clean-up)
from process_fixtures import domain, no_crash_unless_asked, work  # noqa: E402,F401
PYTHON = "/usr/bin/python3"
DEIF_RUN = os.path.join(ROOT, "scripts", "deif-run")
DEFAULT = os.path.join(ROOT, "configs", "default.yaml")
BUILD = os.environ.get("DEIF_BUILD_DIR", os.path.join(ROOT, "build"))
DEIF_SIM = os.path.join(BUILD, "bin", "deif_sim")
AGENTS = 2


def run_tool(argv):
    """Runs a tool to its end; returns (exit status, stdout, stderr lines)."""
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, DEIF_BUILD_DIR=BUILD))
    return proc.returncode, proc.stdout, proc.stderr.splitlines()


def live_processes(out_dir):
    """pid -> name of every live (not zombie) deif_agent / deif_target of the run in out_dir."""
    found = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                argv = f.read().decode(errors="replace").split("\0")
            with open(f"/proc/{pid}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue  # gone meanwhile
        name = os.path.basename(argv[0])
        if name in ("deif_agent", "deif_target") and out_dir in argv and state != "Z":
            found[int(pid)] = name
    return found


def wait_until(predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.1)


@pytest.fixture
def reaper():
    """Kills, after the test, whatever a failed test left running: the launchers and the
    processes of the runs it names."""
    runs = []
    yield lambda launcher, out: runs.append((launcher, out))
    for launcher, out in runs:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
        for pid in live_processes(out):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def start_long_run(domain, out, reaper):
    """A run far longer than the test, in real time (light on the CPU), once every process
    is up and the target has written a step."""
    launcher = subprocess.Popen(
        [PYTHON, DEIF_RUN, DEFAULT, "--agents", str(AGENTS), "--steps", "100000",
         "--domain", str(domain), "--set", "scenario.mode=realtime", "--quiet", "--out", out],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, DEIF_BUILD_DIR=BUILD))
    reaper(launcher, out)

    def running():
        if launcher.poll() is not None:
            pytest.fail(f"deif-run ended early ({launcher.returncode}): {launcher.stderr.read()}")
        target_csv = os.path.join(out, "target.csv")
        rows = len(artefacts.read_csv(target_csv))
        return len(live_processes(out)) == AGENTS + 1 and rows >= 1

    wait_until(running, 120, "the run to start")
    return launcher


def test_sigterm_stops_every_process_and_writes_an_interrupted_summary(domain, work, reaper):
    out = os.path.join(work, "run")
    launcher = start_long_run(domain, out, reaper)
    children = live_processes(out)
    assert sorted(children.values()) == ["deif_agent"] * AGENTS + ["deif_target"]

    launcher.send_signal(signal.SIGTERM)
    _, stderr = launcher.communicate(timeout=120)

    assert launcher.returncode == 128 + signal.SIGTERM
    assert stderr.splitlines()[-1] == (
        f"deif-run: interrupted by signal {int(signal.SIGTERM)}; summary.json written")
    assert live_processes(out) == {}
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    assert summary["interrupted_by_signal"] == signal.SIGTERM
    assert summary["ok"] is False
    assert sorted(p["name"] for p in summary["processes"]) == (
        [f"agent_{j}" for j in range(1, AGENTS + 1)] + ["target"])


def test_sigkill_of_the_launcher_leaves_no_orphan(domain, work, reaper):
    out = os.path.join(work, "run")
    shm_before = deif_launcher.shm_snapshot()
    try:
        launcher = start_long_run(domain, out, reaper)
        assert len(live_processes(out)) == AGENTS + 1

        launcher.send_signal(signal.SIGKILL)
        launcher.communicate(timeout=60)

        assert launcher.returncode == -signal.SIGKILL
        # PR_SET_PDEATHSIG (setpriv --pdeathsig KILL in scripts/deif/launcher.py) kills each
        # child as soon as the launcher is gone; allow the kernel a moment to deliver it.
        wait_until(lambda: live_processes(out) == {}, 30, "the launcher's children to die")
        assert not os.path.exists(os.path.join(out, "summary.json"))  # nobody was left to write it
    finally:
        # A launcher killed with -9 cannot remove its processes' shared-memory files: the
        # test does, once nothing maps them.
        deif_launcher.shm_cleanup(shm_before)


def test_two_runs_on_one_host_leave_each_other_alone(domain, work, reaper):
    """Run A (domain D) ends while run B (domain D + 1, 16 agents) runs. A's clean-up of its
    shared-memory files must leave B's alone: B's ports' lock files are held open, not
    mapped, and a process that opens a port whose lock file is gone takes the port for dead
    and makes it anew, cutting its listener off (docs/RUNNING.md, "Several runs on one
    host"). B's target starts again after A is gone, so it opens every agent's port then."""
    first = start_long_run(domain, os.path.join(work, "a"), reaper)
    out_b = os.path.join(work, "b")
    agents_b, steps_b = 16, 80
    second = subprocess.Popen(
        [PYTHON, DEIF_RUN, DEFAULT, "--agents", str(agents_b), "--steps", str(steps_b),
         "--restart-target", str(steps_b // 2),
         "--domain", str(domain + 1), "--set", "scenario.mode=realtime",
         "--set", "scenario.period_s=0.1", "--quiet",
         "--out", out_b],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, DEIF_BUILD_DIR=BUILD))
    reaper(second, out_b)
    target_csv = os.path.join(out_b, "target.csv")
    wait_until(lambda: len(artefacts.read_csv(target_csv)) >= 5, 120, "run B's first steps")

    first.send_signal(signal.SIGTERM)  # A stops and cleans up now
    first.communicate(timeout=120)
    assert first.returncode == 128 + signal.SIGTERM
    _, stderr = second.communicate(timeout=240)

    assert second.returncode == 0, stderr
    with open(os.path.join(out_b, "summary.json")) as f:
        summary = json.load(f)
    assert summary["ok"] is True
    assert summary["metrics"]["last_step"] == steps_b
    assert summary["metrics"]["final_agents"] == agents_b
    assert [p["name"] for p in summary["processes"] if p["restarts_in_place"]] == []
    for j in range(1, agents_b + 1):
        assert summary["metrics"]["per_agent"][str(j)]["rows"] == steps_b


def test_a_run_stopped_by_its_timeout_is_not_ok(domain, work):
    """--timeout stops a run that has not reached its last step: every process ends, the run
    is not ok (exit 1, summary.json ok false, with the timeout) even though every process
    ended with status 0 on the launcher's SIGTERM, and stderr says why."""
    out = os.path.join(work, "run")
    timeout_s = 10
    status, _, stderr = run_tool(
        [PYTHON, DEIF_RUN, DEFAULT, "--agents", str(AGENTS), "--steps", "100000",
         "--domain", str(domain), "--set", "scenario.mode=realtime", "--timeout", str(timeout_s),
         "--quiet", "--out", out])
    assert status == 1, stderr
    assert (f"deif-run: the run did not reach its last step within {timeout_s} s and was stopped "
            "(--timeout; summary.json: ok false)") in stderr
    assert live_processes(out) == {}
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    assert summary["ok"] is False
    assert summary["timed_out_after_s"] == timeout_s
    assert summary["interrupted_by_signal"] is None
    assert 0 < summary["metrics"]["last_step"] < 100000
    assert all(p["exit_status"] == 0 for p in summary["processes"])


def test_domain_out_of_range_starts_nothing(work):
    out = os.path.join(work, "run")
    status, stdout, stderr = run_tool([PYTHON, DEIF_RUN, DEFAULT, "--domain", "300", "--out", out])
    assert status == 2
    assert stdout == ""
    assert len(stderr) == 1
    # Named by the option the user gave, then by the key it sets.
    assert stderr[0] == ("deif-run: error: --domain 300: key 'network.domain_id': "
                         "must be in 0..232 (got 300)")
    assert not os.path.exists(out)  # no run folder, so no process was started


def test_one_agent_is_refused_by_its_option(work):
    out = os.path.join(work, "run")
    status, stdout, stderr = run_tool([PYTHON, DEIF_RUN, DEFAULT, "--agents", "1", "--out", out])
    assert status == 2
    assert stdout == ""
    assert stderr == ["deif-run: error: --agents 1: key 'agents.count': must be in 2..512 (got 1)"]
    assert not os.path.exists(out)


def test_unwritable_run_folder_is_one_line(work):
    status, stdout, stderr = run_tool([PYTHON, DEIF_RUN, DEFAULT, "--out", "/proc/x"])
    assert status == 2
    assert stdout == ""
    assert len(stderr) == 1
    assert stderr[0].startswith("deif-run: error: --out /proc/x: cannot write there")


def test_a_used_run_folder_is_refused_and_left_alone(domain, work):
    out = os.path.join(work, "run")
    os.makedirs(out)
    kept = os.path.join(out, "target.csv")
    with open(kept, "w") as f:
        f.write("step,t\n1,0.1\n")
    status, stdout, stderr = run_tool(
        [PYTHON, DEIF_RUN, DEFAULT, "--domain", str(domain), "--out", out])
    assert status == 2
    assert stdout == ""
    assert len(stderr) == 1
    assert stderr[0] == (f"deif-run: error: --out {out}: exists and is not an empty folder "
                         "(runs never overwrite or mix; choose another folder or remove it)")
    assert sorted(os.listdir(out)) == ["target.csv"]
    with open(kept) as f:
        assert f.read() == "step,t\n1,0.1\n"


def test_deif_sim_check_of_a_directory_is_one_line(work):
    status, stdout, stderr = run_tool([DEIF_SIM, "--config", work, "--check"])
    assert status == 2
    assert stdout == ""
    assert stderr == [f"deif_sim: error: {work}: is a directory, not a config file"]


@pytest.mark.parametrize("seed", ["-1", "abc", "18446744073709551616"])
def test_deif_sim_refuses_a_bad_seed(work, seed):
    out = os.path.join(work, "run")
    status, stdout, stderr = run_tool(
        [DEIF_SIM, "--config", DEFAULT, "--seed", seed, "--steps", "3", "--out", out])
    assert status == 2
    assert stdout == ""
    assert len(stderr) == 1
    assert stderr[0].startswith("deif_sim: error: ")
    assert "scenario.seed" in stderr[0] and f"'{seed}'" in stderr[0]
    assert not os.path.exists(out)
