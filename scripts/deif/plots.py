"""Figures of one run folder (scripts/deif-plot) and the helpers every figure shares.

Every statistic comes from the run's metrics.csv and summary.json (computed by the C++);
the paths and positions come straight from the artefacts (target.csv, agent_<id>.csv).
Nothing is re-run: a run folder without metrics.csv is evaluated once with
`deif_sim --evaluate`, which only reads the artefacts.

  run.png       left: the RMS and the largest error over the agents at every step, the
                1-sigma claim sqrt(trace P) of the lowest-id agent and the PCRLB; right: the
                true trajectory, one agent's estimate, the sensors' paths and final positions
                (an agent that stopped writing before the end, e.g. killed, is an x).
  geometry.png  top: the largest gap error of the ring; bottom: how many agents wrote each
                step and how many the lowest-id agent believes alive.
The step of every scripted fault is marked.
"""
import glob
import io
import json
import math
import os
import re
import subprocess
import tempfile

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from . import artefacts, config, paths  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class PlotError(Exception):
    pass


def save_png(fig, out_png, dpi, palette=False):
    """Save a figure; with palette=True as a 64-colour palette PNG (a third of the size of an
    RGBA one; the plots use a handful of colours), falling back to matplotlib's own PNG when
    Pillow is missing."""
    os.makedirs(os.path.dirname(os.path.abspath(out_png)), exist_ok=True)
    if not palette:
        fig.savefig(out_png, dpi=dpi)
        plt.close(fig)
        return out_png
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    plt.close(fig)
    try:
        from PIL import Image
        buf.seek(0)
        Image.open(buf).convert("RGB").quantize(colors=64).save(out_png, optimize=True)
    except ImportError:
        with open(out_png, "wb") as f:
            f.write(buf.getvalue())
    return out_png


def is_png(path):
    try:
        with open(path, "rb") as f:
            return os.path.getsize(path) > len(PNG_SIGNATURE) and f.read(8) == PNG_SIGNATURE
    except OSError:
        return False


def load_columns(path):
    """A CSV as {column: [floats]} ({} if missing or empty)."""
    rows = artefacts.read_csv(path)
    if not rows:
        return {}
    return {k: [float(r[k]) for r in rows] for k in rows[0]}


def load_agents(run_dir):
    """{agent id: columns of agent_<id>.csv} for every agent that wrote a row."""
    agents = {}
    for p in glob.glob(os.path.join(run_dir, "agent_*.csv")):
        m = re.search(r"agent_(\d+)\.csv$", p)
        a = load_columns(p)
        if m and a:
            agents[int(m.group(1))] = a
    return dict(sorted(agents.items()))


# ---------------------------------------------------------------------------------------
# A run folder

def _config_of_run(run_dir, summary):
    """The effective config of a run as a dict (None if it cannot be read): config.yaml of a
    multi-process run, or the YAML deif_sim stored in summary.json."""
    have_parser = os.path.exists(os.path.join(paths.build_dir(), "bin", "deif_config"))
    if not have_parser:
        return None
    path = os.path.join(run_dir, "config.yaml")
    try:
        if os.path.exists(path):
            return config.resolve(path)
        text = (summary.get("config") or {}).get("yaml")
        if not text:
            return None
        with tempfile.NamedTemporaryFile("w", suffix=".yaml") as f:
            f.write(text)
            f.flush()
            return config.resolve(f.name)
    except config.ConfigRefused:
        return None


def _ensure_metrics(run_dir):
    """metrics.csv of the run; evaluated by deif_sim when missing (reads artefacts only)."""
    path = os.path.join(run_dir, "metrics.csv")
    if os.path.exists(path):
        return path
    cfg = os.path.join(run_dir, "config.yaml")
    if not os.path.exists(cfg):
        raise PlotError(f"{run_dir}: neither metrics.csv nor config.yaml (to evaluate the run)")
    proc = subprocess.run([paths.executable("deif_sim"), "--config", cfg, "--evaluate", run_dir],
                          capture_output=True, text=True)
    if proc.returncode != 0 or not os.path.exists(path):
        raise PlotError(f"deif_sim --evaluate {run_dir}: {proc.stderr.strip()}")
    return path


def _faults(summary, cfg):
    """[(step, label)] of the scripted faults: as applied (a multi-process run's summary),
    else as configured."""
    out = []
    for f in summary.get("faults") or (cfg or {}).get("faults") or []:
        step = f.get("applied_at_step") or f["step"]
        agent = f.get("agent")
        label = f["action"].replace("_", " ") + (f" {agent}" if agent not in (None, -1) else "")
        out.append((int(step), label))
    return out


def _mark_faults(ax, faults, dt):
    for step, label in faults:
        ax.axvline(step * dt, color="k", ls=":", lw=1)
        ax.text(step * dt, ax.get_ylim()[1], " " + label, va="top", fontsize=8, rotation=90)


def run_figures(run_dir, out_dir=None, dpi=110):
    """Draw run.png and geometry.png of a run folder; returns their paths."""
    out_dir = out_dir or os.path.join(run_dir, "plots")
    truth = load_columns(os.path.join(run_dir, "target.csv"))
    if not truth:
        raise PlotError(f"{run_dir}/target.csv is missing or empty")
    agents = load_agents(run_dir)
    if not agents:
        raise PlotError(f"no agent_<id>.csv rows in {run_dir}")
    metrics = load_columns(_ensure_metrics(run_dir))
    if not metrics:
        raise PlotError(f"{run_dir}/metrics.csv is empty")
    summary = {}
    try:
        with open(os.path.join(run_dir, "summary.json")) as f:
            summary = json.load(f)
    except (OSError, ValueError):
        pass
    faults = _faults(summary, _config_of_run(run_dir, summary) if not summary.get("faults") else None)
    dt = metrics["t"][0] / metrics["step"][0] if metrics["step"][0] else 1.0
    written = [m > 0 for m in metrics["rows"]]
    t_rows = [t for t, w in zip(metrics["t"], written) if w]
    first_id = min(agents)
    first = agents[first_id]

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.2))
    ax1.plot(t_rows, [e for e, w in zip(metrics["rms_error"], written) if w], "C0-", lw=1.2,
             label="RMS over the agents")
    ax1.plot(t_rows, [e for e, w in zip(metrics["max_error"], written) if w], "C3-", lw=0.6,
             alpha=0.8, label="largest over the agents")
    # The filter's own 1-sigma claim: a consistent filter's error hovers around it.
    ax1.plot(first["t"], [math.sqrt(max(0.0, a + b)) for a, b in zip(first["p_xx"], first["p_yy"])],
             "k--", lw=0.8, label=f"sqrt(trace P), agent {first_id}")
    ax1.plot(metrics["t"], metrics["pcrlb"], color="0.5", ls=":", lw=1.0, label="PCRLB")
    ax1.set_xlabel("t [s]")
    ax1.set_ylabel("||x - x_hat|| [m]")
    ax1.set_title("estimation error (metrics.csv)")
    ax1.set_ylim(bottom=0)
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    _mark_faults(ax1, faults, dt)

    ax2.plot(truth["x_true"], truth["y_true"], color="0.6", lw=1, label="true trajectory")
    ax2.plot(first["x_est"], first["y_est"], "b-", lw=0.8, alpha=0.8, label=f"estimate (agent {first_id})")
    last_step = max(int(a["step"][-1]) for a in agents.values())
    for n, (j, a) in enumerate(agents.items()):
        colour = f"C{n % 10}"
        gone = int(a["step"][-1]) < last_step  # killed or stopped before the end: an x
        ax2.plot(a["pos_x"], a["pos_y"], lw=0.5, alpha=0.4, color=colour)
        ax2.plot(a["pos_x"][-1], a["pos_y"][-1], "x" if gone else "o", ms=10, mew=2.5, color=colour)
        label = f"{j} (last step {int(a['step'][-1])})" if gone else str(j)
        ax2.annotate(label, (a["pos_x"][-1], a["pos_y"][-1]), xytext=(6, 6), textcoords="offset points")
    ax2.plot(truth["x_true"][-1], truth["y_true"][-1], "k*", ms=12, label="target (end)")
    ax2.set_aspect("equal")
    ax2.set_title("final positions (x: stopped early), path and estimate")
    ax2.legend(fontsize=8, loc="best")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    run_png = save_png(fig, os.path.join(out_dir, "run.png"), dpi)

    fig, (g1, g2) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    g1.plot(t_rows, [math.degrees(g) for g, w in zip(metrics["gap_error"], written) if w])
    g1.set_ylabel("largest gap error [deg]")
    g1.set_yscale("symlog", linthresh=1.0)
    g1.axhline(1.0, color="r", ls="--", lw=0.8)
    g1.grid(alpha=0.3)
    g1.set_title("ring spacing (optimum: 2 pi/N, pi/2 for two agents)")
    g2.step(metrics["t"], metrics["rows"], where="post", label="agents that wrote the step")
    if "alive" in first:
        g2.step(first["t"], first["alive"], where="post", ls="--", label=f"alive as seen by agent {first_id}")
    g2.set_ylabel("agents")
    g2.set_xlabel("t [s]")
    g2.grid(alpha=0.3)
    g2.legend(fontsize=8)
    _mark_faults(g1, faults, dt)
    fig.tight_layout()
    geometry_png = save_png(fig, os.path.join(out_dir, "geometry.png"), dpi)
    return run_png, geometry_png
