"""The parts of a step's bounds (`OcpProblem.bounds`) that do not depend on the measurement, laid out once.

Every MPC step needs lbx, ubx, lbg, ubg. Most entries never change (joint velocity and torque limits, slack signs,
the torque rows' +-1, the cones' upper bounds) and most of the rest depend only on which feet are in stance at
which node: forces free or zero (eq. 6), a swing foot's horizontal velocity rows free, the friction and wrench
cones active or free. `BoundsTemplate` keeps the constant entries in one array and the contact-dependent ones as
a table (entry, contact flag, value in stance, value in swing), so a step starts from one copy and one gather
instead of some fifty NumPy assignments; `OcpProblem.bounds` then writes what depends on the measurement.
"""

from __future__ import annotations

import numpy as np

INF = np.inf


class BoundsTemplate:
    """lbx, ubx, lbg, ubg of a problem before the measurement's entries: `start(contact, soft)`."""

    def __init__(self, problem):
        robot, N, nf = problem.robot, problem.N, problem.n_feet
        idx, rows = problem.idx, problem.rows
        n_x, n_g = problem.n_variables, problem.n_constraints
        # one buffer [lbx | ubx | lbg | ubg]: a step copies it once
        self._sizes = (n_x, n_g)
        buffer = np.concatenate([np.full(n_x, -INF), np.full(n_x, INF), np.zeros(2 * n_g)])
        lbx, ubx, lbg, ubg = self._views(buffer)
        for name, columns in (("v", slice(6, None)), ("vj", slice(None))):  # joint velocities, eq. (8)
            if name in idx:
                joint_v = idx[name][1:, columns] if name in problem.state_names else idx[name][:, columns]
                lbx[joint_v] = -robot.v_max
                ubx[joint_v] = robot.v_max
        lbx[problem.slack_index] = 0.0
        ubx[problem.slack_index] = 0.0  # the hard OCP; soft steps free them (`start`)
        if "tau" in idx and not rows["torque_limit"].size:
            lbx[idx["tau"][: problem.config.n_torque_nodes]] = -robot.tau_max
            ubx[idx["tau"][: problem.config.n_torque_nodes]] = robot.tau_max
        for tag in ("torque_limit", "torque", "implied_torque"):  # (soft) torque limit rows, estimated / implied
            if rows[tag].size:
                lbg[rows[tag]] = -1.0
                ubg[rows[tag]] = 1.0
        table = []  # (entry of the buffer, contact flag (node * n_feet + foot), value in stance, value in swing)
        node_foot = np.arange((N + 1) * nf).reshape(N + 1, nf)
        if "F" in idx:  # eq. (6) forces: stance F_z >= 0, swing F = 0
            feet_f = idx["F"][:, : 3 * nf].reshape(N, nf, 3)
            lbx[feet_f[..., 2]] = 0.0
            flags = np.broadcast_to(node_foot[:N, :, None], feet_f.shape)
            table.append((n_x + feet_f, flags, INF, 0.0))
            table.append((feet_f[..., :2], flags[..., :2], -INF, 0.0))
            for i in problem.surface_feet:  # a flat foot's moments: free in stance (wrench cone rows), zero in swing
                moments = idx["F"][:, problem.dyn.moment_slice(i)]
                flags = np.broadcast_to(node_foot[:N, i : i + 1], moments.shape)
                table += [(moments, flags, -INF, 0.0), (n_x + moments, flags, INF, 0.0)]
        row_nodes = problem.row_nodes
        lbg_at, ubg_at = 2 * n_x, 2 * n_x + n_g
        foot_rows = rows["foot_vel"].reshape(len(row_nodes["foot_vel"]), nf, 3)  # swing v_xy free, eq. (6)
        flags = np.broadcast_to(node_foot[row_nodes["foot_vel"]][..., None], foot_rows[..., :2].shape)
        table += [(lbg_at + foot_rows[..., :2], flags, 0.0, -INF), (ubg_at + foot_rows[..., :2], flags, 0.0, INF)]
        if problem.surface_feet:  # flat feet: the sole's yaw rate free in swing
            ang_rows = rows["foot_ang"].reshape(len(row_nodes["foot_ang"]), len(problem.surface_feet), 3)
            flags = node_foot[row_nodes["foot_ang"]][:, problem.surface_feet]
            table += [(lbg_at + ang_rows[..., 2], flags, 0.0, -INF), (ubg_at + ang_rows[..., 2], flags, 0.0, INF)]
        if rows["cone"].size:  # friction cones: active in stance, free in swing
            ubg[rows["cone"]] = INF
            table.append((lbg_at + rows["cone"], np.broadcast_to(node_foot[:N][:, problem.point_feet], rows["cone"].shape),
                          0.0, -INF))
        if rows["wrench_cone"].size:
            wrench_rows = rows["wrench_cone"].reshape(N, len(problem.surface_feet), -1)
            ubg[wrench_rows] = INF
            flags = np.broadcast_to(node_foot[:N][:, problem.surface_feet, None], wrench_rows.shape)
            table.append((lbg_at + wrench_rows, flags, 0.0, -INF))
        self._buffer = buffer
        self._entries = np.concatenate([np.ravel(t[0]) for t in table]) if table else np.zeros(0, dtype=int)
        self._flags = np.concatenate([np.ravel(t[1]) for t in table]) if table else np.zeros(0, dtype=int)
        self._stance_values = np.concatenate([np.full(np.size(t[0]), t[2]) for t in table]) if table else np.zeros(0)
        self._swing_values = np.concatenate([np.full(np.size(t[0]), t[3]) for t in table]) if table else np.zeros(0)
        self._slack_entries = n_x + problem.slack_index
        self._x_scale = np.concatenate([problem.x_scale, problem.x_scale])

    def _views(self, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n_x, n_g = self._sizes
        return buffer[:n_x], buffer[n_x : 2 * n_x], buffer[2 * n_x : 2 * n_x + n_g], buffer[2 * n_x + n_g :]

    def start(self, contact: np.ndarray, soft: bool) -> tuple[np.ndarray, ...]:
        """A fresh buffer and its lbx, ubx, lbg, ubg views (physical units: `finish` scales x) for the contact
        flags (N+1, n_feet; bool) and the soft rows' slacks (free with `soft`, pinned to zero without)."""
        buffer = self._buffer.copy()
        buffer[self._entries] = np.where(contact.ravel()[self._flags], self._stance_values, self._swing_values)
        if soft:
            buffer[self._slack_entries] = INF
        return (buffer, *self._views(buffer))

    def finish(self, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lbx, ubx in the NLP's scaled variables (`OcpProblem.x_scale`), lbg, ubg."""
        n_x = self._sizes[0]
        buffer[: 2 * n_x] /= self._x_scale
        return self._views(buffer)
