"""Campaign reports from the result table: push-recovery map, curves over an axis, markdown summary.

- push map: per push direction, the largest speed recovered, i.e. the largest tested speed such
  that every case (all gait phases and seeds) at that speed and every lower one stayed up; also
  the largest speed recovered in at least one case. Polar PNG with the 0.8 and 1.0 m/s goals.
- curves: for every other numeric axis with several values (payload, friction, model errors,
  noise, delay ...): share of cases recovered and the largest torque ratio against the value.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from wbmpc.campaign.cases import STRING_AXES
from wbmpc.campaign.reality_gap import REALITY_GAP_RANGES, axis_effects, effects_markdown
from wbmpc.campaign.table import ResultTable, row_dicts

PUSH_AXES = ("push_direction_deg", "push_speed_m_s", "gait_phase")
MAX_CURVE_VALUES = 12  # an axis with more distinct values was drawn, not gridded: binned (reality_gap.axis_effects)


def push_map(rows: list[dict]) -> dict | None:
    """{direction: {...}} from rows with push direction and speed, or None when the table has none."""
    rows = [r for r in rows if r.get("push_direction_deg") is not None and r.get("push_speed_m_s") is not None]
    if not rows:
        return None
    by_direction: dict[float, dict[float, list[bool]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        by_direction[float(r["push_direction_deg"]) % 360][float(r["push_speed_m_s"])].append(bool(r["recovered"]))
    out = {}
    for direction in sorted(by_direction):
        speeds = sorted(by_direction[direction])
        shares = {s: float(np.mean(by_direction[direction][s])) for s in speeds}
        largest = 0.0
        for s in speeds:
            if shares[s] < 1.0:
                break
            largest = s
        any_ok = max((s for s in speeds if shares[s] > 0), default=0.0)
        out[direction] = {"largest_recovered_m_s": largest, "largest_recovered_any_case_m_s": any_ok,
                          "recovered_share": shares, "cases": sum(len(v) for v in by_direction[direction].values())}
    return out


def curves(rows: list[dict], axes: list[str]) -> dict[str, list[dict]]:
    """Per numeric axis (not the push ones) with >= 2 values: recovered share, torque ratio, drift."""
    out = {}
    for axis in axes:
        if axis in PUSH_AXES or axis in STRING_AXES:
            continue
        groups: dict[float, list[dict]] = defaultdict(list)
        for r in rows:
            if r.get(axis) is not None:
                groups[float(r[axis])].append(r)
        if len(groups) < 2:
            continue
        out[axis] = [{
            "value": value,
            "cases": len(group),
            "recovered_share": float(np.mean([bool(r["recovered"]) for r in group])),
            "max_torque_ratio": _max([r.get("max_torque_ratio") for r in group]),
            "base_drift_cm_s_mean": _mean([r.get("base_drift_cm_s") for r in group]),
        } for value, group in sorted(groups.items())]
    return out


def _max(values):
    values = [v for v in values if v is not None]
    return float(max(values)) if values else None


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def plot_push_map(pmap: dict, path: Path, goals=(0.8, 1.0)) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(6.5, 6))
    ax = fig.add_subplot(projection="polar")
    directions = sorted(pmap)
    theta = np.deg2rad(directions)
    all_speeds = sorted({s for d in directions for s in pmap[d]["recovered_share"]})
    # dots: share of cases recovered at that direction and speed, red (none) -> yellow -> green (all); the
    # blue line (no markers, under the dots) joins the largest speeds recovered in every case
    points = [(np.deg2rad(d), s, share) for d in directions for s, share in pmap[d]["recovered_share"].items()]
    closed = np.append(theta, theta[0]) if len(theta) > 1 else theta
    largest = [pmap[d]["largest_recovered_m_s"] for d in directions]
    ax.plot(closed, np.append(largest, largest[0]) if len(theta) > 1 else largest, "-", color="tab:blue", lw=2.5,
            alpha=0.8, label="largest speed recovered (all phases)", zorder=2)
    dots = ax.scatter([p[0] for p in points], [p[1] for p in points], c=[p[2] for p in points], cmap="RdYlGn",
                      vmin=0.0, vmax=1.0, s=60, edgecolors="k", linewidths=0.4, zorder=3)
    ax.scatter([], [], c="#1a9850", s=60, edgecolors="k", linewidths=0.4, label="every case recovered")
    ax.scatter([], [], c="#d73027", s=60, edgecolors="k", linewidths=0.4, label="no case recovered")
    bar = fig.colorbar(dots, ax=ax, shrink=0.6, pad=0.1)
    bar.set_label("share of cases recovered (all gait phases and seeds)", fontsize=8)
    circle = np.linspace(0, 2 * np.pi, 200)
    for goal, style in zip(goals, ("k--", "k:")):
        ax.plot(circle, np.full_like(circle, goal), style, lw=1, label=f"goal {goal} m/s")
    ax.set_theta_zero_location("N")  # forward up, left to the left
    ax.set_rlim(0, max(all_speeds + [max(goals)]) * 1.05)
    ax.set_title("push recovery map (push speed in m/s by direction; forward up)", fontsize=9)
    ax.legend(loc="lower left", bbox_to_anchor=(-0.1, -0.12), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_curves(name: str, points: list[dict], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = [p["value"] for p in points]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot(x, [p["recovered_share"] for p in points], "g-o", label="share of cases without a fall")
    ax.set_xlabel(name)
    ax.set_ylim(-0.05, 1.05)
    ax.set_ylabel("recovered share")
    ax2 = ax.twinx()
    ax2.plot(x, [p["max_torque_ratio"] if p["max_torque_ratio"] is not None else np.nan for p in points], "r-s",
             label="largest |tau| / tau_max")
    ax2.set_ylabel("largest torque ratio")
    fig.legend(loc="lower center", ncol=2, fontsize=8)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def case_timing(rows: list[dict]) -> list[dict] | None:
    """Per case with a measured or real-time delay: achieved MPC rate, share of late solutions, mean delay, solver."""
    out = []
    for row in rows:
        metrics = json.loads(row.get("metrics_json") or "{}")
        if metrics.get("delay", "none") not in ("realtime", "measured", "measured-wall") or "mpc_rate_hz" not in metrics:
            continue  # a fixed delay or none: the simulation keeps the MPC's rate
        out.append({"case_id": row["case_id"], "params": json.loads(row.get("params_json") or "{}"),
                    "delay": metrics["delay"], "solver": metrics.get("solver"), "fell": bool(row.get("fell")),
                    "mpc_rate_hz": metrics["mpc_rate_hz"], "late_solution_share": metrics["late_solution_share"],
                    "delay_ms_mean": metrics.get("delay_ms_mean"), "sqp_iterations_mean": metrics.get("sqp_iterations_mean")})
    return out or None


def write_report(out_dir: str | Path, run_info: dict | None = None) -> list[Path]:
    """summary.md, summary.json and PNGs in `out_dir` from its result table."""
    out_dir = Path(out_dir)
    table = ResultTable(out_dir).read()
    rows = row_dicts(table)
    params = sorted({k for r in rows for k in json.loads(r.get("params_json") or "{}")})
    drawn = _drawn_axes(out_dir, rows, params)
    pmap = push_map(rows)
    curve_data = curves(rows, [p for p in params if p not in drawn and p != "plant_seed"])
    effects = axis_effects(rows, drawn) if drawn else None
    paths: list[Path] = []
    if pmap:
        paths.append(plot_push_map(pmap, out_dir / "push_map.png"))
    for axis, points in curve_data.items():
        paths.append(plot_curves(axis, points, out_dir / f"curve_{axis}.png"))
    errors = [r for r in rows if r.get("error")]
    summary = {
        "cases": len(rows),
        "recovered": int(sum(bool(r["recovered"]) for r in rows)),
        "fell": int(sum(bool(r["fell"]) for r in rows)),
        "errors": len(errors),
        "solve_ms_max": _max([r.get("solve_ms_max") for r in rows]),
        "case_wall_time_s_mean": _mean([r.get("wall_time_s") for r in rows]),
        "push_map": {str(k): v for k, v in pmap.items()} if pmap else None,
        "timing": case_timing(rows),
        "curves": curve_data,
        "reality_gap": effects,
        "run": run_info,
    }
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    paths.append(out_dir / "summary.json")
    paths.append(_markdown(out_dir / "summary.md", summary, pmap, curve_data, errors,
                           effects_markdown(effects, rows) if effects else []))
    return paths


def _drawn_axes(out_dir: Path, rows: list[dict], params: list[str]) -> list[str]:
    """The axes drawn at random (the spec's random ranges and the reality-gap draw), plus any axis with more distinct
    values than a grid would hold; `plant_seed` is an identifier, not a factor."""
    drawn = set()
    spec_path = out_dir / "spec.json"
    if spec_path.is_file():
        spec = json.loads(spec_path.read_text())
        drawn |= set((spec.get("random") or {}).get("ranges") or {})
        if spec.get("randomize"):
            drawn |= set(REALITY_GAP_RANGES) | set(spec.get("grid") or {})
    for name in params:
        if len({r.get(name) for r in rows if r.get(name) is not None}) > MAX_CURVE_VALUES:
            drawn.add(name)
    drawn.discard("plant_seed")
    return sorted(name for name in drawn if name in params)


def _markdown(path: Path, summary: dict, pmap, curve_data, errors, gap_lines=()) -> Path:
    lines = ["# Campaign summary", "",
             f"{summary['cases']} cases: {summary['recovered']} recovered, {summary['fell']} fell, "
             f"{summary['errors']} errors; longest MPC step {summary['solve_ms_max'] or 0:.0f} ms; "
             f"mean case wall time {summary['case_wall_time_s_mean'] or 0:.1f} s.", ""]
    run = summary.get("run") or {}
    if run:
        lines += [f"Run: {run.get('workers')} workers, {run.get('recorded')} cases recorded in "
                  f"{run.get('wall_time_s', 0):.0f} s ({run.get('throughput_cases_per_min') or 0:.2f} cases/min), "
                  f"{run.get('skipped', 0)} skipped (already done), {len(run.get('unfinished', []))} unfinished.", ""]
    if pmap:
        speeds = sorted({s for d in pmap.values() for s in d["recovered_share"]})
        lines += ["## Push recovery map", "", "Largest speed recovered = every case (all gait phases and seeds) at "
                  "that speed and below stayed up. Cells: share of cases recovered.", "",
                  "| direction (deg) | largest recovered (m/s) | any case (m/s) | " +
                  " | ".join(f"{s:g} m/s" for s in speeds) + " |",
                  "|---|---|---|" + "---|" * len(speeds)]
        for d, info in pmap.items():
            cells = [f"{info['recovered_share'][s]:.2f}" if s in info["recovered_share"] else "" for s in speeds]
            lines.append(f"| {d:g} | {info['largest_recovered_m_s']:g} | {info['largest_recovered_any_case_m_s']:g} | "
                         + " | ".join(cells) + " |")
        lines += ["", "![push map](push_map.png)", ""]
    for axis, points in curve_data.items():
        lines += [f"## {axis}", "", "| value | cases | recovered share | largest torque ratio | mean drift (cm/s) |",
                  "|---|---|---|---|---|"]
        for p in points:
            lines.append(f"| {p['value']:g} | {p['cases']} | {p['recovered_share']:.2f} | "
                         f"{_fmt(p['max_torque_ratio'])} | {_fmt(p['base_drift_cm_s_mean'])} |")
        lines += ["", f"![{axis}](curve_{axis}.png)", ""]
    lines += list(gap_lines)
    if summary.get("timing"):
        lines += ["## Timing per case", "", "| case | delay | solver | fell | MPC rate (Hz) | late share | mean delay (ms) | "
                  "SQP iterations |", "|---|---|---|---|---|---|---|---|"]
        for t in summary["timing"]:
            shown = ", ".join(f"{k}={v}" for k, v in sorted(t["params"].items())) or t["case_id"]
            lines.append(f"| {shown} | {t['delay']} | {t['solver']} | {t['fell']} | {_fmt(t['mpc_rate_hz'])} | "
                         f"{_fmt(t['late_solution_share'])} | {_fmt(t['delay_ms_mean'])} | {_fmt(t['sqp_iterations_mean'])} |")
        lines.append("")
    if errors:
        lines += ["## Errors", ""] + [f"- `{r['case_id']}` {r.get('params_json')}: {r['error']}" for r in errors[:20]]
    path.write_text("\n".join(lines) + "\n")
    return path


def _fmt(value) -> str:
    return "" if value is None else f"{value:.2f}"
