"""Capsule distances in CasADi SX: the collision avoidance rows of the OCP (beyond the paper).

Capsule end points are placed by forward kinematics in the base frame (a distance between two links does
not depend on where the base is, so these rows read the joint angles only); against an obstacle, fixed
in the world, the robot's capsule is placed in the world (those rows read the base pose too). The distance of two segments uses the
clamped closest points written without branches,

    s = clamp((b f - c e) / (a e - b^2)), t = clamp((b s + f) / e), s = clamp((b t - c) / a),

(the segment-segment test of Ericson, Real-Time Collision Detection, 5.1.9, with its "recompute s"
step applied always: where t was not clamped it gives s back). The squared distance has the gradient
of the closest points (envelope theorem: the clamps' own derivatives drop out), parallel segments
included (their numerator vanishes with the denominator); the surface distance sqrt(d^2 + eps^2) - r1 - r2
keeps a finite gradient when two axes cross.

Each row is the smooth minimum of the distances of one group of pairs (`CollisionPair.group`: one arm
body against the base and the legs, or two legs), -log(sum exp(-k d_i)) / k with k = SOFTMIN_SHARPNESS_1_M:
never above the smallest distance, within log(n) / k of it (7 mm for two pairs equally close, none
when one pair is 5 cm closer than the rest). One row per group keeps the OCP small: Fatrop's cost grows
with the rows of a stage, not with the pairs behind them.
"""

from __future__ import annotations

import casadi as ca

from wbmpc.robots.collision_model import Capsule, CollisionModel
from wbmpc.symbolic import spatial as sp
from wbmpc.symbolic.dynamics import Configuration, SymbolicDynamics

SOFTMIN_SHARPNESS_1_M = 100.0
DISTANCE_EPS_M = 1e-4  # sqrt(d^2 + eps^2): smooth where the segments cross
DENOMINATOR_EPS = 1e-12


def _clamp(x):
    return ca.fmin(ca.fmax(x, 0.0), 1.0)


def segment_distance_sq(p0, p1, q0, q1, first_point: bool = False, second_point: bool = False) -> ca.SX:
    """Squared distance of segments [p0, p1] and [q0, q1] (a point when its flag is set: a sphere)."""
    r = p0 - q0
    if first_point and second_point:
        return ca.dot(r, r)
    if first_point:  # point p0 against segment q
        d2 = q1 - q0
        t = _clamp(-ca.dot(d2, r) / ca.dot(d2, d2))
        diff = r - t * d2
        return ca.dot(diff, diff)
    if second_point:
        d1 = p1 - p0
        s = _clamp(-ca.dot(d1, r) / ca.dot(d1, d1))
        diff = r + s * d1
        return ca.dot(diff, diff)
    d1, d2 = p1 - p0, q1 - q0
    a, e, b = ca.dot(d1, d1), ca.dot(d2, d2), ca.dot(d1, d2)
    c, f = ca.dot(d1, r), ca.dot(d2, r)
    s = _clamp((b * f - c * e) / (a * e - b * b + DENOMINATOR_EPS))
    t = _clamp((b * s + f) / e)
    s = _clamp((b * t - c) / a)
    diff = r + s * d1 - t * d2
    return ca.dot(diff, diff)


def base_frame_placements(cfg: Configuration, joints: set[int]) -> dict[int, tuple[ca.SX, ca.SX]]:
    """(rotation, position) of each joint frame in `joints` in the base frame (joint 1)."""
    dyn = cfg.dyn
    out: dict[int, tuple[ca.SX, ca.SX]] = {1: (None, ca.SX.zeros(3))}
    for j in sorted(j for joint in joints for j in dyn.chain(joint) if j > 1):
        if j in out:
            continue
        parent_rot, parent_pos = out[dyn.joints[j].parent]
        if parent_rot is None:  # the base: identity
            out[j] = (cfg.local_rotation[j], cfg.local_translation[j])
        else:
            out[j] = (ca.mtimes(parent_rot, cfg.local_rotation[j]), parent_pos + ca.mtimes(parent_rot, cfg.local_translation[j]))
    return out


def _ends(placements, capsule: Capsule) -> tuple[ca.SX, ca.SX]:
    rot, pos = placements[capsule.joint_id]
    if rot is None:
        return sp.const(capsule.start_m), sp.const(capsule.end_m)
    return pos + ca.mtimes(rot, sp.const(capsule.start_m)), pos + ca.mtimes(rot, sp.const(capsule.end_m))


def _world(cfg: Configuration, point: ca.SX) -> ca.SX:
    return cfg.base_position + ca.mtimes(cfg.base_rotation, point)


def pair_distances(model: CollisionModel, cfg: Configuration) -> ca.SX:
    """Surface distance (m) of every checked pair of `model` at configuration `cfg`."""
    joints = {c.joint_id for pair in model.pairs for c in (pair.first, pair.second) if c.joint_id > 0}
    placements = base_frame_placements(cfg, joints)
    ends, world = {}, {}
    out = []
    for pair in model.pairs:
        for c in (pair.first, pair.second):
            if c.name not in ends:
                ends[c.name] = _ends(placements, c) if c.joint_id > 0 else (sp.const(c.start_m), sp.const(c.end_m))
        if pair.second.joint_id == 0:  # an obstacle: in the world frame, the robot's capsule placed there
            if pair.first.name not in world:
                world[pair.first.name] = tuple(_world(cfg, p) for p in ends[pair.first.name])
            (p0, p1), (q0, q1) = world[pair.first.name], ends[pair.second.name]
        else:
            (p0, p1), (q0, q1) = ends[pair.first.name], ends[pair.second.name]
        d_sq = segment_distance_sq(p0, p1, q0, q1, pair.first.is_sphere, pair.second.is_sphere)
        out.append(ca.sqrt(d_sq + DISTANCE_EPS_M**2) - pair.first.radius_m - pair.second.radius_m)
    return ca.vertcat(*out)


def softmin(values: ca.SX, sharpness: float = SOFTMIN_SHARPNESS_1_M) -> ca.SX:
    """-log(sum exp(-k v)) / k: smooth, never above min(v), within log(n) / k of it."""
    if values.shape[0] == 1:
        return values
    return -ca.log(ca.sum1(ca.exp(-sharpness * values))) / sharpness


def collision_rows(model: CollisionModel, cfg: Configuration) -> ca.SX:
    """One row per pair group (`CollisionModel.groups`): the smooth minimum of its distances (m), >= margin."""
    distances = pair_distances(model, cfg)
    return ca.vertcat(*[softmin(distances[idx]) for idx in model.groups.values()])


def collision_function(model: CollisionModel, dyn: SymbolicDynamics) -> ca.Function:
    """q (pinocchio layout) -> (pair distances, group rows), to evaluate the rows numerically."""
    q = ca.SX.sym("q", dyn.nq)
    cfg = dyn.configuration(q)
    distances = pair_distances(model, cfg)
    rows = ca.vertcat(*[softmin(distances[idx]) for idx in model.groups.values()])
    return ca.Function("collision", [q], [distances, rows], ["q"], ["distances", "rows"])
