"""Benchmarks of the whole system on one host (scripts/deif-bench; docs/BENCHMARKS.md).

Sections (all by default; --only picks some): core, pingpong, alltoall, lockstep, failure,
wire, network, realtime (scripts/deif/bench_network.py), security (scripts/deif/bench_security.py),
hostile (scripts/deif/bench_hostile.py; needs deif_hostile, built with the tests).
Executables come from ${DEIF_BUILD_DIR:-build}/bin: deif_agent, deif_target (through
deif.launcher), core_bench, dds_pingpong, dds_alltoall, step_observer. A benchmark program that is missing,
or older than its bench/<name>.cpp (it did not build from the current source), is skipped
with a message; the rest runs. DDS domains 200..230 only. Every process started here is
waited for; the shared-memory files our runs leave are removed.

Writes bench/results/<date>.json (every figure, with the raw per-run numbers) and
bench/results/<date>.md (the tables), both git-ignored, and prints the tables. It never
writes a tracked file: docs/BENCHMARKS.md is updated by hand. Benchmarks report figures;
they assert nothing.
"""
import datetime
import json
import math
import os
import random
import re
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

from . import artefacts, config, launcher, paths

ROOT = paths.ROOT
DEFAULT_CONFIG = os.path.join(ROOT, "configs", "default.yaml")
RESULTS_DIR = os.path.join(ROOT, "bench", "results")
SECTIONS = ("core", "pingpong", "alltoall", "lockstep", "failure", "wire", "network", "realtime", "security",
            "hostile", "discovery")
# network.exchange: auto picks the tree from this many agents on, and network.membership: auto
# the roll call from ROLL_CALL_FROM_AGENTS on (docs/CONFIG.md). Over the tree the lock-step
# section also runs the membership that auto does not pick, side by side with the default.
TREE_FROM_AGENTS = 17
ROLL_CALL_FROM_AGENTS = 28


def other_membership(n):
    """The membership auto does not pick at n agents (over the tree), as a KEY=VALUE."""
    return "network.membership=" + ("all_pairs" if n >= ROLL_CALL_FROM_AGENTS else "roll_call")
LOG_TIME = re.compile(r"^\[(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d)\.(\d{3})\]")
TARGET_DONE = re.compile(r"done at step (\d+) after ([\d.]+) s")

GOALS = {
    "latency_ratio_4": 3.0,       # 4-agent step latency p50 <= 3 x raw SHM round trip p50
    "steps_per_s_4": 2500.0,      # and >= 2500 steps/s
    "steps_per_s_64": 30.0,       # 64 agents, default config: >= 30 steps/s
    "cpu_ms_per_agent_step_64": 0.5,  # CPU per agent per step at N = 64
    "discovery_s_64": 2.0,        # launch to the first step fused by all 64
    "exclusion_p99_s": 0.5,       # kill-to-exclusion p99 < 0.5 s
    "rss_mb": 20.0,               # resident memory <= 20 MB per agent, every N
}


def log(msg):
    sys.stderr.write(f"bench: {msg}\n")
    sys.stderr.flush()


def bench_program(name):
    """build/bin/<name>, or (None, why) when it is missing or older than bench/<name>.cpp."""
    path = os.path.join(paths.build_dir(), "bin", name)
    source = os.path.join(ROOT, "bench", f"{name}.cpp")
    if not os.path.exists(path):
        return None, (f"{path} not found (cmake --build {paths.build_dir()} --target {name}; "
                      "built only with Google Benchmark / Fast DDS)")
    if os.path.exists(source) and os.path.getmtime(path) < os.path.getmtime(source):
        return None, (f"{path} is older than bench/{name}.cpp: it did not build from the current "
                      f"source (cmake --build {paths.build_dir()} --target {name})")
    return path, None


def pct(values, p):
    """Linear-interpolated percentile (p in 0..100); None for no data."""
    v = sorted(x for x in values if x is not None)
    if not v:
        return None
    rank = p / 100.0 * (len(v) - 1)
    lo = int(math.floor(rank))
    hi = min(lo + 1, len(v) - 1)
    return v[lo] + (rank - lo) * (v[hi] - v[lo])


def rtt_us(result, p):
    """A ping-pong round-trip percentile [us] ("p50", "p99") of dds_pingpong's JSON."""
    if f"rtt_{p}_us" in result:
        return result[f"rtt_{p}_us"]
    return (result.get("rtt_us") or {}).get(p)


def median(values):
    v = [x for x in values if x is not None]
    return statistics.median(v) if v else None


def ms(v):
    return None if v is None else round(v * 1000.0, 3)


def mb(kb):
    return None if kb is None else round(kb / 1024.0, 2)


class Domains:
    """Hands out DDS domain ids 200..230 in turn (other work uses other ids)."""

    def __init__(self):
        self.next = 200

    def take(self):
        d = self.next
        self.next = 200 if self.next >= 230 else self.next + 1
        return d


# ---------------------------------------------------------------------------------------
# /proc readers
def proc_cpu_s(pid):
    """utime + stime of a live process [s]; None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def proc_hwm_kb(pid):
    """VmHWM (peak resident set) of a live process [kB]; None if it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return None


def proc_memory_kb(pid):
    """What a live process costs the host [kB], from /proc/PID/smaps_rollup: "pss", its
    proportional share (each shared page divided among the processes that map it: the
    shared libraries and the peers' shared-memory segments), and "private", the pages no
    other process maps. RSS counts every shared page in full in every process
    (docs/BENCHMARKS.md, "Memory per agent"). None if it is gone."""
    out = {}
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                key, _, rest = line.partition(":")
                if key in ("Pss", "Private_Clean", "Private_Dirty"):
                    out[key] = int(rest.split()[0])
    except (OSError, ValueError, IndexError):
        return None
    if "Pss" not in out:
        return None
    return {"pss": out["Pss"], "private": out.get("Private_Clean", 0) + out.get("Private_Dirty", 0)}


def run_processes(parent=None):
    """{name: pid} of the target and agent processes started by this process (the launcher
    runs them as our children): 'target' and 'agent_<id>'."""
    parent = os.getpid() if parent is None else parent
    out = {}
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            if ppid != parent:
                continue
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                argv = f.read().decode(errors="replace").split("\0")
        except (OSError, IndexError, ValueError):
            continue
        exe = os.path.basename(argv[0]) if argv else ""
        if exe == "deif_target":
            out["target"] = int(pid)
        elif exe == "deif_agent" and "--id" in argv:
            out[f"agent_{argv[argv.index('--id') + 1]}"] = int(pid)
    return out


def lo_counters():
    """(tx bytes, tx packets) of the loopback interface of this network namespace."""
    with open("/proc/net/dev") as f:
        for line in f:
            name, _, rest = line.partition(":")
            if name.strip() == "lo":
                v = rest.split()
                return int(v[8]), int(v[9])
    return 0, 0


def log_unix_time(line):
    """The wall-clock time of an spdlog line '[YYYY-mm-dd HH:MM:SS.mmm] ...' (local time)."""
    m = LOG_TIME.match(line)
    if not m:
        return None
    return time.mktime(time.strptime(m.group(1), "%Y-%m-%d %H:%M:%S")) + int(m.group(2)) / 1000.0


# ---------------------------------------------------------------------------------------
# Micro-benchmarks
def run_core(quick):
    exe, why = bench_program("core_bench")
    if exe is None:
        log(f"core: skipped: {why}")
        return {"skipped": why}
    args = [exe, "--benchmark_format=json", f"--benchmark_min_time={0.02 if quick else 0.2}"]
    if quick:
        args.append("--benchmark_filter=/N:(4|16|64|256|1024)(/|$)")
    log("core micro-benchmarks")
    proc = subprocess.run(args, capture_output=True, text=True)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip()[-300:]}
    rows = []
    for b in json.loads(proc.stdout)["benchmarks"]:
        rows.append({"name": b["name"], "label": b.get("label", ""),
                     "cpu_ns": b["cpu_time"], "real_ns": b["real_time"]})
    return {"rows": rows}


def run_pingpong(exe, transport, samples, domain):
    common = ["--transport", transport, "--domain", str(domain), "--timeout", "60"]
    before = launcher.shm_snapshot()
    pong = subprocess.Popen([exe, "--role", "pong", *common], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        ping = subprocess.run([exe, "--role", "ping", "--samples", str(samples), *common],
                              capture_output=True, text=True, timeout=120)
    finally:
        try:
            pong.wait(10)
        except subprocess.TimeoutExpired:
            pong.kill()
            pong.wait()
        launcher.shm_cleanup(before)
    if ping.returncode != 0:
        return {"transport": transport, "error": ping.stderr.strip()[-300:]}
    try:
        return json.loads(ping.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {"transport": transport, "error": "no JSON on stdout: " + ping.stdout.strip()[-300:]}


def alltoall_rounds(n, quick):
    """Rounds of the all-to-all floor: a few seconds at every N (a round costs ~N^2)."""
    rounds = 3000 if n <= 8 else 600 if n <= 16 else 150 if n <= 32 else 60
    return rounds // 3 if quick else rounds


def exchange_rounds(n, mode, quick):
    """Rounds of a relayed or tree exchange: a few seconds at every N (docs/SCALING.md)."""
    rounds = alltoall_rounds(n, False) * 2 if mode == "relay" else (3000 if n <= 16 else 600)
    return rounds // 3 if quick else rounds


def summarize_runs(runs, **keys):
    """The medians of dds_alltoall runs of one kind (run_alltoall), with their errors."""
    ok = [r for r in runs if "error" not in r]
    out = dict(keys)
    out.update({"runs_ok": len(ok), "runs": len(runs),
                "rounds_per_s": median([r["rounds_per_s"] for r in ok]) if ok else None,
                "cpu_ms_per_round": median([r["cpu_ms_per_round"] for r in ok]) if ok else None,
                "cpu_us_per_delivery": median([r["cpu_us_per_delivery"] for r in ok]) if ok else None,
                "deliveries_per_round": ok[0]["deliveries_per_round"] if ok else None,
                "errors": [r["error"] for r in runs if "error" in r]})
    return out


def exchanges(n):
    """The exchanges measured beside the all-to-all floor at N (docs/SCALING.md): relay
    groups of about sqrt(N) ids, and a tree of fan-out 4. (mode, size) pairs."""
    return [("relay", max(2, round(math.sqrt(n)))), ("tree", 4)]


def deliveries(n, mode="all", size=0):
    """Sample deliveries of one round of an exchange (bench/dds_alltoall.cpp): all to all
    N (N - 1); relay groups of S: N (S - 1) within the groups plus G (N - 1) for the G
    groups' relayed samples; a tree: one up and one down per edge, 2 (N - 1)."""
    if mode == "relay":
        groups = -(-n // size)
        members = [min(n, (g + 1) * size) - g * size for g in range(groups)]
        return sum(m * (m - 1) for m in members) + groups * (n - 1)
    if mode == "tree":
        return 2 * (n - 1)
    return n * (n - 1)


def run_alltoall(exe, n, rounds, domain, timeout_s, mode="all", size=0):
    """N dds_alltoall processes on one domain (docs/BENCHMARKS.md, "The floor"): the rate of
    rounds in which every process hears every other once (directly, or through a relay or
    a tree with mode "relay"/"tree" of group size or fan-out `size`), and the CPU of all of
    them per round."""
    before = launcher.shm_snapshot()
    warmup = max(5, rounds // 10)
    extra = {"relay": ["--relay-group", str(size)], "tree": ["--tree", str(size)]}.get(mode, [])
    argv = lambda j: [exe, "--id", str(j), "--peers", str(n), "--rounds", str(rounds),  # noqa: E731
                      "--warmup", str(warmup), "--domain", str(domain), "--timeout", str(timeout_s)] + extra
    # Under the policy deif-run gives the agents, so that the lock-step is compared with a
    # floor measured alike (docs/BENCHMARKS.md, "Agents under SCHED_BATCH").
    procs = [subprocess.Popen(launcher.sched_prefix("batch") + argv(j), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
             for j in range(1, n + 1)]
    outs = []
    try:
        for p in procs:
            try:
                out, err = p.communicate(timeout=timeout_s + 30)
            except subprocess.TimeoutExpired:
                p.kill()
                out, err = p.communicate()
            outs.append((p.returncode, out, err))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        launcher.shm_cleanup(before)
    figs = []
    for code, out, err in outs:
        try:
            figs.append(json.loads(out.strip().splitlines()[-1]))
        except (ValueError, IndexError):
            return {"n": n, "mode": mode, "size": size, "rounds": rounds,
                    "error": f"exit {code}: {err.strip()[-300:]}"}
    cpu = sum(f["cpu_s"] for f in figs)
    d = deliveries(n, mode, size)
    return {"n": n, "mode": mode, "size": size, "rounds": rounds,
            "rounds_per_s": median([f["rounds_per_s"] for f in figs]),
            "slowest_rounds_per_s": min(f["rounds_per_s"] for f in figs),
            "cpu_ms_per_round": cpu * 1000.0 / rounds,
            "deliveries_per_round": d,
            "cpu_us_per_delivery": cpu * 1e6 / rounds / d}


# ---------------------------------------------------------------------------------------
# One lock-step run, watched
class Monitor(threading.Thread):
    """Samples the run's processes while it lasts: peak RSS of each, peak PSS and private
    memory (every 2 s and at s1: reading them walks the page tables), CPU and the loopback
    counters at two steady-state points (steps s0 and s1). The step is the last row of
    the run's target.csv."""

    def __init__(self, out_dir, s0, s1):
        super().__init__(daemon=True)
        self.out_dir = out_dir
        self.s0, self.s1 = s0, s1
        self.hwm_kb = {}
        self.pss_kb, self.private_kb = {}, {}
        self.marks = {}  # "s0"/"s1"/"last" -> {step, t, cpu_s, lo_bytes, lo_packets}
        self.done = threading.Event()

    def current_step(self):
        row = artefacts.last_row(os.path.join(self.out_dir, "target.csv"))
        return int(row["step"]) if row else 0

    def mark(self, key, step, pids):
        t = time.monotonic()
        cpu = {}
        for pid in pids.values():
            c = proc_cpu_s(pid)
            if c is not None:
                cpu[pid] = c
        lo_b, lo_p = lo_counters()
        self.marks[key] = {"step": step, "t": t, "cpu_s": cpu, "lo_bytes": lo_b, "lo_packets": lo_p}

    def sample_memory(self, pids):
        for name, pid in pids.items():
            m = proc_memory_kb(pid)
            if m is not None:
                self.pss_kb[name] = max(self.pss_kb.get(name, 0), m["pss"])
                self.private_kb[name] = max(self.private_kb.get(name, 0), m["private"])

    def run(self):
        last_hwm = last_scan = last_pss = 0.0
        pids = {}
        while not self.done.is_set():
            if time.monotonic() - last_scan > 0.5:  # the processes rarely change
                pids, last_scan = run_processes(), time.monotonic()
            step = self.current_step()
            if "s0" not in self.marks and step >= self.s0:
                self.mark("s0", step, pids)
            if "s0" in self.marks and "s1" not in self.marks and step >= self.s1:
                self.mark("s1", step, pids)
                self.sample_memory(pids)
            now = time.monotonic()
            # A run that does not reach s1 (a timeout) still gets a steady-state figure.
            if "s0" in self.marks and "s1" not in self.marks and now - self.marks.get(
                    "last", self.marks["s0"])["t"] > 0.5 and step > self.marks["s0"]["step"]:
                self.mark("last", step, pids)
            if now - last_hwm > 0.2 or step >= self.s1:
                for name, pid in pids.items():
                    v = proc_hwm_kb(pid)
                    if v is not None:
                        self.hwm_kb[name] = max(self.hwm_kb.get(name, 0), v)
                last_hwm = now
            if now - last_pss > 2.0 and "s0" in self.marks:
                self.sample_memory(pids)
                last_pss = now
            time.sleep(0.01)


def target_log_rate(log_dir):
    """The target's own figure: 'done at step N after X s' (from its start, the wait for
    the agents included)."""
    try:
        with open(os.path.join(log_dir, "target.log"), errors="replace") as f:
            for line in f:
                m = TARGET_DONE.search(line)
                if m and float(m.group(2)) > 0:
                    return {"steps": int(m.group(1)), "seconds": float(m.group(2)),
                            "steps_per_s": int(m.group(1)) / float(m.group(2))}
    except OSError:
        pass
    return None


def _start_observer(exe, cfg_path, n, steps, domain, run_name, work_dir, overrides=()):
    """step_observer of the run: the run's effective config (its domain and leases) and name."""
    obs_cfg = os.path.join(work_dir, f"observer-{run_name}.yaml")
    with open(obs_cfg, "w") as f:
        f.write(config.canonical_yaml(cfg_path, [f"agents.count={n}", f"scenario.steps={steps}",
                                                 f"network.domain_id={domain}", *overrides]))
    observer = subprocess.Popen([exe, "--config", obs_cfg, "--run", run_name,
                                 "--timeout", str(120 + steps)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    observer.stderr.readline()  # "ready" (or an error: then the JSON is missing)
    return observer


def _stop_observer(observer, timed_out):
    if timed_out:
        observer.send_signal(signal.SIGTERM)  # no end-of-run will come
    try:
        stdout, _ = observer.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        observer.send_signal(signal.SIGTERM)
        stdout, _ = observer.communicate()
    try:
        return json.loads(stdout)
    except ValueError:
        return None


def lockstep_run(n, steps, domain, work_dir, observer_exe=None, config_path=DEFAULT_CONFIG,
                 timeout_s=None, overrides=(), discovery_server=False, secure=False):
    """Launch a target and n agents (deif.launcher), with the step observer when given, and
    reduce the measurements. `overrides` (KEY=VALUE) go to every process, the observer's
    included; discovery_server: the launcher starts the run's Discovery Server; secure: DDS
    Security with the run's own certificates. Returns a dict of figures."""
    run_name = f"bench-n{n}-d{domain}-{random.randrange(16 ** 6):06x}"
    out_dir = os.path.join(work_dir, run_name)
    observer = None
    if observer_exe:
        shm_before = launcher.shm_snapshot()  # the observer's files are not the launcher's to remove
        observer = _start_observer(observer_exe, config_path, n, steps, domain, run_name, work_dir,
                                   overrides)
    usage_before = resource.getrusage(resource.RUSAGE_CHILDREN)
    s0 = max(1, steps // 10)
    s1 = max(s0 + 1, steps - max(1, steps // 10))
    monitor = Monitor(out_dir, s0, s1)
    t_launch = time.monotonic()
    monitor.start()
    result = None
    try:
        with open(os.devnull, "w") as quiet:
            result = launcher.run(config_path, out_dir, agents=n, steps=steps, domain=domain,
                                  run_name=run_name, progress=False, log=quiet, timeout_s=timeout_s,
                                  overrides=list(overrides), discovery_server=discovery_server,
                                  secure=secure)
    except launcher.LaunchError as e:
        return {"n": n, "steps": steps, "domain": domain, "ok": False, "error": str(e)}
    finally:
        monitor.done.set()
        monitor.join()
        summary = result.summary if result else {}
        metrics = summary.get("metrics", {})
        timed_out = summary.get("timed_out_after_s") is not None
        obs = _stop_observer(observer, timed_out or result is None) if observer else None
        if observer:
            launcher.shm_cleanup(shm_before)
    usage_after = resource.getrusage(resource.RUSAGE_CHILDREN)
    total_cpu = (usage_after.ru_utime + usage_after.ru_stime
                 - usage_before.ru_utime - usage_before.ru_stime)

    fig = {"n": n, "steps": steps, "domain": domain, "ok": result.ok,
           "timed_out_s": timeout_s if timed_out else None,
           "last_step": metrics.get("last_step"), "final_agents": metrics.get("final_agents"),
           "wall_time_s": summary.get("wall_time_s"),
           "target_rate": target_log_rate(os.path.join(out_dir, "logs")),
           "observer": "step_observer" if observer_exe else None}
    # Per-step timing seen by the observer.
    if obs:
        rows = [r for r in obs["steps"] if r[0] >= 1]
        full = [r for r in rows if r[2] is not None and r[5] is not None and r[6] >= n]
        lat = [r[5] - r[2] for r in full]
        starts = {r[0]: r[2] for r in rows if r[2] is not None}
        periods = [starts[k + 1] - starts[k] for k in sorted(starts) if k + 1 in starts]
        steady = [k for k in sorted(starts) if s0 <= k <= s1]
        rate = None
        if len(steady) >= 2:
            rate = (steady[-1] - steady[0]) / (starts[steady[-1]] - starts[steady[0]])
        first = next((r for r in rows if r[0] == 1), None)
        fig.update({
            "observed_steps": len(rows),
            "latency_ms": {"p50": ms(pct(lat, 50)), "p99": ms(pct(lat, 99)),
                           "max": ms(pct(lat, 100)), "count": len(lat)},
            "period_ms": {"p50": ms(pct(periods, 50)), "p99": ms(pct(periods, 99))},
            "steps_per_s": rate,
            "discovery_s": {
                "first_range": (first[2] - t_launch) if first and first[2] else None,
                "first_fused_any": (first[4] - t_launch) if first and first[4] else None,
                "first_fused_all": (first[5] - t_launch) if first and first[5] else None},
        })
    # Steady-state rate, CPU and wire counters between s0 and s1.
    m0, m1 = monitor.marks.get("s0"), monitor.marks.get("s1") or monitor.marks.get("last")
    if m0 and m1 and m1["step"] > m0["step"]:
        dk = m1["step"] - m0["step"]
        fig["steady"] = {"steps": dk, "seconds": m1["t"] - m0["t"],
                         "steps_per_s": dk / (m1["t"] - m0["t"]),
                         # per process, only those alive at both marks
                         "cpu_s_per_step": sum(m1["cpu_s"][p] - m0["cpu_s"][p]
                                               for p in m0["cpu_s"] if p in m1["cpu_s"]) / dk,
                         "lo_bytes_per_step": (m1["lo_bytes"] - m0["lo_bytes"]) / dk,
                         "lo_packets_per_step": (m1["lo_packets"] - m0["lo_packets"]) / dk}
    # Whole run from getrusage(RUSAGE_CHILDREN): startup, discovery and the observer included.
    fig["cpu_s_per_step_whole_run_incl_observer"] = total_cpu / max(1, metrics.get("last_step") or 1)
    for key, peaks in (("rss_mb", monitor.hwm_kb), ("pss_mb", monitor.pss_kb),
                       ("private_mb", monitor.private_kb)):
        kb = [v for k, v in peaks.items() if k.startswith("agent_")]
        fig[key] = {"agent_median": mb(median(kb)), "agent_max": mb(max(kb) if kb else None),
                    "target": mb(peaks.get("target")), "agents_sampled": len(kb)}
    fig["out_dir"] = out_dir
    return fig


def steps_per_s(fig):
    """The observer's steady-state rate, else the one from target.csv's progress."""
    if fig.get("steps_per_s") is not None:
        return fig["steps_per_s"]
    return (fig.get("steady") or {}).get("steps_per_s")


def lockstep_steps(n, quick):
    """Enough steps for a steady state; fewer for many agents (each step costs ~N^2)."""
    if quick:
        return 300 if n <= 8 else 150 if n <= 16 else 60
    return 2000 if n <= 8 else 1000 if n <= 16 else 300


def median_run(runs):
    """The run whose step latency p50 (else steps/s) is the median one (figures stay
    consistent)."""
    good = [r for r in runs if (r.get("latency_ms") or {}).get("p50") is not None]
    if good:
        good.sort(key=lambda r: r["latency_ms"]["p50"])
    else:
        good = sorted((r for r in runs if steps_per_s(r) is not None), key=steps_per_s)
    if not good:
        return dict(runs[0], repetitions=len(runs))
    return dict(good[len(good) // 2], repetitions=len(runs))


# ---------------------------------------------------------------------------------------
# Failure detection: kill -9 an agent on a scripted step, watch the survivors exclude it
FAILURE_KILL_STEP = 120     # the ring has settled at the optimum well before
FAILURE_AFTER_STEPS = 120   # the survivors re-spread within ~15 steps


def lost_lines(path, victim):
    """Times of the 'agent <victim> lost' lines of one log."""
    times = []
    try:
        with open(path, errors="replace") as f:
            for line in f:
                if f"agent {victim} lost" in line:
                    t = log_unix_time(line)
                    if t is not None:
                        times.append(t)
    except OSError:
        pass
    return times


def settled_step(metrics_rows, alive_rows, members, after_step):
    """The first step > after_step at which exactly `members` agents wrote a row, each of them
    believes `members` agents alive, and the ring's largest gap error (metrics.csv) is below
    1 degree; None if none."""
    for r in metrics_rows:
        k = int(r["step"])
        if k <= after_step or int(r["rows"]) != members:
            continue
        if all(alive.get(k) == members for alive in alive_rows.values()) and \
                float(r["gap_error"]) < math.radians(1.0):
            return k
    return None


def run_failure(kills, n, domains, work_dir, seed=7):
    """One lock-step run per kill (static target: with the figure eight the speed-limited ring
    keeps a residual of a few degrees): agent V (seeded) is killed by the launcher on step
    FAILURE_KILL_STEP. Kill-to-exclusion: each survivor's 'agent V lost' log line minus the
    wall-clock time the launcher applied the kill. Steps to 1 degree: from metrics.csv."""
    rng = random.Random(seed)
    overrides = ["target.trajectory=static"]
    lease = config.resolve(DEFAULT_CONFIG, overrides)["network"]["liveliness_lease_s"]
    steps = FAILURE_KILL_STEP + FAILURE_AFTER_STEPS
    log(f"failure detection: {kills} kills of 1 of {n} agents (lease {lease} s), one run each")
    cycles = []
    for c in range(kills):
        victim = rng.randint(1, n)
        out_dir = os.path.join(work_dir, f"failure-n{n}-{c:02d}")
        with open(os.devnull, "w") as quiet:
            res = launcher.run(DEFAULT_CONFIG, out_dir, agents=n, steps=steps,
                               domain=domains.take(), overrides=overrides,
                               faults=[launcher.Fault(FAILURE_KILL_STEP, "kill", victim, "bench")],
                               progress=False, log=quiet)
        fault = res.summary["faults"][0]
        t_kill = fault.get("applied_unix_s")
        survivors = [j for j in range(1, n + 1) if j != victim]
        exclusion = []
        for j in survivors:
            seen = lost_lines(os.path.join(out_dir, "logs", f"agent-{j}.log"), victim)
            exclusion.append(seen[0] - t_kill if seen and t_kill else None)
        metrics_rows = artefacts.read_csv(os.path.join(out_dir, "metrics.csv"))
        alive = {j: {int(r["step"]): int(r["alive"])
                     for r in artefacts.read_csv(os.path.join(out_dir, f"agent_{j}.csv"))}
                 for j in survivors}
        k_kill = fault.get("applied_at_step") or FAILURE_KILL_STEP
        alive_all = {**alive, victim: {int(r["step"]): int(r["alive"]) for r in artefacts.read_csv(
            os.path.join(out_dir, f"agent_{victim}.csv"))}}
        settled_before = settled_step(metrics_rows, alive_all, n, 0)
        k_conv = settled_step(metrics_rows, alive, n - 1, k_kill - 1)
        cycles.append({"victim": victim, "kill_step": k_kill, "ok": res.ok,
                       "settled_before_kill": settled_before is not None and settled_before < k_kill,
                       "exclusion_s": exclusion,
                       "steps_to_1deg": (k_conv - k_kill) if k_conv else None})
        log(f"  kill {c + 1}/{kills}: agent {victim} at step {k_kill}: exclusion "
            f"{', '.join('-' if s is None else '%.3f' % s for s in exclusion)} s; "
            f"{cycles[-1]['steps_to_1deg']} steps to 1 deg")
    excl = [s for c in cycles for s in c["exclusion_s"] if s is not None]
    missed = sum(1 for c in cycles for s in c["exclusion_s"] if s is None)
    conv = [c["steps_to_1deg"] for c in cycles if c["steps_to_1deg"] is not None]
    return {"n": n, "kills": len(cycles), "lease_s": lease,
            "exclusion_s": {"p50": pct(excl, 50), "p99": pct(excl, 99), "max": pct(excl, 100),
                            "samples": len(excl), "not_seen": missed},
            "steps_to_1deg": {"p50": pct(conv, 50), "max": pct(conv, 100), "samples": len(conv)},
            "cycles": cycles}


# ---------------------------------------------------------------------------------------
# Wire cost: UDP only, in a private network and mount namespace
def run_wire_inner(ns, steps, work_dir):
    """Runs inside `unshare --net --mount`: loopback only, /dev/shm read-only so Fast DDS
    cannot create its shared-memory transport and falls back to UDPv4 alone."""
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    subprocess.run(["ip", "link", "set", "lo", "multicast", "on"], check=True)
    subprocess.run(["ip", "route", "add", "224.0.0.0/4", "dev", "lo"], check=True)
    subprocess.run(["mount", "--make-rprivate", "/"], check=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", "/dev/shm"], check=True)
    out = []
    # Plain and DDS Security (docs/SECURITY.md) at every N, the secure runs after the plain
    # ones. A secure step at N = 16 takes about 5 times a plain one (docs/BENCHMARKS.md).
    for n, secure in [(n, False) for n in ns] + [(n, True) for n in ns]:
        timeout_s = 90.0 + n * n * steps / 2000.0 if secure else 40.0
        fig = lockstep_run(n, steps, 210 + len(out), work_dir, timeout_s=timeout_s, secure=secure)
        st = fig.get("steady") or {}
        if "error" in fig:
            log(f"  wire n={n}{' secure' if secure else ''}: {fig['error']}")
        out.append({"n": n, "secure": secure, "ok": fig["ok"], "last_step": fig.get("last_step"),
                    "steps_per_s_udp": st.get("steps_per_s"), "wall_time_s": fig.get("wall_time_s"),
                    "bytes_per_step": st.get("lo_bytes_per_step"),
                    "packets_per_step": st.get("lo_packets_per_step"),
                    "bytes_per_agent_per_step": (st["lo_bytes_per_step"] / n) if st else None})
        log(f"  wire n={n}{' secure' if secure else ''}: {out[-1]['bytes_per_agent_per_step']} B/agent/step")
    return out


def run_wire(entry_point, ns, steps, work_dir):
    log(f"wire cost (UDP only, private netns) for N = {ns}")
    res = subprocess.run(
        ["unshare", "--net", "--mount", "--", paths.PYTHON, entry_point,
         "--_wire-inner", ",".join(map(str, ns)), "--_steps", str(steps), "--_work", work_dir],
        capture_output=True, text=True)
    sys.stderr.write(res.stderr)
    if res.returncode != 0:
        return {"error": res.stderr.strip()[-500:]}
    every = json.loads(res.stdout)
    rows = [r for r in every if not r.get("secure")]
    # Growth: bytes per step against N, N^2 (all-to-all).
    for r in rows:
        if r["bytes_per_step"]:
            r["bytes_per_step_over_n2"] = r["bytes_per_step"] / (r["n"] ** 2)
    secure = []
    for r in (r for r in every if r.get("secure")):
        plain = next((p for p in rows if p["n"] == r["n"]), {})
        ratio = (r["bytes_per_step"] / plain["bytes_per_step"]
                 if r["bytes_per_step"] and plain.get("bytes_per_step") else None)
        secure.append(dict(r, plain_bytes_per_step=plain.get("bytes_per_step"),
                           plain_steps_per_s_udp=plain.get("steps_per_s_udp"),
                           bytes_ratio_secure_over_plain=ratio))
    return {"method": "lo tx bytes in a private network namespace, UDPv4 only", "rows": rows,
            "secure_rows": secure}


# ---------------------------------------------------------------------------------------
# Tables
def fmt(v, spec=".1f", none="-"):
    return none if v is None else format(v, spec)


def _finished(f):
    if f.get("timed_out_s"):
        return f"NO (stopped at {f['timed_out_s']} s)"
    if f.get("ok") and f.get("last_step") == f.get("steps"):
        return "ok"
    return "FAILED"


def make_table(res):
    lines = []
    for section, why in sorted((res.get("skipped") or {}).items()):
        lines.append(f"_{section}: skipped: {why}_")
        lines.append("")
    pp = res.get("pingpong")
    if pp:
        lines.append("**Raw floor (dds_pingpong, Contribution, project QoS)**")
        lines.append("")
        lines.append("| transport | round trip p50 [us] | p99 [us] | runs |")
        lines.append("| --- | --- | --- | --- |")
        for t in ("shm", "udp"):
            runs = pp.get(t, [])
            lines.append(f"| {t} | {fmt(median([rtt_us(r, 'p50') for r in runs]))} | "
                         f"{fmt(median([rtt_us(r, 'p99') for r in runs]))} | {len(runs)} |")
        lines.append("")
    if res.get("alltoall"):
        lines.append("**All-to-all floor (dds_alltoall: N processes, each hears every other once a round; "
                     "no range, no state, no maths)**")
        lines.append("")
        lines.append("| N | rounds/s | CPU per round, all processes [ms] | CPU per delivery [us] "
                     "| lock-step steps/s, same invocation | lock-step / floor | runs |")
        lines.append("| --- | --- | --- | --- | --- | --- | --- |")
        for n, f in sorted(res["alltoall"].items(), key=lambda kv: int(kv[0])):
            lk = steps_per_s((res.get("lockstep") or {}).get(n) or {})
            ratio = lk / f["rounds_per_s"] if lk and f.get("rounds_per_s") else None
            lines.append(f"| {n} | {fmt(f.get('rounds_per_s'), '.1f')} | {fmt(f.get('cpu_ms_per_round'), '.2f')} | "
                         f"{fmt(f.get('cpu_us_per_delivery'), '.0f')} | {fmt(lk, '.1f')} | {fmt(ratio, '.2f')} | "
                         f"{f['runs_ok']}/{f['runs']} |")
        lines.append("")
    if res.get("exchanges"):
        lines.append("**Exchanges that scale (dds_alltoall --relay-group S / --tree F: every process hears of "
                     "every other once a round, through a relay or a tree; docs/SCALING.md)**")
        lines.append("")
        lines.append("| N | exchange | deliveries per round | rounds/s | / all-to-all, same invocation "
                     "| CPU per round, all processes [ms] | CPU per delivery [us] | runs |")
        lines.append("| --- | --- | --- | --- | --- | --- | --- | --- |")
        for f in sorted(res["exchanges"], key=lambda e: (e["n"], e["mode"], e["size"])):
            a2a = ((res.get("alltoall") or {}).get(str(f["n"])) or {}).get("rounds_per_s")
            ratio = f["rounds_per_s"] / a2a if a2a and f.get("rounds_per_s") else None
            name = f"relay groups of {f['size']}" if f["mode"] == "relay" else f"tree, fan-out {f['size']}"
            lines.append(f"| {f['n']} | {name} | {fmt(f.get('deliveries_per_round'), 'd')} | "
                         f"{fmt(f.get('rounds_per_s'), '.1f')} | {fmt(ratio, '.1f')} | "
                         f"{fmt(f.get('cpu_ms_per_round'), '.2f')} | {fmt(f.get('cpu_us_per_delivery'), '.0f')} | "
                         f"{f['runs_ok']}/{f['runs']} |")
        lines.append("")
    if res.get("lockstep"):
        lines.append("**Lock-step (1 target + N agent processes, this host)**")
        lines.append("")
        lines.append("| N | finished | steps/s (observed) | steps/s (steady, target.csv) | steps/s (target log, its wait for the agents included) "
                     "| step latency p50 [ms] | p99 [ms] | discovery to first fused step [s] | CPU per step [ms] "
                     "| peak RSS per agent, median / max [MB] | peak PSS per agent, median / max [MB] |")
        lines.append("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        variants = [(int(n), "", f) for n, f in res["lockstep"].items()] + \
            [(int(n), ", " + other_membership(int(n)).split(".")[1].replace("=", " "), f)
             for n, f in (res.get("lockstep_other_membership") or {}).items()]
        for n, variant, f in sorted(variants, key=lambda v: (v[0], v[1])):
            st = f.get("steady") or {}
            cpu = st.get("cpu_s_per_step")
            lines.append(
                f"| {n}{variant} | {f.get('last_step')}/{f.get('steps')} {_finished(f)} | "
                f"{fmt(f.get('steps_per_s'), '.0f')} | {fmt(st.get('steps_per_s'), '.0f')} | "
                f"{fmt((f.get('target_rate') or {}).get('steps_per_s'), '.0f')} | "
                f"{fmt((f.get('latency_ms') or {}).get('p50'), '.2f')} | {fmt((f.get('latency_ms') or {}).get('p99'), '.2f')} | "
                f"{fmt((f.get('discovery_s') or {}).get('first_fused_all'), '.2f')} | "
                f"{fmt(cpu * 1000 if cpu is not None else None, '.2f')} | "
                f"{fmt((f.get('rss_mb') or {}).get('agent_median'))} / {fmt((f.get('rss_mb') or {}).get('agent_max'))} | "
                f"{fmt((f.get('pss_mb') or {}).get('agent_median'))} / {fmt((f.get('pss_mb') or {}).get('agent_max'))} |")
        lines.append("")
    g = res.get("goals", {})
    if g.get("rows"):
        lines.append("**Goals**")
        lines.append("")
        lines.append("| goal | measured | met |")
        lines.append("| --- | --- | --- |")
        for row in g["rows"]:
            lines.append(f"| {row['goal']} | {row['measured']} | {row['met']} |")
        lines.append("")
    fl = res.get("failure")
    if fl and "exclusion_s" in fl:
        e, c = fl["exclusion_s"], fl["steps_to_1deg"]
        lines.append(f"**Failure detection** (N = {fl['n']}, {fl['kills']} kills, liveliness lease "
                     f"{fl['lease_s']} s): kill-to-exclusion at every survivor p50 {fmt(e['p50'], '.3f')} s, "
                     f"p99 {fmt(e['p99'], '.3f')} s, max {fmt(e['max'], '.3f')} s ({e['samples']} samples, "
                     f"{e['not_seen']} not seen); steps until the survivors' gaps are within 1 degree of "
                     f"the new optimum: p50 {fmt(c['p50'], '.0f')}, max {fmt(c['max'], '.0f')}.")
        lines.append("")
    w = res.get("wire")
    if w and "rows" in w:
        lines.append("**Wire cost** (UDPv4 only, loopback of a private network namespace)")
        lines.append("")
        lines.append("| N | bytes per step (all processes) | bytes per agent per step | packets per step | bytes per step / N^2 | steps/s over UDP |")
        lines.append("| --- | --- | --- | --- | --- | --- |")
        for r in w["rows"]:
            lines.append(f"| {r['n']} | {fmt(r['bytes_per_step'], '.0f')} | {fmt(r['bytes_per_agent_per_step'], '.0f')} | "
                         f"{fmt(r['packets_per_step'], '.1f')} | {fmt(r.get('bytes_per_step_over_n2'), '.0f')} | "
                         f"{fmt(r['steps_per_s_udp'], '.0f')} |")
        lines.append("")
        if w.get("secure_rows"):
            lines.append("**Wire cost with DDS Security** (same namespace, same steps; plain from the table above)")
            lines.append("")
            lines.append("| N | bytes per step, plain | secure | secure / plain | steps/s over UDP, plain / secure |")
            lines.append("| --- | --- | --- | --- | --- |")
            for r in w["secure_rows"]:
                lines.append(f"| {r['n']} | {fmt(r['plain_bytes_per_step'], '.0f')} | {fmt(r['bytes_per_step'], '.0f')} | "
                             f"{fmt(r['bytes_ratio_secure_over_plain'], '.2f')} | "
                             f"{fmt(r['plain_steps_per_s_udp'], '.0f')} / {fmt(r['steps_per_s_udp'], '.0f')} |")
            lines.append("")
    elif w and "error" in w:
        lines.append(f"_wire: failed: {w['error'].splitlines()[-1] if w['error'] else '?'}_")
        lines.append("")
    if res.get("network"):
        from .bench_network import make_table as network_table
        lines.append(network_table(res["network"]))
    if res.get("realtime"):
        from .bench_network import realtime_table
        lines.append(realtime_table(res["realtime"]))
    if res.get("security"):
        from .bench_security import make_table as security_table
        lines.append(security_table(res["security"]))
    if res.get("hostile"):
        from .bench_hostile import make_table as hostile_table
        lines.append(hostile_table(res["hostile"]))
    if res.get("discovery"):
        from .bench_discovery import make_table as discovery_table
        lines.append(discovery_table(res["discovery"]))
    core = (res.get("core") or {}).get("rows")
    if core:
        lines.append("**Core micro-benchmarks** (CPU time per call [us])")
        lines.append("")
        wanted = {"BM_DeifAgentStep": "model:0", "BM_NextAngle": "law:2", "BM_PcrlbStep": "model:0"}
        ns = [4, 16, 64, 256, 1024]
        lines.append("| benchmark | " + " | ".join(f"N={n}" for n in ns) + " |")
        lines.append("| --- |" + " --- |" * len(ns))
        for bm, variant in wanted.items():
            cells = []
            for n in ns:
                hit = [r for r in core if r["name"] == f"{bm}/N:{n}/{variant}"]
                cells.append(fmt(hit[0]["cpu_ns"] / 1000.0, ".2f") if hit else "-")
            lines.append(f"| {bm} ({variant}) | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def evaluate_goals(res):
    rows = []
    lock = res.get("lockstep") or {}
    l4 = lock.get("4")
    shm = (res.get("pingpong") or {}).get("shm_p50_us_median")
    yes_no = lambda ok: "-" if ok is None else "yes" if ok else "no"  # noqa: E731
    if l4 is not None:
        ratio = None
        lat = (l4.get("latency_ms") or {}).get("p50")
        if shm and lat:
            ratio = lat * 1000.0 / shm
        res["ratio_4_agent_latency_to_shm_rtt"] = ratio
        rows.append({"goal": f"4 agents: step latency p50 <= {GOALS['latency_ratio_4']:.0f} x SHM round trip p50",
                     "measured": f"{fmt(ratio, '.1f')} x ({fmt(lat, '.2f')} ms vs {fmt(shm, '.0f')} us)",
                     "met": yes_no(None if ratio is None else ratio <= GOALS["latency_ratio_4"])})
        rate = steps_per_s(l4)
        rows.append({"goal": f"4 agents: >= {GOALS['steps_per_s_4']:.0f} steps/s",
                     "measured": f"{fmt(rate, '.0f')} steps/s",
                     "met": yes_no(None if rate is None else rate >= GOALS["steps_per_s_4"])})
    l64 = lock.get("64")
    if l64:
        fin = l64.get("ok") and l64.get("last_step") == l64.get("steps") and l64.get("final_agents") == 64
        rows.append({"goal": "64 agents run the lock-step scenario to the end (default config)",
                     "measured": f"step {l64.get('last_step')}/{l64.get('steps')}, {l64.get('final_agents')} agents at the end",
                     "met": "yes" if fin else "no"})
        rate = steps_per_s(l64)
        rows.append({"goal": f"64 agents: >= {GOALS['steps_per_s_64']:.0f} steps/s",
                     "measured": f"{fmt(rate, '.1f')} steps/s",
                     "met": yes_no(None if rate is None else rate >= GOALS["steps_per_s_64"])})
        cpu = (l64.get("steady") or {}).get("cpu_s_per_step")
        per_agent = cpu * 1000.0 / 65 if cpu is not None else None
        rows.append({"goal": f"64 agents: CPU per agent per step <= {GOALS['cpu_ms_per_agent_step_64']} ms",
                     "measured": f"{fmt(per_agent, '.2f')} ms (all 65 processes / 65)",
                     "met": yes_no(None if per_agent is None else per_agent <= GOALS["cpu_ms_per_agent_step_64"])})
        disc = (l64.get("discovery_s") or {}).get("first_fused_all")
        rows.append({"goal": f"64 agents: launch to the first step fused by all <= {GOALS['discovery_s_64']:.0f} s",
                     "measured": f"{fmt(disc, '.1f')} s",
                     "met": yes_no(None if disc is None else disc <= GOALS["discovery_s_64"])})
    fl = res.get("failure")
    if fl and "exclusion_s" in fl:
        p99 = fl["exclusion_s"]["p99"]
        rows.append({"goal": "kill-to-exclusion p99 < 0.5 s",
                     "measured": f"{fmt(p99, '.3f')} s (lease {fl['lease_s']} s)",
                     "met": "yes" if p99 is not None and p99 < GOALS["exclusion_p99_s"] and fl["exclusion_s"]["not_seen"] == 0 else "no"})
    if lock:
        worst = max([(f.get("rss_mb") or {}).get("agent_max") or 0 for f in lock.values()] or [0])
        rows.append({"goal": f"resident memory <= {GOALS['rss_mb']:.0f} MB per agent (every N)",
                     "measured": f"max {fmt(worst)} MB", "met": "yes" if worst and worst <= GOALS["rss_mb"] else "no"})
        # The same bound on what an agent costs the host: its proportional share of the
        # shared libraries and segments that RSS counts in full in every process.
        pss = [(f.get("pss_mb") or {}).get("agent_max") for f in lock.values()]
        if pss and all(v is not None for v in pss):
            rows.append({"goal": f"proportional memory (PSS) <= {GOALS['rss_mb']:.0f} MB per agent (every N)",
                         "measured": f"max {fmt(max(pss))} MB", "met": yes_no(max(pss) <= GOALS["rss_mb"])})
    res["goals"] = {"rows": rows}


# ---------------------------------------------------------------------------------------
def keep_failed_runs(work_dir, dest):
    """Moves every run folder under work_dir whose summary.json does not say ok (or that has
    none: the launcher never finished it) to dest, so that a run that failed can be read
    afterwards; returns the paths kept. A run folder is one with a config.yaml."""
    kept = []
    for folder, _dirs, files in sorted(os.walk(work_dir)):
        if "config.yaml" not in files:
            continue
        try:
            with open(os.path.join(folder, "summary.json")) as f:
                ok = json.load(f).get("ok") is True
        except (OSError, ValueError):
            ok = False
        if not ok:
            target = os.path.join(dest, os.path.relpath(folder, work_dir).replace(os.sep, "-"))
            os.makedirs(dest, exist_ok=True)
            shutil.move(folder, target)
            kept.append(target)
    return kept


def run(sections, quick=False, agents=None, keep_runs=False, entry_point=None):
    """Runs the sections; writes bench/results/<stamp>.json and .md; returns (results, the
    tables as Markdown, the JSON path)."""
    ns = [int(x) for x in (agents or ("2,4,8,64" if quick else "2,4,8,16,32,64")).split(",")]
    reps = 1 if quick else 3
    domains = Domains()
    work_dir = tempfile.mkdtemp(prefix="deif-bench-")
    started = time.time()
    stamp = datetime.datetime.now().strftime("%Y-%m-%dT%H%M%S")
    res = {"date": stamp, "quick": quick, "sections": sorted(sections), "host": os.uname().nodename,
           "cpus": os.cpu_count(), "loadavg_start": os.getloadavg(), "build_dir": paths.build_dir(),
           "goals_def": GOALS, "skipped": {}}
    try:
        if "core" in sections:
            core = run_core(quick)
            if "skipped" in core:
                res["skipped"]["core"] = core["skipped"]
            else:
                res["core"] = core
        pingpong_exe = observer_exe = None
        if "pingpong" in sections:
            pingpong_exe, why = bench_program("dds_pingpong")
            if why:
                log(f"pingpong: skipped: {why}")
                res["skipped"]["pingpong"] = why
        alltoall_exe = None
        if "alltoall" in sections:
            alltoall_exe, why = bench_program("dds_alltoall")
            if why:
                log(f"alltoall: skipped: {why}")
                res["skipped"]["alltoall"] = why
        if "lockstep" in sections or "discovery" in sections:
            observer_exe, why = bench_program("step_observer")
            if why:
                # The observer is one more matched reader on every writer: the step rates of
                # runs with and without it differ (about a fifth at 4 agents, docs/BENCHMARKS.md).
                lacks = "no latency or discovery figures, and step rates not comparable with runs that had the observer"
                log(f"lockstep: {lacks}: {why}")
                res["skipped"]["step_observer"] = f"{why}; {lacks}"
        pp = {"shm": [], "udp": []}
        lock, lock_alt, floor, exch = {}, {}, {}, {}
        if pingpong_exe or alltoall_exe or "lockstep" in sections:
            samples = 1000 if quick else 5000
            # The baseline and the lock-step runs side by side: ping-pong, then lock-step.
            for rep in range(reps):
                if pingpong_exe:
                    for t in ("shm", "udp"):
                        log(f"ping-pong {t} ({samples} samples)")
                        pp[t].append(run_pingpong(pingpong_exe, t, samples, domains.take()))
                for n in ns if alltoall_exe else ():
                    rounds = alltoall_rounds(n, quick)
                    log(f"all-to-all N={n}, {rounds} rounds (rep {rep + 1}/{reps})")
                    floor.setdefault(n, []).append(
                        run_alltoall(alltoall_exe, n, rounds, domains.take(), 60.0 if n <= 16 else 150.0))
                    for mode, size in exchanges(n) if n >= 4 else ():
                        rounds = exchange_rounds(n, mode, quick)
                        log(f"{mode} exchange ({size}) N={n}, {rounds} rounds (rep {rep + 1}/{reps})")
                        exch.setdefault((n, mode, size), []).append(
                            run_alltoall(alltoall_exe, n, rounds, domains.take(), 60.0 if n <= 16 else 150.0,
                                         mode, size))
                if "lockstep" in sections:
                    for n in ns:
                        steps = lockstep_steps(n, quick)
                        log(f"lock-step N={n}, {steps} steps (rep {rep + 1}/{reps})")
                        cap = (20.0 if n <= 8 else 75.0) if quick else (60.0 if n <= 8 else 150.0)
                        lock.setdefault(n, []).append(
                            lockstep_run(n, steps, domains.take(), work_dir, observer_exe,
                                         DEFAULT_CONFIG, timeout_s=cap))
                        if n >= TREE_FROM_AGENTS:
                            # The other membership (docs/PROTOCOL.md, "Membership from the roll
                            # call"), side by side with the default in the same invocation.
                            other = other_membership(n)
                            log(f"lock-step N={n}, {other}, {steps} steps (rep {rep + 1}/{reps})")
                            lock_alt.setdefault(n, []).append(
                                lockstep_run(n, steps, domains.take(), work_dir, observer_exe,
                                             DEFAULT_CONFIG, timeout_s=cap, overrides=[other]))
            if pingpong_exe:
                pp["shm_p50_us_median"] = median([rtt_us(r, "p50") for r in pp["shm"]])
                pp["udp_p50_us_median"] = median([rtt_us(r, "p50") for r in pp["udp"]])
                res["pingpong"] = pp
            if floor:
                res["alltoall_runs"] = {str(n): v for n, v in floor.items()}
                res["alltoall"] = {str(n): summarize_runs(runs, n=n) for n, runs in floor.items()}
            if exch:
                res["exchanges_runs"] = {f"{n} {mode} {size}": v for (n, mode, size), v in exch.items()}
                res["exchanges"] = [summarize_runs(runs, n=n, mode=mode, size=size)
                                    for (n, mode, size), runs in sorted(exch.items())]
            if lock:
                res["lockstep_runs"] = {str(n): v for n, v in lock.items()}
                res["lockstep"] = {str(n): median_run(v) for n, v in lock.items()}
            if lock_alt:
                res["lockstep_other_membership_runs"] = {str(n): v for n, v in lock_alt.items()}
                res["lockstep_other_membership"] = {str(n): median_run(v) for n, v in lock_alt.items()}
        if "failure" in sections:
            res["failure"] = run_failure(3 if quick else 20, 4, domains, work_dir)
        if "wire" in sections:
            if entry_point is None:
                res["skipped"]["wire"] = "needs the entry point to re-run itself in a namespace"
            else:
                res["wire"] = run_wire(entry_point, [2, 4, 8] if quick else [2, 4, 8, 16],
                                       200 if quick else 1000, work_dir)
        if "network" in sections:
            from .bench_network import run_network
            res["network"] = run_network(quick, domains, work_dir)
        if "realtime" in sections:
            from .bench_network import run_realtime_scale
            res["realtime"] = run_realtime_scale([16, 64] if quick else [16, 32, 64], domains, work_dir,
                                                 100 if quick else 200)
        if "security" in sections:
            from .bench_security import run_security
            res["security"] = run_security(quick, domains, work_dir)
        if "hostile" in sections:
            from .bench_hostile import run_hostile
            res["hostile"] = run_hostile(quick, domains, work_dir)
        if "discovery" in sections and observer_exe:
            from .bench_discovery import run_discovery
            res["discovery"] = run_discovery([16, 64] if agents is None else ns, reps, domains,
                                             work_dir, observer_exe)
    finally:
        if not keep_runs:
            kept = keep_failed_runs(work_dir, os.path.join(RESULTS_DIR, f"{stamp}-failed"))
            if kept:
                log(f"runs that did not finish well kept in {os.path.dirname(kept[0])}: "
                    + ", ".join(os.path.basename(k) for k in kept))
            shutil.rmtree(work_dir, ignore_errors=True)
        else:
            log(f"run folders kept in {work_dir}")
    res["elapsed_s"] = time.time() - started
    res["loadavg_end"] = os.getloadavg()
    evaluate_goals(res)
    table = (f"_Measured {stamp} by `scripts/deif-bench{' --quick' if quick else ''}` on "
             f"{os.uname().nodename} ({os.cpu_count()} CPUs), sections {', '.join(sorted(sections))}._\n\n"
             + make_table(res))
    os.makedirs(RESULTS_DIR, exist_ok=True)
    path = os.path.join(RESULTS_DIR, f"{stamp}.json")
    with open(path, "w") as f:
        json.dump(res, f, indent=1)
    with open(os.path.join(RESULTS_DIR, f"{stamp}.md"), "w") as f:
        f.write(table + "\n")
    return res, table, path
