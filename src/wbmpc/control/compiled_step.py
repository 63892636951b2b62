"""An MPC step's data preparation and its plan's unpacking, each in one C call (`csrc/step_prepare.c`).

`MPC._step_data` in NumPy runs some fifty small steps between the measurement and the solver (the base targets and
q (-) q_k, the schedule, the force guess, p, the bounds, the shifted warm start) and `MPC._unpack` a dozen after it;
right after the solver the interpreter's caches are cold and each costs 2-4 us. `CompiledStep.prepare` keeps in Python
what needs Python objects (the input checks, the anchor's few scalars, push mode, the gait clock's retiming, the
stance references, the feet's placements from pinocchio) and runs the rest in one call, into one fresh buffer
[p | lbx | ubx | lbg | ubg | x | contact | forces] per step (the solution, the recovery and the dual warm start keep
them): with the swing feet's placement references (`csrc/step_feet.c`), and flat feet's wrench warm start in a second
call after it. `unpack` is the plan's compiled function and the finiteness check in one call. The results are the NumPy
path's bit for bit (tests/control/test_compiled_step.py); the NumPy path stays the reference and runs where the
step needs what the C code does not cover (`covers`: terrains, sway, touchdown events, objects, collisions).
"""

from __future__ import annotations

import ctypes
import math

import numpy as np
import pinocchio as pin

from wbmpc.control.foot_placement import heading_of
from wbmpc.control.measured import split_velocities
from wbmpc.control.references import MAX_ANCHOR_OFFSET_M
from wbmpc.gait import SwingProfile
from wbmpc.ocp.problem import StageBounds

_P, _I, _D = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
_FIELDS = [(name, _I) for name in ("nq", "nv", "nodes", "n_feet", "n_force", "arm", "n_x", "n_g", "n_p", "n_state0",
                                     "n_slack", "n_anchors", "n_stand", "n_x0", "soles")] + \
    [(name, _P) for name in ("scalars", "q", "v", "rot", "v_des", "offsets", "node_times", "q_nominal",
                             "phase_offsets", "anchors", "stand", "difference", "plan", "velocities", "arg", "res", "iw",
                             "w", "targets", "dq_des", "progress", "swing_vz", "x0_state", "velocities_out",
                             "contact_flags", "p_template")] + \
    [(name, _I) for name in ("p_q", "p_rot", "p_dq", "p_v", "p_force")] + \
    [(name, _P) for name in ("bounds_template", "bounds_entries", "bounds_flags", "slack_entries", "bounds_stance",
                             "bounds_swing")] + [("n_bounds_entries", _I)] + \
    [(name, _P) for name in ("measured_meta", "measured_tables", "measured_constants", "measured_inputs")] + \
    [("shift_groups", _I), ("shift_vars", _I)] + \
    [(name, _P) for name in ("shift_lengths", "shift_group_node", "shift_by_column", "shift_column_start",
                             "shift_target", "shift_pos", "shift_weight", "shift_times", "old_x", "previous_x",
                             "previous_q", "previous_times", "x_scale", "idx_dq", "state0", "x0_entries",
                             "idx_force", "slack_index", "swing_inputs", "swing_constants", "swing_feet",
                             "swing_start", "swing_vxy", "swing_yaw")]
# the step's scalars (csrc/step_prepare.c's K_*)
(K_T, K_ANCHOR_X, K_ANCHOR_Y, K_VWORLD_X, K_VWORLD_Y, K_HEIGHT, K_SUPPORT, K_FORCE_X, K_FORCE_Y, K_FORCE_Z, K_SOFT,
 K_PIN_SLACK, K_WARM, K_PREVIOUS_T, K_RELAX_EE, K_RELAX_FOOT, K_DUTY, K_PIECE_S, K_APEX, K_LIFTOFF_T, K_TOUCHDOWN_T,
 K_ANCHOR_YAW, K_YAW_RATE, K_COUNT) = range(24)


class _Step(ctypes.Structure):
    _fields_ = _FIELDS


class CompiledStep:
    """The compiled data preparation (`prepare`) and unpacking (`unpack`) of one MPC's steps (the MPC's collaborator:
    it reads the MPC's parts); `supported` False where its problem needs the NumPy path on every step."""

    def __init__(self, mpc, packer, functions_library: str | None):
        problem, robot = mpc.problem, mpc.robot
        template = problem.bounds_template()
        shift_call = mpc._shift.compiled_call
        self.supported = bool(
            packer is not None and functions_library is not None and template.measured is not None
            and shift_call is not None and mpc._measured_velocities.function is not None
            and problem.state_names == ["dq", "v"] and problem.object is None
            and problem.collision is None and mpc._joints_are_coordinates and "F" in problem.idx
            and type(mpc.config.swing) is SwingProfile
            and all(tag in ("ee_vel", "foot_vel") for tag in mpc.config.push.relaxed_rows)
            and all(name in problem.params.names for name in ("q_ref", "rot_ref", "dq_des", "v_des", "F_des")))
        if not self.supported:
            return
        self._mpc, self._packer, self._measured = mpc, packer, template.measured
        N, nodes, n_feet = problem.N, problem.N + 1, len(robot.feet)
        sizes = (problem.params.size, 2 * (problem.n_variables + problem.n_constraints), problem.n_variables,
                 nodes * n_feet, N * problem.nf)
        self._offsets = np.cumsum((0,) + sizes).tolist()
        self._keep = []  # every array the C code reads or writes (kept alive with their addresses)
        self._scalars, self._q, self._v, self._v_des = (self._buffer(n) for n in (K_COUNT, robot.nq, robot.nv, robot.nv))
        self._rot = self._buffer(9).reshape((3, 3), order="F")  # (column-major: p's rot_ref)
        self._stance_offsets = self._buffer(nodes * (robot.nq - 7)).reshape(nodes, -1)
        self._previous_x, self._x = self._buffer(problem.n_variables), self._buffer(problem.n_variables)
        self._previous_q = self._buffer(nodes * robot.nq).reshape(nodes, -1)
        self._previous_times, self._swing_vz = self._buffer(nodes), self._buffer(nodes * n_feet).reshape(nodes, -1)
        self._plan_out = self._buffer(sum(rows * cols for rows, cols in mpc._plan_shapes))
        self._velocities = self._buffer(mpc._measured_velocities.function.outputs[0].size)
        self._node_times = np.array(problem.config.grid.node_times_s, dtype=float)  # this step's (`MPC.node_times`)
        self._step = self._structure(mpc, ctypes.CDLL(functions_library), template, shift_call)
        self._sole_call = self._sole_table(mpc) if problem.surface_feet else None
        self._gait_state, self._p_template, self._p = (None, None), None, None
        # the plan made of the last `unpack` (`MPC._unpack` sets it): the next step reads its x and q from there
        self.last_solution, self._reading_own = None, False
        self._address = ctypes.addressof(self._step)
        n_tau = int(np.prod(mpc._plan_shapes[-1]))
        self._unpack_call = (self._address, self._x.ctypes.data, self._plan_out.ctypes.data, self._plan_out.size - n_tau,
                             n_tau)

    def _buffer(self, size: int, dtype=float) -> np.ndarray:
        values = np.zeros(max(int(size), 1), dtype=dtype)
        self._keep.append(values)
        return values

    def _array(self, values, dtype=float) -> int:
        values = np.ascontiguousarray(np.ravel(values), dtype=dtype)
        self._keep.append(values)
        return values.ctypes.data

    def _structure(self, mpc, functions: ctypes.CDLL, template, shift_call) -> _Step:
        """The C side's view of the problem: sizes, tables, the step's buffers, the generated functions."""
        problem, robot = mpc.problem, mpc.robot
        nodes, n_feet = problem.N + 1, len(robot.feet)
        names = (mpc._difference.function.name(), mpc._plan.function.name(),
                 mpc._measured_velocities.function.function.name())
        work = [_work(functions, name) for name in names]
        n_arg, n_res, n_iw, n_w = (max(sizes[i] for sizes in work) for i in range(4))
        measured = self._measured.c_arguments()
        blocks = [problem.params.block(name).start for name in ("q_ref", "rot_ref", "dq_des", "v_des", "F_des")]
        groups, lengths, _, _, _, _, n_vars, group_node, by_column, column_start, target, _, _, _, pos, weight = \
            shift_call
        state0, x0_entries = mpc._measured_entries
        address = self._array
        self._shift_times = self._buffer(2 * nodes)  # [new | old node times] of the warm start (the wrenches' too)
        scratch = [self._buffer(size, dtype).ctypes.data for size, dtype in (
            (n_arg, np.int64), (n_res, np.int64), (n_iw, np.int64), (n_w, float), (nodes * robot.nq, float),
            (nodes * robot.nv, float))]
        return _Step(
            robot.nq, robot.nv, nodes, n_feet, problem.nf, int(bool(robot.arm_ee)), problem.n_variables,
            problem.n_constraints, problem.params.size, state0.size, problem.slack_index.size, 1, 0, 2 * robot.nv,
            int(bool(robot.soles)),
            *(a.ctypes.data for a in (self._scalars, self._q, self._v, self._rot, self._v_des)), None,
            self._node_times.ctypes.data, address(robot.q_nominal), address(mpc.gait.phase_offsets), None,
            None, *(ctypes.cast(functions[name], _P) for name in names), *scratch,
            self._buffer(nodes * n_feet).ctypes.data, self._swing_vz.ctypes.data, self._buffer(2 * robot.nv).ctypes.data,
            self._velocities.ctypes.data,
            measured["contact"], None, *blocks, *template.c_arguments(), *measured["call"], groups, n_vars, lengths,
            group_node, by_column, column_start, target, pos, weight, self._shift_times.ctypes.data,
            self._buffer(problem.n_variables).ctypes.data,
            *(a.ctypes.data for a in (self._previous_x, self._previous_q, self._previous_times)),
            address(problem.x_scale), address(problem.idx["dq"], np.int64), address(state0, np.int64),
            address(x0_entries, np.int64), address(problem.idx["F"], np.int64), address(problem.slack_index, np.int64),
            *self._swing_fields(mpc))

    def _swing_fields(self, mpc) -> tuple:
        """The struct's swing placement (`References.swing_references` in C: `wbsp_swing_references`): its inputs,
        constants, the measured soles, scratch and outputs; all None where Python's runs (no placement, or a grid
        whose node 0 is not the step's time: the C code reads the swings' progress now from node 0)."""
        placement, robot, nodes = mpc.references.swing_placement, mpc.robot, len(self._node_times)
        self._swing = None
        if placement is None or self._node_times[0] != 0.0:
            return (None,) * 6
        n_feet = len(robot.feet)
        inputs, feet = self._buffer(11), self._buffer(4 * n_feet)  # (csrc/step_feet.c's S_*; positions, headings)
        vxy, yaw = self._buffer(2 * nodes * n_feet).reshape(nodes, n_feet, 2), self._buffer(nodes * n_feet)
        self._swing = (inputs, feet, vxy, yaw.reshape(nodes, n_feet) if robot.soles else None)
        return (inputs.ctypes.data, self._array(placement.c_constants()), feet.ctypes.data,
                self._buffer(3 * n_feet).ctypes.data, vxy.ctypes.data, yaw.ctypes.data if robot.soles else None)

    @property
    def feet_in_c(self) -> tuple[bool, bool]:
        """Whether the swing references (`References.swing_references`) and flat feet's wrench warm start
        (`MPC._shifted_sole_wrenches`) of covered steps run in C (`csrc/step_feet.c`) rather than in Python."""
        return self._swing is not None, self._sole_call is not None

    def _sole_table(self, mpc) -> tuple:
        """`wbsp_sole_wrenches`' fixed arguments (after the times, before the last plan's): flat feet's columns of F
        (`MPC._sole_columns`), the torque nodes, the guess's force entries and scale."""
        problem, nodes = mpc.problem, len(self._node_times)
        feet = sorted(mpc._sole_columns)
        columns = [np.asarray(mpc._sole_columns[foot], dtype=np.int64) for foot in feet]
        starts = np.cumsum([0] + [len(c) for c in columns])
        times = self._shift_times.ctypes.data
        head = (nodes - 1, times, nodes - 1, times + 8 * nodes, len(problem.idx.get("tau", ())), len(mpc.robot.feet))
        tail = (problem.nf, len(feet), self._array(feet, np.int64), self._array(starts, np.int64),
                self._array(np.concatenate(columns), np.int64), self._array(problem.idx["F"], np.int64),
                self._array(problem.x_scale))
        return head, tail

    def _sole_wrenches(self, previous, contact: np.ndarray, x: np.ndarray) -> bool:
        """Flat feet's wrenches of the last plan by contact pattern into the guess x (`MPC._shifted_sole_wrenches`)
        in one C call after `wbsp_prepare` (its warm start's node times); False where the last plan's shapes differ."""
        head, tail = self._sole_call
        forces, before = previous.forces, previous.contact
        if forces.shape != (head[0], tail[0]) or np.shape(before) != contact.shape:
            return False
        forces = np.ascontiguousarray(forces, dtype=float)
        before = np.ascontiguousarray(before, dtype=float)
        self._packer.wbsp_sole_wrenches(*head, contact.ctypes.data, before.ctypes.data, forces.ctypes.data, *tail,
                                        x.ctypes.data)
        return True

    def _swing_references(self, q, v, rot, t_s: float, node_times, v_world, yaw_rate: float) -> tuple:
        """This step's swing references (`References.swing_references`): where C computes them (`_swing_fields`), its
        inputs staged and its output buffers returned (written by `wbsp_prepare`), else Python's."""
        mpc = self._mpc
        references, gait = mpc.references, mpc.gait
        if self._swing is None:
            return references.swing_references(q, v, rot, t_s, node_times, v_world, yaw_rate)
        inputs, feet, vxy, yaw = self._swing
        frames = references.foot_frames(q)
        n_feet = len(frames)
        for i, frame in enumerate(frames):
            feet[3 * i : 3 * i + 3] = frame.translation
        if yaw is not None:
            feet[3 * n_feet :] = [heading_of(frame.rotation) for frame in frames]
        v_base = rot @ v[:3]  # (`References.swing_references`' measured base velocity, the same product)
        inputs[:] = (t_s, q[0], q[1], v_base[0], v_base[1], v_world[0], v_world[1], heading_of(rot), yaw_rate,
                     gait.duty_factor * gait.period_s, gait.swing_duration_s)
        return vxy, yaw

    def covers(self, commands, measured_contact) -> bool:
        """Whether this step's data can be prepared here (else `MPC._step_data`'s NumPy code runs)."""
        mpc = self._mpc
        references = mpc.references
        return references.terrain is None and not references.sway(commands) and \
            not (mpc.config.references.touchdown_events and measured_contact is not None)

    def _gait_tables(self, gait) -> None:
        """Point the struct at the gait clock's anchors and standing intervals when they changed (rarely)."""
        anchors, stand = gait.anchors, gait.stand_intervals
        if self._gait_state[0] is anchors and self._gait_state[1] == stand:
            return
        self._gait_arrays = (np.ascontiguousarray(anchors, dtype=float).reshape(-1, 3),
                             np.ascontiguousarray(stand, dtype=float).reshape(-1, 2))
        step = self._step
        step.anchors, step.stand = (a.ctypes.data for a in self._gait_arrays)
        step.n_anchors, step.n_stand = len(anchors), len(stand)
        self._gait_state = (anchors, [list(interval) for interval in stand])

    def anchor(self, q: np.ndarray, rot: np.ndarray, commands, t_s: float) -> tuple[np.ndarray, float]:
        """`References.targets`' base position reference moved to `t_s`, the same arithmetic on Python floats: the
        commanded velocity in world coordinates (3,), and the anchor's yaw."""
        references = self._mpc.references
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        dt_since = 0.0 if references.last_t_s is None else max(0.0, t_s - references.last_t_s)
        references.last_t_s = t_s
        velocity_only = references.config.base_tracking == "velocity"
        qx, qy = q[:2].tolist()
        if references.anchor_xy_m is None or velocity_only:
            references.anchor_xy_m, references.anchor_yaw_rad = np.array([qx, qy]), yaw
        cos_y, sin_y = math.cos(references.anchor_yaw_rad), math.sin(references.anchor_yaw_rad)
        cx, cy, cz = np.asarray(commands.base_velocity_m_s, dtype=float).tolist()
        wx, wy = cos_y * cx - sin_y * cy, sin_y * cx + cos_y * cy
        ax, ay = references.anchor_xy_m.tolist()
        if not velocity_only:
            ax, ay = ax + wx * dt_since, ay + wy * dt_since
            references.anchor_yaw_rad = references.anchor_yaw_rad + commands.base_yaw_rate_rad_s * dt_since
        ox, oy = ax - qx, ay - qy
        distance = math.hypot(ox, oy)
        if distance > MAX_ANCHOR_OFFSET_M:
            ax, ay = qx + MAX_ANCHOR_OFFSET_M * ox / distance, qy + MAX_ANCHOR_OFFSET_M * oy / distance
        references.anchor_xy_m = np.array([ax, ay])
        return np.array([wx, wy, cz]), references.anchor_yaw_rad

    def prepare(self, q: np.ndarray, v: np.ndarray, commands, t_s: float) -> tuple:
        """This step's (p, bounds, soft_rows, x0, node_times, contact) as `MPC._step_data` makes them."""
        mpc = self._mpc
        problem, references, gait, config = mpc.problem, mpc.references, mpc.gait, mpc.config
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        v_world, anchor_yaw = self.anchor(q, rot, commands, t_s)
        after_push = mpc.push_mode.update(v, rot, v_world, t_s, mpc._previous)
        mpc.push_mode.adapt_cadence(t_s)
        node_times = mpc.node_times(t_s)  # (after the cadence's retiming, as in `MPC._step_data`)
        self._node_times[:] = node_times
        command, yaw_rate = np.asarray(commands.base_velocity_m_s, dtype=float), commands.base_yaw_rate_rad_s
        stance, step = references.stance_reference, self._step
        if stance is not None:
            self._stance_offsets[...] = stance.joint_offsets(gait, t_s + node_times, command, yaw_rate)
        step.offsets = None if stance is None else self._stance_offsets.ctypes.data
        self._gait_tables(gait)
        swing_vxy, swing_yaw_rates = self._swing_references(q, v, rot, t_s, node_times, v_world, yaw_rate)
        relaxed = mpc._relaxed_rows(after_push, commands)
        on_robot = -np.asarray(commands.ee_force_n, dtype=float)
        ee_velocity = references.ee_velocity(q, commands, v_world)
        self._measured.stage_inputs(swing_vxy, ee_velocity, swing_yaw_rates, bool(mpc.robot.arm_ee),
                                    bool(mpc.robot.soles))
        previous = mpc._previous if config.warm_start else None
        warm = previous is not None and previous.x is not None and previous.x.size == self._x.size and \
            previous.q.shape == self._previous_q.shape and previous.node_times_s.shape == self._previous_times.shape
        if warm:
            self._point_at_previous(previous)
        self._q[:], self._v[:], self._rot[...] = q, v, rot
        self._v_des[:3] = rot.T @ v_world  # (`References.targets`' v_des, in NumPy: its matrix product)
        self._v_des[3:6] = yaw_rate * rot[2]
        template = mpc._parameter_template()
        if template is not self._p_template:
            self._p_template, step.p_template = template, template.ctypes.data
        soft, swing, piece_s, anchor_xy = after_push or config.soft_rows_always, config.swing, \
            gait.swing_duration_s / 2, references.anchor_xy_m
        self._scalars[:] = (
            t_s, anchor_xy[0], anchor_xy[1], v_world[0], v_world[1],
            math.nan if commands.base_height_m is None else commands.base_height_m, mpc._support_n(on_robot),
            on_robot[0], on_robot[1], on_robot[2], soft, not after_push, warm, previous.t_s if warm else 0.0,
            "ee_vel" in relaxed, "foot_vel" in relaxed, gait.duty_factor, piece_s, swing.apex_height_m,
            swing.liftoff_velocity_m_s * piece_s, swing.touchdown_velocity_m_s * piece_s, anchor_yaw, yaw_rate)
        out = np.empty(self._offsets[-1])
        address = out.ctypes.data  # (p's: `unpack` reads it)
        if self._packer.wbsp_prepare(self._address, address):
            raise RuntimeError("the MPC's compiled q (-) q over the nodes failed")
        self._p_address = address
        if node_times is not problem.config.grid.node_times_s:  # moved onto the contact switches
            out[problem.params.block("dt")] = np.diff(node_times)
        return self._outputs(out, q, v, t_s, node_times, previous if warm else None, after_push, soft, swing_vxy,
                             swing_yaw_rates, ee_velocity, on_robot)

    def _outputs(self, out: np.ndarray, q, v, t_s: float, node_times, previous, after_push: bool, soft: bool, swing_vxy,
                 swing_yaw_rates, ee_velocity, on_robot) -> tuple:
        """`prepare`'s results as views of the step's buffer `out`: the cold guess (no last plan) NumPy's, flat feet's
        wrenches (`MPC._shifted_sole_wrenches`) C's (`_sole_wrenches`), and the soft rows' `StageBounds` where a failure
        may need them."""
        mpc = self._mpc
        problem = mpc.problem
        p, bounds, x, contact, forces = (out[a:b] for a, b in zip(self._offsets[:-1], self._offsets[1:]))
        self._p = p
        contact, forces = contact.reshape(len(node_times), -1), forces.reshape(problem.N, -1)
        if previous is None:  # the first step (or a foreign last plan): NumPy's guess
            x = mpc._initial_guess(q, v, t_s, node_times, forces)
            if not after_push:
                x[problem.slack_index] = 0.0
        elif problem.surface_feet and not self._sole_wrenches(previous, contact, x):  # (else NumPy's, the same)
            columns = problem.idx["F"]  # flat feet: the last plan's wrenches by contact pattern (`warm_start.py`)
            x[columns] = mpc._shifted_sole_wrenches(forces, previous, t_s + node_times[:-1],
                                                    previous.t_s + previous.node_times_s[:-1]) / problem.x_scale[columns]
        soft_rows = None if soft or not problem.n_slack_variables else StageBounds(
            v0=v, q_ref=q, contact=contact, swing_vz_m_s=self._swing_vz.copy(), swing_vxy_m_s=_copy(swing_vxy),
            swing_yaw_rate_rad_s=_copy(swing_yaw_rates), ee_velocity_m_s=ee_velocity, ee_force_on_robot_n=on_robot,
            **self._measured_values(), soft=True, relaxed_rows=mpc.config.push.relaxed_rows)
        return p, problem.bounds_template().views(bounds), soft_rows, x, node_times, contact

    def _point_at_previous(self, previous) -> None:
        """The last plan's x, q and node times for the C code: the last `unpack`'s own buffers where `previous` is its
        plan (`last_solution`: nothing overwrote them since), else copies of the plan's."""
        step, own = self._step, previous is self.last_solution
        self._previous_times[:] = previous.node_times_s  # (the grid's, or its own where they follow the switches)
        if not own:
            self._previous_x[:], self._previous_q[...] = previous.x, previous.q
        if own != self._reading_own:
            sources = (self._x, self._plan_out) if own else (self._previous_x, self._previous_q)
            step.previous_x, step.previous_q = (a.ctypes.data for a in sources)
            self._reading_own = own

    def _measured_values(self) -> dict:
        """The measured frame velocities of this step (`MeasuredVelocities`' fields), copied from the C code's."""
        return split_velocities(self._mpc.robot, self._velocities.copy())

    def unpack(self, x: np.ndarray, p: np.ndarray):
        """The plan (q, v, a, F, tau as (nodes, size) views of one fresh array) from the solver's x and this step's p,
        and whether x and tau are finite; None where p is not the last `prepare`'s or x's size differs."""
        if p is not self._p or np.shape(x) != self._x.shape:
            return None
        self._x[:] = x
        address, x_address, out, tau_start, n_tau = self._unpack_call
        finite = self._packer.wbsp_unpack(address, x_address, self._p_address, out, tau_start, n_tau)
        if finite < 0:
            raise RuntimeError("the MPC's compiled plan unpacking failed")
        plan, parts, start = self._plan_out.copy(), [], 0
        for rows, cols in self._mpc._plan_shapes:
            parts.append(plan[start : start + rows * cols].reshape(rows, cols))
            start += rows * cols
        return parts, finite == 1


def _copy(values: np.ndarray | None) -> np.ndarray | None:
    """A copy of a step's buffer the soft rows keep (the next step overwrites C's swing references)."""
    return None if values is None else values.copy()


def _work(functions: ctypes.CDLL, name: str) -> tuple[int, ...]:
    """A generated function's (arguments, results, integer work, real work) sizes (its `_work` entry point)."""
    sizes = [ctypes.c_longlong() for _ in range(4)]
    getattr(functions, f"{name}_work")(*(ctypes.byref(size) for size in sizes))
    return tuple(max(int(size.value), 2) for size in sizes)
