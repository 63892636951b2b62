"""`ChunkedTable`: rows of fixed-shape numeric columns in bounded memory, however many rows.

Rows go into one preallocated chunk of `chunk_rows` rows per column; a full chunk is written to
`.npy` files (one per column) in a spill directory and its buffer reused, so the memory held is
one chunk whatever the length of the run. Readers stream the chunks back in order
(`iter_chunks`), take every k-th row (`column(name, every=k)`, for plots and replays) or the
whole column (`column(name)`). The spill directory is a temporary one unless given, and is
removed with the table (`close()`, or when the table is garbage collected).

With a `ChunkWriter` the full chunk is written by the writer's own thread while rows go on into a
second buffer: a real-time loop appending its ticks never waits for the disk (a 5000-row chunk of
g1's ticks is ~6 MB). The memory held is then at most two chunks; readers wait for the writes in
flight, so what they read is the same, bit for bit.
"""

from __future__ import annotations

import queue
import shutil
import tempfile
import threading
import weakref
from pathlib import Path
from typing import Iterator

import numpy as np

from wbmpc.errors import ConfigError

DEFAULT_CHUNK_ROWS = 5000  # 10 s of 500 Hz control ticks
WRITER_IDLE_S = 30.0  # a chunk writer's thread ends after this long without a chunk (a run's come every 10 s)


class ChunkWriter:
    """A thread that writes the chunks of one or more tables, in the order they were handed over.

    The thread starts with the first chunk handed over (or `start()`) and ends `idle_s` after the last one (a short
    run never starts it, a campaign's many runs leave none behind); `flush()` waits until every chunk handed over is on disk. NumPy writes
    a chunk's data with the GIL released (`ndarray.tofile`), so the thread appending rows runs on meanwhile. Its
    priority is the ordinary one (a loop at SCHED_FIFO with SCHED_RESET_ON_FORK starts its threads at it, and
    preempts them). Not lower: a thread descheduled while it holds the GIL stalls the loop (at nice 10 on a loaded
    machine, 0.9 s)."""

    def __init__(self, idle_s: float = WRITER_IDLE_S):
        self.idle_s = idle_s
        self._queue: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._error: BaseException | None = None

    def start(self) -> None:
        """Start the thread now (a real-time loop: before it raises its priority and pins its core, so the writer
        keeps the ordinary policy and every CPU); otherwise the first chunk starts it."""
        with self._lock:
            self._start()

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name="wbmpc-chunk-writer", daemon=True)
            self._thread.start()

    def submit(self, job) -> None:
        """Run `job()` (a chunk's writes) on the writer's thread."""
        with self._lock:
            self._queue.put(job)
            self._start()

    def _work(self) -> None:
        """Jobs in order; the thread ends after `idle_s` without one."""
        while True:
            try:
                job = self._queue.get(timeout=self.idle_s)
            except queue.Empty:
                with self._lock:
                    if self._queue.empty():
                        self._thread = None
                        return
                continue
            try:
                job()
            except BaseException as exc:  # noqa: BLE001 - raised again by the next flush, in the reader's thread
                self._error = exc
            finally:
                self._queue.task_done()

    def flush(self) -> None:
        """Wait until every chunk handed over is written; an error of a write is raised here."""
        if self._thread is threading.current_thread():  # a table collected on the writer's own thread: nothing to wait
            return
        if self._thread is not None:
            self._queue.join()
        if self._error is not None:
            error, self._error = self._error, None
            raise error


class ChunkedTable:
    """Append-only table; `columns` maps a name to (row shape, dtype), e.g. {"q": ((26,), float)}."""

    def __init__(self, columns: dict[str, tuple[tuple[int, ...], type]], chunk_rows: int = DEFAULT_CHUNK_ROWS,
                 spill_dir: str | Path | None = None, name: str = "table", writer: ChunkWriter | None = None):
        """`writer`: full chunks written by that thread (see the module docstring), None: by `append` itself."""
        if chunk_rows < 1:
            raise ConfigError(f"chunk_rows must be >= 1, got {chunk_rows}")
        self.columns = {key: (tuple(shape), np.dtype(dtype)) for key, (shape, dtype) in columns.items()}
        self.chunk_rows = int(chunk_rows)
        self.name = name
        self._buffers = self._new_buffers()
        self._writer = writer
        self._in_flight: dict | None = None  # the buffers of a chunk the writer has not finished (then reused)
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

    def _new_buffers(self) -> dict[str, np.ndarray]:
        return {key: np.empty((self.chunk_rows, *shape), dtype) for key, (shape, dtype) in self.columns.items()}

    def _spill(self) -> None:
        folder = self._folder()
        index = self._spilled_chunks
        full, rows = self._buffers, self._fill
        self._spilled_chunks += 1
        self._fill = 0
        if self._writer is None:
            _write_chunk(folder, index, full, rows)
            return
        spare, self._in_flight = self._in_flight, full
        if spare is None:
            spare = self._new_buffers()
        else:
            self._writer.flush()  # the previous chunk's buffers are free again once it is on disk
        self._buffers = spare
        self._writer.submit(lambda: _write_chunk(folder, index, full, rows))

    def _written(self) -> None:
        """Readers and `close` first wait for the chunks in flight."""
        if self._writer is not None and self._in_flight is not None:
            self._writer.flush()

    def _folder(self) -> Path:
        if self._spill_dir is None:
            if self._spill_root is not None:
                self._spill_root.mkdir(parents=True, exist_ok=True)
            self._spill_dir = Path(tempfile.mkdtemp(prefix=f"wbmpc-{self.name}-", dir=self._spill_root))
            self._finalizer = weakref.finalize(self, _remove, self._spill_dir, self._writer)
        return self._spill_dir

    def close(self) -> None:
        """Delete the spilled chunks (the table is empty afterwards)."""
        self._written()
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
        self._written()
        return np.load(self._chunk_path(self._spilled_chunks - 1, key))[-1].copy()

    def first(self, key: str) -> np.ndarray:
        if not len(self):
            raise IndexError(f"{self.name} is empty")
        if self._spilled_chunks:
            self._written()
            return np.load(self._chunk_path(0, key), mmap_mode="r")[0].copy()
        return self._buffers[key][0].copy()

    def _chunk_path(self, index: int, key: str) -> Path:
        return self._spill_dir / f"{index:06d}_{key}.npy"

    def iter_chunks(self, keys: tuple[str, ...] | None = None) -> Iterator[dict[str, np.ndarray]]:
        """The rows in order, one chunk at a time: {column: (rows of the chunk, *shape)} (the live chunk as copies)."""
        keys = tuple(self.columns) if keys is None else tuple(keys)
        self._check(keys)
        self._written()
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
        """Bytes of the preallocated chunk buffers (what the table holds in memory; two chunks with a writer)."""
        spare = sum(buffer.nbytes for buffer in self._in_flight.values()) if self._in_flight is not None else 0
        return sum(buffer.nbytes for buffer in self._buffers.values()) + spare


def _remove(folder: Path, writer: ChunkWriter | None) -> None:
    """The spill directory deleted once no chunk is being written into it."""
    if writer is not None:
        try:
            writer.flush()
        except Exception:  # noqa: BLE001 - a failed write leaves nothing to keep
            pass
    shutil.rmtree(str(folder), True)


def _write_chunk(folder: Path, index: int, buffers: dict[str, np.ndarray], rows: int) -> None:
    for key, buffer in buffers.items():
        np.save(folder / f"{index:06d}_{key}.npy", buffer[:rows], allow_pickle=False)
