"""The stage-wise OCP (eq. 1) as one NLP whose structure Fatrop can exploit.

Decision variables are ordered x0, u0, x1, u1, ..., xN; the constraints of stage k are the
gap-closing rows x_{k+1} - f(x_k, u_k) first, then the path rows of stage k. Everything that
changes between MPC steps is either a CasADi parameter (reference configuration, dt grid,
targets, weights, friction) or a bound (initial state, contact schedule, swing velocity
references, arm commands, joint limits): one build serves every step.

Path constraints per node (section IV-B):
- dynamics rows of the formulation (eq. 5 for wb_inverse);
- contact (eq. 6): stance feet F_z >= 0 (bound), friction cone mu^2 F_z^2 - F_x^2 - F_y^2 >= 0,
  foot velocity = 0; swing feet F = 0 (bounds), foot v_z = spline reference, v_x, v_y free (or, where
  `StageBounds.swing_vxy_m_s` gives them, equal to a placement reference: bipeds' steps);
- flat feet (surface contacts, 6D wrench [f; tau] at the sole, `robot.soles`): instead of the cone a
  hard wrench cone of linear rows (`wrench_cone`): friction pyramid |f_x|, |f_y| <= mu f_z, centre of
  pressure inside the sole rectangle |tau_x| <= (W/2) f_z, |tau_y| <= (L/2) f_z, and the yaw moment
  |tau_z| <= mu min(L, W)/2 f_z (a conservative bound of the sole's torsional friction); f_z is the
  world normal force (stance soles are flat on flat ground: the sole's normal is world z). Angular
  velocity rows (`foot_ang`): zero in stance (with foot_vel the whole 6D sole velocity), roll and pitch
  rates zero in swing, so the sole stays parallel to the ground from lift-off to touch-down while its
  height follows eq. 6's spline, its yaw rate free (or, where `StageBounds.swing_yaw_rate_rad_s` gives it,
  within SWING_YAW_RATE_BAND_RAD_S of a reference that turns it to its landing heading); swing soles carry
  no wrench (bounds);
- arm (eq. 7): end-effector force = command (bounds), linear velocity = command;
- limits (eq. 8): joint positions and velocities on every node, torques on k < 3 (bounds); on the
  later input nodes, the torques the plan implies (the RNEA's joint rows with the contact forces and
  wrenches, `implied_torque`) within tau_max (`OcpConfig.implied_torque_rows`: by default the leg
  joints of robots with flat feet and a leg joint weaker than their weight on a sole's edge). Without
  them a humanoid's plan put the CoP at the toe in single support beyond what the 35 N m ankle of g1
  can hold, on every node but the first three.
- collision avoidance (beyond the paper, `OcpConfig.collision`, `symbolic/collision.py`): on nodes 1..N
  one row per group of capsule pairs, their smooth minimum distance >= margin (node 1 is free where
  the measurement fixes its configuration; the following nodes start from the measured distance when
  it is below the margin and reach the margin over COLLISION_BLEND_TIME_S).
- the manipulated object (beyond the paper, `OcpConfig.object_model`, `ocp/objects.py`): its states appended to
  x_k on every node, its inputs to u_k, its dynamics / cone / contact rows; the arm force becomes a variable
  (no longer the command's bounds) and the arm's velocity rows of eq. 7 are dropped.
State-only rows (foot/arm velocities, joint limits) start at node 1: node 0 is the measurement.

Soft rows (`OcpConfig.soft_rows`, off by default; e.g. the arm's velocity rows of eq. 7): on nodes
1..N-1 each such row r(x_k) gets two slack inputs s+, s- >= 0 of node k, r - s+ + s- meets the row's
bounds and the cost gains w_slack (s+ + s-), an exact L1 penalty: while the hard problem is
feasible and |multiplier| < w_slack the slacks are zero and the solution is the hard one; after a
push that makes the hard rows infeasible (the arm pinned in the world while the base flies off)
the OCP stays solvable with the least weighted violation; w_slack_sq (s+^2 + s-^2, 0 by default) adds a
quadratic penalty (a hard row's multiplier |lambda| > w_slack leaves a violation (|lambda| - w_slack) /
(2 w_slack_sq); below it the rows stay exact) that is smooth beyond: a command that meets a collision row is followed along the surface instead of stopped (collision
avoidance's arm rows). The slacks are inputs of their own
stage (Fatrop's structure holds); the terminal node keeps its rows hard. `StageBounds.soft=False`
pins the slacks to zero (the hard OCP: free slacks cost nominal steps ~2 extra iterations, so the
MPC releases them only after a push). `StageBounds.relaxed_rows` instead drops rows for one step
(both bounds infinite: no variables added, the default way the MPC recovers from a push). The torque
limits can be soft too (`torque_limit`: rows tau_j / tau_max in [-1, 1] with slacks on k < 3 replace
the variable bounds).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.ocp.bounds_template import BoundsTemplate
from wbmpc.ocp.formulations import Formulation, Node, make_formulation
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.objects import OBJECT_ROW_TAGS, ObjectModel
from wbmpc.ocp.parameters import ParameterPack
from wbmpc.robots import GRAVITY_M_S2, RobotModel
from wbmpc.robots.collision_model import CollisionConfig, CollisionModel, collision_model_for
from wbmpc.symbolic import InertialParameters, SymbolicDynamics
from wbmpc.symbolic.collision import collision_function, collision_rows

INF = np.inf
EARLY_NODES = 4  # nodes after the measurement whose joint limits may be widened (about 50 ms)
BLEND_TIME_S = 0.05  # measured foot / end-effector velocities off their constraint reach it over this time
CONE_SMOOTHING = 1e-3  # in units of the force scale (about 0.15 N on b1_z1)
COLLISION_BLEND_TIME_S = 0.1  # a measured distance below the margin reaches it over this time
# a swing sole's yaw rate stays within this of its reference (`StageBounds.swing_yaw_rate_rad_s`), not on it: g1's
# free soles turned at up to 0.5 rad/s walking straight at 0.4 m/s (the swing leg's yaw balances the stance sole's
# torsional limit); held to the reference exactly, its plans failed 2 s into that walk and it fell
SWING_YAW_RATE_BAND_RAD_S = 0.5
ROW_TAGS = ("gap", "x0", "dynamics", "torque", "torque_limit", "implied_torque", "foot_vel", "foot_ang", "ee_vel",
            "collision", "cone", "wrench_cone") + OBJECT_ROW_TAGS
IMPLIED_TORQUE_ROWS = ("auto", "all", "legs", "weak", "none")  # OcpConfig.implied_torque_rows
WRENCH_CONE_ROWS = 10  # per flat foot: 4 friction pyramid, 4 centre of pressure, 2 yaw moment
# rows that may get L1 slacks: the state-only velocity rows of nodes 1..N-1 and, as rows tau_j / tau_max
# in [-1, 1] instead of variable bounds, the torque limits of the torque variables on k < 3
SOFTENABLE_ROWS = ("ee_vel", "foot_vel", "torque_limit")
SLACK_PARTS = {"ee_vel": "slack", "foot_vel": "slack", "torque_limit": "slack_tau"}  # input part of each tag's slacks


@dataclass(frozen=True)
class OcpConfig:
    """Structure of the OCP (changing any of these needs a new build)."""

    formulation: str = "wb_inverse"
    grid: TimeGrid = field(default_factory=TimeGrid)
    n_torque_nodes: int = 3  # torques (and their limits) on k = 0, 1, 2 (eq. 8)
    # row tags with L1-penalised slacks (see the module docstring); () = all hard, the paper's OCP (1226
    # variables on b1_z1). ("ee_vel",) adds 78 slacks: pinned on nominal steps they still cost 22 % more
    # CPU per trot step (Fatrop makes each fixed variable an equality row), so the MPC's default
    # recovers from pushes by relaxing the arm rows instead (StageBounds.relaxed_rows)
    soft_rows: tuple[str, ...] = ()
    collision: CollisionConfig | None = None  # collision avoidance rows (None: off, the paper's OCP)
    # joints whose torques implied by the plan (the RNEA's joint rows with the contact wrenches) are
    # bounded by tau_max on the input nodes without torque variables (k >= n_torque_nodes, eq. 8 on every
    # node): "all", "legs" (joints on a root-to-foot chain), "weak" (the leg joints weaker than the robot's
    # weight on a sole's edge), "none" (the paper's OCP) or "auto" (see `OcpProblem.implied_torque_joints`)
    implied_torque_rows: str = "auto"
    # the base CoM offset (3, base frame, m), a payload at the hand (kg; the base origin without an arm) and, with
    # an arm, a load at the base origin as NLP parameters "base_com_offset", "payload_kg", "base_payload_kg" of
    # the whole-body dynamics (mass distribution online, estimation/inertial.py)
    inertial_parameters: bool = False
    # the manipulated object's states, inputs, rows and tracking cost (`wbmpc.ocp.objects`); None: the
    # paper's OCP, the arm force fixed to the command
    object_model: ObjectModel | None = None

    def __post_init__(self):
        if self.implied_torque_rows not in IMPLIED_TORQUE_ROWS:
            raise ConfigError(f"implied_torque_rows {self.implied_torque_rows!r}: choose from "
                              f"{', '.join(IMPLIED_TORQUE_ROWS)}")
        if self.inertial_parameters and not self.formulation.startswith("wb_"):
            raise ConfigError(f"inertial parameters enter the whole-body dynamics only; formulation "
                              f"'{self.formulation}' has none: use wb_inverse or wb_forward")
        unknown = [tag for tag in self.soft_rows if tag not in SOFTENABLE_ROWS]
        if unknown:
            raise ConfigError(f"soft_rows {unknown} cannot be softened; choose from {', '.join(SOFTENABLE_ROWS)} "
                              "(or () for the hard OCP)")

    @property
    def n_intervals(self) -> int:
        return self.grid.n_intervals


@dataclass
class StageBounds:
    """Per-step data that enters the NLP through bounds (lbx/ubx/lbg/ubg)."""

    v0: np.ndarray  # measured generalized velocity (node 0)
    q_ref: np.ndarray  # measured configuration (node 0, reference of dq)
    contact: np.ndarray  # (N+1, n_feet) 1 = stance
    swing_vz_m_s: np.ndarray  # (N+1, n_feet) vertical velocity reference of swing feet
    # (N+1, n_feet, 2) world horizontal velocity references of swing feet (NaN or None: free)
    swing_vxy_m_s: np.ndarray | None = None
    # (N+1, n_feet) world yaw rates of swing soles (flat feet; NaN or None: free)
    swing_yaw_rate_rad_s: np.ndarray | None = None
    ee_velocity_m_s: np.ndarray | None = None  # (3,) world
    ee_force_on_robot_n: np.ndarray | None = None  # (3,) world, force acting on the robot
    foot_velocity_m_s: np.ndarray | None = None  # (n_feet, 3) measured world foot velocities (node 0)
    ee_velocity_measured_m_s: np.ndarray | None = None  # (3,) measured world end-effector velocity
    foot_angular_velocity_rad_s: np.ndarray | None = None  # (n_feet, 3) measured world sole angular velocities
    collision_measured_m: np.ndarray | None = None  # collision rows at the measured configuration (m)
    soft: bool = True  # False pins the soft rows' slacks to zero: the hard OCP (same structure per mode)
    relaxed_rows: tuple[str, ...] = ()  # row tags (ee_vel, foot_vel) left unconstrained on every node this step
    object_state: np.ndarray | None = None  # measured object state (node 0), with OcpConfig.object_model
    object_contact_measured: np.ndarray | None = None  # the object's contact rows at the measured state


class OcpProblem:
    """Builds the NLP once; `bounds()` and `parameters` map per-step task data onto it.

    Each stage k is one casadi Function of (x_k, u_k, p_k) -> (f(x_k, u_k), path rows, cost); stages
    of the same kind (first, torque nodes, plain, terminal) share one Function. `nlp` inlines them
    into one SX expression graph (fastest in the virtual machine); code generation differentiates
    each kind once instead (`solvers/codegen.py`).
    """

    def __init__(self, robot: RobotModel, config: OcpConfig = OcpConfig(), dyn: SymbolicDynamics | None = None):
        self.robot = robot
        self.config = config
        self.dyn = dyn or SymbolicDynamics(robot)
        self.formulation: Formulation = make_formulation(config.formulation, self.dyn, config.n_torque_nodes)
        self.N = config.n_intervals
        self.nv, self.nj, self.nf = self.dyn.nv, self.dyn.nv - 6, self.dyn.n_forces
        self.n_feet = len(robot.feet)
        self.surface_feet = [i for i, foot in enumerate(robot.feet) if foot in robot.soles]  # flat feet (6D)
        self.point_feet = [i for i in range(self.n_feet) if i not in self.surface_feet]
        self.has_arm = robot.arm_ee is not None
        self.object: ObjectModel | None = config.object_model
        if self.object is not None and not self.has_arm:
            raise ConfigError(f"an object model couples the object to the arm's force; {robot.name} has no arm")
        self.collision: CollisionModel | None = collision_model_for(robot, config.collision)
        # built now: the first MPC step is timed (the anytime solver's budget check)
        self._collision_function = collision_function(self.collision, self.dyn) if self.collision is not None else None
        self.implied_torque_joints = self._implied_torque_joints()
        self._layout()
        self._stage_functions: dict[tuple, tuple[ca.Function, list[tuple[str, int]]]] = {}
        self._nlp: dict | None = None
        self._bounds_template: BoundsTemplate | None = None  # built at the first `bounds`
        self.bounds_packer = None  # the compiled step packer for `bounds` (solvers/step_pack.py; the MPC sets it)
        self._blend_decays: dict[str, np.ndarray] = {}  # `_blend_from_measurement`'s per row tag

    @property
    def nlp(self) -> dict:
        """The NLP {x, p, f, g} in SX with the stages inlined (built on first use)."""
        if self._nlp is None:
            self._nlp = self._assemble()
        return self._nlp

    def _assembled(self) -> "OcpProblem":
        """Row bookkeeping exists once the NLP is assembled."""
        _ = self.nlp
        return self

    @property
    def rows(self) -> dict[str, np.ndarray]:
        return self._assembled()._rows

    @property
    def row_nodes(self) -> dict[str, np.ndarray]:
        return self._assembled()._row_nodes

    @property
    def n_constraints(self) -> int:
        return self._assembled()._n_constraints

    @property
    def stage_row_starts(self) -> np.ndarray:
        """First constraint row of each stage (its gap rows, then its path rows)."""
        return self._assembled()._stage_row_starts

    @property
    def equality(self) -> np.ndarray:
        """Structural equalities (gap rows) for Fatrop's structure detection."""
        return self._assembled()._equality

    # ------------------------------------------------------------------ layout
    def _layout(self) -> None:
        """Global parameters, decision-variable order (x0, u0, x1, ..., xN) and scales."""
        N, nv, nf = self.N, self.nv, self.nf
        form = self.formulation
        params = ParameterPack()
        params.add("q_ref", self.dyn.nq)
        params.add("rot_ref", 3, 3)
        params.add("dt", 1, N)
        params.add("dq_des", nv, N + 1)
        params.add("v_des", nv)
        params.add("F_des", nf, N)
        params.add("w_dq", nv)
        params.add("w_v", nv)
        params.add("w_a", nv)
        params.add("w_F", nf)
        params.add("w_tau", self.nj)
        params.add("mu", 1)
        # unit normal of the ground under each foot per input node (terrain: `control/terrain_references.py`;
        # world z on a flat floor): the friction and wrench cones of eq. (6) are taken about it
        params.add("contact_normal", 3 * self.n_feet, N)
        params.add("w_slack", 1)  # L1 weight of the soft rows' slacks
        params.add("w_slack_sq", 1)  # ... and their quadratic weight (CostWeights.soft_constraint_quadratic)
        if self.config.inertial_parameters:
            params.add("base_com_offset", 3)
            params.add("payload_kg", 1)
            if self.robot.arm_ee:
                params.add("base_payload_kg", 1)
        if self.object is not None:
            params.add("obj_ref", self.object.n_states, N + 1)
            params.add("obj_w", self.object.n_states)
        self.params = params
        self.state_names = [name for name, _ in self._state_parts()]
        self.nx = sum(size for _, size in self._state_parts())
        bounds = np.cumsum([0] + [size for _, size in self._state_parts()])
        self.state_offsets = {name: slice(bounds[i], bounds[i + 1]) for i, name in enumerate(self.state_names)}
        scales = form.variable_scales()
        if any(name in scales for name in self.state_names):
            raise ConfigError("state parts must stay unscaled: Fatrop needs x_{k+1} with coefficient 1 in the gap rows")
        offset = 0
        index: dict[str, list[np.ndarray]] = {}
        x_scale: list[np.ndarray] = []
        self.stage_slices: list[tuple[slice, slice]] = []  # (state, input) of each node in x
        for k in range(N + 1):
            start = offset
            for name, size in self._stage_parts(k):
                x_scale.append(np.asarray(scales.get(name, np.ones(size)), dtype=float))
                index.setdefault(name, []).append(np.arange(offset, offset + size))
                offset += size
            self.stage_slices.append((slice(start, start + self.nx), slice(start + self.nx, offset)))
        self.n_variables = offset
        self.idx = {name: np.array(rows) for name, rows in index.items()}
        self.x_scale = np.concatenate(x_scale)

    def _state_parts(self) -> list[tuple[str, int]]:
        """The robot's state parts, then the object's (`obj`)."""
        extra = [("obj", self.object.n_states)] if self.object is not None else []
        return self.formulation.state_parts() + extra

    def _stage_parts(self, k: int) -> list[tuple[str, int]]:
        """Node k's variables in order: states, inputs (the robot's, the object's `obj_u`), slacks."""
        inputs = self.formulation.input_parts(k) if k < self.N else []
        if inputs and self.object is not None:
            inputs = inputs + [("obj_u", self.object.n_inputs)]
        return self._state_parts() + inputs + self._slack_parts(k)

    def initial_state(self, q_ref: np.ndarray, v0: np.ndarray, object_state: np.ndarray | None = None) -> np.ndarray:
        """x_0: the robot's measured state and, with an object model, the object's."""
        x0 = self.formulation.initial_state(q_ref, v0)
        if self.object is None:
            return x0
        if object_state is None or np.size(object_state) != self.object.n_states:
            raise ConfigError(f"the OCP models the {self.object.name}: each step needs its measured state "
                              f"({self.object.n_states} values: {', '.join(self.object.state_names)})")
        return np.concatenate([x0, np.asarray(object_state, dtype=float).ravel()])

    def _implied_torque_joints(self) -> np.ndarray:
        """Indices of the joints with implied-torque rows. "auto": "weak" on a robot with flat feet, else none.
        "weak": the leg joints weaker than the robot's weight on a sole's edge (M g times the horizontal distance
        from the foot link's origin to the sole's farthest edge): there a sole's wrench can put the CoP where the
        joint's torque runs out (g1: its 35 N m ankles, 41 N m at the toe 12.5 cm ahead of the ankle; its plans put
        the CoP there in single support). Its 88-139 N m hips and knees are never the limit there (no implied row
        of theirs was active in 40 RTI QPs of g1's walk with rows on every leg joint, "legs"), and each row costs
        the QP and the generated code: 4 rows per node instead of 12, HPIPM 1.00 instead of 1.04 ms per iteration
        on the same 40 QPs, 17.5 MB of C instead of 18.6 (`solvers/codegen.py`). TALOS (100 N m,
        88 N m at its sole's edge) has none: with its leg rows its compiled NLP was 26 MB of C that -O1 did not
        build within 30 minutes on a loaded machine. Point feet carry no contact moment. A leg joint's torque
        depends on its leg's links and its sole's wrench only (RNEA's backward pass over the leg's subtree), every
        joint's on the whole tree; the arms' torques do not depend on where the CoP is."""
        choice = self.config.implied_torque_rows
        if choice == "auto":
            choice = "weak" if self.surface_feet else "none"
        legs = np.asarray(self.robot.leg_joint_mask, dtype=bool)
        mask = {"all": np.ones(self.nj, dtype=bool), "legs": legs, "weak": legs & self._weak_joints(),
                "none": np.zeros(self.nj, dtype=bool)}[choice]
        return np.flatnonzero(mask)

    def _weak_joints(self) -> np.ndarray:
        """Joints weaker than the robot's weight on a sole's edge (all False without flat feet)."""
        if not self.surface_feet:
            return np.zeros(self.nj, dtype=bool)
        robot = self.robot
        # the sole's farthest edge from the foot link's origin (g1's ankle: 3.5 cm behind the sole's centre)
        edge_m = max(max(abs(sole.centre_m[0]) + sole.half_length_m, abs(sole.centre_m[1]) + sole.half_width_m)
                     for sole in robot.soles.values())
        return np.asarray(robot.tau_max, dtype=float) < robot.mass_kg * GRAVITY_M_S2 * edge_m

    def _has_torque_limit_rows(self, k: int) -> bool:
        return ("torque_limit" in self.config.soft_rows and k < min(self.config.n_torque_nodes, self.N)
                and any(name == "tau" for name, _ in self.formulation.input_parts(k)))

    def _slack_parts(self, k: int) -> list[tuple[str, int]]:
        """Slack inputs of node k: `slack` for the soft velocity rows (nodes 1..N-1), `slack_tau` for the
        torque limit rows (k < 3), each s+ then s-."""
        velocity = {"ee_vel": 3 if self.has_arm else 0, "foot_vel": 3 * self.n_feet}
        n_velocity = sum(velocity.get(tag, 0) for tag in self.config.soft_rows) if 0 < k < self.N else 0
        n_torque = self.nj if self._has_torque_limit_rows(k) else 0
        return [(name, 2 * n) for name, n in (("slack_tau", n_torque), ("slack", n_velocity)) if n]

    @cached_property
    def slack_index(self) -> np.ndarray:
        """Positions of every slack variable in x (computed once, read-only: read every MPC step)."""
        parts = [self.idx[name].ravel() for name in ("slack_tau", "slack") if name in self.idx]
        index = np.concatenate(parts) if parts else np.zeros(0, dtype=int)
        index.setflags(write=False)
        return index

    @property
    def n_slack_variables(self) -> int:
        """Slack inputs of the soft rows (the paper's OCP has n_variables - n_slack_variables)."""
        return int(self.slack_index.size)

    def _stage_kind(self, k: int) -> tuple[bool, bool, bool]:
        """(has input, has torque rows/variables, is the measured node) — nodes of one kind share a Function."""
        return k < self.N, k < min(self.config.n_torque_nodes, self.N), k == 0

    def stage_parameters(self, p, k: int):
        """The slice of the global parameter vector stage k reads (its own dt, targets and forces)."""
        N, params = self.N, self.params
        names = params.names
        columns = {"dt": min(k, N - 1), "dq_des": k, "F_des": min(k, N - 1), "obj_ref": k, "contact_normal": min(k, N - 1)}
        return ca.vertcat(*[params.select(p, name, columns.get(name)) for name in names])

    def stage_function(self, k: int) -> tuple[ca.Function, list[tuple[str, int]]]:
        """The SX Function of node k's kind and the tags of its path rows, built on first need."""
        kind = self._stage_kind(k)
        if kind not in self._stage_functions:
            self._stage_functions[kind] = self._build_stage(k)
        return self._stage_functions[kind]

    def _build_stage(self, k: int) -> tuple[ca.Function, list[tuple[str, int]]]:
        form, nf = self.formulation, self.n_feet
        has_input, has_torque, first = self._stage_kind(k)
        local = ParameterPack()
        for name in self.params.names:
            rows, cols = self.params.shape(name)
            local.add(name, rows, cols if name == "rot_ref" else 1)
        q_ref, rot_ref, dt, mu = local["q_ref"], local["rot_ref"], local["dt"], local["mu"]
        layout = self._stage_parts(k)
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", sum(size for name, size in layout) - self.nx)
        scales = form.variable_scales()
        parts, offset, variables = {}, 0, ca.vertcat(x, u)
        for name, size in layout:
            sym = variables[offset : offset + size]
            parts[name] = sym * scales[name] if name in scales else sym  # NLP variable = part / scale
            offset += size
        node = Node(k, parts)
        form.kinematics(node, q_ref, rot_ref)
        if self.config.inertial_parameters:
            self._set_inertial(node, local["base_com_offset"], local["payload_kg"],
                               local["base_payload_kg"] if "base_payload_kg" in local.names else None)

        rows: list[tuple[str, ca.SX]] = []
        if first:
            rows.append(("x0", x))
        if has_input:
            dynamics = form.dynamics_rows(node)
            if dynamics.shape[0]:
                rows.append(("dynamics", dynamics))
            if has_torque:
                estimate = form.torque_estimate(node)
                if estimate is not None:
                    rows.append(("torque", estimate / self.robot.tau_max))
            elif self.implied_torque_joints.size:
                implied = form.implied_torques(node)
                if implied is not None:
                    joints = self.implied_torque_joints
                    rows.append(("implied_torque", implied[joints.tolist()] / self.robot.tau_max[joints]))
        if self._has_torque_limit_rows(k):
            rows.append(("torque_limit", node["tau"] / self.robot.tau_max))
        if not first and node.motion is not None:
            contact_frames = self.dyn.contact_frames[:nf]  # sole frames of flat feet
            feet = [self.dyn.frame_linear_velocity(node.config, node.motion, f) for f in contact_frames]
            rows.append(("foot_vel", ca.vertcat(*feet)))
            if self.surface_feet:
                soles = [self.dyn.frame_velocity(node.config, node.motion, contact_frames[i])[1] for i in self.surface_feet]
                rows.append(("foot_ang", ca.vertcat(*soles)))
            if self.has_arm:
                rows.append(("ee_vel", self.dyn.frame_linear_velocity(node.config, node.motion, self.robot.arm_ee)))
        if not first and self.collision is not None:
            rows.append(("collision", collision_rows(self.collision, node.config)))
        if self.object is not None:
            rows.extend(self._object_rows(node, parts, dt, has_input, first))
        slacks = [parts[name] for name in ("slack_tau", "slack") if name in parts]
        for name in ("slack_tau", "slack"):  # soft rows: r - s+ + s- (slacks in the order of the rows)
            if name not in parts:
                continue
            slack = parts[name]
            n_soft, used = slack.shape[0] // 2, 0
            for i, (tag, expr) in enumerate(rows):
                if tag in self.config.soft_rows and SLACK_PARTS[tag] == name:
                    size = expr.shape[0]
                    rows[i] = (tag, expr - slack[used : used + size] + slack[n_soft + used : n_soft + used + size])
                    used += size
            assert used == n_soft, "slack layout and soft rows disagree"
        if has_input:
            # friction cone (eq. 6) in units of the force scale, written as the smoothed second-order
            # cone mu F_z >= sqrt(F_x^2 + F_y^2 + eps^2) - eps: same set up to eps^2 / (2 |F_t|), but
            # its gradient never vanishes (the squared form is degenerate at F = 0, where unloaded
            # stance feet sit, and stalled Fatrop after pushes)
            # about the ground's normal n (a parameter, world z on a flat floor): normal force n.F, tangential F - (n.F) n
            # (with n = e_z the same numbers as mu F_z and F_x^2 + F_y^2, bit for bit)
            unit = parts["F"][: 3 * nf] / scales["F"][: 3 * nf]
            normals = local["contact_normal"]
            eps = CONE_SMOOTHING
            cone = []
            for i in self.point_feet:
                force, normal = unit[3 * i : 3 * i + 3], normals[3 * i : 3 * i + 3]
                pressing = ca.dot(normal, force)
                tangential = force - pressing * normal
                cone.append(mu * pressing - ca.sqrt(ca.sumsqr(tangential) + eps**2) + eps)
            if cone:
                rows.append(("cone", ca.vertcat(*cone)))
            if self.surface_feet:
                rows.append(("wrench_cone", ca.vertcat(*[self._wrench_cone(parts["F"], i, mu, scales["F"][3 * i + 2],
                                                                           normals[3 * i : 3 * i + 3])
                                                          for i in self.surface_feet])))

        # eq. (3): diagonal tracking cost; the terminal cost is the stage cost on the state
        cost = ca.dot(local["w_dq"], (node["dq"] - local["dq_des"]) ** 2)
        if node.motion is not None:
            cost += ca.dot(local["w_v"], (node.motion.v - local["v_des"]) ** 2)
        if has_input:
            w_a = local["w_a"]
            cost += ca.dot(w_a, node["a"] ** 2) if node.get("a") is not None else 0
            cost += ca.dot(w_a[6:], node["aj"] ** 2) if node.get("aj") is not None else 0
            cost += ca.dot(local["w_F"], (node["F"] - local["F_des"]) ** 2)
            cost += ca.dot(local["w_tau"], node["tau"] ** 2) if node.get("tau") is not None else 0
        for slack in slacks:
            cost += local["w_slack"] * ca.sum1(slack)  # exact L1 penalty of the soft rows
            cost += local["w_slack_sq"] * ca.sumsqr(slack)  # (s+)^2 + (s-)^2: the squared violation
        if self.object is not None:
            cost += ca.dot(local["obj_w"], (parts["obj"] - local["obj_ref"]) ** 2)
        next_state = form.transition(node, dt) if has_input else ca.SX(0, 1)
        if has_input and self.object is not None:
            next_state = ca.vertcat(next_state, self.object.transition(parts["obj"], parts["obj_u"], dt))
        path = ca.vertcat(*[expr for _, expr in rows]) if rows else ca.SX(0, 1)
        name = f"stage_{'first' if first else 'torque' if has_torque else 'plain' if has_input else 'terminal'}"
        function = ca.Function(name, [x, u, local.vector], [next_state, path, cost], ["x", "u", "p"], ["x_next", "g", "cost"])
        return function, [(tag, expr.shape[0]) for tag, expr in rows]

    def _object_rows(self, node: Node, parts: dict, dt, has_input: bool, first: bool) -> list[tuple[str, ca.SX]]:
        """The object's dynamics and cone rows (input nodes) and contact rows (nodes after the measurement)."""
        hand = self.dyn.frame_placement(node.config, self.robot.arm_ee)[0]
        rows = []
        if has_input:
            arm = parts["F"][3 * self.n_feet : 3 * self.n_feet + 3]
            rows.extend(self.object.input_rows(parts["obj"], parts["obj_u"], arm, hand, dt))
        if not first:
            rows.append(("obj_contact", self.object.contact_rows(parts["obj"], hand)))
        return rows

    @staticmethod
    def _set_inertial(node: Node, base_com_offset, payload_kg, base_payload_kg) -> None:
        """The node's dynamics use the mass distribution of these parameters."""
        node.config.inertial = InertialParameters(base_com_offset, payload_kg, base_payload_kg)

    def _wrench_cone(self, forces: ca.SX, i: int, mu: ca.SX, scale: float, normal: ca.SX) -> ca.SX:
        """The linear wrench cone rows (>= 0 in stance) of flat foot i, in units of the force scale, about the ground's
        normal n: the friction pyramid along the tangents t1 = (n_z, 0, -n_x) / |.| and t2 = n x t1 (world x and y
        on a flat floor, exactly), the centre of pressure and the yaw moment of the sole's own moments (the sole
        lies on the ground: its z axis is n). Each row is f_n minus a force (the moment rows divided by their
        lever, the sole's half size), so all rows and their multipliers have the force's scale. With the moment
        rows in N m x lever (hw f_z - tau_x: 3-10x smaller than the friction rows) Fatrop took 13.7 iterations per
        step on g1's walk in place (compiled, closed loop, 1 s), 10.0 with them divided by the lever: the same set,
        the same plans (drift, velocity RMSE to 3 digits)."""
        sole = self.robot.soles[self.robot.feet[i]]
        force = forces[3 * i : 3 * i + 3] / scale
        length = ca.sqrt(normal[2] ** 2 + normal[0] ** 2)
        first = ca.vertcat(normal[2], 0, -normal[0]) / length
        second = ca.cross(normal, first)
        fx, fy, fz = ca.dot(first, force), ca.dot(second, force), ca.dot(normal, force)
        tx, ty, tz = (forces[self.dyn.moment_slice(i)][k] / scale for k in range(3))
        yaw_arm = min(sole.half_length_m, sole.half_width_m)  # torsional friction's lever (times mu)
        return ca.vertcat(
            mu * fz - fx, mu * fz + fx, mu * fz - fy, mu * fz + fy,  # friction pyramid
            fz - tx / sole.half_width_m, fz + tx / sole.half_width_m,  # centre of pressure across the sole
            fz - ty / sole.half_length_m, fz + ty / sole.half_length_m,  # ... and along it
            mu * fz - tz / yaw_arm, mu * fz + tz / yaw_arm,  # torsional friction
        )

    def _assemble(self) -> dict:
        """The NLP with each stage Function called (inlined) once per node, and the row bookkeeping."""
        N = self.N
        x = ca.SX.sym("x", self.n_variables)
        p = ca.SX.sym("p", self.params.size)
        rows: dict[str, list[np.ndarray]] = {tag: [] for tag in ROW_TAGS}
        row_nodes: dict[str, list[int]] = {tag: [] for tag in ROW_TAGS}
        g, cost, n_rows = [], 0, 0
        self._stage_row_starts = np.zeros(N + 1, dtype=int)
        for k in range(N + 1):
            self._stage_row_starts[k] = n_rows
            function, tags = self.stage_function(k)
            state, inputs = self.stage_slices[k]
            next_state, path, stage_cost = function(x[state], x[inputs], self.stage_parameters(p, k))
            cost += stage_cost
            if k < N:
                g.append(x[self.stage_slices[k + 1][0]] - next_state)
                rows["gap"].append(np.arange(n_rows, n_rows + self.nx))
                row_nodes["gap"].append(k)
                n_rows += self.nx
            g.append(path)
            for tag, size in tags:
                rows[tag].append(np.arange(n_rows, n_rows + size))
                row_nodes[tag].append(k)
                n_rows += size
        self._rows = {tag: _stack_rows(idx) for tag, idx in rows.items()}
        self._row_nodes = {tag: np.array(nodes, dtype=int) for tag, nodes in row_nodes.items()}
        self._n_constraints = n_rows
        self._equality = np.zeros(n_rows, dtype=bool)
        self._equality[self._rows["gap"].ravel()] = True
        return {"x": x, "p": p, "f": cost, "g": ca.vertcat(*g)}

    def instructions_per_constraint(self) -> int:
        """Instructions of the dynamics constraint of one plain input node (Table I column): its
        dynamics path rows for path formulations, its state transition for transition formulations."""
        function, tags = self.stage_function(min(self.config.n_torque_nodes, self.N - 1))
        x, u, p = (ca.SX.sym(name, function.size1_in(i)) for i, name in enumerate(("x", "u", "p")))
        next_state, path, _ = function(x, u, p)
        if self.formulation.dynamics_as == "path":
            sizes = dict(tags)
            start = sum(size for tag, size in tags[: [tag for tag, _ in tags].index("dynamics")])
            expr = path[start : start + sizes["dynamics"]]
        else:
            expr = next_state
        return int(ca.Function("dynamics", [x, u, p], [expr]).n_instructions())

    def trajectory_function(self) -> ca.Function:
        """(x, p) -> dq (nv, N+1), v (nv, N+1), a (nv, N), F (nf, N), tau_j (nj, n_torque_nodes):
        the physical trajectories of any formulation (velocity-level ones get a by differences and
        the inverse-dynamics torques of that plan)."""
        form, N = self.formulation, self.N
        x = ca.SX.sym("x", self.n_variables)
        p = ca.SX.sym("p", self.params.size)
        q_ref = ca.reshape(self.params.select(p, "q_ref"), self.dyn.nq, 1)
        rot_ref = ca.reshape(self.params.select(p, "rot_ref"), 3, 3)
        dt = self.params.select(p, "dt")
        physical = x * self.x_scale
        nodes = []
        for k in range(N + 1):
            node = Node(k, {name: physical[rows[k]] for name, rows in self.idx.items() if k < len(rows)})
            form.kinematics(node, q_ref, rot_ref)
            if self.config.inertial_parameters:
                self._set_inertial(node, self.params.select(p, "base_com_offset"), self.params.select(p, "payload_kg"),
                                   self.params.select(p, "base_payload_kg") if "base_payload_kg" in self.params.names else None)
            nodes.append(node)
        velocities = [n.motion.v if n.motion is not None else None for n in nodes]
        for k in range(N + 1):
            if velocities[k] is None:
                velocities[k] = velocities[k - 1]
        accelerations = []
        for k in range(N):
            a = nodes[k].acceleration
            accelerations.append(a if a is not None else (velocities[k + 1] - velocities[k]) / dt[k])
        n_tau = min(self.config.n_torque_nodes, N)
        torques = []
        for k in range(n_tau):  # input nodes: every formulation has their motion
            torques.append(form.joint_torques(nodes[k], accelerations[k]))
        outputs = [
            ca.horzcat(*[n["dq"] for n in nodes]),
            ca.horzcat(*velocities),
            ca.horzcat(*accelerations),
            ca.horzcat(*[nodes[k]["F"] for k in range(N)]),
            ca.horzcat(*torques),
        ]
        return ca.Function("trajectories", [x, p], outputs, ["x", "p"], ["dq", "v", "a", "F", "tau"])

    # ------------------------------------------------------------------ per-step data
    def bounds_template(self) -> BoundsTemplate:
        """The step-independent part of `bounds` (built once per `bounds_packer`)."""
        template = self._bounds_template
        if template is None or template.packer is not self.bounds_packer:
            template = self._bounds_template = BoundsTemplate(self, self.bounds_packer, EARLY_NODES, BLEND_TIME_S,
                                                              SWING_YAW_RATE_BAND_RAD_S)
        return template

    def bounds(self, data: StageBounds) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lbx, ubx, lbg, ubg for one step: the constant and contact-dependent entries from `BoundsTemplate`
        (one copy and one gather), then the measurement's."""
        robot, nf = self.robot, self.n_feet
        rows, idx = self.rows, self.idx  # (properties: read once)
        template = self.bounds_template()
        contact = np.asarray(data.contact, dtype=bool)
        buffer, lbx, ubx, lbg, ubg = template.start(contact, data.soft)
        if template.measured is not None and template.measured.write(template.last_address, data, contact):
            return template.views(buffer)  # the entries below, in C (bounds_template.py)
        # eq. (8): joint position / velocity limits on nodes 1..N, torque limits on k < 3 (the template's)
        # The first nodes follow from the measurement (dq_1 = v_0 dt_0; velocities change only by
        # a dt): over the first EARLY_NODES nodes the limits are widened to contain the coasting
        # extrapolation of the measured state, or a state past a limit (e.g. after a push) would
        # make the whole OCP infeasible. Later nodes keep the true limits (eq. 8).
        early = slice(0, min(EARLY_NODES, self.N))
        if "dq" in idx:
            joint_dq = idx["dq"][1:, 6:]
            q_joints = robot.joint_positions(data.q_ref)
            lbx[joint_dq] = robot.q_min - q_joints
            ubx[joint_dq] = robot.q_max - q_joints
            if "v" in self.state_names:  # Euler: dq_{k+1} = dq_k + v_k dt_k
                coasting = self.config.grid.node_times_s[1:][early, None] * data.v0[6:]
                early_dq = joint_dq[early]
                lbx[early_dq] = np.minimum(lbx[early_dq], np.minimum(coasting, 0.0) - 1e-6)
                ubx[early_dq] = np.maximum(ubx[early_dq], np.maximum(coasting, 0.0) + 1e-6)
        # joint velocities (states from node 1 on, inputs on every node) over the first nodes: the measured overspeed
        for name, columns in (("v", slice(6, None)), ("vj", slice(None))):
            if name in idx:
                joint_v = idx[name][1:, columns] if name in self.state_names else idx[name][:, columns]
                overspeed = np.maximum(robot.v_max, np.abs(data.v0[6:]))
                lbx[joint_v[early]] = -overspeed
                ubx[joint_v[early]] = overspeed
        # velocity-level formulations: the first input's joint velocities are the measured ones (the
        # base velocity follows from the measured momentum), so the plan starts from the robot's motion
        for name, columns in (("v", slice(6, None)), ("vj", slice(None))):
            if name in idx and name not in self.state_names:
                lbx[idx[name][0, columns]] = data.v0[6:]
                ubx[idx[name][0, columns]] = data.v0[6:]
        # eq. (6) forces (the template's: stance F_z >= 0, swing F = 0); eq. (7): arm force fixed to the command
        if "F" in idx and self.has_arm:
            arm_f = idx["F"][:, 3 * nf : 3 * nf + 3]
            force = np.zeros(3) if data.ee_force_on_robot_n is None else data.ee_force_on_robot_n
            lower, upper = (force, force) if self.object is None else self.object.arm_force_bounds()
            lbx[arm_f] = lower
            ubx[arm_f] = upper
        # node 0 = measured state
        x0 = self.initial_state(data.q_ref, data.v0, data.object_state)
        lbg[rows["x0"][0]] = x0
        ubg[rows["x0"][0]] = x0
        self._foot_bounds(lbg, ubg, data, contact)
        if self.has_arm and "ee_vel" not in data.relaxed_rows:  # (relaxed rows are free whatever they held)
            velocity = np.zeros(3) if data.ee_velocity_m_s is None else data.ee_velocity_m_s
            lbg[rows["ee_vel"]] = velocity
            ubg[rows["ee_vel"]] = velocity
            if data.ee_velocity_measured_m_s is not None:
                ee_rows = rows["ee_vel"]
                self._blend_from_measurement(lbg, ubg, ee_rows.ravel(), "ee_vel", velocity[None],
                                             np.asarray(data.ee_velocity_measured_m_s)[None])
        if self.collision is not None:
            self._collision_bounds(lbg, ubg, data)
        if self.object is not None:
            self._object_bounds(lbg, ubg, data)
        for tag in data.relaxed_rows:
            if tag not in ("ee_vel", "foot_vel"):
                raise ConfigError(f"relaxed_rows: only ee_vel and foot_vel rows can be relaxed, got {tag!r}")
            lbg[rows[tag]] = -INF
            ubg[rows[tag]] = INF
        # friction cones: the template's (active in stance, free in swing)
        return template.finish(buffer)

    def _foot_bounds(self, lbg, ubg, data: StageBounds, contact: np.ndarray) -> None:
        """Eq. (6) foot velocities on nodes 1..N: stance 0, swing v_z = reference, v_xy free (the template's) or
        carried to a placement; flat feet: no rotation in stance, roll and pitch rates zero in swing (the template's),
        yaw to a landing heading; stance feet measured moving blend from the measurement."""
        rows, row_nodes, nf = self.rows, self.row_nodes, self.n_feet
        foot_nodes = row_nodes["foot_vel"]
        foot_rows = rows["foot_vel"].reshape(len(foot_nodes), nf, 3)
        swing = ~contact[foot_nodes]
        vz = np.where(swing, data.swing_vz_m_s[foot_nodes], 0.0)
        lbg[foot_rows[..., 2]] = vz
        ubg[foot_rows[..., 2]] = vz
        if data.swing_vxy_m_s is not None:  # swing feet carried to their placement
            vxy = np.asarray(data.swing_vxy_m_s, dtype=float)[foot_nodes]
            placed = swing[..., None] & np.isfinite(vxy)
            lbg[foot_rows[..., :2][placed]] = vxy[placed]
            ubg[foot_rows[..., :2][placed]] = vxy[placed]
        if data.foot_velocity_m_s is not None:  # stance feet measured sliding (right after a push)
            stance = np.broadcast_to(~swing[..., None], foot_rows.shape)
            self._blend_from_measurement(lbg, ubg, foot_rows[stance], "foot_vel", np.zeros((1, nf, 3)),
                                         np.asarray(data.foot_velocity_m_s)[None], stance)
        if not self.surface_feet:
            return
        ang_rows = rows["foot_ang"].reshape(len(row_nodes["foot_ang"]), len(self.surface_feet), 3)
        swing_ang = ~contact[row_nodes["foot_ang"]][:, self.surface_feet]
        if data.swing_yaw_rate_rad_s is not None:  # swing soles turned to their landing heading
            yaw_rate = np.asarray(data.swing_yaw_rate_rad_s, dtype=float)[row_nodes["foot_ang"]]
            yaw_rate = yaw_rate[:, self.surface_feet]
            turned = swing_ang & np.isfinite(yaw_rate)
            lbg[ang_rows[..., 2][turned]] = yaw_rate[turned] - SWING_YAW_RATE_BAND_RAD_S
            ubg[ang_rows[..., 2][turned]] = yaw_rate[turned] + SWING_YAW_RATE_BAND_RAD_S
        if data.foot_angular_velocity_rad_s is not None:  # stance soles measured rotating (after a push)
            stance_ang = np.broadcast_to(~swing_ang[..., None], ang_rows.shape)
            measured = np.asarray(data.foot_angular_velocity_rad_s)[self.surface_feet]
            self._blend_from_measurement(lbg, ubg, ang_rows[stance_ang], "foot_ang",
                                         np.zeros((1, len(self.surface_feet), 3)), measured[None], stance_ang)

    def _object_bounds(self, lbg, ubg, data: StageBounds) -> None:
        """Object rows: dynamics = 0, cone >= 0 (no force while the hand is still planned off the object), contact
        rows from the measured gap to contact over CONTACT_BLEND_TIME_S, free on node 1; the arm's velocity rows of
        eq. (7) dropped (the contact rows place the hand)."""
        if data.object_contact_measured is None:
            raise ConfigError(f"the OCP models the {self.object.name}: pass the measured contact rows "
                              "(StageBounds.object_contact_measured)")
        times = self.config.grid.node_times_s
        nodes = self.row_nodes["obj_contact"]
        lower, upper, may_push = self.object.contact_bounds(np.asarray(data.object_contact_measured), times)
        rows = self.rows["obj_contact"]
        lbg[rows] = lower[nodes]
        ubg[rows] = upper[nodes]
        lbg[rows[nodes == 1]] = -INF
        ubg[rows[nodes == 1]] = INF
        lbg[self.rows["obj_dyn"]] = 0.0
        ubg[self.rows["obj_dyn"]] = 0.0
        cone_nodes = self.row_nodes["obj_cone"]
        lbg[self.rows["obj_cone"]] = 0.0
        ubg[self.rows["obj_cone"]] = self.object.cone_upper(may_push[cone_nodes + 1])
        lbg[self.rows["ee_vel"]] = -INF  # an object model needs an arm (__init__)
        ubg[self.rows["ee_vel"]] = INF

    def collision_rows_at(self, q: np.ndarray) -> np.ndarray:
        """The collision rows (smooth minimum distance per pair group, m) at configuration q."""
        return np.asarray(self._collision_function(q)[1], dtype=float).ravel()

    def _collision_bounds(self, lbg, ubg, data: StageBounds) -> None:
        """Rows >= margin; free on node 1 where the measurement fixes its configuration ([dq, v] states);
        a measured distance below the margin is the bound at the measurement and reaches the margin
        linearly over COLLISION_BLEND_TIME_S (a state past the margin would otherwise be infeasible)."""
        rows, nodes = self.rows["collision"], self.row_nodes["collision"]
        margin = self.collision.config.margin_m
        lower = np.full(rows.shape, margin)
        if data.collision_measured_m is not None:
            deficit = np.maximum(margin - np.asarray(data.collision_measured_m, dtype=float), 0.0)
            decay = np.clip(1.0 - self.config.grid.node_times_s[nodes] / COLLISION_BLEND_TIME_S, 0.0, 1.0)
            lower = lower - decay[:, None] * (deficit[None, :] + 1e-3 * (deficit[None, :] > 0))
        if "v" in self.state_names:
            lower[nodes == 1] = -INF
        lbg[rows] = lower
        ubg[rows] = INF

    def _blend_from_measurement(self, lbg, ubg, rows, tag: str, target, measured, mask=None) -> None:
        """Move the targets of equality rows "velocity = target" on the first nodes onto the path that
        goes linearly from the measured velocity to the target over BLEND_TIME_S.

        A foot or end-effector measured far from its constraint (e.g. right after a push) cannot
        reach it within the first 10 ms step without forces beyond the friction cone and the
        torque limits; requiring it makes the OCP infeasible. The rows stay equalities (Fatrop's
        stage structure is unchanged) and later nodes keep eqs. (6)-(7) exactly.
        """
        decay = self._blend_decays.get(tag)
        if decay is None:  # per row tag, its nodes' share of the way left (constant: computed on first use)
            nodes = self.row_nodes[tag]
            decay = np.minimum(np.maximum(1.0 - self.config.grid.node_times_s[nodes] / BLEND_TIME_S, 0.0), 1.0)
            decay = self._blend_decays[tag] = decay.reshape((-1,) + (1,) * (np.ndim(target) - 1))
        shape = (len(decay),) + np.shape(target)[1:]
        path = np.broadcast_to(target + decay * (measured - target), shape)
        path = (path[mask] if mask is not None else path).ravel()
        lbg[rows] = path
        ubg[rows] = path

    # ------------------------------------------------------------------ variables <-> trajectories
    def unpack(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """NLP vector -> physical trajectories per part, shape (nodes with that part, size)."""
        physical = np.asarray(x, dtype=float) * self.x_scale
        return {name: physical[index] for name, index in self.idx.items()}

    def pack(self, parts: dict[str, np.ndarray]) -> np.ndarray:
        """Physical trajectories per part -> NLP vector (parts not given are zero)."""
        x = np.zeros(self.n_variables)
        for name, value in parts.items():
            x[self.idx[name]] = value
        return x / self.x_scale


def _stack_rows(blocks: list[np.ndarray]) -> np.ndarray:
    """Per-node row blocks as a (nodes, rows) array, or flat when their sizes differ."""
    if not blocks:
        return np.zeros((0, 0), dtype=int)
    if len({b.size for b in blocks}) == 1:
        return np.stack(blocks)
    return np.concatenate(blocks)
