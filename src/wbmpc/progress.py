"""Progress bars on stderr (tqdm): ETA, a count of recovered MPC steps, silent when not a terminal.

The one progress mechanism of wbmpc: `run`, `bench`, `campaign`, `robot-sim` and `deploy` all draw
their bars with `ProgressBar`.

Logs and pipes get nothing from a bar (tqdm's `disable=None`: off unless the stream is a TTY), so
a redirected run writes only its messages. Messages go through `write`, above the bar, never onto
its line; `close(complete=True)` shows 100 % for a run that finished (the last control tick of a
run comes one tick before its end).
"""

from __future__ import annotations

import os
import sys
import warnings

from tqdm import tqdm


class ProgressBar:
    """A bar over `total` units (simulated seconds, steps, ...) updated with absolute positions."""

    def __init__(self, total: float, description: str = "", unit: str = "", enabled: bool | None = None,
                 stream=None, decimals: int = 1):
        self.total = max(float(total), 1e-9)
        self.stream = stream if stream is not None else sys.stderr
        count = f"{{n:.{decimals}f}}/{{total:.{decimals}f}}" + (f" {unit}" if unit else "")
        sized = _terminal_columns(self.stream) > 0  # a pty without a size (e.g. under `script`) reports 0
        self._bar = tqdm(total=self.total, desc=description, file=self.stream, leave=True, dynamic_ncols=sized,
                         ncols=None if sized else 100, nrows=None if sized else 24,
                         disable=None if enabled is None else not enabled, mininterval=0.25,
                         bar_format="{desc}{percentage:3.0f}%|{bar}| " + count + " [{elapsed}<{remaining}{postfix}]")
        self._recoveries = 0
        self._label = description

    @property
    def enabled(self) -> bool:
        return not self._bar.disable

    def update(self, done: float, label: str | None = None) -> None:
        """Move to `done` units (clamped to the total); `label` replaces the description."""
        if label is not None and label != self._label:
            self._label = label
            self._bar.set_description_str(label, refresh=False)
        self._bar.update(min(max(float(done), 0.0), self.total) - self._bar.n)

    def advance(self, units: float = 1.0) -> None:
        """Move on by `units` (e.g. one finished case)."""
        self.update(self._bar.n + units)

    def set_status(self, text: str) -> None:
        """A short status after the count (e.g. the last case's outcome)."""
        self._bar.set_postfix_str(text, refresh=False)

    def set_recoveries(self, count: int) -> None:
        """Mark the steps the MPC recovered with a re-solve (shown once there is one)."""
        if count != self._recoveries:
            self._recoveries = count
            self._bar.set_postfix_str(f"{count} recovered step{'s' if count != 1 else ''}", refresh=False)

    def write(self, message: str) -> None:
        """A line above the bar (or plainly, when the bar is off)."""
        if self.enabled:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self, complete: bool = False) -> None:
        if complete:
            self.update(self.total)
        self._bar.close()

    def __enter__(self) -> "ProgressBar":
        """Within `with bar:` Python warnings are written above the bar too."""
        self._warnings = warnings.catch_warnings()
        self._warnings.__enter__()
        warnings.showwarning = lambda message, category, *args, **kwargs: self.write(f"wbmpc: warning: {message}")
        return self

    def __exit__(self, *exc) -> None:
        self._warnings.__exit__(*exc)
        self._bar.close()


def _terminal_columns(stream) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return 0


def close_all() -> None:
    """Close every open bar (before an error message, so that it starts on its own line)."""
    for bar in list(getattr(tqdm, "_instances", ())):
        bar.close()
