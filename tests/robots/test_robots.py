import numpy as np
import pinocchio as pin
import pytest

from wbmpc.errors import ModelError
from wbmpc.robots import (
    PRESET_NAMES,
    RobotModel,
    RobotSpec,
    custom_spec,
    load_robot,
    preset_spec,
)
from wbmpc.robots.presets import example_robot_data_dir


def test_paper_model_has_22_dof(b1z1):
    assert (b1z1.nq, b1z1.nv, b1z1.n_joints) == (23, 22, 16)
    assert b1z1.joint_names[-4:] == ("joint1", "joint2", "joint3", "joint4")
    assert b1z1.contact_frames == ("FL_foot", "FR_foot", "RL_foot", "RR_foot", "gripperStator")
    assert 55 < b1z1.mass_kg < 65


@pytest.mark.parametrize("name, nv", [("b1_z1_full", 24), ("b1", 18), ("go2", 18), ("a1", 18)])
def test_presets_load(name, nv):
    robot = load_robot(name)
    assert robot.nv == nv
    assert np.all(robot.tau_max > 0) and np.all(robot.v_max > 0)
    assert np.all(robot.q_min < robot.q_max)


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_nominal_pose_stands_on_the_ground(name):
    robot = load_robot(name)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q_nominal)
    # contact frames (a flat foot's sole, on the ground) above the ground by their contact height
    clearance = [data.oMf[robot.frame_id(robot.contact_frame(f))].translation[2] - robot.contact_height_m(f)
                 for f in robot.feet]
    assert min(clearance) == pytest.approx(0.0, abs=1e-9)
    assert max(clearance) - min(clearance) < 0.02
    # the nominal joint angles respect the URDF limits
    assert np.all(robot.q_nominal[7:] >= robot.q_min - 1e-9) and np.all(robot.q_nominal[7:] <= robot.q_max + 1e-9)


def test_locked_joints_keep_their_reference_angle(b1z1):
    full = load_robot("b1_z1_full")
    data_full, data = full.model.createData(), b1z1.model.createData()
    pin.framesForwardKinematics(full.model, data_full, full.q_nominal)
    pin.framesForwardKinematics(b1z1.model, data, b1z1.q_nominal)
    ee_full = data_full.oMf[full.frame_id("gripperStator")].translation
    ee = data.oMf[b1z1.frame_id("gripperStator")].translation
    np.testing.assert_allclose(ee, ee_full, atol=1e-12)


def test_limit_override():
    spec = preset_spec("b1_z1")
    robot = RobotModel(RobotSpec(**{**spec.__dict__, "effort_limit_nm": {"RL_calf_joint": 320.0}}))
    assert robot.tau_max[robot.joint_index("RL_calf_joint")] == 320.0


def test_missing_urdf_names_the_file():
    with pytest.raises(ModelError, match="URDF file not found: /no/such.urdf"):
        RobotModel(custom_spec("/no/such.urdf", ["foot"]))


def test_unknown_frame_lists_frames():
    urdf = example_robot_data_dir() / "go2_description/urdf/go2.urdf"
    with pytest.raises(ModelError, match="unknown frame 'left_foot'.*FL_foot"):
        RobotModel(custom_spec(str(urdf), ["left_foot"]))


def test_unknown_locked_joint_lists_joints():
    urdf = example_robot_data_dir() / "go2_description/urdf/go2.urdf"
    with pytest.raises(ModelError, match="unknown joint to lock 'elbow'.*FL_calf_joint"):
        RobotModel(custom_spec(str(urdf), ["FL_foot"], lock=["elbow"]))


def test_srdf_pose_errors():
    erd = example_robot_data_dir()
    urdf, srdf = erd / "go2_description/urdf/go2.urdf", erd / "go2_description/srdf/go2.srdf"
    with pytest.raises(ModelError, match="no pose name"):
        RobotModel(custom_spec(str(urdf), ["FL_foot"], srdf=str(srdf)))
    with pytest.raises(ModelError, match="no group_state 'crouch'.*standing"):
        RobotModel(custom_spec(str(urdf), ["FL_foot"], srdf=str(srdf), pose="crouch"))


def test_unknown_preset_lists_presets():
    with pytest.raises(ModelError, match="unknown robot 'b2'.*b1_z1"):
        load_robot("b2")
