"""A robot's shins as two-link legs in their sagittal planes: where the knee is for a hip and a foot, and how thick
the shins are (what the terrain's footholds and swings keep clear of step edges, `control/terrain_references.py`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.robots import RobotModel

SHIN_MIN_HEIGHT = 0.3  # the shin's top: the first joint up the leg this share of the standing height above the foot
SHIN_RADIUS_M = 0.02  # a shin's half thickness where the robot's description has no primitive for it


class LegShins:
    """The shins of a robot's legs in their sagittal planes: each leg as two links, hip (the joint above the knee) ->
    knee (the first joint up the leg at least SHIN_MIN_HEIGHT standing heights above the contact point) -> contact
    point, with the knee on the side it is in the nominal pose. `knees` places the knee for a hip and a foot (planar
    inverse kinematics), `clearance` measures how far the shin (knee -> foot) keeps over the terrain."""

    def __init__(self, robot: RobotModel):
        model, data = robot.model, robot.model.createData()
        pin.framesForwardKinematics(model, data, robot.q_nominal)
        rotation = data.oMi[1].rotation
        base = data.oMi[1].translation
        hips, lengths, sides, legged = [], [], [], []
        self.shin_joints: set[int] = set()  # the joints from the knees down (their links make the shins)
        for foot in robot.feet:
            frame = robot.frame_id(robot.contact_frame(foot))
            contact = data.oMf[frame].translation
            joint = model.frames[frame].parentJoint
            knee = None
            while joint > 1:
                self.shin_joints.add(joint)
                if (rotation.T @ (data.oMi[joint].translation - contact))[2] >= SHIN_MIN_HEIGHT * robot.q_nominal[2]:
                    knee = joint
                    break
                joint = model.parents[joint]
            if knee is None or model.parents[knee] <= 1:
                hips.append(np.zeros(3)), lengths.append((1.0, 1.0)), sides.append(0.0), legged.append(False)
                continue
            k, h = data.oMi[knee].translation, data.oMi[model.parents[knee]].translation
            hips.append(rotation.T @ (h - base))
            lengths.append((float(np.linalg.norm(k - h)), float(np.linalg.norm(contact - k))))
            # the knee's side of the hip -> foot line in the sagittal plane (x forward, z up): the cross product's sign
            (hx, hz), (kx, kz), (fx, fz) = ((rotation.T @ (v - base))[[0, 2]] for v in (h, k, contact))
            sides.append(float(np.sign((fx - hx) * (kz - hz) - (fz - hz) * (kx - hx))))
            legged.append(True)
        self.hip_offsets_m = np.array(hips)  # hips in the base frame
        self.lengths_m = np.array(lengths)  # (thigh, shin) per leg
        self.sides = np.array(sides)
        self.legged = np.array(legged)

    def knees(self, foot: int, hip_sz: np.ndarray, feet_sz: np.ndarray) -> np.ndarray:
        """Knee positions (..., 2) in a sagittal plane (along the heading, up) for hips and feet (..., 2)."""
        thigh, shin = self.lengths_m[foot]
        d = feet_sz - hip_sz
        distance = np.clip(np.linalg.norm(d, axis=-1), abs(thigh - shin) + 1e-6, thigh + shin - 1e-6)
        angle = np.arccos(np.clip((thigh**2 + distance**2 - shin**2) / (2 * thigh * distance), -1.0, 1.0))
        unit = d / np.linalg.norm(d, axis=-1, keepdims=True)
        turn = self.sides[foot] * angle  # rotate the hip -> foot direction towards the knee's side
        c, s = np.cos(turn)[..., None], np.sin(turn)[..., None]
        rotated = np.concatenate([c * unit[..., :1] - s * unit[..., 1:], s * unit[..., :1] + c * unit[..., 1:]], axis=-1)
        return hip_sz + thigh * rotated


def shin_radius_m(robot: RobotModel) -> float:
    """The shins' half thickness: of the URDF's collision primitives on the links from the knees down (a box's middle
    half size, a capsule's or cylinder's radius), the largest; SHIN_RADIUS_M where the robot has none (meshes, no
    URDF)."""
    from wbmpc.robots.urdf_geometry import collision_primitives

    shins = LegShins(robot)
    urdf = getattr(robot.spec, "urdf", None)
    primitives = collision_primitives(robot.model, urdf) if urdf else []
    sizes = [sorted(p.size)[1] if p.kind == "box" else p.size[0] for p in primitives
             if p.joint_id in shins.shin_joints and p.kind in ("box", "capsule", "cylinder")]
    return float(max(sizes, default=SHIN_RADIUS_M))
