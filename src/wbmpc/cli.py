"""The `wbmpc` command: robot info, one OCP solve, closed-loop scenarios and benchmarks.

With --json exactly one JSON object (strict JSON: no NaN/Infinity) goes to stdout; human-readable
text goes to stderr. Exit codes (`EXIT_CODES`): 0 done, 1 the run failed its task (the robot
fell, the load was not pulled, the solve did not converge, the simulation diverged) or failed
while running (`RunError`: the first MPC solve failed, the step budget is shorter than one QP, a solver
process did not start, the robot or its arm did not answer), 2 bad
input (`ConfigError`, `ModelError`: the message names the option and the fix; nothing is built or
written), 130 interrupted by Ctrl-C (a run keeps and writes what it measured so far).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import textwrap

from wbmpc import __version__
from wbmpc.errors import ConfigError, ModelError, WbmpcError
from wbmpc.strict_json import to_json

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_CODES = {EXIT_OK: "done", EXIT_FAILED: "the run failed its task: the robot fell, the load (no load of a sweep) was not pulled, "
              "the solve did not converge or the simulation diverged; or it failed while running: the first MPC "
              "solve failed, the step budget is shorter than one QP, a solver process did not start, the robot "
              "or its arm did not answer", EXIT_BAD_INPUT: "bad input (nothing was built or written)",
              EXIT_INTERRUPTED: "interrupted by Ctrl-C (a run writes what it measured until then)"}
EPILOG = "exit codes:\n" + "\n".join(textwrap.fill(text, 90, initial_indent=f"  {code:<4} ", subsequent_indent=" " * 7)
                                       for code, text in EXIT_CODES.items())

# config fields of other commands -> the options that set them, so that errors name what the user typed;
# those of `run` come from its config dataclasses (`field_flags_of_commands`)
OTHER_FIELD_FLAGS = {"delay": "--delay", "samples": "--samples", "out": "--out", "steps": "--steps", "t": "--t"}
CUSTOM_ROBOT_FLAGS = {"srdf": "--srdf", "pose": "--pose", "feet": "--feet", "lock": "--lock", "keyframe": "--keyframe"}
LONG_RUN_S = 60.0  # runs at least this long report their memory and solve-time stability in the summary


def _add_robot_options(parser: argparse.ArgumentParser) -> None:
    from wbmpc.robots.presets import PRESET_NAMES

    group = parser.add_argument_group("robot (a preset, or a custom URDF or MJCF with the options below it)")
    group.add_argument("--robot", default="b1_z1", choices=PRESET_NAMES, metavar="NAME",
                       help=f"preset: {', '.join(PRESET_NAMES)} (default b1_z1: B1 + Z1 arm, 22 DoF as in the paper)")
    group.add_argument("--urdf", metavar="FILE", help="custom robot URDF (replaces --robot; needs --feet)")
    group.add_argument("--mjcf", metavar="FILE", help="custom robot MJCF with a free joint, e.g. MuJoCo Menagerie's or "
                       "unitree_mujoco's (replaces --robot; needs --feet: bodies, sites or geoms of the file)")
    group.add_argument("--srdf", metavar="FILE", help="custom robot: SRDF with the reference pose (needs --pose)")
    group.add_argument("--pose", metavar="NAME", help="custom robot: SRDF group_state used as the nominal pose")
    group.add_argument("--keyframe", metavar="NAME", help="custom MJCF robot: keyframe used as the nominal pose "
                       "(default the file's first, e.g. Menagerie's home; none: its zero pose)")
    group.add_argument("--feet", metavar="F1,F2,...", help="custom robot: comma-separated foot frame names")
    group.add_argument("--arm-ee", metavar="FRAME", help="arm end-effector frame: a custom robot's, another frame of "
                       "a preset (e.g. g1's left_rubber_hand), or with --arm the mounted arm's (default its only leaf link)")
    group.add_argument("--foot-contact", choices=("point", "surface"),
                       help="point feet (3D force) or flat feet (6D wrench at the sole, hard wrench cone); presets say "
                       "their own (g1, talos: surface)")
    group.add_argument("--sole", metavar="LENGTH,WIDTH", help="sole rectangle of flat feet in metres (implies "
                       "--foot-contact surface); default: the foot link's URDF collision geometry")
    group.add_argument("--lock", metavar="J1,J2,...", help="custom robot: joints to lock at the reference pose")
    arm = parser.add_argument_group("an arm mounted on the robot (a preset or --urdf; wbmpc.robots.compose)")
    arm.add_argument("--arm", metavar="URDF|NAME", help="arm URDF, or z1 (example-robot-data's), to mount on the legged "
                     "base (needs --mount); robot-sim/deploy: the model's Z1 goes over its UDP interface (--arm none: not)")
    arm.add_argument("--mount", metavar="FRAME", help="link or joint of the base the arm is fixed to")
    arm.add_argument("--mount-xyz", metavar="X,Y,Z", help="arm base position in the mount frame, m (default 0,0,0)")
    arm.add_argument("--mount-rpy", metavar="R,P,Y", help="arm base roll, pitch, yaw in the mount frame, rad (default 0)")
    arm.add_argument("--arm-lock", metavar="J1,J2,...", help="arm joints to lock at the reference pose (arm URDF names)")
    drive = parser.add_argument_group(
        "drive train of the controller's model (paper VI-D); VALUE or JOINT=VALUE,JOINT=VALUE (others 0)")
    drive.add_argument("--armature", metavar="KG_M2", help="rotor inertia added to the mass-matrix diagonal, kg m^2")
    drive.add_argument("--viscous-friction", metavar="NM_S", help="viscous joint friction b (tau += b v), N m s/rad")
    drive.add_argument("--coulomb-friction", metavar="NM", help="Coulomb joint friction c (tau += c tanh(v / 0.05)), N m")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout (human text on stderr)")


_MODEL_DRIVE = {"armature": "armature_kg_m2", "viscous_friction": "viscous_friction_nm_s",
                "coulomb_friction": "coulomb_friction_nm"}
_PLANT_DRIVE = {"plant_armature": "joint_armature_kg_m2", "plant_viscous_friction": "joint_damping_nm_s_per_rad",
                "plant_coulomb_friction": "joint_frictionloss_nm"}


def _joint_values_arg(text: str, flag: str, joint_names) -> float | dict[str, float]:
    """'0.02' (every joint) or 'JOINT=0.02,JOINT=0.01' (the others 0), checked against the robot's joints."""
    from wbmpc.robots import joint_values

    if "=" not in text:
        value: float | dict[str, float] = _number(text, flag)
    else:
        value = {}
        for item in _split(text):
            joint, _, number = item.partition("=")
            value[joint.strip()] = _number(number, f"{flag} {joint.strip()}")
    joint_values(value, tuple(joint_names), flag)  # names and signs, reported with the flag
    return value


def _number(text: str, flag: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{flag} needs a number or JOINT=NUMBER pairs, got {text!r}") from None


def _split(text: str | None) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()] if text else []


def _triple(text: str | None, flag: str) -> tuple[float, float, float]:
    if text is None:
        return (0.0, 0.0, 0.0)
    values = _split(text)
    try:
        numbers = tuple(float(v) for v in values)
    except ValueError:
        numbers = ()
    if len(numbers) != 3 or not all(math.isfinite(v) for v in numbers):
        raise ConfigError(f"{flag} needs three numbers X,Y,Z, got {text!r}")
    return numbers  # type: ignore[return-value]


def _arm_mount(args: argparse.Namespace):
    """The --arm/--mount options as an ArmMount, or None without --arm."""
    from pathlib import Path

    from wbmpc.robots.compose import ArmMount

    arm_flags = [flag for dest, flag in (("mount", "--mount"), ("mount_xyz", "--mount-xyz"), ("mount_rpy", "--mount-rpy"),
                                         ("arm_lock", "--arm-lock")) if getattr(args, dest, None)]
    if not getattr(args, "arm", None):
        if arm_flags:
            raise ConfigError(f"{', '.join(arm_flags)} place an arm and need --arm URDF")
        return None
    from wbmpc.robots.presets import NAMED_ARMS, example_robot_data_dir

    if args.arm == "none" and not arm_flags:
        return None  # robot-sim/deploy: leave the model's arm off its UDP link
    named = NAMED_ARMS.get(args.arm) if not Path(args.arm).exists() else None
    if not args.mount:
        if named is not None and not arm_flags:
            return None  # `--arm z1` on a robot that carries one (b1_z1, go2_z1): checked in robot_from_args
        raise ConfigError("--arm needs --mount FRAME: the link or joint of the base the arm is fixed to")
    if named is not None:  # an arm of example-robot-data by name, with the paper's locks and pose
        return ArmMount(urdf=example_robot_data_dir() / named["urdf"], mount_frame=args.mount,
                        mount_xyz_m=_triple(args.mount_xyz, "--mount-xyz"), mount_rpy_rad=_triple(args.mount_rpy, "--mount-rpy"),
                        arm_ee=args.arm_ee or named["arm_ee"],
                        locked_joints=tuple(_split(args.arm_lock)) if args.arm_lock else named["locked_joints"],
                        joint_positions_rad=named["joint_positions_rad"])
    return ArmMount(urdf=Path(args.arm), mount_frame=args.mount, mount_xyz_m=_triple(args.mount_xyz, "--mount-xyz"),
                    mount_rpy_rad=_triple(args.mount_rpy, "--mount-rpy"), arm_ee=args.arm_ee,
                    locked_joints=tuple(_split(args.arm_lock)))



def robot_from_args(args: argparse.Namespace):
    import dataclasses

    from wbmpc.robots import RobotModel, custom_spec, load_robot, preset_spec
    from wbmpc.robots.presets import custom_robot

    contact = _foot_contact(args)
    arm = _arm_mount(args)
    mjcf = getattr(args, "mjcf", None)
    if args.urdf and mjcf:
        raise ConfigError("--urdf and --mjcf both describe the robot: give one")
    if getattr(args, "keyframe", None) and not mjcf:
        raise ConfigError("--keyframe names a pose of an MJCF file: it needs --mjcf FILE")
    if args.urdf or mjcf:
        if not args.feet:
            raise ConfigError(f"a custom {'--urdf' if args.urdf else '--mjcf'} needs --feet F1,F2,... (the foot frame "
                              f"names{': bodies, sites or geoms of the file' if mjcf else ''})")
        spec = custom_spec(args.urdf, _split(args.feet), None if arm else args.arm_ee, args.srdf, args.pose,
                           _split(args.lock), mjcf=mjcf, keyframe=getattr(args, "keyframe", None))
        spec = dataclasses.replace(spec, **contact) if contact else spec
        robot = custom_robot(_with_arm(spec, arm) if arm else spec)
    elif arm:
        given = [flag for dest, flag in CUSTOM_ROBOT_FLAGS.items() if dest != "arm_ee" and getattr(args, dest, None)]
        if given:
            raise ConfigError(f"{', '.join(given)} describe a custom robot and need --urdf or --mjcf")
        spec = preset_spec(args.robot)
        robot = RobotModel(_with_arm(dataclasses.replace(spec, **contact) if contact else spec, arm))
    else:
        given = [flag for dest, flag in CUSTOM_ROBOT_FLAGS.items() if getattr(args, dest, None)]
        if given:
            raise ConfigError(f"{', '.join(given)} describe{'s' if len(given) == 1 else ''} a custom robot and need"
                              f"{'s' if len(given) == 1 else ''} --urdf or --mjcf; the preset --robot {args.robot} "
                              f"defines its own (drop {', '.join(given)} or add --urdf FILE or --mjcf FILE)")
        robot = load_robot(args.robot)
        if getattr(args, "arm", None) not in (None, "none") and arm is None and not _carries_arm(robot, args.arm):
            raise ConfigError(f"--robot {args.robot} carries no {args.arm} arm: mount one with --arm {args.arm} "
                              f"--mount FRAME (e.g. --mount base), or pick a preset with one (b1_z1, go2_z1)")
        preset = dict(contact)
        if getattr(args, "arm_ee", None):
            preset["arm_ee"] = args.arm_ee
        if preset:
            robot = RobotModel(dataclasses.replace(robot.spec, **preset))
    drive = {field: _joint_values_arg(getattr(args, option), "--" + option.replace("_", "-"), robot.joint_names)
             for option, field in _MODEL_DRIVE.items() if getattr(args, option, None) is not None}
    return RobotModel(dataclasses.replace(robot.spec, **drive)) if drive else robot


def _foot_contact(args: argparse.Namespace) -> dict:
    """RobotSpec fields set by --foot-contact / --sole (flat feet: a 6D wrench at a sole rectangle)."""
    contact = {}
    if getattr(args, "sole", None):
        try:
            contact["sole_m"] = tuple(float(x) for x in _split(args.sole))
        except ValueError:
            raise ConfigError(f"--sole needs LENGTH,WIDTH in metres, got {args.sole!r}") from None
        if len(contact["sole_m"]) != 2:
            raise ConfigError(f"--sole needs LENGTH,WIDTH in metres, got {args.sole!r}")
        if getattr(args, "foot_contact", None) == "point":
            raise ConfigError("--sole describes flat feet; drop --foot-contact point")
        contact["foot_contact"] = "surface"
    elif getattr(args, "foot_contact", None):
        contact["foot_contact"] = args.foot_contact
        if args.foot_contact == "point":
            contact["sole_m"] = None
    return contact


def _carries_arm(robot, name: str) -> bool:
    """The model's arm joints are those of the named arm (its URDF's joint names)."""
    from wbmpc.hardware.mapping import has_z1_arm

    return name == "z1" and has_z1_arm(robot)


def _with_arm(spec, arm):
    from wbmpc.robots.compose import compose_spec

    composed, composition = compose_spec(spec, arm)
    if composition.renamed:
        print(f"wbmpc: note: {composition.note()}", file=sys.stderr)
    return composed


def plant_config_from_args(args: argparse.Namespace, robot):
    """The plant's drive train (--plant-armature/...), independent of the controller's model: the flags given, over
    the robot's own plant settings (`robot_plant_config`: g1's rotor inertias) unless --plant-model brings its own.
    (A flag alone used to replace those: --plant-coulomb-friction 0.1 took g1's rotors away and its walk fell.)"""
    from wbmpc.sim import PlantConfig, robot_plant_config

    drive = {field: _joint_values_arg(getattr(args, option), "--" + option.replace("_", "-"), robot.joint_names)
             for option, field in _PLANT_DRIVE.items() if getattr(args, option, None) is not None}
    if not drive:
        return None
    own = None if getattr(args, "plant_model", None) else robot_plant_config(robot)
    return dataclasses.replace(own, **drive) if own is not None else PlantConfig(**drive)


def _emit(args: argparse.Namespace, payload: dict, human: str) -> None:
    if args.json:
        print(to_json(payload))
        print(human, file=sys.stderr)
    else:
        print(human)


def cmd_info(args: argparse.Namespace) -> int:
    from wbmpc.control.tuning import RENAMED_SETTINGS, RobotScale, tuning_for
    from wbmpc.solvers import blasfeo

    robot = robot_from_args(args)
    info = robot.summary()
    lines = [f"{k}: {v}" for k, v in info.items()]
    scale = RobotScale.of(robot)
    info["scale"] = dataclasses.asdict(scale)
    info["settings"] = tuning_for(robot).report()
    lines.append(f"scale: {scale.mass_kg:.1f} kg, leg length {scale.leg_length_m:.3f} m, leg torque limit "
                 f"{scale.leg_torque_nm:.1f} N m (mean){'' if scale.arm_mass_kg is None else f', arm carrying {scale.arm_mass_kg:.2f} kg'}")
    lines.append("settings (source: derived from the scale with B1 + Z1 as reference; derived: biped = the two-feet "
                 "rules of control/biped.py; table = control/tuning.py):")
    lines += [f"  {name:36s} {_setting_text(entry['value']):>24s}  {entry['source']}"
              for name, entry in info["settings"].items() if name not in RENAMED_SETTINGS]
    info["controller_assumes"] = _controller_assumptions(robot)
    lines.append(_assumptions_text(info["controller_assumes"]))
    status = blasfeo.status()
    info["blasfeo"] = status.as_dict()
    lines.append(f"blasfeo: {status.active} ({status.reason})")
    _emit(args, info, "\n".join(lines))
    return EXIT_OK


def _controller_assumptions(robot) -> dict:
    """What the controller takes for granted about the ground and the robot link (`wbmpc info`)."""
    from wbmpc.control.loop import LoopConfig
    from wbmpc.control.tuning import tuning_for
    from wbmpc.sim import PlantConfig

    tuning, loop = tuning_for(robot), LoopConfig()
    return {"friction_coefficient": tuning.friction_coefficient, "simulated_floor_friction": PlantConfig().friction_mu,
            "joint_loop_hz": loop.control_rate_hz, "motor_law": loop.motor_law,
            "kd_leg_by_joint_loop_hz": {hz: tuning.gains_at(1.0 / hz).kd_leg for hz in (1000.0, 500.0, 200.0)},
            "leg_joint_mode_inertia_kg_m2": tuning.leg_joint_inertia_kg_m2}


def _assumptions_text(a: dict) -> str:
    from wbmpc.control.joint_loop import DAMPER_BOUND

    kd = ", ".join(f"{v:.3g} at {hz:g} Hz" for hz, v in a["kd_leg_by_joint_loop_hz"].items())
    return (f"controller assumes: ground friction {a['friction_coefficient']:g} (--friction; the simulated floor: "
            f"{a['simulated_floor_friction']:g}, --floor-friction); eq. (10) evaluated at {a['joint_loop_hz']:g} Hz and "
            f"held (--joint-loop-hz); legs' Kd {kd} (Kd T / I <= {DAMPER_BOUND:g} on the lightest leg mode, "
            f"{a['leg_joint_mode_inertia_kg_m2'] or 0:.3g} kg m^2)")


def _setting_text(value) -> str:
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(f"{v:.4g}" for v in value) + ")"
    return "-" if value is None else f"{value:.4g}"


def cmd_setup(args: argparse.Namespace) -> int:
    """Install the fast linear algebra Fatrop and HPIPM run on (see wbmpc.solvers.blasfeo)."""
    from wbmpc.solvers import blasfeo

    status = blasfeo.install(force=args.force)
    _emit(args, {"blasfeo": status.as_dict()}, f"blasfeo: {status.active} ({status.reason})")
    return 0


def cmd_bench_dynamics(args: argparse.Namespace) -> int:
    from wbmpc.bench.dynamics import validate_dynamics
    from wbmpc.errors import check_number

    check_number("samples", args.samples, low=1, high=100_000)  # before loading the robot
    robot = robot_from_args(args)
    report = validate_dynamics(robot, samples=args.samples, seed=args.seed)
    lines = [f"symbolic dynamics of {robot.name} vs pinocchio ({args.samples} random states)"]
    lines += [f"  {name:26s} {r['instructions']:6d} instructions   max error {r['max_abs_error']:.2e}"
              for name, r in report["functions"].items()]
    paper = 3818
    rnea = report["functions"]["rnea"]["instructions"]
    lines.append(f"  RNEA: {rnea} instructions = {rnea / paper:.2f}x the paper's Pinocchio-CasADi RNEA ({paper})")
    _emit(args, report, "\n".join(lines))
    return EXIT_OK


def cmd_bench_robots(args: argparse.Namespace) -> int:
    from wbmpc.bench.dynamics import validate_robots
    from wbmpc.errors import check_number
    from wbmpc.robots import PRESET_NAMES

    names = _split(args.robots) or list(PRESET_NAMES)
    if not args.samples >= 1:
        raise ConfigError(f"--samples must be >= 1, got {args.samples}")

    def row_text(r: dict) -> str:
        types = ", ".join(f"{n} {k}" for k, n in sorted(r["joint_types"].items()))
        return (f"  {r['robot']:16s} nv {r['nv']:3d}  {r['mass_kg']:6.1f} kg  RNEA {r['rnea_instructions']:5d}  "
                f"max error {r['max_abs_error']:.1e}  joints: {types}")

    check_number("steps", args.steps, low=1, high=100_000)
    print(f"symbolic dynamics vs pinocchio, {args.samples} random states per robot", file=sys.stderr)
    report = validate_robots(names, args.samples, args.seed, on_row=lambda r: print(row_text(r), file=sys.stderr))
    if args.mpc:
        from wbmpc.bench.robot_costs import costs_text, robot_costs
        from wbmpc.robots import load_robot
        from wbmpc.robots.presets import QUADRUPEDS

        print(f"MPC per quadruped: wb_inverse OCP size, {args.steps} closed-loop steps of trot in place (MuJoCo), "
              f"{'compiled ' if not args.no_compile else ''}Fatrop and RTI, CPU ms per step", file=sys.stderr)
        for row in report["robots"]:
            if row["robot"] not in QUADRUPEDS:
                row["mpc"] = None  # bipeds: point feet, the MPC is not expected to balance them
                continue
            row["mpc"] = robot_costs(load_robot(row["robot"]), args.steps, compiled=not args.no_compile)
            print(costs_text(row["robot"], row["mpc"]), file=sys.stderr)
    _emit(args, report, f"{len(report['robots'])} robots, worst error {report['max_abs_error']:.1e}")
    return 0


def run_config_from_args(args: argparse.Namespace):
    """Every run option checked (config dataclasses) before a robot or an OCP is built."""
    from wbmpc.control.interpolator import PdGains
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.options import values_from_args
    from wbmpc.scenarios import RunConfig, ScenarioOptions

    values = values_from_args(RunConfig, args)
    if args.delay is not None:  # the one-string --delay of before (deprecated): a mode or a fixed delay in ms
        from wbmpc.control.delay import delay_from_text

        if values.get("delay_mode", "none") != "none" or "delay_ms" in values:
            raise ConfigError("--delay is the old form of --delay-mode / --delay-ms: give one or the other")
        values["delay_mode"], values["delay_ms"] = delay_from_text(args.delay)
        print("wbmpc: warning: --delay is deprecated; use --delay-mode none|measured|measured-wall|realtime or "
              "--delay-ms MS", file=sys.stderr)
    return RunConfig(scenario=args.scenario, options=ScenarioOptions(**values_from_args(ScenarioOptions, args)),
                     gains=PdGains(**values_from_args(PdGains, args)),
                     operator=OperatorConfig(**values_from_args(OperatorConfig, args)), **values)


def ignored_scenario_options(args: argparse.Namespace) -> list[tuple[str, tuple[str, ...]]]:
    """(flag, scenarios that read it) of the scenario options given that this run's scenario does not read."""
    from wbmpc.options import declared, flag_default
    from wbmpc.scenarios import ScenarioOptions

    return [(opt.flag, opt.scenarios) for f, opt in declared(ScenarioOptions)
            if opt.flag and opt.scenarios is not None and args.scenario not in opt.scenarios
            and getattr(args, opt.dest) != flag_default(f, opt)]


def gains_from_args(args: argparse.Namespace, robot, hold_s: float):
    """None without --kp/--kd (the run takes the robot's tuned gains for its joint loop's hold `hold_s`); else
    those gains with --kp/--kd as given."""
    import dataclasses

    from wbmpc.control.tuning import tuning_for

    overrides = {name: value for name, value in (("kp_leg", args.kp), ("kd_leg", args.kd)) if value is not None}
    return dataclasses.replace(tuning_for(robot).gains_at(hold_s), **overrides) if overrides else None


def cmd_run(args: argparse.Namespace) -> int:
    """Closed-loop scenario: progress on stderr, summary, metrics.json + plots + replay in --out."""
    from wbmpc.interrupt import catch_interrupt
    from wbmpc.scenarios import SCENARIOS

    if args.scenario not in SCENARIOS:
        from wbmpc.errors import unknown_name

        raise ConfigError(unknown_name("scenario", args.scenario, SCENARIOS))
    if args.sweep is not None and args.scenario != "pull":
        raise ConfigError(f"--sweep runs the pull scenario over loads; it does not apply to {args.scenario}")
    if args.object_model:  # on a scenario without an object: its own error, not a warning that the scenario ignores it
        run_config_from_args(args)
    for flag, scenarios in ignored_scenario_options(args):
        readers = " and ".join([", ".join(scenarios[:-1]), scenarios[-1]] if len(scenarios) > 1 else scenarios)
        print(f"wbmpc: warning: {flag} is read by {readers} only; {args.scenario} ignores it", file=sys.stderr)
    config = run_config_from_args(args)
    loads = None
    if args.sweep is not None:
        from wbmpc.scenarios.sweep import parse_loads

        loads = parse_loads(args.sweep)
    with catch_interrupt() as stop:  # Ctrl-C from here on: stop the run, keep what it measured
        return _run(args, config, loads, stop)


def _run(args: argparse.Namespace, config, loads, stop) -> int:
    import warnings
    from pathlib import Path

    from wbmpc.control.delay import delay_text
    from wbmpc.scenarios import (
        check_output_dir,
        make_scenario,
        run_scenario,
        write_outputs,
    )

    robot = robot_from_args(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if loads is None:
            make_scenario(args.scenario, robot, config.options)  # bad input or missing arm: exit 2 before building
    for w in caught:
        print(f"wbmpc: warning: {w.message}", file=sys.stderr)
    out_dir = Path(args.out or f"runs/{args.scenario}")
    if not args.no_outputs:
        check_output_dir(out_dir)
    from wbmpc.scenarios.runner import joint_loop_hold_s

    config = dataclasses.replace(config, plant_config=plant_config_from_args(args, robot))
    config = dataclasses.replace(config, gains=gains_from_args(args, robot, joint_loop_hold_s(config))).for_robot(robot)
    if loads is not None:
        return _run_sweep(args, robot, config, loads, out_dir, stop)
    from wbmpc.operator.script import script_duration

    scenario = make_scenario(args.scenario, robot, config.options)  # its default duration may follow the robot
    duration = config.duration_s or script_duration(config.operator.commands_file) or scenario.default_duration_s
    print(f"wbmpc run {args.scenario}: robot {robot.name}, {duration:g} s simulated, solver {config.solver}"
          f"{' (compiled)' if config.compiled else ''}, delay {delay_text(config.delay_mode, config.delay_ms)}"
          f"{' ms' if config.delay_mode == 'fixed' else ''}, plant {args.plant}"
          f"{f' simulating {config.plant_model}' if config.plant_model else ''}, state {args.state}",
          file=sys.stderr)
    from wbmpc.progress import ProgressBar

    with ProgressBar(duration, args.scenario + " ", unit="s") as bar:
        def progress(share: float, recoveries: int) -> None:
            bar.update(share * duration)
            bar.set_recoveries(recoveries)

        result = run_scenario(robot, config, progress=progress, stop=stop)
        m = result.metrics
        bar.close(complete=not (m["fell"] or m["interrupted"]))
    if m["interrupted"]:
        where = "" if args.no_outputs else f", writing it to {out_dir}/ (Ctrl-C again to skip)"
        print(f"wbmpc: interrupted at {m['duration_s']:.2f} s of {duration:g} s; keeping what was measured{where}",
              file=sys.stderr)
    paths = write_outputs(robot, result, out_dir) if not args.no_outputs else []
    failure = result.scenario.failure(m)
    _emit(args, m, "\n".join(_run_summary(m, failure, paths, out_dir)))
    if m["interrupted"]:
        return EXIT_INTERRUPTED
    return EXIT_FAILED if failure else EXIT_OK


def _run_summary(m: dict, failure: str | None, paths: list, out_dir) -> list[str]:
    state = "INTERRUPTED" if m["interrupted"] else f"FELL at {m['fell_at_s']:.2f} s" if m["fell"] else "stayed up"
    solve = m["solve_ms"]
    lines = [
        f"scenario {m['scenario']}: {state} over {m['duration_s']:.2f} s",
        f"  base drift {_fmt(m['base_drift_cm_s'], '.2f')} cm/s, base velocity RMSE {m['base_vel_rmse']:.3f} m/s",
        f"  max torque / limit {m['max_torque_ratio']:.2f}; MPC {m['mpc_solves']} solves, {m['mpc_recoveries']} "
        f"recovered by a re-solve, {m['mpc_failures']} failed; solve {_fmt(solve['mean'])} ms mean "
        f"({_fmt(solve['max'])} max), {m['iterations_mean']:.1f} iterations",
    ]
    if m.get("plant_model"):
        lines.append(plant_model_line(m["plant_model"]))
    if m.get("solver"):
        compiled = "compiled" if m["solver_compiled"] else (
            f"NOT compiled (asked for; CasADi's VM instead, several times slower: {m['compile_error']})"
            if m["compiled_requested"] else "not compiled")
        budget = f", step budget {m['step_budget_ms']:.1f} ms" if m.get("step_budget_ms") else ""
        sqp = (f", {m['sqp_iterations_mean']:.2f} SQP iterations per step, "
               f"{100 * (m['solver_past_deadline_share'] or 0):.0f} % past the deadline"
               if m.get("sqp_iterations_mean") is not None else "")
        direct = f", NOT on its direct binding ({m['direct_fallback']})" if m.get("direct_fallback") else ""
        lines.append(f"  solver {m['solver']} ({compiled}){budget}{sqp}"
                     f"{', delay compensation on' if m.get('delay_compensation') else ''}{direct}")
    if m.get("delay_mode") != "none":
        lines.append(f"  achieved MPC rate {_fmt(m.get('mpc_rate_hz'))} Hz (target {m['mpc_rate_target_hz']:g} Hz), "
                     f"{100 * m['late_solution_share']:.0f} % of solutions late (longer than a period), "
                     f"mean delay {m['delay_ms_mean']:.1f} ms")
        if m.get("sim_cpu_share") is not None:
            lines.append(f"  CPU share: simulation {100 * m['sim_cpu_share']:.0f} %, MPC {100 * (m['mpc_cpu_share'] or 0):.0f} % "
                         f"of a core; scheduling priority {m.get('realtime_priority') or 'default'}"
                         + (f", session nice {m['realtime_session_nice']}"
                            if m.get("realtime_session_nice") is not None else ""))
        if m.get("plant_lateness_ms"):
            late, plan = m["plant_lateness_ms"], m.get("cpu_plan") or {}
            shared = (f"; solver at {plan.get('solver_priority') or 'default'} on CPU {plan['solver']}, its "
                      f"{plan['helper_threads']} helper thread(s) at {plan.get('helper_priority') or 'default'} on CPU "
                      f"{plan['helpers']}" if plan.get("helper_threads") else "")
            lines.append(f"  plant loop lateness {late['mean']:.2f} ms mean, {late['p99']:.2f} p99, {late['max']:.2f} max "
                         f"({100 * m['plant_late_tick_share']:.1f} % of joint ticks over half a period){shared}")
        if m.get("realtime_step_anatomy_ms"):
            lines.append(anatomy_line(m["realtime_step_anatomy_ms"]))
        if m.get("realtime_competitors"):
            lines.append(f"  warning: other processes ran threads at real-time priority at the run's start or end (pids "
                         f"{m['realtime_competitors']}): they share its cores and the kernel's cap on real-time time "
                         "(/proc/sys/kernel/sched_rt_runtime_us), so its plans may be late; run one real-time job at a time")
    if m.get("est_base_vel_rmse_m_s") is not None:
        lines.append(f"  estimator RMSE: base position {100 * m['est_base_pos_rmse_m']:.2f} cm, velocity "
                     f"{m['est_base_vel_rmse_m_s']:.3f} m/s, orientation {math.degrees(m['est_orientation_rmse_rad']):.2f} deg")
    if m.get("ee_pos_rmse_m") is not None:
        lines.append(f"  end-effector position RMSE {100 * m['ee_pos_rmse_m']:.2f} cm")
    if m.get("ee_force_err_rel") is not None:
        lines.append(f"  end-effector force: measured {m['ee_force_measured_mean_n']:.1f} N vs target "
                     f"{m['ee_force_target_mean_n']:.1f} N, mean error {100 * m['ee_force_err_rel']:.1f} % of the target")
    if m.get("load_moved_m") is not None:
        lines.append(f"  load {m['load_kg']:.1f} kg moved {m['load_moved_m']:.3f} m of {m['load_expected_move_m']:.3f} m "
                     f"({'pulled' if m['pulled'] else 'NOT pulled'})")
    if m.get("ee_yield_m") is not None:
        lines.append(f"  end-effector yielded {', '.join(f'{100 * y:.1f}' for y in m['ee_yield_m'])} cm to the hand; "
                     f"max base tilt {m['base_tilt_max_deg']:.1f} deg")
    if m.get("rss_mb_end") is not None and m["duration_s"] >= LONG_RUN_S:
        window = f"{m['stability_window_s']:g} s"
        lines.append(f"  memory (RSS) {m['rss_mb_start']:.0f} MB at the start, {m['rss_mb_after_window']:.0f} MB after "
                     f"{window}, {m['rss_mb_end']:.0f} MB at the end ({m['rss_growth_pct']:+.1f} %); solve "
                     f"{_fmt(m.get('solve_ms_first_window_mean'))} ms mean over the first {window}, "
                     f"{_fmt(m.get('solve_ms_last_window_mean'))} ms over the last")
    if paths:
        lines.append(f"  wrote {len(paths)} files to {out_dir}/ (metrics.json, plots, replay.html)")
    if failure:
        lines.append(f"  FAILED: {failure} (exit code {EXIT_FAILED})")
    return lines


def anatomy_line(anatomy: dict) -> str:
    """Where a real-time plan's delay went beside its solve (ms means; `control/step_anatomy.py`)."""
    outside = sum(part["mean"] for name, part in anatomy.items() if name != "solve")
    parts = ", ".join(f"{name.replace('_', ' ')} {part['mean']:.2f}" for name, part in anatomy.items() if name != "solve")
    return f"  plan delay beside the solve {outside:.2f} ms mean: {parts}"


def plant_model_line(report: dict) -> str:
    """One summary line on the plant model a run simulated (`wbmpc.sim.plant_model`)."""
    reversed_ = f", joints reversed: {', '.join(report['joints_reversed'])}" if report["joints_reversed"] else ""
    welded = f", welded: {', '.join(report['welded_joints'])}" if report["welded_joints"] else ""
    return (f"  plant model {report['file']} ({report['format']}): {report['mass_kg']:.2f} kg against the controller's "
            f"{report['controller_mass_kg']:.2f} kg, joint anchors within {1e3 * report['joint_anchor_mismatch_m']:.1f} mm "
            f"at the zero pose{reversed_}{welded}")


def _fmt(value, spec: str = ".1f") -> str:
    return "-" if value is None else format(value, spec)


def _run_sweep(args: argparse.Namespace, robot, config, loads: list[float], out_dir, stop) -> int:
    from wbmpc.progress import ProgressBar
    from wbmpc.scenarios.outputs import MANIFEST, remove_previous_outputs, replace_file
    from wbmpc.scenarios.sweep import pull_sweep, sweep_table

    print(f"wbmpc run pull --sweep: loads {loads} kg, robot {robot.name}", file=sys.stderr)
    if not args.no_outputs:
        out_dir.mkdir(parents=True, exist_ok=True)
        remove_previous_outputs(out_dir)
        replace_file(out_dir / MANIFEST, to_json({"files": ["sweep.json"]}))
    bar = ProgressBar(len(loads), "pull sweep ", unit="loads")

    def on_row(report: dict) -> None:
        row = report["rows"][-1]
        bar.write(f"{row['load_kg']:5.1f} kg: " + ("rejected" if "rejected" in row else
                  f"{'pulled' if row['pulled'] else 'NOT pulled'}, fell {row['fell']}, load moved {row['load_moved_m']:.2f} m"
                  + (" (interrupted)" if row.get("interrupted") else "")))
        if not args.no_outputs:
            replace_file(out_dir / "sweep.json", to_json(report, indent=2))

    def progress(load: float, share: float, recoveries: int) -> None:
        bar.update(loads.index(load) + share, f"{load:5.1f} kg ")
        bar.set_recoveries(recoveries)

    with bar:
        report = pull_sweep(robot, loads, config, progress=progress, on_row=on_row, stop=stop)
        bar.close(complete=not report["interrupted"])
    _emit(args, report, sweep_table(report))
    if report["interrupted"]:
        return EXIT_INTERRUPTED
    return EXIT_OK if report["max_pulled_kg"] is not None else EXIT_FAILED  # no load pulled: the task failed


def _scenario_list() -> str:
    from wbmpc.scenarios import SCENARIOS, ScenarioOptions

    rows = [cls(ScenarioOptions()) for cls in SCENARIOS.values()]
    return "scenarios (default duration):\n" + "\n".join(
        f"  {s.name:<14} {s.default_duration_s:4g} s  {s.description}" for s in rows)


def _add_run_parser(sub, formatter) -> None:
    """`wbmpc run`: its options come from the fields of RunConfig, PdGains, OperatorConfig and ScenarioOptions
    (`wbmpc.options`),
    the scenario options grouped by the scenarios that read them."""
    from wbmpc.control.interpolator import PdGains
    from wbmpc.control.loop import MPC_RATE_HZ
    from wbmpc.options import add_arguments, scenario_groups
    from wbmpc.scenarios import SCENARIOS, RunConfig, ScenarioOptions

    run = sub.add_parser("run", help="closed-loop scenario in simulation: metrics, plots and a replay",
                         description=textwrap.fill(f"Run a scenario in closed loop (MPC at {MPC_RATE_HZ:g} Hz "
                         "by default, joint PD at 500 Hz) and write metrics.json, PNG plots and replay.html to --out. Ctrl-C stops the run, keeps "
                         "what was measured and exits 130.", 90), epilog=_scenario_list() + "\n\n" + EPILOG, formatter_class=formatter)
    run.add_argument("scenario", metavar="SCENARIO", help=f"one of: {', '.join(SCENARIOS)} (listed below)")
    _add_robot_options(run)
    run.add_argument("--out", metavar="DIR", help="output directory (default runs/SCENARIO); files of an earlier "
                     "wbmpc run there are replaced, other files are left alone")
    run.add_argument("--no-outputs", action="store_true", help="skip plots and replay (metrics only)")
    loop = run.add_argument_group("closed loop, solver and state (every scenario)")
    add_arguments(loop, RunConfig)
    loop.add_argument("--delay", metavar="DELAY", help="deprecated, the old form of --delay-mode / --delay-ms: "
                      "none | measured | measured-wall | realtime | a fixed delay in ms")
    add_arguments(loop, PdGains)
    from wbmpc.operator.config import OperatorConfig

    operator = run.add_argument_group("an operator in the loop: live commands and the viewer (docs/operator.md)")
    add_arguments(operator, OperatorConfig)
    plant_drive = run.add_argument_group(
        "drive train of the simulated robot, independent of the model's; VALUE or JOINT=VALUE,... (others 0)")
    plant_drive.add_argument("--plant-armature", metavar="KG_M2", help="rotor inertia (MuJoCo joint armature), kg m^2")
    plant_drive.add_argument("--plant-viscous-friction", metavar="NM_S",
                             help="viscous joint friction (MuJoCo joint damping), N m s/rad")
    plant_drive.add_argument("--plant-coulomb-friction", metavar="NM",
                             help="dry joint friction (MuJoCo joint frictionloss; mujoco plant only), N m")
    for scenarios in scenario_groups(ScenarioOptions):
        group = run.add_argument_group("scenario options (every scenario)" if scenarios is None else
                                       f"{', '.join(scenarios)} only (the other scenarios ignore these)")
        add_arguments(group, ScenarioOptions, scenarios)
        if scenarios == ("pull",):
            group.add_argument("--sweep", metavar="KG,KG,...", help="run each load and report the largest pulled")
    run.set_defaults(func=cmd_run)


def _add_bench_parsers(sub, formatter):
    """`wbmpc bench dynamics|robots|mpc|scaling|solvers|table1` (logic in wbmpc.bench, imported when a command runs);
    returns the bench subparsers (the hardware module adds `bench dds`)."""
    from wbmpc.control.loop import MPC_RATE_HZ

    bench = sub.add_parser("bench", help="benchmarks", epilog=EPILOG, formatter_class=formatter)
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    dyn = bench_sub.add_parser("dynamics", help="symbolic dynamics: instruction counts and errors vs pinocchio")
    _add_robot_options(dyn)
    dyn.add_argument("--samples", type=int, default=100, help="random states compared, 1-100000 (default 100)")
    dyn.add_argument("--seed", type=int, default=0, help="seed of the random states (default 0)")
    dyn.set_defaults(func=cmd_bench_dynamics)
    robots = bench_sub.add_parser("robots", help="bench dynamics over every legged preset (example-robot-data)")
    robots.add_argument("--robots", metavar="NAME,NAME", help="subset of presets (default: all)")
    robots.add_argument("--samples", type=int, default=10, help="random states per robot (default 10)")
    robots.add_argument("--seed", type=int, default=0, help="seed of the random states (default 0)")
    robots.add_argument("--mpc", action="store_true", help="also per quadruped: decision variables and closed-loop "
                        "Fatrop and RTI step times with its own settings (compiles each robot once, cached)")
    robots.add_argument("--steps", type=int, default=40, help=f"with --mpc: MPC steps at {MPC_RATE_HZ:g} Hz per solver (default 40)")
    robots.add_argument("--no-compile", action="store_true", help="with --mpc: solvers without generated C")
    robots.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    robots.set_defaults(func=cmd_bench_robots)

    mpc = bench_sub.add_parser("mpc", help="receding-horizon MPC benchmark in closed loop (solvers, warm start, grids)")
    _add_robot_options(mpc)
    mpc.add_argument("--steps", type=int, default=100, help=f"MPC steps at {MPC_RATE_HZ:g} Hz per run (default 100 = {100 / MPC_RATE_HZ:g} s)")
    mpc.add_argument("--gait", default="trot", help="stand, trot (default) or walk")
    mpc.add_argument("--plant", default="pinocchio", help="pinocchio (default) or mujoco")
    mpc.add_argument("--solvers", default="fatrop,ipopt", help="comma-separated from fatrop, fatrop-direct, ipopt, rti, sqp (anytime, no deadline: to convergence); the first (fatrop if listed) is the reference")
    mpc.add_argument("--nodes", type=int, default=15, help="horizon nodes (default 15)")
    mpc.add_argument("--uniform-dt", type=float, metavar="MS", help="step of the uniform grid compared (default: same horizon)")
    mpc.add_argument("--compiled", action="store_true", help="compiled solvers (C generated and cached)")
    mpc.add_argument("--collision-avoidance", action="store_true", help="also re-solve the same states with the "
                     "collision avoidance rows (their cost: same_states.collision_vs_plain)")
    mpc.add_argument("--threads", metavar="N[,N...]", help="fatrop-direct's stage evaluation threads (default: 2 "
                     "where two cores are free); several counts (e.g. 1,2) re-solve the same states on each and "
                     "report the speed-up against the first")
    mpc.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    mpc.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    mpc.set_defaults(func=lambda args: _bench_mpc().cli_bench_mpc(args, robot_from_args))

    scaling = bench_sub.add_parser("scaling", help="MPC step time against the horizon's nodes and the robot's "
                                                   "degrees of freedom (closed loop, plotted)")
    scaling.add_argument("--robot", default="b1_z1", metavar="NAME", help="robot of the horizon sweep (default b1_z1)")
    scaling.add_argument("--nodes-list", default="10,15,25,40", metavar="N,N", help="horizon nodes of the horizon "
                         "sweep (default 10,15,25,40)")
    scaling.add_argument("--robots", default="go2,b1_z1,g1,talos", metavar="NAME,NAME", help="presets of the robot "
                         "sweep (default go2,b1_z1,g1,talos)")
    scaling.add_argument("--nodes", type=int, default=15, help="horizon nodes of the robot sweep (default 15)")
    scaling.add_argument("--steps", type=int, default=40, help="MPC steps at 80 Hz per point (default 40)")
    scaling.add_argument("--solver", default="fatrop-direct", help="solver (default fatrop-direct)")
    scaling.add_argument("--compiled", action="store_true", help="compiled solvers (C generated and cached)")
    scaling.add_argument("--threads", type=int, help="fatrop-direct's stage evaluation threads (default: 2 where two "
                         "cores are free)")
    scaling.add_argument("--plot", metavar="FILE", help="draw both sweeps into FILE (PNG)")
    scaling.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    scaling.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    scaling.set_defaults(func=lambda args: _bench_module("scaling").cli_bench_scaling(args, _load_preset))

    solvers = bench_sub.add_parser("solvers", help="Fatrop vs IPOPT, warm vs cold, adaptive vs uniform grid, "
                                                   "solve time vs number of nodes")
    _add_robot_options(solvers)
    solvers.add_argument("--steps", type=int, default=40, help="MPC steps per closed-loop run (default 40)")
    solvers.add_argument("--nodes-list", default="6,10,15,20,25", help="horizon sizes of the scaling sweep")
    solvers.add_argument("--compiled", action="store_true", help="compare compiled solvers (C generated and cached)")
    solvers.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE (and FILE.md)")
    solvers.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    solvers.set_defaults(func=lambda args: _bench_module("solvers").cli_bench_solvers(args, robot_from_args))

    table1 = bench_sub.add_parser("table1", help="the paper's Table I: six formulations before/after compilation")
    _add_robot_options(table1)
    table1.add_argument("--steps", type=int, default=100, help="MPC steps of the closed-loop trot (default 100)")
    table1.add_argument("--formulations", help="comma-separated subset (default: all six)")
    table1.add_argument("--no-compile", action="store_true", help="skip code generation (pre-compiled times only)")
    table1.add_argument("--markdown", action="store_true", help="print the markdown table (beside the paper's values)")
    table1.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE (and FILE.md)")
    table1.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    table1.set_defaults(func=lambda args: _bench_module("table1").cli_bench_table1(args, robot_from_args))
    return bench_sub


def _add_solve_parser(sub, formatter) -> None:
    """`wbmpc solve`: one OCP (logic in wbmpc.bench.mpc)."""
    solve = sub.add_parser("solve", help="one OCP from the nominal stance: size, status, iterations, solve time",
                           epilog=EPILOG, formatter_class=formatter)
    _add_robot_options(solve)
    solve.add_argument("--formulation", default="wb_inverse", help="OCP formulation (default wb_inverse)")
    solve.add_argument("--gait", default="trot", help="stand, trot (default) or walk")
    solve.add_argument("--nodes", type=int, default=15, help="horizon nodes, >= 2 (default 15 = the paper's)")
    solve.add_argument("--solver", default="fatrop", help="fatrop (default), fatrop-direct, ipopt or rti (one SQP iteration)")
    solve.add_argument("--uniform-dt", type=float, metavar="MS", help="uniform steps of MS ms instead of 10-100 ms geometric")
    solve.add_argument("--t", type=float, default=0.0, metavar="S", help="gait time of the solve (default 0)")
    solve.add_argument("--compiled", action="store_true", help="compiled solver (C generated, compiled and cached)")
    solve.set_defaults(func=lambda args: _bench_mpc().cli_solve(args, robot_from_args))


def build_parser() -> argparse.ArgumentParser:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(prog="wbmpc", description=__doc__.splitlines()[0], epilog=EPILOG,
                                     formatter_class=formatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    info = sub.add_parser("info", help="robot model summary", description="Robot model summary: nq, nv, joints, "
                          "mass, feet, arm end-effector.", epilog=EPILOG, formatter_class=formatter)
    _add_robot_options(info)
    info.set_defaults(func=cmd_info)

    setup = sub.add_parser("setup", help="install the AVX2 BLASFEO under Fatrop/HPIPM (from PyPI, verified; "
                                         "about 2-3x faster solver linear algebra)")
    setup.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    setup.add_argument("--force", action="store_true", help="download and verify again even if installed")
    setup.set_defaults(func=cmd_setup)

    _add_run_parser(sub, formatter)

    bench_sub = _add_bench_parsers(sub, formatter)
    _add_solve_parser(sub, formatter)

    from wbmpc.hardware.commands import add_bench_dds, add_hardware_commands

    add_hardware_commands(sub, _add_robot_options, robot_from_args, _emit, _task_library())  # robot-sim, deploy (DDS)
    add_bench_dds(bench_sub, _add_robot_options, robot_from_args, _emit)
    from wbmpc.campaign.command import add_parser as add_campaign_parser

    add_campaign_parser(sub)
    return parser


def _task_library():
    """The scenarios' tasks and run options for robot-sim and deploy (`hardware.commands.TaskLibrary`)."""
    from wbmpc.hardware.commands import TaskLibrary
    from wbmpc.scenarios import RunConfig, ScenarioOptions, make_scenario

    return TaskLibrary(run_options=RunConfig, task_options=ScenarioOptions, make_task=make_scenario)


def _bench_module(name: str):
    import importlib

    return importlib.import_module(f"wbmpc.bench.{name}")


def _load_preset(name: str):
    from wbmpc.robots import load_robot

    return load_robot(name)


def _bench_mpc():
    from wbmpc.bench import mpc

    return mpc


def _dispatch(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except BaseException:
        from wbmpc.progress import close_all

        close_all()
        raise


def field_flags_of_commands() -> dict[str, str]:
    """{config field: flag} of every command: the run options' from their declarations (`wbmpc.options`)."""
    from wbmpc.control.interpolator import PdGains
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.options import field_flags
    from wbmpc.scenarios import RunConfig, ScenarioOptions

    return {**OTHER_FIELD_FLAGS, **field_flags(RunConfig, ScenarioOptions, PdGains, OperatorConfig)}


def main(argv: list[str] | None = None) -> int:
    """Entry point of `wbmpc` and `python -m wbmpc`; returns the exit code (see `EXIT_CODES`)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return _dispatch(args)
    except ConfigError as exc:
        print(f"wbmpc: error: {exc.worded(field_flags_of_commands()) if exc.field else exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ModelError as exc:
        print(f"wbmpc: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except WbmpcError as exc:  # RunError, a diverged simulation, a failed compile: the run failed, the input was fine
        print(f"wbmpc: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("wbmpc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
