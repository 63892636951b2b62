"""The stage functions on several stages at once (solvers/stage_vectors.py): each lane of the rewritten C equals the
scalar generated C bit for bit and CasADi's own evaluation, and fatrop-direct solves the same with lanes as without."""

import ctypes
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

from tests.solvers.mpc_steps import capture_trot_steps
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.solvers import stage_library
from wbmpc.solvers.codegen import CodegenConfig
from wbmpc.solvers.fatrop_direct import FatropDirectSolver
from wbmpc.solvers.nlp import SolverConfig
from wbmpc.solvers.stage_vectors import LANES, vector_body, vectorize

_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


@pytest.fixture(scope="module")
def codegen(tmp_path_factory):
    return CodegenConfig(flags=("-O0", "-march=native"), cache_dir=tmp_path_factory.mktemp("wbmpc_cache"))


@pytest.fixture(scope="module")
def steps(robot, problem):
    """p, bounds and guesses of a few trot steps (moving base, contact changes) as the MPC hands them over."""
    mpc = MPC(robot, MpcConfig(ocp=problem.config, recovery=RecoveryConfig(fallback_solver=None)), problem=problem)
    return capture_trot_steps(mpc, robot)


def _function():
    """Every statement form the stage functions use: arithmetic with numbers, sin/cos/sqrt/tanh, squares, fmax,
    comparisons, negation and if_else_zero; two outputs, one of them sparse."""
    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 2)
    smooth = ca.sqrt(ca.sumsqr(x[:2]) + 1e-6) - 0.1 * ca.tanh(x[2] / 0.2)
    switch = ca.if_else(x[0] <= p[0], ca.sin(x[1]) * x[2], 0) + ca.fmax(x[1], -p[1]) + (x[2] < x[0])
    values = ca.vertcat(smooth, switch, ca.cos(x[0]) ** 2 / (2.5 + x[1] ** 2), -x[2] * p[1], ca.logic_not(x[0] > 0))
    jacobian = ca.jacobian(values, x)
    return ca.Function("vf", [x, p], [values, jacobian])


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    function = _function()
    generator = ca.CodeGenerator("vf.c", {"with_header": False})
    generator.add(function)
    code = stage_library.dense_writes(generator.dump(), [function])
    assert code is not None
    vectorized, done = vectorize(code, ["vf"], {"vf": 2}, {"vf": 2})
    assert done == ["vf"]
    directory = tmp_path_factory.mktemp("lanes")
    libraries = []
    for name, text in (("scalar", code), ("lanes", vectorized)):
        (directory / f"{name}.c").write_text(text)
        subprocess.run([shutil.which("gcc") or "gcc", "-O1", "-march=native", "-shared", "-fPIC", str(directory / f"{name}.c"),
                        "-o", str(directory / f"{name}.so"), "-lm"], check=True)
        libraries.append(ctypes.CDLL(str(directory / f"{name}.so")))
    return function, libraries


def _outputs(function):
    return [np.zeros(function.sparsity_out(i).numel()) for i in range(function.n_out())]


def test_each_lane_equals_the_scalar_code_and_casadi(library):
    function, (scalar, lanes) = library
    rng = np.random.default_rng(3)
    inputs = [[rng.normal(size=function.size1_in(i)) for i in range(2)] for _ in range(LANES)]
    inputs[1][0][0] = inputs[1][1][0] - 1.0  # the branches both ways across the lanes
    inputs[2][0][0] = inputs[2][1][0] + 1.0
    lane_outputs = [_outputs(function) for _ in range(LANES)]
    for out in lane_outputs:  # stale values where no nonzero is written: cleared by the lane function
        for block in out:
            block[:] = np.nan
    arg = (_DOUBLE_P * (2 * LANES))(*[inputs[lane][i].ctypes.data_as(_DOUBLE_P) for i in range(2)
                                      for lane in range(LANES)])
    res = (_DOUBLE_P * (2 * LANES))(*[lane_outputs[lane][i].ctypes.data_as(_DOUBLE_P) for i in range(2)
                                      for lane in range(LANES)])
    assert lanes.vf_lanes(arg, res, (1 << LANES) - 1) == 0
    for lane in range(LANES):
        own = _outputs(function)
        arg1 = (_DOUBLE_P * 2)(*[a.ctypes.data_as(_DOUBLE_P) for a in inputs[lane]])
        res1 = (_DOUBLE_P * 2)(*[o.ctypes.data_as(_DOUBLE_P) for o in own])
        assert scalar.vf(arg1, res1, None, None, 0) == 0
        for got, want in zip(lane_outputs[lane], own):
            assert np.array_equal(got, want)  # bit for bit the scalar code's
        reference = function(*inputs[lane])
        for got, want in zip(lane_outputs[lane], reference):
            np.testing.assert_allclose(got, np.asarray(ca.densify(want)).ravel(order="F"), rtol=1e-14, atol=1e-14)
    # the scalar entry of the rewritten code runs the lane code on its one point
    again = _outputs(function)
    arg1 = (_DOUBLE_P * 2)(*[a.ctypes.data_as(_DOUBLE_P) for a in inputs[3]])
    res1 = (_DOUBLE_P * 2)(*[o.ctypes.data_as(_DOUBLE_P) for o in again])
    assert lanes.vf(arg1, res1, None, None, 0) == 0
    assert all(np.array_equal(a, b) for a, b in zip(again, lane_outputs[3]))


def test_a_statement_of_another_form_keeps_the_scalar_code():
    assert vector_body("  a0=arg[0]? arg[0][1] : 0;\n  res[0][3]=a0;") is not None
    assert vector_body("  a0=arg[0]? arg[0][1] : 0;\n  a1=some_call(a0, 2, 3);") is None
    assert vector_body("  a1=(2.*3.);") is None  # numbers only: not an expression of the lanes
    assert vectorize("int f(void) { return 0; }\n", ["f"], {"f": 0}, {"f": 0}) == ("int f(void) { return 0; }\n", [])


def test_lanes_solve_as_the_scalar_code(problem, codegen, steps, monkeypatch):
    """go2 (its first stage covered by the torque kind: in the cover's lanes) on 1 and 2 threads: the same iterates
    bit for bit with and without lane functions."""
    with_lanes = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen, threads=1))
    monkeypatch.setattr(stage_library, "vectorize", lambda code, names, n_in, n_out: (code, []))
    scalar = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen, threads=1))
    assert scalar.compile_report.library != with_lanes.compile_report.library
    for solver in (with_lanes, with_lanes.recreated(threads=2)):
        for step in steps:
            a, b = solver.recreated().solve(**step, warm_start=True), scalar.recreated().solve(**step, warm_start=True)
            assert a.stats.iterations == b.stats.iterations
            assert np.array_equal(a.x, b.x) and np.array_equal(a.lam_g, b.lam_g)
