#!/usr/bin/python3
"""Plot smoke test: a tiny batch (two thesis scenarios, 2 seeds, 40 steps), then every
figure the thesis layout can draw from it. Each file must exist and be a non-empty PNG
(checked by its 8-byte signature). The plot code reads artefacts only: deleting the
deif_sim executable's access (DEIF_SIM_EXE pointing nowhere) must not matter."""
import os
import sys

from batch_test_util import ROOT, check, finish, sim_exe, work_dir

import batch  # noqa: E402
import thesis_figures  # noqa: E402


def main():
    sim_exe()
    work = work_dir("figures")
    out = os.path.join(work, "batch")
    configs = [os.path.join(ROOT, "configs", "thesis", f"sim{n:02d}.yaml") for n in (1, 2, 5, 6, 9, 13, 17)]
    batch.run_batch(configs, out, seeds=2, steps=40, quiet=True)

    os.environ["DEIF_SIM_EXE"] = os.path.join(work, "no-such-executable")  # plots never run anything
    figs = os.path.join(work, "figures")
    written = thesis_figures.thesis_figures(out, figs)
    written["bar"] = thesis_figures.results_bar_figure(out, os.path.join(figs, "bar.png"), "smoke")
    for num in ("5.2", "5.3", "5.6", "5.7", "5.11", "5.10", "5.15", "5.16", "bar"):
        check(num in written, f"figure {num} written")
    for num, path in sorted(written.items()):
        check(thesis_figures.is_png(path) and os.path.getsize(path) > 1000,
              f"figure {num}: {os.path.basename(path)} is a PNG of {os.path.getsize(path) if os.path.exists(path) else 0} bytes")
    bogus = os.path.join(work, "not-a-png.png")
    with open(bogus, "wb") as f:
        f.write(b"GIF89a....")
    check(not thesis_figures.is_png(bogus), "the PNG check rejects a non-PNG file")
    return finish()


if __name__ == "__main__":
    sys.exit(main())
