import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.robots import GRAVITY_M_S2, PRESET_NAMES, load_robot
from wbmpc.robots.presets import QUADRUPEDS
from wbmpc.sim import (
    MujocoPlant,
    MujocoPlantConfig,
    PinocchioPlant,
    PinocchioPlantConfig,
    Plant,
    PlantConfig,
    PlantDivergedError,
    PlantInputError,
    make_plant,
)
from wbmpc.sim.base import quat_xyzw_to_matrix
from wbmpc.sim.contact_solver import OPEN, SLIDE, STICK, solve_contact_impulses
from wbmpc.sim.mujoco_scene import (
    MIN_INERTIA_KG_M2,
    MIN_MASS_KG,
    build_mjcf,
    build_model,
    mujoco_inertia,
    regularised_bodies,
)

PLANTS = ("mujoco", "pinocchio")


@pytest.fixture(scope="module")
def mj_b1z1(b1z1):
    return MujocoPlant(b1z1)


def static_feedforward(robot):
    """Joint torques that hold q_nominal with the weight spread over the feet (min-norm forces)."""
    model, data = robot.model, robot.model.createData()
    q = robot.q_nominal
    gravity = pin.computeGeneralizedGravity(model, data, q)
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J = np.vstack([pin.getFrameJacobian(model, data, robot.frame_id(f), pin.LOCAL_WORLD_ALIGNED)[:3] for f in robot.feet])
    forces = np.linalg.lstsq(J[:, :6].T, gravity[:6], rcond=None)[0]
    return (gravity - J.T @ forces)[6:]


# ------------------------------------------------------------------------------ MuJoCo scene
@pytest.mark.parametrize("name", PRESET_NAMES)
def test_mujoco_inertias_equal_pinocchio(name):
    robot = load_robot(name)
    model = build_model(robot)
    regularised = regularised_bodies(robot)
    if name in QUADRUPEDS:
        assert regularised == []
    for jid in range(1, robot.model.njoints):
        body = model.body(model.joint(robot.model.names[jid]).bodyid[0])
        if body.name in regularised:
            continue
        ref = robot.model.inertias[jid]
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, body.iquat)
        R = R.reshape(3, 3)
        inertia = R @ np.diag(body.inertia) @ R.T
        assert body.mass[0] == pytest.approx(ref.mass, abs=1e-9)
        np.testing.assert_allclose(body.ipos, ref.lever, atol=1e-9)
        np.testing.assert_allclose(inertia, ref.inertia, atol=1e-9)
    assert sum(model.body_mass) == pytest.approx(robot.mass_kg, abs=1e-6)


def test_unphysical_inertias_are_regularised_for_mujoco():
    inertia = np.diag([0.01, 0.02, 0.025])
    mass, same = mujoco_inertia(2.0, inertia)
    assert mass == 2.0 and same is not None and np.array_equal(same, inertia)  # physical: unchanged
    _, point = mujoco_inertia(0.7, np.zeros((3, 3)))  # a point mass (iCub's hips)
    assert np.linalg.eigvalsh(point).min() >= MIN_INERTIA_KG_M2
    mass, _ = mujoco_inertia(0.0, np.zeros((3, 3)))  # massless link between the axes of a ball joint
    assert mass == MIN_MASS_KG
    rotation = pin.rpy.rpyToMatrix(0.3, -0.2, 1.0)
    flat = rotation @ np.diag([0.0007, 0.0007, 0.0066]) @ rotation.T  # A + B < C (romeo's shoulder)
    _, fixed = mujoco_inertia(0.57, flat)
    moments = np.linalg.eigvalsh(fixed)
    assert moments[0] + moments[1] >= moments[2]
    assert moments[2] == pytest.approx(0.0066)
    # MuJoCo compiles the robots whose URDFs have such links, and names what was changed
    assert "RShoulderYawLink" in regularised_bodies(load_robot("romeo"))
    assert build_model(load_robot("icub")).nbody > 30


def test_mujoco_joints_actuators_and_limits(b1z1, mj_b1z1):
    model = mj_b1z1.model
    assert model.nu == b1z1.n_joints
    for k, name in enumerate(b1z1.joint_names):
        actuator, joint = model.actuator(k), model.joint(name)
        assert actuator.name == name and actuator.trnid[0] == joint.id
        np.testing.assert_allclose(actuator.ctrlrange, [-b1z1.tau_max[k], b1z1.tau_max[k]])
        np.testing.assert_allclose(actuator.forcerange, [-b1z1.tau_max[k], b1z1.tau_max[k]])
        np.testing.assert_allclose(joint.range, [b1z1.q_min[k], b1z1.q_max[k]])
        assert joint.limited[0] and joint.damping[0] == 0.0 and joint.armature[0] == 0.0
    assert model.opt.timestep == 1e-3
    primitives = {mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
                  mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_BOX}  # fmt: skip
    assert {int(t) for t in model.geom_type} <= {int(t) for t in primitives}


def test_only_the_feet_touch_the_floor_at_the_nominal_pose(b1z1, mj_b1z1):
    mj_b1z1.reset()
    model, data = mj_b1z1.model, mj_b1z1.data
    touching = {model.geom(data.contact[i].geom[j]).name for i in range(data.ncon) for j in range(2)}
    assert touching == {"floor", *b1z1.feet}
    assert model.geom("FL_foot").size[0] == b1z1.foot_radius_m


def test_state_round_trip_and_kinematics_match_pinocchio(b1z1, mj_b1z1, rng):
    data = b1z1.model.createData()
    model, mj = mj_b1z1.model, mj_b1z1.data
    for _ in range(5):
        q, v = b1z1.random_configuration(rng), rng.normal(size=b1z1.nv)
        mj_b1z1.reset(q, v)
        q_back, v_back = mj_b1z1.state()
        np.testing.assert_allclose(q_back, q, atol=1e-12)
        np.testing.assert_allclose(v_back, v, atol=1e-12)
        pin.forwardKinematics(b1z1.model, data, q, v)
        pin.updateFramePlacements(b1z1.model, data)
        for foot in b1z1.feet:
            fid = b1z1.frame_id(foot)
            np.testing.assert_allclose(mj.geom(foot).xpos, data.oMf[fid].translation, atol=1e-9)
            velocity = np.zeros(6)  # MuJoCo: [angular, linear] in world axes
            mujoco.mj_objectVelocity(model, mj, mujoco.mjtObj.mjOBJ_GEOM, model.geom(foot).id, velocity, 0)
            ref = pin.getFrameVelocity(b1z1.model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(velocity[3:], ref.linear, atol=1e-9)
            np.testing.assert_allclose(velocity[:3], ref.angular, atol=1e-9)
        ee = data.oMf[b1z1.frame_id(b1z1.arm_ee)].translation
        np.testing.assert_allclose(mj.site(b1z1.arm_ee).xpos, ee, atol=1e-9)


def test_extra_bodies_and_spec_callback(b1z1):
    box = '<body name="crate" pos="1 0 0.2"><freejoint/><geom type="box" size=".1 .1 .1" mass="2"/></body>'
    seen = []
    config = MujocoPlantConfig(extra_bodies_mjcf=(box,), spec_callback=lambda spec: seen.append(spec.worldbody))
    plant = MujocoPlant(b1z1, config)
    assert seen and plant.model.body("crate").mass[0] == pytest.approx(2.0)
    q = b1z1.q_nominal.copy()
    q[7] = 0.1
    plant.reset(q)
    np.testing.assert_allclose(plant.state()[0], q, atol=1e-12)
    for _ in range(300):
        plant.step(np.zeros(b1z1.n_joints))
    assert plant.data.body("crate").xpos[2] == pytest.approx(0.1, abs=2e-3)  # rests on the floor
    with pytest.raises(ValueError, match=r"extra_bodies_mjcf\[0\] is not valid XML"):
        build_mjcf(b1z1, MujocoPlantConfig(extra_bodies_mjcf=("<body>",)))


def test_kinematic_collision_shapes_for_mesh_only_urdf():
    go2 = load_robot("go2")  # its URDF has mesh collisions only
    model = build_model(go2)
    kinds = {int(t) for t in model.geom_type}
    assert int(mujoco.mjtGeom.mjGEOM_CAPSULE) in kinds and int(mujoco.mjtGeom.mjGEOM_BOX) in kinds


# ------------------------------------------------------------------------------ both plants
@pytest.mark.parametrize("kind", PLANTS)
def test_pd_stand_holds_the_robot(b1z1, kind):
    plant = make_plant(kind, b1z1)
    assert isinstance(plant, Plant)
    q0 = b1z1.q_nominal.copy()
    q0[2] += 0.02  # dropped from 2 cm
    plant.reset(q0)
    q_ref, tau_ff = b1z1.q_nominal[7:], static_feedforward(b1z1)
    heights, normal = [], []
    for _ in range(1000):
        q, v = plant.state()
        plant.step(200.0 * (q_ref - q[7:]) - 5.0 * v[6:] + tau_ff)
        heights.append(q[2])
        normal.append(plant.contact_forces()[:, 2].sum())
    q, _ = plant.state()
    assert plant.time_s == pytest.approx(1.0)
    assert np.max(np.abs(np.array(heights) - b1z1.q_nominal[2])) < 0.05
    assert quat_xyzw_to_matrix(q[3:7])[2, 2] > 0.99  # upright
    weight = b1z1.mass_kg * GRAVITY_M_S2
    assert np.mean(normal[-100:]) == pytest.approx(weight, rel=0.1)
    assert np.all(plant.contact_forces()[:, 2] > 0)


def test_plants_agree_on_a_landing(b1z1):
    q0 = b1z1.q_nominal.copy()
    q0[2] += 0.03
    tau_ff, heights = static_feedforward(b1z1), {}
    for kind in PLANTS:
        plant = make_plant(kind, b1z1)
        plant.reset(q0)
        for _ in range(300):
            q, v = plant.state()
            plant.step(200.0 * (b1z1.q_nominal[7:] - q[7:]) - 5.0 * v[6:] + tau_ff)
        heights[kind] = plant.state()[0][2]
    assert heights["mujoco"] == pytest.approx(heights["pinocchio"], abs=3e-3)


@pytest.mark.parametrize("kind", PLANTS)
def test_torques_are_clamped(b1z1, kind):
    plant = make_plant(kind, b1z1)
    request = 10.0 * b1z1.tau_max * np.where(np.arange(b1z1.n_joints) % 2, 1.0, -1.0)
    applied = plant.step(request)
    np.testing.assert_allclose(applied, np.sign(request) * b1z1.tau_max)
    if kind == "mujoco":
        np.testing.assert_allclose(plant.data.actuator_force, applied)


@pytest.mark.parametrize("kind", PLANTS)
def test_bad_inputs_raise_value_errors(b1z1, kind):
    plant = make_plant(kind, b1z1)
    with pytest.raises(ValueError, match=r"tau_joints has shape \(15,\), expected \(16,\)"):
        plant.step(np.zeros(15))
    tau = np.zeros(b1z1.n_joints)
    tau[2] = np.nan
    with pytest.raises(ValueError, match="NaN/inf for joints \\['FL_calf_joint'\\]"):
        plant.step(tau)
    with pytest.raises(ValueError, match=r"q has shape \(22,\), expected \(23,\)"):
        plant.reset(np.zeros(22))
    q = b1z1.q_nominal.copy()
    q[3:7] = [0, 0, 0, 2]
    with pytest.raises(ValueError, match="unit norm"):
        plant.reset(q)
    with pytest.raises(ValueError, match="dv_world_m_s must be a finite 3-vector"):
        plant.apply_base_velocity_kick([1.0, 0.0])
    with pytest.raises(PlantInputError, match="dt_s"):
        PlantConfig(dt_s=0.0)
    with pytest.raises(ValueError, match="unknown plant 'bullet'"):
        make_plant("bullet", b1z1)


@pytest.mark.parametrize("kind", PLANTS)
def test_kick_and_recording(b1z1, kind, rng):
    plant = make_plant(kind, b1z1, PlantConfig(record_every_n_steps=2))
    q = b1z1.q_nominal.copy()
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.1, -0.2, 0.7)).coeffs()
    plant.reset(q, rng.normal(size=b1z1.nv))
    q0, v0 = plant.state()
    plant.apply_base_velocity_kick([0.5, -0.2, 0.1])
    q1, v1 = plant.state()
    R = quat_xyzw_to_matrix(q0[3:7])
    np.testing.assert_allclose(R @ (v1[:3] - v0[:3]), [0.5, -0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose(v1[3:], v0[3:], atol=1e-12)
    for _ in range(10):
        plant.step(np.zeros(b1z1.n_joints))
    time_s, qs = plant.recording.arrays()
    assert qs.shape == (6, b1z1.nq)
    np.testing.assert_allclose(time_s, np.arange(6) * 2e-3, atol=1e-12)


def test_config_types(b1z1):
    assert isinstance(PinocchioPlant(b1z1, PlantConfig(friction_mu=0.5)).config, PinocchioPlantConfig)
    assert MujocoPlant(b1z1, PlantConfig(friction_mu=0.5)).model.geom("floor").friction[0] == 0.5
    with pytest.raises(ValueError, match="contact_timeconst_s"):
        MujocoPlantConfig(dt_s=0.005, contact_timeconst_s=0.005)


# ------------------------------------------------------------------------------ contact solver
@pytest.mark.parametrize("push, mode", [(0.5, STICK), (2.0, SLIDE)])
def test_contact_solver_coulomb_point_mass(push, mode):
    """A 1 kg point on the ground (G = I): sticks below mu * weight impulse, slides with mu * N above."""
    mu, dt = 0.8, 1e-3
    v_free = np.array([push * GRAVITY_M_S2 * dt, 0.0, -GRAVITY_M_S2 * dt])
    solution = solve_contact_impulses(np.eye(3), v_free, mu)
    lam = solution.impulses
    assert lam[2] == pytest.approx(GRAVITY_M_S2 * dt)
    assert solution.modes[0] == mode
    expected_t = -min(push, mu) * GRAVITY_M_S2 * dt
    assert lam[0] == pytest.approx(expected_t) and lam[1] == pytest.approx(0.0, abs=1e-15)
    lifting = solve_contact_impulses(np.eye(3), np.array([0.0, 0.0, 0.1]), mu)
    assert lifting.modes[0] == OPEN and np.allclose(lifting.impulses, 0.0)


@pytest.mark.parametrize("kind", PLANTS)
def test_divergence_raises(b1z1, kind, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warning to MUJOCO_LOG.TXT in the working directory
    plant = make_plant(kind, b1z1)
    plant.reset(v=np.full(b1z1.nv, 1e200))
    with pytest.raises(PlantDivergedError, match="reset"):
        plant.step(np.zeros(b1z1.n_joints))
