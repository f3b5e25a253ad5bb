"""Where the project and its executables are."""
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PYTHON = "/usr/bin/python3"  # Debian's interpreter, with numpy and matplotlib


def build_dir():
    return os.environ.get("DEIF_BUILD_DIR", os.path.join(ROOT, "build"))


def executable(name):
    """build/bin/<name>; exits with a clear message when it has not been built."""
    path = os.path.join(build_dir(), "bin", name)
    if not os.path.exists(path):
        raise SystemExit(f"error: {path} not found; build first (scripts/build)")
    return path
