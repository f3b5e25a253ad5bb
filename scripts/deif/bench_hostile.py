"""The hostile section of scripts/deif-bench (docs/BENCHMARKS.md, "Hostile peers"): the
lock-step rate of a 4-agent run (the default config) while deif_hostile
(tests/multiprocess/hostile_peer.cpp) attacks it, next to an undisturbed run, alternating
in one invocation so that both see the same machine load. Each figure is the median over the
repetitions; the ratio is undisturbed / attacked (goal: the attacked run within 2x).

The rate is measured from step 30, when the attack starts, to the end of the run. The
estimate's quality is the run's own metrics (summary.json, computed by the C++ core): the
ANEES (about 2 for an estimate consistent with its own covariance in 2-D) and the RMSE.
Reports figures; asserts nothing.
Every run is over UDPv4, and the flood runs at a lower CPU priority (nice 10), as in
mp_hostile_flood: a flooder on another host spends its own CPU, and over shared memory a
flooder on the same host delivers every sample (docs/FASTDDS_NOTES.md).
"""
import os
import subprocess
import time

from . import launcher, paths

ATTACKS = ("none", "contributions", "truth", "ranges", "states", "impersonate", "flood")
GOAL_RATIO = 2.0  # every attacked run within 2x of the undisturbed rate
AGENTS = 4
START_STEP = 30


def _median(values):
    from .bench import median
    values = [v for v in values if v is not None]
    return median(values) if values else None


def _one(attack, steps, seconds, domain, work_dir, rep):
    from .bench import DEFAULT_CONFIG
    overrides = ["network.transport=udp"]  # every case, so that the flood's compares alike
    out_dir = os.path.join(work_dir, f"hostile-{attack}-{rep}")
    lau = launcher.Launcher(DEFAULT_CONFIG, out_dir, agents=AGENTS, steps=steps, domain=domain,
                            overrides=overrides, progress=False)
    fig = {"attack": attack, "ok": False}
    try:
        lau.start()
        lau.wait_for_step(START_STEP)
        t0, s0 = time.monotonic(), lau.current_step()
        if attack != "none":
            argv = [paths.executable("deif_hostile"), "--config", lau.config_path, "--run",
                    lau.run_name, "--attack", attack, "--follow", lau.out_dir]
            if attack in ("flood", "impersonate"):
                argv += ["--seconds", str(seconds)]
            h = subprocess.run(argv, capture_output=True, text=True, timeout=120,
                               preexec_fn=(lambda: os.nice(10)) if attack == "flood" else None)
            fig["hostile_exit"] = h.returncode
            sent = [line for line in h.stdout.splitlines() if line.startswith("sent ")]
            fig["sent"] = int(sent[0].split()[1]) if sent else None
        lau.wait()
        t1, s1 = time.monotonic(), lau.current_step()
    finally:
        lau.terminate_all()
        res = lau.finish()
    fig["ok"] = bool(res.ok)
    fig["steps_per_s"] = (s1 - s0) / (t1 - t0) if t1 > t0 and s1 > s0 else None
    metrics = res.summary.get("metrics", {})
    fig["anees"], fig["rmse_m"] = metrics.get("anees"), metrics.get("rmse_m")
    counters = res.summary.get("counters", {})
    fig["rejected"] = {k: v.get("rejected", 0) + v.get("dropped", 0) for k, v in counters.items()}
    return fig


def run_hostile(quick, domains, work_dir):
    from .bench import log
    reps = 1 if quick else 3
    steps = 3000 if quick else 8000
    seconds = 3.0 if quick else 8.0
    out = {"reps": reps, "steps": steps, "seconds": seconds, "runs": {}}
    for rep in range(reps):
        order = ATTACKS if rep % 2 == 0 else tuple(reversed(ATTACKS))
        for attack in order:
            log(f"hostile: {attack}, N={AGENTS}, {steps} steps (rep {rep + 1}/{reps})")
            out["runs"].setdefault(attack, []).append(
                _one(attack, steps, seconds, domains.take(), work_dir, rep))
    return summarize(out)


def summarize(out):
    """Adds the medians per attack and the goal to out (its "runs": attack -> [figures])."""
    base = _median([f["steps_per_s"] for f in out["runs"].get("none", []) if f["ok"]])
    out["medians"] = {}
    for attack, runs in out["runs"].items():
        rate = _median([f["steps_per_s"] for f in runs if f["ok"]])
        out["medians"][attack] = {
            "steps_per_s": rate,
            "slowdown": (base / rate) if base and rate else None,
            "anees": _median([f["anees"] for f in runs]),
            "rmse_m": _median([f["rmse_m"] for f in runs]),
            "sent": _median([f.get("sent") for f in runs]),
            "runs_ok": sum(1 for f in runs if f["ok"]),
        }
    slowdowns = [m["slowdown"] for a, m in out["medians"].items() if a != "none"]
    if slowdowns and all(s is not None for s in slowdowns):
        out["goal"] = {"name": f"every attacked run within {GOAL_RATIO}x of the undisturbed rate",
                       "worst": max(slowdowns), "met": max(slowdowns) <= GOAL_RATIO}
    return out


def make_table(h):
    lines = [f"**Hostile peers** (N = {AGENTS}, lock-step, default config over UDPv4, {h['steps']} steps, "
             f"attack from step {START_STEP}; medians of {h['reps']} run(s); "
             "slowdown = undisturbed rate / attacked rate)", "",
             "| attack | sent | rate [steps/s] | slowdown | ANEES | RMSE [m] | runs ok |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for attack in ATTACKS:
        m = h.get("medians", {}).get(attack)
        if not m:
            continue
        fmt = (lambda v, spec: "-" if v is None else format(v, spec))
        lines.append(f"| {attack} | {fmt(m['sent'], '.0f')} | {fmt(m['steps_per_s'], '.0f')} | "
                     f"{fmt(m['slowdown'], '.2f')} | {fmt(m['anees'], '.2f')} | "
                     f"{fmt(m['rmse_m'], '.4f')} | {m['runs_ok']}/{h['reps']} |")
    lines.append("")
    goal = h.get("goal")
    if goal:
        lines.append(f"Goal: {goal['name']}: worst slowdown {goal['worst']:.2f}: "
                     f"**{'met' if goal['met'] else 'not met'}**.")
        lines.append("")
    return "\n".join(lines)
