"""The MPC step's data preparation and plan unpacking in one C call each (`control/compiled_step.py`) against the NumPy
path they replace: the solver's inputs (p, bounds, initial guess, shifted multipliers) and the unpacked plans bit for
bit, on the states of short closed loops (a trot turning and speeding up, a push, a flat-footed biped's walk with
swing placement). The NumPy MPC replays the compiled MPC's solver results, so both see the same last plans."""

from dataclasses import replace

import numpy as np

from wbmpc.control import MPC, Commands, MpcConfig
from wbmpc.control.config import ReferenceConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import RobotModel, RobotSpec, load_robot
from wbmpc.solvers import make_solver

SMALL = OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05))
PLAN_FIELDS = ("q", "v", "a", "forces", "tau", "contact", "x", "q_joints", "node_times_s")


def paired_mpcs(robot, config: MpcConfig) -> tuple[MPC, MPC]:
    """Two MPCs of `config` with the compiled step packer and one non-compiled solver (no NLP to compile): the first
    prepares its steps in C, the second in NumPy (`compiled_step` None)."""
    config = replace(config, solver=replace(config.solver, compiled=True),
                     recovery=replace(config.recovery, fallback_solver=None))
    mpcs = []
    for _ in range(2):
        problem = OcpProblem(robot, config.ocp)
        mpcs.append(MPC(robot, config, problem=problem, solver=make_solver(problem, replace(config.solver, compiled=False))))
    compiled, numpy_path = mpcs
    assert compiled.compiled_step is not None, "the compiled step should cover this problem"
    numpy_path.compiled_step = None
    return compiled, numpy_path


def run_both(compiled: MPC, numpy_path: MPC, steps) -> int:
    """Each (q, v, commands, t) of `steps` (q, v None: the compiled MPC's plan at its node 1) through both MPCs;
    asserts the solver's inputs and the plans equal bitwise; returns the steps the C code prepared."""
    recorded, prepared = [], []
    solve, prepare = compiled.solver.solve, compiled.compiled_step.prepare

    def recording(*args, **kwargs):
        result = solve(*args, **kwargs)
        recorded.append(([np.array(a, copy=True) if isinstance(a, np.ndarray) else a for a in args], result))
        return result

    def replaying(*args, **kwargs):
        inputs, result = recorded.pop(0)
        assert len(args) == len(inputs)
        for k, (got, expected) in enumerate(zip(args, inputs)):
            if isinstance(expected, np.ndarray):
                np.testing.assert_array_equal(got, expected, err_msg=f"solver input {k}", strict=True)
        return result

    def counting(*args, **kwargs):
        prepared.append(1)
        return prepare(*args, **kwargs)

    compiled.solver.solve, numpy_path.solver.solve, compiled.compiled_step.prepare = recording, replaying, counting
    plan = None
    for q, v, commands, t_s in steps:
        if q is None:
            q, v = plan.q[1].copy(), plan.v[1].copy()
        plan, reference = compiled.solve(q, v, commands, t_s=t_s), numpy_path.solve(q, v, commands, t_s=t_s)
        assert plan.success == reference.success and plan.stats.status == reference.stats.status
        for name in PLAN_FIELDS:
            np.testing.assert_array_equal(getattr(plan, name), getattr(reference, name), err_msg=name, strict=True)
    assert not recorded
    return len(prepared)


def test_a_trots_steps_are_prepared_in_c_as_numpy_prepares_them():
    """go2 trotting: standing start, speeding up while turning, a body-height command, a push (the soft rows, the
    relaxed rows, the faster cadence), then back to the command."""
    robot = load_robot("go2")
    compiled, numpy_path = paired_mpcs(robot, MpcConfig(ocp=SMALL, gait="trot"))
    walk = Commands(base_velocity_m_s=np.array([0.3, 0.05, 0.0]), base_yaw_rate_rad_s=0.3)
    lower = Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0]), base_height_m=0.9 * robot.q_nominal[2])
    pushed = np.zeros(robot.nv)
    pushed[:2] = [0.9, -0.6]
    steps = [(robot.q_nominal.copy(), np.zeros(robot.nv), Commands(), 0.0)] + \
        [(None, None, walk, 0.0125 * k) for k in range(1, 6)] + [(None, None, lower, 0.0125 * k) for k in range(6, 8)]
    steps += [(robot.q_nominal.copy(), pushed, walk, 0.1)] + [(None, None, walk, 0.1 + 0.0125 * k) for k in range(1, 4)]
    assert run_both(compiled, numpy_path, steps) == len(steps)


def test_a_flat_footed_bipeds_walk_is_prepared_in_c_as_numpy_prepares_it(tmp_path):
    """A small flat-footed biped walking forward and turning with its swing feet carried to landing points: the soles'
    bounds, the wrench warm start by contact pattern, the shifted multipliers where the solver takes them."""
    from tests.control.test_humanoid import _biped_urdf

    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    robot = RobotModel(RobotSpec(name="biped", urdf=str(urdf), feet=("l_foot", "r_foot"), foot_contact="surface"))
    config = MpcConfig(gait="walk", ocp=SMALL, references=ReferenceConfig(swing_placement=True))
    compiled, numpy_path = paired_mpcs(robot, config)
    assert compiled.compiled_step.feet_in_c == (True, True)  # swing references and sole wrenches in C
    walk = Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0]), base_yaw_rate_rad_s=0.2)
    steps = [(robot.q_nominal.copy(), np.zeros(robot.nv), Commands(), 0.0)] + \
        [(None, None, walk, 0.0125 * k) for k in range(1, 10)]
    assert run_both(compiled, numpy_path, steps) == len(steps)


def test_node_times_following_the_switches_are_prepared_in_c_as_numpy_prepares_them(tmp_path):
    """The flat-footed biped walking on a grid whose far nodes follow the contact switches
    (`TimeGrid.follow_contact_switches`): each step's own node times reach the C code's schedule, targets, swing
    references, warm start and p's time steps as NumPy's, and the shifted multipliers as NumPy's."""
    from tests.control.test_humanoid import _biped_urdf

    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    robot = RobotModel(RobotSpec(name="biped", urdf=str(urdf), feet=("l_foot", "r_foot"), foot_contact="surface"))
    grid = TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.08, follow_contact_switches=True)
    config = MpcConfig(gait="walk", ocp=OcpConfig(grid=grid), references=ReferenceConfig(swing_placement=True))
    compiled, numpy_path = paired_mpcs(robot, config)
    walk = Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0]), base_yaw_rate_rad_s=0.2)
    steps = [(robot.q_nominal.copy(), np.zeros(robot.nv), Commands(), 0.0)] + \
        [(None, None, walk, 0.0125 * k) for k in range(1, 24)]
    moved = []
    solve = compiled.solve
    compiled.solve = lambda *args, **kwargs: moved.append(solve(*args, **kwargs)) or moved[-1]
    assert run_both(compiled, numpy_path, steps) == len(steps)
    assert sum(not np.array_equal(plan.node_times_s, grid.node_times_s) for plan in moved) >= 5


def test_point_feet_swing_placement_is_prepared_in_c_as_numpy_prepares_it():
    """go2 trotting forward and turning with its swing feet carried to landing points (point feet: no soles' yaw
    rates), after a push (capture-point feedback, the reach limit), from a state off the plan."""
    robot = load_robot("go2")
    config = MpcConfig(gait="trot", ocp=SMALL, references=ReferenceConfig(swing_placement=True))
    compiled, numpy_path = paired_mpcs(robot, config)
    assert compiled.compiled_step.feet_in_c == (True, False)
    walk = Commands(base_velocity_m_s=np.array([0.4, 0.1, 0.0]), base_yaw_rate_rad_s=-0.4)
    pushed = np.zeros(robot.nv)
    pushed[:2] = [1.5, 0.8]
    steps = [(robot.q_nominal.copy(), np.zeros(robot.nv), Commands(), 0.0)] + \
        [(None, None, walk, 0.0125 * k) for k in range(1, 8)] + [(robot.q_nominal.copy(), pushed, walk, 0.1)] + \
        [(None, None, walk, 0.1 + 0.0125 * k) for k in range(1, 4)]
    assert run_both(compiled, numpy_path, steps) == len(steps)


def test_the_numpy_path_runs_where_the_c_code_does_not_cover_the_step():
    """A biped's sway (a lean over the next stance foot) is NumPy's: such steps are not prepared in C, and the plan
    is the NumPy MPC's all the same."""
    robot = load_robot("go2")
    config = MpcConfig(ocp=SMALL, gait="trot", references=ReferenceConfig(support_sway=0.5))
    compiled, numpy_path = paired_mpcs(robot, config)
    steps = [(robot.q_nominal.copy(), np.zeros(robot.nv), Commands(), 0.0), (None, None, Commands(), 0.0125)]
    assert run_both(compiled, numpy_path, steps) == 0
