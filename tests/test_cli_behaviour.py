"""The command as users and scripts meet it: bad input refused before anything is built, exit
codes, strict JSON, Ctrl-C, progress bars and the --out directory."""

from __future__ import annotations

import argparse
import io
import json
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import wbmpc
from wbmpc.cli import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, build_parser, main
from wbmpc.cli_reference import arguments, command, commands
from wbmpc.control import Commands, CostWeights, MpcConfig
from wbmpc.control.interpolator import PdGains
from wbmpc.errors import ConfigError, ModelError
from wbmpc.progress import ProgressBar
from wbmpc.robots import custom_spec
from wbmpc.robots.presets import preset_spec
from wbmpc.scenarios import RunConfig, ScenarioOptions
from wbmpc.scenarios.outputs import MANIFEST, write_output_files
from wbmpc.strict_json import to_json

SRC = str(Path(wbmpc.__file__).parents[1])


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}


@pytest.fixture
def no_build(monkeypatch):
    """Fail the test if an OCP would be built: bad input must be refused before that."""
    from wbmpc.ocp import problem

    def refuse(*args, **kwargs):
        raise AssertionError("an OCP was built for bad input")

    monkeypatch.setattr(problem.OcpProblem, "__init__", refuse)


@pytest.fixture(scope="module")
def go2_files():
    spec = preset_spec("go2")
    return str(spec.urdf), str(spec.srdf)


@pytest.mark.parametrize("argv, words", [
    (["run", "stand", "--duration", "inf"], "--duration must be a finite number"),
    (["run", "stand", "--duration", "1e9"], "--duration must be <= 3600 s"),
    (["run", "stand", "--uniform-dt", "0"], "--uniform-dt must be > 0 ms"),  # was silently geometric
    (["run", "stand", "--uniform-dt", "1e9"], "--uniform-dt must be <= 500 ms"),
    (["solve", "--uniform-dt", "1e9"], "--uniform-dt must be <= 500 ms"),  # hung inside Fatrop
    (["run", "stand", "--nodes", "100000"], "--nodes must be <= 100"),
    (["solve", "--nodes", "100000"], "--nodes must be <= 100"),
    (["run", "stand", "--delay-ms", "inf"], "--delay-ms must be a finite number"),
    (["run", "stand", "--delay-ms", "2000"], "--delay-ms must be <= 1000 ms"),
    (["run", "stand", "--delay-mode", "fixed"], "a fixed delay needs its length: --delay-ms MS"),
    (["run", "stand", "--delay-mode", "realtime", "--delay-ms", "5"], "does not go with --delay-mode realtime"),
    (["run", "stand", "--delay", "5", "--delay-mode", "measured"], "--delay is the old form"),
    (["run", "stand", "--delay", "inf"], "--delay must be a finite number"),  # the old form, one release
    (["run", "stand", "--delay", "later"], "--delay must be none, measured, measured-wall, realtime or a number of ms"),
    (["run", "pull", "--pull-speed", "nan"], "--pull-speed must be a finite number"),
    (["run", "stand", "--kp", "-1"], "--kp must be >= 0"),
    (["run", "stand", "--kd", "-0.5"], "--kd must be >= 0"),
    (["run", "stand", "--seed", "-1"], "--seed must be an integer >= 0"),
    (["run", "trot-forward", "--speed", "5"], "--speed must be <= 1.5 m/s"),
    (["run", "push", "--push-speed", "nan"], "--push-speed must be a finite number"),
    (["run", "wipe", "--force-n", "1e6"], "--force-n must be <= 10000 N"),
    (["run", "wipe", "--wipe-period", "0"], "--wipe-period must be > 0 s"),
    (["run", "stand", "--sweep", "10"], "--sweep runs the pull scenario"),
    (["run", "pull", "--sweep", "10,inf"], "--sweep loads must be masses in kg in (0, 1000], got [inf]"),
    (["bench", "dynamics", "--samples", "0"], "--samples must be >= 1"),  # claimed error 0 over no samples
    (["solve", "--t", "nan"], "--t must be a finite number"),
    (["info", "--feet", "a,b"], "--feet describes a custom robot and needs --urdf"),
    (["info", "--lock", "joint5"], "--lock describes a custom robot and needs --urdf"),
    (["info", "--lock", "x", "--srdf", "y.srdf"], "--srdf, --lock describe a custom robot and need --urdf"),
    (["info", "--sole", "0.2"], "--sole needs LENGTH,WIDTH in metres"),
    (["info", "--pose", "standing"], "--pose describes a custom robot and needs --urdf"),
    (["info", "--urdf", "a.urdf", "--mjcf", "a.xml", "--feet", "f"], "--urdf and --mjcf both describe the robot"),
    (["info", "--keyframe", "home"], "--keyframe names a pose of an MJCF file: it needs --mjcf FILE"),
    (["info", "--mjcf", "a.xml"], "a custom --mjcf needs --feet F1,F2,... (the foot frame names: bodies, sites or geoms"),
    (["info", "--mjcf", "nothere.xml", "--feet", "a,b"], "MJCF file not found: nothere.xml"),
    (["run", "stand", "--plant", "pinocchio", "--plant-model", "a.xml"], "--plant-model is simulated by MuJoCo"),
    (["run", "stand", "--plant-model", "nothere.xml"], "--plant-model file not found: nothere.xml"),
])
def test_bad_input_exits_2_naming_the_flag_before_building(argv, words, capsys, no_build, tmp_path):
    out = tmp_path / "never"
    if argv[0] == "run":
        argv = argv + ["--out", str(out)]
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("wbmpc: error: ") and words in err, err
    assert "_m_s" not in err and "_ms " not in err  # the flag, not the dataclass field
    assert not out.exists()  # nothing written for bad input


def _declared_run_options():
    from wbmpc.options import declared

    return [(cls, f, opt) for cls in (RunConfig, PdGains, ScenarioOptions) for f, opt in declared(cls) if opt.flag]


@pytest.mark.parametrize("cls, f, opt", [case for case in _declared_run_options()
                                         if case[2].low is not None or case[2].high is not None],
                         ids=lambda value: getattr(value, "flag", None) or "")
def test_every_declared_range_is_refused_on_the_command_line_naming_its_flag(cls, f, opt, capsys, no_build):
    """Derived from the declarations (`wbmpc.options`): out of range -> exit 2, the flag named, nothing built."""
    value = opt.high * 10 + 1 if opt.high is not None else opt.low - 1
    argv = ["run", (opt.scenarios or ("stand",))[0], opt.flag, str(int(value) if opt.integer else value), "--no-outputs"]
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith(f"wbmpc: error: {opt.flag} must be "), err


def test_run_options_come_from_their_declarations():
    """Flag, default and scenario grouping of `wbmpc run` are those declared on the config fields."""
    from wbmpc.cli import field_flags_of_commands
    from wbmpc.options import flag_default
    from wbmpc.scenarios import SCENARIOS

    parser = build_parser()
    run = command(parser, "run")
    actions = {a.option_strings[0]: a for a, _ in arguments(run) if a.option_strings}
    titles = {a.option_strings[0]: title for a, title in arguments(run) if a.option_strings}
    flags = field_flags_of_commands()
    for cls, f, opt in _declared_run_options():
        action = actions[opt.flag]
        assert action.default == (None if opt.repeat else flag_default(f, opt)), opt.flag
        assert opt.help in action.help and flags[f.name] == opt.flag
        if opt.scenarios is not None:
            assert set(opt.scenarios) <= set(SCENARIOS), opt.scenarios
            assert titles[opt.flag].startswith(", ".join(opt.scenarios) + " only"), titles[opt.flag]
    args = parser.parse_args(["run", "pull", "--load-kg", "12", "--kd", "7", "--delay-compensation", "off"])
    from wbmpc.cli import run_config_from_args

    config = run_config_from_args(args)
    assert config.options.load_kg == 12.0 and config.gains.kd_leg == 7.0 and config.delay_compensation is False
    assert config.solver == "sqp" and config.options == ScenarioOptions(load_kg=12.0)  # auto, uncompiled: sqp


@pytest.mark.parametrize("argv, flag", [(["deploy", "--speed", "2"], "--speed"), (["deploy", "--nodes", "1"], "--nodes"),
                                        (["deploy", "--kd", "-1"], "--kd"),
                                        (["robot-sim", "--push-speed", "9"], "--push-speed")])
def test_robot_sim_and_deploy_share_the_run_declarations(argv, flag, capsys, no_build):
    """deploy/robot-sim reuse `wbmpc run`'s declared options (type, range, unit): out of range -> exit 2
    naming the flag, before any DDS or model work."""
    pytest.importorskip("cyclonedds")
    assert main(argv) == EXIT_BAD_INPUT
    assert capsys.readouterr().err.startswith(f"wbmpc: error: {flag} must be ")
    kd = next(a for a, _ in arguments(command(build_parser(), "deploy")) if "--kd" in a.option_strings)
    assert "leg joint Kd of eq. (10)" in kd.help and "sent in LowCmd" in kd.help and kd.type is float


def test_a_scenario_option_the_scenario_does_not_read_is_named_in_a_warning(capsys, no_build, tmp_path):
    from wbmpc.cli import ignored_scenario_options

    args = build_parser().parse_args(["run", "stand", "--load-kg", "12", "--gait", "stand", "--speed", "0.2"])
    assert ignored_scenario_options(args) == [("--load-kg", ("pull",))]  # --speed at its default: not given
    assert main(["run", "stand", "--load-kg", "12", "--uniform-dt", "0", "--out", str(tmp_path / "x")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "warning: --load-kg is read by pull only; stand ignores it" in err


def test_custom_robot_input_errors(go2_files, tmp_path, capsys, no_build):
    urdf, srdf = go2_files
    feet = "FL_foot,FR_foot,RL_foot,RR_foot"
    cases = [
        (["--feet", "FL_foot,FL_foot,RL_foot,RR_foot"], "FL_foot given more than once (--feet)"),
        (["--feet", feet, "--pose", "standing"], "needs the SRDF that defines it (--srdf FILE)"),
        (["--feet", feet, "--arm-ee", "FL_foot"], "both as a foot and as the arm end-effector"),
    ]
    broken = tmp_path / "broken.srdf"
    broken.write_text("<robot name='go2'><group_state name='standing'")
    cases.append((["--feet", feet, "--srdf", str(broken), "--pose", "standing"], "is not well-formed XML"))
    text = Path(srdf).read_text()
    bad_value = tmp_path / "bad_value.srdf"
    bad_value.write_text(re.sub(r'(<joint name="FL_hip_joint" value=")[^"]*"', r'\1abc"', text, count=1))
    assert "abc" in bad_value.read_text()
    cases.append((["--feet", feet, "--srdf", str(bad_value), "--pose", "standing"],
                  "joint 'FL_hip_joint' has a non-numeric value 'abc'"))
    for extra, words in cases:
        assert main(["info", "--urdf", urdf] + extra) == EXIT_BAD_INPUT, extra
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, err


def test_config_dataclasses_protect_the_python_api():
    with pytest.raises(ConfigError, match="base_yaw_rate_rad_s must be a finite number"):
        Commands(base_yaw_rate_rad_s=float("nan"))  # used to give all-NaN torques
    with pytest.raises(ConfigError, match="ee_force_n must be 3 finite numbers"):
        Commands(ee_force_n=np.array([0.0, np.inf, 0.0]))
    with pytest.raises(ConfigError, match="weights.joint_torque must be >= 0"):
        CostWeights(joint_torque=-1.0)
    with pytest.raises(ConfigError, match="weights.base_position must be >= 0"):
        CostWeights(base_position=(1.0, -2.0, 3.0))
    with pytest.raises(ConfigError, match="gait_period_s must be > 0 s"):
        MpcConfig(gait_period_s=0.0)
    with pytest.raises(ConfigError, match="kd_leg must be >= 0"):
        PdGains(kd_leg=-1.0)
    with pytest.raises(ConfigError, match="uniform_dt_ms must be > 0 ms"):
        RunConfig(uniform_dt_ms=0.0)
    with pytest.raises(ConfigError, match="load_kg must be"):
        ScenarioOptions(load_kg=float("inf"))
    with pytest.raises(ModelError, match="given more than once"):
        custom_spec("x.urdf", ["a", "a"])


def test_mpc_refuses_impossible_commands_before_solving(monkeypatch):
    from wbmpc.control import MPC
    from wbmpc.ocp.grid import TimeGrid
    from wbmpc.ocp.problem import OcpConfig
    from wbmpc.robots import load_robot

    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=OcpConfig(grid=TimeGrid(n_intervals=3)), gait="stand"))

    def refuse(*args, **kwargs):
        raise AssertionError("the solver ran on an impossible command")

    monkeypatch.setattr(mpc.solver, "solve", refuse)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    start = time.perf_counter()
    with pytest.raises(ConfigError, match="end-effector force command 1e\\+06 N exceeds"):
        mpc.solve(q, v, Commands(ee_force_n=np.array([1e6, 0.0, 0.0])))  # took 23 s before failing
    assert time.perf_counter() - start < 1.0
    with pytest.raises(ConfigError, match="base height command 5 m is outside"):
        mpc.solve(q, v, Commands(base_height_m=5.0))
    command = Commands()
    command.base_yaw_rate_rad_s = float("nan")  # set after construction: still refused
    with pytest.raises(ConfigError, match="base_yaw_rate_rad_s must be finite"):
        mpc.solve(q, v, command)


def test_ctrl_c_inside_a_solve_is_delivered_after_it():
    from wbmpc.interrupt import catch_interrupt, deliver_after

    # Python's own handler, as in a terminal (a job started in the background inherits SIGINT ignored)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    before = signal.getsignal(signal.SIGINT)
    done = []
    with pytest.raises(KeyboardInterrupt):
        with deliver_after():
            signal.raise_signal(signal.SIGINT)  # as if it came while CasADi runs
            done.append("the call went on")
    assert done == ["the call went on"]
    with catch_interrupt() as flag:
        with deliver_after():
            signal.raise_signal(signal.SIGINT)
        assert flag.requested  # given to the run's flag, not raised
        with pytest.raises(KeyboardInterrupt):  # a second Ctrl-C is the hard stop
            signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is before  # restored
    signal.signal(signal.SIGINT, inherited)


def test_strict_json_turns_non_finite_numbers_into_null():
    text = to_json({"a": float("nan"), "b": [float("inf"), 1.5], "c": np.float64(2.0), "d": np.arange(2),
                    "e": np.bool_(True), "f": None})

    def refuse(token):
        raise ValueError(f"non-standard JSON token {token}")

    assert json.loads(text, parse_constant=refuse) == {"a": None, "b": [None, 1.5], "c": 2.0, "d": [0, 1],
                                                       "e": True, "f": None}


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_is_silent_in_logs_and_complete_on_a_terminal():
    log = io.StringIO()
    bar = ProgressBar(2.0, "run ", unit="s", stream=log)
    bar.update(1.0)
    bar.write("a message")
    bar.close(complete=True)
    assert log.getvalue() == "a message\n"  # only the message: no bar in a file or pipe

    term = _Terminal()
    with ProgressBar(2.0, "run ", unit="s", stream=term) as bar:
        bar.update(0.5)
        bar.set_recoveries(3)
        bar.update(1.9)  # a run ends one control tick before its duration: never 100 % on its own
        bar.write("a message")
        warnings.warn("compiled solver unavailable", RuntimeWarning)  # above the bar as well
        bar.close(complete=True)
    text = term.getvalue()
    assert "wbmpc: warning: compiled solver unavailable" in text.replace("\r", "\n").split("\n")
    assert "100%" in text and "2.0/2.0 s" in text and "3 recovered steps" in text
    assert "a message" in text.replace("\r", "\n").split("\n")  # on its own line, not glued onto the bar


def test_every_option_has_help_and_run_help_lists_scenarios_and_exit_codes():
    parser = build_parser()
    for prog, p in commands(parser):
        for action, _ in arguments(p):
            assert action.help and action.help != argparse.SUPPRESS, (prog, action.dest)
    text = command(parser, "run").format_help()
    assert "trot-in-place    10 s" in text and "exit codes:" in text and "130" in text


def test_version_and_python_dash_m():
    out = subprocess.run([sys.executable, "-m", "wbmpc", "--version"], capture_output=True, text=True, env=_env(),
                         timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == f"wbmpc {wbmpc.__version__}"


def test_output_dir_replaces_only_what_wbmpc_wrote(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "old_plot.png").write_text("stale")
    (out / MANIFEST).write_text(json.dumps({"files": ["old_plot.png", "../notes.txt"]}))

    def write(folder: Path):
        (folder / "metrics.json").write_text("{}")
        return [folder / "metrics.json"]

    paths = write_output_files(out, write)
    assert paths == [out / "metrics.json"]
    assert sorted(p.name for p in out.iterdir()) == sorted([MANIFEST, "metrics.json", "notes.txt"])
    assert json.loads((out / MANIFEST).read_text()) == {"files": ["metrics.json"]}

    def broken(folder: Path):
        (folder / "metrics.json").write_text("{")
        raise OSError("disk full")

    fresh = tmp_path / "fresh"
    with pytest.raises(OSError):
        write_output_files(fresh, broken)
    assert not fresh.exists()  # no empty or half-written --out
    with pytest.raises(OSError):
        write_output_files(out, broken)
    assert (out / "metrics.json").read_text() == "{}"  # the previous complete outputs stay


def test_a_fall_exits_1(tmp_path, capsys):
    # a 1 s solver delay leaves the trot without new plans: go2 falls within a second
    code = main(["run", "trot-in-place", "--robot", "go2", "--plant", "pinocchio", "--delay-ms", "1000",
                 "--duration", "1.5", "--nodes", "6", "--no-outputs", "--json"])
    captured = capsys.readouterr()
    metrics = json.loads(captured.out)
    assert metrics["fell"] is True and code == EXIT_FAILED
    assert "FAILED: the robot fell" in captured.err
    assert metrics["mpc_rate_hz"] < 10 and metrics["late_solution_share"] > 0  # the real-time summary's figures
    assert "achieved MPC rate" in captured.err


def test_sweep_of_loads_the_arm_cannot_hold_exits_1_with_its_report(tmp_path, capsys):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "metrics.json").write_text("{}")  # from an earlier single run: stale here
    assert main(["run", "pull", "--sweep", "500,900", "--out", str(out), "--json"]) == EXIT_FAILED
    report = json.loads(capsys.readouterr().out)
    assert [r["load_kg"] for r in report["rows"]] == [500.0, 900.0]
    assert all("beyond the arm's torque limits" in r["rejected"] for r in report["rows"])
    assert report["max_pulled_kg"] is None and report["interrupted"] is False
    assert json.loads((out / "sweep.json").read_text()) == report
    assert not (out / "metrics.json").exists()


def test_sweep_stops_at_once_when_asked(b1z1):
    from wbmpc.scenarios.sweep import pull_sweep

    report = pull_sweep(b1z1, [6.0, 10.0], RunConfig(scenario="pull"), stop=lambda: True)
    assert report["interrupted"] is True and report["rows"] == []


def test_ctrl_c_stops_the_run_keeps_the_metrics_and_exits_130():
    """SIGINT to a running `wbmpc run` (stderr on a pseudo-terminal, so the bar shows the loop running)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "wbmpc", "run", "stand", "--robot", "go2", "--plant", "pinocchio",
                             "--duration", "60", "--nodes", "6", "--json", "--no-outputs"],
                            stdout=subprocess.PIPE, stderr=slave, env=_env())
    os.close(slave)
    seen, deadline = b"", time.time() + 120
    try:
        while time.time() < deadline:  # wait until the closed loop has simulated 0.2 s
            if select.select([master], [], [], 1.0)[0]:
                seen += os.read(master, 4096)
            if any(float(x) >= 0.2 for x in re.findall(rb"(\d+\.\d)/60\.0 s", seen)):
                break
        else:
            pytest.fail(f"the run never showed progress: {seen[-500:]!r}")
        sent = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        stopped_s = time.perf_counter() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    assert proc.returncode == EXIT_INTERRUPTED
    metrics = json.loads(out)
    assert metrics["interrupted"] is True and not metrics["fell"]
    assert 0.1 <= metrics["duration_s"] < 30  # what ran until Ctrl-C, not the 60 s asked for
    assert metrics["mpc_solves"] > 10 and metrics["mpc_failures"] == 0  # the interrupt failed no solve
    assert stopped_s < 15  # stops within a solve (about 0.1 s here); generous for a loaded machine
