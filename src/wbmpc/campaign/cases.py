"""Cases of a campaign: one closed-loop MuJoCo run each, identified by a hash of what defines it.

`expand(spec)` makes the cases (grid product x random samples x seeds); `Case.run_config()`
maps a case onto `RunConfig` (scenario options, `ModelErrors` of the plant, sensor noise,
delay). The id is a hash of the case's content, so a re-run or `--resume` recognises the
cases already in the table whatever their order.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass

import numpy as np

from wbmpc.errors import ConfigError, unknown_name
from wbmpc.options import declared, help_text
from wbmpc.scenarios.base import ScenarioOptions

# axis -> (where it goes, help); ScenarioOptions fields are added below
_MODEL_AXES = {
    "base_com_offset_x_m": "plant base CoM moved forward by this (m, negative = rearward)",
    "base_com_offset_y_m": "plant base CoM moved to the left (m)",
    "base_com_offset_z_m": "plant base CoM moved up (m)",
    "link_mass_scale": "every plant link mass and inertia x this factor",
    "link_mass_noise_rel": "per-link random mass factor 1 + N(0, this) (seeded by the case seed)",
    "ee_payload_kg": "mass attached at the arm end-effector in the plant (kg)",
    "joint_armature_kg_m2": "rotor inertia of every plant joint (kg m^2)",
    "joint_damping_nm_s_per_rad": "viscous friction of every plant joint (N m s/rad)",
    "joint_frictionloss_nm": "dry (Coulomb) friction of every plant joint (N m)",
    "floor_friction_mu": "floor friction coefficient of the plant (the MPC's is friction_mu)",
    "link_mass_spread_rel": "each plant link's mass and inertia x its own factor uniform in 1 +- this (drawn from "
                            "plant_seed)",
    "joint_armature_scale": "rotor inertia of every plant joint, x the robot's reference drive train",
    "joint_damping_scale": "viscous friction of every plant joint, x the robot's reference drive train",
    "joint_frictionloss_scale": "dry friction of every plant joint, x the robot's reference drive train",
    "plant_seed": "seed of the plant's per-link draws (default: the case seed)",
}
_LOOP_AXES = {
    "joint_position_noise_rad": "std of the joint position measurement noise (rad)",
    "joint_velocity_noise_rad_s": "std of the joint velocity measurement noise (rad/s)",
    "delay_ms": "fixed solver delay before a solution applies (ms)",
    "push_gait_period_scale": "gait period factor after a push, (0, 1]; 1: the paper's fixed schedule",
    "identify_mass": "1: estimate the base CoM offset and hand payload online and plan with them (--identify-mass)",
    "sensor_noise_scale": "the IMU's and encoders' noise and biases x this (state estimated; 1: the sensor models' "
                          "defaults)",
    "friction_mu": "the ground friction the MPC plans with (--friction)",
    "joint_loop_hz": "rate of the joint loop: eq. (10) evaluated per command and held (--joint-loop-hz)",
    "joint_loop_jitter_ms": "each command late by a uniform draw in [0, this] (--joint-loop-jitter)",
    "physics_dt_ms": "the simulator's step (--physics-dt)",
    "kd_leg": "the legs' Kd as given (not capped by the joint loop; default: the robot's tuning)",
    "kp_arm": "the arm's Kp of eq. (10) (default: the robot's tuning)",
    "kd_arm": "the arm's Kd as given (default: the robot's tuning)",
    "touchdown_events": "1: the contact schedule follows the feet's measured touch-down (--touchdown-events)",
}
_OTHER_AXES = {
    "gait_phase": "push time shifted by this share of the gait period (0..1)",
    "robot": "robot preset (b1_z1, b1, go2, a1, ...)",
    "state": "true (the simulator's state) or estimated (IMU + encoders and the estimator)",
    "motor_law": "held or continuous (--motor-law)",
    "plant_model": "MJCF or URDF file MuJoCo simulates instead of the controller's model (--plant-model); "
                   "none: the controller's model",
}
_SCENARIO_AXES = {f.name: f"scenario option: {help_text(f, opt)}" + (f" [{opt.flag}]" if opt.flag else "")
                  for f, opt in declared(ScenarioOptions)}
AXES: dict[str, str] = {**_SCENARIO_AXES, **_MODEL_AXES, **_LOOP_AXES, **_OTHER_AXES}
_SCENARIO_TYPES = {f.name: str(f.type) for f, _ in declared(ScenarioOptions)}  # "float", "str | None", "int", ...
# axes whose values are names or paths: the loop's and the scenario options declared as text (arm_target_path, ...)
STRING_AXES = {"robot", "state", "motor_law", "plant_model"} | {
    name for name, kind in _SCENARIO_TYPES.items() if kind.split(" |")[0] == "str"}
INTEGER_AXES = {"plant_seed"} | {name for name, kind in _SCENARIO_TYPES.items() if kind.split(" |")[0] == "int"}


def check_axes(spec) -> None:
    """Every axis of the spec exists and its values have the right kind (raises ConfigError)."""
    named = list(spec.grid.items()) + [(k, [v]) for k, v in spec.fixed.items()] + \
        [(k, list(v)) for k, v in spec.random.ranges.items()]
    for name, values in named:
        if name not in AXES:
            raise ConfigError(unknown_name("campaign axis", name, AXES))
        for value in values:
            if name in STRING_AXES:
                if not isinstance(value, str):
                    raise ConfigError(f"axis {name} takes names, got {value!r}")
            elif isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ConfigError(f"axis {name} takes finite numbers, got {value!r}")
    for name in spec.random.ranges:
        if name in STRING_AXES:
            raise ConfigError(f"axis {name} takes names and cannot be sampled from a range")
    if "gait_phase" in spec.grid or "gait_phase" in spec.fixed or "gait_phase" in spec.random.ranges:
        if spec.scenario != "push":
            raise ConfigError("gait_phase shifts the push time and only applies to the push scenario")


@dataclass(frozen=True)
class Case:
    """One closed-loop run: scenario, robot, duration, axis values and seed."""

    scenario: str
    robot: str
    duration_s: float
    nodes: int
    compiled: bool
    formulation: str
    params: tuple[tuple[str, float | str], ...]  # sorted (axis, value)
    seed: int
    delay: str = "none"  # CampaignSpec.delay
    solver: str | None = None

    @property
    def id(self) -> str:
        extra = [] if self.delay == "none" and self.solver is None else [self.delay, self.solver]  # old ids unchanged
        payload = json.dumps([self.scenario, self.robot, self.duration_s, self.nodes, self.compiled, self.formulation,
                              [list(p) for p in self.params], self.seed, *extra], sort_keys=True)
        return hashlib.sha1(payload.encode()).hexdigest()[:16]

    @property
    def values(self) -> dict:
        return dict(self.params)

    def label(self) -> str:
        shown = ", ".join(f"{k}={v}" for k, v in self.params)
        return f"{self.scenario} [{shown}] seed {self.seed}"

    def model_errors(self):
        from wbmpc.sim.model_errors import ModelErrors

        v = self.values
        offset = tuple(float(v.get(f"base_com_offset_{axis}_m", 0.0)) for axis in "xyz")
        return ModelErrors(
            base_com_offset_m=offset,
            link_mass_scale=float(v.get("link_mass_scale", 1.0)),
            link_mass_noise_rel=float(v.get("link_mass_noise_rel", 0.0)),
            ee_payload_kg=float(v.get("ee_payload_kg", 0.0)),
            joint_armature_kg_m2=_optional(v, "joint_armature_kg_m2"),
            joint_damping_nm_s_per_rad=_optional(v, "joint_damping_nm_s_per_rad"),
            joint_frictionloss_nm=_optional(v, "joint_frictionloss_nm"),
            floor_friction_mu=_optional(v, "floor_friction_mu"),
            link_mass_spread_rel=float(v.get("link_mass_spread_rel", 0.0)),
            joint_armature_scale=_optional(v, "joint_armature_scale"),
            joint_damping_scale=_optional(v, "joint_damping_scale"),
            joint_frictionloss_scale=_optional(v, "joint_frictionloss_scale"),
            seed=int(v.get("plant_seed", self.seed)),
        )

    def run_config(self):
        """The `RunConfig` of this case (raises ConfigError on values the scenario rejects)."""
        from wbmpc.control.tuning import tuning_for
        from wbmpc.gait import make_gait
        from wbmpc.scenarios import RunConfig
        from wbmpc.scenarios.library import SCENARIOS

        v = self.values
        options = ScenarioOptions(**{k: _scenario_value(k, x) for k, x in v.items() if k in _SCENARIO_AXES})
        if "gait_phase" in v:
            gait = options.gait or SCENARIOS[self.scenario](ScenarioOptions()).gait
            period = make_gait(gait, 4, tuning_for(self.robot).gait_period_s).period_s  # a1: 0.6 s
            options.push_time_s += float(v["gait_phase"]) * period
        from wbmpc.control.delay import delay_from_text

        delay_mode, delay_ms = delay_from_text(self.delay) if v.get("delay_ms") is None else ("fixed", float(v["delay_ms"]))
        solver = self.solver or ("auto" if delay_mode == "realtime" else "fatrop")
        loop = {name: float(v[name]) for name in ("friction_mu", "joint_loop_hz", "joint_loop_jitter_ms", "physics_dt_ms")
                if name in v}
        loop.update({name: str(v[name]) for name in ("state", "motor_law") if name in v})
        if "touchdown_events" in v:
            loop["touchdown_events"] = bool(float(v["touchdown_events"]))
        if "sensor_noise_scale" in v:
            from wbmpc.estimation import SensorConfig

            if loop.get("state") != "estimated":
                raise ConfigError("sensor_noise_scale scales the IMU's and encoders' noise, read only with "
                                  "state=estimated: add --set state=estimated")
            loop["sensors"] = SensorConfig(seed=self.seed).scaled(float(v["sensor_noise_scale"]))
        gains = {name: float(v[name]) for name in ("kd_leg", "kp_arm", "kd_arm") if name in v}
        if gains:  # the tuned gains at the paper's 500 Hz joint loop, these as given
            from dataclasses import replace

            loop["gains"] = replace(tuning_for(self.robot).gains_at(), **gains)
        return RunConfig(scenario=self.scenario, duration_s=self.duration_s, nodes=self.nodes, compiled=self.compiled,
                         formulation=self.formulation, seed=self.seed, options=options, delay_mode=delay_mode,
                         delay_ms=delay_ms, solver=solver, model_errors=self.model_errors(), **loop,
                         joint_position_noise_rad=float(v.get("joint_position_noise_rad", 0.0)),
                         joint_velocity_noise_rad_s=float(v.get("joint_velocity_noise_rad_s", 0.0)),
                         identify_mass=bool(float(v.get("identify_mass", 0.0))),
                         plant_model=None if v.get("plant_model", "none") == "none" else v["plant_model"],
                         **({"push_gait_period_scale": float(v["push_gait_period_scale"])}
                            if "push_gait_period_scale" in v else {}))


def _optional(values: dict, name: str) -> float | None:
    return float(values[name]) if name in values else None


def expand(spec) -> list[Case]:
    """Grid product x random samples x seeds, in a stable order (grid axes sorted by name)."""
    axes = sorted(spec.grid)
    grid_points = [dict(zip(axes, combo)) for combo in itertools.product(*(spec.grid[a] for a in axes))] or [{}]
    rng = np.random.default_rng(spec.random.seed)
    ranges, fixed, samples = spec.random.ranges, spec.fixed, spec.random.samples
    if getattr(spec, "randomize", False):
        from wbmpc.campaign.reality_gap import randomized

        ranges, fixed, samples = randomized(spec)
    cases = []
    for point in grid_points:
        draws = [{}] if not samples else [{name: _draw(rng, name, low, high) for name, (low, high) in sorted(ranges.items())}
                                          for _ in range(samples)]
        for draw in draws:
            values = {**fixed, **point, **draw}
            robot = str(values.pop("robot", spec.robot))
            params = tuple(sorted((k, _normal(k, x)) for k, x in values.items()))
            for seed in spec.seeds:
                cases.append(Case(spec.scenario, robot, float(spec.duration_s), int(spec.nodes), bool(spec.compiled),
                                  spec.formulation, params, int(seed), spec.delay, spec.solver))
    return cases


def _scenario_value(name: str, value):
    """A scenario option's axis value as its declared type (text, whole number, flag or number)."""
    kind = _SCENARIO_TYPES[name].split(" |")[0]
    if kind == "str":
        return value
    if kind == "int":
        return int(round(float(value)))
    return bool(float(value)) if kind == "bool" else float(value)


def _draw(rng, name: str, low: float, high: float):
    if name in INTEGER_AXES:
        return int(rng.integers(int(low), int(high) + 1))
    return round(float(rng.uniform(low, high)), 6)


def _normal(name: str, value):
    if name in INTEGER_AXES:
        return int(value)
    return value if name in STRING_AXES else float(value)
