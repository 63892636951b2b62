"""Ctrl-C (SIGINT) as a flag that long loops poll, so that an interrupted run keeps what it measured.

CasADi's Fatrop interface swallows a KeyboardInterrupt raised inside a solve (the solve goes on
and succeeds) and its IPOPT interface turns it into a failed solve (`NonIpopt_Exception_Thrown`)
that the MPC would re-solve: the default Python handler never stops a closed-loop run. Hence:
- `deliver_after()` wraps every solve (`NlpSolver.solve`): a Ctrl-C during the solve is held and
  given to the previous handler when the solve returns (KeyboardInterrupt by default);
- inside `catch_interrupt()` a Ctrl-C only sets `requested`; the loop checks it every control tick
  and stops within one MPC solve, keeping its log. A second Ctrl-C raises KeyboardInterrupt.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator


class InterruptFlag:
    """Set by SIGINT while installed; `requested` is what loops poll."""

    def __init__(self) -> None:
        self.requested = False
        self.installed = False

    def __call__(self) -> bool:
        return self.requested

    def _handle(self, signum, frame) -> None:
        if self.requested:  # second Ctrl-C: stop now, whatever is running
            raise KeyboardInterrupt
        self.requested = True


@contextmanager
def catch_interrupt() -> Iterator[InterruptFlag]:
    """Within the block, SIGINT sets the yielded flag instead of raising (main thread only; elsewhere
    the flag is never set and Ctrl-C keeps its usual meaning). The previous handler is restored after."""
    flag = InterruptFlag()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return
    previous = signal.signal(signal.SIGINT, flag._handle)
    flag.installed = True
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)


@contextmanager
def stop_flag(stop=None) -> Iterator:
    """`stop` itself when given (the caller already catches Ctrl-C), else a fresh `catch_interrupt()` flag."""
    if stop is not None:
        yield stop
        return
    with catch_interrupt() as flag:
        yield flag


@contextmanager
def deliver_after() -> Iterator[None]:
    """Hold Ctrl-C during a call into code that would swallow it (a CasADi solve) and deliver it after.

    The SIGINT handler that was installed before runs once the call returns: Python's default raises
    KeyboardInterrupt, an `InterruptFlag` sets its flag. Main thread only (signals go nowhere else)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append((signum, frame)))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received and callable(previous):
            previous(*received[0])
