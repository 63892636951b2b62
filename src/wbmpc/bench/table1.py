"""`wbmpc bench table1`: the paper's Table I on this machine.

Each formulation runs N MPC steps (80 Hz) of a trot in closed loop on the pinocchio plant with the
non-compiled solver (CasADi's SX virtual machine); the states it met are recorded (iterations,
failures and falls come from this run). Its NLP is then generated as C, compiled (or taken from the
cache) and the recorded states are re-solved in sequence by both solvers, each warm-started from its
own previous solution, alternating state by state so that load affects both alike: these give the
"pre-compilation" and "post-compilation" solve times. Rows carry the table's columns next to the
paper's values.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from wbmpc.bench.mpc import (
    MPC_RATE_HZ,
    _closed_loop,
    _machine,
    _output,
    _stats,
    mpc_config,
    write_report,
)
from wbmpc.errors import ConfigError, unknown_name
from wbmpc.progress import ProgressBar

# Table I of the paper (B2 + Z1, 15 nodes): instructions, decision variables, solve ms mean (std)
PAPER_TABLE1 = {
    "wb_inverse": {"instructions": 3818, "decision_variables": 1226, "precompiled": (29.0, 0.9), "compiled": (12.5, 0.5)},
    "wb_forward": {"instructions": 7764, "decision_variables": 1094, "precompiled": (81.6, 9.2), "compiled": (34.2, 3.8)},
    "centroidal_vel_path": {"instructions": 4070, "decision_variables": 938, "precompiled": (33.0, 1.9), "compiled": (16.0, 0.9)},
    "centroidal_vel": {"instructions": 4727, "decision_variables": 854, "precompiled": (115.5, 14.5), "compiled": None},
    "centroidal_acc_path": {"instructions": 15628, "decision_variables": 1178, "precompiled": (103.7, 3.9), "compiled": None},
    "centroidal_acc": {"instructions": 16339, "decision_variables": 1094, "precompiled": (189.8, 18.0), "compiled": None},
}
STATE_INPUT = {
    "wb_inverse": ("[q, v]", "[tau_j, a, F]"),
    "wb_forward": ("[q, v]", "[tau_j, F]"),
    "centroidal_vel_path": ("[h_com, q]", "[v, F]"),
    "centroidal_vel": ("[h_com, q]", "[v_j, F]"),
    "centroidal_acc_path": ("[q, v]", "[a, F]"),
    "centroidal_acc": ("[q, v]", "[a_j, F]"),
}


def _resolve_interleaved(mpcs: dict, states) -> dict:
    """Re-solve recorded (q, v, commands, t) in sequence with each MPC (own warm start), state by
    state in turn, so that the machine's load affects every variant alike."""
    records = {label: {"ms": [], "iterations": [], "ok": []} for label in mpcs}
    for mpc in mpcs.values():
        mpc.reset()
    for q, v, commands, t in states:
        for label, mpc in mpcs.items():
            solution = mpc.solve(q, v, commands, t)
            records[label]["ms"].append(solution.stats.solve_time_s * 1e3)
            records[label]["iterations"].append(solution.stats.iterations)
            records[label]["ok"].append(solution.success)
    return {label: {"solve_ms": _stats(r["ms"]), "iterations_mean": float(np.mean(r["iterations"])),
                    "failures": int(len(r["ok"]) - sum(r["ok"]))} for label, r in records.items()}


def table1_row(robot, formulation: str, steps: int, compiled: bool, progress) -> dict:
    from dataclasses import replace

    from wbmpc.control import MPC
    from wbmpc.solvers.nlp import NlpSolver

    config = mpc_config(formulation=formulation, robot=robot)
    start = time.perf_counter()
    mpc = MPC(robot, config)
    build_s = time.perf_counter() - start
    problem = mpc.problem
    summary, states, iterations = _closed_loop(robot, mpc, "pinocchio", steps, progress)
    states_dims = problem.nx
    inputs_dims = int(np.max([problem.stage_slices[k][1].stop - problem.stage_slices[k][1].start
                              for k in range(problem.config.n_torque_nodes, problem.N)]))
    row = {
        "formulation": formulation,
        "dynamics_as": problem.formulation.dynamics_as,
        "states": STATE_INPUT[formulation][0],
        "inputs": STATE_INPUT[formulation][1],
        "state_dim": int(states_dims),
        "input_dim": inputs_dims,
        "instructions_per_constraint": problem.instructions_per_constraint(),
        "decision_variables": int(problem.n_variables),
        "solve_ms_precompiled": {k: summary["solve_ms"][k] for k in ("mean", "std")},
        "solve_ms_compiled": {"mean": None, "std": None},
        "iterations_mean": summary["iterations"]["mean"],
        "failures": summary["failures"],
        "fell": summary["fell"],
        "build_s": build_s,
        "compile": None,
        "paper": PAPER_TABLE1[formulation],
    }
    row["closed_loop"] = {"solve_ms": summary["solve_ms"], "iterations_mean": summary["iterations"]["mean"],
                          "failures": summary["failures"], "fell": summary["fell"]}
    if compiled:
        start = time.perf_counter()
        solver = NlpSolver(problem, replace(config.solver, compiled=True))
        if solver.is_compiled:
            row["compile"] = {**solver.compile_report.as_dict(), "load_s": time.perf_counter() - start}
            compiled_mpc = MPC(robot, config, problem=problem, solver=solver)
            same = _resolve_interleaved({"precompiled": mpc, "compiled": compiled_mpc}, states)
            row["same_states"] = same
            row["solve_ms_precompiled"] = {k: same["precompiled"]["solve_ms"][k] for k in ("mean", "std")}
            row["solve_ms_compiled"] = {k: same["compiled"]["solve_ms"][k] for k in ("mean", "std")}
            pre, post = row["solve_ms_precompiled"]["mean"], row["solve_ms_compiled"]["mean"]
            row["speedup_compiled"] = pre / post if pre and post else None
        else:
            row["compile"] = {"error": solver.compile_error}
    return row


def bench_table1(robot, steps: int = 100, formulations: list[str] | None = None, compiled: bool = True,
                 show_progress: bool = True) -> dict:
    from wbmpc.ocp.formulations import FORMULATIONS

    names = formulations or list(FORMULATIONS)
    for name in names:
        if name not in FORMULATIONS:
            raise ConfigError(unknown_name("formulation", name, FORMULATIONS))
    if not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"--steps must be an integer >= 1, got {steps}")
    progress = ProgressBar(len(names), unit="formulations", enabled=None if show_progress else False)
    machine_start, wall_start = _machine(), time.perf_counter()
    rows = []
    for i, name in enumerate(names):
        progress.update(i, f"{name}: closed loop")
        rows.append(table1_row(robot, name, steps, compiled,
                               lambda share, i=i, name=name: progress.update(i + 0.5 * share, f"{name}: closed loop")))
        progress.update(i + 1, f"{name}: done")
    progress.close(complete=True)
    return {"robot": robot.name, "steps": steps, "nodes": 15, "plant": "pinocchio", "mpc_rate_hz": MPC_RATE_HZ,
            "rows": rows, "machine": {"start": machine_start, "end": _machine()},
            "wall_s": time.perf_counter() - wall_start}


def _ms(stats: dict | None) -> str:
    if not stats or stats.get("mean") is None:
        return "-"
    return f"{stats['mean']:.1f} ({stats['std']:.1f})"


def _paper_ms(value) -> str:
    return "- (*)" if value is None else f"{value[0]:.1f} ({value[1]:.1f})"


def table1_markdown(report: dict) -> str:
    lines = [f"## Table I on this machine: {report['robot']}, trot, {report['steps']} MPC steps in closed loop "
             f"on the pinocchio plant (paper: B2 + Z1, its machine)", "",
             "| formulation | states | inputs | dynamics as | instr. per constr. (paper) | dec. vars (paper) "
             "| solve ms pre-comp. (paper) | post-comp. (paper) | speed-up | iterations | failures | fell | compile s / MB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        paper = r["paper"]
        compile_info = r.get("compile") or {}
        if "error" in compile_info:
            compile_text = "failed"
        elif compile_info:
            compile_text = ("cached" if compile_info["cached"] else
                            f"{compile_info['compile_s']:.0f} s / {compile_info['peak_memory_mb']:.0f} MB")
        else:
            compile_text = "-"
        speedup = r.get("speedup_compiled")
        lines.append(
            f"| {r['formulation']} | {r['states']} | {r['inputs']} | {r['dynamics_as']} | "
            f"{r['instructions_per_constraint']} ({paper['instructions']}) | "
            f"{r['decision_variables']} ({paper['decision_variables']}) | "
            f"{_ms(r['solve_ms_precompiled'])} ({_paper_ms(paper['precompiled'])}) | "
            f"{_ms(r['solve_ms_compiled'])} ({_paper_ms(paper['compiled'])}) | "
            f"{'-' if speedup is None else f'{speedup:.2f}x'} | "
            f"{r['iterations_mean']:.2f} | {r['failures']} | {r['fell']} | {compile_text} |")
    m = report["machine"]
    lines += ["", "(*) the paper's compilation ran out of 32 GB of memory. Solve times re-solve the states of the "
              "closed-loop run with both solvers, alternating state by state; iterations, failures and falls are "
              "the closed loop's.",
              f"Machine: {m['start']['cpus']} CPUs, load average {m['start']['loadavg_1_5_15']} at start, "
              f"{m['end']['loadavg_1_5_15']} at end; wall time {report['wall_s']:.0f} s."]
    return "\n".join(lines)


def cli_bench_table1(args, robot_from_args) -> int:
    formulations = [s.strip() for s in (args.formulations or "").split(",") if s.strip()] or None
    robot = robot_from_args(args)
    report = bench_table1(robot, steps=args.steps, formulations=formulations, compiled=not args.no_compile,
                          show_progress=not args.no_progress)
    text = table1_markdown(report)
    if args.out:
        write_report(Path(args.out), report, text)
    if args.markdown and not args.json:
        print(text)
        return 0
    _output(args, report, text)
    return 0
