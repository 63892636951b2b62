"""Scene objects for loco-manipulation (section VI-C) and what they measure.

Each object adds MuJoCo bodies (`bodies_mjcf`), optional model edits (`edit_spec`: tendons, sites
on the robot), an optional scripted action before every physics step (`before_step`) and a
measurement after it (`measure`): the force the end-effector applies ON the object, in world
coordinates, which the MPC never sees (it treats the arm force as a fixed input, eq. 7; with
`--object-model` it plans that force and reads the object's measured state instead).

- `CableLoad`: a box on the floor with its own friction, tied to the end-effector by a massless
  cable (a MuJoCo spatial tendon with a length limit: it pulls, never pushes). Measured: the
  cable tension and the force along the cable.
- `BoxAtWall`: a free box on the floor standing against a fixed wall. Measured: contact force of
  the end-effector sphere on the box.
- `FreeBox`: a free box on the floor to push along a path. Measured: the end-effector's contact force
  on it and its planar state (`planar_state`: x, y, yaw, vx, vy, wz), which `--object-model` feeds to the MPC.
- `Board`: a fixed board (vertical like a whiteboard, or horizontal like a table) with its own
  friction. Measured: contact force of the end-effector sphere on the board.
- `FixedBox`: a box fixed in the world (a post to reach around). Measured: whether the robot touches it.
- `ExternalHand`: a scripted hand moving the end-effector through a capped spring-damper (a
  person pushing the gripper). Measured: the force the hand applies.

`Scene` groups objects, turns them into a `MujocoPlantConfig` and records every measurement;
`Scene.replay_objects()` gives the objects' boxes and lines over the run for the HTML replay
(`wbmpc.viz.replay`): {"name", "kind": "box", "color", "half_size_m", "position_m", "rotation"}
(static, or with "t" and one pose per time) and {"name", "kind": "line", "color", "t", "points_m"}.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Protocol

import mujoco
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.robots import RobotModel
from wbmpc.sim.mujoco_scene import (
    ROBOT_CONAFFINITY,
    ROBOT_CONTYPE,
    MujocoPlantConfig,
    scene_bodies,
)

EE_SITE = "ee_attach"


def ee_body(spec: mujoco.MjSpec, robot: RobotModel):
    """(MuJoCo body carrying the arm end-effector frame, the frame's position in that body) in the scene `spec` builds."""
    name, placement = scene_bodies(spec, robot).frame(robot, robot.arm_ee)
    return spec.body(name), placement.translation.copy()


def _positive(name: str, value: float, allow_zero: bool = False) -> None:
    ok = value >= 0 if allow_zero else value > 0
    if not (np.isfinite(value) and ok):
        raise ConfigError(f"{name} must be {'>= 0' if allow_zero else 'positive'}, got {value}")


def _vec(values) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(values, dtype=float).ravel())


def _box(name: str, color: str, half_size_m, position_m, rotation=None, t=None) -> dict:
    """A box for the replay: static (one pose) or moving (`t` and one pose per time)."""
    shape = {"name": name, "kind": "box", "color": color, "half_size_m": np.asarray(half_size_m, dtype=float),
             "position_m": np.asarray(position_m, dtype=float),
             "rotation": np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)}
    if t is not None:
        shape["t"] = np.asarray(t, dtype=float)
    return shape


def _friction(mu: float) -> str:
    return _vec([mu, 0.005, 0.0001])


class SceneObject(Protocol):
    name: str

    def bodies_mjcf(self, robot: RobotModel) -> list[str]: ...

    def edit_spec(self, spec: mujoco.MjSpec, robot: RobotModel) -> None: ...

    def before_step(self, plant) -> None: ...

    def measure(self, plant) -> dict[str, np.ndarray | float]: ...

    def replay_shapes(self, recording: "SceneRecording") -> list[dict]: ...


# ----------------------------------------------------------------------------------- objects
@dataclass(frozen=True)
class CableLoad:
    """A load of `mass_kg` on the floor, its hook `cable_length_m` of cable away from the end-effector.

    `position_m` is the load centre on the floor (world x, y); the hook is on the load's face
    towards -x (the robot) at `hook_height_m`. The cable is a tendon with a length limit, soft
    like a stiff rope (`cable_timeconst_s`); its tension is the force of that limit constraint.
    """

    mass_kg: float = 10.0
    friction_mu: float = 0.3
    position_m: tuple[float, float] = (2.0, 0.0)
    size_m: tuple[float, float, float] = (0.3, 0.3, 0.2)
    hook_height_m: float = 0.1
    cable_length_m: float = 1.6
    cable_timeconst_s: float = 0.02
    name: str = "load"

    def __post_init__(self):
        _positive("load mass (kg)", self.mass_kg)
        _positive("load friction coefficient", self.friction_mu, allow_zero=True)
        _positive("cable length (m)", self.cable_length_m)
        for s in self.size_m:
            _positive("load size (m)", s)

    @property
    def hook_m(self) -> np.ndarray:
        """World position of the hook when the load rests at `position_m`."""
        return np.array([self.position_m[0] - self.size_m[0] / 2, self.position_m[1], self.hook_height_m])

    def bodies_mjcf(self, robot):
        sx, sy, sz = self.size_m
        x, y = self.position_m
        return [
            f'<body name="{self.name}" pos="{_vec([x, y, sz / 2])}"><freejoint name="{self.name}_joint"/>'
            f'<geom name="{self.name}" type="box" size="{_vec([sx / 2, sy / 2, sz / 2])}" mass="{self.mass_kg!r}" '
            f'friction="{_friction(self.friction_mu)}" priority="2" rgba=".8 .5 .2 1"/>'
            f'<site name="{self.name}_hook" pos="{_vec([-sx / 2, 0.0, self.hook_height_m - sz / 2])}" size="0.015"/>'
            "</body>"
        ]

    def edit_spec(self, spec, robot):
        _add_ee_site(spec, robot)
        tendon = spec.add_tendon(name=f"{self.name}_cable")
        tendon.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        tendon.range = [0.0, self.cable_length_m]
        tendon.solref_limit = [self.cable_timeconst_s, 1.0]
        tendon.width = 0.005
        tendon.rgba = [0.1, 0.1, 0.1, 1.0]
        tendon.wrap_site(EE_SITE)
        tendon.wrap_site(f"{self.name}_hook")

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        m, d = plant.model, plant.data
        tid = m.tendon(f"{self.name}_cable").id
        n = d.nefc
        rows = (d.efc_type[:n] == mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON) & (d.efc_id[:n] == tid)
        tension = float(np.sum(d.efc_force[:n][rows]))
        ee, hook = d.site(EE_SITE).xpos, d.site(f"{self.name}_hook").xpos
        towards_ee = (ee - hook) / max(np.linalg.norm(ee - hook), 1e-9)
        return {
            "tension_n": tension,
            "force_n": tension * towards_ee,  # the end-effector pulls the cable towards itself
            **planar_box_state(plant, self.name),
            "cable_m": np.array([ee, hook]),
        }

    def replay_shapes(self, recording):
        t, position = recording.series(self.name, "object_position_m")
        _, rotation = recording.series(self.name, "object_rotation")
        _, cable = recording.series(self.name, "cable_m")
        return [_box(self.name, "#cc8033", np.asarray(self.size_m) / 2, position, rotation, t),
                {"name": f"{self.name} cable", "kind": "line", "color": "#1a1a1a", "t": t, "points_m": cable}]


def _check_box(mass_kg: float, friction_mu: float, size_m) -> None:
    _positive("box mass (kg)", mass_kg)
    _positive("box friction coefficient", friction_mu, allow_zero=True)
    for s in size_m:
        _positive("box size (m)", s)


def _free_box_mjcf(name: str, centre_xy_m, size_m, mass_kg: float, friction_mu: float) -> str:
    """A box on the floor with a free joint (priority 2: its friction is the contact's, with floor and hand)."""
    sx, sy, sz = size_m
    return (f'<body name="{name}" pos="{_vec([centre_xy_m[0], centre_xy_m[1], sz / 2 + 1e-3])}">'
            f'<freejoint name="{name}_joint"/>'
            f'<geom name="{name}" type="box" size="{_vec([sx / 2, sy / 2, sz / 2])}" mass="{mass_kg!r}" '
            f'friction="{_friction(friction_mu)}" priority="2" rgba=".6 .45 .3 1"/></body>')


@dataclass(frozen=True)
class BoxAtWall:
    """A free box of `mass_kg` on the floor whose far face (+x) touches a fixed wall.

    `near_face_x_m` is the world x of the face the end-effector pushes; the box spans
    `size_m` (depth x, width y, height z) behind it, then comes the wall.
    """

    near_face_x_m: float = 0.5
    mass_kg: float = 5.0
    friction_mu: float = 0.5
    size_m: tuple[float, float, float] = (0.3, 0.5, 1.0)
    wall_thickness_m: float = 0.1
    name: str = "box"

    def __post_init__(self):
        _check_box(self.mass_kg, self.friction_mu, self.size_m)

    def bodies_mjcf(self, robot):
        sx = self.size_m[0]
        cx = self.near_face_x_m + sx / 2
        wall_x = self.near_face_x_m + sx + self.wall_thickness_m / 2 + 1e-3
        return [
            _free_box_mjcf(self.name, (cx, 0.0), self.size_m, self.mass_kg, self.friction_mu),
            f'<body name="{self.name}_wall" pos="{_vec([wall_x, 0.0, 1.0])}">'
            f'<geom name="{self.name}_wall" type="box" size="{_vec([self.wall_thickness_m / 2, 1.5, 1.0])}" '
            'rgba=".75 .75 .7 1"/></body>',
        ]

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        body = plant.data.body(self.name)
        return {"force_n": -plant.ee_contact_force([self.name]), "object_position_m": body.xpos.copy(),
                "object_rotation": body.xmat.reshape(3, 3).copy()}

    def replay_shapes(self, recording):
        t, position = recording.series(self.name, "object_position_m")
        _, rotation = recording.series(self.name, "object_rotation")
        sx, sy, sz = self.size_m
        wall_x = self.near_face_x_m + sx + self.wall_thickness_m / 2 + 1e-3
        return [_box(self.name, "#99734d", np.asarray(self.size_m) / 2, position, rotation, t),
                _box(f"{self.name} wall", "#bfbfb3", [self.wall_thickness_m / 2, 1.5, 1.0], [wall_x, 0.0, 1.0])]


@dataclass(frozen=True)
class FreeBox:
    """A free box of `mass_kg` on the floor (no wall) for the end-effector to push along a path.

    `near_face_x_m` is the world x of the face the end-effector pushes (the box's -x face at the start);
    its friction `friction_mu` is that of the floor and of the end-effector on it (priority: MuJoCo uses
    the box's coefficient in both contacts). Wide and deep for its height, so that the push at the hand's
    height (~0.87 m on b1_z1) slides it without tipping it (mu h < depth / 2). The object model of the MPC
    (`wbmpc.ocp.objects.SlidingBox.from_scene`) reads these same numbers. Measured: the end-effector's
    contact force on the box and its planar state [x, y, yaw, vx, vy, wz] (`planar_state`).
    """

    near_face_x_m: float = 0.45
    mass_kg: float = 5.0
    friction_mu: float = 0.3
    size_m: tuple[float, float, float] = (0.6, 0.6, 1.0)
    name: str = "box"

    def __post_init__(self):
        _check_box(self.mass_kg, self.friction_mu, self.size_m)

    @property
    def centre_xy_m(self) -> np.ndarray:
        return np.array([self.near_face_x_m + self.size_m[0] / 2, 0.0])

    def bodies_mjcf(self, robot):
        return [_free_box_mjcf(self.name, self.centre_xy_m, self.size_m, self.mass_kg, self.friction_mu)]

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        return {"force_n": -plant.ee_contact_force([self.name]), **planar_box_state(plant, self.name)}

    def replay_shapes(self, recording):
        t, position = recording.series(self.name, "object_position_m")
        _, rotation = recording.series(self.name, "object_rotation")
        return [_box(self.name, "#99734d", np.asarray(self.size_m) / 2, position, rotation, t)]


def planar_box_state(plant, name: str) -> dict:
    """Position, rotation and the planar state [x, y, yaw, vx, vy, wz] (world) of a free body."""
    body = plant.data.body(name)
    rotation = body.xmat.reshape(3, 3).copy()
    qvel = plant.data.joint(f"{name}_joint").qvel  # free joint: world linear, local angular velocity
    yaw = float(np.arctan2(rotation[1, 0], rotation[0, 0]))
    angular = rotation @ qvel[3:6]
    return {"object_position_m": body.xpos.copy(), "object_rotation": rotation,
            "planar_state": np.array([body.xpos[0], body.xpos[1], yaw, qvel[0], qvel[1], angular[2]])}


@dataclass(frozen=True)
class Board:
    """A fixed board to wipe: `normal` is the direction from the board face towards the robot side.

    `vertical` boards face -x (a whiteboard in front of the robot; `face_m` is a point of the
    face); `horizontal` boards face +z (a table top at `face_m[2]`).
    """

    orientation: str = "vertical"
    face_m: tuple[float, float, float] = (0.5, 0.0, 0.8)
    size_m: tuple[float, float] = (1.0, 0.8)  # in-plane extent
    centre_offset_m: tuple[float, float] = (0.0, 0.0)  # board centre from `face_m`, along `plane_axes`
    thickness_m: float = 0.04
    friction_mu: float = 0.3
    contact_timeconst_s: float = 0.02  # a wiping pad is soft
    # contacts act from this distance on, and the geom sits this much behind `face_m` so the
    # effective surface is at `face_m`: without it, sliding with friction chatters (contact lost
    # and re-made every few steps)
    contact_margin_m: float = 0.003
    name: str = "board"

    def __post_init__(self):
        if self.orientation not in ("vertical", "horizontal"):
            raise ConfigError(f"board orientation must be 'vertical' or 'horizontal', got {self.orientation!r}")
        _positive("board friction coefficient", self.friction_mu, allow_zero=True)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the face, pointing out of the board (towards the end-effector)."""
        return np.array([-1.0, 0.0, 0.0]) if self.orientation == "vertical" else np.array([0.0, 0.0, 1.0])

    @property
    def plane_axes(self) -> np.ndarray:
        """(2, 3) in-plane unit axes (horizontal first)."""
        if self.orientation == "vertical":
            return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

    def boxes(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(name, centre, half sizes) in world of the board and, for a table, the block under it."""
        face = np.asarray(self.face_m, dtype=float) - self.normal * self.contact_margin_m
        face = face + self.plane_axes.T @ np.asarray(self.centre_offset_m, dtype=float)
        centre = face - self.normal * self.thickness_m / 2
        half = np.abs(self.plane_axes.T @ (np.asarray(self.size_m) / 2)) + np.abs(self.normal) * self.thickness_m / 2
        out = [(self.name, centre, half)]
        if self.orientation == "horizontal":  # a table: the top rests on a block under its far edge
            height = centre[2] - self.thickness_m / 2
            leg = min(0.1, half[0])
            out.append((f"{self.name}_stand", np.array([centre[0] + half[0] - leg, centre[1], height / 2]),
                        np.array([leg, half[1] * 0.8, height / 2])))
        return out

    def replay_shapes(self, recording):
        return [_box(name.replace("_", " "), "#f2f2f2" if k == 0 else "#806633", half, centre)
                for k, (name, centre, half) in enumerate(self.boxes())]

    def bodies_mjcf(self, robot):
        (_, centre, half), *stand = self.boxes()
        bodies = [
            f'<body name="{self.name}" pos="{_vec(centre)}"><geom name="{self.name}" type="box" size="{_vec(half)}" '
            f'friction="{_friction(self.friction_mu)}" priority="2" solref="{_vec([self.contact_timeconst_s, 1.0])}" '
            f'margin="{self.contact_margin_m!r}" '
            'rgba=".95 .95 .95 1"/></body>'
        ]
        for name, stand_centre, stand_half in stand:
            bodies.append(f'<body name="{name}" pos="{_vec(stand_centre)}"><geom name="{name}" type="box" '
                          f'size="{_vec(stand_half)}" rgba=".5 .4 .3 1"/></body>')
        return bodies

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        return {"force_n": -plant.ee_contact_force([self.name])}


@dataclass(frozen=True)
class FixedBox:
    """A box fixed in the world (a post, a shelf) that the robot must not touch: `centre_m` and
    `half_size_m` along the world axes. Measured: whether any robot geom touches it (`touching`, 0/1)
    and the force of the end-effector sphere on it. Collision avoidance sees the same box as
    `wbmpc.robots.collision_model.Obstacle` (`obstacle()`)."""

    centre_m: tuple[float, float, float] = (0.8, 0.0, 0.5)
    half_size_m: tuple[float, float, float] = (0.05, 0.05, 0.5)
    name: str = "post"

    def __post_init__(self):
        for s in self.half_size_m:
            _positive("box half size (m)", s)

    def obstacle(self, keep_off: tuple[str, ...] = ("arm", "feet")):
        from wbmpc.robots.collision_model import Obstacle

        return Obstacle(self.name, tuple(self.centre_m), tuple(self.half_size_m), keep_off)

    def bodies_mjcf(self, robot):
        return [f'<body name="{self.name}" pos="{_vec(self.centre_m)}"><geom name="{self.name}" type="box" '
                f'size="{_vec(self.half_size_m)}" rgba=".85 .3 .25 1"/></body>']

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        d, m = plant.data, plant.model
        n = d.ncon
        touching = 0.0
        if n:
            box = m.geom(self.name).id
            geoms = d.contact.geom[:n]
            other = np.where(geoms[:, 0] == box, geoms[:, 1], np.where(geoms[:, 1] == box, geoms[:, 0], -1))
            other = other[other >= 0]
            touching = float(bool(np.any(plant.layout.robot_geoms[other])))
        return {"touching": touching, "force_n": -plant.ee_contact_force([self.name])}

    def replay_shapes(self, recording):
        return [_box(self.name, "#d94d40", self.half_size_m, self.centre_m)]


def contact_count(t: np.ndarray, touching: np.ndarray) -> dict:
    """Touches (a step touching after one that did not) and time in contact of a 0/1 series at physics steps."""
    touching = np.asarray(touching, dtype=bool)
    starts = int(touching[0]) + int(np.sum(touching[1:] & ~touching[:-1])) if len(touching) else 0
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return {"contacts": starts, "time_s": float(touching.sum() * dt)}


@dataclass(frozen=True)
class CompliantPad:
    """A sprung wiping pad on the end-effector: a light sphere (the pad) on three orthogonal slide
    joints with springs and dampers, replacing the rigid end-effector sphere at the same place.

    A real wiping tool is compliant (a sponge, a spring-loaded holder). Between the arm's inertia
    and a rigid sliding contact, MuJoCo's contact makes and breaks at ~200 Hz (the contact chatters);
    the spring keeps the pad pressed on while the arm moves, so the force on the board follows the
    arm's force. The spring is isotropic, `stiffness_n_m` per axis, damped at `damping_ratio` of
    critical for the pad's `mass_kg`; at 10 N and 2000 N/m it compresses 5 mm. The MPC does not
    model the pad (its mass is a few grams against the arm's kilograms).
    """

    stiffness_n_m: float = 2000.0
    damping_ratio: float = 1.0
    mass_kg: float = 0.05
    radius_m: float = 0.03
    name: str = "pad"

    def __post_init__(self):
        _positive("pad stiffness (N/m)", self.stiffness_n_m)
        _positive("pad damping ratio", self.damping_ratio, allow_zero=True)
        _positive("pad mass (kg)", self.mass_kg)
        _positive("pad radius (m)", self.radius_m)

    @property
    def damping_n_s_m(self) -> float:
        return 2.0 * self.damping_ratio * float(np.sqrt(self.stiffness_n_m * self.mass_kg))

    def bodies_mjcf(self, robot):
        return []

    def edit_spec(self, spec, robot):
        body, position = ee_body(spec, robot)
        for geom in list(body.geoms):  # the rigid end-effector sphere gives way to the pad
            if geom.name == robot.arm_ee:
                spec.delete(geom)
        inertia = 0.4 * self.mass_kg * self.radius_m**2
        pad = body.add_body(name=self.name, pos=position.tolist(), mass=self.mass_kg,
                            inertia=[inertia] * 3, explicitinertial=True)
        for axis, label in zip(np.eye(3), "xyz"):
            pad.add_joint(name=f"{self.name}_{label}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=axis.tolist(),
                          stiffness=self.stiffness_n_m, damping=self.damping_n_s_m, range=[-0.03, 0.03], limited=True)
        pad.add_geom(name=self.name, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[self.radius_m, 0, 0],
                     contype=ROBOT_CONTYPE, conaffinity=ROBOT_CONAFFINITY, rgba=[0.95, 0.75, 0.2, 1.0])

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        d = plant.data
        return {"deflection_m": np.array([d.joint(f"{self.name}_{a}").qpos[0] for a in "xyz"])}

    def replay_shapes(self, recording):
        return []  # the replay draws the end-effector itself


@dataclass(frozen=True)
class HandPush:
    """One push of the hand: from `start_s` it moves `travel_m` (world) in `move_s`, holds for
    `hold_s`, then lets go."""

    start_s: float
    travel_m: tuple[float, float, float]
    move_s: float = 0.8
    hold_s: float = 0.5

    @property
    def end_s(self) -> float:
        return self.start_s + self.move_s + self.hold_s


@dataclass(frozen=True)
class ExternalHand:
    """A scripted hand moving the end-effector: during each `HandPush` a point moves from where the
    end-effector was at the push's start, coupled to the end-effector point by a spring-damper (a
    person's arm is compliant too) whose force is capped at `max_force_n`; between pushes the hand
    lets go. A compliant arm follows with little force; a stiff one needs the cap.
    """

    pushes: tuple[HandPush, ...] = (HandPush(1.0, (-0.12, 0.0, 0.0)),)
    stiffness_n_m: float = 400.0
    damping_n_s_m: float = 40.0
    max_force_n: float = 30.0
    name: str = "hand"

    def __post_init__(self):
        for a, b in zip(self.pushes, self.pushes[1:]):
            if b.start_s < a.end_s:
                raise ConfigError(f"hand pushes overlap: one starts at {b.start_s} s before the previous ends ({a.end_s} s)")
        for push in self.pushes:
            if not (push.move_s > 0 and push.hold_s >= 0):
                raise ConfigError(f"a hand push needs move_s > 0 and hold_s >= 0, got {push}")
        _positive("hand stiffness (N/m)", self.stiffness_n_m)
        _positive("hand damping (N s/m)", self.damping_n_s_m, allow_zero=True)
        _positive("hand force cap (N)", self.max_force_n)
        object.__setattr__(self, "_state", {})

    def push_at(self, t_s: float) -> HandPush | None:
        return next((p for p in self.pushes if p.start_s <= t_s <= p.end_s), None)

    def force_on_ee(self, t_s: float, ee_m: np.ndarray, ee_velocity_m_s: np.ndarray) -> np.ndarray:
        """Force (N, world) of the hand on the end-effector at `ee_m` moving at `ee_velocity_m_s`."""
        push = self.push_at(t_s)
        if push is None:
            self._state.clear()
            return np.zeros(3)
        if self._state.get("push") is not push:
            self._state.update(push=push, start=np.array(ee_m, dtype=float))
        share = min((t_s - push.start_s) / push.move_s, 1.0)
        travel = np.asarray(push.travel_m, dtype=float)
        velocity = travel / push.move_s if share < 1.0 else np.zeros(3)
        target = self._state["start"] + share * travel
        force = self.stiffness_n_m * (target - ee_m) + self.damping_n_s_m * (velocity - ee_velocity_m_s)
        size = np.linalg.norm(force)
        return force * (self.max_force_n / size) if size > self.max_force_n else force

    def before_step(self, plant) -> None:
        m, d = plant.model, plant.data
        body = m.body(plant.ee_body).id
        site = m.site(EE_SITE).id
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, site, velocity, 0)
        point = d.site_xpos[site]
        force = self.force_on_ee(plant.time_s, point, velocity[3:])
        self._state["last"] = force
        # xfrc_applied acts at the body's centre of mass: add the moment of the force about it
        d.xfrc_applied[body, :3] = force
        d.xfrc_applied[body, 3:] = np.cross(point - d.xipos[body], force)

    def measure(self, plant):
        return {"hand_force_n": np.array(self._state.get("last", np.zeros(3)))}

    def replay_shapes(self, recording):
        return []

    def bodies_mjcf(self, robot):
        return []

    def edit_spec(self, spec, robot):
        _add_ee_site(spec, robot)


def _add_ee_site(spec: mujoco.MjSpec, robot: RobotModel) -> None:
    """A site at the end-effector frame origin (cable attachment, hand contact point), added once."""
    body, position = ee_body(spec, robot)
    if any(s.name == EE_SITE for s in body.sites):
        return
    body.add_site(name=EE_SITE, pos=position.tolist(), size=[0.01, 0.01, 0.01])


# ----------------------------------------------------------------------------------- scene
@dataclass
class SceneRecording:
    """Measurements of every object after each physics step: `series(obj, key)` -> (t, values)."""

    t: list = field(default_factory=list)
    values: dict = field(default_factory=dict)

    def series(self, obj: str, key: str) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.t), np.array(self.values[obj][key])


class Scene:
    """Objects added to a MuJoCo plant; `attach(plant)` measures them at every physics step."""

    def __init__(self, robot: RobotModel, objects: list):
        if robot.arm_ee is None:
            raise ConfigError(f"scene objects act on the arm end-effector; {robot.name} has no arm")
        names = [o.name for o in objects]
        if len(set(names)) != len(names):
            raise ConfigError(f"scene object names must be unique, got {names}")
        self.robot = robot
        self.objects = list(objects)
        self.recording = SceneRecording()

    def plant_config(self, base: MujocoPlantConfig | None = None) -> MujocoPlantConfig:
        base = base or MujocoPlantConfig()
        bodies = tuple(b for o in self.objects for b in o.bodies_mjcf(self.robot))
        previous = base.spec_callback

        def edit(spec: mujoco.MjSpec) -> None:
            if previous is not None:
                previous(spec)
            _add_ee_site(spec, self.robot)
            for o in self.objects:
                o.edit_spec(spec, self.robot)

        return replace(base, extra_bodies_mjcf=base.extra_bodies_mjcf + bodies, spec_callback=edit)

    def attach(self, plant) -> None:
        """Run the objects' scripts before and record their measurements after every step of `plant`."""
        if not hasattr(plant, "add_step_hook"):
            raise ConfigError("scene objects need the MuJoCo plant (--plant mujoco)")
        self.recording = SceneRecording()
        plant.add_step_hook(self)

    def before_step(self, plant) -> None:
        for o in self.objects:
            o.before_step(plant)

    def after_step(self, plant) -> None:
        rec = self.recording
        rec.t.append(plant.time_s)
        for o in self.objects:
            for key, value in o.measure(plant).items():
                rec.values.setdefault(o.name, {}).setdefault(key, []).append(value)

    def replay_objects(self) -> list[dict]:
        """Boxes and lines of every object over the recorded run (for `wbmpc.viz.replay`)."""
        if not self.recording.t:
            return []
        return [shape for o in self.objects for shape in o.replay_shapes(self.recording)]

    def object(self, name: str):
        for o in self.objects:
            if o.name == name:
                return o
        raise ConfigError(f"no scene object named '{name}'")
