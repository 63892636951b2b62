"""The per-step targets of the cost (eq. 3) and the swing-feet references, formed from the commands.

The base follows the commanded velocity from a position reference (`ReferenceConfig.base_tracking`), the
joints a nominal posture moved with the feet (`foot_placement.StanceReference`); bipeds lean over their
next stance foot (`sway_towards_support`) and carry their swing feet to a landing point (`swing_references`).
On a terrain (`ReferenceConfig.terrain`) the base rides over its support and the feet land on it
(`terrain_step`, control/terrain_references.py).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from wbmpc.control.commands import Commands
from wbmpc.control.config import ReferenceConfig
from wbmpc.control.foot_placement import StanceReference, SwingPlacement, heading_of
from wbmpc.control.terrain_references import TerrainReferences, TerrainStep
from wbmpc.gait import GaitClock, SwingProfile
from wbmpc.robots import RobotModel

MAX_ANCHOR_OFFSET_M = 0.3  # the base's position reference stays this close to the measured base (no wind-up)


class References:
    """Targets of one robot's steps; keeps the base's position reference between steps (`reset` forgets it)."""

    def __init__(self, robot: RobotModel, config: ReferenceConfig, gait: GaitClock, difference,
                 swing: SwingProfile | None = None):
        self.robot = robot
        self.config = config
        self.gait = gait
        self._difference = difference  # the MPC's buffered q (-) q_k over the nodes
        self._nominal_targets = None  # q_nominal on every node, copied by each step's `targets`
        self._data = robot.model.createData()
        self._foot_ids = [robot.frame_id(robot.contact_frame(foot)) for foot in robot.feet]  # soles of flat feet
        self._ee_id = robot.frame_id(robot.arm_ee) if robot.arm_ee else None
        self._stance_reference = self.stance_reference = StanceReference(robot) if config.stance_posture else None
        self._swing_placement = SwingPlacement(robot) if config.swing_placement else None
        # on a terrain (not the flat floor): its footholds, swing splines, cone normals and base targets
        self.terrain = TerrainReferences(robot, config.terrain, swing or SwingProfile(), config.footholds,
                                         config.support_lead_s) if config.terrain is not None and not config.terrain.is_flat else None
        # the base's position reference (`base_tracking` "position": the commanded velocity integrated from where the
        # run started; "velocity": the measured base of the last step), world x/y and yaw; None before a step
        self.anchor_xy_m: np.ndarray | None = None
        self.anchor_yaw_rad: float | None = None
        self.last_t_s: float | None = None  # time of the last step's targets

    def reset(self) -> None:
        self.anchor_xy_m = None
        self.anchor_yaw_rad = None
        self.last_t_s = None
        if self.terrain is not None:
            self.terrain.reset()

    def ee_free(self, commands: Commands) -> bool:
        """The end-effector's velocity rows are dropped this step (`free_ee_without_command`, no command)."""
        return bool(self.config.free_ee_without_command and self.robot.arm_ee and commands.ee_velocity_m_s is None)

    def ee_velocity(self, q: np.ndarray, commands: Commands, base_velocity_world: np.ndarray) -> np.ndarray:
        """The end effector's world velocity reference of eq. (7): the command, else the hand carried with the
        commanded base motion (the base's velocity plus, turning, the yaw rate about the base). Held still in the
        world instead, the hand pinned a turn about itself: b1_z1 turning in place at 0.6 rad/s swung its base
        sideways at 0.25 m/s."""
        if commands.ee_velocity_m_s is not None:
            return np.asarray(commands.ee_velocity_m_s, dtype=float)
        if not commands.base_yaw_rate_rad_s or self._ee_id is None:
            return base_velocity_world
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        lever = self._data.oMf[self._ee_id].translation - q[:3]
        return base_velocity_world + np.cross([0.0, 0.0, commands.base_yaw_rate_rad_s], lever)

    def targets(self, q: np.ndarray, rot: np.ndarray, commands: Commands, t_s: float, node_times: np.ndarray):
        """dq_des per node (nominal posture, base following the commanded velocity), v_des, and the
        commanded base velocity in world coordinates (`advance`, then `targets_at`)."""
        v_world = self.advance(q, rot, commands, t_s)
        return (*self.targets_at(q, rot, commands, t_s, node_times, v_world), v_world)

    def advance(self, q: np.ndarray, rot: np.ndarray, commands: Commands, t_s: float) -> np.ndarray:
        """Move the base anchor to `t_s` along the command; returns the commanded base velocity in world coordinates."""
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        dt_since = 0.0 if self.last_t_s is None else max(0.0, t_s - self.last_t_s)
        self.last_t_s = t_s
        velocity_only = self.config.base_tracking == "velocity"
        if self.anchor_xy_m is None or velocity_only:
            self.anchor_xy_m, self.anchor_yaw_rad = q[:2].copy(), yaw
        command = np.asarray(commands.base_velocity_m_s, dtype=float)
        cos_y, sin_y = math.cos(self.anchor_yaw_rad), math.sin(self.anchor_yaw_rad)
        cx, cy, cz = command.tolist()  # (Python floats: the same products, without NumPy scalars)
        v_world = np.array([cos_y * cx - sin_y * cy, sin_y * cx + cos_y * cy, cz])
        if not velocity_only:
            self.anchor_xy_m = self.anchor_xy_m + v_world[:2] * dt_since
            self.anchor_yaw_rad = self.anchor_yaw_rad + commands.base_yaw_rate_rad_s * dt_since
        offset = self.anchor_xy_m - q[:2]
        distance = math.hypot(offset[0], offset[1])
        if distance > MAX_ANCHOR_OFFSET_M:
            self.anchor_xy_m = q[:2] + MAX_ANCHOR_OFFSET_M * offset / distance
        return v_world

    def targets_at(self, q: np.ndarray, rot: np.ndarray, commands: Commands, t_s: float, node_times: np.ndarray,
                   v_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """dq_des at the nodes `t_s + node_times` from the anchor `advance` set, and v_des."""
        robot, command = self.robot, np.asarray(commands.base_velocity_m_s, dtype=float)
        if self._nominal_targets is None or len(self._nominal_targets) != len(node_times):
            self._nominal_targets = np.tile(robot.q_nominal, (len(node_times), 1))
        targets = self._nominal_targets.copy()
        if self._stance_reference is not None:
            targets[:, 7:] += self._stance_reference.joint_offsets(self.gait, t_s + node_times, command,
                                                                   commands.base_yaw_rate_rad_s)
        targets[:, :2] = self.anchor_xy_m + node_times[:, None] * v_world[:2]  # (np.outer, without its Python)
        if commands.base_height_m is not None:
            targets[:, 2] = commands.base_height_m
        yaws = self.anchor_yaw_rad + commands.base_yaw_rate_rad_s * node_times
        targets[:, 3:5] = 0.0
        half_yaws = yaws / 2
        targets[:, 5], targets[:, 6] = np.sin(half_yaws), np.cos(half_yaws)
        if self.terrain is not None:  # height over the terrain's support, its pitch
            self.terrain.shape_base_targets(targets, yaws)
        dq_des = self._difference(q, targets.T, shaped=True)[0].copy()
        v_des = np.zeros(robot.nv)
        v_des[:3] = rot.T @ v_world
        v_des[3:6] = commands.base_yaw_rate_rad_s * rot[2]  # rot.T (0, 0, yaw rate)
        return dq_des, v_des

    def sway(self, commands: Commands) -> float:
        """The share of the lean over the stance feet this step (`support_sway`, `support_sway_free_ee`)."""
        if self.config.support_sway_free_ee is not None and self.ee_free(commands):
            return self.config.support_sway_free_ee
        return self.config.support_sway

    def sway_towards_support(self, q: np.ndarray, rot: np.ndarray, dq_des: np.ndarray, t_s: float,
                             node_times: np.ndarray, sway: float) -> np.ndarray:
        """Base xy targets moved by `sway` x (centre of each node's stance feet `support_lead_s` later - centre
        of all feet): a biped's pelvis leans over the foot it will stand on, so the plan shifts its weight in
        double support instead of lifting a foot with the CoM between the feet (measured foot positions)."""
        contact = self.gait.contact(t_s + node_times + self.config.support_lead_s)
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        feet = np.array([self._data.oMf[i].translation[:2] for i in self._foot_ids])
        stance = contact / np.maximum(contact.sum(axis=1, keepdims=True), 1)
        shift = sway * (stance @ feet - feet.mean(axis=0))  # (nodes, 2) world
        dq_des = dq_des.copy()  # (nv, nodes); its base position part is (nearly) in the base frame
        dq_des[:3] += rot.T[:, :2] @ shift.T
        return dq_des

    @property
    def swing_placement(self) -> SwingPlacement | None:
        """The swing feet's landing placement (`ReferenceConfig.swing_placement`), None without."""
        return self._swing_placement

    def foot_frames(self, q: np.ndarray) -> list:
        """The feet's (flat feet's soles') placements at q (pinocchio SE3s: translation, rotation): the joints' and
        these frames' placements only (framesForwardKinematics' for every frame of g1 cost twice as much)."""
        model, data = self.robot.model, self._data
        pin.forwardKinematics(model, data, q)
        return [pin.updateFramePlacement(model, data, i) for i in self._foot_ids]

    def swing_references(self, q, v, rot, t_s, node_times, command_world, yaw_rate_rad_s: float = 0.0
                         ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Swing feet's xy velocity references to their landing points and swing soles' yaw rates to their headings
        at touch-down (`SwingPlacement.velocities`, `yaw_rates`: one forward kinematics and one pass over the
        horizon's swings for both), each None without a placement (the yaw rates also without flat feet)."""
        if self._swing_placement is None:
            return None, None
        frames = self.foot_frames(q)
        placement, swings = self._swing_placement, self._swing_placement.swings(self.gait, t_s, node_times)
        velocities = placement.velocities(self.gait, t_s, node_times, q, rot @ v[:3], command_world, heading_of(rot),
                                          np.array([frame.translation for frame in frames]), yaw_rate_rad_s, swings)
        if not self.robot.soles:
            return velocities, None
        feet_yaw = np.array([heading_of(frame.rotation) for frame in frames])
        return velocities, placement.yaw_rates(self.gait, t_s, node_times, heading_of(rot), yaw_rate_rad_s, feet_yaw,
                                               swings)

    def follow_support(self, rot: np.ndarray, dq_des: np.ndarray, terrain: TerrainStep) -> np.ndarray:
        """Base xy targets moved with the footholds of a biped's support on a terrain
        (`TerrainReferences.support_shift`)."""
        if terrain.support_shift_m is None:
            return dq_des
        dq_des = dq_des.copy()  # (nv, nodes); its base position part is (nearly) in the base frame
        dq_des[:3] += rot.T[:, :2] @ terrain.support_shift_m.T
        return dq_des

    def terrain_step(self, q, v, rot, t_s, node_times, command_world) -> TerrainStep | None:
        """On a terrain, this step's swing references, footholds and cone normals (`TerrainReferences.step`)."""
        if self.terrain is None:
            return None
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        feet = np.array([self._data.oMf[i].translation for i in self._foot_ids])
        yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
        return self.terrain.step(self.gait, t_s, node_times, q, rot @ v[:3], command_world, yaw, feet)
