"""The deploy loop's tick: `DeployPhase`, the phase it is in, and `DeployTick`, what it tells its tick listeners
after each valid LowState (an operator's remote read from the LowState's bytes, a live page drawing the estimate
and the plan)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DeployTick:
    """Robot time, MPC time (None before the MPC phase), the LowState, the estimate, the plan in use (None before
    the first) and the phase."""

    t_s: float
    t_mpc_s: float | None
    msg: object
    q: np.ndarray
    v: np.ndarray
    plan: object
    phase: str | None


@dataclass
class DeployPhase:
    """The deploy loop's phase (stand-up, hold, mpc, lie-down, damping), when it started and the pose it started
    from."""

    name: str | None = None
    t0: float = 0.0
    pose_start: np.ndarray | None = None
