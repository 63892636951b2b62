"""Collision avoidance (issue 22): capsule distances against coal, the OCP rows keep the plan clear, a start
in collision is refused naming the pair, MuJoCo counts robot-robot contacts."""

from __future__ import annotations

from dataclasses import replace

import coal
import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import MPC, Commands
from wbmpc.errors import ConfigError
from wbmpc.robots import load_robot
from wbmpc.robots.collision_model import (
    CollisionConfig,
    CollisionError,
    CollisionModel,
    Obstacle,
    arm_workspace,
    random_configurations,
)
from wbmpc.symbolic import SymbolicDynamics
from wbmpc.symbolic.collision import collision_function


@pytest.fixture(scope="module")
def robot(b1z1):  # the session's B1 + Z1 (conftest)
    return b1z1


OBSTACLE = Obstacle("crate", (0.9, 0.3, 0.3), (0.15, 0.12, 0.1))


@pytest.fixture(scope="module")
def collision(robot):
    return CollisionModel(robot, CollisionConfig())


@pytest.fixture(scope="module")
def with_obstacle(robot):
    return CollisionModel(robot, CollisionConfig(obstacles=(OBSTACLE,)))


def _coal_geometry(model: CollisionModel) -> pin.GeometryModel:
    """The capsules of the checked pairs as coal shapes in a pinocchio GeometryModel, one collision pair each."""
    geometry = pin.GeometryModel()
    index = {}
    for capsule in {c.name: c for p in model.pairs for c in (p.first, p.second)}.values():
        axis = capsule.end_m - capsule.start_m
        length = float(np.linalg.norm(axis))
        if length < 1e-9:
            shape, rotation = coal.Sphere(capsule.radius_m), np.eye(3)
        else:
            shape = coal.Capsule(capsule.radius_m, length)
            rotation = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), axis / length).matrix()
        placement = pin.SE3(rotation, 0.5 * (capsule.start_m + capsule.end_m))
        obj = pin.GeometryObject(capsule.name, capsule.joint_id, placement, shape)
        index[capsule.name] = geometry.addGeometryObject(obj)
    for pair in model.pairs:
        geometry.addCollisionPair(pin.CollisionPair(index[pair.first.name], index[pair.second.name]))
    return geometry


def test_capsules_and_pairs_of_b1_z1(collision):
    names = {c.link for c in collision.capsules}
    assert {"trunk", "FL_thigh", "link03"} <= names
    assert "link01" in collision.skipped_links  # no <collision> in the Z1's URDF: listed, not modelled
    kinds = {p.kind for p in collision.pairs}
    assert kinds == {"arm-body", "leg-leg"}
    assert any("trunk" in p.second.link for p in collision.pairs if p.kind == "arm-body")
    # clear at the nominal pose by more than the margin (neighbours left out)
    assert collision.distances(load_robot("b1_z1").q_nominal).min() > collision.config.margin_m


def test_capsule_distances_match_coal(robot, with_obstacle):
    """CasADi rows (our FK in the base frame, the world for the obstacle + branch-free segment distance) against
    pinocchio's FK and coal's capsule distance on random configurations and base poses, deep penetrations and
    parallel capsules included."""
    collision = with_obstacle
    assert any(p.kind == "obstacle" for p in collision.pairs)
    geometry = _coal_geometry(collision)
    geometry_data = pin.GeometryData(geometry)
    data = robot.model.createData()
    function = collision_function(collision, SymbolicDynamics(robot))
    checked = 0
    rng = np.random.default_rng(7)
    for q in random_configurations(robot, 40, seed=3, leg_range_rad=1.0):
        q = q.copy()
        q[:3] += rng.uniform(-0.3, 0.3, 3)
        q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(rng.uniform(-0.3, 0.3, 3))).coeffs()
        pin.computeDistances(robot.model, data, geometry, geometry_data, q)
        reference = np.array([r.min_distance for r in geometry_data.distanceResults])
        ours = np.asarray(function(q)[0]).ravel()
        clear = reference > 1e-3  # coal reports penetration depth differently for overlapping capsules
        np.testing.assert_allclose(ours[clear], reference[clear], atol=2e-5)
        np.testing.assert_allclose(ours, collision.distances(q), atol=2e-4)  # the numeric twin used for checks
        checked += int(clear.sum())
    assert checked > 500


def test_group_rows_never_exceed_their_closest_pair(robot, collision):
    function = collision_function(collision, SymbolicDynamics(robot))
    for q in random_configurations(robot, 20, seed=5, leg_range_rad=0.5):
        distances, rows = (np.asarray(x).ravel() for x in function(q))
        for row, idx in zip(rows, collision.groups.values()):
            closest = distances[idx].min()
            assert closest - np.log(len(idx)) / 100.0 - 1e-9 <= row <= closest + 1e-9


def _colliding_arm(robot, collision) -> np.ndarray:
    """A configuration with the hand inside the trunk."""
    for q in random_configurations(robot, 2000, seed=1, leg_range_rad=0.0):
        d = collision.distances(q)
        names = [p.name for p in collision.pairs]
        if min(d[i] for i, n in enumerate(names) if "trunk" in n) < -0.03:
            return q
    raise AssertionError("no colliding arm configuration found")


def test_obstacle_in_the_way_of_the_start_names_it(robot):
    crate_on_hand = Obstacle("crate", tuple(robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]),
                             (0.1, 0.1, 0.1))
    model = CollisionModel(robot, CollisionConfig(obstacles=(crate_on_hand,)))
    with pytest.raises(CollisionError, match="crate"):
        model.check_clear(robot.q_nominal)
    with pytest.raises(ConfigError, match="half_size_m"):
        Obstacle("flat", (0.0, 0.0, 0.0), (0.1, 0.0, 0.1))


def test_start_in_collision_names_the_pair(robot, collision):
    q = _colliding_arm(robot, collision)
    with pytest.raises(CollisionError, match="starts in collision: .* / .*|starts in collision: .* and .*"):
        collision.check_clear(q)
    try:
        collision.check_clear(q)
    except CollisionError as exc:
        assert "trunk" in str(exc) or "hip" in str(exc) or "thigh" in str(exc) or "link00" in str(exc)
        assert "--collision-avoidance" in str(exc)


def test_mpc_keeps_the_hand_off_the_trunk(robot, collision):
    """From a pose with the hand 7 cm from the trunk, a command driving it at the trunk's centre at 0.5 m/s: the plan's
    configurations keep every checked pair at the margin (pinocchio FK on the planned q), the soft arm rows
    give way instead of the OCP turning infeasible."""
    from wbmpc.bench.mpc import mpc_config
    from wbmpc.ocp.grid import TimeGrid

    config = mpc_config(robot=robot, nodes=8)
    config = replace(config, soft_rows_always=True,
                     ocp=replace(config.ocp, grid=TimeGrid(n_intervals=7), collision=CollisionConfig(),
                                 soft_rows=("ee_vel",)))
    mpc = MPC(robot, config)
    q = robot.with_joint_positions(robot.q_nominal, robot.joint_positions(robot.q_nominal))
    joints = robot.joint_positions(q)
    names = list(robot.joint_names)
    for joint, value in (("joint2", 1.2), ("joint3", -0.1), ("joint4", 1.5)):  # the wrist bent down to the trunk
        joints[names.index(joint)] = value
    q = robot.with_joint_positions(q, joints)
    model = mpc.problem.collision
    assert model.config.margin_m < model.distances(q).min() < 0.08
    hand = robot.frame_trajectories(q, [robot.arm_ee])[robot.arm_ee][0]
    towards = 0.5 * (q[:3] - hand) / np.linalg.norm(q[:3] - hand)
    command = Commands(ee_velocity_m_s=towards)
    solution = mpc.solve(q, np.zeros(robot.nv), command, 0.0)
    assert solution.success, solution.stats.status
    planned = np.array([model.distances(qk).min() for qk in solution.q[2:]])
    assert planned.min() >= model.config.margin_m - 2e-3
    # without the rows the same command takes the hand deeper than the margin
    free = MPC(robot, replace(config, ocp=replace(config.ocp, collision=None)))
    unconstrained = free.solve(q, np.zeros(robot.nv), command, 0.0)
    assert min(model.distances(qk).min() for qk in unconstrained.q[2:]) < model.config.margin_m - 0.02


def test_mujoco_counts_robot_robot_contacts(robot, collision):
    from wbmpc.sim.mujoco_plant import MujocoPlant
    from wbmpc.sim.mujoco_scene import MujocoPlantConfig

    q = _colliding_arm(robot, collision)
    plant = MujocoPlant(robot, MujocoPlantConfig(record_every_n_steps=0))
    plant.reset(robot.q_nominal)
    assert plant.self_contacts.contacts == 0  # nominal pose: nothing touches
    plant.set_state(q, np.zeros(robot.nv))
    plant.step(np.zeros(robot.n_joints))
    assert plant.self_contacts.contacts > 0 and plant.self_contacts.steps == 1
    assert any("base" in name or "hip" in name or "thigh" in name for name in plant.self_contacts.pairs)
    off = MujocoPlant(robot, MujocoPlantConfig(record_every_n_steps=0, self_collision=False))
    off.reset(q)
    off.step(np.zeros(robot.n_joints))
    robot_geom = np.asarray(off.model.geom_contype) & 2 > 0
    geoms = off.data.contact.geom[: off.data.ncon]
    assert not np.any(robot_geom[geoms[:, 0]] & robot_geom[geoms[:, 1]])
    assert off.self_contacts.contacts == 0
    assert mujoco.mj_name2id(plant.model, mujoco.mjtObj.mjOBJ_BODY, "base") >= 0


def test_behind_base_reachable_part(robot):
    from wbmpc.scenarios import ScenarioOptions, make_scenario

    scenario = make_scenario("arm-track", robot, ScenarioOptions(arm_target_path="behind-base", speed_m_s=0.0))
    t = np.linspace(0.0, 8.0, 81)
    reachable = scenario.reachable(robot, t)
    assert reachable[t <= 1.0].all()  # the nominal hand position
    assert not reachable[(t >= 5.0) & (t <= 6.5)].any()  # behind the trunk, beyond the arm
    workspace = arm_workspace(robot)
    assert 0.5 < workspace.reach_m < 1.0


@pytest.mark.slow
def test_run_reports_self_collision_contacts():
    from wbmpc.scenarios import RunConfig, run_scenario

    a1 = load_robot("a1")
    result = run_scenario(a1, RunConfig(scenario="stand", duration_s=0.1, nodes=4))
    assert result.metrics["self_collision_contacts"] == 0
    assert result.metrics["collision_avoidance"] is None


def test_run_option_sets_the_ocp(robot):
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.runner import mpc_config_for

    scenario = make_scenario_for(robot)
    config = mpc_config_for(scenario, RunConfig(scenario="arm-track", collision_avoidance=True, collision_margin_m=0.04),
                            robot)
    assert config.ocp.collision.margin_m == 0.04
    assert config.ocp.soft_rows == ("ee_vel",) and config.soft_rows_always
    plain = mpc_config_for(scenario, RunConfig(scenario="arm-track", collision_avoidance=False), robot)
    assert plain.ocp.collision is None and plain.ocp.soft_rows == () and not plain.soft_rows_always
    # compiled without delay: Fatrop, but the anytime SQP with collision avoidance (the soft arm rows)
    assert RunConfig(scenario="arm-track", solver="auto", compiled=True,
                     collision_avoidance=False).solver.startswith("fatrop")  # -direct, or its fallback
    assert RunConfig(scenario="arm-track", solver="auto", compiled=True, collision_avoidance=True).solver == "sqp"


def test_arm_track_avoids_collisions_unless_told_otherwise(robot):
    """Left open, collision avoidance is on for arm-track on a legged base with an arm (the paper's path brings the
    Z1's wrist onto its shoulder in MuJoCo) and the automatic solver is chosen again with it; elsewhere it stays off,
    and what the user set or chose is kept."""
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.runner import mpc_config_for

    auto = RunConfig(scenario="arm-track", solver="auto", compiled=True)
    assert auto.collision_avoidance is None and auto.solver.startswith("fatrop")  # before the robot is known
    on_robot = replace(auto, seed=1).for_robot(robot)  # the CLI's replace keeps the automatic choice
    assert on_robot.collision_avoidance is True and on_robot.solver == "sqp"
    assert mpc_config_for(make_scenario_for(robot), RunConfig(scenario="arm-track"), robot).ocp.collision is not None
    assert RunConfig(scenario="arm-track", solver="fatrop").for_robot(robot).solver == "fatrop"  # chosen: kept
    assert RunConfig(scenario="arm-track", collision_avoidance=False).for_robot(robot).collision_avoidance is False
    assert RunConfig(scenario="trot-in-place", solver="auto", compiled=True).for_robot(robot).collision_avoidance is False
    assert RunConfig(scenario="arm-track").for_robot(load_robot("a1")).collision_avoidance is False  # no arm


def test_collision_avoidance_flag():
    from wbmpc.cli import build_parser, run_config_from_args

    parser = build_parser()
    values = [run_config_from_args(parser.parse_args(["run", "arm-track", *extra])).collision_avoidance
              for extra in ([], ["--collision-avoidance"], ["--collision-avoidance", "on"], ["--collision-avoidance", "off"])]
    assert values == [None, True, True, False]


def make_scenario_for(robot):
    from wbmpc.scenarios import ScenarioOptions, make_scenario

    return make_scenario("arm-track", robot, ScenarioOptions(arm_target_path="behind-base"))


def test_around_obstacle_path_crosses_the_post(robot):
    """--target-path around-obstacle: the straight sweep goes through the post (reference inside the box, not
    reachable there), the base trots in place, the MPC's obstacle is the MuJoCo box, kept off the arm only."""
    from wbmpc.scenarios import ScenarioOptions, make_scenario
    from wbmpc.sim.objects import FixedBox

    scenario = make_scenario("arm-track", robot, ScenarioOptions(arm_target_path="around-obstacle"))
    post = scenario.post(robot)
    assert isinstance(post, FixedBox)
    assert post.centre_m[2] == pytest.approx(post.half_size_m[2])  # stands on the floor
    reference = scenario.ee_reference(robot)
    middle = np.asarray(reference(4.75))  # halfway from the left to the right of the robot
    assert np.all(np.abs(middle[:2] - np.asarray(post.centre_m[:2])) < np.asarray(post.half_size_m[:2]) + 0.05)
    assert middle[2] < post.centre_m[2] + post.half_size_m[2]
    t = np.linspace(0.0, 8.0, 161)
    reachable = scenario.reachable(robot, t)
    assert reachable[t <= 3.5].all() and not reachable[np.isclose(t, 4.75)].any()
    assert scenario.commands(robot)(0.0, robot.q_nominal, np.zeros(robot.nv)).base_velocity_m_s[0] == 0.0
    (obstacle,) = scenario.obstacles(robot)
    assert obstacle.keep_off == ("arm",) and obstacle.half_size_m == post.half_size_m
    model = CollisionModel(robot, CollisionConfig(obstacles=(obstacle,)))
    on_post = [p for p in model.pairs if p.kind == "obstacle"]
    assert {p.group for p in on_post} == {"arm vs post"}  # one row: forearm and hand
    assert {p.first.link for p in on_post} >= {"link03"}
    model.check_clear(robot.q_nominal)  # the nominal pose is clear of it
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.runner import mpc_config_for

    config = mpc_config_for(scenario, RunConfig(scenario="arm-track", collision_avoidance=True), robot)
    assert config.ocp.collision.obstacles == (obstacle,)


def test_mujoco_post_measures_the_robot_touching_it(robot):
    """The post (a FixedBox in the MuJoCo scene): `touching` when the hand is inside it, not at the nominal pose;
    contact_count counts touches once."""
    from wbmpc.sim.mujoco_plant import MujocoPlant
    from wbmpc.sim.mujoco_scene import MujocoPlantConfig
    from wbmpc.sim.objects import FixedBox, Scene, contact_count

    hand = robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]
    for centre, expected in (((hand[0] + 0.5, 0.0, 0.5), 0.0), ((hand[0], hand[1], hand[2] + 0.05), 1.0)):
        scene = Scene(robot, [FixedBox(centre, (0.05, 0.05, 0.05))])
        plant = MujocoPlant(robot, scene.plant_config(MujocoPlantConfig(record_every_n_steps=0)))
        scene.attach(plant)
        plant.reset(robot.q_nominal)
        plant.step(np.zeros(robot.n_joints))
        assert scene.recording.series("post", "touching")[1][-1] == expected
    assert contact_count(np.arange(6) * 0.002, [0, 1, 1, 0, 1, 0]) == {"contacts": 2, "time_s": pytest.approx(0.006)}
    with pytest.raises(ConfigError, match="keep_off"):
        Obstacle("crate", (1.0, 0.0, 0.5), (0.1, 0.1, 0.1), keep_off=("head",))


@pytest.mark.slow
def test_quadratic_slack_slides_the_hand_along_an_obstacle(robot):
    """A post 5 cm past the margin beside the hand, its axis 3 cm beyond the hand, a command straight into it:
    under the L1 weight alone the plan stops the hand at the margin; with the quadratic weight of collision
    runs it slides along the post (towards the robot); both keep the margin (pinocchio FK on the planned q)."""
    from wbmpc.bench.mpc import mpc_config
    from wbmpc.control.policy import COLLISION_SOFT_WEIGHT_SQ
    from wbmpc.ocp.grid import TimeGrid

    q = robot.q_nominal.copy()
    hand = robot.frame_trajectories(q, [robot.arm_ee])[robot.arm_ee][0]
    post = Obstacle("post", (hand[0] + 0.03, hand[1] - 0.19, 0.5), (0.05, 0.05, 0.5), keep_off=("arm",))
    config = mpc_config(robot=robot, nodes=8, solver="sqp")
    moved = {}
    for weight in (0.0, COLLISION_SOFT_WEIGHT_SQ):
        mpc = MPC(robot, replace(config, soft_rows_always=True,
                                 weights=replace(config.weights, soft_constraint_quadratic=weight),
                                 ocp=replace(config.ocp, grid=TimeGrid(n_intervals=7), soft_rows=("ee_vel",),
                                             collision=CollisionConfig(obstacles=(post,)))))
        model = mpc.problem.collision
        on_post = [i for i, p in enumerate(model.pairs) if p.kind == "obstacle"]
        assert 0.04 < model.distances(q)[on_post].min() < 0.07
        solution = mpc.solve(q, np.zeros(robot.nv), Commands(ee_velocity_m_s=np.array([0.0, -0.3, 0.0])), 0.0)
        assert solution.success, solution.stats.status
        assert min(model.distances(qk)[on_post].min() for qk in solution.q[1:]) >= model.config.margin_m - 2e-3
        ee = robot.frame_trajectories(np.asarray(solution.q), [robot.arm_ee])[robot.arm_ee]
        moved[weight] = ee[-1] - ee[0]
    assert abs(moved[0.0][0]) < 0.005  # stopped
    assert moved[COLLISION_SOFT_WEIGHT_SQ][0] < -0.01  # slid along the post, towards the robot
