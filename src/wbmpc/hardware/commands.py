"""`wbmpc robot-sim` and `wbmpc deploy` (argument parsing and printing; logic in robot_sim/deploy)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from dataclasses import dataclass
from typing import Callable

from wbmpc.errors import ConfigError
from wbmpc.hardware.network import check_interface
from wbmpc.progress import ProgressBar

DEPLOY_SCENARIOS = ("stand", "trot-in-place", "trot-forward", "walk-in-place", "walk-forward", "arm-track")


@dataclass(frozen=True)
class TaskLibrary:
    """The tasks `wbmpc deploy` runs and the declarations of the `wbmpc run` options robot-sim and deploy share,
    passed in by the front end (`wbmpc.cli` gives the scenarios'): the robot interface itself does not depend on
    the simulated scenarios or their runner. The MPC's options come from `wbmpc.control.policy.MpcChoices`."""

    run_options: type  # declares duration_s and seed (`wbmpc.scenarios.RunConfig`)
    task_options: type  # declares and checks speed_m_s, push_speed_m_s, push_time_s (`ScenarioOptions`)
    # (name, robot, task options) -> a task: needs(robot) (`TaskNeeds`), commands(robot), ee_reference(robot),
    # pd_gains(gains) (`wbmpc.scenarios.make_scenario`)
    make_task: Callable


def add_hardware_commands(sub, add_robot_options, robot_from_args, emit, tasks: TaskLibrary) -> None:
    """robot-sim and deploy; options they share with `wbmpc run` come from its declarations (`wbmpc.options`)."""
    _add_robot_sim_parser(sub, add_robot_options, robot_from_args, emit, tasks)
    _add_deploy_parser(sub, add_robot_options, robot_from_args, emit, tasks)


def _add_robot_sim_parser(sub, add_robot_options, robot_from_args, emit, tasks: TaskLibrary) -> None:
    from wbmpc.options import add_declared

    RunConfig, ScenarioOptions = tasks.run_options, tasks.task_options
    sim = sub.add_parser("robot-sim", help="MuJoCo standing in for the robot behind Unitree LowState/LowCmd (DDS)")
    add_robot_options(sim)
    _add_network_options(sim)
    sim.add_argument("--mode", default="realtime", choices=("realtime", "lockstep"),
                     help="realtime: wall-clock ticks; lockstep: wait for each tick's LowCmd (simulated time)")
    add_declared(sim, RunConfig, "duration_s", cli_default=None, default_text="until Ctrl-C",
                 help="simulated seconds after the first LowCmd")
    sim.add_argument("--start", default="standing", choices=("standing", "lying"), help="initial pose")
    sim.add_argument("--no-noise", action="store_true", help="perfect sensors (default: Unitree-like noise)")
    sim.add_argument("--watchdog-ms", type=float, default=100.0, help="no LowCmd for this long -> damping (realtime)")
    sim.add_argument("--idle-exit", type=float, metavar="S", help="exit when no valid LowCmd came for S seconds")
    add_declared(sim, ScenarioOptions, "push_time_s", cli_default=None, default_text="no kick",
                 help="base velocity kick at this simulated time")
    add_declared(sim, ScenarioOptions, "push_speed_m_s", help="kick speed to the robot's left (world y)")
    add_declared(sim, RunConfig, "seed", help="seed of the sensor noise")
    add_declared(sim, RunConfig, "plant_model")
    sim.add_argument("--plant-payload-kg", type=float, metavar="KG", help="a mass the model does not know, at the hand "
                     "(a robot with an arm) or at the base origin (without): what deploy --identify-mass estimates")
    sim.add_argument("--plant-com-offset", metavar="X,Y,Z", help="the plant's base CoM moved by this (base frame, m)")
    sim.add_argument("--drift-window", metavar="T0,T1", help="also report the true drift between these simulated "
                     "times (e.g. 2.5,22.5: the MPC phase of deploy after stand-up)")
    sim.add_argument("--sport-mode", default="normal", help="the motion switcher's mode at start (LowCmd is ignored "
                     "until a controller releases it; '' for none)")
    sim.add_argument("--refuse-sport-release", action="store_true", help="keep the sport mode when asked to release "
                     "it (a robot that refuses)")
    sim.add_argument("--arm-silent-after", type=float, metavar="S", help="fault: the Z1 stops sending its state S "
                     "simulated seconds after the first LowCmd")
    sim.add_argument("--corrupt-every", type=int, metavar="N", help="fault: every N-th LowState with a bad CRC and "
                     "Z1 state with a NaN")
    sim.add_argument("--gantry", action="store_true", help="a safety strap above the base, slack while the robot "
                     "stands, carrying it once it sinks 30 %% below its standing height (humanoids: deploy's crouch and "
                     "damping end in it, as under a gantry on hardware)")
    sim.add_argument("--state-rate", type=float, metavar="HZ", help="LowState rate (default 500 Hz as a Unitree robot; "
                     "200 Hz with --robot-link sim, unitree_mujoco's 5 ms step)")
    sim.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    remote = sim.add_mutually_exclusive_group()
    remote.add_argument("--remote-script", metavar="FILE.yaml", help="an operator's remote, scripted (sticks and keys "
                        "at times after the first LowCmd; see docs/operator.md): published in LowState's "
                        "wireless_remote and on rt/wirelesscontroller")
    remote.add_argument("--remote-gamepad", metavar="DEVICE", nargs="?", const="auto", help="a gamepad on this machine "
                        "as the robot's remote (evdev; without DEVICE the first gamepad found)")
    _add_arm_options(sim)
    sim.set_defaults(func=lambda args: cmd_robot_sim(args, robot_from_args, emit, tasks))


def _add_deploy_parser(sub, add_robot_options, robot_from_args, emit, tasks: TaskLibrary) -> None:
    from wbmpc.control.interpolator import PdGains
    from wbmpc.control.policy import MpcChoices
    from wbmpc.options import add_declared, declared_help

    RunConfig, ScenarioOptions = tasks.run_options, tasks.task_options
    dep = sub.add_parser("deploy", help="run the MPC on a robot (or robot-sim) over LowState/LowCmd: stand up, "
                                        "MPC, lie down")
    add_robot_options(dep)
    _add_network_options(dep)
    dep.add_argument("--scenario", default="trot-in-place", help=f"one of: {', '.join(DEPLOY_SCENARIOS)}")
    add_declared(dep, RunConfig, "duration_s", default_text="10 s; a command script's own duration; until the "
                 "lie-down command with --remote, --keyboard or --gamepad", help="seconds of MPC control (robot time)")
    dep.add_argument("--lockstep", action="store_true", help="solve each MPC step before answering (robot-sim "
                                                              "--mode lockstep); default: MPC in its own process")
    for name in ("compiled", "nodes", "mpc_rate_hz"):
        add_declared(dep, MpcChoices, name)
    add_declared(dep, ScenarioOptions, "speed_m_s", help="trot-forward / arm-track speed")
    add_declared(dep, MpcChoices, "solver", help="the MPC's solver as `wbmpc run --solver`, but auto: the anytime "
                 "SQP on the period's budget in real time, converged Fatrop in a compiled lock-step")
    add_declared(dep, MpcChoices, "identify_mass", help="estimate the base CoM offset and a payload online from the "
                 "estimated state and the motor law's torques and plan with them; the report gives "
                 "base_com_offset_estimate_m and payload_estimate_kg")
    for name in ("kp_leg", "kd_leg"):  # sent in LowCmd
        add_declared(dep, PdGains, name, help=f"{declared_help(PdGains, name)}, sent in LowCmd")
    dep.add_argument("--no-sport-release", action="store_true", help="do not call the motion switcher (a robot "
                     "without one, its sport mode stopped by hand)")
    dep.add_argument("--max-plan-age-ms", type=float, default=250.0, help="an MPC plan older than this -> damping "
                     "and exit 1 (default 250 ms)")
    _add_arm_options(dep)
    dep.add_argument("--no-lie-down", action="store_true", help="go straight to damping at the end")
    dep.add_argument("--state-timeout-ms", type=float, help="no LowState (or Z1 state) for this long -> damping, exit 1 (default "
                     "100 ms; 3000 ms with --lockstep, where the robot process may stall on a loaded machine)")
    dep.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    _add_operator_options(dep)
    dep.set_defaults(func=lambda args: cmd_deploy(args, robot_from_args, emit, tasks))


def _add_operator_options(dep) -> None:
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.options import add_declared

    operator = dep.add_argument_group("an operator in the loop (docs/operator.md)")
    operator.add_argument("--remote", action="store_true", help="drive the MPC phase from the robot's own remote "
                          "(LowState wireless_remote and rt/wirelesscontroller): left stick moves, right stick turns, "
                          "start walk/stand, B stop, L2+A lie down")
    for name in ("commands_file", "keyboard", "gamepad", "max_accel_m_s2", "max_yaw_accel_rad_s2"):
        add_declared(operator, OperatorConfig, name)
    operator.add_argument("--meshcat", action="store_true", help="serve a live page (meshcat, localhost) with the "
                          "estimated state and the MPC's plan at 25 Hz")


def add_bench_dds(bench_sub, add_robot_options, robot_from_args, emit) -> None:
    dds = bench_sub.add_parser("dds", help="DDS round trip LowState -> LowCmd through an echo process (p50/p99)")
    add_robot_options(dds)
    _add_network_options(dds)
    dds.add_argument("--samples", type=int, default=2000, help="round trips measured (default 2000)")
    dds.add_argument("--rate", type=float, default=500.0, help="LowState rate, Hz")
    dds.set_defaults(func=lambda args: cmd_bench_dds(args, robot_from_args, emit))


def cmd_bench_dds(args, robot_from_args, emit) -> int:
    from wbmpc.hardware.latency import dds_round_trip
    from wbmpc.hardware.sdk import load_sdk

    load_sdk()
    check_interface(args.network)
    robot = robot_from_args(args)
    r = dds_round_trip(robot, args.network, args.domain, args.samples, args.rate)
    emit(args, r, f"DDS round trip on {r['network']} ({r['samples']} of {r['sent']} at {r['rate_hz']:.0f} Hz): "
                  f"p50 {r['rtt_ms_p50']:.3f} ms, p90 {r['rtt_ms_p90']:.3f} ms, p99 {r['rtt_ms_p99']:.3f} ms, "
                  f"max {r['rtt_ms_max']:.2f} ms, lost {100 * r['lost_share']:.1f} %")
    return 0


def _add_arm_options(parser) -> None:
    """--arm (unless the robot options define it, as the model's arm) and the Z1's UDP ports."""
    if "--arm" not in parser._option_string_actions:
        parser.add_argument("--arm", default="auto", choices=("auto", "z1", "none"),
                            help="z1: the model's Z1 arm over the Z1's UDP interface (auto: when the model has one)")
    parser.add_argument("--z1-ports", default="8071,8072", metavar="CTRL,SDK", help="UDP ports of z1_controller and of "
                        "its SDK (default 8071,8072 as Unitree's; robot-sim serves the first)")
    if parser.prog.endswith("deploy"):
        parser.add_argument("--z1-ip", default="127.0.0.1", help="address of z1_controller (it answers the SDK on "
                            "127.0.0.1 only: run deploy on the arm's computer)")


def _arm_settings(args) -> dict:
    try:
        ports = tuple(int(p) for p in args.z1_ports.split(","))
    except ValueError:
        ports = ()
    if len(ports) != 2 or not all(0 < p < 65536 for p in ports):
        raise ConfigError(f"--z1-ports takes two UDP ports CTRL,SDK (e.g. 8071,8072), got {args.z1_ports!r}")
    # the robot options' --arm names the model's arm; the Z1 link follows the model (auto: when it has Z1 joints)
    arm = getattr(args, "arm", None)
    arm = arm if arm in ("z1", "none") else "auto"
    return {"arm": arm, "z1_ports": ports}


def deploy_mpc_config(robot, task_needs, *, nodes: int, compiled: bool, solver: str, lockstep: bool,
                      mpc_rate_hz: float | None = None, identify_mass: bool = False):
    """The MPC configuration of `wbmpc deploy`: the one `wbmpc run` builds for the same robot and task with an
    estimated state (`--state estimated`) and, unless lock-step, in real time (`--delay-mode realtime`);
    `identify_mass`: with the inertial parameters in the NLP (set from the identification with each request)."""
    from wbmpc.control.policy import MpcChoices, mpc_config

    rate = {} if mpc_rate_hz is None else {"mpc_rate_hz": mpc_rate_hz}
    choices = MpcChoices(nodes=nodes, compiled=compiled, solver=solver, estimated_state=True,
                         delay_mode="none" if lockstep else "realtime", **rate)
    config = mpc_config(robot, task_needs, choices)
    if identify_mass:  # a real-time solver process too: the estimate goes with each request
        config = dataclasses.replace(config, ocp=dataclasses.replace(config.ocp, inertial_parameters=True))
    return config


def _add_network_options(parser) -> None:
    parser.add_argument("--network", default="lo", help="network interface of the robot (lo: robot-sim on this machine)")
    parser.add_argument("--domain", type=int, default=0, help="DDS domain id (default 0, as on Unitree robots; "
                        "Unitree's simulator uses 1)")
    if parser.prog.endswith("deploy"):
        parser.add_argument("--robot-link", default="robot", choices=("robot", "sim"), help="robot: a Unitree robot, "
                            "strict (LowStates without header, CRC, advancing tick or motor temperatures are rejected, "
                            "counted and named); sim: Unitree's simulator (unitree_mujoco), which leaves them at 0: "
                            "accepted, time from the receive clock")
    elif parser.prog.endswith("robot-sim"):
        parser.add_argument("--robot-link", default="robot", choices=("robot", "sim"), help="robot: publish as a Unitree "
                            "robot; sim: imitate Unitree's simulator (unitree_mujoco: header, CRC, tick and temperatures "
                            "0, 200 Hz, the motor law once per LowCmd and held, no checks, no watchdog)")


def _plant_errors(args, robot):
    """robot-sim's --plant-payload-kg / --plant-com-offset as `ModelErrors` (None without either)."""
    from wbmpc.sim.model_errors import ModelErrors

    payload, offset = args.plant_payload_kg, args.plant_com_offset
    if payload is None and offset is None:
        return None
    try:
        xyz = tuple(float(x) for x in offset.split(",")) if offset else (0.0, 0.0, 0.0)
    except ValueError:
        xyz = ()
    if len(xyz) != 3:
        raise ConfigError(f"--plant-com-offset takes X,Y,Z in metres (base frame), got {offset!r}")
    payload = payload or 0.0
    return ModelErrors(base_com_offset_m=xyz, **({"ee_payload_kg": payload} if robot.arm_ee else {"base_payload_kg": payload}))


def _write(path, payload) -> None:
    if path:
        with open(path, "w") as fh:
            json.dump(payload, fh, indent=2)


def cmd_robot_sim(args: argparse.Namespace, robot_from_args, emit, tasks: TaskLibrary) -> int:
    from wbmpc.hardware.robot_sim import RobotSimulator
    from wbmpc.hardware.sdk import load_sdk

    load_sdk()
    tasks.task_options(push_speed_m_s=args.push_speed, push_time_s=args.push_time or 0.0)  # the declared ranges
    check_interface(args.network)
    robot = robot_from_args(args)
    config = dataclasses.replace(_robot_sim_config(args), model_errors=_plant_errors(args, robot))
    sim = RobotSimulator(robot, config)
    if args.remote_script or args.remote_gamepad:
        from wbmpc.operator.remote_script import GamepadRemote, RemotePublisher, ScriptedRemote, read_remote_script

        sim.remote = RemotePublisher(ScriptedRemote(read_remote_script(args.remote_script)) if args.remote_script
                                     else GamepadRemote(None if args.remote_gamepad == "auto" else args.remote_gamepad))
    arm = (f"; Z1 arm on UDP {config.z1_ports[0]} ({sim.arm_map.describe()})" if sim.arm_map is not None else "")
    link = (f"imitating Unitree's simulator (unset header, CRC, tick, temperatures; {config.state_rate_hz:.0f} Hz)"
            if config.robot_link == "sim" else f"sport mode '{config.sport_mode}'")
    print(f"wbmpc robot-sim: {robot.name} on {args.network} (DDS domain {args.domain}), {args.mode}, motors "
          f"{sim.motors.describe()}{arm}; {link}; waiting for LowCmd (Ctrl-C stops)",
          file=sys.stderr, flush=True)
    import signal

    signal.signal(signal.SIGINT, lambda *_: sim.stop())
    signal.signal(signal.SIGTERM, lambda *_: sim.stop())
    if args.duration:  # the bar (silent off a terminal) counts the simulated seconds after the first LowCmd
        with ProgressBar(args.duration, "robot-sim ", unit="s") as bar:
            result = sim.run(progress=lambda share: bar.update(share * args.duration))
    else:
        result = sim.run()
    report = {**result.summary(), "plant_model": sim.plant.plant_model_report()}
    if args.drift_window:
        start, end = (float(x) for x in args.drift_window.split(","))
        report["window_drift_cm_s"] = result.drift_cm_s(start, end)
    _write(args.out, report)
    emit(args, report, "\n".join(_robot_sim_summary(report, config, args)))
    return 0


def _robot_sim_config(args: argparse.Namespace):
    from wbmpc.estimation import SensorConfig
    from wbmpc.hardware.robot_sim import UNITREE_SIM_STATE_RATE_HZ, RobotSimConfig
    from wbmpc.hardware.safety import SafetyConfig

    sensors = SensorConfig.noiseless() if args.no_noise else SensorConfig(seed=args.seed)
    return RobotSimConfig(network=args.network, domain_id=args.domain, mode=args.mode, duration_s=args.duration,
                          start=args.start, sensors=sensors, safety=SafetyConfig(command_timeout_ms=args.watchdog_ms),
                          idle_exit_s=args.idle_exit, push_time_s=args.push_time,
                          push_velocity_m_s=(0.0, args.push_speed, 0.0), sport_mode=args.sport_mode,
                          refuse_sport_release=args.refuse_sport_release, arm_silent_after_s=args.arm_silent_after,
                          corrupt_every=args.corrupt_every, robot_link=args.robot_link, gantry=args.gantry,
                          state_rate_hz=args.state_rate or (UNITREE_SIM_STATE_RATE_HZ if args.robot_link == "sim"
                                                            else 500.0),
                          plant_model=args.plant_model, **_arm_settings(args))


def _robot_sim_summary(report: dict, config, args: argparse.Namespace) -> list[str]:
    share = report["ticks_on_time_share"]
    lines = [
        f"robot-sim {report['mode']}: {report['sim_time_s']:.2f} s simulated in {report['wall_time_s']:.1f} s, "
        f"{'FELL at %.2f s' % report['fell_at_s'] if report['fell'] else 'stayed up'}, "
        f"drift {report['base_drift_cm_s'] or 0:.2f} cm/s",
        (f"  ticks {report['ticks']}, on time {100 * share:.2f} %; CPU per tick p50 {report['tick_cpu_ms_p50']:.2f} ms, "
         f"p99 {report['tick_cpu_ms_p99']:.2f} ms (budget {1e3 / config.state_rate_hz:.1f} ms)") if share else "  no ticks",
        f"  LowCmd received {report['commands_received']}, rejected {report['commands_rejected']}, "
        f"watchdog (damping) at {report['watchdog_events_s']} s, "
        f"{', '.join(f'{x:.0f}' for x in report['watchdog_latency_ms']) or 'no'} ms after the last valid LowCmd",
    ]
    if report["gantry"] is not None:
        gantry = report["gantry"]
        lines.append("  gantry: " + ("slack throughout" if gantry["taut_since_s"] is None else
                                     f"taut from {gantry['taut_since_s']:.2f} s, largest pull {gantry['max_force_n']:.0f} N"))
    if "window_drift_cm_s" in report:
        lines.append(f"  true drift between {args.drift_window} s: {report['window_drift_cm_s']:.2f} cm/s")
    if report["plant_model"] is not None:
        from wbmpc.cli import plant_model_line

        lines.append(plant_model_line(report["plant_model"]))
    if report["rtt_ms_p50"] is not None:
        lines.append(f"  LowState -> LowCmd round trip p50 {report['rtt_ms_p50']:.2f} ms, p99 {report['rtt_ms_p99']:.2f} ms "
                     f"({report['rtt_samples']} samples; includes the controller's work)")
    arm = report["arm"]
    if arm is not None:
        rtt = (f"; Z1 state -> command round trip p50 {arm['rtt_ms_p50']:.2f} ms, p99 {arm['rtt_ms_p99']:.2f} ms"
               if arm["rtt_ms_p50"] is not None else "")
        lines.append(f"  Z1 commands received {arm['commands_received']}, rejected {arm['commands_rejected']}, "
                     f"watchdog (PASSIVE) {arm['watchdog_events']}x "
                     f"({', '.join(f'{x:.0f}' for x in arm['watchdog_latency_ms']) or 'no'} ms after the last valid command), "
                     f"passive at end {arm['passive_at_end']}{rtt}")
    return lines


def cmd_deploy(args: argparse.Namespace, robot_from_args, emit, tasks: TaskLibrary) -> int:
    from wbmpc.hardware.deploy import Controller, DeployFailure
    from wbmpc.hardware.sdk import load_sdk
    from wbmpc.solvers.nlp import SOLVERS

    load_sdk()
    if args.scenario not in DEPLOY_SCENARIOS:
        raise ConfigError(f"unknown deploy scenario '{args.scenario}'; available: {', '.join(DEPLOY_SCENARIOS)} "
                          "(scene objects and pushes exist only in simulation)")
    if args.solver not in ("auto", *SOLVERS):
        raise ConfigError(f"unknown solver '{args.solver}'; available: auto, {', '.join(SOLVERS)}")
    check_interface(args.network)
    robot = robot_from_args(args)
    scenario = tasks.make_task(args.scenario, robot, tasks.task_options(speed_m_s=args.speed))
    operator = _deploy_operator(args, robot, scenario)  # sources checked before anything is built
    if args.duration is None:  # a script's own length; live sources: until the operator lies the robot down
        args.duration = operator.duration_s or (math.inf if operator.active and operator.script is None else 10.0)
    mpc_config = deploy_mpc_config(robot, scenario.needs(robot), nodes=args.nodes, compiled=args.compiled,
                                   solver=args.solver, lockstep=args.lockstep, mpc_rate_hz=args.mpc_rate,
                                   identify_mass=args.identify_mass)
    config = _deploy_config(args, robot, scenario)
    print(f"wbmpc deploy {args.scenario}: {robot.name} on {args.network} (DDS domain {args.domain}, robot link "
          f"{args.robot_link}), {'lock-step' if args.lockstep else 'real time'}, solver {args.solver}; building the MPC",
          file=sys.stderr, flush=True)
    controller = Controller(robot, mpc_config, config)
    failure = None
    operator.attach(controller)
    try:
        operator.start()
        ee_reference = scenario.ee_reference(robot) if args.scenario == "arm-track" else None
        bar_length = args.duration if math.isfinite(args.duration) else None  # silent off a terminal or unbounded
        with ProgressBar(bar_length or 1.0, f"deploy {args.scenario} ", unit="s", enabled=None if bar_length else False) as bar:
            report = controller.run(operator.commands, ee_reference=ee_reference, stop=operator.stop,
                                    progress=(lambda share: bar.update(share * args.duration)) if bar_length else None
                                    ).summary()
    except DeployFailure as exc:
        failure = exc
        report = controller.report.summary()
    finally:
        operator.close()
    report.update(operator.metrics(controller))
    _write(args.out, report)
    emit(args, report, "\n".join(_deploy_summary(report, args) + operator.summary_lines(report.get("operator"))))
    if failure is not None:
        print(f"wbmpc: error: {failure}", file=sys.stderr)
        return 1
    return 0 if not report["fell"] else 1


def _deploy_operator(args, robot, scenario):
    """The deploy's operator sources (`--remote`, `--commands`, `--keyboard`, `--gamepad`) and live page; a standing
    scenario moves onto the robot's walking gait when a source may start it walking."""
    from wbmpc.gait import natural_gait
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.operator.deploy import DeployOperator
    from wbmpc.options import declared

    given = {f.name: getattr(args, opt.dest) for f, opt in declared(OperatorConfig)  # deploy has no --viewer
             if opt.flag and getattr(args, opt.dest, None) is not None}
    operator = DeployOperator(robot, OperatorConfig(**given), scenario, remote=args.remote, meshcat=args.meshcat)
    if operator.active and scenario.gait == "stand":
        scenario.gait = natural_gait(len(robot.feet))
    return operator


def _deploy_config(args: argparse.Namespace, robot, scenario):
    from wbmpc.control.tuning import tuning_for
    from wbmpc.hardware.deploy import DeployConfig
    from wbmpc.hardware.safety import SafetyConfig

    overrides = {k: v for k, v in (("kp_leg", args.kp), ("kd_leg", args.kd)) if v is not None}
    tuning = tuning_for(robot)
    gains = dataclasses.replace(tuning.gains, **overrides)

    def joint_loop_gains(hold_s: float):  # the tuned gains for the link's hold; --kp/--kd as given
        return scenario.pd_gains(dataclasses.replace(tuning.gains_at(hold_s), **overrides))

    return DeployConfig(network=args.network, domain_id=args.domain, duration_s=args.duration, lockstep=args.lockstep,
                        lie_down=not args.no_lie_down, gains=scenario.pd_gains(gains),
                        joint_loop_gains=joint_loop_gains, identify_mass=args.identify_mass,
                        safety=SafetyConfig(state_timeout_ms=args.state_timeout_ms or (3000.0 if args.lockstep else 100.0)),
                        sport_release=not args.no_sport_release, max_plan_age_s=args.max_plan_age_ms / 1e3,
                        arm_state_timeout_ms=args.state_timeout_ms or (3000.0 if args.lockstep else 100.0),
                        z1_ip=args.z1_ip, robot_link=args.robot_link, mpc_rate_hz=args.mpc_rate, **_arm_settings(args))


def _deploy_summary(report: dict, args: argparse.Namespace) -> list[str]:
    arm = report["arm"]
    lines = [
        f"deploy {args.scenario}: phases {' -> '.join(f'{p} ({t:.2f} s)' for t, p in report['phases'])}",
        f"  stopped by {report['stopped_by']}, fell {report['fell']}; LowState {report['states_received']} "
        f"(rejected {report['states_rejected']}), LowCmd {report['commands_sent']}",
        f"  robot link {report['robot_link']}: time from the {report['time_source']}"
        + (f", accepted unset {report['accepted_unset']}" if report["accepted_unset"] else "")
        + (f", mode_machine {report['mode_machine']}" if report["mode_machine"] is not None else "")
        + (f"; the robot's clock ran at {report['clock_rate']:.2f} x this clock (joint motion against reported velocity)"
           + (": the robot (a simulator falling behind the wall clock?) did not run in real time"
              if abs(report["clock_rate"] - 1.0) > 0.1 else "") if report["clock_rate"] is not None else ""),
        f"  MPC {report['mpc_solves']} solves, {report['mpc_failures']} failed, "
        f"{report['solve_ms_mean'] or 0:.1f} ms mean; plan age p50 {report['plan_age_ms_p50'] or 0:.1f} ms, max "
        f"{report['plan_age_ms_max'] or 0:.1f} ms; controller work per tick p50 "
        f"{report['controller_tick_ms_p50'] or 0:.2f} ms, p99 {report['controller_tick_ms_p99'] or 0:.2f} ms",
    ]
    scheduling = report.get("scheduling")
    if scheduling is not None:
        plan = scheduling["cpu_plan"]
        lines.append(f"  controller loop at {scheduling['realtime_priority']} on CPU {plan['loop'] or 'any'}, solver on "
                     f"{plan['solver'] or 'any'}, its {plan['helper_threads']} helper thread(s) on {plan['helpers'] or 'any'}"
                     + (f" (solver at {plan['solver_priority']}, helpers at {plan['helper_priority']})"
                        if plan.get("solver_priority") else ""))
    if report["ee_rmse_estimated_m"] is not None:
        lines.append(f"  end effector RMSE {100 * report['ee_rmse_estimated_m']:.2f} cm (from the estimated state)")
    if arm is not None:
        lines.append(f"  Z1 states {arm['states_received']} (rejected {arm['states_rejected']}), commands "
                     f"{arm['commands_sent']}")
    if report["sport_mode"] is not None:
        lines.append(f"  sport mode '{report['sport_mode']['released']}' released, restored {report['sport_mode']['restored']}")
    return lines
