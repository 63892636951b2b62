"""The `wbmpc` command: info, solve, run and benchmarks (contracts in DESIGN.md).

With --json exactly one JSON object goes to stdout; human-readable text goes to stderr.
Bad input exits with code 2 and a message naming the problem and the fix.
"""

from __future__ import annotations

import argparse
import json
import sys

from wbmpc.errors import WbmpcError


def _add_robot_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("robot")
    group.add_argument("--robot", default="b1_z1", help="preset: b1_z1 (default), b1_z1_full, b1, go2, a1")
    group.add_argument("--urdf", help="custom robot URDF (overrides --robot)")
    group.add_argument("--srdf", help="SRDF with the reference pose of a custom robot")
    group.add_argument("--pose", help="SRDF group_state name used as nominal pose")
    group.add_argument("--feet", help="comma-separated foot frame names of a custom robot")
    group.add_argument("--arm-ee", help="arm end-effector frame of a custom robot")
    group.add_argument("--lock", help="comma-separated joints to lock at the reference pose")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _split(text: str | None) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()] if text else []


def robot_from_args(args: argparse.Namespace):
    from wbmpc.robots import RobotModel, custom_spec, load_robot

    if args.urdf:
        if not args.feet:
            raise WbmpcError("a custom --urdf needs --feet F1,F2,... (the foot frame names)")
        return RobotModel(custom_spec(args.urdf, _split(args.feet), args.arm_ee, args.srdf, args.pose, _split(args.lock)))
    return load_robot(args.robot)


def _emit(args: argparse.Namespace, payload: dict, human: str) -> None:
    if args.json:
        print(json.dumps(payload))
        print(human, file=sys.stderr)
    else:
        print(human)


def cmd_info(args: argparse.Namespace) -> int:
    robot = robot_from_args(args)
    info = robot.summary()
    lines = [f"{k}: {v}" for k, v in info.items()]
    _emit(args, info, "\n".join(lines))
    return 0


def cmd_bench_dynamics(args: argparse.Namespace) -> int:
    from wbmpc.bench.dynamics import validate_dynamics

    robot = robot_from_args(args)
    report = validate_dynamics(robot, samples=args.samples, seed=args.seed)
    lines = [f"symbolic dynamics of {robot.name} vs pinocchio ({args.samples} random states)"]
    lines += [f"  {name:26s} {r['instructions']:6d} instructions   max error {r['max_abs_error']:.2e}"
              for name, r in report["functions"].items()]
    paper = 3818
    rnea = report["functions"]["rnea"]["instructions"]
    lines.append(f"  RNEA: {rnea} instructions = {rnea / paper:.2f}x the paper's Pinocchio-CasADi RNEA ({paper})")
    _emit(args, report, "\n".join(lines))
    return 0


def _scenario_options(args: argparse.Namespace):
    from wbmpc.scenarios import ScenarioOptions

    return ScenarioOptions(
        speed_m_s=args.speed, push_speed_m_s=args.push_speed, push_time_s=args.push_time,
        push_direction_deg=args.push_direction, gait=args.gait, load_kg=args.load_kg,
        load_friction_mu=args.load_friction, cable_length_m=args.cable_length, pull_speed_m_s=args.pull_speed,
        force_n=args.force_n, box_kg=args.box_kg, board=args.board, board_friction_mu=args.board_friction,
        wipe_pattern=args.pattern, wipe_size_m=args.wipe_size, wipe_period_s=args.wipe_period,
        hand_force_n=args.hand_force, compliant_kp_arm=args.compliant_kp_arm, compliant_kd_arm=args.compliant_kd_arm,
        compliant_return_gain_1_s=args.compliant_return,
    )


def _progress(share: float, label: str = "") -> None:
    bar = int(30 * min(share, 1.0))
    print(f"\r{label}[{'#' * bar}{' ' * (30 - bar)}] {100 * share:5.1f}%", end="", file=sys.stderr, flush=True)


def cmd_run(args: argparse.Namespace) -> int:
    """Closed-loop scenario: progress on stderr, summary, metrics.json + plots + replay in --out."""
    import warnings
    from pathlib import Path

    from wbmpc.control.interpolator import PdGains
    from wbmpc.scenarios import RunConfig, make_scenario, prepare_output_dir, run_scenario, write_outputs

    robot = robot_from_args(args)
    options = _scenario_options(args)
    if args.sweep is not None and args.scenario != "pull":
        raise WbmpcError(f"--sweep runs the pull scenario over loads; it does not apply to {args.scenario}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.sweep is None:
            make_scenario(args.scenario, robot, options)  # bad input or missing arm: exit 2 before building
    for w in caught:
        print(f"wbmpc: warning: {w.message}", file=sys.stderr)
    if args.duration is not None and not args.duration > 0:
        raise WbmpcError(f"--duration must be positive, got {args.duration}")
    out_dir = Path(args.out or f"runs/{args.scenario}")
    if not args.no_outputs:
        prepare_output_dir(out_dir)
    config = RunConfig(scenario=args.scenario, duration_s=args.duration, delay=args.delay, plant=args.plant,
                       nodes=args.nodes, uniform_dt_ms=args.uniform_dt, seed=args.seed, options=options,
                       gains=PdGains(kp_leg=args.kp, kd_leg=args.kd), formulation=args.formulation,
                       compiled=args.compiled)
    if args.sweep is not None:
        return _run_sweep(args, robot, config, out_dir)
    print(f"wbmpc run {args.scenario}: robot {robot.name}, delay {args.delay}, plant {args.plant}", file=sys.stderr)
    result = run_scenario(robot, config, progress=_progress)
    print(file=sys.stderr)
    paths = write_outputs(robot, result, out_dir) if not args.no_outputs else []
    m = result.metrics
    lines = [
        f"scenario {m['scenario']}: {'FELL at %.2f s' % m['fell_at_s'] if m['fell'] else 'stayed up'} "
        f"over {m['duration_s']:.2f} s",
        f"  base drift {m['base_drift_cm_s']:.2f} cm/s, base velocity RMSE {m['base_vel_rmse']:.3f} m/s",
        f"  max torque / limit {m['max_torque_ratio']:.2f}; MPC {m['mpc_solves']} solves, {m['mpc_failures']} failed, "
        f"solve {m['solve_ms']['mean']:.1f} ms mean ({m['solve_ms']['max']:.1f} max), {m['iterations_mean']:.1f} iterations",
    ]
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
    if paths:
        lines.append(f"  wrote {len(paths)} files to {out_dir}/ (metrics.json, plots, replay.html)")
    _emit(args, m, "\n".join(lines))
    return 0


def _run_sweep(args: argparse.Namespace, robot, config, out_dir) -> int:
    from wbmpc.scenarios.sweep import parse_loads, pull_sweep, sweep_table

    loads = parse_loads(args.sweep)
    print(f"wbmpc run pull --sweep: loads {loads} kg, robot {robot.name}", file=sys.stderr)
    def on_row(report: dict) -> None:
        row = report["rows"][-1]
        print(f"\r{row['load_kg']:5.1f} kg: " + ("rejected" if "rejected" in row else
              f"{'pulled' if row['pulled'] else 'NOT pulled'}, fell {row['fell']}, load moved {row['load_moved_m']:.2f} m")
              + " " * 20, file=sys.stderr)
        if not args.no_outputs:
            (out_dir / "sweep.json").write_text(json.dumps(report, indent=2))

    report = pull_sweep(robot, loads, config, progress=lambda load, s: _progress(s, f"{load:5.1f} kg "), on_row=on_row)
    print(file=sys.stderr)
    _emit(args, report, sweep_table(report))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="wbmpc", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    info = sub.add_parser("info", help="robot model summary")
    _add_robot_options(info)
    info.set_defaults(func=cmd_info)

    from wbmpc.scenarios import SCENARIOS

    run = sub.add_parser("run", help="closed-loop scenario in simulation: metrics, plots and a replay")
    run.add_argument("scenario", help=f"one of: {', '.join(SCENARIOS)}")
    _add_robot_options(run)
    run.add_argument("--duration", type=float, help="simulated seconds (scenario default otherwise)")
    run.add_argument("--delay", default="none", help="none | measured | realtime | a fixed delay in ms")
    run.add_argument("--plant", default="mujoco", help="mujoco (default) | pinocchio")
    run.add_argument("--out", help="output directory (default runs/SCENARIO)")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--nodes", type=int, default=15)
    run.add_argument("--uniform-dt", type=float, help="uniform time steps of this many ms instead of geometric")
    run.add_argument("--speed", type=float, default=0.2, help="forward speed of trot-forward/arm-track, m/s")
    run.add_argument("--push-speed", type=float, default=0.8, help="push: base velocity kick, m/s")
    run.add_argument("--push-time", type=float, default=2.0, help="push: time of the kick, s")
    run.add_argument("--push-direction", type=float, default=90.0, help="push: direction in the heading frame, deg")
    run.add_argument("--kp", type=float, default=0.0, help="leg joint Kp of eq. (10)")
    run.add_argument("--kd", type=float, default=5.0, help="leg joint Kd of eq. (10)")
    run.add_argument("--no-outputs", action="store_true", help="skip plots and replay (metrics only)")
    run.add_argument("--formulation", default="wb_inverse", help="OCP formulation (default wb_inverse; see bench table1)")
    run.add_argument("--compiled", action="store_true",
                     help="generate C for the NLP, compile it once (cached in ~/.cache/wbmpc) and use it")
    run.add_argument("--gait", help="override the scenario's gait: stand, trot or walk (pull: stand = pull in stance)")
    manip = run.add_argument_group("loco-manipulation (pull, push-box, wipe, compliant)")
    manip.add_argument("--load-kg", type=float, default=10.0, help="pull: mass of the load on the floor, kg")
    manip.add_argument("--load-friction", type=float, default=0.3, help="pull: load-floor friction coefficient")
    manip.add_argument("--cable-length", type=float, default=1.6, help="pull: cable length, m")
    manip.add_argument("--pull-speed", type=float, default=0.1, help="pull: backwards walking (or arm) speed, m/s")
    manip.add_argument("--sweep", metavar="KG,KG,...", help="pull: run each load and report the largest pulled")
    manip.add_argument("--force-n", type=float, help="end-effector force target, N (pull: the load's sliding "
                       "tension; push-box: 20; wipe: 10 normal)")
    manip.add_argument("--box-kg", type=float, default=5.0, help="push-box: mass of the box, kg")
    manip.add_argument("--board", default="vertical", help="wipe: vertical (whiteboard) or horizontal (table)")
    manip.add_argument("--board-friction", type=float, default=0.3, help="wipe: board friction coefficient")
    manip.add_argument("--pattern", default="circle", help="wipe: circle or eight")
    manip.add_argument("--wipe-size", type=float, default=0.1, help="wipe: pattern radius, m")
    manip.add_argument("--wipe-period", type=float, default=4.0, help="wipe: pattern period, s")
    manip.add_argument("--hand-force", type=float, default=30.0, help="compliant: peak force of the external hand, N")
    manip.add_argument("--compliant-kp-arm", type=float, default=2.0, help="compliant: arm joint Kp")
    manip.add_argument("--compliant-kd-arm", type=float, default=0.3, help="compliant: arm joint Kd")
    manip.add_argument("--compliant-return", type=float, default=0.5, metavar="1/S",
                       help="compliant: gain of the slow return to the nominal end-effector place (0 = none)")
    run.set_defaults(func=cmd_run)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    dyn = bench_sub.add_parser("dynamics", help="symbolic dynamics: instruction counts and errors vs pinocchio")
    _add_robot_options(dyn)
    dyn.add_argument("--samples", type=int, default=100)
    dyn.add_argument("--seed", type=int, default=0)
    dyn.set_defaults(func=cmd_bench_dynamics)

    # solve / bench mpc: logic in wbmpc.bench.mpc (imported when the command runs)
    solve = sub.add_parser("solve", help="one OCP from the nominal stance: size, status, iterations, solve time")
    _add_robot_options(solve)
    solve.add_argument("--formulation", default="wb_inverse", help="OCP formulation (default wb_inverse)")
    solve.add_argument("--gait", default="trot", help="stand, trot (default) or walk")
    solve.add_argument("--nodes", type=int, default=15, help="horizon nodes, >= 2 (default 15 = the paper's)")
    solve.add_argument("--solver", default="fatrop", help="fatrop (default) or ipopt")
    solve.add_argument("--uniform-dt", type=float, metavar="MS", help="uniform steps of MS ms instead of 10-100 ms geometric")
    solve.add_argument("--t", type=float, default=0.0, metavar="S", help="gait time of the solve (default 0)")
    solve.add_argument("--compiled", action="store_true", help="compiled solver (C generated, compiled and cached)")
    solve.set_defaults(func=lambda args: _bench_mpc().cli_solve(args, robot_from_args))

    mpc = bench_sub.add_parser("mpc", help="receding-horizon MPC benchmark in closed loop (solvers, warm start, grids)")
    _add_robot_options(mpc)
    mpc.add_argument("--steps", type=int, default=100, help="MPC steps at 80 Hz per run (default 100 = 1.25 s)")
    mpc.add_argument("--gait", default="trot", help="stand, trot (default) or walk")
    mpc.add_argument("--plant", default="pinocchio", help="pinocchio (default) or mujoco")
    mpc.add_argument("--solvers", default="fatrop,ipopt", help="comma-separated; the first (fatrop if listed) is the reference")
    mpc.add_argument("--nodes", type=int, default=15, help="horizon nodes (default 15)")
    mpc.add_argument("--uniform-dt", type=float, metavar="MS", help="step of the uniform grid compared (default: same horizon)")
    mpc.add_argument("--out", metavar="FILE", help="also write the JSON report to FILE")
    mpc.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    mpc.set_defaults(func=lambda args: _bench_mpc().cli_bench_mpc(args, robot_from_args))

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

    from wbmpc.campaign.command import add_parser as add_campaign_parser

    add_campaign_parser(sub)
    return parser


def _bench_module(name: str):
    import importlib

    return importlib.import_module(f"wbmpc.bench.{name}")


def _bench_mpc():
    from wbmpc.bench import mpc

    return mpc


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except WbmpcError as exc:
        print(f"wbmpc: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
