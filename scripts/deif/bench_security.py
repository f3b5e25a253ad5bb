"""The security section of scripts/deif-bench (docs/BENCHMARKS.md, "Security"): the same
lock-step run with and without DDS Security (docs/SECURITY.md), alternating secure and plain
runs in one invocation so that both see the same machine load, each figure the median over
the repetitions and the ratio secure/plain. Reports figures; asserts nothing.

Cases: N = 4 over shared memory (the default transport) and over UDPv4, N = 16 over UDPv4.
A secure run of 16 agents over shared memory did not start on the 2-core machine of
docs/BENCHMARKS.md (0 of 3 runs; docs/SECURITY.md, "Known limits"), so that case would
only measure timeouts.

Every run is bench.lockstep_run (the step observer included). The secure runs use one
folder of certificates per N, issued once before the runs (scripts/deif-certs's module, for
any run name): the processes get `network.security.enabled` and `network.security.dir` as
overrides, and the step observer, whose participant is named "bench-observer", gets a copy
of the observer-1 identity under that name (the name only picks the files; the
certificate's subject is what the permissions grant).
"""
import os
import shutil

from . import certs

CASES = ((4, "shm"), (4, "udp"), (16, "udp"))  # (N, network.transport)
GOAL_CASE = (4, "shm")
# Where the secure time goes (docs/BENCHMARKS.md, "Security"): at GOAL_CASE also runs whose
# governance protects less. "submessages-none" is `scripts/deif-certs --submessages none`;
# "no-crypto" authenticates and checks permissions but neither signs nor encrypts anything
# of the user topics: a measurement only, not a configuration anyone should run.
LEVELS = ("submessages-none", "no-crypto")
GOAL_RATIO = 1.5  # secure lock-step at N = 4 within 1.5x of plain (steps/s)

# (key, label, unit, getter, higher is better)
FIGURES = (
    ("steps_per_s", "lock-step rate", "steps/s", lambda f: _steps_per_s(f), True),
    ("latency_p50_ms", "step latency p50", "ms", lambda f: (f.get("latency_ms") or {}).get("p50"), False),
    ("latency_p99_ms", "step latency p99", "ms", lambda f: (f.get("latency_ms") or {}).get("p99"), False),
    ("cpu_ms_per_step", "CPU per step (all processes)", "ms",
     lambda f: _times((f.get("steady") or {}).get("cpu_s_per_step"), 1e3), False),
    ("discovery_s", "launch to first step fused by all", "s",
     lambda f: (f.get("discovery_s") or {}).get("first_fused_all"), False),
    # A run that lost agents on the way measures its breakdown, not the cost of security.
    ("final_agents", "agents alive at the end", "agents", lambda f: f.get("final_agents"), True),
)


def _times(v, k):
    return None if v is None else v * k


def _steps_per_s(fig):
    from .bench import steps_per_s
    return steps_per_s(fig)


def _median(values):
    from .bench import median
    values = [v for v in values if v is not None]
    return median(values) if values else None


def _key(n, transport):
    return f"{n} {transport}"


def _certs_for(n, work_dir, level="secure"):
    """A folder with the files of the target, agent-1..N and the step observer, under the
    governance of `level` ("secure" or one of LEVELS)."""
    folder = os.path.join(work_dir, f"security-certs-n{n}-{level}")
    certs.ensure(folder, n, observers=1,
                 submessages="SIGN" if level == "secure" else "NONE",
                 payloads="NONE" if level == "no-crypto" else "ENCRYPT")
    for suffix in (".cert.pem", ".key.pem", ".permissions.p7s"):
        shutil.copy(os.path.join(folder, "observer-1" + suffix),
                    os.path.join(folder, "bench-observer" + suffix))
    return folder


def run_security(quick, domains, work_dir):
    from .bench import (DEFAULT_CONFIG, bench_program, lockstep_run, lockstep_steps, log)
    observer_exe, why = bench_program("step_observer")
    if why:
        log(f"security: no step latency or discovery figures: {why}")
    reps = 1 if quick else 3
    out = {"reps": reps, "runs": {}, "skipped_observer": why}
    folders = {(n, "secure"): _certs_for(n, work_dir) for n in sorted({n for n, _ in CASES})}
    folders.update({(GOAL_CASE[0], level): _certs_for(GOAL_CASE[0], work_dir, level)
                    for level in LEVELS})
    for rep in range(reps):
        for n, transport in CASES:
            steps = lockstep_steps(n, quick)
            cap = (60.0 if n <= 8 else 150.0) if quick else (120.0 if n <= 8 else 300.0)
            # Alternate which goes first, so that neither always meets the other's leftovers.
            modes = ("secure", "plain") + (LEVELS if (n, transport) == GOAL_CASE else ())
            order = modes if rep % 2 == 0 else modes[::-1]
            for mode in order:
                overrides = [f"network.transport={transport}"]
                if mode != "plain":
                    overrides += ["network.security.enabled=true",
                                  f"network.security.dir={folders[(n, mode)]}"]
                log(f"security: {mode} lock-step N={n} over {transport}, {steps} steps "
                    f"(rep {rep + 1}/{reps})")
                fig = lockstep_run(n, steps, domains.take(), work_dir, observer_exe,
                                   DEFAULT_CONFIG, timeout_s=cap, overrides=overrides)
                out["runs"].setdefault(_key(n, transport), {}).setdefault(mode, []).append(fig)
    out["medians"] = {}
    for n, modes in out["runs"].items():
        row = {}
        for key, _, _, get, _ in FIGURES:
            plain = _median([get(f) for f in modes.get("plain", []) if f.get("ok")])
            secure = _median([get(f) for f in modes.get("secure", []) if f.get("ok")])
            row[key] = {"plain": plain, "secure": secure,
                        "ratio": (secure / plain) if plain and secure is not None else None}
        row["runs_ok"] = {m: sum(1 for f in v if f.get("ok")) for m, v in modes.items()}
        out["medians"][n] = row
        for level in (lv for lv in LEVELS if lv in modes):
            fig = {key: _median([get(f) for f in modes[level] if f.get("ok")])
                   for key, _, _, get, _ in FIGURES}
            fig["runs_ok"] = row["runs_ok"].get(level, 0)
            out.setdefault("levels", {}).setdefault(n, {})[level] = fig
    goal = (out["medians"].get(_key(*GOAL_CASE)) or {}).get("steps_per_s") or {}
    if goal.get("ratio"):
        slowdown = 1.0 / goal["ratio"]
        out["goal"] = {"name": f"secure lock-step at N = {GOAL_CASE[0]} ({GOAL_CASE[1]}) "
                               f"within {GOAL_RATIO}x of plain",
                       "plain_over_secure": slowdown, "met": slowdown <= GOAL_RATIO}
    return out


def _fmt(v, unit):
    if v is None:
        return "-"
    if unit in ("steps/s", "agents"):
        return f"{v:.0f}"
    if unit == "s":
        return f"{v:.2f}"
    return f"{v:.2f}" if v < 10 else f"{v:.1f}"


def make_table(sec):
    lines = [f"**Security** (lock-step, secure and plain alternating in one invocation, "
             f"medians of {sec['reps']} run(s) each; ratio = secure / plain)", "",
             "| N, transport | figure | plain | secure | ratio |", "| --- | --- | --- | --- | --- |"]
    for n, row in sec.get("medians", {}).items():
        for key, label, unit, _, _ in FIGURES:
            c = row.get(key) or {}
            ratio = f"{c['ratio']:.2f}" if c.get("ratio") is not None else "-"
            lines.append(f"| {n} | {label} [{unit}] | {_fmt(c.get('plain'), unit)} | "
                         f"{_fmt(c.get('secure'), unit)} | {ratio} |")
        ok = row.get("runs_ok", {})
        if any(ok.get(m, 0) < sec["reps"] for m in ("plain", "secure")):
            lines.append(f"| {n} | runs that completed | {ok.get('plain', 0)}/{sec['reps']} | "
                         f"{ok.get('secure', 0)}/{sec['reps']} | |")
    lines.append("")
    for n, levels in sec.get("levels", {}).items():
        row = sec["medians"][n]
        lines.append(f"**Where the secure time goes** (N, transport = {n}; the same invocation; "
                     "ratio = steps/s of plain / steps/s of the level)")
        lines.append("")
        lines.append("| governance | steps/s | plain / level | CPU per step [ms] | step latency p50 [ms] "
                     "| runs that completed |")
        lines.append("| --- | --- | --- | --- | --- | --- |")
        plain_rate = (row.get("steps_per_s") or {}).get("plain")
        ok = row.get("runs_ok", {})
        entries = [("plain (no security)", {k: (row.get(k) or {}).get("plain") for k in row}, ok.get("plain", 0)),
                   ("secure: submessages signed, payloads encrypted (default)",
                    {k: (row.get(k) or {}).get("secure") for k in row}, ok.get("secure", 0)),
                   ("secure: submessages not protected, payloads encrypted (--submessages none)",
                    levels.get("submessages-none", {}), levels.get("submessages-none", {}).get("runs_ok", 0)),
                   ("authenticated and access-controlled, nothing signed or encrypted (measurement only)",
                    levels.get("no-crypto", {}), levels.get("no-crypto", {}).get("runs_ok", 0))]
        for label, fig, runs in entries:
            rate = fig.get("steps_per_s")
            ratio = f"{plain_rate / rate:.2f}" if plain_rate and rate else "-"
            lines.append(f"| {label} | {_fmt(rate, 'steps/s')} | {ratio} | "
                         f"{_fmt(fig.get('cpu_ms_per_step'), 'ms')} | {_fmt(fig.get('latency_p50_ms'), 'ms')} "
                         f"| {runs}/{sec['reps']} |")
        lines.append("")
    goal = sec.get("goal")
    if goal:
        lines.append(f"Goal: {goal['name']}: plain is {goal['plain_over_secure']:.2f}x as fast "
                     f"as secure: **{'met' if goal['met'] else 'not met'}**.")
        lines.append("")
    return "\n".join(lines)
