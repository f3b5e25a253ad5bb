"""Plot smoke test: a tiny batch of every thesis and beyond scenario (2 seeds, 40 and 320 steps),
then every figure the thesis layout draws from it, and docs/RESULTS.md's text written to a
scratch file. Each figure must exist and be a non-empty PNG (checked by its 8-byte
signature). The figures and the report read the batch folders only: with DEIF_SIM_EXE and
DEIF_BUILD_DIR pointing nowhere they must still work."""
import os

import pytest

from conftest import ROOT
from deif import batch, thesis, thesis_report


@pytest.fixture(scope="module")
def batches(deif_sim, module_work_dir):
    thesis_dir = os.path.join(module_work_dir, "batch-thesis")
    beyond_dir = os.path.join(module_work_dir, "batch-beyond")
    batch.run_batch(batch.expand_configs([os.path.join(ROOT, "configs", "thesis")]), thesis_dir,
                    seeds=2, steps=40, quiet=True)
    # Past step 315, where kill_sim07 kills agent 2.
    batch.run_batch(batch.expand_configs([os.path.join(ROOT, "configs", "beyond")]), beyond_dir,
                    seeds=2, steps=320, quiet=True)
    return thesis_dir, beyond_dir


@pytest.fixture
def nothing_runs(monkeypatch, work_dir):
    """Drawing never runs an executable: point every executable path nowhere."""
    monkeypatch.setenv("DEIF_SIM_EXE", os.path.join(work_dir, "no-such-executable"))
    monkeypatch.setenv("DEIF_BUILD_DIR", os.path.join(work_dir, "no-such-build"))


def test_every_thesis_figure_is_a_png(batches, nothing_runs, work_dir):
    thesis_dir, beyond_dir = batches
    figs = os.path.join(work_dir, "figures")
    written = thesis.thesis_figures(thesis_dir, figs)
    written["bar"] = thesis.results_bar_figure(thesis_dir, os.path.join(figs, "bar.png"), "smoke")
    written["kill"] = thesis.scenario_figure(beyond_dir, "kill_sim07", os.path.join(figs, "kill.png"))
    expected = [f"5.{n}" for n in range(2, 17)] + ["bar", "kill"]  # 5.2-5.9, 5.10, 5.11-5.14, 5.15, 5.16
    assert sorted(written) == sorted(expected)
    for num, path in written.items():
        assert thesis.is_png(path), num
        assert os.path.getsize(path) > 1000, num


def test_results_md_is_written_from_the_batches(batches, nothing_runs, work_dir):
    thesis_dir, beyond_dir = batches
    doc_figs = thesis.draw(thesis_dir, beyond_dir, os.path.join(work_dir, "doc-figures"))
    assert set(doc_figs) >= {"5.5", "5.14", "5.10", "5.15", "5.16", "overview", "beyond", "kill_sim07",
                             "range_sim10"}
    assert all(thesis.is_png(p) for p in doc_figs.values())
    report = thesis_report.write_results_md(os.path.join(work_dir, "RESULTS.md"), thesis_dir, beyond_dir,
                                            doc_figs)
    with open(report) as f:
        text = f.read()
    assert "## The 20 simulations" in text and "## Beyond the thesis" in text
    assert "| 20 | stationary |" in text  # the Monte Carlo table has every simulation and mode
    assert "{" not in text.replace("{x}", "").replace("\\hat{", "")  # every field was filled in
    assert "scripts/deif/thesis_report.py" in text


def test_png_check_rejects_a_non_png(work_dir):
    bogus = os.path.join(work_dir, "not-a-png.png")
    with open(bogus, "wb") as f:
        f.write(b"GIF89a....")
    assert not thesis.is_png(bogus)
    assert not thesis.is_png(os.path.join(work_dir, "missing.png"))
