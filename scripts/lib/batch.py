"""Monte Carlo batches: run scenarios over M seeds and reduce the run artefacts to statistics.

Used by scripts/deif-batch (command line), scripts/deif-thesis and tests/batch. Every
statistic is computed here from the run artefacts alone (target.csv, ranges.csv,
agent_<id>.csv and the config), so a batch of in-process runs (deif_sim) and a batch of
multi-process runs (scripts/lib/deifrun.py) are reduced by the same code.

Layout of a batch folder (runs/batch-<name>/ by default):

  batch.json                  what was run: configs, modes, base seed, the derived seeds
  results.csv, results.json   one row per (scenario, mode); byte-identical on a rerun
  timing.json                 wall-clock times (kept apart so results.json is reproducible)
  <scenario>/<mode>/config.yaml      the config as run (control law overridden if stationary)
  <scenario>/<mode>/per_seed.csv     the per-run statistics of every seed
  <scenario>/<mode>/timeseries.csv   per-step statistics across seeds (for the figures)
  <scenario>/<mode>/seed-000/        the full artefacts of the first seed (for the figures)

Only the Python standard library, numpy and PyYAML (Debian's python3-numpy, python3-yaml).
"""
import concurrent.futures
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import deifrun  # noqa: E402

ROOT = deifrun.ROOT
MAX_JOBS = 2          # the machine has two shared cores
MODES = ("moving", "stationary")
_MASK64 = (1 << 64) - 1


# ---------------------------------------------------------------------------------------
# Seeds

def derive_seed(base_seed, index):
    """The seed of Monte Carlo run `index` (0-based): SplitMix64 of (base seed, index).

    The same base seed gives the same list on every rerun. Every scenario and both modes use
    the same list (common random numbers: moving and stationary sensors see the same noise
    draws, so their difference is not blurred by independent noise)."""
    x = (int(base_seed) * 0x9E3779B97F4A7C15 + int(index) + 1) & _MASK64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK64
    x ^= x >> 31
    return x >> 1  # below 2^63: safe for every integer parser on the way


# ---------------------------------------------------------------------------------------
# Configs

def load_yaml(path):
    with open(path) as f:
        cfg = yaml.safe_load(f) or {}
    if not isinstance(cfg, dict):
        raise SystemExit(f"deif-batch: error: {path}: top level must be a mapping")
    return cfg


def config_for_mode(cfg, mode):
    """The config a mode runs: `moving` is the file as written; `stationary` overrides the
    control law (everything else, the seed included, is the same)."""
    out = json.loads(json.dumps(cfg))  # deep copy
    if mode == "stationary":
        out.setdefault("agents", {})["control_law"] = "stationary"
    elif mode != "moving":
        raise ValueError(f"unknown mode '{mode}' (allowed: {', '.join(MODES)})")
    return out


def write_config(cfg, path, comment=None):
    """Write a config as YAML (PyYAML spells infinity .inf, as the C++ parser wants)."""
    with open(path, "w") as f:
        if comment:
            f.write(f"# {comment}\n")
        yaml.safe_dump(cfg, f, sort_keys=False)


def expand_configs(paths):
    """Files as given; a directory means every *.yaml in it, sorted by name."""
    out = []
    for p in paths:
        if os.path.isdir(p):
            out += sorted(os.path.join(p, n) for n in os.listdir(p) if n.endswith(".yaml"))
        elif os.path.isfile(p):
            out.append(p)
        else:
            raise SystemExit(f"deif-batch: error: {p}: no such config file or folder")
    if not out:
        raise SystemExit("deif-batch: error: no config files given")
    return out


def _rel(path):
    path = os.path.abspath(path)
    return os.path.relpath(path, ROOT) if path.startswith(ROOT + os.sep) else path


def scenario_name(path):
    return os.path.splitext(os.path.basename(path))[0]


def _get(cfg, section, key, default):
    return (cfg.get(section) or {}).get(key, default)


# ---------------------------------------------------------------------------------------
# Statistics of one run, from its artefacts

def _sensing(cfg):
    s = cfg.get("sensing") or {}
    r1 = s.get("r1_m", math.inf)
    return (float(s.get("c0", 0.0)), float(s.get("r0_m", 0.0)),
            math.inf if r1 in (".inf", None) else float(r1), float(s.get("beta", 1)))


def sensing_gradient(p_target, p_sensor, sensing):
    """d f(||x - p||) / dx at x = p_target (eq 2.1; f(r) = r by default): the row g_j."""
    c0, r0, r1, beta = sensing
    dx, dy = p_target[0] - p_sensor[0], p_target[1] - p_sensor[1]
    r = math.hypot(dx, dy)
    if r <= 0.0 or not (r0 < r < r1):
        return 0.0, 0.0
    df = beta * r ** (beta - 1.0)
    return df * dx / r, df * dy / r


def motion_model(cfg):
    """(F, Q, P0) of the filter's model, as in common/models.cpp and common/config.cpp."""
    dt = float(_get(cfg, "scenario", "dt_s", 0.1))
    q = float(_get(cfg, "filter", "process_noise", 1.3e-4))
    v_pos = float(_get(cfg, "filter", "initial_position_variance_m2", 1.0))
    if _get(cfg, "filter", "motion_model", "random_walk") == "constant_velocity":
        i2 = np.eye(2)
        F = np.block([[i2, dt * i2], [np.zeros((2, 2)), i2]])
        Q = q * np.block([[dt ** 3 / 3 * i2, dt ** 2 / 2 * i2], [dt ** 2 / 2 * i2, dt * i2]])
        v_vel = float(_get(cfg, "filter", "initial_velocity_variance_m2ps2", 1.0))
        P0 = np.diag([v_pos, v_pos, v_vel, v_vel])
    else:
        F, Q, P0 = np.eye(2), q * np.eye(2), v_pos * np.eye(2)  # eq (5.1)
    return F, Q, P0


SETTLE_S = 1.0  # "settled" statistics leave out t < SETTLE_S (the start-up transient)


def analyse_run(run_dir, cfg):
    """Per-step and per-run statistics of one run folder.

    error: ||x - x_hat|| of every agent that reported the step (with full communication all
    agents hold the same estimate; after a kill only the survivors report).
    PCRLB: J(k) = (Q + F J(k-1)^-1 F^T)^-1 + sum_j H_j^T H_j / sigma^2 with H_j at the TRUE
    target position and the position each range was measured from (ranges.csv), sigma^2 the
    TRUE range variance (target.range_noise_variance_m2; ranges.csv carries the filter's R).
    J(0) = P0^-1. The bound is for the filter's motion model (Tichavsky et al. 1998).
    Optimality: det J_geo / (tr J_geo / 2)^2 of the sensors of the step at the true position
    (1 at the optimum of Proposition 1).
    Settled maximum: the largest error over t >= SETTLE_S, leaving out the first update from
    the initial guess, which depends mostly on the (unstated) initial covariance.
    """
    truth = {}
    for r in deifrun.read_csv(os.path.join(run_dir, "target.csv")):
        truth[int(r["step"])] = (float(r["t"]), float(r["x_true"]), float(r["y_true"]))
    if not truth:
        raise RuntimeError(f"{run_dir}: target.csv is missing or empty")
    n_agents = int(_get(cfg, "agents", "count", 4))
    per_step = {k: [] for k in truth}  # k -> [(agent id, err^2, nees)]
    finals = {}
    for j in range(1, n_agents + 1):
        rows = deifrun.read_csv(os.path.join(run_dir, f"agent_{j}.csv"))
        for r in rows:
            k = int(r["step"])
            if k not in truth:
                continue
            ex = truth[k][1] - float(r["x_est"])
            ey = truth[k][2] - float(r["y_est"])
            pxx, pxy, pyy = float(r["p_xx"]), float(r["p_xy"]), float(r["p_yy"])
            det = pxx * pyy - pxy * pxy
            nees = (pyy * ex * ex - 2.0 * pxy * ex * ey + pxx * ey * ey) / det if det > 0 else math.inf
            per_step[k].append((j, ex * ex + ey * ey, nees))
        if rows:
            finals[j] = (int(rows[-1]["step"]), float(rows[-1]["angle"]))

    sensors = {}
    for r in deifrun.read_csv(os.path.join(run_dir, "ranges.csv")):
        sensors.setdefault(int(r["step"]), []).append((float(r["sensor_x"]), float(r["sensor_y"])))

    true_var = float(_get(cfg, "target", "range_noise_variance_m2", 5.3e-4))
    sensing = _sensing(cfg)
    F, Q, P0 = motion_model(cfg)
    J = np.linalg.inv(P0)
    steps = sorted(truth)
    ts = {"step": [], "t": [], "mse": [], "max": [], "first": [], "bound": [], "nees": [],
          "opt": []}
    for k in steps:
        t, x, y = truth[k]
        # PCRLB recursion: prediction with the model, then the information of every range.
        J = np.linalg.inv(Q + F @ np.linalg.inv(J) @ F.T)
        Jg = np.zeros((2, 2))
        for p in sensors.get(k, []):
            gx, gy = sensing_gradient((x, y), p, sensing)
            Jg += np.array([[gx * gx, gx * gy], [gx * gy, gy * gy]]) / true_var
        J[:2, :2] += Jg
        bound = float(np.trace(np.linalg.inv(J)[:2, :2]))
        tr = Jg[0, 0] + Jg[1, 1]
        opt = (Jg[0, 0] * Jg[1, 1] - Jg[0, 1] ** 2) / (tr / 2.0) ** 2 if tr > 0 else math.nan
        samples = per_step[k]
        if not samples:
            continue
        ts["step"].append(k)
        ts["t"].append(t)
        ts["mse"].append(sum(s[1] for s in samples) / len(samples))
        ts["max"].append(math.sqrt(max(s[1] for s in samples)))
        ts["first"].append(math.sqrt(min(samples)[1]))  # the lowest reporting id
        ts["bound"].append(bound)
        ts["nees"].append(sum(s[2] for s in samples) / len(samples) / 2.0)
        ts["opt"].append(opt)

    all_sq = [s[1] for k in steps for s in per_step[k]]
    all_nees = [s[2] for k in steps for s in per_step[k]]
    last = max((s for s, _ in finals.values()), default=0)
    final_angles = [a for s, a in finals.values() if s == last]
    opt_values = [o for o in ts["opt"] if not math.isnan(o)]
    settled = [m for t, m in zip(ts["t"], ts["max"]) if t >= SETTLE_S - 1e-9]
    run = {
        "steps": len(ts["step"]),
        "mse_m2": sum(all_sq) / len(all_sq) if all_sq else math.nan,
        "max_error_m": math.sqrt(max(all_sq)) if all_sq else math.nan,
        "max_error_settled_m": max(settled) if settled else math.nan,
        "pcrlb_mean_trace_m2": sum(ts["bound"]) / len(ts["bound"]) if ts["bound"] else math.nan,
        "anees": sum(all_nees) / len(all_nees) / 2.0 if all_nees else math.nan,
        "mean_optimality_ratio": sum(opt_values) / len(opt_values) if opt_values else math.nan,
        "final_max_gap_error_rad": deifrun.max_gap_error(final_angles),
        "final_alive": len(final_angles),
    }
    return run, ts


# ---------------------------------------------------------------------------------------
# Running one seed

def sim_executable():
    exe = os.environ.get("DEIF_SIM_EXE")
    if exe:
        return exe
    return os.path.join(deifrun.build_dir(), "bin", "deif_sim")


def run_one(task):
    """Worker: run one (scenario, mode, seed) and reduce it. Returns plain data."""
    cfg_path, out_dir, seed, steps, cfg, processes, domain, keep = (
        task["config_path"], task["out_dir"], task["seed"], task["steps"], task["cfg"],
        task["processes"], task["domain"], task["keep"])
    shutil.rmtree(out_dir, ignore_errors=True)
    if processes:
        with open(os.devnull, "w") as quiet_log:
            res = deifrun.run(cfg_path, out_dir, domain=domain, steps=steps, seed=seed,
                              progress=False, log=quiet_log)
        if not res.ok:
            raise RuntimeError(f"{out_dir}: a process exited unexpectedly (see {out_dir}/logs)")
    else:
        argv = [sim_executable(), "--config", cfg_path, "--out", out_dir, "--seed", str(seed),
                "--quiet"]
        if steps is not None:
            argv += ["--steps", str(steps)]
        proc = subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(argv)} exited with {proc.returncode}:\n{proc.stdout}")
    run_cfg = json.loads(json.dumps(cfg))
    if steps is not None:
        run_cfg.setdefault("scenario", {})["steps"] = steps
    run, ts = analyse_run(out_dir, run_cfg)
    if not keep:
        shutil.rmtree(out_dir, ignore_errors=True)
    return {"key": task["key"], "index": task["index"], "seed": seed, "run": run, "ts": ts}


# ---------------------------------------------------------------------------------------
# Reduction across seeds

RESULT_COLUMNS = [
    "scenario", "mode", "control_law", "seeds", "steps", "true_range_variance_m2",
    "filter_range_variance_m2", "rmse_m", "rmse_se_m", "max_error_m", "median_run_max_error_m",
    "max_error_settled_m", "median_run_max_error_settled_m",
    "pcrlb_rmse_m", "rmse_over_pcrlb", "anees", "mean_optimality_ratio",
    "final_max_gap_error_rad", "final_alive_min",
]


def reduce_seeds(scenario, mode, cfg, runs):
    """One results row from the per-seed runs (sorted by seed index: a fixed summation order,
    so that a rerun gives bit-identical numbers).

    rmse_m: sqrt of the mean over seeds, steps and agents of ||x - x_hat||^2.
    rmse_se_m: its Monte Carlo standard error, se(MSE) / (2 RMSE) with se(MSE) the standard
      error of the per-seed MSEs (seeds are independent; steps within a seed are not).
    max_error_m: the largest ||x - x_hat|| over steps, agents and seeds;
    median_run_max_error_m: the median over seeds of each run's largest error (what one run,
      like each of the thesis's, typically shows).
    max_error_settled_m, median_run_max_error_settled_m: the same over t >= SETTLE_S.
    pcrlb_rmse_m: sqrt of the mean over seeds and steps of the trace of the position PCRLB.
    anees: mean over seeds, steps and agents of NEES / 2 (1 for a consistent filter).
    """
    runs = sorted(runs, key=lambda r: r["index"])
    m = len(runs)
    mses = np.array([r["run"]["mse_m2"] for r in runs])
    rmse = math.sqrt(float(np.mean(mses)))
    se_mse = float(np.std(mses, ddof=1)) / math.sqrt(m) if m > 1 else math.nan
    pcrlb = math.sqrt(float(np.mean([r["run"]["pcrlb_mean_trace_m2"] for r in runs])))
    maxes = [r["run"]["max_error_m"] for r in runs]
    return {
        "scenario": scenario,
        "mode": mode,
        "control_law": _get(cfg, "agents", "control_law", "voronoi"),
        "seeds": m,
        "steps": runs[0]["run"]["steps"],
        "true_range_variance_m2": float(_get(cfg, "target", "range_noise_variance_m2", 5.3e-4)),
        "filter_range_variance_m2": float(_get(cfg, "filter", "range_variance_m2", 5.3e-4)),
        "rmse_m": rmse,
        "rmse_se_m": se_mse / (2.0 * rmse) if rmse > 0 else math.nan,
        "max_error_m": max(maxes),
        "median_run_max_error_m": float(np.median(maxes)),
        "max_error_settled_m": max(r["run"]["max_error_settled_m"] for r in runs),
        "median_run_max_error_settled_m": float(np.median(
            [r["run"]["max_error_settled_m"] for r in runs])),
        "pcrlb_rmse_m": pcrlb,
        "rmse_over_pcrlb": rmse / pcrlb if pcrlb > 0 else math.nan,
        "anees": float(np.mean([r["run"]["anees"] for r in runs])),
        "mean_optimality_ratio": float(np.mean([r["run"]["mean_optimality_ratio"] for r in runs])),
        "final_max_gap_error_rad": float(np.mean([r["run"]["final_max_gap_error_rad"] for r in runs])),
        "final_alive_min": min(r["run"]["final_alive"] for r in runs),
    }


def write_timeseries(path, runs):
    """Per-step statistics across seeds: RMS, mean and max of the error, the first seed's
    error, sqrt of the mean PCRLB trace, mean NEES/2 and mean optimality ratio."""
    runs = sorted(runs, key=lambda r: r["index"])
    steps = runs[0]["ts"]["step"]
    by_seed = []
    for r in runs:
        ts = r["ts"]
        by_seed.append({key: dict(zip(ts["step"], ts[key]))
                        for key in ("mse", "max", "first", "bound", "nees", "opt")})
    with open(path, "w") as f:
        f.write("step,t,rms_error_m,mean_error_m,max_error_m,seed0_error_m,pcrlb_m,anees,optimality_ratio\n")
        t_of = dict(zip(runs[0]["ts"]["step"], runs[0]["ts"]["t"]))
        for k in steps:
            mse = [s["mse"][k] for s in by_seed if k in s["mse"]]
            mx = [s["max"][k] for s in by_seed if k in s["max"]]
            bound = [s["bound"][k] for s in by_seed if k in s["bound"]]
            nees = [s["nees"][k] for s in by_seed if k in s["nees"]]
            opt = [s["opt"][k] for s in by_seed if k in s["opt"] and not math.isnan(s["opt"][k])]
            f.write(",".join([str(k), f"{t_of[k]:.6g}"] + [f"{v:.6g}" for v in (
                math.sqrt(float(np.mean(mse))), float(np.mean(np.sqrt(mse))), max(mx),
                by_seed[0]["first"].get(k, math.nan), math.sqrt(float(np.mean(bound))),
                float(np.mean(nees)), float(np.mean(opt)) if opt else math.nan)]) + "\n")


def write_per_seed(path, runs):
    runs = sorted(runs, key=lambda r: r["index"])
    keys = list(runs[0]["run"].keys())
    with open(path, "w") as f:
        f.write(",".join(["index", "seed"] + keys) + "\n")
        for r in runs:
            f.write(",".join([str(r["index"]), str(r["seed"])] +
                             [repr(r["run"][k]) for k in keys]) + "\n")


# ---------------------------------------------------------------------------------------
# The batch

class Progress:
    """One line of progress on stderr: rewritten in place on a terminal, else every 10 s."""

    def __init__(self, total, label, quiet=False, stream=sys.stderr):
        self.total, self.label, self.quiet, self.stream = total, label, quiet, stream
        self.done, self.start, self.last = 0, time.time(), 0.0
        self.tty = stream.isatty()

    def update(self, what):
        self.done += 1
        if self.quiet:
            return
        now = time.time()
        if not self.tty and now - self.last < 10.0 and self.done != self.total:
            return
        self.last = now
        elapsed = now - self.start
        eta = elapsed / self.done * (self.total - self.done)
        line = (f"{self.label}: {self.done}/{self.total} runs  {what}  "
                f"elapsed {elapsed:.0f} s  eta {eta:.0f} s")
        self.stream.write(("\r\033[K" + line) if self.tty else line + "\n")
        if self.tty and self.done == self.total:
            self.stream.write("\n")
        self.stream.flush()


def run_batch(config_paths, out_dir, seeds=20, base_seed=1, steps=None, modes=MODES,
              jobs=MAX_JOBS, processes=False, domain=150, keep_runs=False, quiet=False,
              label="deif-batch"):
    """Run every config in every mode over `seeds` derived seeds; write the batch folder and
    return the list of results rows."""
    if seeds < 1:
        raise SystemExit("deif-batch: error: --seeds must be >= 1")
    jobs = max(1, min(int(jobs), MAX_JOBS))
    if processes:
        # A multi-process run already keeps N + 1 processes busy on the two cores; two at
        # once would starve the lock-step timeouts. Run them one after another.
        jobs = 1
    elif not os.path.exists(sim_executable()):
        raise SystemExit(f"deif-batch: error: {sim_executable()} not found; build the deif_sim "
                         "target (or set DEIF_SIM_EXE / DEIF_BUILD_DIR)")
    out_dir = os.path.abspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    seed_list = [derive_seed(base_seed, i) for i in range(seeds)]

    scenarios = []
    tasks = []
    for path in config_paths:
        name = scenario_name(path)
        base = load_yaml(path)
        for mode in modes:
            cfg = config_for_mode(base, mode)
            mode_dir = os.path.join(out_dir, name, mode)
            os.makedirs(mode_dir, exist_ok=True)
            cfg_path = os.path.join(mode_dir, "config.yaml")
            write_config(cfg, cfg_path, f"{_rel(path)}, mode {mode}")
            scenarios.append((name, mode, cfg, mode_dir, path))
            for i, seed in enumerate(seed_list):
                tasks.append({"key": (name, mode), "index": i, "seed": seed, "steps": steps,
                              "config_path": cfg_path, "cfg": cfg, "processes": processes,
                              "domain": domain,
                              "out_dir": os.path.join(mode_dir, f"seed-{i:03d}"),
                              "keep": keep_runs or i == 0})

    with open(os.path.join(out_dir, "batch.json"), "w") as f:
        json.dump({"configs": [_rel(p) for p in config_paths],
                   "modes": list(modes), "seeds": seeds, "base_seed": base_seed,
                   "derived_seeds": seed_list, "steps_override": steps,
                   "runner": "deifrun (multi-process)" if processes else "deif_sim (in-process)"},
                  f, indent=2)

    progress = Progress(len(tasks), label, quiet)
    started = time.time()
    collected = {}
    if jobs == 1:
        for t in tasks:
            r = run_one(t)
            collected.setdefault(r["key"], []).append(r)
            progress.update(f"{t['key'][0]} {t['key'][1]} seed {t['index']}")
    else:
        with concurrent.futures.ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(run_one, t): t for t in tasks}
            for fut in concurrent.futures.as_completed(futures):
                t = futures[fut]
                r = fut.result()
                collected.setdefault(r["key"], []).append(r)
                progress.update(f"{t['key'][0]} {t['key'][1]} seed {t['index']}")

    rows = []
    for name, mode, cfg, mode_dir, path in scenarios:
        runs = collected[(name, mode)]
        write_per_seed(os.path.join(mode_dir, "per_seed.csv"), runs)
        write_timeseries(os.path.join(mode_dir, "timeseries.csv"), runs)
        row = reduce_seeds(name, mode, cfg, runs)
        row["config"] = _rel(path)
        rows.append(row)

    with open(os.path.join(out_dir, "results.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(RESULT_COLUMNS)
        for row in rows:
            w.writerow([f"{row[c]:.6g}" if isinstance(row[c], float) else row[c]
                        for c in RESULT_COLUMNS])
    with open(os.path.join(out_dir, "results.json"), "w") as f:
        json.dump({"base_seed": base_seed, "seeds": seeds, "modes": list(modes),
                   "runner": "processes" if processes else "in-process", "results": rows},
                  f, indent=2)
    with open(os.path.join(out_dir, "timing.json"), "w") as f:
        json.dump({"wall_time_s": time.time() - started, "runs": len(tasks), "jobs": jobs}, f,
                  indent=2)
    return rows


def load_results(batch_dir):
    with open(os.path.join(batch_dir, "results.json")) as f:
        return json.load(f)


def read_timeseries(batch_dir, scenario, mode):
    rows = deifrun.read_csv(os.path.join(batch_dir, scenario, mode, "timeseries.csv"))
    if not rows:
        return {}
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}
