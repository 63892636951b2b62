"""The stage-wise OCP (eq. 1) as one NLP whose structure Fatrop can exploit.

Decision variables are ordered x0, u0, x1, u1, ..., xN; the constraints of stage k are the
gap-closing rows x_{k+1} - f(x_k, u_k) first, then the path rows of stage k. Everything that
changes between MPC steps is either a CasADi parameter (reference configuration, dt grid,
targets, weights, friction) or a bound (initial state, contact schedule, swing velocity
references, arm commands, joint limits): one build serves every step.

Path constraints per node (section IV-B):
- dynamics rows of the formulation (eq. 5 for wb_inverse);
- contact (eq. 6): stance feet F_z >= 0 (bound), friction cone mu^2 F_z^2 - F_x^2 - F_y^2 >= 0,
  foot velocity = 0; swing feet F = 0 (bounds), foot v_z = spline reference, v_x, v_y free;
- arm (eq. 7): end-effector force = command (bounds), linear velocity = command;
- limits (eq. 8): joint positions and velocities on every node, torques on k < 3 (bounds).
State-only rows (foot/arm velocities, joint limits) start at node 1: node 0 is the measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from wbmpc.ocp.formulations import Formulation, Node, make_formulation
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.parameters import ParameterPack
from wbmpc.robots import RobotModel
from wbmpc.symbolic import SymbolicDynamics

INF = np.inf
EARLY_NODES = 4  # nodes after the measurement whose joint limits may be widened (about 50 ms)
CONE_SMOOTHING = 1e-3  # in units of the force scale (about 0.15 N on b1_z1)


@dataclass(frozen=True)
class OcpConfig:
    """Structure of the OCP (changing any of these needs a new build)."""

    formulation: str = "wb_inverse"
    grid: TimeGrid = field(default_factory=TimeGrid)
    n_torque_nodes: int = 3  # torques (and their limits) on k = 0, 1, 2 (eq. 8)

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
    ee_velocity_m_s: np.ndarray | None = None  # (3,) world
    ee_force_on_robot_n: np.ndarray | None = None  # (3,) world, force acting on the robot


class OcpProblem:
    """Builds the NLP once; `bounds()` and `parameters` map per-step task data onto it."""

    def __init__(self, robot: RobotModel, config: OcpConfig = OcpConfig(), dyn: SymbolicDynamics | None = None):
        self.robot = robot
        self.config = config
        self.dyn = dyn or SymbolicDynamics(robot)
        self.formulation: Formulation = make_formulation(config.formulation, self.dyn, config.n_torque_nodes)
        self.N = config.n_intervals
        self.nv, self.nj, self.nf = self.dyn.nv, self.dyn.nv - 6, self.dyn.n_forces
        self.n_feet = len(robot.feet)
        self.has_arm = robot.arm_ee is not None
        self._build()

    # ------------------------------------------------------------------ build
    def _build(self) -> None:
        N, nv, nf = self.N, self.nv, self.nf
        form = self.formulation
        params = ParameterPack()
        q_ref = params.add("q_ref", self.dyn.nq)
        rot_ref = params.add("rot_ref", 3, 3)
        dt = params.add("dt", N)
        dq_des = params.add("dq_des", nv, N + 1)
        v_des = params.add("v_des", nv)
        f_des = params.add("F_des", nf, N)
        w_dq = params.add("w_dq", nv)
        w_v = params.add("w_v", nv)
        w_a = params.add("w_a", nv)
        w_f = params.add("w_F", nf)
        w_tau = params.add("w_tau", self.nj)
        mu = params.add("mu", 1)
        self.params = params

        # decision variables in stage order, with index bookkeeping
        blocks, offset = [], 0
        index: dict[str, list[np.ndarray]] = {}
        scales = form.variable_scales()
        x_scale: list[np.ndarray] = []
        nodes: list[Node] = []
        for k in range(N + 1):
            parts = {}
            layout = form.state_parts() + (form.input_parts(k) if k < N else [])
            for name, size in layout:
                sym = ca.SX.sym(f"{name}_{k}", size)
                scale = np.asarray(scales.get(name, np.ones(size)), dtype=float)
                parts[name] = sym * scale if name in scales else sym  # NLP variable = part / scale
                blocks.append(sym)
                x_scale.append(scale)
                index.setdefault(name, []).append(np.arange(offset, offset + size))
                offset += size
            nodes.append(Node(k, parts))
        self.n_variables = offset
        self.idx = {name: np.array(rows) for name, rows in index.items()}
        self.x_scale = np.concatenate(x_scale)
        state_names = [n for n, _ in form.state_parts()]

        rows: dict[str, list] = {name: [] for name in ("gap", "x0", "dynamics", "foot_vel", "ee_vel", "cone")}
        g, n_rows = [], 0

        def add(tag: str, expr: ca.SX) -> np.ndarray:
            nonlocal n_rows
            index = np.arange(n_rows, n_rows + expr.shape[0])
            g.append(expr)
            n_rows += expr.shape[0]
            rows[tag].append(index)
            return index

        cost = 0
        feet = self.robot.feet
        force_scale = np.asarray(scales.get("F", np.ones(nf)), dtype=float)
        for k, node in enumerate(nodes):
            node.config, node.motion = form.kinematics(node, q_ref, rot_ref)
            x_k = ca.vertcat(*[node[n] for n in state_names])
            if k < N:
                x_next = ca.vertcat(*[nodes[k + 1][n] for n in state_names])
                add("gap", x_next - form.transition(node, dt[k]))
                if k == 0:
                    add("x0", x_k)
                dyn_rows = form.dynamics_rows(node)
                if dyn_rows.shape[0]:
                    add("dynamics", dyn_rows)
            if k >= 1:
                foot_vel = [self.dyn.frame_linear_velocity(node.config, node.motion, f) for f in feet]
                add("foot_vel", ca.vertcat(*foot_vel))
                if self.has_arm:
                    add("ee_vel", self.dyn.frame_linear_velocity(node.config, node.motion, self.robot.arm_ee))
            if k < N:
                forces = node["F"] if "F" in node.parts else None
                if forces is not None:
                    # friction cone (eq. 6) in units of the force scale, written as the smoothed second-order
                    # cone mu F_z >= sqrt(F_x^2 + F_y^2 + eps^2) - eps: same set up to eps^2 / (2 |F_t|),
                    # but its gradient never vanishes (the squared form is degenerate at F = 0, where
                    # unloaded stance feet sit, and stalled Fatrop after pushes)
                    unit = forces[: 3 * self.n_feet] / force_scale[: 3 * self.n_feet]
                    eps = CONE_SMOOTHING
                    cone = [mu * unit[3 * i + 2] - ca.sqrt(unit[3 * i] ** 2 + unit[3 * i + 1] ** 2 + eps**2) + eps
                            for i in range(self.n_feet)]
                    add("cone", ca.vertcat(*cone))
            # eq. (3): diagonal tracking cost; terminal cost = stage cost on the state
            v_k = node.motion.v
            cost += ca.dot(w_dq, (node.get("dq") - dq_des[:, k]) ** 2) if "dq" in node.parts else 0
            cost += ca.dot(w_v, (v_k - v_des) ** 2)
            if k < N:
                if node.get("a") is not None:
                    cost += ca.dot(w_a, node["a"] ** 2)
                if node.get("F") is not None:
                    cost += ca.dot(w_f, (node["F"] - f_des[:, k]) ** 2)
                if node.get("tau") is not None:
                    cost += ca.dot(w_tau, node["tau"] ** 2)

        self.rows = {tag: _stack_rows(idx) for tag, idx in rows.items()}
        self.n_constraints = n_rows
        self.nlp = {"x": ca.vertcat(*blocks), "p": params.vector, "f": cost, "g": ca.vertcat(*g)}
        self.equality = np.zeros(n_rows, dtype=bool)  # structural equalities (gap rows) for Fatrop
        self.equality[self.rows["gap"].ravel()] = True
        self.state_names = state_names

    # ------------------------------------------------------------------ per-step data
    def bounds(self, data: StageBounds) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lbx, ubx, lbg, ubg for one step (vectorised, no rebuild)."""
        robot, N, nf = self.robot, self.N, self.n_feet
        lbx = np.full(self.n_variables, -INF)
        ubx = np.full(self.n_variables, INF)
        lbg = np.zeros(self.n_constraints)
        ubg = np.zeros(self.n_constraints)
        contact = np.asarray(data.contact, dtype=bool)
        # eq. (8): joint position / velocity limits on nodes 1..N, torque limits on k < 3
        # The first nodes follow from the measurement (dq_1 = v_0 dt_0; velocities change only by
        # a dt): over the first EARLY_NODES nodes the limits are widened to contain the coasting
        # extrapolation of the measured state, or a state past a limit (e.g. after a push) would
        # make the whole OCP infeasible. Later nodes keep the true limits (eq. 8).
        early = slice(0, min(EARLY_NODES, self.N))
        if "dq" in self.idx:
            joint_dq = self.idx["dq"][1:, 6:]
            lbx[joint_dq] = robot.q_min - data.q_ref[7:]
            ubx[joint_dq] = robot.q_max - data.q_ref[7:]
            if "v" in self.state_names:  # Euler: dq_{k+1} = dq_k + v_k dt_k
                coasting = np.outer(self.config.grid.node_times_s[1:], data.v0[6:])[early]
                rows = joint_dq[early]
                lbx[rows] = np.minimum(lbx[rows], np.minimum(coasting, 0.0) - 1e-6)
                ubx[rows] = np.maximum(ubx[rows], np.maximum(coasting, 0.0) + 1e-6)
        if "v" in self.idx:
            joint_v = self.idx["v"][1:, 6:]
            lbx[joint_v] = -robot.v_max
            ubx[joint_v] = robot.v_max
            overspeed = np.maximum(robot.v_max, np.abs(data.v0[6:]))
            lbx[joint_v[early]] = -overspeed
            ubx[joint_v[early]] = overspeed
        if "tau" in self.idx:
            lbx[self.idx["tau"]] = -robot.tau_max
            ubx[self.idx["tau"]] = robot.tau_max
        # eq. (6) forces: stance F_z >= 0, swing F = 0; eq. (7): arm force fixed to the command
        if "F" in self.idx:
            feet_f = self.idx["F"][:, : 3 * nf].reshape(N, nf, 3)
            stance = contact[:N]
            lbx[feet_f[..., 2]] = 0.0
            ubx[feet_f] = np.where(stance[..., None], INF, 0.0)
            lbx[feet_f[..., :2]] = np.where(stance[..., None], -INF, 0.0)
            if self.has_arm:
                arm_f = self.idx["F"][:, 3 * nf : 3 * nf + 3]
                force = np.zeros(3) if data.ee_force_on_robot_n is None else data.ee_force_on_robot_n
                lbx[arm_f] = force
                ubx[arm_f] = force
        # node 0 = measured state
        x0 = self.formulation.initial_state(data.v0)
        lbg[self.rows["x0"][0]] = x0
        ubg[self.rows["x0"][0]] = x0
        # eq. (6) foot velocities on nodes 1..N: stance 0, swing v_z = reference, v_xy free
        foot_rows = self.rows["foot_vel"].reshape(N, nf, 3)
        swing = ~contact[1:]
        vz = np.where(swing, data.swing_vz_m_s[1:], 0.0)
        lbg[foot_rows[..., 2]] = vz
        ubg[foot_rows[..., 2]] = vz
        lbg[foot_rows[..., :2]] = np.where(swing[..., None], -INF, 0.0)
        ubg[foot_rows[..., :2]] = np.where(swing[..., None], INF, 0.0)
        if self.has_arm:
            velocity = np.zeros(3) if data.ee_velocity_m_s is None else data.ee_velocity_m_s
            lbg[self.rows["ee_vel"]] = velocity
            ubg[self.rows["ee_vel"]] = velocity
        # friction cone: active in stance, free in swing
        if self.rows["cone"].size:
            ubg[self.rows["cone"]] = INF
            lbg[self.rows["cone"]] = np.where(contact[:N], 0.0, -INF)
        return lbx / self.x_scale, ubx / self.x_scale, lbg, ubg

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
