"""scripts/deif-plot and deif.plots: the figures of one run folder, from its artefacts and
metrics.csv. A run with a scripted kill gets both PNGs; a folder without metrics.csv is
evaluated by deif_sim first; a folder without artefacts is refused with exit 2."""
import json
import os
import shutil
import subprocess

import pytest

from conftest import ROOT
from deif import artefacts, paths, plots


@pytest.fixture(scope="module")
def kill_run(deif_sim, module_work_dir):
    out = os.path.join(module_work_dir, "kill")
    subprocess.run([deif_sim, "--config", os.path.join(ROOT, "configs", "beyond", "kill_sim07.yaml"),
                    "--out", out, "--steps", "330", "--quiet"], check=True)
    return out


def test_plot_command_draws_both_figures(kill_run):
    p = subprocess.run([paths.PYTHON, os.path.join(ROOT, "scripts", "deif-plot"), kill_run],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 0, p.stdout
    for name in ("run.png", "geometry.png"):
        path = os.path.join(kill_run, "plots", name)
        assert plots.is_png(path) and os.path.getsize(path) > 10000, name


def test_faults_come_from_the_config_deif_sim_stored(kill_run):
    with open(os.path.join(kill_run, "summary.json")) as f:
        summary = json.load(f)
    assert plots._faults(summary, plots._config_of_run(kill_run, summary)) == [(315, "kill 2")]
    # A multi-process run's summary names the step each fault was applied at.
    applied = {"faults": [{"step": 315, "action": "kill", "agent": 2, "applied_at_step": 316}]}
    assert plots._faults(applied, None) == [(316, "kill 2")]


def test_folder_without_metrics_is_evaluated_first(kill_run, work_dir, deif_sim):
    run = os.path.join(work_dir, "copy")
    shutil.copytree(kill_run, run, ignore=shutil.ignore_patterns("metrics.csv", "plots"))
    with open(os.path.join(run, "config.yaml"), "w") as f:
        subprocess.run([os.path.join(paths.build_dir(), "bin", "deif_config"), "--config",
                        os.path.join(ROOT, "configs", "beyond", "kill_sim07.yaml"), "--set", "scenario.steps=330",
                        "--print", "yaml"], stdout=f, check=True)
    written = plots.run_figures(run, os.path.join(work_dir, "figures"))
    assert all(plots.is_png(p) for p in written)
    assert artefacts.read_csv(os.path.join(run, "metrics.csv")) == \
        artefacts.read_csv(os.path.join(kill_run, "metrics.csv"))


def test_empty_folder_is_refused(work_dir):
    p = subprocess.run([paths.PYTHON, os.path.join(ROOT, "scripts", "deif-plot"), work_dir],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 2 and "target.csv is missing" in p.stdout
