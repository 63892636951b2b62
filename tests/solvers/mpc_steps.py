"""go2's tiny OCP (2 intervals) and MPC steps' solver inputs, for the solver tests."""

import numpy as np

from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig

TINY = OcpConfig(grid=TimeGrid(n_intervals=2, dt_first_s=0.01, dt_last_s=0.02))


def capture_step_data(robot, problem, ocp: OcpConfig) -> dict:
    """p, bounds and initial guess of one trot MPC step from a moving base, as the MPC hands them to its solver."""
    mpc = MPC(robot, MpcConfig(ocp=ocp, recovery=RecoveryConfig(fallback_solver=None)), problem=problem)
    captured = {}
    solve = mpc.solver.solve

    def spy(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs):
        captured.update(p=np.array(p), lbx=lbx.copy(), ubx=ubx.copy(), lbg=lbg.copy(), ubg=ubg.copy(), x0=x0.copy())
        return solve(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs)

    mpc.solver.solve = spy
    v0 = np.zeros(robot.nv)
    v0[:2] = [0.1, 0.05]
    assert mpc.solve(robot.q_nominal, v0, t_s=0.1).success
    return captured


def capture_trot_steps(mpc: MPC, robot) -> list[dict]:
    """p, bounds and guesses of a few trot steps (moving base, contact changes) as `mpc` hands them to its solver."""
    captured = []
    solve = mpc.solver.solve

    def spy(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs):
        captured.append(dict(p=np.array(p), lbx=lbx.copy(), ubx=ubx.copy(), lbg=lbg.copy(), ubg=ubg.copy(),
                             x0=x0.copy()))
        return solve(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs)

    mpc.solver.solve = spy
    v0 = np.zeros(robot.nv)
    v0[:2] = [0.2, -0.05]
    for t in (0.1, 0.1125, 0.125, 0.2):
        assert mpc.solve(robot.q_nominal, v0, t_s=t).success
    return captured
