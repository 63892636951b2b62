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

    def block(self, name: str) -> slice:
        """Where block `name` sits in p (its values column-major, as `pack` writes them)."""
        return self._slices[name]

    def write(self, p: np.ndarray, name: str, value) -> None:
        """Block `name` of `p` set to `value` in place (as `pack` lays it out)."""
        rows, cols = self._shapes[name]
        value = np.asarray(value, dtype=float)
        if value.size != rows * cols:
            raise ConfigError(f"parameter '{name}' needs {(rows, cols)} values, got {value.shape}")
        p[self._slices[name]] = value.ravel() if cols == 1 else value.reshape(rows, cols).ravel(order="F")

    def template(self, constant: dict[str, np.ndarray]) -> np.ndarray:
        """p with the `constant` blocks packed and every other block zero, for a caller that writes those each step
        (`write`, or `block`'s slices on its hot path) instead of packing every block again."""
        out = np.zeros(self._size)
        for name, value in constant.items():
            self.write(out, name, value)
        return out

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
