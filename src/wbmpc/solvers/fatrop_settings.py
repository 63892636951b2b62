"""fatrop-direct's settings for MPC steps: its own tolerances, the multiplier warm start's barrier and cap, the quiet
steps' start, the rehearsal of a new Fatrop instance and the stage evaluations' thread count, each with the measurement
that chose it (used by `fatrop_direct.py`)."""

from __future__ import annotations

import os

from wbmpc.solvers.nlp import SolverConfig

# The binding's own KKT and constraint tolerances, used while SolverConfig holds its defaults (1e-4 / 1e-6) and
# `extra_options={"mpc_tolerances": False}` does not ask for those: on b1_z1's compiled closed loop (plant waiting)
# 3.01 -> 2.39 Fatrop iterations per step with the same trot-in-place, trot-forward and arm-track metrics to 4-5
# digits (drift, base velocity RMSE, EE RMSE); 1e-2 / 1e-3 (2.08 iterations) moved arm-track's 4th digit
MPC_TOLERANCE = 1e-3
MPC_CONSTRAINT_TOLERANCE = 1e-4
# Flat feet's KKT tolerance (the constraint tolerance stays): a biped's plan keeps a sole's centre-of-pressure row
# active over single stance (g1 walking in place: the lateral edge at nearly every stance node), and reaching 1e-3
# means driving the barrier below 1e-3 around that active set, 2-3 more iterations per step. At 1e-2 a plan stops
# with the barrier at its start value: its active rows then sit mu / z inside their bound (< 1e-3 of the force
# scale, ~0.1 N on g1). g1 walk-in-place (compiled, 2 s, plant waiting): 9.22 -> 5.41 iterations per step with the
# warm start below, drift 0.351 / 0.345 cm/s and base velocity RMSE 0.0187 / 0.0185 m/s (4.59 since the warm start
# moves wrenches and multipliers by contact pattern, control/warm_start.py; 2e-2 / 3e-2 / 5e-2 would give 4.31 /
# 4.14 / 3.95 on 100 recorded walking states against 4.52 here, not taken: looser plans, not a better start)
FLAT_FEET_MPC_TOLERANCE = 1e-2
# the warm attempt from given multipliers (`takes_multipliers`): its barrier and iteration cap. g1 walk-in-place,
# 2 s at FLAT_FEET_MPC_TOLERANCE: 5.94 iterations per step from 1e-3, 5.41 from 3e-3, 6.98 from 1e-2 (Fatrop's own
# start from 1e-3: 6.66; the instance's multipliers by position from 3e-3: 9 failed attempts of 59, 6.98). With the
# contact-pattern warm start, 100 recorded walking states: 4.67 from 2e-3, 4.52 from 3e-3, 4.84 from 5e-3
MULTIPLIER_BARRIER_INIT = 3e-3
# At the MPC tolerances no iterative refinement of the search directions (Fatrop's default: a KKT residual after each
# direction, up to 5 refinement solves): that residual never asked for one on 100 recorded g1 walk or 200 b1_z1
# trot steps (same bits either way; the g1 states solved cold: x within 6e-12, same iterations) and cost 21 % (g1) /
# 11 % (b1_z1) of the linear algebra. `extra_options={"fatrop": {"max_iterative_refinement": 5}}` restores it
MPC_ITERATIVE_REFINEMENT = 0
MULTIPLIER_MAX_ITERATIONS = 12
# after a warm step that converged within this many iterations (the plan nearly still: standing) the next attempt
# starts from the instance's multipliers and slacks at `warm_barrier_init` (same rows, no time shift to speak of):
# g1 standing 2 s 1.71 -> 1.01 iterations per step. At 2 g1 walking (its sole moments weighted) got there and failed
# the capped attempt from another instance's stale multipliers: 10-12 iterations with the cold re-solve after it; at
QUIET_ITERATIONS = 1  # 1 never (walking in place 3.98 -> 3.84 iterations per step, 8 -> 0 such steps; standing same)
# A Fatrop instance's first solve cost b1_z1 ~0.9 ms more than the same solve on it again (4.8 against 3.9 ms, quiet:
# functions, initialization and line search on memory and code paths not touched for a while), and the first MPC
# step, a cold 5-iteration solve, was the closed loop's longest (2.5x the mean). `prepare_structures` therefore
# solves on each instance it builds, capped at this many iterations, the first step's instance last, right before
# the clock; the instance then forgets that solution (no later warm start sees it): the steps' iterates stay the same
REHEARSAL_ITERATIONS = 2


def default_threads() -> int:
    """Threads of the stage evaluations when SolverConfig.threads is None: two where this process may run on two
    cores (the 15 stages' functions split well in two; more threads wait for the Riccati recursion in between)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return min(2, max(cores, 1))


def mpc_tolerances(config: SolverConfig, flat_feet: bool) -> tuple[float, float]:
    """(KKT, constraint) tolerances of the binding: its MPC ones (flat feet: FLAT_FEET_MPC_TOLERANCE) while
    SolverConfig keeps its defaults and `extra_options["mpc_tolerances"]` is not False, else SolverConfig's."""
    defaults = SolverConfig()
    own = config.extra_options.get("mpc_tolerances", True) and \
        (config.tolerance, config.constraint_tolerance) == (defaults.tolerance, defaults.constraint_tolerance)
    if not own:
        return config.tolerance, config.constraint_tolerance
    return FLAT_FEET_MPC_TOLERANCE if flat_feet else MPC_TOLERANCE, MPC_CONSTRAINT_TOLERANCE


def multiplier_start(config: SolverConfig, flat_feet: bool) -> tuple[bool, float, int]:
    """Whether warm attempts start from the multipliers the MPC gives (`extra_options["shifted_multipliers"]`, by
    default on flat feet), and that attempt's barrier and iteration cap (`multiplier_barrier_init`,
    `multiplier_max_iterations`)."""
    options = config.extra_options
    return (bool(options.get("shifted_multipliers", flat_feet)),
            float(options.get("multiplier_barrier_init", MULTIPLIER_BARRIER_INIT)),
            int(options.get("multiplier_max_iterations", MULTIPLIER_MAX_ITERATIONS)))
