"""Joint armature and friction (paper section VI-D) in the controller's model and in the MuJoCo plant."""

import dataclasses

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.bench.dynamics import validate_dynamics
from wbmpc.errors import ModelError
from wbmpc.robots import RobotModel, load_robot, preset_spec
from wbmpc.sim import (
    MujocoPlant,
    MujocoPlantConfig,
    PinocchioPlant,
    PlantConfig,
    PlantInputError,
)
from wbmpc.symbolic import Motion, SymbolicDynamics

ARMATURE = {"FL_calf_joint": 0.05, "FR_calf_joint": 0.05, "RL_calf_joint": 0.05, "RR_calf_joint": 0.05}


@pytest.fixture(scope="module")
def a1_drive():
    """a1 with rotor inertia on the knees (per joint), viscous friction everywhere (scalar)."""
    spec = dataclasses.replace(preset_spec("a1"), armature_kg_m2={**ARMATURE, "FL_hip_joint": 0.01},
                               viscous_friction_nm_s=0.3, coulomb_friction_nm=0.4)
    return RobotModel(spec)


def _rnea_function(robot):
    import casadi as ca

    dyn = SymbolicDynamics(robot)
    q, v, a = ca.SX.sym("q", robot.nq), ca.SX.sym("v", robot.nv), ca.SX.sym("a", robot.nv)
    cfg = dyn.configuration(q)
    return ca.Function("rnea", [q, v, a], [dyn.rnea(cfg, Motion(cfg, v), a)]), dyn


def test_armature_is_pinocchios_and_on_the_mass_matrix_diagonal(a1_drive, rng):
    k = a1_drive.joint_index("FL_calf_joint")
    assert a1_drive.armature_kg_m2[k] == 0.05 and a1_drive.armature_kg_m2[a1_drive.joint_index("FR_hip_joint")] == 0.0
    np.testing.assert_array_equal(a1_drive.model.armature[6:], a1_drive.armature_kg_m2)
    # every symbolic function against pinocchio with model.armature (+ the friction torques)
    report = validate_dynamics(a1_drive, samples=4, seed=2)
    for name, row in report["functions"].items():
        assert row["max_abs_error"] < 1e-9, (name, row)
    # the mass matrix differs from the rigid-body one by exactly the armature on the diagonal
    fns = SymbolicDynamics(a1_drive).functions()
    q = a1_drive.random_configuration(rng)
    plain = pin.crba(load_robot("a1").model, load_robot("a1").model.createData(), q)
    plain = np.triu(plain) + np.triu(plain, 1).T
    np.testing.assert_allclose(np.array(fns["crba"](q)) - plain, np.diag(np.r_[np.zeros(6), a1_drive.armature_kg_m2]),
                               atol=1e-12)


def test_friction_torques_in_the_inverse_dynamics(a1_drive, rng):
    rnea, _ = _rnea_function(a1_drive)
    rigid, _ = _rnea_function(load_robot("a1"))
    q, a = a1_drive.random_configuration(rng), np.zeros(a1_drive.nv)
    for speed in (0.002, 2.0):
        v = np.r_[np.zeros(6), np.full(a1_drive.n_joints, speed)]
        extra = np.array(rnea(q, v, a) - rigid(q, v, a)).ravel()
        np.testing.assert_allclose(extra[:6], 0.0, atol=1e-12)
        expected = 0.3 * speed + 0.4 * np.tanh(speed / a1_drive.coulomb_velocity_rad_s)
        np.testing.assert_allclose(extra[6:], expected, rtol=1e-12)
    assert expected == pytest.approx(0.3 * 2.0 + 0.4, rel=1e-9)  # sliding: the full Coulomb torque


def test_mujoco_inverse_dynamics_with_armature_and_damping_match_ours(a1_drive, rng):
    """MuJoCo's mj_inverse (rotor inertia in its mass matrix, damping as passive force) against our RNEA."""
    plant = MujocoPlant(a1_drive, MujocoPlantConfig(joint_armature_kg_m2={**ARMATURE, "FL_hip_joint": 0.01},
                                                    joint_damping_nm_s_per_rad=0.3, self_collision=False))
    model, data = plant.model, plant.data  # random configurations: legs would touch each other (robot-robot contacts)
    vadr = np.array([model.joint(n).dofadr[0] for n in a1_drive.joint_names])
    root = model.joint("root_joint").dofadr[0]
    spec = dataclasses.replace(preset_spec("a1"), armature_kg_m2={**ARMATURE, "FL_hip_joint": 0.01},
                               viscous_friction_nm_s=0.3)  # the plant has no Coulomb term here
    rnea, _ = _rnea_function(RobotModel(spec))
    for _ in range(3):
        q, v, a = a1_drive.random_configuration(rng), rng.normal(size=18), rng.normal(size=18) * 5
        q[2] = 3.0  # in the air: no contact forces in the inverse dynamics
        plant.reset(q, v)
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        data.qacc[:] = 0
        data.qacc[root : root + 3] = rot @ (a[:3] + np.cross(v[3:6], v[:3]))  # MuJoCo: world linear velocity
        data.qacc[root + 3 : root + 6] = a[3:6]
        data.qacc[vadr] = a[6:]
        mujoco.mj_inverse(model, data)
        ours = np.array(rnea(q, v, a)).ravel()
        np.testing.assert_allclose(data.qfrc_inverse[vadr], ours[6:], atol=1e-8)
        np.testing.assert_allclose(data.qfrc_inverse[root : root + 3], rot @ ours[:3], atol=1e-8)
    assert np.all(model.dof_armature[vadr] == a1_drive.armature_kg_m2)


def test_mujoco_coulomb_friction_holds_below_and_resists_with_c_when_sliding():
    """Dry friction in the plant: a torque below c does not move a joint, above c it slides against c."""
    robot = load_robot("a1")
    c = 2.0
    plant = MujocoPlant(robot, MujocoPlantConfig(joint_frictionloss_nm={"FL_calf_joint": c}))
    k = robot.joint_index("FL_calf_joint")
    vadr = plant.model.joint("FL_calf_joint").dofadr[0]
    assert plant.model.dof_frictionloss[vadr] == c
    q = robot.q_nominal.copy()
    q[2] = 3.0  # free fall: no contact, the legs are weightless relative to the base
    moved = {}
    for torque in (0.5 * c, 3.0 * c):
        plant.reset(q)
        tau = np.zeros(robot.n_joints)
        tau[k] = torque
        for _ in range(10):
            plant.step(tau)
        moved[torque] = abs(plant.state()[1][6 + k])
    assert moved[0.5 * c] < 0.01 and moved[3.0 * c] > 1.0
    # the friction the plant applies while sliding is c, opposing the motion
    data = plant.data
    friction = data.efc_force[data.efc_type == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF]
    assert friction == pytest.approx([-c * np.sign(plant.state()[1][6 + k])], rel=1e-6)


def test_bad_drive_train_values_name_the_field():
    with pytest.raises(ModelError, match="armature_kg_m2 must be a finite number >= 0, got -1"):
        RobotModel(dataclasses.replace(preset_spec("a1"), armature_kg_m2=-1.0))
    with pytest.raises(ModelError, match="viscous_friction_nm_s: unknown joint 'knee'.*FL_calf_joint"):
        RobotModel(dataclasses.replace(preset_spec("a1"), viscous_friction_nm_s={"knee": 0.1}))
    with pytest.raises(PlantInputError, match="joint_frictionloss_nm must be a finite number >= 0"):
        PlantConfig(joint_frictionloss_nm=float("nan"))
    with pytest.raises(PlantInputError, match="joint_armature_kg_m2: unknown joint 'knee'"):
        MujocoPlant(load_robot("a1"), MujocoPlantConfig(joint_armature_kg_m2={"knee": 0.1}))
    with pytest.raises(PlantInputError, match="no Coulomb joint friction.*MuJoCo"):
        PinocchioPlant(load_robot("a1"), PlantConfig(joint_frictionloss_nm=0.5))


def test_cli_options_reach_the_model_and_the_plant(capsys, tmp_path):
    import json

    from wbmpc.cli import build_parser, main, plant_config_from_args, robot_from_args

    assert main(["info", "--robot", "a1", "--json", "--armature", "FL_calf_joint=0.02", "--coulomb-friction", "0.5"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["armature_kg_m2"]["FL_calf_joint"] == 0.02 and info["armature_kg_m2"]["FR_calf_joint"] == 0.0
    assert info["coulomb_friction_nm"] == 0.5 and info["viscous_friction_nm_s"] == 0.0
    args = build_parser().parse_args(["run", "stand", "--robot", "a1", "--plant-viscous-friction", "0.2",
                                      "--plant-armature", "RR_calf_joint=0.03"])
    robot = robot_from_args(args)
    assert not np.any(robot.armature_kg_m2)  # the model keeps its own (none)
    plant = MujocoPlant(robot, plant_config_from_args(args, robot))
    vadr = plant.model.joint("RR_calf_joint").dofadr[0]
    assert plant.model.dof_armature[vadr] == 0.03 and np.all(plant.model.dof_damping[6:] == 0.2)
    for argv, words in (
        (["info", "--robot", "a1", "--armature", "knee=0.1"], "--armature: unknown joint 'knee'"),
        (["info", "--robot", "a1", "--viscous-friction", "-1"], "--viscous-friction must be a finite number >= 0"),
        (["run", "stand", "--robot", "a1", "--plant-coulomb-friction", "x", "--out", str(tmp_path)],
         "--plant-coulomb-friction needs a number"),
    ):
        assert main(argv) == 2
        assert words in capsys.readouterr().err


def test_plant_flags_keep_the_robots_own_rotors():
    """--plant-coulomb-friction on g1 adds dry friction to the plant's joints and keeps g1's rotor inertias (its
    preset's, `robot_plant_config`); they were dropped, and g1's walk fell at 0.8 s with 0.1 N m. With --plant-model
    the file brings its own drive train: nothing of the preset is added."""
    from wbmpc.cli import build_parser, plant_config_from_args, robot_from_args

    args = build_parser().parse_args(["run", "walk-in-place", "--robot", "g1", "--plant-coulomb-friction", "0.1"])
    robot = robot_from_args(args)
    assert np.any(robot.armature_kg_m2)
    plant = MujocoPlant(robot, plant_config_from_args(args, robot))
    dofs = [plant.model.joint(name).dofadr[0] for name in robot.joint_names]
    np.testing.assert_allclose(plant.model.dof_armature[dofs], robot.armature_kg_m2)
    np.testing.assert_allclose(plant.model.dof_frictionloss[dofs], 0.1)
    args = build_parser().parse_args(["run", "walk-in-place", "--robot", "g1", "--plant-coulomb-friction", "0.1",
                                      "--plant-model", "g1.xml"])
    config = plant_config_from_args(args, robot)
    assert config.joint_frictionloss_nm == 0.1 and config.joint_armature_kg_m2 == 0.0
