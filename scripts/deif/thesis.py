"""Chapter 5 of the thesis: the figures of a Monte Carlo batch in the thesis's layout, and the
whole reproduction (scripts/deif-thesis).

The figures read only what deif.batch wrote (results.json, <scenario>/<mode>/timeseries.csv
and the first seed's artefacts in <scenario>/<mode>/seed-000/); they never run anything.

  scenario_figure(...)  figs 5.2-5.9, 5.11-5.14: left, the error over time, moving against
                        stationary (first seed thin, RMS over the seeds thick), with the PCRLB
                        dashed; right, the first seed's true path, estimates and final sensor
                        positions.
  summary_figure(...)   figs 5.10, 5.15, 5.16: RMS error over time of several scenarios,
                        stationary on top, moving below, one column per group.
  results_bar_figure(...) RMSE of moving against stationary per scenario, with the PCRLB.
"""
import math
import os
import shutil
import subprocess
import sys
import time

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from . import batch, paths, plots  # noqa: E402

DPI = 80
COLOURS = {"moving": "tab:blue", "stationary": "tab:red"}
is_png = plots.is_png


def _save(fig, out_png):
    return plots.save_png(fig, out_png, DPI, palette=True)


def _results_by_key(batch_dir):
    res = batch.load_results(batch_dir)
    return {(r["scenario"], r["mode"]): r for r in res["results"]}


def _first_seed(batch_dir, scenario, mode):
    """Truth, the estimate of the lowest-id agent alive at the end, and the final positions
    of the agents alive at the end, from the first seed's run folder."""
    run = os.path.join(batch_dir, scenario, mode, "seed-000")
    truth = plots.load_columns(os.path.join(run, "target.csv"))
    agents = plots.load_agents(run)
    if not truth or not agents:
        return None
    last = max(a["step"][-1] for a in agents.values())
    finals = {j: (a["pos_x"][-1], a["pos_y"][-1]) for j, a in agents.items() if a["step"][-1] == last}
    return {"truth": truth, "estimate": agents[min(finals)], "finals": finals}


def _label(row):
    if row is None:
        return "?"
    if abs(row["filter_range_variance_m2"] - row["true_range_variance_m2"]) > 1e-15:
        return f"R = {row['filter_range_variance_m2']:.2g}"
    return f"$\\sigma^2$ = {row['true_range_variance_m2']:.2g}"


def scenario_figure(batch_dir, scenario, out_png, title=None):
    rows = _results_by_key(batch_dir)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8), gridspec_kw={"width_ratios": [1.5, 1]})
    for mode in batch.MODES:
        ts = batch.read_timeseries(batch_dir, scenario, mode)
        if not ts:
            continue
        c = COLOURS[mode]
        row = rows.get((scenario, mode))
        m = row["seeds"] if row else "?"
        ax1.plot(ts["t"], ts["seed0_error_m"], color=c, lw=0.6, alpha=0.6)
        ax1.plot(ts["t"], ts["rms_error_m"], color=c, lw=1.8, label=f"{mode}: RMS over {m} seeds (thin: seed 0)")
        ax1.plot(ts["t"], ts["pcrlb_m"], color=c, lw=1.0, ls="--", label=f"{mode}: PCRLB")
    ax1.set_xlabel("t [s]")
    ax1.set_ylabel(r"$\|x - \hat{x}\|$ [m]")
    ax1.set_ylim(bottom=0)
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7, loc="upper right")
    for mode in batch.MODES:
        fs = _first_seed(batch_dir, scenario, mode)
        if fs is None:
            continue
        c = COLOURS[mode]
        if mode == batch.MODES[0]:
            ax2.plot(fs["truth"]["x_true"], fs["truth"]["y_true"], "k-", lw=1.2, label="true path x")
        ax2.plot(fs["estimate"]["x_est"], fs["estimate"]["y_est"], color=c, lw=0.7, alpha=0.8,
                 label=rf"$\hat{{x}}$ {mode}")
        px = [p[0] for p in fs["finals"].values()]
        py = [p[1] for p in fs["finals"].values()]
        ax2.plot(px, py, "o" if mode == "moving" else "s", color=c, mfc=c if mode == "moving" else "none",
                 ms=7, ls="none", label=f"final sensors {mode}")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=7, loc="best")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("y [m]")
    ref = rows.get((scenario, "moving")) or rows.get((scenario, "stationary"))
    fig.suptitle(title or f"{scenario}: stationary vs moving sensors, {_label(ref)}", fontsize=10)
    fig.tight_layout()
    return _save(fig, out_png)


def summary_figure(batch_dir, groups, out_png, title):
    """groups: [(column title, [scenario, ...]), ...]. Stationary on top, moving below."""
    rows = _results_by_key(batch_dir)
    fig, axes = plt.subplots(2, len(groups), figsize=(4.6 * len(groups) + 0.6, 5.6), squeeze=False,
                             sharey=True)
    for col, (col_title, scenarios) in enumerate(groups):
        for r, mode in enumerate(("stationary", "moving")):
            ax = axes[r][col]
            for scen in scenarios:
                ts = batch.read_timeseries(batch_dir, scen, mode)
                if not ts:
                    continue
                ax.semilogy(ts["t"], ts["rms_error_m"], lw=1.2, label=f"{scen}: {_label(rows.get((scen, mode)))}")
            ax.set_title(f"{col_title}: {mode}", fontsize=9)
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=7, loc="best")
            if r == 1:
                ax.set_xlabel("t [s]")
            if col == 0:
                ax.set_ylabel(r"RMS $\|x - \hat{x}\|$ [m]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, out_png)


def results_bar_figure(batch_dir, out_png, title, scenarios=None):
    """RMSE per scenario, moving against stationary, with the PCRLB as a tick."""
    rows = _results_by_key(batch_dir)
    names = scenarios or sorted({s for s, _ in rows})
    fig, ax = plt.subplots(figsize=(max(5.0, 0.45 * len(names) + 2.0), 3.4))
    width = 0.4
    for i, mode in enumerate(batch.MODES):
        xs = [k + (i - 0.5) * width for k in range(len(names))]
        vals = [rows[(n, mode)]["rmse_m"] if (n, mode) in rows else math.nan for n in names]
        bounds = [rows[(n, mode)]["pcrlb_rmse_m"] if (n, mode) in rows else math.nan for n in names]
        ax.bar(xs, vals, width, color=COLOURS[mode], alpha=0.8, label=f"{mode} RMSE")
        ax.plot(xs, bounds, "k_", ms=10, mew=1.5, label="PCRLB" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels(names, rotation=60, fontsize=7, ha="right")
    ax.set_ylabel("RMSE [m]")
    ax.grid(alpha=0.3, axis="y", which="both")
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, out_png)


# The thesis's figures and which simulation each shows.
SCENARIO_FIGURES = {f"sim{n:02d}": f"5.{n + 1}" for n in range(1, 9)}
SCENARIO_FIGURES.update({f"sim{n:02d}": f"5.{n + 2}" for n in range(9, 13)})
SUMMARY_FIGURES = {
    "5.10": ("Simulations 1-8: stationary vs moving sensors (fig 5.10)",
             [("sims 1-4, non-optimal start", [f"sim{n:02d}" for n in range(1, 5)]),
              ("sims 5-8, optimal start", [f"sim{n:02d}" for n in range(5, 9)])]),
    "5.15": ("Simulations 9-12 (eq 5.7): stationary vs moving sensors (fig 5.15)",
             [("sims 9-12, optimal start", [f"sim{n:02d}" for n in range(9, 13)])]),
    "5.16": ("Simulations 13-20: filter R varied (fig 5.16)",
             [("sims 13-16, true $\\sigma^2$ = 5.3e-5", [f"sim{n:02d}" for n in range(13, 17)]),
              ("sims 17-20, true $\\sigma^2$ = 0.53", [f"sim{n:02d}" for n in range(17, 21)])]),
}


def thesis_figures(batch_dir, out_dir):
    """Every thesis figure the batch has data for; returns {figure number: png path}."""
    rows = _results_by_key(batch_dir)
    have = {s for s, _ in rows}
    written = {}
    for scen, num in sorted(SCENARIO_FIGURES.items()):
        if scen in have:
            written[num] = scenario_figure(
                batch_dir, scen, os.path.join(out_dir, f"fig_{num.replace('.', '_')}_{scen}.png"),
                f"Simulation {int(scen[3:])} (thesis fig {num}): stationary vs moving, "
                f"{_label(rows.get((scen, 'moving')) or rows.get((scen, 'stationary')))}")
    for num, (title, groups) in SUMMARY_FIGURES.items():
        groups = [(t, [s for s in scens if s in have]) for t, scens in groups]
        if all(scens for _, scens in groups):
            written[num] = summary_figure(batch_dir, groups,
                                          os.path.join(out_dir, f"fig_{num.replace('.', '_')}.png"), title)
    return written


# ---------------------------------------------------------------------------------------
# The reproduction

THESIS_BATCH = os.path.join(paths.ROOT, "runs", "batch-thesis")
BEYOND_BATCH = os.path.join(paths.ROOT, "runs", "batch-beyond")
DOC_FIGURES = os.path.join(paths.ROOT, "docs", "figures")
RESULTS_MD = os.path.join(paths.ROOT, "docs", "RESULTS.md")
# The figures committed under docs/figures (the rest stay in runs/batch-thesis/figures).
DOC_FIGURE_NUMBERS = ("5.5", "5.14", "5.10", "5.15", "5.16")
BUILD_TARGETS = ("deif_sim", "deif_config")  # what a batch runs


def log(msg, quiet=False):
    if not quiet:
        print(f"deif-thesis: {msg}", file=sys.stderr, flush=True)


def build(quiet):
    """Build the executables a batch runs (incremental); a new build folder is configured
    first. Skipped when DEIF_SIM_EXE names the simulation to use."""
    if os.environ.get("DEIF_SIM_EXE"):
        return
    build_dir = paths.build_dir()
    jobs = os.environ.get("DEIF_JOBS", str(min(2, os.cpu_count() or 1)))
    out = subprocess.DEVNULL if quiet else None
    if not os.path.exists(os.path.join(build_dir, "CMakeCache.txt")):
        log(f"configuring {build_dir}", quiet)
        # Configure as scripts/build does; without Fast DDS, the simulation alone.
        if subprocess.run(["cmake", "-S", paths.ROOT, "-B", build_dir, "-DCMAKE_BUILD_TYPE=Release"],
                          stdout=out).returncode != 0:
            subprocess.run(["cmake", "-S", paths.ROOT, "-B", build_dir, "-DCMAKE_BUILD_TYPE=Release",
                            "-DDEIF_BUILD_DDS=OFF"], stdout=out, check=True)
    log(f"building {', '.join(BUILD_TARGETS)} in {build_dir} (-j{jobs})", quiet)
    cmd = ["cmake", "--build", build_dir, "-j", jobs]
    for t in BUILD_TARGETS:
        cmd += ["--target", t]
    if subprocess.run(cmd, stdout=out).returncode != 0:
        raise batch.BatchError(f"building {', '.join(BUILD_TARGETS)} failed (see above)")


def draw(thesis_dir=THESIS_BATCH, beyond_dir=BEYOND_BATCH, doc_figures=DOC_FIGURES):
    """Every figure of the thesis batch into <thesis_dir>/figures, and the few shown in
    RESULTS.md into doc_figures. Returns {name: png path} of the latter."""
    all_figs = thesis_figures(thesis_dir, os.path.join(thesis_dir, "figures"))
    all_figs["overview"] = results_bar_figure(
        thesis_dir, os.path.join(thesis_dir, "figures", "overview.png"),
        "Simulations 1-20: RMSE over all seeds (tick: PCRLB)")
    os.makedirs(doc_figures, exist_ok=True)
    doc_figs = {}
    for num in DOC_FIGURE_NUMBERS + ("overview",):
        if num in all_figs:
            dest = os.path.join(doc_figures, "thesis_" + os.path.basename(all_figs[num]))
            shutil.copyfile(all_figs[num], dest)
            doc_figs[num] = dest
    if beyond_dir and os.path.exists(os.path.join(beyond_dir, "results.json")):
        doc_figs["beyond"] = results_bar_figure(
            beyond_dir, os.path.join(doc_figures, "beyond_overview.png"),
            "Beyond the thesis: RMSE over all seeds (tick: PCRLB)")
        for scen in ("kill_sim07", "range_sim10"):
            if os.path.isdir(os.path.join(beyond_dir, scen)):
                doc_figs[scen] = scenario_figure(
                    beyond_dir, scen, os.path.join(doc_figures, f"beyond_{scen}.png"))
    return doc_figs


def reproduce(seeds=50, base_seed=1, beyond=True, report_only=False, quiet=False):
    """Build, run the thesis (and beyond) batches, draw, write docs/RESULTS.md. Returns the
    report's path. Raises batch.BatchError."""
    from . import thesis_report
    started = time.time()
    times = {}
    if not report_only:
        t = time.time()
        build(quiet)
        times["build"] = time.time() - t
        t = time.time()
        shutil.rmtree(THESIS_BATCH, ignore_errors=True)
        batch.run_batch(batch.expand_configs([os.path.join(paths.ROOT, "configs", "thesis")]),
                        THESIS_BATCH, seeds=seeds, base_seed=base_seed, quiet=quiet,
                        label="deif-thesis sims 1-20")
        times["thesis"] = time.time() - t
        if beyond:
            t = time.time()
            shutil.rmtree(BEYOND_BATCH, ignore_errors=True)
            batch.run_batch(batch.expand_configs([os.path.join(paths.ROOT, "configs", "beyond")]),
                            BEYOND_BATCH, seeds=seeds, base_seed=base_seed, quiet=quiet,
                            label="deif-thesis beyond")
            times["beyond"] = time.time() - t
    if not os.path.exists(os.path.join(THESIS_BATCH, "results.json")):
        raise batch.BatchError(f"{THESIS_BATCH}/results.json not found; run without --report-only")
    t = time.time()
    have_beyond = os.path.exists(os.path.join(BEYOND_BATCH, "results.json"))
    doc_figs = draw(THESIS_BATCH, BEYOND_BATCH if have_beyond else None)
    times["figures"] = time.time() - t
    if not report_only:
        times["total"] = time.time() - started
    report = thesis_report.write_results_md(RESULTS_MD, THESIS_BATCH, BEYOND_BATCH if have_beyond else None,
                                            doc_figs, times if not report_only else None)
    log(f"figures: {os.path.join(THESIS_BATCH, 'figures')} and {DOC_FIGURES}", quiet)
    log(f"report: {report}", quiet)
    log(f"done in {time.time() - started:.0f} s", quiet)
    return report
