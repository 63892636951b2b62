"""Running a campaign on Dask distributed: one task per case, rows streamed to the table.

A `LocalCluster` by default (one single-threaded worker process per core, `--workers N`), or an
existing scheduler (`--scheduler ADDRESS`; its workers must import this wbmpc). Each worker
process keeps the robots and MPCs it built (`_WORKER_CACHE`), so the OCP and its solver are
built once per worker and reused by every case of the same structure.

Nothing is lost or duplicated: a task's key is its case id; when a worker dies mid-case the
scheduler re-runs the task on another worker (up to `distributed.scheduler.allowed-failures`
times), and the row is written once, by the client, under the case id. Cases that could not be
finished (a worker killed on every attempt, the client stopped) have no row and are run again
by `--resume`.
"""

from __future__ import annotations

import json
import os
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa

from wbmpc.campaign.cases import STRING_AXES, Case, expand
from wbmpc.campaign.spec import CampaignSpec
from wbmpc.campaign.table import ResultTable
from wbmpc.errors import ConfigError

_WORKER_CACHE: dict[tuple, object] = {}  # per worker process: robots and MPCs by structure
# a campaign with cases left and no worker for this long stops (their cases stay unfinished, for --resume)
# instead of waiting forever: killed workers whose nanny could not restart them (seen once at load ~20)
NO_WORKER_TIMEOUT_S = 120.0


@dataclass
class CampaignRun:
    """What a `run_campaign` call did."""

    out_dir: Path
    n_cases: int
    skipped: int  # already in the table (--resume)
    recorded: int
    unfinished: list[str] = field(default_factory=list)  # case ids without a row (workers killed too often)
    wall_time_s: float = 0.0
    workers: int = 0
    errors: int = 0

    @property
    def throughput_cases_per_min(self) -> float | None:
        return 60.0 * self.recorded / self.wall_time_s if self.recorded and self.wall_time_s > 0 else None


# ---------------------------------------------------------------------------- worker side
def _cached(key: tuple, build: Callable):
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = build()
    return _WORKER_CACHE[key]


def run_case(case: Case) -> dict:
    """One closed-loop run -> one row (errors are recorded in the row, never raised)."""
    from wbmpc.control.policy import mpc_config
    from wbmpc.robots import load_robot
    from wbmpc.scenarios import make_scenario, run_scenario

    row = base_row(case)
    try:
        config = case.run_config()
        robot = _cached(("robot", case.robot), lambda: load_robot(case.robot))
        scenario = make_scenario(config.scenario, robot, config.options)
        settings = mpc_config(robot, scenario.needs(robot), config.mpc_choices())
        # one MPC per distinct configuration (gait, grid, solver, tuning, delay's recovery budget, cadence)
        mpc = _cached(("mpc", case.robot, repr(settings)), lambda: _built_mpc(robot, settings))
        result = run_scenario(robot, config, mpc=mpc)
        m = result.metrics
        row.update(
            fell=bool(m["fell"]), fell_at_s=m["fell_at_s"], duration_s=m["duration_s"],
            base_drift_cm_s=m["base_drift_cm_s"], max_torque_ratio=m["max_torque_ratio"],
            solve_ms_mean=m["solve_ms"]["mean"], solve_ms_max=m["solve_ms"]["max"],
            iterations_mean=m["iterations_mean"], mpc_solves=m["mpc_solves"], mpc_failures=m["mpc_failures"],
            recovery_solves=sum("recovery" in str(s) for s in result.log.status), wall_time_s=m["wall_time_s"],
            metrics_json=json.dumps(_jsonable(m)),
        )
        row["recovered"] = not row["fell"]
    except Exception as exc:  # a failing case is a row with its error, not a lost case
        row["error"] = f"{type(exc).__name__}: {exc}"[:2000]
        row["recovered"] = False
        if not isinstance(exc, ConfigError):
            row["metrics_json"] = json.dumps({"traceback": traceback.format_exc()[-4000:]})
    return row


def _built_mpc(robot, config):
    """The MPC with its fallback solver built too, so no case's step times include a solver build."""
    from wbmpc.control.mpc import MPC

    mpc = MPC(robot, config)
    mpc.prepare_fallback()
    return mpc


def base_row(case: Case) -> dict:
    try:
        from distributed import get_worker

        worker = get_worker().address
    except (ImportError, ValueError):
        worker = "local"
    row = {"case_id": case.id, "scenario": case.scenario, "robot": case.robot, "seed": case.seed,
           "worker": worker, "pid": os.getpid(), "params_json": json.dumps(case.values), "error": None}
    row.update(case.values)
    return row


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# ---------------------------------------------------------------------------- client side
def axis_types(cases: list[Case]) -> dict[str, pa.DataType]:
    names = sorted({name for case in cases for name, _ in case.params})
    return {name: pa.string() if name in STRING_AXES else pa.float64() for name in names}


def worker_env() -> dict[str, str]:
    """Worker processes import this wbmpc (not another install) and use one BLAS thread each."""
    src = str(Path(__file__).resolve().parents[2])
    path = os.environ.get("PYTHONPATH", "")
    return {"PYTHONPATH": src + (os.pathsep + path if path else ""), "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def start_client(workers: int | None = None, scheduler: str | None = None):
    """(client, cluster or None): a LocalCluster of single-threaded worker processes, or `scheduler`."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {exc}; start one with "
                              "`dask scheduler` (and `dask worker ADDRESS --nthreads 1`) or omit --scheduler") from None
    n = workers or os.cpu_count() or 1
    if n < 1:
        raise ConfigError(f"--workers must be >= 1, got {n}")
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR, env=worker_env())
    return Client(cluster), cluster


def run_campaign(spec: CampaignSpec, out_dir: str | Path, *, workers: int | None = None, scheduler: str | None = None,
                 resume: bool = False, overwrite: bool = False, progress: bool = True,
                 runner: Callable[[Case], dict] = run_case, client=None,
                 no_worker_timeout_s: float = NO_WORKER_TIMEOUT_S) -> CampaignRun:
    """Run every case of `spec` not yet in `out_dir`'s table; rows are written as cases finish."""
    cases = list({case.id: case for case in expand(spec)}.values())
    for case in cases:  # a value a run refuses is refused here, before a cluster starts (ConfigError names it)
        case.run_config()
    out_dir = Path(out_dir)
    table = ResultTable(out_dir, axis_types(cases))
    finished = table.finished_ids()
    if finished and not (resume or overwrite):
        raise ConfigError(f"{out_dir} already holds {len(finished)} campaign rows; pass --resume to run only the "
                          "missing cases, --overwrite to start again, or choose another --out")
    if overwrite:
        for path in table.rows_dir.glob("*.parquet"):
            path.unlink()
        finished = set()
    (out_dir / "spec.json").write_text(json.dumps(asdict(spec), indent=2))
    todo = [case for case in cases if case.id not in finished]
    run = CampaignRun(out_dir, len(cases), len(cases) - len(todo), 0)
    if not todo:
        table.compact()
        return run
    start = time.perf_counter()
    if spec.delay == "realtime" and client is None and scheduler is None:
        if workers not in (None, 1):
            raise ConfigError(f"--delay-mode realtime runs one case at a time (the two cores are the solver's and the "
                              f"simulation's); drop --workers {workers} or set it to 1")
        run.workers = 1
        run = _run_here(todo, table, run, runner, progress)
        run.wall_time_s = time.perf_counter() - start
        table.compact()
        return run
    own = client is None
    cluster = None
    if own:
        client, cluster = start_client(workers, scheduler)
    try:
        run.workers = len(client.scheduler_info(n_workers=-1)["workers"]) if hasattr(client, "scheduler_info") else 0
        run = _gather(client, todo, table, run, runner, progress, no_worker_timeout_s)
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()
    run.wall_time_s = time.perf_counter() - start
    table.compact()
    return run


def _gather(client, todo: list[Case], table: ResultTable, run: CampaignRun, runner, progress: bool,
            no_worker_timeout_s: float = NO_WORKER_TIMEOUT_S) -> CampaignRun:
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    from wbmpc.progress import ProgressBar

    futures = {}
    for case in todo:
        future = client.submit(runner, case, key=f"case-{case.id}", pure=False)
        futures[future] = case
    # silent off a terminal (a redirected log gets the messages only), or when progress=False
    bar = ProgressBar(len(todo), "campaign ", unit="cases", enabled=None if progress else False, decimals=0)
    pending = as_completed(futures)
    workerless_since = None
    try:
        while not pending.is_empty():
            batch = pending.next_batch(block=False)
            if not batch:
                if _worker_count(client) > 0:
                    workerless_since = None
                elif workerless_since is None:
                    workerless_since = time.monotonic()
                elif time.monotonic() - workerless_since > no_worker_timeout_s:
                    left = [futures[f] for f in futures if not f.done()]
                    run.unfinished += [case.id for case in left]  # no row: --resume runs them again
                    bar.write(f"campaign: no Dask worker for {no_worker_timeout_s:.0f} s; stopping with {len(left)} "
                              "case(s) unfinished (run again with --resume)")
                    break
                time.sleep(0.2)
                continue
            for future in batch:
                _record(future, futures[future], table, run, bar, KilledWorker)
    finally:
        bar.close()
        for future in futures:
            future.release()
    return run


def _run_here(todo: list[Case], table: ResultTable, run: CampaignRun, runner, progress: bool) -> CampaignRun:
    """The cases one after the other in this process (real time: a Dask worker is a daemon process, which
    may not start the solver process, and a second case beside it would take the solver's core)."""
    from wbmpc.progress import ProgressBar

    bar = ProgressBar(len(todo), "campaign ", unit="cases", enabled=None if progress else False, decimals=0)
    try:
        for case in todo:
            row = runner(case)
            table.write(row)
            run.recorded += 1
            run.errors += row.get("error") is not None
            bar.advance(1)
            bar.set_status("ok" if row.get("recovered") else "FELL" if row.get("fell") else "error")
    finally:
        bar.close()
    return run


def _worker_count(client) -> int:
    try:
        return len(client.scheduler_info(n_workers=-1)["workers"])
    except Exception:  # the scheduler itself is gone: no worker will come back either
        return 0


def _record(future, case: Case, table: ResultTable, run: CampaignRun, bar, killed_worker) -> None:
    """Write one finished case's row (a case whose workers were killed too often gets none)."""
    try:
        row = future.result()
    except killed_worker:
        run.unfinished.append(case.id)  # no row: --resume runs it again
        bar.advance(1)
        return
    except Exception as exc:  # the runner itself raised (run_case never does)
        row = base_row(case)
        row.update(recovered=False, error=f"{type(exc).__name__}: {exc}"[:2000], worker="unknown")
    table.write(row)
    run.recorded += 1
    run.errors += row.get("error") is not None
    bar.advance(1)
    bar.set_status(f"{'ok' if row.get('recovered') else 'FELL' if row.get('fell') else 'error'}")
