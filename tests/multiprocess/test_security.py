"""Multi-process tests of DDS Security (docs/SECURITY.md): the real deif_target and
deif_agent processes with PKI-DH authentication, access control by partition and AES-GCM
encryption, launched by deif.launcher with --secure (a CA, certificates and permissions of
the run's own), each on its own DDS domain.
"""
import datetime
import os
import shutil
import signal
import struct
import subprocess
import time

from deif import artefacts, certs, launcher, paths

from test_processes import SLOW_CIRCLE, rows

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
    assert plain.ok and secure.ok, (plain.summary["processes"], secure.summary["processes"])
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
def capture(work, domain, name, secure):
    """A run captured with tcpdump on every interface, UDP ports of the domain only (the
    transport is UDPv4, so every sample crosses the capture); returns (result, pcap bytes)."""
    pcap = os.path.join(work, f"{name}.pcap")
    base = 7400 + 250 * domain  # RTPS port mapping: PB + DG * domain
    tcpdump = subprocess.Popen(["tcpdump", "-i", "any", "-U", "-s", "0", "-w", pcap, "udp",
                                "portrange", f"{base}-{base + 249}"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while "listening on" not in tcpdump.stderr.readline():
            assert tcpdump.poll() is None, "tcpdump could not start"
        res = launcher.run(SLOW_CIRCLE, os.path.join(work, name), agents=4, steps=150,
                           domain=domain, progress=False, secure=secure,
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
    secure run holds none."""
    plain, plain_pcap = capture(work, domain, "plain", secure=False)
    secure, secure_pcap = capture(work, domain, "secure", secure=True)
    assert plain.ok and secure.ok
    plain_values = plaintext_values(plain.out_dir)
    secure_values = plaintext_values(secure.out_dir)
    assert len(plain_values) > 500 and len(secure_values) > 500
    found_plain = sum(1 for v in plain_values if v in plain_pcap)
    found_secure = [v for v in secure_values if v in secure_pcap]
    print(f"plain: {found_plain} of {len(plain_values)} values on the wire "
          f"({len(plain_pcap)} bytes); secure: {len(found_secure)} of {len(secure_values)} "
          f"({len(secure_pcap)} bytes)")
    assert found_plain >= 0.5 * len(plain_values)   # the search finds plaintext when it is there
    assert len(secure_pcap) > len(plain_pcap) // 2  # the secure run was captured as well
    assert found_secure == []


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
