"""Sport mode off before low-level control and back on after: Unitree's motion switcher service (RPC over DDS).

A Unitree robot (Go2, B2, ...) runs its built-in sport controller on the same motors; low-level LowCmd
fights it until the motion switcher releases it (Unitree's low-level examples do this first). The service
`motion_switcher` (API version 1.0.0.1) answers CheckMode (1001: `{"name": mode, ...}`, "" when released),
SelectMode (1002, `{"name": mode}`) and ReleaseMode (1003). unitree_sdk2py ships a `MotionSwitcherClient`
from its version after 1.0.1; with 1.0.1 (no such module) the same calls go through the SDK's RPC client.

`wbmpc robot-sim` serves the same service (`MotionSwitcherServer`): it starts in mode "normal" and
ignores LowCmd until the mode is released, as the robot's motors do.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time

from wbmpc.errors import RunError
from wbmpc.hardware.sdk import load_sdk

SERVICE = "motion_switcher"
API_VERSION = "1.0.0.1"
CHECK_MODE, SELECT_MODE, RELEASE_MODE = 1001, 1002, 1003


class SportModeError(RunError):
    """The robot's sport mode could not be released (no answer, or refused): nothing was commanded."""


def _client():
    load_sdk()
    try:  # the SDK's own client where it has one
        from unitree_sdk2py.comm.motion_switcher.motion_switcher_client import MotionSwitcherClient

        return MotionSwitcherClient()
    except ImportError:
        pass
    from unitree_sdk2py.rpc.client import Client

    class _MotionSwitcherClient(Client):
        """CheckMode / SelectMode / ReleaseMode over the SDK's RPC client (unitree_sdk2py 1.0.1 has no module)."""

        def __init__(self):
            super().__init__(SERVICE, False)

        def Init(self):
            self._SetApiVerson(API_VERSION)
            for api in (CHECK_MODE, SELECT_MODE, RELEASE_MODE):
                self._RegistApi(api, 0)

        def CheckMode(self):
            code, data = self._Call(CHECK_MODE, json.dumps({}))
            return (code, json.loads(data)) if code == 0 else (code, None)

        def SelectMode(self, name: str):
            return self._Call(SELECT_MODE, json.dumps({"name": name}))[0], None

        def ReleaseMode(self):
            return self._Call(RELEASE_MODE, json.dumps({}))[0], None

    return _MotionSwitcherClient()


class SportModeRelease:
    """`release()` before the first LowCmd, `restore()` after the last one (the mode found at release)."""

    def __init__(self, timeout_s: float = 5.0):
        self.timeout_s = timeout_s
        self.previous: str = ""
        with contextlib.redirect_stdout(sys.stderr):
            self._client = _client()
            self._client.SetTimeout(min(timeout_s, 2.0))
            self._client.Init()

    def _check(self) -> str:
        code, result = self._client.CheckMode()
        if code != 0 or not isinstance(result, dict):
            raise SportModeError(
                f"the robot's motion switcher service ('{SERVICE}') did not answer CheckMode (code {code}): is the "
                "robot (or `wbmpc robot-sim`) on this interface and DDS domain? A robot without the service (older "
                "firmware) needs its sport mode stopped by hand and --no-sport-release. Nothing was commanded.")
        return str(result.get("name", ""))

    def release(self) -> str:
        """Release the sport mode; returns the mode that was active ("" if none). SportModeError if refused."""
        self.previous = mode = self._check()
        deadline = time.monotonic() + self.timeout_s
        while mode:
            if time.monotonic() > deadline:
                raise SportModeError(
                    f"the robot refused to release its sport mode '{self.previous}' (still '{mode}' after "
                    f"{self.timeout_s:.0f} s): lay it down and release the remote's sport controls, then retry. "
                    "Nothing was commanded.")
            self._client.ReleaseMode()
            time.sleep(0.2)
            mode = self._check()
        return self.previous

    def restore(self) -> bool:
        """Select the mode found at release again; False when it fails (reported, not raised: we are exiting)."""
        if not self.previous:
            return True
        code, _ = self._client.SelectMode(self.previous)
        return code == 0


class MotionSwitcherServer:
    """robot-sim's motion switcher: mode `initial_mode` until released; `refuse` keeps it (a robot that refuses)."""

    def __init__(self, initial_mode: str = "normal", refuse: bool = False):
        from unitree_sdk2py.rpc.server import Server

        load_sdk()
        self.mode, self.refuse = initial_mode, refuse
        self.calls: list = []
        outer = self

        class _Server(Server):
            def Init(self):
                self._SetApiVersion(API_VERSION)
                self._RegistHandler(CHECK_MODE, outer._check, False)
                self._RegistHandler(SELECT_MODE, outer._select, False)
                self._RegistHandler(RELEASE_MODE, outer._release, False)

        with contextlib.redirect_stdout(sys.stderr):  # the SDK prints; robot-sim's stdout is its JSON report
            self._server = _Server(SERVICE)
            self._server.Init()
            self._server.Start(False)

    @property
    def released(self) -> bool:
        return not self.mode

    def _check(self, parameter: str):
        self.calls.append("check")
        return 0, json.dumps({"form": "0", "name": self.mode})

    def _select(self, parameter: str):
        self.calls.append("select")
        self.mode = str(json.loads(parameter or "{}").get("name", ""))
        return 0, ""

    def _release(self, parameter: str):
        self.calls.append("release")
        if not self.refuse:
            self.mode = ""
        return 0, ""
