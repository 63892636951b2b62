"""Diagnostic plots of a closed-loop run (`wbmpc.control.loop.RunLog`), written as PNG files.

`save_plots(robot, log, out_dir)` writes what a legged-robotics engineer checks first:

- `base_velocity.png`  base velocity in the heading frame (and yaw rate) against the commands
- `ee_position.png`    arm end-effector position (pinocchio FK) against an optional reference
- `joint_torques.png`  applied torques per leg and for the arm with their limits; the joints that
                       came closest to their limits (largest |tau| / tau_max) in a highlighted panel
- `foot_heights.png`   foot clearance (pinocchio FK) with the planned stance phases shaded
- `contact_forces.png` measured normal contact forces with the planned stance phases shaded
- `solver.png`         solve time and iterations per MPC step against the MPC period (the run's rate)
- `ee_force.png`       (manipulation scenarios) measured end-effector force against its target

Every time plot marks the run's events (`RunMarks`): scripted events such as a push (dash-dot
purple line), the fall (black line), MPC steps that needed the recovery re-solve (orange
triangles at the top) and failed steps (red crosses at the top).

Figures are drawn on the Agg canvas directly (no pyplot state, no display needed); each
`plot_*` writes the figure its `*_figure` twin builds.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from wbmpc.control.loop import MPC_RATE_HZ
from wbmpc.errors import ConfigError

DPI = 110
PLOT_FULL_RATE_TICKS = 30_000  # up to 60 s at 500 Hz the plots get every control tick
MAX_ITERATION_BARS = 4000  # up to 50 s at 80 Hz the solver plot draws a bar per MPC step (a line beyond)
COMMAND_STYLE = dict(color="black", linestyle="--", linewidth=1.4)
STANCE_COLOR = "#9ecae1"
HIGHLIGHT_COLOR = "#c0392b"
EVENT_COLOR = "#8e44ad"
FALL_COLOR = "#000000"
RECOVERY_COLOR = "#e67e22"
RECOVERY_MARK = "(recovery after"  # in the status of a step solved by MPC._recover
HIGHLIGHT_MIN_JOINTS, HIGHLIGHT_MAX_JOINTS, HIGHLIGHT_RATIO = 2, 4, 0.9


@dataclass(frozen=True)
class RunMarks:
    """Events of a run drawn on every time plot (times in the log's clock, s)."""

    events: tuple[tuple[float, str], ...] = ()  # scripted events applied to the plant (a push)
    fell_at_s: float | None = None
    recovered_s: np.ndarray = field(default_factory=lambda: np.zeros(0))  # steps solved by the recovery path
    failed_s: np.ndarray = field(default_factory=lambda: np.zeros(0))  # failed steps (never applied)

    @classmethod
    def from_log(cls, log) -> "RunMarks":
        mpc_t = np.asarray(getattr(log, "mpc_t", []), dtype=float)
        success = np.asarray(getattr(log, "success", []), dtype=bool)
        status = list(getattr(log, "status", []) or [])
        recovered = np.array([RECOVERY_MARK in str(s) for s in status], dtype=bool)
        if hasattr(log, "first_tick"):
            t0 = float(log.first_tick("t")) if log.n_ticks else 0.0
        else:
            t = getattr(log, "t", [])
            t0 = float(t[0]) if len(t) else 0.0
        fell = getattr(log, "fell_at_s", None)
        return cls(
            events=tuple((float(te), str(name)) for te, name in getattr(log, "events", []) or []),
            fell_at_s=None if fell is None else t0 + float(fell),
            recovered_s=mpc_t[recovered & success] if recovered.size == mpc_t.size == success.size else np.zeros(0),
            failed_s=mpc_t[~success] if success.size == mpc_t.size else np.zeros(0),
        )

    def draw(self, ax, labels: bool = True) -> None:
        """Vertical lines for the events and the fall, markers along the top for recovered and failed steps."""
        seen = set()

        def label(name):
            if not labels or name in seen:
                return None
            seen.add(name)
            return name

        for time_s, name in self.events:
            ax.axvline(time_s, color=EVENT_COLOR, linestyle="-.", linewidth=1.8, label=label(name))
        if self.fell_at_s is not None:
            ax.axvline(self.fell_at_s, color=FALL_COLOR, linewidth=2.4, label=label("fell"))
        top = ax.get_xaxis_transform()
        if self.recovered_s.size:
            ax.plot(self.recovered_s, np.full(self.recovered_s.size, 0.96), "v", color=RECOVERY_COLOR, markersize=6,
                    transform=top, linestyle="none", label=label(f"recovery re-solve ({self.recovered_s.size})"))
        if self.failed_s.size:
            ax.plot(self.failed_s, np.full(self.failed_s.size, 0.96), "X", color=HIGHLIGHT_COLOR, markersize=7,
                    transform=top, linestyle="none", label=label(f"failed step ({self.failed_s.size})"))


# ----------------------------------------------------------------------------- kinematics helpers
def frame_positions(robot, q: np.ndarray, frames: Sequence[str]) -> dict[str, np.ndarray]:
    """World positions (n, 3) of named frames for every configuration row of `q` (pinocchio FK)."""
    return robot.frame_trajectories(q, frames)


def _rotations(q: np.ndarray) -> np.ndarray:
    """Base rotation matrices (n, 3, 3) from the quaternions (x, y, z, w) in q[:, 3:7]."""
    x, y, z, w = (q[:, 3 + i] for i in range(4))
    norm = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def base_velocity_heading(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Base linear velocity in the heading (yaw-only) frame (n, 3) and world yaw rate (n,).

    `v[:, :6]` is pinocchio's free-flyer velocity: linear and angular velocity in the base frame.
    """
    rot = _rotations(q)
    v_world = np.einsum("nij,nj->ni", rot, v[:, :3])
    omega_world = np.einsum("nij,nj->ni", rot, v[:, 3:6])
    yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    v_heading = np.stack([c * v_world[:, 0] + s * v_world[:, 1], -s * v_world[:, 0] + c * v_world[:, 1], v_world[:, 2]], axis=-1)
    return v_heading, omega_world[:, 2]


def leg_joint_groups(robot) -> list[tuple[str, list[int]]]:
    """(foot name, joint indices from the root to that foot) for every foot."""
    groups = []
    for foot in robot.feet:
        joint = robot.model.frames[robot.frame_id(foot)].parentJoint
        chain = []
        while joint > 1:
            chain.append(robot.joint_index(robot.model.names[joint]))
            joint = robot.model.parents[joint]
        groups.append((foot, sorted(chain)))
    return groups


def _short_names(names: Sequence[str]) -> list[str]:
    """Joint labels without their common prefix ('FL_') and the '_joint' suffix."""
    prefix = os.path.commonprefix(list(names)) if len(names) > 1 else ""
    if prefix and not prefix.endswith(("_", "-", ".")):
        prefix = prefix[: max(prefix.rfind("_"), prefix.rfind("-"), prefix.rfind(".")) + 1]
    out = []
    for name in names:
        label = name[len(prefix):]
        for suffix in ("_joint", "_JOINT", "Joint"):
            if label.endswith(suffix) and len(label) > len(suffix):
                label = label[: -len(suffix)]
        out.append(label or name)
    return out


# ----------------------------------------------------------------------------- figure helpers
def _figure(width: float, height: float) -> Figure:
    """A figure on the Agg canvas with a tight (constrained) layout that also fits outside legends."""
    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path


def _figure_legend(fig: Figure, ax) -> None:
    """One legend for stacked panels, below them (so it never hides data)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=len(handles), fontsize=8, frameon=False)


def _stance_intervals(mpc_t: np.ndarray, stance: np.ndarray, t_end: float) -> list[tuple[float, float]]:
    """Time intervals where a planned-contact column is 1 (each MPC step holds until the next)."""
    intervals = []
    start = None
    edges = np.append(mpc_t, max(t_end, mpc_t[-1]) if mpc_t.size else t_end)
    for k, on in enumerate(stance > 0.5):
        if on and start is None:
            start = edges[k]
        if not on and start is not None:
            intervals.append((start, edges[k]))
            start = None
    if start is not None:
        intervals.append((start, edges[-1]))
    return intervals


def _shade_stance(ax, intervals: Iterable[tuple[float, float]], label: str | None = "planned stance") -> None:
    for k, (a, b) in enumerate(intervals):
        ax.axvspan(a, b, color=STANCE_COLOR, alpha=0.35, linewidth=0, label=label if k == 0 else None)


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2))) if a.size else float("nan")


def _command_series(log, n_mpc: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Commanded heading-frame base velocity (m, 3) and yaw rate (m,) per MPC step, if logged."""
    if hasattr(log, "command_array"):  # a RunLog: the numbers as stored, no `Commands` built per step
        rows = log.command_array()
        return (rows[:, 0:3], rows[:, 3]) if n_mpc and len(rows) == n_mpc else None
    commands = list(getattr(log, "commands", []) or [])[:n_mpc]
    if not commands or len(commands) != n_mpc:
        return None
    lin = np.array([np.asarray(c.base_velocity_m_s, dtype=float).ravel()[:3] for c in commands])
    yaw = np.array([float(getattr(c, "base_yaw_rate_rad_s", 0.0)) for c in commands])
    return lin, yaw


def _hold(mpc_t: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Zero-order hold of per-MPC-step values at the control ticks `t`."""
    idx = np.clip(np.searchsorted(mpc_t, t + 1e-9, side="right") - 1, 0, len(mpc_t) - 1)
    return values[idx]


# ----------------------------------------------------------------------------- the plots
# ----------------------------------------------------------------------------- the plots
def base_velocity_figure(robot, data: dict, log, marks: RunMarks | None = None) -> Figure:
    t, q, v = data["t"], data["q"], data["v"]
    v_heading, yaw_rate = base_velocity_heading(q, v)
    mpc_t = data["mpc_t"]
    commanded = _command_series(log, mpc_t.size) if mpc_t.size else None
    fig = _figure(11, 6.5)
    axes = fig.subplots(2, 2, sharex=True).ravel()
    series = [(v_heading[:, i], f"$v_{axis}$", "m/s") for i, axis in enumerate("xyz")] + [(yaw_rate, r"$\omega_z$", "rad/s")]
    titles = ["forward (heading x)", "lateral (heading y)", "vertical (z)", "yaw rate"]
    for i, (ax, (meas, sym, unit), title) in enumerate(zip(axes, series, titles)):
        ax.plot(t, meas, color=f"C{i}", linewidth=1.0, label=f"measured {sym}")
        text = ""
        if commanded is not None:
            cmd = commanded[0][:, i] if i < 3 else commanded[1]
            ax.step(np.append(mpc_t, t[-1]), np.append(cmd, cmd[-1]), where="post", label=f"commanded {sym}", **COMMAND_STYLE)
            text = f"RMSE {_rmse(meas, _hold(mpc_t, cmd, t)):.3f} {unit}"
        (marks or RunMarks()).draw(ax)
        ax.set_title(f"{title}" + (f"  ({text})" if text else ""), fontsize=10)
        ax.set_ylabel(f"{sym} [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    for ax in axes[2:]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"{robot.name}: base velocity in the heading frame vs command", fontsize=12)
    return fig


def plot_base_velocity(robot, data: dict, log, path: Path, marks: RunMarks | None = None) -> Path:
    return save_figure(base_velocity_figure(robot, data, log, marks), path)


EeError = Callable[[np.ndarray, np.ndarray], "tuple[np.ndarray, np.ndarray] | None"]


def ee_position_figure(robot, data: dict, ee_reference: Callable | None, marks: RunMarks | None = None,
                       ee_error: EeError | None = None, error_label: str = "|p - p_ref|") -> Figure:
    """`ee_error(t, ee) -> (error (n, 3), mask)` is the tracking error as the run's metric defines it
    (e.g. in the board's plane, from the pattern's start): the error panel and its RMSE show exactly
    that; without it the 3D distance to `ee_reference` over the whole run."""
    t, q = data["t"], data["q"]
    ee = frame_positions(robot, q, [robot.arm_ee])[robot.arm_ee]
    ref = None
    if ee_reference is not None:
        ref = np.array([np.asarray(ee_reference(float(tk)), dtype=float).ravel()[:3] for tk in t])
    tracked = ee_error(t, ee) if ee_error is not None else None
    if tracked is None and ref is not None:
        tracked = ee - ref, np.ones(t.size, dtype=bool)
    rows = 4 if tracked is not None else 3
    fig = _figure(10, 2.0 * rows + 1.0)
    axes = fig.subplots(rows, 1, sharex=True)
    marks = marks or RunMarks()
    for i, axis in enumerate("xyz"):
        ax = axes[i]
        ax.plot(t, ee[:, i], color=f"C{i}", linewidth=1.2, label=f"measured {axis} (FK)")
        if ref is not None:
            ax.plot(t, ref[:, i], label=f"reference {axis}", **COMMAND_STYLE)
        marks.draw(ax, labels=i == 0)
        ax.set_ylabel(f"{axis} [m]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    if tracked is not None:
        error, use = tracked
        err_mm = np.where(use, 1e3 * np.linalg.norm(error, axis=1), np.nan)
        axes[3].plot(t, err_mm, color="C3", linewidth=1.2, label=error_label)
        marks.draw(axes[3], labels=False)
        axes[3].set_ylabel("error [mm]")
        axes[3].grid(True, alpha=0.3)
        axes[3].legend(loc="best", fontsize=8)
        rmse = ee_rmse_m(error, use)
        title = f"{robot.name}: end-effector '{robot.arm_ee}' position vs reference (RMSE {1e3 * rmse:.1f} mm)"
    else:
        title = f"{robot.name}: end-effector '{robot.arm_ee}' position (world frame)"
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=12)
    return fig


def ee_rmse_m(error: np.ndarray, use: np.ndarray) -> float:
    """Root mean square of the error vectors' lengths over the samples in `use` (`ee_pos_rmse_m`)."""
    use = np.asarray(use, dtype=bool)
    return float(np.sqrt(np.mean(np.sum(error[use] ** 2, axis=1)))) if use.any() else float("nan")


def plot_ee_position(robot, data: dict, path: Path, ee_reference: Callable | None, marks: RunMarks | None = None,
                     ee_error: EeError | None = None, error_label: str = "|p - p_ref|") -> Path:
    return save_figure(ee_position_figure(robot, data, ee_reference, marks, ee_error, error_label), path)


def _torque_panel(ax, t, tau, limits, labels, title) -> None:
    for k, (label, limit) in enumerate(zip(labels, limits)):
        color = f"C{k % 10}"
        ax.plot(t, tau[:, k], color=color, linewidth=1.0, label=label)
        for sign in (1, -1):
            ax.axhline(sign * limit, color=color, linestyle="--", linewidth=1.0, alpha=0.7)
    top = 1.1 * max(np.max(limits), np.max(np.abs(tau)) if tau.size else 0.0)
    ax.set_ylim(-top, top)
    ax.set_title(title, fontsize=10)
    ax.set_ylabel("torque [Nm]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="dashed: ±limit", title_fontsize=7)


def most_loaded_joints(robot, tau: np.ndarray) -> list[int]:
    """Indices of the joints closest to their torque limits (peak |tau| / tau_max, largest first):
    every joint above HIGHLIGHT_RATIO, at least HIGHLIGHT_MIN_JOINTS and at most HIGHLIGHT_MAX_JOINTS."""
    if not tau.size:
        return []
    peak = np.max(np.abs(tau) / robot.tau_max, axis=0)
    order = [int(i) for i in np.argsort(-peak, kind="stable")]
    n = int(np.clip(np.sum(peak > HIGHLIGHT_RATIO), HIGHLIGHT_MIN_JOINTS, HIGHLIGHT_MAX_JOINTS))
    return order[: min(n, len(order))]


def joint_torques_figure(robot, data: dict, marks: RunMarks | None = None) -> Figure:
    t, tau = data["t"], data["tau"]
    names = list(robot.joint_names)
    panels: list[tuple[str, list[int]]] = [(f"leg '{foot}'", idx) for foot, idx in leg_joint_groups(robot) if idx]
    arm = [i for i, is_leg in enumerate(robot.leg_joint_mask) if not is_leg]
    if arm:
        panels.append(("arm", arm))
    loaded = most_loaded_joints(robot, tau)
    n = len(panels) + (1 if loaded else 0)
    cols = 2 if n > 1 else 1
    rows = int(np.ceil(n / cols))
    fig = _figure(6.0 * cols, 2.9 * rows + 0.6)
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, squeeze=False).ravel())
    marks = marks or RunMarks()
    for ax, (title, idx) in zip(axes, panels):
        peak = np.max(np.abs(tau[:, idx]) / robot.tau_max[idx]) if tau.size else 0.0
        _torque_panel(ax, t, tau[:, idx], robot.tau_max[idx], _short_names([names[i] for i in idx]),
                      f"{title}: peak {100 * peak:.0f}% of limit")
        marks.draw(ax, labels=False)
    if loaded:
        ax = axes[len(panels)]
        limits = robot.tau_max[loaded]
        ratio = np.abs(tau[:, loaded]) / limits
        peaks = ratio.max(axis=0)
        labels = [f"{names[i].removesuffix('_joint')} ({100 * p:.0f}%)" for i, p in zip(loaded, peaks)]
        _torque_panel(ax, t, tau[:, loaded], limits, labels,
                      f"MOST LOADED JOINTS: peak {100 * float(peaks.max()):.0f}% of limit")
        if "tau_ff" in data and data["tau_ff"].shape == tau.shape:
            for k, i in enumerate(loaded):
                ax.plot(t, data["tau_ff"][:, i], color=f"C{k}", linewidth=0.8, linestyle=":", alpha=0.9)
        near = np.any(ratio > HIGHLIGHT_RATIO, axis=1)
        if np.any(near):
            ax.fill_between(t, 0, 1, where=near, transform=ax.get_xaxis_transform(), color=HIGHLIGHT_COLOR,
                            alpha=0.18, linewidth=0, label=f"> {100 * HIGHLIGHT_RATIO:.0f}% of limit")
        marks.draw(ax)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="dashed: ±limit\ndotted: feed-fwd", title_fontsize=7)
        for spine in ax.spines.values():
            spine.set_edgecolor(HIGHLIGHT_COLOR)
            spine.set_linewidth(2.0)
        ax.title.set_color(HIGHLIGHT_COLOR)
        ax.title.set_fontweight("bold")
    for ax in axes[n:]:
        ax.remove()
    for ax in axes[:n][-cols:]:
        ax.set_xlabel("time [s]")
        ax.xaxis.set_tick_params(labelbottom=True)
    fig.suptitle(f"{robot.name}: applied joint torques vs limits", fontsize=12)
    return fig


def plot_joint_torques(robot, data: dict, path: Path, marks: RunMarks | None = None) -> Path:
    return save_figure(joint_torques_figure(robot, data, marks), path)


def _planned_intervals(robot, data: dict) -> list[list[tuple[float, float]]] | None:
    planned, mpc_t, t = data["planned_contact"], data["mpc_t"], data["t"]
    if planned.ndim != 2 or planned.shape[0] != mpc_t.size or planned.shape[1] != len(robot.feet) or not mpc_t.size:
        return None
    return [_stance_intervals(mpc_t, planned[:, i], float(t[-1])) for i in range(len(robot.feet))]


def _measured_contact(data: dict, n_feet: int, threshold_n: float = 5.0) -> np.ndarray | None:
    forces = data["contact_forces"]
    if forces.ndim != 3 or forces.shape[1] < n_feet or forces.shape[0] != data["t"].size:
        return None
    return forces[:, :n_feet, 2] > threshold_n


def foot_heights_figure(robot, data: dict, marks: RunMarks | None = None) -> Figure:
    t, q = data["t"], data["q"]
    feet = list(robot.feet)
    contact = {foot: getattr(robot, "contact_frame", lambda f: f)(foot) for foot in feet}  # flat feet: the sole
    pos = frame_positions(robot, q, list(contact.values()))
    pos = {foot: pos[frame] for foot, frame in contact.items()}
    intervals = _planned_intervals(robot, data)
    measured = _measured_contact(data, len(feet))
    fig = _figure(10, 1.7 * len(feet) + 1.2)
    axes = np.atleast_1d(fig.subplots(len(feet), 1, sharex=True, squeeze=False).ravel())
    for i, (ax, foot) in enumerate(zip(axes, feet)):
        if intervals is not None:
            _shade_stance(ax, intervals[i])
        height = robot.contact_height_m(foot) if hasattr(robot, "contact_height_m") else robot.foot_radius_m
        ax.plot(t, 100 * (pos[foot][:, 2] - height), color=f"C{i}", linewidth=1.2, label="foot height (FK)")
        if measured is not None and np.any(measured[:, i]):
            ax.fill_between(t, 0, 0.08, where=measured[:, i], transform=ax.get_xaxis_transform(), color="0.25",
                            linewidth=0, label="measured contact")
        (marks or RunMarks()).draw(ax, labels=i == 0)
        ax.axhline(0.0, color="0.5", linewidth=0.8)
        ax.set_ylabel(f"{foot}\n[cm]")
        ax.grid(True, alpha=0.3)
    _figure_legend(fig, axes[0])
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{robot.name}: foot height above ground (sole) with planned contact schedule", fontsize=12)
    return fig


def plot_foot_heights(robot, data: dict, path: Path, marks: RunMarks | None = None) -> Path:
    return save_figure(foot_heights_figure(robot, data, marks), path)


def contact_forces_figure(robot, data: dict, marks: RunMarks | None = None) -> Figure:
    t, forces = data["t"], data["contact_forces"]
    feet = list(robot.feet)
    intervals = _planned_intervals(robot, data)
    fig = _figure(10, 1.7 * len(feet) + 1.2)
    axes = np.atleast_1d(fig.subplots(len(feet), 1, sharex=True, sharey=True, squeeze=False).ravel())
    weight = robot.mass_kg * 9.81
    share = stance_at_t = None
    planned = data["planned_contact"]
    if intervals is not None:
        stance_at_t = _hold(data["mpc_t"], planned > 0.5, t)
        share = weight / np.maximum(stance_at_t.sum(axis=1), 1)
    for i, (ax, foot) in enumerate(zip(axes, feet)):
        if intervals is not None:
            _shade_stance(ax, intervals[i])
        ax.plot(t, forces[:, i, 2], color=f"C{i}", linewidth=1.0, label="normal force $f_z$")
        ax.plot(t, np.linalg.norm(forces[:, i, :2], axis=1), color="0.4", linewidth=0.8, label="tangential $|f_{xy}|$")
        if share is not None:
            ax.plot(t, np.where(stance_at_t[:, i], share, np.nan), color="0.2", linestyle=":", linewidth=1.2,
                    label="weight / planned stance feet")
        (marks or RunMarks()).draw(ax, labels=i == 0)
        ax.set_ylabel(f"{foot}\n[N]")
        ax.grid(True, alpha=0.3)
    _figure_legend(fig, axes[0])
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{robot.name}: measured contact forces (world) with planned contact schedule", fontsize=12)
    return fig


def plot_contact_forces(robot, data: dict, path: Path, marks: RunMarks | None = None) -> Path:
    return save_figure(contact_forces_figure(robot, data, marks), path)


def solver_figure(robot, data: dict, budget_ms: float = 1e3 / MPC_RATE_HZ, marks: RunMarks | None = None) -> Figure:
    """Solve time per MPC step against `budget_ms` (the MPC period) and the solver's iterations."""
    mpc_t, solve_ms, iterations = data["mpc_t"], data["solve_ms"].astype(float), data["iterations"]
    success = data["success"].astype(bool) if data["success"].size == mpc_t.size else np.ones(mpc_t.size, bool)
    marks = marks or RunMarks()
    fig = _figure(10, 6)
    ax_ms, ax_it = fig.subplots(2, 1, sharex=True)
    ax_ms.plot(mpc_t, solve_ms, "o-", color="C0", markersize=2.5, linewidth=0.8, label="solve time")
    ax_ms.axhline(budget_ms, color=HIGHLIGHT_COLOR, linestyle="--", linewidth=1.4,
                  label=f"{1e3 / budget_ms:.0f} Hz budget ({budget_ms:.1f} ms)")
    over = solve_ms > budget_ms
    if np.any(over):
        ax_ms.plot(mpc_t[over], solve_ms[over], "o", color="C1", markersize=4, label=f"over budget ({int(over.sum())})")
    marks.draw(ax_ms)
    ax_ms.set_ylabel("solve time [ms]")
    ax_ms.set_ylim(bottom=0, top=max(1.15 * budget_ms, 1.1 * float(np.max(solve_ms)) if solve_ms.size else 0))
    if solve_ms.size:
        ax_ms.set_title(f"solve time: mean {np.mean(solve_ms):.2f} ± {np.std(solve_ms):.2f} ms, "
                        f"max {np.max(solve_ms):.2f} ms, {int(over.sum())}/{solve_ms.size} over budget", fontsize=10)
    ax_ms.grid(True, alpha=0.3)
    ax_ms.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    if mpc_t.size > 1:
        width = 0.8 * float(np.median(np.diff(mpc_t)))
    else:
        width = 0.01
    if mpc_t.size <= MAX_ITERATION_BARS:
        ax_it.bar(mpc_t, iterations, width=width, color=np.where(success, "C2", HIGHLIGHT_COLOR), align="edge")
    else:  # a long run: one stair line, failed steps as dots (48000 bars of a 10 min run took 24 s and 400 MB)
        ax_it.plot(mpc_t, iterations, drawstyle="steps-post", color="C2", linewidth=0.6)
        ax_it.plot(mpc_t[~success], iterations[~success], "o", color=HIGHLIGHT_COLOR, markersize=3)
    marks.draw(ax_it, labels=False)
    ax_it.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax_it.set_ylabel("iterations")
    ax_it.set_xlabel("time [s]")
    if iterations.size:
        ax_it.set_title(f"solver iterations per MPC step: mean {np.mean(iterations):.1f}, max {int(np.max(iterations))}", fontsize=10)
    ax_it.grid(True, alpha=0.3)
    fig.suptitle(f"{robot.name}: MPC solver statistics ({mpc_t.size} steps)", fontsize=12)
    return fig


def plot_solver(robot, data: dict, path: Path, budget_ms: float = 1e3 / MPC_RATE_HZ, marks: RunMarks | None = None) -> Path:
    return save_figure(solver_figure(robot, data, budget_ms, marks), path)


def ee_force_figure(t: np.ndarray, measured_n: np.ndarray, target_n: np.ndarray, title: str = "end-effector force",
                    marks: RunMarks | None = None) -> Figure:
    """Force the end-effector applies on an object (measured in simulation, along the target's
    direction) against the MPC's force target of eq. (7), and the relative error."""
    fig = _figure(9, 5)
    ax, ax_err = fig.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    ax.plot(t, measured_n, linewidth=0.8, label="measured (simulation)")
    ax.plot(t, target_n, label="MPC target", **COMMAND_STYLE)
    (marks or RunMarks()).draw(ax)
    ax.set_ylabel("force [N]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    active = target_n > 1e-6
    rel = np.full_like(measured_n, np.nan)
    rel[active] = 100 * (measured_n[active] - target_n[active]) / target_n[active]
    ax_err.plot(t, rel, linewidth=0.8, color=HIGHLIGHT_COLOR)
    full = active & (target_n > 0.5 * float(np.max(target_n, initial=0.0)))  # not the ramp's first newtons
    if full.any():
        span = max(20.0, 1.2 * float(np.nanmax(np.abs(rel[full]))))
        ax_err.set_ylim(-span, span)
    (marks or RunMarks()).draw(ax_err, labels=False)
    ax_err.axhline(10, color="gray", linestyle=":", linewidth=1)
    ax_err.axhline(-10, color="gray", linestyle=":", linewidth=1)
    ax_err.set_ylabel("error [% of target]")
    ax_err.set_xlabel("time [s]")
    ax_err.grid(alpha=0.3)
    _figure_legend(fig, ax)
    return fig


def plot_ee_force(t: np.ndarray, measured_n: np.ndarray, target_n: np.ndarray, path: Path,
                  title: str = "end-effector force", marks: RunMarks | None = None) -> Path:
    return save_figure(ee_force_figure(t, measured_n, target_n, title, marks), path)


# ----------------------------------------------------------------------------- entry point
def save_plots(robot, log, out_dir, ee_reference: Callable[[float], np.ndarray] | None = None,
               budget_ms: float | None = None, ee_error: EeError | None = None,
               ee_error_label: str = "|p - p_ref|") -> list[Path]:
    """Write the diagnostic PNGs of a run into `out_dir` (created) and return their paths.

    `ee_reference(t) -> (3,)` is the end-effector position reference in world, if any;
    `ee_error(t, ee) -> (error (n, 3), mask)` the tracking error behind the run's `ee_pos_rmse_m`
    (the plot's RMSE is then the metric's). The end-effector plot is skipped for robots without
    an arm, the solver plot for logs without MPC steps. The run's events (`RunMarks.from_log`)
    are marked on every plot. `budget_ms`: the solve-time line of the solver plot; None: the run's MPC period.
    """
    # a long run is plotted from every k-th control tick (k = ceil(ticks / PLOT_FULL_RATE_TICKS)): a PNG
    # shows no more, and the whole 500 Hz run would not fit in memory for long; the MPC steps stay whole
    every = max(1, -(-log.n_ticks // PLOT_FULL_RATE_TICKS)) if hasattr(log, "n_ticks") else 1
    data = log.arrays(every=every) if every > 1 else log.arrays()
    t = data["t"]
    if t.size < 2:
        raise ConfigError(f"the run log has {t.size} control ticks; plots need at least 2")
    if data["q"].shape != (t.size, robot.nq) or data["v"].shape != (t.size, robot.nv):
        raise ConfigError(
            f"the run log does not match robot '{robot.name}': q {data['q'].shape}, v {data['v'].shape}, "
            f"expected ({t.size}, {robot.nq}) and ({t.size}, {robot.nv})"
        )
    marks = RunMarks.from_log(log)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [plot_base_velocity(robot, data, log, out / "base_velocity.png", marks)]
    if robot.arm_ee:
        paths.append(plot_ee_position(robot, data, out / "ee_position.png", ee_reference, marks, ee_error, ee_error_label))
    if data["tau"].shape == (t.size, robot.n_joints):
        paths.append(plot_joint_torques(robot, data, out / "joint_torques.png", marks))
    paths.append(plot_foot_heights(robot, data, out / "foot_heights.png", marks))
    if data["contact_forces"].ndim == 3 and data["contact_forces"].shape[0] == t.size:
        paths.append(plot_contact_forces(robot, data, out / "contact_forces.png", marks))
    if data["mpc_t"].size:
        if budget_ms is None:
            budget_ms = 1e3 / (getattr(log, "mpc_rate_hz", None) or MPC_RATE_HZ)
        paths.append(plot_solver(robot, data, out / "solver.png", budget_ms, marks))
    return paths
