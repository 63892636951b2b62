"""Delay compensation: the state a plan will start from when it is applied, not when it was measured.

A solution computed from the state measured at t reaches the motors at t + d (solve time plus
transport). Real deployments therefore start the OCP (eq. 1) at the state predicted for t + d: the
measured state rolled forward over d with the accelerations of the plan being applied meanwhile
(the previous solution; eq. 9 applies its a_k between nodes). Within one interval of piecewise
constant a_k this is the continuous limit of the OCP's own integration (eq. 4, increments dq in the
tangent space of the measured q):

    v(t + h) = v(t) + a_k h,    dq(t + h) = dq(t) + v(t) h + a_k h^2 / 2,    q = q_meas (+) dq

so a plant that moves as the plan says is predicted exactly.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.solution import Solution
from wbmpc.errors import ConfigError, check_number

# when a plan reaches the plant in closed loop (control/loop.py): none (the simulation waits for the solver), measured
# (the step's CPU time elapses: its time on a core of its own), measured-wall (its wall time), fixed (`delay_ms`),
# realtime (the solver in its own process, the simulation paced by the wall clock)
DELAY_MODES = ("none", "measured", "measured-wall", "fixed", "realtime")
MAX_FIXED_DELAY_MS = 1000.0


def check_delay(delay_mode: str, delay_ms: float | None) -> None:
    """Refuse an unknown mode, a fixed delay without its milliseconds, milliseconds with another mode."""
    if delay_mode not in DELAY_MODES:
        raise ConfigError.for_field("delay_mode", f"must be one of {', '.join(DELAY_MODES)}; got {delay_mode!r}")
    if delay_mode == "fixed":
        if delay_ms is None:
            raise ConfigError("a fixed delay needs its length: --delay-ms MS (delay_ms)")
        check_number("delay_ms", delay_ms, low=0.0, high=MAX_FIXED_DELAY_MS, unit="ms")
    elif delay_ms is not None:
        raise ConfigError(f"--delay-ms sets a fixed delay; it does not go with --delay-mode {delay_mode}")


def delay_from_text(text: str) -> tuple[str, float | None]:
    """(delay_mode, delay_ms) of the one-string delay of before (`--delay-mode none|measured|measured-wall|realtime|MS`)."""
    if text in DELAY_MODES and text != "fixed":
        return text, None
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ConfigError.for_field("delay", "must be none, measured, measured-wall, realtime or a number of ms; "
                                    f"got '{text}'") from None
    check_number("delay", value, low=0.0, high=MAX_FIXED_DELAY_MS, unit="ms")
    return "fixed", value


def delay_text(delay_mode: str, delay_ms: float | None) -> str:
    """The one-string form of a delay (the metrics' `delay` key of before): the mode, or the milliseconds."""
    return f"{delay_ms:g}" if delay_mode == "fixed" else delay_mode


def roll_forward(model: pin.Model, q: np.ndarray, v: np.ndarray, plan: Solution | None, t_s: float,
                 delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(q, v) at t_s + delay_s from the measurement (q, v) at t_s under the plan's accelerations
    (piecewise constant per interval, the last one held beyond the horizon). Without a plan the
    velocity is held (zero acceleration)."""
    if not delay_s > 0:
        return q, v
    dq = np.zeros(model.nv)
    velocity = np.array(v, dtype=float)
    if plan is None:
        dq += velocity * delay_s
    else:
        times = plan.t_s + plan.node_times_s
        n_intervals = plan.a.shape[0]
        s, end = t_s, t_s + delay_s
        while s < end - 1e-15:  # one or two intervals: the delay is shorter than a few of them
            k = int(np.clip(np.searchsorted(times, s, side="right") - 1, 0, n_intervals - 1))
            segment_end = times[k + 1] if k < n_intervals - 1 and times[k + 1] > s else end
            h = min(segment_end, end) - s
            acceleration = plan.a[k]
            dq += velocity * h + 0.5 * acceleration * h * h
            velocity += acceleration * h
            s += h
    return pin.integrate(model, np.asarray(q, dtype=float), dq), velocity
