"""The delay prediction's joint loop (control/delay.py) as one compiled call: eq. (10) held per 500 Hz tick and the
forward dynamics with the stance feet held (`symbolic/constrained.py`), a semi-implicit Euler step per tick, over
up to TICKS_PER_CALL ticks in one CasADi `mapaccum` (padding ticks of zero length leave the state as it is).

Built from the OCP's own symbolic dynamics and compiled into the cache with the MPC's other functions
(`MPC._step_functions`); pinocchio's `constraintDynamics` (`DelayPredictor`'s loop) stays the reference
(tests/control/test_delay_compensation.py: the same states to ~1e-12). The Python loop over the ticks took ~60 us a
tick on g1 (0.37 ms a real-time step); the compiled call takes what the arithmetic takes.
"""

from __future__ import annotations

import ctypes

import casadi as ca
import numpy as np

from wbmpc.solvers.buffered import BufferedFunction
from wbmpc.solvers.codegen import CompileError, compile_functions
from wbmpc.symbolic import Motion
from wbmpc.symbolic.constrained import held_forward_dynamics

TICKS_PER_CALL = 8  # a call's ticks (16 ms at 500 Hz: a real-time step's delay); longer delays chain calls
PROXIMAL_MU = 1e-10  # pinocchio's proximal damping in `DelayPredictor` (ProximalSettings(1e-12, 1e-10, 1))


def supports(robot) -> bool:
    """Whether the compiled ticks cover this robot: joint angles are q[7:] (no continuous joint)."""
    return robot.nq == robot.nv + 1 and not robot.continuous.any()


def tick_function(dyn, robot) -> ca.Function:
    """One joint-loop tick: (q, v, tau_ff, q_des, v_des, held feet 0/1, tick length h, kp, kd, Baumgarte Kd) ->
    (q, v) after h: eq. (10)'s torques clipped to the limits, held over the tick (control/interpolator.pd_torque)."""
    nj = robot.n_joints
    q, v = ca.SX.sym("q", robot.nq), ca.SX.sym("v", robot.nv)
    tau_ff, q_des, v_des = ca.SX.sym("tau_ff", nj), ca.SX.sym("q_des", nj), ca.SX.sym("v_des", nj)
    held, h = ca.SX.sym("held", len(robot.feet)), ca.SX.sym("h")
    kp, kd, baumgarte = ca.SX.sym("kp", nj), ca.SX.sym("kd", nj), ca.SX.sym("baumgarte_kd")
    tau_max = np.asarray(robot.tau_max, dtype=float)
    motor = tau_ff + kp * (q_des - q[7:]) + kd * (v_des - v[6:])
    tau = ca.fmin(ca.fmax(motor, -tau_max), tau_max)
    cfg = dyn.configuration(q)
    a = held_forward_dynamics(dyn, cfg, Motion(cfg, v), tau, held, baumgarte, PROXIMAL_MU)
    v_next = v + a * h
    return ca.Function("delay_tick", [q, v, tau_ff, q_des, v_des, held, h, kp, kd, baumgarte],
                       [dyn.integrate(q, v_next * h), v_next])


def ticks_function(dyn, robot, ticks: int = TICKS_PER_CALL) -> ca.Function:
    """`tick_function` over `ticks` ticks: (q, v, tau_ff, q_des, v_des, held, h (each a column per tick), kp, kd,
    Baumgarte Kd) -> (q, v) after the last one."""
    tick = tick_function(dyn, robot)
    accumulated = tick.mapaccum("delay_ticks_acc", ticks, 2)
    nj, n_feet = robot.n_joints, len(robot.feet)
    q, v = ca.MX.sym("q", robot.nq), ca.MX.sym("v", robot.nv)
    tau_ff, q_des, v_des = (ca.MX.sym(name, nj, ticks) for name in ("tau_ff", "q_des", "v_des"))
    held, h = ca.MX.sym("held", n_feet, ticks), ca.MX.sym("h", 1, ticks)
    kp, kd, baumgarte = ca.MX.sym("kp", nj), ca.MX.sym("kd", nj), ca.MX.sym("baumgarte_kd")
    q_all, v_all = accumulated(q, v, tau_ff, q_des, v_des, held, h, ca.repmat(kp, 1, ticks), ca.repmat(kd, 1, ticks),
                               ca.repmat(baumgarte, 1, ticks))
    return ca.Function("delay_ticks", [q, v, tau_ff, q_des, v_des, held, h, kp, kd, baumgarte],
                       [q_all[:, -1], v_all[:, -1]],
                       ["q", "v", "tau_ff", "q_des", "v_des", "held", "h", "kp", "kd", "baumgarte_kd"],
                       ["q_next", "v_next"])


def compiled_ticks(dyn, robot, solver_config) -> CompiledTicks | None:
    """The ticks compiled into the cache (`SolverConfig.codegen`, a library of their own: MPCs without delay
    compensation do not build it) where the solver is compiled and the robot is covered; None otherwise or where it
    cannot be compiled (`DelayPredictor` then steps pinocchio's dynamics tick by tick)."""
    if not (solver_config.compiled and supports(robot)):
        return None
    function, tick = ticks_function(dyn, robot), tick_function(dyn, robot)
    try:
        report = compile_functions([function, tick], "delay_ticks", solver_config.codegen)
    except CompileError:
        return None
    from wbmpc.solvers.step_pack import library

    return CompiledTicks(BufferedFunction(ca.external(function.name(), str(report.library))), robot,
                         library(solver_config.codegen), (ctypes.CDLL(str(report.library)), tick.name()))


class CompiledTicks:
    """Runs the ticks on a `BufferedFunction` of `ticks_function`: `run(q, v, tau_ff, q_des, v_des, held, steps,
    kp, kd, baumgarte_kd)` with one row per tick (as `DelayPredictor` builds them), TICKS_PER_CALL at a call."""

    def __init__(self, function, robot, packer=None, tick=None):
        self.function = function
        self.ticks = int(function.function.size_in(6)[1])
        nj, n_feet = robot.n_joints, len(robot.feet)
        self._columns = [np.zeros((nj, self.ticks)), np.zeros((nj, self.ticks)), np.zeros((nj, self.ticks)),
                         np.zeros((n_feet, self.ticks)), np.zeros((1, self.ticks))]
        # with the step packer (`solvers.step_pack.library()`): `predict`'s tick inputs written in place in one C call
        self._packer, self._n_feet = packer, n_feet
        self._columns_at = tuple(function.inputs[i].ctypes.data for i in range(2, 7))
        self._gains: tuple | None = None  # (kp, kd, Baumgarte Kd) last written into the inputs
        # with the one-tick function compiled too ((library, name)): the delay's ticks only, run from C, not the
        # padding ticks of a TICKS_PER_CALL call (a 10 ms delay: 5 of 8 ticks)
        self._run = None if packer is None or tick is None else self._tick_runner(robot, *tick)

    @property
    def runs_ticks_in_c(self) -> bool:
        """Whether `predict` runs the delay's ticks one by one from C (the one-tick function compiled too)."""
        return self._run is not None

    def _tick_runner(self, robot, library: ctypes.CDLL, name: str) -> tuple:
        """`wbsp_ticks_run`'s arguments after the tick count: sizes, the state and the columns, the gains, the
        one-tick function's work arrays (its `_work` sizes), the next state's scratch (kept with their addresses)."""
        sizes = [ctypes.c_longlong() for _ in range(4)]
        getattr(library, f"{name}_work")(*(ctypes.byref(size) for size in sizes))
        n_arg, n_res, n_iw, n_w = (max(int(size.value), 2) for size in sizes)
        inputs = self.function.inputs
        self._state = (np.zeros(robot.nq), np.zeros(robot.nv))
        self._work = (np.zeros(n_arg, dtype=np.int64), np.zeros(n_res, dtype=np.int64), np.zeros(n_iw, dtype=np.int64),
                      np.zeros(n_w), np.zeros(robot.nq), np.zeros(robot.nv))
        self._library = library
        return (ctypes.cast(library[name], ctypes.c_void_p), robot.nq, robot.nv, len(robot.feet),
                *(a.ctypes.data for a in self._state), *self._columns_at,
                *(inputs[i].ctypes.data for i in (7, 8, 9)), *(a.ctypes.data for a in self._work))

    def predict(self, q, v, plan, t_s: float, delay_s: float, hold: float, lead: float, kp, kd):
        """`DelayPredictor.predict`'s joint loop over the delay from (q, v) at t_s under `plan` (ticks of `hold`
        s, eq. (9) sampled `lead` s after each), its tick inputs made in C (`csrc/delay_ticks.c`: the same
        arithmetic as `DelayPredictor`'s NumPy); None without the packer or where the plan's arrays do not suit it."""
        packer, function = self._packer, self.function
        if packer is None:
            return None
        times, tau, q_joints, v_plan, a = plan.node_times_s, plan.tau, plan.q_joints, plan.v, plan.a
        contact = np.ascontiguousarray(plan.contact, dtype=float)  # (a view where the plan's is: the MPC's are)
        if not all(type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous
                   for x in (times, tau, v_plan, a)) or q_joints.dtype != np.float64 or \
                q_joints.strides[1] != 8 or len(times) < 2 or contact.shape[1:] != (self._n_feet,):
            return None
        inputs = function.inputs
        if self._gains is None or self._gains[0] is not kp or self._gains[1] is not kd or self._gains[2] != hold:
            inputs[7][:], inputs[8][:], inputs[9][0] = kp, kd, 1.0 / hold
            self._gains = (kp, kd, hold)
        n_ticks = packer.wbsp_tick_count(t_s, delay_s, hold)
        call = (len(times), contact.ctypes.data, self._n_feet, tau.ctypes.data, len(tau), q_joints.ctypes.data,
                q_joints.strides[0] // 8, v_plan.ctypes.data, a.ctypes.data, v_plan.shape[1], *self._columns_at)
        if self._run is not None:
            return self._run_ticks(q, v, n_ticks, (t_s, delay_s, hold, lead, n_ticks), plan.t_s, times, call)
        q_next, v_next = q, v
        for start in range(0, n_ticks, self.ticks):  # (one call for delays up to TICKS_PER_CALL ticks)
            inputs[0][:], inputs[1][:] = q_next, v_next
            packer.wbsp_tick_inputs(t_s, delay_s, hold, lead, n_ticks, start, self.ticks, plan.t_s, times.ctypes.data,
                                    *call)
            q_next, v_next = function.evaluate()
        return np.array(q_next, dtype=float), np.array(v_next, dtype=float)

    def _run_ticks(self, q, v, n_ticks: int, head: tuple, plan_t_s: float, times, call) -> tuple:
        """`predict`'s ticks by the one-tick function from C (`wbsp_ticks_run`), TICKS_PER_CALL columns at a time."""
        packer, (q_now, v_now) = self._packer, self._state
        q_now[:], v_now[:] = q, v
        for start in range(0, n_ticks, self.ticks):
            packer.wbsp_tick_inputs(*head, start, self.ticks, plan_t_s, times.ctypes.data, *call)
            if packer.wbsp_ticks_run(self._run[0], min(self.ticks, n_ticks - start), *self._run[1:]):
                raise RuntimeError("the delay prediction's compiled tick failed")
        return q_now.copy(), v_now.copy()

    def run(self, q, v, tau_ff, q_des, v_des, held, steps, kp, kd, baumgarte_kd: float):
        n = len(steps)
        for start in range(0, n, self.ticks):
            count = min(self.ticks, n - start)
            rows = slice(start, start + count)
            for column, values in zip(self._columns, (tau_ff, q_des, v_des, held, steps[:, None])):
                column[:, :count] = values[rows].T
                column[:, count:] = 0.0  # padding ticks: h = 0, nothing held
            q, v = self.function(q, v, *self._columns, kp, kd, baumgarte_kd)
            q, v = q.copy(), v.copy()
        return q, v
