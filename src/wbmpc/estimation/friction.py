"""The floor's friction observed from slipping feet, fed to the MPC's cones (eq. 6).

The MPC plans contact forces inside cones of its assumed coefficient (`--friction`). On a floor with less
friction a plan that leans on its cone makes the stance feet slide: b1_z1 with 10 % more mass, its CoM 2 cm
back, pushed at 0.8 m/s towards 315 deg on a floor of 0.5 planned with 0.7; its stance feet then held exactly
|F_t| / F_z = 0.50 (MuJoCo's cone) while sliding at up to 1.2 m/s, and it fell 0.49 s after the kick. Planned
with 0.5 from the start it stayed up, but a lower default costs the pushes on a good floor (0.8 m/s forward:
up with 0.7, fell with 0.5).

A sliding foot measures the coefficient: the ratio of its tangential to its normal force. `FrictionObserver`
watches the loaded feet (normal force above `load_share` of a foot's share of the weight) and, when one slides
faster than `slip_speed_m_s` for `slip_time_s`, takes its force ratio as the floor's coefficient; the MPC then
plans with `margin` times it (never above its own assumption). Without slips the estimate relaxes back towards
the assumption at `relax_per_s` (the floor may change under the robot); a new slip pulls it down again.
Forces and foot velocities come from the plant (foot force sensors, the simulator's contacts; a step hook).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.errors import check_number
from wbmpc.robots import RobotModel


@dataclass(frozen=True)
class FrictionObserverConfig:
    slip_speed_m_s: float = 0.05  # a loaded foot moving faster than this over the floor slides
    slip_time_s: float = 0.004  # ... for this long (two 500 Hz ticks)
    load_share: float = 0.25  # loaded: normal force above this share of a foot's share of the weight
    margin: float = 0.9  # the MPC plans with this share of the observed coefficient
    relax_per_s: float = 0.05  # without slips the estimate climbs back towards the assumption at this rate
    minimum: float = 0.1  # never below

    def __post_init__(self):
        for name in ("slip_speed_m_s", "slip_time_s", "load_share", "margin", "minimum"):
            check_number(f"friction_observer.{name}", getattr(self, name), low=0.0, low_open=True)
        check_number("friction_observer.relax_per_s", self.relax_per_s, low=0.0)


class FrictionObserver:
    """A plant step hook: observes the feet every `every_n_steps` physics steps and sets the MPC's coefficient."""

    def __init__(self, robot: RobotModel, assumed_mu: float, mpc=None, config: FrictionObserverConfig = FrictionObserverConfig(),
                 every_n_steps: int = 2):
        self.robot, self.config, self.mpc = robot, config, mpc
        self.assumed_mu = float(assumed_mu)
        self.estimate = float(assumed_mu)  # the floor's coefficient as observed (the assumption until a slip)
        self._data = robot.model.createData()
        self._frames = [robot.frame_id(robot.contact_frame(f)) for f in robot.feet]
        self._foot_load_n = robot.mass_kg * 9.81 / len(robot.feet)
        self._sliding_s = np.zeros(len(robot.feet))
        self._every, self._steps = max(1, int(every_n_steps)), 0
        self.slips = 0  # slip events (a foot starting to slide)
        self.history: list[tuple[float, float]] = []  # (t, coefficient planned with) at every change

    @property
    def planned_mu(self) -> float:
        return min(self.assumed_mu, max(self.config.minimum, self.config.margin * self.estimate))

    def before_step(self, plant) -> None:
        pass

    def after_step(self, plant) -> None:
        self._steps += 1
        if self._steps % self._every:
            return
        q, v = plant.state()
        self.observe(plant.time_s, q, v, plant.contact_forces(), self._every * plant.dt_s)

    def observe(self, t_s: float, q: np.ndarray, v: np.ndarray, forces_world_n: np.ndarray, dt_s: float) -> None:
        """One sample: the state and each foot's world-frame force (n_feet, 3)."""
        cfg = self.config
        model, data = self.robot.model, self._data
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        before = self.planned_mu
        slid = False
        for i, frame in enumerate(self._frames):
            force = forces_world_n[i]
            if force[2] < cfg.load_share * self._foot_load_n:
                self._sliding_s[i] = 0.0
                continue
            speed = np.linalg.norm(pin.getFrameVelocity(model, data, frame, pin.LOCAL_WORLD_ALIGNED).linear[:2])
            if speed <= cfg.slip_speed_m_s:
                self._sliding_s[i] = 0.0
                continue
            if self._sliding_s[i] == 0.0:
                self.slips += 1
            self._sliding_s[i] += dt_s
            if self._sliding_s[i] >= cfg.slip_time_s:
                ratio = float(np.linalg.norm(force[:2]) / force[2])
                self.estimate = min(self.estimate, max(ratio, cfg.minimum))
                slid = True
        if not slid and self.estimate < self.assumed_mu:
            self.estimate = min(self.assumed_mu, self.estimate + cfg.relax_per_s * dt_s)
        after = self.planned_mu
        if after != before:
            if self.mpc is not None:
                self.mpc.set_friction_coefficient(after)
            if not self.history or abs(after - self.history[-1][1]) > 0.01 or slid:
                self.history.append((float(t_s), after))

    def metrics(self) -> dict:
        return {"friction_observed": self.estimate, "friction_planned_final": self.planned_mu,
                "friction_slips": self.slips, "friction_history": [[t, mu] for t, mu in self.history[-200:]]}
