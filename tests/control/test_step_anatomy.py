"""A real-time plan's delay split into its segments (control/step_anatomy.py): they add up to the delay, each
is the difference of the stamps it names, and the run's summary gives each one's mean, p95 and max."""

import numpy as np

from wbmpc.control.step_anatomy import SEGMENTS, SOLVER_STAMPS, StepStamps, segments, summary


def _stamps() -> np.ndarray:
    # received, answered, then the MPC's start, predicted, prepared, solved, unpacked, end (s on one clock)
    named = {"received": 100.0002, "answered": 100.0110, "start": 100.0003, "predicted": 100.0007,
             "prepared": 100.0012, "solved": 100.0104, "unpacked": 100.0105, "end": 100.0106}
    return np.array([named[name] for name in SOLVER_STAMPS])


def test_the_segments_are_the_stamps_differences_and_add_up_to_the_delay():
    loop = (100.0, 100.0001, 100.0111, 100.0115, 100.0116)  # measured, sent, woken, noticed, taken
    delay_s = 0.012
    parts = dict(zip(SEGMENTS, segments(_stamps(), 0.0088, loop, delay_s)))
    expected = {"measure": 0.1, "request": 0.1, "before_mpc": 0.1, "prediction": 0.4, "preparation": 0.5,
                "solver_wrapper": 9.2 - 8.8, "solve": 8.8, "unpacking": 0.1, "after_mpc": 0.1, "answer": 0.4,
                "wake": 0.1, "to_step": 0.4, "take": 0.1, "to_plant": 12.0 - 11.6}
    assert list(parts) == list(expected)
    for name, value in expected.items():
        assert abs(parts[name] - value) < 1e-6, name
    assert abs(sum(parts.values()) - 1e3 * delay_s) < 1e-9


def test_a_stand_in_without_stamps_leaves_its_segments_unknown_and_the_sum_whole():
    """An MPC stand-in without `step_stamps`: its segments NaN, what the loop measured kept, the rest in to_plant."""
    stamps = np.full(len(SOLVER_STAMPS), np.nan)
    out = dict(zip(SEGMENTS, segments(stamps, 0.005, (0.0, 0.0001, 0.0062, 0.0065, 0.0066), 0.007)))
    assert np.isnan(out["prediction"]) and np.isnan(out["request"])
    assert abs(out["to_step"] - 0.3) < 1e-9 and abs(out["take"] - 0.1) < 1e-9
    assert abs(np.nansum(list(out.values())) - 7.0) < 1e-9


def test_the_summary_gives_each_segments_mean_p95_and_max():
    rows = np.tile(np.arange(len(SEGMENTS), dtype=float), (20, 1))
    rows[:, 0] = np.arange(20)
    out = summary(rows)
    assert list(out) == list(SEGMENTS)
    assert out["measure"] == {"mean": 9.5, "p95": np.percentile(np.arange(20), 95), "max": 19.0}
    assert out["solve"]["mean"] == SEGMENTS.index("solve")
    assert summary(np.zeros((0, len(SEGMENTS)))) == {}


def test_an_mpc_step_stamps_in_order():
    stamps = StepStamps()
    stamps.start()
    for name in ("predicted", "prepared", "solved", "unpacked", "end"):
        stamps.mark(name)
    assert (np.diff(stamps.values) >= 0).all() and np.isfinite(stamps.values).all()
    stamps.start()
    assert np.isnan(stamps.values[1:]).all()
