"""The manipulated object inside the MPC (issue 22 part 2, `wbmpc.ocp.objects`): the box model's plan against a
MuJoCo box sliding under the planned force, the plan's rows recomputed independently in NumPy, a short
closed loop, and bad input."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from wbmpc.control import MPC, Commands
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.objects import ObjectCommand, SlidingBox
from wbmpc.robots import GRAVITY_M_S2
from wbmpc.scenarios import RunConfig, ScenarioOptions, make_scenario, run_scenario
from wbmpc.scenarios.runner import mpc_config_for
from wbmpc.sim.objects import FreeBox

SPEED_M_S = 0.1


@pytest.fixture(scope="module")
def box_plan(b1z1):
    """One converged plan (IPOPT, 12 uniform 40 ms steps) of push-box --object-model from the nominal stance, the box
    already sliding at SPEED_M_S with the hand on its face, its path straight ahead at that speed."""
    robot = b1z1
    options = ScenarioOptions(object_model=True)
    scenario = make_scenario("push-box", robot, options)
    config = mpc_config_for(scenario, RunConfig(scenario="push-box", options=options, solver="ipopt"), robot)
    grid = TimeGrid.uniform_steps(12, 0.04)
    config = dataclasses.replace(config, ocp=dataclasses.replace(config.ocp, grid=grid),
                                 solver=dataclasses.replace(config.solver, max_iterations=300))
    mpc = MPC(robot, config)
    model: SlidingBox = config.ocp.object_model
    hand = robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]
    start = np.array([hand[0] + model.hand_radius_m + model.size_m[0] / 2, hand[1], 0.0, SPEED_M_S, 0.0, 0.0])

    def reference(times):
        times = np.asarray(times, dtype=float)
        return np.column_stack([start[0] + SPEED_M_S * times, np.zeros((len(times), 2)),
                                np.full(len(times), SPEED_M_S), np.zeros((len(times), 2))])

    solution = mpc.solve(robot.q_nominal, np.zeros(robot.nv), Commands(object_command=ObjectCommand(start, reference)))
    assert solution.success, solution.stats.status
    parts = mpc.problem.unpack(solution.x)
    hands = robot.frame_trajectories(solution.q, [robot.arm_ee])[robot.arm_ee]
    nf = 3 * len(robot.feet)
    return {"model": model, "grid": grid, "obj": parts["obj"], "obj_u": parts["obj_u"], "hands": hands,
            "push": -solution.forces[:, nf : nf + 3], "problem": mpc.problem}


def _mujoco_box(model: SlidingBox) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The scene's box alone on the floor (the same MJCF as `FreeBox` and the plant's floor and options)."""
    box = FreeBox(near_face_x_m=0.0, mass_kg=model.mass_kg, friction_mu=model.friction_mu, size_m=model.size_m)
    xml = ('<mujoco><option timestep="0.001" integrator="implicitfast" cone="elliptic"/><worldbody>'
           '<geom name="floor" type="plane" size="0 0 0.05" priority="1"/>' + box.bodies_mjcf(None)[0] +
           "</worldbody></mujoco>")
    m = mujoco.MjModel.from_xml_string(xml)
    return m, mujoco.MjData(m)


def test_box_plan_reproduces_a_mujoco_box_sliding_under_the_planned_force(box_plan):
    """The planned hand force (zero-order hold per interval, at the planned hand position) applied to a free MuJoCo box
    moves it as the plan says: within 1 cm and 2 degrees over the 0.48 s horizon (the plan's friction is smoothed
    Coulomb, MuJoCo's a soft elliptic cone)."""
    model, obj = box_plan["model"], box_plan["obj"]
    m, d = _mujoco_box(model)
    mujoco.mj_resetData(m, d)
    d.qpos[:3] = [obj[0, 0], obj[0, 1], model.size_m[2] / 2]
    d.qvel[:2] = obj[0, 3:5]
    for _ in range(200):  # settle on the floor at the initial speed (contacts made), then restart from the plan's state
        mujoco.mj_step(m, d)
        d.qvel[:2] = obj[0, 3:5]
        d.qpos[:2] = obj[0, :2]
    body = m.body("box").id
    dt = box_plan["grid"].dt_s
    reached = [obj[0, :3].copy()]
    for k, step in enumerate(dt):
        push = box_plan["push"][k]
        lever = box_plan["hands"][k] - d.xipos[body]
        d.xfrc_applied[body, :3] = [push[0], push[1], 0.0]
        d.xfrc_applied[body, 3:] = [0.0, 0.0, lever[0] * push[1] - lever[1] * push[0]]
        for _ in range(round(step / m.opt.timestep)):
            mujoco.mj_step(m, d)
        rot = d.xmat[body].reshape(3, 3)
        reached.append([d.xpos[body][0], d.xpos[body][1], np.arctan2(rot[1, 0], rot[0, 0])])
    reached = np.array(reached)
    assert np.linalg.norm(obj[-1, :2] - obj[0, :2]) > 0.03  # the box slides in the plan
    assert np.abs(reached[:, :2] - obj[:, :2]).max() < 0.01
    assert np.degrees(np.abs(reached[:, 2] - obj[:, 2]).max()) < 2.0


def test_box_plan_rows_hold_recomputed_in_numpy(box_plan):
    """Residuals of the plan recomputed without CasADi: Newton-Euler of the box with Coulomb friction smoothed at its
    four corners (with `push_shifts_loads`, loads shifted by the push's tipping moment), the hand force in the face's friction pyramid, the hand on
    the face within its width."""
    model, obj, u, push, hands = (box_plan[k] for k in ("model", "obj", "obj_u", "push", "hands"))
    dt = box_plan["grid"].dt_s
    weight = model.mass_kg * GRAVITY_M_S2
    inertia = model.mass_kg * (model.size_m[0] ** 2 + model.size_m[1] ** 2) / 12
    for k in range(len(dt)):
        yaw = obj[k, 2]
        rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        force, moment = push[k, :2].copy(), 0.0
        lever = hands[k, :2] - obj[k, :2]
        moment += lever[0] * push[k, 1] - lever[1] * push[k, 0]
        local_push = rot.T @ push[k, :2]
        sx, sy = model.size_m[:2]
        for corner in model.corners_m():
            r = rot @ corner
            a, b = np.sign(corner)  # the push's tipping moment shifts the load towards the far corners
            load = weight / 4 + (hands[k, 2] / 2 * (a * local_push[0] / sx + b * local_push[1] / sy)
                                 if model.push_shifts_loads else 0.0)
            sliding = u[k, :2] + u[k, 2] * np.array([-r[1], r[0]])
            f = -model.friction_mu * load * sliding / np.sqrt(sliding @ sliding + model.smoothing_m_s**2)
            force += f
            moment += r[0] * f[1] - r[1] * f[0]
        assert np.allclose(model.mass_kg * (u[k, :2] - obj[k, 3:5]) / dt[k], force, atol=1e-3 * weight)
        assert abs(inertia * (u[k, 2] - obj[k, 5]) / dt[k] - moment) < 1e-3 * weight
        assert np.allclose(obj[k + 1], np.concatenate([obj[k, :3] + dt[k] * u[k], u[k]]), atol=1e-6)  # transition
        normal, tangential = rot.T @ push[k, :2]
        assert normal >= -1e-4 * weight and abs(tangential) <= model.cone_share * model.friction_mu * normal + 1e-4 * weight
        assert abs(push[k, 2]) < 1e-9  # no vertical force
    for k in range(2, len(obj)):  # nodes 2..N: the hand sphere on the face (within the band), within its width
        yaw = obj[k, 2]
        local = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]]) @ (hands[k, :2] - obj[k, :2])
        assert abs(local[0] + model.size_m[0] / 2 + model.hand_radius_m) < 2.5e-3
        assert abs(local[1]) <= model.size_m[1] / 2 - model.face_margin_m + 1e-4


def test_python_api_picks_the_clis_solver_with_an_object_model(b1z1):
    """RunConfig's default solver (None) and --solver auto decide in one place (`runner.default_solver`): the anytime
    SQP with an object model (Fatrop's line search fails on the contact rows), casadi's Fatrop otherwise; a solver
    named is kept."""
    options = ScenarioOptions(object_model=True)
    config = RunConfig(scenario="push-box", options=options)
    assert config.solver == "sqp" and config.for_robot(b1z1).solver == "sqp"
    assert RunConfig(scenario="push-box", options=options, solver="auto", compiled=True).solver == "sqp"
    assert RunConfig(scenario="pull", options=ScenarioOptions(object_model=True)).solver == "sqp"
    assert RunConfig(scenario="push-box").solver == "fatrop"
    assert RunConfig(scenario="arm-track", collision_avoidance=True).solver == "sqp"  # as --collision-avoidance
    assert RunConfig(scenario="push-box", compiled=True, solver="auto").solver == "fatrop-direct"
    named = RunConfig(scenario="push-box", options=options, solver="ipopt")
    assert named.solver == "ipopt" and named.for_robot(b1z1).solver == "ipopt"


def test_push_box_object_model_stays_up_and_moves_the_box(b1z1):
    # RunConfig's default solver: the anytime SQP with an object model, as `wbmpc run --object-model` picks
    result = run_scenario(b1z1, RunConfig(scenario="push-box", duration_s=1.6, options=ScenarioOptions(object_model=True)))
    assert result.metrics["solver"] == "sqp"
    m = result.metrics
    assert not m["fell"] and m["object_model"]
    assert m["box_pos_rmse_m"] is not None and m["box_pos_rmse_m"] < 0.03
    assert m["box_travel_m"] > 0.01  # the path started at 1 s: the box moved with it
    # the hand's sprung pad keeps the contact closed: on the box most of the time once it pushes (the rigid sphere: 60 %)
    t, force = result.scene.recording.series("box", "force_n")
    pushing = t > 1.2
    assert np.mean(np.linalg.norm(force[pushing], axis=1) > 0.5) > 0.8


def test_object_model_is_read_from_the_scene(b1z1):
    """One source of truth: the OCP's box is the scene's (mass from --box-kg, friction and size from FreeBox)."""
    scenario = make_scenario("push-box", b1z1, ScenarioOptions(object_model=True, box_kg=7.0))
    box = scenario.free_box(b1z1)
    model = scenario.object_model(b1z1)
    assert (model.mass_kg, model.friction_mu, model.size_m) == (7.0, box.friction_mu, tuple(box.size_m))
    # the hand's pad: the push that slides the box compresses it by half the OCP's contact tolerance
    from wbmpc.ocp.objects import CONTACT_TOLERANCE_M

    pad = scenario.push_pad(b1z1)
    push_n = box.friction_mu * 7.0 * GRAVITY_M_S2
    assert abs(push_n / pad.stiffness_n_m - 0.5 * CONTACT_TOLERANCE_M) < 1e-12
    assert any(obj is not box and type(obj).__name__ == "CompliantPad" for obj in scenario.scene(b1z1).objects)
    assert model.push_height_m is None
    # --push-height: the OCP's contact row, the crouch and the sideslip lead's pivot (mu h) follow it
    low = make_scenario("push-box", b1z1, ScenarioOptions(object_model=True, push_height_m=0.8))
    assert low.object_model(b1z1).push_height_m == 0.8 and low.base_height_m(b1z1) < b1z1.q_nominal[2]
    assert abs(low.push_pivot_m(b1z1) - box.friction_mu * 0.8) < 1e-12
    assert make_scenario("push-box", b1z1, ScenarioOptions(push_height_m=0.8)).push_height_m is None  # object model only
    # --box-turn-radius: the commanded path's turn, and the run long enough to finish it
    wide = make_scenario("push-box", b1z1, ScenarioOptions(object_model=True, box_turn_radius_m=1.5))
    assert wide.box_path(b1z1).radius_m == 1.5 and scenario.box_path(b1z1).radius_m == 0.8
    path = wide.box_path(b1z1)
    assert wide.default_duration_s >= path.start_s + path.moving_s > scenario.default_duration_s
    pull = make_scenario("pull", b1z1, ScenarioOptions(object_model=True, load_kg=14.0))
    load = pull.object_model(b1z1)
    assert load.mass_kg == 14.0 and load.cable_length_m == pull.options.cable_length_m


def test_object_model_on_a_scenario_without_an_object_names_those_with_one():
    with pytest.raises(ConfigError, match="push-box or pull"):
        RunConfig(scenario="trot-in-place", options=ScenarioOptions(object_model=True))


def test_cli_refuses_object_model_without_an_object():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "wbmpc", "run", "wipe", "--object-model"], capture_output=True, text=True)
    assert out.returncode == 2
    assert "push-box or pull" in out.stderr and "warning" not in out.stderr


def test_mpc_with_an_object_model_needs_the_object_command(box_plan, b1z1):
    from wbmpc.control.commands import object_reference

    with pytest.raises(ConfigError, match="object_command"):
        object_reference(box_plan["problem"].object, Commands().object_command, np.zeros(3))


@pytest.mark.slow
def test_pull_object_model_drags_the_load_at_the_commanded_speed(b1z1):
    result = run_scenario(b1z1, RunConfig(scenario="pull", duration_s=4.0, solver="sqp",
                                          options=ScenarioOptions(object_model=True, load_kg=14.0)))
    m = result.metrics
    assert not m["fell"] and m["pulled"]
    assert m["load_speed_rmse_m_s"] < 0.05


def test_sideslip_lead_puts_the_pivot_on_a_circle_tangent_to_the_heading():
    """The yaw lead of the box's reference (`object_paths.sideslip_lead`): none on the straights; on the arc the
    point `pivot_m` ahead of the centre, about which the pushed box turns without sliding sideways, moves along the
    box's heading (its velocity, from finite differences of the path, parallel to the led heading)."""
    from wbmpc.scenarios.object_paths import BoxPath, sideslip_lead

    path, pivot_m = BoxPath(), 0.26
    t = np.array([0.5, 1.5, path.start_s + path.moving_s + 1.0])
    assert np.allclose(sideslip_lead(path, t, pivot_m), 0.0)
    t = np.linspace(5.0, 8.0, 301)
    states = path.states(t)
    yaw = states[:, 2] + sideslip_lead(path, t, pivot_m)
    assert np.allclose(sideslip_lead(path, t, pivot_m), np.arcsin(pivot_m / path.radius_m))
    pivot = states[:, :2] + pivot_m * np.column_stack([np.cos(yaw), np.sin(yaw)])
    velocity = np.gradient(pivot, t, axis=0)[1:-1]
    heading = np.column_stack([np.cos(yaw), np.sin(yaw)])[1:-1]
    sideways = velocity[:, 0] * heading[:, 1] - velocity[:, 1] * heading[:, 0]
    assert np.max(np.abs(sideways)) < 1e-4 * path.speed_m_s and np.all(np.sum(velocity * heading, axis=1) > 0)


def test_a_mujoco_box_pushed_high_turns_about_the_pivot_of_the_lead():
    """The premise of `sideslip_lead`, in MuJoCo: a box pushed at the hand's height h (b1_z1's 0.87 m) off the centre
    of its near face, sliding at ~0.1 m/s and turning, slides sideways at its centre at w mu h (its floor load's
    centre mu h ahead of its centre does not slip sideways), where even corner loads would not slide it at all."""
    model = SlidingBox()
    m, d = _mujoco_box(model)
    mujoco.mj_resetData(m, d)
    d.qpos[:3] = [0.0, 0.0, model.size_m[2] / 2]
    height, weight = 0.87, model.weight_n
    body = m.body("box").id
    lateral, rate = [], []
    for k in range(6000):  # 6 s at 1 ms
        rot = d.xmat[body].reshape(3, 3)
        forward = rot[:, 0]
        speed = float(forward @ d.qvel[:3])
        push = (model.friction_mu * weight + 60.0 * (0.1 - speed)) * forward  # sliding at ~0.1 m/s
        point = d.xpos[body] + rot @ np.array([-model.size_m[0] / 2, -0.15, height - model.size_m[2] / 2])
        d.xfrc_applied[body, :3] = push
        d.xfrc_applied[body, 3:] = np.cross(point - d.xipos[body], push)
        mujoco.mj_step(m, d)
        if k >= 3000:
            lateral.append(float(rot[:, 1] @ d.qvel[:3]))
            rate.append(float(rot @ d.qvel[3:6] @ np.array([0.0, 0.0, 1.0])))
    w, v_lateral = float(np.mean(rate)), float(np.mean(lateral))
    assert w > 0.05  # it turns left (pushed right of the centre)
    expected = -w * model.friction_mu * height
    assert abs(v_lateral - expected) < 0.25 * abs(expected), (v_lateral, expected)


def test_push_height_rows_bring_the_hand_down_before_it_touches_the_face():
    """`SlidingBox.push_height_m`: the third contact row is the hand's height above it (numeric, at a hand placed by
    hand); a hand 30 cm above it must descend on a line that reaches the band by PUSH_HEIGHT_BLEND_TIME_S (the first
    node already below the measurement: a band left free would never move it) and keeps off the face with no force
    meanwhile; within PUSH_HEIGHT_APPROACH_M it closes the gap as without a push height."""
    from wbmpc.ocp.objects import PUSH_HEIGHT_APPROACH_M, PUSH_HEIGHT_BLEND_TIME_S, PUSH_HEIGHT_TOLERANCE_M

    model = SlidingBox(push_height_m=0.55)
    state = np.array([1.0, 0.2, np.pi / 2, 0.0, 0.0, 0.0])  # the near face at y = -0.1, facing -y
    hand = np.array([1.0, 0.2 - 0.3 - model.hand_radius_m - 0.05, 0.85])  # 5 cm off the face, 30 cm high
    rows = model.contact_values(state, hand)
    assert np.allclose(rows, [-0.05, 0.0, 0.30], atol=1e-12)
    times = np.array([0.0, 0.01, 0.1, PUSH_HEIGHT_BLEND_TIME_S, 0.8])
    lower, upper, may_push = model.contact_bounds(rows, times)
    assert not may_push.any()
    assert np.all(upper[:, 0] <= -0.01 + 2e-3 + 1e-12) and np.all(np.isinf(lower[:, 0]))
    assert upper[1, 2] < rows[2] and np.all(np.diff(upper[:, 2]) <= 0)
    assert np.allclose(upper[3:, 2], PUSH_HEIGHT_TOLERANCE_M) and np.allclose(lower[:, 2], -PUSH_HEIGHT_TOLERANCE_M)
    near = rows.copy()
    near[2] = 0.5 * PUSH_HEIGHT_APPROACH_M
    lower_near, upper_near, may_push_near = model.contact_bounds(near, times)
    reference_lower, reference_upper, reference_push = SlidingBox().contact_bounds(near[:2], times)
    assert np.allclose(lower_near[:, :2], reference_lower) and np.allclose(upper_near[:, :2], reference_upper)
    assert np.array_equal(may_push_near, reference_push)


def test_no_hand_force_is_planned_while_the_hand_is_still_off_the_face():
    """`contact_bounds`' may_push: a hand measured 5 cm off the box's face (gap row -0.05) closes the gap over
    CONTACT_BLEND_TIME_S; force only from the nodes whose gap target is within `force_gap_m` of contact (the
    first nodes none: a force there would push the box through air). A hand on the face may push on every node."""
    from wbmpc.ocp.objects import CONTACT_BLEND_TIME_S

    model = SlidingBox()
    times = np.linspace(0.0, 2.0 * CONTACT_BLEND_TIME_S, 9)
    _, _, may_push = model.contact_bounds(np.array([-0.05, 0.0]), times)
    target = np.clip(1.0 - times / CONTACT_BLEND_TIME_S, 0.0, 1.0) * -0.05
    assert not may_push[0] and may_push[-1]
    assert np.array_equal(may_push, target >= -model.force_gap_m)
    assert model.contact_bounds(np.array([0.0, 0.0]), times)[2].all()
    assert not model.cone_upper(may_push)[0].any() and np.isinf(model.cone_upper(may_push)[-1]).all()
