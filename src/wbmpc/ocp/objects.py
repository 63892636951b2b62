"""The manipulated object inside the OCP (the paper's future work, section VII: "model
object-level dynamics for interaction, allowing the MPC to optimize arm end-effector force and motion
instead of having them as an external command").

An `ObjectModel` adds, stage-ordered as Fatrop needs:

- object states `obj` on every node (appended to the robot's x_k: the gap rows x_{k+1} - f(x_k, u_k) stay
  one block per stage), measured on node 0 (the `x0` rows);
- object inputs `obj_u` on the input nodes: the object's velocity at the end of the interval (the object
  is integrated with implicit Euler, see below; the load's cable tension too);
- rows `obj_dyn` (its dynamics, = 0) and `obj_cone` (the hand force's friction cone / the cable's sign,
  >= 0) on input nodes, `obj_contact` (where the hand must be: on the box face, at the cable's length, within
  CONTACT_TOLERANCE_M) on nodes 2..N (node 1's configuration follows from the measurement alone, as for
  collision rows); a measured gap closes over CONTACT_BLEND_TIME_S and no force is planned before;
- a tracking cost on the object's state against a reference per node (the command: the object's path),
  parameters `obj_ref` (n_obj, N+1) and `obj_w` (n_obj).

The coupling force is the arm force F_arm of eq. (2) (the force ON the robot, a variable of the OCP):
the object feels -F_arm. Without an object model it is fixed to the command (eq. 7); with one it is free
within the object's cone rows, and the arm's velocity rows of eq. 7 are dropped (the contact rows say
where the hand goes).

Ground friction: Coulomb friction smoothed as f = -mu N u / sqrt(|u|^2 + eps^2) (u the sliding velocity,
eps `smoothing_m_s`), evaluated at the END of each interval (implicit Euler in the velocity, the velocity
at the end an input). Why this model: f is the gradient of the convex dissipation potential
mu N sqrt(|u|^2 + eps^2), so m (u' - u) / dt = F_hand + f(u') has exactly one solution u' for any hand
force: the rows are smooth and well posed, Fatrop's interior point converges on them. A complementarity
model (stick/slip as |f| <= mu N with v (mu N - |f|) = 0) violates the constraint qualifications an
interior point needs (it stalls without relaxation schemes), and explicit Euler on the smoothed law is
unstable: its stiffness mu N / (m eps) is ~300 1/s, the horizon's steps are 10-100 ms. The price: below
the static friction the object creeps at about eps F / (mu N - F), and at speed v the friction is
v / sqrt(v^2 + eps^2) of Coulomb's: eps = 1 cm/s gives 99.5 % at 0.1 m/s (3 cm/s gave 95.8 %, and a MuJoCo box
under the planned force lagged the plan by 1.1 cm over 0.48 s). Fatrop's line search still failed on most
push-box steps with the contact rows (IPOPT solved them in 10-50 iterations): `wbmpc run --object-model` and
`RunConfig`'s default use the anytime SQP (`control/policy.default_solver`).

What the box model lacks (push-box, measured in MuJoCo): pushed at the hand's height h, the box rests on its far
corners (91 % of the weight at 0.87 m) and turns about that edge, its centre sliding out of a turn at w mu h; the
even corner loads here do not. With the loads shifted by the push (`push_shifts_loads`) or by a fixed share (the
floor load's centre mu h ahead) the anytime SQP, one iteration per step at its 10 ms budget, pushed in bursts (the
hand on the box 7 % of the time; 24-31 cm RMSE through the turn); with a 50 ms budget the fixed share tracked at
10 cm, the even loads at 5.8 cm. The reference's yaw leads instead (`scenarios/object_paths.sideslip_lead`).

- `SlidingBox`: a box pushed by the hand sphere on its near face (-x face in the box frame), states
  [x, y, yaw, vx, vy, wz] (world), ground friction at its four bottom corners with a quarter of the
  weight each (as MuJoCo's box-plane contact: translation and rotation friction coupled, the yaw moment
  from the footprint), hand force in the face's friction cone (normal >= 0, |tangential| <= mu normal,
  no vertical force), the hand on the face (gap = 0) within its width.
- `CableLoad1D`: a load dragged along the floor (world x) by a cable; states [x, vx] of its centre, inputs its
  velocity and the cable's tension T >= 0, the arm force T along the cable, the cable taut: |hand - hook| =
  length.

Numbers (box mass, friction, size; load mass, friction, cable length) come from the scene objects
(`wbmpc.sim.objects`), the one source of truth: `SlidingBox.from_scene`, `CableLoad1D.from_scene`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.robots import GRAVITY_M_S2

OBJECT_ROW_TAGS = ("obj_dyn", "obj_cone", "obj_contact")
CONTACT_BLEND_TIME_S = 0.3  # a measured hand-object gap reaches zero over this time
CONTACT_FORCE_GAP_M = 2e-3  # no force planned on nodes whose gap target is beyond this (complementarity)
# the hand's gap to the object within this of its target, not exactly on it: with an equality Fatrop's line search
# failed on most steps (the hand pinned to a box that only friction holds); 2 mm is within MuJoCo's contact softness
CONTACT_TOLERANCE_M = 2e-3
PUSH_HEIGHT_TOLERANCE_M = 0.02  # SlidingBox.push_height_m: the hand within this of its height on the face
PUSH_HEIGHT_BLEND_TIME_S = 0.4  # a measured hand height off the push height reaches it over this time
# ... and the hand stays off the face (no force) while its measured height is further than this from the push height:
# it moves to its height first and only then closes the gap, so it never slides down the face in contact
PUSH_HEIGHT_APPROACH_M = 0.05


@dataclass(frozen=True)
class ObjectCommand:
    """Per MPC step: the measured object state (node 0) and its reference, a function of the node times
    (absolute, s) -> (nodes, n_obj) states (the object's commanded path)."""

    state: np.ndarray
    reference: Callable[[np.ndarray], np.ndarray]

    def __post_init__(self):
        state = np.asarray(self.state, dtype=float).ravel()
        if not np.all(np.isfinite(state)):
            raise ConfigError(f"the measured object state must be finite, got {state}")
        object.__setattr__(self, "state", state)


@dataclass(frozen=True)
class ObjectModel:
    """Shared interface; see the module docstring. Frozen: part of `OcpConfig` (a new build per model)."""

    name = "object"
    state_names: tuple[str, ...] = ()

    @property
    def n_states(self) -> int:
        return len(self.state_names)

    @property
    def n_inputs(self) -> int:
        raise NotImplementedError

    tracking_weights: tuple[float, ...] = ()  # per state, cost per unit^2
    mass_kg: float = 1.0

    def weights(self) -> np.ndarray:
        """Tracking weights of the object's states (cost per unit^2)."""
        return np.asarray(self.tracking_weights, dtype=float)

    @property
    def weight_n(self) -> float:
        return self.mass_kg * GRAVITY_M_S2

    def transition(self, x, u, dt) -> ca.SX:
        raise NotImplementedError

    def input_rows(self, x, u, force_on_robot, hand, dt) -> list[tuple[str, ca.SX]]:
        """obj_dyn (= 0) and obj_cone (>= 0) rows of an input node (hand: world position of the hand)."""
        raise NotImplementedError

    def contact_rows(self, x, hand) -> ca.SX:
        """obj_contact rows of a state node (bounds from `contact_bounds`)."""
        raise NotImplementedError

    def contact_values(self, x: np.ndarray, hand: np.ndarray) -> np.ndarray:
        """The contact rows at a measured state (numeric)."""
        return np.asarray(self._numeric_contact(x, hand), dtype=float).ravel()

    @cached_property
    def _numeric_contact(self) -> ca.Function:
        """Built once per model (cached_property writes the instance dict: fine on a frozen dataclass)."""
        xs, hs = ca.SX.sym("x", self.n_states), ca.SX.sym("hand", 3)
        return ca.Function("contact", [xs, hs], [self.contact_rows(xs, hs)])

    def contact_bounds(self, measured: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lower, upper) of the obj_contact rows on nodes at `times` (nodes, rows), and per node whether the
        hand may exert force there (the measured gap closes over CONTACT_BLEND_TIME_S; no force before)."""
        raise NotImplementedError

    def arm_force_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of F_arm (world, on the robot) as variable bounds; the cone rows do the rest."""
        return np.full(3, -np.inf), np.full(3, np.inf)

    def cone_upper(self, may_push: np.ndarray) -> np.ndarray:
        """ubg of the obj_cone rows per input node (nodes, rows): no force where the hand may not push."""
        raise NotImplementedError

    def input_guess(self, state: np.ndarray) -> np.ndarray:
        raise NotImplementedError


def _smooth_friction(velocity, normal_n, mu, eps):
    """Smoothed Coulomb friction -mu N u / sqrt(|u|^2 + eps^2) of a point sliding at `velocity` (2D)."""
    return -mu * normal_n * velocity / ca.sqrt(ca.sumsqr(velocity) + eps**2)


def _blended(measured: float, times: np.ndarray) -> np.ndarray:
    """A measured contact gap (or slack) at the node times, closed linearly over CONTACT_BLEND_TIME_S."""
    return np.clip(1.0 - times / CONTACT_BLEND_TIME_S, 0.0, 1.0) * measured


def _rot2(yaw):
    c, s = ca.cos(yaw), ca.sin(yaw)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


@dataclass(frozen=True)
class SlidingBox(ObjectModel):
    """A box sliding on the floor pushed on its near face (-x in the box frame) by the hand sphere."""

    name = "box"
    mass_kg: float = 5.0
    friction_mu: float = 0.3  # box-ground and hand-box (the box's geom friction in MuJoCo)
    size_m: tuple[float, float, float] = (0.6, 0.6, 1.0)
    hand_radius_m: float = 0.03  # the end-effector sphere: the hand frame is this far off the face
    smoothing_m_s: float = 0.01
    face_margin_m: float = 0.08  # the hand stays this far inside the face's side edges
    # the plan's hand force within this share of the face's friction cone: a margin against slipping on the face, and
    # the box turned by where the hand pushes rather than by sideways force (with the full cone the plan turned the box
    # with a tangential push that also shoved it sideways, 14 cm off its path through a 0.8 m turn)
    cone_share: float = 0.3
    # the push's tipping moment shifts the corners' loads (`corner_loads`); off: a quarter of the weight each. Closer to
    # MuJoCo's box, yet push-box --object-model (16 s, b1_z1, SQP) did worse with it: 31.5 cm RMSE, the box overshooting
    # the turn's end by 66 cm, against 22.9 cm with even loads
    push_shifts_loads: bool = False
    # the hand's height on the face (m, world; None: free, the robot's posture decides): a low push keeps the box's
    # floor load near its centre (the tipping moment mu m g h), so the box turns about a pivot mu h ahead of it instead
    # of about its far edge (`scenarios/object_paths.sideslip_lead`); a third contact row, within PUSH_HEIGHT_TOLERANCE_M.
    # Measured, it did not track push-box's turn better: the low-pushed box resisted turning (`object_paths.object_command`)
    push_height_m: float | None = None
    # force planned on the nodes whose gap target is within this of contact: the hand's pad and its chatter. 16 s
    # push-box --object-model (b1_z1, compiled SQP): 2 mm (CONTACT_FORCE_GAP_M) 7.6 cm RMSE, 1 cm 5.0 cm; force on
    # every node, however far the hand (a sign error before), 4.4 cm: a plan pushing through air
    force_gap_m: float = 0.01
    state_names: tuple[str, ...] = ("x_m", "y_m", "yaw_rad", "vx_m_s", "vy_m_s", "wz_rad_s")
    # tracking weights of [x, y, yaw, vx, vy, wz]: the yaw too, as the hand's force stays within atan(mu) (17 deg at
    # mu 0.3) of the face normal, so the box only goes where its face points
    tracking_weights: tuple[float, ...] = (1e5, 1e5, 3e4, 3000.0, 3000.0, 10.0)

    @classmethod
    def from_scene(cls, box, hand_radius_m: float, **overrides) -> "SlidingBox":
        """The model of a scene's `wbmpc.sim.objects.FreeBox` (its mass, friction and size)."""
        return cls(mass_kg=box.mass_kg, friction_mu=box.friction_mu, size_m=tuple(box.size_m),
                   hand_radius_m=hand_radius_m, **overrides)

    @property
    def n_inputs(self) -> int:
        return 3

    @property
    def inertia_kg_m2(self) -> float:
        sx, sy, _ = self.size_m
        return self.mass_kg * (sx**2 + sy**2) / 12.0

    def corners_m(self) -> np.ndarray:
        """(4, 2) bottom corners in the box frame."""
        sx, sy, _ = self.size_m
        return np.array([[a * sx / 2, b * sy / 2] for a in (-1, 1) for b in (-1, 1)])

    def transition(self, x, u, dt):
        """Positions advance with the velocity at the end of the interval (semi-implicit Euler)."""
        return ca.vertcat(x[:3] + dt * u, u)

    def corner_loads(self, push_local, height):
        """Normal force on each bottom corner (`corners_m` order): a quarter of the weight, shifted towards the far edges
        by the push's tipping moment at the hand's `height` (moment balance about the footprint, the box not tipping).
        On b1_z1 the hand pushes at ~0.87 m: 14.7 N put 91 % of the weight on the front corners (`push_shifts_loads`)."""
        sx, sy, _ = self.size_m
        return [self.weight_n / 4 + height / 2 * (a * push_local[0] / sx + b * push_local[1] / sy)
                for a, b in np.sign(self.corners_m())]

    def ground_wrench(self, x, u, push_local=None, height=0.0):
        """Friction force (2) and yaw moment of the floor at velocities u = [vx, vy, wz] (yaw of x), under the hand's
        push (box frame) at `height` (None: no push, even corner loads)."""
        rot = _rot2(x[2])
        force, moment = ca.SX.zeros(2), 0
        loads = self.corner_loads(push_local, height) if push_local is not None else [self.weight_n / 4] * 4
        for corner, load in zip(self.corners_m(), loads):
            r = ca.mtimes(rot, ca.DM(corner))
            sliding = u[:2] + u[2] * ca.vertcat(-r[1], r[0])
            f = _smooth_friction(sliding, load, self.friction_mu, self.smoothing_m_s)
            force += f
            moment += r[0] * f[1] - r[1] * f[0]
        return force, moment

    def input_rows(self, x, u, force_on_robot, hand, dt):
        """Newton-Euler of the box over the interval (scaled by the weight and the half diagonal) and the hand
        force on the box, -F_arm, in the face's friction pyramid: [mu f_n - f_t, mu f_n + f_t] >= 0 (they imply
        f_n >= 0; a third row f_n >= 0 would make three rows active in two variables at zero force, where the
        box rests: degenerate for the interior point)."""
        push = -force_on_robot[:2]
        lever = hand[:2] - x[:2]
        push_local = ca.mtimes(_rot2(x[2]).T, push)
        friction, friction_moment = (self.ground_wrench(x, u, push_local, hand[2]) if self.push_shifts_loads
                                     else self.ground_wrench(x, u))
        moment = lever[0] * push[1] - lever[1] * push[0] + friction_moment
        half_diagonal = 0.5 * float(np.hypot(*self.size_m[:2]))
        dynamics = ca.vertcat((self.mass_kg * (u[:2] - x[3:5]) / dt - push - friction) / self.weight_n,
                              (self.inertia_kg_m2 * (u[2] - x[5]) / dt - moment) / (self.weight_n * half_diagonal))
        local = push_local / self.weight_n
        mu = self.cone_share * self.friction_mu
        cone = ca.vertcat(mu * local[0] - local[1], mu * local[0] + local[1])
        return [("obj_dyn", dynamics), ("obj_cone", cone)]

    def contact_rows(self, x, hand):
        """[gap of the hand sphere to the near face (m), the hand's offset along the face (m)] and, with a
        `push_height_m`, the hand's height above it (m)."""
        local = ca.mtimes(_rot2(x[2]).T, hand[:2] - x[:2])
        rows = [local[0] + self.size_m[0] / 2 + self.hand_radius_m, local[1]]
        if self.push_height_m is not None:
            rows.append(hand[2] - self.push_height_m)
        return ca.vertcat(*rows)

    def contact_bounds(self, measured, times):
        target = _blended(float(measured[0]), times)
        half = self.size_m[1] / 2 - self.face_margin_m
        side = max(half, abs(float(measured[1])) + 1e-3)  # a hand measured beyond the margin is not infeasible
        lower = [np.minimum(target, 0.0) - CONTACT_TOLERANCE_M, np.full(len(times), -side)]
        upper = [np.maximum(target, 0.0) + CONTACT_TOLERANCE_M, np.full(len(times), side)]
        if self.push_height_m is not None:
            # a straight line from the measured height to the band's near edge: the band's tolerance does not leave the
            # first nodes free (re-blended every step, a proportional blend within a band never moved the hand)
            height, tol = float(measured[2]), PUSH_HEIGHT_TOLERANCE_M
            edge = float(np.clip(height, -tol, tol))
            line = height + np.clip(times / PUSH_HEIGHT_BLEND_TIME_S, 0.0, 1.0) * (edge - height)
            lower.append(line if height < -tol else np.full(len(times), -tol))
            upper.append(line if height > tol else np.full(len(times), tol))
            if abs(height) > PUSH_HEIGHT_APPROACH_M:  # off its height: the hand keeps 1 cm off the face (the row < 0)
                gap = float(measured[0])
                target = np.full(len(times), -np.inf)  # no force
                lower[0] = np.full(len(times), -np.inf)
                upper[0] = np.full(len(times), max(gap, -0.01) + CONTACT_TOLERANCE_M)
        return np.column_stack(lower), np.column_stack(upper), target >= -self.force_gap_m

    def arm_force_bounds(self):
        return np.array([-np.inf, -np.inf, 0.0]), np.array([np.inf, np.inf, 0.0])

    def cone_upper(self, may_push):
        upper = np.full((len(may_push), 2), np.inf)
        upper[~may_push] = 0.0  # both pyramid rows = 0: no force
        return upper

    def input_guess(self, state):
        return np.asarray(state, dtype=float)[3:6]


@dataclass(frozen=True)
class CableLoad1D(ObjectModel):
    """A load dragged on the floor along world x by a cable from the hand: states [x, vx] of the load's centre, inputs
    [vx at the interval's end, cable tension T]. The arm force on the robot is T along the cable towards the hook
    (rows `obj_dyn`: F_arm - T d / |d| = 0, d = hook - hand), T >= 0 (`obj_cone`), the load's normal force its
    weight less the cable's lift; the cable taut, |d| = length (`obj_contact`, within CONTACT_TOLERANCE_M, the
    measured slack closed over CONTACT_BLEND_TIME_S; no tension before)."""

    name = "load"
    mass_kg: float = 10.0
    friction_mu: float = 0.3
    size_m: tuple[float, float, float] = (0.3, 0.3, 0.2)
    hook_height_m: float = 0.1
    hook_y_m: float = 0.0
    cable_length_m: float = 1.6
    smoothing_m_s: float = 0.01
    state_names: tuple[str, ...] = ("x_m", "vx_m_s")
    tracking_weights: tuple[float, ...] = (100.0, 3000.0)  # the load's speed is the command; its position mildly

    @classmethod
    def from_scene(cls, load, **overrides) -> "CableLoad1D":
        """The model of a scene's `wbmpc.sim.objects.CableLoad` (mass, friction, size, hook, cable)."""
        return cls(mass_kg=load.mass_kg, friction_mu=load.friction_mu, size_m=tuple(load.size_m),
                   hook_height_m=load.hook_height_m, hook_y_m=float(load.position_m[1]),
                   cable_length_m=load.cable_length_m, **overrides)

    @property
    def n_inputs(self) -> int:
        return 2

    def hook(self, x):
        return ca.vertcat(x[0] - self.size_m[0] / 2, self.hook_y_m, self.hook_height_m)

    def transition(self, x, u, dt):
        return ca.vertcat(x[0] + dt * u[0], u[0])

    def input_rows(self, x, u, force_on_robot, hand, dt):
        d = self.hook(x) - hand
        along = d / ca.sqrt(ca.sumsqr(d) + 1e-9)
        tension = u[1]
        on_load = -force_on_robot
        normal = self.weight_n - on_load[2]
        friction = _smooth_friction(u[0], normal, self.friction_mu, self.smoothing_m_s)
        dynamics = ca.vertcat((self.mass_kg * (u[0] - x[1]) / dt - on_load[0] - friction) / self.weight_n,
                              (force_on_robot - tension * along) / self.weight_n)
        return [("obj_dyn", dynamics), ("obj_cone", tension / self.weight_n)]

    def contact_rows(self, x, hand):
        """The cable's stretch |hook - hand| - length (m; < 0: slack)."""
        return ca.norm_2(self.hook(x) - hand) - self.cable_length_m

    def contact_bounds(self, measured, times):
        target = _blended(float(measured[0]), times)
        lower = (np.minimum(target, 0.0) - CONTACT_TOLERANCE_M)[:, None]
        upper = (np.maximum(target, 0.0) + CONTACT_TOLERANCE_M)[:, None]
        return lower, upper, target >= -CONTACT_FORCE_GAP_M

    def cone_upper(self, may_push):
        return np.where(may_push, np.inf, 0.0)[:, None]

    def input_guess(self, state):
        return np.array([float(np.asarray(state)[1]), 0.0])
