"""Velocity-level frictional contact problem for point contacts (time stepping, Stewart-Trinkle style).

Given the Delassus matrix G = J M^-1 J^T (3k x 3k, rows [t1, t2, n] per contact) and the free
velocity g (contact velocities without impulses; normal rows include the gap term), find the
impulses lam such that, for every contact i, with w = G lam + g:
    0 <= lam_n  _|_  w_n >= 0                                  (unilateral, no penetration)
    ||lam_t|| <= mu lam_n, and lam_t = -mu lam_n w_t/||w_t|| if w_t != 0   (Coulomb, max. dissipation)
Method: an active-set iteration over contact modes (open / stick / slide with a direction), one
small linear solve per iteration, exact when it settles (typically 1-3 solves: 1 when standing);
a warm-started projected Gauss-Seidel is the fallback when the modes cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OPEN, STICK, SLIDE = 0, 1, 2


@dataclass(frozen=True)
class ContactSolution:
    """Impulses (N s, rows [t1, t2, n] per contact), contact modes (OPEN/STICK/SLIDE) and sliding
    directions of the friction force (unit 2-vectors) to warm-start the next step, and how the
    problem was solved: method 'none' | 'active_set' | 'pgs' with its iteration count."""

    impulses: np.ndarray
    modes: np.ndarray
    directions: np.ndarray
    method: str
    iterations: int


def solve_contact_impulses(
    G: np.ndarray,
    g: np.ndarray,
    mu: float,
    warm_start: ContactSolution | None = None,
    max_iterations: int = 100,
    tolerance: float = 1e-7,
) -> ContactSolution:
    """Solve the problem above; `warm_start` (same contacts) gives initial modes and impulses."""
    k = g.size // 3
    if k == 0:
        return ContactSolution(np.zeros(0), np.zeros(0, int), np.zeros((0, 2)), "none", 0)
    if warm_start is None or warm_start.modes.size != k:
        warm_start = ContactSolution(np.zeros(3 * k), np.full(k, STICK), np.zeros((k, 2)), "none", 0)
    G = G + (1e-12 * np.trace(G) / g.size) * np.eye(g.size)
    modes, dirs = warm_start.modes.copy(), warm_start.directions.copy()
    lam, iterations = _active_set(G, g, mu, modes, dirs, max_iterations=4 * k + 8)
    if lam is not None:
        return ContactSolution(lam, modes, dirs, "active_set", iterations)
    lam, sweeps = _pgs(G, g, mu, warm_start.impulses, max_iterations, tolerance)
    modes, dirs = _modes_of(lam, G @ lam + g, mu)
    return ContactSolution(lam, modes, dirs, "pgs", sweeps)


def _active_set(
    G: np.ndarray, g: np.ndarray, mu: float, modes: np.ndarray, dirs: np.ndarray, max_iterations: int
) -> tuple[np.ndarray | None, int]:
    """Mode iteration; `modes` and `dirs` are updated in place. None if it does not settle."""
    k = g.size // 3
    for it in range(1, max_iterations + 1):
        A, b = np.zeros_like(G), np.zeros_like(g)
        for i in range(k):
            s = 3 * i
            if modes[i] == OPEN:
                A[s : s + 3, s : s + 3] = np.eye(3)
            elif modes[i] == STICK:
                A[s : s + 3], b[s : s + 3] = G[s : s + 3], -g[s : s + 3]
            else:  # slide: w_n = 0 and lam_t = mu lam_n d
                A[s + 2], b[s + 2] = G[s + 2], -g[s + 2]
                A[s : s + 2, s : s + 2] = np.eye(2)
                A[s : s + 2, s + 2] = -mu * dirs[i]
        try:
            lam = np.linalg.solve(A, b)
        except np.linalg.LinAlgError:
            return None, it
        w = G @ lam + g
        lam_tol = 1e-9 * max(1e-6, float(np.abs(lam).max()))
        w_tol = 1e-9 * max(1e-6, float(np.abs(g).max()))
        changed = False
        for i in range(k):
            s = 3 * i
            lam_t, lam_n, w_t = lam[s : s + 2], lam[s + 2], w[s : s + 2]
            if modes[i] == OPEN:
                if w[s + 2] < -w_tol:
                    modes[i], changed = STICK, True
            elif lam_n < -lam_tol:
                modes[i], changed = OPEN, True
            elif modes[i] == STICK:
                norm_t = float(np.hypot(*lam_t))
                if norm_t > mu * lam_n + lam_tol:
                    modes[i], dirs[i], changed = SLIDE, lam_t / norm_t, True
            else:
                slip = float(np.hypot(*w_t))
                if slip > w_tol:
                    new_dir = -w_t / slip
                    if new_dir @ dirs[i] < 0:  # slipping along the friction force: it must stick
                        modes[i], changed = STICK, True
                    elif np.abs(new_dir - dirs[i]).max() > 1e-4:
                        dirs[i], changed = new_dir, True
        if not changed:
            return lam, it
    return None, max_iterations


def _pgs(
    G: np.ndarray, g: np.ndarray, mu: float, lam0: np.ndarray | None, max_iterations: int, tolerance: float
) -> tuple[np.ndarray, int]:
    """Projected Gauss-Seidel, one 3-row block per contact (normal first, then the friction disc)."""
    k = g.size // 3
    lam = np.zeros_like(g) if lam0 is None or lam0.size != g.size else _project(lam0.astype(float), mu)
    rows = [G[3 * i : 3 * i + 3] for i in range(k)]
    inv_tt = [np.linalg.inv(G[3 * i : 3 * i + 2, 3 * i : 3 * i + 2]) for i in range(k)]
    scale = max(float(np.abs(g).max()), 1e-12)
    sweep = 0
    for sweep in range(1, max_iterations + 1):
        change = 0.0
        for i in range(k):
            s = 3 * i
            w = rows[i] @ lam + g[s : s + 3]
            old = lam[s : s + 3].copy()
            lam_n = max(0.0, old[2] - w[2] / G[s + 2, s + 2])
            w_t = w[:2] + G[s : s + 2, s + 2] * (lam_n - old[2])
            lam_t = old[:2] - inv_tt[i] @ w_t
            norm_t = float(np.hypot(*lam_t))
            if norm_t > mu * lam_n:
                lam_t *= mu * lam_n / norm_t
            lam[s : s + 2], lam[s + 2] = lam_t, lam_n
            change = max(change, float(np.abs(lam[s : s + 3] - old).max()) * G[s + 2, s + 2])
        if change < tolerance * scale:
            break
    return lam, sweep


def _modes_of(lam: np.ndarray, w: np.ndarray, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """Contact modes and friction directions read from a solution (to warm-start the next step)."""
    lam3, w3 = lam.reshape(-1, 3), w.reshape(-1, 3)
    scale = 1e-6 * max(1e-9, float(np.abs(lam).max()))
    slip = np.hypot(w3[:, 0], w3[:, 1])
    modes = np.where(lam3[:, 2] <= scale, OPEN, np.where(slip > 1e-6, SLIDE, STICK))
    dirs = -w3[:, :2] / np.maximum(slip, 1e-300)[:, None]
    return modes, dirs


def _project(lam: np.ndarray, mu: float) -> np.ndarray:
    """Project stacked 3-vectors onto the friction cones (normal clipped, tangential scaled)."""
    lam3 = lam.reshape(-1, 3)
    lam3[:, 2] = np.maximum(lam3[:, 2], 0.0)
    norm = np.hypot(lam3[:, 0], lam3[:, 1])
    over = norm > mu * lam3[:, 2]
    lam3[over, :2] *= (mu * lam3[over, 2] / np.maximum(norm[over], 1e-300))[:, None]
    return lam
