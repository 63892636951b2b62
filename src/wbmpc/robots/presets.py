"""Robot presets from the installed example-robot-data package, and custom-URDF specs."""

from __future__ import annotations

import importlib.metadata
from dataclasses import replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from wbmpc.errors import ModelError, unknown_name
from wbmpc.robots.compose import ArmMount, compose_spec
from wbmpc.robots.model import RobotModel, RobotSpec

QUADRUPED_FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
ANYMAL_FEET = ("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT")
SOLO_FEET = ("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT")
TALOS_FEET = ("left_sole_link", "right_sole_link")


@lru_cache(maxsize=1)
def example_robot_data_dir() -> Path:
    """The `robots/` folder of the installed example-robot-data wheel (found through pip metadata)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:
        raise ModelError("example-robot-data is not installed: pip install example-robot-data") from exc
    for candidate in (
        "cmeel.prefix/share/example-robot-data/robots",
        "share/example-robot-data/robots",
    ):
        path = Path(dist.locate_file(candidate))
        if path.is_dir():
            return path
    for file in dist.files or []:
        if str(file).endswith("robots/b1_description/urdf/b1.urdf"):
            return Path(dist.locate_file(file)).parents[2]
    raise ModelError("example-robot-data is installed but its robots/ folder was not found")


def _erd(relative: str) -> Path:
    return example_robot_data_dir() / relative


# Legged robots of example-robot-data: (urdf, srdf, pose, feet, arm end-effector, locked joints).
# Quadrupeds trot under the MPC; g1 and TALOS stand and walk on flat feet (_FLAT_FEET); the other bipeds
# and humanoids keep point feet: they load, simulate and pass `bench dynamics`.
_LEGGED: dict[str, tuple] = {
    # quadrupeds (Unitree, ANYbotics, IIT, ODRI)
    "b1": ("b1_description/urdf/b1.urdf", "b1_description/srdf/b1.srdf", "standing", QUADRUPED_FEET, None, ()),
    "go1": ("go1_description/urdf/go1.urdf", "go1_description/srdf/go1.srdf", "standing", QUADRUPED_FEET, None, ()),
    "go2": ("go2_description/urdf/go2.urdf", "go2_description/srdf/go2.srdf", "standing", QUADRUPED_FEET, None, ()),
    "a1": ("a1_description/urdf/a1.urdf", "a1_description/srdf/a1.srdf", "standing", QUADRUPED_FEET, None, ()),
    "laikago": ("laikago_description/urdf/laikago.urdf", None, None, QUADRUPED_FEET, None, ()),  # pose below
    "anymal_b": ("anymal_b_simple_description/robots/anymal.urdf", "anymal_b_simple_description/srdf/anymal.srdf",
                 "standing", ANYMAL_FEET, None, ()),
    "anymal_b_kinova": ("anymal_b_simple_description/robots/anymal-kinova.urdf",
                        "anymal_b_simple_description/srdf/anymal-kinova.srdf", "standing_with_arm_up", ANYMAL_FEET,
                        "j2s6s200_end_effector", ()),
    "anymal_c": ("anymal_c_simple_description/urdf/anymal.urdf", "anymal_c_simple_description/srdf/anymal.srdf",
                 "standing", ANYMAL_FEET, None, ()),
    "hyq": ("hyq_description/robots/hyq_no_sensors.urdf", "hyq_description/srdf/hyq.srdf", "standing",
            ("lf_foot", "rf_foot", "lh_foot", "rh_foot"), None, ()),
    "solo8": ("solo_description/robots/solo.urdf", "solo_description/srdf/solo.srdf", "standing", SOLO_FEET, None, ()),
    "solo12": ("solo_description/robots/solo12.urdf", "solo_description/srdf/solo.srdf", "standing", SOLO_FEET, None, ()),
    "quadruped": ("quadruped_description/urdf/quadruped.urdf", None, None,
                  ("FL_contact", "FR_contact", "BL_contact", "BR_contact"), None, ()),
    "centauro": ("centauro_description/urdf/centauro.urdf", "centauro_description/srdf/centauro.srdf", "homing_nominal",
                 ("contact_1", "contact_2", "contact_3", "contact_4"), "arm1_8", ()),
    # bipeds and humanoids
    "bolt": ("bolt_description/robots/bolt.urdf", "bolt_description/srdf/bolt.srdf", "standing",
             ("FL_FOOT", "FR_FOOT"), None, ()),
    "alexander": ("alexander_description/urdf/alexander_v1.lowerBodyOnly.urdf", "alexander_description/srdf/alexander.srdf",
                  "default", ("LEFT_FOOT", "RIGHT_FOOT"), None, ()),
    "talos": ("talos_data/robots/talos_reduced.urdf", "talos_data/srdf/talos.srdf", "half_sitting", TALOS_FEET, None, ()),
    "talos_full": ("talos_data/robots/talos_full_v2.urdf", "talos_data/srdf/talos.srdf", "half_sitting", TALOS_FEET,
                   None, ()),
    "romeo": ("romeo_description/urdf/romeo_small.urdf", "romeo_description/srdf/romeo_small.srdf", "half_sitting",
              ("l_sole", "r_sole"), None, ()),
    "icub": ("icub_description/robots/icub_reduced.urdf", "icub_description/srdf/icub.srdf", "half_sitting",
             ("l_sole", "r_sole"), None, ()),
    "icub_full": ("icub_description/robots/icub.urdf", "icub_description/srdf/icub.srdf", "half_sitting",
                  ("l_sole", "r_sole"), None, ()),
    # g1: the right hand as end-effector; the six wrist joints locked (the hand is a point in eq. 7, its
    # orientation is not tracked, and the 1-3 N m wrists only add variables): 6 + 23 DoF
    "g1": ("g1_description/urdf/g1_29dof_rev_1_0.urdf", None, None, ("left_ankle_roll_link", "right_ankle_roll_link"),
           "right_rubber_hand", tuple(f"{side}_wrist_{axis}_joint" for side in ("left", "right")
                                      for axis in ("roll", "pitch", "yaw"))),
    "simple_humanoid": ("simple_humanoid_description/urdf/simple_humanoid.urdf",
                        "simple_humanoid_description/srdf/simple_humanoid.srdf", "half_sitting", ("l_ankle", "r_ankle"),
                        None, ()),
}
# flat feet (6D wrench at the sole, soles.py): the sole from the foot link's collision geometry (None) or a size
# (length, width) for feet whose links carry meshes only (TALOS: its 0.21 x 0.138 m sole, rounded inwards)
_FLAT_FEET: dict[str, tuple[float, float] | None] = {"g1": None, "talos": (0.2, 0.13), "talos_full": (0.2, 0.13)}
# rotor inertias reflected through the gearboxes (kg m^2), where the URDF lacks them: g1's from Unitree's
# MJCF (MuJoCo Menagerie unitree_g1). They matter beyond the model: a lifted g1 foot (0.6 kg, ~3e-4 kg m^2
# about its roll axis) under the legs' joint damping Kd ~4 at the 1 ms control tick is an unstable explicit
# damper (Kd dt / I > 2: the ankle roll rate reached 160 rad/s 40 ms into a walk) unless the plant has them
_G1_ROTORS = {"hip_pitch": 0.01017752, "hip_roll": 0.025101925, "hip_yaw": 0.01017752, "knee": 0.025101925,
              "ankle_pitch": 0.00721945, "ankle_roll": 0.00721945, "shoulder_pitch": 0.003609725,
              "shoulder_roll": 0.003609725, "shoulder_yaw": 0.003609725, "elbow": 0.003609725}
_ARMATURE: dict[str, dict[str, float] | float] = {
    "g1": {**{f"{side}_{joint}_joint": value for side in ("left", "right") for joint, value in _G1_ROTORS.items()},
           "waist_yaw_joint": 0.01017752, "waist_roll_joint": 0.00721945, "waist_pitch_joint": 0.00721945},
    # TALOS: its URDF and example-robot-data carry none; 0.01 kg m^2 on every joint is a stand-in of g1's hip
    # order, not PAL's data. Without it TALOS standing failed 57 of 104 steps in 1.3 s (explicit damping of its
    # light distal links), with it 3
    "talos": 0.01, "talos_full": 0.01,
}
# reference-pose overrides: laikago has no SRDF and its zero pose puts the knees beyond their limit;
# simple_humanoid's URDF limits are shifted by one joint along the legs, outside which its SRDF
# half-sitting pose lies, so it stands on straight legs
_POSES = {
    "simple_humanoid": {f"{side}LEG_{joint}": 0.0 for side in "LR" for joint in ("HIP_P", "KNEE", "ANKLE_P")},
    # g1 on slightly bent knees (Unitree's default standing pose; straight knees are singular), elbows bent
    "g1": {**{f"{side}_{joint}": value for side in ("left", "right")
              for joint, value in (("hip_pitch_joint", -0.1), ("knee_joint", 0.3), ("ankle_pitch_joint", -0.2),
                                   ("shoulder_pitch_joint", 0.2), ("elbow_joint", 0.6))},
           "left_shoulder_roll_joint": 0.2, "right_shoulder_roll_joint": -0.2},
    "laikago": {f"{leg}_{joint}": value for leg in ("FL", "FR", "RL", "RR")
                for joint, value in (("thigh_joint", 0.7), ("calf_joint", -1.4))},
}
# an arm on a base, composed from the two URDFs (robots/compose.py): {preset: (base preset, arm)}
Z1_ARM_UP = {"joint2": 0.26178, "joint3": -0.26178}  # z1.srdf's arm_up, as b1-z1.srdf's standing_with_arm_up
# arms of example-robot-data by name (`--arm z1 --mount FRAME`): URDF, end effector, the paper's locks, pose
NAMED_ARMS: dict[str, dict] = {
    "z1": dict(urdf="z1_description/urdf/z1.urdf", arm_ee="gripperStator", locked_joints=("joint5", "joint6", "jointGripper"),
               joint_positions_rad=Z1_ARM_UP),
}
_COMPOSED: dict[str, tuple[str, dict]] = {
    # Z1 on the Go2's back: base frame (0, 0, 0.057) m, the centre of the top of its trunk (Unitree's trunk
    # box 0.376 x 0.0935 x 0.114 m). With the arm up (z1.srdf's arm_up) the standing CoM is 6 mm ahead of
    # the feet's centre (Go2 alone: 19 mm). The paper's four arm DoF: joint5, joint6 and the gripper locked
    # as on b1_z1. 21.3 kg: the Z1 (4.7 kg) is heavy for a 16 kg Go2, a D1-class arm is lighter
    "go2_z1": ("go2", dict(mount_frame="base", mount_xyz_m=(0.0, 0.0, 0.057), **NAMED_ARMS["z1"])),
}
QUADRUPEDS = ("b1_z1", "b1_z1_full", "go2_z1", "b1", "go1", "go2", "a1", "laikago", "anymal_b", "anymal_b_kinova", "anymal_c",
              "hyq", "solo8", "solo12", "quadruped", "centauro")


def _presets() -> dict[str, RobotSpec]:
    b1z1 = dict(
        urdf=_erd("b1_description/urdf/b1-z1.urdf"),
        srdf=_erd("b1_description/srdf/b1-z1.srdf"),
        pose="standing_with_arm_up",
        feet=QUADRUPED_FEET,
        arm_ee="gripperStator",
    )
    presets = {
        # Paper model: 6 base + 12 legs + 4 arm DoF (section V-B).
        "b1_z1": RobotSpec(name="b1_z1", locked_joints=("joint5", "joint6", "jointGripper"), **b1z1),
        "b1_z1_full": RobotSpec(name="b1_z1_full", locked_joints=("jointGripper",), **b1z1),
    }
    for name, (urdf, srdf, pose, feet, arm_ee, locked) in _LEGGED.items():
        presets[name] = RobotSpec(
            name=name, urdf=_erd(urdf), srdf=_erd(srdf) if srdf else None, pose=pose, feet=feet, arm_ee=arm_ee,
            locked_joints=locked, joint_positions_rad=_POSES.get(name, {}),
            foot_contact="surface" if name in _FLAT_FEET else "point", sole_m=_FLAT_FEET.get(name),
            armature_kg_m2=_ARMATURE.get(name, 0.0),
        )
    return presets


PRESET_NAMES = ("b1_z1", "b1_z1_full", "go2_z1", *_LEGGED)


def preset_spec(name: str) -> RobotSpec:
    presets = _presets()
    if name in _COMPOSED:
        base, arm = _COMPOSED[name]
        mount = ArmMount(**{**arm, "urdf": _erd(arm["urdf"])})
        return compose_spec(presets[base], mount, name=name)[0]
    if name not in presets:
        raise ModelError(unknown_name("robot", name, PRESET_NAMES))
    return presets[name]


# --------------------------------------------------------------------------- another file of a preset's robot
MATCH_MASS_REL = 0.25  # another file of a preset's robot: its mass within this share of the preset's ...
MATCH_LEG_REL = 0.1  # ... and its leg length within this share


def matching_preset(robot: RobotModel) -> str | None:
    """The preset `robot` is another description of (Unitree's or Menagerie's MJCF of g1 or go2, a URDF with hands):
    every moving joint of the preset among the robot's (moving or locked), as many feet, the mass within 25 % and the
    legs' length (`leg_chain_length_m`, whatever the pose) within 10 % of the preset's; of several, the one with the
    most joints, then the nearest in mass and leg length (go2, go1 and a1 share their joint names)."""
    names = set(robot.full_model.names[2:])
    candidates = []
    for preset, (joints, n_feet, mass_kg) in _preset_joints().items():
        mass = abs(robot.mass_kg / mass_kg - 1.0)
        if n_feet != len(robot.feet) or not joints <= names or mass > MATCH_MASS_REL:
            continue
        leg = abs(leg_chain_length_m(robot) / leg_chain_length_m(load_robot(preset)) - 1.0)
        if leg <= MATCH_LEG_REL:
            candidates.append((-len(joints), mass + leg, preset))
    return min(candidates)[2] if candidates else None


def leg_chain_length_m(robot: RobotModel) -> float:
    """Mean over the feet of the summed distances between successive joints from the root to the foot (the legs'
    length whatever the pose)."""
    model, lengths = robot.model, []
    for foot in robot.feet:
        frame = model.frames[robot.frame_id(robot.contact_frame(foot))]
        total, joint = float(np.linalg.norm(frame.placement.translation)), frame.parentJoint
        while model.parents[joint] > 1:
            total += float(np.linalg.norm(model.jointPlacements[joint].translation))
            joint = model.parents[joint]
        lengths.append(total)
    return float(np.mean(lengths))


@lru_cache(maxsize=1)
def _preset_joints() -> dict[str, tuple[frozenset[str], int, float]]:
    """{preset: (its moving joints, its number of feet, its mass)}, read by pinocchio without loading the robots."""
    import pinocchio as pin

    out = {}
    for name in PRESET_NAMES:
        spec = preset_spec(name)
        try:
            model = pin.buildModelFromUrdf(str(spec.urdf))
        except (RuntimeError, ValueError):
            continue
        moving = frozenset(model.names[1:]) - set(spec.locked_joints)
        out[name] = (moving, len(spec.feet), float(sum(i.mass for i in model.inertias)))
    return out


def custom_robot(spec: RobotSpec) -> RobotModel:
    """A robot from the user's file with what its preset knows where the file is silent: when it is another file of
    a preset's robot (`matching_preset`), that preset's settings (`like_preset`: the tuning table's overrides), its
    rotor inertias where the file has none, its standing pose where the file has none (no SRDF pose, no keyframe),
    and its flat feet (its sole size if the file's feet carry no sole geometry) where the spec leaves the contact
    open. A robot like no preset keeps what the file says and the settings derived from its size."""
    robot = RobotModel(spec)
    like = spec.like_preset or matching_preset(robot)
    if like is None:
        return robot
    preset = load_robot(like)
    changes: dict = {"like_preset": like}
    if spec.armature_kg_m2 is None and not np.any(robot.armature_kg_m2) and np.any(preset.armature_kg_m2):
        changes["armature_kg_m2"] = {n: float(a) for n, a in zip(preset.joint_names, preset.armature_kg_m2)
                                     if n in robot.joint_names}
    if robot.pose_source == "zero" and not spec.joint_positions_rad:
        changes["joint_positions_rad"] = {n: float(x) for n, x in zip(preset.joint_names, preset.joint_positions(preset.q_nominal))
                                         if n in robot.joint_names}
    if spec.foot_contact is None and preset.soles and not robot.soles:
        changes["foot_contact"] = "surface"
        if preset.spec.sole_m is not None:
            changes["sole_m"] = preset.spec.sole_m
    try:
        return RobotModel(replace(spec, **changes))
    except ModelError:  # e.g. the preset's sole read from geometry this file's feet lack: keep the file's own
        return RobotModel(replace(spec, like_preset=like))


@lru_cache(maxsize=32)
def load_robot(name: str = "b1_z1") -> RobotModel:
    """Load a preset robot (cached: robots are immutable once built)."""
    return RobotModel(preset_spec(name))


def custom_spec(
    urdf: str | None,
    feet: list[str],
    arm_ee: str | None = None,
    srdf: str | None = None,
    pose: str | None = None,
    lock: list[str] | None = None,
    name: str | None = None,
    mjcf: str | None = None,
    keyframe: str | None = None,
) -> RobotSpec:
    """Spec for any legged robot given by the user (CLI --urdf or --mjcf, --srdf/--pose or --keyframe, --feet,
    --arm-ee, --lock)."""
    return RobotSpec(
        name=name or Path(urdf or mjcf).stem,
        urdf=Path(urdf) if urdf else None,
        mjcf=Path(mjcf) if mjcf else None,
        keyframe=keyframe,
        srdf=Path(srdf) if srdf else None,
        pose=pose,
        feet=tuple(feet),
        arm_ee=arm_ee,
        locked_joints=tuple(lock or ()),
    )
