"""Real-time push map: `wbmpc campaign --delay-mode realtime` runs one case at a time and reports each case's
achieved MPC rate and late share (the runs themselves are in tests/control/test_loop.py and tests/solvers/test_anytime.py)."""

import json

import pytest

from wbmpc.campaign.cases import expand
from wbmpc.campaign.execution import run_campaign
from wbmpc.campaign.report import case_timing
from wbmpc.campaign.spec import CampaignSpec
from wbmpc.errors import ConfigError


def test_realtime_cases_use_the_real_time_defaults_and_keep_old_ids():
    plain = expand(CampaignSpec(grid={"push_direction_deg": [90.0]}))[0]
    realtime = expand(CampaignSpec(grid={"push_direction_deg": [90.0]}, delay="realtime"))[0]
    assert plain.id != realtime.id  # another experiment, another row
    assert plain.run_config().delay_mode == "none" and plain.run_config().solver == "fatrop"
    config = realtime.run_config()
    assert config.delay_mode == "realtime" and config.solver == "sqp"
    with pytest.raises(ConfigError, match="delay"):
        CampaignSpec(delay="sometimes")


def test_realtime_campaign_refuses_parallel_workers(tmp_path):
    spec = CampaignSpec(grid={"push_direction_deg": [90.0]}, delay="realtime", duration_s=0.1)
    with pytest.raises(ConfigError, match="one case at a time"):
        run_campaign(spec, tmp_path, workers=2, progress=False)


def test_summary_lists_rate_and_late_share_per_case():
    rows = [{"case_id": "a", "params_json": json.dumps({"push_direction_deg": 90.0}), "fell": False,
             "metrics_json": json.dumps({"delay": "realtime", "solver": "sqp", "mpc_rate_hz": 79.6,
                                         "late_solution_share": 0.01, "delay_ms_mean": 9.1, "sqp_iterations_mean": 1.9})},
            {"case_id": "b", "params_json": "{}", "fell": True, "metrics_json": json.dumps({"delay": "none"})}]
    timing = case_timing(rows)
    assert len(timing) == 1 and timing[0]["mpc_rate_hz"] == 79.6 and timing[0]["late_solution_share"] == 0.01
    assert case_timing(rows[1:]) is None


def test_campaign_delay_options_as_in_run(capsys):
    """--delay-mode/--delay-ms as `wbmpc run` names them; the one-string --delay of before still works, with a
    warning, and mixing the two forms is refused."""
    import argparse

    from wbmpc.campaign.command import delay_from_args

    def parsed(**given):
        return argparse.Namespace(**{"delay": None, "delay_mode": None, "delay_ms": None, **given})

    assert delay_from_args(parsed()) is None  # the spec's own
    assert delay_from_args(parsed(delay_mode="realtime")) == "realtime"
    assert delay_from_args(parsed(delay_ms=12.5)) == "12.5" and delay_from_args(parsed(delay_mode="fixed", delay_ms=5.0)) == "5"
    assert delay_from_args(parsed(delay="realtime")) == "realtime" and "deprecated" in capsys.readouterr().err
    for bad, match in ((parsed(delay="10", delay_mode="realtime"), "one or the other"),
                       (parsed(delay_mode="realtime", delay_ms=5.0), "--delay-mode fixed"),
                       (parsed(delay_mode="fixed"), "needs --delay-ms")):
        with pytest.raises(ConfigError, match=match):
            delay_from_args(bad)
