"""`MPC.prepare_structures` builds, before the clock runs, the solver instances of every row pattern that steps meet in
the first two gait cycles, also where a step's plan starts between the MPC's ticks (in real time at its measurement
plus the delay). Checked on a small flat-footed biped walking (its double support makes the row counts change), whose
80 Hz ticks alone miss patterns that starts between them meet."""

import numpy as np

from tests.control.test_humanoid import _biped_urdf
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import RobotModel, RobotSpec
from wbmpc.solvers.codegen import CodegenConfig
from wbmpc.solvers.nlp import SolverConfig


def test_starts_between_the_ticks_meet_only_prepared_instances(tmp_path):
    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    robot = RobotModel(RobotSpec(name="biped", urdf=str(urdf), feet=("l_foot", "r_foot"), foot_contact="surface"))
    ocp = OcpConfig(grid=TimeGrid(n_intervals=10, dt_first_s=0.01, dt_last_s=0.08))
    codegen = CodegenConfig(flags=("-O0", "-march=native"), cache_dir=tmp_path)
    config = MpcConfig(ocp=ocp, gait="walk", gait_period_s=0.9, recovery=RecoveryConfig(fallback_solver=None),
                       solver=SolverConfig(name="fatrop-direct", codegen=codegen))
    problem = OcpProblem(robot, ocp)
    prepared, fine = MPC(robot, config, problem=problem), MPC(robot, config, problem=problem)
    prepared.prepare_structures(rate_hz=80.0)
    fine.prepare_structures(rate_hz=8000.0)  # plan starts every 0.125 ms: what steps between the ticks can meet
    assert len(set(fine.solver.structure_keys)) > 1
    assert set(prepared.solver.structure_keys) == set(fine.solver.structure_keys)
    # and a step at such a time builds nothing: its instance is one of them
    before = set(prepared.solver.structure_keys)
    prepared.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.4567)
    assert set(prepared.solver.structure_keys) == before
