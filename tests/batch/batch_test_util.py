"""Helpers shared by the batch tests (tests/batch/*_test.py), run by ctest with label unit.

Environment: DEIF_SIM_EXE (set by tests/batch/CMakeLists.txt) is the deif_sim to use;
BATCH_TEST_WORK is a scratch folder (default: a fresh temporary folder).
"""
import os
import shutil
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "scripts", "lib"))

FAILURES = []


def check(cond, msg):
    """Record the outcome of one assertion and print it."""
    print(("  ok: " if cond else "  FAIL: ") + msg, flush=True)
    if not cond:
        FAILURES.append(msg)


def work_dir(name):
    base = os.environ.get("BATCH_TEST_WORK") or tempfile.mkdtemp(prefix="deif-batch-test-")
    path = os.path.join(base, name)
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path


def sim_exe():
    exe = os.environ.get("DEIF_SIM_EXE")
    if not exe:
        exe = os.path.join(os.environ.get("DEIF_BUILD_DIR", os.path.join(ROOT, "build")), "bin", "deif_sim")
        os.environ["DEIF_SIM_EXE"] = exe
    if not os.path.exists(exe):
        print(f"deif_sim not found at {exe}; build the deif_sim target", file=sys.stderr)
        sys.exit(2)
    return exe


def finish():
    if FAILURES:
        print(f"{len(FAILURES)} check(s) failed:")
        for f in FAILURES:
            print(f"  - {f}")
        return 1
    print("all checks passed")
    return 0
