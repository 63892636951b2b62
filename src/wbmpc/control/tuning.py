"""Control settings that follow the robot: derived from its size, with the paper's B1 + Z1 as reference.

Every setting the paper tuned on its 61 kg B1 + Z1 (gait period, swing profile, cost weights of eq. (3),
joint PD gains of eq. (10), push detection and cadence) is carried to another robot by dimensional
analysis on its own mass M, leg length L (hip to foot in the standing pose) and the mass its arm carries,
taking B1 + Z1 as the point where the derived settings equal the paper robot's (`REFERENCE`):

- time: Froude similarity (equal v^2 / (g L)), so durations scale with sqrt(L / g): gait period, the
  push hold times; speeds with sqrt(g L): lift-off/touch-down speeds, the push-detection threshold;
- lengths with L: swing apex height;
- cost weights of eq. (3) in the robot's own units, so that the tracking optimum is the same in units
  of L and sqrt(L/g): weights on metres scale with 1/L^2, on m/s with 1/(g L), on rad/s with L/g, on
  joint accelerations with (L/g)^2; angles are unscaled. The force and torque terms only regularise
  (the force scale and the nominal standing forces are the weight shared over the stance feet in the
  OCP already, `formulations.variable_scales`, `MPC._force_guess`): they keep the paper's weights per
  N^2 and (N m)^2. Scaled by 1/(M g)^2 like the rest they grow 14x on a Go2 and hold the feet to equal
  shares of the weight (5 s trot in place: drift 1.75 cm/s against 0.06 kept);
- the legs' damping gain Kd with sqrt(M) (`_leg_damping`), as a critical damping 2 sqrt(k m) at the
  same stiffness: 2.6 on a Go2, 5 on B1 + Z1 (Froude's M L^1.5 g^0.5 gives 0.6 on a Go2, where Kd 1
  already drifts 9 cm/s on an A1, and 3.3, proportional to L, saturates its thigh joints); where the motor
  law is held between commands, each Kd is capped by the held damper's stability at that hold (`gains_at`,
  `wbmpc.control.joint_loop`: a 2.5 kg Solo12 fell at 0.03 s on sqrt(M)'s Kd 1.0 at the 500 Hz joint loop, a Go2
  at 200 Hz on its 2.6); the arm's gains with the mass it carries (the same Z1 gets the same gains on any base);
- the base's horizontal position weight (the anchor of `ReferenceConfig.base_tracking = "position"`) 10x on a
  robot without an arm (`ANCHOR_WITHOUT_ARM`): on B1 + Z1 the hand's world-frame velocity rows of eq. (7)
  hold the trunk in place too; the B1 alone walked off backwards at 12 cm/s on the paper's weight, 0.4
  cm/s (10 s) with 10x;
- two settings the reference robot does not keep, for trotting forward: the legs' posture weight 20x the paper's
  (`LEG_POSTURE`) and the acceleration regularisation 0.1x (`ACCELERATION`). With the paper's 50 per rad^2 and 1e-2
  the swing legs' acceleration cost wins over the posture targets (which move ahead with the command,
  `control/foot_placement.py`): the feet land under the hips, the base leads its support by v T_st / 2 and the
  trunk sways sideways at the gait frequency. Trot forward at 0.3 sqrt(L / L_ref) m/s, 5 s, per-tick planar base
  velocity RMSE after 2 s, go2: 0.183 m/s (paper's weights, nominal pose targets), 0.169 (posture targets), 0.073
  (weight 10x, nominal targets), 0.033 (targets and 10x), 0.036 (20x), 0.027 (20x, acceleration 0.1x); anymal_c,
  the hardest of the list: 0.054 (10x), 0.047 (20x), 0.042 (20x, 0.1x). Fatrop needs fewer iterations (go2 7.2 ->
  4.6), go2's 0.5 m/s push 1 failed step instead of 10, b1_z1's 0.8 m/s push no recovery re-solves instead of 3;
- two feet: the biped rules of `control/biped.py` (walk period from the leg length, weight shift towards
  the next stance foot, force regularisation, free hands), source "derived: biped".

`TUNINGS` holds overrides per preset (empty fields keep the derived value); `tuning_for` returns the
settings with `sources` saying for each one whether it was derived or comes from the table. A robot
loaded with --urdf from a preset's files is the same robot and gets the same settings.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from wbmpc.control.biped import BIPED_SOURCE, biped_overrides
from wbmpc.control.config import MpcConfig, PushConfig, ReferenceConfig
from wbmpc.control.interpolator import PdGains
from wbmpc.control.joint_loop import held_gains, joint_mode_inertia
from wbmpc.control.weights import CostWeights
from wbmpc.gait import SwingProfile
from wbmpc.robots import RobotModel


@dataclass(frozen=True)
class RobotScale:
    """What the settings are derived from: the robot's mass, leg length and arm (torque limits and inertia
    are reported by `wbmpc info`)."""

    mass_kg: float
    leg_length_m: float  # mean hip (first joint of the leg) to foot distance in the standing pose
    leg_torque_nm: float  # mean effort limit of the leg joints
    arm_mass_kg: float | None  # mass carried by the arm joints (None: no arm)
    inertia_kg_m2: tuple[float, float, float]  # composite rotational inertia at the CoM, standing (reported)
    feet: int = 4  # number of feet (two: the biped rules of control/biped.py)
    # the lightest mode of the legs' and the arm's joint space (kg m^2, base fixed, with the model's armature, at
    # the nominal pose): the bound of eq. (10)'s held damper (`wbmpc.control.joint_loop`); None: no such joints
    leg_joint_inertia_kg_m2: float | None = None
    arm_joint_inertia_kg_m2: float | None = None

    @classmethod
    def of(cls, robot: RobotModel) -> RobotScale:
        model = robot.model
        data = model.createData()
        q = robot.q_nominal
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        lengths = []
        for foot in robot.feet:
            frame = robot.frame_id(foot)
            joint, hip = model.frames[frame].parentJoint, None
            while joint > 1:
                hip, joint = joint, model.parents[joint]
            origin = data.oMi[hip].translation if hip is not None else data.oMi[1].translation
            lengths.append(float(np.linalg.norm(data.oMf[frame].translation - origin)))
        legs = robot.leg_joint_mask
        pin.ccrba(model, data, q, np.zeros(model.nv))
        arm_joints = [model.getJointId(name) for name, leg in zip(robot.joint_names, legs) if not leg]
        carried = {j for joint in arm_joints for j in model.subtrees[joint]}
        arm_mass = float(sum(model.inertias[j].mass for j in carried))
        return cls(mass_kg=robot.mass_kg, leg_length_m=float(np.mean(lengths)),
                   leg_torque_nm=float(np.mean(robot.tau_max[legs])),
                   arm_mass_kg=arm_mass if robot.arm_ee and arm_joints else None,
                   inertia_kg_m2=tuple(float(x) for x in np.diag(data.Ig.inertia)),
                   leg_joint_inertia_kg_m2=joint_mode_inertia(robot, legs),
                   arm_joint_inertia_kg_m2=joint_mode_inertia(robot, ~legs), feet=len(robot.feet))


ARM_MASS_KG = 4.74849502  # the Z1's links below its first joint, gripper included
# B1 + Z1 (the paper's robot, preset b1_z1) as RobotScale.of measures it: the default
# settings belong to this robot (a test checks that the preset still measures this).
REFERENCE = RobotScale(mass_kg=60.90997083000001, leg_length_m=0.5038964968484939, leg_torque_nm=108.11116666666665,
                       arm_mass_kg=ARM_MASS_KG, inertia_kg_m2=(1.9978002757960795, 6.102540023768754, 5.734928234776217),
                       leg_joint_inertia_kg_m2=0.03734085573998684, arm_joint_inertia_kg_m2=0.007888212427344573)
REFERENCE_GAIT_PERIOD_S = 0.8  # the paper's trot
ANCHOR_WITHOUT_ARM = 10.0  # base x/y position weight factor on a robot without an arm (module docstring)
LEG_POSTURE = 20.0  # leg joint posture weight factor over the paper's 50 (module docstring)
ACCELERATION = 0.1  # acceleration regularisation factor over the paper's 1e-2 (module docstring)
# RobotTuning's settings of push recovery mode (PushConfig field by tuning name) and of the targets (ReferenceConfig)
TUNED_PUSH = {"push_velocity_error_m_s": "velocity_error_m_s", "push_hold_s": "hold_s",
              "push_cadence_hold_s": "cadence_hold_s"}
TUNED_REFERENCES = ("support_sway", "support_lead_s", "support_sway_free_ee", "free_ee_without_command",
                    "swing_placement")
# settings renamed (old report name -> new): the report carries both for one release
RENAMED_SETTINGS = {"support_sway_free_hands": "support_sway_free_ee",
                    "base_linear_velocity_hand_held": "base_linear_velocity_ee_commanded"}
DEFAULT_HOLD_S = 1 / 500  # eq. (10) held one tick of the paper's 500 Hz joint loop (`LoopConfig.control_rate_hz`)


@dataclass(frozen=True)
class RobotTuning:
    """Control settings of one robot (units in the names); `sources` says where each came from."""

    weights: CostWeights = field(default_factory=CostWeights)
    gains: PdGains = field(default_factory=PdGains)
    swing: SwingProfile = field(default_factory=SwingProfile)
    gait_period_s: float | None = None  # None: the gait's default
    push_velocity_error_m_s: float = PushConfig.velocity_error_m_s
    push_hold_s: float = PushConfig.hold_s
    push_cadence_hold_s: float = PushConfig.cadence_hold_s
    support_sway: float = ReferenceConfig.support_sway  # bipeds: lean over the next stance foot (control/biped.py)
    support_lead_s: float = ReferenceConfig.support_lead_s
    support_sway_free_ee: float | None = ReferenceConfig.support_sway_free_ee
    free_ee_without_command: bool = ReferenceConfig.free_ee_without_command
    swing_placement: bool = ReferenceConfig.swing_placement  # bipeds: swing feet carried to a landing point
    # the base's linear velocity weight in tasks that hold a hand (`for_task`; g1's table); None: weights' own
    base_linear_velocity_ee_commanded: float | None = None
    # the ground's friction coefficient the MPC plans with (eq. 6's cone rows; `--friction`)
    friction_coefficient: float = MpcConfig.friction_coefficient
    # the lightest joint-space modes (kg m^2, `RobotScale`): the held damper's bound (`gains_at`)
    leg_joint_inertia_kg_m2: float | None = None
    arm_joint_inertia_kg_m2: float | None = None
    note: str = ""
    sources: dict = field(default_factory=dict, compare=False)

    def gains_at(self, hold_s: float = DEFAULT_HOLD_S) -> PdGains:
        """The PD gains of eq. (10) for a motor law held `hold_s` seconds between evaluations
        (`wbmpc.control.joint_loop.hold_s`): each Kd capped by the held damper's stability."""
        return held_gains(self.gains, self.leg_joint_inertia_kg_m2, self.arm_joint_inertia_kg_m2, hold_s)

    def push_config(self, **settings) -> PushConfig:
        """Push recovery mode with these settings' detection and hold times (`settings`: the other fields)."""
        return PushConfig(**{key: getattr(self, name) for name, key in TUNED_PUSH.items()}, **settings)

    def reference_config(self, **settings) -> ReferenceConfig:
        """How the targets are formed with these settings' biped rules (`settings`: the other fields)."""
        return ReferenceConfig(**{name: getattr(self, name) for name in TUNED_REFERENCES}, **settings)

    def apply_to(self, config: MpcConfig) -> MpcConfig:
        """`config` with these settings (weights, swing, gait period, push detection, biped rules)."""
        return dataclasses.replace(
            config, weights=self.weights, swing=self.swing, gait_period_s=self.gait_period_s,
            friction_coefficient=self.friction_coefficient, push=dataclasses.replace(config.push, **{key: getattr(self, name) for name, key in TUNED_PUSH.items()}),
            references=dataclasses.replace(config.references, **{name: getattr(self, name) for name in TUNED_REFERENCES}))

    def as_used_in(self, config: MpcConfig) -> RobotTuning:
        """These settings as `config` holds them (a run's options or its task may have changed some)."""
        return dataclasses.replace(
            self, weights=config.weights, swing=config.swing, gait_period_s=config.gait_period_s,
            friction_coefficient=config.friction_coefficient, **{name: getattr(config.push, key) for name, key in TUNED_PUSH.items()},
            **{name: getattr(config.references, name) for name in TUNED_REFERENCES})

    def for_task(self, commands_ee: bool) -> RobotTuning:
        """The settings of a task that holds a hand (its velocity or force commanded: arm-track, pull, ...) or
        not: with a hand held the base velocity weight is `base_linear_velocity_ee_commanded` if set (g1's table)."""
        if not commands_ee or self.base_linear_velocity_ee_commanded is None:
            return self
        weights = dataclasses.replace(self.weights, base_linear_velocity=self.base_linear_velocity_ee_commanded)
        return dataclasses.replace(self, weights=weights, sources={
            **self.sources, "weights.base_linear_velocity": self.sources.get("base_linear_velocity_ee_commanded", "default")})

    def report(self, options: dict | None = None, hold_s: float = DEFAULT_HOLD_S) -> dict:
        """{setting: {"value", "source"}} for `wbmpc info` and a run's metrics; `options` ({name: value})
        are settings given on the command line (source "option"); the gains are those for a motor law held
        `hold_s` (the paper's 500 Hz joint loop by default)."""
        held = self.gains_at(hold_s)
        flat = {"gait_period_s": self.gait_period_s,
                **{f"swing.{k}": v for k, v in dataclasses.asdict(self.swing).items()},
                **{f"gains.{k}": v for k, v in dataclasses.asdict(held).items()},
                **{f"weights.{k}": (list(v) if isinstance(v, tuple) else v)
                   for k, v in dataclasses.asdict(self.weights).items()},
                "push_velocity_error_m_s": self.push_velocity_error_m_s, "push_hold_s": self.push_hold_s,
                "push_cadence_hold_s": self.push_cadence_hold_s, "support_sway": self.support_sway,
                "support_lead_s": self.support_lead_s, "support_sway_free_ee": self.support_sway_free_ee,
                "free_ee_without_command": self.free_ee_without_command, "swing_placement": self.swing_placement,
                "base_linear_velocity_ee_commanded": self.base_linear_velocity_ee_commanded,
                "friction_coefficient": self.friction_coefficient}
        out = {name: {"value": value, "source": self.sources.get(name, "default")} for name, value in flat.items()}
        for key, value in dataclasses.asdict(held).items():
            if value != getattr(self.gains, key):
                out[f"gains.{key}"]["source"] = f"joint loop: {getattr(self.gains, key):.3g} capped, held {1e3 * hold_s:.3g} ms"
        for old_name, name in RENAMED_SETTINGS.items():  # the names of before, one release (CHANGELOG.md)
            out[old_name] = out[name]
        for name, value in (options or {}).items():
            out[name] = {"value": value, "source": "option"}
        return out


def _leg_damping(scale: RobotScale) -> float:
    """Kd of the legs: 5 on B1 + Z1, times sqrt(M / M_ref) (2.6 on Go2, 2.4 on A1): the damping the legs get
    from a motor law evaluated continuously; a joint loop that holds the law's torque between commands caps
    it by the stability of the held damper (`RobotTuning.gains_at`, `wbmpc.control.joint_loop`).

    A1, 2 s trot in place: Kd 1 drifts 9.4 cm/s, 3 holds, 5 (B1's) saturates the calves at touch-down;
    Go2, 5 s: Kd 3.3 (proportional to L) saturates the thigh joints (torque ratio 1.0), 2.6 holds (0.55)."""
    return PdGains().kd_leg * math.sqrt(scale.mass_kg / REFERENCE.mass_kg)


def derive(scale: RobotScale) -> RobotTuning:
    """The settings of a robot of this scale (module docstring): equal to the defaults at `REFERENCE`."""
    s = scale.leg_length_m / REFERENCE.leg_length_m  # length ratio
    time, speed = math.sqrt(s), math.sqrt(s)  # Froude: durations sqrt(L/g), speeds sqrt(g L)
    w = CostWeights()
    # a biped's hands swing free (control/biped.py): no hand velocity rows hold its trunk either
    anchor = 1.0 if scale.arm_mass_kg is not None and scale.feet != 2 else ANCHOR_WITHOUT_ARM
    position = (anchor * w.base_position[0], anchor * w.base_position[1], w.base_position[2])
    weights = CostWeights(
        base_position=tuple(x / s**2 for x in position),
        base_orientation=w.base_orientation,
        leg_joint_position=LEG_POSTURE * w.leg_joint_position,
        arm_joint_position=w.arm_joint_position,
        base_linear_velocity=w.base_linear_velocity / speed**2,
        base_angular_velocity=w.base_angular_velocity * time**2,
        joint_velocity=w.joint_velocity * time**2,
        acceleration=ACCELERATION * w.acceleration * time**4,
        contact_force=w.contact_force,  # regularisation: per N^2 as on the paper robot (module docstring)
        joint_torque=w.joint_torque,
        soft_constraint=w.soft_constraint,
    )
    g = PdGains()
    arm = 1.0 if scale.arm_mass_kg is None else scale.arm_mass_kg / REFERENCE.arm_mass_kg
    gains = PdGains(kp_leg=g.kp_leg, kd_leg=_leg_damping(scale), kp_arm=g.kp_arm * arm, kd_arm=g.kd_arm * arm)
    sw = SwingProfile()
    swing = SwingProfile(apex_height_m=sw.apex_height_m * s, liftoff_velocity_m_s=sw.liftoff_velocity_m_s * speed,
                         touchdown_velocity_m_s=sw.touchdown_velocity_m_s * speed)
    push = PushConfig
    tuning = RobotTuning(weights=weights, gains=gains, swing=swing, gait_period_s=REFERENCE_GAIT_PERIOD_S * time,
                         push_velocity_error_m_s=push.velocity_error_m_s * speed, push_hold_s=push.hold_s * time,
                         push_cadence_hold_s=push.cadence_hold_s * time, note="derived from the robot's size",
                         leg_joint_inertia_kg_m2=scale.leg_joint_inertia_kg_m2,
                         arm_joint_inertia_kg_m2=scale.arm_joint_inertia_kg_m2)
    tuning = dataclasses.replace(tuning, sources={name: "derived" for name in tuning.report()})
    if scale.feet == 2:
        tuning = with_overrides(tuning, {**biped_overrides(scale.leg_length_m),
                                         "weights.base_position": weights.base_position}, source=BIPED_SOURCE)
        tuning = dataclasses.replace(tuning, note="derived from the robot's size, biped rules (control/biped.py)")
    return tuning


# Overrides per preset: {setting: value} with the names of `RobotTuning.report` ("gains.kd_leg",
# "swing.apex_height_m", "gait_period_s", ...); every other setting stays derived.
TUNINGS: dict[str, dict] = {
    # ANYmal B + Kinova, 5 s trot in place: its 6-DoF arm's hand rows do not hold the trunk as the Z1's do
    # on B1 (derived settings: drift 2.97 cm/s, 9.4 settled); the anchor of a robot without an arm: 0.31
    "anymal_b_kinova": {"weights.base_position": (5180.0, 5180.0, 10360.0)},
    # Go1, trot forward at 0.22 m/s (6 s, compiled Fatrop): the derived 4.3 cm steps run its 23.7 N m thigh
    # motors into their limits, 14.4 iterations a step and 39 failed steps of 480; 3 cm steps: 6.0 and 0
    # (trot in place, 10 s: 6.2 -> 5.5 iterations, drift 0.06 -> 0.05 cm/s)
    "go1": {"swing.apex_height_m": 0.03},
    # A1, the same (derived 4.1 cm): trotting forward at 0.22 m/s 6.8 -> 5.9 iterations, 7 -> 0 failed steps;
    # in place (10 s) unchanged: drift 0.06 cm/s, 6.7 -> 6.4 iterations
    "a1": {"swing.apex_height_m": 0.03},
    # TALOS (90 kg on two legs): the torque regularisation of eq. (3) at 1e-3 per (N m)^2 outweighed the posture
    # on the torque nodes k < 3: its standing plans let the soles carry 829 N of its 886 N weight there (base
    # accelerating down at 0.7 m/s^2, pitching back), the applied torques sagged it backwards and it fell at 0.9 s;
    # 1e-5: 885 N, 10 s standing with 0 failed steps. Not a biped rule: on g1 (33 kg) 1e-5 took walking forward
    # from 0 to 35 failed steps of 800 (14.5 -> 17.0 iterations)
    # g1: with the hands free the lean over the next stance foot is not needed (the placed swing foot does the
    # work) and only adds sway, so support_sway_free_ee is 0 (walking forward at 0.3 m/s, per-tick base velocity
    # error 0.134 against 0.175 m/s with the lean); a task that holds the end-effector keeps the lean (without it
    # arm-track while walking fell). The base's linear velocity weight is 1000 (the biped rule's 5): the pelvis
    # carries the commanded velocity and the hips and trunk take up the sway from one sole to the other (0.020
    # against 0.134 m/s, 0 failed steps; the CoM still sways, as it must: `com_vel_rmse_settled`). With the
    # end-effector commanded it stays 5: the pinned end-effector and the lean leave the trunk little room (arm-track
    # walking in place failed 25 steps of 800 at 1000, 0 at 5). Not a biped rule: TALOS fell at 1000.
    "g1": {"support_sway_free_ee": 0.0, "weights.base_linear_velocity": 1000.0, "base_linear_velocity_ee_commanded": 5.0},
    "talos": {"weights.joint_torque": 1e-5},
    "talos_full": {"weights.joint_torque": 1e-5},
}


def with_overrides(tuning: RobotTuning, overrides: dict, source: str = "table") -> RobotTuning:
    """`tuning` with some settings replaced (names of `RobotTuning.report`), their source recorded."""
    groups: dict[str, dict] = {}
    top: dict = {}
    sources = dict(tuning.sources)
    for name, value in overrides.items():
        group, _, key = name.partition(".")
        if key:
            groups.setdefault(group, {})[key] = tuple(value) if isinstance(value, list) else value
        else:
            top[name] = value
        sources[name] = source
    for group, values in groups.items():
        top[group] = dataclasses.replace(getattr(tuning, group), **values)
    return dataclasses.replace(tuning, **top, sources=sources)


def tuning_for(robot: RobotModel | str) -> RobotTuning:
    """The settings of a robot (or a preset by name): derived from its size, then the table's overrides."""
    if isinstance(robot, str):
        from wbmpc.robots import load_robot

        robot = load_robot(robot)
    tuning = derive(RobotScale.of(robot))
    overrides = TUNINGS.get(robot.name) or TUNINGS.get(robot.spec.like_preset)  # another file of a preset's robot
    tuning = with_overrides(tuning, overrides) if overrides else tuning
    return tuning
