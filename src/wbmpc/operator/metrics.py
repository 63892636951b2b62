"""Metrics of an operator session (`metrics.json`'s "operator"): per command segment, the base velocity and yaw
rate against the command after a settling time, the hand's error, each stop's time to standing still, and
the latency from each command's timestamp to the MPC step that used it."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.operator.board import Posted
from wbmpc.robots import RobotModel

SEGMENT_SETTLE_S = 1.0  # the "after 1 s of settling"
STILL_SPEED_M_S = 0.05  # standing still: planar base speed below this ...
STILL_YAW_RATE_RAD_S = 0.1  # ... yaw rate below this, every foot planned in stance ...
STILL_HOLD_S = 0.25  # ... for this long
MIN_WINDOW_S = 0.25  # shorter measured windows are not scored


def _segments(posts: list[Posted], t_end: float) -> list[tuple[float, float, Posted]]:
    """(start, end, post) of each distinct command: consecutive posts with the same targets merge."""
    kept: list[Posted] = []
    for post in posts:
        if kept and post.stamp_s <= kept[-1].stamp_s + 1e-9:
            kept[-1] = post  # two posts at one time (a stop then its changes): the last one holds
            continue
        if kept and post.command == kept[-1].command:
            continue
        kept.append(post)
    times = [p.stamp_s for p in kept] + [t_end]
    return [(times[i], times[i + 1], p) for i, p in enumerate(kept) if times[i] < t_end]


def _base_motion(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per tick: the base's planar velocity in its heading frame (n, 2) and its angular velocity in world (n, 3)."""
    n = len(q)
    yaw, v_world, w_world = np.empty(n), np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        rot = pin.Quaternion(q[i, 3:7]).toRotationMatrix()
        yaw[i] = np.arctan2(rot[1, 0], rot[0, 0])
        v_world[i] = rot @ v[i, :3]
        w_world[i] = rot @ v[i, 3:6]
    c, s = np.cos(yaw), np.sin(yaw)
    return np.column_stack([c * v_world[:, 0] + s * v_world[:, 1], -s * v_world[:, 0] + c * v_world[:, 1]]), w_world


def operator_metrics(robot: RobotModel, arrays: dict, session, period_s: float, transitions=(),
                     labels: dict | None = None, mpc_period_s: float = 1 / 80) -> dict:
    """`arrays`: the run's ticks (t, q, v) and steps (mpc_t, planned_contact); `session`: the `OperatorSession`;
    `period_s`: the walking gait's period; `labels`: {board entry seq: label} (a script's)."""
    t, q, v = arrays["t"], arrays["q"], arrays["v"]
    n = len(t)
    v_heading, w_world = _base_motion(q, v)
    step_t = np.asarray(arrays["mpc_t"], dtype=float)
    stance = np.asarray(arrays["planned_contact"], dtype=float)
    all_stance = stance.min(axis=1) > 0.5 if stance.size else np.zeros(0, dtype=bool)
    step_at_tick = np.clip(np.searchsorted(step_t, t, side="right") - 1, 0, max(len(step_t) - 1, 0))
    planted = all_stance[step_at_tick] if len(step_t) else np.zeros(n, dtype=bool)
    hand = _hand_errors(robot, t, q, session)
    segments, stops = [], []
    t_end = float(t[-1]) if n else 0.0
    previous = None
    for start, end, post in _segments(session.posts(), t_end):
        command = post.command
        window = (t >= start + SEGMENT_SETTLE_S) & (t < end)
        target = np.array([command.forward_m_s, command.lateral_m_s]) if command.walking else np.zeros(2)
        yaw_target = command.yaw_rate_rad_s if command.walking else 0.0
        scored = window.sum() * (t[1] - t[0] if n > 1 else 0.0) >= MIN_WINDOW_S
        entry = {"label": (labels or {}).get(post.seq) or post.note or post.source, "source": post.source,
                 "start_s": float(start), "end_s": float(end), "command": command.as_dict(),
                 "base_vel_rmse": float(np.sqrt(np.mean(np.sum((v_heading[window] - target) ** 2, axis=1))))
                 if scored else None,
                 "yaw_rate_rmse": float(np.sqrt(np.mean((w_world[window, 2] - yaw_target) ** 2))) if scored else None,
                 "hand_error_rmse_m": None}
        if hand is not None and scored and command.hand_offset_m is not None:
            errors = hand[window]
            errors = errors[np.isfinite(errors)]
            entry["hand_error_rmse_m"] = float(np.sqrt(np.mean(errors**2))) if errors.size else None
        segments.append(entry)
        if previous is not None and (previous.walking or previous.moving) and not command.walking:
            stops.append(_stop(t, start, end, v_heading, w_world, planted, period_s))
        previous = command
    latencies = np.array([lat for _, lat in session.latencies]) if session.latencies else np.zeros(0)
    scored_segments = [s for s in segments if s["base_vel_rmse"] is not None]
    return {
        "segments": segments,
        "worst_base_vel_rmse": max((s["base_vel_rmse"] for s in scored_segments), default=None),
        "worst_yaw_rate_rmse": max((s["yaw_rate_rmse"] for s in scored_segments), default=None),
        "stops": stops,
        "command_latency_ms": {"max": float(1e3 * latencies.max()) if latencies.size else None,
                               "mean": float(1e3 * latencies.mean()) if latencies.size else None,
                               "commands": int(latencies.size), "mpc_period_ms": 1e3 * mpc_period_s},
        "gait_transitions": [{"requested_s": float(a), "switched_s": float(b), "to": mode} for a, b, mode in transitions],
        "gait_period_s": float(period_s),
        "limits": session.limits.as_dict(),
        "notices": [{"t_s": float(ts), "text": text} for ts, text in session.board.notices],
        "sources": [getattr(source, "name", type(source).__name__) for source in session.sources],
    }


def _stop(t, start, end, v_heading, w_world, planted, period_s) -> dict:
    """Time from a stop command to standing still (every foot planned in stance, base speed and yaw rate below
    their thresholds for STILL_HOLD_S), in seconds and in gait periods."""
    dt = t[1] - t[0] if len(t) > 1 else 1.0
    still = planted & (np.linalg.norm(v_heading, axis=1) < STILL_SPEED_M_S) & (np.abs(w_world[:, 2]) < STILL_YAW_RATE_RAD_S)
    inside = (t >= start) & (t < end)
    hold = max(1, int(round(STILL_HOLD_S / dt)))
    run, found = 0, None
    for i in np.flatnonzero(inside):
        run = run + 1 if still[i] else 0
        if run >= hold:
            found = t[i - hold + 1]
            break
    after = None if found is None else float(found - start)
    return {"t_s": float(start), "still_after_s": after,
            "gait_periods": None if after is None else after / period_s,
            "within_2_periods": bool(after is not None and after <= 2 * period_s)}


def _hand_errors(robot: RobotModel, t, q, session) -> np.ndarray | None:
    """|hand - target| per tick while a hand target is set (NaN elsewhere), None without targets."""
    if robot.arm_ee is None or not session.hand_targets:
        return None
    times = np.array([ts for ts, _ in session.hand_targets])
    targets = np.array([p for _, p in session.hand_targets])
    index = np.searchsorted(times, t, side="right") - 1
    data, frame = robot.model.createData(), robot.frame_id(robot.arm_ee)
    out = np.full(len(t), np.nan)
    step_times = np.array([ts for ts, _ in session.steps]) if session.steps else times
    for i in np.flatnonzero(index >= 0):
        # a target counts only while the step that computed it is the newest step (no stale target after release)
        if times[index[i]] < step_times[np.searchsorted(step_times, t[i], side="right") - 1] - 1e-9:
            continue
        pin.framesForwardKinematics(robot.model, data, q[i])
        out[i] = np.linalg.norm(data.oMf[frame].translation - targets[index[i]])
    return out
