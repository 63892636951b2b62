"""Named closed-loop scenarios, their metrics and the runner behind `wbmpc run`."""

from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.library import SCENARIOS, make_scenario
from wbmpc.scenarios.outputs import check_output_dir
from wbmpc.scenarios.runner import RunConfig, ScenarioResult, run_scenario, write_outputs

__all__ = ["SCENARIOS", "RunConfig", "Scenario", "ScenarioOptions", "ScenarioResult", "make_scenario",
           "check_output_dir", "run_scenario", "write_outputs"]
