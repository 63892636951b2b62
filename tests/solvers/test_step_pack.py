"""The solvers' input checks in C (`solvers/step_pack.py` `invalid_input`) against NumPy's: NaN and infinities in
the parameters or the initial guess, crossed bounds, NaN bounds (no refusal, as NumPy compares them)."""

import numpy as np
import pytest

from wbmpc.gait import SwingProfile
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


def test_the_compiled_swing_velocity_equals_the_profiles_bitwise():
    """`SwingVelocity` (C) against `SwingProfile.vertical_velocity` (NumPy): stance, both cubic pieces and their
    joint, lift-off and touch-down velocities, a standing gait (no swing time)."""
    packer = step_pack.library()
    if packer is None:
        pytest.skip("no C compiler")
    rng = np.random.default_rng(2)
    for profile in (SwingProfile(), SwingProfile(apex_height_m=0.11, liftoff_velocity_m_s=0.3, touchdown_velocity_m_s=-0.2)):
        compiled = step_pack.SwingVelocity(profile, packer, (16, 4))
        for duration in (0.25, 0.1 / 3, 0.0):
            progress = np.where(rng.uniform(size=(16, 4)) < 0.4, -1.0, rng.uniform(size=(16, 4)))
            progress[0, :3] = [0.0, 0.5, np.nextafter(0.5, 0)]
            if duration == 0.0:  # a standing gait: every foot in stance
                progress[:] = -1.0
            expected, got = profile.vertical_velocity(progress, duration), compiled(progress, duration)
            assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
        assert np.array_equal(compiled(progress[:3], 0.25), profile.vertical_velocity(progress[:3], 0.25))  # other shape
