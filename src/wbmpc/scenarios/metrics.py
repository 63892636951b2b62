"""Scenario metrics from a closed-loop `RunLog` (the keys of `metrics.json`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control import step_anatomy
from wbmpc.control.run_log import RunLog
from wbmpc.robots import RobotModel

SETTLE_S = 2.0


def heading_rotation(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def base_world_velocity(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 3) base linear velocity in world coordinates from pinocchio-layout states."""
    out = np.empty((len(q), 3))
    for i in range(len(q)):
        out[i] = pin.Quaternion(q[i, 3:7]).toRotationMatrix() @ v[i, :3]
    return out


def common_metrics(robot: RobotModel, log: RunLog, scenario: str) -> dict:
    """The metrics every scenario reports, streamed over the log's chunks (exact, bounded memory)."""
    t0, t_end = float(log.first_tick("t")), float(log.last_tick("t"))
    duration = t_end - t0 if log.n_ticks > 1 else 0.0
    # commanded base velocity (heading frame of the start) integrated over the run
    yaw0 = base_yaw(log.first_tick("q"))
    steps = log.arrays(("mpc_t", "solve_ms", "iterations"))
    cmd_t = steps["mpc_t"]
    cmd_world = log.command_array()[:, 0:3] @ heading_rotation(yaw0).T
    # the same after the start transient (the first SETTLE_S, at most half the run): with velocity-only
    # base tracking an initial shift is never pulled back and would dominate the whole-run figure
    settle_time = t0 + min(SETTLE_S, 0.5 * duration) if duration > 0 else None
    ticks = _TickStatistics(robot, cmd_t, cmd_world, settle_time)
    for chunk in log.tick_chunks(("t", "q", "v", "tau", "tau_ff")):
        ticks.add(chunk)
    path = ticks.commanded_path
    displacement = ticks.q_last[:2] - ticks.q_first[:2] - path
    settled_s = float(t_end - ticks.settle_t) if duration > 0 else 0.0
    settled_displacement = displacement - (ticks.settle_q[:2] - ticks.q_first[:2]) + ticks.settle_path \
        if duration > 0 else displacement
    solve = steps["solve_ms"]
    n_solves = len(solve)
    delay_ms = log.arrays(("delay_ms",))["delay_ms"]
    torque_ratio = ticks.max_abs_tau / robot.tau_max
    return {
        "scenario": scenario,
        "robot": robot.name,
        "fell": bool(log.fell),
        "fell_at_s": log.fell_at_s,
        "duration_s": duration,
        "base_drift_cm_s": float(100 * np.linalg.norm(displacement) / duration) if duration > 0 else None,
        "base_drift_settled_cm_s": float(100 * np.linalg.norm(settled_displacement) / settled_s) if settled_s > 0 else None,
        "base_drift_settled_from_s": float(ticks.settle_t - t0) if duration > 0 else None,
        # planar: the base's (x, y) velocity in the world against the command, at every 500 Hz tick (vertical
        # velocity and yaw rate not counted); the trot's sway at the gait frequency counts in full
        "base_vel_rmse": float(np.sqrt(ticks.velocity_error_sq_sum / ticks.n)),
        # after the start transient (the command steps from rest at t = 0), as base_drift_settled_cm_s
        "base_vel_rmse_settled": float(np.sqrt(ticks.settled_error_sq_sum / ticks.settled_n)) if ticks.settled_n else None,
        "ee_pos_rmse_m": None,
        "ee_force_err_rel": None,
        "max_torque_ratio": float(np.max(torque_ratio)),
        "max_feedforward_torque_ratio": float(np.max(ticks.max_abs_tau_ff / robot.tau_max)),
        "torque_margin_per_joint": {name: float(1.0 - r) for name, r in zip(robot.joint_names, torque_ratio)},
        "solve_ms": {"mean": float(np.mean(solve)), "std": float(np.std(solve)), "max": float(np.max(solve))},
        "iterations_mean": float(np.mean(steps["iterations"])),
        "mpc_failures": int(log.mpc_failures),
        "mpc_recoveries": int(log.mpc_recoveries),  # failed first, solved by a recovery re-solve
        "mpc_solves": n_solves,
        "mpc_rate_hz": float(n_solves / duration) if duration > 0 else None,
        "late_solution_share": float(log.late_solutions / max(n_solves, 1)),
        "delay_ms_mean": float(np.mean(delay_ms)) if delay_ms.size else 0.0,
        "wall_time_s": log.wall_time_s,
        "sim_cpu_share": log.sim_cpu_share,  # real time: simulation process CPU / wall (must not starve the MPC)
        "mpc_cpu_share": log.mpc_cpu_share,
        "realtime_priority": log.realtime_priority,  # real time: "fifo 10" / "nice -10" where permitted, else "default"
        "realtime_session_nice": log.session_nice,  # real time: the session group's nice (Linux autogroups), else None
        **realtime_plant_metrics(log),
        **stability_metrics(log, cmd_t, solve, duration),
        **solver_detail_metrics(log),
    }


def realtime_plant_metrics(log: RunLog) -> dict:
    """Real time: the plant loop's own lateness per joint-loop tick (ms after its wall-clock time: mean, 99th
    percentile, max; the share of ticks later than half a joint-loop period), where each plan's delay went
    (`control/step_anatomy.py`: per segment mean, p95, max in ms) and the CPUs of the loop, the solver and
    its helper threads with their priorities (None for the other delay modes)."""
    late = log.plant_lateness
    plan = log.cpu_plan
    out: dict = {"plant_lateness_ms": None, "plant_late_tick_share": None, "cpu_plan": None,
                 "realtime_step_anatomy_ms": step_anatomy.summary(log.anatomy()) or None}
    if late is not None and late.count:
        out["plant_lateness_ms"] = {"mean": late.mean, "p99": late.percentile(99), "max": late.max}
        out["plant_late_tick_share"] = late.share_over()
    if plan is not None:
        out["realtime_competitors"] = list(log.realtime_competitors)
        out["cpu_plan"] = {"loop": sorted(plan.loop), "solver": sorted(plan.solver), "helpers": sorted(plan.helpers),
                           "helper_threads": int(log.solver_helper_threads), **log.solver_scheduling}
    return out


def solver_detail_metrics(log: RunLog) -> dict:
    """The anytime SQP's per-step record: SQP iterations, KKT residuals of the returned iterates, how
    many steps it ended by its deadline and how many ended past it (None when the solver reports none)."""
    details = log.solver_details()
    n = details["sqp_iterations"].size
    if not n:
        return {"sqp_iterations_mean": None}

    def stat(values, how):
        values = values[np.isfinite(values)]
        return float(how(values)) if values.size else None

    iterations = details["sqp_iterations"][np.isfinite(details["sqp_iterations"])]
    return {"sqp_iterations_mean": float(np.mean(iterations)) if iterations.size else None,
            "sqp_iterations_min": int(np.min(iterations)) if iterations.size else None,
            "primal_residual_median": stat(details["primal_residual"], np.median),
            "primal_residual_max": stat(details["primal_residual"], np.max),
            "dual_residual_median": stat(details["dual_residual"], np.median),
            "step_budget_ms_mean": stat(details["budget_ms"], np.mean),
            "solver_past_deadline_share": stat(details["late"], np.mean)}


STABILITY_WINDOW_S = 60.0


def stability_metrics(log: RunLog, mpc_t: np.ndarray, solve_ms: np.ndarray, duration_s: float) -> dict:
    """Resident memory and solve time at the start and the end of a run (flat over a long run?).

    The window is the first and the last minute, or half the run when it is shorter than two minutes;
    memory growth is counted from the end of the first window (after the warm-up's allocations)."""
    window_s = min(STABILITY_WINDOW_S, 0.5 * duration_s)
    out: dict = {"stability_window_s": window_s}
    if mpc_t.size and window_s > 0:
        first = mpc_t <= mpc_t[0] + window_s
        last = mpc_t >= mpc_t[0] + duration_s - window_s
        out["solve_ms_first_window_mean"] = float(np.mean(solve_ms[first]))
        out["solve_ms_last_window_mean"] = float(np.mean(solve_ms[last])) if last.any() else None
    samples = np.array(log.rss_samples, dtype=float).reshape(-1, 2)
    if samples.size:
        warm = samples[np.searchsorted(samples[:, 0], window_s - 1e-9).clip(max=len(samples) - 1)]
        end = samples[-1]
        out.update(rss_mb_start=float(samples[0, 1]), rss_mb_after_window=float(warm[1]), rss_mb_end=float(end[1]),
                   rss_growth_pct=float(100 * (end[1] - warm[1]) / warm[1]),
                   rss_mb_samples=[[round(float(time_s), 3), round(float(mb), 1)] for time_s, mb in samples])
    return out


class _TickStatistics:
    """Whole-run sums and extrema over the control ticks, fed a chunk at a time in order."""

    def __init__(self, robot: RobotModel, cmd_t: np.ndarray, cmd_world: np.ndarray, settle_time: float | None):
        self.cmd_t, self.cmd_world, self.settle_time = cmd_t, cmd_world, settle_time
        self.n = 0
        self.q_first: np.ndarray | None = None
        self.q_last: np.ndarray | None = None
        self.commanded_path = np.zeros(2)  # integral of the commanded xy velocity up to the last tick
        self._previous: tuple[float, np.ndarray] | None = None  # (t, commanded xy velocity) of the last tick
        self.settle_t, self.settle_q, self.settle_path = None, None, None
        self.velocity_error_sq_sum = 0.0
        self.settled_error_sq_sum, self.settled_n = 0.0, 0  # the same after the start transient
        self.max_abs_tau = np.zeros(robot.n_joints)
        self.max_abs_tau_ff = np.zeros(robot.n_joints)

    def add(self, chunk: dict) -> None:
        t, q, v = chunk["t"], chunk["q"], chunk["v"]
        if not len(t):
            return
        cmd = np.stack([np.interp(t, self.cmd_t, self.cmd_world[:, k]) for k in range(3)], axis=1)
        if self.q_first is None:
            self.q_first = q[0].copy()
            times, velocities, path0 = t, cmd[:, :2], self.commanded_path
        else:  # continue the integral across the chunk boundary
            times = np.r_[self._previous[0], t]
            velocities = np.vstack([self._previous[1], cmd[:, :2]])
            path0 = self.commanded_path
        increments = velocities[:-1] * np.diff(times)[:, None]
        # the same sequential sum as one cumsum over the whole run would do, so bit for bit the same
        path = np.cumsum(np.vstack([path0[None, :], increments]), axis=0)[1:]
        at_tick = np.vstack([path0[None, :], path]) if self._previous is None else path  # the integral up to each tick
        if self.settle_t is None and self.settle_time is not None and t[-1] >= self.settle_time:
            k = int(np.searchsorted(t, self.settle_time))
            self.settle_t, self.settle_q, self.settle_path = float(t[k]), q[k].copy(), at_tick[k].copy()
        if len(path):
            self.commanded_path = path[-1].copy()
        self._previous = (float(t[-1]), cmd[-1, :2].copy())
        self.q_last = q[-1].copy()
        vel_world = base_world_velocity(q, v)
        error_sq = np.sum((vel_world[:, :2] - cmd[:, :2]) ** 2, axis=1)
        self.velocity_error_sq_sum += float(np.sum(error_sq))
        self.n += len(t)
        if self.settle_time is not None:
            settled = t >= self.settle_time
            self.settled_error_sq_sum += float(np.sum(error_sq[settled]))
            self.settled_n += int(np.sum(settled))
        self.max_abs_tau = np.maximum(self.max_abs_tau, np.max(np.abs(chunk["tau"]), axis=0))
        self.max_abs_tau_ff = np.maximum(self.max_abs_tau_ff, np.max(np.abs(chunk["tau_ff"]), axis=0))


def base_yaw(q: np.ndarray) -> float:
    """Yaw of the base orientation of a pinocchio-layout configuration (rad)."""
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    return float(np.arctan2(rot[1, 0], rot[0, 0]))
