"""`DeployReport`: what a `wbmpc deploy` run did (phases, messages, MPC solves, timing, the estimated drift)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
    solve_ms: list = field(default_factory=list)
    tick_ms: list = field(default_factory=list)  # controller work per LowState (excluding MPC solves)
    plan_age_ms: list = field(default_factory=list)
    arm_state_age_ms: list = field(default_factory=list)  # age of the Z1 state used, per tick
    ee_error_m: list = field(default_factory=list)  # |reference - end effector| from the estimated state, MPC phase
    fell: bool = False
    stopped_by: str = "done"
    error: str | None = None
    estimated_xy_m: list = field(default_factory=list)
    link: dict = field(default_factory=dict)  # robot link, time source, accepted unset fields, mode_machine
    joint_loop: dict | None = None  # the command period and hold measured before the MPC phase, the gains it took
    inertial: dict | None = None  # --identify-mass: the estimate (`InertialIdentification.metrics`)
    scheduling: dict | None = None  # real time: the loop's priority granted and the CPU plan (`DeployScheduling`)

    def summary(self) -> dict:
        tick = np.array(self.tick_ms)
        age = np.array(self.plan_age_ms)
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
            "solve_ms_mean": float(np.mean(self.solve_ms)) if self.solve_ms else None,
            "controller_tick_ms_p50": float(np.percentile(tick, 50)) if tick.size else None,
            "controller_tick_ms_p99": float(np.percentile(tick, 99)) if tick.size else None,
            "plan_age_ms_p50": float(np.percentile(age, 50)) if age.size else None,
            "plan_age_ms_max": float(age.max()) if age.size else None,
            "ee_rmse_estimated_m": float(np.sqrt(np.mean(np.square(self.ee_error_m)))) if self.ee_error_m else None,
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
