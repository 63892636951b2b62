"""`DeployReport`: what a `wbmpc deploy` run did (phases, messages, MPC solves, timing, the estimated drift).

The per-tick figures (500 Hz: controller work, plan age, the Z1 state's age, the end effector's error, the estimated
position) are kept as streaming statistics and end points, in fixed memory however long the robot runs (as lists
they grew by ~470 MB an hour)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from wbmpc.control.streaming_stats import StreamingStats


@dataclass
class DeployReport:
    phases: list = field(default_factory=list)  # (robot time s, phase name)
    states_received: int = 0
    states_rejected: dict = field(default_factory=dict)
    commands_sent: int = 0
    arm: dict | None = None  # the Z1 link's counters
    sport_mode: dict | None = None  # {"released": mode found, "restored": bool}
    mpc_solves: int = 0
    mpc_failures: int = 0
    first_solve_failures: int = 0
    solve_ms: StreamingStats = field(default_factory=lambda: StreamingStats(range_max=1000.0))
    # controller work per LowState (excluding MPC solves)
    tick_ms: StreamingStats = field(default_factory=lambda: StreamingStats(resolution=0.001, range_max=50.0))
    plan_age_ms: StreamingStats = field(default_factory=lambda: StreamingStats(range_max=1000.0))
    arm_state_age_ms: StreamingStats = field(default_factory=StreamingStats)  # age of the Z1 state used, per tick
    # |reference - end effector| from the estimated state, MPC phase: (sum of squares m^2, samples)
    ee_error_sq_sum: float = 0.0
    ee_error_samples: int = 0
    fell: bool = False
    stopped_by: str = "done"
    error: str | None = None
    estimated_xy_m: list = field(default_factory=list)  # the MPC phase's first and last estimated base position
    link: dict = field(default_factory=dict)  # robot link, time source, accepted unset fields, mode_machine
    joint_loop: dict | None = None  # the command period and hold measured before the MPC phase, the gains it took
    inertial: dict | None = None  # --identify-mass: the estimate (`InertialIdentification.metrics`)
    scheduling: dict | None = None  # real time: the loop's priority granted and the CPU plan (`DeployScheduling`)

    def record_position(self, xy_m) -> None:
        """The estimated base position of an MPC-phase tick: the first and the latest are kept."""
        point = [float(xy_m[0]), float(xy_m[1])]
        if len(self.estimated_xy_m) < 2:
            self.estimated_xy_m.append(point)
        else:
            self.estimated_xy_m[1] = point

    def record_ee_error(self, error_m: float) -> None:
        self.ee_error_sq_sum += float(error_m) ** 2
        self.ee_error_samples += 1

    def summary(self) -> dict:
        tick, age = self.tick_ms, self.plan_age_ms
        return {
            "phases": self.phases,
            "states_received": self.states_received,
            "states_rejected": dict(self.states_rejected),
            **self.link,
            "joint_loop": self.joint_loop,
            "scheduling": self.scheduling,
            **(self.inertial or {}),
            "commands_sent": self.commands_sent,
            "arm": self.arm,
            "sport_mode": self.sport_mode,
            "mpc_solves": self.mpc_solves,
            "mpc_failures": self.mpc_failures,
            "first_solve_failures": self.first_solve_failures,
            "solve_ms_mean": self.solve_ms.summary()["mean"],
            "controller_tick_ms_p50": tick.summary()["p50"],
            "controller_tick_ms_p99": tick.summary()["p99"],
            "plan_age_ms_p50": age.summary()["p50"],
            "plan_age_ms_max": age.summary()["max"],
            "ee_rmse_estimated_m": (math.sqrt(self.ee_error_sq_sum / self.ee_error_samples) if self.ee_error_samples
                                    else None),
            "fell": self.fell,
            "stopped_by": self.stopped_by,
            "error": self.error,
            "mpc_phase_s": self._mpc_phase_s(),
            "estimated_drift_cm_s": self._estimated_drift(),
        }

    def _mpc_phase_s(self) -> float | None:
        times = [t for t, p in self.phases if p == "mpc"]
        later = [t for t, p in self.phases if times and t > times[0]]
        return (later[0] - times[0]) if times and later else None

    def _estimated_drift(self) -> float | None:
        """Base displacement over the MPC phase from the controller's own estimate, cm/s."""
        duration = self._mpc_phase_s()
        if not duration or len(self.estimated_xy_m) < 2:
            return None
        return float(100 * np.linalg.norm(np.subtract(self.estimated_xy_m[-1], self.estimated_xy_m[0])) / duration)
