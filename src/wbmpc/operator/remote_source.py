"""The robot's own remote as a command source of `wbmpc deploy --remote`.

Two channels carry the same remote: the 40 bytes of every LowState (`wireless_remote`, read in the deploy
loop's tick, `on_tick`) and the `rt/wirelesscontroller` topic (a DDS subscriber of its own). Both go through one
`RemoteMapping`, which acts on a key once whichever channel brought it first. Blocks that fail the layout's
checks (`RemoteError`) are counted and ignored.
"""

from __future__ import annotations

import threading

from wbmpc.operator.board import CommandBoard
from wbmpc.operator.command import OperatorLimits
from wbmpc.operator.remote import RemoteError, RemoteMapping, decode_remote, decode_wireless_controller

WIRELESS_CONTROLLER_TOPIC = "rt/wirelesscontroller"


def wireless_controller_type():
    """The SDK's `WirelessController_` IDL type (after `load_sdk`, which makes its package importable)."""
    from wbmpc.hardware.sdk import load_sdk

    load_sdk()
    from unitree_sdk2py.idl.unitree_go.msg.dds_ import WirelessController_

    return WirelessController_


class RemoteSource:
    name = "remote"

    def __init__(self, limits: OperatorLimits, topic: bool = True):
        self.mapping = RemoteMapping(limits, source=self.name)
        self.topic = topic
        self.board: CommandBoard | None = None
        self._lock = threading.Lock()
        self._last_bytes = None
        self._last_topic = None
        self._subscriber = None
        self.received = {"lowstate": 0, "topic": 0}
        self.rejected = 0

    def start(self, board: CommandBoard) -> None:
        self.board = board

    def _subscribe(self) -> None:
        """The topic's reader, made at the first tick (the deploy loop has opened DDS by then)."""
        from wbmpc.hardware.sdk import load_sdk

        sdk = load_sdk()
        self._subscriber = sdk.ChannelSubscriber(WIRELESS_CONTROLLER_TOPIC, wireless_controller_type())
        self._subscriber.Init(self._on_topic, 10)

    def on_tick(self, tick) -> None:
        """A deploy tick: the LowState's remote bytes, decoded when they changed."""
        if self.topic and self._subscriber is None:
            self._subscribe()
        raw = getattr(tick.msg, "wireless_remote", None)
        if raw is None or self.board is None:
            return
        raw = bytes(bytearray(int(b) & 0xFF for b in raw))
        if raw == self._last_bytes:
            return
        self._last_bytes = raw
        try:
            state = decode_remote(raw)
        except RemoteError:
            self.rejected += 1
            return
        with self._lock:
            self.received["lowstate"] += 1
            self.mapping.update(state, self.board.now_s, self.board, channel="lowstate")

    def _on_topic(self, msg) -> None:
        if self.board is None:
            return
        try:
            state = decode_wireless_controller(msg)
        except RemoteError:
            self.rejected += 1
            return
        if state == self._last_topic:
            return
        self._last_topic = state
        with self._lock:
            self.received["topic"] += 1
            self.mapping.update(state, self.board.now_s, self.board, channel="topic")

    def close(self) -> None:
        if self._subscriber is not None:
            try:
                self._subscriber.Close()
            except Exception:  # noqa: BLE001
                pass
            self._subscriber = None
