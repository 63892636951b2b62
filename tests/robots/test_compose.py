"""An arm on any base (robots/compose.py): the composed robot has the dynamics of the robot its author wrote
as one URDF (b1-z1.urdf), of pinocchio's own appendModel, and bad input names the fix."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.cli import build_parser, robot_from_args
from wbmpc.control.tuning import tuning_for
from wbmpc.errors import ConfigError, ModelError
from wbmpc.robots import RobotModel, load_robot, preset_spec
from wbmpc.robots.compose import ArmMount, compose, compose_spec
from wbmpc.robots.presets import example_robot_data_dir

ERD = example_robot_data_dir()
B1, Z1, B1_Z1 = (ERD / p for p in ("b1_description/urdf/b1.urdf", "z1_description/urdf/z1.urdf",
                                   "b1_description/urdf/b1-z1.urdf"))
B1_Z1_MOUNT = ArmMount(urdf=Z1, mount_frame="trunk", mount_xyz_m=(0.35, 0.0, 0.09))  # b1-z1.urdf's z1_static_joint


def _dynamics_equal(a: pin.Model, b: pin.Model, rng, samples: int = 5) -> None:
    """RNEA and CRBA of two models with the same joints (matched by name) agree to 1e-9."""
    assert a.nq == b.nq and a.nv == b.nv
    names = list(a.names)[1:]
    assert sorted(names) == sorted(list(b.names)[1:])
    # velocity / configuration index maps from a's order to b's
    iv = np.concatenate([np.arange(b.idx_vs[b.getJointId(n)], b.idx_vs[b.getJointId(n)] + b.nvs[b.getJointId(n)])
                         for n in names])
    iq = np.concatenate([np.arange(b.idx_qs[b.getJointId(n)], b.idx_qs[b.getJointId(n)] + b.nqs[b.getJointId(n)])
                         for n in names])
    da, db = a.createData(), b.createData()
    for _ in range(samples):
        q = pin.randomConfiguration(a, -np.ones(a.nq), np.ones(a.nq))
        v, acc = rng.normal(size=a.nv), rng.normal(size=a.nv)
        qb, vb, ab = np.empty(b.nq), np.empty(b.nv), np.empty(b.nv)
        qb[iq], vb[iv], ab[iv] = q, v, acc
        tau_a, tau_b = pin.rnea(a, da, q, v, acc), pin.rnea(b, db, qb, vb, ab)
        np.testing.assert_allclose(tau_a, tau_b[iv], atol=1e-9, rtol=0)
        m_a, m_b = pin.crba(a, da, q), pin.crba(b, db, qb)
        m_a, m_b = np.triu(m_a) + np.triu(m_a, 1).T, np.triu(m_b) + np.triu(m_b, 1).T
        np.testing.assert_allclose(m_a, m_b[np.ix_(iv, iv)], atol=1e-9, rtol=0)


def test_b1_plus_z1_composed_at_b1_z1s_mount_has_b1_z1_urdfs_dynamics(tmp_path, rng):
    composed = compose(B1, B1_Z1_MOUNT, cache_dir=tmp_path)
    assert composed.renamed == {} and composed.arm_ee == "gripperMover"  # z1's only leaf link
    model = pin.buildModelFromUrdf(str(composed.urdf), pin.JointModelFreeFlyer())
    reference = pin.buildModelFromUrdf(str(B1_Z1), pin.JointModelFreeFlyer())
    _dynamics_equal(model, reference, rng)
    # and pinocchio's own composition of the two models at the same placement
    base = pin.buildModelFromUrdf(str(B1), pin.JointModelFreeFlyer())
    # (pinocchio's appendModel refuses z1's link and fixed joint that share the name gripperStator)
    arm = pin.buildModelFromXML(Z1.read_text().replace('joint name="gripperStator"', 'joint name="gripperStator_joint"'))
    appended = pin.appendModel(base, arm, base.getFrameId("trunk"), pin.SE3(np.eye(3), np.array([0.35, 0.0, 0.09])))
    _dynamics_equal(model, appended, rng)


def test_the_composed_robot_loads_with_the_arm_as_end_effector(tmp_path):
    spec, composition = compose_spec(preset_spec("b1"), ArmMount(
        urdf=Z1, mount_frame="trunk", mount_xyz_m=(0.35, 0.0, 0.09), arm_ee="gripperStator",
        locked_joints=("joint5", "joint6", "jointGripper"), joint_positions_rad={"joint2": 0.26178, "joint3": -0.26178}))
    robot, paper = RobotModel(spec), load_robot("b1_z1")
    assert (robot.nq, robot.nv, robot.arm_ee) == (paper.nq, paper.nv, "gripperStator")
    assert robot.mass_kg == pytest.approx(paper.mass_kg, abs=1e-9)
    np.testing.assert_allclose(robot.q_nominal, paper.q_nominal, atol=1e-9)
    assert list(robot.leg_joint_mask) == list(paper.leg_joint_mask)


def test_go2_z1_preset_is_go2_with_a_z1_on_its_back():
    robot, go2 = load_robot("go2_z1"), load_robot("go2")
    assert robot.arm_ee == "gripperStator" and robot.n_joints == 16 and robot.feet == go2.feet
    assert robot.mass_kg > go2.mass_kg + 4  # the Z1 weighs 4.3 kg without its locked joints' links counted twice


def test_cli_mounts_an_arm_on_a_preset_like_the_go2_z1_preset():
    args = build_parser().parse_args(["info", "--robot", "go2", "--arm", str(Z1), "--mount", "base",
                                      "--mount-xyz", "0,0,0.057", "--arm-ee", "gripperStator",
                                      "--arm-lock", "joint5,joint6,jointGripper"])
    robot, preset = robot_from_args(args), load_robot("go2_z1")
    assert robot.joint_names == preset.joint_names and robot.mass_kg == pytest.approx(preset.mass_kg)
    mounted, preset_tuning = tuning_for(robot), tuning_for(preset)
    # the same robot gets the same settings; the arm's lightest joint mode (the Kd cap's inertia) is taken at the
    # nominal pose, and the preset's nominal arm pose is its own (a mount cannot know it): within 15 %
    assert mounted.arm_joint_inertia_kg_m2 == pytest.approx(preset_tuning.arm_joint_inertia_kg_m2, rel=0.15)
    assert dataclasses.replace(mounted, arm_joint_inertia_kg_m2=None) == dataclasses.replace(
        preset_tuning, arm_joint_inertia_kg_m2=None)


def test_an_unknown_mount_frame_lists_the_base_frames(tmp_path):
    with pytest.raises(ModelError, match="not a link or joint.*trunk.*FL_hip_joint"):
        compose(B1, ArmMount(urdf=Z1, mount_frame="roof"), cache_dir=tmp_path)


def test_colliding_arm_names_are_prefixed_and_said(tmp_path):
    composed = compose(B1_Z1, ArmMount(urdf=Z1, mount_frame="FL_hip"), cache_dir=tmp_path)  # a second Z1
    assert composed.renamed["joint1"] == "arm_joint1" and composed.renamed["link00"] == "arm_link00"
    assert "prefixed" in composed.note() and composed.arm_ee == "arm_gripperMover"
    model = pin.buildModelFromUrdf(str(composed.urdf), pin.JointModelFreeFlyer())
    assert model.existJointName("arm_joint1") and model.existJointName("joint1")


def test_an_arm_with_several_leaves_needs_its_end_effector_named(tmp_path):
    two_fingers = tmp_path / "arm.urdf"
    two_fingers.write_text("""<robot name="arm"><link name="root"><inertial><mass value="1"/>
      <inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
      <link name="left"/><link name="right"/>
      <joint name="a" type="revolute"><parent link="root"/><child link="left"/><axis xyz="0 0 1"/>
        <limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
      <joint name="b" type="revolute"><parent link="root"/><child link="right"/><axis xyz="0 0 1"/>
        <limit effort="1" velocity="1" lower="-1" upper="1"/></joint></robot>""")
    with pytest.raises(ModelError, match="ends in 2 links.*left, right.*--arm-ee"):
        compose(B1, ArmMount(urdf=two_fingers, mount_frame="trunk"), cache_dir=tmp_path)
    assert compose(B1, ArmMount(urdf=two_fingers, mount_frame="trunk", arm_ee="left"), cache_dir=tmp_path).arm_ee == "left"


def test_arm_options_need_arm_and_mount():
    with pytest.raises(ConfigError, match="--mount"):
        robot_from_args(build_parser().parse_args(["info", "--robot", "go2", "--arm", str(Z1)]))
    with pytest.raises(ConfigError, match="need --arm"):
        robot_from_args(build_parser().parse_args(["info", "--robot", "go2", "--mount", "base"]))
