"""How an MPC step's time grows with the horizon and with the robot (`wbmpc bench scaling`).

Two sweeps of closed-loop runs (the pinocchio plant, each robot's own tuning: quadrupeds trot, bipeds walk):
- horizon: one robot (default b1_z1) on 10, 15, 25 and 40 nodes of the paper's geometric grid (10 -> 100 ms steps,
  so a longer horizon also reaches further ahead);
- degrees of freedom: go2 (18), b1_z1 (22), g1 (29) and TALOS (38) on 15 nodes.
Each point reports the solve and whole-step times (wall and this process's CPU), iterations and failures; `--plot`
draws both sweeps. The compiled stage functions depend on the robot and formulation only (`solvers/stage_library.py`),
so the horizon sweep compiles once per robot. Times are the machine's of the moment: compare points of one run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wbmpc.bench.mpc import MPC_RATE_HZ, _closed_loop, _output, grid_for, mpc_config
from wbmpc.errors import ConfigError, check_number
from wbmpc.strict_json import to_json

NODES = (10, 15, 25, 40)
ROBOTS = ("go2", "b1_z1", "g1", "talos")


def _gait(robot) -> str:
    return "trot" if len(robot.feet) >= 4 else "walk"


def scaling_point(robot, nodes: int, steps: int, solver: str, compiled: bool, threads: int | None) -> dict:
    """One closed-loop run of `steps` MPC steps: sizes, times, iterations."""
    from wbmpc.control import MPC

    config = mpc_config(gait=_gait(robot), solver=solver, nodes=nodes, compiled=compiled, robot=robot,
                        threads=threads)
    mpc = MPC(robot, config)
    summary, _, _ = _closed_loop(robot, mpc, "pinocchio", steps, lambda share: None)
    return {"robot": robot.name, "nv": int(robot.nv), "nodes": nodes, "gait": config.gait,
            "decision_variables": int(mpc.problem.n_variables), "solve_ms": summary["solve_ms"],
            "step_cpu_ms": summary["step_cpu_ms"], "iterations_mean": summary["iterations"]["mean"],
            "failures": summary["failures"], "fell": summary["fell"],
            "parts_ms_mean": (summary.get("split") or {}).get("parts_ms_mean")}


def bench_scaling(load_robot, robot_name: str = "b1_z1", nodes_list=NODES, robots=ROBOTS, nodes: int = 15,
                  steps: int = 40, solver: str = "fatrop-direct", compiled: bool = True, threads: int | None = None,
                  progress=None) -> dict:
    """The horizon sweep of `robot_name` over `nodes_list` and the robot sweep over `robots` at `nodes`."""
    for n in (*nodes_list, nodes):
        grid_for(n)
    check_number("steps", steps, low=1, high=100_000)
    say = progress or (lambda text: None)
    horizon, dof = [], []
    robot = load_robot(robot_name)
    for n in nodes_list:
        say(f"{robot_name}, {n} nodes")
        horizon.append(scaling_point(robot, n, steps, solver, compiled, threads))
    for name in robots:
        say(f"{name}, {nodes} nodes")
        dof.append(scaling_point(load_robot(name), nodes, steps, solver, compiled, threads))
    return {"solver": solver, "compiled": compiled, "steps": steps, "mpc_rate_hz": MPC_RATE_HZ, "threads": threads,
            "horizon": {"robot": robot_name, "points": horizon}, "dof": {"nodes": nodes, "points": dof}}


def scaling_text(report: dict) -> str:
    lines = [f"## MPC step time against the horizon and the robot ({report['solver']}"
             f"{', compiled' if report['compiled'] else ''}, {report['steps']} closed-loop steps each)", "",
             "| robot | nv | nodes | decision variables | solve ms mean | max | step CPU ms mean | iterations | "
             "failures | fell |", "|---|---|---|---|---|---|---|---|---|---|"]
    for point in (*report["horizon"]["points"], *report["dof"]["points"]):
        ms, cpu = point["solve_ms"], point["step_cpu_ms"]
        lines.append(f"| {point['robot']} | {point['nv']} | {point['nodes']} | {point['decision_variables']} | "
                     f"{ms['mean']:.1f} | {ms['max']:.1f} | {cpu['mean']:.1f} | {point['iterations_mean']:.2f} | "
                     f"{point['failures']} | {point['fell']} |")
    return "\n".join(lines)


def plot_scaling(report: dict, path: Path) -> Path:
    """Step time against nodes (left) and against the robot's degrees of freedom (right), mean and max."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4), dpi=120, layout="constrained")
    FigureCanvasAgg(fig)
    for ax, sweep, key, label in ((fig.add_subplot(1, 2, 1), report["horizon"], "nodes", "horizon nodes"),
                                  (fig.add_subplot(1, 2, 2), report["dof"], "nv", "degrees of freedom (nv)")):
        points = sorted(sweep["points"], key=lambda p: p[key])
        x = np.array([p[key] for p in points], dtype=float)
        for field, style in (("solve_ms", "o-"), ("step_cpu_ms", "s--")):
            ax.plot(x, [p[field]["mean"] for p in points], style, label=f"{field.replace('_', ' ')} mean")
        ax.plot(x, [p["solve_ms"]["max"] for p in points], "^:", label="solve ms max")
        if key == "nv":
            for p in points:
                ax.annotate(p["robot"], (p["nv"], p["solve_ms"]["mean"]), textcoords="offset points", xytext=(4, 4),
                            fontsize=8)
        title = f"{sweep['robot']}" if key == "nodes" else f"{sweep['nodes']} nodes"
        ax.set(xlabel=label, ylabel="ms", title=f"{report['solver']}: {title}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return Path(path)


def _ints(text: str, name: str) -> tuple[int, ...]:
    try:
        return tuple(int(item) for item in text.split(",") if item.strip())
    except ValueError:
        raise ConfigError(f"--{name} takes comma-separated integers, got {text!r}") from None


def cli_bench_scaling(args, load_robot) -> int:
    import sys

    report = bench_scaling(load_robot, robot_name=args.robot, nodes_list=_ints(args.nodes_list, "nodes-list"),
                           robots=tuple(r.strip() for r in args.robots.split(",") if r.strip()), nodes=args.nodes,
                           steps=args.steps, solver=args.solver, compiled=args.compiled, threads=args.threads,
                           progress=lambda text: print(f"bench scaling: {text}", file=sys.stderr))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(to_json(report, indent=2) + "\n")
    if args.plot:
        report["plot"] = str(plot_scaling(report, Path(args.plot)))
    _output(args, report, scaling_text(report))
    return 0
