"""Named CasADi parameters packed into one flat vector `p` (everything that changes between steps)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError


class ParameterPack:
    """Allocates named SX parameter blocks and packs numeric values in the same order."""

    def __init__(self):
        self._symbols: dict[str, ca.SX] = {}
        self._slices: dict[str, slice] = {}
        self._shapes: dict[str, tuple[int, int]] = {}  # (rows, cols) of each block, read by `pack` every step
        self._size = 0

    def add(self, name: str, rows: int, cols: int = 1) -> ca.SX:
        symbol = ca.SX.sym(name, rows, cols)
        self._symbols[name] = symbol
        self._slices[name] = slice(self._size, self._size + rows * cols)
        self._shapes[name] = (rows, cols)
        self._size += rows * cols
        return symbol

    def __getitem__(self, name: str) -> ca.SX:
        return self._symbols[name]

    @property
    def names(self) -> list[str]:
        return list(self._symbols)

    def shape(self, name: str) -> tuple[int, int]:
        return self._shapes[name]

    def select(self, p, name: str, column: int | None = None):
        """Block `name` (flattened column-major) of a flat parameter vector `p` (SX or MX), or one
        of its columns."""
        block = self._slices[name]
        if column is None:
            return p[block.start : block.stop]
        rows = self._symbols[name].shape[0]
        start = block.start + column * rows
        return p[start : start + rows]

    @property
    def size(self) -> int:
        return self._size

    @property
    def vector(self) -> ca.SX:
        return ca.vertcat(*[ca.vec(s) for s in self._symbols.values()])

    def pack(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """Flat numeric p; matrices are stored column-major like casadi.vec."""
        out = np.empty(self._size)
        for name, shape in self._shapes.items():  # (shapes kept as numbers: CasADi's size queries cost microseconds)
            if name not in values:
                raise ConfigError(f"parameter '{name}' has no value")
            value = np.asarray(values[name], dtype=float)
            if value.size != shape[0] * shape[1]:
                raise ConfigError(f"parameter '{name}' needs {shape} values, got {value.shape}")
            out[self._slices[name]] = value.ravel() if shape[1] == 1 else value.reshape(shape).ravel(order="F")
        return out
