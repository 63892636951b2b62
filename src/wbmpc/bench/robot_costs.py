"""What a robot costs the MPC (`wbmpc bench robots --mpc`): NLP size and closed-loop step times.

Per robot: the decision variables of its wb_inverse OCP (15 nodes), then a short trot in place in MuJoCo
with the robot's own settings and PD gains (`wbmpc.control.tuning`) under the compiled Fatrop (converged)
and the compiled RTI (one SQP step per MPC step). Step times are this process's CPU time per MPC step
(they do not grow when other processes share the cores), after `WARMUP_STEPS` cold first steps (the
first one is reported apart).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from wbmpc.robots import RobotModel

MPC_SOLVERS = ("fatrop", "rti")
WARMUP_STEPS = 8  # the first steps start cold (up to hundreds of iterations): reported apart


def robot_costs(robot: RobotModel, steps: int = 40, compiled: bool = True,
                on_progress: Callable[[str], None] | None = None) -> dict:
    """{"decision_variables", "nodes", SOLVER: {step_cpu_ms, first_step_cpu_ms, iterations_mean, failures, fell,
    steps, build_s, compiled}} for the solvers of `MPC_SOLVERS`."""
    from wbmpc.bench.mpc import _stats
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
        cpu_ms, iterations, success, fell = _trot(robot, mpc, steps + WARMUP_STEPS)
        warm = slice(WARMUP_STEPS, None)
        out[solver] = {
            "step_cpu_ms": _stats(cpu_ms[warm]), "first_step_cpu_ms": float(cpu_ms[0]),
            "iterations_mean": float(np.mean(iterations[warm])) if len(iterations) > WARMUP_STEPS else None,
            "failures": int(np.sum(~success[warm])), "fell": fell, "steps": int(len(cpu_ms[warm])),
            "build_s": build_s, "compiled": bool(mpc.solver.is_compiled),
        }
    return out


def _trot(robot: RobotModel, mpc, steps: int):
    """`steps` MPC steps at 80 Hz trotting in place in MuJoCo: CPU ms, iterations and success per step."""
    from wbmpc.bench.mpc import MPC_RATE_HZ, _Recorder
    from wbmpc.control.loop import ClosedLoop, LoopConfig
    from wbmpc.control.tuning import tuning_for
    from wbmpc.sim import make_plant

    plant = make_plant("mujoco", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    recorder = _Recorder(mpc)
    loop = ClosedLoop(recorder, plant, LoopConfig(mpc_rate_hz=MPC_RATE_HZ, gains=tuning_for(robot).gains))
    log = loop.run(steps / MPC_RATE_HZ)
    arrays = log.arrays()
    n = min(steps, len(arrays["iterations"]), len(recorder.cpu_ms))
    return (np.asarray(recorder.cpu_ms[:n]), np.asarray(arrays["iterations"][:n], dtype=float),
            np.asarray(arrays["success"][:n], dtype=bool), bool(log.fell))


def costs_text(name: str, costs: dict) -> str:
    parts = [f"  {name:16s} {costs['decision_variables']:5d} variables"]
    for solver in MPC_SOLVERS:
        entry = costs[solver]
        cpu = entry["step_cpu_ms"]["mean"]
        parts.append(f"{solver}{'' if entry['compiled'] else ' (not compiled)'} {cpu or float('nan'):6.1f} ms/step "
                     f"({entry['iterations_mean'] or 0:.1f} it{', FELL' if entry['fell'] else ''})")
    return "   ".join(parts)
