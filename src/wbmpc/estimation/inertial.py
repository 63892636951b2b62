"""Online identification of the mass distribution: the base CoM offset and a payload (beyond the paper).

The paper's B2 carried its mass ~60 % further back than its URDF says (section VI); the authors moved the
CoM by hand. Here the floating-base dynamics identify it while the robot walks. With the joint torque
regressor Y(q, v, a) of pinocchio (tau = Y pi, pi the bodies' ten inertial parameters about their joints)
and the contact Jacobian J_c of the feet:

    tau_applied + J_c^T f = Y (pi_nominal + delta_pi(theta)) + drive train (armature, friction),

theta = [base CoM offset (3, base frame, m), payload (kg) at the hand or the base origin, and with an arm a load
at the base origin (kg)]. None moves a leg's own rows (the base and the hand are not below a leg joint), so the leg rows give the feet's contact
forces from the measured torques, f = (J_c,legs^T)^+ r_legs, r = Y pi_nominal + drive - tau_applied; the
base's six rows and the arm's rows are then linear in theta:

    Y_B G theta = -(r_B - J_c,B^T f) - Y_B (delta_pi(theta_hat) - G theta_hat),   G = d delta_pi / d theta

(the base's rotational inertia about its joint is quadratic in the offset: linearised at the estimate).
Exponentially weighted least squares with a Gaussian prior (theta = 0) accumulates these rows every plant
step; the accelerations are the plant's velocities differenced over the step. The estimate goes to the MPC
as NLP parameters (`MPC.set_inertial_parameters`, `OcpConfig.inertial_parameters`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.errors import check_number
from wbmpc.robots import RobotModel
from wbmpc.symbolic.dynamics import payload_placement


@dataclass(frozen=True)
class InertialEstimatorConfig:
    """Weights of the least squares (row noise and prior standard deviations) and its memory."""

    forgetting_time_s: float = 5.0  # older rows fade with this time constant (a slowly changing payload)
    force_noise_n: float = 20.0  # base force rows (impacts and finite differences)
    moment_noise_nm: float = 5.0  # base moment rows
    arm_torque_noise_nm: float = 2.0  # arm joint rows
    prior_offset_m: float = 0.05  # prior std of the CoM offset's x and y around 0
    # ... and of its z: on a level base gravity's moment does not see it, only tilts and accelerations do, where
    # it trades off against x (a 3 kg hand payload, standing: z -2 cm, x -4.4 cm of a true -5 cm with 5 cm)
    prior_offset_z_m: float = 0.005
    prior_payload_kg: float = 5.0
    huber_threshold: float = 2.0  # in units of a row's noise
    # once settled, a sample with a base row this far off (row noises) is dropped: a contact the model does not
    # have (a shin on the floor: 60 N, 20 N m). Rejections that last gate_reopen_s are a new mass distribution
    # (a payload picked up): the samples count again
    gate_threshold: float = 6.0
    gate_reopen_s: float = 0.3
    # measured velocities differenced over one step amplify their noise (1e-2 rad/s -> 10 rad/s^2 at 1 ms): a
    # first-order low-pass of this cutoff on both sides of the regression (exact for constant parameters,
    # the rows are linear in them) averages it out; None: the rows as they come (noise-free simulator state)
    row_filter_hz: float | None = None
    # a joint this close to a position limit gets the limit's unmeasured torque: its row is left out (a leg's:
    # the whole sample; b1_z1's elbow rests 0.26 rad below its limit, a 5 kg hand payload pushes it there)
    limit_margin_rad: float = 0.02
    estimate_payload: bool = True
    estimate_base_payload: bool = True  # robots with an arm: a load at the base origin too (told apart by the arm rows)
    max_offset_m: float = 0.2  # the estimate is clipped to |offset_i| <= this and 0 <= payload <= max_payload_kg
    max_payload_kg: float = 20.0
    settle_s: float = 0.5  # the MPC gets the estimate after this much observed time

    def __post_init__(self):
        for name in ("forgetting_time_s", "force_noise_n", "moment_noise_nm", "arm_torque_noise_nm",
                     "prior_offset_m", "prior_offset_z_m", "prior_payload_kg", "huber_threshold", "gate_threshold", "limit_margin_rad", "max_offset_m", "max_payload_kg"):
            check_number(f"inertial_estimator.{name}", getattr(self, name), low=0.0, low_open=True)
        check_number("inertial_estimator.settle_s", self.settle_s, low=0.0)
        check_number("inertial_estimator.gate_reopen_s", self.gate_reopen_s, low=0.0)
        check_number("inertial_estimator.row_filter_hz", self.row_filter_hz, low=0.0, low_open=True, allow_none=True)


class InertialEstimator:
    """Recursive least squares of theta = [base CoM offset (m), payload (kg)] from (q, v, v_next, tau)."""

    def __init__(self, robot: RobotModel, config: InertialEstimatorConfig = InertialEstimatorConfig()):
        self.robot, self.config = robot, config
        self.model = robot.model
        self.data = self.model.createData()
        nv = self.model.nv
        self.pi_nominal = np.concatenate([self.model.inertias[i].toDynamicParameters()
                                          for i in range(1, self.model.njoints)])
        self.payload_joint, self.payload_offset = payload_placement(robot)
        self.foot_ids = [robot.frame_id(robot.contact_frame(f)) for f in robot.feet]
        self.foot_rows = [6 if f in robot.soles else 3 for f in robot.feet]
        # a point foot's force acts at the bottom of its sphere, not at the frame (the sphere's centre): on
        # b1_z1 standing, the tangential forces' moments about the centre read as a CoM 1.4 cm low otherwise
        radius = float(robot.foot_radius_m or 0.0)
        self._contact_offset = np.array([[0.0, radius, 0.0], [-radius, 0.0, 0.0], [0.0, 0.0, 0.0]])  # skew(-R e_z)
        legs = np.flatnonzero(robot.leg_joint_mask) + 6
        self.leg_rows = legs
        self.model_rows = np.r_[np.arange(6), np.flatnonzero(~robot.leg_joint_mask) + 6]  # base + arm
        noise = np.r_[[config.force_noise_n] * 3, [config.moment_noise_nm] * 3,
                      [config.arm_torque_noise_nm] * (self.model_rows.size - 6)]
        self._row_weight = 1.0 / noise
        n_payloads = 0 if not config.estimate_payload else 2 if config.estimate_base_payload and robot.arm_ee else 1
        self.n_theta = 3 + n_payloads
        prior = np.r_[[config.prior_offset_m] * 2, [config.prior_offset_z_m], [config.prior_payload_kg] * 2][: self.n_theta]
        self._prior_information = np.diag(1.0 / prior**2)
        self._information = np.zeros((self.n_theta, self.n_theta))
        self._vector = np.zeros(self.n_theta)
        self.theta = np.zeros(self.n_theta)
        self.observed_s = 0.0
        self.samples = 0
        self.rejected = 0  # samples dropped by the gate
        self._filtered: tuple[np.ndarray, np.ndarray] | None = None
        self._rejecting_s = 0.0
        self._armature = np.r_[np.zeros(6), robot.armature_kg_m2]
        self._nv = nv

    # ------------------------------------------------------------------ parameters
    def _delta_pi(self, theta: np.ndarray) -> np.ndarray:
        """Change of the stacked inertial parameters from the nominal model for theta."""
        delta = np.zeros_like(self.pi_nominal)
        base = self.model.inertias[1]
        edited = pin.Inertia(base.mass, np.array(base.lever) + theta[:3], np.array(base.inertia))
        delta[0:10] = edited.toDynamicParameters() - base.toDynamicParameters()
        if self.n_theta >= 4:
            k = 10 * (self.payload_joint - 1)
            delta[k : k + 10] += pin.Inertia(1.0, self.payload_offset, np.zeros((3, 3))).toDynamicParameters() * theta[3]
        if self.n_theta == 5:
            delta[0] += theta[4]  # a point mass at the base origin: mass only
        return delta

    def _jacobian(self, theta: np.ndarray) -> np.ndarray:
        """G = d delta_pi / d theta (central differences: exact, delta_pi is at most quadratic)."""
        step = 1e-3
        columns = []
        for i in range(self.n_theta):
            e = np.zeros(self.n_theta)
            e[i] = step
            columns.append((self._delta_pi(theta + e) - self._delta_pi(theta - e)) / (2 * step))
        return np.column_stack(columns)

    # ------------------------------------------------------------------ observation
    def rows(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, tau_joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A, b) of one sample: A theta ~= b on the base and arm rows (unweighted; NaN rows: a joint at its
        position limit, whose torque is not measured)."""
        model, data = self.model, self.data
        angles = self.robot.joint_positions(q)
        margin = self.config.limit_margin_rad
        at_limit = np.r_[np.zeros(6, bool), (angles < self.robot.q_min + margin) | (angles > self.robot.q_max - margin)]
        if at_limit[self.leg_rows].any():  # the leg's force from its torques would be wrong: no rows at all
            return np.full((self.model_rows.size, self.n_theta), np.nan), np.full(self.model_rows.size, np.nan)
        regressor = pin.computeJointTorqueRegressor(model, data, q, v, a)
        drive = self._armature * a + np.r_[np.zeros(6), self.robot.joint_friction_torque(v[6:])]
        residual = regressor @ self.pi_nominal + drive - np.r_[np.zeros(6), tau_joints]
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        blocks = []
        for fid, rows in zip(self.foot_ids, self.foot_rows):
            frame_jacobian = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            if rows == 3:  # velocity of the sphere's lowest point: v - [d]x w, d = -R e_z
                frame_jacobian = frame_jacobian[:3] - self._contact_offset @ frame_jacobian[3:]
            blocks.append(frame_jacobian)
        jacobian = np.vstack(blocks)
        forces = np.linalg.lstsq(jacobian[:, self.leg_rows].T, residual[self.leg_rows], rcond=None)[0]
        rows = self.model_rows
        error = residual[rows] - jacobian[:, rows].T @ forces  # = -Y_B delta_pi(theta)
        y = regressor[rows]
        g = self._jacobian(self.theta)
        a_rows = y @ g
        b_rows = -error - y @ (self._delta_pi(self.theta) - g @ self.theta)
        b_rows[at_limit[rows]] = np.nan
        return a_rows, b_rows

    def observe(self, q: np.ndarray, v: np.ndarray, v_next: np.ndarray, tau_joints: np.ndarray, dt_s: float,
                elapsed_s: float | None = None) -> None:
        """One plant step of dt_s: state (q, v) before it, velocity after it, the torques applied over it;
        `elapsed_s` since the previous sample (default dt_s) sets the forgetting."""
        elapsed_s = dt_s if elapsed_s is None else elapsed_s
        a = (np.asarray(v_next, float) - np.asarray(v, float)) / dt_s
        a_rows, b_rows = self.rows(q, v, a, tau_joints)
        valid = np.isfinite(b_rows)
        a_rows, b_rows = np.where(valid[:, None], a_rows, 0.0), np.where(valid, b_rows, 0.0)
        if self.config.row_filter_hz is not None:
            if self._filtered is None:
                self._filtered = (a_rows, b_rows)
            alpha = 1.0 - np.exp(-2 * np.pi * self.config.row_filter_hz * elapsed_s)
            a_f, b_f = self._filtered
            a_rows, b_rows = a_f + alpha * (a_rows - a_f), b_f + alpha * (b_rows - b_f)
            self._filtered = (a_rows, b_rows)
        w = self._row_weight[:, None]
        # Huber weights: a row off the current estimate by more than huber_threshold of its noise (impacts,
        # the drop at the start) counts as if it were that far off
        residual = np.abs(w[:, 0] * (b_rows - a_rows @ self.theta))
        self.observed_s += elapsed_s
        if self.settled and residual[:6].max() > self.config.gate_threshold:
            if self._rejecting_s < self.config.gate_reopen_s:  # after that long off, the samples count again
                self._rejecting_s += elapsed_s
                self.rejected += 1
                return
        else:
            self._rejecting_s = 0.0
        w = w * np.sqrt(np.minimum(1.0, self.config.huber_threshold / np.maximum(residual, 1e-12)))[:, None]
        decay = np.exp(-elapsed_s / self.config.forgetting_time_s)
        self._information = decay * self._information + (w * a_rows).T @ (w * a_rows)
        self._vector = decay * self._vector + (w * a_rows).T @ (w[:, 0] * b_rows)
        theta = np.linalg.solve(self._information + self._prior_information, self._vector)
        cfg = self.config
        theta[:3] = np.clip(theta[:3], -cfg.max_offset_m, cfg.max_offset_m)
        theta[3:] = np.clip(theta[3:], 0.0, cfg.max_payload_kg)
        self.theta = theta
        self.samples += 1

    # ------------------------------------------------------------------ estimate
    @property
    def base_com_offset_m(self) -> np.ndarray:
        return self.theta[:3].copy()

    @property
    def payload_kg(self) -> float:
        return float(self.theta[3]) if self.n_theta >= 4 else 0.0

    @property
    def base_payload_kg(self) -> float:
        return float(self.theta[4]) if self.n_theta == 5 else 0.0

    @property
    def settled(self) -> bool:
        return self.observed_s >= self.config.settle_s

    def report(self) -> dict:
        """JSON keys of a run: the final estimate."""
        return {"base_com_offset_estimate_m": [float(x) for x in self.base_com_offset_m],
                "payload_estimate_kg": self.payload_kg, "base_payload_estimate_kg": self.base_payload_kg,
                "inertial_estimate_samples": self.samples,
                "inertial_estimate_rejected": self.rejected}


# from the state estimator's state (--state estimated): velocities from IMU and encoders differenced over a 2 ms
# tick, low-passed at 5 Hz; the weakly observable vertical offset held closer to 0 (b1_z1 trotting 6 s with the base
# CoM 5 cm back: unfiltered z ran to -9.6 cm; 10 Hz: x -4.99, z -1.9 cm and still moving; 5 Hz: z -0.8 cm;
# 5 Hz with a 2 mm z prior: x -4.996, z -0.16 cm after 8 s)
ESTIMATED_STATE_CONFIG = InertialEstimatorConfig(row_filter_hz=5.0, prior_offset_z_m=0.002)


class InertialIdentification:
    """A MuJoCo plant step hook: observes the robot's motion and applied torques and feeds the estimate to the
    MPC's NLP. From the simulator's state (every `every_n_steps` physics steps), or with `from_estimate` from the
    state estimator's (`on_estimate`, every control tick) and the torques averaged over the steps in between, as
    on a robot whose state comes from its IMU and encoders."""

    def __init__(self, estimator: InertialEstimator, mpc=None, record_every_s: float = 0.1, every_n_steps: int = 2,
                 from_estimate: bool = False):
        """`every_n_steps`: physics steps between samples (an observation costs ~0.3 ms of CPU on b1_z1; 2: the
        500 Hz of the control loop at MuJoCo's 1 ms step)."""
        self.estimator, self.mpc = estimator, mpc
        self.from_estimate = from_estimate
        self._before: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._every, self._steps = max(1, int(every_n_steps)), 0
        self.history: list[tuple[float, list[float], float, float]] = []  # (observed s, offset, payload, base payload)
        self._record_every_s = record_every_s
        self._torque_sum: np.ndarray | None = None  # from_estimate: torques applied since the last estimate
        self._torque_steps = 0
        self._last_estimate: tuple[float, np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_estimated_state(cls, robot: RobotModel, mpc=None) -> InertialIdentification:
        """Fed by a state estimator's output (`on_estimate`) and the applied torques (`on_torque`), as on a robot
        (`wbmpc deploy --identify-mass`); its MPC may be set later (`mpc`)."""
        return cls(InertialEstimator(robot, ESTIMATED_STATE_CONFIG), mpc, from_estimate=True)

    def on_torque(self, tau_joints: np.ndarray) -> None:
        """`from_estimate`: the joint torques applied over one step since the last state estimate (a plant's step,
        or on a robot the motor law of the command just sent with this tick's joint readings)."""
        tau = np.asarray(tau_joints, dtype=float)
        self._torque_sum = tau.copy() if self._torque_sum is None else self._torque_sum + tau
        self._torque_steps += 1

    def parameters(self) -> np.ndarray | None:
        """(base CoM offset x, y, z (m), hand payload, base payload (kg)) once settled, else None: what a solver in
        another process is sent with each request (`SolverProcess.request(inertial=...)`)."""
        est = self.estimator
        if not est.settled:
            return None
        return np.r_[est.base_com_offset_m, est.payload_kg, est.base_payload_kg]

    def before_step(self, plant) -> None:
        if self.from_estimate:
            self.on_torque(plant.applied_torques())
            return
        self._steps += 1
        if self._steps % self._every == 0:
            q, v = plant.state()
            self._before = (q, v, plant.applied_torques())

    def after_step(self, plant) -> None:
        if self._before is None:
            return
        q, v, tau = self._before
        self._before = None
        _, v_next = plant.state()
        self._observe(q, v, v_next, tau, plant.dt_s, self._every * plant.dt_s)

    def on_estimate(self, t_s: float, q: np.ndarray, v: np.ndarray) -> None:
        """`from_estimate`: one sample per state estimate, between the previous estimate and this one."""
        previous, self._last_estimate = self._last_estimate, (t_s, np.array(q, float), np.array(v, float))
        tau = self._torque_sum / self._torque_steps if self._torque_steps else None
        self._torque_sum, self._torque_steps = None, 0
        if previous is None or tau is None or t_s <= previous[0]:
            return
        self._observe(previous[1], previous[2], v, tau, t_s - previous[0], t_s - previous[0])

    def _observe(self, q, v, v_next, tau, dt_s: float, elapsed_s: float) -> None:
        est = self.estimator
        est.observe(q, v, v_next, tau, dt_s, elapsed_s=elapsed_s)
        if est.observed_s + 1e-9 >= len(self.history) * self._record_every_s:
            self.history.append((est.observed_s, est.base_com_offset_m.tolist(), est.payload_kg, est.base_payload_kg))
        if self.mpc is not None and est.settled:
            self.mpc.set_inertial_parameters(est.base_com_offset_m, est.payload_kg, est.base_payload_kg)

    def metrics(self, model_errors=None) -> dict:
        """metrics.json keys: the final estimate, its history (every `record_every_s` of observed time: t, offset
        x, y, z, payload, base payload) and, against a plant with known `ModelErrors`, the estimate's errors."""
        out = {**self.estimator.report(),
               "inertial_estimate_history": [[t, *offset, payload, base] for t, offset, payload, base in self.history]}
        if model_errors is not None:
            true_offset = np.asarray(model_errors.base_com_offset_m, dtype=float)
            out["base_com_offset_estimate_error_m"] = float(np.linalg.norm(self.estimator.base_com_offset_m - true_offset))
            out["payload_estimate_error_kg"] = abs(self.estimator.payload_kg - float(model_errors.ee_payload_kg))
        return out

