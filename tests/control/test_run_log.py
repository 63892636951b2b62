"""Long runs in bounded memory: `ChunkedTable`, the chunked `RunLog`, metrics streamed over its chunks."""

import threading
import tracemalloc

import numpy as np
import pinocchio as pin
import pytest

import wbmpc.chunked_table as chunked_table
from wbmpc.chunked_table import ChunkedTable, ChunkWriter
from wbmpc.control import MPC, MpcConfig
from wbmpc.control.commands import Commands
from wbmpc.control.loop import ClosedLoop, LoopConfig
from wbmpc.control.realtime_channel import COMMAND_WIDTH, command_from_row, command_row
from wbmpc.control.run_log import RunLog
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.scenarios.metrics import SETTLE_S, common_metrics, stability_metrics
from wbmpc.sim import make_plant


def test_table_reads_back_exactly_what_was_written_across_chunks(tmp_path):
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(1003, 4, 3))
    table = ChunkedTable({"t": ((), float), "x": ((4, 3), float), "k": ((), np.int64), "ok": ((), bool)},
                         chunk_rows=100, spill_dir=tmp_path)
    for i, row in enumerate(rows):
        table.append({"t": 0.002 * i, "x": row, "k": i, "ok": i % 3 == 0})
    assert len(table) == 1003 and table.spilled_chunks == 10
    np.testing.assert_array_equal(table.column("x"), rows)  # bit for bit
    np.testing.assert_array_equal(table.column("k"), np.arange(1003))
    np.testing.assert_array_equal(table.column("ok"), np.arange(1003) % 3 == 0)
    for every in (1, 7, 100, 2000):
        np.testing.assert_array_equal(table.column("x", every=every), rows[::every])
    chunks = list(table.iter_chunks(("k",)))
    assert [len(c["k"]) for c in chunks] == [100] * 10 + [3]
    np.testing.assert_array_equal(table.last("x"), rows[-1])
    np.testing.assert_array_equal(table.first("x"), rows[0])
    folder = table.spill_dir
    assert folder.parent == tmp_path and len(list(folder.iterdir())) == 40
    table.close()
    assert not folder.exists() and len(table) == 0
    with pytest.raises(ConfigError, match="no column"):
        table.column("y")


def test_a_writer_thread_spills_the_same_chunks_off_the_appending_thread(tmp_path, monkeypatch):
    """The full chunks are written by the writer's thread, never by the one appending rows (a real-time loop), and
    the files and columns are the same, bit for bit, as when `append` writes them itself."""
    writers = []
    write = chunked_table._write_chunk

    def recording_write(*args):
        writers.append(threading.current_thread())
        write(*args)

    monkeypatch.setattr(chunked_table, "_write_chunk", recording_write)
    rng = np.random.default_rng(1)
    rows = rng.normal(size=(1050, 5))
    columns = {"x": ((5,), float), "k": ((), np.int64)}
    tables = [ChunkedTable(columns, 100, tmp_path / "inline", "t"),
              ChunkedTable(columns, 100, tmp_path / "thread", "t", ChunkWriter())]
    for table in tables:
        for i, row in enumerate(rows):
            table.append({"x": row, "k": i})
    inline, threaded = tables
    np.testing.assert_array_equal(threaded.column("x"), rows)  # a reader waits for the chunk in flight
    assert len(writers) == 20 and writers[:10] == [threading.current_thread()] * 10
    assert threading.current_thread() not in writers[10:]
    assert threaded.spilled_chunks == inline.spilled_chunks == 10
    for path in sorted(inline.spill_dir.iterdir()):
        assert (threaded.spill_dir / path.name).read_bytes() == path.read_bytes()
    np.testing.assert_array_equal(threaded.last("x"), rows[-1])
    assert threaded.nbytes_in_memory == 2 * inline.nbytes_in_memory  # the chunk filling and the one being written
    folder = threaded.spill_dir
    threaded.close()
    assert not folder.exists()


def test_spilled_chunks_go_with_the_table():
    table = ChunkedTable({"x": ((2,), float)}, chunk_rows=2)
    for i in range(5):
        table.append({"x": [i, i]})
    folder = table.spill_dir
    assert folder.exists()
    del table
    assert not folder.exists()


def _go2_tick(robot, k):
    q = robot.q_nominal.copy()
    q[0] = 1e-4 * k
    return (0.002 * k, q, np.full(robot.nv, 0.01 * k), np.full(robot.n_joints, float(k)),
            np.zeros(robot.n_joints), q[7:], np.full((len(robot.feet), 3), float(k)))


def test_run_log_memory_stays_bounded_however_many_ticks():
    """60 s of 500 Hz ticks (~20 MB of numbers) and 80 Hz steps: the log holds two chunks of each table (the one
    filling, the one its writer thread writes: 2 x 1.4 MB of ticks here). The ticks come here ~100x faster than a
    run's, so the writer is waited for at each chunk boundary, where the log's own allocations (those made in
    run_log.py and chunked_table.py) are counted: the process's peak also counts what other threads allocate meanwhile
    (7.3 MB in a full suite, none of it the log's)."""
    robot = load_robot("go2")
    command = Commands(base_velocity_m_s=np.array([0.3, 0.0, 0.0]))
    log = RunLog(chunk_rows=2000)
    log_files = [tracemalloc.Filter(True, "*run_log.py"), tracemalloc.Filter(True, "*chunked_table.py")]
    held = []  # the log's own bytes at each chunk boundary, the chunk just handed over still queued
    tracemalloc.start()
    try:
        for k in range(30_000):
            log.record_tick(*_go2_tick(robot, k))
            if k % 2000 == 1999:
                held.append(sum(stat.size for stat in
                                tracemalloc.take_snapshot().filter_traces(log_files).statistics("filename")))
                log.flush()
            if k % 6 == 0:
                log.record_step(0.002 * k, 1.0, 4, True, "Solve_Succeeded", command, np.ones(4))
                log.record_delay(0.0)
    finally:
        tracemalloc.stop()
    row_bytes = 8 * (1 + robot.nq + robot.nv + 3 * robot.n_joints + 3 * len(robot.feet))
    written = 30_000 * row_bytes
    assert written > 15e6 and len(held) == 15
    assert max(held) < 0.2 * written, f"the log held {max(held) / 1e6:.1f} MB for {written / 1e6:.1f} MB written"
    assert max(held) > 2000 * row_bytes  # it does hold the chunk it fills (the count sees the log's arrays)
    assert log.n_ticks == 30_000 and log.n_steps == 5000
    a = log.arrays(("t", "q", "tau", "contact_forces", "mpc_t"))
    np.testing.assert_array_equal(a["t"], 0.002 * np.arange(30_000))
    np.testing.assert_array_equal(a["tau"][:, 0], np.arange(30_000))
    np.testing.assert_array_equal(a["q"][:, 0], 1e-4 * np.arange(30_000))
    np.testing.assert_array_equal(a["contact_forces"][12_345], np.full((4, 3), 12_345.0))
    assert a["mpc_t"].size == 5000 and log.status == ["Solve_Succeeded"] * 5000
    np.testing.assert_array_equal(log.arrays(("t",), every=500)["t"], 0.002 * np.arange(0, 30_000, 500))


def test_commands_round_trip_through_their_numbers():
    for command in (Commands(), Commands(base_velocity_m_s=np.array([0.3, -0.1, 0.0]), base_yaw_rate_rad_s=0.2,
                                         ee_velocity_m_s=np.array([0.0, 0.1, -0.2]), ee_force_n=np.array([5.0, 0, 0]),
                                         base_height_m=0.4, walking=False), Commands(walking=True)):
        assert command_row(command).shape == (COMMAND_WIDTH,)  # also the width of an empty log's command array
        back = command_from_row(command_row(command))
        for name in ("base_velocity_m_s", "ee_force_n"):
            np.testing.assert_array_equal(getattr(back, name), getattr(command, name))
        assert back.base_yaw_rate_rad_s == command.base_yaw_rate_rad_s
        assert back.base_height_m == command.base_height_m
        assert back.walking is command.walking
        assert (back.ee_velocity_m_s is None) == (command.ee_velocity_m_s is None)
        if command.ee_velocity_m_s is not None:
            np.testing.assert_array_equal(back.ee_velocity_m_s, command.ee_velocity_m_s)


def in_memory_metrics(robot, a: dict, commands: list) -> dict:
    """The metrics as `common_metrics` computed them from whole in-memory arrays before the chunked log."""
    t, q, v = a["t"], a["q"], a["v"]
    duration = float(t[-1] - t[0])
    rot0 = pin.Quaternion(q[0, 3:7]).toRotationMatrix()
    yaw0 = np.arctan2(rot0[1, 0], rot0[0, 0])
    c, s = np.cos(yaw0), np.sin(yaw0)
    heading = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    cmd_world = np.array([cmd.base_velocity_m_s for cmd in commands]) @ heading.T
    cmd_at_t = np.stack([np.interp(t, a["mpc_t"], cmd_world[:, k]) for k in range(3)], axis=1)
    path = np.vstack([np.zeros((1, 2)), np.cumsum(cmd_at_t[:-1, :2] * np.diff(t)[:, None], axis=0)])
    displacement = q[-1, :2] - q[0, :2] - path[-1]
    settle = np.searchsorted(t, t[0] + min(SETTLE_S, 0.5 * duration))
    settled = displacement - (q[settle, :2] - q[0, :2]) + path[settle]
    vel_world = np.array([pin.Quaternion(qi[3:7]).toRotationMatrix() @ vi[:3] for qi, vi in zip(q, v)])
    return {
        "duration_s": duration,
        "base_drift_cm_s": 100 * np.linalg.norm(displacement) / duration,
        "base_drift_settled_cm_s": 100 * np.linalg.norm(settled) / (t[-1] - t[settle]),
        "base_drift_settled_from_s": t[settle] - t[0],
        "base_vel_rmse": np.sqrt(np.mean(np.sum((vel_world[:, :2] - cmd_at_t[:, :2]) ** 2, axis=1))),
        "max_torque_ratio": np.max(np.abs(a["tau"]) / robot.tau_max),
        "max_feedforward_torque_ratio": np.max(np.abs(a["tau_ff"]) / robot.tau_max),
        "solve_ms_mean": np.mean(a["solve_ms"]),
        "iterations_mean": np.mean(a["iterations"]),
    }


def assert_same_metrics(robot, log: RunLog) -> dict:
    m = common_metrics(robot, log, "check")
    expected = in_memory_metrics(robot, log.arrays(), log.commands)
    got = dict(m, solve_ms_mean=m["solve_ms"]["mean"])
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key
    return m


def test_streamed_metrics_equal_the_in_memory_ones_on_a_turning_walk():
    """Commands that change, a base that turns and drifts, 37-tick chunks: the chunk edges fall anywhere."""
    robot = load_robot("go2")
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 5.0, 0.002)
    q = np.tile(robot.q_nominal, (t.size, 1))
    q[:, 0] = 0.25 * t + 0.01 * np.sin(3 * t)
    q[:, 1] = 0.02 * t**2
    for k, tk in enumerate(t):
        q[k, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.01, 0.02, 0.3 + 0.2 * tk)).coeffs()
    v = rng.normal(0.0, 0.2, (t.size, robot.nv))
    tau = rng.uniform(-1, 1, (t.size, robot.n_joints)) * robot.tau_max
    mpc_t = np.arange(0.0, 5.0, 1 / 80)
    commands = [Commands(base_velocity_m_s=np.array([0.2 + 0.1 * np.sin(tk), 0.05 * np.cos(2 * tk), 0.0]))
                for tk in mpc_t]
    log = RunLog.from_columns(t, q, v, tau, 0.5 * tau, mpc_t=mpc_t, commands=commands,
                              solve_ms=rng.uniform(1, 9, mpc_t.size), iterations=rng.integers(1, 9, mpc_t.size),
                              chunk_rows=37)
    assert log.spilled_chunks > 60
    m = assert_same_metrics(robot, log)
    assert m["base_drift_cm_s"] > 1.0  # not a trivially zero figure


def test_a_short_closed_loop_run_gives_the_in_memory_metrics(tmp_path):
    """A real run whose log spilled to `log_dir`: the streamed metrics are those of the whole arrays."""
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06)),
                               gait="trot"))
    plant = make_plant("mujoco", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    loop = ClosedLoop(mpc, plant, LoopConfig(), log_dir=tmp_path, log_chunk_rows=32)
    log = loop.run(0.3, commands=lambda t, q, v: Commands(base_velocity_m_s=np.array([0.2 * t, 0.0, 0.0])))
    assert not log.fell and log.n_ticks == 150 and log.spilled_chunks == 4
    assert any(tmp_path.iterdir())  # spilled where asked
    assert_same_metrics(robot, log)
    assert log.rss_samples[0][0] == 0.0 and log.rss_samples[-1][1] > 10.0  # sampled at the start and the end


def test_stability_metrics_compare_the_first_and_last_minute():
    log = RunLog()
    log.rss_samples = [(10.0 * k, 200.0 + (50.0 if k >= 6 else 5.0 * k) + 0.1 * k) for k in range(61)]
    mpc_t = np.arange(0.0, 600.0, 1 / 80)
    solve_ms = np.where(mpc_t < 60, 2.0, np.where(mpc_t >= 540, 3.0, 10.0))
    m = stability_metrics(log, mpc_t, solve_ms, 600.0)
    assert m["stability_window_s"] == 60.0
    assert m["solve_ms_first_window_mean"] == pytest.approx(2.0 + 8.0 / mpc_t[mpc_t <= 60].size)  # the step at 60 s
    assert m["solve_ms_last_window_mean"] == pytest.approx(3.0)
    assert m["rss_mb_start"] == 200.0 and m["rss_mb_after_window"] == pytest.approx(250.6)
    assert m["rss_growth_pct"] == pytest.approx(100 * (256.0 - 250.6) / 250.6)
    short = stability_metrics(log, mpc_t[:800], solve_ms[:800], 10.0)
    assert short["stability_window_s"] == 5.0


def test_long_runs_are_plotted_from_every_kth_tick(monkeypatch, tmp_path):
    """Beyond PLOT_FULL_RATE_TICKS ticks the plots read a decimated copy; the MPC steps stay whole."""
    from wbmpc.viz import plots

    robot = load_robot("go2")
    t = np.arange(0.0, 0.3, 0.002)
    q = np.tile(robot.q_nominal, (t.size, 1))
    log = RunLog.from_columns(t, q, np.zeros((t.size, robot.nv)), np.zeros((t.size, robot.n_joints)),
                              contact_forces=np.zeros((t.size, 4, 3)), mpc_t=np.arange(0.0, 0.3, 1 / 80),
                              planned_contact=np.ones((24, 4)), chunk_rows=16)
    read = []
    original = log.arrays
    monkeypatch.setattr(log, "arrays", lambda keys=None, every=1: read.append((keys, every)) or original(keys, every))
    monkeypatch.setattr(plots, "PLOT_FULL_RATE_TICKS", 40)
    plots.save_plots(robot, log, tmp_path)
    assert [every for keys, every in read if keys is None] == [4]  # ceil(150 / 40); the step lists whole
    assert all(every == 1 for keys, every in read if keys is not None)
    data = original(every=4)
    assert data["t"].size == 38 and data["mpc_t"].size == 24


def test_a_long_run_solver_plot_draws_a_stair_line_not_a_bar_per_step(monkeypatch):
    from wbmpc.viz import plots

    mpc_t = np.arange(0.0, 0.3, 1 / 80)
    success = np.arange(mpc_t.size) != 5
    data = {"mpc_t": mpc_t, "solve_ms": np.full(mpc_t.size, 5.0), "iterations": np.arange(mpc_t.size) % 4 + 1,
            "success": success}
    robot = load_robot("go2")
    assert len(plots.solver_figure(robot, data).axes[1].patches) == mpc_t.size  # short: a bar per step
    monkeypatch.setattr(plots, "MAX_ITERATION_BARS", 10)
    ax = plots.solver_figure(robot, data).axes[1]
    assert not ax.patches
    stairs, failed = ax.get_lines()
    assert stairs.get_drawstyle() == "steps-post" and stairs.get_xdata().size == mpc_t.size
    np.testing.assert_array_equal(failed.get_xdata(), mpc_t[[5]])
