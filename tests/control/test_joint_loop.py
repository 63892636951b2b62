"""The joint loop's timing: the held damper's bound against the rigid-body dynamics, jitter, the motor law."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.interpolator import PdGains
from wbmpc.control.joint_loop import DAMPER_BOUND, held_gains, hold_s, joint_mode_inertia, unstable_gains
from wbmpc.robots import load_robot


def _swing_leg_growth(robot, kd: float, hold: float, holds: int = 10) -> float:
    """A leg swinging with the base held still, under eq. (10)'s damper -Kd v evaluated once per `hold` and held
    (no gravity, no feed-forward): |v| after `holds` holds over |v| at the start, integrated by pinocchio's ABA
    at 0.05 ms (independent of the bound's formula)."""
    model = robot.model.copy()
    model.gravity.linear[:] = 0.0
    data = model.createData()
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    leg = np.flatnonzero(robot.leg_joint_mask)[:3]  # the first leg
    v[6 + leg] = [0.3, -0.5, 1.0]
    start = np.linalg.norm(v[6 + leg])
    substeps = int(round(hold / 5e-5))
    for _ in range(holds):
        tau = np.zeros(robot.nv)
        tau[6 + leg] = -kd * v[6 + leg]
        for _ in range(substeps):
            a = pin.aba(model, data, q, v, tau)
            a[:6] = 0.0  # base held
            v = v + 5e-5 * a
            v[:6] = 0.0
            q = pin.integrate(model, q, 5e-5 * v)
    return float(np.linalg.norm(v[6 + leg]) / start)


def test_the_held_damper_bound_matches_the_swinging_legs_dynamics():
    """Kd T / I with I the lightest joint-space mode: a held damper at the bound decays, at 2.6x it grows."""
    robot = load_robot("go2")
    inertia = joint_mode_inertia(robot, robot.leg_joint_mask)
    hold = 0.005
    assert _swing_leg_growth(robot, 1.0 * inertia / hold, hold) < 0.05  # dead-beat
    assert _swing_leg_growth(robot, DAMPER_BOUND * inertia / hold, hold) < 0.5
    assert _swing_leg_growth(robot, 2.6 * inertia / hold, hold) > 10.0
    # the diagonal of the mass matrix (the former bound) overestimates the lightest mode
    data = robot.model.createData()
    diagonal = np.diag(pin.crba(robot.model, data, robot.q_nominal))[6:][robot.leg_joint_mask].min()
    assert inertia < 0.7 * diagonal
    assert _swing_leg_growth(robot, 2.0 * diagonal / hold * 0.99, hold) > 10.0


def test_held_gains_cap_only_above_the_bound_and_name_the_unstable_ones():
    gains = PdGains(kp_leg=0.0, kd_leg=3.0, kp_arm=20.0, kd_arm=1.0)
    capped = held_gains(gains, 0.003, None, 0.005)
    assert capped.kd_leg == pytest.approx(DAMPER_BOUND * 0.003 / 0.005) and capped.kd_arm == 1.0
    assert held_gains(gains, 0.003, None, 0.0005) is gains
    problems = unstable_gains(gains, 0.003, 0.01, 0.005)
    assert len(problems) == 1 and problems[0].startswith("kd_leg 3") and "Kd T / I = 5.00" in problems[0]
    assert unstable_gains(PdGains(kd_leg=1.19), 0.003, None, 0.005) == []  # Kd T / I = 1.98
    assert unstable_gains(capped, 0.003, 0.01, 0.005) == []


def test_the_hold_is_a_period_plus_its_jitter_in_physics_steps():
    assert hold_s(500.0) == pytest.approx(0.002)
    assert hold_s(200.0, physics_dt_s=0.002) == pytest.approx(0.006)  # 5 ms on a 2 ms step: up to 3 steps
    assert hold_s(500.0, jitter_ms=1.0) == pytest.approx(0.003)
    assert hold_s(200.0, motor_law="continuous", physics_dt_s=0.001) == pytest.approx(0.001)
    assert hold_s(2000.0, physics_dt_s=0.001) == pytest.approx(0.001)


class _CountingPlant:
    """A plant stand-in: records the torque of each physics step; the joints follow a fixed velocity."""

    def __init__(self, robot, dt_s=1e-3):
        self.robot, self.dt_s, self._t = robot, dt_s, 0.0
        self.torques = []

    @property
    def time_s(self):
        return self._t

    def state(self):
        v = np.zeros(self.robot.nv)
        v[6:] = np.sin(50 * self._t)  # the joint velocity changes every step
        return self.robot.q_nominal.copy(), v

    def contact_forces(self):
        return np.zeros((len(self.robot.feet), 3))

    def step(self, tau):
        self.torques.append(np.array(tau))
        self._t += self.dt_s


class _ConstantPlan:
    """An MPC stand-in whose every plan holds the nominal pose with zero torques."""

    config = None

    def __init__(self, robot, n: int = 4):
        self.robot, self._n = robot, n

    def solve(self, q, v, command, t, **kw):
        from types import SimpleNamespace

        robot, n = self.robot, self._n
        return SimpleNamespace(
            t_s=t, node_times_s=np.linspace(0.0, 0.3, n), tau=np.zeros((3, robot.n_joints)),
            q_joints=np.tile(robot.joint_positions(robot.q_nominal), (n, 1)), v=np.zeros((n, robot.nv)),
            a=np.zeros((n, robot.nv)), success=True, held_previous=False, contact=np.ones((n, len(robot.feet))),
            stats=SimpleNamespace(solve_time_s=1e-3, iterations=1, status="ok", details=None))


def _loop_torques(motor_law: str, jitter_ms: float = 0.0, seed: int = 0):
    from wbmpc.control.loop import ClosedLoop, LoopConfig

    robot = load_robot("go2")
    plant = _CountingPlant(robot)
    mpc = _ConstantPlan(robot)
    config = LoopConfig(control_rate_hz=200.0, motor_law=motor_law, joint_loop_jitter_ms=jitter_ms, seed=seed,
                        gains=PdGains(kp_leg=0.0, kd_leg=0.5))
    loop = ClosedLoop(mpc, plant, config)
    log = loop.run(0.1)
    return np.array(plant.torques), log


def test_a_held_law_changes_only_when_a_command_arrives_a_continuous_one_every_step():
    held, log = _loop_torques("held")
    changes = np.flatnonzero(np.any(np.diff(held, axis=0) != 0, axis=1)) + 1
    assert np.all(changes % 5 == 0)  # 200 Hz on a 1 ms step: a new torque every 5 steps
    assert log.n_ticks == 20
    continuous, _ = _loop_torques("continuous")
    assert np.all(np.any(np.diff(continuous, axis=0) != 0, axis=1))


def test_jitter_delays_commands_reproducibly_from_the_seed():
    a, log_a = _loop_torques("held", jitter_ms=3.0, seed=1)
    b, _ = _loop_torques("held", jitter_ms=3.0, seed=1)
    c, _ = _loop_torques("held", jitter_ms=3.0, seed=2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    ticks = np.asarray(log_a.t)
    gaps = np.diff(ticks)
    assert gaps.min() >= 0.002 - 1e-9 and gaps.max() <= 0.008 + 1e-9 and np.ptp(gaps) > 0.001
    assert np.all(ticks[1:] >= 0.005 * np.arange(1, len(ticks)) - 1e-9)  # never early


def test_run_config_refuses_a_jitter_longer_than_the_period():
    from wbmpc.errors import ConfigError
    from wbmpc.scenarios import RunConfig

    with pytest.raises(ConfigError, match="joint_loop_jitter_ms"):
        RunConfig(joint_loop_hz=500.0, joint_loop_jitter_ms=3.0)
    assert dataclasses.replace(RunConfig(), joint_loop_hz=200.0, joint_loop_jitter_ms=3.0).joint_loop_hz == 200.0
