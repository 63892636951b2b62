"""Delay compensation: the state a plan will start from when it is applied, not when it was measured.

A solution computed from the state measured at t reaches the motors at t + d (solve time plus
transport). Real deployments therefore start the OCP (eq. 1) at the state predicted for t + d.

The plant does not apply the plan's accelerations: it applies the motor law (eqs. 9-10, the plan's
torques plus a PD onto its references), and where the PD dominates a joint's inertia (a humanoid's
arms, Kd / I ~ 1 / 4 ms; the Z1's) the joint follows the plan's references within a few milliseconds,
wherever it was measured. `DelayPredictor` therefore runs the joint loop itself over the delay
(`MotorLaw`: the closed loop's gains and rate): eq. (10) evaluated at the loop's ticks on the plan
applied meanwhile and held between them, through pinocchio's constrained forward dynamics with the
feet the plan has in stance held still (rigid 6D contacts for soles, 3D for points), so the
predicted stance soles stay where the OCP's rows assume them.

`roll_forward` is the prediction of before: the measured state rolled forward with the plan's
accelerations, the continuous limit of the OCP's own integration (eq. 4, increments dq in the
tangent space of the measured q; exact for a plant that moves as the plan says),

    v(t + h) = v(t) + a_k h,    dq(t + h) = dq(t) + v(t) h + a_k h^2 / 2,    q = q_meas (+) dq.

It missed the plant by the plan's own error; the next plan started from that miss, its references
pulled the plant the other way, and the miss flipped sign and grew every step (g1's elbows at a
20 ms delay: x1.3 a step, 0.6 to 45 deg within 0.6 s; b1_z1's Z1 at 12.5-20 ms: failed steps, and
falls on stairs). It stays for the first step (no plan yet: the velocity held).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from wbmpc.control.interpolator import PdGains
from wbmpc.control.solution import Solution
from wbmpc.errors import ConfigError, check_number

if TYPE_CHECKING:
    from wbmpc.control.delay_ticks import CompiledTicks
    from wbmpc.robots import RobotModel

# when a plan reaches the plant in closed loop (control/loop.py): none (the simulation waits for the solver), measured
# (the step's CPU time elapses: its time on a core of its own), measured-wall (its wall time), fixed (`delay_ms`),
# realtime (the solver in its own process, the simulation paced by the wall clock)
DELAY_MODES = ("none", "measured", "measured-wall", "fixed", "realtime")
MAX_FIXED_DELAY_MS = 1000.0


def check_delay(delay_mode: str, delay_ms: float | None) -> None:
    """Refuse an unknown mode, a fixed delay without its milliseconds, milliseconds with another mode."""
    if delay_mode not in DELAY_MODES:
        raise ConfigError.for_field("delay_mode", f"must be one of {', '.join(DELAY_MODES)}; got {delay_mode!r}")
    if delay_mode == "fixed":
        if delay_ms is None:
            raise ConfigError("a fixed delay needs its length: --delay-ms MS (delay_ms)")
        check_number("delay_ms", delay_ms, low=0.0, high=MAX_FIXED_DELAY_MS, unit="ms")
    elif delay_ms is not None:
        raise ConfigError(f"--delay-ms sets a fixed delay; it does not go with --delay-mode {delay_mode}")


def delay_from_text(text: str) -> tuple[str, float | None]:
    """(delay_mode, delay_ms) of the one-string delay of before (`--delay-mode none|measured|measured-wall|realtime|MS`)."""
    if text in DELAY_MODES and text != "fixed":
        return text, None
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ConfigError.for_field("delay", "must be none, measured, measured-wall, realtime or a number of ms; "
                                    f"got '{text}'") from None
    check_number("delay", value, low=0.0, high=MAX_FIXED_DELAY_MS, unit="ms")
    return "fixed", value


def delay_text(delay_mode: str, delay_ms: float | None) -> str:
    """The one-string form of a delay (the metrics' `delay` key of before): the mode, or the milliseconds."""
    return f"{delay_ms:g}" if delay_mode == "fixed" else delay_mode


def roll_forward(model: pin.Model, q: np.ndarray, v: np.ndarray, plan: Solution | None, t_s: float,
                 delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(q, v) at t_s + delay_s from the measurement (q, v) at t_s under the plan's accelerations
    (piecewise constant per interval, the last one held beyond the horizon). Without a plan the
    velocity is held (zero acceleration)."""
    if not delay_s > 0:
        return q, v
    dq = np.zeros(model.nv)
    velocity = np.array(v, dtype=float)
    if plan is None:
        dq += velocity * delay_s
    else:
        times = plan.t_s + plan.node_times_s
        n_intervals = plan.a.shape[0]
        s, end = t_s, t_s + delay_s
        while s < end - 1e-15:  # one or two intervals: the delay is shorter than a few of them
            k = int(np.clip(np.searchsorted(times, s, side="right") - 1, 0, n_intervals - 1))
            segment_end = times[k + 1] if k < n_intervals - 1 and times[k + 1] > s else end
            h = min(segment_end, end) - s
            acceleration = plan.a[k]
            dq += velocity * h + 0.5 * acceleration * h * h
            velocity += acceleration * h
            s += h
    return pin.integrate(model, np.asarray(q, dtype=float), dq), velocity


def joint_references(plan: Solution, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (9) at several times at once: (tau_ff, q_des, v_des), each (len(times_s), n_joints), the numbers
    `control/interpolator.interpolate` gives at each time (same rule, same arithmetic)."""
    times = plan.t_s + plan.node_times_s
    k = (np.asarray(times_s) >= times[1]).astype(int)
    t_local = np.clip(times_s - times[k], 0.0, times[k + 1] - times[k])[:, None]
    dt_k = (times[k + 1] - times[k])[:, None]
    n_tau = plan.tau.shape[0]
    tau_k, tau_next = plan.tau[np.minimum(k, n_tau - 1)], plan.tau[np.minimum(k + 1, n_tau - 1)]
    tau_ff = tau_k + (tau_next - tau_k) * (t_local / dt_k)
    return tau_ff, plan.q_joints[k] + plan.v[k, 6:] * t_local, plan.v[k, 6:] + plan.a[k, 6:] * t_local


@dataclass(frozen=True)
class MotorLaw:
    """The joint loop a plan reaches the motors through (`LoopConfig`: eq. 10's gains, its rate, where eq. 9 is
    sampled): what `DelayPredictor` runs over the delay. `kp`, `kd` per joint (Nm/rad, Nm s/rad)."""

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    control_rate_hz: float = 500.0
    sample_mid_hold: bool = True  # `LoopConfig.sample_mid_hold`: eq. (9) sampled half a tick ahead

    @classmethod
    def of(cls, gains: PdGains, is_arm: np.ndarray, control_rate_hz: float = 500.0,
           sample_mid_hold: bool = True) -> "MotorLaw":
        kp, kd = gains.vectors(np.asarray(is_arm, dtype=bool))
        return cls(tuple(map(float, kp)), tuple(map(float, kd)), float(control_rate_hz), bool(sample_mid_hold))


def expect_motor_law(mpc, gains: PdGains, control_rate_hz: float, sample_mid_hold: bool) -> None:
    """Tell an MPC with delay compensation the closed loop's motor law (`MpcConfig.delay_compensation` becomes
    it; an MPC stand-in without a config is left alone). Set before a real-time run starts: its solver process
    gets the config."""
    config = getattr(mpc, "config", None)
    if config is not None and getattr(config, "delay_compensation", False):
        config.delay_compensation = MotorLaw.of(gains, ~mpc.robot.leg_joint_mask, control_rate_hz, sample_mid_hold)


@dataclass
class DelayPredictor:
    """The state the plant will be in when the next plan applies (module docstring): the measurement carried over
    the delay by the motor law on the plan applied meanwhile, through the constrained rigid-body dynamics.
    Without a plan the velocity is held (`roll_forward`)."""

    robot: RobotModel
    # the joint loop as one compiled call (control/delay_ticks.py), None: pinocchio's dynamics tick by tick
    ticks: CompiledTicks | None = None
    _contacts: dict = field(init=False, repr=False, default_factory=dict)

    def __post_init__(self):
        self._settings = pin.ProximalSettings(1e-12, 1e-10, 1)  # no proximal damping: the contacts held exactly
        self._default_law: MotorLaw | None = None
        self._gain_arrays = None  # (law, kp, kd) of the last law used
        self._last_ms: float | None = None  # the last prediction's wall time, until `account`

    def predict(self, q: np.ndarray, v: np.ndarray, plan: Solution | None, t_s: float, delay_s: float,
                law: MotorLaw | bool | None) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) at t_s + delay_s from the measurement (q, v) at t_s while `plan` is applied; `law`: the joint
        loop's (`MpcConfig.delay_compensation`), anything else: the robot's tuned one."""
        start = time.perf_counter()
        if not delay_s > 0 or plan is None:
            return roll_forward(self.robot.model, q, v, plan, t_s, delay_s)
        law = law if isinstance(law, MotorLaw) else self._tuned_law()
        robot, model = self.robot, self.robot.model
        kp, kd = self._gains(law)
        hold = 1.0 / law.control_rate_hz
        lead = 0.5 * hold if law.sample_mid_hold else 0.0
        predicted = self.ticks.predict(q, v, plan, t_s, delay_s, hold, lead, kp, kd) if self.ticks is not None else None
        if predicted is not None:  # the ticks' inputs in C and the ticks compiled: one call each (delay_ticks.py)
            self._last_ms = 1e3 * (time.perf_counter() - start)
            return predicted
        ticks = np.arange(t_s, t_s + delay_s - 1e-12, hold)  # the joint loop's, from the measurement on
        steps = np.diff(np.r_[ticks, t_s + delay_s])
        nodes = np.searchsorted(plan.t_s + plan.node_times_s, ticks, side="right") - 1
        stances = plan.contact[np.clip(nodes, 0, len(plan.contact) - 1)].astype(bool)
        tau_ff, q_des, v_des = joint_references(plan, ticks + lead)
        coordinates = robot.nq == robot.nv + 1 and not robot.continuous.any()  # joint angles are q[7:]
        q, v = np.array(q, dtype=float), np.array(v, dtype=float)
        if self.ticks is not None and coordinates:
            q, v = self.ticks.run(q, v, tau_ff, q_des, v_des, stances, steps, kp, kd, 1.0 / hold)
            self._last_ms = 1e3 * (time.perf_counter() - start)
            return q, v
        tau = np.zeros(model.nv)
        for i, (h, stance) in enumerate(zip(steps, stances)):  # a semi-implicit Euler step per tick, eq. (10) held
            q_j = q[7:] if coordinates else robot.joint_positions(q, near=q_des[i])
            motor = tau_ff[i] + kp * (q_des[i] - q_j) + kd * (v_des[i] - v[6:])  # control/interpolator.pd_torque
            tau[6:] = np.minimum(np.maximum(motor, -robot.tau_max), robot.tau_max)
            models, datas, data = self._held_feet(stance, hold)
            if models is None:
                a = pin.aba(model, data, q, v, tau)
            else:
                a = pin.constraintDynamics(model, data, q, v, tau, models, datas, self._settings)
            v = v + a * h
            q = pin.integrate(model, q, v * h)
        self._last_ms = 1e3 * (time.perf_counter() - start)
        return q, v

    def account(self, stats) -> None:
        """Put this step's prediction time into the solver stats' split as its own part (`delay_prediction`, ms;
        `control/solution.python_share` then leaves it out of `python`); nothing when it did not run."""
        if self._last_ms is not None and stats.split_ms:
            stats.split_ms["delay_prediction"] = self._last_ms
        self._last_ms = None

    def _gains(self, law: MotorLaw) -> tuple[np.ndarray, np.ndarray]:
        if self._gain_arrays is None or self._gain_arrays[0] is not law:
            self._gain_arrays = (law, np.array(law.kp), np.array(law.kd))
        return self._gain_arrays[1], self._gain_arrays[2]

    def _tuned_law(self) -> MotorLaw:
        """Without a loop's motor law: the robot's tuned gains on the paper's 500 Hz joint loop."""
        if self._default_law is None:
            from wbmpc.control.tuning import tuning_for

            self._default_law = MotorLaw.of(tuning_for(self.robot).gains_at(), ~self.robot.leg_joint_mask)
        return self._default_law

    def _held_feet(self, stance: np.ndarray, hold: float):
        """The rigid contacts of the stance feet and their pinocchio data (built once per stance set and tick
        length): the sole's 6D velocity, a point foot's 3D one, driven to zero within a tick (a touchdown's
        impact)."""
        key = (stance.tobytes(), hold)
        if key not in self._contacts:
            robot, model = self.robot, self.robot.model
            models, datas = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
            for foot, held in zip(robot.feet, stance):
                if not held:
                    continue
                frame = model.frames[robot.frame_id(robot.contact_frame(foot))]
                kind = pin.ContactType.CONTACT_6D if foot in (robot.soles or {}) else pin.ContactType.CONTACT_3D
                contact = pin.RigidConstraintModel(kind, model, frame.parentJoint, frame.placement,
                                                   pin.ReferenceFrame.LOCAL)
                corrector = contact.m_baumgarte_parameters
                corrector.Kd = 1.0 / hold
                contact.setBaumgarteCorrectorParameters(corrector)
                models.append(contact)
            for contact in models:
                datas.append(contact.createData())
            data = model.createData()  # one per set: pinocchio sizes its buffers for the contacts it was given
            if len(models):
                pin.initConstraintDynamics(model, data, models, datas)
            self._contacts[key] = (models, datas, data) if len(models) else (None, None, data)
        return self._contacts[key]
