"""Figures of a Monte Carlo batch in the layout of the thesis's chapter 5 (matplotlib PNG).

Reads only what scripts/lib/batch.py wrote (results.json, <scenario>/<mode>/timeseries.csv
and the first seed's artefacts in <scenario>/<mode>/seed-000/); never runs anything.

  scenario_figure(...)  figs 5.2-5.9, 5.11-5.14: left, ||x - x_hat|| over time, moving
                        against stationary (first seed thin, RMS over the seeds thick), with
                        the PCRLB dashed; right, the first seed's true path, estimates and
                        final sensor positions.
  summary_figure(...)   figs 5.10, 5.15, 5.16: RMS error over time of several scenarios,
                        stationary on top, moving below, one column per group.
  results_bar_figure(...) RMSE of moving against stationary per scenario, with the PCRLB.
"""
import io
import math
import os

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import batch  # noqa: E402
import deifrun  # noqa: E402

DPI = 80
COLOURS = {"moving": "tab:blue", "stationary": "tab:red"}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _save(fig, out_png):
    """Save at DPI as a 64-colour palette PNG (a third of the size of an RGBA one; the plots
    use a handful of colours), falling back to matplotlib's own PNG without Pillow."""
    os.makedirs(os.path.dirname(os.path.abspath(out_png)), exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=DPI, format="png")
    plt.close(fig)
    try:
        from PIL import Image
        buf.seek(0)
        Image.open(buf).convert("RGB").quantize(colors=64).save(out_png, optimize=True)
    except ImportError:
        with open(out_png, "wb") as f:
            f.write(buf.getvalue())
    return out_png


def _load_csv(path):
    rows = deifrun.read_csv(path)
    if not rows:
        return {}
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def _results_by_key(batch_dir):
    res = batch.load_results(batch_dir)
    return {(r["scenario"], r["mode"]): r for r in res["results"]}


def _first_seed(batch_dir, scenario, mode):
    """Truth, the estimate of the lowest-id agent that reports every step, and the final
    positions of the agents alive at the end, from the first seed's run folder."""
    run = os.path.join(batch_dir, scenario, mode, "seed-000")
    truth = _load_csv(os.path.join(run, "target.csv"))
    agents = {}
    j = 1
    while os.path.exists(os.path.join(run, f"agent_{j}.csv")):
        a = _load_csv(os.path.join(run, f"agent_{j}.csv"))
        if a:
            agents[j] = a
        j += 1
    if not truth or not agents:
        return None
    last = max(a["step"][-1] for a in agents.values())
    finals = {j: (a["pos_x"][-1], a["pos_y"][-1]) for j, a in agents.items() if a["step"][-1] == last}
    survivor = agents[min(finals)]
    return {"truth": truth, "estimate": survivor, "finals": finals}


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


def is_png(path):
    try:
        with open(path, "rb") as f:
            return os.path.getsize(path) > len(PNG_SIGNATURE) and f.read(8) == PNG_SIGNATURE
    except OSError:
        return False
