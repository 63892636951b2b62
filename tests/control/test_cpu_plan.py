"""Where the real-time run's threads go (`solver_process.cpu_plan`, `place_helper_threads`, `raise_solver_thread`):
one core for the plant loop, the others for the solver; on two CPUs the solver's helper threads (its stage pool) take
the loop's core at the loop's FIFO priority (below it where FIFO is refused) and its main thread its own core at FIFO.
The placement is checked on real threads of a child process, read back from the kernel."""

import multiprocessing
import os
import threading

import pytest

from wbmpc.control.solver_process import (
    HELPER_FIFO_PRIORITY,
    HELPER_NICE,
    SOLVER_FIFO_PRIORITY,
    CpuPlan,
    cpu_plan,
    cpu_split,
    helper_priority,
    place_helper_threads,
    raise_solver_thread,
    thread_ids,
)


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
    fifo = os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
    queue.put((placed == others >= 1, set(os.sched_getaffinity(tid)), start_nice, os.getpriority(os.PRIO_PROCESS, tid),
               os.getpriority(os.PRIO_PROCESS, main),
               set(os.sched_getaffinity(0)) == all_cpus, tid in thread_ids() and main in thread_ids(),
               os.sched_getparam(tid).sched_priority if fifo else None, helper_priority(main),
               os.sched_getscheduler(main) == os.SCHED_OTHER))
    done.set()
    helper.join()


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task"),
                    reason="thread affinity is Linux's")
def test_helper_threads_are_pinned_and_share_the_loops_priority_the_main_thread_is_not_moved():
    cpus = sorted(os.sched_getaffinity(0))
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    child = context.Process(target=_placement_child, args=([cpus[0]], queue))
    child.start()
    (placed, helper_cpus, start_nice, helper_nice, main_nice, main_unchanged, listed, helper_fifo, reported,
     main_ordinary) = queue.get(timeout=60)
    child.join(timeout=60)
    assert placed and listed
    assert helper_cpus == {cpus[0]}
    assert main_unchanged and main_ordinary and main_nice == start_nice  # the main thread keeps its place and priority
    # sharing the loop's core (loop == helpers here) the helper runs at the loop's FIFO priority where permitted (root,
    # CAP_SYS_NICE), else below the loop: nice HELPER_NICE (0) or its own if that is lower already
    if helper_fifo is not None:
        assert helper_fifo == HELPER_FIFO_PRIORITY and reported == f"fifo {HELPER_FIFO_PRIORITY}"
    else:
        assert helper_nice == max(HELPER_NICE, start_nice) and reported == f"nice {helper_nice}"


def _solver_thread_child(plan, queue):
    os.sched_setaffinity(0, plan.solver)
    granted = raise_solver_thread(plan)
    fifo = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
    queue.put((granted, fifo, os.sched_getparam(0).sched_priority, _fifo_permitted()))


def _fifo_permitted() -> bool:
    """Whether this process may take SCHED_FIFO (tried on a thread of its own, which then ends)."""
    result = []

    def attempt():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            result.append(True)
        except OSError:
            result.append(False)

    thread = threading.Thread(target=attempt)
    thread.start()
    thread.join()
    return result[0]


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs two CPUs and Linux's scheduling policies")
@pytest.mark.parametrize("share", [True, False])
def test_the_solver_thread_takes_fifo_only_on_a_core_of_its_own_beside_a_fifo_loop(share):
    """Two CPUs with a FIFO loop: the solver's main thread at SOLVER_FIFO_PRIORITY on its core where permitted (what
    it reports is what the kernel says); a loop without FIFO (one core each): the main thread keeps the ordinary
    policy."""
    plan = cpu_plan(sorted(os.sched_getaffinity(0))[:2], share_loop_core=share)
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    child = context.Process(target=_solver_thread_child, args=(plan, queue))
    child.start()
    granted, fifo, priority, permitted = queue.get(timeout=60)
    child.join(timeout=60)
    if share and permitted:
        assert fifo and priority == SOLVER_FIFO_PRIORITY and granted == f"fifo {SOLVER_FIFO_PRIORITY}"
    else:
        assert not fifo and granted.startswith("nice ")


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


def _fifo_child(ready, done):
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        ready.put(True)
    except OSError:
        ready.put(False)
        return
    done.wait(60)


@pytest.mark.skipif(not os.path.isdir("/proc/self/task") or not hasattr(os, "sched_setscheduler"),
                    reason="reads Linux's /proc")
def test_other_processes_at_fifo_are_found_and_kernel_threads_are_not():
    """`fifo_competitors`: another process with a FIFO thread is listed while it runs, not after; kernel threads (no
    command line: migration, irq threads at FIFO) never are."""
    from wbmpc.control.solver_process import fifo_competitors

    context = multiprocessing.get_context("spawn")
    ready, done = context.Queue(), context.Event()
    child = context.Process(target=_fifo_child, args=(ready, done))
    child.start()
    permitted = ready.get(timeout=60)
    try:
        found = fifo_competitors()
    finally:
        done.set()
        child.join(timeout=60)
    if not permitted:
        pytest.skip("SCHED_FIFO is not permitted here")
    assert child.pid in found and os.getpid() not in found
    assert child.pid not in fifo_competitors()
    for pid in found:
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                assert f.read(1), f"kernel thread {pid} listed"
        except FileNotFoundError:  # ended since (the child, or another session's process)
            continue
