"""A plant that is not the controller's model (`--plant-model`, wbmpc.sim.plant_model): MuJoCo simulates another
file of the robot, its joints matched by name, its actuators replaced by torque motors with its force limits.

The files are written here from wbmpc's own scene of go2 (no downloaded model), then edited the way other
authors' files differ: link masses, position servos (Menagerie) with a force range, a joint axis pointing the
other way, a keyframe, sensors, a floor of its own, unnamed bodies."""

import dataclasses
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.campaign.cases import expand
from wbmpc.campaign.spec import CampaignSpec
from wbmpc.errors import ConfigError, ModelError
from wbmpc.robots import RobotModel, load_robot, preset_spec
from wbmpc.scenarios import RunConfig, ScenarioOptions, run_scenario
from wbmpc.scenarios.library import make_scenario
from wbmpc.sim import MujocoPlant, MujocoPlantConfig
from wbmpc.sim.mujoco_scene import build_mjcf

FLIPPED = "FL_thigh_joint"


@pytest.fixture(scope="module")
def go2():
    return load_robot("go2")


def plant_file(robot, folder, mass_scale=1.0, flip=FLIPPED, servo_kp=None, rename=None, free=True, name="plant.xml"):
    """wbmpc's own MJCF of `robot` as another author might have written it (see the module docstring)."""
    root = ET.fromstring(build_mjcf(robot))
    for inertial in root.iter("inertial"):
        inertial.set("mass", repr(float(inertial.get("mass")) * mass_scale))
        values = np.array(inertial.get("fullinertia").split(), dtype=float) * mass_scale
        inertial.set("fullinertia", " ".join(repr(float(x)) for x in values))
    for joint in root.iter("joint"):
        if joint.get("name") == flip:  # the same joint, its axis pointing the other way
            joint.set("axis", " ".join(repr(-float(x)) for x in joint.get("axis").split()))
            low, high = (float(x) for x in joint.get("range").split())
            joint.set("range", f"{-high!r} {-low!r}")
        if rename and joint.get("name") == rename[0]:
            joint.set("name", rename[1])
    if not free:
        body = next(root.iter("worldbody")).find("body")
        body.remove(body.find("freejoint"))
    for body in root.iter("body"):
        if body.get("name") == "FR_calf":
            del body.attrib["name"]  # an unnamed body
    actuator = root.find("actuator")
    if servo_kp is not None:  # Menagerie's position servos with a force range instead of torque motors
        for motor in list(actuator):
            actuator.remove(motor)
            low, high = motor.get("forcerange").split()
            joint = rename[1] if rename and motor.get("joint") == rename[0] else motor.get("joint")
            ET.SubElement(actuator, "position", name=f"servo_{joint}", joint=joint, kp=repr(servo_kp),
                          forcerange=f"{0.5 * float(low)!r} {0.5 * float(high)!r}")
    sensor = ET.SubElement(root, "sensor")
    for motor in list(actuator)[:3]:
        ET.SubElement(sensor, "actuatorfrc", actuator=motor.get("name"))
    keyframe = ET.SubElement(root, "keyframe")
    nq = robot.nq if free else robot.nq - 7
    ET.SubElement(keyframe, "key", name="home", qpos=" ".join(["0"] * nq))
    path = folder / name
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


def test_a_plant_model_with_other_masses_runs_and_reports_that_model(go2, tmp_path):
    """Masses x 1.1, position servos, an axis reversed: the trot in place holds and the metrics say what ran."""
    path = plant_file(go2, tmp_path, mass_scale=1.1, servo_kp=100.0)
    m = run_scenario(go2, RunConfig(scenario="trot-in-place", duration_s=1.0, plant_model=str(path))).metrics
    assert not m["fell"] and m["mpc_failures"] == 0
    report = m["plant_model"]
    assert report["file"] == str(path) and report["format"] == "mjcf"
    assert report["mass_kg"] == pytest.approx(1.1 * go2.mass_kg, rel=1e-9)
    assert report["controller_mass_kg"] == pytest.approx(go2.mass_kg)
    assert report["joints_reversed"] == [FLIPPED]
    assert report["dropped_world_geoms"] == ["floor"]
    # the servos' force range (half the controller's limit) is the plant's, the motors' own
    low, high = report["torque_limit_nm"]["FL_calf_joint"]
    assert high == pytest.approx(0.5 * go2.tau_max[go2.joint_index("FL_calf_joint")]) and low == -high
    plain = run_scenario(go2, RunConfig(scenario="stand", duration_s=0.1)).metrics
    assert plain["plant_model"] is None


def test_the_plant_reads_and_drives_a_reversed_joint_as_the_controller_names_it(go2, tmp_path):
    """The same robot written with one axis reversed and a floor of its own: in the air, from the same state under
    the same torques, the plant model and wbmpc's own plant move the same to 1e-9 (states in the controller's
    layout, the applied torques in the controller's signs)."""
    plant = MujocoPlant(go2, MujocoPlantConfig(plant_model=str(plant_file(go2, tmp_path))))
    own = MujocoPlant(go2)
    assert plant.model.nu == go2.n_joints and all(plant.model.actuator(n).id >= 0 for n in go2.joint_names)
    rng = np.random.default_rng(3)
    q = go2.q_nominal.copy()
    q[2] += 1.0  # in the air
    v = rng.normal(0.0, 0.5, go2.nv)
    for sim in (plant, own):
        sim.reset(q, v)
    tau = rng.uniform(-0.5, 0.5, go2.n_joints) * go2.tau_max
    for _ in range(50):
        applied = [sim.step(tau) for sim in (plant, own)]
    np.testing.assert_allclose(applied[0], applied[1])
    np.testing.assert_allclose(plant.applied_torques(), tau)
    for a, b in zip(plant.state(), own.state()):
        np.testing.assert_allclose(a, b, atol=1e-9)
    # the foot geoms found by distance are the feet (not the calves' capsules); the renamed body is found
    for k, foot in enumerate(go2.feet):
        names = {plant.model.geom(g).name for g in plant.layout.foot_geoms[k]}
        assert names == {foot}


def test_the_files_force_limits_clamp_the_torque(go2, tmp_path):
    plant = MujocoPlant(go2, MujocoPlantConfig(plant_model=str(plant_file(go2, tmp_path, servo_kp=50.0))))
    plant.reset()
    applied = plant.step(go2.tau_max)  # the controller's limits ...
    assert np.allclose(applied, go2.tau_max)
    mujoco.mj_forward(plant.model, plant.data)
    force = plant.data.actuator_force[list(plant.layout.actuators)]
    np.testing.assert_allclose(np.abs(force), 0.5 * go2.tau_max)  # ... and the file's half of them on the joints


def test_joints_that_do_not_match_are_an_error_listing_both_sides(go2, tmp_path):
    path = plant_file(go2, tmp_path, rename=("RR_calf_joint", "RR_knee"))
    with pytest.raises(ModelError) as err:
        MujocoPlant(go2, MujocoPlantConfig(plant_model=str(path)))
    text = str(err.value)
    assert "Not in the plant model: RR_calf_joint" in text and "In the plant model only: RR_knee" in text
    assert "Controller joints: FL_hip_joint" in text and "Plant model joints: FL_hip_joint" in text


def test_a_plant_model_without_free_joint_or_file_is_an_error(go2, tmp_path):
    with pytest.raises(ModelError, match="no free joint"):
        MujocoPlant(go2, MujocoPlantConfig(plant_model=str(plant_file(go2, tmp_path, free=False))))
    with pytest.raises(ModelError, match="plant model file not found: .*nothere.xml"):
        MujocoPlant(go2, MujocoPlantConfig(plant_model=str(tmp_path / "nothere.xml")))
    with pytest.raises(ConfigError, match="--plant mujoco"):
        RunConfig(plant="pinocchio", plant_model="x.xml")
    with pytest.raises(ConfigError, match="plant_model file not found: .*nothere.xml"):  # before anything is built
        RunConfig(plant_model=str(tmp_path / "nothere.xml"))


def test_a_missing_mesh_is_an_error_naming_the_file(go2, tmp_path):
    root = ET.fromstring(build_mjcf(go2))
    ET.SubElement(root.find("asset"), "mesh", name="shell", file="meshes/shell.stl")
    base = next(root.iter("worldbody")).find("body")
    ET.SubElement(base, "geom", type="mesh", mesh="shell", contype="0", conaffinity="0")
    path = tmp_path / "with_mesh.xml"
    path.write_text(ET.tostring(root, encoding="unicode"))
    with pytest.raises(ModelError, match=r"shell\.stl.*missing"):
        MujocoPlant(go2, MujocoPlantConfig(plant_model=str(path)))


def test_joints_the_controller_locks_are_welded_at_its_angles(tmp_path):
    """A b1_z1 controller with the arm's joint2 and joint3 locked too (at 0.26 and -0.26 rad, its SRDF's arm-up
    pose) besides joint5, joint6 and the gripper; the plant file (b1_z1_full) has them all but the gripper's (fixed
    there): the plant welds them at those angles, and its end-effector frame sits where the controller's is."""
    locked = ("joint2", "joint3", "joint5", "joint6", "jointGripper")
    controller = RobotModel(dataclasses.replace(preset_spec("b1_z1"), locked_joints=locked))
    assert abs(controller.locked_positions["joint3"]) > 0.2
    path = tmp_path / "b1_z1_full.xml"
    path.write_text(build_mjcf(load_robot("b1_z1_full")))
    plant = MujocoPlant(controller, MujocoPlantConfig(plant_model=str(path)))
    assert plant.plant_model_report()["welded_joints"] == ["joint2", "joint3", "joint5", "joint6"]
    assert plant.model.nu == controller.n_joints
    plant.reset()
    body, placement = plant.layout.bodies.frame(controller, controller.arm_ee)
    b = plant.model.body(body).id
    ee_plant = plant.data.xpos[b] + plant.data.xmat[b].reshape(3, 3) @ placement.translation
    data = controller.model.createData()
    pin.framesForwardKinematics(controller.model, data, controller.q_nominal)
    np.testing.assert_allclose(ee_plant, data.oMf[controller.frame_id(controller.arm_ee)].translation, atol=1e-9)


def test_a_urdf_plant_model_is_wbmpcs_scene_of_that_file(go2, tmp_path):
    """Another URDF of the robot: its masses and its <dynamics damping friction> become the plant's."""
    text = Path(go2.spec.urdf).read_text()
    text = re.sub(r'(<joint\s+name="FL_calf_joint"\s+type="revolute">)', r'\1<dynamics damping="0.3" friction="0.1"/>', text)
    text = re.sub(r'<mass\s+value="([^"]+)"', lambda match: f'<mass value="{1.05 * float(match.group(1))!r}"', text)
    path = tmp_path / "go2_other.urdf"
    path.write_text(text)
    plant = MujocoPlant(go2, MujocoPlantConfig(plant_model=str(path), joint_damping_nm_s_per_rad=0.05))
    report = plant.plant_model_report()
    assert report["format"] == "urdf" and report["mass_kg"] == pytest.approx(1.05 * go2.mass_kg)
    dof = plant.model.joint("FL_calf_joint").dofadr[0]
    assert plant.model.dof_damping[dof] == pytest.approx(0.35)  # the file's, plus the plant config's on every joint
    assert plant.model.dof_frictionloss[dof] == pytest.approx(0.1)
    assert plant.model.dof_damping[plant.model.joint("FR_calf_joint").dofadr[0]] == pytest.approx(0.05)


def test_scene_objects_attach_to_the_plant_models_hand_where_the_controller_has_it(b1z1, tmp_path):
    """pull's load and cable in the plant model: the cable's end on the hand, the load and the cable's length
    where wbmpc's own scene has them."""
    path = tmp_path / "b1_z1_full.xml"
    path.write_text(build_mjcf(load_robot("b1_z1_full")))
    scene = make_scenario("pull", b1z1, ScenarioOptions()).scene(b1z1)
    plants = [MujocoPlant(b1z1, scene.plant_config(MujocoPlantConfig(plant_model=model))) for model in (str(path), None)]
    for plant in plants:
        plant.reset()
    for read in (lambda p: p.data.site("ee_attach").xpos, lambda p: p.data.body("load").xpos, lambda p: p.data.ten_length):
        np.testing.assert_allclose(read(plants[0]), read(plants[1]), atol=1e-9)


def test_robot_sim_simulates_the_plant_model(go2, tmp_path):
    """`wbmpc robot-sim --plant-model`: the robot behind LowState/LowCmd is the file's (it settles lying down on it)."""
    from wbmpc.hardware.robot_sim import RobotSimConfig, RobotSimulator

    path = plant_file(go2, tmp_path, mass_scale=0.9)
    sim = RobotSimulator(go2, RobotSimConfig(plant_model=str(path), start="lying"))
    assert sim.plant.plant_model_report()["mass_kg"] == pytest.approx(0.9 * go2.mass_kg)
    assert sim.plant.state()[0][2] < 0.5 * go2.q_nominal[2]


def test_plant_model_is_a_campaign_axis_and_model_errors_apply_to_it(go2, tmp_path):
    path = str(plant_file(go2, tmp_path))
    cases = expand(CampaignSpec(scenario="stand", robot="go2", grid={"plant_model": [path, "none"],
                                                                      "link_mass_scale": [1.2]}))
    configs = {case.values["plant_model"]: case.run_config() for case in cases}
    assert configs["none"].plant_model is None and configs[path].plant_model == path
    errors = configs[path].model_errors
    plant = MujocoPlant(go2, errors.plant_config(go2, MujocoPlantConfig(plant_model=path)))
    assert plant.plant_model_report()["mass_kg"] == pytest.approx(1.2 * go2.mass_kg)
