"""`wbmpc solve` and `wbmpc bench mpc`: JSON reports, sizes and the error path."""

import json

import pytest

from wbmpc.cli import main

SOLVE_KEYS = {"formulation", "solver", "decision_variables", "status", "success", "iterations", "solve_ms",
              "max_constraint_violation"}


def _run_json(capsys, argv):
    code = main(argv)
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


def test_solve_small_horizon_json(capsys):
    code, report, err = _run_json(capsys, ["solve", "--json", "--nodes", "6"])
    assert code == 0
    assert SOLVE_KEYS <= set(report)
    assert report["success"] is True, report
    assert report["decision_variables"] > 0
    assert report["iterations"] >= 1 and report["solve_ms"] > 0
    assert report["max_constraint_violation"] < 1e-5
    assert (report["formulation"], report["solver"], report["nodes"]) == ("wb_inverse", "fatrop", 6)
    assert "decision variables" in err  # human text goes to stderr with --json


def test_solve_default_has_the_papers_1226_variables(capsys):
    code, report, _ = _run_json(capsys, ["solve", "--json"])
    assert code == 0
    assert report["decision_variables"] == 1226
    assert report["success"] is True, report


@pytest.mark.parametrize("argv, words", [
    (["solve", "--nodes", "1"], ["--nodes", ">= 2"]),
    (["solve", "--solver", "osqp"], ["unknown solver 'osqp'", "fatrop", "ipopt"]),
    (["solve", "--gait", "gallop"], ["unknown gait 'gallop'", "trot"]),
    (["solve", "--formulation", "srbd"], ["unknown formulation 'srbd'", "wb_inverse"]),
    (["solve", "--uniform-dt", "0"], ["--uniform-dt"]),
    (["bench", "mpc", "--solvers", "fatrop,osqp"], ["unknown solver 'osqp'"]),
    (["bench", "mpc", "--plant", "gazebo"], ["unknown plant 'gazebo'", "pinocchio"]),
    (["bench", "mpc", "--steps", "0"], ["--steps"]),
    (["run", "stand", "--solver", "osqp"], ["unknown solver 'osqp'", "rti", "sqp"]),
])
def test_bad_input_exits_2_with_a_message(capsys, argv, words):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("wbmpc: error:")
    for word in words:
        assert word in err


def test_bench_mpc_quick_smoke(capsys, tmp_path):
    out = tmp_path / "bench.json"
    code, report, err = _run_json(capsys, ["bench", "mpc", "--steps", "3", "--solvers", "fatrop,rti", "--json",
                                           "--out", str(out)])
    assert code == 0
    assert json.loads(out.read_text()) == report
    run = report["solvers"]["fatrop"]
    assert run["steps"] == 3 and run["failures"] == 0 and run["decision_variables"] == 1226
    assert set(run["solve_ms"]) == {"mean", "std", "max"} and set(run["iterations"]) == {"mean", "max"}
    same = report["same_states"]
    assert same["states"] == 3
    assert set(same["runs"]) == {"fatrop", "fatrop_cold", "fatrop_uniform", "rti"}
    assert same["fatrop_vs_ipopt"] is None  # IPOPT not requested
    rti = report["solvers"]["rti"]
    assert rti["failures"] == 0 and rti["step_cpu_ms"]["mean"] > 0 and rti["function_eval_ms_mean"] > 0
    assert same["rti_vs_fatrop"]["time_ratio"] > 0
    assert same["warm_resolve_matches_closed_loop"] is True
    for key in ("iteration_reduction_pct", "time_reduction_pct"):
        assert key in same["warm_vs_cold"]
    assert same["adaptive_vs_uniform"]["uniform"]["grid"] == "uniform 40 ms"
    assert same["adaptive_vs_uniform"]["time_ratio"] > 0
    assert "%|" not in err and "\r" not in err  # stderr is no terminal here: no progress bar in logs


def test_bench_scaling_sweeps_the_horizon_and_the_robots(capsys, tmp_path):
    """Both sweeps on small uncompiled runs: one point per horizon and per robot, sizes growing with the horizon and
    the degrees of freedom, the plot written."""
    plot = tmp_path / "scaling.png"
    code, report, _ = _run_json(capsys, ["bench", "scaling", "--robot", "a1", "--nodes-list", "4,6", "--robots",
                                         "a1,go2", "--nodes", "4", "--steps", "2", "--solver", "fatrop", "--json",
                                         "--plot", str(plot)])
    assert code == 0 and plot.stat().st_size > 0 and report["plot"] == str(plot)
    horizon, dof = report["horizon"]["points"], report["dof"]["points"]
    assert [p["nodes"] for p in horizon] == [4, 6] and [p["robot"] for p in dof] == ["a1", "go2"]
    assert horizon[0]["decision_variables"] < horizon[1]["decision_variables"]
    assert all(p["failures"] == 0 and not p["fell"] and p["solve_ms"]["mean"] > 0 for p in horizon + dof)
    assert dof[0]["nv"] == dof[1]["nv"] == 18 and {p["gait"] for p in dof} == {"trot"}


def test_bench_mpc_threads_are_checked(capsys):
    code = main(["bench", "mpc", "--steps", "2", "--solvers", "fatrop", "--threads", "1,2"])
    assert code == 2
    assert "fatrop-direct" in capsys.readouterr().err


@pytest.mark.parametrize("foot_contact", ["surface", "point"])
def test_bench_mpc_plans_on_the_grid_a_run_uses(tmp_path, foot_contact):
    """`bench mpc` measures the MPC a run builds: flat feet's far nodes on the contact switches (the solver's
    iterations on g1 depend on it), point feet on the fixed grid; the uniform comparison grid never moves."""
    from tests.control.test_humanoid import _biped_urdf
    from wbmpc.bench.mpc import grid_for, mpc_config
    from wbmpc.control.policy import follows_contact_switches
    from wbmpc.robots import RobotModel, RobotSpec

    urdf = tmp_path / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    robot = RobotModel(RobotSpec(name="biped", urdf=str(urdf), feet=("l_foot", "r_foot"), foot_contact=foot_contact))
    flat = foot_contact == "surface"
    assert follows_contact_switches(robot) is flat
    assert mpc_config(gait="walk", nodes=15, robot=robot).ocp.grid.follow_contact_switches is flat
    assert grid_for(15, robot=robot).follow_contact_switches is flat
    assert not grid_for(15, 40.0, robot=robot).follow_contact_switches
