"""`Solution`: the optimal trajectories of one MPC step over the horizon."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.control.trajectory import interp_rows
from wbmpc.solvers.nlp import SolverStats


@dataclass
class Solution:
    """q (N+1, nq), v (N+1, nv), a (N, nv), forces (N, nf), tau (n_torque_nodes, n_joints).

    For velocity-level formulations v_N repeats v_{N-1}, a comes from differences of v and tau is
    the inverse dynamics of the plan.

    Times are absolute: node k is at `t_s + node_times_s[k]`. Forces are world-frame forces on the
    robot at `robot.contact_frames`. Use only when `success` is true.
    """

    t_s: float
    node_times_s: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    forces: np.ndarray
    tau: np.ndarray
    contact: np.ndarray
    stats: SolverStats
    success: bool
    x: np.ndarray | None = None  # the NLP solution vector (scaled variables), for warm starts
    q_joints: np.ndarray | None = None  # (N+1, n_joints) joint angles of q (continuous joints unwrapped)
    # a failed step's stand-in: the last good plan re-sampled at the new node times (`MpcConfig.
    # hold_previous_on_failure`); `success` stays False, the loop applies it all the same
    held_previous: bool = False
    # timings of the step, set by the loop or solver process that ran it (0 until then)
    wall_time_s: float = 0.0  # wall time of `MPC.solve`
    cpu_time_s: float = 0.0  # CPU time of the thread that ran it (`--delay-mode measured`)
    process_cpu_s: float = 0.0  # the solver process's CPU clock when the step ended (real-time CPU share)
    stamps: np.ndarray | None = None  # real time: the step's clock stamps (control/step_anatomy.SOLVER_STAMPS)

    def __post_init__(self) -> None:
        if self.q_joints is None:  # nq = nv + 1: the joint coordinates are q[:, 7:]
            self.q_joints = np.asarray(self.q)[:, 7:]

    @property
    def dt_s(self) -> np.ndarray:
        return np.diff(self.node_times_s)

    def as_dict(self) -> dict:
        return {
            "t_s": self.t_s,
            "dt_s": self.dt_s.tolist(),
            "success": self.success,
            "status": self.stats.status,
            "iterations": self.stats.iterations,
            "solve_ms": self.stats.solve_time_s * 1e3,
            "max_constraint_violation": self.stats.max_constraint_violation,
        }


def python_share(stats, step_ms: float) -> None:
    """`split_ms["python"]`: the step's wall time outside the solver's own work (its split's parts other than
    `outside_solver`; without a split, its solve time): input checks, references, parameters, bounds, warm start,
    the solver wrapper's packing and calls (its `outside_solver`, folded in here) and unpacking. The parts then
    add up to the step."""
    split = stats.split_ms
    split.pop("python", None)
    outside = split.pop("outside_solver", 0.0)
    inside = sum(split.values()) if split else 1e3 * stats.solve_time_s
    split["python"] = max(step_ms - inside, outside, 0.0)


def joint_trajectory(robot, q_traj: np.ndarray) -> np.ndarray:
    """Joint positions per node; continuous joints unwrapped along the horizon (no 2 pi jumps)."""
    positions = robot.joint_positions(q_traj)
    continuous = robot.continuous
    if continuous.any():
        positions[:, continuous] = np.unwrap(positions[:, continuous], axis=0)
    return positions


def shifted_plan(prev: Solution, t: float, node_times: np.ndarray, contact: np.ndarray, stats, robot) -> Solution:
    """The last good plan `prev` re-sampled at the new node times (held beyond its horizon), returned as a failed step
    (`success` False, `held_previous` True): the loop keeps applying a plan that moves on in time instead of the
    stale one."""
    old, new = prev.t_s + prev.node_times_s, t + node_times
    n_tau = prev.tau.shape[0]
    q = interp_rows(new, old, prev.q)
    q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
    stats.status = f"{stats.status}; holding the last good plan shifted by {1e3 * (t - prev.t_s):.0f} ms"
    return Solution(t_s=t, node_times_s=node_times.copy(), q=q, v=interp_rows(new, old, prev.v),
                    a=interp_rows(new[:-1], old[:-1], prev.a), forces=interp_rows(new[:-1], old[:-1], prev.forces),
                    tau=interp_rows(new[:n_tau], old[:n_tau], prev.tau), contact=contact, stats=stats,
                    success=False, x=None, q_joints=joint_trajectory(robot, q), held_previous=True)
