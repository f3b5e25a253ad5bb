"""Every thesis config (configs/thesis/sim01..sim20.yaml) holds the parameters of tables
5.2-5.18 as the C++ parser reads them (deif_config), and runs a short horizon
(deif_sim --steps 20) both moving and stationary. The configs of configs/beyond/ parse and
run too, far enough to reach every scripted fault."""
import math
import os
import subprocess

import pytest

from conftest import ROOT
from deif import artefacts, batch, config

NON_OPTIMAL = [2.1818, 2.4500, 3.7160, 4.5167]  # tables 5.2-5.5, 5.10
OPTIMAL = [0.0, math.pi / 2, math.pi, 3 * math.pi / 2]  # tables 5.6-5.9, 5.11-5.18
VARIANCES = [5.3e-5, 5.3e-4, 5.3e-2, 0.53]
SIMS = list(range(1, 21))
BEYOND = sorted(n for n in os.listdir(os.path.join(ROOT, "configs", "beyond")) if n.endswith(".yaml"))


def thesis_path(n):
    return os.path.join(ROOT, "configs", "thesis", f"sim{n:02d}.yaml")


def expected(n):
    """(angles, true variance, trajectory) of simulation n per the thesis's tables."""
    if n <= 12:
        traj = "figure_eight_shifted" if n >= 9 else "figure_eight"  # eq (5.7) for 9-12
        return (NON_OPTIMAL if n <= 4 else OPTIMAL), VARIANCES[(n - 1) % 4], traj
    return OPTIMAL, (5.3e-5 if n <= 16 else 0.53), "figure_eight"  # tables 5.17, 5.18


def run_short(deif_sim, cfg_path, out, steps=20, overrides=()):
    argv = [deif_sim, "--config", cfg_path, "--out", out, "--steps", str(steps), "--quiet"]
    for o in overrides:
        argv += ["--set", o]
    return subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.parametrize("n", SIMS)
def test_thesis_config_holds_the_tables_parameters(deif_sim, n):
    assert os.path.exists(thesis_path(n))
    cfg = config.resolve(thesis_path(n))
    angles, true_var, traj = expected(n)
    ag, tg, fl = cfg["agents"], cfg["target"], cfg["filter"]
    assert ag["count"] == 4
    assert ag["initial_angles_rad"] == pytest.approx(angles, abs=1e-4)
    assert float(tg["range_noise_variance_m2"]) == pytest.approx(true_var, rel=1e-12)
    assert tg["trajectory"] == traj
    assert float(fl["process_noise"]) == pytest.approx(1.3e-4, rel=1e-12)
    assert fl["motion_model"] == "random_walk"
    assert fl["initial_estimate_m"] == [0.0, 0.0]
    assert ag["control_law"] == "voronoi"  # the file is the moving run
    if n <= 12:
        assert float(fl["range_variance_m2"]) == pytest.approx(true_var, rel=1e-12)


@pytest.mark.parametrize("first", [13, 17])
def test_sims_13_to_20_vary_the_filter_r_around_the_truth(deif_sim, first):
    true_var = expected(first)[1]
    rs = [float(config.resolve(thesis_path(n))["filter"]["range_variance_m2"]) for n in range(first, first + 4)]
    assert len(set(rs)) == 4
    assert any(r < true_var for r in rs)
    assert any(r == pytest.approx(true_var, rel=1e-12) for r in rs)


@pytest.mark.parametrize("n", SIMS)
@pytest.mark.parametrize("mode", batch.MODES)
def test_thesis_config_runs_a_short_horizon(deif_sim, work_dir, n, mode):
    out = os.path.join(work_dir, f"sim{n:02d}-{mode}")
    p = run_short(deif_sim, thesis_path(n), out, overrides=batch.mode_overrides(mode))
    assert p.returncode == 0, p.stdout
    rows = artefacts.read_csv(os.path.join(out, "agent_1.csv"))
    assert len(rows) == 20
    if mode == "stationary":
        assert rows[0]["pos_x"] == rows[-1]["pos_x"] and rows[0]["pos_y"] == rows[-1]["pos_y"]
    else:
        assert rows[0]["pos_x"] != rows[-1]["pos_x"] or rows[0]["pos_y"] != rows[-1]["pos_y"]


@pytest.mark.parametrize("name", BEYOND)
def test_beyond_config_runs_past_its_faults(deif_sim, work_dir, name):
    path = os.path.join(ROOT, "configs", "beyond", name)
    faults = config.resolve(path).get("faults") or []
    steps = max([20] + [int(f["step"]) + 5 for f in faults])  # reach every scripted fault
    out = os.path.join(work_dir, "beyond-" + batch.scenario_name(path))
    p = run_short(deif_sim, path, out, steps)
    assert p.returncode == 0, p.stdout
    assert len(artefacts.read_csv(os.path.join(out, "metrics.csv"))) == steps
