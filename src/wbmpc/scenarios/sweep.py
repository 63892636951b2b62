"""Largest pullable load: the `pull` scenario over a list of masses (`wbmpc run pull --sweep ...`).

One MPC serves every run (reset in between). A load counts as pulled when the robot stayed up
and the load followed at least half the commanded way (`pulled` in the pull metrics); a load
whose force target the arm cannot hold (checked before the run) is reported as rejected.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

from wbmpc.control.mpc import MPC
from wbmpc.errors import ConfigError
from wbmpc.interrupt import stop_flag
from wbmpc.robots import RobotModel
from wbmpc.scenarios.library import make_scenario
from wbmpc.scenarios.runner import RunConfig, mpc_config_for, run_scenario

ROW_KEYS = ("fell", "pulled", "load_moved_m", "load_expected_move_m", "target_tension_n", "tension_mean_n",
            "ee_force_err_rel", "torque_ratio_joint2", "torque_ratio_joint3", "max_torque_ratio", "mpc_failures")


def parse_loads(text: str) -> list[float]:
    try:
        loads = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"--sweep takes comma-separated masses in kg, e.g. 6,10,14,18; got {text!r}") from None
    if not loads:
        raise ConfigError("--sweep needs at least one load in kg")
    bad = [x for x in loads if not 0 < x <= 1000]  # also NaN and inf
    if bad:
        raise ConfigError(f"--sweep loads must be masses in kg in (0, 1000], got {bad}")
    return sorted(loads)


def pull_sweep(robot: RobotModel, loads_kg: list[float], config: RunConfig,
               progress: Callable[[float, float, int], None] | None = None,
               on_row: Callable[[dict], None] | None = None, stop: Callable[[], bool] | None = None) -> dict:
    """Run `pull` for each load; returns {"gait", "rows": [...], "max_pulled_kg", "interrupted"}.

    `progress(load, share, recovered steps)`; `on_row(report so far)` is called after every load (a
    long sweep keeps what it measured). Ctrl-C (or `stop()`) ends the sweep after the current run."""
    if config.scenario != "pull":
        raise ConfigError(f"the load sweep runs the pull scenario, not {config.scenario!r}")
    mpc: MPC | None = None
    rows, interrupted = [], False
    with stop_flag(stop) as stop:
        for load in loads_kg:
            if stop():
                interrupted = True
                break
            run_config = replace(config, options=replace(config.options, load_kg=load))
            row = {"load_kg": load}
            try:
                scenario = make_scenario("pull", robot, run_config.options)
            except ConfigError as exc:
                row.update({"rejected": str(exc), "pulled": False})
            else:
                mpc = mpc or MPC(robot, mpc_config_for(scenario, run_config, robot))
                result = run_scenario(robot, run_config, mpc=mpc, stop=stop,
                                      progress=(lambda s, r, m=load: progress(m, s, r)) if progress else None)
                row.update({k: result.metrics.get(k) for k in ROW_KEYS})
                row["solve_ms_mean"] = result.metrics["solve_ms"]["mean"]
                row["interrupted"] = interrupted = result.metrics["interrupted"]
            rows.append(row)
            if on_row:
                on_row(_report(config, rows, interrupted))
            if interrupted:
                break
    return _report(config, rows, interrupted)


def _report(config: RunConfig, rows: list[dict], interrupted: bool = False) -> dict:
    pulled = [r["load_kg"] for r in rows if r.get("pulled") and not r.get("interrupted")]
    return {"scenario": "pull", "gait": config.options.gait or "trot", "load_friction_mu": config.options.load_friction_mu,
            "duration_s": config.duration_s, "rows": list(rows), "max_pulled_kg": max(pulled) if pulled else None,
            "interrupted": bool(interrupted)}


def sweep_table(report: dict) -> str:
    lines = [f"pull sweep ({report['gait']}, load friction {report['load_friction_mu']}):",
             f"{'load kg':>8} {'pulled':>7} {'fell':>5} {'moved m':>8} {'T target N':>10} {'T mean N':>9} "
             f"{'F err %':>8} {'joint3':>7}"]
    for r in report["rows"]:
        if "rejected" in r:
            lines.append(f"{r['load_kg']:8.1f}  rejected: {r['rejected']}")
            continue

        def f(x, fmt):
            return format(x, fmt) if x is not None else "-"

        lines.append(f"{r['load_kg']:8.1f} {str(r['pulled']):>7} {str(r['fell']):>5} {f(r['load_moved_m'], '8.3f')} "
                     f"{f(r['target_tension_n'], '10.1f')} {f(r['tension_mean_n'], '9.1f')} "
                     f"{f(r['ee_force_err_rel'] and 100 * r['ee_force_err_rel'], '8.1f')} "
                     f"{f(r['torque_ratio_joint3'], '7.2f')}")
    lines.append(f"largest load pulled: {report['max_pulled_kg']} kg")
    if report.get("interrupted"):
        lines.append("(interrupted by Ctrl-C: loads after the last row were not run)")
    return "\n".join(lines)
