"""MPC solve benchmarks: one OCP from the nominal stance (`wbmpc solve`) and a receding-horizon
benchmark in closed loop (`wbmpc bench mpc`, section V-A).

`bench mpc` runs each requested solver for N MPC steps (80 Hz) in closed loop on a plant, then
re-solves the states recorded in the reference run (Fatrop, warm-started) with:
- the other solvers on the very same NLP (`problem=` shared): the Fatrop-vs-IPOPT speedup of
  section V-A1 (paper: over 10x);
- Fatrop without warm start (V-A2; paper: 15-20 % less solve time with it);
- Fatrop on a uniform grid of the same horizon (IV-C: geometric 10-100 ms vs fixed 40 ms).
The re-solves are interleaved state by state (warm, cold, uniform, IPOPT, ...) so that the load
of the machine affects every variant alike; each variant keeps its own warm start across states.
Every MPC here runs without recovery re-solves, so times and failures are the named solver's own. As in a run,
each MPC builds its solver's instances for the first two gait cycles' row patterns right before its closed loop
(`MPC.prepare_structures`: fatrop-direct builds and rehearses one Fatrop instance per pattern, ~11 ms each on g1).
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from wbmpc.control.loop import MPC_RATE_HZ
from wbmpc.errors import ConfigError, check_number, unknown_name
from wbmpc.progress import ProgressBar
from wbmpc.strict_json import to_json

PLANTS = ("pinocchio", "mujoco")


# ---------------------------------------------------------------------------- configuration
def grid_for(nodes: int, uniform_dt_ms: float | None = None, robot=None):
    """Paper grid (geometric 10 ms -> 100 ms) on `nodes` nodes, its far nodes on the contact switches where a run's
    would be (`robot`'s flat feet: `policy.follows_contact_switches`), or uniform steps of `uniform_dt_ms`."""
    from wbmpc.control.policy import follows_contact_switches
    from wbmpc.ocp.grid import MAX_INTERVALS, MAX_STEP_S, TimeGrid

    if isinstance(nodes, bool) or not isinstance(nodes, int):
        raise ConfigError.for_field("nodes", f"must be an integer >= 2, got {nodes!r}")
    check_number("nodes", nodes, low=2, high=MAX_INTERVALS + 1)
    if uniform_dt_ms is not None:
        check_number("uniform_dt_ms", uniform_dt_ms, low=0.0, high=1e3 * MAX_STEP_S, low_open=True, unit="ms")
        return TimeGrid.uniform_steps(nodes - 1, uniform_dt_ms / 1e3)
    return TimeGrid(n_intervals=nodes - 1, follow_contact_switches=follows_contact_switches(robot))


def check_names(formulation: str | None = None, gait: str | None = None, solvers: list[str] | None = None,
                plant: str | None = None) -> None:
    """Fail fast (before any build) on unknown names, listing what exists."""
    from wbmpc.gait import GAIT_NAMES
    from wbmpc.ocp.formulations import FORMULATIONS
    from wbmpc.solvers.nlp import SOLVERS

    if formulation is not None and formulation not in FORMULATIONS:
        raise ConfigError(unknown_name("formulation", formulation, FORMULATIONS))
    if gait is not None and gait not in GAIT_NAMES:
        raise ConfigError(unknown_name("gait", gait, GAIT_NAMES))
    for name in solvers or []:
        if name not in SOLVERS:
            raise ConfigError(unknown_name("solver", name, SOLVERS))
    if plant is not None and plant not in PLANTS:
        raise ConfigError(unknown_name("plant", plant, PLANTS))


def mpc_config(formulation: str = "wb_inverse", gait: str = "trot", solver: str = "fatrop", nodes: int = 15,
               uniform_dt_ms: float | None = None, warm_start: bool = True, compiled: bool = False, robot=None,
               threads: int | None = None):
    """The benchmarks' MPC settings; with `robot`, its own weights, gait period and swing (control/tuning.py);
    `threads`: fatrop-direct's stage evaluation threads (None: its default)."""
    from wbmpc.control import MpcConfig
    from wbmpc.ocp.problem import OcpConfig
    from wbmpc.solvers.nlp import SolverConfig

    check_names(formulation=formulation, gait=gait, solvers=[solver])
    grid = grid_for(nodes, uniform_dt_ms, robot)
    # measure the requested solver alone: RTI and the anytime SQP (here without a deadline: iterated to
    # convergence) without their Fatrop recovery of failed QPs either
    extra = {"recovery_barrier_init": None} if solver in ("rti", "sqp") else {}
    config = MpcConfig(ocp=OcpConfig(formulation=formulation, grid=grid),
                       solver=SolverConfig(name=solver, compiled=compiled, extra_options=extra, threads=threads),
                       gait=gait, warm_start=warm_start)
    # measure the requested solver alone: a failed step stays a failure (no recovery re-solve)
    config = replace(config, recovery=replace(config.recovery, fallback_solver=None, barrier_init=None))
    if robot is not None:
        from wbmpc.control.tuning import tuning_for

        config = tuning_for(robot).apply_to(config)
    return config


def _direct_fallback(solver) -> dict:
    """fatrop-direct only: why it ran casadi's Fatrop instead (null when the direct binding ran)."""
    return {"direct_fallback": solver.direct_error} if hasattr(solver, "direct_error") else {}


def _finite(value) -> float | None:
    """JSON has no inf/NaN: non-finite numbers become null."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _stats(values) -> dict:
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return {"mean": None, "std": None, "max": None}
    return {"mean": float(values.mean()), "std": float(values.std()), "max": float(values.max())}


def _machine() -> dict:
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    from wbmpc.solvers import blasfeo

    return {"cpus": os.cpu_count(), "loadavg_1_5_15": [round(x, 2) for x in load], "blasfeo": blasfeo.status().active}


# ---------------------------------------------------------------------------- wbmpc solve
def solve_nominal(robot, formulation: str = "wb_inverse", gait: str = "trot", nodes: int = 15,
                  solver: str = "fatrop", uniform_dt_ms: float | None = None, t: float = 0.0,
                  compiled: bool = False) -> dict:
    """Build one OCP and solve it once from the nominal stance (q_nominal, v = 0) at gait time t."""
    from wbmpc.control import MPC, Commands

    check_number("t", t, low=0.0, high=1e6, unit="s")
    config = mpc_config(formulation, gait, solver, nodes, uniform_dt_ms, compiled=compiled, robot=robot)
    start = time.perf_counter()
    mpc = MPC(robot, config)
    build_s = time.perf_counter() - start
    solution = mpc.solve(robot.q_nominal, np.zeros(robot.nv), Commands(), t)
    stats = solution.stats
    return {
        "formulation": formulation,
        "solver": solver,
        "decision_variables": int(mpc.problem.n_variables),
        "status": str(stats.status),
        "success": bool(solution.success),
        "iterations": int(stats.iterations),
        "solve_ms": float(stats.solve_time_s * 1e3),
        "max_constraint_violation": _finite(stats.max_constraint_violation),
        "robot": robot.name,
        "gait": gait,
        "nodes": nodes,
        "grid": f"uniform {uniform_dt_ms:g} ms" if uniform_dt_ms else "geometric 10-100 ms",
        "horizon_s": float(config.ocp.grid.horizon_s),
        "t_s": t,
        "build_s": build_s,
        "compiled": mpc.solver.is_compiled,
        "compile": (mpc.solver.compile_report.as_dict() if mpc.solver.is_compiled
                    else {"error": mpc.solver.compile_error} if compiled else None),
        **_direct_fallback(mpc.solver),
    }


def solve_text(report: dict) -> str:
    viol = report["max_constraint_violation"]
    return (f"{report['formulation']} OCP of {report['robot']} ({report['nodes']} nodes, {report['grid']}, "
            f"{report['gait']} at t = {report['t_s']:g} s): {report['decision_variables']} decision variables, "
            f"built in {report['build_s']:.1f} s\n"
            f"{report['solver']}: {report['status']} in {report['iterations']} iterations, "
            f"{report['solve_ms']:.1f} ms{' (compiled)' if report.get('compiled') else ''}, max constraint violation "
            f"{'inf' if viol is None else f'{viol:.1e}'}")


def cli_solve(args, robot_from_args) -> int:
    check_names(formulation=args.formulation, gait=args.gait, solvers=[args.solver])
    grid_for(args.nodes, args.uniform_dt)  # validate before loading anything heavy
    robot = robot_from_args(args)
    report = solve_nominal(robot, args.formulation, args.gait, args.nodes, args.solver, args.uniform_dt, args.t,
                           compiled=args.compiled)
    _output(args, report, solve_text(report))
    return 0 if report["success"] else 1


# ---------------------------------------------------------------------------- wbmpc bench mpc
@dataclass
class _Recorder:
    """Stands in for an MPC inside `ClosedLoop` and records every (q, v, commands, t) it solves."""

    mpc: object
    states: list = field(default_factory=list)
    eval_ms: list = field(default_factory=list)
    cpu_ms: list = field(default_factory=list)
    splits: list = field(default_factory=list)
    commands_ms: float = 0.0  # the loop's command source of the step being solved (`commands`)

    @property
    def robot(self):
        return self.mpc.robot

    def commands(self, t_s, q, v):
        """The loop's command source (the benchmark's constant commands), timed: its Python is part of the step's."""
        from wbmpc.control import Commands

        start = time.perf_counter()
        commands = Commands()
        self.commands_ms = 1e3 * (time.perf_counter() - start)
        return commands

    def solve(self, q, v, commands=None, t_s=0.0):
        self.states.append((np.array(q, dtype=float), np.array(v, dtype=float), commands, float(t_s)))
        solution, cpu_ms = _timed_solve(self.mpc, q, v, commands, t_s)
        self.eval_ms.append(_function_eval_ms(solution))
        split = dict(solution.stats.split_ms)
        split["python"] = split.get("python", 0.0) + self.commands_ms
        self.splits.append(split)
        self.cpu_ms.append(cpu_ms)
        return solution


def _timed_solve(mpc, q, v, commands, t):
    """One MPC step and the CPU time this process spent in it (ms): unlike wall time, it does not grow
    when other processes share the cores (single-threaded solvers)."""
    start = time.process_time()
    solution = mpc.solve(q, v, commands, t)
    return solution, 1e3 * (time.process_time() - start)


def _function_eval_ms(solution) -> float:
    """Wall time of a solve spent in CasADi's NLP function evaluations (f, g, jacobians, Hessian), from
    its time split (`wbmpc.solvers.nlp.time_split_ms`; RTI: linearisation + evaluation at the step).

    Solve time minus this is the solver's own linear algebra and logic (what Fatrop's Riccati
    recursion speeds up); function evaluations are what C code generation speeds up.
    """
    split = solution.stats.split_ms
    if "functions" in split:
        return split["functions"]
    if "linearize" in split:
        return split["linearize"] + split.get("evaluate", 0.0)
    return float("nan")


def _split_summary(splits: list[dict]) -> dict:
    """Mean ms per part of a step (see `wbmpc.solvers.nlp.time_split_ms`; `python`: the rest of the step, with the
    solver's `outside_solver`, see `wbmpc.control.mpc`)."""
    keys = dict.fromkeys(k for split in splits for k in split)
    means = {k: float(np.mean([split.get(k, 0.0) for split in splits])) for k in keys}
    return {"parts_ms_mean": means, "step_ms_mean": float(sum(means.values())) if means else None}


def _run_summary(solutions_ms, iterations, success, n_variables, eval_ms=None, cpu_ms=None) -> dict:
    iterations = np.asarray(iterations, dtype=float)
    solve = np.asarray(solutions_ms, dtype=float)
    evals = np.asarray(eval_ms if eval_ms is not None else [], dtype=float)
    split = evals.size == solve.size and solve.size > 0 and np.all(np.isfinite(evals))
    return {
        "steps": int(len(solutions_ms)),
        "decision_variables": int(n_variables),
        "solve_ms": _stats(solutions_ms),
        "iterations": {"mean": float(iterations.mean()) if iterations.size else None,
                       "max": int(iterations.max()) if iterations.size else None},
        "failures": int(len(success) - int(np.sum(success))),
        # mean split of the solve time: CasADi function evaluations vs the solver itself
        "function_eval_ms_mean": float(evals.mean()) if split else None,
        "solver_only_ms_mean": float((solve - evals).mean()) if split else None,
        "step_cpu_ms": _stats(cpu_ms if cpu_ms is not None else []),  # whole MPC step, this process's CPU
    }


def _closed_loop(robot, mpc, plant_kind: str, steps: int, on_progress: Callable[[float], None]) -> tuple[dict, list, list]:
    """N MPC steps at 80 Hz on a fresh plant from the nominal stance: summary, recorded states, iterations."""
    from wbmpc.control.loop import ClosedLoop, LoopConfig
    from wbmpc.sim import make_plant

    plant = make_plant(plant_kind, robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    recorder = _Recorder(mpc)
    duration = steps / MPC_RATE_HZ
    from wbmpc.control.tuning import tuning_for

    gains = tuning_for(robot).gains  # the robot's own PD (B1's Kd 5 saturates a Go2's legs)
    log = ClosedLoop(recorder, plant, LoopConfig(mpc_rate_hz=MPC_RATE_HZ, gains=gains)).run(
        duration, commands=recorder.commands, progress=lambda share, _recoveries: on_progress(share))
    arrays = log.arrays()
    n = min(steps, len(arrays["solve_ms"]))
    summary = _run_summary(arrays["solve_ms"][:n], arrays["iterations"][:n], arrays["success"][:n],
                           mpc.problem.n_variables, recorder.eval_ms[:n], recorder.cpu_ms[:n])
    summary.update({"fell": bool(log.fell), "simulated_s": float(n / MPC_RATE_HZ), "wall_s": float(log.wall_time_s),
                    "split": _split_summary(recorder.splits[:n])})
    return summary, recorder.states[:n], [int(i) for i in arrays["iterations"][:n]]


def _percent_reduction(reference: float | None, reduced: float | None) -> float | None:
    if reference is None or reduced is None or reference == 0:
        return None
    return float(100.0 * (reference - reduced) / reference)


def _ratio(numerator: float | None, denominator: float | None) -> float | None:
    if numerator is None or denominator is None or denominator == 0:
        return None
    return float(numerator / denominator)


def bench_mpc(robot, steps: int = 100, gait: str = "trot", plant: str = "pinocchio",
              solvers: tuple[str, ...] = ("fatrop", "ipopt"), nodes: int = 15, uniform_dt_ms: float | None = None,
              show_progress: bool = True, compiled: bool = False, collision_avoidance: bool = False,
              threads: tuple[int, ...] | None = None) -> dict:
    """Closed-loop receding-horizon benchmark plus same-state comparisons (see module docstring);
    `collision_avoidance` adds the reference solver with the collision rows (`OcpConfig.collision`) to the
    same-state re-solves: the rows' cost on the very same states. `threads`: fatrop-direct's stage evaluation
    threads, the first for the closed loops; each further count re-solves the same states with fatrop-direct on
    that many threads (`same_states.threads`: times and the speed-up against the first count)."""
    from wbmpc.control import MPC
    from wbmpc.ocp.problem import OcpProblem

    solvers = tuple(dict.fromkeys(solvers))  # unique, in order
    if not solvers:
        raise ConfigError("--solvers needs at least one solver, e.g. fatrop,ipopt")
    if not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"--steps must be an integer >= 1, got {steps}")
    check_names(gait=gait, solvers=list(solvers), plant=plant)
    threads = _check_threads(threads, solvers)
    grid = grid_for(nodes)
    if uniform_dt_ms is None:
        # about the same horizon, in whole ms: 40 ms for the paper's 15 nodes (0.56 s)
        uniform_dt_ms = float(max(1, round(1e3 * grid.horizon_s / (nodes - 1))))
    grid_for(nodes, uniform_dt_ms)
    reference = "fatrop" if "fatrop" in solvers else solvers[0]

    machine_start = _machine()
    wall_start = time.perf_counter()
    # warm, cold, uniform, other solvers, collision, other thread counts
    n_resolve = 3 + (len(solvers) - 1) + int(collision_avoidance) + len(threads) - 1
    progress = ProgressBar(len(solvers) * steps + n_resolve * steps + 0.5 * (len(solvers) + 2), unit="solves",
                           enabled=None if show_progress else False)
    done = 0.0

    # one OCP build shared by every solver on the paper grid
    progress.update(done, "building the OCP")
    start = time.perf_counter()
    problem = OcpProblem(robot, replace(mpc_config(gait=gait, nodes=nodes).ocp, grid=grid_for(nodes, robot=robot)))
    build = {"problem_s": time.perf_counter() - start}
    mpcs = {}
    for name in solvers:
        progress.update(done, f"building {name}")
        start = time.perf_counter()
        mpcs[name] = MPC(robot, mpc_config(gait=gait, solver=name, nodes=nodes, compiled=compiled, robot=robot,
                                           threads=threads[0]), problem=problem)
        build[f"{name}_s"] = time.perf_counter() - start
        done += 0.5

    # closed loop per solver (the reference first: its states are re-solved below)
    runs, states, reference_iterations = {}, [], []
    for name in (reference,) + tuple(s for s in solvers if s != reference):
        base = done

        def on_progress(share, base=base, name=name):
            progress.update(base + share * steps, f"closed loop {name}")

        start = time.perf_counter()
        # as a run does right before its clock starts (not before another solver's build: its first step then met
        # cold caches, ~1 ms more on b1_z1)
        mpcs[name].prepare_structures(MPC_RATE_HZ)
        build[f"{name}_s"] += time.perf_counter() - start
        runs[name], recorded, iterations = _closed_loop(robot, mpcs[name], plant, steps, on_progress)
        runs[name].update(_direct_fallback(mpcs[name].solver))
        if name == reference:
            states, reference_iterations = recorded, iterations
        done = base + steps
        progress.update(done, f"closed loop {name}")

    # same states, re-solved sequentially by each variant (own warm start), interleaved per state
    progress.update(done, "building cold / uniform variants")
    start = time.perf_counter()
    variants = {reference: mpcs[reference]}
    variants[f"{reference}_cold"] = MPC(robot, mpc_config(gait=gait, solver=reference, nodes=nodes, warm_start=False, robot=robot,
                                                          compiled=compiled, threads=threads[0]),
                                        problem=problem)
    variants[f"{reference}_uniform"] = MPC(robot, mpc_config(gait=gait, solver=reference, nodes=nodes, robot=robot,
                                                             uniform_dt_ms=uniform_dt_ms, compiled=compiled,
                                                             threads=threads[0]))
    for name in solvers:
        if name != reference:
            variants[name] = mpcs[name]
    for count in threads[1:]:
        variants[f"fatrop-direct_threads{count}"] = MPC(robot, mpc_config(
            gait=gait, solver="fatrop-direct", nodes=nodes, compiled=compiled, robot=robot, threads=count),
            problem=problem)
    if collision_avoidance:
        from wbmpc.robots.collision_model import CollisionConfig

        config = mpc_config(gait=gait, solver=reference, nodes=nodes, robot=robot, compiled=compiled)
        variants[f"{reference}_collision"] = MPC(robot, replace(config, ocp=replace(config.ocp, collision=CollisionConfig())))
    for mpc in variants.values():
        mpc.prepare_structures(MPC_RATE_HZ)
        mpc.reset()
    build["variants_s"] = time.perf_counter() - start
    done += 1.0
    records = {label: {"ms": [], "it": [], "ok": [], "eval": [], "cpu": []} for label in variants}
    for i, (q, v, commands, t) in enumerate(states):
        for label, mpc in variants.items():
            solution, cpu_ms = _timed_solve(mpc, q, v, commands, t)
            records[label]["cpu"].append(cpu_ms)
            records[label]["ms"].append(solution.stats.solve_time_s * 1e3)
            records[label]["it"].append(int(solution.stats.iterations))
            records[label]["ok"].append(solution.success)
            records[label]["eval"].append(_function_eval_ms(solution))
            done += 1
            progress.update(done, f"same states {i + 1}/{len(states)}")
    progress.close(complete=True)

    same = {label: _run_summary(r["ms"], r["it"], r["ok"], variants[label].problem.n_variables, r["eval"], r["cpu"])
            for label, r in records.items()}
    warm, cold, uniform = same[reference], same[f"{reference}_cold"], same[f"{reference}_uniform"]
    fatrop_vs_ipopt = None
    if "fatrop" in records and "ipopt" in records:
        ratios = np.asarray(records["ipopt"]["ms"]) / np.maximum(np.asarray(records["fatrop"]["ms"]), 1e-9)
        fatrop_vs_ipopt = {
            "fatrop_solve_ms": same["fatrop"]["solve_ms"],
            "ipopt_solve_ms": same["ipopt"]["solve_ms"],
            "fatrop_iterations_mean": same["fatrop"]["iterations"]["mean"],
            "ipopt_iterations_mean": same["ipopt"]["iterations"]["mean"],
            "time_ratio": _ratio(same["ipopt"]["solve_ms"]["mean"], same["fatrop"]["solve_ms"]["mean"]),
            "time_ratio_median": float(np.median(ratios)) if ratios.size else None,
            # the same ratio without CasADi's function evaluations (what the solvers themselves cost)
            "solver_only_time_ratio": _ratio(same["ipopt"]["solver_only_ms_mean"], same["fatrop"]["solver_only_ms_mean"]),
        }
    rti_vs_fatrop = None
    if "fatrop" in same and "rti" in same:  # same states: one RTI step vs a converged Fatrop solve
        rti_vs_fatrop = {
            "fatrop_solve_ms": same["fatrop"]["solve_ms"], "rti_solve_ms": same["rti"]["solve_ms"],
            "fatrop_step_cpu_ms": same["fatrop"]["step_cpu_ms"], "rti_step_cpu_ms": same["rti"]["step_cpu_ms"],
            "time_ratio": _ratio(same["fatrop"]["solve_ms"]["mean"], same["rti"]["solve_ms"]["mean"]),
            "cpu_ratio": _ratio(same["fatrop"]["step_cpu_ms"]["mean"], same["rti"]["step_cpu_ms"]["mean"]),
        }
    collision_vs_plain = None
    if collision_avoidance:
        plain, rows = same[reference], same[f"{reference}_collision"]
        problem_c = variants[f"{reference}_collision"].problem
        collision_vs_plain = {
            "pairs": len(problem_c.collision.pairs), "rows_per_node": len(problem_c.collision.groups),
            "plain_solve_ms": plain["solve_ms"], "collision_solve_ms": rows["solve_ms"],
            "plain_iterations_mean": plain["iterations"]["mean"], "collision_iterations_mean": rows["iterations"]["mean"],
            "collision_failures": rows["failures"],
            "time_ratio": _ratio(rows["solve_ms"]["mean"], plain["solve_ms"]["mean"]),
            "cpu_ratio": _ratio(rows["step_cpu_ms"]["mean"], plain["step_cpu_ms"]["mean"]),
        }
    return {
        "robot": robot.name,
        "gait": gait,
        "threads": list(threads),
        "plant": plant,
        "compiled": compiled,
        "delay": "none",
        "mpc_rate_hz": MPC_RATE_HZ,
        "steps": steps,
        "nodes": nodes,
        "decision_variables": int(problem.n_variables),
        "solvers": runs,
        "same_states": {
            "reference_solver": reference,
            "states": len(states),
            "runs": same,
            "fatrop_vs_ipopt": fatrop_vs_ipopt,
            "rti_vs_fatrop": rti_vs_fatrop,
            "collision_vs_plain": collision_vs_plain,
            "threads": _threads_summary(same, threads),
            "warm_vs_cold": {
                "warm": {"solve_ms": warm["solve_ms"], "iterations_mean": warm["iterations"]["mean"],
                         "failures": warm["failures"]},
                "cold": {"solve_ms": cold["solve_ms"], "iterations_mean": cold["iterations"]["mean"],
                         "failures": cold["failures"]},
                "iteration_reduction_pct": _percent_reduction(cold["iterations"]["mean"], warm["iterations"]["mean"]),
                "time_reduction_pct": _percent_reduction(cold["solve_ms"]["mean"], warm["solve_ms"]["mean"]),
            },
            "adaptive_vs_uniform": {
                "adaptive": {"grid": "geometric 10-100 ms", "horizon_s": float(grid.horizon_s),
                             "solve_ms": warm["solve_ms"], "iterations_mean": warm["iterations"]["mean"],
                             "failures": warm["failures"]},
                "uniform": {"grid": f"uniform {uniform_dt_ms:g} ms",
                            "horizon_s": float(variants[f"{reference}_uniform"].problem.config.grid.horizon_s),
                            "solve_ms": uniform["solve_ms"], "iterations_mean": uniform["iterations"]["mean"],
                            "failures": uniform["failures"]},
                "time_ratio": _ratio(uniform["solve_ms"]["mean"], warm["solve_ms"]["mean"]),
            },
            # determinism check: re-solving the recorded states reproduces the closed-loop iterations
            "warm_resolve_matches_closed_loop": records[reference]["it"] == reference_iterations,
        },
        "build_s": build,
        "machine": {"start": machine_start, "end": _machine()},
        "wall_s": time.perf_counter() - wall_start,
    }


def _check_threads(threads, solvers) -> tuple:
    """(None,) for the solvers' default; several counts need fatrop-direct among the solvers."""
    if not threads:
        return (None,)
    threads = tuple(dict.fromkeys(threads))
    for count in threads:
        check_number("threads", count, low=1, high=64)
    if len(threads) > 1 and "fatrop-direct" not in solvers:
        raise ConfigError("--threads with several counts compares fatrop-direct's stage evaluations: add "
                          "fatrop-direct to --solvers")
    return threads


def _threads_summary(same: dict, threads: tuple) -> dict | None:
    """fatrop-direct on each thread count, same states: times and speed-ups against the first count."""
    if len(threads) < 2:
        return None
    labels = {threads[0]: "fatrop-direct", **{t: f"fatrop-direct_threads{t}" for t in threads[1:]}}
    runs = {str(t): {"solve_ms": same[label]["solve_ms"], "step_cpu_ms": same[label]["step_cpu_ms"],
                     "function_eval_ms_mean": same[label]["function_eval_ms_mean"],
                     "iterations_mean": same[label]["iterations"]["mean"], "failures": same[label]["failures"]}
            for t, label in labels.items()}
    first = runs[str(threads[0])]
    return {"counts": list(threads), "runs": runs,
            "speedup_vs_first": {str(t): _ratio(first["solve_ms"]["mean"], r["solve_ms"]["mean"])
                                 for t, r in runs.items()},
            "function_speedup_vs_first": {str(t): _ratio(first["function_eval_ms_mean"], r["function_eval_ms_mean"])
                                          for t, r in runs.items()}}


def _fmt(value, spec: str = ".1f") -> str:
    return "-" if value is None else format(value, spec)


def bench_markdown(report: dict) -> str:
    lines = [f"## MPC benchmark: {report['robot']}, {report['gait']} in closed loop on the {report['plant']} plant "
             f"({report['steps']} steps at {report['mpc_rate_hz']:g} Hz, {report['nodes']} nodes, "
             f"{report['decision_variables']} decision variables)", "",
             "| solver | steps | solve ms mean | std | max | of which f/g/jac/hess evals | solver only "
             "| step CPU ms mean | max | iterations mean | max | failures | fell |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in report["solvers"].items():
        ms, it, cpu = r["solve_ms"], r["iterations"], r.get("step_cpu_ms") or {}
        lines.append(f"| {name} | {r['steps']} | {_fmt(ms['mean'])} | {_fmt(ms['std'])} | {_fmt(ms['max'])} | "
                     f"{_fmt(r['function_eval_ms_mean'])} | {_fmt(r['solver_only_ms_mean'])} | "
                     f"{_fmt(cpu.get('mean'))} | {_fmt(cpu.get('max'))} | "
                     f"{_fmt(it['mean'], '.2f')} | {_fmt(it['max'], 'd')} | {r['failures']} | {r['fell']} |")
    lines += ["", "Where a closed-loop step's time goes (mean ms; `python`: everything outside the solver's own work: "
                  "input checks, references, parameters, bounds, warm start, the solver wrapper's packing and "
                  "unpacking):", ""]
    for name, r in report["solvers"].items():
        split = r.get("split") or {}
        parts = ", ".join(f"{k} {v:.1f}" for k, v in (split.get("parts_ms_mean") or {}).items())
        lines.append(f"- {name}: {parts or 'not reported by this solver'}")
    same = report["same_states"]
    lines += ["", f"Same {same['states']} states of the {same['reference_solver']} run, re-solved in sequence "
                  "(each variant warm-started from its own previous solution unless cold):", "",
              "| variant | solve ms mean | std | max | of which evals | solver only | step CPU ms mean "
              "| iterations mean | failures |",
              "|---|---|---|---|---|---|---|---|---|"]
    for label, r in same["runs"].items():
        ms = r["solve_ms"]
        lines.append(f"| {label} | {_fmt(ms['mean'])} | {_fmt(ms['std'])} | {_fmt(ms['max'])} | "
                     f"{_fmt(r['function_eval_ms_mean'])} | {_fmt(r['solver_only_ms_mean'])} | "
                     f"{_fmt((r.get('step_cpu_ms') or {}).get('mean'))} | "
                     f"{_fmt(r['iterations']['mean'], '.2f')} | {r['failures']} |")
    lines.append("")
    fvi = same["fatrop_vs_ipopt"]
    if fvi:
        lines.append(f"- IPOPT / Fatrop solve time: {_fmt(fvi['time_ratio'], '.2f')}x (mean), "
                     f"{_fmt(fvi['time_ratio_median'], '.2f')}x (median per state), "
                     f"{_fmt(fvi['solver_only_time_ratio'], '.2f')}x without function evaluations; paper: > 10x")
    rvf = same.get("rti_vs_fatrop")
    if rvf:
        lines.append(f"- converged Fatrop / one RTI step: {_fmt(rvf['time_ratio'], '.2f')}x wall time, "
                     f"{_fmt(rvf['cpu_ratio'], '.2f')}x CPU time (RTI step {_fmt(rvf['rti_solve_ms']['mean'])} ms mean, "
                     f"{_fmt(rvf['rti_solve_ms']['max'])} max; target <= 5 / 10 ms)")
    cvp = same.get("collision_vs_plain")
    if cvp:
        lines.append(f"- collision avoidance rows ({cvp['pairs']} capsule pairs, {cvp['rows_per_node']} rows per node) / "
                     f"plain solve time: {_fmt(cvp['time_ratio'], '.2f')}x, step CPU {_fmt(cvp['cpu_ratio'], '.2f')}x "
                     f"({_fmt(cvp['plain_iterations_mean'], '.2f')} -> {_fmt(cvp['collision_iterations_mean'], '.2f')} "
                     "iterations; goal <= 1.2x)")
    th = same.get("threads")
    if th:
        parts = ", ".join(f"{t} threads {_fmt(r['solve_ms']['mean'])} ms (functions {_fmt(r['function_eval_ms_mean'])})"
                          for t, r in th["runs"].items())
        speedups = ", ".join(f"{t}: {_fmt(v, '.2f')}x" for t, v in th["speedup_vs_first"].items())
        lines.append(f"- fatrop-direct's stage evaluations: {parts}; solve-time speed-up against {th['counts'][0]} "
                     f"thread(s) {speedups} (same states, one run: a ratio, not an absolute time)")
    wc = same["warm_vs_cold"]
    lines.append(f"- warm start vs cold: {_fmt(wc['iteration_reduction_pct'])} % fewer iterations, "
                 f"{_fmt(wc['time_reduction_pct'])} % less solve time; paper: 15-20 % less time")
    au = same["adaptive_vs_uniform"]
    lines.append(f"- {au['uniform']['grid']} / geometric grid solve time: {_fmt(au['time_ratio'], '.2f')}x "
                 f"(same horizon {au['adaptive']['horizon_s']:.2f} s)")
    m = report["machine"]
    lines.append(f"- machine: {m['start']['cpus']} CPUs, load average {m['start']['loadavg_1_5_15']} at start, "
                 f"{m['end']['loadavg_1_5_15']} at end; wall time {report['wall_s']:.0f} s")
    return "\n".join(lines)


def cli_bench_mpc(args, robot_from_args) -> int:
    solvers = [s.strip() for s in (args.solvers or "").split(",") if s.strip()]
    if not solvers:
        raise ConfigError("--solvers needs at least one solver, e.g. fatrop,ipopt")
    check_names(gait=args.gait, solvers=solvers, plant=args.plant)
    check_number("steps", args.steps, low=1, high=100_000)
    grid_for(args.nodes, args.uniform_dt)
    robot = robot_from_args(args)
    report = bench_mpc(robot, steps=args.steps, gait=args.gait, plant=args.plant, solvers=tuple(solvers),
                       nodes=args.nodes, uniform_dt_ms=args.uniform_dt, show_progress=not args.no_progress,
                       compiled=args.compiled, collision_avoidance=getattr(args, "collision_avoidance", False),
                       threads=_parse_threads(getattr(args, "threads", None)))
    if args.out:
        path = Path(args.out)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(to_json(report, indent=2) + "\n")
    _output(args, report, bench_markdown(report))
    return 0


def _parse_threads(text: str | None) -> tuple[int, ...] | None:
    if not text:
        return None
    try:
        return tuple(int(item) for item in text.split(",") if item.strip())
    except ValueError:
        raise ConfigError(f"--threads takes comma-separated counts such as 1,2; got {text!r}") from None


def write_report(path: Path, report: dict, text: str) -> None:
    """A benchmark's JSON report at `path` and its markdown beside it (same name, .md)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(to_json(report, indent=2) + "\n")
    path.with_suffix(".md").write_text(text + "\n")


def _output(args, payload: dict, human: str) -> None:
    """--json: one JSON object on stdout, human text on stderr; otherwise human text on stdout."""
    if args.json:
        print(to_json(payload))
        print(human, file=sys.stderr)
    else:
        print(human)
