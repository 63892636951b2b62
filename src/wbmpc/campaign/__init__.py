"""Robustness campaigns: many closed-loop runs on Dask, one Parquet row each, maps and curves.

spec.py (what to run) -> cases.py (one run each, hashed id) -> execution.py (Dask, worker caches,
retries) -> table.py (rows streamed to Parquet) -> report.py (push map, curves, markdown);
faults.py kills workers on purpose to show nothing is lost; command.py is `wbmpc campaign`.
"""

from wbmpc.campaign.cases import AXES, Case, expand
from wbmpc.campaign.execution import CampaignRun, run_campaign, run_case
from wbmpc.campaign.report import write_report
from wbmpc.campaign.spec import CampaignSpec, load_spec
from wbmpc.campaign.table import ResultTable

__all__ = ["AXES", "Case", "CampaignRun", "CampaignSpec", "ResultTable", "expand", "load_spec", "run_campaign",
           "run_case", "write_report"]
