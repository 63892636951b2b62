"""The anatomy of a real-time MPC step: where the plan delay goes, segment by segment, beside the solve.

In real time (`--delay-mode realtime`) a plan's delay runs from the plant's measurement to the physics step
the plan first applies at. The solve is only part of it; the rest is the request and the answer crossing
between the processes (`realtime_channel.py`), the MPC's own work around the solve (the delay prediction,
the step's data, unpacking) and the plant loop noticing the answer. Both processes stamp the step on the same
clock (`time.perf_counter`, CLOCK_MONOTONIC on Linux: one clock for every process of the machine):

- the MPC (`MPC.solve`): `MPC_STAMPS`, written into `MPC.step_stamps` as the step goes;
- the solver process: `received` (the request read), `answered` (the plan written, just before its wake-up);
- the plant loop: `measured` (the wall time of the plant's time of the measurement), `sent` (before the request is written), `woken` (its wait on the answer returned, or the
  answer found ready), `noticed` (the loop turns to the answer: its physics step's wall time reached), `taken`
  (the plan copied out).

`segments` turns them into SEGMENTS (ms), which add up to the plan's delay exactly; `summary` gives each
segment's mean, 95th percentile and max over a run (the metrics' `realtime_step_anatomy_ms`).
"""

from __future__ import annotations

import time

import numpy as np

# stamps of the MPC's step (`MPC.step_stamps`), in this order
MPC_STAMPS = ("start", "predicted", "prepared", "solved", "unpacked", "end")
# ... and of the solver process around it: the request read, the plan written
PROCESS_STAMPS = ("received", "answered")
SOLVER_STAMPS = PROCESS_STAMPS + MPC_STAMPS  # what a plan carries back (`Solution.stamps`), in this order

SEGMENTS = (
    "measure",  # the plant's time of the measurement on the wall clock -> the request written (the loop's tick)
    "request",  # the request written by the loop -> read by the solver process (wake-up, copies)
    "before_mpc",  # the request's fields -> MPC.solve called (the command rebuilt, inertial parameters)
    "prediction",  # the state's checks and the delay compensation's prediction (control/delay.py)
    "preparation",  # the gait, the step's parameters, bounds and initial guess (compiled_step.prepare)
    "solver_wrapper",  # the solver's call less its own solve: shifted duals, the wrapper's Python and copies
    "solve",  # the solver's own solve (`SolverStats.solve_time_s`, the run log's solve_ms)
    "unpacking",  # the plan out of the solution vector (compiled_step.unpack)
    "after_mpc",  # the rest of MPC.solve (duals recorded, the split)
    "answer",  # MPC.solve returned -> the plan written to the channel
    "wake",  # the plan written -> the plant loop woken by it (or finding it at its next physics step)
    "to_step",  # woken -> the loop takes the plan: the wall clock reaching the loop's next physics step
    "take",  # the plan copied out of the channel
    "to_plant",  # the rest of the delay: the plant's physics step of the plan against its wall time
)
INDEX = {name: k for k, name in enumerate(SOLVER_STAMPS)}


class StepStamps:
    """`MPC_STAMPS` of the step in progress: `mark(name)` when the step reaches it (`time.perf_counter`)."""

    def __init__(self):
        self.values = np.full(len(MPC_STAMPS), np.nan)
        self._index = {name: k for k, name in enumerate(MPC_STAMPS)}

    def mark(self, name: str) -> None:
        self.values[self._index[name]] = time.perf_counter()

    def start(self) -> None:
        self.values[:] = np.nan
        self.values[0] = time.perf_counter()


def segments(solver_stamps: np.ndarray, solve_s: float, loop_stamps, delay_s: float) -> np.ndarray:
    """SEGMENTS (ms) of one step: `solver_stamps` (SOLVER_STAMPS, from the plan), the solver's own `solve_s`,
    the loop's (measured, sent, woken, noticed, taken) stamps (`measured`: the wall time of the plant's time
    of the measurement) and the plan's delay (their sum). A stamp the step did not reach (NaN: a stand-in MPC
    without stamps) leaves its segments NaN and the rest in `to_plant`."""
    s = {name: float(solver_stamps[k]) for k, name in enumerate(SOLVER_STAMPS)}
    measured, sent, woken, noticed, taken = loop_stamps
    woken = min(max(woken, s["answered"]), noticed) if np.isfinite(s["answered"]) else woken
    parts = [sent - measured, s["received"] - sent, s["start"] - s["received"], s["predicted"] - s["start"],
             s["prepared"] - s["predicted"], s["solved"] - s["prepared"] - solve_s, solve_s,
             s["unpacked"] - s["solved"], s["end"] - s["unpacked"], s["answered"] - s["end"],
             woken - s["answered"], noticed - woken, taken - noticed]
    out = 1e3 * np.array(parts + [0.0])
    out[-1] = 1e3 * delay_s - np.nansum(out[:-1])
    return out


def summary(rows: np.ndarray) -> dict[str, dict[str, float]]:
    """{segment: {"mean", "p95", "max"}} (ms) over a run's rows (SEGMENTS each); {} without rows."""
    rows = np.asarray(rows, dtype=float).reshape(-1, len(SEGMENTS))
    if not rows.shape[0]:
        return {}
    out = {}
    for k, name in enumerate(SEGMENTS):
        column = rows[:, k][np.isfinite(rows[:, k])]
        if column.size:
            out[name] = {"mean": float(np.mean(column)), "p95": float(np.percentile(column, 95)),
                         "max": float(np.max(column))}
    return out
