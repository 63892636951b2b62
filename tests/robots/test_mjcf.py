"""Robots from MJCF (`--mjcf`, robots/mjcf.py): wbmpc's pinocchio model of a file against MuJoCo's own numbers on
the same file (mass matrix, bias forces, frame placements at random states), and what the file says beyond the
kinematics (limits, torque limits, keyframe, drive train, feet as bodies, sites or geoms).

The quadruped is written here: `<default>` classes with `childclass`, degrees (MJCF's default unit), euler and
axis-angle orientations, diagonal inertias with a frame rotation and a full inertia, armature, damping,
frictionloss, joint ranges, a joint `actuatorfrcrange`, motors with a gear and a ctrlrange, a position servo with
a forcerange, a keyframe `home`, feet as a body, a site and geoms."""

import dataclasses
import subprocess
import sys

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.errors import ModelError
from wbmpc.robots import RobotModel, custom_spec

LEGS = {"FL": (0.2, 0.1), "FR": (0.2, -0.1), "RL": (-0.2, 0.1), "RR": (-0.2, -0.1)}
FEET = ("FL_foot", "FR_tip", "RL_sole", "RR_sole")  # a body, a site, two geoms


def quadruped_mjcf(free: bool = True, extra_mesh: bool = False) -> str:
    legs = []
    for leg, (x, y) in LEGS.items():
        foot = {
            "FL": '<geom class="foot" pos="0 0 -0.2"/><body name="FL_foot" pos="0 0 -0.2"/>',
            "FR": '<geom class="foot" pos="0 0 -0.2"/><site name="FR_tip" pos="0.002 0 -0.2" euler="0 30 0"/>',
            "RL": '<geom name="RL_sole" class="foot" pos="0.001 0 -0.2"/>',
            "RR": '<geom name="RR_sole" class="foot" pos="0.001 0 -0.2"/>',
        }[leg]
        legs.append(f"""
      <body name="{leg}_hip" pos="{x} {y} 0" euler="0 0 {5 if y > 0 else -5}">
        <inertial pos="0 {0.01 if y > 0 else -0.01} 0" quat="0.9 0.1 0.2 0.3" mass="0.7" diaginertia="0.0009 0.0006 0.0005"/>
        <joint name="{leg}_hip_joint" class="abduction"/>
        <geom type="cylinder" size="0.04 0.02" quat="1 1 0 0"/>
        <body name="{leg}_thigh" pos="0 {0.08 if y > 0 else -0.08} 0" axisangle="0 0 1 3">
          <inertial pos="-0.004 0 -0.03" mass="1.1" fullinertia="0.006 0.0058 0.0009 0.0001 -0.0002 0.00005"/>
          <joint name="{leg}_thigh_joint" range="-90 200"/>
          <geom type="box" size="0.1 0.012 0.017" pos="0 0 -0.1" euler="0 90 0"/>
          <body name="{leg}_calf" pos="0 0 -0.2">
            <inertial pos="0.006 0 -0.14" quat="0.7 0.001 -0.004 0.7" mass="0.25" diaginertia="0.0015 0.00145 0.00006"/>
            <joint name="{leg}_calf_joint" class="knee"/>
            <geom type="capsule" size="0.012" fromto="0 0 0 0 0 -0.15"/>
            {foot}
          </body>
        </body>
      </body>""")
    mesh_asset = '<asset><mesh name="shell" file="meshes/shell.stl"/></asset>' if extra_mesh else ""
    mesh_geom = '<geom type="mesh" mesh="shell" contype="0" conaffinity="0"/>' if extra_mesh else ""
    actuators = "\n".join(
        f'<motor name="{leg}_hip" joint="{leg}_hip_joint" class="quad" gear="2" ctrlrange="-12 12"/>'
        f'<motor name="{leg}_thigh" joint="{leg}_thigh_joint" class="quad"/>'
        + (f'<position name="{leg}_calf" joint="{leg}_calf_joint" kp="80" forcerange="-40 40"/>' if leg != "RR" else "")
        for leg in LEGS)
    home = "0 0 0.3 1 0 0 0 " + " ".join(["0.1", "0.8", "-1.6"] * 4)  # keyframes are in radians
    keyframes = (f'<keyframe><key name="crouch" qpos="{home}"/>'
                 f'<key name="home" qpos="{home.replace("0.8", "0.9").replace("-1.6", "-1.8")}"/></keyframe>')
    return f"""<mujoco model="little_dog">
  {mesh_asset}
  <default>
    <default class="quad">
      <joint axis="0 1 0" damping="0.05" armature="0.012" frictionloss="0.1"/>
      <geom friction="0.6" condim="3"/>
      <motor ctrlrange="-20 20"/>
      <default class="abduction"><joint axis="1 0 0" range="-45 45"/></default>
      <default class="knee"><joint range="-160 -30" armature="0.02" actuatorfrcrange="-35 35"/></default>
      <default class="foot"><geom type="sphere" size="0.02" priority="1" friction="0.5"/></default>
    </default>
  </default>
  <worldbody>
    <body name="trunk" pos="0 0 0.4" childclass="quad">
      <inertial pos="0.01 0.002 -0.005" quat="0.99 0.02 0.1 0.01" mass="6.0" diaginertia="0.1 0.09 0.025"/>
      {'<freejoint name="floating"/>' if free else ''}
      <geom type="box" size="0.2 0.05 0.05"/>
      {mesh_geom}
      <site name="imu" pos="-0.02 0 0.04"/>{''.join(legs)}
    </body>
  </worldbody>
  <actuator>{actuators}</actuator>
  {keyframes if free else ''}
</mujoco>"""


@pytest.fixture(scope="module")
def mjcf_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("mjcf") / "little_dog.xml"
    path.write_text(quadruped_mjcf())
    return path


@pytest.fixture(scope="module")
def dog(mjcf_path):
    return RobotModel(custom_spec(None, list(FEET), mjcf=str(mjcf_path), keyframe="home"))


def _mujoco_state(robot, m, q, v):
    """MuJoCo qpos/qvel of a pinocchio (q, v) and T with qvel = T v (the free joint's linear velocity in the world)."""
    qpos, qvel = m.qpos0.copy(), np.zeros(m.nv)
    qpos[:3], qpos[3:7] = q[:3], q[[6, 3, 4, 5]]
    rotation = pin.Quaternion(q[3:7]).toRotationMatrix()
    angles = robot.joint_positions(q)
    for k, name in enumerate(robot.joint_names):
        joint = m.joint(name)
        qpos[joint.qposadr[0]] += angles[k]
        qvel[joint.dofadr[0]] = v[6 + k]
    qvel[:3], qvel[3:6] = rotation @ v[:3], v[3:6]
    T = np.eye(m.nv)
    T[:3, :3] = rotation
    return qpos, qvel, T


def test_the_mjcf_robot_is_mujocos_robot_at_random_states(dog, mjcf_path):
    """Mass matrix (armature included), bias forces and the placements of bodies, sites and foot geoms: pinocchio's
    model of the file against MuJoCo's compile of the same file, 1e-8."""
    m = mujoco.MjModel.from_xml_path(str(mjcf_path))
    d = mujoco.MjData(m)
    model, data = dog.model, dog.model.createData()
    assert m.nv == dog.nv and dog.model.names[1] == "floating"
    rng = np.random.default_rng(7)
    for _ in range(10):
        q = dog.random_configuration(rng)
        v = rng.normal(0.0, 1.0, dog.nv)
        d.qpos[:], d.qvel[:], T = _mujoco_state(dog, m, q, v)
        mujoco.mj_forward(m, d)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        np.testing.assert_allclose(M, T.T @ full @ T, atol=1e-8)
        # qacc = T a + c (the world-frame linear velocity turns with the base)
        c = np.zeros(m.nv)
        c[:3] = T[:3, :3] @ np.cross(v[3:6], v[:3])
        np.testing.assert_allclose(pin.rnea(model, data, q, v, np.zeros(dog.nv)), T.T @ (d.qfrc_bias + full @ c),
                                   atol=1e-8)
        pin.framesForwardKinematics(model, data, q)
        for b in range(1, m.nbody):
            oMf = data.oMf[model.getFrameId(m.body(b).name, pin.FrameType.BODY)]
            np.testing.assert_allclose(oMf.translation, d.xpos[b], atol=1e-8)
            np.testing.assert_allclose(oMf.rotation, d.xmat[b].reshape(3, 3), atol=1e-8)
        for kind, name in (("site", "FR_tip"), ("geom", "RL_sole"), ("site", "imu")):
            element = getattr(d, kind)(name)
            oMf = data.oMf[dog.frame_id(name)]
            np.testing.assert_allclose(oMf.translation, element.xpos, atol=1e-8)
            np.testing.assert_allclose(oMf.rotation, element.xmat.reshape(3, 3), atol=1e-8)


def test_limits_torques_keyframe_and_drive_train_come_from_the_file(dog):
    j = dog.joint_index
    # ranges in degrees (MJCF's default unit), in radians in the model
    assert (dog.q_min[j("FL_thigh_joint")], dog.q_max[j("FL_thigh_joint")]) == pytest.approx(np.radians([-90, 200]))
    assert dog.q_max[j("RL_hip_joint")] == pytest.approx(np.radians(45))
    # motor: gear 2 x ctrlrange 12; class motor: ctrlrange 20; servo: its forcerange within the joint's actuatorfrcrange
    assert dog.tau_max[j("FL_hip_joint")] == pytest.approx(24.0)
    assert dog.tau_max[j("FL_thigh_joint")] == pytest.approx(20.0)
    assert dog.tau_max[j("FL_calf_joint")] == pytest.approx(35.0)
    assert dog.tau_max[j("RR_calf_joint")] == pytest.approx(35.0)  # no actuator: the joint's actuatorfrcrange
    # the keyframe named (the file's second), standing on its feet
    assert dog.keyframe == "home"
    np.testing.assert_allclose(dog.joint_positions(dog.q_nominal)[[j("FL_thigh_joint"), j("FL_calf_joint")]], [0.9, -1.8])
    # rotor inertia, damping and dry friction of the file as the controller's drive train; armature in pinocchio's
    assert dog.armature_kg_m2[j("FL_calf_joint")] == pytest.approx(0.02) and dog.armature_kg_m2[0] == pytest.approx(0.012)
    assert np.all(dog.viscous_friction_nm_s == pytest.approx(0.05)) and np.all(dog.coulomb_friction_nm == pytest.approx(0.1))
    # feet: the foot sphere's radius; point contacts at a body, a site, geoms
    assert dog.foot_radius_m == pytest.approx(0.02)
    assert dog.mass_kg == pytest.approx(6.0 + 4 * (0.7 + 1.1 + 0.25))


def test_without_a_keyframe_name_the_first_is_the_nominal_pose(mjcf_path):
    first = RobotModel(custom_spec(None, list(FEET), mjcf=str(mjcf_path)))
    assert first.keyframe == "crouch"
    assert first.joint_positions(first.q_nominal)[first.joint_index("RR_thigh_joint")] == pytest.approx(0.8)


def test_mjcf_errors_name_the_file_and_the_fix(mjcf_path, tmp_path):
    with pytest.raises(ModelError, match=r"has no keyframe 'stand'; its keyframes: crouch, home"):
        RobotModel(custom_spec(None, list(FEET), mjcf=str(mjcf_path), keyframe="stand"))
    with pytest.raises(ModelError, match=r"no body, site or geom named 'FL_toe'.*its bodies: .*FL_foot.*its sites: imu, FR_tip"):
        RobotModel(custom_spec(None, ["FL_toe", *FEET[1:]], mjcf=str(mjcf_path)))
    fixed = tmp_path / "fixed.xml"
    fixed.write_text(quadruped_mjcf(free=False))
    with pytest.raises(ModelError, match=r"fixed.xml has no free joint at its root.*<freejoint/>"):
        RobotModel(custom_spec(None, list(FEET), mjcf=str(fixed)))
    meshes = tmp_path / "meshes.xml"
    meshes.write_text(quadruped_mjcf(extra_mesh=True))
    with pytest.raises(ModelError, match=r"meshes.xml.*shell\.stl.*missing"):
        RobotModel(custom_spec(None, list(FEET), mjcf=str(meshes)))
    with pytest.raises(ModelError, match="MJCF file not found"):
        RobotModel(custom_spec(None, list(FEET), mjcf=str(tmp_path / "none.xml")))
    with pytest.raises(ModelError, match="exactly one"):
        RobotModel(dataclasses.replace(custom_spec(None, list(FEET), mjcf=str(mjcf_path)), urdf=mjcf_path))


def test_wbmpc_info_reads_an_mjcf(mjcf_path):
    out = subprocess.run([sys.executable, "-m", "wbmpc", "info", "--mjcf", str(mjcf_path), "--feet", ",".join(FEET),
                          "--keyframe", "home", "--json"], capture_output=True, text=True, check=True).stdout
    import json

    info = json.loads(out)
    assert info["robot"] == "little_dog" and info["nv"] == 18 and info["feet"] == list(FEET)
    assert info["armature_kg_m2"]["FL_calf_joint"] == pytest.approx(0.02)


# ------------------------------------------------------------------------------ what a preset knows, a file derives
def biped_mjcf(foot_geoms: str) -> str:
    legs = "".join(f"""
      <body name="{side}_thigh" pos="0 {y} -0.05">
        <inertial pos="0 0 -0.15" mass="2.0" diaginertia="0.02 0.02 0.004"/>
        <joint name="{side}_hip_pitch" axis="0 1 0" range="-1.5 1.5"/>
        <body name="{side}_shin" pos="0 0 -0.3">
          <inertial pos="0 0 -0.15" mass="1.5" diaginertia="0.015 0.015 0.003"/>
          <joint name="{side}_knee" axis="0 1 0" range="0 2.5"/>
          <body name="{side}_foot" pos="0 0 -0.3">
            <inertial pos="0.03 0 -0.02" mass="0.5" diaginertia="0.001 0.002 0.002"/>
            <joint name="{side}_ankle" axis="0 1 0" range="-1 1"/>
            {foot_geoms}
          </body>
        </body>
      </body>""" for side, y in (("left", 0.1), ("right", -0.1)))
    motors = "".join(f'<motor joint="{side}_{j}" ctrlrange="-80 80"/>' for side in ("left", "right")
                     for j in ("hip_pitch", "knee", "ankle"))
    return f"""<mujoco model="walker"><worldbody><body name="pelvis" pos="0 0 0.7"><freejoint/>
      <inertial pos="0 0 0.1" mass="12" diaginertia="0.2 0.15 0.1"/><geom type="box" size="0.1 0.15 0.1"/>{legs}
      </body></worldbody><actuator>{motors}</actuator></mujoco>"""


CORNERS = "".join(f'<geom size="0.005" pos="{x} {y} -0.04"/>' for x in (-0.05, 0.15) for y in (-0.035, 0.035))


@pytest.mark.parametrize("feet, contact", [(CORNERS, "surface"), ('<geom size="0.03" pos="0 0 -0.03"/>', "point")])
def test_two_feet_that_carry_a_sole_stand_on_it(tmp_path, feet, contact):
    """A custom biped whose foot bodies carry a sole (g1's four corner spheres: 0.21 x 0.08 m) gets flat feet; ball
    feet stay points. Said to be derived; --foot-contact still decides."""
    path = tmp_path / "walker.xml"
    path.write_text(biped_mjcf(feet))
    robot = RobotModel(custom_spec(None, ["left_foot", "right_foot"], mjcf=str(path)))
    assert set(robot.contact_kinds.values()) == {contact} and robot.foot_contact_source == "derived"
    if contact == "surface":
        sole = robot.soles["left_foot"]
        assert (sole.length_m, sole.width_m) == pytest.approx((0.21, 0.08))
        np.testing.assert_allclose(sole.centre_m, [0.05, 0.0, -0.045])
        forced = RobotModel(dataclasses.replace(robot.spec, foot_contact="point"))
        assert set(forced.contact_kinds.values()) == {"point"} and forced.foot_contact_source == "spec"


def test_another_file_of_a_presets_robot_gets_what_the_preset_knows(tmp_path):
    """g1 written as MJCF (wbmpc's own scene of the preset: no keyframe, no armature, box soles): it is the g1 preset's
    robot (`like_preset`), so its rotor inertias, its bent-knee standing pose, its tuning table and flat feet apply;
    go2's MJCF is go2's (not a1's or go1's, which share its joint names)."""
    from wbmpc.control.tuning import tuning_for
    from wbmpc.robots import load_robot
    from wbmpc.robots.presets import custom_robot
    from wbmpc.sim.mujoco_scene import build_mjcf

    g1 = load_robot("g1")
    path = tmp_path / "g1.xml"
    path.write_text(build_mjcf(g1))
    robot = custom_robot(custom_spec(None, list(g1.feet), mjcf=str(path), name="my_g1"))
    assert robot.spec.like_preset == "g1" and robot.name == "my_g1"
    np.testing.assert_allclose(robot.armature_kg_m2, g1.armature_kg_m2)
    np.testing.assert_allclose(robot.joint_positions(robot.q_nominal), g1.joint_positions(g1.q_nominal), atol=1e-12)
    assert set(robot.contact_kinds.values()) == {"surface"}
    assert tuning_for(robot).report()["weights.base_linear_velocity"] == tuning_for(g1).report()["weights.base_linear_velocity"]
    assert robot.summary()["pose_source"] == "preset"
    go2 = load_robot("go2")
    path = tmp_path / "quad.xml"
    path.write_text(build_mjcf(go2))
    assert custom_robot(custom_spec(None, list(go2.feet), mjcf=str(path))).spec.like_preset == "go2"


def test_an_arm_on_an_mjcf_base_equals_the_urdf_composition(tmp_path):
    """go2 written as MJCF with example-robot-data's Z1 mounted as go2_z1 mounts it (`--arm z1 --mount base
    --mount-xyz 0,0,0.057`): the same robot as the go2_z1 preset composed from the two URDFs (RNEA and CRBA at random
    states, joints matched by name, 1e-9); the arm's collision shapes come from its URDF, the legs' from the MJCF."""
    from wbmpc.robots import load_robot
    from wbmpc.robots.compose import ArmMount, compose_spec
    from wbmpc.robots.presets import NAMED_ARMS, example_robot_data_dir
    from wbmpc.sim.mujoco_scene import build_mjcf

    preset = load_robot("go2_z1")
    path = tmp_path / "go2.xml"
    path.write_text(build_mjcf(load_robot("go2")))
    z1 = NAMED_ARMS["z1"]
    mount = ArmMount(urdf=example_robot_data_dir() / z1["urdf"], mount_frame="base", mount_xyz_m=(0.0, 0.0, 0.057),
                     arm_ee=z1["arm_ee"], locked_joints=z1["locked_joints"], joint_positions_rad=z1["joint_positions_rad"])
    spec, _ = compose_spec(custom_spec(None, list(preset.feet), mjcf=str(path)), mount)
    robot = RobotModel(dataclasses.replace(spec, armature_kg_m2=0.0))
    assert sorted(robot.joint_names) == sorted(preset.joint_names) and robot.arm_ee == preset.arm_ee
    assert robot.mass_kg == pytest.approx(preset.mass_kg, abs=1e-9)
    order = [robot.joint_names.index(n) for n in preset.joint_names]  # preset's joint order in the robot's vectors
    rng = np.random.default_rng(3)
    data, pdata = robot.model.createData(), preset.model.createData()
    for _ in range(5):
        qp = preset.random_configuration(rng)
        vp, ap = rng.normal(size=preset.nv), rng.normal(size=preset.nv)
        q = robot.with_joint_positions(np.r_[qp[:7], np.zeros(robot.nq - 7)],
                                       np.array(preset.joint_positions(qp))[np.argsort(order)])
        v, a = np.r_[vp[:6], vp[6:][np.argsort(order)]], np.r_[ap[:6], ap[6:][np.argsort(order)]]
        tau = pin.rnea(robot.model, data, q, v, a)
        np.testing.assert_allclose(np.r_[tau[:6], tau[6:][order]], pin.rnea(preset.model, pdata, qp, vp, ap), atol=1e-9)
    # the legs' shapes from the MJCF, the arm's meshes from its URDF (the replay, collision avoidance)
    assert "FL_calf" in {p.link for p in robot.collision_primitives()}
    arm_joints = {robot.model.getJointId(n) for n in ("joint1", "joint2", "joint3", "joint4")}
    visual = robot.geometry(pin.GeometryType.VISUAL)
    assert {o.parentJoint for o in visual.geometryObjects} >= arm_joints


def test_the_plant_of_an_mjcf_robot_has_the_files_drive_train(dog):
    """wbmpc's own MuJoCo scene of an MJCF robot: the file's armature, damping and frictionloss on the plant's joints."""
    from wbmpc.sim import make_plant

    plant = make_plant("mujoco", dog)
    dof = plant.model.joint("FL_calf_joint").dofadr[0]
    assert plant.model.dof_armature[dof] == pytest.approx(0.02)
    assert plant.model.dof_damping[dof] == pytest.approx(0.05) and plant.model.dof_frictionloss[dof] == pytest.approx(0.1)
