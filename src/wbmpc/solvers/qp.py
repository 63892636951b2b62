"""The structured QP of one SQP iteration on the stage-wise OCP, solved by HPIPM.

The QP in the step d = x - x_lin (eq. 1 linearised at x_lin):

    min 1/2 d' H d + grad_f' d   s.t.  lbg - g <= J d <= ubg - g,  lbx - x_lin <= d <= ubx - x_lin

keeps the OCP's stage structure: variables (x_0, u_0, x_1, ...), per stage the gap rows
d_{k+1} - A_k d_k - B_k du_k = -gap_k then the path rows C_k d_k + D_k du_k, a block-diagonal H.
HPIPM (through CasADi's `conic('hpipm')`, which splits J and H into those blocks once) solves it
with a Riccati-based interior-point method whose cost is linear in the number of nodes. HPIPM
uses the BLASFEO that CasADi loads: run with the AVX2 build on the library path for speed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers import blasfeo

HPIPM_MODES = ("speed_abs", "speed", "balance", "robust")
HPIPM_STATUS = {0: "Solve_Succeeded", 1: "QP_Maximum_Iterations_Exceeded", 2: "QP_Minimum_Step_Length",
                3: "QP_NaN_In_Computations"}


@dataclass(frozen=True)
class QpConfig:
    """HPIPM settings. Tolerances of 1e-6 on every residual: HPIPM's defaults (1e-8 on the
    complementarity) cost up to 100 interior-point iterations on this problem from a cold start."""

    mode: str = "speed"
    tolerance: float = 1e-6
    max_iterations: int = 100
    infinity: float = 1e8  # bounds beyond this are treated as absent
    # initial barrier mu0 and the primal guess (d = 0: the linearisation point) as HPIPM's starting point:
    # 4.0 instead of 5.4 interior-point iterations per closed-loop trot step (mu0 10 -> 100; 1e3 and up: more)
    barrier_init: float = 100.0
    warm_start: bool = True
    hpipm_options: dict = field(default_factory=dict)  # further HPIPM arguments (mu0, warm_start, ...)
    # our binding (solvers/hpipm_direct.py) leaves inputs with lb == ub and the initial state out of HPIPM's QP
    # (csrc/hpipm_reduce.c: same QP, smaller Riccati blocks); casadi's conic keeps them
    eliminate_fixed: bool = True
    # our binding first tries the active-set guess "no inequality active": the equality rows eliminated, one Riccati
    # factorisation, the dropped inequalities checked (csrc/hpipm_eqelim.c); HPIPM's interior point where one is violated
    active_set_guess: bool = True

    def __post_init__(self):
        if self.mode not in HPIPM_MODES:
            raise ConfigError(f"unknown HPIPM mode '{self.mode}'; available modes: {', '.join(HPIPM_MODES)}")
        if not self.tolerance > 0:
            raise ConfigError(f"QP tolerance must be positive, got {self.tolerance}")
        if self.max_iterations < 1:
            raise ConfigError(f"QP max_iterations must be >= 1, got {self.max_iterations}")


@dataclass
class QpResult:
    step: np.ndarray  # d
    lam_g: np.ndarray  # multipliers of the linearised constraints (CasADi's sign convention)
    lam_x: np.ndarray
    status: str
    success: bool
    iterations: int
    solve_time_s: float
    pack_s: float = 0.0  # of solve_time_s, the binding's Python around its C call (which loads, solves, unpacks)


def stage_dimensions(problem: OcpProblem) -> dict[str, list[int]]:
    """HPIPM's N, nx, nu, ng (path rows) per stage of the OCP's variable and row order."""
    N = problem.N
    nu = [problem.stage_slices[k][1].stop - problem.stage_slices[k][1].start for k in range(N)]
    ng = [problem.stage_function(k)[0].size1_out(1) for k in range(N + 1)]
    return {"N": N, "nx": [problem.nx] * (N + 1), "nu": nu + [0], "ng": ng}


class StructuredQp:
    """One HPIPM conic for the sparsity of (H, J) of an OCP, built once; `solve` is numeric only."""

    def __init__(self, problem: OcpProblem, hessian: ca.Sparsity, jacobian: ca.Sparsity, config: QpConfig = QpConfig()):
        self.config = config
        dims = stage_dimensions(problem)
        if jacobian.shape != (problem.n_constraints, problem.n_variables) or hessian.shape != (problem.n_variables,) * 2:
            raise ConfigError(f"QP matrices of shape {hessian.shape} / {jacobian.shape} do not fit the OCP "
                              f"({problem.n_variables} variables, {problem.n_constraints} constraints)")
        tol = config.tolerance
        options = {
            **dims, "inf": config.infinity, "error_on_fail": False, "print_time": False,
            "hpipm": {"mode": config.mode, "iter_max": config.max_iterations, "res_g_max": tol, "res_b_max": tol,
                      "res_d_max": tol, "res_m_max": tol, "mu0": config.barrier_init,
                      "warm_start": int(config.warm_start), **config.hpipm_options},
        }
        blasfeo.activate()  # before casadi loads the HPIPM plugin (and its BLASFEO)
        self.conic = ca.conic("ocp_qp_hpipm", "hpipm", {"h": hessian, "a": jacobian}, options)
        self.hessian_sparsity, self.jacobian_sparsity = hessian, jacobian

    def solve(self, H, gradient, J, lbg, ubg, lbx, ubx) -> QpResult:
        """Bounds are on the step (already shifted by the linearisation point's g and x)."""
        start = time.perf_counter()
        out = self.conic(h=H, g=gradient, a=J, lba=lbg, uba=ubg, lbx=lbx, ubx=ubx)
        elapsed = time.perf_counter() - start
        stats = self.conic.stats()
        flag = int(stats.get("return_status", -1))
        step = np.asarray(out["x"]).ravel()
        success = flag == 0 and bool(np.all(np.isfinite(step)))
        return QpResult(step=step, lam_g=np.asarray(out["lam_a"]).ravel(), lam_x=np.asarray(out["lam_x"]).ravel(),
                        status=HPIPM_STATUS.get(flag, f"hpipm_flag_{flag}"), success=success,
                        iterations=int(stats.get("iter_count", -1)), solve_time_s=elapsed)
