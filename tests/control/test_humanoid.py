"""Flat feet (6D surface contacts), biped gaits and humanoids: checked against pinocchio and MuJoCo."""

import dataclasses

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import MPC, Commands, MpcConfig, RecoveryConfig
from wbmpc.errors import ConfigError, ModelError
from wbmpc.gait import SwingProfile, biped_walk_timing, make_gait
from wbmpc.ocp.problem import SWING_YAW_RATE_BAND_RAD_S, WRENCH_CONE_ROWS, OcpConfig, OcpProblem, StageBounds
from wbmpc.robots import GRAVITY_M_S2, RobotModel, RobotSpec, load_robot
from wbmpc.scenarios.base import ScenarioOptions
from wbmpc.scenarios.library import make_scenario
from wbmpc.symbolic import Motion, SymbolicDynamics


@pytest.fixture(scope="module")
def g1():
    return load_robot("g1")


def _pinocchio_fext(robot: RobotModel, q: np.ndarray, forces: np.ndarray) -> list:
    """fext built independently of wbmpc's conversion: each contact's wrench expressed in its own frame
    (sole frames: R^T f and the sole moment; the hand: R^T f), moved to its joint by the frame placement."""
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, q)
    fext = [pin.Force.Zero() for _ in range(model.njoints)]
    frames = [robot.soles[f].frame for f in robot.feet] + [robot.arm_ee]
    for c, name in enumerate(frames):
        fid = robot.frame_id(name)
        frame = model.frames[fid]
        rotation = data.oMf[fid].rotation
        moment = forces[3 * len(frames) + 3 * c : 3 * len(frames) + 3 * c + 3] if c < len(robot.feet) else np.zeros(3)
        local = pin.Force(rotation.T @ forces[3 * c : 3 * c + 3], moment)
        fext[frame.parentJoint] += frame.placement.act(local)
    return fext


def test_surface_contact_rnea_matches_pinocchio_fext(g1, rng):
    dyn = SymbolicDynamics(g1)
    assert dyn.n_forces == 3 * 3 + 3 * 2  # two soles (force + moment) and the hand (force)
    q, v, a, f = (ca.SX.sym(n, size) for n, size in (("q", g1.nq), ("v", g1.nv), ("a", g1.nv), ("f", dyn.n_forces)))
    cfg = dyn.configuration(q)
    rnea = ca.Function("rnea", [q, v, a, f], [dyn.rnea(cfg, Motion(cfg, v), a, f)])
    data = g1.model.createData()
    for _ in range(5):
        qs = g1.random_configuration(rng)
        vs, acc = rng.normal(size=g1.nv), rng.normal(size=g1.nv) * 5
        forces = rng.normal(size=dyn.n_forces) * 100
        reference = pin.rnea(g1.model, data, qs, vs, acc, _pinocchio_fext(g1, qs, forces))
        np.testing.assert_allclose(np.array(rnea(qs, vs, acc, forces)).ravel(), reference, atol=1e-9 * max(1, np.abs(reference).max()))


def test_implied_torque_rows_match_pinocchio_rnea_with_fext(g1, rng):
    """The plain nodes' torque rows (eq. 8 where the torques are no variables) are the joint torques of
    pinocchio's RNEA with the soles' wrenches and the hand's force as fext, at q = q_ref (+) dq."""
    problem = OcpProblem(g1, OcpConfig(implied_torque_rows="all"))  # every joint: the whole RNEA checked
    assert problem.implied_torque_joints.size == g1.n_joints
    k = problem.config.n_torque_nodes + 1
    function, tags = problem.stage_function(k)
    names = [tag for tag, _ in tags]
    start = sum(size for _, size in tags[: names.index("implied_torque")])
    stage_p = ca.Function("p_k", [problem.nlp["p"]], [problem.stage_parameters(problem.nlp["p"], k)])
    scales = problem.formulation.variable_scales()
    data = g1.model.createData()
    for _ in range(4):
        q_ref = g1.random_configuration(rng)
        dq = rng.normal(size=g1.nv) * 0.1
        v, a, forces = rng.normal(size=g1.nv), rng.normal(size=g1.nv) * 5, rng.normal(size=problem.nf) * 100
        values = {name: np.zeros(problem.params.shape(name)) for name in problem.params.names}
        values.update(q_ref=q_ref, rot_ref=pin.Quaternion(q_ref[3:7]).normalized().toRotationMatrix(), mu=0.5)
        _, rows, _ = function(np.r_[dq, v], np.r_[a, forces / scales["F"]], stage_p(problem.params.pack(values)))
        torques = np.array(rows).ravel()[start : start + g1.n_joints] * g1.tau_max
        q = pin.integrate(g1.model, q_ref, dq)
        reference = pin.rnea(g1.model, data, q, v, a, _pinocchio_fext(g1, q, forces))[6:]
        np.testing.assert_allclose(torques, reference, atol=1e-9 * np.abs(reference).max())
    # bounded by the torque limits on every input node past the torque variables, and nowhere else
    assert list(problem.row_nodes["implied_torque"]) == list(range(problem.config.n_torque_nodes, problem.N))
    lbg, ubg = problem.bounds(_standing_bounds(problem, g1))[2:]
    assert np.all(lbg[problem.rows["implied_torque"]] == -1.0) and np.all(ubg[problem.rows["implied_torque"]] == 1.0)


def test_implied_torque_rows_choice(g1):
    assert OcpProblem(g1, OcpConfig(implied_torque_rows="none")).implied_torque_joints.size == 0
    legs = OcpProblem(g1, OcpConfig(implied_torque_rows="legs")).implied_torque_joints
    assert [g1.joint_names[j] for j in legs] == [n for n in g1.joint_names if n.startswith(("left_", "right_"))
                                                 and ("hip" in n or "knee" in n or "ankle" in n)]
    # flat feet: by default the leg joints weaker than g1's weight on its sole's edge (41 N m), its 35 N m ankles
    weak = OcpProblem(g1, OcpConfig(implied_torque_rows="weak")).implied_torque_joints
    assert list(OcpProblem(g1).implied_torque_joints) == list(weak)
    assert [g1.joint_names[j] for j in weak] == [f"{side}_ankle_{axis}_joint" for side in ("left", "right")
                                                 for axis in ("pitch", "roll")]
    edge_nm = g1.mass_kg * 9.81 * max(abs(s.centre_m[0]) + s.half_length_m for s in g1.soles.values())
    assert np.all(g1.tau_max[weak] < edge_nm) and np.all(g1.tau_max[np.setdiff1d(legs, weak)] >= edge_nm)
    assert OcpProblem(load_robot("b1_z1")).implied_torque_joints.size == 0  # point feet: the paper's OCP
    assert OcpProblem(load_robot("talos")).implied_torque_joints.size == 0  # 100 N m legs, 88 N m at its sole's edge
    with pytest.raises(ConfigError, match="implied_torque_rows"):
        OcpConfig(implied_torque_rows="ankles")


def _standing_bounds(problem: OcpProblem, robot: RobotModel) -> StageBounds:
    n = problem.N + 1
    return StageBounds(v0=np.zeros(robot.nv), q_ref=robot.q_nominal, contact=np.ones((n, len(robot.feet))),
                       swing_vz_m_s=np.zeros((n, len(robot.feet))))


def test_single_support_plan_keeps_the_leg_torques_in_their_limits_on_every_node(g1):
    """g1 on its right foot, its base moving forward at 0.4 m/s: pinocchio's RNEA of the plan (q, v, a and the
    soles' wrenches) stays within the leg joints' torque limits on every node, not only on the torque nodes
    k < 3 (without the implied-torque rows this plan asks 1.74 times the right ankle pitch's 35 N m on 4 nodes)."""
    from wbmpc.control.tuning import tuning_for

    mpc = MPC(g1, tuning_for(g1).apply_to(MpcConfig(gait="walk")))
    t = 0.3  # the left foot in swing (0.21-0.51 s), the right one carrying the robot
    assert list(mpc.schedule(t)[1][0]) == [0.0, 1.0]
    v0 = np.zeros(g1.nv)
    v0[0] = 0.4
    solution = mpc.solve(g1.q_nominal, v0, Commands(base_velocity_m_s=np.array([0.3, 0.0, 0.0])), t)
    assert solution.success
    legs, data = g1.leg_joint_mask, g1.model.createData()
    ratios = []
    for k in range(len(solution.a)):
        fext = _pinocchio_fext(g1, solution.q[k], solution.forces[k])
        tau = pin.rnea(g1.model, data, solution.q[k], solution.v[k], solution.a[k], fext)[6:]
        ratios.append(np.abs(tau[legs]) / g1.tau_max[legs])
    assert np.max(ratios) <= 1 + 1e-6


def test_swing_placement_carries_each_swing_foot_to_its_landing_point(g1):
    """The swing feet's xy velocity references integrate, over the swing left, to Raibert's landing point
    (under the hip at touch-down, v T_st / 2 ahead, capture-point feedback); stance nodes stay free."""
    from wbmpc.control.foot_placement import SwingPlacement

    placement = SwingPlacement(g1)
    gait = make_gait("walk", 2, leg_length_m=0.65)
    swing_s, stance_s = (1 - gait.duty_factor) * gait.period_s, gait.duty_factor * gait.period_s
    lift_off, touch_down = 0.2 * gait.period_s, 0.5 * gait.period_s  # the left foot's first swing
    command, measured = np.array([0.3, 0.0, 0.0]), np.array([0.2, 0.1, 0.0])
    q = g1.q_nominal.copy()
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    feet = np.array([data.oMf[g1.frame_id(g1.contact_frame(f))].translation for f in g1.feet])
    for t in (0.0, lift_off + 0.3 * swing_s):  # before lift-off (from the planted foot) and mid-swing
        start = feet[0, :2] + (0.05 if t > lift_off else 0.0)
        feet_now = feet.copy()
        feet_now[0, :2] = start
        times = np.linspace(0.0, touch_down - t, 20001)[:-1]
        v_ref = placement.velocities(gait, t, times, q, measured, command, 0.0, feet_now)
        assert np.all(np.isnan(v_ref[:, 1]))  # the right foot stands throughout
        swinging = np.isfinite(v_ref[:, 0, 0])
        assert np.all(swinging[t + times > lift_off + 1e-9]) and not np.any(swinging[t + times < lift_off - 1e-9])
        landed = start + np.trapezoid(np.nan_to_num(v_ref[:, 0]), times, axis=0)
        capture = (measured[:2] - command[:2]) * np.sqrt(g1.q_nominal[2] / 9.81)
        target = q[:2] + (touch_down - t) * command[:2] + feet[0, :2] - q[:2] + command[:2] * stance_s / 2 + capture
        np.testing.assert_allclose(landed, target, atol=2e-3)
    # the OCP's swing rows take the references (both feet swing within this horizon), stance rows stay zero
    problem = OcpProblem(g1)
    times = 0.3 + problem.config.grid.node_times_s
    contact = gait.contact(times)
    swing_vz = SwingProfile().vertical_velocity(gait.swing_phase(times), gait.swing_duration_s)
    vxy = placement.velocities(gait, 0.3, problem.config.grid.node_times_s, q, measured, command, 0.0, feet)
    bounds = StageBounds(v0=np.zeros(g1.nv), q_ref=q, contact=contact, swing_vz_m_s=swing_vz, swing_vxy_m_s=vxy)
    lbg, ubg = problem.bounds(bounds)[2:]
    nodes = problem.row_nodes["foot_vel"]
    rows = problem.rows["foot_vel"].reshape(len(nodes), 2, 3)[..., :2]
    swing = contact[nodes] == 0
    assert swing[:, 0].any() and swing[:, 1].any()
    placed = swing[..., None] & np.isfinite(vxy[nodes])
    np.testing.assert_allclose(lbg[rows[placed]], vxy[nodes][placed])
    np.testing.assert_allclose(ubg[rows[placed]], vxy[nodes][placed])
    assert np.all(lbg[rows[~swing]] == 0.0) and np.all(ubg[rows[~swing]] == 0.0)


def test_swing_placement_turns_each_sole_to_its_landing_heading_and_steps_with_the_turn(g1):
    """Turning: the swing soles' yaw rates integrate over the swing left to the heading at touch-down plus half a
    stance of turn (the sole's measured heading wound back by 0.4 rad, as a turn in place left g1's soles without
    them); the landing point is under the hip turned to the touch-down heading, v_hip T_st / 2 ahead with
    v_hip = omega x r_hip; the OCP's swing soles keep within a band of the yaw rates, stance soles stay still."""
    from wbmpc.control.foot_placement import SwingPlacement

    placement = SwingPlacement(g1)
    gait = make_gait("walk", 2, leg_length_m=0.65)
    swing_s, stance_s = (1 - gait.duty_factor) * gait.period_s, gait.duty_factor * gait.period_s
    lift_off, touch_down = 0.2 * gait.period_s, 0.5 * gait.period_s  # the left foot's first swing
    yaw, yaw_rate = 0.3, 0.6
    q = g1.q_nominal.copy()
    q[3:7] = (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    feet = np.array([data.oMf[g1.frame_id(g1.contact_frame(f))].translation for f in g1.feet])
    nominal = g1.q_nominal.copy()
    nominal[3:7] = (0.0, 0.0, 0.0, 1.0)
    pin.framesForwardKinematics(g1.model, data, nominal)
    r_hip = data.oMf[g1.frame_id(g1.contact_frame(g1.feet[0]))].translation[:2] - nominal[:2]
    t = lift_off + 0.3 * swing_s
    times = np.linspace(0.0, touch_down - t, 20001)[:-1]
    feet_yaw = np.array([yaw - 0.4, yaw])
    rates = placement.yaw_rates(gait, t, times, yaw, yaw_rate, feet_yaw)
    assert np.all(np.isnan(rates[:, 1])) and np.all(np.isfinite(rates[:, 0]))  # the right foot stands throughout
    turned = feet_yaw[0] + np.trapezoid(rates[:, 0], times)
    assert turned == pytest.approx(yaw + yaw_rate * ((touch_down - t) + stance_s / 2), abs=2e-3)
    command = np.zeros(3)
    v_ref = placement.velocities(gait, t, times, q, command, command, yaw, feet, yaw_rate)
    landed = feet[0, :2] + np.trapezoid(v_ref[:, 0], times, axis=0)
    psi = yaw + yaw_rate * (touch_down - t)
    lever = np.array([[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]]) @ r_hip
    target = q[:2] + lever + yaw_rate * np.array([-lever[1], lever[0]]) * stance_s / 2
    np.testing.assert_allclose(landed, target, atol=2e-3)
    # the OCP: swing soles' yaw rows equal the references, stance soles' zero
    problem = OcpProblem(g1)
    times = t + problem.config.grid.node_times_s
    contact = gait.contact(times)
    rates = placement.yaw_rates(gait, t, problem.config.grid.node_times_s, yaw, yaw_rate, feet_yaw)
    bounds = StageBounds(v0=np.zeros(g1.nv), q_ref=q, contact=contact,
                         swing_vz_m_s=SwingProfile().vertical_velocity(gait.swing_phase(times), gait.swing_duration_s),
                         swing_yaw_rate_rad_s=rates)
    lbg, ubg = problem.bounds(bounds)[2:]
    nodes = problem.row_nodes["foot_ang"]
    yaw_rows = problem.rows["foot_ang"].reshape(len(nodes), 2, 3)[..., 2]
    swing = contact[nodes] == 0
    turned = swing & np.isfinite(rates[nodes])
    assert turned[:, 0].any() and turned[:, 1].any()
    np.testing.assert_allclose(lbg[yaw_rows[turned]], rates[nodes][turned] - SWING_YAW_RATE_BAND_RAD_S)
    np.testing.assert_allclose(ubg[yaw_rows[turned]], rates[nodes][turned] + SWING_YAW_RATE_BAND_RAD_S)
    assert np.all(lbg[yaw_rows[~swing]] == 0.0) and np.all(ubg[yaw_rows[~swing]] == 0.0)


def test_centroidal_wrench_includes_sole_moments(g1, rng):
    """hdot from the contact wrenches equals pinocchio's total external wrench about the CoM plus gravity."""
    dyn = SymbolicDynamics(g1)
    q, f = ca.SX.sym("q", g1.nq), ca.SX.sym("f", dyn.n_forces)
    wrench = ca.Function("w", [q, f], [dyn.centroidal_wrench(dyn.configuration(q), f)])
    qs, forces = g1.random_configuration(rng), rng.normal(size=dyn.n_forces) * 50
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, qs)
    com = pin.centerOfMass(g1.model, data, qs)
    total = pin.Force.Zero()
    for j, force in enumerate(_pinocchio_fext(g1, qs, forces)):
        total += data.oMi[j].act(force)  # world frame, about the origin
    expected_lin = total.linear + g1.mass_kg * g1.model.gravity.linear
    expected_ang = total.angular - np.cross(com, total.linear)
    np.testing.assert_allclose(np.array(wrench(qs, forces)).ravel(), np.r_[expected_lin, expected_ang], atol=1e-9 * 1e3)


def test_sole_from_urdf_collision_box(tmp_path):
    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    robot = RobotModel(RobotSpec(name="biped", urdf=urdf, feet=("l_foot", "r_foot"), foot_contact="surface"))
    sole = robot.soles["l_foot"]
    assert (sole.length_m, sole.width_m) == pytest.approx((0.22, 0.1))
    np.testing.assert_allclose(sole.centre_m, [0.03, 0.0, -0.05])  # box centre x, bottom face z
    assert robot.summary()["contacts"] == {"l_foot": "surface", "r_foot": "surface"}
    # the nominal pose puts the soles on the ground
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q_nominal)
    assert data.oMf[robot.frame_id("l_foot_sole")].translation[2] == pytest.approx(0.0, abs=1e-12)


def test_foot_without_collision_geometry_names_the_link_and_option(tmp_path):
    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=False))
    with pytest.raises(ModelError, match=r"'l_foot'.*--sole"):
        RobotModel(RobotSpec(name="biped", urdf=urdf, feet=("l_foot", "r_foot"), foot_contact="surface"))
    robot = RobotModel(RobotSpec(name="biped", urdf=urdf, feet=("l_foot", "r_foot"), foot_contact="surface",
                                 sole_m=(0.2, 0.08)))
    assert robot.soles["r_foot"].length_m == 0.2


def test_standing_humanoid_wrenches_satisfy_the_cone_and_carry_its_weight(g1):
    mpc = MPC(g1, MpcConfig(gait="stand"))
    solution = mpc.solve(g1.q_nominal, np.zeros(g1.nv), Commands(), 0.0)
    assert solution.success
    dyn, mu = mpc.problem.dyn, mpc.config.friction_coefficient
    for forces in solution.forces:
        lin = forces[: dyn.n_linear_forces].reshape(-1, 3)
        for i, foot in enumerate(g1.feet):
            sole = g1.soles[foot]
            fx, fy, fz = lin[i]
            tx, ty, tz = forces[dyn.moment_slice(i)]
            tol = 1e-6 * g1.mass_kg * GRAVITY_M_S2
            assert fz >= -tol
            assert abs(fx) <= mu * fz + tol and abs(fy) <= mu * fz + tol
            assert abs(tx) <= sole.half_width_m * fz + tol and abs(ty) <= sole.half_length_m * fz + tol  # CoP in sole
            assert abs(tz) <= mu * min(sole.half_length_m, sole.half_width_m) * fz + tol
    # near rest the vertical forces of the soles (and the unloaded hand) carry the weight
    lin0 = solution.forces[0][: dyn.n_linear_forces].reshape(-1, 3)
    assert lin0[:, 2].sum() == pytest.approx(g1.mass_kg * GRAVITY_M_S2, rel=0.02)
    assert mpc.problem.rows["wrench_cone"].shape == (mpc.problem.N, 2 * WRENCH_CONE_ROWS)


def test_biped_walk_has_double_support_phases_on_the_time_grid():
    period, share = biped_walk_timing(0.78)
    gait = make_gait("walk", 2, leg_length_m=0.78)
    assert gait.period_s == pytest.approx(period)
    times = np.linspace(0, 2 * period, 4001)[:-1]
    contact = gait.contact(times)
    assert contact.sum(axis=1).min() == 1  # never both feet in the air
    both = contact.sum(axis=1) == 2
    assert both.mean() == pytest.approx(share, abs=2e-3)
    # two double-support phases per period, each share/2 long, the first one at t = 0
    phase = np.mod(times / period, 1.0)
    expected = (phase < share / 2) | ((phase >= 0.5) & (phase < 0.5 + share / 2))
    assert np.mean(both == expected) > 0.998
    swing = 1 - contact
    assert swing[:, 0].mean() == pytest.approx((1 - share) / 2, abs=2e-3)


def test_a_biped_asked_to_trot_is_told_its_gaits(g1):
    with pytest.raises(ConfigError, match="stand, walk"):
        make_gait("trot", 2)
    with pytest.raises(ConfigError, match="its gaits: stand, walk"):
        make_scenario("trot-in-place", g1)
    assert make_scenario("walk-in-place", g1).gait == "walk"
    assert make_scenario("walk-in-place", load_robot("b1_z1")).gait == "trot"
    assert make_scenario("push", g1, ScenarioOptions(gait="stand")).gait == "stand"


def test_mujoco_soles_touch_with_the_measured_cop_inside(g1):
    from wbmpc.sim.mujoco_plant import MujocoPlant

    plant = MujocoPlant(g1)
    plant.reset(g1.q_nominal, np.zeros(g1.nv))
    kp, kd = 300.0, 10.0
    q_ref = g1.joint_positions(g1.q_nominal)
    for _ in range(250):  # 0.5 s holding the nominal pose with a stiff joint PD
        q, v = plant.state()
        plant.step(kp * (q_ref - g1.joint_positions(q)) - kd * v[6:])
    pressure = plant.sole_pressure()
    total = 0.0
    for foot, measured in pressure.items():
        assert measured is not None, f"{foot} does not touch the floor"
        cop, normal = measured
        sole = g1.soles[foot]
        assert abs(cop[0]) <= sole.half_length_m and abs(cop[1]) <= sole.half_width_m
        total += normal
    assert total == pytest.approx(g1.mass_kg * GRAVITY_M_S2, rel=0.05)


def test_short_standing_run_keeps_the_cop_inside_the_soles(g1):
    from wbmpc.scenarios.runner import RunConfig, run_scenario

    result = run_scenario(g1, RunConfig(scenario="stand", duration_s=0.4))
    metrics = result.metrics
    assert not metrics["fell"] and metrics["mpc_failures"] == 0
    assert metrics["cop_outside_sole_ticks"] == 0 and metrics["cop_checked_ticks"] > 0


def _biped_urdf(with_box: bool) -> str:
    inertial = ('<inertial><origin xyz="0 0 0"/><mass value="{m}"/>'
                '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>')
    box = ('<collision><origin xyz="0.03 0 -0.04"/><geometry><box size="0.22 0.1 0.02"/></geometry></collision>'
           if with_box else "")
    legs = ""
    for side, y in (("l", 0.1), ("r", -0.1)):
        legs += f"""
  <link name="{side}_thigh">{inertial.format(m=2.0)}</link>
  <joint name="{side}_hip" type="revolute"><parent link="base"/><child link="{side}_thigh"/>
    <origin xyz="0 {y} -0.1"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="100" velocity="10"/></joint>
  <link name="{side}_foot">{inertial.format(m=0.5)}{box}</link>
  <joint name="{side}_knee" type="revolute"><parent link="{side}_thigh"/><child link="{side}_foot"/>
    <origin xyz="0 0 -0.5"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="100" velocity="10"/></joint>"""
    return f'<robot name="biped"><link name="base">{inertial.format(m=10.0)}</link>{legs}\n</robot>'


def test_biped_settings_are_derived_with_the_biped_rules_and_say_so(g1):
    from wbmpc.control.biped import BIPED_BASE_LINEAR_VELOCITY_WEIGHT, BIPED_SOURCE
    from wbmpc.control.tuning import ANCHOR_WITHOUT_ARM, REFERENCE, RobotScale, derive, tuning_for

    scale = RobotScale.of(g1)
    assert scale.feet == 2
    tuning = tuning_for(g1)
    report = tuning.report()
    period, share = biped_walk_timing(scale.leg_length_m)
    assert tuning.gait_period_s == pytest.approx(period) and 0.9 < period < 1.2  # g1: 1.03 s
    assert tuning_for(g1).support_sway_free_ee == 0.0  # g1 leans only while a hand is held
    assert tuning.support_lead_s == pytest.approx(0.5 * period * share)
    assert tuning.free_ee_without_command and tuning.support_sway > 0
    assert tuning.swing_placement
    assert tuning_for(load_robot("talos")).report()["weights.joint_torque"] == {"value": 1e-5, "source": "table"}
    for name in ("gait_period_s", "support_sway", "weights.contact_force", "weights.base_position", "swing_placement"):
        assert report[name]["source"] == BIPED_SOURCE
    talos = tuning_for(load_robot("talos"))
    assert talos.weights.base_linear_velocity == BIPED_BASE_LINEAR_VELOCITY_WEIGHT and talos.for_task(True) is talos
    # g1's pelvis carries the commanded velocity while its hands are free (its table, control/tuning.py) ...
    assert report["weights.base_linear_velocity"] == {"value": 1000.0, "source": "table"}
    assert tuning.weights.base_linear_velocity > 10 * derive(dataclasses.replace(scale, feet=4)).weights.base_linear_velocity
    # ... not while a hand is held: tasks that command the hand keep the biped rule's weight, and their runs say so
    held = tuning.for_task(commands_ee=True)
    assert held.weights.base_linear_velocity == BIPED_BASE_LINEAR_VELOCITY_WEIGHT
    assert held.report()["weights.base_linear_velocity"]["source"] == "table"
    assert dataclasses.replace(held, sources={}) == dataclasses.replace(
        tuning, weights=dataclasses.replace(tuning.weights, base_linear_velocity=BIPED_BASE_LINEAR_VELOCITY_WEIGHT),
        sources={})
    from wbmpc.scenarios.runner import RunConfig, mpc_config_for

    for scenario, weight in (("arm-track", BIPED_BASE_LINEAR_VELOCITY_WEIGHT), ("walk-forward", 1000.0)):
        config = RunConfig(scenario=scenario)
        assert mpc_config_for(make_scenario(scenario, g1, config.options), config, g1).weights.base_linear_velocity == weight
    assert report["gains.kd_leg"]["source"] == "derived"
    # free hands hold no trunk: the anchor of a robot without an arm, scaled by the leg as on quadrupeds
    s = scale.leg_length_m / REFERENCE.leg_length_m
    assert tuning.weights.base_position[0] == pytest.approx(ANCHOR_WITHOUT_ARM * 500.0 / s**2)
    # the same robot counted as four-footed gets none of it
    quadruped = derive(dataclasses.replace(scale, feet=4))
    assert quadruped.support_sway == 0.0 and not quadruped.free_ee_without_command and not quadruped.swing_placement
    assert set(entry["source"] for entry in quadruped.report().values()) == {"derived"}
    assert quadruped.for_task(commands_ee=True) is quadruped


def test_g1_rotor_inertias_reach_the_plant(g1):
    """The preset's rotor inertias (Unitree's MJCF) are the MuJoCo plant's joint armature by default."""
    from wbmpc.scenarios.runner import RunConfig, run_scenario

    assert g1.armature_kg_m2.min() > 0.003
    result = run_scenario(g1, RunConfig(scenario="stand", duration_s=0.05))
    model = result.plant.model  # MuJoCo model
    import mujoco

    for name, value in zip(g1.joint_names, g1.armature_kg_m2):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert model.dof_armature[model.jnt_dofadr[jid]] == pytest.approx(value)


def test_plants_made_without_a_config_get_the_robots_rotor_inertias(g1):
    """`make_plant` (bench mpc's plants) as the runner: without them the pinocchio plant's lifted ankle roll
    of g1 reached 110 rad/s within 0.25 s of walking (an explicit damper unstable at the 1 ms tick)."""
    from wbmpc.sim import PlantConfig, make_plant

    plant = make_plant("pinocchio", g1)
    assert plant.model.armature[6:] == pytest.approx(g1.armature_kg_m2)
    mass = pin.crba(plant.model, plant.model.createData(), g1.q_nominal)
    bare = pin.crba(g1.model, g1.model.createData(), g1.q_nominal) - np.diag(np.r_[np.zeros(6), g1.armature_kg_m2])
    assert np.diag(mass)[6:] - np.diag(bare)[6:] == pytest.approx(g1.armature_kg_m2)  # the inertia the plant integrates
    assert not np.any(make_plant("pinocchio", g1, PlantConfig()).model.armature)  # a config given is the plant's own


def test_walk_velocity_error_splits_into_forward_and_lateral():
    """The walk's per-tick velocity error along and across the start's heading; squares add up to the planar one."""
    from wbmpc.scenarios.locomotion import forward_lateral_rmse

    t = np.linspace(0.0, 4.0, 2001)
    heading = np.array([np.cos(0.5), np.sin(0.5)])  # started facing 0.5 rad
    across = np.array([-heading[1], heading[0]])
    command = 0.3 * heading
    velocity = command + np.outer(0.02 * np.ones_like(t), heading) + np.outer(0.1 * np.sin(2 * np.pi * t), across)
    out = forward_lateral_rmse(velocity, command, yaw=0.5)
    assert out["base_vel_rmse_settled_forward"] == pytest.approx(0.02)
    assert out["base_vel_rmse_settled_lateral"] == pytest.approx(0.1 / np.sqrt(2), rel=1e-3)
    planar = np.sqrt(np.mean(np.sum((velocity - command) ** 2, axis=1)))
    assert np.hypot(out["base_vel_rmse_settled_forward"], out["base_vel_rmse_settled_lateral"]) == pytest.approx(planar)


def test_walk_com_velocity_error_follows_the_whole_bodys_centre_of_mass(g1, rng):
    """The CoM's per-tick velocity error: with the joints still the CoM moves with the base (a translation);
    a joint motion alone moves it by pinocchio's CoM Jacobian, the base frame standing still."""
    from wbmpc.scenarios.locomotion import com_forward_lateral_rmse

    n, yaw = 200, 0.3
    q = np.tile(g1.q_nominal, (n, 1))
    q[:, 3:7] = (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
    heading = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    v = np.zeros((n, g1.nv))
    along, across = 0.3 + 0.05 * rng.standard_normal(n), 0.1 * rng.standard_normal(n)
    v[:, :2] = np.column_stack([along, across])  # base frame = the start's heading frame
    command = heading @ np.array([0.3, 0.0])
    out = com_forward_lateral_rmse(g1, q, v, command, yaw)
    assert out["com_vel_rmse_settled_forward"] == pytest.approx(np.sqrt(np.mean((along - 0.3) ** 2)))
    assert out["com_vel_rmse_settled_lateral"] == pytest.approx(np.sqrt(np.mean(across**2)))
    joint = np.zeros((1, g1.nv))
    joint[0, 6:] = rng.standard_normal(g1.nv - 6)
    expected = (pin.jacobianCenterOfMass(g1.model, g1.model.createData(), q[0]) @ joint[0])[:2] @ heading
    out = com_forward_lateral_rmse(g1, q[:1], joint, np.zeros(2), yaw)
    assert out["com_vel_rmse_settled_forward"] == pytest.approx(abs(expected[0]))
    assert out["com_vel_rmse_settled_lateral"] == pytest.approx(abs(expected[1]))


@pytest.mark.slow
def test_g1_walks_forward_at_the_commanded_speed_per_tick():
    """Issue 19's walk-forward: the base's per-tick velocity error after 2 s within 0.05 m/s (6 s of the 10 s run,
    compiled Fatrop; 10 s measured 0.020 m/s), the CoP inside the soles."""
    from wbmpc.scenarios.runner import RunConfig, run_scenario

    metrics = run_scenario(load_robot("g1"), RunConfig(scenario="walk-forward", duration_s=6.0, compiled=True)).metrics
    assert not metrics["fell"] and metrics["cop_outside_sole_ticks"] == 0
    assert metrics["base_vel_rmse_settled"] <= 0.05
    assert metrics["com_vel_rmse_settled"] > metrics["base_vel_rmse_settled"]  # the CoM still sways over the soles


@pytest.mark.slow
@pytest.mark.parametrize("robot_name,scenario", [
    ("g1", "walk-in-place"),
    ("g1", "walk-forward"),  # swing placement: 10 s at 0.3 m/s up, 0 failed steps
    ("talos", "stand"),  # its torque weight (control/tuning.py): 10 s up, drift 0.02 cm/s
    ("talos", "walk-in-place"),  # 10 s up, 0 failed steps
])
def test_humanoids_stay_up_with_the_cop_inside_their_soles(robot_name, scenario):
    """Minutes-long: 4 s of the issue's 10 s runs (compiled Fatrop on g1; TALOS's generated C, 25 MB, took
    over 30 minutes to compile at -O1, so it runs Fatrop in CasADi's VM: 0.25 s a standing step)."""
    from wbmpc.scenarios.runner import RunConfig, run_scenario

    metrics = run_scenario(load_robot(robot_name), RunConfig(scenario=scenario, duration_s=4.0,
                                                             compiled=robot_name == "g1", solver="fatrop")).metrics
    assert not metrics["fell"]
    assert metrics["cop_outside_sole_ticks"] == 0


def test_pull_tipping_check_counts_the_soles(g1):
    """g1's 5 kg pull needs the CoP 5 cm ahead of its ankles: inside its soles (toes 10 cm ahead), so the
    scenario is accepted; a pull far beyond the soles is still refused with the CoP it would need."""
    from wbmpc.scenarios.arm_statics import support_points

    points = support_points(g1)
    assert points.shape == (8, 2) and points[:, 0].max() > 0.09  # two soles' corners
    make_scenario("pull", g1, ScenarioOptions(load_kg=5.0))
    with pytest.raises(ConfigError, match="tip the robot over"):
        make_scenario("pull", g1, ScenarioOptions(load_kg=5.0, force_n=60.0))


def test_real_time_sqp_on_flat_feet_holds_the_last_plan_after_a_failed_qp(g1):
    """With a plant that does not wait, a failed RTI/SQP step on flat feet holds the last good plan at once: no
    Fatrop re-solve (~200 ms on g1), no IPOPT fallback, no HPIPM balance-mode re-solve; point feet and runs whose
    plant waits keep them."""
    from wbmpc.scenarios.runner import RunConfig, mpc_config_for
    from wbmpc.solvers.qp import QpResult

    scenario = make_scenario("walk-in-place", g1)
    realtime = mpc_config_for(scenario, RunConfig(scenario="walk-in-place", solver="rti", delay_mode="realtime"), g1)
    options = realtime.solver.extra_options
    assert options["recovery_barrier_init"] is None and options["fallback_qp_mode"] is None
    assert realtime.recovery.fallback_solver is None
    for name, delay in (("g1", "none"), ("b1_z1", "realtime")):
        robot = g1 if name == "g1" else load_robot(name)
        other = mpc_config_for(make_scenario("walk-in-place", robot), RunConfig(scenario="walk-in-place", solver="rti",
                                                                                 delay_mode=delay), robot)
        assert "recovery_barrier_init" not in other.solver.extra_options and "fallback_qp_mode" not in \
            other.solver.extra_options
        assert other.recovery.fallback_solver == RecoveryConfig().fallback_solver
    sqp = mpc_config_for(scenario, RunConfig(scenario="walk-in-place", solver="sqp", delay_mode="measured"), g1)
    assert sqp.solver.extra_options["recovery_barrier_init"] is None and sqp.recovery.fallback_solver is None
    # the plan: solved once, then a QP that fails (its iteration cap) leaves the last plan shifted, finite
    mpc = MPC(g1, realtime)
    mpc.prepare_fallback()
    assert mpc.solver.recovery_solver is None and mpc.solver.fallback_qp is None and not mpc.recovery.built()
    first = mpc.solve(g1.q_nominal, np.zeros(g1.nv), t_s=0.0)
    assert first.success, first.stats.status
    n = mpc.problem.n_variables
    mpc.solver.qp.solve = lambda *data: QpResult(step=np.full(n, np.nan), lam_g=np.zeros(mpc.problem.n_constraints),
                                                lam_x=np.zeros(n), status="QP_Maximum_Iterations_Exceeded",
                                                success=False, iterations=30, solve_time_s=0.03)
    held = mpc.solve(g1.q_nominal, np.zeros(g1.nv), t_s=0.0125)
    assert not held.success and held.held_previous
    assert held.stats.status.startswith("QP_Maximum_Iterations_Exceeded; holding the last good plan")
    assert all(np.all(np.isfinite(part)) for part in (held.q, held.v, held.a, held.forces, held.tau))
    assert mpc.solver.recovery_solver is None and not mpc.recovery.built()  # nothing was built or run to rescue it


def test_delay_compensation_is_on_by_default_with_a_delay_on_every_robot(g1):
    """Plans from the state predicted with the motor law (control/delay.py) keep g1's arms still: flat feet
    compensate any delay as point feet do; none without a delay; an explicit choice wins."""
    from wbmpc.scenarios.runner import RunConfig, mpc_config_for

    def compensation(robot, **fields):
        config = RunConfig(scenario="walk-in-place", solver="rti", **fields)
        return mpc_config_for(make_scenario("walk-in-place", robot), config, robot).delay_compensation

    b1_z1 = load_robot("b1_z1")
    assert compensation(g1, delay_mode="realtime") and compensation(g1, delay_ms=12.0)
    assert not compensation(g1, delay_mode="realtime", delay_compensation=False)
    assert compensation(b1_z1, delay_mode="realtime") and compensation(b1_z1, delay_mode="measured")
    assert not compensation(b1_z1, delay_mode="none") and not compensation(g1, delay_mode="none")
