"""Validation of the symbolic dynamics against pinocchio's numeric algorithms, and their size.

`wbmpc bench dynamics` reports, per function, the instruction count of the expanded SX
function and the max error over random states (random q on the manifold, v, a, forces).
"""

from __future__ import annotations

from typing import Callable

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError, check_number
from wbmpc.robots import RobotModel
from wbmpc.symbolic import Motion, SymbolicDynamics


def world_forces_to_pinocchio(robot: RobotModel, data: pin.Data, forces: np.ndarray) -> list:
    """Stacked contact forces (world-frame linear forces at the contact frames, then the sole-frame moments
    of the flat feet) -> pinocchio fext (joint frames).

    Requires the frame placements in `data` to be up to date for the configuration.
    """
    model = robot.model
    fext = [pin.Force.Zero() for _ in range(model.njoints)]
    frames = [robot.contact_frame(f) for f in robot.feet] + ([robot.arm_ee] if robot.arm_ee else [])
    n_moments = 0
    for c, name in enumerate(frames):
        fid = robot.frame_id(name)
        joint = model.frames[fid].parentJoint
        point = data.oMf[fid].translation
        force = forces[3 * c : 3 * c + 3]
        moment = np.cross(point, force)
        if c < len(robot.feet) and robot.feet[c] in robot.soles:
            start = 3 * len(frames) + 3 * n_moments
            moment = moment + data.oMf[fid].rotation @ forces[start : start + 3]
            n_moments += 1
        fext[joint] += data.oMi[joint].actInv(pin.Force(force, moment))
    return fext


def _relative_error(value, reference) -> float:
    value = np.asarray(value, dtype=float)
    reference = np.asarray(reference, dtype=float)
    scale = max(1.0, float(np.abs(reference).max()))
    return float(np.abs(value - reference).max() / scale)


def _references(robot: RobotModel) -> dict[str, Callable]:
    """Per function: (sample) -> (symbolic args, pinocchio reference), with the EE frame for frame functions.

    pinocchio's rnea/crba/aba include the robot's armature (`model.armature`); its algorithms have
    no joint friction, so the robot's friction torques are added to the references that need them.
    """
    model, data = robot.model, robot.model.createData()
    fid = robot.frame_id(robot.contact_frames[-1])

    def friction(v):
        return np.concatenate([np.zeros(6), robot.joint_friction_torque(v[6:])])

    def fk(s):
        pin.framesForwardKinematics(model, data, s["q"])
        oMf = data.oMf[fid]
        return (s["q"],), np.concatenate([oMf.translation, oMf.rotation.ravel(order="F")])

    def frame_velocity(s):
        pin.forwardKinematics(model, data, s["q"], s["v"])
        pin.updateFramePlacements(model, data)
        return (s["q"], s["v"]), pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).vector

    def jacobian(s):
        return (s["q"],), pin.computeFrameJacobian(model, data, s["q"], fid, pin.LOCAL_WORLD_ALIGNED)

    def rnea(s):
        pin.framesForwardKinematics(model, data, s["q"])
        fext = world_forces_to_pinocchio(robot, data, s["f"])
        return (s["q"], s["v"], s["a"], s["f"]), pin.rnea(model, data, s["q"], s["v"], s["a"], fext) + friction(s["v"])

    def crba(s):
        mass = pin.crba(model, data, s["q"])
        return (s["q"],), np.triu(mass) + np.triu(mass, 1).T

    def nle(s):
        return (s["q"], s["v"]), pin.nonLinearEffects(model, data, s["q"], s["v"]) + friction(s["v"])

    def forward_dynamics(s):
        pin.framesForwardKinematics(model, data, s["q"])
        fext = world_forces_to_pinocchio(robot, data, s["f"])
        tau = np.concatenate([np.zeros(6), s["tau_j"]]) - friction(s["v"])
        return (s["q"], s["v"], s["tau_j"], s["f"]), pin.aba(model, data, s["q"], s["v"], tau, fext)

    def com(s):
        return (s["q"],), pin.centerOfMass(model, data, s["q"])

    def centroidal_momentum(s):
        return (s["q"], s["v"]), pin.computeCentroidalMomentum(model, data, s["q"], s["v"]).vector

    def centroidal_momentum_rate(s):
        pin.computeCentroidalMomentumTimeVariation(model, data, s["q"], s["v"], s["a"])
        return (s["q"], s["v"], s["a"]), data.dhg.vector

    def integrate(s):
        return (s["q"], s["dq"]), pin.integrate(model, s["q"], s["dq"])

    def difference(s):
        return (s["q"], s["q1"]), pin.difference(model, s["q"], s["q1"])

    return {f.__name__: f for f in (
        rnea, fk, frame_velocity, jacobian, crba, nle, forward_dynamics, com,
        centroidal_momentum, centroidal_momentum_rate, integrate, difference,
    )}


def random_samples(robot: RobotModel, n_forces: int, count: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    samples = []
    for _ in range(count):
        samples.append({
            "q": robot.random_configuration(rng),
            "q1": robot.random_configuration(rng),
            "v": rng.normal(size=robot.nv) * 2.0,
            "a": rng.normal(size=robot.nv) * 10.0,
            "dq": rng.normal(size=robot.nv),
            "tau_j": rng.normal(size=robot.n_joints) * robot.tau_max * 0.5,
            "f": rng.normal(size=n_forces) * robot.mass_kg * 3.0,
        })
    return samples


def validate_dynamics(robot: RobotModel, samples: int = 100, seed: int = 0) -> dict:
    """Instruction counts and max scale-aware errors of every symbolic function vs pinocchio."""
    if isinstance(samples, bool) or not isinstance(samples, int):
        raise ConfigError.for_field("samples", f"must be an integer, got {samples!r}")
    check_number("samples", samples, low=1, high=100_000)  # an error over no samples would read 0
    dyn = SymbolicDynamics(robot)
    functions = dyn.functions()
    references = _references(robot)
    states = random_samples(robot, dyn.n_forces, samples, seed)
    report = {}
    for name, reference in references.items():
        fn = functions[name]
        worst = 0.0
        for state in states:
            args, expected = reference(state)
            out = fn(*args)
            value = ca.vertcat(*[ca.vec(o) for o in out]) if isinstance(out, (list, tuple)) else out
            value = np.array(value)
            if name == "integrate":  # a quaternion and its negative are the same rotation
                flipped = np.array(expected, copy=True)
                flipped[3:7] *= -1
                worst = max(worst, min(_relative_error(value.ravel(), expected), _relative_error(value.ravel(), flipped)))
                continue
            worst = max(worst, _relative_error(value.reshape(np.shape(expected), order="F"), expected))
        report[name] = {"instructions": int(fn.n_instructions()), "max_abs_error": worst, "samples": samples}
    report["rnea_constraint"] = {
        "instructions": int(rnea_constraint_function(dyn).n_instructions()),
        "max_abs_error": report["rnea"]["max_abs_error"],
        "samples": samples,
    }
    return {"robot": robot.name, "functions": report}


def rnea_constraint_function(dyn: SymbolicDynamics) -> ca.Function:
    """The OCP's eq. (5) as built on each node: RNEA at q_ref (+) dq, reference as parameters."""
    dq = ca.SX.sym("dq", dyn.nv)
    v = ca.SX.sym("v", dyn.nv)
    a = ca.SX.sym("a", dyn.nv)
    forces = ca.SX.sym("f", dyn.n_forces)
    q_ref = ca.SX.sym("q_ref", dyn.nq)
    rot_ref = ca.SX.sym("R_ref", 3, 3)

    cfg = dyn.configuration_from_increment(rot_ref, q_ref, dq)
    tau = dyn.rnea(cfg, Motion(cfg, v), a, forces)
    return ca.Function("rnea_constraint", [dq, v, a, forces, q_ref, rot_ref], [tau])


def joint_types(robot: RobotModel) -> dict[str, int]:
    """How many joints of each pinocchio type the (reduced) model has, e.g. {'RevoluteUnaligned': 6}."""
    counts: dict[str, int] = {}
    for i in range(2, robot.model.njoints):
        kind = robot.model.joints[i].shortname().removeprefix("JointModel")
        counts[kind] = counts.get(kind, 0) + 1
    return counts


def validate_robots(names, samples: int = 10, seed: int = 0, on_row: Callable[[dict], None] | None = None) -> dict:
    """`validate_dynamics` over several presets: one row per robot (size, joint types, worst error)."""
    from wbmpc.robots import load_robot

    rows = []
    for name in names:
        robot = load_robot(name)
        report = validate_dynamics(robot, samples=samples, seed=seed)
        functions = report["functions"]
        worst = max(functions.items(), key=lambda item: item[1]["max_abs_error"])
        rows.append({
            "robot": name, "nq": robot.nq, "nv": robot.nv, "mass_kg": robot.mass_kg, "feet": len(robot.feet),
            "arm_ee": robot.arm_ee, "joint_types": joint_types(robot),
            "rnea_instructions": functions["rnea"]["instructions"],
            "max_abs_error": worst[1]["max_abs_error"], "worst_function": worst[0], "samples": samples,
        })
        if on_row is not None:
            on_row(rows[-1])
    return {"samples": samples, "robots": rows, "max_abs_error": max((r["max_abs_error"] for r in rows), default=None)}
