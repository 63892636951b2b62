"""`wbmpc robot-sim` and `wbmpc deploy` (argument parsing and printing; logic in robot_sim/deploy)."""

from __future__ import annotations

import argparse
import json
import sys

from wbmpc.errors import ConfigError
from wbmpc.hardware.network import check_interface

DEPLOY_SCENARIOS = ("stand", "trot-in-place", "trot-forward", "arm-track")


def add_hardware_commands(sub, add_robot_options, robot_from_args, emit) -> None:
    sim = sub.add_parser("robot-sim", help="MuJoCo standing in for the robot behind Unitree LowState/LowCmd (DDS)")
    add_robot_options(sim)
    _add_network_options(sim)
    sim.add_argument("--mode", default="realtime", choices=("realtime", "lockstep"),
                     help="realtime: wall-clock ticks; lockstep: wait for each tick's LowCmd (simulated time)")
    sim.add_argument("--duration", type=float, help="simulated seconds after the first LowCmd (default: until Ctrl-C)")
    sim.add_argument("--start", default="standing", choices=("standing", "lying"), help="initial pose")
    sim.add_argument("--no-noise", action="store_true", help="perfect sensors (default: Unitree-like noise)")
    sim.add_argument("--watchdog-ms", type=float, default=100.0, help="no LowCmd for this long -> damping (realtime)")
    sim.add_argument("--idle-exit", type=float, metavar="S", help="exit when no valid LowCmd came for S seconds")
    sim.add_argument("--push-time", type=float, metavar="S", help="base velocity kick at this simulated time")
    sim.add_argument("--push-speed", type=float, default=0.8, help="kick speed, m/s, to the robot's left (world y)")
    sim.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    sim.add_argument("--drift-window", metavar="T0,T1", help="also report the true drift between these simulated "
                     "times (e.g. 2.5,22.5: the MPC phase of deploy after stand-up)")
    sim.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    sim.set_defaults(func=lambda args: cmd_robot_sim(args, robot_from_args, emit))

    dep = sub.add_parser("deploy", help="run the MPC on a robot (or robot-sim) over LowState/LowCmd: stand up, "
                                        "MPC, lie down")
    add_robot_options(dep)
    _add_network_options(dep)
    dep.add_argument("--scenario", default="trot-in-place", help=f"one of: {', '.join(DEPLOY_SCENARIOS)}")
    dep.add_argument("--duration", type=float, default=10.0, help="seconds of MPC control (robot time)")
    dep.add_argument("--lockstep", action="store_true", help="solve each MPC step before answering (robot-sim "
                                                              "--mode lockstep); default: MPC in its own process")
    dep.add_argument("--compiled", action="store_true", help="compiled solver (C generated and cached)")
    dep.add_argument("--nodes", type=int, default=15, help="horizon nodes (default 15 = the paper's)")
    dep.add_argument("--speed", type=float, default=0.2, help="trot-forward / arm-track speed, m/s")
    dep.add_argument("--kp", type=float, default=0.0, help="leg joint Kp of eq. (10), sent in LowCmd")
    dep.add_argument("--kd", type=float, default=5.0, help="leg joint Kd of eq. (10), sent in LowCmd")
    dep.add_argument("--no-lie-down", action="store_true", help="go straight to damping at the end")
    dep.add_argument("--state-timeout-ms", type=float, help="no LowState for this long -> stop commanding (default "
                     "100 ms; 3000 ms with --lockstep, where the robot process may stall on a loaded machine)")
    dep.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    dep.set_defaults(func=lambda args: cmd_deploy(args, robot_from_args, emit))


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


def _add_network_options(parser) -> None:
    parser.add_argument("--network", default="lo", help="network interface of the robot (lo: robot-sim on this machine)")
    parser.add_argument("--domain", type=int, default=0, help="DDS domain id (default 0, as on Unitree robots)")


_shown = [-1]


def _progress(share: float) -> None:
    percent = int(100 * min(share, 1.0))
    if percent == _shown[0]:
        return
    _shown[0] = percent
    bar = int(30 * min(share, 1.0))
    print(f"\r[{'#' * bar}{' ' * (30 - bar)}] {100 * share:5.1f}%", end="", file=sys.stderr, flush=True)


def _write(path, payload) -> None:
    if path:
        with open(path, "w") as fh:
            json.dump(payload, fh, indent=2)


def cmd_robot_sim(args: argparse.Namespace, robot_from_args, emit) -> int:
    from wbmpc.estimation import SensorConfig
    from wbmpc.hardware.robot_sim import RobotSimConfig, RobotSimulator
    from wbmpc.hardware.safety import SafetyConfig
    from wbmpc.hardware.sdk import load_sdk

    load_sdk()
    check_interface(args.network)
    robot = robot_from_args(args)
    sensors = SensorConfig.noiseless() if args.no_noise else SensorConfig(seed=args.seed)
    config = RobotSimConfig(network=args.network, domain_id=args.domain, mode=args.mode, duration_s=args.duration,
                            start=args.start, sensors=sensors, safety=SafetyConfig(command_timeout_ms=args.watchdog_ms),
                            idle_exit_s=args.idle_exit, push_time_s=args.push_time,
                            push_velocity_m_s=(0.0, args.push_speed, 0.0))
    sim = RobotSimulator(robot, config)
    print(f"wbmpc robot-sim: {robot.name} on {args.network} (DDS domain {args.domain}), {args.mode}, motors "
          f"{sim.motors.describe()}; waiting for LowCmd (Ctrl-C stops)", file=sys.stderr, flush=True)
    import signal

    signal.signal(signal.SIGINT, lambda *_: sim.stop())
    signal.signal(signal.SIGTERM, lambda *_: sim.stop())
    result = sim.run(progress=_progress if args.duration else None)
    report = result.summary()
    if args.drift_window:
        start, end = (float(x) for x in args.drift_window.split(","))
        report["window_drift_cm_s"] = result.drift_cm_s(start, end)
    print(file=sys.stderr)
    _write(args.out, report)
    share = report["ticks_on_time_share"]
    lines = [
        f"robot-sim {report['mode']}: {report['sim_time_s']:.2f} s simulated in {report['wall_time_s']:.1f} s, "
        f"{'FELL at %.2f s' % report['fell_at_s'] if report['fell'] else 'stayed up'}, "
        f"drift {report['base_drift_cm_s'] or 0:.2f} cm/s",
        (f"  ticks {report['ticks']}, on time {100 * share:.2f} %; CPU per tick p50 {report['tick_cpu_ms_p50']:.2f} ms, "
         f"p99 {report['tick_cpu_ms_p99']:.2f} ms (budget {1e3 / config.state_rate_hz:.1f} ms)") if share else "  no ticks",
        f"  LowCmd received {report['commands_received']}, rejected {report['commands_rejected']}, "
        f"watchdog (damping) at {report['watchdog_events_s']} s",
    ]
    if "window_drift_cm_s" in report:
        lines.append(f"  true drift between {args.drift_window} s: {report['window_drift_cm_s']:.2f} cm/s")
    if report["rtt_ms_p50"] is not None:
        lines.append(f"  LowState -> LowCmd round trip p50 {report['rtt_ms_p50']:.2f} ms, p99 {report['rtt_ms_p99']:.2f} ms "
                     f"({report['rtt_samples']} samples; includes the controller's work)")
    emit(args, report, "\n".join(lines))
    return 0


def cmd_deploy(args: argparse.Namespace, robot_from_args, emit) -> int:
    from wbmpc.control.interpolator import PdGains
    from wbmpc.hardware.deploy import Controller, DeployConfig
    from wbmpc.hardware.safety import SafetyConfig
    from wbmpc.hardware.sdk import load_sdk
    from wbmpc.scenarios import RunConfig, ScenarioOptions, make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    load_sdk()
    if args.scenario not in DEPLOY_SCENARIOS:
        raise ConfigError(f"unknown deploy scenario '{args.scenario}'; available: {', '.join(DEPLOY_SCENARIOS)} "
                          "(scene objects and pushes exist only in simulation)")
    check_interface(args.network)
    robot = robot_from_args(args)
    scenario = make_scenario(args.scenario, robot, ScenarioOptions(speed_m_s=args.speed))
    # the robot does not wait for the solver: the real-time defaults (anytime SQP with the period's budget,
    # delay compensation, short recovery), lockstep included, so a robot-sim rehearsal runs what the robot runs
    mpc_config = mpc_config_for(scenario, RunConfig(scenario=args.scenario, nodes=args.nodes, compiled=args.compiled,
                                                    solver="auto", delay="realtime"))
    config = DeployConfig(network=args.network, domain_id=args.domain, duration_s=args.duration, lockstep=args.lockstep,
                          lie_down=not args.no_lie_down, gains=scenario.pd_gains(PdGains(kp_leg=args.kp, kd_leg=args.kd)),
                          safety=SafetyConfig(state_timeout_ms=args.state_timeout_ms or (3000.0 if args.lockstep else 100.0)))
    print(f"wbmpc deploy {args.scenario}: {robot.name} on {args.network} (DDS domain {args.domain}), "
          f"{'lock-step' if args.lockstep else 'real time'}; building the MPC", file=sys.stderr, flush=True)
    controller = Controller(robot, mpc_config, config)
    report = controller.run(scenario.commands(robot), progress=_progress).summary()
    print(file=sys.stderr)
    _write(args.out, report)
    lines = [
        f"deploy {args.scenario}: phases {' -> '.join(f'{p} ({t:.2f} s)' for t, p in report['phases'])}",
        f"  stopped by {report['stopped_by']}, fell {report['fell']}; LowState {report['states_received']} "
        f"(rejected {report['states_rejected']}), LowCmd {report['commands_sent']}",
        f"  MPC {report['mpc_solves']} solves, {report['mpc_failures']} failed, "
        f"{report['solve_ms_mean'] or 0:.1f} ms mean; controller work per tick p50 "
        f"{report['controller_tick_ms_p50'] or 0:.2f} ms, p99 {report['controller_tick_ms_p99'] or 0:.2f} ms",
    ]
    emit(args, report, "\n".join(lines))
    return 0 if not report["fell"] else 1
