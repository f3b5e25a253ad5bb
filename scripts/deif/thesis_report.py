"""docs/RESULTS.md from the thesis and beyond batches (their results.json only; nothing is run).

The tables and the agree/differ verdicts are computed from the numbers. The explanations
of WHY our numbers differ are fixed text written against the default run of
scripts/deif-thesis (50 seeds, base seed 1); the runs are deterministic, so they stay true
for that command.
"""
import datetime
import json
import os

from . import batch

# What the thesis says about each simulation's largest error ||x - x_hat|| (one run each):
# (moving text, moving bound, stationary text, stationary number, "bound" | "value" | None).
THESIS = {
    1: ("< 0.2", 0.2, "about 0.25 at one time", 0.25, "value"),
    2: ("< 0.2 (fig 5.10)", 0.2, "similar to sim 1; moving mostly better (no number)", None, None),
    3: ("< 0.20", 0.2, "up to 0.45", 0.45, "value"),
    4: ("< 0.21", 0.21, "up to 0.91", 0.91, "value"),
    5: ("< 0.2 (fig 5.10)", 0.2, "as good as moving (no number)", None, None),
    6: ("< 0.2", 0.2, "< 0.2, same as moving", 0.2, "bound"),
    7: ("< 0.2", 0.2, "< 0.2, no longer the same as moving", 0.2, "bound"),
    8: ("< 0.2 (fig 5.10)", 0.2, "< 0.2 but visibly worse than moving", 0.2, "bound"),
    9: ("< 0.2 (fig 5.15)", 0.2, "as good as moving (no number)", None, None),
    10: ("< 0.2", 0.2, "< 0.2, same as moving", 0.2, "bound"),
    11: ("< 0.2", 0.2, "up to 0.26", 0.26, "value"),
    12: ("< 0.2 (fig 5.15)", 0.2, "up to 0.37", 0.37, "value"),
}
for _n in range(13, 17):
    THESIS[_n] = ("< 0.2 for every R", 0.2, "smaller R gives the best estimate (no number)", None, None)
for _n in range(17, 21):
    THESIS[_n] = ("< 0.2 for every R", 0.2, "worse than moving; smaller R best (no number)", None, None)


def _f(x, digits=3):
    if x is None:
        return "-"
    if x == 0 or 1e-3 <= abs(x) < 1e4:
        return f"{x:.{digits}g}"
    return f"{x:.2e}"


def _rows(batch_dir):
    res = batch.load_results(batch_dir)
    return {(r["scenario"], r["mode"]): r for r in res["results"]}, res


def _setting(n, row):
    start = "non-opt" if n <= 4 else "opt"
    path = "(5.7)" if 9 <= n <= 12 else "(5.3)"
    if n <= 12:
        return f"{_f(row['true_range_variance_m2'], 2)}", start, path
    return (f"{_f(row['true_range_variance_m2'], 2)}, R = {_f(row['filter_range_variance_m2'], 2)}",
            start, path)


def _max_cell(row):
    return (f"{_f(row['median_run_max_error_m'], 2)} ({_f(row['median_run_max_error_settled_m'], 2)}) "
            f"/ {_f(row['max_error_m'], 2)}")


def _verdict(n, mov, sta):
    _, mbound, _, sval, skind = THESIS[n]
    out = []
    m = mov["median_run_max_error_m"]
    if m <= mbound:
        out.append(f"moving: agrees (< {mbound:g})")
    else:
        out.append(f"moving: **differs**, {m / mbound:.1f}x the thesis's bound")
    s = sta["median_run_max_error_m"]
    if skind == "bound":
        out.append(f"stationary: agrees (< {sval:g})" if s <= sval
                   else f"stationary: **differs**, {s / sval:.1f}x the thesis's bound")
    elif skind == "value":
        ratio = s / sval
        out.append(f"stationary: agrees ({ratio:.2f}x)" if 0.67 <= ratio <= 1.5
                   else f"stationary: **differs**, {ratio:.2g}x the thesis's value")
    gain = sta["rmse_m"] / mov["rmse_m"] - 1.0
    # Conservative: the two modes share their seeds, so the paired difference is less noisy.
    se = (sta["rmse_se_m"] ** 2 + mov["rmse_se_m"] ** 2) ** 0.5 / mov["rmse_m"]
    out.append(f"stationary RMSE {gain * 100:+.1f} % vs moving (se <= {se * 100:.1f} %)")
    return "; ".join(out)


def thesis_tables(batch_dir):
    rows, res = _rows(batch_dir)
    lines = [
        "| sim | true $\\sigma^2$ (filter R) | start | path | thesis: moving | ours: moving | "
        "thesis: stationary | ours: stationary | verdict |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for n in range(1, 21):
        scen = f"sim{n:02d}"
        mov, sta = rows.get((scen, "moving")), rows.get((scen, "stationary"))
        if not mov or not sta:
            continue
        noise, start, path = _setting(n, mov)
        lines.append(f"| {n} | {noise} | {start} | {path} | {THESIS[n][0]} | {_max_cell(mov)} | "
                     f"{THESIS[n][2]} | {_max_cell(sta)} | {_verdict(n, mov, sta)} |")
    stats = [
        "| sim | mode | RMSE [m] (± MC se) | PCRLB [m] | RMSE / PCRLB | ANEES | det-J optimality | final gap error [rad] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for n in range(1, 21):
        for mode in batch.MODES:
            r = rows.get((f"sim{n:02d}", mode))
            if not r:
                continue
            gap = _f(r["final_max_gap_error_rad"], 2) if mode == "moving" else "-"
            stats.append(f"| {n} | {mode} | {_f(r['rmse_m'])} (± {_f(r['rmse_se_m'], 1)}) | "
                         f"{_f(r['pcrlb_rmse_m'])} | {r['rmse_over_pcrlb']:.2f} | {r['anees']:.2f} | "
                         f"{r['mean_optimality_ratio']:.3f} | {gap} |")
    return "\n".join(lines), "\n".join(stats), res


BEYOND_GROUPS = [
    ("Constant-velocity filter model vs the random walk (eq 5.1)",
     [("sim02", "thesis", "random walk, $\\sigma^2$ = 5.3e-4"), ("cv_sim02", "beyond", "constant velocity, $\\sigma^2$ = 5.3e-4"),
      ("sim04", "thesis", "random walk, $\\sigma^2$ = 0.53"), ("cv_sim04", "beyond", "constant velocity, $\\sigma^2$ = 0.53")]),
    ("Limited sensing range (R1 = 2.5 m), shifted figure eight, $\\sigma^2$ = 5.3e-4",
     [("sim10", "thesis", "unlimited range (sim 10)"), ("range_sim10", "beyond", "R1 = 2.5 m")]),
    ("Number of sensors, $\\sigma^2$ = 0.053, evenly spaced start",
     [("n3_sim07", "beyond", "N = 3"), ("sim07", "thesis", "N = 4 (sim 7)"), ("n6_sim07", "beyond", "N = 6"),
      ("n8_sim07", "beyond", "N = 8")]),
    ("N - 1: agent 2 killed at step 315 of 629, $\\sigma^2$ = 0.053",
     [("sim07", "thesis", "no fault (sim 7)"), ("kill_sim07", "beyond", "agent 2 killed at t = 3.15 s")]),
    ("Sensitivity to the unstated time step (same per-step Q)",
     [("dt1_sim01", "beyond", "sim 1, dt = 1 s (63 steps)"), ("dt0p1_sim01", "beyond", "sim 1, dt = 0.1 s"),
      ("sim01", "thesis", "sim 1, dt = 0.01 s (ours)"), ("dt0p001_sim01", "beyond", "sim 1, dt = 0.001 s"),
      ("dt1_sim04", "beyond", "sim 4, dt = 1 s (63 steps)"), ("dt0p1_sim04", "beyond", "sim 4, dt = 0.1 s"),
      ("sim04", "thesis", "sim 4, dt = 0.01 s (ours)"), ("dt0p001_sim04", "beyond", "sim 4, dt = 0.001 s")]),
]


def beyond_tables(thesis_dir, beyond_dir):
    rows = {"thesis": _rows(thesis_dir)[0], "beyond": _rows(beyond_dir)[0]}
    out = []
    for title, entries in BEYOND_GROUPS:
        out.append(f"**{title}**\n")
        out.append("| scenario | mode | RMSE [m] | median run max (settled) / worst [m] | PCRLB [m] | "
                   "RMSE / PCRLB | ANEES | det-J optimality | alive at end |")
        out.append("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for scen, src, label in entries:
            for mode in batch.MODES:
                r = rows[src].get((scen, mode))
                if not r:
                    continue
                out.append(f"| {label} (`{scen}`) | {mode} | {_f(r['rmse_m'])} | {_max_cell(r)} | "
                           f"{_f(r['pcrlb_rmse_m'])} | {r['rmse_over_pcrlb']:.2f} | {r['anees']:.2f} | "
                           f"{r['mean_optimality_ratio']:.3f} | {r['final_alive_min']} |")
        out.append("")
    return "\n".join(out)


def _fig(path, alt, doc_dir):
    return f"![{alt}]({os.path.relpath(path, doc_dir)})"


def _nested(rows):
    """{scenario: {mode: row}} for str.format's {T[sim04][moving][rmse_m]}."""
    out = {}
    for (scen, mode), r in rows.items():
        out.setdefault(scen, {})[mode] = r
    return out


def _gains(rows):
    """{scenario: stationary RMSE / moving RMSE - 1, in percent}."""
    return {scen: 100.0 * (m["stationary"]["rmse_m"] / m["moving"]["rmse_m"] - 1.0)
            for scen, m in _nested(rows).items() if "moving" in m and "stationary" in m}


def _range(values, digits=2):
    lo, hi = min(values), max(values)
    return f"{lo:.{digits}f}-{hi:.{digits}f}"


def write_results_md(path, thesis_dir, beyond_dir, figures, times=None):
    doc_dir = os.path.dirname(os.path.abspath(path))
    table, stats, res = thesis_tables(thesis_dir)
    trows = _rows(thesis_dir)[0]
    T, G = _nested(trows), _gains(trows)
    B, GB = {}, {}
    if beyond_dir:
        brows = _rows(beyond_dir)[0]
        B, GB = _nested(brows), _gains(brows)
    timing_path = os.path.join(os.path.dirname(thesis_dir), "thesis-timing.json")
    if times:
        with open(timing_path, "w") as f:
            json.dump(times, f, indent=2)
    elif os.path.exists(timing_path):
        with open(timing_path) as f:
            times = json.load(f)
    timing = ""
    if times:
        parts = ", ".join(f"{k} {v:.0f} s" for k, v in times.items() if k != "total")
        timing = (f"\n\nOn the 2-core development machine the whole command took "
                  f"{times.get('total', sum(times.values())) / 60:.1f} min ({parts}).")
    fig = {k: _fig(v, k, doc_dir) for k, v in figures.items()}
    low = [f"sim{n:02d}" for n in (1, 2, 5, 6, 9, 10)]
    high = [f"sim{n:02d}" for n in (3, 4, 7, 8, 11, 12)]
    ctx = dict(
        seeds=res["seeds"], base_seed=res["base_seed"], timing=timing, table=table, stats=stats,
        T=T, G=G, B=B, GB=GB,
        low_ratio=_range([T[s][m]["rmse_over_pcrlb"] for s in low for m in batch.MODES]),
        low_anees=_range([T[s][m]["anees"] for s in low for m in batch.MODES]),
        low_gain_opt=_range([G[s] for s in ("sim05", "sim06", "sim09", "sim10")], 1),
        low_gain_nonopt=_range([G[s] for s in ("sim01", "sim02")], 1),
        high_gain=_range([G[s] for s in high], 1),
        high_ratio=_range([T[s][m]["rmse_over_pcrlb"] for s in ("sim04", "sim08", "sim12") for m in batch.MODES]),
        low_max=_range([T[s][m]["max_error_m"] for s in low for m in batch.MODES]),
        fig_overview=fig.get("overview", ""), fig_5_5=fig.get("5.5", ""),
        fig_5_14=fig.get("5.14", ""), fig_5_10=fig.get("5.10", ""), fig_5_15=fig.get("5.15", ""),
        fig_5_16=fig.get("5.16", ""),
        fig_beyond=fig.get("beyond", ""), fig_kill=fig.get("kill_sim07", ""), fig_range=fig.get("range_sim10", ""),
        date=datetime.date.today().isoformat())
    text = TEMPLATE.format(**ctx)
    if beyond_dir:
        ctx["n_ratio"] = B["n8_sim07"]["moving"]["rmse_m"] / B["n3_sim07"]["moving"]["rmse_m"]
        ctx["range_factor"] = B["range_sim10"]["stationary"]["rmse_m"] / B["range_sim10"]["moving"]["rmse_m"]
        text += BEYOND_TEMPLATE.format(beyond=beyond_tables(thesis_dir, beyond_dir), **ctx)
    else:
        text += "\n## Beyond the thesis\n\nNot run (scripts/deif-thesis --no-beyond).\n"
    with open(path, "w") as f:
        f.write(text)
    return path


TEMPLATE = """# Results: chapter 5 of the thesis, reproduced

Generated by `scripts/deif-thesis` ({date}) from `runs/batch-thesis/` and
`runs/batch-beyond/`; do not edit by hand (edit `scripts/deif/thesis_report.py`). The setup,
and the reasons for every value the thesis leaves unstated, are in
[THESIS_SETUP.md](THESIS_SETUP.md). Each of the 20 simulations ran moving (Voronoi law) and
stationary over {seeds} seeds (derived from base seed {base_seed}; both modes see the same
noise), in-process (`deif_sim`), 629 steps of 0.01 s.{timing}

## In short

1. **At low noise (variance 5.3e-5 and 5.3e-4) we agree with the thesis, with errors far
   below its bounds.** Our largest error over all seeds is {low_max} m against the thesis's
   "< 0.2". The filter is efficient there: RMSE/PCRLB {low_ratio}, ANEES {low_anees}. The
   stationary RMSE is {low_gain_opt} % above the moving one from the optimal start (the
   thesis: "almost the same") and {low_gain_nonopt} % from the non-optimal start (the
   thesis: moving better).
2. **At high noise (0.053 and 0.53) we do not reproduce the thesis's main claim.** The thesis
   reports moving sensors below 0.21 against stationary ones up to 0.91 (sim 4). Our
   stationary RMSE is only {high_gain} % above the moving one, and in sim 4 a typical run's
   largest error is {T[sim04][moving][median_run_max_error_m]:.2f} m moving and
   {T[sim04][stationary][median_run_max_error_m]:.2f} m stationary. Two facts
   that sensor motion cannot change dominate: (a) the random-walk model (5.1) with
   Q = 0.00013 per step lags behind a target moving at up to 1.4 m/s; at variance 0.53 the
   RMSE is {high_ratio} times the PCRLB of that model, with ANEES near 10 (the filter is
   overconfident because its model is wrong); (b) even the thesis's "non-optimal" angles keep
   {T[sim04][stationary][mean_optimality_ratio]:.0%} of the optimal det J on average and the
   optimal stationary ring {T[sim08][stationary][mean_optimality_ratio]:.0%}, so motion can add
   at most ~25 % information (~10 % in RMSE).
3. **Sims 13-20 (filter R varied) agree only in part.** At high noise (true 0.53) a smaller
   filter R helps, as the thesis says: R = 0.053 (x0.1) gives RMSE
   {T[sim18][moving][rmse_m]:.3f} m against {T[sim19][moving][rmse_m]:.3f} m at the true R,
   because a larger gain shortens the lag of (a); it is not monotone (R = 0.0053 gives
   {T[sim17][moving][rmse_m]:.3f} m). At low noise (true 5.3e-5) the true R is best
   ({T[sim15][moving][rmse_m]:.4f} m) and the smaller ones are worse
   ({T[sim14][moving][rmse_m]:.4f} and {T[sim13][moving][rmse_m]:.4f} m), contrary to the
   thesis. At high noise the moving error is not below 0.2 for any R.

The thesis shows one run per simulation. We compare its "the error gets as high as X" with
the **median over seeds of each run's largest error**; in brackets the same over t >= 1 s,
which leaves out the first update from the initial guess (it depends on the unstated P0);
after the slash the worst over all {seeds} seeds.

## The 20 simulations: largest error ||x - x_hat||

Ours: median run max (settled, t >= 1 s) / worst over all seeds [m]. Verdict: the moving
median run max against the thesis's bound; the stationary one against the thesis's number
(a "< X" must hold; an "up to X" agrees within a factor 1.5); and how much larger the
stationary RMSE is than the moving one, with a conservative Monte Carlo standard error.

{table}

### Why our numbers differ where they do

- **High noise, both modes (sims 3, 4, 7, 8, 11, 12, 17-20).** The error is the lag of the
  random-walk filter behind the moving target (see the right-hand panels: the estimate cuts
  the corners of the figure eight), not the geometry. The PCRLB of the filter's own model is
  {T[sim04][moving][pcrlb_rmse_m]:.2f} m at variance 0.53; the RMSE is about three times
  that, for moving and stationary sensors alike. The thesis's moving "< 0.21" at variance
  0.53 needs a finer time step (at dt = 0.001 s our sim 4 moving RMSE is
  {B[dt0p001_sim04][moving][rmse_m]:.3f} m, settled median run max
  {B[dt0p001_sim04][moving][median_run_max_error_settled_m]:.2f} m) or a model that follows
  the target (the constant-velocity filter below: RMSE {B[cv_sim04][moving][rmse_m]:.3f} m).
  The time step is unstated in the thesis; we chose ours from Q before running anything
  (THESIS_SETUP.md) and report the others as a sensitivity only.
- **Stationary at high noise (sims 3, 4: thesis 0.45 and 0.91; 11, 12: 0.26 and 0.37).** Ours
  are {T[sim03][stationary][median_run_max_error_m]:.2f}, {T[sim04][stationary][median_run_max_error_m]:.2f},
  {T[sim11][stationary][median_run_max_error_m]:.2f} and {T[sim12][stationary][median_run_max_error_m]:.2f} m,
  and the moving ones about the same. The thesis's gap between moving and stationary does not
  appear at any time step we tried (dt = 1, 0.1, 0.01, 0.001 s). The non-optimal angles
  [2.18, 2.45, 3.72, 4.52] rad span 2.3 rad around the target; the range information of
  four such sensors is not poor enough to make a stationary error four times a moving one.
  We cannot tell from the text what made the thesis's stationary runs that much worse (a
  single unlucky run, or a difference in the Matlab code).
- **Low noise (sims 1, 2, 5, 6, 9, 10, 13-16).** The thesis's "< 0.2" holds with a wide
  margin. Its 0.25 for the stationary sensors of sim 1 is
  {T[sim01][stationary][max_error_m]:.3f} m at worst here. At dt = 1 s (eq 5.3 read
  literally, t = k) our sim 1 gives a typical largest error of
  {B[dt1_sim01][moving][median_run_max_error_m]:.2f} m moving and
  {B[dt1_sim01][stationary][median_run_max_error_m]:.2f} m stationary, the thesis's size, so the
  thesis may have used a coarse step; but then sim 4 fails for both modes
  ({B[dt1_sim04][moving][median_run_max_error_m]:.1f} m).
- **Sims 13-16, R below the truth.** With little lag at low noise the best R is the true one,
  as Kalman theory says; a 10-100x smaller R makes the filter trust each range too much
  (ANEES {T[sim14][moving][anees]:.0f} and {T[sim13][moving][anees]:.0f}). The thesis's "trusting
  the measurements more gives the best estimate" holds only where the lag dominates (high
  noise), where shrinking R is a crude way of raising the filter's gain.

{fig_overview}

### Monte Carlo statistics

RMSE over all steps, agents and seeds; the PCRLB of the filter's model at the true noise and
the true positions (a bound for a target that follows the model, so a ratio above 1 mostly
measures the model mismatch); ANEES (1 = consistent); det J / det J* of the true geometry
(1 = Proposition 1's optimum); the moving ring's final largest gap error.

{stats}

### Figures

Equivalents of figs 5.2-5.9 and 5.11-5.14 are in `runs/batch-thesis/figures/` (one per
simulation): left, ||x - x_hat|| over time, moving (blue) against stationary (red), thick the
RMS over the seeds, thin the first seed, dashed the PCRLB; right, the first seed's true path,
estimates and final sensor positions. Two of them (sim 4: the thesis's 0.91 against 0.21;
sim 12: the shifted path at the highest noise):

{fig_5_5}

{fig_5_14}

Summary figures 5.10, 5.15 and 5.16: the RMS error over time, stationary on top, moving below.

{fig_5_10}

{fig_5_15}

{fig_5_16}
"""

BEYOND_TEMPLATE = """
## Beyond the thesis

Configs in `configs/beyond/`, each a thesis config with the keys marked `[changed]`; same
seeds, same statistics.

{beyond}

{fig_beyond}

- **Constant velocity vs random walk.** With q = 1 m^2/s^3 (the order of the path's
  mean-square acceleration; not tuned) the constant-velocity filter follows the target: at
  variance 0.53 the moving RMSE falls from {T[sim04][moving][rmse_m]:.3f} to
  {B[cv_sim04][moving][rmse_m]:.3f} m, the filter becomes consistent (ANEES
  {B[cv_sim04][moving][anees]:.2f}, RMSE/PCRLB {B[cv_sim04][moving][rmse_over_pcrlb]:.2f}), and
  the stationary sensors are {GB[cv_sim04]:.0f} % worse. At 5.3e-4 it helps too
  ({T[sim02][moving][rmse_m]:.4f} -> {B[cv_sim02][moving][rmse_m]:.4f} m). At high noise the
  motion model matters far more than the sensor motion.
- **Limited sensing range.** With R1 = 2.5 m the stationary sensors on the origin circle lose
  the shifted figure eight (eq 5.7) for part of each lap (det-J optimality
  {B[range_sim10][stationary][mean_optimality_ratio]:.2f}); their RMSE is
  {B[range_sim10][stationary][rmse_m]:.3f} m against {B[range_sim10][moving][rmse_m]:.3f} m for
  the moving ones, which keep 2 m from the estimate and never leave range. Here motion pays
  by a factor {range_factor:.0f}: the
  thesis's point, in the setting its conclusion proposes for future work.
- **N = 3, 4, 6, 8.** Moving RMSE {B[n3_sim07][moving][rmse_m]:.3f}, {T[sim07][moving][rmse_m]:.3f},
  {B[n6_sim07][moving][rmse_m]:.3f}, {B[n8_sim07][moving][rmse_m]:.3f} m. With a random walk the
  steady-state variance is ~sqrt(Q / J), so the PCRLB falls only as N^-1/4
  ({B[n3_sim07][moving][pcrlb_rmse_m]:.3f} -> {B[n8_sim07][moving][pcrlb_rmse_m]:.3f} m, (8/3)^-1/4 = 0.78),
  while the lag, which dominates the RMSE here, falls as the gain rises, ~N^-1/2
  ((8/3)^-1/2 = 0.61): the RMSE ratio from N = 3 to 8 is {n_ratio:.2f}. Evenly spaced
  stationary sensors are already near the optimum: moving and stationary stay within a few %.
- **N - 1.** After agent 2 is killed at t = 3.15 s the three moving survivors re-form their
  ring (final gap error {B[kill_sim07][moving][final_max_gap_error_rad]:.3f} rad from 2 pi / 3;
  det-J optimality {B[kill_sim07][moving][mean_optimality_ratio]:.3f} over the run); the
  stationary survivors keep gaps pi, pi/2, pi/2 (optimality
  {B[kill_sim07][stationary][mean_optimality_ratio]:.2f}). RMSE {B[kill_sim07][moving][rmse_m]:.3f} m
  moving, {B[kill_sim07][stationary][rmse_m]:.3f} m stationary, against
  {T[sim07][moving][rmse_m]:.3f} m without the fault.
- **Time step.** With the per-step Q fixed, a finer dt makes the target move less per step
  relative to Q, and the lag falls: sim 4's moving RMSE is
  {B[dt1_sim04][moving][rmse_m]:.2f}, {B[dt0p1_sim04][moving][rmse_m]:.2f},
  {T[sim04][moving][rmse_m]:.2f} and {B[dt0p001_sim04][moving][rmse_m]:.3f} m at dt = 1, 0.1,
  0.01 and 0.001 s. The unstated time step is the parameter the thesis's high-noise numbers
  depend on most; at no time step do stationary sensors fall behind as far as the thesis
  reports.

{fig_kill}

{fig_range}
"""
