"""Solvers on the stage-wise OCP: `make_solver` picks Fatrop/IPOPT (`nlp.py`), RTI (`rti.py`) or Fatrop
through its C interface (`fatrop_direct.py`).

Each solver puts the fast BLASFEO under Fatrop and HPIPM (where `wbmpc setup` installed and verified it, see
`blasfeo.py`) before it loads either; importing this package changes nothing.
"""

from __future__ import annotations


def make_solver(problem, config):
    """The solver `config.name` names, built once for `problem` (NlpSolver, RtiSolver, AnytimeSqpSolver or
    FatropDirectSolver)."""
    if config.name == "fatrop-direct":
        from wbmpc.solvers.fatrop_direct import FatropDirectSolver

        return FatropDirectSolver(problem, config)
    if config.name == "sqp":
        from wbmpc.solvers.anytime import AnytimeSqpSolver

        return AnytimeSqpSolver(problem, config)
    if config.name == "rti":
        from wbmpc.solvers.rti import RtiSolver

        return RtiSolver(problem, config)
    from wbmpc.solvers.nlp import NlpSolver

    return NlpSolver(problem, config)
