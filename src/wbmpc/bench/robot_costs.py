"""What a robot costs the MPC (`wbmpc bench robots --mpc`): NLP size and closed-loop step times.

Per robot: the decision variables of its wb_inverse OCP (15 nodes), then a short trot in place in MuJoCo
with the robot's own settings (`wbmpc.control.tuning`) under the compiled Fatrop (converged) and the
compiled RTI (one SQP step per MPC step). Step times are this process's CPU time per MPC step (they do
not grow when other processes share the cores); wall-time solve means are reported beside them.
"""

from __future__ import annotations

import time
from typing import Callable

from wbmpc.robots import RobotModel

MPC_SOLVERS = ("fatrop", "rti")


def robot_costs(robot: RobotModel, steps: int = 40, compiled: bool = True,
                on_progress: Callable[[str], None] | None = None) -> dict:
    """{"decision_variables", "nodes", SOLVER: {step_cpu_ms, solve_ms, iterations_mean, failures, fell,
    build_s, compiled}} for the solvers of `MPC_SOLVERS`."""
    from wbmpc.bench.mpc import _closed_loop
    from wbmpc.control.mpc import MPC
    from wbmpc.scenarios import RunConfig, make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    scenario = make_scenario("trot-in-place", robot, RunConfig().options)
    out: dict = {}
    for solver in MPC_SOLVERS:
        if on_progress is not None:
            on_progress(f"{robot.name}: {solver}{' (compiling)' if compiled else ''}")
        config = mpc_config_for(scenario, RunConfig(solver=solver, compiled=compiled), robot)
        start = time.perf_counter()
        mpc = MPC(robot, config)
        build_s = time.perf_counter() - start
        out["decision_variables"] = int(mpc.problem.n_variables)
        out["nodes"] = int(mpc.problem.N + 1)
        summary, _states, _iterations = _closed_loop(robot, mpc, "mujoco", steps, lambda share: None)
        out[solver] = {
            "step_cpu_ms": summary["step_cpu_ms"], "solve_ms": summary["solve_ms"],
            "iterations_mean": summary["iterations"]["mean"], "failures": summary["failures"],
            "fell": summary["fell"], "steps": summary["steps"], "build_s": build_s,
            "compiled": bool(mpc.solver.is_compiled),
        }
    return out


def costs_text(name: str, costs: dict) -> str:
    parts = [f"  {name:16s} {costs['decision_variables']:5d} variables"]
    for solver in MPC_SOLVERS:
        entry = costs[solver]
        cpu = entry["step_cpu_ms"]["mean"]
        parts.append(f"{solver}{'' if entry['compiled'] else ' (not compiled)'} {cpu or float('nan'):6.1f} ms/step "
                     f"({entry['iterations_mean'] or 0:.1f} it{', FELL' if entry['fell'] else ''})")
    return "   ".join(parts)
