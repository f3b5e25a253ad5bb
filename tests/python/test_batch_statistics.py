"""The batch runner's statistics on cases with a known answer (deif.batch, scripts/deif-batch).

Case A: a static target at the centre of four stationary sensors at the optimum (gaps
pi/2). The filter is then (near) efficient, so its RMSE must approach the PCRLB, its
ANEES must be near 1, and the optimality ratio must be exactly 1.

Case B: the same, but the filter assumes R = 4 x the true range variance. The estimate is
the same weighted average (the prior weighs next to nothing), so RMSE/PCRLB must stay near
1 -- which fails if the bound were built from the filter's R instead of the true one --
while the filter's covariance is 4x too large: ANEES near 1/4.

Also: a rerun of the same command gives byte-identical results; another base seed gives
other numbers; a one-seed batch reproduces deif_sim's own summary.json and metrics.csv; the
command line runs.
"""
import json
import math
import os
import subprocess

import pytest

from conftest import ROOT
from deif import artefacts, batch, paths

SEEDS = 200
STEPS = 100

# Why these numbers (GIVEN):
# - true range sigma 0.1 m at a range of 2 m: the range's curvature error e^2 / (2 r) is
#   below 1e-3 m for the first update's error (~0.07 m), 1 % of sigma: the EKF is linear.
# - P0 = 1 m^2 against the first step's information N / (2 sigma^2) = 200 m^-2 per axis: the
#   estimator starts at the truth, so its MSE is J^-1 - J^-2 P0^-1 = J^-1 (1 - 1/J), at most
#   0.5 % below the bound at step 1 and less later.
# - q = 1e-9 m^2 per step: the bound allows a walk the truth does not make; over 100 steps it
#   adds 1e-7 m^2 against a bound of 1 / 20000 m^2 at step 100: 0.2 %.
# So the expected RMSE/PCRLB is 1 within ~0.5 %, far inside the statistical tolerance:
#
# TOLERANCE: each seed gives one MSE (its mean over the steps). For a 2-D error with equal
# variances ||e||^2 is a scaled chi^2 with 2 degrees of freedom: relative std 1. Averaging
# correlated steps cannot raise the relative std of the per-seed mean above 1, so over M
# independent seeds the MSE's relative standard error is at most 1/sqrt(M), and the RMSE's
# (half of it, by the delta method) at most 1/(2 sqrt(M)) = 0.035 for M = 200. We allow three
# of them: |RMSE/PCRLB - 1| < 3/(2 sqrt(M)) = 0.106. NEES/2 is chi^2_2 / 2 (mean 1, relative
# std 1); the same argument gives |ANEES - 1| < 3/sqrt(M) = 0.21 (and 0.25 x that in case B).
RATIO_TOL = 3.0 / (2.0 * math.sqrt(SEEDS))
ANEES_TOL = 3.0 / math.sqrt(SEEDS)

KNOWN = """
scenario: {{name: "known", steps: {steps}, dt_s: 0.1}}
target:
  trajectory: static
  start_m: [0.0, 0.0]
  range_noise_variance_m2: 0.01
filter:
  motion_model: random_walk
  process_noise: 1.0e-9
  range_variance_m2: {filter_r}
  initial_estimate_m: [0.0, 0.0]
  initial_position_variance_m2: 1.0
agents:
  count: 4
  initial_angles_rad: [0.0, 1.5707963267948966, 3.141592653589793, 4.71238898038469]
  initial_centre_m: [0.0, 0.0]
  radius_m: 2.0
  control_law: stationary
"""


def known_batch(work, name, filter_r, seeds=SEEDS, base_seed=1):
    cfg = os.path.join(work, f"{name}.yaml")
    with open(cfg, "w") as f:
        f.write(KNOWN.format(steps=STEPS, filter_r=filter_r))
    out = os.path.join(work, f"batch-{name}-{base_seed}")
    rows = batch.run_batch([cfg], out, seeds=seeds, base_seed=base_seed, modes=("stationary",),
                           quiet=True)
    return rows[0], out


@pytest.fixture(scope="module")
def case_a(deif_sim, module_work_dir):
    """The filter knows the true noise."""
    return known_batch(module_work_dir, "consistent", 0.01)[0]


@pytest.fixture(scope="module")
def case_b(deif_sim, module_work_dir):
    """The filter overstates R by 4."""
    return known_batch(module_work_dir, "overstated", 0.04)[0]


def test_efficient_filter_reaches_the_pcrlb(case_a):
    assert case_a["seeds"] == SEEDS and case_a["steps"] == STEPS
    assert abs(case_a["rmse_over_pcrlb"] - 1.0) < RATIO_TOL, case_a
    assert abs(case_a["anees"] - 1.0) < ANEES_TOL, case_a


def test_pcrlb_equals_the_closed_form(case_a):
    # J(k) = 1 + k * N / (2 sigma^2) per axis (q negligible), the trace of the position bound
    # 2 / J(k); pcrlb_rmse = sqrt(mean_k 2 / J(k)).
    expected = math.sqrt(sum(2.0 / (1.0 + k * 4 / (2 * 0.01)) for k in range(1, STEPS + 1)) / STEPS)
    assert case_a["pcrlb_rmse_m"] == pytest.approx(expected, rel=1e-3)


def test_optimal_ring_stays_at_the_optimum(case_a):
    assert case_a["mean_optimality_ratio"] > 1.0 - 1e-9
    # Angles are measured about the estimate, ~0.005 m off the truth at 2 m: ~0.003 rad.
    assert case_a["final_max_gap_error_rad"] < 0.02
    assert case_a["final_alive_min"] == 4


def test_overstated_r_keeps_the_ratio_and_lowers_anees(case_a, case_b):
    # The bound is built from the TRUE range variance, so the ratio stays near 1 ...
    assert abs(case_b["rmse_over_pcrlb"] - 1.0) < RATIO_TOL, case_b
    # ... while a covariance 4x too large moves ANEES to 1/4, the right way.
    assert abs(case_b["anees"] - 0.25) < 0.25 * ANEES_TOL, case_b
    assert case_b["anees"] < case_a["anees"]


def test_rerun_is_byte_identical_and_seeds_matter(deif_sim, work_dir):
    def results(base_seed):
        _, out = known_batch(work_dir, "repeat", 0.01, seeds=20, base_seed=base_seed)
        with open(os.path.join(out, "results.json")) as f, open(os.path.join(out, "results.csv")) as g:
            return f.read(), g.read()

    first = results(7)
    assert results(7) == first
    other = json.loads(results(8)[0])["results"][0]
    assert other["rmse_m"] != json.loads(first[0])["results"][0]["rmse_m"]


def test_same_command_twice_gives_the_same_folder_contents(deif_sim, work_dir):
    thesis = os.path.join(ROOT, "configs", "thesis", "sim04.yaml")
    out = os.path.join(work_dir, "twice")
    contents = []
    for _ in range(2):
        batch.run_batch([thesis], out, seeds=3, steps=60, quiet=True)
        files = {}
        for name in ("results.csv", "results.json", "batch.json"):
            with open(os.path.join(out, name)) as f:
                files[name] = f.read()
        for mode in batch.MODES:
            for name in ("per_seed.csv", "timeseries.csv", "config.yaml"):
                with open(os.path.join(out, "sim04", mode, name)) as f:
                    files[f"{mode}/{name}"] = f.read()
        contents.append(files)
    assert contents[0] == contents[1]


def test_derived_seeds_are_distinct_and_below_2_63():
    seeds = [batch.derive_seed(7, i) for i in range(1000)]
    assert len(set(seeds)) == 1000
    assert all(0 <= s < 2 ** 63 for s in seeds)
    assert seeds == [batch.derive_seed(7, i) for i in range(1000)]


def test_one_seed_batch_reproduces_deif_sims_metrics(deif_sim, work_dir):
    """Every statistic is deif_sim's: a one-seed batch's row and timeseries are its
    summary.json and metrics.csv, reduced over one seed."""
    thesis = os.path.join(ROOT, "configs", "thesis", "sim04.yaml")
    out = os.path.join(work_dir, "crosscheck")
    rows = batch.run_batch([thesis], out, seeds=1, steps=150, quiet=True)
    assert [r["mode"] for r in rows] == list(batch.MODES)
    for row in rows:
        run = os.path.join(out, "sim04", row["mode"], "seed-000")
        with open(os.path.join(run, "summary.json")) as f:
            summ = json.load(f)["metrics"]
        for key in ("rmse_m", "max_error_m", "pcrlb_rmse_m", "anees", "mean_optimality_ratio",
                    "final_max_gap_error_rad"):
            assert row[key] == pytest.approx(summ[key], rel=1e-12, abs=1e-15), key
        assert row["final_alive_min"] == summ["final_agents"]
        assert row["steps"] == summ["last_step"] == 150
        assert row["control_law"] == ("stationary" if row["mode"] == "stationary" else "voronoi")
        metrics = artefacts.read_csv(os.path.join(run, "metrics.csv"))
        ts = batch.read_timeseries(out, "sim04", row["mode"])
        assert len(ts["step"]) == len(metrics) == 150
        for i in (0, 74, 149):
            m = metrics[i]
            assert ts["rms_error_m"][i] == pytest.approx(float(m["rms_error"]), rel=1e-5)
            assert ts["seed0_error_m"][i] == pytest.approx(float(m["rms_error"]), rel=1e-5)
            assert ts["max_error_m"][i] == pytest.approx(float(m["max_error"]), rel=1e-5)
            assert ts["pcrlb_m"][i] == pytest.approx(float(m["pcrlb"]), rel=1e-5)
            assert ts["anees"][i] == pytest.approx(float(m["mean_nees"]) / 2, rel=1e-5)
            assert ts["optimality_ratio"][i] == pytest.approx(float(m["optimality_ratio"]), rel=1e-5)
        settled = max(float(m["max_error"]) for m in metrics if float(m["t"]) >= batch.SETTLE_S - 1e-9)
        assert row["max_error_settled_m"] == settled


def test_stationary_mode_is_an_override_not_a_rewritten_file(deif_sim, work_dir):
    thesis = os.path.join(ROOT, "configs", "thesis", "sim05.yaml")
    out = os.path.join(work_dir, "modes")
    batch.run_batch([thesis], out, seeds=1, steps=20, quiet=True)
    with open(os.path.join(out, "batch.json")) as f:
        meta = json.load(f)
    assert meta["mode_overrides"]["stationary"] == ["agents.control_law=stationary"]
    assert meta["mode_overrides"]["moving"] == []
    with open(os.path.join(out, "sim05", "stationary", "config.yaml")) as f:
        text = f.read()
    assert "control_law: stationary" in text
    rows = artefacts.read_csv(os.path.join(out, "sim05", "stationary", "seed-000", "agent_1.csv"))
    assert rows[0]["pos_x"] == rows[-1]["pos_x"] and rows[0]["pos_y"] == rows[-1]["pos_y"]


def test_a_refused_config_is_reported(deif_sim, work_dir):
    bad = os.path.join(work_dir, "bad.yaml")
    with open(bad, "w") as f:
        f.write("agents: {count: 0}\n")
    with pytest.raises(batch.BatchError):
        batch.run_batch([bad], os.path.join(work_dir, "bad"), seeds=1, quiet=True)
    with pytest.raises(batch.BatchError):
        batch.expand_configs([os.path.join(work_dir, "no-such.yaml")])


def test_command_line_writes_results(deif_sim, work_dir):
    thesis = os.path.join(ROOT, "configs", "thesis", "sim04.yaml")
    out = os.path.join(work_dir, "cli")
    p = subprocess.run([paths.PYTHON, os.path.join(ROOT, "scripts", "deif-batch"), thesis, "--seeds", "2",
                        "--steps", "30", "--out", out],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 0, p.stdout
    assert os.path.exists(os.path.join(out, "results.csv"))
    assert "sim04" in p.stdout and "stationary" in p.stdout
    p = subprocess.run([paths.PYTHON, os.path.join(ROOT, "scripts", "deif-batch"), thesis, "--modes", "sideways"],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 2 and "sideways" in p.stdout
