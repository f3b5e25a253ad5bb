"""Monte Carlo batches: run scenarios over M seeds and reduce the runs' metrics across seeds.

Used by scripts/deif-batch (command line), scripts/deif-thesis and tests/python. Every
per-run number is computed once, in C++: a run folder's summary.json ("metrics") and
metrics.csv (one row per step), written by deif_sim for an in-process run and by
`deif_sim --evaluate` (through deif.launcher) for a multi-process run. This module only
reduces those numbers across seeds (means, maxima, medians), so both kinds of batch are
reduced by the same code.

Layout of a batch folder (runs/batch-<name>/ by default):

  batch.json                  what was run: configs, modes, base seed, the derived seeds
  results.csv, results.json   one row per (scenario, mode); byte-identical on a rerun
  timing.json                 wall-clock times (kept apart so results.json is reproducible)
  <scenario>/<mode>/config.yaml      the effective config of the mode (deif_config's YAML)
  <scenario>/<mode>/per_seed.csv     the per-run statistics of every seed
  <scenario>/<mode>/timeseries.csv   per-step statistics across seeds (for the figures)
  <scenario>/<mode>/seed-000/        the full artefacts of the first seed (for the figures)
"""
import concurrent.futures
import csv
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import time

from . import artefacts, config, paths

ROOT = paths.ROOT
MAX_JOBS = 2          # the machine has two shared cores
MODES = ("moving", "stationary")
# The overrides (`--set`) of each mode; `moving` is the file as written.
MODE_OVERRIDES = {"moving": [], "stationary": ["agents.control_law=stationary"]}
SETTLE_S = 1.0        # "settled" maxima leave out t < SETTLE_S (the start-up transient)
_MASK64 = (1 << 64) - 1


class BatchError(Exception):
    """Bad arguments or a refused config (nothing ran); str() says which."""


class RunFailed(BatchError):
    """A run could not be completed or evaluated; str() says which."""


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

def mode_overrides(mode):
    if mode not in MODE_OVERRIDES:
        raise ValueError(f"unknown mode '{mode}' (allowed: {', '.join(MODES)})")
    return list(MODE_OVERRIDES[mode])


def expand_configs(config_paths):
    """Files as given; a directory means every *.yaml in it, sorted by name."""
    out = []
    for p in config_paths:
        if os.path.isdir(p):
            out += sorted(os.path.join(p, n) for n in os.listdir(p) if n.endswith(".yaml"))
        elif os.path.isfile(p):
            out.append(p)
        else:
            raise BatchError(f"{p}: no such config file or folder")
    if not out:
        raise BatchError("no config files given")
    return out


def rel(path):
    path = os.path.abspath(path)
    return os.path.relpath(path, ROOT) if path.startswith(ROOT + os.sep) else path


def scenario_name(path):
    return os.path.splitext(os.path.basename(path))[0]


def sim_executable():
    exe = os.environ.get("DEIF_SIM_EXE")
    if exe:
        return exe
    return os.path.join(paths.build_dir(), "bin", "deif_sim")


# ---------------------------------------------------------------------------------------
# The statistics of one run, from its summary.json and metrics.csv

def _num(v):
    """A JSON number, or NaN for null (deif_sim writes a NaN as null)."""
    return math.nan if v is None else float(v)


def run_statistics(run_dir, metrics=None):
    """Per-run and per-step statistics of one run folder, as computed by the C++.

    metrics: summary.json's "metrics" (read from run_dir when not given).
    Returns (run, per_step): run holds the per-run numbers the reduction needs; per_step
    maps a column to a list over the steps at which some agent wrote a row."""
    if metrics is None:
        try:
            with open(os.path.join(run_dir, "summary.json")) as f:
                metrics = json.load(f)["metrics"]
        except (OSError, ValueError, KeyError):
            raise RunFailed(f"{run_dir}: summary.json with metrics is missing")
    if "error" in metrics:
        raise RunFailed(f"{run_dir}: the run could not be evaluated: {metrics['error']}")
    rows = artefacts.read_csv(os.path.join(run_dir, "metrics.csv"))
    if not rows:
        raise RunFailed(f"{run_dir}: metrics.csv is missing or empty")
    per_step = {"step": [], "t": [], "ms_error": [], "rms_error": [], "max_error": [],
                "pcrlb_sq": [], "nees_half": [], "opt": []}
    for r in rows:
        if int(r["rows"]) == 0:
            continue
        rms = float(r["rms_error"])
        per_step["step"].append(int(r["step"]))
        per_step["t"].append(float(r["t"]))
        per_step["ms_error"].append(rms * rms)
        per_step["rms_error"].append(rms)
        per_step["max_error"].append(float(r["max_error"]))
        per_step["pcrlb_sq"].append(float(r["pcrlb"]) ** 2)
        per_step["nees_half"].append(float(r["mean_nees"]) / 2.0)  # ANEES's normalisation
        # No range measured at the step: no geometry, no ratio.
        per_step["opt"].append(float(r["optimality_ratio"]) if int(r["measured"]) > 0 else math.nan)
    settled = [m for t, m in zip(per_step["t"], per_step["max_error"]) if t >= SETTLE_S - 1e-9]
    rmse = _num(metrics.get("rmse_m"))
    pcrlb = _num(metrics.get("pcrlb_rmse_m"))
    run = {
        "steps": int(metrics.get("last_step", 0)),
        "mse_m2": rmse * rmse,
        "max_error_m": _num(metrics.get("max_error_m")),
        "max_error_settled_m": max(settled) if settled else math.nan,
        "pcrlb_mean_trace_m2": pcrlb * pcrlb,
        "anees": _num(metrics.get("anees")),
        "mean_optimality_ratio": _num(metrics.get("mean_optimality_ratio")),
        "final_max_gap_error_rad": _num(metrics.get("final_max_gap_error_rad")),
        "final_alive": int(metrics.get("final_agents", 0)),
        "agreement_fraction": _num(metrics.get("agreement_fraction")),
        "non_finite_estimates": bool(metrics.get("non_finite_estimates", False)),
    }
    return run, per_step


# ---------------------------------------------------------------------------------------
# Running one seed

def run_one(task):
    """Run one (scenario, mode, seed) and reduce it. Returns plain data."""
    out_dir, seed, steps = task["out_dir"], task["seed"], task["steps"]
    shutil.rmtree(out_dir, ignore_errors=True)
    metrics = None
    if task["processes"]:
        from . import launcher  # the DDS launcher only when asked for
        with open(os.devnull, "w") as quiet_log:
            res = launcher.run(task["config_path"], out_dir, steps=steps, seed=seed,
                               domain=task["domain"], overrides=task["overrides"],
                               progress=False, log=quiet_log)
        ok = res.ok
        metrics = res.summary.get("metrics")
    else:
        argv = [sim_executable(), "--config", task["config_path"], "--out", out_dir,
                "--seed", str(seed), "--quiet"]
        for o in task["overrides"]:
            argv += ["--set", o]
        if steps is not None:
            argv += ["--steps", str(steps)]
        proc = subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        ok = proc.returncode == 0
        # Exit 1 with a summary.json whose "ok" is false: the run went to its end but a
        # simulated process failed. Anything else is an error of the run itself.
        if not ok and not (proc.returncode == 1 and _summary_says_not_ok(out_dir)):
            how = (f"was killed by signal {-proc.returncode}" if proc.returncode < 0
                   else f"exited with {proc.returncode}")
            raise RunFailed(f"{' '.join(argv)} {how}:\n{proc.stdout}")
    if not ok and not metrics and not os.path.exists(os.path.join(out_dir, "summary.json")):
        raise RunFailed(f"{out_dir}: the run failed and wrote no summary.json")
    run, per_step = run_statistics(out_dir, metrics)
    run["ok"] = ok
    if not task["keep"] and ok:  # a failed run's artefacts stay, to look at
        shutil.rmtree(out_dir, ignore_errors=True)
    return {"key": task["key"], "index": task["index"], "seed": seed, "run": run, "ts": per_step,
            "out_dir": out_dir}


def _summary_says_not_ok(run_dir):
    try:
        with open(os.path.join(run_dir, "summary.json")) as f:
            summary = json.load(f)
    except (OSError, ValueError):
        return False
    return summary.get("ok") is False and "metrics" in summary


# ---------------------------------------------------------------------------------------
# Reduction across seeds

RESULT_COLUMNS = [
    "scenario", "mode", "control_law", "seeds", "steps", "true_range_variance_m2",
    "filter_range_variance_m2", "rmse_m", "rmse_se_m", "max_error_m", "median_run_max_error_m",
    "max_error_settled_m", "median_run_max_error_settled_m",
    "pcrlb_rmse_m", "rmse_over_pcrlb", "anees", "mean_optimality_ratio",
    "final_max_gap_error_rad", "final_alive_min", "runs_not_ok",
]


def _mean(values):
    return math.fsum(values) / len(values) if values else math.nan


def reduce_seeds(scenario, mode, resolved, runs):
    """One results row from the per-seed runs (sorted by seed index: a fixed summation order,
    so that a rerun gives bit-identical numbers). `resolved` is the mode's effective config.

    rmse_m: sqrt of the mean over seeds of each run's MSE (rmse_m^2 of its summary.json);
      every run has the same number of agent rows unless an agent dies, so this is the
      RMSE over seeds, steps and agents.
    rmse_se_m: its Monte Carlo standard error, se(MSE) / (2 RMSE) with se(MSE) the standard
      error of the per-seed MSEs (seeds are independent; steps within a seed are not).
    max_error_m: the largest error over seeds; median_run_max_error_m: the median over seeds
      of each run's largest error (what one run, like each of the thesis's, typically shows).
    max_error_settled_m, median_run_max_error_settled_m: the same over t >= SETTLE_S (the
      largest per-step max_error of metrics.csv there).
    pcrlb_rmse_m: sqrt of the mean over seeds of each run's pcrlb_rmse_m^2.
    anees, mean_optimality_ratio, final_max_gap_error_rad: means over seeds of the runs'.
    runs_not_ok: runs in which a process failed (they are counted in every statistic; their
      artefacts are kept in seed-<i>/).
    """
    runs = sorted(runs, key=lambda r: r["index"])
    m = len(runs)
    mses = [r["run"]["mse_m2"] for r in runs]
    rmse = math.sqrt(_mean(mses))
    se_mse = statistics.stdev(mses) / math.sqrt(m) if m > 1 else math.nan
    pcrlb = math.sqrt(_mean([r["run"]["pcrlb_mean_trace_m2"] for r in runs]))
    maxes = [r["run"]["max_error_m"] for r in runs]
    settled = [r["run"]["max_error_settled_m"] for r in runs]
    return {
        "scenario": scenario,
        "mode": mode,
        "control_law": resolved["agents"]["control_law"],
        "seeds": m,
        "steps": runs[0]["run"]["steps"],
        "true_range_variance_m2": float(resolved["target"]["range_noise_variance_m2"]),
        "filter_range_variance_m2": float(resolved["filter"]["range_variance_m2"]),
        "rmse_m": rmse,
        "rmse_se_m": se_mse / (2.0 * rmse) if rmse > 0 else math.nan,
        "max_error_m": max(maxes),
        "median_run_max_error_m": float(statistics.median(maxes)),
        "max_error_settled_m": max(settled),
        "median_run_max_error_settled_m": float(statistics.median(settled)),
        "pcrlb_rmse_m": pcrlb,
        "rmse_over_pcrlb": rmse / pcrlb if pcrlb > 0 else math.nan,
        "anees": _mean([r["run"]["anees"] for r in runs]),
        "mean_optimality_ratio": _mean([r["run"]["mean_optimality_ratio"] for r in runs]),
        "final_max_gap_error_rad": _mean([r["run"]["final_max_gap_error_rad"] for r in runs]),
        "final_alive_min": min(r["run"]["final_alive"] for r in runs),
        "runs_not_ok": sum(1 for r in runs if not r["run"]["ok"]),
    }


TIMESERIES_COLUMNS = ["step", "t", "rms_error_m", "mean_error_m", "max_error_m", "seed0_error_m",
                      "pcrlb_m", "anees", "optimality_ratio"]


def write_timeseries(path, runs):
    """Per-step statistics across seeds, from the seeds' metrics.csv: the RMS over seeds of
    the per-step RMS error (over agents), its mean, the largest error, the first seed's RMS
    error, sqrt of the mean squared PCRLB, the mean NEES / 2 and the mean optimality ratio
    (over the seeds that measured the step)."""
    runs = sorted(runs, key=lambda r: r["index"])
    by_seed = []
    for r in runs:
        ts = r["ts"]
        by_seed.append({key: dict(zip(ts["step"], ts[key]))
                        for key in ("t", "ms_error", "rms_error", "max_error", "pcrlb_sq",
                                    "nees_half", "opt")})
    steps = sorted({k for s in by_seed for k in s["t"]})
    with open(path, "w") as f:
        f.write(",".join(TIMESERIES_COLUMNS) + "\n")
        for k in steps:
            have = [s for s in by_seed if k in s["t"]]
            opt = [s["opt"][k] for s in have if not math.isnan(s["opt"][k])]
            f.write(",".join([str(k), f"{have[0]['t'][k]:.6g}"] + [f"{v:.6g}" for v in (
                math.sqrt(_mean([s["ms_error"][k] for s in have])),
                _mean([s["rms_error"][k] for s in have]),
                max(s["max_error"][k] for s in have),
                by_seed[0]["rms_error"].get(k, math.nan),
                math.sqrt(_mean([s["pcrlb_sq"][k] for s in have])),
                _mean([s["nees_half"][k] for s in have]),
                _mean(opt))]) + "\n")


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


def _resolve(path, overrides):
    try:
        return config.resolve(path, overrides), config.canonical_yaml(path, overrides)
    except config.ConfigRefused as e:
        raise BatchError(str(e))


def run_batch(config_paths, out_dir, seeds=20, base_seed=1, steps=None, modes=MODES,
              jobs=MAX_JOBS, processes=False, domain=150, keep_runs=False, quiet=False,
              label="deif-batch"):
    """Run every config in every mode over `seeds` derived seeds; write the batch folder and
    return the list of results rows. Raises BatchError."""
    if seeds < 1:
        raise BatchError("--seeds must be >= 1")
    if steps is not None and steps < 1:
        raise BatchError("--steps must be >= 1")
    jobs = max(1, min(int(jobs), MAX_JOBS))
    if processes:
        # A multi-process run already keeps N + 1 processes busy on the two cores; two at
        # once would starve the lock-step timeouts. Run them one after another.
        jobs = 1
    elif not os.path.exists(sim_executable()):
        raise BatchError(f"{sim_executable()} not found; build the deif_sim target (or set "
                         "DEIF_SIM_EXE / DEIF_BUILD_DIR)")
    out_dir = os.path.abspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    seed_list = [derive_seed(base_seed, i) for i in range(seeds)]

    scenarios = []
    tasks = []
    for path in config_paths:
        name = scenario_name(path)
        for mode in modes:
            overrides = mode_overrides(mode)
            # The steps override is checked with the rest (a fault beyond it is refused here).
            resolved, canonical = _resolve(path, overrides + (
                [f"scenario.steps={steps}"] if steps is not None else []))
            mode_dir = os.path.join(out_dir, name, mode)
            os.makedirs(mode_dir, exist_ok=True)
            with open(os.path.join(mode_dir, "config.yaml"), "w") as f:
                f.write(f"# {rel(path)}, mode {mode}"
                        + "".join(f", --set {o}" for o in overrides) + "\n" + canonical)
            scenarios.append((name, mode, resolved, mode_dir, path))
            for i, seed in enumerate(seed_list):
                tasks.append({"key": (name, mode), "index": i, "seed": seed, "steps": steps,
                              "config_path": path, "overrides": overrides,
                              "processes": processes, "domain": domain,
                              "out_dir": os.path.join(mode_dir, f"seed-{i:03d}"),
                              "keep": keep_runs or i == 0})

    with open(os.path.join(out_dir, "batch.json"), "w") as f:
        json.dump({"configs": [rel(p) for p in config_paths],
                   "modes": list(modes), "mode_overrides": {m: MODE_OVERRIDES[m] for m in modes},
                   "seeds": seeds, "base_seed": base_seed,
                   "derived_seeds": seed_list, "steps_override": steps,
                   "runner": "deif.launcher (multi-process)" if processes else "deif_sim (in-process)"},
                  f, indent=2)

    progress = Progress(len(tasks), label, quiet)
    started = time.time()
    collected = {}

    def record(task, result):
        collected.setdefault(result["key"], []).append(result)
        progress.update(f"{task['key'][0]} {task['key'][1]} seed {task['index']}")

    if jobs == 1:
        for t in tasks:
            record(t, run_one(t))
    else:
        # The work is in the deif_sim processes; threads only wait for them and read CSVs.
        with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(run_one, t): t for t in tasks}
            try:
                for fut in concurrent.futures.as_completed(futures):
                    record(futures[fut], fut.result())
            except BaseException:
                for fut in futures:  # the first failure ends the batch: start nothing more
                    fut.cancel()
                raise

    failed = sorted(r["out_dir"] for runs in collected.values() for r in runs if not r["run"]["ok"])
    if failed:
        sys.stderr.write(f"{label}: warning: {len(failed)} run(s) in which a process failed "
                         f"(see their summary.json): {', '.join(rel(p) for p in failed[:5])}"
                         f"{' ...' if len(failed) > 5 else ''}\n")
    rows = []
    for name, mode, resolved, mode_dir, path in scenarios:
        runs = collected[(name, mode)]
        write_per_seed(os.path.join(mode_dir, "per_seed.csv"), runs)
        write_timeseries(os.path.join(mode_dir, "timeseries.csv"), runs)
        row = reduce_seeds(name, mode, resolved, runs)
        row["config"] = rel(path)
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
    """timeseries.csv of one scenario and mode as {column: [floats]} ({} if absent)."""
    rows = artefacts.read_csv(os.path.join(batch_dir, scenario, mode, "timeseries.csv"))
    if not rows:
        return {}
    return {k: [float(r[k]) for r in rows] for k in rows[0]}


def print_table(rows, stream=sys.stdout):
    stream.write(f"{'scenario':<14}{'mode':<11}{'rmse [m]':>10}{'max [m]':>10}{'med max':>10}"
                 f"{'PCRLB':>10}{'ratio':>8}{'ANEES':>9}{'opt':>7}{'not ok':>8}\n")
    for r in rows:
        stream.write(f"{r['scenario']:<14}{r['mode']:<11}{r['rmse_m']:>10.4f}{r['max_error_m']:>10.4f}"
                     f"{r['median_run_max_error_m']:>10.4f}{r['pcrlb_rmse_m']:>10.4f}"
                     f"{r['rmse_over_pcrlb']:>8.2f}{r['anees']:>9.2f}{r['mean_optimality_ratio']:>7.3f}"
                     f"{r['runs_not_ok']:>8}\n")
