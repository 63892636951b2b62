"""The reality gap as a campaign: plants drawn around the robot's model, and which factor breaks the control.

`wbmpc campaign --randomize` draws, per case, a plant that differs from the controller's model as a real robot
differs from its URDF (issue 37): every link's mass and rotational inertia x its own factor in [0.9, 1.1]
(`link_mass_spread_rel`, from the case's `plant_seed`), the base CoM moved by up to 2 cm on each axis, the floor's
friction in [0.4, 1.0], the rotor inertia, viscous and dry friction of every joint at 0-2x the robot's reference
drive train (`wbmpc.sim.model_errors.reference_drive_train`), a fixed delay of 0-10 ms before each plan applies,
and the IMU's and encoders' noise and biases at 0-2x the sensor models' (the MPC then sees the estimator's state,
not the simulator's). `--grid plant_model=FILE,...` adds independent plant files as a further axis. Every drawn
value is an axis column of the case's row (and `plant_seed` reproduces the per-link factors, listed in its
metrics), so a case runs again identically from its row.

`axis_effects` reads the rows back: per axis the share of cases that stayed up in quartile bins of the drawn
value, and the breaking point: the threshold (towards the end where the falls gather) that separates the falls
best, with the falls beyond and before it and Fisher's exact p (p < 0.05: the axis explains the falls; larger: the
falls there are as likely by chance, with ~100 cases and nine axes drawn at once).
"""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np

# axis -> (low, high) of the uniform draw; plant_seed is drawn as an integer
REALITY_GAP_RANGES: dict[str, tuple[float, float]] = {
    "base_com_offset_x_m": (-0.02, 0.02),
    "base_com_offset_y_m": (-0.02, 0.02),
    "base_com_offset_z_m": (-0.02, 0.02),
    "floor_friction_mu": (0.4, 1.0),
    "joint_armature_scale": (0.0, 2.0),
    "joint_damping_scale": (0.0, 2.0),
    "joint_frictionloss_scale": (0.0, 2.0),
    "delay_ms": (0.0, 10.0),
    "sensor_noise_scale": (0.0, 2.0),
    "plant_seed": (0, 2**31 - 1),
}
# the same in every case: each link's own factor within +-10 %, the estimator's state (the sensors' noise acts there)
REALITY_GAP_FIXED: dict[str, float | str] = {"link_mass_spread_rel": 0.1, "state": "estimated"}
DEFAULT_SAMPLES = 100
# derived per-case values analysed like axes: {name: (metrics path, help)}
DERIVED_AXES = {"plant_mass_ratio": "the plant's mass over the model's (the per-link factors and any payload)"}
MIN_CASES_PER_SIDE = 3


def randomized(spec) -> tuple[dict, dict, int]:
    """(random ranges, fixed values, samples) of a spec with `randomize`: the defaults above under the spec's own."""
    ranges = {**REALITY_GAP_RANGES, **spec.random.ranges}
    fixed = {**REALITY_GAP_FIXED, **spec.fixed}
    for name in spec.grid:  # an axis on the grid is not drawn
        ranges.pop(name, None)
        fixed.pop(name, None)
    for name in spec.fixed:
        ranges.pop(name, None)
    return ranges, fixed, spec.random.samples or DEFAULT_SAMPLES


def derived_values(row: dict) -> dict:
    """The derived axes of a row, from its metrics (None where the run did not report them)."""
    metrics = json.loads(row.get("metrics_json") or "{}")
    mass, plant = metrics.get("mass_kg"), metrics.get("plant_mass_kg")
    return {"plant_mass_ratio": plant / mass if plant and mass else None}


def axis_effects(rows: list[dict], axes: list[str]) -> dict[str, dict]:
    """Per drawn axis (numeric, or named values such as plant files): stayed-up share per bin and the breaking point."""
    from scipy.stats import fisher_exact

    rows = [dict(r, **derived_values(r)) for r in rows]
    out = {}
    for axis in list(axes) + list(DERIVED_AXES):
        pairs = [(r[axis], bool(r["recovered"])) for r in rows if r.get(axis) is not None and not r.get("error")]
        if len(pairs) < 2 * MIN_CASES_PER_SIDE:
            continue
        if isinstance(pairs[0][0], str):
            groups = defaultdict(list)
            for value, ok in pairs:
                groups[value].append(ok)
            out[axis] = {"kind": "named", "groups": [{"value": k, "cases": len(v), "stayed_up_share": float(np.mean(v))}
                                                     for k, v in sorted(groups.items())]}
            continue
        values = np.array([p[0] for p in pairs], dtype=float)
        ok = np.array([p[1] for p in pairs])
        if np.ptp(values) == 0:
            continue
        edges = np.unique(np.quantile(values, [0, 0.25, 0.5, 0.75, 1.0]))
        bins = []
        for k in range(len(edges) - 1):
            inside = (values >= edges[k]) & ((values < edges[k + 1]) if k < len(edges) - 2 else (values <= edges[k + 1]))
            if inside.any():
                bins.append({"from": float(edges[k]), "to": float(edges[k + 1]), "cases": int(inside.sum()),
                             "stayed_up_share": float(ok[inside].mean())})
        effect = {"kind": "numeric", "low": float(values.min()), "high": float(values.max()), "bins": bins,
                  "falls": int((~ok).sum()), "breaking_point": None}
        if (~ok).any() and ok.any():
            high_side = values[~ok].mean() > values.mean()  # the falls gather at the high end
            best = None
            for threshold in np.unique(values):
                beyond = values >= threshold if high_side else values <= threshold
                if min(beyond.sum(), (~beyond).sum()) < MIN_CASES_PER_SIDE:
                    continue
                table = [[int((~ok & beyond).sum()), int((ok & beyond).sum())],
                         [int((~ok & ~beyond).sum()), int((ok & ~beyond).sum())]]
                p = float(fisher_exact(table, alternative="greater")[1])
                if best is None or p < best["p_value"]:
                    best = {"value": float(threshold), "side": "above" if high_side else "below", "p_value": p,
                            "falls_beyond": table[0][0], "cases_beyond": int(beyond.sum()),
                            "falls_before": table[1][0], "cases_before": int((~beyond).sum())}
            effect["breaking_point"] = best
        out[axis] = effect
    return out


def effects_markdown(effects: dict[str, dict], rows: list[dict]) -> list[str]:
    """The report's reality-gap section."""
    valid = [r for r in rows if not r.get("error")]
    up = sum(bool(r["recovered"]) for r in valid)
    lines = ["## Reality gap: which factor breaks it", "",
             f"{up} of {len(valid)} randomized plants stayed up ({100 * up / max(len(valid), 1):.1f} %). Per axis: the "
             "share that stayed up in quartile bins of the drawn value, and the threshold that separates the falls "
             "best (Fisher's exact p; p < 0.05: the axis explains the falls).", "",
             "| axis | drawn | stayed up per quartile bin | breaks | falls beyond / cases | before | p |",
             "|---|---|---|---|---|---|---|"]
    for axis, e in effects.items():
        if e["kind"] == "named":
            cells = ", ".join(f"{g['value']}: {g['stayed_up_share']:.2f} of {g['cases']}" for g in e["groups"])
            lines.append(f"| {axis} | named | {cells} | | | | |")
            continue
        cells = ", ".join(f"{b['stayed_up_share']:.2f}" for b in e["bins"])
        bp = e["breaking_point"]
        if bp is None:
            lines.append(f"| {axis} | {e['low']:.3g} to {e['high']:.3g} | {cells} | none | | | |")
        else:
            lines.append(f"| {axis} | {e['low']:.3g} to {e['high']:.3g} | {cells} | {bp['side']} {bp['value']:.3g} | "
                         f"{bp['falls_beyond']} / {bp['cases_beyond']} | {bp['falls_before']} / {bp['cases_before']} | "
                         f"{bp['p_value']:.3f} |")
    fallen = [r for r in valid if not r["recovered"]]
    if fallen:
        lines += ["", "Plants that fell (drawn values):", ""]
        for r in fallen[:30]:
            params = json.loads(r.get("params_json") or "{}")
            shown = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in sorted(params.items()))
            lines.append(f"- `{r['case_id']}` fell at {r.get('fell_at_s') or 0:.2f} s: {shown}")
    return lines + [""]
