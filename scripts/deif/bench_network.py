"""The network section of scripts/deif-bench (docs/BENCHMARKS.md, "Real networks"): the real
processes over three network-namespace hosts on one bridge (target on host 1, agents on
hosts 2-3), with random loss of each host's outgoing packets and a host cut off for a while,
each lossy run side by side with its loss-free baseline; then the same loss rates in the
in-process simulated network (deif_sim, network_sim.loss) over several seeds, to compare the
two. Root only (namespaces). Reports figures; asserts nothing.
"""
import json
import os
import statistics
import subprocess
import tempfile

from . import artefacts, launcher, paths

DEFAULT_CONFIG = os.path.join(paths.ROOT, "configs", "default.yaml")
PERIOD_S = 0.1
REALTIME = ["scenario.mode=realtime", f"scenario.period_s={PERIOD_S}"]
AGREE_M = 1e-6


def _rows(run, j):
    return artefacts.read_csv(os.path.join(run, f"agent_{j}.csv"))


def _excluded_live_peer(run, agents):
    """How many agents logged the loss of a peer by liveliness (every agent stays alive in
    these runs, so each is a false exclusion)."""
    n = 0
    for j in agents:
        try:
            with open(os.path.join(run, "logs", f"agent-{j}.log"), errors="replace") as f:
                n += "lost (liveliness)" in f.read()
        except OSError:
            pass
    return n


def _disagreement_runs(per_step, from_step=1):
    """Lengths of the maximal runs of consecutive steps whose agents disagree (> 1e-6 m)."""
    runs, cur = [], 0
    for s in per_step:
        if int(s["step"]) < from_step:
            continue
        if float(s["max_disagreement"]) > AGREE_M:
            cur += 1
        elif cur:
            runs.append(cur)
            cur = 0
    if cur:
        runs.append(cur)
    return runs


def _one(name, out, domain, steps, agents=4, **kwargs):
    """One launch over three hosts, reduced to the figures of the network issue."""
    with open(os.devnull, "w") as quiet:
        try:
            res = launcher.run(DEFAULT_CONFIG, out, agents=agents, steps=steps, domain=domain,
                               hosts=3, progress=False, log=quiet, **kwargs)
        except launcher.LaunchError as e:
            return {"name": name, "ok": False, "error": str(e)}
    m = res.summary.get("metrics", {})
    written = [len(_rows(res.out_dir, j)) for j in range(1, agents + 1)]
    per_step = artefacts.read_csv(os.path.join(res.out_dir, "metrics.csv"))
    runs = _disagreement_runs(per_step)
    wall = res.summary.get("wall_time_s") or 0.0
    fig = {"name": name, "ok": res.ok, "steps": steps,
           "rows_written_fraction": min(written) / steps,
           "agreement_fraction": m.get("agreement_fraction"),
           "longest_disagreement_steps": max(runs) if runs else 0,
           "disagreement_episodes": len(runs),
           "rmse_m": m.get("rmse_m"), "max_error_m": m.get("max_error_m"),
           "false_exclusions": _excluded_live_peer(res.out_dir, range(1, agents + 1)),
           "wall_time_s": wall}
    done = _target_done(res.out_dir)
    if done:
        fig["steps_per_s_target"] = done
    parts = res.summary.get("partitions") or []
    if parts and parts[0].get("healed_at_step"):
        healed = parts[0]["healed_at_step"]
        # The first step from which the agents agree to 1e-6 m for good, after the heal.
        bad = [int(s["step"]) for s in per_step
               if int(s["step"]) >= healed and float(s["max_disagreement"]) > AGREE_M]
        agreed_from = (max(bad) + 1) if bad else healed
        full_ring = [int(r["step"]) for r in _rows(res.out_dir, 1)
                     if int(r["step"]) >= healed and r["alive"] != str(agents)]
        fig["partition"] = {"cut_at_step": parts[0].get("cut_at_step"), "healed_at_step": healed,
                            "agree_after_heal_s": (agreed_from - healed) * PERIOD_S,
                            "full_ring_after_heal_s": ((max(full_ring) + 1 - healed) * PERIOD_S
                                                       if full_ring else 0.0)}
    return fig


def _target_done(out_dir):
    """Steps per second of the target from its first step to its last: the times of its log
    lines 'starting at step 1' and 'done at step N' (the wait for the agents excluded)."""
    from .bench import TARGET_DONE, log_unix_time
    start = end = steps = None
    try:
        with open(os.path.join(out_dir, "logs", "target.log"), errors="replace") as f:
            for line in f:
                if "starting at step 1" in line:
                    start = log_unix_time(line)
                m = TARGET_DONE.search(line)
                if m:
                    end, steps = log_unix_time(line), int(m.group(1))
    except OSError:
        return None
    if start is None or end is None or end <= start or not steps:
        return None
    return (steps - 1) / (end - start)


def _sim_sweep(losses, seeds, steps, work):
    """deif_sim in real-time mode at each loss rate over `seeds` seeds: mean and standard
    error of the RMSE and of the agreement fraction."""
    out = {}
    for loss in losses:
        rmse, agree = [], []
        for seed in range(1, seeds + 1):
            d = os.path.join(work, f"sim-{loss}-{seed}")
            subprocess.run([paths.executable("deif_sim"), "--config", DEFAULT_CONFIG, "--out", d,
                            "--quiet", "--set", f"network_sim.loss={loss}", "--set",
                            f"scenario.seed={seed}", "--set", f"scenario.steps={steps}",
                            *[a for o in REALTIME for a in ("--set", o)]], check=True)
            with open(os.path.join(d, "summary.json")) as fh:
                m = json.load(fh)["metrics"]
            rmse.append(m["rmse_m"])
            agree.append(m["agreement_fraction"])
        out[str(loss)] = {"rmse_mean": statistics.mean(rmse),
                          "rmse_se": statistics.stdev(rmse) / len(rmse) ** 0.5 if len(rmse) > 1 else None,
                          "agreement_mean": statistics.mean(agree), "seeds": seeds}
    return out


def run_network(quick, domains, work_dir):
    steps = 100 if quick else 300
    work = tempfile.mkdtemp(prefix="net-", dir=work_dir)
    rows = []
    for loss in (0.0, 0.10, 0.20):
        rows.append(_one(f"realtime 10 Hz, {loss:.0%} loss", os.path.join(work, f"rt{loss}"),
                         domains.take(), steps, overrides=REALTIME, loss=loss))
    for loss in (0.0, 0.10):
        rows.append(_one(f"lock-step, {loss:.0%} loss", os.path.join(work, f"ls{loss}"),
                         domains.take(), steps, loss=loss))
    rows.append(_one("realtime 10 Hz, host 3 cut off for 3 s", os.path.join(work, "cut"),
                     domains.take(), max(steps, 150), overrides=REALTIME,
                     partitions=[launcher.Partition(60, 3.0, 3)]))
    seeds = 5 if quick else 20
    sim = _sim_sweep((0.0, 0.10, 0.20), seeds, steps, work)
    return {"rows": rows, "sim": sim, "steps": steps}


def make_table(net):
    f = lambda v, spec=".3f": "-" if v is None else format(v, spec)  # noqa: E731
    lines = ["**Real networks** (N = 4, three namespace hosts, loss of each host's outgoing packets)", "",
             "| run | finished | rows written | agree <= 1e-6 | longest disagreement [steps] "
             "| RMSE [m] | RMSE / loss-free | peers excluded by liveliness | steps/s |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    base = {}
    for r in net["rows"]:
        if "error" in r:
            lines.append(f"| {r['name']} | FAILED: {r['error'].splitlines()[-1]} |" + " |" * 7)
            continue
        kind = r["name"].split(",")[0]
        if r["name"].endswith(" 0% loss"):
            base[kind] = r["rmse_m"]
        # A cut-off host's agents get no ranges: their error is not the network's doing.
        ratio = (r["rmse_m"] / base[kind] if base.get(kind) and r.get("rmse_m")
                 and "partition" not in r else None)
        lines.append(f"| {r['name']} | {'ok' if r['ok'] else 'NO'} | {r['rows_written_fraction']:.1%} | "
                     f"{f(r['agreement_fraction'], '.1%')} | {r['longest_disagreement_steps']} | "
                     f"{f(r['rmse_m'], '.4f')} | {f(ratio, '.2f')} | {r['false_exclusions']} | "
                     f"{f(r.get('steps_per_s_target'), '.0f')} |")
    lines.append("")
    for r in net["rows"]:
        p = r.get("partition")
        if p:
            lines.append(f"Partition: cut at step {p['cut_at_step']}, healed at step {p['healed_at_step']}; "
                         f"all agents agree to 1e-6 m {p['agree_after_heal_s']:.1f} s after the heal, "
                         f"the ring holds all four {p['full_ring_after_heal_s']:.1f} s after it.")
            lines.append("")
    lines.append(f"**Simulated network** (deif_sim, real-time mode, {net['steps']} steps, mean over seeds "
                 "+- standard error) against the namespace runs above")
    lines.append("")
    lines.append("| loss | sim RMSE [m] | namespaces RMSE [m] | sim agreement | namespaces agreement |")
    lines.append("| --- | --- | --- | --- | --- |")
    real = {r["name"]: r for r in net["rows"]}
    for loss, s in net["sim"].items():
        rr = real.get(f"realtime 10 Hz, {float(loss):.0%} loss", {})
        lines.append(f"| {float(loss):.0%} | {s['rmse_mean']:.4f} +- {f(s['rmse_se'], '.4f')} | "
                     f"{f(rr.get('rmse_m'), '.4f')} | {s['agreement_mean']:.1%} | "
                     f"{f(rr.get('agreement_fraction'), '.1%')} |")
    lines.append("")
    return "\n".join(lines)


def run_realtime_scale(ns, domains, work_dir, steps):
    """Real time at 10 Hz with N agents on this host (default config): in how many
    agent-steps every member's contribution was fused by the deadline (the `complete`
    column), the deadline misses, and the rows written. The largest N runs a second time
    with the agents under SCHED_OTHER, the baseline of deif-run's SCHED_BATCH measured side
    by side (docs/RUNNING.md, "CPU scheduling")."""
    out = []
    for n, sched in [(n, "batch") for n in ns] + [(max(ns), "normal")]:
        d = os.path.join(work_dir, f"rt-n{n}-{sched}")
        with open(os.devnull, "w") as quiet:
            try:
                res = launcher.run(DEFAULT_CONFIG, d, agents=n, steps=steps, domain=domains.take(),
                                   overrides=REALTIME, progress=False, log=quiet,
                                   timeout_s=steps * PERIOD_S + 180, agent_sched=sched)
            except launcher.LaunchError as e:
                out.append({"n": n, "agent_sched": sched, "error": str(e)})
                continue
        complete = total = 0
        written = []
        by_agent = {}
        for j in range(1, n + 1):
            rows = _rows(res.out_dir, j)
            by_agent[j] = rows
            written.append(len(rows))
            total += len(rows)
            complete += sum(r["complete"] == "1" for r in rows)
        steps_complete = complete_steps(by_agent, steps)
        m = res.summary.get("metrics", {})
        out.append({"n": n, "agent_sched": sched, "steps": steps, "ok": res.ok,
                    "delivery_ms": launcher.median_delivery_ms(res.summary.get("counters", {})),
                    "rows_written_fraction": sum(written) / (n * steps),
                    "complete_fraction": complete / total if total else None,
                    "steps_complete_fraction": len(steps_complete) / steps,
                    "first_incomplete_steps": sorted(set(range(1, steps + 1)) - steps_complete)[:10],
                    "agreement_fraction": m.get("agreement_fraction"),
                    "final_agents": m.get("final_agents"), "rmse_m": m.get("rmse_m")})
    return out


def complete_steps(rows_by_agent, steps):
    """The steps 1..steps in which every agent wrote a row that fused every member of the
    step's roll call by its deadline (`complete` = 1): the figure of a network whose every
    sensor is up to date, stricter than the share of agent-steps. A step an agent wrote no
    row for is not complete."""
    full = set(range(1, steps + 1))
    for rows in rows_by_agent.values():
        full &= {int(r["step"]) for r in rows if r["complete"] == "1"}
    return full


def _steps_cell(r):
    if r.get("steps_complete_fraction") is None:
        return "-"
    first = r.get("first_incomplete_steps") or []
    return f"{r['steps_complete_fraction']:.1%}" + (f" ({' '.join(map(str, first))})" if first else "")


def _n_cell(r):
    sched = r.get("agent_sched")
    return f"{r['n']} ({'SCHED_BATCH' if sched == 'batch' else 'SCHED_OTHER'})" if sched else str(r["n"])


def realtime_table(rows):
    lines = ["**Real time at 10 Hz on this host** (default config, N agents)", "",
             "| N (agents' CPU policy) | finished | rows written | agent-steps with every member fused by the deadline "
             "| steps in which every agent did (first that did not) "
             "| agree <= 1e-6 | agents at the end | RMSE [m] | delivery p50 / p99 [ms], median agent |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {_n_cell(r)} | FAILED: {r['error'].splitlines()[-1]} | | | | | | | |")
            continue
        f = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
        lines.append(f"| {_n_cell(r)} | {'ok' if r['ok'] else 'NO'} | {r['rows_written_fraction']:.1%} | "
                     f"{f(r['complete_fraction'], '.1%')} | {_steps_cell(r)} | {f(r['agreement_fraction'], '.1%')} | "
                     f"{r['final_agents']} | {f(r['rmse_m'], '.4f')} | "
                     + ", ".join(f"{k} {v[0]:.1f} / {v[1]:.1f}" for k, v in sorted(r.get("delivery_ms", {}).items()))
                     + " |")
    lines.append("")
    return "\n".join(lines)
