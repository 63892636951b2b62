"""The Z1 arm's low-level UDP link: `Z1Client` (deploy, in the place of Unitree's z1_sdk) and `Z1Server`
(`wbmpc robot-sim --arm z1`, in the place of z1_controller). Messages and ports: `wbmpc.hardware.z1_messages`.

The controller side sends a RecvState every tick (500 Hz) to the SDK's port and takes the latest valid
SendCmd; the SDK side answers with one SendCmd per tick. FSM: only PASSIVE may switch to LOWCMD; in LOWCMD
each joint follows the motor law tau + kp (q - q_m) + kd (dq - dq_m); a silent SDK (no valid command for
`command_timeout_ms`) sends the arm back to PASSIVE, which damps it.

Both sides receive on a thread of their own (as the DDS callbacks of the legs) and count what they reject
(wrong length or head, unknown FSM state, non-finite values, negative gains): a rejected datagram is never
used.
"""

from __future__ import annotations

import socket
import threading
import time
from collections import Counter

import numpy as np

from wbmpc.errors import ConfigError, RunError
from wbmpc.hardware.messages import MessageError
from wbmpc.hardware.safety import Watchdog
from wbmpc.hardware.z1_messages import (
    CONTROLLER_IP,
    CONTROLLER_PORT,
    N_Z1_JOINTS,
    SDK_PORT,
    ArmFsmState,
    Z1Command,
    Z1State,
    decode_recv_state,
    decode_send_cmd,
    encode_recv_state,
    encode_send_cmd,
)

_MAX_DATAGRAM = 2048


class ArmNotAnsweringError(RunError):
    """The Z1 arm sent no valid state in time, or refused LOWCMD; nothing was commanded to the legs."""


def _reason(exc: MessageError) -> str:
    text = str(exc)
    return "length" if "bytes" in text else "head" if "head" in text else "state" if "FSM" in text else "malformed"


class _Endpoint:
    """A UDP socket bound to `own_port`, sending to (`to_ip`, `to_port`), receiving on a thread."""

    def __init__(self, to_ip: str, to_port: int, own_port: int, decode):
        self._to = (to_ip, int(to_port))
        self._decode = decode
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._sock.bind(("0.0.0.0", int(own_port)))
        except OSError as exc:
            self._sock.close()
            raise ConfigError(f"cannot bind UDP port {own_port} for the Z1 link ({exc}): is another Z1 SDK or "
                              "controller (or a second wbmpc) running on this machine?") from None
        self._sock.settimeout(0.05)
        self._poll_sock = self._sock.dup()  # same socket, never waits: for `poll`
        self._poll_sock.setblocking(False)
        self.rejected: Counter = Counter()
        self.received = 0
        self._lock = threading.Condition()
        self._latest = None
        self._latest_wall: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive, daemon=True, name=f"z1-udp-{own_port}")
        self._thread.start()

    def latest(self):
        """The last valid message received (a `Z1State` at the client, a `Z1Command` at the server), or None."""
        with self._lock:
            return self._latest

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._sock.recv(_MAX_DATAGRAM)
            except (socket.timeout, BlockingIOError):
                continue
            except OSError:
                return
            self._take(data)

    def _take(self, data: bytes) -> None:
        now = time.perf_counter()
        try:
            message = self._decode(data)
        except MessageError as exc:
            with self._lock:
                self.rejected[_reason(exc)] += 1
            return
        with self._lock:
            self.received += 1
            self._on_message(message, now)
            self._lock.notify_all()

    def poll(self) -> None:
        """Take what is waiting on the socket in the caller's thread (the 500 Hz loop must not depend on the
        receiver thread getting the GIL in time)."""
        while True:
            try:
                data = self._poll_sock.recv(_MAX_DATAGRAM)
            except OSError:  # nothing waiting (BlockingIOError), or closed
                return
            self._take(data)

    def _on_message(self, message, now: float) -> None:
        self._latest, self._latest_wall = message, now

    def _send(self, data: bytes) -> None:
        try:
            self._sock.sendto(data, self._to)
        except OSError:
            pass  # nobody listening yet (ICMP port unreachable): the other side's watchdog handles silence

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._poll_sock.close()
        self._sock.close()


class Z1Client(_Endpoint):
    """The SDK side: sends SendCmd to the controller, keeps the latest RecvState."""

    def __init__(self, controller_ip: str = CONTROLLER_IP, controller_port: int = CONTROLLER_PORT,
                 own_port: int = SDK_PORT, state_timeout_ms: float = 100.0):
        self.watchdog = Watchdog(state_timeout_ms, clock=time.perf_counter)  # before the receiver thread starts
        self.commands_sent = 0
        super().__init__(controller_ip, controller_port, own_port, decode_recv_state)

    def _on_message(self, message, now: float) -> None:
        super()._on_message(message, now)
        self.watchdog.feed()

    def send(self, command: Z1Command) -> None:
        self._send(encode_send_cmd(command))
        self.commands_sent += 1

    def wait_state(self, timeout_s: float, where=lambda s: True) -> Z1State | None:
        deadline = time.perf_counter() + timeout_s
        with self._lock:
            while True:
                if self._latest is not None and where(self._latest):
                    return self._latest
                left = deadline - time.perf_counter()
                if left <= 0 or not self._lock.wait(timeout=min(left, 0.01)):
                    if left <= 0:
                        return None

    def enter_lowcmd(self, timeout_s: float, hold_kp: np.ndarray, hold_kd: np.ndarray) -> Z1State:
        """PASSIVE, then LOWCMD (holding the measured pose by PD), as z1_sdk's setFsm does.
        ArmNotAnsweringError when the arm is silent or does not switch within `timeout_s`."""
        deadline = time.perf_counter() + timeout_s
        where = f"UDP {self._to[0]}:{self._to[1]}"
        with self._lock:
            self._latest = None  # a state from before (e.g. before a long MPC build) does not count
        if self.wait_state(timeout_s) is None:
            raise ArmNotAnsweringError(
                f"the Z1 arm sent no valid state within {timeout_s:.1f} s ({where}; rejected {dict(self.rejected)}): is "
                "z1_controller (or `wbmpc robot-sim --arm z1`) running on this computer? Nothing was commanded.")
        for target in (ArmFsmState.PASSIVE, ArmFsmState.LOWCMD):
            while True:
                state = self.latest()
                if state.state == target:
                    break
                if time.perf_counter() > deadline:
                    raise ArmNotAnsweringError(
                        f"the Z1 arm stays in FSM state {state.state.name}, it did not switch to {target.name} within "
                        f"{timeout_s:.1f} s ({where}). Nothing was commanded to the legs.")
                if target == ArmFsmState.LOWCMD:
                    self.send(Z1Command(ArmFsmState.LOWCMD, state.q_rad, np.zeros(N_Z1_JOINTS), np.zeros(N_Z1_JOINTS),
                                        hold_kp, hold_kd))
                else:
                    self.send(Z1Command.switch(ArmFsmState.PASSIVE))
                self.wait_state(0.01, lambda s, t=target: s.state == t)
        return self.latest()

    def damp(self, kd: float) -> None:
        """Damping in LOWCMD (kp = 0, kd, tau = 0), then PASSIVE (the controller's own damping)."""
        z = np.zeros(N_Z1_JOINTS)
        self.send(Z1Command(ArmFsmState.LOWCMD, z, z, z, z, np.full(N_Z1_JOINTS, kd)))
        self.send(Z1Command.switch(ArmFsmState.PASSIVE))


class Z1Server(_Endpoint):
    """The controller side (robot-sim): FSM PASSIVE/LOWCMD, latest valid LOWCMD command, watchdog."""

    def __init__(self, sdk_ip: str = CONTROLLER_IP, sdk_port: int = SDK_PORT, own_port: int = CONTROLLER_PORT,
                 command_timeout_ms: float = 100.0):
        self.fsm = ArmFsmState.PASSIVE  # before the receiver thread starts
        self.command_timeout_s = command_timeout_ms / 1e3
        self.watchdog_events = 0
        self.watchdog_latency_ms: list = []  # wall time from the last valid command to PASSIVE
        self.rtt_ms: list = []
        self._state_sent_wall: float | None = None
        self._answered = True
        super().__init__(sdk_ip, sdk_port, own_port, decode_send_cmd)

    def _on_message(self, message: Z1Command, now: float) -> None:
        if message.state == ArmFsmState.PASSIVE:
            self.fsm = ArmFsmState.PASSIVE
        elif message.state == ArmFsmState.LOWCMD:
            if self.fsm in (ArmFsmState.PASSIVE, ArmFsmState.LOWCMD):
                self.fsm = ArmFsmState.LOWCMD
                self._latest, self._latest_wall = message, now
                if not self._answered and self._state_sent_wall is not None:
                    self.rtt_ms.append(1e3 * (now - self._state_sent_wall))
                    self._answered = True
            else:
                self.rejected["lowcmd-not-from-passive"] += 1
        elif message.state != ArmFsmState.INVALID:
            self.rejected["unsupported-state"] += 1  # trajectories etc. are z1_controller's, not robot-sim's

    def publish(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> None:
        state = Z1State(self.fsm, q, dq, np.zeros(N_Z1_JOINTS), tau, np.full(N_Z1_JOINTS, 30), np.zeros(N_Z1_JOINTS, int),
                        np.zeros(6))
        with self._lock:
            self._state_sent_wall, self._answered = time.perf_counter(), False
        self._send(encode_recv_state(state))

    def command(self) -> Z1Command | None:
        """The LOWCMD command to apply now, or None (PASSIVE: damping). A stale command -> PASSIVE."""
        self.poll()
        with self._lock:
            if self.fsm != ArmFsmState.LOWCMD:
                return None
            age_s = time.perf_counter() - self._latest_wall
            if age_s > self.command_timeout_s:
                self.fsm = ArmFsmState.PASSIVE
                self.watchdog_events += 1
                self.watchdog_latency_ms.append(1e3 * age_s)
                return None
            return self._latest
