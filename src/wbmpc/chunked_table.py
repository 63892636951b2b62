"""`ChunkedTable`: rows of fixed-shape numeric columns in bounded memory, however many rows.

Rows go into one preallocated chunk of `chunk_rows` rows per column; a full chunk is written to
`.npy` files (one per column) in a spill directory and its buffer reused, so the memory held is
one chunk whatever the length of the run. Readers stream the chunks back in order
(`iter_chunks`), take every k-th row (`column(name, every=k)`, for plots and replays) or the
whole column (`column(name)`). The spill directory is a temporary one unless given, and is
removed with the table (`close()`, or when the table is garbage collected).
"""

from __future__ import annotations

import shutil
import tempfile
import weakref
from pathlib import Path
from typing import Iterator

import numpy as np

from wbmpc.errors import ConfigError

DEFAULT_CHUNK_ROWS = 5000  # 10 s of 500 Hz control ticks


class ChunkedTable:
    """Append-only table; `columns` maps a name to (row shape, dtype), e.g. {"q": ((26,), float)}."""

    def __init__(self, columns: dict[str, tuple[tuple[int, ...], type]], chunk_rows: int = DEFAULT_CHUNK_ROWS,
                 spill_dir: str | Path | None = None, name: str = "table"):
        if chunk_rows < 1:
            raise ConfigError(f"chunk_rows must be >= 1, got {chunk_rows}")
        self.columns = {key: (tuple(shape), np.dtype(dtype)) for key, (shape, dtype) in columns.items()}
        self.chunk_rows = int(chunk_rows)
        self.name = name
        self._buffers = {key: np.empty((self.chunk_rows, *shape), dtype) for key, (shape, dtype) in self.columns.items()}
        self._fill = 0  # rows in the live chunk
        self._spilled_chunks = 0
        self._spill_root = None if spill_dir is None else Path(spill_dir)
        self._spill_dir: Path | None = None
        self._finalizer: weakref.finalize | None = None

    # ------------------------------------------------------------------ writing
    def append(self, row: dict) -> None:
        """Add one row: a value for every column (anything NumPy can cast to the column's shape)."""
        k = self._fill
        buffers = self._buffers
        for key in self.columns:
            buffers[key][k] = row[key]
        self._fill = k + 1
        if self._fill == self.chunk_rows:
            self._spill()

    def _spill(self) -> None:
        folder = self._folder()
        index = self._spilled_chunks
        for key, buffer in self._buffers.items():
            np.save(folder / f"{index:06d}_{key}.npy", buffer[: self._fill], allow_pickle=False)
        self._spilled_chunks += 1
        self._fill = 0

    def _folder(self) -> Path:
        if self._spill_dir is None:
            if self._spill_root is not None:
                self._spill_root.mkdir(parents=True, exist_ok=True)
            self._spill_dir = Path(tempfile.mkdtemp(prefix=f"wbmpc-{self.name}-", dir=self._spill_root))
            self._finalizer = weakref.finalize(self, shutil.rmtree, str(self._spill_dir), True)
        return self._spill_dir

    def close(self) -> None:
        """Delete the spilled chunks (the table is empty afterwards)."""
        if self._finalizer is not None:
            self._finalizer()
        self._spill_dir, self._finalizer = None, None
        self._spilled_chunks, self._fill = 0, 0

    # ------------------------------------------------------------------ reading
    def __len__(self) -> int:
        return self._spilled_chunks * self.chunk_rows + self._fill

    @property
    def spilled_chunks(self) -> int:
        return self._spilled_chunks

    @property
    def spill_dir(self) -> Path | None:
        return self._spill_dir

    def last(self, key: str) -> np.ndarray:
        """The last row of a column (a copy)."""
        if not len(self):
            raise IndexError(f"{self.name} is empty")
        if self._fill:
            return self._buffers[key][self._fill - 1].copy()
        return np.load(self._chunk_path(self._spilled_chunks - 1, key))[-1].copy()

    def first(self, key: str) -> np.ndarray:
        if not len(self):
            raise IndexError(f"{self.name} is empty")
        if self._spilled_chunks:
            return np.load(self._chunk_path(0, key), mmap_mode="r")[0].copy()
        return self._buffers[key][0].copy()

    def _chunk_path(self, index: int, key: str) -> Path:
        return self._spill_dir / f"{index:06d}_{key}.npy"

    def iter_chunks(self, keys: tuple[str, ...] | None = None) -> Iterator[dict[str, np.ndarray]]:
        """The rows in order, one chunk at a time: {column: (rows of the chunk, *shape)} (the live chunk as copies)."""
        keys = tuple(self.columns) if keys is None else tuple(keys)
        self._check(keys)
        for index in range(self._spilled_chunks):
            yield {key: np.load(self._chunk_path(index, key)) for key in keys}
        if self._fill:
            yield {key: self._buffers[key][: self._fill].copy() for key in keys}

    def column(self, key: str, every: int = 1) -> np.ndarray:
        """The whole column (every `every`-th row, counted from the first), read back from the spilled chunks."""
        self._check((key,))
        if every < 1:
            raise ConfigError(f"every must be >= 1, got {every}")
        shape, dtype = self.columns[key]
        n = len(self)
        out = np.empty(((n + every - 1) // every, *shape), dtype)
        written, start = 0, 0  # `start`: the table row of the chunk's first row
        for chunk in self.iter_chunks((key,)):
            rows = chunk[key]
            offset = (-start) % every
            picked = rows[offset::every]
            out[written : written + len(picked)] = picked
            written += len(picked)
            start += len(rows)
        return out

    def _check(self, keys) -> None:
        unknown = [key for key in keys if key not in self.columns]
        if unknown:
            raise ConfigError(f"{self.name} has no column {unknown}; it has {', '.join(self.columns)}")

    @property
    def nbytes_in_memory(self) -> int:
        """Bytes of the preallocated chunk buffers (what the table holds in memory)."""
        return sum(buffer.nbytes for buffer in self._buffers.values())
