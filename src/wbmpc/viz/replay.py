"""A self-contained HTML 3D replay of a run: plain JavaScript on a <canvas>, no network access.

`save_replay(robot, time_s, q, out_path)` samples the run at `fps`, computes with pinocchio the
world positions of every joint origin, the feet, the arm end-effector and the corners of the
base box, and embeds them (rounded to millimetres) as JSON in one HTML file that draws the robot
as a capsule figure over a ground grid: drag rotates the orbit camera, the wheel zooms, the
camera follows the base; play/pause, time slider and playback speed at the bottom.

JSON layout (`<script id="replay-data" type="application/json">`, also `replay_data(...)`):
`frames[k]` = flat [x0, y0, z0, x1, ...] in mm of the points `names[i]` at time `t[k]`;
`links` = [[i, j, group]] drawn as capsules; `box_edges` = [[i, j]]; `extras` = named
trajectories [{"name", "color", "frames": [[x, y, z] | null]}] in mm; `objects` = the scene's
objects (`wbmpc.sim.objects.Scene.replay_objects`): boxes {"name", "kind": "box", "color",
"half": [mm x3], "frames": [[x, y, z (mm), R row-major x9]]} and lines {"name", "kind": "line",
"color", "frames": [[x0, y0, z0, x1, y1, z1] (mm)]}, one frame per replay frame or a single one
for static objects; `scenario` names the run shown in the page's title.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from html import escape as html_escape
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError

LEG_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")
ARM_COLOR = "#17becf"
EXTRA_COLORS = ("#e6194b", "#3cb44b", "#f58231", "#911eb4", "#4363d8", "#808000")


# ----------------------------------------------------------------------------- geometry
def _root_bodies(model: pin.Model) -> list[int]:
    return [i for i, f in enumerate(model.frames) if f.parentJoint == 1 and f.type == pin.FrameType.BODY]


def base_box(robot) -> tuple[pin.SE3, np.ndarray]:
    """Placement of the base box in the root-joint frame and its half sizes.

    The largest URDF collision box of a link on the root body when there is one, else a box
    spanning the origins of the root's child joints.
    """
    model = robot.model
    best: tuple[float, pin.SE3, np.ndarray] | None = None
    try:
        links = {link.get("name"): link for link in ET.parse(Path(robot.spec.urdf)).getroot().iter("link")}
    except (ET.ParseError, OSError, AttributeError):
        links = {}
    for fid in _root_bodies(model):
        link = links.get(model.frames[fid].name)
        if link is None:
            continue
        for collision in link.iter("collision"):
            box = collision.find("geometry/box")
            if box is None:
                continue
            half = 0.5 * np.array([float(x) for x in box.get("size", "0 0 0").split()])
            origin = collision.find("origin")
            xyz = np.array([float(x) for x in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
            rpy = np.array([float(x) for x in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
            volume = float(np.prod(half))
            if best is None or volume > best[0]:
                best = (volume, model.frames[fid].placement * pin.SE3(pin.rpy.rpyToMatrix(rpy), xyz), half)
    if best is not None and best[0] > 1e-6:
        return best[1], best[2]
    children = [model.jointPlacements[j].translation for j in range(2, model.njoints) if model.parents[j] == 1]
    if not children:
        return pin.SE3.Identity(), np.array([0.1, 0.05, 0.04])
    pts = np.array(children)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    half = np.maximum(0.5 * (hi - lo), 0.03)
    half[2] = max(half[2], 0.25 * min(half[0], half[1]), 0.03)
    return pin.SE3(np.eye(3), 0.5 * (hi + lo)), half


_BOX_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
_BOX_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(_BOX_SIGNS[a] != _BOX_SIGNS[b]) == 1]


def _skeleton(robot) -> dict[str, Any]:
    """Point names/kinds, links [i, j, group] and groups (one per leg, then the arm)."""
    model = robot.model
    names: list[str] = [model.names[j] for j in range(1, model.njoints)]
    kinds: list[str] = ["joint"] * len(names)
    point_of_joint = {j: j - 1 for j in range(1, model.njoints)}

    group_of_joint: dict[int, int] = {}
    for g, foot in enumerate(robot.feet):
        joint = model.frames[robot.frame_id(foot)].parentJoint
        while joint > 1:
            group_of_joint.setdefault(joint, g)
            joint = model.parents[joint]
    arm_group = len(robot.feet)
    groups = [{"name": foot, "color": LEG_COLORS[g % len(LEG_COLORS)]} for g, foot in enumerate(robot.feet)]
    groups.append({"name": "arm" if robot.arm_ee else "other", "color": ARM_COLOR})

    links: list[list[int]] = []
    for j in range(2, model.njoints):
        parent = model.parents[j]
        if parent >= 1:
            links.append([point_of_joint[parent], point_of_joint[j], group_of_joint.get(j, arm_group)])
    feet_idx = []
    for g, foot in enumerate(robot.feet):
        names.append(foot)
        kinds.append("foot")
        feet_idx.append(len(names) - 1)
        parent = model.frames[robot.frame_id(foot)].parentJoint
        links.append([point_of_joint[parent], feet_idx[-1], g])
    ee_idx = None
    if robot.arm_ee:
        names.append(robot.arm_ee)
        kinds.append("ee")
        ee_idx = len(names) - 1
        parent = model.frames[robot.frame_id(robot.arm_ee)].parentJoint
        links.append([point_of_joint[parent], ee_idx, group_of_joint.get(parent, arm_group)])
    box_start = len(names)
    names.extend(f"base_box_{k}" for k in range(8))
    kinds.extend(["box"] * 8)
    return {
        "names": names,
        "kinds": kinds,
        "links": links,
        "groups": groups,
        "feet": feet_idx,
        "ee": ee_idx,
        "base": 0,
        "box_edges": [[box_start + a, box_start + b] for a, b in _BOX_EDGES],
    }


def _frame_samples(time_s: np.ndarray, fps: float) -> tuple[np.ndarray, float]:
    """Indices of the samples shown at t0 + k / fps (nearest in time) and the run duration."""
    if time_s.size > 1:
        step = float(np.median(np.diff(time_s)))
        duration = float(time_s[-1] - time_s[0]) + step
    else:
        duration = 1.0 / fps
    n_frames = max(1, int(round(duration * fps)))
    wanted = time_s[0] + np.arange(n_frames) / fps
    return _nearest(time_s, wanted), duration


def _normalise_extras(extras, time_s: np.ndarray) -> list[tuple[str, Any, str | None]]:
    out = []
    for k, item in enumerate(extras or []):
        if isinstance(item, dict):
            name = item.get("name", f"extra {k}")
            positions = item.get("positions", item.get("points"))
            color = item.get("color")
        else:
            name, positions = item[0], item[1]
            color = item[2] if len(item) > 2 else None
        if positions is None:
            raise ConfigError(f"extra trajectory '{name}' has no positions")
        if not callable(positions):
            positions = np.asarray(positions, dtype=float)
            if positions.shape != (time_s.size, 3):
                raise ConfigError(
                    f"extra trajectory '{name}' has shape {positions.shape}; expected ({time_s.size}, 3), "
                    "one world point per time sample (or a callable t -> (3,))"
                )
        out.append((str(name), positions, color))
    return out


def _nearest(times: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    right = np.clip(np.searchsorted(times, wanted), 0, times.size - 1)
    left = np.clip(right - 1, 0, times.size - 1)
    return np.where(np.abs(times[left] - wanted) <= np.abs(times[right] - wanted), left, right)


def _objects(objects: Sequence[dict] | None, frame_times: np.ndarray) -> list[dict]:
    """Scene objects sampled at the replay's frame times (see the module docstring)."""
    out = []
    for k, obj in enumerate(objects or []):
        name, kind = str(obj.get("name", f"object {k}")), obj.get("kind")
        times = obj.get("t")
        index = None if times is None else _nearest(np.asarray(times, dtype=float), frame_times)
        if kind == "box":
            half = np.asarray(obj["half_size_m"], dtype=float).reshape(3)
            position = np.asarray(obj["position_m"], dtype=float).reshape(-1, 3)
            rotation = np.asarray(obj.get("rotation", np.eye(3)), dtype=float).reshape(-1, 9)
            if index is not None:
                position, rotation = position[index], rotation[index]
            frames = [np.rint(1e3 * p).astype(int).tolist() + np.round(r, 3).tolist() for p, r in zip(position, rotation)]
            out.append({"name": name, "kind": "box", "color": obj.get("color", "#999999"),
                        "half": np.rint(1e3 * half).astype(int).tolist(), "frames": frames})
        elif kind == "line":
            points = np.asarray(obj["points_m"], dtype=float).reshape(-1, 6)
            if index is not None:
                points = points[index]
            out.append({"name": name, "kind": "line", "color": obj.get("color", "#222222"),
                        "frames": np.rint(1e3 * points).astype(int).tolist()})
        else:
            raise ConfigError(f"scene object '{name}' has kind {kind!r}; the replay draws 'box' and 'line'")
    return out


def replay_data(robot, time_s, q, fps: float = 30, extras: Sequence | None = None,
                objects: Sequence[dict] | None = None, scenario: str | None = None) -> dict[str, Any]:
    """The JSON-ready replay content (see the module docstring for its layout)."""
    time_s = np.asarray(time_s, dtype=float).ravel()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if not fps > 0:
        raise ConfigError(f"fps must be positive, got {fps}")
    if time_s.size == 0:
        raise ConfigError("the replay needs at least one sample")
    if q.shape != (time_s.size, robot.nq):
        raise ConfigError(f"q has shape {q.shape}; expected ({time_s.size}, {robot.nq}) for robot '{robot.name}'")
    if np.any(np.diff(time_s) < 0):
        raise ConfigError("time_s must be non-decreasing")
    skeleton = _skeleton(robot)
    samples, duration = _frame_samples(time_s, fps)
    model, data = robot.model, robot.model.createData()
    frame_ids = [robot.frame_id(n) for n, kind in zip(skeleton["names"], skeleton["kinds"]) if kind in ("foot", "ee")]
    box_placement, half = base_box(robot)
    corners_local = box_placement.translation + (box_placement.rotation @ (_BOX_SIGNS * half).T).T
    frames = []
    for idx in samples:
        pin.forwardKinematics(model, data, q[idx])
        points = [data.oMi[j].translation for j in range(1, model.njoints)]
        points += [pin.updateFramePlacement(model, data, fid).translation for fid in frame_ids]
        base = data.oMi[1]
        points += list((base.rotation @ corners_local.T).T + base.translation)
        frames.append(np.rint(1e3 * np.asarray(points)).astype(int).ravel().tolist())

    extra_out = []
    for k, (name, positions, color) in enumerate(_normalise_extras(extras, time_s)):
        pts = []
        for idx in samples:
            p = np.asarray(positions(float(time_s[idx])) if callable(positions) else positions[idx], dtype=float).ravel()
            pts.append(np.rint(1e3 * p[:3]).astype(int).tolist() if p.size >= 3 and np.all(np.isfinite(p[:3])) else None)
        extra_out.append({"name": name, "color": color or EXTRA_COLORS[k % len(EXTRA_COLORS)], "frames": pts})

    return {
        "version": 1,
        "robot": robot.name,
        "fps": float(fps),
        "n_frames": len(frames),
        "duration_s": round(duration, 6),
        "t": [round(float(time_s[i]), 4) for i in samples],
        "foot_radius_m": float(getattr(robot, "foot_radius_m", 0.02)),
        **skeleton,
        "frames": frames,
        "extras": extra_out,
        "objects": _objects(objects, time_s[samples]),
        "scenario": scenario,
    }


def save_replay(robot, time_s, q, out_path, fps: float = 30, extras: Sequence | None = None,
                objects: Sequence[dict] | None = None, scenario: str | None = None) -> Path:
    """Write the HTML replay of configurations `q` (n, nq) at times `time_s` (n,) and return its path.

    `extras`: optional named world-point trajectories drawn as coloured dots with a trail, each
    `{"name": str, "positions": (n, 3) array or callable t -> (3,), "color": "#rrggbb"}` or a
    `(name, positions[, color])` tuple; non-finite points are not drawn. `objects`: the scene's
    boxes and lines (`Scene.replay_objects()`); `scenario`: the run's name, shown in the title.
    """
    payload = replay_data(robot, time_s, q, fps, extras, objects, scenario)
    blob = json.dumps(payload, separators=(",", ":")).replace("</", "<\\/")
    title = f"wbmpc replay: {scenario} ({robot.name})" if scenario else f"wbmpc replay: {robot.name}"
    html = _TEMPLATE.replace("__TITLE__", html_escape(title)).replace("__DATA__", blob)
    path = Path(out_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html, encoding="utf-8")
    return path


_TEMPLATE = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>__TITLE__</title>
<style>
  html, body { margin: 0; height: 100%; background: #f4f5f7; font: 13px system-ui, sans-serif; color: #222; overflow: hidden; }
  #view { position: absolute; left: 0; top: 0; right: 0; bottom: 44px; }
  canvas { width: 100%; height: 100%; display: block; cursor: grab; }
  canvas.dragging { cursor: grabbing; }
  #bar { position: absolute; left: 0; right: 0; bottom: 0; height: 44px; display: flex; align-items: center; gap: 10px;
         padding: 0 12px; background: #fff; border-top: 1px solid #ccd; box-sizing: border-box; }
  #bar button { min-width: 70px; height: 28px; font-size: 13px; }
  #slider { flex: 1; }
  #time { font-variant-numeric: tabular-nums; min-width: 150px; text-align: right; }
  #info { position: absolute; left: 12px; top: 8px; pointer-events: none; }
  #info b { font-size: 15px; }
  #info span { color: #666; }
  #legend { position: absolute; right: 12px; top: 8px; background: rgba(255,255,255,0.85); padding: 6px 9px;
            border-radius: 4px; pointer-events: none; line-height: 1.5; }
  .sw { display: inline-block; width: 11px; height: 11px; border-radius: 50%; margin-right: 5px; vertical-align: -1px; }
</style>
</head>
<body>
<div id="view"><canvas id="c"></canvas>
  <div id="info"><b id="title"></b><br><span>drag: rotate &middot; wheel: zoom &middot; space: play/pause &middot; &larr;/&rarr;: step</span></div>
  <div id="legend"></div>
</div>
<div id="bar">
  <button id="play">Pause</button>
  <input id="slider" type="range" min="0" max="0" value="0" step="1">
  <span id="time"></span>
  <label>speed <select id="speed">
    <option value="0.1">0.1&times;</option><option value="0.25">0.25&times;</option><option value="0.5">0.5&times;</option>
    <option value="1" selected>1&times;</option><option value="2">2&times;</option><option value="4">4&times;</option>
  </select></label>
  <label><input id="follow" type="checkbox" checked> follow base</label>
</div>
<script id="replay-data" type="application/json">__DATA__</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("replay-data").textContent);
const canvas = document.getElementById("c"), ctx = canvas.getContext("2d");
const slider = document.getElementById("slider"), playBtn = document.getElementById("play");
const timeEl = document.getElementById("time"), speedEl = document.getElementById("speed");
const followEl = document.getElementById("follow");
const N = D.n_frames, NP = D.names.length;
document.getElementById("title").textContent = "wbmpc replay: " + (D.scenario ? D.scenario + " (" + D.robot + ")" : D.robot);
slider.max = String(N - 1);

// legend
(function () {
  const used = new Set(D.links.map(l => l[2]));
  const rows = D.groups.filter((g, k) => used.has(k)).map(g => [g.color, g.name])
    .concat(D.extras.map(e => [e.color, e.name])).concat(D.objects.map(o => [o.color, o.name]));
  document.getElementById("legend").innerHTML = rows.map(r =>
    '<div><span class="sw" style="background:' + r[0] + '"></span>' + escapeHtml(r[1]) + "</div>").join("");
})();
function escapeHtml(s) { return String(s).replace(/[&<>"']/g, c => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c])); }

function P(f, i) { const a = D.frames[f]; return [a[3 * i] / 1e3, a[3 * i + 1] / 1e3, a[3 * i + 2] / 1e3]; }
function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
function norm(a) { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }

// camera: orbit around a target that follows the base
let yaw = -1.2, pitch = 0.38, dist = 2.5;
(function () {  // fit the first frame
  const b = P(0, D.base); let r = 0.3;
  for (let i = 0; i < NP; i++) { const p = P(0, i); r = Math.max(r, Math.hypot(p[0] - b[0], p[1] - b[1], p[2] - b[2])); }
  dist = Math.min(Math.max(4.0 * r, 1.2), 20);
})();
let target = P(0, D.base);
const cam = {eye: [0, 0, 0], f: [1, 0, 0], r: [0, 1, 0], u: [0, 0, 1], focal: 500, W: 1, H: 1};
const NEAR = 0.05;
function setupCamera(W, H) {
  const cp = Math.cos(pitch), sp = Math.sin(pitch);
  cam.eye = [target[0] + dist * cp * Math.cos(yaw), target[1] + dist * cp * Math.sin(yaw), target[2] + dist * sp];
  cam.f = norm(sub(target, cam.eye));
  cam.r = norm(cross(cam.f, [0, 0, 1]));
  cam.u = cross(cam.r, cam.f);
  cam.W = W; cam.H = H; cam.focal = 0.5 * H / Math.tan(0.5 * 45 * Math.PI / 180);
}
function toCam(p) { const d = sub(p, cam.eye); return [dot(d, cam.r), dot(d, cam.u), dot(d, cam.f)]; }
function screen(c) { return [cam.W / 2 + cam.focal * c[0] / c[2], cam.H / 2 - cam.focal * c[1] / c[2]]; }
function project(p) { const c = toCam(p); return c[2] < NEAR ? null : [...screen(c), c[2]]; }
function segment(a, b) {  // clipped to the near plane: [x0, y0, x1, y1, depth] or null
  let ca = toCam(a), cb = toCam(b);
  if (ca[2] < NEAR && cb[2] < NEAR) return null;
  if (ca[2] < NEAR || cb[2] < NEAR) {
    const s = (NEAR - ca[2]) / (cb[2] - ca[2]);
    const m = [ca[0] + s * (cb[0] - ca[0]), ca[1] + s * (cb[1] - ca[1]), NEAR];
    if (ca[2] < NEAR) ca = m; else cb = m;
  }
  const sa = screen(ca), sb = screen(cb);
  return [sa[0], sa[1], sb[0], sb[1], 0.5 * (ca[2] + cb[2])];
}

// playback state
let frame = 0, playing = true, playT = 0, last = null;
function setFrame(k) { frame = Math.max(0, Math.min(N - 1, k)); playT = frame / D.fps; }
function togglePlay() { playing = !playing; playBtn.textContent = playing ? "Pause" : "Play"; last = null; }
playBtn.onclick = togglePlay;
slider.oninput = () => { setFrame(parseInt(slider.value, 10)); };
window.addEventListener("keydown", e => {
  if (e.code === "Space") { togglePlay(); e.preventDefault(); }
  else if (e.code === "ArrowRight") { if (playing) togglePlay(); setFrame(frame + 1); }
  else if (e.code === "ArrowLeft") { if (playing) togglePlay(); setFrame(frame - 1); }
});

// mouse: drag rotates, wheel zooms
let drag = null;
canvas.addEventListener("mousedown", e => { drag = [e.clientX, e.clientY]; canvas.classList.add("dragging"); });
window.addEventListener("mouseup", () => { drag = null; canvas.classList.remove("dragging"); });
window.addEventListener("mousemove", e => {
  if (!drag) return;
  yaw -= 0.008 * (e.clientX - drag[0]);
  pitch = Math.max(-0.15, Math.min(1.5, pitch + 0.008 * (e.clientY - drag[1])));
  drag = [e.clientX, e.clientY];
});
canvas.addEventListener("wheel", e => {
  dist = Math.max(0.3, Math.min(40, dist * Math.exp(0.0012 * e.deltaY))); e.preventDefault();
}, {passive: false});

function linkWidth(depth, radius) { return Math.max(1.5, 2 * radius * cam.focal / depth); }

function draw() {
  const dpr = window.devicePixelRatio || 1;
  const W = canvas.clientWidth, H = canvas.clientHeight;
  if (canvas.width !== Math.round(W * dpr) || canvas.height !== Math.round(H * dpr)) {
    canvas.width = Math.round(W * dpr); canvas.height = Math.round(H * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  const base = P(frame, D.base);
  if (followEl.checked) target = [base[0], base[1], 0.6 * base[2]];
  setupCamera(W, H);
  const sky = ctx.createLinearGradient(0, 0, 0, H);
  sky.addColorStop(0, "#e9eef5"); sky.addColorStop(1, "#f8f8f6");
  ctx.fillStyle = sky; ctx.fillRect(0, 0, W, H);
  ctx.lineCap = "round"; ctx.lineJoin = "round";

  // ground grid (fixed in the world, so walking is visible), fading with distance
  const step = 0.25, reach = Math.max(3, 1.5 * dist), gx = Math.round(target[0] / step) * step, gy = Math.round(target[1] / step) * step;
  const n = Math.ceil(reach / step);
  for (let i = -n; i <= n; i++) {
    for (let j = -n; j < n; j++) {
      for (const dir of [0, 1]) {
        const a = dir ? [gx + i * step, gy + j * step, 0] : [gx + j * step, gy + i * step, 0];
        const b = dir ? [a[0], a[1] + step, 0] : [a[0] + step, a[1], 0];
        const dd = Math.hypot(0.5 * (a[0] + b[0]) - target[0], 0.5 * (a[1] + b[1]) - target[1]);
        const alpha = Math.max(0, 1 - dd / reach);
        if (alpha <= 0) continue;
        const s = segment(a, b); if (!s) continue;
        const major = dir ? Math.abs(Math.round(a[0] / step) % 4) === 0 : Math.abs(Math.round(a[1] / step) % 4) === 0;
        ctx.strokeStyle = "rgba(90,100,120," + (alpha * (major ? 0.55 : 0.25)).toFixed(3) + ")";
        ctx.lineWidth = major ? 1.2 : 0.7;
        ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[2], s[3]); ctx.stroke();
      }
    }
  }

  // shadows (links projected on the ground)
  ctx.strokeStyle = "rgba(0,0,0,0.13)";
  for (const [i, j] of D.links) {
    const a = P(frame, i), b = P(frame, j);
    const s = segment([a[0], a[1], 0.001], [b[0], b[1], 0.001]); if (!s) continue;
    ctx.lineWidth = linkWidth(s[4], 0.03);
    ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[2], s[3]); ctx.stroke();
  }

  // scene objects (boxes: faces far to near, then edges; lines: cables), under the robot
  const faces = [];
  for (const o of D.objects) {
    const f = o.frames.length === 1 ? o.frames[0] : o.frames[frame];
    if (!f) continue;
    if (o.kind === "line") {
      const s = segment([f[0] / 1e3, f[1] / 1e3, f[2] / 1e3], [f[3] / 1e3, f[4] / 1e3, f[5] / 1e3]);
      if (s) faces.push({d: s[4], line: s, color: o.color});
      continue;
    }
    const c = [f[0] / 1e3, f[1] / 1e3, f[2] / 1e3], R = f.slice(3), h = o.half.map(x => x / 1e3);
    const corner = (sx, sy, sz) => [0, 1, 2].map(r => c[r] + R[3 * r] * sx * h[0] + R[3 * r + 1] * sy * h[1] + R[3 * r + 2] * sz * h[2]);
    const quads = [[[-1,-1,-1],[1,-1,-1],[1,1,-1],[-1,1,-1]], [[-1,-1,1],[1,-1,1],[1,1,1],[-1,1,1]],
                   [[-1,-1,-1],[1,-1,-1],[1,-1,1],[-1,-1,1]], [[-1,1,-1],[1,1,-1],[1,1,1],[-1,1,1]],
                   [[-1,-1,-1],[-1,1,-1],[-1,1,1],[-1,-1,1]], [[1,-1,-1],[1,1,-1],[1,1,1],[1,-1,1]]];
    for (const quad of quads) {
      const pts = quad.map(v => project(corner(v[0], v[1], v[2])));
      if (pts.some(p => !p)) continue;
      faces.push({d: pts.reduce((a, p) => a + p[2], 0) / 4, quad: pts, color: o.color});
    }
  }
  faces.sort((a, b) => b.d - a.d);
  for (const f of faces) {
    if (f.line) {
      ctx.strokeStyle = f.color; ctx.lineWidth = 2.5;
      ctx.beginPath(); ctx.moveTo(f.line[0], f.line[1]); ctx.lineTo(f.line[2], f.line[3]); ctx.stroke();
      continue;
    }
    ctx.beginPath(); ctx.moveTo(f.quad[0][0], f.quad[0][1]);
    for (let k = 1; k < 4; k++) ctx.lineTo(f.quad[k][0], f.quad[k][1]);
    ctx.closePath();
    ctx.globalAlpha = 0.55; ctx.fillStyle = f.color; ctx.fill(); ctx.globalAlpha = 1;
    ctx.strokeStyle = "rgba(40,40,40,0.8)"; ctx.lineWidth = 1; ctx.stroke();
  }

  // depth-sorted robot drawables
  const items = [];
  for (const [i, j, g] of D.links) {
    const s = segment(P(frame, i), P(frame, j));
    if (s) items.push({d: s[4], kind: "link", s: s, color: D.groups[g].color});
  }
  for (const [i, j] of D.box_edges) {
    const s = segment(P(frame, i), P(frame, j));
    if (s) items.push({d: s[4], kind: "edge", s: s});
  }
  for (let i = 0; i < NP; i++) {
    const kind = D.kinds[i]; if (kind === "box") continue;
    const p = P(frame, i), s = project(p); if (!s) continue;
    items.push({d: s[2] - 1e-3, kind: kind, s: s, z: p[2]});
  }
  D.extras.forEach(e => {
    const p = e.frames[frame]; if (!p) return;
    const s = project([p[0] / 1e3, p[1] / 1e3, p[2] / 1e3]); if (s) items.push({d: s[2] - 2e-3, kind: "extra", s: s, color: e.color});
  });
  items.sort((a, b) => b.d - a.d);

  // extra trails (last second) under the robot
  D.extras.forEach(e => {
    const k0 = Math.max(0, frame - Math.round(D.fps));
    let prev = null;
    for (let k = k0; k <= frame; k++) {
      const p = e.frames[k]; if (!p) { prev = null; continue; }
      const q = [p[0] / 1e3, p[1] / 1e3, p[2] / 1e3];
      if (prev) {
        const s = segment(prev, q);
        if (s) {
          ctx.strokeStyle = e.color; ctx.globalAlpha = 0.15 + 0.6 * (k - k0) / Math.max(1, frame - k0);
          ctx.lineWidth = 2.5; ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[2], s[3]); ctx.stroke();
        }
      }
      prev = q;
    }
    ctx.globalAlpha = 1;
  });

  for (const it of items) {
    const s = it.s;
    if (it.kind === "link") {
      ctx.strokeStyle = "#2b2b2b"; ctx.lineWidth = linkWidth(s[4], 0.03) + 2;
      ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[2], s[3]); ctx.stroke();
      ctx.strokeStyle = it.color; ctx.lineWidth = linkWidth(s[4], 0.03);
      ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[2], s[3]); ctx.stroke();
    } else if (it.kind === "edge") {
      ctx.strokeStyle = "#333a44"; ctx.lineWidth = Math.max(1.5, linkWidth(s[4], 0.006));
      ctx.beginPath(); ctx.moveTo(s[0], s[1]); ctx.lineTo(s[2], s[3]); ctx.stroke();
    } else {
      const r = it.kind === "foot" ? linkWidth(s[2], D.foot_radius_m) / 2 + 1 : it.kind === "ee" ? linkWidth(s[2], 0.03) / 2 + 1
              : it.kind === "extra" ? Math.max(4, linkWidth(s[2], 0.02) / 2) : linkWidth(s[2], 0.022) / 2;
      ctx.beginPath(); ctx.arc(s[0], s[1], r, 0, 2 * Math.PI);
      if (it.kind === "foot") {  // filled when touching the ground
        const contact = it.z - D.foot_radius_m < 0.01;
        ctx.fillStyle = contact ? "#111" : "#fff"; ctx.fill();
        ctx.lineWidth = 2; ctx.strokeStyle = "#111"; ctx.stroke();
      } else if (it.kind === "ee") {
        ctx.fillStyle = "#f1c40f"; ctx.fill(); ctx.lineWidth = 2; ctx.strokeStyle = "#333"; ctx.stroke();
      } else if (it.kind === "extra") {
        ctx.fillStyle = it.color; ctx.fill(); ctx.lineWidth = 1.5; ctx.strokeStyle = "#fff"; ctx.stroke();
      } else {
        ctx.fillStyle = "#dfe3e8"; ctx.fill(); ctx.lineWidth = 1.2; ctx.strokeStyle = "#333"; ctx.stroke();
      }
    }
  }
  slider.value = String(frame);
  const t0 = D.t[0];
  timeEl.textContent = "t = " + (D.t[frame] - t0).toFixed(3) + " / " + D.duration_s.toFixed(3) + " s";
}

function loop(ts) {
  if (playing) {
    if (last !== null) {
      playT += (ts - last) / 1000 * parseFloat(speedEl.value);
      if (playT >= N / D.fps) playT = 0;
      frame = Math.min(N - 1, Math.floor(playT * D.fps));
    }
    last = ts;
  }
  draw();
  requestAnimationFrame(loop);
}
draw();
requestAnimationFrame(loop);
</script>
</body>
</html>
"""
