"""Launch a target and N agents as separate OS processes and collect one run folder.

Used by scripts/deif-run (command line), scripts/deif-batch and the multi-process tests.
Only the Python standard library and PyYAML (Debian's python3-yaml).
"""
import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field

import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHM_DIR = "/dev/shm"
SHM_PREFIXES = ("fastrtps_", "sem.fastrtps_", "fast_datasharing_")


@dataclass
class Fault:
    step: int
    action: str  # kill | stop | cont | restart_target
    agent: int = -1
    applied_unix_s: float = None  # wall-clock time the launcher applied it
    applied_at_step: int = None

    @staticmethod
    def parse(text, action):
        """'STEP:ID' for agent faults, 'STEP' for restart_target."""
        try:
            if action == "restart_target":
                return Fault(int(text), action)
            step, agent = text.split(":")
            return Fault(int(step), action, int(agent))
        except ValueError:
            raise SystemExit(f"deif-run: error: bad --{action.replace('_', '-')} value '{text}' "
                             f"(expected {'STEP' if action == 'restart_target' else 'STEP:ID'})")


@dataclass
class Proc:
    name: str
    argv: list
    popen: subprocess.Popen = None
    expected_death: bool = False   # killed on purpose by a scripted fault
    stopped: bool = False
    exit_status: int = None
    log_path: str = ""
    restarts: int = 0


@dataclass
class RunResult:
    out_dir: str
    ok: bool
    processes: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)


def build_dir():
    return os.environ.get("DEIF_BUILD_DIR", os.path.join(ROOT, "build"))


def executable(name):
    path = os.path.join(build_dir(), "bin", name)
    if not os.path.exists(path):
        raise SystemExit(f"deif-run: error: {path} not found; build first (scripts/build)")
    return path


def load_config(path, agents=None, extra_faults=(), steps=None, seed=None):
    """Read the YAML config and apply command-line overrides. The C++ executables validate it."""
    try:
        with open(path) as f:
            cfg = yaml.safe_load(f) or {}
    except OSError as e:
        raise SystemExit(f"deif-run: error: {path}: cannot read config: {e.strerror}")
    except yaml.YAMLError as e:
        raise SystemExit(f"deif-run: error: {path}: YAML syntax error: {e}")
    if not isinstance(cfg, dict):
        raise SystemExit(f"deif-run: error: {path}: top level must be a mapping")
    if agents is not None:
        ag = cfg.setdefault("agents", {})
        if ag.get("count") != agents and "initial_angles_rad" in ag:
            # The angle list is per agent: with another count the agents start evenly spaced.
            del ag["initial_angles_rad"]
        ag["count"] = agents
    if steps is not None:
        cfg.setdefault("scenario", {})["steps"] = steps
    if seed is not None:
        cfg.setdefault("scenario", {})["seed"] = seed
    if extra_faults:
        faults = list(cfg.get("faults") or [])
        for f in extra_faults:
            entry = {"step": f.step, "action": f.action}
            if f.action != "restart_target":
                entry["agent"] = f.agent
            faults.append(entry)
        cfg["faults"] = faults
    return cfg


def shm_snapshot():
    try:
        return {n for n in os.listdir(SHM_DIR) if n.startswith(SHM_PREFIXES)}
    except OSError:
        return set()


def _shm_in_use():
    """Names under /dev/shm that some live process maps or holds open."""
    used = set()
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/maps") as f:
                for line in f:
                    i = line.find(SHM_DIR + "/")
                    if i >= 0:
                        used.add(os.path.basename(line[i:].strip()))
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    target = os.readlink(f"/proc/{pid}/fd/{fd}")
                except OSError:
                    continue
                if target.startswith(SHM_DIR + "/"):
                    used.add(os.path.basename(target))
        except OSError:
            continue
    return used


def shm_cleanup(before):
    """Remove the Fast DDS shared-memory files that appeared during our run and that no live
    process still uses (kill -9 leaves them behind; see docs/RUNNING.md)."""
    leftovers = shm_snapshot() - before
    if not leftovers:
        return 0
    in_use = _shm_in_use()
    removed = 0
    for name in sorted(leftovers - in_use):
        try:
            os.unlink(os.path.join(SHM_DIR, name))
            removed += 1
        except OSError:
            pass
    return removed


def _last_csv_row(path):
    """The last complete line of a CSV as a dict (None if no data row yet)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 4096))
            tail = f.read().decode(errors="replace")
        with open(path) as f:
            header = f.readline().strip().split(",")
    except OSError:
        return None
    lines = [l for l in tail.split("\n") if l]
    if not tail.endswith("\n") and lines:
        lines = lines[:-1]  # a row being written
    if not lines or lines[-1].startswith(header[0] + ","):
        return None
    values = lines[-1].split(",")
    if len(values) != len(header):
        return None
    return dict(zip(header, values))


def read_csv(path):
    rows = []
    try:
        with open(path) as f:
            header = f.readline().strip().split(",")
            for line in f:
                if not line.endswith("\n"):
                    break  # torn final row of a killed process
                values = line.strip().split(",")
                if len(values) == len(header):
                    rows.append(dict(zip(header, values)))
    except OSError:
        pass
    return rows


def wrap_two_pi(a):
    return a % (2.0 * math.pi)


def optimal_gap(n):
    return 2.0 * math.pi / n if n >= 3 else (math.pi / 2.0 if n == 2 else 0.0)


def gaps_of(angles):
    """Counter-clockwise gaps of the ring formed by the angles; they sum to 2 pi."""
    a = sorted(wrap_two_pi(x) for x in angles)
    if len(a) < 2:
        return []
    return [a[i + 1] - a[i] for i in range(len(a) - 1)] + [a[0] + 2.0 * math.pi - a[-1]]


def max_gap_error(angles):
    g = gaps_of(angles)
    n = len(g)
    if n < 2:
        return 0.0
    if n == 2:
        return abs(min(g) - math.pi / 2.0)
    return max(abs(x - optimal_gap(n)) for x in g)


def compute_metrics(out_dir, n_agents):
    """Metrics from the artefacts alone (so they can be recomputed for any run folder)."""
    truth = {int(r["step"]): (float(r["x_true"]), float(r["y_true"]))
             for r in read_csv(os.path.join(out_dir, "target.csv"))}
    sq_sum, count, max_err = 0.0, 0, 0.0
    per_agent = {}
    last_angles = {}
    last_step = 0
    for j in range(1, n_agents + 1):
        rows = read_csv(os.path.join(out_dir, f"agent_{j}.csv"))
        a_sq, a_n, a_max = 0.0, 0, 0.0
        for r in rows:
            k = int(r["step"])
            if k not in truth:
                continue
            e = math.hypot(float(r["x_est"]) - truth[k][0], float(r["y_est"]) - truth[k][1])
            a_sq += e * e
            a_n += 1
            a_max = max(a_max, e)
        if rows:
            last_step = max(last_step, int(rows[-1]["step"]))
        per_agent[j] = {"steps": a_n, "rmse_m": math.sqrt(a_sq / a_n) if a_n else None,
                        "max_error_m": a_max if a_n else None,
                        "last_step": int(rows[-1]["step"]) if rows else 0,
                        "rejected": int(rows[-1].get("rejected", 0)) if rows else 0,
                        "dropped": int(rows[-1].get("dropped", 0)) if rows else 0}
        sq_sum += a_sq
        count += a_n
        max_err = max(max_err, a_max)
        if rows:
            last_angles[j] = (int(rows[-1]["step"]), float(rows[-1]["angle"]))
    finishers = [a for (s, a) in last_angles.values() if s == last_step]
    return {
        "rmse_m": math.sqrt(sq_sum / count) if count else None,
        "max_error_m": max_err if count else None,
        "last_step": last_step,
        "final_agents": len(finishers),
        "final_max_gap_error_rad": max_gap_error(finishers),
        "per_agent": per_agent,
    }


class Launcher:
    """Starts and watches the processes of one run."""

    def __init__(self, config_path, out_dir, agents=None, faults=(), domain=None, steps=None,
                 seed=None, progress=True, log=sys.stderr):
        self.out_dir = os.path.abspath(out_dir)
        os.makedirs(self.out_dir, exist_ok=True)
        self.cfg = load_config(config_path, agents, faults, steps, seed)
        self.config_path = os.path.join(self.out_dir, "config.yaml")
        with open(self.config_path, "w") as f:
            yaml.safe_dump(self.cfg, f, sort_keys=False)
        self.n = int((self.cfg.get("agents") or {}).get("count", 4))
        self.steps = int((self.cfg.get("scenario") or {}).get("steps", 300))
        self.domain = domain
        self.faults = sorted(
            [Fault(int(f["step"]), f["action"], int(f.get("agent", -1)))
             for f in (self.cfg.get("faults") or [])], key=lambda f: f.step)
        self.progress = progress and log.isatty()
        self.log = log
        self.procs = {}
        self.log_dir = os.path.join(self.out_dir, "logs")
        os.makedirs(self.log_dir, exist_ok=True)
        self.shm_before = shm_snapshot()
        self.started = time.time()

    def _common_args(self):
        args = ["--config", self.config_path, "--out", self.out_dir, "--log-dir", self.log_dir]
        if self.domain is not None:
            args += ["--domain", str(self.domain)]
        return args

    def _spawn(self, proc):
        logf = open(proc.log_path, "ab")
        proc.popen = subprocess.Popen(proc.argv, stdout=logf, stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL)
        logf.close()

    def start(self):
        for j in range(1, self.n + 1):
            p = Proc(f"agent_{j}", [executable("deif_agent"), *self._common_args(), "--id", str(j)],
                     log_path=os.path.join(self.log_dir, f"agent_{j}.out"))
            self._spawn(p)
            self.procs[p.name] = p
        t = Proc("target", [executable("deif_target"), *self._common_args()],
                 log_path=os.path.join(self.log_dir, "target.out"))
        self._spawn(t)
        self.procs["target"] = t

    def current_step(self):
        row = _last_csv_row(os.path.join(self.out_dir, "target.csv"))
        return int(row["step"]) if row else 0

    def _apply(self, fault):
        fault.applied_unix_s = time.time()
        fault.applied_at_step = self.current_step()
        if fault.action == "restart_target":
            t = self.procs["target"]
            if t.popen.poll() is None:
                t.popen.send_signal(signal.SIGKILL)
                t.popen.wait()
            t.restarts += 1
            self._print(f"fault: target killed at step {self.current_step()}, restarting")
            time.sleep(0.5)
            self._spawn(t)
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
        self._print(f"fault: {fault.action} agent {fault.agent} at step {self.current_step()}")

    def _print(self, msg):
        if self.progress:
            self.log.write("\r\033[K")
        self.log.write(f"deif-run: {msg}\n")
        self.log.flush()

    def _progress_line(self, step):
        if not self.progress:
            return
        alive = sum(1 for n, p in self.procs.items()
                    if n != "target" and p.popen.poll() is None and not p.stopped)
        err = ""
        truth = _last_csv_row(os.path.join(self.out_dir, "target.csv"))
        for j in range(1, self.n + 1):
            p = self.procs[f"agent_{j}"]
            if p.popen.poll() is not None or p.stopped:
                continue
            row = _last_csv_row(os.path.join(self.out_dir, f"agent_{j}.csv"))
            if row and truth:
                # Compare with the truth of the agent's own step.
                e = math.hypot(float(row["x_est"]) - float(truth["x_true"]),
                               float(row["y_est"]) - float(truth["y_true"]))
                err = f"  error {e:.3f} m (agent {j}, step {row['step']})"
            break
        self.log.write(f"\r\033[Kstep {step}/{self.steps}  agents alive {alive}/{self.n}{err}")
        self.log.flush()

    def wait(self, timeout_s):
        """Apply the faults as the run reaches their steps; return when the target is done."""
        pending = list(self.faults)
        deadline = time.time() + timeout_s
        target = self.procs["target"]
        last_print = 0.0
        while time.time() < deadline:
            step = self.current_step()
            while pending and step >= pending[0].step:
                self._apply(pending.pop(0))
            if target.popen.poll() is not None and not pending:
                break
            if time.time() - last_print > 0.2:
                self._progress_line(step)
                last_print = time.time()
            time.sleep(0.02)
        else:
            self._print(f"timeout after {timeout_s:.0f} s; stopping every process")
        # Agents finish by themselves once the target says the run is over.
        agent_deadline = time.time() + 10.0
        for name, p in self.procs.items():
            if p.stopped and p.popen.poll() is None:
                p.popen.send_signal(signal.SIGCONT)
                p.stopped = False
            remaining = max(0.1, agent_deadline - time.time())
            try:
                p.popen.wait(remaining)
            except subprocess.TimeoutExpired:
                p.popen.send_signal(signal.SIGTERM)
                try:
                    p.popen.wait(3.0)
                except subprocess.TimeoutExpired:
                    p.popen.send_signal(signal.SIGKILL)
                    p.popen.wait()
            p.exit_status = p.popen.returncode
        if self.progress:
            self.log.write("\n")

    def terminate_all(self):
        for p in self.procs.values():
            if p.popen is not None and p.popen.poll() is None:
                if p.stopped:
                    p.popen.send_signal(signal.SIGCONT)
                p.popen.send_signal(signal.SIGKILL)
                p.popen.wait()
                p.exit_status = p.popen.returncode

    def finish(self):
        removed = shm_cleanup(self.shm_before)
        procs = []
        ok = True
        for name, p in self.procs.items():
            status = p.exit_status
            unexpected = not (status == 0 or (p.expected_death and status == -signal.SIGKILL))
            if unexpected:
                ok = False
            procs.append({"name": name, "argv": p.argv, "exit_status": status,
                          "signal": -status if status is not None and status < 0 else None,
                          "expected": not unexpected, "restarts": p.restarts,
                          "log": os.path.relpath(p.log_path, self.out_dir)})
        scen = self.cfg.get("scenario") or {}
        summary = {
            "config": self.cfg,
            "config_file": "config.yaml",
            "seeds": {"scenario": scen.get("seed", 1)},
            "domain_id": self.domain,
            "faults": [f.__dict__ for f in self.faults],
            "processes": procs,
            "wall_time_s": time.time() - self.started,
            "shm_files_removed": removed,
            "metrics": compute_metrics(self.out_dir, self.n),
            "ok": ok,
        }
        with open(os.path.join(self.out_dir, "summary.json"), "w") as f:
            json.dump(summary, f, indent=2)
        return RunResult(self.out_dir, ok, procs, summary)


def run(config_path, out_dir, agents=None, faults=(), domain=None, steps=None, seed=None,
        timeout_s=None, progress=True, log=sys.stderr):
    launcher = Launcher(config_path, out_dir, agents, faults, domain, steps, seed, progress, log)
    if timeout_s is None:
        timeout_s = 120.0 + 0.5 * launcher.steps
    try:
        launcher.start()
        launcher.wait(timeout_s)
    except KeyboardInterrupt:
        launcher._print("interrupted; stopping every process")
        launcher.terminate_all()
        launcher.finish()
        raise
    except BaseException:
        launcher.terminate_all()
        launcher.finish()
        raise
    return launcher.finish()
