"""Deployment pipeline: eq. 9 interpolation, eq. 10 PD, a short closed-loop run and `wbmpc run`."""

import json
import os

import numpy as np
import pytest

from wbmpc.cli import main
from wbmpc.control import MPC, MpcConfig
from wbmpc.control.interpolator import JointReference, interpolate, pd_torque
from wbmpc.control.loop import ClosedLoop, Event, LoopConfig
from wbmpc.control.solution import Solution
from wbmpc.control.solver_process import session_group_nice
from wbmpc.control.step_anatomy import SEGMENTS
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.sim import make_plant
from wbmpc.solvers.nlp import SolverStats

SMALL = OcpConfig(grid=TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.06))


def _synthetic_solution(nq=9, nv=8, nj=2) -> Solution:
    rng = np.random.default_rng(0)
    n = 4
    q = rng.normal(size=(n + 1, nq))
    return Solution(t_s=1.0, node_times_s=np.array([0.0, 0.01, 0.03, 0.06, 0.1]), q=q, v=rng.normal(size=(n + 1, nv)),
                    a=rng.normal(size=(n, nv)), forces=np.zeros((n, 3)), tau=rng.normal(size=(3, nj)),
                    contact=np.ones((n + 1, 1)), stats=SolverStats("ok", True, 1, 0.0, 0.0, 0.0), success=True)


def test_interpolation_follows_eq_9():
    sol = _synthetic_solution()
    ref = interpolate(sol, 1.004)  # 4 ms into the first 10 ms step
    np.testing.assert_allclose(ref.tau_ff, sol.tau[0] + (sol.tau[1] - sol.tau[0]) * 0.4)
    np.testing.assert_allclose(ref.q_des, sol.q[0, 7:] + sol.v[0, 6:] * 0.004)
    np.testing.assert_allclose(ref.v_des, sol.v[0, 6:] + sol.a[0, 6:] * 0.004)
    assert ref.segment == 0


def test_late_solution_is_interpolated_between_t1_and_t2():
    sol = _synthetic_solution()
    ref = interpolate(sol, 1.015)  # t1 = 1.01 passed, t2 = 1.03
    np.testing.assert_allclose(ref.tau_ff, sol.tau[1] + (sol.tau[2] - sol.tau[1]) * 0.25)
    np.testing.assert_allclose(ref.q_des, sol.q[1, 7:] + sol.v[1, 6:] * 0.005)
    np.testing.assert_allclose(ref.v_des, sol.v[1, 6:] + sol.a[1, 6:] * 0.005)
    assert ref.segment == 1
    held = interpolate(sol, 1.5)  # far beyond t2: held at t2, never extrapolated
    np.testing.assert_allclose(held.tau_ff, sol.tau[2])


def test_pd_adds_feedback_and_clamps_to_limits():
    ref = JointReference(tau_ff=np.array([10.0, -10.0]), q_des=np.array([0.1, 0.0]), v_des=np.zeros(2), segment=0)
    tau = pd_torque(ref, q_j=np.zeros(2), v_j=np.array([0.0, 1.0]), kp=np.array([100.0, 0.0]),
                    kd=np.array([0.0, 5.0]), tau_max=np.array([15.0, 100.0]))
    np.testing.assert_allclose(tau, [15.0, -15.0])  # 10 + 100*0.1 = 20 clamped to 15; -10 - 5*1


def test_short_trot_stays_up_in_mujoco(b1z1):
    mpc = MPC(b1z1, MpcConfig(ocp=SMALL, gait="trot"))
    plant = make_plant("mujoco", b1z1)
    plant.reset(b1z1.q_nominal, np.zeros(b1z1.nv))
    log = ClosedLoop(mpc, plant, LoopConfig(delay_mode="none")).run(0.8, events=[Event(0.4, lambda p: None, name="tap")])
    a = log.arrays()
    assert not log.fell
    assert [name for _, name in log.events] == ["tap"] and abs(log.events[0][0] - 0.4) <= 1e-3  # logged for the plots
    assert log.mpc_failures == 0
    assert a["q"][:, 2].min() > 0.85 * b1z1.q_nominal[2]
    assert np.all(np.abs(a["tau"]) <= b1z1.tau_max + 1e-9)
    # the planned swing legs really lift: some foot was in the air (zero contact force) at some time
    assert (np.linalg.norm(a["contact_forces"], axis=2) < 1e-6).any()


def test_fixed_delay_applies_solutions_late(b1z1):
    mpc = MPC(b1z1, MpcConfig(ocp=SMALL, gait="stand"))
    plant = make_plant("pinocchio", b1z1)
    plant.reset(b1z1.q_nominal, np.zeros(b1z1.nv))
    log = ClosedLoop(mpc, plant, LoopConfig(delay_ms=20.0)).run(0.1)
    assert all(d == pytest.approx(20.0) for d in log.delay_ms)
    assert log.late_solutions > 0  # 20 ms > the 12.5 ms period: the single solver skips ticks
    assert not log.fell


def test_bad_loop_inputs():
    with pytest.raises(ConfigError, match="delay_mode must be one of none, measured, measured-wall, fixed, realtime; got 'soon'"):
        LoopConfig(delay_mode="soon")
    with pytest.raises(ConfigError, match=">= 0 ms"):
        LoopConfig(delay_ms=-5.0)
    for delay_ms in (float("inf"), float("nan"), 1e9):
        with pytest.raises(ConfigError, match="delay_ms must be"):
            LoopConfig(delay_ms=delay_ms)
    with pytest.raises(ConfigError, match="needs its length"):
        LoopConfig(delay_mode="fixed")
    with pytest.raises(ConfigError, match="does not go with --delay-mode realtime"):
        LoopConfig(delay_mode="realtime", delay_ms=5.0)
    assert LoopConfig(delay_ms=5.0).delay_mode == "fixed" and LoopConfig(delay_ms=5.0).fixed_delay_s == 0.005


def _refuse_non_json(token):
    raise ValueError(f"{token} is not JSON")


def test_run_command_writes_metrics_with_the_contract_keys(tmp_path, capsys):
    code = main(["run", "stand", "--duration", "0.15", "--nodes", "6", "--out", str(tmp_path), "--json"])
    assert code == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text(), parse_constant=_refuse_non_json)
    assert metrics["interrupted"] is False and metrics["mpc_recoveries"] == 0
    assert json.loads((tmp_path / ".wbmpc-outputs.json").read_text())["files"]  # what a later run may replace
    for key in ("scenario", "fell", "duration_s", "base_drift_cm_s", "base_vel_rmse", "ee_pos_rmse_m",
                "ee_force_err_rel", "max_torque_ratio", "solve_ms", "mpc_failures", "mpc_recoveries",
                "mpc_rate_hz", "late_solution_share"):
        assert key in metrics
    assert set(metrics["solve_ms"]) >= {"mean", "std", "max"}
    assert json.loads(capsys.readouterr().out)["scenario"] == "stand"
    assert (tmp_path / "replay.html").stat().st_size > 1000
    assert len(list(tmp_path.glob("*.png"))) >= 4


@pytest.mark.parametrize("argv, message", [
    (["run", "moonwalk"], "unknown scenario 'moonwalk'"),
    (["run", "stand", "--duration", "0"], "--duration must be > 0 s"),
    (["run", "stand", "--out", "/proc/wbmpc_cannot_write"], "--out directory /proc/wbmpc_cannot_write cannot be created or written"),
    (["run", "arm-track", "--robot", "a1"], "needs a robot with an arm"),
])
def test_run_command_bad_input_exits_2(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_settled_drift_leaves_out_the_start_transient():
    """`base_drift_settled_cm_s` measures from SETTLE_S on: a 3 cm shift in the first 0.5 s followed by
    1 cm/s from 2 s on reads 1.0 cm/s there, 1.17 cm/s over the whole run."""
    from wbmpc.control import Commands
    from wbmpc.control.run_log import RunLog
    from wbmpc.robots import load_robot
    from wbmpc.scenarios.metrics import common_metrics

    robot = load_robot("go2")
    t = np.arange(0.0, 6.0, 0.002)
    q = np.tile(robot.q_nominal, (t.size, 1))
    q[:, 0] += np.where(t < 0.5, 0.06 * t, 0.03) + 0.01 * np.maximum(t - 2.0, 0.0)
    log = RunLog.from_columns(t, q, np.zeros((t.size, robot.nv)), np.zeros((t.size, robot.n_joints)), mpc_t=[0.0],
                              commands=[Commands()], solve_ms=[1.0], iterations=[1], success=[True], chunk_rows=700)
    m = common_metrics(robot, log, "synthetic")
    assert m["base_drift_settled_from_s"] == pytest.approx(2.0)
    assert m["base_drift_settled_cm_s"] == pytest.approx(1.0, rel=1e-3)
    assert m["base_drift_cm_s"] == pytest.approx(100 * 0.07 / t[-1], rel=1e-3)


class _SleepyMpc:
    """Wraps an MPC: every step also waits 40 ms without using the CPU (another process's load)."""

    def __init__(self, mpc):
        self.mpc, self.robot, self.config = mpc, mpc.robot, mpc.config

    def solve(self, *args, **kwargs):
        import time

        time.sleep(0.04)
        return self.mpc.solve(*args, **kwargs)


@pytest.mark.parametrize("delay, waits_count", [("measured", False), ("measured-wall", True)])
def test_measured_delay_counts_cpu_time_not_waiting(delay, waits_count):
    from wbmpc.robots import load_robot

    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=OcpConfig(grid=TimeGrid(n_intervals=4, dt_first_s=0.01, dt_last_s=0.05)),
                               gait="stand"))
    plant = make_plant("pinocchio", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    log = ClosedLoop(_SleepyMpc(mpc), plant, LoopConfig(delay_mode=delay)).run(0.05)
    assert log.delay_ms, "no solution applied"
    assert (min(log.delay_ms) >= 40.0) == waits_count, log.delay_ms


def test_recovered_and_failed_steps_are_counted_apart():
    from dataclasses import replace

    from wbmpc.control import Commands
    from wbmpc.control.run_log import RunLog

    log = RunLog()
    for status, ok in [("Solve_Succeeded", True),
                       ("Solve_Succeeded (recovery after Line_Search_Failed; fatrop mu_init 0.1: Line_Search_Failed)", True),
                       ("Maximum_Iterations_Exceeded (recovery after Line_Search_Failed)", False)]:
        solution = replace(_synthetic_solution(), stats=SolverStats(status, ok, 5, 0.01, 0.0, 0.0), success=ok)
        log.record_solution(0.0, Commands(), solution)
    assert (log.mpc_recoveries, log.mpc_failures) == (1, 1)


def _priority_child(queue):
    from wbmpc.control.solver_process import raise_priority

    granted = raise_priority()
    queue.put((granted, os.getpriority(os.PRIO_PROCESS, 0)))


def test_realtime_processes_ask_for_a_higher_priority_and_report_what_they_got():
    """Granted (root / CAP_SYS_NICE): the process runs at nice -10 and says so; refused: "default" and
    its priority is unchanged. Run in a child so the test process keeps its own priority."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    child = context.Process(target=_priority_child, args=(queue,))
    child.start()
    granted, nice = queue.get(timeout=60)
    child.join(timeout=60)
    if granted == "default":
        assert nice == os.getpriority(os.PRIO_PROCESS, 0)
    else:
        assert granted == f"nice {nice}" and nice <= -10


def test_realtime_loop_solves_in_its_own_process_and_measures_itself():
    """`--delay-mode realtime` on a small problem: the solver process answers, every answer is logged with its
    wall time as the delay, late ones are counted, the two processes' CPU shares are measured; the robot
    (go2, 6 nodes, standing) stays up. The run ends after a number of answers (however long a loaded machine
    takes to give them), not after a wall-clock time."""
    from wbmpc.robots import load_robot

    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.02, dt_last_s=0.08)),
                               gait="stand"))
    plant = make_plant("pinocchio", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    loop = ClosedLoop(mpc, plant, LoopConfig(delay_mode="realtime"))
    answers = 6
    group = session_group_nice()
    log = loop.run(60.0, stop=lambda: loop.log is not None and loop.log.n_steps >= answers)
    assert not log.fell and log.interrupted  # stopped by the count, within the minute
    assert len(log.solve_ms) >= answers
    assert len(log.delay_ms) == len(log.solve_ms) - 1  # all but the first (solved before the clock starts)
    assert 0 <= log.late_solutions <= len(log.delay_ms)
    assert log.late_solutions == sum(d > 1e3 / 80 for d in log.delay_ms)
    # where each plan's delay went (step_anatomy.py): one row per plan taken, stamps in the order the step ran them
    # (no segment negative), the segments adding up to the plan's delay, the solve's being the solver's own
    anatomy = log.anatomy()
    assert anatomy.shape == (len(log.delay_ms), len(SEGMENTS)) and np.isfinite(anatomy).all()
    assert (anatomy >= -1e-9).all(), anatomy.min(axis=0)
    np.testing.assert_allclose(anatomy.sum(axis=1), log.delay_ms, rtol=0, atol=1e-9)
    np.testing.assert_allclose(anatomy[:, SEGMENTS.index("solve")], log.solve_ms[1:], rtol=0, atol=1e-9)
    assert 0 < log.sim_cpu_share <= 1.05 and 0 < log.mpc_cpu_share <= 1.05
    assert log.realtime_priority is not None
    assert 0 < log.wall_time_s < 60.0
    # the plant's own lateness: one figure per joint-loop tick, never negative; the plan's CPUs are this process's
    late = log.plant_lateness
    assert late.count == len(log.t) and late.min >= 0 and late.max >= late.percentile(99) >= 0
    cpus = set(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else set()
    assert log.cpu_plan.loop | log.cpu_plan.solver == (cpus if len(cpus) >= 2 else set())
    if hasattr(os, "sched_getscheduler"):  # the loop's real-time policy and core are given back after the run
        assert os.sched_getscheduler(0) == os.SCHED_OTHER and set(os.sched_getaffinity(0)) == cpus
    assert session_group_nice() == group  # the session's group given back too (Linux autogroups)
    assert log.session_nice is None or log.session_nice <= min(group, -10)  # None: no autogroups (or not permitted)
