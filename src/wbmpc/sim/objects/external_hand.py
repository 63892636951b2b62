"""`ExternalHand`: a scripted hand moving the end-effector through a capped spring-damper (a person pushing the
gripper), along `HandPush` strokes. Measured: the force the hand applies."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.sim.objects.common import EE_SITE, add_ee_site, check_positive


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
        check_positive("hand stiffness (N/m)", self.stiffness_n_m)
        check_positive("hand damping (N s/m)", self.damping_n_s_m, allow_zero=True)
        check_positive("hand force cap (N)", self.max_force_n)
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
        add_ee_site(spec, robot)
