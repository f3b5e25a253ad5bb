"""Certificates for DDS Security (docs/SECURITY.md), made with the openssl command line.

One folder holds everything a network needs:

    ca.pem, ca.key.pem                the CA (prime256v1); it signs every other file
    governance.xml, governance.p7s    the domain's rules, and the same S/MIME-signed
    <name>.key.pem, <name>.cert.pem   one identity per process: target, agent-<J>, observer-<M>
    <name>.permissions.xml, .p7s      what that identity may publish and read, signed

Idempotent: the CA is kept; a file that is missing, no longer valid (expired, not the
CA's, not matching its key) or different from what the arguments ask for is issued again;
everything else is kept. The CA's private key signs; keep it off the hosts (docs/SECURITY.md).
"""
import datetime
import os
import re
import secrets
import subprocess
import tempfile

from . import paths

CA_SUBJECT = "/O=deif/CN=deif network CA"
CA_DAYS_MIN = 3650          # the CA outlives the certificates it signs
MAX_AGENTS = 512            # agents.count's range
RUN_NAME = re.compile(r"^[A-Za-z0-9._-]{1,64}$")

TOPIC_TRUTH = "deif/truth"
TOPIC_RANGE = "deif/range"
TOPIC_CONTRIBUTION = "deif/contribution"
TOPIC_STATE = "deif/agent_state"

CA_EXTENSIONS = """[ca]
basicConstraints = critical, CA:TRUE
keyUsage = critical, keyCertSign, cRLSign, digitalSignature
subjectKeyIdentifier = hash
"""
IDENTITY_EXTENSIONS = """[identity]
basicConstraints = critical, CA:FALSE
keyUsage = critical, digitalSignature, keyAgreement
subjectKeyIdentifier = hash
authorityKeyIdentifier = keyid
"""
REQ_CONFIG = """[req]
distinguished_name = dn
prompt = no
[dn]
"""


class CertsError(Exception):
    """A refusal; str() is one line."""


def identities(agents, observers):
    return (["target"] + [f"agent-{j}" for j in range(1, agents + 1)]
            + [f"observer-{m}" for m in range(1, observers + 1)])


def openssl(*args, stdin=None):
    """Runs openssl; its stdout, or CertsError with openssl's last line."""
    try:
        proc = subprocess.run(["openssl", *args], input=stdin, capture_output=True, text=True)
    except FileNotFoundError:
        raise CertsError("the openssl command is missing (scripts/setup-deps installs it)")
    if proc.returncode != 0:
        lines = [l for l in (proc.stderr or proc.stdout).splitlines() if l.strip()]
        raise CertsError(f"openssl {args[0]}: {lines[-1] if lines else f'exit {proc.returncode}'}")
    return proc.stdout


def works(*args):
    """Whether an openssl command succeeds (a check, not an action)."""
    return subprocess.run(["openssl", *args], capture_output=True).returncode == 0


def subject_rfc2253(cert):
    """The certificate's subject as Fast DDS compares it with a grant (RFC 2253)."""
    return openssl("x509", "-in", cert, "-noout", "-subject", "-nameopt", "RFC2253") \
        .strip().removeprefix("subject=")


def public_key(path, of_certificate):
    if of_certificate:
        return openssl("x509", "-in", path, "-noout", "-pubkey")
    return openssl("pkey", "-in", path, "-pubout")


def key_matches(key, cert):
    try:
        return public_key(key, False) == public_key(cert, True)
    except CertsError:
        return False


def signed_text(p7s, ca):
    """The text of an S/MIME document if it verifies against the CA, else None."""
    proc = subprocess.run(["openssl", "smime", "-verify", "-in", p7s, "-CAfile", ca, "-text"],
                          capture_output=True, text=True)
    return proc.stdout if proc.returncode == 0 else None


def write_private(path, text):
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def new_key(path):
    write_private(path, openssl("genpkey", "-algorithm", "EC", "-pkeyopt",
                                "ec_paramgen_curve:prime256v1"))


def iso(t):
    return t.strftime("%Y-%m-%dT%H:%M:%S")


# ---------------------------------------------------------------------------------------
# The documents
SUBMESSAGE_PROTECTION = ("SIGN", "ENCRYPT", "NONE")  # metadata_protection_kind


def governance_xml(submessages="SIGN", payloads="ENCRYPT"):
    """Discovery, liveliness and data protected; nobody unauthenticated; payloads encrypted;
    every submessage of the user topics (data, heartbeat, acknowledgement, gap) signed,
    encrypted or left as it is (`submessages`; docs/SECURITY.md, "Submessage protection").
    payloads="NONE" leaves the payloads readable: for measuring what the encryption costs
    (the security benchmark, docs/BENCHMARKS.md), never offered on the command line."""
    if submessages not in SUBMESSAGE_PROTECTION:
        raise CertsError(f"--submessages {submessages.lower()}: must be one of "
                         + ", ".join(k.lower() for k in SUBMESSAGE_PROTECTION))
    if payloads not in ("ENCRYPT", "NONE"):
        raise CertsError(f"payloads {payloads}: must be ENCRYPT or NONE")
    return """<?xml version="1.0" encoding="UTF-8"?>
<!-- deif-network governance (docs/SECURITY.md), made by scripts/deif-certs -->
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains>
        <id_range><min>0</min><max>232</max></id_range>
      </domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>NONE</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>%s</metadata_protection_kind>
          <data_protection_kind>%s</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
""" % (submessages, payloads)


def criteria(kind, topics, partitions):
    t = "".join(f"<topic>{x}</topic>" for x in topics)
    p = "".join(f"<partition>{x}</partition>" for x in partitions)
    return (f"        <{kind}>\n          <topics>{t}</topics>\n"
            f"          <partitions>{p}</partitions>\n        </{kind}>\n")


def grant_rules(name, run):
    """Least privilege (docs/SECURITY.md): the target publishes the truth and the ranges in
    its own partition; agent J its contributions and states in partition ...agent.J only;
    an observer publishes nothing. Everybody reads the run's partitions."""
    reads = [f"deif.{run}.*" if run else "deif.*"]
    run = run or "*"
    if name == "target":
        return (criteria("publish", [TOPIC_TRUTH, TOPIC_RANGE], [f"deif.{run}.target"])
                + criteria("subscribe", [TOPIC_STATE, TOPIC_RANGE], reads))
    if name.startswith("agent-"):
        j = name[len("agent-"):]
        return (criteria("publish", [TOPIC_CONTRIBUTION, TOPIC_STATE], [f"deif.{run}.agent.{j}"])
                + criteria("subscribe", [TOPIC_RANGE, TOPIC_CONTRIBUTION, TOPIC_STATE], reads))
    return criteria("subscribe", [TOPIC_TRUTH, TOPIC_RANGE, TOPIC_CONTRIBUTION, TOPIC_STATE], reads)


VALIDITY = re.compile(r"<validity>.*?</validity>", re.S)


def permissions_xml(name, subject, not_before, not_after, run):
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- permissions of {name} (docs/SECURITY.md), made by scripts/deif-certs -->
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="{name}">
      <subject_name>{subject}</subject_name>
      <validity><not_before>{iso(not_before)}</not_before><not_after>{iso(not_after)}</not_after></validity>
      <allow_rule>
        <domains>
          <id_range><min>0</min><max>232</max></id_range>
        </domains>
{grant_rules(name, run)}      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
"""


# ---------------------------------------------------------------------------------------
class Issuer:
    def __init__(self, folder, days, log):
        self.dir = folder
        self.days = days
        self.log = log
        self.ca = os.path.join(folder, "ca.pem")
        self.ca_key = os.path.join(folder, "ca.key.pem")
        self.issued, self.kept = [], []
        self.tmp = tempfile.mkdtemp(prefix="deif-certs-")

    def path(self, name):
        return os.path.join(self.dir, name)

    def conf(self, name, text):
        p = os.path.join(self.tmp, name)
        with open(p, "w") as f:
            f.write(text)
        return p

    def note(self, what, why=None):
        (self.issued if why else self.kept).append(what)
        if why:
            self.log(f"issued {what} ({why})")

    # -- the CA
    def ensure_ca(self):
        have_cert, have_key = os.path.exists(self.ca), os.path.exists(self.ca_key)
        if have_cert and have_key:
            if not works("x509", "-in", self.ca, "-noout", "-checkend", "0"):
                raise CertsError(f"{self.ca}: the CA is unreadable or expired; move ca.pem and "
                                 "ca.key.pem away to start a new CA (every file is then issued again)")
            if not key_matches(self.ca_key, self.ca):
                raise CertsError(f"{self.ca_key}: is not the key of {self.ca}")
            self.note("ca.pem")
            return False
        if have_cert != have_key:
            present, missing = (self.ca, self.ca_key) if have_cert else (self.ca_key, self.ca)
            raise CertsError(f"{missing}: missing while {present} exists; restore it, or move "
                             "both away to start a new CA")
        new_key(self.ca_key)
        req = self.conf("ca.cnf", REQ_CONFIG + "O = deif\nCN = deif network CA\n" + CA_EXTENSIONS)
        openssl("req", "-x509", "-new", "-config", req, "-extensions", "ca", "-key", self.ca_key,
                "-sha256", "-days", str(max(self.days, CA_DAYS_MIN)), "-set_serial",
                "0x" + secrets.token_hex(8), "-out", self.ca)
        self.note("ca.pem", "a new CA")
        return True

    # -- one identity
    def ensure_identity(self, name, new_ca):
        key, cert = self.path(f"{name}.key.pem"), self.path(f"{name}.cert.pem")
        why = None
        if new_ca:
            why = "new CA"
        elif not os.path.exists(cert) or not os.path.exists(key):
            why = "missing"
        elif not works("verify", "-CAfile", self.ca, cert):
            why = "not issued by this CA, or expired"
        elif not works("x509", "-in", cert, "-noout", "-checkend", "86400"):
            why = "expires within a day"
        elif not key_matches(key, cert):
            why = "the key does not match"
        elif subject_rfc2253(cert) != f"CN={name},O=deif":
            why = "another subject"
        if why is None:
            self.note(f"{name}.cert.pem")
            return False
        new_key(key)
        csr = os.path.join(self.tmp, f"{name}.csr")
        req = self.conf(f"{name}.cnf", REQ_CONFIG + f"O = deif\nCN = {name}\n")
        openssl("req", "-new", "-config", req, "-key", key, "-out", csr)
        ext = self.conf("identity.cnf", IDENTITY_EXTENSIONS)
        openssl("x509", "-req", "-in", csr, "-CA", self.ca, "-CAkey", self.ca_key, "-sha256",
                "-days", str(self.days), "-set_serial", "0x" + secrets.token_hex(8),
                "-extfile", ext, "-extensions", "identity", "-out", cert)
        self.note(f"{name}.cert.pem", why)
        return True

    # -- signed documents
    def ensure_signed(self, base, text, renew=None, same=lambda old, new: old == new):
        """<base>.xml and <base>.p7s: kept when the signed text verifies and equals `text`
        (by `same`) and there is no reason `renew`; else written and signed."""
        xml, p7s = self.path(f"{base}.xml"), self.path(f"{base}.p7s")
        why = renew
        if why is None:
            if not os.path.exists(p7s):
                why = "missing"
            else:
                signed = signed_text(p7s, self.ca)
                if signed is None:
                    why = "its signature does not verify against this CA"
                elif not same(signed.replace("\r\n", "\n"), text):
                    why = "changed"
        if why is None:
            self.note(f"{base}.p7s")
            return
        with open(xml, "w") as f:
            f.write(text)
        openssl("smime", "-sign", "-text", "-in", xml, "-out", p7s, "-signer", self.ca,
                "-inkey", self.ca_key)
        self.note(f"{base}.p7s", why)


def ensure(folder, agents, observers=1, days=365, run=None, log=None, submessages="SIGN",
           payloads="ENCRYPT"):
    """Makes `folder` hold a CA and every file of target, agent-1..agent-N and
    observer-1..M (see the module's docstring), with the governance of `submessages` and
    `payloads`. Returns {"issued": [...], "kept": [...]}. Raises CertsError (one line)."""
    log = log or (lambda msg: None)
    governance = governance_xml(submessages, payloads)
    if not 1 <= agents <= MAX_AGENTS:
        raise CertsError(f"--agents {agents}: must be in 1..{MAX_AGENTS}")
    if not 0 <= observers <= 64:
        raise CertsError(f"--observers {observers}: must be in 0..64")
    if not 1 <= days <= 36500:
        raise CertsError(f"--days {days}: must be in 1..36500")
    if run is not None and not RUN_NAME.match(run):
        raise CertsError(f"--run {run}: a run name is 1..64 characters of letters, digits, "
                         "'.', '_' and '-'")
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
    except OSError as e:
        raise CertsError(f"{folder}: cannot create the folder ({e.strerror})")
    if not os.access(folder, os.W_OK):
        raise CertsError(f"{folder}: not writable")
    issuer = Issuer(folder, days, log)
    try:
        new_ca = issuer.ensure_ca()
        issuer.ensure_signed("governance", governance, "new CA" if new_ca else None)
        now = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0, tzinfo=None)
        # A day's margin before: Fast DDS reads the validity in local time.
        not_before, not_after = now - datetime.timedelta(days=1), now + datetime.timedelta(days=days)
        for name in identities(agents, observers):
            new_cert = issuer.ensure_identity(name, new_ca)
            subject = subject_rfc2253(issuer.path(f"{name}.cert.pem"))
            text = permissions_xml(name, subject, not_before, not_after, run)

            def same(old, new):  # the same grant, still valid tomorrow
                m = re.search(r"<not_after>([^<]+)</not_after>", old)
                return (VALIDITY.sub("", old) == VALIDITY.sub("", new) and m is not None
                        and m.group(1) > iso(now + datetime.timedelta(days=1)))
            renew = "new CA" if new_ca else "new certificate" if new_cert else None
            issuer.ensure_signed(f"{name}.permissions", text, renew, same)
    finally:
        for f in os.listdir(issuer.tmp):
            os.unlink(os.path.join(issuer.tmp, f))
        os.rmdir(issuer.tmp)
    return {"issued": issuer.issued, "kept": issuer.kept}


def script():
    return os.path.join(paths.ROOT, "scripts", "deif-certs")
