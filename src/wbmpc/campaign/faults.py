"""Fault injection: kill the worker process in the middle of chosen cases, once per case.

Used by the tests and by `wbmpc campaign --kill-workers N` to show that a worker dying mid-case
loses and duplicates nothing. A marker file per case (created atomically before the kill) makes
the retry on the restarted worker run normally.
"""

from __future__ import annotations

import os
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

from wbmpc.campaign.cases import Case
from wbmpc.campaign.execution import run_case


@dataclass(frozen=True)
class KillWorkerOnce:
    """A case runner (picklable) that SIGKILLs its own worker `after_s` into each case in `case_ids`
    the first time that case runs, then runs cases normally."""

    marker_dir: str
    case_ids: frozenset[str]
    after_s: float = 0.5

    def __call__(self, case: Case) -> dict:
        if case.id in self.case_ids:
            Path(self.marker_dir).mkdir(parents=True, exist_ok=True)
            marker = Path(self.marker_dir) / f"{case.id}.killed"
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                pass  # killed once already: this is the retry
            else:
                os.write(fd, str(os.getpid()).encode())
                os.close(fd)
                pid = os.getpid()
                if self.after_s <= 0:
                    os.kill(pid, signal.SIGKILL)  # before the case starts: no race with a fast case
                threading.Timer(self.after_s, os.kill, (pid, signal.SIGKILL)).start()
        return run_case(case)

    def killed(self) -> list[str]:
        return sorted(p.stem for p in Path(self.marker_dir).glob("*.killed"))
