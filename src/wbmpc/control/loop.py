"""The deployment pipeline (section V-B): MPC at 80 Hz, interpolation and joint PD at 500 Hz.

Delay modes: `none` (the simulation waits for the solver, section VI-B1), `measured` (the
step's CPU time elapses in simulation before its solution applies, VI-B2: the time the step takes on
a core of its own, whatever else the machine runs), `measured-wall` (its wall time instead), a fixed
delay in milliseconds, and `realtime` (the MPC runs in its own process while the simulation
advances at wall-clock speed). Until a newer solution is ready the
last good one keeps being interpolated; failed solves are counted and never applied.
"""

from __future__ import annotations

import gc
import os
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
import pinocchio as pin

from wbmpc.chunked_table import DEFAULT_CHUNK_ROWS
from wbmpc.control.commands import Commands
from wbmpc.control.delay import check_delay, expect_motor_law
from wbmpc.control.interpolator import PdGains, interpolate, pd_torque
from wbmpc.control.mpc import MPC
from wbmpc.control.run_log import RSS_SAMPLE_PERIOD_S, RunLog
from wbmpc.control.solution import Solution
from wbmpc.control.solver_process import (
    REALTIME_NICE,
    SolverProcess,
    available_cpus,
    cpu_plan,
    fifo_competitors,
    raise_loop_priority,
    raise_session_priority,
    restore_scheduling,
    restore_session_priority,
)
from wbmpc.control.step_anatomy import segments
from wbmpc.control.streaming_stats import StreamingStats
from wbmpc.errors import ConfigError, RunError, check_number
from wbmpc.resident_memory import rss_mb

Progress = Callable[[float, int], None]  # (share of the run done, recovered steps so far)
MPC_RATE_HZ = 80.0  # the paper's MPC rate (section V-B)


MOTOR_LAWS = ("held", "continuous")
FALL_GROUND_CELL_M = 0.01  # the fall check's ground on a terrain: fitted again per cm of base motion (or 0.01 rad)


@dataclass(frozen=True)
class LoopConfig:
    """The closed loop: MPC and control rates, when plans apply (`delay_mode`, `delay_ms` for a fixed delay),
    the joint PD, measurement noise, the fall criterion.

    `control_rate_hz` is the joint loop: the rate at which a command (eq. 9's references) reaches the motors and
    the motor law (eq. 10) is evaluated with the joint readings of that moment (a LowCmd arriving). `motor_law`:
    "held" keeps that torque until the next command (unitree_mujoco's LowCmd callback, the paper's 500 Hz PD),
    "continuous" re-evaluates eq. 10 at every physics step with the last command's references (a robot's motor
    driver). `joint_loop_jitter_ms`: each command arrives late by a uniform draw in [0, MS] (a LowCmd over DDS).
    `sample_mid_hold`: eq. (9) is sampled half a joint-loop period ahead, at the middle of the time its command is
    held, so that the held feed-forward torque is the plan's mean over the hold instead of lagging it by half a
    period (docs/design/reality-gap.md)."""

    mpc_rate_hz: float = MPC_RATE_HZ
    control_rate_hz: float = 500.0
    joint_loop_jitter_ms: float = 0.0
    motor_law: str = "held"
    sample_mid_hold: bool = True
    touchdown_events: bool = False  # pass the plant's measured foot contacts to the MPC (`ReferenceConfig.touchdown_events`)
    delay_mode: str = "none"  # control/delay.py: DELAY_MODES
    delay_ms: float | None = None  # the fixed delay of delay_mode "fixed" (given alone, it implies it)
    gains: PdGains = field(default_factory=PdGains)
    joint_position_noise_rad: float = 0.0
    joint_velocity_noise_rad_s: float = 0.0
    velocity_filter_hz: float | None = None  # first-order low-pass on joint velocities (paper: 50 Hz)
    fall_height_ratio: float = 0.5  # fell when the base drops below this share of its nominal height
    # the ground (`wbmpc.terrain.Terrain`): the fall check measures the base's height from its support there
    terrain: object | None = None
    seed: int = 0

    def __post_init__(self):
        if not (self.mpc_rate_hz > 0 and self.control_rate_hz > 0):
            raise ConfigError("MPC and control rates must be positive")
        if self.motor_law not in MOTOR_LAWS:
            raise ConfigError.for_field("motor_law", f"must be held or continuous, got {self.motor_law!r}")
        check_number("joint_loop_jitter_ms", self.joint_loop_jitter_ms, low=0.0, high=1e3 / self.control_rate_hz,
                     unit="ms")
        if self.delay_ms is not None and self.delay_mode == "none":
            object.__setattr__(self, "delay_mode", "fixed")
        check_delay(self.delay_mode, self.delay_ms)

    @property
    def fixed_delay_s(self) -> float | None:
        return self.delay_ms / 1e3 if self.delay_mode == "fixed" else None


class CommandSource(Protocol):
    """Commands at time t given the measured state (feedback commands such as arm tracking need it)."""

    def __call__(self, t_s: float, q: np.ndarray, v: np.ndarray) -> Commands: ...


@dataclass
class Event:
    """Something done to the plant at a time, e.g. a push: `action(plant)`; `name` labels it in plots."""

    time_s: float
    action: Callable
    done: bool = False
    name: str = "event"


class ClosedLoop:
    """Runs an `MPC` against a plant (`wbmpc.sim`) with the paper's interpolation, PD and delays."""

    def __init__(self, mpc: MPC, plant, config: LoopConfig = LoopConfig(), state_source=None,
                 log_dir=None, log_chunk_rows: int = DEFAULT_CHUNK_ROWS):
        """`state_source.measure() -> (q, v)` replaces the plant's true state (e.g. a state estimator);
        `log_dir` is where the `RunLog` spills full chunks of `log_chunk_rows` rows (a temporary directory if None)."""
        self.mpc = mpc
        self.log_dir = log_dir
        self.log_chunk_rows = log_chunk_rows
        self.state_source = state_source
        self.robot = mpc.robot
        self.plant = plant
        self.config = config
        self.kp, self.kd = config.gains.vectors(~self.robot.leg_joint_mask)
        expect_motor_law(mpc, config.gains, config.control_rate_hz, config.sample_mid_hold)  # what it predicts with
        self._rng = np.random.default_rng(config.seed)
        self._jitter_rng = np.random.default_rng([config.seed, 1])  # its own stream: noise draws stay as they were
        self._nominal_tick = 0.0
        self._reference = None  # the last command's references (eq. 9)
        self._filtered_v: np.ndarray | None = None
        self._delay_mean_s = 0.0  # running mean of the measured delays (delay compensation's guess)
        self.log: RunLog | None = None  # the log of the run in progress (or the last one): a `stop` may read it
        self._support = None  # the terrain's support plane under the base (the fall check's ground)
        self._ground_key, self._ground_m = None, 0.0  # ... where it was fitted last, and its height there
        if config.terrain is not None and not config.terrain.is_flat:
            from wbmpc.control.terrain_references import support_footprint

            self._support = support_footprint(self.robot, config.terrain)
        # callables(t_s, solution) told of every plan as it is logged (a live viewer draws it)
        self.solution_listeners: list[Callable] = []

    # ------------------------------------------------------------------ measurement
    def _measure(self) -> tuple[np.ndarray, np.ndarray]:
        """State estimate: plant state plus optional joint noise and the low-pass on joint velocities."""
        if self.state_source is not None:
            return self.state_source.measure()
        q, v = self.plant.state()
        cfg = self.config
        if cfg.joint_position_noise_rad:
            noise = np.r_[np.zeros(6), self._rng.normal(0, cfg.joint_position_noise_rad, self.robot.n_joints)]
            q = pin.integrate(self.robot.model, q, noise)
        if cfg.joint_velocity_noise_rad_s:
            v = v.copy()
            v[6:] += self._rng.normal(0, cfg.joint_velocity_noise_rad_s, v.size - 6)
        if cfg.velocity_filter_hz:
            dt = 1.0 / cfg.control_rate_hz
            alpha = dt / (dt + 1.0 / (2 * np.pi * cfg.velocity_filter_hz))
            if self._filtered_v is None:
                self._filtered_v = v.copy()
            self._filtered_v[6:] += alpha * (v[6:] - self._filtered_v[6:])
            v = v.copy()
            v[6:] = self._filtered_v[6:]
        return q, v

    def _ground(self, xy: np.ndarray, yaw: float) -> float:
        """The support plane's height under the base for the fall check, fitted again when the base has moved a
        FALL_GROUND_CELL_M cell or turned FALL_GROUND_CELL_M per metre: on every control tick the fit cost seven
        times the flat floor's fall check."""
        key = (*np.round(np.asarray(xy) / FALL_GROUND_CELL_M).astype(int).tolist(), round(yaw / FALL_GROUND_CELL_M))
        if key != self._ground_key:
            self._ground_key, self._ground_m = key, float(self._support.height(xy, yaw))
        return self._ground_m

    def _fallen(self, q: np.ndarray) -> bool:
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        ground = 0.0 if self._support is None else self._ground(q[:2], float(np.arctan2(rot[1, 0], rot[0, 0])))
        height_ok = q[2] - ground > self.config.fall_height_ratio * self.robot.q_nominal[2]
        upright = rot[2, 2] > 0.5  # tilted less than 60 degrees
        return not (height_ok and upright)

    # ------------------------------------------------------------------ run
    def run(self, duration_s: float, commands: CommandSource | None = None,
            events: list[Event] | None = None, progress: Progress | None = None,
            stop: Callable[[], bool] | None = None) -> RunLog:
        """Run for `duration_s` simulated seconds or until the robot falls or `stop()` turns true
        (polled every control tick, e.g. `wbmpc.interrupt.InterruptFlag`; the log then has `interrupted`)."""
        if not duration_s > 0:
            raise ConfigError(f"duration must be positive, got {duration_s}")
        commands = commands or (lambda t_s, q, v: Commands())
        events = sorted(events or [], key=lambda e: e.time_s)
        if self.config.delay_mode == "realtime":
            return self._run_realtime(duration_s, commands, events, progress, stop)
        return self._run_simulated_time(duration_s, commands, events, progress, stop)

    def _expected_delay_s(self, log: RunLog) -> float:
        """The delay the next plan will see (for `MpcConfig.delay_compensation`): the fixed one, else the
        running mean of the measured ones (0 before any)."""
        if self.config.delay_mode == "none":
            return 0.0
        fixed = self.config.fixed_delay_s
        return fixed if fixed is not None else self._delay_mean_s

    def _note_delay(self, delay_s: float) -> None:
        self._delay_mean_s = delay_s if self._delay_mean_s == 0.0 else 0.8 * self._delay_mean_s + 0.2 * delay_s

    def _solve(self, log: RunLog, t_s: float, commands: CommandSource, first: bool = False) -> Solution:
        """One MPC step from the state measured now; `first`: the run's first step, applied at once."""
        q, v = self._measure()
        command = commands(t_s, q, v)
        start, start_cpu = time.perf_counter(), time.thread_time()
        delay_s = 0.0 if first else self._expected_delay_s(log)
        # passed only when there is one: MPC stand-ins (benchmarks' recorders) take (q, v, commands, t)
        extra = {"delay_s": delay_s} if delay_s else {}
        if self.config.touchdown_events:
            from wbmpc.control.touchdown import measured_contacts

            extra["measured_contact"] = measured_contacts(self.plant.contact_forces(), self.robot.mass_kg * 9.81)
        solution = self.mpc.solve(q, v, command, t_s, **extra)
        solution.wall_time_s = time.perf_counter() - start
        solution.cpu_time_s = time.thread_time() - start_cpu
        self._record(log, t_s, command, solution)
        return solution

    def _record(self, log: RunLog, t_s: float, command: Commands, solution: Solution) -> None:
        """Log a plan and tell the solution listeners."""
        log.record_solution(t_s, command, solution)
        for listener in self.solution_listeners:
            listener(t_s, solution)

    def _new_log(self) -> RunLog:
        log = self.log = RunLog(self.log_dir, self.log_chunk_rows)
        log.mpc_rate_hz = self.config.mpc_rate_hz
        log.control_rate_hz = self.config.control_rate_hz
        return log

    def _control_tick(self, log: RunLog, active: Solution, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The torques of this tick and the plant's true configuration (logged)."""
        q, v = self._measure()
        lead = 0.5 / self.config.control_rate_hz if self.config.sample_mid_hold else 0.0
        reference = interpolate(active, t_s + lead)
        self._reference = reference
        q_j = self.robot.joint_positions(q, near=reference.q_des)
        tau = pd_torque(reference, q_j, v[6:], self.kp, self.kd, self.robot.tau_max)
        q_true, v_true = self.plant.state()
        log.record_tick(t_s, q_true, v_true, tau, reference.tau_ff, reference.q_des, self.plant.contact_forces())
        return tau, q_true

    def _motor_driver(self) -> np.ndarray:
        """`motor_law` "continuous": eq. (10) with the last command's references and the joint readings of this
        physics step (a motor driver's own loop between commands)."""
        q, v = self.plant.state()
        q_j = self.robot.joint_positions(q, near=self._reference.q_des)
        return pd_torque(self._reference, q_j, v[6:], self.kp, self.kd, self.robot.tau_max)

    def _start_ticks(self, t0: float) -> float:
        """The joint loop's first tick (at t0, no jitter: the run starts on a command)."""
        self._nominal_tick = t0
        self._reference = None
        return t0

    def _next_tick(self) -> float:
        """When the next command arrives: the next period of the joint loop, late by its jitter."""
        cfg = self.config
        self._nominal_tick += 1.0 / cfg.control_rate_hz
        jitter = self._jitter_rng.uniform(0.0, cfg.joint_loop_jitter_ms) / 1e3 if cfg.joint_loop_jitter_ms else 0.0
        return self._nominal_tick + jitter

    def _low_level(self, log, active, t_s, next_control, tau, t0, duration_s, progress, stop=None):
        """The joint loop (eqs. 9-10) when a command is due: returns (torques for this physics step, next tick, end
        the run). Between commands the torque is held, or re-evaluated with the held references (`motor_law`)."""
        if t_s < next_control - 1e-9:
            if self.config.motor_law == "continuous" and self._reference is not None:
                tau = self._motor_driver()
            return tau, next_control, False
        tau, q_true = self._control_tick(log, active, t_s)
        next_control = self._next_tick()
        if t_s - t0 >= len(log.rss_samples) * RSS_SAMPLE_PERIOD_S - 1e-9:
            log.rss_samples.append((t_s - t0, rss_mb()))
        if self._fallen(q_true):
            log.fell, log.fell_at_s = True, t_s - t0
            return tau, next_control, True
        if progress:
            progress((t_s - t0) / duration_s, log.mpc_recoveries)
        if stop is not None and stop():
            log.interrupted = True
            return tau, next_control, True
        return tau, next_control, False

    def _apply_events(self, events: list[Event], t_s: float, log: RunLog) -> None:
        for event in events:
            if not event.done and t_s >= event.time_s:
                event.action(self.plant)
                event.done = True
                log.events.append((t_s, event.name))

    def _run_simulated_time(self, duration_s, commands, events, progress, stop=None) -> RunLog:
        cfg, plant = self.config, self.plant
        log = self._new_log()
        wall_start = time.perf_counter()
        mpc_period = 1.0 / cfg.mpc_rate_hz
        t0 = plant.time_s
        active = self._solve(log, t0, commands, first=True)
        if not active.success:
            raise RunError(f"the MPC failed on the initial state ({active.stats.status}); check the start pose")
        pending: list[tuple[float, Solution]] = []
        next_mpc, next_control = t0 + mpc_period, self._start_ticks(t0)
        solver_free_at = t0  # with a delay, the single solver is busy until its solution is out
        tau = np.zeros(self.robot.n_joints)
        while plant.time_s - t0 < duration_s - 1e-9:
            t = plant.time_s
            self._apply_events(events, t, log)
            if t >= next_mpc - 1e-9 and t >= solver_free_at - 1e-9:
                solution = self._solve(log, t, commands)
                delay = 0.0 if cfg.delay_mode == "none" else (
                    solution.cpu_time_s if cfg.delay_mode == "measured" else
                    solution.wall_time_s if cfg.delay_mode == "measured-wall" else cfg.fixed_delay_s)
                solver_free_at = t + delay
                self._note_delay(delay)
                if delay > mpc_period:
                    log.late_solutions += 1
                while next_mpc <= t + 1e-9:
                    next_mpc += mpc_period
                if solution.success or solution.held_previous:  # failed: the last plan, shifted
                    log.record_delay(delay * 1e3)
                    pending.append((t + delay, solution))
            while pending and pending[0][0] <= t + 1e-9:
                active = pending.pop(0)[1]
            tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress, stop)
            if fell:
                break
            plant.step(tau)
        log.wall_time_s = time.perf_counter() - wall_start
        log.rss_samples.append((plant.time_s - t0, rss_mb()))
        return log

    def _run_realtime(self, duration_s, commands, events, progress, stop=None) -> RunLog:
        """Simulation paced by the wall clock while the MPC solves in its own process (`SolverProcess`,
        built before the clock starts); each new solve starts at the next MPC tick after the previous one ended."""
        log = self._new_log()
        t0 = self.plant.time_s
        # this process's own first step, before its priority and core change (its MPC's stage pool then has both)
        active = self._solve(log, t0, commands, first=True)
        if not active.success:
            raise RunError(f"the MPC failed on the initial state ({active.stats.status}); check the start pose")
        own_cpus = available_cpus()
        own_nice = os.getpriority(os.PRIO_PROCESS, 0) if hasattr(os, "getpriority") else None
        # the loop's priority first: the solver's helper threads share its core only where the loop preempts them at
        # once (SCHED_FIFO; at nice -10 against their nice 0 the fair scheduler let them delay g1's loop by up to 100 ms)
        log.start_writer()  # its thread at the ordinary policy, on every CPU: the loop never waits for the disk
        log.realtime_priority, log.realtime_competitors = raise_loop_priority(), fifo_competitors()
        session_before = raise_session_priority()  # against other sessions' load too (Linux autogroups)
        log.session_nice = None if session_before is None else min(session_before, REALTIME_NICE)
        plan = log.cpu_plan = cpu_plan(own_cpus, share_loop_core=log.realtime_priority.startswith("fifo"))
        try:
            solver = SolverProcess(self.robot.spec, self.mpc.config, plan, stop)
        except BaseException:
            restore_scheduling(log.realtime_priority, own_nice)
            restore_session_priority(session_before)
            raise
        log.solver_helper_threads, log.solver_scheduling = solver.helper_threads, solver.scheduling
        if plan.loop:
            os.sched_setaffinity(0, plan.loop)
        gc.collect()
        gc.freeze()  # what exists now stays out of the collector's full passes while the clock runs (a 60-100 ms pause)
        try:
            if solver.interrupted:
                log.interrupted = True
                return log
            # the solver process solves the first step too, before the clock: its MPC then warm-starts (a cold
            # step of the anytime SQP ignores its deadline to converge) from the same state as this one's
            q, v = self._measure()
            solver.request(q, v, commands(t0, q, v), t0)
            solver.receive()  # from here on requests and plans go through shared memory
            self._paced_loop(log, solver, active, t0, duration_s, commands, events, progress, stop)
        finally:
            gc.unfreeze()
            if plan.loop:
                os.sched_setaffinity(0, own_cpus)
            restore_scheduling(log.realtime_priority, own_nice)  # back to the caller's policy and priority
            restore_session_priority(session_before)
            solver.close()
            log.realtime_competitors = sorted({*log.realtime_competitors, *fifo_competitors()})  # also at its end
        return log

    def _paced_loop(self, log: RunLog, solver: SolverProcess, active: Solution, t0: float, duration_s, commands,
                    events, progress, stop) -> None:
        """The 500 Hz simulation on the wall clock: a request to the solver process at each free MPC tick,
        its answer taken as soon as it is ready, the last good plan interpolated meanwhile (eqs. 9-10). Each physics
        step's plant state exists before its wall-clock time comes: the loop waits for that time on the answer
        (woken by it), measures the state and builds the request meanwhile, and sends it when the time comes."""
        plant, mpc_period = self.plant, 1.0 / self.config.mpc_rate_hz
        next_mpc, next_control = t0 + mpc_period, self._start_ticks(t0)
        pending = None  # (t, command, wall time sent) of the request being solved; None: the solver is free
        # the transport (shared memory, wake-ups, this loop noticing the answer) measured per step: the
        # solver's budget is the period less it, so that the answer is back before the next MPC tick
        transport_s = REALTIME_TRANSPORT_GUESS_S
        tau = np.zeros(self.robot.n_joints)
        # per joint-loop tick: how long after its wall-clock time it ran (ms), over half a period counted as late
        lateness = log.plant_lateness = StreamingStats(threshold=0.5e3 / self.config.control_rate_hz)
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        clock = _WallClock(wall_start, t0)
        while plant.time_s - t0 < duration_s - 1e-9:
            t = plant.time_s
            self._apply_events(events, t, log)
            answer = None
            if pending is not None:  # waited for until this step's wall-clock time
                answer, transport_s = self._answer(solver, pending, t, clock, transport_s)
                if answer is not None:
                    pending = None
                    active = answer[0] if answer[0].success or answer[0].held_previous else active
            measured = self._measured(solver, t, commands) if pending is None and t >= next_mpc - 1e-9 else None
            lag = clock.at(t) - time.perf_counter()
            if lag > 0:
                time.sleep(lag)
            if t >= next_control - 1e-9:
                lateness.add(max(1e3 * -(clock.at(t) - time.perf_counter()), 0.0))
            if measured is not None:  # the request when its measurement's time comes, the last answer logged after it
                while next_mpc <= t + 1e-9:
                    next_mpc += mpc_period
                pending = self._request(solver, measured, mpc_period - transport_s, clock.at(next_mpc))
            if answer is not None:
                log.mpc_cpu_share = (answer[0].process_cpu_s - solver.cpu_start_s) / max(answer[2][-1] - wall_start, 1e-9)
                self._log_answer(log, *answer)
            tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress, stop)
            if fell:
                break
            plant.step(tau)
        log.wall_time_s = time.perf_counter() - wall_start
        log.rss_samples.append((plant.time_s - t0, rss_mb()))
        log.sim_cpu_share = (time.process_time() - cpu_start) / max(log.wall_time_s, 1e-9)

    def _answer(self, solver: SolverProcess, pending, t_s: float, clock, transport_s: float) -> tuple:
        """The solver process's answer to `pending` if it is ready by plant time `t_s`'s wall-clock time (waiting for
        it until then): ((plan, pending, loop stamps, delay) or None, the updated transport estimate)."""
        timeout = clock.at(t_s) - time.perf_counter()
        if not (solver.wait(timeout) if timeout > 0 else solver.ready()):
            return None, transport_s
        woken = time.perf_counter()
        solution = solver.receive()
        stamps = (clock.at(pending[0]), pending[2], woken, woken, time.perf_counter())  # step_anatomy's loop stamps
        delay, transport_s = self._delay_of(solution, pending, t_s, stamps, transport_s)
        return (solution, pending, stamps, delay), transport_s

    def _measured(self, solver: SolverProcess, t_s: float, commands: CommandSource) -> tuple:
        """The next request's content: the state at plant time `t_s` and its command."""
        if not solver.is_alive():
            raise RunError("the real-time MPC process died (see its error above)")
        q, v = self._measure()
        return t_s, q, v, commands(t_s, q, v)

    def _request(self, solver: SolverProcess, measured: tuple, budget_s: float, next_request_s: float) -> tuple:
        """A plan asked of the solver process from `measured` (`_measured`), with the step's budget (less a margin for
        the transport's jitter) and when the next request is due (perf_counter); returns (t_s, command, wall time
        sent)."""
        t_s, q, v, command = measured
        sent = time.perf_counter()
        solver.request(q, v, command, t_s, self._delay_mean_s, max(budget_s - REALTIME_MARGIN_S, REALTIME_MARGIN_S),
                       next_request_s=next_request_s)
        return t_s, command, sent

    def _delay_of(self, solution: Solution, request, t_s: float, loop_stamps, transport_s: float) -> tuple:
        """The delay the plant sees of a plan from the solver process (from the measurement to the plan's first physics
        step, transport included; `loop_stamps`: the loop's measured, sent, woken, noticed, taken), noted for the
        delay compensation, and the updated transport estimate."""
        delay = max(t_s - request[0], loop_stamps[-1] - loop_stamps[0])  # plant time, or wall time if the loop ran late
        self._note_delay(delay)
        return delay, 0.8 * transport_s + 0.2 * max(delay - solution.wall_time_s, 0.0)

    def _log_answer(self, log: RunLog, solution: Solution, request, loop_stamps, delay: float) -> None:
        """Log a plan from the solver process with its delay and where it went (`step_anatomy.segments`)."""
        self._record(log, request[0], request[1], solution)
        log.record_delay(delay * 1e3)
        if solution.stamps is not None:
            log.record_anatomy(segments(solution.stamps, solution.stats.solve_time_s, loop_stamps, delay))
        if delay > 1.0 / self.config.mpc_rate_hz:
            log.late_solutions += 1


@dataclass(frozen=True)
class _WallClock:
    """The real-time loop's wall clock (time.perf_counter) of plant times: `at(t_s)`."""

    wall_start_s: float
    t0_s: float

    def at(self, t_s: float) -> float:
        return self.wall_start_s + (t_s - self.t0_s)


REALTIME_TRANSPORT_GUESS_S = 1e-3  # the transport's first guess, before one was measured
REALTIME_MARGIN_S = 0.5e-3  # kept free of the budget for the jitter of the transport
