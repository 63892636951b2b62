"""Primitive collision shapes for a `RobotModel`, expressed in the frames of its pinocchio joints.

Two sources, per moving body (= pinocchio joint):
1. the file's own primitive collision geometry (box, cylinder, sphere, capsule) of the links merged
   into that body (a URDF's `<collision>` as pinocchio reads it, an MJCF's colliding geoms as MuJoCo
   compiles them; meshes are ignored), when present and allowed;
2. otherwise shapes guessed from the kinematics: a box spanning the children's joint origins for
   the floating base, and capsules from the joint origin to each child joint origin / frame of
   interest for the other bodies.
Every point foot gets a sphere of `robot.foot_radius_m` at its frame, every flat foot a box sole
(`robot.soles`: the sole rectangle, SOLE_THICKNESS_M thick, its bottom face on the sole frame) -- the
only shape on foot links, so that the contact matches the MPC's point or surface contact model; the
arm end-effector gets an optional sphere. Capsules ending at a foot stop short and are thin enough to stay inside the foot sphere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.robots import RobotModel

MIN_SHAPE_SIZE_M = 0.005  # URDF shapes smaller than this in every direction (IMU boxes) are dropped
SOLE_THICKNESS_M = 0.01  # box soles of flat feet


@dataclass(frozen=True)
class CollisionShape:
    """A primitive in the frame of pinocchio joint `joint_id`; `size` follows MuJoCo's convention.

    kind: "sphere" (radius,), "capsule" (radius, half_length), "cylinder" (radius, half_length),
    "box" (half_x, half_y, half_z); capsule and cylinder axes are the local z axis.
    """

    name: str
    joint_id: int
    kind: str
    size: tuple[float, ...]
    pos: np.ndarray
    rotation: np.ndarray  # 3x3, shape frame in joint frame
    is_foot: bool = False


def robot_collision_shapes(
    robot: RobotModel, use_urdf_primitives: bool = True, ee_sphere_radius_m: float | None = 0.03
) -> list[CollisionShape]:
    """All collision shapes of the robot (see module docstring)."""
    model = robot.model
    shapes: list[CollisionShape] = []
    for foot in robot.feet:
        if foot in robot.soles:  # flat foot: a box whose bottom face is the sole rectangle
            sole = robot.soles[foot]
            frame = model.frames[robot.frame_id(sole.frame)]
            half = 0.5 * SOLE_THICKNESS_M
            centre = frame.placement.translation + frame.placement.rotation @ np.array([0.0, 0.0, half])
            shapes.append(CollisionShape(foot, frame.parentJoint, "box", (sole.half_length_m, sole.half_width_m, half),
                                         centre, frame.placement.rotation.copy(), True))
            continue
        frame = model.frames[robot.frame_id(foot)]
        centre = frame.placement.translation.copy()
        shapes.append(CollisionShape(foot, frame.parentJoint, "sphere", (robot.foot_radius_m,), centre, np.eye(3), True))
    if robot.arm_ee and ee_sphere_radius_m:
        frame = model.frames[robot.frame_id(robot.arm_ee)]
        centre = frame.placement.translation.copy()
        shapes.append(CollisionShape(robot.arm_ee, frame.parentJoint, "sphere", (ee_sphere_radius_m,), centre, np.eye(3)))
    urdf = urdf_primitives(robot) if use_urdf_primitives else {}
    for jid in range(1, model.njoints):
        shapes.extend(urdf.get(jid) or _kinematic_shapes(robot, jid))
    return shapes


# ------------------------------------------------------------------------------- URDF primitives
def urdf_primitives(robot: RobotModel) -> dict[int, list[CollisionShape]]:
    """URDF box/cylinder/sphere/capsule collisions (read by pinocchio, `wbmpc.robots.urdf_geometry`)
    grouped by the pinocchio joint that carries their link; none on the feet, none of IMU size."""
    foot_links = set(robot.feet)
    out: dict[int, list[CollisionShape]] = {}
    for shape in robot.collision_primitives():
        if shape.link in foot_links or max(shape.size) < MIN_SHAPE_SIZE_M:
            continue
        out.setdefault(shape.joint_id, []).append(
            CollisionShape(shape.name, shape.joint_id, shape.kind, shape.size, shape.placement.translation.copy(),
                           shape.placement.rotation.copy()))
    return out


# ------------------------------------------------------------------------------ kinematic guesses
def _kinematic_shapes(robot: RobotModel, jid: int) -> list[CollisionShape]:
    model = robot.model
    children = [model.jointPlacements[c].translation for c in range(jid + 1, model.njoints) if model.parents[c] == jid]
    if jid == 1:  # floating base: a box spanning the hips (and arm mount), as thick as it is wide
        if not children:
            return []
        pts = np.abs(np.array(children))
        hx, hy = max(pts[:, 0].max(), 0.05), max(pts[:, 1].max(), 0.03)
        return [CollisionShape("base_box", jid, "box", (hx, hy, hy), np.zeros(3), np.eye(3))]
    ends = [(p, False) for p in children]
    for name in (*robot.feet, *([robot.arm_ee] if robot.arm_ee else [])):
        if name in robot.soles:  # the box sole is the flat foot: no capsule down to it
            continue
        frame = model.frames[robot.frame_id(name)]
        if frame.parentJoint == jid:
            ends.append((frame.placement.translation, name in robot.feet))
    shapes = []
    for k, (end, to_foot) in enumerate(ends):
        length = float(np.linalg.norm(end))
        if length < 1e-6:
            continue
        radius = float(np.clip(0.1 * length, 0.01, 0.04))
        if to_foot:  # stop at the top of the foot sphere and stay thin: the foot sphere makes the contact
            radius = min(radius, 0.5 * robot.foot_radius_m)
            end = end * (1.0 - robot.foot_radius_m / length)
            length = float(np.linalg.norm(end))
        shapes.append(_capsule(f"{model.names[jid]}_capsule{k}", jid, np.zeros(3), end, radius))
    return shapes


def _capsule(name: str, jid: int, start: np.ndarray, end: np.ndarray, radius: float) -> CollisionShape:
    """Capsule between two points (a sphere when they are closer than the diameter)."""
    axis = end - start
    length = float(np.linalg.norm(axis))
    centre = 0.5 * (start + end)
    if length < 2 * radius:
        return CollisionShape(name, jid, "sphere", (radius,), centre, np.eye(3))
    z = axis / length
    rotation = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), z).matrix()
    return CollisionShape(name, jid, "capsule", (radius, 0.5 * length), centre, rotation)
