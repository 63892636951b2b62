"""The real-time loop's shared-memory channel carries requests and plans unchanged (both ends in one
process here; tests/control/test_loop.py and tests/solvers/test_anytime.py run it across processes)."""

import multiprocessing
import os
import signal as signal_module
import threading
import time

import numpy as np
import pytest

from wbmpc.control import Commands
from wbmpc.control.realtime_channel import ChannelLayout, SharedChannel, Signal, command_from_row, command_row
from wbmpc.control.solution import Solution
from wbmpc.solvers.nlp import SolverStats


def _solution(rng, status="Deadline", held=False) -> Solution:
    n, nq, nv, nj = 7, 19, 18, 12
    stats = SolverStats(status, True, 9, 0.004, 1e-7, 215.1, cpu_time_s=0.0039,
                        details={"sqp_iterations": 2, "primal_residual": 1e-7, "dual_residual": None, "late": False})
    solution = Solution(t_s=1.25, node_times_s=np.linspace(0, 0.5, n), q=rng.normal(size=(n, nq)),
                        v=rng.normal(size=(n, nv)), a=rng.normal(size=(n - 1, nv)), forces=rng.normal(size=(n - 1, 12)),
                        tau=rng.normal(size=(3, nj)), contact=rng.random((n, 4)) > 0.5, stats=stats, success=True)
    solution.wall_time_s, solution.process_cpu_s = 0.0051, 12.5
    if held:
        solution.held_previous = True
    return solution


def test_requests_and_plans_cross_unchanged():
    rng = np.random.default_rng(0)
    first = _solution(rng)
    command = Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0]), ee_force_n=np.array([0.0, 0.0, -5.0]))
    layout = ChannelLayout.from_solution(first, len(command_row(command)))
    events = SharedChannel.events(multiprocessing.get_context("spawn"))
    sim = SharedChannel.create(layout, events)
    solver = SharedChannel.attach(*sim.handle, events)
    try:
        q, v = rng.normal(size=19), rng.normal(size=18)
        sim.send_request(q, v, command_row(command), 2.5, 0.006, 0.0095)
        assert events[0].is_set() and not events[1].is_set()
        q2, v2, row, t, delay_s, budget_s, inertial = solver.receive_request()
        assert np.array_equal(q2, q) and np.array_equal(v2, v) and (t, delay_s, budget_s) == (2.5, 0.006, 0.0095)
        assert inertial is None  # nothing identified: the MPC keeps its parameters
        sim.send_request(q, v, command_row(command), 2.5, 0.006, None, np.array([-0.02, 0.0, 0.001, 1.5, 0.0]))
        *_, budget_s, inertial = solver.receive_request()
        assert budget_s is None and inertial.tolist() == [-0.02, 0.0, 0.001, 1.5, 0.0]
        assert np.array_equal(command_from_row(row).ee_force_n, command.ee_force_n)
        plan = _solution(rng, status="ipopt: Solve_Succeeded (recovery after Deadline)", held=True)
        plan.stamps = np.r_[10.0, np.nan, np.arange(11.0, 17.0)]  # received, (answered), the MPC's
        before = time.perf_counter()
        solver.send_solution(plan)
        assert events[1].is_set()
        got = sim.receive_solution()
        for name in ("node_times_s", "q", "v", "a", "forces", "tau", "contact", "q_joints"):
            np.testing.assert_array_equal(getattr(got, name), getattr(plan, name))
        assert got.contact.dtype == bool and got.t_s == plan.t_s and got.success and got.held_previous
        assert got.stats.status == plan.stats.status and got.stats.iterations == 9
        assert got.stats.details == {"sqp_iterations": 2, "primal_residual": 1e-7, "late": 0.0}
        assert (got.wall_time_s, got.process_cpu_s) == (0.0051, 12.5)
        # the step's stamps cross too, the channel's own `answered` stamped as it wrote the plan
        assert got.stamps[0] == 10.0 and got.stamps[2:].tolist() == list(range(11, 17))
        assert before <= got.stamps[1] <= time.perf_counter()
        sim.send_stop()
        assert solver.receive_request() is None
    finally:
        solver.close()
        sim.close()


def _waiting_child(signal, started, queue):
    started.set()
    queue.put(signal.wait(120))


@pytest.mark.skipif(not hasattr(signal_module, "SIGSTOP"), reason="needs SIGSTOP/SIGCONT")
def test_a_signal_is_posted_while_its_waiter_cannot_run():
    """The plant loop's request must not wait for the solver process to be scheduled: `Signal.set` returns while the
    process sleeping in `wait` is stopped (multiprocessing.Event.set would block until it runs again), and the
    waiter takes the post once it continues."""
    context = multiprocessing.get_context("spawn")
    signal, started, queue = Signal(context), context.Event(), context.Queue()
    child = context.Process(target=_waiting_child, args=(signal, started, queue))
    child.start()
    try:
        assert started.wait(60)
        time.sleep(0.2)  # let it reach the semaphore (set() must return whether it sleeps there already or not)
        os.kill(child.pid, signal_module.SIGSTOP)
        setter = threading.Thread(target=signal.set, daemon=True)
        setter.start()
        setter.join(30)
        returned = not setter.is_alive()
        os.kill(child.pid, signal_module.SIGCONT)
        assert returned, "set() waited for the stopped waiter"
        assert queue.get(timeout=60) is True
    finally:
        os.kill(child.pid, signal_module.SIGCONT)
        child.join(60)


@pytest.mark.parametrize("due_in_s", [60.0, -1.0, None])
def test_the_solver_side_takes_a_request_whenever_it_comes(due_in_s):
    """The solver process waits for the next request asleep until shortly before the time the last request said it
    is due, awake (polling) around it: a request that comes long before that time (60 s), or after it (a late answer's
    next request), or without a time is taken all the same, and `idle_s` says how long until the next is due."""
    rng = np.random.default_rng(1)
    layout = ChannelLayout.from_solution(_solution(rng), len(command_row(Commands())))
    events = SharedChannel.events(multiprocessing.get_context("spawn"))
    sim = SharedChannel.create(layout, events)
    solver = SharedChannel.attach(*sim.handle, events)
    try:
        q, v, row = rng.normal(size=19), rng.normal(size=18), command_row(Commands())
        due = None if due_in_s is None else time.perf_counter() + due_in_s
        sim.send_request(q, v, row, 1.0, 0.01, None, next_request_s=due)
        assert solver.receive_request()[3] == 1.0
        assert (solver.idle_s() > 0) == (due_in_s == 60.0)  # the next request is due in a minute, or now, or unknown
        later = threading.Timer(0.05, sim.send_request, args=(q, v, row, 2.0, 0.01, None))
        later.start()
        assert solver.receive_request()[3] == 2.0  # taken when it came, not at the minute
        later.join()
    finally:
        solver.close()
        sim.close()
