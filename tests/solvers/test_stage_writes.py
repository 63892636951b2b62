"""The stage library's generated C writes each output's structural nonzeros straight into the dense column-major
buffer the shim passes (stage_library.dense_writes): every nonzero at its place, the rest zeroed once, and CasADi's
own densified outputs where its text is not as expected. End to end (the shim's dense blocks against CasADi's
evaluation of the stage functions): test_fatrop_threads.test_stage_derivatives_are_the_stage_functions."""

import ctypes
import re
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

from wbmpc.solvers import stage_library


def _function() -> ca.Function:
    """Two outputs with structural zeros (a lower triangle, a sparse column) and one dense scalar."""
    x = ca.SX.sym("x", 3)
    lower = ca.tril(ca.mtimes(x, x.T)) + ca.diag(ca.sin(x))
    column = ca.vertcat(x[0] * x[2], ca.SX(1, 1), ca.cos(x[1]), ca.SX(1, 1))  # structural zeros
    return ca.Function("wbk0_hess", [x], [lower, column, ca.sumsqr(x)])


def _generated(function: ca.Function) -> str:
    generator = ca.CodeGenerator("f.c", {"with_header": False})
    generator.add(function)
    return generator.dump()


def test_each_nonzero_is_written_at_its_dense_place_once():
    function = _function()
    code = stage_library.dense_writes(_generated(function), [function])
    assert code is not None
    written = [(int(i), int(k)) for i, k in re.findall(r"res\[(\d)\]\[(\d+)\]=", code)]
    expected = []
    for i in range(function.n_out()):
        dense = np.array(ca.DM(function.sparsity_out(i), 1)).ravel(order="F")
        expected += [(i, int(k)) for k in np.flatnonzero(dense)]
    assert sorted(written) == sorted(expected)
    assert "!=0) res[" not in code  # the shim passes every output
    # the outputs with structural zeros are cleared first, the dense one is not
    assert re.findall(r"memset\(res\[(\d)\], 0, sizeof\(casadi_real\) \* (\d+)\)", code) == [("0", "9"), ("1", "4")]


@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_compiled_writes_equal_casadi_dense_values(tmp_path):
    function = _function()
    source = tmp_path / "f.c"
    source.write_text(stage_library.dense_writes(_generated(function), [function]))
    library = tmp_path / "f.so"
    subprocess.run(["gcc", "-O1", "-shared", "-fPIC", str(source), "-o", str(library), "-lm"], check=True)
    call = ctypes.CDLL(str(library)).wbk0_hess
    x = np.array([0.3, -1.2, 0.7])
    outputs = [np.full(function.sparsity_out(i).numel(), np.nan) for i in range(function.n_out())]  # no zeros given
    pointer = ctypes.POINTER(ctypes.c_double)
    arg = (pointer * 1)(x.ctypes.data_as(pointer))
    res = (pointer * 3)(*[o.ctypes.data_as(pointer) for o in outputs])
    work = (ctypes.c_double * 64)()
    assert call(arg, res, (ctypes.c_longlong * 8)(), work, 0) == 0
    for output, value in zip(outputs, function(x)):
        np.testing.assert_array_equal(output, np.array(value).ravel(order="F"))


def test_unexpected_text_falls_back_to_densified_outputs(monkeypatch):
    function = _function()
    assert stage_library.dense_writes(_generated(function).replace("return 0;", "return  0;"), [function]) is None
    assert stage_library.dense_writes("int f(void) { return 0; }\n", [function]) is None
