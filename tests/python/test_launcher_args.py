"""deif.launcher's argument, fault and partition parsing and its config verdict, without
starting a process: every check happens in the Launcher constructor (which only resolves the
config through deif_config and writes the run folder's config.yaml) or in the parsers."""
import os

import pytest

from conftest import ROOT
from deif import config, launcher

DEFAULT = os.path.join(ROOT, "configs", "default.yaml")


def test_agent_fault_is_step_colon_id():
    f = launcher.Fault.parse("100:2", "kill")
    assert (f.step, f.action, f.agent, f.origin) == (100, "kill", 2, "--kill 100:2")
    assert f.as_config() == {"step": 100, "action": "kill", "agent": 2}
    s = launcher.Fault.parse("80:1", "stop")
    assert (s.step, s.action, s.agent, s.origin) == (80, "stop", 1, "--stop 80:1")


def test_restart_target_is_a_step_alone():
    f = launcher.Fault.parse("120", "restart_target")
    assert (f.step, f.action, f.agent, f.origin) == (120, "restart_target", None, "--restart-target 120")
    assert f.as_config() == {"step": 120, "action": "restart_target"}


@pytest.mark.parametrize("text,action,flag", [
    ("100", "kill", "--kill"), ("a:2", "kill", "--kill"), ("1:2:3", "stop", "--stop"),
    ("", "cont", "--cont"), ("1:2", "restart_target", "--restart-target"),
])
def test_malformed_fault_names_its_flag(text, action, flag):
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Fault.parse(text, action)
    assert str(e.value).startswith(f"{flag} {text}: expected")


def test_partition_is_step_seconds_host():
    p = launcher.Partition.parse("50:1.5:2")
    assert (p.step, p.seconds, p.host) == (50, 1.5, 2)


@pytest.mark.parametrize("text", ["50:1.5", "x:1:2", "0:1:2", "50:0:2", "50:3600:2", "50:1:0"])
def test_bad_partition_is_refused(text):
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Partition.parse(text)
    assert str(e.value).startswith(f"--partition {text}:")


@pytest.mark.parametrize("kwargs,message", [
    ({"hosts": 0}, "--hosts 0"),
    ({"loss": 1.0, "hosts": 2}, "--loss"),
    ({"loss": 0.1}, "need --hosts 2"),
    ({"partitions": [launcher.Partition(10, 1.0, 2)]}, "need --hosts 2"),
    ({"hosts": 2, "partitions": [launcher.Partition(10, 1.0, 3)]}, "only 2 hosts"),
    ({"secure": True, "discovery_server": True}, "cannot authenticate through a Discovery Server"),
])
def test_bad_host_arguments_start_nothing(deif_sim, work_dir, kwargs, message):
    out = os.path.join(work_dir, "run")
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(DEFAULT, out, **kwargs)
    assert message in str(e.value)
    assert not os.path.exists(out)


def test_refused_config_names_the_key_and_starts_nothing(deif_sim, work_dir):
    out = os.path.join(work_dir, "run")
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(DEFAULT, out, agents=0)
    assert "agents.count" in str(e.value)
    bad = os.path.join(work_dir, "bad.yaml")
    with open(bad, "w") as f:
        f.write("scenario:\n  steps: -3\n")
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(bad, out)
    assert "bad.yaml:2" in str(e.value) and "scenario.steps" in str(e.value)
    with pytest.raises(launcher.LaunchError):
        launcher.run(bad, out)
    assert not os.path.exists(out)


@pytest.mark.parametrize("text,reason", [("10:9", "1..3"), ("60:1", "scenario.steps")])
def test_refused_command_line_fault_is_blamed_on_its_flag(deif_sim, work_dir, text, reason):
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(DEFAULT, os.path.join(work_dir, "run"), agents=3, steps=50,
                          faults=[launcher.Fault.parse(text, "kill")])
    assert str(e.value).startswith(f"--kill {text}:") and reason in str(e.value)


def test_overrides_reach_the_config_every_process_reads(deif_sim, work_dir):
    out = os.path.join(work_dir, "run")
    la = launcher.Launcher(DEFAULT, out, agents=3, steps=50, seed=9, domain=77,
                           overrides=["target.trajectory=static"],
                           faults=[launcher.Fault.parse("30:3", "stop"), launcher.Fault.parse("10:2", "kill")])
    assert (la.n, la.steps, la.domain) == (3, 50, 77)
    assert [(f.step, f.action, f.agent) for f in la.faults] == [(10, "kill", 2), (30, "stop", 3)]
    assert sorted(os.listdir(out)) == ["config.yaml", "logs"]  # nothing else: nothing ran
    written = config.resolve(os.path.join(out, "config.yaml"))
    assert written["agents"]["count"] == 3
    assert written["scenario"]["steps"] == 50 and written["scenario"]["seed"] == 9
    assert written["network"]["domain_id"] == 77
    assert written["target"]["trajectory"] == "static"
    assert sorted(f["step"] for f in written["faults"]) == [10, 30]
    assert written == la.cfg


def test_a_used_run_folder_is_refused(deif_sim, work_dir):
    out = os.path.join(work_dir, "run")
    os.makedirs(out)
    with open(os.path.join(out, "target.csv"), "w") as f:
        f.write("step,t,x_true,y_true\n")
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(DEFAULT, out)
    assert "exists and is not an empty folder" in str(e.value)


def test_default_run_folder_is_under_runs():
    path = launcher.default_out_dir(DEFAULT)
    assert path.startswith(os.path.join(ROOT, "runs", "default-"))


@pytest.mark.parametrize("agents,configured,expected", [(16, None, 96.0), (4, None, 30.0), (16, 120.0, 120.0)])
def test_secure_start_timeout_covers_the_staggered_start(deif_sim, work_dir, agents, configured, expected):
    """A secure run starts its processes one after another (docs/SECURITY.md, "Start-up"):
    the start timeout is raised to 6 s per agent when it is shorter, never lowered, and the
    raise is written to the config every process reads."""
    out = os.path.join(work_dir, "run")
    sets = ["network.security.enabled=true", "network.security.dir=" + os.path.join(work_dir, "certs")]
    if configured is not None:
        sets.append(f"network.start_timeout_s={configured:g}")
    la = launcher.Launcher(DEFAULT, out, agents=agents, overrides=sets)
    written = config.resolve(os.path.join(out, "config.yaml"))
    assert written["network"]["start_timeout_s"] == expected
    assert la.cfg["network"]["start_timeout_s"] == expected
    plain = launcher.Launcher(DEFAULT, os.path.join(work_dir, "plain"), agents=agents)
    assert plain.cfg["network"]["start_timeout_s"] == 30.0
    assert la.staggered and not plain.staggered


def test_the_start_order_can_be_chosen(deif_sim, work_dir):
    """Secure runs start one process after another unless told otherwise (deif-run --start);
    the start timeout of a secure run is raised either way."""
    sets = ["network.security.enabled=true", "network.security.dir=" + os.path.join(work_dir, "certs")]
    together = launcher.Launcher(DEFAULT, os.path.join(work_dir, "a"), agents=16, overrides=sets,
                                 staggered=False)
    assert not together.staggered
    assert together.cfg["network"]["start_timeout_s"] == 96.0
    plain = launcher.Launcher(DEFAULT, os.path.join(work_dir, "b"), agents=4, staggered=True)
    assert plain.staggered


def test_agents_start_under_their_scheduling_policy(deif_sim, work_dir):
    """SCHED_BATCH by default (chrt, inside setpriv so the process still dies with the
    launcher); the target never; none with --agent-sched normal; anything else is refused
    before anything starts."""
    lau = launcher.Launcher(DEFAULT, os.path.join(work_dir, "a"), agents=2)
    agent = launcher.Proc("agent_1", ["deif_agent", "--id", "1"], 1)
    target = launcher.Proc("target", ["deif_target"], 1)
    assert lau.command(agent) == ["setpriv", "--pdeathsig", "KILL", "--", "chrt", "--batch", "0",
                                  "deif_agent", "--id", "1"]
    assert lau.command(target) == ["setpriv", "--pdeathsig", "KILL", "--", "deif_target"]
    normal = launcher.Launcher(DEFAULT, os.path.join(work_dir, "b"), agents=2, agent_sched="normal")
    assert normal.command(agent) == ["setpriv", "--pdeathsig", "KILL", "--", "deif_agent", "--id", "1"]
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(DEFAULT, os.path.join(work_dir, "c"), agents=2, agent_sched="fifo")
    assert str(e.value) == "--agent-sched fifo: must be one of batch, normal"
    assert not os.path.exists(os.path.join(work_dir, "c"))


def test_the_run_comes_first_with_a_nice_value(deif_sim, work_dir, monkeypatch):
    """--nice N: the target and the agents start under nice (before their policy, so every
    thread has both); the live observer keeps its own. Out of -20..19, or below 0 without
    root, it is refused before anything starts."""
    lau = launcher.Launcher(DEFAULT, os.path.join(work_dir, "a"), agents=2, nice=-10)
    agent = launcher.Proc("agent_1", ["deif_agent", "--id", "1"], 1)
    target = launcher.Proc("target", ["deif_target"], 1)
    observer = launcher.Proc("observer", ["deif_observer"], 1)
    assert lau.command(agent) == ["setpriv", "--pdeathsig", "KILL", "--", "nice", "-n", "-10", "chrt", "--batch",
                                  "0", "deif_agent", "--id", "1"]
    assert lau.command(target) == ["setpriv", "--pdeathsig", "KILL", "--", "nice", "-n", "-10", "deif_target"]
    assert lau.command(observer) == ["setpriv", "--pdeathsig", "KILL", "--", "deif_observer"]
    for value, message in ((20, "--nice 20: must be an integer in -20..19"),
                           (-21, "--nice -21: must be an integer in -20..19")):
        with pytest.raises(launcher.LaunchError) as e:
            launcher.Launcher(DEFAULT, os.path.join(work_dir, "c"), agents=2, nice=value)
        assert str(e.value) == message
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    with pytest.raises(launcher.LaunchError) as e:
        launcher.Launcher(DEFAULT, os.path.join(work_dir, "c"), agents=2, nice=-5)
    assert str(e.value) == "--nice -5: a negative nice value needs root (CAP_SYS_NICE)"
    assert launcher.Launcher(DEFAULT, os.path.join(work_dir, "d"), agents=2, nice=5).nice == 5
    assert not os.path.exists(os.path.join(work_dir, "c"))


def _touch(d, name):
    with open(os.path.join(d, name), "wb") as f:
        f.write(b"\0" * 4096)


def test_shm_cleanup_keeps_every_file_of_a_port_some_process_uses(tmp_path, monkeypatch):
    """A port's lock file (_el) is held open, not mapped; its mapped file and named mutex may
    not be in use at the moment. The cleanup keeps the whole family while any file of it is
    mapped or open, and removes families nobody uses (docs/RUNNING.md, "Several runs on one
    host"), glibc's temporary semaphore files too. Files that were there before the run are
    never touched."""
    import mmap
    d = str(tmp_path)
    monkeypatch.setattr(launcher, "SHM_DIR", d)
    _touch(d, "fastrtps_port7000")                    # there before the run
    before = launcher.shm_snapshot()
    live_port = ["fastrtps_port7411", "fastrtps_port7411_el", "sem.fastrtps_port7411_mutex"]
    live_segment = ["fastrtps_0123abcd4567ef89", "fastrtps_0123abcd4567ef89_el"]
    # glibc's temporary file of a named semaphore, left by a process killed inside sem_open;
    # one still open belongs to a sem_open in progress.
    live_temporary = ["sem.Qz81mK"]
    dead = ["fastrtps_port7413", "fastrtps_port7413_el", "sem.fastrtps_port7413_mutex",
            "fastrtps_fedcba9876543210", "fastrtps_fedcba9876543210_el", "sem.a7XbQ2"]
    unrelated = ["unrelated_file", "sem.someone_else", "sem.a7XbQ"]
    for name in live_port + live_segment + live_temporary + dead + unrelated:
        _touch(d, name)
    lock = open(os.path.join(d, "fastrtps_port7411_el"), "rb")  # held open, like a listener's lock
    opening = open(os.path.join(d, "sem.Qz81mK"), "rb")
    seg = open(os.path.join(d, "fastrtps_0123abcd4567ef89"), "r+b")
    mapped = mmap.mmap(seg.fileno(), 4096)                       # mapped, like a segment
    seg.close()
    try:
        assert launcher.shm_cleanup(before) == len(dead)
        left = set(os.listdir(d))
    finally:
        mapped.close()
        lock.close()
        opening.close()
    assert left == set(live_port + live_segment + live_temporary + ["fastrtps_port7000"] + unrelated)
    # Nobody uses them now.
    assert launcher.shm_cleanup(before) == len(live_port + live_segment + live_temporary)
    assert set(os.listdir(d)) == {"fastrtps_port7000", *unrelated}


def test_a_domain_in_use_over_shared_memory_is_seen(tmp_path, monkeypatch):
    """deif-run warns when another process on this host uses its domain over shared memory
    (docs/RUNNING.md, "Several runs on one host"): it maps or holds open one of the domain's
    ports, 7400 + 250 x domain and the 249 after it."""
    d = str(tmp_path)
    monkeypatch.setattr(launcher, "SHM_DIR", d)
    _touch(d, "fastrtps_port55160")     # domain 191's first unicast port, nobody using it
    _touch(d, "fastrtps_port55160_el")
    _touch(d, "fastrtps_port55649_el")  # domain 192's last
    assert not launcher.shm_domain_in_use(191)
    lock = open(os.path.join(d, "fastrtps_port55649_el"), "rb")  # held open, like a listener's lock
    try:
        assert launcher.shm_domain_in_use(192)
        assert not launcher.shm_domain_in_use(191)
        assert not launcher.shm_domain_in_use(193)
    finally:
        lock.close()
    assert not launcher.shm_domain_in_use(192)
