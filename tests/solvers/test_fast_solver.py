"""Fast linear algebra under Fatrop (the AVX2 BLASFEO) and Fatrop options kept across contact switches."""

import ctypes
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, StageBounds
from wbmpc.robots import load_robot
from wbmpc.solvers import blasfeo
from wbmpc.solvers.nlp import SolverConfig

SMALL = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


def test_the_active_blasfeo_is_the_only_one_loaded():
    """After a Fatrop solve the process holds exactly the BLASFEO the status names: never both."""
    status = blasfeo.status()
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="stand"))
    assert mpc.solve(robot.q_nominal, np.zeros(robot.nv)).success
    loaded = blasfeo.loaded_libraries("libblasfeo")
    if status.active == "avx2":
        assert loaded == [status.library]
    else:
        assert len(loaded) == 1 and Path(loaded[0]).parent.name == "casadi"


def test_importing_wbmpc_loads_no_blasfeo():
    """No import-time side effects: importing the packages (solvers included) loads no BLASFEO; the first solver
    made activates the one `status` names before Fatrop loads."""
    code = """
import json
from pathlib import Path
def loaded():
    return sorted({l.split()[-1] for l in Path('/proc/self/maps').read_text().splitlines()
                   if 'libblasfeo' in l.split()[-1]})
import wbmpc.solvers, wbmpc.solvers.nlp, wbmpc.control, wbmpc.scenarios
before = loaded()
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.solvers import blasfeo, make_solver
from wbmpc.solvers.nlp import SolverConfig
problem = OcpProblem(load_robot("a1"), OcpConfig(grid=TimeGrid(n_intervals=2, dt_first_s=0.01, dt_last_s=0.02)))
make_solver(problem, SolverConfig())
print(json.dumps({"before": before, "after": loaded(), "library": blasfeo.status().library}))
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["before"] == []
    assert len(report["after"]) == 1
    if report["library"] is not None:
        assert report["after"] == [report["library"]]


@pytest.mark.skipif(not blasfeo.library_path().exists(), reason="the AVX2 BLASFEO is not installed (wbmpc setup)")
def test_avx2_blasfeo_gives_the_generic_solution():
    ok, detail = blasfeo.verify(blasfeo.library_path())
    assert ok, detail
    assert "iterations" in detail


def test_verification_rejects_a_broken_library(tmp_path):
    broken = tmp_path / "libblasfeo.so.0"
    broken.write_bytes(b"\x7fELF not really a library")
    ok, detail = blasfeo.verify(broken)
    assert not ok
    assert "crashed" in detail


def test_bad_mode_is_refused(monkeypatch):
    monkeypatch.setenv("WBMPC_BLASFEO", " AVX2 ")
    assert blasfeo.requested_mode() == "avx2"
    monkeypatch.setenv("WBMPC_BLASFEO", "fastest")
    with pytest.raises(ConfigError, match="'fastest' is not a choice; use auto, generic or avx2"):
        blasfeo.requested_mode()


def test_cpu_flags_are_read():
    assert isinstance(blasfeo.cpu_has_avx2_fma(), bool)
    assert ctypes.sizeof(ctypes.c_void_p) == 8


@pytest.fixture(scope="module")
def switching():
    """go2 switching between four feet in stance and a trot pair in swing: the per-stage row counts
    change (trot and walk keep them constant, a stop or a start of the gait does not)."""
    robot = load_robot("go2")
    config = MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(max_iterations=2),
                       recovery=RecoveryConfig(barrier_init=None, fallback_solver=None))
    mpc = MPC(robot, config)
    node_times = mpc.problem.config.grid.node_times_s
    stance = np.ones((len(node_times), 4), dtype=bool)
    trot = stance.copy()
    trot[2:, [1, 2]] = False
    schedules = {"stand": stance, "trot": trot}
    mpc.pattern = "stand"
    mpc.schedule = lambda t: (node_times, schedules[mpc.pattern], np.zeros((len(node_times), 4)))
    keys = {name: mpc.solver.structure_key(*mpc.problem.bounds(StageBounds(
        v0=np.zeros(robot.nv), q_ref=robot.q_nominal, contact=contact, swing_vz_m_s=np.zeros(contact.shape))))
        for name, contact in schedules.items()}
    return robot, mpc, keys


def test_structure_key_counts_rows_like_casadi(switching):
    robot, mpc, keys = switching
    stand, trot = (np.frombuffer(keys[name], dtype=np.int32).reshape(2, -1) for name in ("stand", "trot"))
    assert stand.shape == (2, mpc.problem.N + 1)
    # a swing foot trades F_z >= 0 and its cone row (2 inequalities) for F_x = F_y = 0 (2 more equalities;
    # F_z = 0 replaces v_z = 0): per swing foot +1 equality, -2 inequalities, from node 2 on
    np.testing.assert_array_equal(trot[0, 2:-1] - stand[0, 2:-1], 2)
    np.testing.assert_array_equal(trot[1, 2:-1] - stand[1, 2:-1], -4)
    np.testing.assert_array_equal(trot[:, :2], stand[:, :2])


def test_options_hold_after_contact_switches(switching):
    """max_iter = 2 must bind on every pattern, also when a pattern comes back (casadi 3.8 forgets it)."""
    robot, mpc, keys = switching
    for pattern in ("stand", "trot", "stand", "trot"):
        mpc.pattern = pattern
        mpc.reset()
        mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.0)
        assert mpc.solver.solver.stats()["iter_count"] <= 3, pattern
    assert set(mpc.solver.structure_keys) == set(keys.values())


def test_buffered_function_matches_a_plain_call():
    """The hot path's NumPy-buffer calls give what CasADi's own call gives: matrix inputs column-major,
    sparse outputs as their nonzeros, omitted inputs at their defaults, outputs overwritten per call."""
    import casadi as ca

    from wbmpc.solvers.buffered import BufferedFunction

    x, y = ca.SX.sym("x", 3, 2), ca.SX.sym("y", 2)
    f = ca.Function("f", [x, y], [ca.sin(x) * 2, ca.mtimes(x, y), ca.jacobian(ca.vec(x) * y[0], ca.vec(x))])
    buffered = BufferedFunction(f)
    rng = np.random.default_rng(0)
    for _ in range(2):
        X, Y = rng.normal(size=(3, 2)), rng.normal(size=2)
        expected = f(X, Y)
        out = buffered(X, Y, shaped=True)
        np.testing.assert_allclose(out[0], np.asarray(expected[0]), rtol=1e-15)
        np.testing.assert_allclose(out[1].ravel(), np.asarray(expected[1]).ravel(), rtol=1e-15)
        np.testing.assert_allclose(out[2], expected[2].nonzeros(), rtol=1e-15)
    np.testing.assert_allclose(buffered(X)[1], 0.0)  # y omitted: its default, 0
    with pytest.raises(TypeError, match="takes 2 inputs"):
        buffered(X, Y, Y)


@pytest.fixture(scope="module")
def trot_steps(b1z1):
    """B1 + Z1 trotting (7 nodes, pinocchio plant): the NLP data of 12 consecutive warm-started MPC steps."""
    from wbmpc.control.loop import ClosedLoop, LoopConfig
    from wbmpc.sim import make_plant

    robot = b1z1
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(warm_barrier_init=None)))
    calls = []
    solve = mpc.solver.solve

    def recording(*args, **kwargs):
        result = solve(*args, **kwargs)
        if kwargs.get("warm_start") and result.stats.success:
            calls.append(args)
        return result

    mpc.solver.solve = recording
    plant = make_plant("pinocchio", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    ClosedLoop(mpc, plant, LoopConfig(delay_mode="none")).run(13 / 80)
    assert len(calls) >= 8
    return mpc.problem, calls


def test_small_barrier_attempt_on_warm_steps_converges_to_the_same_solution(trot_steps):
    """`warm_start=True`: Fatrop first from mu 1e-5 (capped); same optimum to the solver tolerance, fewer
    iterations; a failed attempt falls back to the normal solve and pauses the attempts."""
    from wbmpc.solvers.nlp import NlpSolver

    problem, steps = trot_steps
    plain = NlpSolver(problem, SolverConfig(warm_barrier_init=None))
    warm = NlpSolver(problem, SolverConfig())
    iterations = {"plain": 0, "warm": 0}
    for data in steps:
        reference, result = plain.solve(*data), warm.solve(*data, warm_start=True)
        assert reference.stats.success and result.stats.success
        np.testing.assert_allclose(result.x, reference.x, atol=1e-3)
        assert result.stats.cost == pytest.approx(reference.stats.cost, rel=1e-4)
        iterations["plain"] += reference.stats.iterations
        iterations["warm"] += result.stats.iterations
    # no more iterations (the saving shows on the 15-node trot: 3.1 instead of 4.0 per step, `wbmpc bench mpc`)
    assert iterations["warm"] <= iterations["plain"]
    # an attempt that cannot converge (1 iteration): the normal solve still answers, then the attempts pause
    capped = NlpSolver(problem, SolverConfig(warm_max_iterations=1, warm_backoff_steps=2))
    first = capped.solve(*steps[0], warm_start=True)
    assert first.stats.success and "(after mu_init 1e-05: Maximum_Iterations_Exceeded)" in first.stats.status
    paused = [capped.solve(*data, warm_start=True).stats.status for data in steps[1:4]]
    assert [("after mu_init" in status) for status in paused] == [False, False, True]
