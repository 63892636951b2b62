"""`wbmpc bench solvers`: Fatrop vs IPOPT on the same NLPs, warm vs cold start, adaptive vs uniform
grid (all from `bench mpc`'s same-state re-solves), and solve time against the number of nodes
(paper, section VI-A: about linear for Fatrop).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from wbmpc.bench.mpc import (
    _closed_loop,
    _output,
    bench_markdown,
    bench_mpc,
    grid_for,
    mpc_config,
    write_report,
)
from wbmpc.errors import ConfigError
from wbmpc.progress import ProgressBar


def node_scaling(robot, nodes_list: list[int], steps: int, compiled: bool, progress=None) -> dict:
    """Closed-loop trot with Fatrop for each horizon size; a least-squares line through the means."""
    from wbmpc.control import MPC

    rows = []
    for i, nodes in enumerate(nodes_list):
        mpc = MPC(robot, mpc_config(nodes=nodes, compiled=compiled, robot=robot))
        summary, _, _ = _closed_loop(robot, mpc, "pinocchio", steps,
                                     lambda share, i=i: progress and progress(i + share, f"{nodes} nodes"))
        rows.append({"nodes": nodes, "decision_variables": summary["decision_variables"],
                     "solve_ms": summary["solve_ms"], "iterations_mean": summary["iterations"]["mean"],
                     "failures": summary["failures"], "compiled": mpc.solver.is_compiled,
                     "ms_per_iteration": (summary["solve_ms"]["mean"] / summary["iterations"]["mean"]
                                          if summary["iterations"]["mean"] else None)})
    x = np.array([r["nodes"] for r in rows], dtype=float)
    y = np.array([r["ms_per_iteration"] or np.nan for r in rows], dtype=float)
    fit = None
    if len(rows) >= 2 and np.all(np.isfinite(y)):
        slope, intercept = np.polyfit(x, y, 1)
        residual = y - (slope * x + intercept)
        r2 = 1 - float(np.sum(residual**2)) / max(float(np.sum((y - y.mean()) ** 2)), 1e-12)
        fit = {"ms_per_iteration_per_node": float(slope), "intercept_ms": float(intercept), "r_squared": r2}
    return {"rows": rows, "linear_fit": fit}


def bench_solvers(robot, steps: int = 40, nodes_list: list[int] | None = None, compiled: bool = False,
                  show_progress: bool = True) -> dict:
    nodes_list = nodes_list or [6, 10, 15, 20, 25]
    for nodes in nodes_list:
        grid_for(nodes)
    if not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"--steps must be an integer >= 1, got {steps}")
    start = time.perf_counter()
    comparison = bench_mpc(robot, steps=steps, compiled=compiled, show_progress=show_progress)
    progress = ProgressBar(len(nodes_list), unit="runs", enabled=None if show_progress else False)
    scaling = node_scaling(robot, nodes_list, steps, compiled, progress.update)
    progress.close(complete=True)
    return {"robot": robot.name, "compiled": compiled, "comparison": comparison, "node_scaling": scaling,
            "wall_s": time.perf_counter() - start}


def solvers_markdown(report: dict) -> str:
    lines = [bench_markdown(report["comparison"]), "",
             f"### Solve time vs horizon nodes (Fatrop{', compiled' if report['compiled'] else ''}, closed-loop trot)", "",
             "| nodes | decision variables | solve ms mean | std | iterations | ms per iteration | failures |",
             "|---|---|---|---|---|---|---|"]
    for r in report["node_scaling"]["rows"]:
        ms = r["solve_ms"]
        per_it = "-" if r["ms_per_iteration"] is None else f"{r['ms_per_iteration']:.2f}"
        lines.append(f"| {r['nodes']} | {r['decision_variables']} | {ms['mean']:.1f} | {ms['std']:.1f} | "
                     f"{r['iterations_mean']:.2f} | {per_it} | {r['failures']} |")
    fit = report["node_scaling"]["linear_fit"]
    if fit:
        lines.append(f"\nLinear fit of time per iteration: {fit['ms_per_iteration_per_node']:.2f} ms per node "
                     f"+ {fit['intercept_ms']:.2f} ms, R^2 = {fit['r_squared']:.3f} (paper: about linear).")
    return "\n".join(lines)


def cli_bench_solvers(args, robot_from_args) -> int:
    try:
        nodes_list = [int(n) for n in args.nodes_list.split(",") if n.strip()]
    except ValueError:
        raise ConfigError(f"--nodes-list must be comma-separated integers, got {args.nodes_list!r}") from None
    robot = robot_from_args(args)
    report = bench_solvers(robot, steps=args.steps, nodes_list=nodes_list, compiled=args.compiled,
                           show_progress=not args.no_progress)
    text = solvers_markdown(report)
    if args.out:
        write_report(Path(args.out), report, text)
    _output(args, report, text)
    return 0
