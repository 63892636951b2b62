"""Commanded object paths: the box's path of `push-box --box-path turn` / `--object-model`,
the commands that follow it with and without the object inside the MPC, and the path's tracking metrics.

`BoxPath`: at rest until `start_s`, then the box centre moves at `speed_m_s` (reached over `ramp_s`) straight
ahead for `straight_m`, turns left by 90 degrees on an arc of `radius_m` (its yaw following the path's
tangent), then goes straight again. 0.8 m: on a 0.4 m arc the push that turns the 0.6 m box at the path's rate
would need a lever of 0.47 m from the face's centre (4-corner Coulomb friction), beyond its 0.22 m. The robot's base follows the box's path at its starting offset from
the box (rotating with the box), by velocity commands with position feedback.

- force command (the paper's MPC, the box only in MuJoCo): the hand's velocity command carries it along the face
  of the box's reference pose (`feedback.ee_velocity_feedback`), its force command is the friction that slides the box, mu m g
  along the face normal, scaled with the path's speed;
- object model: the box's measured state and its path go to the MPC (`Commands.object_command`), the path's yaw
  led by the box's sideslip about the push's pivot (`sideslip_lead`); hand force and motion are the OCP's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.ocp.objects import ObjectCommand
from wbmpc.robots import GRAVITY_M_S2
from wbmpc.scenarios.metrics import base_yaw

BASE_GAIN_1_S = 1.0  # base position / yaw feedback of the path-following commands
MAX_BASE_SPEED_M_S = 0.5
MAX_YAW_RATE_RAD_S = 0.8


def _rot(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class BoxPath:
    """Planar path of the box centre: states [x, y, yaw, vx, vy, wz] at any time (see the module docstring)."""

    start_xy_m: tuple[float, float] = (0.75, 0.0)
    start_s: float = 1.0
    speed_m_s: float = 0.1
    ramp_s: float = 0.5
    straight_m: float = 0.1
    radius_m: float = 0.8
    turn_rad: float = np.pi / 2

    def distance(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Path length travelled and speed at times t."""
        tau = np.maximum(np.asarray(t_s, dtype=float) - self.start_s, 0.0)
        v, ramp = self.speed_m_s, self.ramp_s
        s = np.where(tau < ramp, 0.5 * v * tau**2 / ramp, v * (tau - 0.5 * ramp))
        return s, np.where(tau < ramp, v * tau / ramp, v)

    def states(self, t_s) -> np.ndarray:
        """(n, 6) reference states at times t."""
        t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
        s, speed = self.distance(t_s)
        arc = self.radius_m * self.turn_rad
        phi = np.clip((s - self.straight_m) / self.radius_m, 0.0, self.turn_rad)
        after = np.maximum(s - self.straight_m - arc, 0.0)
        along = np.minimum(s, self.straight_m) + self.radius_m * np.sin(phi)
        across = self.radius_m * (1 - np.cos(phi))
        # beyond the arc: straight along the final heading
        along = along + after * np.cos(self.turn_rad)
        across = across + after * np.sin(self.turn_rad)
        turning = (s > self.straight_m) & (s < self.straight_m + arc)
        rate = np.where(turning, speed / self.radius_m, 0.0)
        x0, y0 = self.start_xy_m
        return np.column_stack([x0 + along, y0 + across, phi, speed * np.cos(phi), speed * np.sin(phi), rate])

    @property
    def moving_s(self) -> float:
        """Time the path takes from its start to the end of the turn."""
        length = self.straight_m + self.radius_m * self.turn_rad
        return self.ramp_s + (length - 0.5 * self.speed_m_s * self.ramp_s) / self.speed_m_s


class PathFollower:
    """Base commands that keep the robot at its starting offset from the box's measured pose (moving at the path's
    velocity): behind the box as it actually stands. Behind its reference pose instead, a box lagging the turn put
    its corner in the way of a front foot (b1_z1 kicked it at 4 s, after which the hand lost the box)."""

    def __init__(self, path: BoxPath, base_start_xy_m: np.ndarray):
        self.path = path
        self.offset = np.asarray(base_start_xy_m, dtype=float) - np.asarray(path.start_xy_m, dtype=float)

    def base_command(self, t_s: float, q: np.ndarray, box_state: np.ndarray | None = None) -> dict:
        """Base velocity (heading frame) and yaw rate; `box_state` the measured [x, y, yaw, ...] (None: the path's)."""
        reference = self.path.states(t_s)[0]
        x, y, yaw = (reference if box_state is None else box_state)[:3]
        vx, vy, wz = reference[3:]
        arm = _rot(yaw) @ self.offset
        reference = np.array([x, y]) + arm
        velocity = np.array([vx, vy]) + wz * np.array([-arm[1], arm[0]])
        world = velocity + BASE_GAIN_1_S * (reference - q[:2])
        speed = np.linalg.norm(world)
        if speed > MAX_BASE_SPEED_M_S:
            world *= MAX_BASE_SPEED_M_S / speed
        heading = base_yaw(q)
        local = _rot(heading).T @ world
        yaw_rate = float(np.clip(wz + BASE_GAIN_1_S * float(_wrap(yaw - heading)), -MAX_YAW_RATE_RAD_S, MAX_YAW_RATE_RAD_S))
        return {"base_velocity_m_s": np.array([local[0], local[1], 0.0]), "base_yaw_rate_rad_s": yaw_rate}


def measured_box_state(scene, name: str, fallback: np.ndarray, reference_yaw: float) -> np.ndarray:
    """The box's last measured planar state (the scene's recording), its yaw unwrapped next to the reference."""
    values = scene.recording.values.get(name, {}).get("planar_state") if scene is not None else None
    state = np.array(values[-1] if values else fallback, dtype=float)
    state[2] = reference_yaw + float(_wrap(state[2] - reference_yaw))
    return state


def sideslip_lead(path: BoxPath, t_s, pivot_m: float) -> np.ndarray:
    """The yaw (rad) by which the box must lead its path's tangent at times t so that its centre moves along the path.

    Pushed at the hand's height h, the box's weight rests towards its far edge: the push's tipping moment moves the
    centre of its floor load mu h ahead of its centre (`pivot_m`; 26 cm on b1_z1, 91 % of the weight on the front
    corners). Turning at rate w, the box pivots about that point (there its corners' sideways slip, which that
    friction resists, vanishes): its centre slides outwards at w mu h. Measured in MuJoCo (push-box --object-model,
    b1_z1): -3.4 cm/s in the box frame at 0.1 m/s and 0.125 rad/s, against w mu h = 3.3 cm/s; with the yaw on the
    tangent the box drifted 36 cm out of the 0.8 m turn while its yaw stayed within 1 deg. On a circle of radius R the
    pivot moves along the heading (no sideways slip) when the heading leads the tangent by asin(pivot / R) (19 deg at
    0.26 m and 0.8 m): then the centre follows the path. The OCP's box (even corner loads) does not slide so: an
    MPC with the loads shifted by the push (`SlidingBox.push_shifts_loads`) or by a fixed pivot pushed in bursts
    (the hand in contact 7 % of the time) and missed the path by 24 cm."""
    s, speed = path.distance(np.asarray(t_s, dtype=float))
    arc = path.radius_m * path.turn_rad
    turning = (s > path.straight_m) & (s < path.straight_m + arc)
    rate = np.where(turning, speed / path.radius_m, 0.0)
    return np.arcsin(np.clip(rate * pivot_m / np.maximum(speed, 1e-6), 0.0, 1.0))


def object_command(path: BoxPath, scene, name: str, t_s: float, pivot_m: float = 0.0) -> ObjectCommand:
    """The box's measured state and its path (the MPC's reference over the horizon), its yaw leading the path's
    tangent by `sideslip_lead` about the push's `pivot_m` (0: on the tangent). b1_z1, 16 s, compiled SQP: 5.0 cm
    RMSE with the lead and the hand's pad, 22.9 cm without either. What is left sits at the turn's start and end:
    building the lead turns the box about its pivot, which swings its centre out (even the best trajectory of a box
    turning about a pivot 0.26 m ahead misses the path by 2.7 cm RMSE). What was tried and measured, and why a
    lower push did worse: docs/design/object-model.md."""
    reference = path.states(t_s)[0]
    state = measured_box_state(scene, name, np.concatenate([path.start_xy_m, np.zeros(4)]), reference[2])
    if not pivot_m:
        return ObjectCommand(state=state, reference=path.states)

    def reference_with_lead(times):
        states = path.states(times)
        states[:, 2] += sideslip_lead(path, times, pivot_m)
        return states

    return ObjectCommand(state=state, reference=reference_with_lead)


def force_command(path: BoxPath, t_s: float, box, hand_radius_m: float, hand_height_m: float, p_ee: np.ndarray,
                  feedback) -> tuple[np.ndarray, np.ndarray]:
    """(hand velocity, hand force) commands of the force-command version: the hand on the face of the box's
    reference pose (pressed in 5 mm, as push-box's wall task), the force that slides the box along the face normal."""
    x, y, yaw, vx, vy, wz = path.states(t_s)[0]
    face = np.array([x, y]) + _rot(yaw) @ np.array([-(box.size_m[0] / 2 + hand_radius_m) + 0.005, 0.0])
    lever = face - np.array([x, y])
    v_face = np.array([vx, vy]) + wz * np.array([-lever[1], lever[0]])
    p_ref = np.array([face[0], face[1], hand_height_m])
    velocity = feedback(np.array([v_face[0], v_face[1], 0.0]), p_ref, p_ee)
    _, speed = path.distance(np.array([t_s]))
    share = float(speed[0]) / path.speed_m_s
    normal = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return velocity, share * box.friction_mu * box.mass_kg * GRAVITY_M_S2 * normal


def path_metrics(path: BoxPath, t_s: np.ndarray, states: np.ndarray, prefix: str = "box", pivot_m: float = 0.0) -> dict:
    """`box_pos_rmse_m` (the box centre against its commanded path while the path moves) and friends: the same on
    the straight before the turn and from the turn's start on (`_before_turn_`, `_turn_`), the yaw against the
    path's tangent and (`pivot_m` > 0, the object model's reference) against the tangent led by `sideslip_lead`."""
    reference = path.states(t_s)
    use = t_s >= path.start_s
    if not use.any():
        return {f"{prefix}_pos_rmse_m": None}
    error = np.linalg.norm(states[use, :2] - reference[use, :2], axis=1)
    yaw_error = np.degrees(_wrap(states[use, 2] - reference[use, 2]))
    straight = path.distance(t_s[use])[0] <= path.straight_m  # before the turn
    led = _wrap(states[use, 2] - reference[use, 2] - sideslip_lead(path, t_s[use], pivot_m)) if pivot_m else None
    return {f"{prefix}_pos_rmse_m": float(np.sqrt(np.mean(error**2))),
            f"{prefix}_pos_rmse_before_turn_m": float(np.sqrt(np.mean(error[straight] ** 2))) if straight.any() else None,
            f"{prefix}_pos_rmse_turn_m": float(np.sqrt(np.mean(error[~straight] ** 2))) if (~straight).any() else None,
            f"{prefix}_yaw_rmse_led_deg": float(np.degrees(np.sqrt(np.mean(led**2)))) if led is not None else None,
            f"{prefix}_pos_max_err_m": float(error.max()),
            f"{prefix}_pos_final_err_m": float(error[-1]),
            f"{prefix}_yaw_rmse_deg": float(np.sqrt(np.mean(yaw_error**2))),
            f"{prefix}_travel_m": float(np.linalg.norm(states[-1, :2] - states[0, :2])),
            f"{prefix}_path": {"speed_m_s": path.speed_m_s, "straight_m": path.straight_m, "radius_m": path.radius_m,
                               "turn_deg": float(np.degrees(path.turn_rad)), "start_s": path.start_s}}
