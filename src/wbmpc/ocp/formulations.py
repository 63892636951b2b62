"""Dynamics formulations: what a stage's state and input are and how the dynamics are imposed.

Every formulation shares the OCP machinery (gait, contact, arm, limits, cost); it only defines
its state/input parts, the state transition and the dynamics path rows. `wb_inverse` is the
paper's (section IV-B1): x = [dq, v], u = [a, F, tau (k < 3)], explicit Euler (eq. 4) and RNEA
as path constraint (eq. 5).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError, unknown_name
from wbmpc.robots import GRAVITY_M_S2
from wbmpc.symbolic import Configuration, Motion, SymbolicDynamics


@dataclass
class Node:
    """Symbols of one stage k: named state and input parts, plus derived kinematics."""

    k: int
    parts: dict[str, ca.SX]
    config: Configuration | None = None
    motion: Motion | None = None

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

    @abstractmethod
    def state_parts(self) -> list[tuple[str, int]]:
        """Named blocks of x_k (the same on every node)."""

    @abstractmethod
    def input_parts(self, k: int) -> list[tuple[str, int]]:
        """Named blocks of u_k; may differ per node (torques only on k < n_torque_nodes)."""

    @abstractmethod
    def transition(self, node: Node, dt) -> ca.SX:
        """x_{k+1} as a function of x_k, u_k and the step dt_k."""

    def dynamics_rows(self, node: Node) -> ca.SX:
        """Equality rows (= 0) imposing the dynamics on node k (path formulations)."""
        return ca.SX(0, 1)

    @abstractmethod
    def kinematics(self, node: Node, q_ref: ca.SX, rot_ref: ca.SX) -> tuple[Configuration, Motion]:
        """Configuration and generalized velocity of the node (for contact and arm constraints)."""

    def variable_scales(self) -> dict[str, np.ndarray]:
        """Typical magnitude of each part: the NLP variable is part / scale (better conditioning)."""
        robot = self.dyn.robot
        force = np.full(self.nf, robot.mass_kg * GRAVITY_M_S2 / max(len(robot.feet), 1))
        return {"F": force, "tau": np.asarray(robot.tau_max, dtype=float)}

    def dynamics_row_scale(self, n_rows: int) -> np.ndarray:
        """Rows of eq. (5) are divided by the weight (base rows) and the torque limits (joint rows)."""
        robot = self.dyn.robot
        return np.concatenate([np.full(6, robot.mass_kg * GRAVITY_M_S2), robot.tau_max])[:n_rows]

    @abstractmethod
    def initial_state(self, v0: np.ndarray) -> np.ndarray:
        """x_0 for the measured generalized velocity (the configuration is the reference q_hat)."""


class WholeBodyInverse(Formulation):
    """x = [dq, v], u = [a, F, tau_j (k < 3)]; RNEA rows = [0_6; tau_j] (eq. 5)."""

    name = "wb_inverse"
    dynamics_as = "path"
    description = "whole-body inverse dynamics, RNEA as path constraint"

    def state_parts(self):
        return [("dq", self.nv), ("v", self.nv)]

    def input_parts(self, k):
        parts = [("a", self.nv), ("F", self.nf)]
        if k < self.n_torque_nodes:
            parts.append(("tau", self.nj))
        return parts

    def transition(self, node, dt):
        return ca.vertcat(node["dq"] + dt * node["v"], node["v"] + dt * node["a"])

    def initial_state(self, v0):
        return np.concatenate([np.zeros(self.nv), v0])

    def kinematics(self, node, q_ref, rot_ref):
        cfg = self.dyn.configuration_from_increment(rot_ref, q_ref, node["dq"])
        return cfg, Motion(cfg, node["v"])

    def dynamics_rows(self, node):
        tau = self.dyn.rnea(node.config, node.motion, node["a"], node["F"])
        rows = tau - ca.vertcat(ca.SX.zeros(6), node["tau"]) if node.get("tau") is not None else tau[:6]
        return rows / self.dynamics_row_scale(rows.shape[0])


FORMULATIONS: dict[str, type[Formulation]] = {WholeBodyInverse.name: WholeBodyInverse}


def make_formulation(name: str, dyn: SymbolicDynamics, n_torque_nodes: int) -> Formulation:
    if name not in FORMULATIONS:
        raise ConfigError(unknown_name("formulation", name, FORMULATIONS))
    return FORMULATIONS[name](dyn, n_torque_nodes)
