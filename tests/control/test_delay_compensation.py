"""Delay compensation: the plan starts at the state predicted for when it applies (control/delay.py)."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.control.delay import DelayPredictor, roll_forward
from wbmpc.control.loop import ClosedLoop, LoopConfig
from wbmpc.control.solution import Solution
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.sim import make_plant
from wbmpc.solvers.nlp import SolverStats

SMALL = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


@pytest.fixture(scope="module")
def go2():
    return load_robot("go2")


def _plan(robot, accelerations: np.ndarray, t_s: float, node_times: np.ndarray) -> Solution:
    n = len(node_times)
    stats = SolverStats("ok", True, 0, 0.0, 0.0, 0.0)
    return Solution(t_s=t_s, node_times_s=node_times, q=np.tile(robot.q_nominal, (n, 1)), v=np.zeros((n, robot.nv)),
                    a=accelerations, forces=np.zeros((n - 1, 3)), tau=np.zeros((1, robot.n_joints)),
                    contact=np.ones((n, 4), bool), stats=stats, success=True)


def _model_plant(model, q, v, plan: Solution, t0: float, t1: float, substeps: int):
    """The plant of the model: q' = v, v' = the plan's acceleration of the current interval, integrated in
    `substeps` steps (exact for piecewise constant accelerations where the chart composes)."""
    times = plan.t_s + plan.node_times_s
    grid = np.unique(np.r_[np.linspace(t0, t1, substeps + 1), times[(times > t0) & (times < t1)]])
    for a, b in zip(grid[:-1], grid[1:]):
        k = min(int(np.searchsorted(times, a, side="right") - 1), len(plan.a) - 1)
        h = b - a
        q = pin.integrate(model, q, v * h + 0.5 * plan.a[k] * h * h)
        v = v + plan.a[k] * h
    return q, v


@pytest.mark.parametrize("motion", ["translation", "yaw"])
def test_roll_forward_predicts_the_model_plant_exactly(go2, motion):
    """Across a node of the plan (accelerations change there) the predicted state is the model plant's."""
    rng = np.random.default_rng(3)
    node_times = np.array([0.0, 0.01, 0.02, 0.04, 0.08])
    a = rng.normal(size=(4, go2.nv))
    v0 = rng.normal(size=go2.nv)
    # the base chart composes exactly for a pure translation or a rotation about a fixed axis
    if motion == "translation":
        a[:, 3:6] = v0[3:6] = 0.0
    else:
        a[:, :5] = v0[:5] = 0.0
    plan = _plan(go2, a, t_s=0.1, node_times=node_times)
    q0 = go2.q_nominal.copy()
    t, delay = 0.105, 0.012  # from inside the first interval to inside the second
    q_pred, v_pred = roll_forward(go2.model, q0, v0, plan, t, delay)
    q_true, v_true = _model_plant(go2.model, q0, v0, plan, t, t + delay, substeps=17)
    np.testing.assert_allclose(q_pred, q_true, atol=1e-12)
    np.testing.assert_allclose(v_pred, v_true, atol=1e-12)
    # no delay: the measurement itself; no plan: the velocity held
    q_same, v_same = roll_forward(go2.model, q0, v0, plan, t, 0.0)
    assert np.array_equal(q_same, q0) and np.array_equal(v_same, v0)
    q_hold, v_hold = roll_forward(go2.model, q0, v0, None, t, delay)
    np.testing.assert_allclose(q_hold, pin.integrate(go2.model, q0, v0 * delay), atol=1e-14)
    np.testing.assert_allclose(v_hold, v0, atol=1e-14)


def test_mpc_plans_from_the_predicted_state(go2):
    """With compensation the plan starts at t + delay from the predicted state (node 0 of the OCP is pinned to
    it; without a loop's motor law, the robot's tuned one); without, at the measurement."""
    config = MpcConfig(ocp=SMALL, gait="trot", recovery=RecoveryConfig(fallback_solver=None), delay_compensation=True)
    mpc = MPC(go2, config)
    v = np.zeros(go2.nv)
    v[:3] = [0.2, 0.0, 0.0]
    first = mpc.solve(go2.q_nominal, v, t_s=0.0)
    assert first.success and first.t_s == 0.0
    q1, v1 = first.q[1], first.v[1]
    delay = 0.006
    predicted = DelayPredictor(go2).predict(q1, v1, first, 0.01, delay, None)
    second = mpc.solve(q1, v1, t_s=0.01, delay_s=delay)
    assert second.success, second.stats.status
    assert second.t_s == pytest.approx(0.01 + delay)
    np.testing.assert_allclose(second.q[0], predicted[0], atol=1e-9)
    np.testing.assert_allclose(second.v[0], predicted[1], atol=1e-9)
    off = MPC(go2, MpcConfig(ocp=SMALL, gait="trot", recovery=RecoveryConfig(fallback_solver=None)), problem=mpc.problem)
    plain = off.solve(q1, v1, t_s=0.01, delay_s=delay)
    assert plain.t_s == 0.01
    np.testing.assert_allclose(plain.q[0], q1, atol=1e-9)


def test_fixed_delay_run_with_compensation_stays_up(go2):
    """A closed loop with a 6 ms delay and compensation: plans start 6 ms after their measurement. (go2 on this
    small grid holds the last plan on a few steps with any delay, compensated or not: not asserted.)"""
    config = MpcConfig(ocp=SMALL, gait="trot", delay_compensation=True)
    mpc = MPC(go2, config)
    plant = make_plant("mujoco", go2)
    plant.reset(go2.q_nominal, np.zeros(go2.nv))
    log = ClosedLoop(mpc, plant, LoopConfig(delay_ms=6.0)).run(0.3)
    assert not log.fell
    np.testing.assert_allclose(log.delay_ms, 6.0)
    # every plan starts where it applies: 6 ms after the step's measurement
    assert mpc.last_plan.t_s == pytest.approx(log.mpc_t[-1] + 0.006) or not log.success[-1]
