"""`MPC`: measured state + commands + time -> `Solution` (section V-A).

One OCP and one solver are built at construction; every step only packs parameters and bounds,
warm-starts from the previous solution shifted in time (contact forces re-initialised: weight
shared over the stance feet, zero on swing feet, section V-A2) and calls the solver. The step's
targets come from `References`, push recovery mode from `PushMode`, the re-solves of a failed step
from `Recovery`; the settings from `MpcConfig` (control/config.py).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.control.commands import Commands, object_reference
from wbmpc.control.compiled_step import CompiledStep
from wbmpc.control.config import BASE_TRACKING_MODES, MpcConfig
from wbmpc.control.delay import DelayPredictor
from wbmpc.control.delay_ticks import compiled_ticks
from wbmpc.control.inputs import checked_state
from wbmpc.control.measured import MeasuredVelocities, velocities_function
from wbmpc.control.push import PushMode
from wbmpc.control.recovery import Recovery
from wbmpc.control.references import References
from wbmpc.control.solution import Solution, joint_trajectory, python_share, shifted_plan
from wbmpc.control.step_anatomy import StepStamps
from wbmpc.control.touchdown import follow_touchdown
from wbmpc.control.trajectory import interp_rows
from wbmpc.control.warm_start import ShiftedDuals, ShiftedGuess, shifted_sole_wrenches
from wbmpc.control.weights import CostWeights
from wbmpc.errors import ConfigError, check_number
from wbmpc.gait import GaitClock, SwingProfile, make_gait
from wbmpc.ocp.problem import OcpProblem, StageBounds
from wbmpc.robots import GRAVITY_M_S2, RobotModel
from wbmpc.solvers import make_solver, step_pack
from wbmpc.solvers.buffered import BufferedFunction
from wbmpc.solvers.codegen import CompileError, compile_functions
from wbmpc.solvers.nlp import NlpSolver

__all__ = ["MPC", "BASE_TRACKING_MODES", "Commands", "CostWeights", "MpcConfig"]


@dataclass
class _StepData:
    """One step's NLP data (`MPC._step_data`)."""

    p: np.ndarray
    bounds: tuple
    soft_rows: StageBounds | None  # a failed hard step's retry with the soft rows free (bounds built on need)
    x0: np.ndarray
    node_times: np.ndarray
    contact: np.ndarray


class MPC:
    """Whole-body MPC on a robot: `solve(q, v, commands, t_s)` returns the optimal `Solution`."""

    def __init__(self, robot: RobotModel, config: MpcConfig = MpcConfig(), problem: OcpProblem | None = None,
                 solver: NlpSolver | None = None):
        self.robot = robot
        self.config = config
        # the MPC's own clock: its period changes after pushes (PushConfig.gait_period_scale); estimators read it too.
        # Without a period (the policy's comes from control/tuning.py) the base height stands in for a biped's leg
        self.gait = GaitClock(make_gait(config.gait, len(robot.feet), config.gait_period_s,
                                        leg_length_m=float(robot.q_nominal[2])))
        self.problem = problem or OcpProblem(robot, config.ocp)
        self.solver = solver or make_solver(self.problem, config.solver)
        dyn, N = self.problem.dyn, self.problem.N
        q, q1 = ca.SX.sym("q", robot.nq), ca.SX.sym("q1", robot.nq)
        # called on NumPy buffers every step (no DM conversions); outputs are reused: copy what is kept
        difference, plan, velocities = self._step_functions(
            ca.Function("difference", [q, q1], [dyn.difference(q, q1)]).map(N + 1, [True, False], [False]),
            self._plan_function(), velocities_function(self.problem, robot))  # q (-) q1 over the nodes, one q for all
        self._difference, self._plan = BufferedFunction(difference), BufferedFunction(plan)
        # the measured frame velocities of the bounds: compiled with these where they are, else pinocchio's
        self._measured_velocities = MeasuredVelocities(robot, BufferedFunction(velocities) if self._functions_library
                                                       else None)
        self._weights = config.weights.vectors(robot, self.problem.nf)
        # the model's mass distribution (OcpConfig.inertial_parameters): NLP parameters, set between steps
        self._inertial = self._nominal_inertial()
        self._p_template: np.ndarray | None = None  # p's blocks that stay between steps (`_parameters`)
        self._p_blocks = tuple(self.problem.params.block(name) for name in ("q_ref", "rot_ref", "dq_des", "v_des", "F_des"))
        self._data = robot.model.createData()
        self._ee_id = robot.frame_id(robot.arm_ee) if robot.arm_ee else None
        self._joints_are_coordinates = robot.nq == robot.nv + 1 and not robot.continuous.any()
        self.references = References(robot, config.references, self.gait, self._difference, config.swing)
        self._flat_normals = np.tile([0.0, 0.0, 1.0], (N, len(robot.feet))).T.copy()  # (3 n_feet, N): world z
        self.push_mode = PushMode(config.push, self.gait)
        self.recovery = Recovery(self.problem, self.solver, config.recovery)
        # the warm start's re-sampling (forces: re-initialised), the bounds and the swing v_z references in C with the
        # solver's compiled code (solvers/step_pack.py; NumPy without it: the same numbers)
        packer = step_pack.library(config.solver.codegen) if config.solver.compiled else None
        self._shift, self.problem.bounds_packer = ShiftedGuess(self.problem, packer=packer), packer
        self._swing_vz = step_pack.SwingVelocity(config.swing, packer if type(config.swing) is SwingProfile else None,
                                                 (N + 1, len(robot.feet)))
        states = self.problem.state_names  # node 0's state variables and their entries of the measured x0
        self._measured_entries = (np.concatenate([self.problem.idx[name][0] for name in states]),
                                  np.concatenate([np.arange(self.problem.state_offsets[name].start,
                                                            self.problem.state_offsets[name].stop) for name in states]))
        self._previous: Solution | None = None
        # delay compensation's state prediction, its joint loop compiled where the solver is (control/delay_ticks.py)
        self._delay = DelayPredictor(robot, compiled_ticks(dyn, robot, config.solver) if config.delay_compensation
                                     else None)
        self.step_stamps = StepStamps()  # where the last step's time went (control/step_anatomy.py)
        self._after_solve_s = 0.5e-3  # running mean of the step's time after the solver returns (unpacking)
        # a solver that starts from given multipliers (fatrop-direct on flat feet) gets the last plan's, moved by
        # constraint identity (ocp/multipliers.py)
        self._duals = ShiftedDuals(self.problem) if getattr(self.solver, "takes_multipliers", False) else None
        dyn = self.problem.dyn  # flat feet's columns of F: force and sole moments (`_shifted_sole_wrenches`)
        self._sole_columns = {i: np.r_[3 * i : 3 * i + 3, dyn.moment_slice(i)] for i in self.problem.surface_feet}
        # the step's data preparation and unpacking in one C call each where the problem allows (compiled_step.py)
        compiled = CompiledStep(self, packer, self._functions_library) if packer is not None else None
        self.compiled_step = compiled if compiled is not None and compiled.supported else None

    def _plan_function(self) -> ca.Function:
        """(x, p) -> the plan's trajectories (`OcpProblem.trajectory_function`) with the configurations q_ref (+) dq
        integrated in the same call (one evaluation per step instead of two), as one vector: q, v, a, F, tau each
        column by column, i.e. node by node (`_unpack` reads them as row-major (nodes, size) views of one copy)."""
        problem = self.problem
        x, p = ca.SX.sym("x", problem.n_variables), ca.SX.sym("p", problem.params.size)
        dq, v, a, forces, tau = problem.trajectory_function()(x, p)
        q_ref = problem.params.select(p, "q_ref")
        q = ca.horzcat(*[problem.dyn.integrate(q_ref, dq[:, k]) for k in range(dq.shape[1])])
        parts = (q, v, a, forces, tau)
        self._plan_shapes = [(part.shape[1], part.shape[0]) for part in parts]  # (nodes, size), row-major
        return ca.Function("plan", [x, p], [ca.vertcat(*[ca.vec(part) for part in parts])], ["x", "p"], ["plan"])

    def _step_functions(self, *functions: ca.Function) -> list[ca.Function]:
        """The MPC's own functions of every step, compiled with the solver's (`SolverConfig.compiled`; cached):
        b1_z1's plan unpacking and q (-) q over the nodes take 3.5 and 2.4 us compiled against 26 and 10 us in
        CasADi's virtual machine. Where they cannot be compiled, the virtual machine's (the solver's warning says why)."""
        self._functions_library = None
        if not self.config.solver.compiled:
            return list(functions)
        try:
            report = compile_functions(list(functions), f"{self.problem.config.formulation}_mpc",
                                       self.config.solver.codegen)
        except CompileError:
            return list(functions)
        self._functions_library = str(report.library)  # (also called from C: `CompiledStep`)
        return [ca.external(function.name(), self._functions_library) for function in functions]

    def _nominal_inertial(self) -> dict[str, np.ndarray]:
        names = [n for n in ("base_com_offset", "payload_kg", "base_payload_kg") if n in self.problem.params.names]
        return {name: np.zeros(self.problem.params.shape(name)[0]) for name in names}

    def set_inertial_parameters(self, base_com_offset_m, payload_kg: float, base_payload_kg: float = 0.0) -> None:
        """The base CoM offset (base frame, m), hand payload (kg; the base's without an arm) and, with an arm, a
        load at the base origin (kg) the next plans use (no rebuild); needs `OcpConfig.inertial_parameters`."""
        if not self._inertial:
            raise ConfigError("this MPC's OCP has no inertial parameters: build it with "
                              "OcpConfig(inertial_parameters=True) (wbmpc run --identify-mass)")
        offset = np.asarray(base_com_offset_m, dtype=float).reshape(3)
        if not (np.all(np.isfinite(offset)) and np.isfinite(payload_kg) and np.isfinite(base_payload_kg)):
            raise ConfigError(f"inertial parameters must be finite, got offset {offset} m, payload {payload_kg} kg "
                              f"and base payload {base_payload_kg} kg")
        if base_payload_kg and "base_payload_kg" not in self._inertial:
            raise ConfigError(f"{self.robot.name} has no arm: its payload_kg already sits at the base origin")
        self._p_template = None
        self._inertial = {"base_com_offset": offset, "payload_kg": np.array([float(payload_kg)]),
                          **({"base_payload_kg": np.array([float(base_payload_kg)])} if "base_payload_kg" in self._inertial
                             else {})}

    def reset(self) -> None:
        """Forget the warm start and the position references (e.g. after a reset of the plant)."""
        self._previous = None
        if self._duals is not None:
            self._duals.reset()
        self.references.reset()
        self.recovery.reset()
        self.push_mode.reset()
        self.gait.reset()
        self._inertial = self._nominal_inertial()  # until an estimator sets it again
        self._p_template = None

    @property
    def last_plan(self) -> Solution | None:
        """The last good plan (None before the first successful step): the next step warm-starts from it and,
        if it fails, holds it shifted in time."""
        return self._previous

    def continue_from(self, solution: Solution) -> None:
        """Take `solution` as the last good plan, as after a successful step: the next step warm-starts
        from it and, if it fails, holds it shifted in time."""
        self._previous = solution

    def enter_push_recovery(self, until_t_s: float = np.inf) -> None:
        """Push recovery mode (soft rows, relaxed rows, the push cadence) until `until_t_s`, as the push
        detector sets it after a kick."""
        self.push_mode.enter(until_t_s)

    def prepare_fallback(self) -> None:
        """Build the recovery solvers and the solver's instances (`prepare_structures`) now: before the clock runs."""
        self.recovery.prepare()
        self.prepare_structures()

    def prepare_structures(self, rate_hz: float = 80.0, sample_s: float = 1e-3) -> None:
        """Build the solver's instances (`prepare_structures`: a Fatrop instance costs ~11 ms of CPU on g1, and its
        first solve more than the next) for the row patterns of the first two gait cycles, plans starting every
        `sample_s` (real time: between the ticks at `rate_hz`), then reset the MPC."""
        prepare = getattr(self.solver, "prepare_structures", None)
        if prepare is not None and self.gait.duty_factor < 1:
            q, v, end_s = self.robot.q_nominal, np.zeros(self.robot.nv), self.gait.start_lead_s + 2 * self.gait.period_s
            starts_s = np.arange(0.0, end_s, min(1 / rate_hz, sample_s)).tolist()
            steps = (self._step_data(q, v, Commands(), t_s) for t_s in starts_s)
            prepare(tuple(np.array(a) for a in (*step.bounds, step.p, step.x0)) for step in steps)
            self.reset()

    def _object_data(self, q: np.ndarray, t: float, node_times: np.ndarray, commands: Commands) -> tuple[dict, dict]:
        """With an object model: its reference and weights (NLP parameters) and its measured state and contact
        rows (bounds); empty without one."""
        model = self.problem.object
        if model is None:
            return {}, {}
        command = commands.object_command
        reference = object_reference(model, command, t + node_times)
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        ee = self._data.oMf[self._ee_id].translation
        return ({"obj_ref": reference.T, "obj_w": model.weights()},
                {"object_state": command.state, "object_contact_measured": model.contact_values(command.state, ee)})

    def _force_guess(self, contact: np.ndarray, commands: Commands) -> np.ndarray:
        """(N, nf) weight shared over the stance feet, zero on swing feet, arm force = -command."""
        N, n_feet = self.problem.N, len(self.robot.feet)
        forces = np.zeros((N, self.problem.nf))
        on_robot = -np.asarray(commands.ee_force_n, dtype=float)
        support = self._support_n(on_robot)
        stance = contact[:N]
        n_stance = np.maximum(stance.sum(axis=1, keepdims=True), 1)
        forces[:, 2 : 3 * n_feet : 3] = stance * support / n_stance
        if self.robot.arm_ee:
            forces[:, 3 * n_feet : 3 * n_feet + 3] = on_robot
        return forces

    def _support_n(self, on_robot: np.ndarray) -> float:
        """The weight (with the payloads) less the arm's vertical force on the robot: what the feet carry."""
        mass = self.robot.mass_kg + sum(float(self._inertial[name][0]) for name in ("payload_kg", "base_payload_kg")
                                        if name in self._inertial)
        return mass * GRAVITY_M_S2 - (on_robot[2] if self.robot.arm_ee else 0.0)

    def node_times(self, t_s: float) -> np.ndarray:
        """The horizon's node times from `t_s`: the grid's, the far ones on the gait's contact switches with
        `TimeGrid.follow_contact_switches` (not with an object model: its rows read the grid's times)."""
        grid = self.problem.config.grid
        if not grid.follow_contact_switches or self.problem.object is not None:
            return grid.node_times_s
        return grid.on_switches(self.gait.switch_times(t_s, t_s + grid.horizon_s) - t_s)

    def schedule(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Node times (`node_times`), contact flags and swing v_z references of the horizon starting at `t_s`."""
        node_times = self.node_times(t_s)
        times = t_s + node_times
        progress = self.gait.swing_phase(times)
        contact = (progress < 0).astype(float)  # gait.contact's, from the same phases
        swing_vz = self._swing_vz(progress, self.gait.swing_duration_s)
        return node_times, contact, swing_vz

    # ------------------------------------------------------------------ solve
    def solve(self, q: np.ndarray, v: np.ndarray, commands: Commands | None = None, t_s: float = 0.0,
              delay_s: float = 0.0, budget_s: float | None = None, *, t: float | None = None,
              measured_contact=None) -> Solution:
        """The plan from the state (q, v) measured at `t_s`. `delay_s`: when the plan will reach the robot, after
        t_s; with `MpcConfig.delay_compensation` the plan starts there (state rolled forward, `Solution.t_s` =
        t_s + delay_s). `budget_s`: this step's time budget (overrides `MpcConfig.step_budget_s`) for a solver
        with a deadline. `measured_contact` (one bool per foot: loaded now): with `ReferenceConfig.touchdown_events` the
        schedule follows it (`control/touchdown.py`). (`t`: the name of `t_s` before, deprecated.)"""
        if t is not None:
            warnings.warn("MPC.solve(..., t=...) is deprecated; use t_s", DeprecationWarning, stacklevel=2)
            t_s = t
        t = t_s
        stamps = self.step_stamps
        stamps.start()
        start = stamps.values[0]
        clock = getattr(self.solver, "clock", None)
        clock_start = clock() if clock is not None else None
        commands = commands or Commands()
        q, v = checked_state(self.robot, self.config.limits, q, v, commands, t)
        check_number("delay_s", delay_s, low=0.0, high=1.0, unit="s")
        if self.config.delay_compensation and delay_s > 0:
            q, v = self._delay.predict(q, v, self._previous, t, delay_s, self.config.delay_compensation)
            t = t + delay_s
        stamps.mark("predicted")
        self.gait.follow(t, commands.walking)  # stand <-> walk on command, where the feet allow it
        step = self._step_data(q, v, commands, t, measured_contact)
        stamps.mark("prepared")
        result, solve_end = self._solve_step(step, t, budget_s, clock, clock_start)
        stamps.mark("solved")
        solution = self._unpack(result.x, step.p, q, t, step.node_times, step.contact, result.stats)
        stamps.mark("unpacked")
        if solution.success:
            self._previous = solution
            if self._duals is not None:
                self._duals.record(t, result, step.bounds, step.node_times)
        elif self.config.recovery.hold_previous and self._previous is not None:
            solution = shifted_plan(self._previous, t, step.node_times, step.contact, result.stats, self.robot)
        if solve_end is not None:  # the MPC's work after a deadline-bound solve: the next deadline leaves room for it
            self._after_solve_s = 0.8 * self._after_solve_s + 0.2 * (clock() - solve_end)
        self._delay.account(result.stats)  # the prediction's own part of the step's split
        python_share(result.stats, 1e3 * (time.perf_counter() - start))
        stamps.mark("end")
        return solution

    def _step_data(self, q: np.ndarray, v: np.ndarray, commands: Commands, t: float, measured_contact=None) -> _StepData:
        """This step's NLP data: parameters (targets, weights, schedule), bounds (hard, and with the soft rows free
        where a failed hard step retries them) and the initial guess; in one C call where it covers the step."""
        if self.compiled_step is not None and self.compiled_step.covers(commands, measured_contact):
            return _StepData(*self.compiled_step.prepare(q, v, commands, t))
        problem, references = self.problem, self.references
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        base_velocity_world = references.advance(q, rot, commands, t)
        after_push = self.push_mode.update(v, rot, base_velocity_world, t, self._previous)
        self.push_mode.adapt_cadence(t)
        node_times, contact, swing_vz = self.schedule(t)
        dq_des, v_des = references.targets_at(q, rot, commands, t, node_times, base_velocity_world)
        sway = references.sway(commands)
        if sway:  # lean over the feet that will stand support_lead_s later
            dq_des = references.sway_towards_support(q, rot, dq_des, t, node_times, sway)
        swing_vxy, swing_yaw_rates = references.swing_references(q, v, rot, t, node_times, base_velocity_world,
                                                                 commands.base_yaw_rate_rad_s)
        # on a terrain: footholds, eq. (6) between its heights and the cones' normals (control/terrain_references.py)
        terrain = references.terrain_step(q, v, rot, t, node_times, base_velocity_world)
        if terrain is not None:
            swing_vz, swing_vxy = terrain.swing_vz_m_s, terrain.swing_vxy_m_s
            dq_des = references.follow_support(rot, dq_des, terrain)  # a biped's base over its footholds
        if self.config.references.touchdown_events and measured_contact is not None:  # (on the terrain's splines too)
            contact, swing_vz = follow_touchdown(self.gait, t, node_times, contact, swing_vz, measured_contact,
                                                 self.config.swing.touchdown_velocity_m_s)
        forces = self._force_guess(contact, commands)
        object_values, object_bounds = self._object_data(q, t, node_times, commands)
        p = self._parameters(q, rot, dq_des, v_des, forces, terrain, object_values)
        if node_times is not problem.config.grid.node_times_s:  # moved onto the contact switches
            p[problem.params.block("dt")] = np.diff(node_times)
        stage_bounds = StageBounds(
            v0=v, q_ref=q, contact=contact, swing_vz_m_s=swing_vz, swing_vxy_m_s=swing_vxy,
            swing_yaw_rate_rad_s=swing_yaw_rates,
            ee_velocity_m_s=references.ee_velocity(q, commands, base_velocity_world),
            ee_force_on_robot_n=-np.asarray(commands.ee_force_n, dtype=float),
            **self._measured_velocities(q, v),
            soft=after_push or self.config.soft_rows_always, relaxed_rows=self._relaxed_rows(after_push, commands),
            collision_measured_m=problem.collision_rows_at(q) if problem.collision is not None else None,
            **object_bounds,
        )
        if problem.collision is not None and self._previous is None:  # the start: refuse a pose in collision
            problem.collision.check_clear(q)
        x0 = self._initial_guess(q, v, t, node_times, forces, object_bounds.get("object_state"))
        if not after_push:
            x0[problem.slack_index] = 0.0  # pinned: the hard OCP
        bounds = problem.bounds(stage_bounds)
        # with soft rows, a hard step that fails is re-solved with the slacks free first (it may be infeasible)
        soft_rows = None if after_push or self.config.soft_rows_always or not problem.n_slack_variables else \
            replace(stage_bounds, soft=True, relaxed_rows=self.config.push.relaxed_rows)
        return _StepData(p, bounds, soft_rows, x0, node_times, contact)

    def _parameters(self, q, rot, dq_des, v_des, forces, terrain, object_values: dict) -> np.ndarray:
        """p of this step: the blocks that stay (time steps, friction, weights, the flat ground's normals, inertial
        parameters) from a template packed once, this step's targets and force guess written into a copy."""
        params = self.problem.params
        p = self._parameter_template().copy()
        q_ref, rot_ref, dq_block, v_block, force_block = self._p_blocks
        p[q_ref], p[v_block] = q, v_des
        p[rot_ref], p[dq_block] = rot.ravel(order="F"), dq_des.ravel(order="F")  # (column-major, as `pack`)
        p[force_block] = forces.ravel()  # F_des = forces.T
        if terrain is not None:
            params.write(p, "contact_normal", terrain.contact_normal)
        for name, value in object_values.items():
            params.write(p, name, value)
        return p

    def _parameter_template(self) -> np.ndarray:
        """p's blocks that stay between steps (time steps, friction, weights, normals, inertial parameters)."""
        if self._p_template is None:
            self._p_template = self.problem.params.template({
                "dt": self.problem.config.grid.dt_s, "mu": [self.config.friction_coefficient],
                "contact_normal": self._flat_normals, **self._weights, **self._inertial})
        return self._p_template

    def _solve_step(self, step: _StepData, t: float, budget_s: float | None, clock, clock_start):
        """One step's solve: the push fallback solver first in the wake of a push, else the solver on this
        step's deadline, then the recovery ladder unless a deadline forbids it. Returns the result and the
        solver clock's time at the end of a deadline-bound solve (None otherwise)."""
        cfg, p, bounds, soft_rows, x0 = self.config, step.p, step.bounds, step.soft_rows, step.x0
        solve_end = None
        if self.recovery.fallback_first(t):
            result = self.recovery.fallback_solver().solve(p, *bounds, x0)  # still in the wake of a push
            result.stats.status = f"{result.stats.status} (recovery: {cfg.recovery.fallback_solver} first after a push)"
            if not result.stats.success:
                result = self._recover(result, p, bounds, x0, t, fallback_tried=True, soft_rows=soft_rows)
        else:
            budget = budget_s if budget_s is not None else cfg.step_budget_s
            # the cold first step's deadline only checks that the budget fits a QP (its solve converges): it counts
            # from the solver's call, as that step's own work before it holds one-off costs and, on a wall clock,
            # any load spike (a real-time run on a loaded machine was refused at start with 0.3 ms left of 10)
            origin = clock_start if self._previous is not None or clock is None else clock()
            deadline = {} if clock is None or budget is None else \
                {"deadline": origin + budget - self._after_solve_s}
            result = self.solver.solve(p, *bounds, x0, *self._shifted_duals(t, bounds, step.node_times),
                                       warm_start=self._previous is not None and cfg.warm_start, **deadline)
            solve_end = clock() if deadline else None
            if not result.stats.success and deadline and self._previous is not None and not cfg.recovery.past_deadline:
                # the recovery ladder (converged re-solves) takes 50-150 ms after a push: a step with a deadline
                # holds the last good plan instead and the next step, one period later, tries again
                result.stats.status = f"{result.stats.status}; no recovery re-solve past the step's deadline"
            elif not result.stats.success:
                result = self._recover(result, p, bounds, x0, t, soft_rows=soft_rows)
        return result, solve_end

    def _shifted_duals(self, t: float, bounds, node_times) -> tuple:
        """The last plan's multipliers at this step's rows for a solver that takes them (`ShiftedDuals`); () otherwise."""
        if self._duals is None or self._previous is None or not self.config.warm_start:
            return ()
        return self._duals.at(t, bounds, self._previous.t_s, node_times)

    def _recover(self, failed, p, bounds, x0, t: float, fallback_tried: bool = False, soft_rows=None):
        """The recovery ladder (`Recovery.recover`; `soft_rows`: the step's data with the soft rows free, whose
        bounds are built here, on a failure only); a rescue with the soft rows free enters push recovery mode."""
        soft_bounds = None if soft_rows is None else self.problem.bounds(soft_rows)
        rescue = self.recovery.recover(failed, p, bounds, x0, t, has_plan=self._previous is not None,
                                       fallback_tried=fallback_tried, soft_bounds=soft_bounds)
        if rescue.soft_rows_succeeded:
            self.push_mode.enter(t + self.config.push.hold_s)
        return rescue.result

    def _relaxed_rows(self, after_push: bool, commands: Commands) -> tuple[str, ...]:
        """Rows dropped this step: `PushConfig.relaxed_rows` in push recovery mode, the arm's velocity rows
        while the hands are free (`ReferenceConfig.free_ee_without_command`)."""
        rows = self.config.push.relaxed_rows if after_push else ()
        if self.references.ee_free(commands):
            rows = tuple(dict.fromkeys((*rows, "ee_vel")))
        return rows

    def _initial_guess(self, q, v, t, node_times, forces, object_state=None) -> np.ndarray:
        """Cold: the measured state held over the horizon, weight-sharing forces. Warm: the previous
        solution's variables shifted to the new node times (any formulation, `ShiftedGuess`), forces re-initialised
        (the arm's shifted, where an object model makes it a variable of the plan)."""
        problem, idx = self.problem, self.problem.idx
        x0 = problem.initial_state(q, v, object_state)
        previous = self._previous if self.config.warm_start else None
        if previous is None:
            guess = {name: np.tile(x0[problem.state_offsets[name]], (len(idx[name]), 1)) for name in problem.state_names}
            if problem.object is not None:
                guess["obj_u"] = np.tile(problem.object.input_guess(object_state), (len(idx["obj_u"]), 1))
            for name, value in (("v", v), ("vj", v[6:])):
                if name in idx and name not in problem.state_names:
                    guess[name] = np.tile(value, (len(idx[name]), 1))
            guess["F"] = forces
            return problem.pack(guess)
        new_times, old_times = t + node_times, previous.t_s + previous.node_times_s
        # re-sampled in physical units, as the parts were before (bit for bit the same guess: a one-ulp change of
        # it moved a QP solved to 1e-9 from 9 HPIPM iterations to its cap)
        scale = problem.x_scale
        old_x = previous.x * scale
        # the previous configurations re-expressed as increments on the new reference q
        old_x[idx["dq"]] = self._difference(q, previous.q.T, shaped=True)[0].T
        x = self._shift(old_x, new_times, old_times)
        state0, x0_entries = self._measured_entries
        x[state0] = x0[x0_entries]  # node 0 is the measurement
        if problem.object is not None:  # the arm force is the plan's: shifted like the motion
            arm = slice(3 * len(self.robot.feet), 3 * len(self.robot.feet) + 3)
            forces = forces.copy()
            forces[:, arm] = interp_rows(new_times[:-1], old_times[:-1], previous.forces[:, arm])
        if problem.surface_feet:
            forces = self._shifted_sole_wrenches(forces, previous, new_times[:-1], old_times[:-1])
        x[idx["F"]] = forces
        return x / scale

    def _shifted_sole_wrenches(self, forces: np.ndarray, previous: Solution, new_times: np.ndarray,
                               old_times: np.ndarray) -> np.ndarray:
        """Flat feet: the previous plan's wrenches (force and moments) shifted in time by contact pattern
        (`warm_start.shifted_sole_wrenches`), instead of the weight share. A sole's wrench carries the plan's centre
        of pressure; re-initialised (moments 0, equal shares) it violated the dynamics rows by up to half the weight
        at the warm start."""
        return shifted_sole_wrenches(forces, previous.forces, previous.contact, self.gait.contact(new_times), new_times,
                                     old_times, self._sole_columns, len(self.problem.idx.get("tau", ())))

    def _unpack(self, x: np.ndarray, p: np.ndarray, q: np.ndarray, t: float, node_times, contact, stats) -> Solution:
        unpacked = self.compiled_step.unpack(x, p) if self.compiled_step is not None else None
        unpacked_in_c = unpacked is not None
        if unpacked is None:
            plan, parts, start = self._plan(x, p)[0].copy(), [], 0
            for rows, cols in self._plan_shapes:
                parts.append(plan[start : start + rows * cols].reshape(rows, cols))
                start += rows * cols
            tau = parts[-1]  # (no NaN or inf in x or tau: two reductions, not four)
            unpacked = parts, math.isfinite(float(np.vdot(x, x)) + float(np.vdot(tau, tau)))
        (q_traj, v, a, forces, tau), finite = unpacked
        # one coordinate per joint, none continuous: the joint positions are q[:, 7:] (Solution's own view)
        q_joints = None if self._joints_are_coordinates else joint_trajectory(self.robot, q_traj)
        solution = Solution(t_s=t, node_times_s=node_times.copy(), q=q_traj, v=v, a=a, forces=forces, tau=tau,
                            contact=contact, stats=stats, success=bool(stats.success and finite),
                            x=np.asarray(x, dtype=float), q_joints=q_joints)
        if self.compiled_step is not None:  # (its buffers hold this plan's x and q until the next unpacking)
            self.compiled_step.last_solution = solution if unpacked_in_c else None
        return solution

