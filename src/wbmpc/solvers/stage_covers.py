"""Stage kinds whose derivatives another kind's generated code already computes (a "cover").

The OCP's first stage is the torque stages' kind without the foot rows and with the linear x0 rows (x_0 = the
measured state): same cost, same transition, the same RNEA and wrench-cone rows. Its Lagrangian Hessian is the
torque kind's with zero multipliers on the foot rows (their terms vanish), and its rows' Jacobian is the torque
kind's columns of the shared rows next to the x0 rows' constant ones. So its Hessian and Jacobian need no code of
their own: two small C wrappers call the cover's (`wrappers`). Per Fatrop iteration each core fetches every kind's
machine code once from memory (g1: 1.1 MB for the first stage's Hessian, 0.7 MB for its Jacobian, used by one
stage); without them the first stage reuses the torque kind's code fetched for stages 1 and 2.

`find_cover` accepts a cover only if the kinds have the same sizes, every row tag of the kind is one of the
cover's (same size) or linear in (u, x) (proved symbolically), and the transition, cost and shared rows agree at
random points to 1e-12 (the same expressions built twice by the same formulation code).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

AGREEMENT = 1e-12  # relative difference of the kinds' shared outputs at the random points
N_POINTS = 3


@dataclass(frozen=True)
class Cover:
    """Kind `kind`'s Hessian and Jacobian from kind `cover`'s: its path row i is the cover's row `rows[i]`, or
    (-1) a linear row whose transposed Jacobian column has the constant nonzeros `linear[i]` ((place, value)
    pairs in the column of length n_u + n_x)."""

    kind: int
    cover: int
    rows: tuple[int, ...]
    linear: dict[int, tuple[tuple[int, float], ...]]
    n_z: int
    cover_rows: int


def _symbols(function: ca.Function):
    x, u, p = (ca.SX.sym(name, function.size1_in(i)) for i, name in ((0, "x"), (1, "u"), (2, "p")))
    return x, u, p


def _row_map(tags: list[tuple[str, int]], cover_tags: list[tuple[str, int]]) -> list[int] | None:
    """Each row of `tags` as a row of `cover_tags` (-1: not there); None if a tag is there with another size."""
    starts, start = {}, 0
    for name, size in cover_tags:
        starts.setdefault(name, []).append((start, size))
        start += size
    rows = []
    for name, size in tags:
        found = starts.get(name, [])
        if found and found[0][1] != size:
            return None
        first = found.pop(0)[0] if found else None
        rows += list(range(first, first + size)) if first is not None else [-1] * size
    return rows


def find_cover(kind: int, function: ca.Function, tags, cover: int, cover_function: ca.Function, cover_tags,
               seed: int = 0) -> Cover | None:
    """The cover of `kind` by `cover` if it is one (module docstring), else None."""
    if any(function.size1_in(i) != cover_function.size1_in(i) for i in range(3)) or \
            function.size1_out(0) != cover_function.size1_out(0):
        return None
    rows = _row_map(tags, cover_tags)
    if rows is None or all(r < 0 for r in rows):
        return None
    x, u, p = _symbols(function)
    z = ca.vertcat(u, x)
    own = [i for i, r in enumerate(rows) if r < 0]
    path = function(x, u, p)[1]
    jacobian = ca.jacobian(path[own], z) if own else ca.SX(0, z.shape[0])
    if ca.depends_on(jacobian, ca.vertcat(z, p)):
        return None  # a row of its own is not linear in (u, x)
    shared = [i for i, r in enumerate(rows) if r >= 0]
    rng = np.random.default_rng(seed)
    for _ in range(N_POINTS):
        point = [rng.normal(size=function.size1_in(i)) for i in range(3)]
        mine, theirs = function(*point), cover_function(*point)
        pairs = [(mine[0], theirs[0]), (mine[2], theirs[2]),
                 (np.asarray(mine[1]).ravel()[shared], np.asarray(theirs[1]).ravel()[[rows[i] for i in shared]])]
        for a, b in pairs:
            a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
            if not np.all(np.abs(a - b) <= AGREEMENT * np.maximum(1.0, np.abs(b))):
                return None
    constant = np.array(ca.evalf(ca.densify(jacobian))) if own else np.zeros((0, z.shape[0]))
    linear = {i: tuple((int(j), float(constant[n, j])) for j in np.flatnonzero(constant[n])) for n, i in enumerate(own)}
    return Cover(kind, cover, tuple(rows), linear, z.shape[0], cover_function.size1_out(1))


def find_covers(stages: list[tuple[ca.Function, list[tuple[str, int]]]]) -> dict[int, Cover]:
    """Each stage kind's cover (`find_cover`) by a kind with code of its own, where there is one."""
    covers: dict[int, Cover] = {}
    for kind, (function, tags) in enumerate(stages):
        for other, (cover_function, cover_tags) in enumerate(stages):
            if other == kind or other in covers or any(c.cover == kind for c in covers.values()):
                continue
            found = find_cover(kind, function, tags, other, cover_function, cover_tags)
            if found is not None:
                covers[kind] = found
                break
    return covers


def wrappers(cover: Cover, jac_work: int) -> str:
    """C of `wbk<kind>_hess` and `wbk<kind>_jac` calling the cover's: the multipliers scattered to the cover's rows
    (zeros on the rows the kind does not have: `wbk<kind>_cover_lam`); the Jacobian's shared columns copied from the
    cover's, computed into the work array past the cover's own `jac_work` doubles, the linear rows' columns set from
    constants (`wbk<kind>_cover_rows`). The shim calls the two adapters itself where it evaluates the kind's stages in
    a lane of the cover's lane functions (stage_vectors.py)."""
    k, c, n = cover.kind, cover.cover, cover.n_z
    rows = ", ".join(str(r) for r in cover.rows) or "0"
    places = [place for i in sorted(cover.linear) for place, _ in cover.linear[i]]
    values = [repr(value) for i in sorted(cover.linear) for _, value in cover.linear[i]]
    starts = np.cumsum([0] + [len(cover.linear.get(i, ())) if r < 0 else 0 for i, r in enumerate(cover.rows)])
    return f"""
/* ---- wbmpc: stage kind {k}'s Hessian and Jacobian are kind {c}'s (solvers/stage_covers.py) ---- */
static const int wbk{k}_rows[] = {{{rows}}};
static const int wbk{k}_linear_start[] = {{{', '.join(str(s) for s in starts)}}};
static const int wbk{k}_linear_place[] = {{{', '.join(str(p) for p in places) or '0'}}};
static const casadi_real wbk{k}_linear_value[] = {{{', '.join(values) or '0'}}};
/* the kind's row multipliers (NULL: zeros) as the cover's ({cover.cover_rows} rows) */
void wbk{k}_cover_lam(const casadi_real* lam, casadi_real* cover_lam) {{
  int i;
  memset(cover_lam, 0, sizeof(casadi_real) * {max(cover.cover_rows, 1)});
  for (i = 0; i < {len(cover.rows)}; ++i)
    if (wbk{k}_rows[i] >= 0) cover_lam[wbk{k}_rows[i]] = lam ? lam[i] : 0;
}}
/* the kind's transposed row Jacobian from the cover's ({n} x {cover.cover_rows}, column-major) */
void wbk{k}_cover_rows(const casadi_real* cover_rows, casadi_real* rows) {{
  int i, j;
  for (i = 0; i < {len(cover.rows)}; ++i) {{
    casadi_real* column = rows + (size_t) i * {n};
    if (wbk{k}_rows[i] >= 0) {{
      memcpy(column, cover_rows + (size_t) wbk{k}_rows[i] * {n}, sizeof(casadi_real) * {n});
      continue;
    }}
    memset(column, 0, sizeof(casadi_real) * {n});
    for (j = wbk{k}_linear_start[i]; j < wbk{k}_linear_start[i + 1]; ++j)
      column[wbk{k}_linear_place[j]] = wbk{k}_linear_value[j];
  }}
}}
int wbk{k}_hess(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem) {{
  casadi_real lam[{max(cover.cover_rows, 1)}];
  const casadi_real* cover_arg[6];
  int i;
  wbk{k}_cover_lam(arg[5], lam);
  for (i = 0; i < 5; ++i) cover_arg[i] = arg[i];
  cover_arg[5] = lam;
  return wbk{c}_hess(cover_arg, res, iw, w, mem);
}}
int wbk{k}_jac(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem) {{
  casadi_real* cover_rows = w + {jac_work};
  casadi_real* cover_res[2];
  int flag;
  cover_res[0] = res[0];
  cover_res[1] = cover_rows;
  flag = wbk{c}_jac(arg, cover_res, iw, w, mem);
  wbk{k}_cover_rows(cover_rows, res[1]);
  return flag;
}}
"""
