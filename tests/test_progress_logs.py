"""One progress mechanism (`wbmpc.progress.ProgressBar`, tqdm), silent when stderr is not a terminal:
a campaign redirected to a log gets its messages and no bar."""

from __future__ import annotations

import io
import re
import sys
from pathlib import Path

import pytest

import wbmpc
from wbmpc.campaign import CampaignSpec, run_campaign


def _instant_case(case) -> dict:
    """A case that does not simulate: the bar, not the runs, is under test."""
    from wbmpc.campaign.execution import base_row

    row = base_row(case)
    row.update(recovered=True, fell=False)
    return row


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True

    def fileno(self) -> int:
        raise OSError("no file descriptor")


@pytest.fixture(scope="module")
def client():
    import logging

    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    with Client(cluster) as c:
        yield c
    cluster.close()


def _campaign(client, out: Path, stderr, monkeypatch):
    spec = CampaignSpec(name="bar", scenario="push", robot="a1", duration_s=0.1, nodes=5,
                        grid={"push_direction_deg": [0, 90, 180], "push_speed_m_s": [0.2, 0.4]})
    monkeypatch.setattr(sys, "stderr", stderr)
    return run_campaign(spec, out, client=client, runner=_instant_case, progress=True)


def test_campaign_writes_no_bar_into_a_redirected_log(client, tmp_path, monkeypatch):
    log_path = tmp_path / "campaign.log"
    with open(log_path, "w") as log:
        run = _campaign(client, tmp_path / "log", log, monkeypatch)
    assert run.recorded == 6
    text = log_path.read_text()
    assert "\r" not in text and "%|" not in text and "cases" not in text, repr(text)

    terminal = _Terminal()  # the same campaign on a terminal does draw its bar
    assert _campaign(client, tmp_path / "tty", terminal, monkeypatch).recorded == 6
    shown = terminal.getvalue()
    assert "%|" in shown and "6/6 cases" in shown


def test_every_bar_goes_through_progress_py():
    """No other module draws its own bar (tqdm directly or carriage returns on stderr)."""
    src = Path(wbmpc.__file__).parent
    offenders = []
    for path in src.rglob("*.py"):
        if path.name == "progress.py":
            continue
        text = path.read_text()
        if re.search(r"^\s*(from tqdm|import tqdm)", text, re.M) or re.search(r"print\(f?[\"']\\r", text):
            offenders.append(str(path.relative_to(src)))
    assert offenders == []


def test_push_map_dots_are_green_when_recovered_and_red_when_not(tmp_path, monkeypatch):
    """The legend speaks of green and red dots: the dots are drawn in those colours (not blue)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from wbmpc.campaign.report import plot_push_map

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig: kept.append(fig))
    pmap = {d: {"recovered_share": {0.4: 1.0, 0.8: 0.5, 1.2: 0.0}, "largest_recovered_m_s": 0.4} for d in (0, 90, 180)}
    assert plot_push_map(pmap, tmp_path / "map.png").stat().st_size > 1000
    ax = kept[0].axes[0]
    dots = next(c for c in ax.collections if len(c.get_offsets()) == 9)
    colours = {round(float(r), 1): tuple(dots.get_facecolors()[k][:3]) for k, (_, r) in enumerate(dots.get_offsets())}
    (r1, g1, b1), (r0, g0, b0) = colours[0.4], colours[1.2]
    assert g1 > r1 and g1 > b1  # every case recovered: green
    assert r0 > g0 and r0 > b0  # none recovered: red
    labels = ax.get_legend_handles_labels()[1]
    assert "every case recovered" in labels and "no case recovered" in labels
    monkeypatch.undo()
    plt.close(kept[0])
