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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="wbmpc", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    info = sub.add_parser("info", help="robot model summary")
    _add_robot_options(info)
    info.set_defaults(func=cmd_info)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    dyn = bench_sub.add_parser("dynamics", help="symbolic dynamics: instruction counts and errors vs pinocchio")
    _add_robot_options(dyn)
    dyn.add_argument("--samples", type=int, default=100)
    dyn.add_argument("--seed", type=int, default=0)
    dyn.set_defaults(func=cmd_bench_dynamics)
    return parser


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
