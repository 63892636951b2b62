import numpy as np
import pytest

from wbmpc.robots import load_robot


@pytest.fixture(scope="session")
def b1z1():
    return load_robot("b1_z1")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def _forward_plan(robot, nodes: int = 8):
    """A plan moving forward 5 cm per node with the weight on the stance feet (the shape the MPC returns)."""
    from wbmpc.control.solution import Solution
    from wbmpc.solvers.nlp import SolverStats

    q = np.tile(robot.q_nominal, (nodes, 1))
    q[:, 0] += 0.05 * np.arange(nodes)
    n_feet = len(robot.feet)
    forces = np.zeros((nodes - 1, 3 * n_feet + (3 if robot.arm_ee else 0)))
    forces[:, 2 : 3 * n_feet : 3] = robot.mass_kg * 9.81 / n_feet
    return Solution(t_s=0.0, node_times_s=np.linspace(0, 0.3, nodes), q=q, v=np.zeros((nodes, robot.nv)),
                    a=np.zeros((nodes - 1, robot.nv)), forces=forces, tau=np.zeros((3, robot.n_joints)),
                    contact=np.ones((nodes, n_feet), dtype=bool), stats=SolverStats(status="ok", success=True, iterations=1, solve_time_s=0.0,
                                                                             max_constraint_violation=0.0, cost=0.0),
                    success=True, x=None, q_joints=q[:, 7:])


@pytest.fixture
def forward_plan():
    """`forward_plan(robot, nodes=8)`: a plan as the MPC returns it, for the viewers' tests."""
    return _forward_plan
