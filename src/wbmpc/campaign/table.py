"""`ResultTable`: campaign rows streamed to a Parquet dataset as cases finish.

Each finished case is written at once as `rows/<case id>.parquet` (written to a temporary name,
then renamed, so a killed client never leaves half a row). A case id names at most one file:
a case recorded twice (a retried task whose first attempt also finished) overwrites itself,
never duplicates. `read()` gives the whole table; `compact()` also writes `results.parquet`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

# metrics of every row (the axis columns are added per campaign)
METRIC_COLUMNS: dict[str, pa.DataType] = {
    "case_id": pa.string(),
    "scenario": pa.string(),
    "robot": pa.string(),
    "seed": pa.int64(),
    "recovered": pa.bool_(),  # no fall and no error over the whole run
    "fell": pa.bool_(),
    "fell_at_s": pa.float64(),
    "duration_s": pa.float64(),
    "base_drift_cm_s": pa.float64(),
    "max_torque_ratio": pa.float64(),
    "solve_ms_mean": pa.float64(),
    "solve_ms_max": pa.float64(),
    "iterations_mean": pa.float64(),
    "mpc_solves": pa.int64(),
    "mpc_failures": pa.int64(),
    "recovery_solves": pa.int64(),
    "wall_time_s": pa.float64(),
    "worker": pa.string(),
    "pid": pa.int64(),
    "error": pa.string(),
    "params_json": pa.string(),
    "metrics_json": pa.string(),
}


class ResultTable:
    def __init__(self, out_dir: str | Path, axis_types: dict[str, pa.DataType] | None = None):
        self.out_dir = Path(out_dir)
        self.rows_dir = self.out_dir / "rows"
        self.rows_dir.mkdir(parents=True, exist_ok=True)
        columns = dict(METRIC_COLUMNS)
        for name, kind in (axis_types or {}).items():
            columns.setdefault(name, kind)
        self.schema = pa.schema(list(columns.items()))

    def finished_ids(self) -> set[str]:
        return {p.stem for p in self.rows_dir.glob("*.parquet")}

    def write(self, row: dict) -> Path:
        """One finished case, atomically; columns missing from `row` are null."""
        values = {name: [row.get(name)] for name in self.schema.names}
        table = pa.table(values, schema=self.schema)
        path = self.rows_dir / f"{row['case_id']}.parquet"
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, path)
        return path

    def read(self) -> pa.Table:
        """All rows (schemas of earlier campaigns in the same directory are unified)."""
        files = sorted(self.rows_dir.glob("*.parquet"))
        if not files:
            return self.schema.empty_table()
        tables = [pq.read_table(f) for f in files]
        return pa.concat_tables(tables, promote_options="permissive")

    def compact(self) -> Path:
        path = self.out_dir / "results.parquet"
        pq.write_table(self.read(), path)
        return path


def row_dicts(table: pa.Table) -> list[dict]:
    """Rows as dicts, with the case parameters of `params_json` merged in."""
    rows = table.to_pylist()
    for row in rows:
        row.update(json.loads(row.get("params_json") or "{}"))
    return rows
