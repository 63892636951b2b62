"""The solvers' input checks in C (`solvers/step_pack.py` `invalid_input`) against NumPy's: NaN and infinities in
the parameters or the initial guess, crossed bounds, NaN bounds (no refusal, as NumPy compares them)."""

import numpy as np
import pytest

from wbmpc.solvers import step_pack


@pytest.mark.parametrize("compiled", [False, True])
def test_invalid_inputs_are_refused_by_name(compiled):
    packer = step_pack.library() if compiled else None
    if compiled and packer is None:
        pytest.skip("no C compiler")
    rng = np.random.default_rng(0)
    n_x, n_g, n_p = 40, 30, 12
    p, x0 = rng.normal(size=n_p), rng.normal(size=n_x)
    lbx, lbg = rng.normal(size=n_x), rng.normal(size=n_g)
    ubx, ubg = lbx + 1.0, lbg + np.where(rng.uniform(size=n_g) < 0.5, 0.0, np.inf)

    def check(**changes):
        values = {"p": p, "x0": x0, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}
        for name, (entry, value) in changes.items():
            values[name] = values[name].copy()
            values[name][entry] = value
        return step_pack.invalid_input(packer, *values.values())

    assert check() is None
    for name in ("p", "x0"):
        for value in (np.nan, np.inf, -np.inf):
            assert check(**{name: (3, value)}) == "invalid_input_nan"
    assert check(lbx=(5, 2.0), ubx=(5, 1.0)) == "invalid_bounds"
    assert check(lbg=(7, 0.5), ubg=(7, -0.5)) == "invalid_bounds"
    assert check(lbx=(5, np.nan)) is None and check(ubg=(2, np.nan)) is None  # NaN compares false, as in NumPy
    assert check(lbx=(5, np.inf), ubx=(5, np.inf)) is None
    assert check(p=(0, np.nan), lbx=(5, 2.0), ubx=(5, 1.0)) == "invalid_input_nan"  # the NaN is named first
    # lists and other dtypes: the NumPy checks
    assert step_pack.invalid_input(packer, list(p), x0.astype(np.float32), lbx, ubx, lbg, ubg) is None
