"""Where the real-time run's threads go (`solver_process.cpu_plan`, `place_helper_threads`): one core for the plant
loop, the others for the solver; on two CPUs the solver's helper threads (its stage pool) take the loop's core below
the loop's priority. The placement is checked on real threads of a child process, read back from the kernel."""

import multiprocessing
import os
import threading

import pytest

from wbmpc.control.solver_process import HELPER_NICE, CpuPlan, cpu_plan, cpu_split, place_helper_threads, thread_ids


@pytest.mark.parametrize("cpus", [[], [3]])
def test_one_cpu_or_none_pins_nothing(cpus):
    plan = cpu_plan(cpus)
    assert plan == CpuPlan() and not plan.shares_loop_core and plan.solver_process == frozenset()


def test_two_cpus_give_the_helpers_the_loops_core():
    plan = cpu_plan([5, 2])
    assert (plan.loop, plan.solver, plan.helpers) == ({2}, {5}, {2})
    assert plan.shares_loop_core and plan.solver_process == {2, 5}  # the pool is sized from both while it is built
    alone = cpu_plan([5, 2], share_loop_core=False)  # the loop could not get a higher priority than the helpers
    assert (alone.loop, alone.solver, alone.helpers) == ({2}, {5}, {5}) and not alone.shares_loop_core
    assert alone.solver_process == {5}


def test_four_cpus_keep_the_helpers_on_the_solvers_cores():
    for share in (True, False):
        plan = cpu_plan([0, 1, 2, 3], share_loop_core=share)
        assert (plan.loop, plan.solver, plan.helpers) == ({0}, {1, 2, 3}, {1, 2, 3})
        assert not plan.shares_loop_core


def test_cpu_split_keeps_one_core_each():
    loop, solver = cpu_split()
    cpus = set(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else set()
    if len(cpus) < 2:
        assert (loop, solver) == (set(), set())
    else:
        assert len(loop) == 1 and loop | solver == cpus and not loop & solver


def _placement_child(helpers, queue):
    """A process with one extra native thread: place it by a plan, report what the kernel says."""
    try:  # threads started from here inherit this nice value: -5 where permitted (root, CAP_SYS_NICE), else 5
        os.setpriority(os.PRIO_PROCESS, 0, -5)
    except OSError:
        os.setpriority(os.PRIO_PROCESS, 0, 5)
    start_nice = os.getpriority(os.PRIO_PROCESS, 0)
    started, done = threading.Event(), threading.Event()
    helper = threading.Thread(target=lambda: (started.set(), done.wait(60)))
    helper.start()
    started.wait(60)
    main = threading.get_native_id()
    all_cpus = set(os.sched_getaffinity(0))
    plan = CpuPlan(loop=frozenset(helpers), solver=frozenset(all_cpus - set(helpers)) or frozenset(helpers),
                   helpers=frozenset(helpers))
    others = len(thread_ids()) - 1  # the helper and any the libraries started (BLAS): all placed
    placed = place_helper_threads(plan, main)
    tid = helper.native_id
    queue.put((placed == others >= 1, set(os.sched_getaffinity(tid)), start_nice, os.getpriority(os.PRIO_PROCESS, tid),
               os.getpriority(os.PRIO_PROCESS, main),
               set(os.sched_getaffinity(0)) == all_cpus, tid in thread_ids() and main in thread_ids()))
    done.set()
    helper.join()


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task"),
                    reason="thread affinity is Linux's")
def test_helper_threads_are_pinned_and_lowered_the_main_thread_is_not():
    cpus = sorted(os.sched_getaffinity(0))
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    child = context.Process(target=_placement_child, args=([cpus[0]], queue))
    child.start()
    placed, helper_cpus, start_nice, helper_nice, main_nice, main_unchanged, listed = queue.get(timeout=60)
    child.join(timeout=60)
    assert placed and listed
    assert helper_cpus == {cpus[0]}
    assert main_unchanged
    # sharing the loop's core (loop == helpers here) the helper runs below the loop: nice HELPER_NICE (0) or its own
    # if that is lower already; the main thread keeps its priority
    assert helper_nice == max(HELPER_NICE, start_nice) and main_nice == start_nice


def test_the_session_group_is_raised_and_restored(tmp_path):
    """Linux autogroups (one scheduling group per session, a process's nice weighing only inside it): the run's group
    goes to nice -10 and back; a group already higher is left; no autogroup file or an empty one, nothing done."""
    from wbmpc.control.solver_process import (
        REALTIME_NICE,
        raise_session_priority,
        restore_session_priority,
        session_group_nice,
    )

    group = tmp_path / "autogroup"
    group.write_text("/autogroup-152 nice 0\n")
    before = raise_session_priority(path=str(group))
    assert before == 0 and group.read_text() == str(REALTIME_NICE)
    restore_session_priority(before, path=str(group))
    assert group.read_text() == "0"
    group.write_text("/autogroup-152 nice -15\n")
    assert raise_session_priority(path=str(group)) == -15 and group.read_text().endswith("nice -15\n")
    assert raise_session_priority(path=str(tmp_path / "none")) is None
    empty = tmp_path / "empty"  # autogroups disabled (CI containers): the file is there but empty
    empty.write_text("")
    assert raise_session_priority(path=str(empty)) is None and session_group_nice(str(empty)) is None
    assert empty.read_text() == ""
    restore_session_priority(None, path=str(group))  # nothing changed: nothing to give back
    assert group.read_text().endswith("nice -15\n")
