"""Every joint type legged URDFs produce, checked against pinocchio and MuJoCo.

The a1 URDF is rewritten so that one robot carries all of them: continuous (RUBX, nq = 2, nv = 1),
continuous about an unaligned axis, revolute about an unaligned axis, prismatic along a frame
axis and along an unaligned axis; its feet are fixed joints.
"""

import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.bench.dynamics import validate_dynamics
from wbmpc.errors import ModelError
from wbmpc.robots import RobotModel, preset_spec
from wbmpc.sim import MujocoPlant
from wbmpc.symbolic import SymbolicDynamics

REWRITES = {  # joint: (URDF type, axis, limits)
    "FL_hip_joint": ("continuous", "1 0 0", None),
    "RL_hip_joint": ("continuous", "0.8 0.6 0", None),
    "FR_hip_joint": ("revolute", "0.96 0 0.28", (-0.8, 0.8)),
    "FL_calf_joint": ("prismatic", "0 0 1", (-0.05, 0.05)),
    "RR_calf_joint": ("prismatic", "0 0.6 0.8", (-0.05, 0.05)),
}
EXPECTED_TYPES = {
    "FL_hip_joint": "JointModelRUBX",
    "RL_hip_joint": "JointModelRevoluteUnboundedUnaligned",
    "FR_hip_joint": "JointModelRevoluteUnaligned",
    "FL_calf_joint": "JointModelPZ",
    "RR_calf_joint": "JointModelPrismaticUnaligned",
}


def _rewrite(urdf_in, urdf_out, rewrites):
    tree = ET.parse(urdf_in)
    for joint in tree.getroot().iter("joint"):
        if joint.get("name") not in rewrites:
            continue
        kind, axis, limits = rewrites[joint.get("name")]
        joint.set("type", kind)
        joint.find("axis").set("xyz", axis)
        limit = joint.find("limit")
        for key in ("lower", "upper"):
            limit.attrib.pop(key, None)
        if limits:
            limit.set("lower", str(limits[0]))
            limit.set("upper", str(limits[1]))
    tree.write(urdf_out)


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    spec = preset_spec("a1")
    urdf = tmp_path_factory.mktemp("urdf") / "a1_mixed.urdf"
    _rewrite(spec.urdf, urdf, REWRITES)
    return RobotModel(spec.__class__(**{**spec.__dict__, "name": "a1_mixed", "urdf": urdf}))


def test_the_rewritten_robot_has_every_joint_type(mixed):
    model = mixed.model
    types = {name: model.joints[model.getJointId(name)].shortname() for name in EXPECTED_TYPES}
    assert types == EXPECTED_TYPES
    assert (mixed.nq, mixed.nv) == (21, 18)  # two continuous joints: (cos, sin) each
    assert list(mixed.continuous) == [name in ("FL_hip_joint", "RL_hip_joint") for name in mixed.joint_names]
    k = mixed.joint_index("FL_hip_joint")
    assert mixed.q_min[k] < -1e9 and mixed.q_max[k] > 1e9  # continuous: no position limit
    k = mixed.joint_index("FL_calf_joint")
    assert (mixed.q_min[k], mixed.q_max[k]) == (-0.05, 0.05)


def test_symbolic_dynamics_match_pinocchio(mixed):
    report = validate_dynamics(mixed, samples=6, seed=3)
    for function, row in report["functions"].items():
        assert row["max_abs_error"] < 1e-10, (function, row)


def test_joint_positions_round_trip_across_the_seam(mixed, rng):
    q = mixed.random_configuration(rng)
    positions = mixed.joint_positions(q)
    np.testing.assert_allclose(mixed.with_joint_positions(q, positions), q, atol=1e-12)
    k = mixed.joint_index("FL_hip_joint")
    positions[k] = np.pi - 0.01
    q = mixed.with_joint_positions(q, positions)
    near = positions.copy()
    near[k] = -np.pi + 0.01  # 0.02 rad away across the +-pi seam
    assert mixed.joint_positions(q, near=near)[k] == pytest.approx(-np.pi - 0.01)
    # pinocchio agrees on the difference of two configurations
    dq = pin.difference(mixed.model, q, mixed.with_joint_positions(q, near))
    assert dq[6 + k] == pytest.approx(0.02)


def test_mujoco_scene_has_the_same_kinematics_and_dynamics(mixed, rng):
    plant = MujocoPlant(mixed)
    model, data = plant.model, plant.data
    for name, kind in REWRITES.items():
        expected = mujoco.mjtJoint.mjJNT_SLIDE if kind[0] == "prismatic" else mujoco.mjtJoint.mjJNT_HINGE
        assert model.joint(name).type[0] == expected
        assert bool(model.joint(name).limited[0]) == (kind[0] != "continuous")
    pdata = mixed.model.createData()
    for _ in range(3):
        q, v = mixed.random_configuration(rng), rng.normal(size=mixed.nv)
        plant.reset(q, v)
        q_back, v_back = plant.state()
        np.testing.assert_allclose(q_back, q, atol=1e-12)
        np.testing.assert_allclose(v_back, v, atol=1e-12)
        pin.forwardKinematics(mixed.model, pdata, q, v)
        pin.updateFramePlacements(mixed.model, pdata)
        for foot in mixed.feet:
            np.testing.assert_allclose(data.site(foot).xpos, pdata.oMf[mixed.frame_id(foot)].translation, atol=1e-9)
        # joint-space inertia: MuJoCo's (free joint in world axes) vs pinocchio's on the joint rows
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        vadr = [model.joint(n).dofadr[0] for n in mixed.joint_names]
        mass = pin.crba(mixed.model, pdata, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        np.testing.assert_allclose(full[np.ix_(vadr, vadr)], mass[6:, 6:], atol=1e-9)


def test_unsupported_joint_names_the_joint_and_type(tmp_path):
    spec = preset_spec("a1")
    urdf = tmp_path / "a1_planar.urdf"
    tree = ET.parse(spec.urdf)
    for joint in tree.getroot().iter("joint"):
        if joint.get("name") == "FR_hip_joint":
            joint.set("type", "planar")
    tree.write(urdf)
    with pytest.raises(ModelError, match="joint 'FR_hip_joint' has type JointModelPlanar .* lock the joint"):
        RobotModel(spec.__class__(**{**spec.__dict__, "urdf": urdf}))


def test_mpc_solves_on_the_mixed_robot(mixed):
    from wbmpc.control import MPC, Commands, MpcConfig
    from wbmpc.ocp.grid import TimeGrid
    from wbmpc.ocp.problem import OcpConfig

    mpc = MPC(mixed, MpcConfig(gait="stand", ocp=OcpConfig(grid=TimeGrid(n_intervals=6))))
    q = mixed.q_nominal.copy()
    solution = mpc.solve(q, np.zeros(mixed.nv), Commands(), t_s=0.0)
    assert solution.success, solution.stats.status
    assert solution.q.shape == (7, mixed.nq) and solution.q_joints.shape == (7, mixed.n_joints)
    np.testing.assert_allclose(solution.q_joints[0], mixed.joint_positions(q), atol=1e-9)
    # the plan respects the prismatic joints' 5 cm limits
    k = mixed.joint_index("FL_calf_joint")
    assert np.all(np.abs(solution.q_joints[:, k]) <= 0.05 + 1e-6)
    assert SymbolicDynamics(mixed).joints[mixed.model.getJointId("FL_hip_joint")].unbounded
