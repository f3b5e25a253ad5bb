"""Multi-process tests of DDS Security (docs/SECURITY.md): the real deif_target and
deif_agent processes with PKI-DH authentication, access control by partition and AES-GCM
encryption, launched by deif.launcher with --secure (a CA, certificates and permissions of
the run's own), each on its own DDS domain. Hostile participants are deif_hostile with a
chosen identity: none, another CA's, or an identity of the run used for what it may not do.
"""
import datetime
import os
import re
import shutil
import signal
import struct
import subprocess
import time

from deif import artefacts, certs, launcher, paths

from test_processes import SLOW_CIRCLE, largest_difference, oracle, rows, steps_of

AGENT_FILES = (".cert.pem", ".key.pem", ".permissions.p7s")


# ----------------------------------------------------------------------------------------
def test_secure_equals_plain(work, domain):
    """A secure 4-agent lock-step run writes the same agent CSVs, byte for byte, as the same
    run without security; every process authenticated (its certificates were issued for the
    run) and nothing was rejected."""
    plain = launcher.run(SLOW_CIRCLE, os.path.join(work, "plain"), agents=4, steps=300,
                         domain=domain, progress=False)
    secure = launcher.run(SLOW_CIRCLE, os.path.join(work, "secure"), agents=4, steps=300,
                          domain=domain, progress=False, secure=True)
    assert plain.ok and secure.ok, (plain.why_not_ok(), secure.why_not_ok())
    assert secure.summary["security"]["enabled"] and not plain.summary["security"]["enabled"]
    assert secure.summary["config"]["network"]["security"]["enabled"] is True
    assert os.path.exists(os.path.join(secure.out_dir, "certs", "agent-4.permissions.p7s"))
    assert not os.path.exists(os.path.join(secure.out_dir, "certs", "ca.key.pem"))
    for j in range(1, 5):
        with open(os.path.join(plain.out_dir, f"agent_{j}.csv"), "rb") as f:
            a = f.read()
        with open(os.path.join(secure.out_dir, f"agent_{j}.csv"), "rb") as f:
            b = f.read()
        assert a.count(b"\n") == 301
        assert a == b, f"agent {j}: the secure run's CSV differs from the plain run's"
        assert all(r["fused"] == "4" for r in rows(secure.out_dir, j))
    for name, c in secure.summary["counters"].items():
        assert c["rejected"] == 0, (name, c)


# ----------------------------------------------------------------------------------------
def hostile_argv(lau, attack, *extra):
    return [paths.executable("deif_hostile"), "--config", lau.config_path, "--run", lau.run_name,
            "--attack", attack, "--follow", lau.out_dir, *extra]


# These runs are compared with the simulation, so a live agent must never look lost. On a
# busy 2-core machine every process was seen to report all its live peers lost at once, in
# secure and plain runs alike, with the default 0.4 s lease; and secure runs over shared
# memory twice stopped hearing each other for good, likely a Fast DDS deadlock when a peer
# is removed (docs/SECURITY.md, "Known limits"; not seen over UDPv4 in these tests).
# Failure detection and the transport are not what these tests are about.
LONG_LEASE = "network.liveliness_lease_s=3.0"
STALL_PROOF = [LONG_LEASE, "network.transport=udp"]


def stop_run(lau, wait_s=30.0):
    """SIGTERM to every process of the run at once; each writes its rows and counters and
    exits 0. A secure participant can take seconds to be deleted on a busy machine, longer
    than the launcher's own grace of 3 s: this waits up to wait_s before the launcher reaps
    what is left."""
    live = [p.popen for p in lau.procs.values() if p.popen is not None and p.popen.poll() is None]
    for popen in live:
        popen.send_signal(signal.SIGTERM)
    deadline = time.time() + wait_s
    for popen in live:
        try:
            popen.wait(max(0.1, deadline - time.time()))
        except subprocess.TimeoutExpired:
            pass
    lau.terminate_all()


def with_hostiles(work, domain, hostiles, at_step=30, after_steps=100, live=False):
    """A secure lock-step run with hostile peers started together at `at_step`. Each stays in
    the domain (--linger) once done, so that no participant leaves while the run is observed.
    When all are done, the run goes on for `after_steps` more steps and is then stopped
    (SIGTERM: every process writes its rows and counters and exits 0), so that the attack
    falls inside the run whatever the machine's speed. Returns (result, [(exit status,
    stdout, stderr)], the step the run was at when the hostiles were done). live: with the
    live view's observer."""
    lau = launcher.Launcher(SLOW_CIRCLE, os.path.join(work, "run"), agents=4, steps=100000,
                            domain=domain, progress=False, secure=True, overrides=STALL_PROOF)
    if live:
        lau.live_port = 0
    outcomes, procs = [], []
    try:
        lau.start()
        lau.wait_for_step(at_step)
        procs = [subprocess.Popen(make(lau) + ["--linger"], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True) for make in hostiles]
        for p in procs:
            out = ""
            while not re.search(r"^received \d+$", out, re.M):  # done, now lingering
                line = p.stdout.readline()
                assert line, f"the hostile peer ended early: {out[-800:]}"
                out += line
            outcomes.append(out)
        done_at = lau.current_step()
        lau.wait_for_step(done_at + after_steps)
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        stop_run(lau)
        res = lau.finish()
    results = []
    for p, out in zip(procs, outcomes):
        rest, err = p.communicate(timeout=60)
        results.append((p.returncode, out + rest, err))
    return res, results, done_at


def warnings(res, j):
    """Agent j's warnings and errors: why a step was fused without a member."""
    with open(os.path.join(res.out_dir, "logs", f"agent-{j}.log")) as f:
        return [line.strip() for line in f if "[warning]" in line or "[error]" in line][:10]


def received(out):
    return int(re.search(r"^received (\d+)$", out, re.M).group(1))


def sent(out):
    return int(re.search(r"^sent (\d+)", out, re.M).group(1))


def assert_unharmed(res, work, done_at):
    """Every process exited 0; every agent wrote every step from 1 without a gap, past the
    end of the attack; and every row equals the in-process simulation of the run's config
    bit for bit: nothing a hostile sent was fused or changed a roll call."""
    assert res.ok, res.why_not_ok()
    for j in range(1, 5):
        steps = steps_of(res.out_dir, j)
        assert steps == list(range(1, len(steps) + 1)), f"agent {j} skipped a step"
        assert steps[-1] > done_at, (j, steps[-1], done_at)
    worst, n = largest_difference(res.out_dir, oracle(res.out_dir), range(1, 5))
    assert n > 4 * done_at and worst == 0.0, f"largest difference from the oracle {worst:.3g}"


def test_unauthenticated_peers(work, domain):
    """A participant without certificates (as agent-9), and one with a complete set of
    another CA's (as agent-2), each claim agent 1 for every step and read every topic for
    4 s: neither receives one sample, no process counts one sample of theirs (nothing of
    theirs reaches an application, so nothing is fused), and the run completes with every
    step written. (Not that every agent equals the simulation: with the handshakes they keep
    attempting, the run's agents lost each other's liveliness for a moment in 2 of 2 runs on
    a loaded 2-core machine, which changes roll calls; docs/SECURITY.md, "Known limits".)"""
    foreign = os.path.join(work, "foreign")
    certs.ensure(foreign, agents=4, observers=0)
    # --peers 0: neither can match an agent, so neither waits for the agents' endpoints
    # (10 s) before it starts. The foreign one's start still takes its 5 participants
    # made anew, each after a handshake stalled for 3 s (docs/SECURITY.md, "Start-up").
    res, outcomes, done_at = with_hostiles(work, domain, [
        lambda lau: hostile_argv(lau, "impersonate", "--claim", "1", "--seconds", "4",
                                 "--security", "off", "--name", "agent-9", "--peers", "0"),
        lambda lau: hostile_argv(lau, "impersonate", "--claim", "1", "--seconds", "4",
                                 "--security", foreign, "--name", "agent-2", "--peers", "0"),
    ])
    for code, out, err in outcomes:
        assert code == 0, err[-800:]
        assert sent(out) > 0, out       # it did publish ...
        assert received(out) == 0, out  # ... and heard nothing
    for name, c in res.summary["counters"].items():
        assert c["rejected"] == 0 and c.get("dropped", 0) == 0, (name, c)  # the target has no drops
    assert res.ok, res.why_not_ok()
    for j in range(1, 5):
        steps = steps_of(res.out_dir, j)
        assert steps == list(range(1, len(steps) + 1)), f"agent {j} skipped a step"
        assert steps[-1] > done_at, (j, steps[-1], done_at)


def central_difference(res, work):
    """The largest difference, over every row of every agent, between the agents' estimate
    and the centralized EIF replayed over the ranges the target sent (ranges.csv: the ranges
    of each step's actual roll call); and the steps replayed."""
    central_csv = os.path.join(work, "central.csv")
    subprocess.run([paths.executable("deif_sim"), "--config", os.path.join(res.out_dir, "config.yaml"),
                    "--replay-ranges", os.path.join(res.out_dir, "ranges.csv"), "--replay-out",
                    central_csv, "--quiet"], check=True)
    central = {r["step"]: r for r in artefacts.read_csv(central_csv)}
    worst = 0.0
    for j in range(1, 5):
        for r in rows(res.out_dir, j):
            for k in ("x_est", "y_est", "p_xx", "p_xy", "p_yy"):
                worst = max(worst, abs(float(r[k]) - float(central[r["step"]][k])))
    return worst, len(central)


def test_claimed_id(work, domain):
    """An authenticated process with the run's agent-2 identity claims agent 3 (contributions
    and states, for the next step, every 10 ms) for 3 s. It is authenticated (it
    hears the run) and its samples reach the agents and the target, which refuse them as not
    authorised for id 3. None is fused: every agent wrote every step with every contribution
    of its roll call, all agree, and every estimate equals the centralized EIF replayed over
    the ranges the target actually sent, to 1e-9 (a forged contribution fused once would
    move it by far more). The live view's observer ignores the forged states too.

    Not compared with the simulation: the burst can evict agent 3's own state from the
    target's reader (keep-last per key) before it is read, so that agent 3 sits out a roll
    call (docs/SECURITY.md, "Known limits"): the run then differs from the simulation while
    no forged sample was fused."""
    res, outcomes, done_at = with_hostiles(work, domain, [
        lambda lau: hostile_argv(lau, "impersonate", "--claim", "3", "--seconds", "3",
                                 "--name", "agent-2"),
    ], live=True)
    code, out, err = outcomes[0]
    assert code == 0, err[-800:]
    assert sent(out) > 0 and received(out) > 0, out
    for name in ("agent_1", "agent_2", "agent_3", "agent_4", "target"):
        c = res.summary["counters"][name]
        refused = c["by_reason"].get("rejected: not_authorised", 0)
        # Each receiver saw some of them (not necessarily all: a busy receiver's keep-last
        # history drops part of a fast burst) and rejected nothing else.
        assert 0 < refused <= sent(out) and c["rejected"] == refused, (name, c)
    assert res.ok, res.why_not_ok()
    for j in range(1, 5):
        steps = steps_of(res.out_dir, j)
        assert steps == list(range(1, len(steps) + 1)), f"agent {j} skipped a step"
        assert steps[-1] > done_at, (j, steps[-1], done_at)
        incomplete = [r["step"] for r in rows(res.out_dir, j) if r["complete"] != "1"]
        assert not incomplete, (j, incomplete, warnings(res, j))
    assert res.summary["metrics"]["agreement_fraction"] == 1.0
    worst, replayed = central_difference(res, work)
    assert replayed > done_at
    assert worst <= 1e-9, f"largest difference from the centralized EIF {worst:.3g}"
    marks = artefacts.read_csv(os.path.join(res.out_dir, "observer_marks.csv"))
    assert any(m["kind"] == "ignored" and "not_authorised" in m["text"] for m in marks), marks


def test_roles(work, domain):
    """What a certificate's permissions refuse: the run's agent-2 identity cannot create a
    writer of ranges or of the truth (so it can neither measure an agent nor say anything
    about the world or the run's end), and the observer identity cannot create a writer of
    contributions or states; nothing of theirs arrives and the run equals the simulation."""
    res, outcomes, done_at = with_hostiles(work, domain, [
        lambda lau: hostile_argv(lau, "ranges", "--name", "agent-2"),
        lambda lau: hostile_argv(lau, "truth", "--name", "agent-2"),
        lambda lau: hostile_argv(lau, "contributions", "--name", "observer-1"),
    ])
    (c_ranges, o_ranges, _), (c_truth, o_truth, _), (c_obs, o_obs, _) = outcomes
    assert c_ranges == 3 and "refused deif/range" in o_ranges and sent(o_ranges) == 0
    assert c_truth == 3 and "refused deif/truth" in o_truth and sent(o_truth) == 0
    assert c_obs == 3 and "refused deif/contribution" in o_obs and sent(o_obs) == 0
    # The control: the same agent identity may publish its contributions and states; the
    # observer's may publish nothing.
    for out in (o_ranges, o_truth):
        assert "refused deif/contribution" not in out and "refused deif/agent_state" not in out
    assert "refused deif/agent_state" in o_obs
    for name, c in res.summary["counters"].items():
        assert c["rejected"] == 0, (name, c)
    assert_unharmed(res, work, done_at)


# ----------------------------------------------------------------------------------------
def capture(work, domain, name, secure, certs_dir=None):
    """A run captured with tcpdump on every interface, UDP ports of the domain only (the
    transport is UDPv4, so every sample crosses the capture); returns (result, pcap bytes).
    certs_dir: the certificates to use instead of the run's own."""
    pcap = os.path.join(work, f"{name}.pcap")
    base = 7400 + 250 * domain  # RTPS port mapping: PB + DG * domain
    tcpdump = subprocess.Popen(["tcpdump", "-i", "any", "-U", "-s", "0", "-w", pcap, "udp",
                                "portrange", f"{base}-{base + 249}"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while "listening on" not in tcpdump.stderr.readline():
            assert tcpdump.poll() is None, "tcpdump could not start"
        res = launcher.run(SLOW_CIRCLE, os.path.join(work, name), agents=4, steps=150,
                           domain=domain, progress=False, secure=secure, certs_dir=certs_dir,
                           overrides=["network.transport=udp"])
        time.sleep(0.5)
    finally:
        tcpdump.send_signal(signal.SIGINT)
        tcpdump.wait(timeout=10)
    with open(pcap, "rb") as f:
        return res, f.read()


def plaintext_values(run_dir):
    """The doubles the processes put on the wire, as little-endian IEEE bytes: each agent's
    position (its state, and p_j in its contributions) and every range the target sent. The
    CSVs print 17 significant digits, so each parses back to the exact double."""
    values = set()
    for j in range(1, 5):
        for r in rows(run_dir, j):
            values.update((float(r["pos_x"]), float(r["pos_y"])))
    for r in artefacts.read_csv(os.path.join(run_dir, "ranges.csv")):
        values.add(float(r["range"]))
    values.discard(0.0)
    return [struct.pack("<d", v) for v in values]


def test_wire_encrypted(work, domain):
    """On the wire no payload is readable: of the doubles the processes sent (positions and
    ranges, from their CSVs), a capture of a plain run holds most; a capture of the same
    secure run holds none, with the default governance and with `deif-certs --submessages
    none` (docs/SECURITY.md, "Submessage protection"), which leaves the submessages
    unsigned but still encrypts every payload."""
    plain, plain_pcap = capture(work, domain, "plain", secure=False)
    assert plain.ok, plain.why_not_ok()
    plain_values = plaintext_values(plain.out_dir)
    assert len(plain_values) > 500
    found_plain = sum(1 for v in plain_values if v in plain_pcap)
    print(f"plain: {found_plain} of {len(plain_values)} values on the wire ({len(plain_pcap)} bytes)")
    assert found_plain >= 0.5 * len(plain_values)   # the search finds plaintext when it is there
    unsigned = os.path.join(work, "certs-submessages-none")
    certs.ensure(unsigned, agents=4, observers=0, submessages="NONE")
    with open(os.path.join(unsigned, "governance.xml")) as f:
        assert "<metadata_protection_kind>NONE</metadata_protection_kind>" in f.read()
    for name, certs_dir in (("secure", None), ("submessages-none", unsigned)):
        secure, secure_pcap = capture(work, domain, name, secure=True, certs_dir=certs_dir)
        assert secure.ok, (name, secure.why_not_ok())
        secure_values = plaintext_values(secure.out_dir)
        assert len(secure_values) > 500
        found_secure = [v for v in secure_values if v in secure_pcap]
        print(f"{name}: {len(found_secure)} of {len(secure_values)} values on the wire "
              f"({len(secure_pcap)} bytes)")
        assert len(secure_pcap) > len(plain_pcap) // 2, name  # the secure run was captured as well
        assert found_secure == [], name


# ----------------------------------------------------------------------------------------
def start_agent(run_dir, certs_dir, domain):
    """deif_agent 1 with the security files in certs_dir; (exit status, stderr)."""
    p = subprocess.run([paths.executable("deif_agent"), "--config", SLOW_CIRCLE, "--id", "1",
                        "--domain", str(domain), "--out", run_dir,
                        "--set", "network.security.enabled=true",
                        "--set", f"network.security.dir={certs_dir}"],
                       capture_output=True, text=True, timeout=30)
    return p.returncode, p.stderr


def expired_certificate(certs_dir, name):
    """Replaces <name>.cert.pem with a certificate of the same key and subject, signed by
    the same CA, that expired yesterday (the cryptography package sets any dates)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization

    def load(path, kind):
        with open(path, "rb") as f:
            data = f.read()
        return (x509.load_pem_x509_certificate(data) if kind == "cert"
                else serialization.load_pem_private_key(data, None))
    ca = load(os.path.join(certs_dir, "ca.pem"), "cert")
    ca_key = load(os.path.join(certs_dir, "ca.key.pem"), "key")
    old = load(os.path.join(certs_dir, f"{name}.cert.pem"), "cert")
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(old.subject).issuer_name(ca.subject)
            .public_key(old.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(days=30))
            .not_valid_after(now - datetime.timedelta(days=1))
            .sign(ca_key, hashes.SHA256()))
    with open(os.path.join(certs_dir, f"{name}.cert.pem"), "wb") as f:
        f.write(cert.public_bytes(serialization.Encoding.PEM))


def test_bad_files(work, domain):
    """A process whose security files are missing or bad exits 2 at start with one line that
    names the file and the reason: a missing certificate, an expired one, one from another CA,
    unsigned permissions, permissions for another identity; with good files it starts."""
    good = os.path.join(work, "good")
    certs.ensure(good, agents=2, observers=0)
    other_ca = os.path.join(work, "other")
    certs.ensure(other_ca, agents=2, observers=0)

    def case(name, spoil):
        d = os.path.join(work, name)
        shutil.copytree(good, d)
        spoil(d)
        code, err = start_agent(os.path.join(work, name + "-run"), d, domain)
        lines = [l for l in err.splitlines() if l.strip()]
        assert code == 2, (name, code, err[-800:])
        assert len(lines) == 1, (name, lines)
        return lines[0]

    line = case("missing", lambda d: os.unlink(os.path.join(d, "agent-1.cert.pem")))
    assert "agent-1.cert.pem" in line and "missing" in line, line

    line = case("expired", lambda d: expired_certificate(d, "agent-1"))
    assert "agent-1.cert.pem" in line and "expired" in line, line

    def foreign(d):
        for suffix in (".cert.pem", ".key.pem"):
            shutil.copy(os.path.join(other_ca, "agent-1" + suffix), os.path.join(d, "agent-1" + suffix))
    line = case("foreign", foreign)
    assert "agent-1.cert.pem" in line and "not issued by the CA" in line, line

    line = case("unsigned", lambda d: shutil.copy(os.path.join(d, "agent-1.permissions.xml"),
                                                  os.path.join(d, "agent-1.permissions.p7s")))
    assert "agent-1.permissions.p7s" in line and "not an S/MIME signed document" in line, line

    line = case("swapped", lambda d: shutil.copy(os.path.join(d, "agent-2.permissions.p7s"),
                                                 os.path.join(d, "agent-1.permissions.p7s")))
    assert "agent-1.permissions.p7s" in line and "grants nothing to 'CN=agent-1,O=deif'" in line, line

    # The control: the same start with the good files gets past the checks (it then waits
    # for a target; stopped after 2 s, it exits 0 having written its CSV header).
    run_dir = os.path.join(work, "good-run")
    p = subprocess.Popen([paths.executable("deif_agent"), "--config", SLOW_CIRCLE, "--id", "1",
                          "--domain", str(domain), "--out", run_dir,
                          "--set", "network.security.enabled=true",
                          "--set", f"network.security.dir={good}"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(2.0)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 0, err[-800:]
    assert os.path.exists(os.path.join(run_dir, "agent_1.csv"))


def test_live_observer(work, domain):
    """deif-run --secure --live: the observer authenticates as observer-1 (its own
    certificate, not the process name's), reads the secure run and ends with status 0; its
    per-step figures cover every step with all four agents alive and the error of agent 1,
    the lowest live id, against the truth."""
    res = launcher.run(SLOW_CIRCLE, os.path.join(work, "run"), agents=4, steps=60, domain=domain,
                       progress=False, secure=True, live=0)
    assert res.ok, res.why_not_ok()
    observer = next(p for p in res.summary["processes"] if p["name"] == "observer")
    assert observer["exit_status"] == 0, observer
    live = {int(r["step"]): r for r in artefacts.read_csv(os.path.join(res.out_dir, "observer.csv"))}
    assert sorted(live) == list(range(1, 61))
    assert all(int(r["alive"]) == 4 for r in live.values())
    truth = {int(r["step"]): r for r in artefacts.read_csv(os.path.join(res.out_dir, "target.csv"))}
    agent_1 = {int(r["step"]): r for r in rows(res.out_dir, 1)}
    with_estimate = [k for k, r in live.items() if r["agent"] == "1"]
    assert len(with_estimate) >= 48, f"only {len(with_estimate)} of 60 steps with an estimate"
    for k in with_estimate:
        err = ((float(agent_1[k]["x_est"]) - float(truth[k]["x_true"])) ** 2
               + (float(agent_1[k]["y_est"]) - float(truth[k]["y_true"])) ** 2) ** 0.5
        assert abs(float(live[k]["error"]) - err) <= 1e-12 * max(1.0, err), k


# ----------------------------------------------------------------------------------------
def up_time(log_path):
    """When a process's log says it is up, in Unix seconds (the log's local time)."""
    with open(log_path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if " up: run " in line:
                stamp = line[1:line.index("]")]
                return datetime.datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S.%f").timestamp()
    return None


def test_sixteen_agents(work, domain):
    """A secure lock-step run of 16 agents starts with all of them and every agent fuses all
    16 at every step. Started all at once, such runs stalled in Fast DDS's handshakes and
    began with 3 or 4 agents (docs/SECURITY.md, "Start-up"): the launcher starts each agent
    once the previous one's log says it is up. With the security tests' 3 s lease: on a busy
    2-core machine a secure agent starved for more than the default 0.4 s lease is taken for
    lost and a step is fused without it (docs/SECURITY.md, "Known limits")."""
    res = launcher.run(SLOW_CIRCLE, os.path.join(work, "run"), agents=16, steps=40, domain=domain,
                       progress=False, secure=True, overrides=[LONG_LEASE])
    assert res.ok, res.why_not_ok()
    assert res.summary["metrics"]["final_agents"] == 16
    for j in range(1, 17):
        assert steps_of(res.out_dir, j) == list(range(1, 41)), j
        short = [r["step"] for r in rows(res.out_dir, j) if r["fused"] != "16"]
        assert not short, (j, short, warnings(res, j))
    started = {p["name"]: p["started_unix_s"] for p in res.summary["processes"]}
    for j in range(1, 16):
        up = up_time(os.path.join(res.out_dir, "logs", f"agent-{j}.log"))
        assert up is not None, j
        # The log's time is cut to milliseconds. The launcher waits at most 30 s for a
        # process to be up, then starts the next anyway (in CI an agent whose authentication
        # stalled 5 times at start took 35 s).
        due = min(up, started[f"agent_{j}"] + 30.0)
        assert started[f"agent_{j + 1}"] >= due - 0.002, f"agent {j + 1} started before agent {j} was up"


def test_agents_sched(work, domain):
    """A secure run's agents start under SCHED_OTHER and get SCHED_BATCH, every thread, at the
    run's first step; an agent restarted later gets it once it is up. With the agents under
    SCHED_BATCH from their start, the handshakes of a secure start stalled again and again
    (16 agents: 2 of 2 starts left agents that never heard each other; docs/RUNNING.md, "CPU
    scheduling")."""
    lau = launcher.Launcher(SLOW_CIRCLE, os.path.join(work, "run"), agents=3, steps=3000,
                            domain=domain, progress=False, secure=True, overrides=[LONG_LEASE])

    def policies(name):
        pid = lau.procs[name].popen.pid
        tasks = os.listdir(f"/proc/{pid}/task")
        assert len(tasks) > 3, name  # Fast DDS's threads are up
        return {os.sched_getscheduler(int(t)) for t in tasks}

    agents = [f"agent_{j}" for j in (1, 2, 3)]
    try:
        lau.start()  # returns once every agent is up, before the run's first step
        at_start = {a: policies(a) for a in agents}
        lau.wait_for_step(5)
        running = {a: policies(a) for a in agents}
        lau.restart_agent(2)
        p = lau.procs["agent_2"]
        deadline = time.time() + 120
        while not lau._is_up(p) and time.time() < deadline:
            lau.service()
            time.sleep(0.1)
        up = lau._is_up(p)
        restarted = set()
        while time.time() < deadline:  # the launcher gives it its policy when it sees it up
            lau.service()
            restarted = policies("agent_2")
            if restarted == {os.SCHED_BATCH}:
                break
            time.sleep(0.1)
        target = policies("target")
    finally:
        lau.terminate_all()
        lau.finish()
    assert at_start == {a: {os.SCHED_OTHER} for a in agents}, at_start
    assert running == {a: {os.SCHED_BATCH} for a in agents}, running
    assert up, "the restarted agent never said it was up"
    assert restarted == {os.SCHED_BATCH}, restarted
    assert target == {os.sched_getscheduler(0)}, target
