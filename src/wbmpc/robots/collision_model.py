"""Capsules of a robot's links and the pairs of them that collision avoidance checks (beyond the paper).

Chosen once per robot from the URDF's collision geometry as pinocchio reads it (`pin.buildGeomFromUrdf`,
the same placements pinocchio's and coal's collision checking use), in the frame of the pinocchio joint
that carries each link:

- sphere: itself (a capsule of zero length); capsule: itself; cylinder: the capsule of the same radius
  and axis (it contains the cylinder);
- box with half sizes a >= b >= c: a thick bar (b < 1.5 c) becomes one capsule along its longest axis
  of radius sqrt(b^2 + c^2) (its cross-section's circumcircle); a flat box (the trunk) becomes ceil(b / c)
  capsules of radius c side by side, flush with its large faces. Caps end at the end faces' centres,
  so corners and edges are rounded off by up to a few centimetres: the distance margin covers them;
- mesh: the capsule around its bounding box (as a thick bar, of half length a: it contains the mesh).

Capsules inside another capsule of the same body and shapes under 5 mm are dropped. Obstacles
(`CollisionConfig.obstacles`, boxes in the world) become capsules the same way. Links without any
collision geometry are skipped and listed (`skipped_links`).

Pairs: the capsules of the arm's last `arm_bodies` bodies (forearm and hand) against the base and the
legs, and the last two bodies of each leg against those of the other legs (leg vs leg, swing foot vs
stance leg). Left out: capsules of one body or of a parent and child body (adjacent in the kinematic
tree), pairs closer than margin + `nominal_clearance_m` at the nominal pose (neighbours by design),
pairs that never come within `reach_slack_m` of the margin over `reach_samples` random joint
configurations (they cannot collide) and pairs at a constant distance. Every pair costs: its exact
Hessian is ~2500 instructions per node (capsule against capsule), so the selection stays lean.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError, ModelError, check_number
from wbmpc.robots.model import RobotModel

log = logging.getLogger(__name__)

MIN_SHAPE_SIZE_M = 0.005  # shapes smaller than this in every direction (IMU boxes) are dropped
THICK_BAR_RATIO = 2.0  # a box whose middle half size is below this times its smallest is one capsule
MERGE_RADIUS_RATIO = 1.25  # a body's capsules become one when its radius stays within this of the largest


class CollisionError(ConfigError):
    """The robot starts in collision: a checked pair of capsules is closer than the margin."""


@dataclass(frozen=True)
class Obstacle:
    """A box fixed in the world (a wall, a table): centre and half sizes along the world axes (m)."""

    name: str
    centre_m: tuple[float, float, float]
    half_size_m: tuple[float, float, float]
    keep_off: tuple[str, ...] = ("arm", "feet")  # what it is kept off: the arm's checked bodies, each leg's last body

    def __post_init__(self):
        if len(self.centre_m) != 3 or len(self.half_size_m) != 3 or min(self.half_size_m) <= 0 \
                or not np.all(np.isfinite(self.centre_m)):
            raise ConfigError(f"obstacle {self.name!r}: centre_m needs 3 finite numbers and half_size_m 3 positive "
                              f"ones, got {self.centre_m} and {self.half_size_m}")
        if not self.keep_off or not set(self.keep_off) <= {"arm", "feet"}:
            raise ConfigError(f"obstacle {self.name!r}: keep_off takes 'arm' and/or 'feet', got {self.keep_off}")


@dataclass(frozen=True)
class CollisionConfig:
    """What collision avoidance checks (changing it rebuilds the OCP)."""

    margin_m: float = 0.03  # smallest distance kept between two capsules
    arm_vs_body: bool = True  # arm capsules against the base and the legs
    arm_bodies: int = 2  # ... of the last this many bodies with capsules of the arm's chain (forearm and hand)
    nominal_clearance_m: float = 0.01  # pairs closer than margin + this at the nominal pose are neighbours (left out)
    leg_vs_leg: bool = True  # the last two bodies of each leg against those of the other legs
    reach_samples: int = 800  # random joint configurations that decide which pairs can meet: the arm's joints
    # anywhere within their limits, the legs' within this of the nominal pose (trotting, stepping after a push)
    leg_range_rad: float = 0.5
    reach_slack_m: float = 0.03  # ... a pair is kept when it came this close to the margin in one of them
    max_pairs_per_group: int = 16  # ... at most this many per OCP row: those closest in the nearest 5 % of samples
    # boxes in the world kept off the arm's checked bodies and the feet (each leg's last body): one row per
    # limb and obstacle (these rows read the base pose too); a scenario's scene boxes (Scenario.obstacles)
    obstacles: tuple[Obstacle, ...] = ()
    seed: int = 0

    def __post_init__(self):
        check_number("margin_m", self.margin_m, low=0.0, high=0.5, unit="m")
        check_number("reach_samples", self.reach_samples, low=0, high=100_000)
        check_number("reach_slack_m", self.reach_slack_m, low=0.0, high=1.0, unit="m")
        check_number("nominal_clearance_m", self.nominal_clearance_m, low=0.0, high=1.0, unit="m")
        check_number("arm_bodies", self.arm_bodies, low=1, high=100)
        check_number("max_pairs_per_group", self.max_pairs_per_group, low=1, high=10_000)
        check_number("leg_range_rad", self.leg_range_rad, low=0.0, high=2 * np.pi, unit="rad")


@dataclass(frozen=True)
class Capsule:
    """A segment [start_m, end_m] (equal for a sphere) swept by a ball of radius_m, in joint `joint_id`'s frame."""

    name: str
    link: str
    joint_id: int
    start_m: np.ndarray
    end_m: np.ndarray
    radius_m: float

    @property
    def is_sphere(self) -> bool:
        return bool(np.allclose(self.start_m, self.end_m, atol=1e-9))

    @property
    def half_length_m(self) -> float:
        return 0.5 * float(np.linalg.norm(self.end_m - self.start_m))


@dataclass(frozen=True)
class CollisionPair:
    first: Capsule
    second: Capsule
    kind: str  # "arm-body" | "leg-leg" | "obstacle" (second: a capsule of the obstacle, joint 0 = the world)
    group: str  # pairs of one group share one OCP row (their smooth minimum): an arm body, or two legs

    @property
    def name(self) -> str:
        return f"{self.first.name} / {self.second.name}"


class CollisionModel:
    """The capsules and checked pairs of `robot` (see the module docstring)."""

    def __init__(self, robot: RobotModel, config: CollisionConfig = CollisionConfig()):
        self.robot = robot
        self.config = config
        self.capsules, self.skipped_links = robot_capsules(robot)
        if self.skipped_links:
            log.info("collision avoidance: links without collision geometry skipped: %s", ", ".join(self.skipped_links))
        self.excluded: dict[str, str] = {}  # pair name -> why it is not checked
        self.pairs = self._choose_pairs() + self._obstacle_pairs()

    # ------------------------------------------------------------------ pair selection
    def _candidates(self) -> list[tuple[Capsule, Capsule, str, str]]:
        robot, model = self.robot, self.robot.model
        legs, arm, arm_checked = self._limbs()
        leg_of = {j: i for i, chain in enumerate(legs) for j in chain if j not in arm}
        distal = {j for chain in legs for j in chain[-2:]}
        names = model.names
        out = []
        for a_index, a in enumerate(self.capsules):
            for b in self.capsules[a_index + 1:]:
                ja, jb = a.joint_id, b.joint_id
                if ja == jb or model.parents[ja] == jb or model.parents[jb] == ja:
                    continue
                if self.config.arm_vs_body and (ja in arm) != (jb in arm) and (ja in arm_checked or jb in arm_checked):
                    arm_capsule, other = (a, b) if ja in arm else (b, a)
                    out.append((arm_capsule, other, "arm-body", f"{names[arm_capsule.joint_id]} vs body"))
                elif (self.config.leg_vs_leg and ja not in arm and jb not in arm and ja in distal and jb in distal
                      and leg_of.get(ja) is not None and leg_of.get(jb) is not None and leg_of[ja] != leg_of[jb]):
                    i, k = sorted((leg_of[ja], leg_of[jb]))
                    out.append((a, b, "leg-leg", f"{robot.feet[i]} vs {robot.feet[k]} legs"))
        return out

    def _limbs(self) -> tuple[list[list[int]], set[int], list[int]]:
        """The legs' joint chains, the arm's joints and its checked bodies (the last `arm_bodies` with capsules)."""
        robot, model = self.robot, self.robot.model
        legs = [_chain(model, model.frames[robot.frame_id(f)].parentJoint) for f in robot.feet]
        arm = set(_chain(model, model.frames[robot.frame_id(robot.arm_ee)].parentJoint)) if robot.arm_ee else set()
        arm_checked = sorted({c.joint_id for c in self.capsules if c.joint_id in arm})[-self.config.arm_bodies:]
        return legs, arm, arm_checked

    def _obstacle_pairs(self) -> list[CollisionPair]:
        """Every capsule of the arm's checked bodies (forearm and hand: one row) and of each leg's last body (a
        row per leg) against every obstacle, as its `keep_off` says. A flat box is ceil(b / c) capsules: a 1 m x
        10 cm wall is 10, so 60 pairs with b1_z1's arm and feet (~2500 Hessian instructions each per node):
        obstacles are for thick boxes today."""
        legs, _, arm_checked = self._limbs()
        limbs = {"arm": [("arm", set(arm_checked))], "feet": [(foot, {chain[-1]}) for foot, chain in zip(self.robot.feet, legs)]}
        pairs = []
        for obstacle in self.config.obstacles:
            pieces = _box_capsules(np.asarray(obstacle.half_size_m, dtype=float), np.asarray(obstacle.centre_m, dtype=float),
                                   bounding=False)
            boxes = [Capsule(f"{obstacle.name}_{k}", obstacle.name, 0, start, end, radius)
                     for k, (start, end, radius) in enumerate(pieces)]
            for label, joints in (limb for kind in obstacle.keep_off for limb in limbs[kind]):
                pairs += [CollisionPair(c, box, "obstacle", f"{label} vs {obstacle.name}")
                          for c in self.capsules if c.joint_id in joints for box in boxes]
        return pairs

    def _choose_pairs(self) -> list[CollisionPair]:
        candidates = self._candidates()
        if not candidates:
            return []
        robot, cfg = self.robot, self.config
        first = [c[0] for c in candidates]
        second = [c[1] for c in candidates]
        nominal = capsule_distances(robot, robot.q_nominal, first, second)
        data = robot.model.createData()
        samples = np.array([capsule_distances(robot, q, first, second, data)
                            for q in random_configurations(robot, cfg.reach_samples, cfg.seed, cfg.leg_range_rad)])
        samples = samples if len(samples) else nominal[None, :]
        reach, farthest = samples.min(axis=0), np.maximum(samples.max(axis=0), nominal)
        likely = np.percentile(samples, 5, axis=0)
        pairs, ranks = [], []
        for (a, b, kind, group), d_nominal, d_reach, d_far, d_likely in zip(candidates, nominal, reach, farthest, likely):
            pair = CollisionPair(a, b, kind, group)
            if d_nominal < cfg.margin_m + cfg.nominal_clearance_m:
                self.excluded[pair.name] = f"{d_nominal:.3f} m apart at the nominal pose (neighbours by design)"
            elif cfg.reach_samples and d_reach > cfg.margin_m + cfg.reach_slack_m:
                self.excluded[pair.name] = f"never closer than {d_reach:.3f} m over {cfg.reach_samples} random configurations"
            elif cfg.reach_samples and d_far - d_reach < 1e-6:
                self.excluded[pair.name] = f"always {d_nominal:.3f} m apart (the joints between them do not move them)"
            else:
                pairs.append(pair)
                ranks.append(d_likely)
        kept = []
        for group in dict.fromkeys(p.group for p in pairs):
            members = sorted((i for i, p in enumerate(pairs) if p.group == group), key=lambda i: ranks[i])
            for i in members[cfg.max_pairs_per_group:]:
                self.excluded[pairs[i].name] = f"beyond the {cfg.max_pairs_per_group} pairs of {group} most likely to meet"
            kept += members[: cfg.max_pairs_per_group]
        return [pairs[i] for i in sorted(kept)]

    @property
    def groups(self) -> dict[str, list[int]]:
        """Pair indices per OCP row (see `CollisionPair.group`), in order of first appearance."""
        out: dict[str, list[int]] = {}
        for i, pair in enumerate(self.pairs):
            out.setdefault(pair.group, []).append(i)
        return out

    # ------------------------------------------------------------------ numeric checks
    def distances(self, q: np.ndarray) -> np.ndarray:
        """Distance (m, negative: penetration) of every checked pair at configuration q (pinocchio FK)."""
        return capsule_distances(self.robot, q, [p.first for p in self.pairs], [p.second for p in self.pairs])

    def check_clear(self, q: np.ndarray, margin_m: float | None = None) -> None:
        """Raise `CollisionError` naming the closest pair when q has a checked pair closer than the margin."""
        if not self.pairs:
            return
        margin = self.config.margin_m if margin_m is None else margin_m
        d = self.distances(q)
        worst = int(np.argmin(d))
        if d[worst] < margin:
            pair = self.pairs[worst]
            raise CollisionError(
                f"the robot starts in collision: {pair.first.name} ({pair.first.link}) and {pair.second.name} "
                f"({pair.second.link}) are {d[worst]:.3f} m apart, below the {margin:.3f} m margin of collision "
                "avoidance; start from a pose where they are apart (the nominal pose), lower the margin or run "
                "without --collision-avoidance")

    @cached_property
    def summary(self) -> dict:
        return {"capsules": len(self.capsules), "pairs": [p.name for p in self.pairs],
                "skipped_links": list(self.skipped_links), "margin_m": self.config.margin_m}


def _chain(model: pin.Model, joint_id: int) -> list[int]:
    """Joints from below the free-flyer root down to `joint_id`."""
    out = []
    while joint_id > 1:
        out.append(joint_id)
        joint_id = model.parents[joint_id]
    return out[::-1]


# ------------------------------------------------------------------------------ capsules
def robot_capsules(robot: RobotModel) -> tuple[list[Capsule], list[str]]:
    """The capsules of every link with collision geometry, and the links without any."""
    import coal

    from wbmpc.robots.urdf_geometry import _package_dirs

    model = robot.model
    try:
        if robot.mjcf is not None:  # an MJCF robot: its colliding geoms as pinocchio reads them
            geometry = robot.geometry(pin.GeometryType.COLLISION)
        else:
            geometry = pin.buildGeomFromUrdf(model, str(robot.spec.urdf), pin.GeometryType.COLLISION,
                                             package_dirs=_package_dirs(robot.spec.urdf))
    except (RuntimeError, ValueError) as exc:
        raise ModelError(f"collision avoidance: pinocchio could not read the collision geometry of "
                         f"{robot.model_file} ({exc}); check the file's collision geometry and meshes") from exc
    capsules: list[Capsule] = []
    with_geometry = set()
    for obj in geometry.geometryObjects:
        link = model.frames[obj.parentFrame].name
        placement = pin.SE3(obj.placement)
        shape = obj.geometry
        if isinstance(shape, coal.Sphere):
            pieces = [(np.zeros(3), np.zeros(3), float(shape.radius))]
        elif isinstance(shape, (coal.Capsule, coal.Cylinder)):
            h = float(shape.halfLength)
            pieces = [(np.array([0, 0, -h]), np.array([0, 0, h]), float(shape.radius))]
        elif isinstance(shape, coal.Box):
            pieces = _box_capsules(np.asarray(shape.halfSide, dtype=float), np.zeros(3), bounding=False)
        else:  # a mesh (or another BVH / convex shape): the capsule around its bounding box
            try:
                shape.computeLocalAABB()
                box = shape.aabb_local
                low, high = np.asarray(box.min_, dtype=float), np.asarray(box.max_, dtype=float)
            except (AttributeError, RuntimeError):
                continue
            if not np.all(np.isfinite(low)) or np.any(high < low):
                continue
            pieces = _box_capsules(0.5 * (high - low), 0.5 * (high + low), bounding=True)
        pieces = [(s, e, r) for s, e, r in pieces if max(r, 0.5 * np.linalg.norm(e - s) + r) >= MIN_SHAPE_SIZE_M]
        if pieces:
            with_geometry.add(link)
        for k, (start, end, radius) in enumerate(pieces):
            suffix = f"_{k}" if len(pieces) > 1 else ""
            capsules.append(Capsule(f"{obj.name}{suffix}", link, int(obj.parentJoint), placement.act(start),
                                    placement.act(end), radius))
    capsules = [c for c in capsules if not any(o is not c and o.joint_id == c.joint_id and _inside(c, o)
                                               for o in capsules)]
    capsules = [merged for joint in dict.fromkeys(c.joint_id for c in capsules)
                for merged in _merge_body([c for c in capsules if c.joint_id == joint])]
    links = [f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint > 0]
    skipped = [name for name in dict.fromkeys(links) if name not in with_geometry]
    return capsules, skipped


def _box_capsules(half: np.ndarray, centre: np.ndarray, bounding: bool) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Capsules of a box (half sizes along its own axes, centred at `centre`), see the module docstring."""
    order = np.argsort(half)[::-1]
    a, b, c = half[order]
    long_axis, mid_axis = np.eye(3)[order[0]], np.eye(3)[order[1]]
    if bounding or b < THICK_BAR_RATIO * c:
        radius = float(np.hypot(b, c))
        h = a if bounding else max(a - radius, 0.0)
        return [(centre - h * long_axis, centre + h * long_axis, radius)]
    n = int(np.ceil(b / c - 1e-9))
    h = max(a - c, 0.0)
    offsets = np.linspace(-(b - c), b - c, n)
    return [(centre + o * mid_axis - h * long_axis, centre + o * mid_axis + h * long_axis, float(c)) for o in offsets]


def _merge_body(capsules: list[Capsule]) -> list[Capsule]:
    """One capsule around all of a body's capsules (along their end points' principal axis) when its
    radius stays within MERGE_RADIUS_RATIO of their largest; else the capsules as they are."""
    if len(capsules) < 2:
        return capsules
    points = np.array([p for c in capsules for p in (c.start_m, c.end_m)])
    radii = np.array([c.radius_m for c in capsules for _ in range(2)])
    centre = points.mean(axis=0)
    axis = np.linalg.svd(points - centre)[2][0]
    along = (points - centre) @ axis
    across = np.linalg.norm(points - centre - np.outer(along, axis), axis=1)
    radius = float(np.max(across + radii))
    if radius > MERGE_RADIUS_RATIO * max(c.radius_m for c in capsules):
        return capsules
    room = np.sqrt(np.maximum((radius - radii) ** 2 - across**2, 0.0))  # how far each end ball may pass the segment's end
    low, high = float(np.min(along + room)), float(np.max(along - room))
    if high < low:
        low = high = 0.5 * (low + high)
    links = "+".join(dict.fromkeys(c.link for c in capsules))
    return [Capsule(links, links, capsules[0].joint_id, centre + low * axis, centre + high * axis, radius)]


def _inside(inner: Capsule, outer: Capsule) -> bool:
    """Whether capsule `inner` lies inside `outer` (both end balls within it); ties keep the first."""
    if outer.radius_m < inner.radius_m or (outer.radius_m == inner.radius_m and outer.half_length_m <= inner.half_length_m):
        return False
    reach = outer.radius_m - inner.radius_m
    return all(_point_segment_distance(p, outer.start_m, outer.end_m) <= reach for p in (inner.start_m, inner.end_m))


def _point_segment_distance(p, a, b) -> float:
    d = b - a
    t = 0.0 if d @ d < 1e-18 else float(np.clip((p - a) @ d / (d @ d), 0.0, 1.0))
    return float(np.linalg.norm(p - a - t * d))


# ------------------------------------------------------------------------------ numeric distances
def segment_distances(p0, p1, q0, q1) -> np.ndarray:
    """Distances between segments [p0, p1] and [q0, q1], rows of (n, 3) arrays (the branch-free clamped
    closest points that `wbmpc.symbolic.collision` writes in CasADi)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    b = np.einsum("ij,ij->i", d1, d2)
    c = np.einsum("ij,ij->i", d1, r)
    f = np.einsum("ij,ij->i", d2, r)
    a_safe, e_safe = np.maximum(a, 1e-12), np.maximum(e, 1e-12)
    s = np.clip((b * f - c * e) / np.maximum(a * e - b * b, 1e-12), 0.0, 1.0)
    s = np.where(a < 1e-12, 0.0, s)
    t = np.where(e < 1e-12, 0.0, np.clip((b * s + f) / e_safe, 0.0, 1.0))
    s = np.where(a < 1e-12, 0.0, np.clip((b * t - c) / a_safe, 0.0, 1.0))
    return np.linalg.norm(r + s[:, None] * d1 - t[:, None] * d2, axis=1)


def capsule_distances(robot: RobotModel, q: np.ndarray, first: list[Capsule], second: list[Capsule],
                      data: pin.Data | None = None) -> np.ndarray:
    """Surface distances of capsules first[i] and second[i] at configuration q (negative: penetration)."""
    model = robot.model
    data = data or model.createData()
    pin.forwardKinematics(model, data, np.asarray(q, dtype=float))
    rotations = np.array([data.oMi[j].rotation for j in range(model.njoints)])
    positions = np.array([data.oMi[j].translation for j in range(model.njoints)])

    def ends(capsules):
        joints = np.array([c.joint_id for c in capsules])
        starts = np.einsum("nij,nj->ni", rotations[joints], np.array([c.start_m for c in capsules])) + positions[joints]
        stops = np.einsum("nij,nj->ni", rotations[joints], np.array([c.end_m for c in capsules])) + positions[joints]
        return starts, stops

    (p0, p1), (q0, q1) = ends(first), ends(second)
    radii = np.array([a.radius_m + b.radius_m for a, b in zip(first, second)])
    return segment_distances(p0, p1, q0, q1) - radii


def random_configurations(robot: RobotModel, n: int, seed: int, leg_range_rad: float):
    """n configurations: base at the nominal pose, the legs' joints uniform within `leg_range_rad` of the
    nominal pose, the others (arm) within their limits (+-pi where unlimited)."""
    rng = np.random.default_rng(seed)
    low = np.where(np.isfinite(robot.q_min), robot.q_min, -np.pi)
    high = np.where(np.isfinite(robot.q_max), robot.q_max, np.pi)
    legs = robot.leg_joint_mask
    nominal = robot.joint_positions(robot.q_nominal)
    low[legs] = np.maximum(low[legs], nominal[legs] - leg_range_rad)
    high[legs] = np.minimum(high[legs], nominal[legs] + leg_range_rad)
    for _ in range(n):
        yield robot.with_joint_positions(robot.q_nominal, rng.uniform(low, high))


@dataclass(frozen=True)
class ArmWorkspace:
    """Where the hand can be without touching the body, at the nominal pose (base-relative points
    expressed as at q_nominal): within `reach_m` of the arm's first joint and farther than `clearance_m`
    from every capsule of the base and the legs."""

    shoulder_m: np.ndarray
    reach_m: float
    body: tuple[tuple[np.ndarray, np.ndarray, float], ...]  # (start, end, radius) in the world at q_nominal
    clearance_m: float

    def reaches(self, points: np.ndarray) -> np.ndarray:
        points = np.atleast_2d(points)
        inside = np.linalg.norm(points - self.shoulder_m, axis=1) <= self.reach_m
        for start, end, radius in self.body:
            n = len(points)
            d = segment_distances(points, points, np.tile(start, (n, 1)), np.tile(end, (n, 1))) - radius
            inside &= d >= self.clearance_m
        return inside


def arm_workspace(robot: RobotModel, margin_m: float = 0.03, samples: int = 2000) -> ArmWorkspace:
    """The arm's `ArmWorkspace`: its reach sampled over random joint configurations, the clearance the hand
    capsule's radius plus `margin_m`."""
    if robot.arm_ee is None:
        raise ConfigError(f"{robot.name} has no arm (--arm-ee)")
    model = robot.model
    data = model.createData()
    ee_joint = model.frames[robot.frame_id(robot.arm_ee)].parentJoint
    arm = _chain(model, ee_joint)
    pin.framesForwardKinematics(model, data, robot.q_nominal)
    shoulder = data.oMi[arm[0]].translation.copy()
    reach = 0.0
    for q in random_configurations(robot, samples, 0, 0.0):
        pin.framesForwardKinematics(model, data, q)
        reach = max(reach, float(np.linalg.norm(data.oMf[robot.frame_id(robot.arm_ee)].translation - data.oMi[arm[0]].translation)))
    pin.forwardKinematics(model, data, robot.q_nominal)
    capsules, _ = robot_capsules(robot)
    hand = max((c.radius_m for c in capsules if c.joint_id == ee_joint), default=0.0)
    body = tuple((data.oMi[c.joint_id].act(c.start_m), data.oMi[c.joint_id].act(c.end_m), c.radius_m)
                 for c in capsules if c.joint_id not in arm)
    return ArmWorkspace(shoulder, reach, body, hand + margin_m)


def collision_model_for(robot: RobotModel, config: CollisionConfig | None) -> CollisionModel | None:
    """The robot's collision model, or None when collision avoidance is off; refuses robots without pairs."""
    if config is None:
        return None
    model = CollisionModel(robot, config)
    if not model.pairs:
        raise ConfigError(f"collision avoidance on {robot.name}: no pair of links to check (capsules: "
                          f"{len(model.capsules)}; links without collision geometry: "
                          f"{', '.join(model.skipped_links) or 'none'}); run without --collision-avoidance")
    return model
