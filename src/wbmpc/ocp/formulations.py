"""Dynamics formulations (Table I): what a stage's state and input are and how the dynamics enter.

Every formulation shares the OCP machinery (gait, contact, arm, limits, cost); it only defines its
state/input parts, the state transition, the dynamics path rows and how to read q, v, a and the
joint torques off a node. All of them carry the configuration as an increment dq on the reference
q_hat (eq. 4) and use explicit Euler steps.

| name                  | x         | u            | dynamics                                          |
|-----------------------|-----------|--------------|---------------------------------------------------|
| `wb_inverse`          | [dq, v]   | [a, F, tau_j]| path: [0; tau_j] = RNEA(q, v, a, F) (eq. 5)        |
| `wb_forward`          | [dq, v]   | [tau_j, F]   | transition: a = M^-1([0; tau_j] + J^T F - b)       |
| `centroidal_vel_path` | [h, dq]   | [v, F]       | path: h = A(q) v                                   |
| `centroidal_vel`      | [h, dq]   | [v_j, F]     | transition: v_b = A_b^-1 (h - A_j v_j)             |
| `centroidal_acc_path` | [dq, v]   | [a, F]       | path: hdot(F) = Adot v + A a                       |
| `centroidal_acc`      | [dq, v]   | [a_j, F]     | transition: a_b = A_b^-1 (hdot(F) - Adot v - A_j a_j) |

The centroidal ones evolve h with hdot = [sum F + m g; sum (p_i - c) x F_i + sum R_i tau_i] (the
moments tau_i of flat feet, in their sole frames R_i: `SymbolicDynamics.centroidal_wrench`). Joint torques appear as
variables only where the formulation has them (`tau` on k < 3 for `wb_inverse`, every node for
`wb_forward`); the centroidal ones bound the quasi-static estimate g_j(q) - J_j^T F on k < 3
instead, as the paper does (section VI-A).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError, unknown_name
from wbmpc.robots import GRAVITY_M_S2
from wbmpc.symbolic import Configuration, Motion, SymbolicDynamics

MOMENT_ARM_SCALE_M = 0.02  # lever of a sole moment's variable (tau / (force scale x this)): 0.1 and 1 stall Fatrop on g1's single support


@dataclass
class Node:
    """Symbols of one stage k: named state and input parts, plus derived kinematics."""

    k: int
    parts: dict[str, ca.SX]
    config: Configuration | None = None
    motion: Motion | None = None
    acceleration: ca.SX | None = None  # generalized acceleration of an input node, built once
    inverse_dynamics: ca.SX | None = None  # RNEA(q, v, a, F) of the node's plan, where a row computed it

    def __getitem__(self, name: str) -> ca.SX:
        return self.parts[name]

    def get(self, name: str):
        return self.parts.get(name)


class Formulation(ABC):
    """One way of imposing the rigid-body dynamics on the OCP nodes."""

    name: str = ""
    dynamics_as: str = "path"  # "path" | "transition"
    description: str = ""

    def __init__(self, dyn: SymbolicDynamics, n_torque_nodes: int):
        self.dyn = dyn
        self.nv = dyn.nv
        self.nj = dyn.nv - 6
        self.nf = dyn.n_forces
        self.n_torque_nodes = n_torque_nodes
        self._momentum_fn: ca.Function | None = None

    @abstractmethod
    def state_parts(self) -> list[tuple[str, int]]:
        """Named blocks of x_k (the same on every node)."""

    @abstractmethod
    def input_parts(self, k: int) -> list[tuple[str, int]]:
        """Named blocks of u_k; may differ per node (torques only on k < n_torque_nodes)."""

    @abstractmethod
    def transition(self, node: Node, dt) -> ca.SX:
        """x_{k+1} as a function of x_k, u_k and the step dt_k (same order as `state_parts`);
        `node.acceleration` is set when the formulation has one."""

    def dynamics_rows(self, node: Node) -> ca.SX:
        """Equality rows (= 0) imposing the dynamics on node k (path formulations), scaled."""
        return ca.SX(0, 1)

    def velocity(self, node: Node) -> ca.SX | None:
        """Generalized velocity of the node (None where it is an input the last node lacks)."""
        return node.get("v")

    def acceleration(self, node: Node) -> ca.SX | None:
        """Generalized acceleration of an input node (None for velocity-level formulations)."""
        return node.get("a")

    def kinematics(self, node: Node, q_ref: ca.SX, rot_ref: ca.SX) -> None:
        """Sets the node's configuration q_hat (+) dq, its motion and acceleration (built once, shared
        by the dynamics, contact, arm and cost rows)."""
        node.config = self.dyn.configuration_from_increment(rot_ref, q_ref, node["dq"])
        v = self.velocity(node)
        node.motion = Motion(node.config, v) if v is not None else None
        has_input = node.get("F") is not None  # every formulation's input carries the contact forces
        node.acceleration = self.acceleration(node) if (has_input and node.motion is not None) else None

    def torque_estimate(self, node: Node) -> ca.SX | None:
        """Joint torques to bound on k < n_torque_nodes when they are no variables: the
        quasi-static estimate tau_j = g_j(q) - J_j^T F (gravity compensation and contact Jacobian)."""
        if node.get("tau") is not None:
            return None
        zero = ca.SX.zeros(self.nv)
        return self.dyn.rnea(node.config, Motion(node.config, zero), zero, node["F"])[6:]

    def implied_torques(self, node: Node) -> ca.SX | None:
        """Joint torques the node's plan implies where they are no variables (None: the formulation
        has none to offer). Call after `dynamics_rows` (it may reuse that node's RNEA)."""
        return None

    def joint_torques(self, node: Node, a: ca.SX) -> ca.SX:
        """Joint torques to apply (eq. 10's tau_ff): the variable, or inverse dynamics of the plan."""
        if node.get("tau") is not None:
            return node["tau"]
        return self.dyn.rnea(node.config, node.motion, a, node["F"])[6:]

    def variable_scales(self) -> dict[str, np.ndarray]:
        """Typical magnitude of each input part: the NLP variable is part / scale."""
        robot = self.dyn.robot
        force = np.full(self.nf, robot.mass_kg * GRAVITY_M_S2 / max(len(robot.feet), 1))
        force[self.dyn.n_linear_forces :] *= MOMENT_ARM_SCALE_M  # flat feet's sole moments
        return {"F": force, "tau": np.asarray(robot.tau_max, dtype=float)}

    def dynamics_row_scale(self, n_rows: int) -> np.ndarray:
        """Rows of eq. (5) are divided by the weight (base rows) and the torque limits (joint rows)."""
        robot = self.dyn.robot
        return np.concatenate([np.full(6, robot.mass_kg * GRAVITY_M_S2), robot.tau_max])[:n_rows]

    def initial_state(self, q_ref: np.ndarray, v0: np.ndarray) -> np.ndarray:
        """x_0 for the measured state (the configuration is the reference q_hat, so dq_0 = 0)."""
        values = {"dq": np.zeros(self.nv), "v": v0}
        if any(name == "h" for name, _ in self.state_parts()):
            values["h"] = self.centroidal_momentum(q_ref, v0)
        return np.concatenate([values[name] for name, _ in self.state_parts()])

    def centroidal_momentum(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Numeric h_com = A(q) v with the same symbolic algorithm the constraints use."""
        if self._momentum_fn is None:
            q_sym, v_sym = ca.SX.sym("q", self.dyn.nq), ca.SX.sym("v", self.nv)
            cfg = self.dyn.configuration(q_sym)
            self._momentum_fn = ca.Function("h", [q_sym, v_sym], [self.dyn.centroidal_momentum(cfg, Motion(cfg, v_sym))])
        return np.asarray(self._momentum_fn(q, v)).ravel()

    def _euler_dq_v(self, node: Node, dt) -> ca.SX:
        """Explicit Euler on [dq, v] (eq. 4)."""
        return ca.vertcat(node["dq"] + dt * node["v"], node["v"] + dt * node.acceleration)


class WholeBodyInverse(Formulation):
    """x = [dq, v], u = [a, F, tau_j (k < 3)]; RNEA rows = [0_6; tau_j] (eq. 5)."""

    name = "wb_inverse"
    dynamics_as = "path"
    description = "whole-body inverse dynamics, RNEA as path constraint (ours)"

    def state_parts(self):
        return [("dq", self.nv), ("v", self.nv)]

    def input_parts(self, k):
        parts = [("a", self.nv), ("F", self.nf)]
        if k < self.n_torque_nodes:
            parts.append(("tau", self.nj))
        return parts

    def transition(self, node, dt):
        return self._euler_dq_v(node, dt)

    def dynamics_rows(self, node):
        tau = self.dyn.rnea(node.config, node.motion, node["a"], node["F"])
        node.inverse_dynamics = tau
        rows = tau - ca.vertcat(ca.SX.zeros(6), node["tau"]) if node.get("tau") is not None else tau[:6]
        return rows / self.dynamics_row_scale(rows.shape[0])

    def implied_torques(self, node):
        """The joint rows of the node's RNEA (eq. 5 with the contact wrenches): the torques the motors
        must give for the planned accelerations and forces, on nodes without torque variables."""
        if node.get("tau") is not None or node.get("a") is None:
            return None
        if node.inverse_dynamics is None:
            node.inverse_dynamics = self.dyn.rnea(node.config, node.motion, node["a"], node["F"])
        return node.inverse_dynamics[6:]


class WholeBodyForward(Formulation):
    """x = [dq, v], u = [tau_j, F]; a = FD(q, v, tau_j, F) (CRBA + sparse LTDL) in the transition."""

    name = "wb_forward"
    dynamics_as = "transition"
    description = "whole-body forward dynamics in the state transition"

    def state_parts(self):
        return [("dq", self.nv), ("v", self.nv)]

    def input_parts(self, k):
        return [("tau", self.nj), ("F", self.nf)]

    def acceleration(self, node):
        return self.dyn.forward_dynamics(node.config, node.motion, node["tau"], node["F"])

    def transition(self, node, dt):
        return self._euler_dq_v(node, dt)


class CentroidalVelocityPath(Formulation):
    """x = [h, dq], u = [v, F]; h_{k+1} = h_k + dt hdot(F); path rows A(q) v - h = 0."""

    name = "centroidal_vel_path"
    dynamics_as = "path"
    description = "centroidal momentum, h = A(q) v as path constraint"

    def state_parts(self):
        return [("h", 6), ("dq", self.nv)]

    def input_parts(self, k):
        return [("v", self.nv), ("F", self.nf)]

    def transition(self, node, dt):
        hdot = self.dyn.centroidal_wrench(node.config, node["F"])
        return ca.vertcat(node["h"] + dt * hdot, node["dq"] + dt * node.motion.v)

    def dynamics_rows(self, node):
        residual = self.dyn.centroidal_momentum(node.config, node.motion) - node["h"]
        return residual / self.dyn.robot.mass_kg


class CentroidalVelocity(CentroidalVelocityPath):
    """x = [h, dq], u = [v_j, F]; v_b = A_b^-1 (h - A_j v_j) inside the transition (and kinematics)."""

    name = "centroidal_vel"
    dynamics_as = "transition"
    description = "centroidal momentum, base velocity from A_b^-1 in the transition"

    def input_parts(self, k):
        return [("vj", self.nj), ("F", self.nf)]

    def velocity(self, node):
        if node.get("vj") is None:
            return None
        joints = ca.vertcat(ca.SX.zeros(6), node["vj"])
        joint_momentum = self.dyn.centroidal_momentum(node.config, Motion(node.config, joints))
        base = self.dyn.centroidal_base_inverse(node.config, node["h"] - joint_momentum)
        return ca.vertcat(base, node["vj"])

    def dynamics_rows(self, node):
        return ca.SX(0, 1)


class CentroidalAccelerationPath(Formulation):
    """x = [dq, v], u = [a, F]; path rows hdot(F) - (Adot v + A a) = 0."""

    name = "centroidal_acc_path"
    dynamics_as = "path"
    description = "centroidal momentum rate, hdot = Adot v + A a as path constraint"

    def state_parts(self):
        return [("dq", self.nv), ("v", self.nv)]

    def input_parts(self, k):
        return [("a", self.nv), ("F", self.nf)]

    def transition(self, node, dt):
        return self._euler_dq_v(node, dt)

    def dynamics_rows(self, node):
        hdot = self.dyn.centroidal_wrench(node.config, node["F"])
        residual = hdot - self.dyn.centroidal_momentum_rate(node.config, node.motion, node["a"])
        return residual / (self.dyn.robot.mass_kg * GRAVITY_M_S2)


class CentroidalAcceleration(CentroidalAccelerationPath):
    """x = [dq, v], u = [a_j, F]; a_b = A_b^-1 (hdot(F) - Adot v - A_j a_j) inside the transition."""

    name = "centroidal_acc"
    dynamics_as = "transition"
    description = "centroidal momentum rate, base acceleration from A_b^-1 in the transition"

    def input_parts(self, k):
        return [("aj", self.nj), ("F", self.nf)]

    def acceleration(self, node):
        joints = ca.vertcat(ca.SX.zeros(6), node["aj"])
        bias = self.dyn.centroidal_momentum_rate(node.config, node.motion, joints)  # Adot v + A_j a_j
        hdot = self.dyn.centroidal_wrench(node.config, node["F"])
        return ca.vertcat(self.dyn.centroidal_base_inverse(node.config, hdot - bias), node["aj"])

    def dynamics_rows(self, node):
        return ca.SX(0, 1)


FORMULATIONS: dict[str, type[Formulation]] = {
    cls.name: cls
    for cls in (WholeBodyInverse, WholeBodyForward, CentroidalVelocityPath, CentroidalVelocity,
                CentroidalAccelerationPath, CentroidalAcceleration)
}


def make_formulation(name: str, dyn: SymbolicDynamics, n_torque_nodes: int) -> Formulation:
    if name not in FORMULATIONS:
        raise ConfigError(unknown_name("formulation", name, FORMULATIONS))
    return FORMULATIONS[name](dyn, n_torque_nodes)
