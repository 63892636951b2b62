"""`estimation.png`: the state estimate against the simulator's truth (base position, velocity, attitude)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from wbmpc.viz.plots import DPI


def save_estimation_plot(log, out_dir: Path) -> Path:
    """Plot an `EstimationLog` (estimate solid, truth dashed) to out_dir/estimation.png."""
    from wbmpc.estimation.metrics import orientation_errors_rad

    a = log.arrays()
    t = a["t"] - a["t"][0]
    fig = Figure(figsize=(11, 9), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    colors = ("tab:red", "tab:green", "tab:blue")
    for k, axis in enumerate("xyz"):
        axes[0].plot(t, a["q_est"][:, k] - (a["q_true"][0, k] if k < 2 else 0), color=colors[k], label=f"{axis} estimate")
        axes[0].plot(t, a["q_true"][:, k] - (a["q_true"][0, k] if k < 2 else 0), color=colors[k], linestyle="--",
                     label=f"{axis} truth")
        axes[1].plot(t, a["v_est"][:, k], color=colors[k], linewidth=0.8, label=f"v{axis} estimate")
        axes[1].plot(t, a["v_true"][:, k], color=colors[k], linestyle="--", linewidth=1.2, label=f"v{axis} truth")
    err = np.rad2deg(orientation_errors_rad(a["q_est"], a["q_true"]))
    for k, name in enumerate(("roll", "pitch", "yaw")):
        axes[2].plot(t, err[:, k], color=colors[k], label=f"{name} error")
    axes[0].set_ylabel("base position (m)\n(x, y from the start)")
    axes[1].set_ylabel("base velocity (m/s)\nbase frame")
    axes[2].set_ylabel("orientation error (deg)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", ncol=3, fontsize=7)
    fig.suptitle("state estimate (solid) vs simulator truth (dashed)")
    path = Path(out_dir) / "estimation.png"
    fig.savefig(path)
    return path
