"""The parts of a step's bounds (`OcpProblem.bounds`) that do not depend on the measurement, laid out once.

Every MPC step needs lbx, ubx, lbg, ubg. Most entries never change (joint velocity and torque limits, slack signs,
the torque rows' +-1, the cones' upper bounds) and most of the rest depend only on which feet are in stance at
which node: forces free or zero (eq. 6), a swing foot's horizontal velocity rows free, the friction and wrench
cones active or free. `BoundsTemplate` keeps the constant entries in one array and the contact-dependent ones as
a table (entry, contact flag, value in stance, value in swing), so a step starts from one copy and one gather
instead of some fifty NumPy assignments; `OcpProblem.bounds` then writes what depends on the measurement. With the
compiled step packer (`solvers/step_pack.py`, `OcpProblem.bounds_packer`) `start` is one C call.
"""

from __future__ import annotations

import ctypes

import numpy as np

INF = np.inf
_ZERO3 = np.zeros(3)


class BoundsTemplate:
    """lbx, ubx, lbg, ubg of a problem before the measurement's entries: `start(contact, soft)`."""

    def __init__(self, problem, packer=None, early_nodes: int = 0, blend_time_s: float = 1.0,
                 yaw_band_rad_s: float = 0.0):
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
        self.packer, self.last_address = packer, None
        if packer is not None:  # the C call's arguments but the contact flags, the soft flag and the output
            tables = (self._entries, self._flags, self._slack_entries)
            self._tables = tuple(np.ascontiguousarray(t, dtype=np.int64) for t in tables) + \
                (np.ascontiguousarray(self._stance_values), np.ascontiguousarray(self._swing_values))
            entries, flags, slack, stance, swing = (a.ctypes.data for a in self._tables)
            self._call_head = (self._buffer.ctypes.data, self._buffer.size, entries, flags, stance, swing,
                               self._entries.size)
            self._call_slack = (slack, self._slack_entries.size)
            self._flags_needed = int(self._flags.max(initial=-1)) + 1  # contact flags the table reads
        # `OcpProblem.bounds`' measured entries in C too, where the problem's rows allow (early_nodes, blend_time_s:
        # its EARLY_NODES and BLEND_TIME_S)
        measured = CompiledMeasuredBounds(problem, packer, early_nodes, blend_time_s, yaw_band_rad_s) \
            if packer is not None else None
        self.measured = measured if measured is not None and measured.supported else None

    def _views(self, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n_x, n_g = self._sizes
        return buffer[:n_x], buffer[n_x : 2 * n_x], buffer[2 * n_x : 2 * n_x + n_g], buffer[2 * n_x + n_g :]

    def start(self, contact: np.ndarray, soft: bool) -> tuple[np.ndarray, ...]:
        """A fresh buffer and its lbx, ubx, lbg, ubg views (physical units: `finish` scales x) for the contact
        flags (N+1, n_feet; bool) and the soft rows' slacks (free with `soft`, pinned to zero without)."""
        if self.packer is not None and contact.dtype == np.bool_ and contact.flags.c_contiguous and \
                contact.size >= self._flags_needed:
            buffer = np.empty(self._buffer.size)
            self.last_address = buffer.ctypes.data  # (for `measured.write`)
            self.packer.wbsp_bounds_start(*self._call_head, contact.ctypes.data, *self._call_slack, int(bool(soft)),
                                          self.last_address)
            return (buffer, *self._views(buffer))
        self.last_address = None  # (NumPy's buffer: `measured` does not write it)
        buffer = self._buffer.copy()
        buffer[self._entries] = np.where(contact.ravel()[self._flags], self._stance_values, self._swing_values)
        if soft:
            buffer[self._slack_entries] = INF
        return (buffer, *self._views(buffer))

    def c_arguments(self) -> tuple:
        """`start`'s C call for `csrc/step_prepare.c`: the template's address, its entries', contact flags' and
        slacks' tables, the stance and swing values and the table's size."""
        buffer, _, entries, flags, stance, swing, n_entries = self._call_head
        return buffer, entries, flags, self._call_slack[0], stance, swing, n_entries

    def views(self, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lbx, ubx, lbg, ubg of a buffer that `measured` finished."""
        return self._views(buffer)

    def finish(self, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lbx, ubx in the NLP's scaled variables (`OcpProblem.x_scale`), lbg, ubg."""
        n_x = self._sizes[0]
        buffer[: 2 * n_x] /= self._x_scale
        return self._views(buffer)


class CompiledMeasuredBounds:
    """`OcpProblem.bounds`' measured entries in one call of the compiled step packer (`csrc/step_pack.c`
    `wbsp_bounds_measured`): the joint limits about the measurement, x_0's rows, the feet's and the end effector's
    velocity rows, the relaxed rows, x's scaling. The tables are the index selections `OcpProblem.bounds` makes,
    taken once; `write` returns False (the caller then runs its NumPy code) for what it does not cover: an object or
    collision model, other row tags relaxed, data of other shapes."""

    def __init__(self, problem, packer, early_nodes: int, blend_time_s: float, yaw_band_rad_s: float):
        idx, rows, robot, N = problem.idx, problem.rows, problem.robot, problem.N
        self.supported = problem.object is None and problem.collision is None and "dq" in idx
        if not self.supported:
            return
        self._problem, self._packer, nj = problem, packer, idx["dq"].shape[1] - 6
        early = slice(0, min(early_nodes, N))
        joint_dq = idx["dq"][1:, 6:]
        times = problem.config.grid.node_times_s
        coasting = "v" in problem.state_names
        overspeed, v0_rows = [], []
        for name, columns in (("v", slice(6, None)), ("vj", slice(None))):
            if name in idx:
                joint_v = idx[name][1:, columns] if name in problem.state_names else idx[name][:, columns]
                overspeed.append(joint_v[early])
                if name not in problem.state_names:
                    v0_rows.append(idx[name][0, columns][None])
        arm = idx["F"][:, 3 * problem.n_feet : 3 * problem.n_feet + 3] if "F" in idx and problem.has_arm else \
            np.zeros((0, 3), dtype=int)
        foot_nodes = problem.row_nodes["foot_vel"]
        ee_rows = rows["ee_vel"] if problem.has_arm else np.zeros((0, 3), dtype=int)

        def decay(nodes):  # `OcpProblem._blend_from_measurement`'s
            return np.minimum(np.maximum(1.0 - times[nodes] / blend_time_s, 0.0), 1.0)

        surface = np.asarray(problem.surface_feet, dtype=int)  # flat feet: their soles' angular velocity rows
        ang_nodes = problem.row_nodes["foot_ang"] if surface.size else np.zeros(0, dtype=int)
        tables = [joint_dq, joint_dq[early] if coasting else joint_dq[:0],
                  np.concatenate(overspeed) if overspeed else np.zeros((0, nj), dtype=int),
                  np.concatenate(v0_rows) if v0_rows else np.zeros((0, nj), dtype=int), arm, rows["x0"][0],
                  rows["foot_vel"], foot_nodes, ee_rows, rows["foot_ang"] if surface.size else ang_nodes, ang_nodes,
                  surface]
        if any(np.shape(table)[-1] != nj for table in tables[:4]) or robot.q_min.size != nj:
            self.supported = False
            return
        self._tables = [np.ascontiguousarray(np.ravel(table), dtype=np.int64) for table in tables]
        self._constants = [np.ascontiguousarray(value, dtype=float) for value in (
            robot.q_min, robot.q_max, times[1:][early], robot.v_max,
            decay(foot_nodes) if foot_nodes.size else np.zeros(1),
            decay(problem.row_nodes["ee_vel"]) if ee_rows.size else np.zeros(1),
            np.concatenate([problem.x_scale, problem.x_scale]), decay(ang_nodes) if ang_nodes.size else np.zeros(1),
            [yaw_band_rad_s])]
        meta = [problem.n_variables, problem.n_constraints, nj, len(joint_dq), len(tables[1]), len(tables[2]),
                len(tables[3]), len(arm), rows["x0"][0].size, len(foot_nodes), problem.n_feet, len(ee_rows),
                len(ang_nodes), surface.size]
        self._meta = np.array(meta, dtype=np.int64)
        self._table_pointers = (ctypes.c_void_p * len(tables))(*[t.ctypes.data for t in self._tables])
        self._constant_pointers = (ctypes.c_void_p * len(self._constants))(*[c.ctypes.data for c in self._constants])
        # the step's inputs are copied into one kept array (their addresses taken once, not per step: ~1.6 us each)
        nf = problem.n_feet
        self._shapes = ((nj,), (nj,), (3,), (rows["x0"][0].size,), (N + 1, nf), (N + 1, nf, 2), (nf, 3), (3,), (3,),
                        (N + 1, nf), (nf, 3))
        self._offsets = np.concatenate([[0], np.cumsum([np.prod(shape) for shape in self._shapes])]).tolist()
        self._inputs = np.zeros(self._offsets[-1])
        self._input_addresses = [self._inputs.ctypes.data + 8 * offset for offset in self._offsets[:-1]]
        self._input_views = [self._inputs[start:stop].reshape(shape) for start, stop, shape in
                             zip(self._offsets[:-1], self._offsets[1:], self._shapes)]
        self._step_pointers = (ctypes.c_void_p * len(self._shapes))(*self._input_addresses)
        self._soles, self._staged = bool(surface.size), None
        self._contact = np.zeros((N + 1, nf), dtype=bool)
        self._call_head = (self._meta.ctypes.data, self._table_pointers, self._constant_pointers, self._step_pointers,
                           self._contact.ctypes.data)

    def c_arguments(self) -> dict:
        """`write`'s C call for `csrc/step_prepare.c` (after `stage_inputs`): its contact flags' address and its
        tables, constants and step inputs (ctypes pointer arrays: their addresses)."""
        meta, tables, constants, inputs, contact = self._call_head
        return {"contact": contact, "call": (meta, *(ctypes.addressof(a) for a in (tables, constants, inputs)))}

    def stage_inputs(self, swing_vxy, ee_velocity, swing_yaw_rates, arm: bool, soles: bool) -> None:
        """The step inputs from Python's side (the swing references, the end effector's target: each an array of its
        shape or None) for the C call; the others (joint positions and velocities, arm force, x_0, swing v_z, the
        measured frame velocities, where the robot has them) are the C code's."""
        views, addresses = self._input_views, self._input_addresses
        values = ((5, swing_vxy), (7, ee_velocity if ee_velocity is not None else _ZERO3), (9, swing_yaw_rates))
        staged = (swing_vxy is None, swing_yaw_rates is None, arm, soles)
        if staged != self._staged:  # (the pointers change only with these: set then)
            pointers = self._step_pointers
            for k in (0, 1, 2, 3, 4, 6):
                pointers[k] = addresses[k]
            pointers[8], pointers[10] = addresses[8] if arm else None, addresses[10] if soles else None
            for k, value in values:
                pointers[k] = None if value is None else addresses[k]
            self._staged = staged
        for k, value in values:
            if value is not None:
                views[k][...] = value

    def write(self, address: int | None, data, contact: np.ndarray) -> bool:
        """The measured entries of `data` (a `StageBounds`) into the buffer [lbx | ubx | lbg | ubg] at `address` after
        `BoundsTemplate.start`, lbx and ubx scaled; False (buffer untouched) where the NumPy code must run."""
        problem = self._problem
        relaxed = data.relaxed_rows
        if address is None or any(tag not in ("ee_vel", "foot_vel") for tag in relaxed) or \
                contact.shape != self._contact.shape or data.object_state is not None:
            return False
        values = (problem.robot.joint_positions(data.q_ref), data.v0[6:],
                  data.ee_force_on_robot_n if data.ee_force_on_robot_n is not None else _ZERO3,
                  problem.initial_state(data.q_ref, data.v0, None), data.swing_vz_m_s, data.swing_vxy_m_s,
                  data.foot_velocity_m_s, data.ee_velocity_m_s if data.ee_velocity_m_s is not None else _ZERO3,
                  data.ee_velocity_measured_m_s)
        if self._soles:  # (point feet: the C code reads neither)
            values += (data.swing_yaw_rate_rad_s, data.foot_angular_velocity_rad_s)
        pointers, views = self._step_pointers, self._input_views
        self._staged = None  # (the pointers change below: `stage_inputs` sets its own again)
        for k, value in enumerate(values):
            if value is None:
                pointers[k] = None
                continue
            if (value.shape if type(value) is np.ndarray else np.shape(value)) != self._shapes[k]:
                return False
            views[k][...] = value
            pointers[k] = self._input_addresses[k]
        self._contact[...] = contact
        self._packer.wbsp_bounds_measured(address, *self._call_head, int("ee_vel" in relaxed),
                                          int("foot_vel" in relaxed))
        return True
