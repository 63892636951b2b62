"""`ForceTask`: a loco-manipulation scenario of section VI-C whose metric is force tracking against a scene object.

The MPC never models the objects (unless `--object-model`: push-box and pull then plan with the box or the load
inside the OCP, `wbmpc.ocp.objects`): it receives the end-effector force target F_arm^des and the end-effector
velocity command v_arm^des of eq. (7) (`Commands.ee_force_n`, `ee_velocity_m_s`). The velocity command comes from
a position reference by feedback (scenarios/feedback.py), except along a contact normal, where the force target
alone presses the end-effector on.

Force metric: `ee_force_err_rel` = mean over the time the full target is applied of |F_meas . u - F_target| /
F_target, where F_meas is the force the end-effector applies on the object (cable tension or contact force,
measured by MuJoCo at every physics step and passed through a first-order low-pass of
`FORCE_SENSOR_BANDWIDTH_HZ`, the bandwidth of a wrist force sensor), u the unit direction of the target (the
board normal for `wipe`) and F_target the target's magnitude along u. The same error of the unfiltered contact
force is `ee_force_err_rel_raw`. A rigid end-effector sphere sliding on a board with friction makes and breaks
MuJoCo's contact at ~200 Hz with micrometre motions of the light wrist (23 % filtered, ~100 % raw error); a
sprung pad keeps the contact closed and the raw and filtered errors agree (about 2 %).
"""

from __future__ import annotations

import numpy as np

from wbmpc.control.run_log import RunLog
from wbmpc.errors import ConfigError
from wbmpc.scenarios.base import Scenario
from wbmpc.scenarios.signals import (
    FORCE_SENSOR_BANDWIDTH_HZ,
    arm_torque_metrics,
    commanded_forces,
    force_tracking,
    low_pass,
)
from wbmpc.sim.objects import Scene


class ForceTask(Scenario):
    """Shared by the scenarios whose metric is force tracking against a scene object."""

    object_name = ""
    force_window_start_s = 1.0

    def __post_init__(self):
        super().__post_init__()
        self._scene: Scene | None = None

    def scene(self, robot):
        self._scene = Scene(robot, self._objects(robot))
        return self._scene

    def _objects(self, robot) -> list:
        raise NotImplementedError

    def _force_direction(self, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(unit directions, magnitudes) of the target along which the measured force is compared."""
        magnitude = np.linalg.norm(targets, axis=1)
        return targets / np.maximum(magnitude, 1e-9)[:, None], magnitude

    def measured_force(self) -> tuple[np.ndarray, np.ndarray]:
        if self._scene is None or not self._scene.recording.t:
            raise ConfigError(f"scenario '{self.name}' has no scene measurements; run it on the MuJoCo plant")
        return self._scene.recording.series(self.object_name, "force_n")

    def force_series(self, log: RunLog) -> dict:
        """Measured force along the target direction, and the target, at every physics step."""
        t, raw = self.measured_force()
        measured = low_pass(t, raw, FORCE_SENSOR_BANDWIDTH_HZ)
        direction, target = self._force_direction(commanded_forces(log, t))
        return {"t": t, "measured_n": np.einsum("ij,ij->i", measured, direction), "target_n": target,
                "measured_vec_n": measured, "raw_vec_n": raw, "direction": direction}

    def extra_metrics(self, robot, log):
        s = self.force_series(log)
        t_end = float(log.last_tick("t")) if log.n_ticks else 0.0
        window = (s["t"] >= self.force_window_start_s) & (s["t"] <= t_end + 1e-9)
        out = force_tracking(s["t"], s["measured_vec_n"], s["direction"], s["target_n"], window)
        raw = force_tracking(s["t"], s["raw_vec_n"], s["direction"], s["target_n"], window)
        out["ee_force_err_rel_raw"] = raw["ee_force_err_rel"]
        out["force_sensor_bandwidth_hz"] = FORCE_SENSOR_BANDWIDTH_HZ
        out["force_window_start_s"] = self.force_window_start_s
        out.update(arm_torque_metrics(robot, log))
        return out

    def extra_plots(self, robot, log, out_dir):
        from wbmpc.viz.plots import RunMarks, plot_ee_force

        s = self.force_series(log)
        return [plot_ee_force(s["t"], s["measured_n"], s["target_n"], out_dir / "ee_force.png",
                              title=f"{self.name}: end-effector force on the {self.object_name}",
                              marks=RunMarks.from_log(log))]
