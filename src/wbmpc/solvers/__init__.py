"""NLP solvers on the stage-wise OCP: `make_solver` picks Fatrop/IPOPT (`nlp.py`) or RTI (`rti.py`)."""

from __future__ import annotations


def make_solver(problem, config):
    """The solver `config.name` names, built once for `problem` (NlpSolver or RtiSolver)."""
    if config.name == "rti":
        from wbmpc.solvers.rti import RtiSolver

        return RtiSolver(problem, config)
    from wbmpc.solvers.nlp import NlpSolver

    return NlpSolver(problem, config)
