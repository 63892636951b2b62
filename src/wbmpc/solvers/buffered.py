"""CasADi Functions called on preallocated NumPy arrays, for the MPC's hot path.

A plain call `f(x, p)` converts every NumPy argument to a DM and every result back (CasADi's
Python `DM.full()` goes through a Python list): about 0.1 ms per 1000 numbers, ~13 times per MPC
step. `Function.buffer()` evaluates on memory the caller owns instead; `BufferedFunction` keeps
one NumPy array per input and output (their nonzeros, column-major) bound to such a buffer.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


class BufferedFunction:
    """`f(*args)` writes the args into bound input arrays, evaluates, returns the output arrays.

    Inputs are dense arrays of the input's shape (or its nonzeros) or None (the input's default, as
    in a plain call: e.g. zero initial multipliers of an nlpsol). Outputs are the bound arrays themselves — the next call overwrites them — as
    nonzero vectors, or matrices of the output's shape with `shaped=True` (dense outputs only).
    """

    def __init__(self, function: ca.Function):
        self.function = function
        self._buffer, self._evaluate = function.buffer()
        self.inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self.outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        for i, array in enumerate(self.inputs):
            self._buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self.outputs):
            self._buffer.set_res(i, memoryview(array))
        self._defaults = [function.default_in(i) for i in range(function.n_in())]
        self._dense_out = [function.sparsity_out(i).is_dense() for i in range(function.n_out())]
        self._shapes_out = [function.size_out(i) for i in range(function.n_out())]

    def __call__(self, *args, shaped: bool = False) -> list[np.ndarray]:
        if len(args) > len(self.inputs):
            raise TypeError(f"CasADi function '{self.function.name()}' takes {len(self.inputs)} inputs, got {len(args)}")
        for i, target in enumerate(self.inputs):
            value = args[i] if i < len(args) else None
            if value is None:
                target[:] = self._defaults[i]
                continue
            target[:] = np.asarray(value, dtype=float).ravel(order="F")  # CasADi stores matrices column-major
        self.evaluate()
        if not shaped:
            return self.outputs
        return [array.reshape(shape, order="F") if dense else array
                for array, dense, shape in zip(self.outputs, self._dense_out, self._shapes_out)]

    def evaluate(self) -> list[np.ndarray]:
        """Evaluate on the bound `inputs` as they are (for a caller that writes them in place); the outputs."""
        self._evaluate()
        if self._buffer.ret() != 0:
            raise RuntimeError(f"evaluation of CasADi function '{self.function.name()}' failed "
                               f"(return code {self._buffer.ret()})")
        return self.outputs

    def stats(self) -> dict:
        """Statistics of the last evaluation (solvers: iterations, status, timings)."""
        return self._buffer.stats()
