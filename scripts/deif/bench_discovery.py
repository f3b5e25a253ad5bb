"""The discovery section of scripts/deif-bench (docs/BENCHMARKS.md, "Discovery, simple and
server"): launch to the first step fused by every agent, for N agents with simple discovery
(SPDP multicast, every participant announces itself to every other) and with the Fast DDS
Discovery Server the launcher starts for the run (`deif-run --discovery-server`), in one
invocation, the two alternating (the order flips every repetition) so both see the same
machine load. Each run is a short lock-step run of the default config; the step observer
(bench/step_observer.cpp) gives the time the last agent's state of step 1 arrived.
Reports figures; asserts nothing.
"""
from .bench import DEFAULT_CONFIG, fmt, lockstep_run, log, median

MODES = ("simple", "server")
STEPS = 20


def _overrides(mode, domain):
    if mode == "simple":
        return []
    # The launcher's server for this run listens on the loopback at 11811 + domain; the
    # observer, started before it, must be a client of the same server.
    return ["network.discovery=server", f"network.discovery_server=127.0.0.1:{11811 + domain}"]


def run_discovery(ns, reps, domains, work_dir, observer_exe):
    runs = {}
    for rep in range(reps):
        for n in ns:
            for mode in (MODES if rep % 2 == 0 else MODES[::-1]):
                domain = domains.take()
                log(f"discovery N={n}, {mode} (rep {rep + 1}/{reps})")
                fig = lockstep_run(n, STEPS, domain, work_dir, observer_exe, DEFAULT_CONFIG,
                                   timeout_s=150.0, overrides=_overrides(mode, domain),
                                   discovery_server=(mode == "server"))
                d = fig.get("discovery_s") or {}
                runs.setdefault(f"{n}/{mode}", []).append({
                    "ok": fig.get("ok"), "last_step": fig.get("last_step"),
                    "first_range_s": d.get("first_range"), "first_fused_all_s": d.get("first_fused_all"),
                    "cpu_s_per_step_whole_run": fig.get("cpu_s_per_step_whole_run_incl_observer")})
    out = {"ns": ns, "reps": reps, "steps": STEPS, "runs": runs, "rows": []}
    for n in ns:
        row = {"n": n}
        for mode in MODES:
            rs = runs.get(f"{n}/{mode}", [])
            fused = [r["first_fused_all_s"] for r in rs if r["first_fused_all_s"] is not None]
            row[mode] = {"first_fused_all_s_median": median(fused) if fused else None,
                         "first_fused_all_s": [r["first_fused_all_s"] for r in rs],
                         "completed": sum(1 for r in rs if r["ok"]), "runs": len(rs)}
        s, v = row["simple"]["first_fused_all_s_median"], row["server"]["first_fused_all_s_median"]
        row["server_over_simple"] = v / s if s and v else None
        out["rows"].append(row)
    return out


def make_table(res):
    lines = [f"**Discovery, simple and server** (launch to the first step fused by all N; "
             f"lock-step, {res['steps']} steps, {res['reps']} repetition(s) alternating; median [s])", "",
             "| N | simple | server | server / simple | runs completed, simple / server |",
             "| --- | --- | --- | --- | --- |"]
    for r in res["rows"]:
        s, v = r["simple"], r["server"]
        lines.append(f"| {r['n']} | {fmt(s['first_fused_all_s_median'], '.2f')} | "
                     f"{fmt(v['first_fused_all_s_median'], '.2f')} | {fmt(r['server_over_simple'], '.2f')} | "
                     f"{s['completed']}/{s['runs']} / {v['completed']}/{v['runs']} |")
    lines.append("")
    return "\n".join(lines)
