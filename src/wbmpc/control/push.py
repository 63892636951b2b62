"""Push recovery mode: when the MPC treats a step as right after a push, and the faster steps it takes then.

In the mode the soft rows' slacks are free and `PushConfig.relaxed_rows` are dropped (control/mpc.py), and
the gait's period is scaled by `PushConfig.gait_period_scale` (phases continuous, `GaitClock.retime`) until
`cadence_hold_s` after the mode ends: faster steps place more feet within the horizon.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from wbmpc.control.config import PushConfig
from wbmpc.control.solution import Solution
from wbmpc.gait import GaitClock


class PushMode:
    """Push recovery mode of one MPC and its step cadence, updated once per step."""

    def __init__(self, config: PushConfig, gait: GaitClock):
        self.config = config
        self.gait = gait
        self.until_t_s: float | None = None  # in the mode until this time
        self.fast_cadence_until_t_s: float | None = None  # the faster steps until this time

    def reset(self) -> None:
        self.until_t_s = None
        self.fast_cadence_until_t_s = None

    def enter(self, until_t_s: float) -> None:
        self.until_t_s = until_t_s

    def active(self, t_s: float) -> bool:
        return self.until_t_s is not None and t_s < self.until_t_s

    def update(self, v: np.ndarray, rot: np.ndarray, commanded_world: np.ndarray, t_s: float,
               previous: Solution | None) -> bool:
        """Whether the step at `t_s` is in the mode: within `hold_s` of a step whose measured base velocity was more
        than `velocity_error_m_s` off the last plan (the push), kept while it stays that far off the command
        (the robot still moving away after it).

        Only the plan starts the mode: a light robot's trot strays from the command by more than the threshold
        on its own (a1, 15 nodes: 0.38 m/s at most, off its plan by 0.04 m/s at most)."""
        cfg = self.config
        pushed = (self.active(t_s) or previous is None) and \
            np.linalg.norm(rot @ v[:3] - commanded_world) > cfg.velocity_error_m_s
        if previous is not None and not pushed:
            (vx, vy, vz), (px, py, pz) = v[:3].tolist(), _planned_at(previous, t_s)
            ex, ey, ez = vx - px, vy - py, vz - pz  # (scalar arithmetic: NumPy's for 3 numbers, at a fraction of its cost)
            pushed = math.sqrt(ex * ex + ey * ey + ez * ez) > cfg.velocity_error_m_s
        if pushed:
            self.until_t_s = t_s + cfg.hold_s
        return self.active(t_s)

    def adapt_cadence(self, t_s: float) -> None:
        """Faster steps while in the mode and `cadence_hold_s` after it, then the gait's own period again (both
        switches keep every foot's phase)."""
        cfg, gait = self.config, self.gait
        if cfg.gait_period_scale is None or gait.duty_factor >= 1:
            return
        if self.active(t_s):
            self.fast_cadence_until_t_s = self.until_t_s + cfg.cadence_hold_s
            fast_period_s = cfg.gait_period_scale * gait.nominal_period_s
            if gait.period_s != fast_period_s:
                gait.retime(t_s, fast_period_s)
        elif self.fast_cadence_until_t_s is not None and t_s >= self.fast_cadence_until_t_s:
            gait.retime(t_s, gait.nominal_period_s)
            self.fast_cadence_until_t_s = None


def _planned_at(plan: Solution, t_s: float) -> list[float]:
    """The plan's base velocity (v[:3]) at t_s: `interp_rows` at one time, in scalar arithmetic (every MPC step)."""
    start = plan.t_s
    times = [start + node for node in plan.node_times_s.tolist()]
    if len(times) < 2:
        return plan.v[0, :3].tolist()
    k = min(max(bisect.bisect_left(times, t_s) - 1, 0), len(times) - 2)
    w = min(max((t_s - times[k]) / max(times[k + 1] - times[k], 1e-12), 0.0), 1.0)
    before, after = plan.v[k, :3].tolist(), plan.v[k + 1, :3].tolist()
    return [(1 - w) * b + w * a for b, a in zip(before, after)]
