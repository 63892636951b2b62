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
