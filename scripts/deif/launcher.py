"""Launch a target and N agents as separate OS processes, on this host or on K
network-namespace hosts, apply scripted faults on their exact step, and collect one run
folder (docs/RUNNING.md, docs/ARTEFACTS.md).

Faults: the target is started with --hold-for-faults. In lock-step it stops before a step
with faults and prints "hold K"; the launcher applies them (kill -9, SIGSTOP, SIGCONT,
restart) and answers "go K"; the target then waits until the network sees the fault (a
killed agent lost, a resumed one caught up) before it publishes step K. So a faulted
lock-step run is reproducible bit for bit from its seed. In real time the target goes on
and the launcher applies the faults as soon as it reads "hold K".

Every process dies with the launcher (SIGKILL on parent death), on every path.
"""
import datetime
import json
import math
import os
import queue
import random
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

from . import artefacts, certs as certs_mod, config as cfg, hosts as hosts_mod, paths

SHM_DIR = "/dev/shm"
SHM_PREFIXES = ("fastrtps_", "sem.fastrtps_", "fast_datasharing_")
FAULT_ACTIONS = ("kill", "stop", "cont", "restart_target")


class LaunchError(Exception):
    """Bad arguments or config: nothing was started. str() is one line."""


class Interrupted(Exception):
    def __init__(self, signum):
        super().__init__(f"signal {signum}")
        self.signum = signum


@dataclass
class Fault:
    step: int
    action: str
    agent: int = None
    origin: str = "config"        # "config", or the command-line flag that asked for it
    applied_unix_s: float = None
    applied_at_step: int = None

    @staticmethod
    def parse(text, action):
        """'STEP:ID' for agent faults, 'STEP' for restart_target."""
        flag = "--" + action.replace("_", "-")
        try:
            if action == "restart_target":
                return Fault(int(text), action, None, f"{flag} {text}")
            step, agent = text.split(":")
            return Fault(int(step), action, int(agent), f"{flag} {text}")
        except ValueError:
            want = "STEP" if action == "restart_target" else "STEP:ID"
            raise LaunchError(f"{flag} {text}: expected {want} (integers)")

    def as_config(self):
        entry = {"step": self.step, "action": self.action}
        if self.action != "restart_target":
            entry["agent"] = self.agent
        return entry


@dataclass
class Partition:
    step: int
    seconds: float
    host: int
    cut_unix_s: float = None
    cut_at_step: int = None
    healed_unix_s: float = None
    healed_at_step: int = None

    @staticmethod
    def parse(text):
        try:
            step, seconds, host = text.split(":")
            p = Partition(int(step), float(seconds), int(host))
        except ValueError:
            raise LaunchError(f"--partition {text}: expected STEP:SECONDS:HOST")
        if p.step < 1 or not (0 < p.seconds < 3600) or p.host < 1:
            raise LaunchError(f"--partition {text}: need STEP >= 1, 0 < SECONDS < 3600, HOST >= 1")
        return p


@dataclass
class Proc:
    name: str
    argv: list
    host: int = 1
    popen: subprocess.Popen = None
    log_path: str = ""
    expected_death: bool = False  # killed on purpose by a scripted fault
    stopped: bool = False
    exit_status: int = None
    restarts: int = 0
    started_unix_s: float = None  # when it was (last) started
    log_offset: int = 0  # the size of its log when it was (last) started


@dataclass
class RunResult:
    out_dir: str
    ok: bool
    summary: dict = field(default_factory=dict)

    def why_not_ok(self, lines=6):
        """Why the run is not ok, in a few lines: each process that ended unexpectedly with its
        exit status and the last error or warning lines of its log, an interruption, a
        non-finite estimate. Empty when the run is ok."""
        why = []
        if self.summary.get("interrupted_by_signal"):
            why.append(f"interrupted by signal {self.summary['interrupted_by_signal']}")
        for p in self.summary.get("processes", []):
            if p.get("expected", True):
                continue
            why.append(f"{p['name']} (host {p.get('host')}) ended with status {p['exit_status']}, "
                       f"restarts {p.get('restarts')}, in place {p.get('restarts_in_place')}:")
            try:
                with open(os.path.join(self.out_dir, p["log"]), encoding="utf-8", errors="replace") as f:
                    bad = [line.rstrip() for line in f if "[error]" in line or "[warning]" in line]
                why.extend("  " + line[:300] for line in bad[-lines:])
            except OSError as e:
                why.append(f"  (no log: {e.strerror})")
        if self.summary.get("metrics", {}).get("non_finite_estimates"):
            why.append("an estimate was not finite (NaN or inf)")
        return "\n".join(why)


# The run's Discovery Server (deif-run --discovery-server): a server over UDPv4 only.
DISCOVERY_SERVER_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <transport_descriptors>
      <transport_descriptor><transport_id>udp</transport_id><type>UDPv4</type></transport_descriptor>
    </transport_descriptors>
    <participant profile_name="deif_discovery_server" is_default_profile="true">
      <rtps>
        <userTransports><transport_id>udp</transport_id></userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
        <builtin>
          <discovery_config><discoveryProtocol>SERVER</discoveryProtocol></discovery_config>
        </builtin>
      </rtps>
    </participant>
  </profiles>
</dds>
"""


# glibc's sem_open makes a named semaphore as a temporary file "sem.XXXXXX" (6 letters or
# digits), links it to its name and removes the temporary one; a process killed in between
# (kill -9 while Fast DDS opens a port's mutex) leaves the temporary file behind.
SEM_TEMPORARY = re.compile(r"sem\.[A-Za-z0-9]{6}")


def shm_snapshot():
    try:
        return {n for n in os.listdir(SHM_DIR)
                if n.startswith(SHM_PREFIXES) or SEM_TEMPORARY.fullmatch(n)}
    except OSError:
        return set()


def _shm_family(name):
    """The Fast DDS object a /dev/shm file belongs to: a port or a segment (the file that is
    mapped), its lock file (_el, _sl: held open with flock, never mapped) and its named mutex
    (sem.*_mutex: mapped only while in use) share it."""
    if name.startswith("sem."):
        name = name[len("sem."):]
    for suffix in ("_mutex", "_el", "_sl"):
        if name.endswith(suffix):
            return name[:-len(suffix)]
    return name


def _shm_in_use():
    """Families of /dev/shm files that some live process maps or holds open."""
    used = set()
    prefix = SHM_DIR + "/"
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/maps") as f:
                for line in f:
                    i = line.find(prefix)
                    if i >= 0:
                        used.add(_shm_family(os.path.basename(line[i:].strip())))
        except OSError:
            continue
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith(prefix):
                used.add(_shm_family(target[len(prefix):].removesuffix(" (deleted)")))
    return used


def shm_domain_in_use(domain):
    """Whether a live process on this host uses DDS domain `domain` over shared memory: it maps
    or holds open a shared-memory port of the domain (RTPS's port mapping gives domain d the
    ports 7400 + 250 d up to 7400 + 250 (d + 1) - 1)."""
    base = 7400 + 250 * domain
    ports = {f"fastrtps_port{p}" for p in range(base, base + 250)}
    return not ports.isdisjoint(_shm_in_use())


def shm_cleanup(before):
    """Removes the Fast DDS shared-memory files our run left (kill -9 leaves them), a port's
    or segment's files together and only when no live process maps or holds open any of
    them: another run on this host (another domain) made some of the files that appeared
    during ours, and a live port whose lock file is removed looks dead to its peers, which
    then stop sending to it (docs/RUNNING.md, "Several runs on one host")."""
    leftovers = shm_snapshot() - before
    if not leftovers:
        return 0
    used = _shm_in_use()
    removed = 0
    for name in sorted(leftovers):
        if _shm_family(name) in used:
            continue
        try:
            os.unlink(os.path.join(SHM_DIR, name))
            removed += 1
        except OSError:
            pass
    return removed


def default_out_dir(config_path):
    stem = os.path.splitext(os.path.basename(config_path))[0]
    return os.path.join(paths.ROOT, "runs",
                        f"{stem}-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}")


# The agents' CPU scheduling policies deif-run offers (docs/RUNNING.md, "CPU scheduling"):
# SCHED_BATCH, or the launcher's own (normally SCHED_OTHER).
AGENT_SCHED = ("batch", "normal")


def sched_prefix(policy):
    """The command prefix that starts a process under an AGENT_SCHED policy (chrt; every
    thread the process makes inherits it)."""
    return ["chrt", "--batch", "0"] if policy == "batch" else []


class Launcher:
    live_port = None  # deif-run --live [PORT]: run deif_observer beside the run (docs/LIVE.md)
    live_url = None   # the page's URL, once the observer printed it

    def __init__(self, config_path, out_dir, *, agents=None, steps=None, seed=None, domain=None,
                 overrides=(), faults=(), hosts=1, loss=0.0, partitions=(), run_name=None,
                 progress=True, log=sys.stderr, timeout_s=None, discovery_server=False,
                 secure=False, certs_dir=None, staggered=None, agent_sched="batch", nice=0):
        """staggered: start the processes one after another (True) or all at once (False);
        None: one after another when the run is secure (start()). agent_sched: the agents' CPU
        scheduling policy, "batch" (SCHED_BATCH: a woken agent does not preempt the process
        that runs, so the target, the world's clock, is not starved by N agents;
        docs/RUNNING.md, "CPU scheduling") or "normal". nice: the nice value of the target,
        the agents and the Discovery Server (-20..19; below 0 needs root): a run in real time on
        a host that does other work holds its period better when it comes first."""
        self.log = log
        self.progress = progress and hasattr(log, "isatty") and log.isatty()
        if hosts < 1:
            raise LaunchError(f"--hosts {hosts}: must be >= 1")
        if not 0.0 <= loss < 1.0:
            raise LaunchError(f"--loss: must be in [0, 100) percent (got {loss * 100:g})")
        if (loss > 0 or partitions) and hosts < 2:
            raise LaunchError("--loss and --partition need --hosts 2 or more (they act on the "
                              "links between hosts)")
        for p in partitions:
            if p.host > hosts:
                raise LaunchError(f"--partition {p.step}:{p.seconds:g}:{p.host}: there are only "
                                  f"{hosts} hosts")
        if agent_sched not in AGENT_SCHED:
            raise LaunchError(f"--agent-sched {agent_sched}: must be one of {', '.join(AGENT_SCHED)}")
        self.agent_sched = agent_sched
        if not isinstance(nice, int) or not -20 <= nice <= 19:
            raise LaunchError(f"--nice {nice}: must be an integer in -20..19")
        if nice < 0 and os.geteuid() != 0:
            raise LaunchError(f"--nice {nice}: a negative nice value needs root (CAP_SYS_NICE)")
        self.nice = nice
        if hosts > 1:
            try:
                hosts_mod.require_root()
            except hosts_mod.HostsError as e:
                raise LaunchError(str(e))

        # The effective config: the C++ parser's verdict on the file plus every override.
        sets = list(overrides)
        # An override this launcher made from one of its options is named by that option in
        # an error ("--agents 1: key 'agents.count': ..."), not as a --set the user never gave.
        flags = {}
        for option, key, value in (("--agents", "agents.count", agents),
                                   ("--steps", "scenario.steps", steps),
                                   ("--seed", "scenario.seed", seed),
                                   ("--domain", "network.domain_id", domain)):
            if value is not None:
                sets.append(f"{key}={value}")
                flags[f"--set {key}:"] = f"{option} {value}:"
        if hosts > 1:
            sets.append("network.transport=udp")  # shared memory would cross the "hosts"
        self.discovery_server = None  # (address, port) when the run has its own server
        if discovery_server:
            sets.append("network.discovery=server")
        # DDS Security (docs/SECURITY.md): the run's own CA and certificates in <out>/certs,
        # or the given folder's. Every process gets the same two keys.
        self.secure = secure or certs_dir is not None
        self.certs_given = certs_dir is not None
        if self.secure:
            self.certs_dir = os.path.abspath(certs_dir if certs_dir is not None
                                             else os.path.join(out_dir, "certs"))
            sets += ["network.security.enabled=true",
                     "network.security.dir=" + cfg.flow(self.certs_dir)]
        try:
            resolved = cfg.resolve(config_path, sets)
        except cfg.ConfigRefused as e:
            reason = str(e)
            for given, option in flags.items():
                if reason.startswith(given):
                    reason = option + reason[len(given):]
            raise LaunchError(reason)
        file_faults = [Fault(int(f["step"]), f["action"], f.get("agent"))
                       for f in resolved.get("faults") or []]
        extra = list(faults)
        if extra:
            sets.append("faults=" + cfg.flow([f.as_config() for f in file_faults + extra]))
            try:
                resolved = cfg.resolve(config_path, sets)
            except cfg.ConfigRefused as e:
                raise LaunchError(self._blame_fault(str(e), len(file_faults), extra))
        self.n = int(resolved["agents"]["count"])
        self.steps = int(resolved["scenario"]["steps"])
        self.domain = int(resolved["network"]["domain_id"])
        if discovery_server:
            # One server per run: on host 1 with --hosts, else on the loopback; its port
            # follows from the domain (as the address range does).
            host_ip = f"10.211.{self.domain}.1" if hosts > 1 else "127.0.0.1"
            self.discovery_server = (host_ip, 11811 + self.domain)
            sets.append(f"network.discovery_server={host_ip}:{11811 + self.domain}")
            resolved = cfg.resolve(config_path, sets)
        # A secure run starts its processes one after another (start()); each takes a second
        # or more to authenticate with those before it, and a stalled handshake 3 s and a
        # random wait more (19-29 s for 16 agents on a quiet 2-core machine, more than 48 s
        # on a busy one). The target's wait for the agents must cover that, and about as much
        # when they start together: 6 s per agent. It only costs time when an agent never
        # comes up (docs/SECURITY.md, "Start-up").
        self.start_timeout_raised = None
        secure_run = bool(resolved["network"]["security"]["enabled"])
        # Whether the agents start under SCHED_OTHER and get agent_sched at the first step.
        self._sched_deferred = secure_run and self.agent_sched != "normal"
        self._sched_given = False
        self.staggered = secure_run if staggered is None else bool(staggered)
        if secure_run:
            least = 6.0 * self.n
            if float(resolved["network"]["start_timeout_s"]) < least:
                self.start_timeout_raised = least
                sets.append(f"network.start_timeout_s={least:g}")
                resolved = cfg.resolve(config_path, sets)
        self.cfg = resolved
        self.faults = sorted(file_faults + extra, key=lambda f: f.step)
        self.realtime = resolved["scenario"]["mode"] == "realtime"
        self.partitions = sorted(partitions, key=lambda p: p.step)
        self.hosts_count = hosts
        self.loss = loss
        self.hosts = None
        self.run_name = run_name or (
            f"{os.path.splitext(os.path.basename(config_path))[0][:20]}-"
            f"{datetime.datetime.now().strftime('%H%M%S')}-{random.randrange(16**4):04x}")
        self.timeout_s = timeout_s if timeout_s is not None else self._default_timeout()

        # The run folder: new, or empty.
        self.out_dir = os.path.abspath(out_dir)
        if os.path.exists(self.out_dir) and (not os.path.isdir(self.out_dir) or os.listdir(self.out_dir)):
            raise LaunchError(f"--out {out_dir}: exists and is not an empty folder (runs never "
                              "overwrite or mix; choose another folder or remove it)")
        try:
            os.makedirs(os.path.join(self.out_dir, "logs"), exist_ok=True)
            self.config_path = os.path.join(self.out_dir, "config.yaml")
            with open(self.config_path, "w") as f:
                f.write(cfg.canonical_yaml(config_path, sets))
        except OSError as e:
            raise LaunchError(f"--out {out_dir}: cannot write there ({e.strerror})")
        if self.secure:
            self._prepare_certs()
        self.source_config = config_path
        self.overrides = sets
        self.procs = {}
        self.holds = queue.Queue()
        self.shm_before = shm_snapshot()
        self.started = time.time()
        self.interrupted = None
        self.timed_out = False

    def _prepare_certs(self):
        """Issues the run's certificates (a CA of its own, permissions for this run's
        partitions only, the CA's private key deleted once they are signed), or checks that
        the given folder has every process's files. The processes check the files
        themselves at start (exit 2, naming the file and the reason)."""
        names = certs_mod.identities(self.n, 0)
        if self.certs_given:
            for name in names:
                for suffix in (".cert.pem", ".key.pem", ".permissions.p7s"):
                    path = os.path.join(self.certs_dir, name + suffix)
                    if not os.path.isfile(path):
                        raise LaunchError(f"--certs {self.certs_dir}: {name}{suffix} is missing "
                                          f"(scripts/deif-certs {self.certs_dir} --agents {self.n})")
            for common in ("ca.pem", "governance.p7s"):
                if not os.path.isfile(os.path.join(self.certs_dir, common)):
                    raise LaunchError(f"--certs {self.certs_dir}: {common} is missing")
            return
        try:
            certs_mod.ensure(self.certs_dir, self.n, observers=1, days=30, run=self.run_name)
        except certs_mod.CertsError as e:
            raise LaunchError(f"--secure: {e}")
        # Nobody issues more certificates for this run (docs/SECURITY.md).
        os.unlink(os.path.join(self.certs_dir, "ca.key.pem"))

    def _blame_fault(self, message, n_file, extra):
        """A refused command-line fault is blamed on its flag, not on the config file."""
        for i, fault in enumerate(extra):
            tag = f"'faults[{n_file + i}]"
            if tag in message:
                reason = message.split(": ", 2)[-1]
                return f"{fault.origin}: {reason}"
        return message

    def _default_timeout(self):
        net = self.cfg["network"]
        per_step = float(self.cfg["scenario"]["period_s"]) if self.realtime else 0.05
        if not self.realtime and self.loss:
            # A lock-step step waits for every hop's repairs: 20 agents on 4 hosts took 0.12 s
            # a step at 10 % loss and 0.45 s at 30 % (docs/RUNNING.md, "Several hosts on one machine").
            per_step += 2.0 * self.loss
        # Discovery grows as N^2 (every endpoint is announced to every participant): 128
        # agents on 4 namespace hosts took 80-130 s to start on 2 cores.
        return (60.0 + 2 * float(net["start_timeout_s"]) + self.n ** 2 / 200.0
                + self.steps * per_step * 1.5
                + len(self.faults) * (float(net["start_timeout_s"]) + 5.0))

    # ------------------------------------------------------------------ processes
    def _argv(self, exe, *extra):
        return [paths.executable(exe), "--config", self.config_path, "--out", self.out_dir,
                "--run", self.run_name, *extra]

    def _host_of(self, name):
        if self.hosts_count == 1:
            return 1
        if name == "target":
            return 1
        agent = int(name.split("_")[1])
        return 2 + (agent - 1) % (self.hosts_count - 1)

    def command(self, proc):
        """The command line that starts proc: it dies with the launcher, whatever kills it
        (PR_SET_PDEATHSIG through setpriv); an agent runs under its scheduling policy (chrt,
        inherited by every thread Fast DDS makes); inside its host's namespace."""
        argv = list(proc.argv)
        if proc.name.startswith("agent_"):
            argv = sched_prefix(self._start_sched()) + argv
        if self.nice != 0 and proc.name != "observer":
            argv = ["nice", "-n", str(self.nice)] + argv  # before any thread: every one has it
        argv = ["setpriv", "--pdeathsig", "KILL", "--", *argv]
        if self.hosts is not None:
            argv = self.hosts.command(proc.host, argv)
        return argv

    def _start_sched(self):
        """The policy an agent starts under. A secure run's agents start under SCHED_OTHER and
        are given their policy at the run's first step (service(); one restarted later, once
        it is up): with the agents under SCHED_BATCH the handshakes of a secure start stalled
        again and again (docs/RUNNING.md, "CPU scheduling")."""
        return "normal" if self._sched_deferred else self.agent_sched

    def _spawn(self, proc, control=False):
        argv = self.command(proc)
        logf = open(proc.log_path, "ab")
        proc.log_offset = logf.tell()
        proc.started_unix_s = time.time()
        proc.popen = subprocess.Popen(
            argv, stdout=subprocess.PIPE if control else logf, stderr=logf,
            stdin=subprocess.PIPE if control else subprocess.DEVNULL)
        logf.close()
        if control:
            threading.Thread(target=self._read_holds, args=(proc.popen,), daemon=True).start()
        if proc.name.startswith("agent_") and self._sched_given:
            threading.Thread(target=self._sched_once_up, args=(proc, proc.popen), daemon=True).start()

    def _give_sched(self, popen):
        """Gives every thread of the running agent `popen` the agents' policy (what `chrt
        --all-tasks --batch --pid 0 PID` does, without a process per agent); threads made
        later inherit it from the thread that makes them. Twice, for a thread made while the
        first pass ran."""
        for _ in range(2):
            try:
                tids = os.listdir(f"/proc/{popen.pid}/task")
            except OSError:
                return  # it ended
            for tid in tids:
                try:
                    os.sched_setscheduler(int(tid), os.SCHED_BATCH, os.sched_param(0))
                except OSError:
                    pass  # that thread ended meanwhile

    def _sched_once_up(self, proc, popen):
        """An agent (re)started after the run's first step gets its policy once it is up."""
        while popen.poll() is None and not self._is_up(proc):
            time.sleep(0.05)
        self._give_sched(popen)

    def _read_holds(self, popen):
        for line in popen.stdout:
            parts = line.decode(errors="replace").split()
            if len(parts) >= 2 and parts[0] == "hold" and parts[1].isdigit():
                self.holds.put(int(parts[1]))

    def _start_observer(self):
        """deif_observer, a passive participant serving the live page (docs/LIVE.md), started
        before the others so it sees every step; its first line on stdout is the URL."""
        p = Proc("observer", self._argv("deif_observer", "--port", str(self.live_port)), 1,
                 log_path=os.path.join(self.out_dir, "logs", "observer.log"))
        p.expected_death = True  # stopped by the launcher at the end
        logf = open(p.log_path, "ab")
        p.popen = subprocess.Popen(self.command(p), stdout=subprocess.PIPE, stderr=logf, stdin=subprocess.DEVNULL)
        logf.close()
        self.procs[p.name] = p
        line = p.popen.stdout.readline().decode(errors="replace").strip()
        if line.startswith("deif_observer: "):
            self.live_url = line.split(" ", 1)[1]
            where = f" (inside host 1's namespace {self.hosts.namespace(1)})" if self.hosts else ""
            self._say(f"live view: {self.live_url}{where}")
        else:
            self._say(f"live view: the observer did not start; see {p.log_path}")

    def start(self):
        if self.hosts_count == 1 and self.cfg["network"]["transport"] == "shm" and shm_domain_in_use(self.domain):
            self._say(f"warning: another process on this host already uses DDS domain {self.domain} over "
                      "shared memory (another run?). Runs of one domain discover each other's processes: when one "
                      "ends, the other's processes can lose their receive to its last messages and start "
                      "again in place. Give each run its own --domain (docs/RUNNING.md, \"Several runs on "
                      "one host\").")
        if self.hosts_count > 1:
            self.hosts = hosts_mod.Hosts(self.hosts_count, self.domain).create()
            for h in range(1, self.hosts_count + 1):
                self.hosts.set_loss(h, self.loss)
        if self.discovery_server:
            ip, port = self.discovery_server
            # The server itself, not the `fastdds discovery` wrapper: the wrapper starts it as
            # a child that outlived the wrapper's SIGTERM (and then held the port, so the next
            # run's server could not start).
            # UDPv4 only (its clients reach it at ip:port anyway): with Fast DDS's default
            # transports it also opened a shared-memory port of domain 0, which a run now and
            # then left behind in /dev/shm.
            profile = os.path.join(self.out_dir, "discovery-server.xml")
            with open(profile, "w") as f:
                f.write(DISCOVERY_SERVER_PROFILE)
            p = Proc("discovery_server", ["/usr/bin/fast-discovery-server", "-i", "0", "-l", ip, "-p", str(port),
                                          "-x", profile],
                     host=1, log_path=os.path.join(self.out_dir, "logs", "discovery-server.log"))
            self._spawn(p)
            p.expected_death = True  # stopped by the launcher at the end
            self.procs[p.name] = p
            time.sleep(0.5)
        if self.live_port is not None:
            self._start_observer()
        # Secure processes start one after another, the target first: Fast DDS 2.9.1 can stall
        # the handshake of a participant that discovers two new ones at once. Started all
        # together (--start together), 16 secure agents began with all of them in 10 runs of
        # 13 (a stalled participant waits a random time before it is re-created), 32 still
        # stall in cascade; a target started last, finding everyone at once, stalled again
        # and again (docs/SECURITY.md, "Start-up").
        t = Proc("target", self._argv("deif_target", "--hold-for-faults"), self._host_of("target"),
                 log_path=os.path.join(self.out_dir, "logs", "target.log"))
        raised = (f"network.start_timeout_s raised to {self.start_timeout_raised:g} s"
                  if self.start_timeout_raised else "")
        if self.staggered:
            self._say("secure: starting the target, then the agents one after another "
                      "(docs/SECURITY.md, \"Start-up\")" + (f"; {raised}" if raised else ""))
            self._spawn(t, control=True)
            self.procs["target"] = t
            self._await_up(t)
        for j in range(1, self.n + 1):
            name = f"agent_{j}"
            p = Proc(name, self._argv("deif_agent", "--id", str(j)), self._host_of(name),
                     log_path=os.path.join(self.out_dir, "logs", f"agent-{j}.log"))
            self._spawn(p)
            self.procs[name] = p
            if self.staggered:
                self._await_up(p)
        if not self.staggered:
            if raised:
                self._say(f"secure, every process at once: {raised} (docs/SECURITY.md, \"Start-up\")")
            self._spawn(t, control=True)
            self.procs["target"] = t

    def _await_up(self, p, timeout_s=30.0):
        """Until p's log says it is up (its participant made and, when secure, authenticated
        with every peer it found), it ended, or timeout_s (then the next one starts anyway)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and p.popen.poll() is None and not self._is_up(p):
            time.sleep(0.05)

    @staticmethod
    def _is_up(p):
        """Whether p's log says it is up (since its last start: a restarted agent's log is
        appended to, so the lines of a start before it do not count)."""
        try:
            with open(p.log_path, "rb") as f:
                f.seek(p.log_offset)
                return b" up: run " in f.read()
        except OSError:
            return False

    def current_step(self):
        row = artefacts.last_row(os.path.join(self.out_dir, "target.csv"))
        return int(row["step"]) if row else 0

    def _say(self, msg):
        if self.progress:
            self.log.write("\r\033[K")
        self.log.write(f"deif-run: {msg}\n")
        self.log.flush()

    # ------------------------------------------------------------------ faults
    def _apply(self, fault, step):
        fault.applied_unix_s = time.time()
        fault.applied_at_step = step
        if fault.action == "restart_target":
            t = self.procs["target"]
            if t.popen.poll() is None:
                t.popen.send_signal(signal.SIGKILL)
                t.popen.wait()
            t.restarts += 1
            t.argv = self._argv("deif_target", "--hold-for-faults", "--start-step", str(step))
            self._spawn(t, control=True)
            self._say(f"fault: the target killed before step {step} and restarted")
            return
        p = self.procs.get(f"agent_{fault.agent}")
        if p is None or p.popen.poll() is not None:
            return
        if fault.action == "kill":
            p.expected_death = True
            p.popen.send_signal(signal.SIGKILL)
        elif fault.action == "stop":
            p.stopped = True
            p.popen.send_signal(signal.SIGSTOP)
        elif fault.action == "cont":
            p.stopped = False
            p.popen.send_signal(signal.SIGCONT)
        self._say(f"fault: {fault.action} agent {fault.agent} at step {step}")

    def restart_agent(self, agent):
        """kill -9 agent and start it again in the same slot (its CSV is appended to); it
        rejoins the running network by adopting a peer's posterior (docs/PROTOCOL.md)."""
        p = self.procs[f"agent_{agent}"]
        if p.popen.poll() is None:
            p.popen.send_signal(signal.SIGKILL)
            p.popen.wait()
        p.restarts += 1
        p.argv = self._argv("deif_agent", "--id", str(agent), "--append")
        self._spawn(p)

    def _go(self, step):
        t = self.procs["target"]
        try:
            t.popen.stdin.write(f"go {step}\n".encode())
            t.popen.stdin.flush()
        except (BrokenPipeError, OSError):
            pass

    def _handle_holds(self):
        while True:
            try:
                step = self.holds.get_nowait()
            except queue.Empty:
                return
            due = [f for f in self.faults if f.step == step and f.applied_unix_s is None]
            restarted = False
            for fault in due:
                self._apply(fault, step)
                restarted = restarted or fault.action == "restart_target"
            if not restarted:
                self._go(step)

    def _handle_partitions(self, step):
        now = time.time()
        for p in self.partitions:
            if p.cut_unix_s is None and step >= p.step:
                self.hosts.cut(p.host)
                p.cut_unix_s, p.cut_at_step = now, step
                self._say(f"partition: host {p.host} cut off at step {step} for {p.seconds:g} s")
            elif p.cut_unix_s is not None and p.healed_unix_s is None and now - p.cut_unix_s >= p.seconds:
                self.hosts.heal(p.host)
                p.healed_unix_s, p.healed_at_step = now, step
                self._say(f"partition: host {p.host} back at step {step}")

    # ------------------------------------------------------------------ progress
    def _progress_line(self, step):
        if not self.progress:
            return
        alive = sum(1 for n, p in self.procs.items()
                    if n != "target" and p.popen.poll() is None and not p.stopped)
        misses = 0
        err = ""
        truth = artefacts.last_row(os.path.join(self.out_dir, "target.csv"))
        for j in range(1, self.n + 1):
            row = artefacts.last_row(os.path.join(self.out_dir, f"agent_{j}.csv"))
            if not row:
                continue
            misses += int(row.get("misses", 0))
            if not err and truth:
                e = math.hypot(float(row["x_est"]) - float(truth["x_true"]),
                               float(row["y_est"]) - float(truth["y_true"]))
                err = f"  error {e:.3f} m (agent {j})"
        self.log.write(f"\r\033[Kstep {step}/{self.steps}  agents alive {alive}/{self.n}"
                       f"  deadline misses {misses}{err}")
        self.log.flush()

    # ------------------------------------------------------------------ the run
    def service(self):
        """One round of the launcher's duties: answer held steps, cut and heal partitions.
        Returns the step the target reached."""
        self._handle_holds()
        step = self.current_step()
        if self._sched_deferred and not self._sched_given and step >= 1:
            self._sched_given = True
            for name, p in self.procs.items():
                if name.startswith("agent_") and p.popen is not None:
                    self._give_sched(p.popen)
        # A fault whose step the target never held is applied now, late: a real-time target
        # restarted meanwhile resumes after the agents' newest step and skips the steps in
        # between (docs/PROTOCOL.md, "Resuming in real time"). Before, such a fault waited
        # for the end of the run (an agent frozen at 10 and resumed at 40 stayed frozen).
        late = [f for f in self.faults if f.applied_unix_s is None and f.step < step]
        for fault in late:
            self._apply(fault, step)
        if self.hosts is not None and self.partitions:
            self._handle_partitions(step)
        return step

    def wait_for_step(self, step, timeout_s=120.0):
        """Runs the launcher's duties until the target reached `step` (for scripts and
        tests that act on a running network). Raises TimeoutError."""
        deadline = time.time() + timeout_s
        while self.service() < step:
            if time.time() > deadline or self.procs["target"].popen.poll() is not None:
                raise TimeoutError(f"the run did not reach step {step}")
            time.sleep(0.02)

    def wait(self):
        deadline = time.time() + self.timeout_s
        target = self.procs["target"]
        last_print = 0.0
        timed_out = True
        while time.time() < deadline:
            step = self.service()
            pending = [f for f in self.faults if f.applied_unix_s is None]
            if target.popen.poll() is not None and self.holds.empty():
                if target.popen.returncode != 0 or not pending or not any(
                        f.action == "restart_target" for f in pending):
                    timed_out = False
                    break
            if time.time() - last_print > 0.2:
                self._progress_line(step)
                last_print = time.time()
            time.sleep(0.02)
        self.timed_out = timed_out
        if timed_out:
            self._say(f"timeout after {self.timeout_s:.0f} s; stopping every process")
        for p in self.partitions:  # a partition still open heals before the end
            if p.cut_unix_s is not None and p.healed_unix_s is None:
                self.hosts.heal(p.host)
                p.healed_unix_s, p.healed_at_step = time.time(), self.current_step()
        # The agents finish on their own after the last step.
        agent_deadline = time.time() + 10.0 + float(self.cfg["network"]["step_timeout_s"])
        server = self.procs.get("discovery_server")
        observer = self.procs.get("observer")
        for name, p in self.procs.items():
            if p is server or p is observer:
                continue
            if p.stopped and p.popen.poll() is None:
                p.popen.send_signal(signal.SIGCONT)
                p.stopped = False
            self._reap(p, max(0.1, agent_deadline - time.time()))
        for p in (observer, server):
            if p is not None:
                p.popen.send_signal(signal.SIGTERM)
                self._reap(p, 3.0)
        if self.progress:
            self.log.write("\n")

    def _reap(self, p, wait_s):
        try:
            p.popen.wait(wait_s)
        except subprocess.TimeoutExpired:
            p.popen.send_signal(signal.SIGTERM)
            try:
                p.popen.wait(3.0)
            except subprocess.TimeoutExpired:
                p.popen.send_signal(signal.SIGKILL)
                p.popen.wait()
        p.exit_status = p.popen.returncode

    def terminate_all(self):
        for p in self.procs.values():
            if p.popen is not None and p.popen.poll() is None:
                if p.stopped:
                    p.popen.send_signal(signal.SIGCONT)
                p.popen.send_signal(signal.SIGTERM)
        for p in self.procs.values():
            if p.popen is not None:
                self._reap(p, 3.0)

    def finish(self):
        if self.hosts is not None:
            self.hosts.remove()
        removed = shm_cleanup(self.shm_before)
        procs = []
        # A run stopped by --timeout did not reach its last step: not ok, whatever its
        # processes' exit status after the SIGTERM.
        ok = self.interrupted is None and not self.timed_out
        for name, p in self.procs.items():
            status = p.exit_status
            expected = status == 0 or (p.expected_death and status in (-signal.SIGKILL, -signal.SIGTERM))
            ok = ok and expected
            procs.append({"name": name, "argv": p.argv, "host": p.host, "exit_status": status,
                          "signal": -status if status is not None and status < 0 else None,
                          "expected": expected, "restarts": p.restarts,
                          "restarts_in_place": restarts_in_place(p.log_path),
                          "crashes": crashes(p.log_path),
                          "reader_loops": log_count(p.log_path, READER_LOOP),
                          "readers_made_anew": log_count(p.log_path, READER_MADE_ANEW),
                          "started_unix_s": p.started_unix_s,
                          "log": os.path.relpath(p.log_path, self.out_dir)})
        metrics = self.evaluate()
        if metrics.get("non_finite_estimates"):
            ok = False
        # What every process rejected and dropped, by reason (each leaves its counters).
        counters = {}
        for name in sorted(os.listdir(self.out_dir)):
            if name.endswith(".counters.json"):
                try:
                    with open(os.path.join(self.out_dir, name)) as f:
                        counters[name[:-len(".counters.json")]] = json.load(f)
                except (OSError, ValueError):
                    pass
        summary = {
            "config": self.cfg,
            "config_file": "config.yaml",
            "config_source": self.source_config,
            "overrides": self.overrides,
            "seeds": {"scenario": self.cfg["scenario"]["seed"]},
            "run_name": self.run_name,
            "domain_id": self.domain,
            "hosts": self.hosts_count,
            "loss": self.loss,
            "security": ({"enabled": True, "certs": self.certs_dir,
                          "issued_for_run": not self.certs_given} if self.secure
                         else {"enabled": False}),
            "partitions": [p.__dict__ for p in self.partitions],
            "faults": [f.__dict__ for f in self.faults],
            "agent_sched": self.agent_sched,
            "nice": self.nice,
            "processes": procs,
            "wall_time_s": time.time() - self.started,
            "live_url": self.live_url,
            "shm_files_removed": removed,
            "metrics": metrics,
            "counters": counters,
            "interrupted_by_signal": self.interrupted,
            "timed_out_after_s": self.timeout_s if self.timed_out else None,
            "ok": ok,
        }
        with open(os.path.join(self.out_dir, "summary.json"), "w") as f:
            json.dump(summary, f, indent=2)
        return RunResult(self.out_dir, ok, summary)

    def evaluate(self):
        """The run's metrics, computed by deif_sim --evaluate (metrics.csv beside the run)."""
        proc = subprocess.run([paths.executable("deif_sim"), "--config", self.config_path,
                               "--evaluate", self.out_dir], capture_output=True, text=True)
        if proc.returncode != 0:
            return {"error": proc.stderr.strip()}
        return json.loads(proc.stdout)


def restarts_in_place(log_path):
    """How often a process started again in place with a new participant (its log says
    so; docs/RUNNING.md, "Restarting in place")."""
    try:
        with open(log_path, "rb") as f:
            return f.read().count(b"starts again in place")
    except OSError:
        return 0


# What a process logs when Fast DDS 2.9.1's reader loops over a change its history lost track
# of: caught inside a call (it starts again in place, counted in restarts_in_place too), or
# by the application, which made the reader anew (docs/FASTDDS_NOTES.md, "A reader that hands
# out one sample for ever").
READER_LOOP = b"a reader is caught in Fast DDS's loop"
READER_MADE_ANEW = b"handed out the same sample twice"


def log_count(log_path, text):
    """How often `text` (bytes) is in the log; 0 without a log."""
    try:
        with open(log_path, "rb") as f:
            return f.read().count(text)
    except OSError:
        return 0


def crashes(log_path):
    """How often a process crashed while its run went on and started again in place (its log
    says so; docs/RUNNING.md, "A crash"); counted in restarts_in_place too."""
    try:
        with open(log_path, "rb") as f:
            return f.read().count(b": error: crashed (signal ")
    except OSError:
        return 0


def run(config_path, out_dir, live=None, **kwargs):
    """Runs one launch to the end. SIGINT/SIGTERM stop every process, write summary.json and
    raise Interrupted; namespaces are removed on every path. live: a port for deif_observer's
    page (0: any free port), or None for no observer."""
    launcher = Launcher(config_path, out_dir, **kwargs)
    launcher.live_port = live

    def on_signal(signum, frame):
        raise Interrupted(signum)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        launcher.start()
        launcher.wait()
    except Interrupted as e:
        launcher.interrupted = e.signum
        launcher._say(f"interrupted (signal {e.signum}); stopping every process")
        launcher.terminate_all()
        launcher.finish()
        raise
    except BaseException:
        launcher.terminate_all()
        launcher.finish()
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return launcher.finish()


def median_delivery_ms(counters):
    """Per kind of sample the agents took, the median over the agents of each one's p50 and
    of each one's p99 delivery delay [ms] (docs/ARTEFACTS.md, "Delivery delays"), from
    summary.json's `counters`: {"range": [p50, p99], ...}."""
    by_kind = {}
    for name, c in counters.items():
        if name.startswith("agent"):
            for kind, d in (c.get("delivery_ms") or {}).items():
                by_kind.setdefault(kind, []).append((d["p50"], d["p99"]))
    return {kind: [sorted(v[i] for v in rows)[len(rows) // 2] for i in (0, 1)]
            for kind, rows in by_kind.items()}
