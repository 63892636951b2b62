"""End-to-end smoke tests of `wbmpc run` as the README tells users to call it: every `--state`,
`--solver`, `--delay` mode, `--compiled`, `--json` and the files written, each run to its end
through the real entry point (`wbmpc.cli.main`), checking the exit code and the JSON.

Short runs (0.3 s simulated) on the small robot (a1, 6 nodes) keep the default set to about two
minutes on a loaded 2-core machine (most of it building the OCPs); the compiled solvers (a C compile on a fresh cache), the loco-manipulation scenarios on the
arm robot and the README's 10 s estimated-state run are marked slow.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

import wbmpc
from wbmpc.cli import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, main

SMALL = ["--robot", "a1", "--nodes", "6"]
SHORT_S = 0.3
# keys every run's JSON carries (the CLI contract: README and metrics.json)
RUN_KEYS = {"scenario", "robot", "fell", "fell_at_s", "duration_s", "requested_duration_s", "interrupted",
            "base_drift_cm_s", "base_vel_rmse", "max_torque_ratio", "torque_margin_per_joint", "solve_ms",
            "iterations_mean", "mpc_solves", "mpc_failures", "mpc_recoveries", "mpc_rate_hz", "late_solution_share",
            "delay_ms_mean", "state", "delay", "delay_mode", "delay_ms", "mpc_rate_target_hz", "plant", "nodes", "time_steps", "base_tracking", "drive_train"}
SRC = str(Path(wbmpc.__file__).parents[1])


def run_json(capsys, *argv: str) -> tuple[int, dict, str]:
    """`wbmpc run ... --json` in this process: exit code, the one JSON object on stdout, stderr."""
    code = main(["run", *argv, "--json"])
    captured = capsys.readouterr()
    lines = captured.out.strip().splitlines()
    assert len(lines) == 1, f"--json prints exactly one line on stdout, got {captured.out[:500]!r}"
    return code, json.loads(lines[0], parse_constant=_no_constants), captured.err


def _no_constants(name: str):
    raise AssertionError(f"strict JSON has no {name}")


def check_run(code: int, m: dict, err: str, scenario: str = "trot-in-place", duration_s: float = SHORT_S,
              robot: str = "a1", task_may_fail: bool = False, **expected) -> None:
    """What every finished run must report, whatever its mode (`task_may_fail`: a task beyond staying up,
    e.g. pulling the load, that a short run may not finish: exit 1 with the reason)."""
    assert RUN_KEYS <= set(m), sorted(RUN_KEYS - set(m))
    assert (m["scenario"], m["robot"]) == (scenario, robot)
    assert isinstance(m["fell"], bool) and m["interrupted"] is False
    if task_may_fail and code == EXIT_FAILED:
        assert "FAILED:" in err
    else:
        assert code == (EXIT_FAILED if m["fell"] else EXIT_OK), (code, m["fell"], err[-2000:])
    if not m["fell"]:
        assert m["fell_at_s"] is None
        assert m["duration_s"] == pytest.approx(duration_s, abs=0.02)  # the run went to its end
    assert m["requested_duration_s"] == pytest.approx(duration_s)
    assert set(m["solve_ms"]) >= {"mean", "max"} and m["solve_ms"]["mean"] > 0
    assert m["solve_ms"]["max"] >= m["solve_ms"]["mean"]
    assert m["mpc_solves"] >= 1 and m["iterations_mean"] >= 1
    assert 0 <= m["mpc_failures"] <= m["mpc_solves"]
    assert 0 <= m["late_solution_share"] <= 1
    assert 0 < m["max_torque_ratio"] < 10 and math.isfinite(m["base_vel_rmse"])
    for key, value in expected.items():
        assert m[key] == value, (key, m[key], value)
    assert f"scenario {scenario}:" in err  # the human summary went to stderr, to its end


# ----------------------------------------------------------------------------- default set
def test_default_run_writes_metrics_plots_and_replay(capsys, tmp_path):
    """fatrop, no delay, the simulator's state: the README's first command, shortened, with its outputs."""
    out = tmp_path / "run"
    code, m, err = run_json(capsys, "trot-in-place", *SMALL, "--duration", str(SHORT_S), "--out", str(out))
    check_run(code, m, err, state="true", delay_mode="none", plant="mujoco", nodes=6, time_steps="geometric")
    assert m["mpc_solves"] >= int(SHORT_S * 80) - 1 and m["mpc_failures"] == 0  # 80 Hz MPC in simulated time
    assert m["mpc_rate_hz"] == pytest.approx(80, rel=0.05)
    files = {p.name for p in out.iterdir()}
    assert {"metrics.json", "replay.html", "base_velocity.png", "joint_torques.png"} <= files, files
    assert json.loads((out / "metrics.json").read_text()) == m  # the file holds what stdout printed
    assert "estimation.png" not in files
    assert f"wrote {len(files) - 1} files to {out}" in err or f"to {out}/" in err


def test_estimated_state_runs_to_its_end(capsys, tmp_path):
    """`--state estimated ... --json` crashed in the summary (issue 21); run it to its end with outputs."""
    out = tmp_path / "est"
    code, m, err = run_json(capsys, "trot-in-place", *SMALL, "--duration", "0.5", "--state", "estimated",
                            "--out", str(out))
    check_run(code, m, err, duration_s=0.5, state="estimated")
    for key in ("est_base_pos_rmse_m", "est_base_vel_rmse_m_s", "est_orientation_rmse_rad"):
        assert isinstance(m[key], float) and 0 <= m[key] < 1, (key, m[key])
    assert "estimator RMSE" in err
    assert (out / "estimation.png").is_file()


@pytest.mark.parametrize("solver", ["ipopt", "rti"])
def test_each_solver(capsys, solver):
    code, m, err = run_json(capsys, "trot-in-place", *SMALL, "--duration", str(SHORT_S), "--solver", solver,
                            "--no-outputs")
    check_run(code, m, err)
    assert f"solver {solver}" in err


@pytest.mark.parametrize("delay", ["measured", "20", "realtime"])
def test_each_delay_mode(capsys, delay):
    flag = ["--delay-ms", delay] if delay[0].isdigit() else ["--delay-mode", delay]
    code, m, err = run_json(capsys, "trot-in-place", *SMALL, "--duration", str(SHORT_S), *flag, "--no-outputs")
    check_run(code, m, err, delay=delay)
    assert (m["delay_mode"], m["delay_ms"]) == (("fixed", 20.0) if delay == "20" else (delay, None))
    assert m["mpc_rate_hz"] is not None and m["mpc_rate_hz"] > 0  # achieved rates, not asserted (loaded machines)
    assert "achieved MPC rate" in err
    if delay == "20":
        assert m["delay_ms_mean"] == pytest.approx(20.0, abs=0.5)  # a fixed delay is exactly that
    if delay == "realtime":
        assert m["sim_cpu_share"] is not None and m["mpc_cpu_share"] is not None  # two processes measured


def test_a_failed_first_solve_is_a_run_error_exit_1(capsys, tmp_path, monkeypatch):
    """Runtime failures exit 1 (the run failed), not 2 (bad input): nothing is written."""
    import dataclasses

    from wbmpc.control import MPC

    solve = MPC.solve

    def failing(self, *args, **kwargs):
        solution = solve(self, *args, **kwargs)
        return dataclasses.replace(solution, success=False)

    monkeypatch.setattr(MPC, "solve", failing)
    out = tmp_path / "never"
    code = main(["run", "stand", *SMALL, "--duration", str(SHORT_S), "--out", str(out), "--json"])
    err = capsys.readouterr().err
    assert code == EXIT_FAILED
    assert "wbmpc: error: the MPC failed on the initial state" in err
    assert not out.exists()


def test_a_real_time_solver_process_that_does_not_start_is_a_run_error(capsys, monkeypatch):
    from wbmpc.control import solver_process

    monkeypatch.setattr(solver_process, "mpc_worker", sys.exit)  # the spawned process dies on its arguments at once
    code = main(["run", "stand", *SMALL, "--duration", str(SHORT_S), "--delay-mode", "realtime", "--no-outputs", "--json"])
    err = capsys.readouterr().err
    assert code == EXIT_FAILED, err[-2000:]
    assert "wbmpc: error: the real-time MPC process did not start" in err


def test_documented_exit_codes_hold(capsys):
    """README table and `--help` epilog: 0 done, 1 failed, 2 bad input, 130 Ctrl-C (tested in test_cli_behaviour)."""
    from wbmpc.cli import EPILOG, EXIT_CODES, EXIT_INTERRUPTED

    assert (EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED) == (0, 1, 2, 130)
    assert "first MPC solve failed" in EXIT_CODES[EXIT_FAILED] and "130" in EPILOG
    assert main(["run", "stand", *SMALL, "--delay", "soon"]) == EXIT_BAD_INPUT  # refused before a build
    assert "--delay" in capsys.readouterr().err
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    for code in ("| 0 |", "| 1 |", "| 2 |", "| 130 |"):
        assert code in readme


def test_python_dash_m_runs_end_to_end(tmp_path):
    """The entry point in a fresh process (`python -m wbmpc`), pinocchio plant, no --json, stderr
    redirected to a file: the summary on stdout, the start line in the log and no progress bar there."""
    log = tmp_path / "stderr.log"
    with open(log, "w") as stderr:
        proc = subprocess.run([sys.executable, "-m", "wbmpc", "run", "stand", *SMALL, "--duration", "0.2",
                               "--plant", "pinocchio", "--no-outputs"], stdout=subprocess.PIPE,
                              stderr=stderr, text=True, timeout=600,
                              env={**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")})
    text = log.read_text()
    assert proc.returncode == EXIT_OK, text[-2000:]
    assert "scenario stand: stayed up over 0.20 s" in proc.stdout and "{" not in proc.stdout  # no --json: text
    assert "wbmpc run stand: robot a1" in text
    assert "\r" not in text and "%|" not in text, text  # no bar in a redirected log


# ----------------------------------------------------------------------------- slow set
@pytest.mark.slow
@pytest.mark.parametrize("solver", ["fatrop", "rti"])
def test_compiled_solvers_on_the_small_robot(capsys, solver):
    code, m, err = run_json(capsys, "trot-in-place", *SMALL, "--duration", str(SHORT_S), "--compiled",
                            "--solver", solver, "--no-outputs")
    check_run(code, m, err)
    assert "(compiled)" in err


@pytest.mark.slow
def test_estimated_state_in_real_time(capsys):
    code, m, err = run_json(capsys, "trot-in-place", *SMALL, "--duration", "0.5", "--state", "estimated",
                            "--delay-mode", "realtime", "--no-outputs")
    check_run(code, m, err, duration_s=0.5, state="estimated", delay_mode="realtime")
    assert m["est_base_vel_rmse_m_s"] is not None


@pytest.mark.slow
def test_the_issues_ten_second_estimated_run(capsys, tmp_path):
    """`wbmpc run trot-in-place --state estimated --duration 10 --json` on the default robot, to its end."""
    code, m, err = run_json(capsys, "trot-in-place", "--state", "estimated", "--duration", "10",
                            "--out", str(tmp_path / "est10"))
    check_run(code, m, err, duration_s=10.0, robot="b1_z1", state="estimated")
    assert m["fell"] is False


@pytest.mark.slow
@pytest.mark.parametrize("scenario, extra", [
    ("push", ["--push-time", "0.2", "--push-speed", "0.3"]),
    ("arm-track", []),
    ("pull", ["--gait", "stand"]),
    ("push-box", []),
    ("wipe", []),
    ("compliant", []),
])
def test_each_scenario_on_the_arm_robot(capsys, tmp_path, scenario, extra):
    code, m, err = run_json(capsys, scenario, "--nodes", "8", "--duration", "0.5", *extra,
                            "--out", str(tmp_path / scenario))
    check_run(code, m, err, scenario=scenario, duration_s=0.5, robot="b1_z1", task_may_fail=True)
    assert (tmp_path / scenario / "replay.html").is_file()
