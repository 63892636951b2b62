"""Delay compensation: the plan starts at the state predicted for when it applies (control/delay.py)."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.control.delay import DelayPredictor, MotorLaw, joint_references, roll_forward
from wbmpc.control.interpolator import interpolate, pd_torque
from wbmpc.control.loop import ClosedLoop, LoopConfig
from wbmpc.control.solution import Solution
from wbmpc.control.tuning import tuning_for
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
    assert second.stats.split_ms["delay_prediction"] > 0  # the prediction's own part of the step's time
    off = MPC(go2, MpcConfig(ocp=SMALL, gait="trot", recovery=RecoveryConfig(fallback_solver=None)), problem=mpc.problem)
    plain = off.solve(q1, v1, t_s=0.01, delay_s=delay)
    assert plain.t_s == 0.01 and "delay_prediction" not in plain.stats.split_ms
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


def _standing_plan(robot, q: np.ndarray, t_s: float = 0.0) -> Solution:
    """A plan that holds the pose q on both soles: at rest, with the joint torques of its static equilibrium
    (gravity carried by the soles' wrenches, least squares)."""
    model, data = robot.model, robot.model.createData()
    jacobian = np.vstack([pin.computeFrameJacobian(model, data, q, robot.frame_id(robot.contact_frame(foot)), pin.LOCAL)
                          for foot in robot.feet])
    gravity = pin.computeGeneralizedGravity(model, data, q)
    wrenches = np.linalg.lstsq(jacobian[:, :6].T, gravity[:6], rcond=None)[0]
    tau = gravity[6:] - jacobian[:, 6:].T @ wrenches
    node_times = np.array([0.0, 0.01, 0.022, 0.036])
    n = len(node_times)
    return Solution(t_s=t_s, node_times_s=node_times, q=np.tile(q, (n, 1)), v=np.zeros((n, robot.nv)),
                    a=np.zeros((n - 1, robot.nv)), forces=np.zeros((n - 1, 6 * len(robot.feet))),
                    tau=np.tile(tau, (2, 1)), contact=np.ones((n, len(robot.feet)), bool),
                    stats=SolverStats("ok", True, 0, 0.0, 0.0, 0.0), success=True)


def _run_motor_law(plant, robot, plan: Solution, law: MotorLaw, t0: float, t1: float) -> None:
    """The plant under eq. (10) on `plan`, held per tick of the law's joint loop (control/loop.py's rule)."""
    hold = 1.0 / law.control_rate_hz
    for tick in np.arange(t0, t1 - 1e-9, hold):
        q, v = plant.state()
        reference = interpolate(plan, tick + 0.5 * hold)
        tau = pd_torque(reference, robot.joint_positions(q), v[6:], np.array(law.kp), np.array(law.kd), robot.tau_max)
        for _ in range(round(hold / plant.dt_s)):
            plant.step(tau)


@pytest.fixture(scope="module")
def g1():
    return load_robot("g1")


def test_prediction_runs_the_motor_law_as_mujoco_does(g1):
    """g1 standing, its arms measured swinging at 1 rad/s against a plan that holds them: over a 20 ms delay
    MuJoCo's plant under eq. (10) (g1's tuned PD, 500 Hz) puts the arms back on the plan's references, and the
    prediction lands where the plant does. Integrating the plan's accelerations (the compensation of before, which
    g1's arms oscillated with) keeps them swinging: it misses by the whole swing."""
    law = MotorLaw.of(tuning_for(g1).gains_at(), ~g1.leg_joint_mask)
    plan = _standing_plan(g1, g1.q_nominal)
    plant = make_plant("mujoco", g1)
    plant.reset(g1.q_nominal, np.zeros(g1.nv))
    _run_motor_law(plant, g1, plan, law, -0.1, 0.0)  # settled on the floor
    q, v = plant.state()
    arm = np.flatnonzero(~g1.leg_joint_mask)
    v[6 + arm] += np.where(np.arange(arm.size) % 2, 1.0, -1.0)
    plant.set_state(q, v)
    delay = 0.02
    q_pred, v_pred = DelayPredictor(g1).predict(q, v, plan, 0.0, delay, law)
    q_old, v_old = roll_forward(g1.model, q, v, plan, 0.0, delay)
    _run_motor_law(plant, g1, plan, law, 0.0, delay)
    q_true, v_true = plant.state()
    miss = pin.difference(g1.model, q_true, q_pred)
    assert np.abs(miss[6:]).max() < np.radians(0.1) and np.abs(v_pred[6:] - v_true[6:]).max() < 0.05
    assert np.abs(miss[:6]).max() < 2e-4 and np.abs(v_pred[:6] - v_true[:6]).max() < 0.02  # the base's reaction too
    assert np.abs(v_old[6:] - v_true[6:]).max() > 0.8  # the accelerations' roll-forward: the swing kept


def test_prediction_keeps_the_stance_soles_on_the_ground(g1):
    """The plan's feet in stance stay where they were measured (pinocchio's kinematics of the predicted state),
    whatever the measured joint velocities and the plan's accelerations would make them do: the OCP's node 0 and
    its stance rows (eq. 6, zero sole velocity) see a state they can hold. A sole measured sliding stops within a
    tick (an impact); the swing sole is free."""
    rng = np.random.default_rng(5)
    law = MotorLaw.of(tuning_for(g1).gains_at(), ~g1.leg_joint_mask)
    plan = _standing_plan(g1, g1.q_nominal)
    plan.a[:] = rng.normal(scale=20.0, size=plan.a.shape)  # accelerations that move the soles
    plan.contact[:, 1] = False  # the right foot swings
    model, data = g1.model, g1.model.createData()
    left = g1.frame_id(g1.contact_frame(g1.feet[0]))
    v = np.zeros(g1.nv)
    v[6:] = rng.normal(scale=0.3, size=g1.n_joints)
    pin.forwardKinematics(model, data, g1.q_nominal, v)
    measured = pin.updateFramePlacement(model, data, left).copy()
    assert np.abs(pin.getFrameVelocity(model, data, left, pin.LOCAL).vector).max() > 0.1  # measured sliding
    def moved(state):
        pin.forwardKinematics(model, data, *state)
        placement = pin.updateFramePlacement(model, data, left)
        offset = np.r_[placement.translation - measured.translation, pin.log3(measured.rotation.T @ placement.rotation)]
        return np.abs(offset).max(), np.abs(pin.getFrameVelocity(model, data, left, pin.LOCAL).vector).max()

    offset, velocity = moved(DelayPredictor(g1).predict(g1.q_nominal, v, plan, 0.0, 0.02, law))
    assert offset < 1e-4 and velocity < 1e-3
    offset, velocity = moved(roll_forward(model, g1.q_nominal, v, plan, 0.0, 0.02))  # the plan's accelerations
    assert offset > 5e-3 and velocity > 0.1


def test_joint_references_are_the_loops_interpolation(go2):
    """The prediction's eq. (9) at all its ticks at once gives `interpolate`'s numbers at each, bit for bit: in
    the first interval, in the second (a late plan) and held beyond it."""
    rng = np.random.default_rng(7)
    node_times = np.array([0.0, 0.01, 0.022, 0.036])
    plan = _plan(go2, rng.normal(size=(3, go2.nv)), t_s=0.3, node_times=node_times)
    plan.v[:] = rng.normal(size=plan.v.shape)
    plan.q[:, 7:] += rng.normal(scale=0.1, size=(4, go2.n_joints))
    plan.q_joints = plan.q[:, 7:]
    plan.tau = rng.normal(size=(3, go2.n_joints))
    times = 0.3 + np.array([-0.001, 0.0, 0.004, 0.0099, 0.01, 0.017, 0.022, 0.03])
    tau_ff, q_des, v_des = joint_references(plan, times)
    for i, t in enumerate(times):
        reference = interpolate(plan, t)
        assert np.array_equal(tau_ff[i], reference.tau_ff) and np.array_equal(q_des[i], reference.q_des)
        assert np.array_equal(v_des[i], reference.v_des)


def _moving_plan(robot, rng) -> Solution:
    """A plan whose references move (eq. 9 varies over the ticks), a foot lifting off inside the delay and another
    landing: the held feet change from tick to tick."""
    node_times = np.array([0.0, 0.004, 0.01, 0.022, 0.036])
    n = len(node_times)
    q = np.tile(robot.q_nominal, (n, 1))
    q[:, 7:] += rng.normal(scale=0.05, size=(n, robot.n_joints))
    contact = np.ones((n, len(robot.feet)), bool)
    contact[2:, 0] = False  # lifts off at 10 ms
    contact[:1, -1] = False  # lands at 4 ms
    return Solution(t_s=0.0, node_times_s=node_times, q=q, v=rng.normal(scale=0.3, size=(n, robot.nv)),
                    a=rng.normal(scale=5.0, size=(n - 1, robot.nv)), forces=np.zeros((n - 1, 3)),
                    tau=rng.normal(scale=3.0, size=(3, robot.n_joints)), contact=contact,
                    stats=SolverStats("ok", True, 0, 0.0, 0.0, 0.0), success=True)


@pytest.mark.parametrize("name", ["g1", "go2", "b1_z1"])
def test_the_joint_loop_as_one_casadi_call_predicts_what_pinocchio_does(name):
    """`delay_ticks`: eq. (10) held per tick and the forward dynamics with the stance feet held, from our symbolic
    dynamics (6D soles on g1, 3D points on the quadrupeds, b1_z1's arm), land on the state pinocchio's
    constraintDynamics loop (`DelayPredictor`) gives: over 1 to 18 ticks (a partial last tick, several calls), with
    feet lifting off and landing within the delay, from a state away from the plan."""
    from wbmpc.control.delay_ticks import CompiledTicks, ticks_function
    from wbmpc.solvers.buffered import BufferedFunction
    from wbmpc.solvers.step_pack import library
    from wbmpc.symbolic import SymbolicDynamics

    robot = load_robot(name)
    law = MotorLaw.of(tuning_for(robot).gains_at(), ~robot.leg_joint_mask)
    function = BufferedFunction(ticks_function(SymbolicDynamics(robot), robot))
    packer = library()
    assert packer is not None, "the test machine compiles the step packer"
    # the ticks' inputs in NumPy, and in C (`csrc/delay_ticks.c`, `CompiledTicks.predict`)
    tick_runs = (CompiledTicks(function, robot), CompiledTicks(function, robot, packer))
    rng = np.random.default_rng(11)
    for delay in (0.0013, 0.0113, 0.02, 0.0351):
        plan = _moving_plan(robot, rng)
        q = pin.integrate(robot.model, robot.q_nominal, rng.normal(scale=0.05, size=robot.nv))
        v = rng.normal(scale=0.3, size=robot.nv)
        q_ref, v_ref = DelayPredictor(robot).predict(q, v, plan, 0.001, delay, law)
        for ticks in tick_runs:
            q_got, v_got = DelayPredictor(robot, ticks).predict(q, v, plan, 0.001, delay, law)
            np.testing.assert_allclose(q_got, q_ref, rtol=0, atol=1e-9)
            np.testing.assert_allclose(v_got, v_ref, rtol=0, atol=1e-9)
        assert np.abs(pin.difference(robot.model, q, q_ref)).max() > 1e-3  # the state moved: a real prediction


def _pinocchio_contacts(robot, stance: np.ndarray, baumgarte_kd: float):
    """pinocchio's rigid contacts of the stance feet (LOCAL frame; 6D for a sole, 3D for a point), their data and a
    model data sized for them."""
    model = robot.model
    models, datas = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
    for foot in np.asarray(robot.feet)[stance]:
        frame = model.frames[robot.frame_id(robot.contact_frame(foot))]
        kind = pin.ContactType.CONTACT_6D if foot in (robot.soles or {}) else pin.ContactType.CONTACT_3D
        contact = pin.RigidConstraintModel(kind, model, frame.parentJoint, frame.placement, pin.ReferenceFrame.LOCAL)
        corrector = contact.m_baumgarte_parameters
        corrector.Kd = baumgarte_kd
        contact.setBaumgarteCorrectorParameters(corrector)
        models.append(contact)
    for contact in models:
        datas.append(contact.createData())
    data = model.createData()
    if len(models):
        pin.initConstraintDynamics(model, data, models, datas)
    return models, datas, data


def test_held_forward_dynamics_is_pinocchios_constraint_dynamics():
    """symbolic/constrained.py against pinocchio's `constraintDynamics` on g1 (soles, 6D) and go2 (points, 3D):
    every foot held, one foot free, none held (then `aba`), at random states and torques."""
    import casadi as ca

    from wbmpc.symbolic import Motion, SymbolicDynamics
    from wbmpc.symbolic.constrained import held_forward_dynamics

    rng = np.random.default_rng(2)
    for name in ("g1", "go2"):
        robot = load_robot(name)
        model, dyn = robot.model, SymbolicDynamics(robot)
        q, v = ca.SX.sym("q", robot.nq), ca.SX.sym("v", robot.nv)
        tau, held = ca.SX.sym("tau", robot.n_joints), ca.SX.sym("held", len(robot.feet))
        cfg = dyn.configuration(q)
        f = ca.Function("f", [q, v, tau, held], [held_forward_dynamics(dyn, cfg, Motion(cfg, v), tau, held, 400.0, 1e-10)])
        for free in (None, 0, "all"):
            stance = np.ones(len(robot.feet), bool)
            if free == "all":
                stance[:] = False
            elif free is not None:
                stance[free] = False
            qn = pin.integrate(model, robot.q_nominal, rng.normal(scale=0.2, size=robot.nv))
            vn, tn = rng.normal(scale=0.5, size=robot.nv), rng.normal(scale=5.0, size=robot.n_joints)
            models, datas, data = _pinocchio_contacts(robot, stance, baumgarte_kd=400.0)
            tau_full = np.r_[np.zeros(6), tn]
            expected = pin.aba(model, data, qn, vn, tau_full) if not len(models) else pin.constraintDynamics(
                model, data, qn, vn, tau_full, models, datas, pin.ProximalSettings(1e-12, 1e-10, 1))
            got = np.asarray(f(qn, vn, tn, stance.astype(float))).ravel()
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * max(1.0, np.abs(expected).max()))


def test_the_delays_ticks_one_by_one_from_c_predict_what_pinocchio_does(tmp_path):
    """`compiled_ticks`: the one-tick function compiled beside the TICKS_PER_CALL one and run from C for the ticks
    the delay has (`wbsp_ticks_run`, no padding ticks), on a small flat-footed biped (6D soles) with feet lifting off
    and landing within the delay: the state pinocchio's constraintDynamics loop gives, over 1 to 18 ticks."""
    from tests.control.test_humanoid import _biped_urdf
    from wbmpc.control.delay_ticks import compiled_ticks
    from wbmpc.robots import RobotModel, RobotSpec
    from wbmpc.solvers.nlp import SolverConfig
    from wbmpc.symbolic import SymbolicDynamics

    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    robot = RobotModel(RobotSpec(name="biped", urdf=str(urdf), feet=("l_foot", "r_foot"), foot_contact="surface"))
    ticks = compiled_ticks(SymbolicDynamics(robot), robot, SolverConfig(compiled=True))
    assert ticks is not None and ticks.runs_ticks_in_c
    law = MotorLaw.of(tuning_for(robot).gains_at(), ~robot.leg_joint_mask)
    rng = np.random.default_rng(5)
    for delay in (0.0013, 0.0113, 0.0351):
        plan = _moving_plan(robot, rng)
        q = pin.integrate(robot.model, robot.q_nominal, rng.normal(scale=0.05, size=robot.nv))
        v = rng.normal(scale=0.3, size=robot.nv)
        q_ref, v_ref = DelayPredictor(robot).predict(q, v, plan, 0.001, delay, law)
        q_got, v_got = DelayPredictor(robot, ticks).predict(q, v, plan, 0.001, delay, law)
        np.testing.assert_allclose(q_got, q_ref, rtol=0, atol=1e-9)
        np.testing.assert_allclose(v_got, v_ref, rtol=0, atol=1e-9)
        assert np.abs(pin.difference(robot.model, q, q_ref)).max() > 1e-4  # the state moved: a real prediction
