"""The operator's command interface: the remote's bytes against Unitree's documented layout, its mapping, command
scripts (good and bad), the shaper's ramps, the keyboard through a pseudo-terminal, a gamepad's events and its
disappearance, and short closed-loop runs driven by a script, the keyboard and a vanishing gamepad."""

import json
import os
import pty
import select
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from wbmpc.control.mpc import Commands
from wbmpc.errors import ConfigError
from wbmpc.operator.board import CommandBoard
from wbmpc.operator.command import OperatorCommand, OperatorLimits
from wbmpc.operator.remote import (
    KEY_REPEAT_S,
    RemoteError,
    RemoteMapping,
    RemoteState,
    decode_remote,
    decode_wireless_controller,
    encode_remote,
)
from wbmpc.operator.script import ScriptSource, read_script
from wbmpc.operator.shaper import CommandShaper, RampLimits
from wbmpc.robots import load_robot

SRC = str(Path(__file__).resolve().parents[2] / "src")
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
LIMITS = OperatorLimits(max_forward_m_s=1.0, max_lateral_m_s=0.5, max_yaw_rate_rad_s=1.0, height_range_m=(-0.1, 0.03))


@pytest.fixture(scope="module")
def a1():
    return load_robot("a1")


@pytest.fixture(scope="module")
def b1_z1():
    return load_robot("b1_z1")


# ---------------------------------------------------------------------------------------------------- the remote
def _documented_block(keys_low: int, keys_high: int, lx: float, rx: float, ry: float, l2: float, ly: float) -> bytes:
    """A 40-byte block written field by field from Unitree's xRockerBtnDataStruct: head[2], btn (uint16: byte 2 holds
    R1 L1 start select R2 L2 F1 F2 from bit 0, byte 3 A B X Y up right down left), then lx, rx, ry, L2, ly as
    little-endian float32, then 16 idle bytes."""
    head = bytes([0x55, 0xAA])
    return head + bytes([keys_low, keys_high]) + struct.pack("<5f", lx, rx, ry, l2, ly) + bytes(16)


def test_remote_bytes_decode_as_unitree_documents_them():
    # start (byte 2 bit 2) and A (byte 3 bit 0); left stick half forward, a quarter right; right stick left
    block = _documented_block(0b0000_0100, 0b0000_0001, lx=0.25, rx=-0.75, ry=0.125, l2=0.0, ly=0.5)
    assert len(block) == 40
    state = decode_remote(block)
    assert state.key_names == ("start", "A")
    assert (state.lx, state.ly, state.rx, state.ry) == (0.25, 0.5, -0.75, 0.125)
    # R1 is bit 0 of byte 2, left is bit 7 of byte 3, L2 bit 5 of byte 2 with its analog value at bytes 16-19
    state = decode_remote(_documented_block(0b0010_0001, 0b1000_0000, 0.0, 0.0, 0.0, 1.0, 0.0))
    assert state.key_names == ("R1", "L2", "left") and state.l2 == 1.0
    assert decode_remote(list(block)).keys == state_keys(block)  # LowState hands over a list of ints
    assert bytes(encode_remote(decode_remote(block)))[2:24] == block[2:24]  # robot-sim writes what robots send


def state_keys(block: bytes) -> int:
    return block[2] | block[3] << 8


def test_bad_remote_blocks_are_refused():
    with pytest.raises(RemoteError, match="39 bytes"):
        decode_remote(bytes(39))
    with pytest.raises(RemoteError, match="lx reads nan"):
        decode_remote(_documented_block(0, 0, float("nan"), 0, 0, 0, 0))
    with pytest.raises(RemoteError, match="ly reads 7"):
        decode_remote(_documented_block(0, 0, 0, 0, 0, 0, 7.0))


def test_wireless_controller_message_decodes_with_the_same_key_bits():
    class Message:  # the fields of unitree_go's WirelessController_
        lx, ly, rx, ry, keys = 0.1, -0.2, 0.3, 0.4, (1 << 2) | (1 << 9)

    state = decode_wireless_controller(Message())
    assert state.key_names == ("start", "B") and state.ly == pytest.approx(-0.2)


def test_remote_mapping_sticks_keys_and_channels():
    board = CommandBoard(OperatorCommand(), LIMITS)
    mapping = RemoteMapping(LIMITS)
    mapping.update(RemoteState(), 0.0, board)
    assert board.latest().seq == 0  # an idle remote does not override the other sources
    mapping.update(RemoteState.with_keys("start"), 0.1, board)
    assert board.latest().command.walking
    mapping.update(RemoteState.with_keys("start"), 0.12, board, channel="topic")  # the same press on the topic
    assert board.latest().command.walking
    mapping.update(RemoteState(ly=1.0, lx=0.5, rx=1.0), 0.2, board)  # right stick right: turn right
    command = board.latest().command
    assert command.forward_m_s == pytest.approx(1.0) and command.yaw_rate_rad_s == pytest.approx(-1.0)
    assert -0.5 < command.lateral_m_s < -0.2  # stick right: move right (negative y), past the dead zone
    mapping.update(RemoteState(), 0.3, board)  # released: stop moving, keep walking
    assert not board.latest().command.moving and board.latest().command.walking
    mapping.update(RemoteState.with_keys("up"), 0.4, board)
    assert board.latest().command.height_offset_m == pytest.approx(0.02)
    mapping.update(RemoteState.with_keys("B"), 0.5, board)
    assert not board.latest().command.walking
    mapping.update(RemoteState.with_keys("L2", "A", l2=1.0), 0.5 + KEY_REPEAT_S, board)
    assert board.latest().command.lie_down
    mapping.update(RemoteState.with_keys("R1", ly=1.0), 1.0, board)  # R1 held: the sticks move the hand
    mapping.update(RemoteState.with_keys("R1", ly=1.0), 1.5, board)
    assert board.latest().command.hand_offset_m[0] == pytest.approx(0.05, abs=1e-6)  # 0.1 m/s for 0.5 s


# ---------------------------------------------------------------------------------------------------- scripts
def _script(tmp_path, text: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return path


def test_the_shipped_session_reads_on_every_robot_of_the_issue():
    for name in ("b1_z1", "go2", "g1"):
        robot = load_robot(name)
        script = read_script(EXAMPLES / "session.yaml", OperatorLimits.for_robot(robot))
        assert script.duration_s == 60 and [e.at_s for e in script.entries][:3] == [0, 2, 10]
        assert script.ignored == (() if robot.arm_ee else ("hand",))
        walks = [e for e in script.entries if e.command.walking]
        assert {e.command.forward_m_s for e in walks} >= {0.4, 0.3}


def test_bad_scripts_are_refused_with_the_line_and_the_fix(tmp_path):
    limits = LIMITS
    cases = {"- {at: 0, walk: true, speed: 0.4}\n": r"s.yaml:1: unknown command 'speed'; known: at, label, forward",
             "- {at: 0, walk: true, forward: 3.0}\n": r"forward 3 m/s is beyond this robot's range of \+-1 m/s",
             "- {at: 0, walk: true}\n- {at: 5, yaw_rate: -4}\n": r"s.yaml:2: yaw_rate -4 rad/s is beyond",
             "- {at: 1}\n- {at: 1}\n": "times must increase",
             "- {at: 0, walk: maybe}\n": "walk must be true or false",
             "- {at: 0, hand: [0.5, 0, 0]}\n": "hand offset 0.5 m is beyond 0.3 m",
             "duration: 5\ncommands:\n  - {at: 6}\n": "not before the script's duration",
             "[1, 2]\n": "each command is a mapping"}
    for text, message in cases.items():
        with pytest.raises(ConfigError, match=message):
            read_script(_script(tmp_path, text), limits)
    with pytest.raises(ConfigError, match="no command script at"):
        read_script(tmp_path / "missing.yaml", limits)


def test_script_source_posts_each_entry_at_its_time(tmp_path):
    script = read_script(_script(tmp_path, "- {at: 0.5, walk: true, forward: 0.3}\n- {at: 1.0, stop: true}\n"), LIMITS)
    board = CommandBoard(OperatorCommand(), LIMITS)
    source = ScriptSource(script)
    source.poll(0.4875, board)
    assert board.latest().seq == 0
    source.poll(0.5, board)
    assert board.latest().command.forward_m_s == 0.3 and board.latest().stamp_s == 0.5
    source.poll(1.0125, board)
    assert not board.latest().command.walking and board.latest().stamp_s == 1.0


# ---------------------------------------------------------------------------------------------------- shaping
def test_shaper_ramps_within_its_limits_and_stands_only_once_still(a1):
    ramp = RampLimits(linear_accel_m_s2=1.0, yaw_accel_rad_s2=2.0, max_lead_m_s=10.0, max_yaw_lead_rad_s=10.0)
    shaper = CommandShaper(a1, OperatorCommand(), ramp)
    q, v = a1.q_nominal, np.zeros(a1.nv)
    go = OperatorCommand(forward_m_s=0.6, yaw_rate_rad_s=0.5, walking=True)
    dt = 1 / 80
    speeds, yaw_rates, walking = [], [], []
    for k in range(130):
        command = go if k < 60 else go.stopped()
        out = shaper(k * dt, q, v, command, Commands())
        speeds.append(out.base_velocity_m_s[0])
        yaw_rates.append(out.base_yaw_rate_rad_s)
        walking.append(out.walking)
    assert np.max(np.abs(np.diff(speeds))) <= 1.0 * dt + 1e-12
    assert np.max(np.abs(np.diff(yaw_rates))) <= 2.0 * dt + 1e-12
    assert max(speeds) == pytest.approx(0.6)
    still = next(k for k in range(60, 130) if speeds[k] == 0 and yaw_rates[k] == 0)
    assert still - 59 == pytest.approx(0.6 / dt)  # 0.6 s down the ramp, from the stop's own step on
    assert all(walking[60:still]) and not any(walking[still:])


def test_reference_governor_waits_for_a_robot_that_does_not_move(a1):
    shaper = CommandShaper(a1, OperatorCommand(), RampLimits(max_lead_m_s=0.15))
    q, v = a1.q_nominal, np.zeros(a1.nv)
    for k in range(100):
        out = shaper(k / 80, q, v, OperatorCommand(forward_m_s=0.8, walking=True), Commands())
    assert out.base_velocity_m_s[0] == pytest.approx(0.15)  # never more than 0.15 m/s ahead of the standing robot


def test_hand_target_becomes_a_velocity_command_towards_it(b1_z1):
    shaper = CommandShaper(b1_z1, OperatorCommand())
    q, v = b1_z1.q_nominal, np.zeros(b1_z1.nv)
    for k in range(400):  # 5 s: the target has moved its 0.1 m at 0.15 m/s
        out = shaper(k / 80, q, v, OperatorCommand(hand_offset_m=(0.1, 0.0, 0.0)), Commands())
    assert shaper.hand_offset == pytest.approx([0.1, 0.0, 0.0])
    # the hand (still at its standing place) is asked towards +x, at gain x error
    assert out.ee_velocity_m_s[0] == pytest.approx(3.0 * 0.1, rel=1e-6) and abs(out.ee_velocity_m_s[1]) < 1e-9
    free = shaper(5.0, q, v, OperatorCommand(), Commands())
    assert free.ee_velocity_m_s is None  # no target: the scenario's (here none: carried with the base)


# ---------------------------------------------------------------------------------------------------- keyboard
def test_keyboard_keys_through_a_pseudo_terminal(b1_z1):
    from wbmpc.operator.keyboard import KeyboardSource

    master, slave = pty.openpty()
    try:
        limits = OperatorLimits.for_robot(b1_z1)
        board = CommandBoard(OperatorCommand(), limits)
        echo = open(os.devnull, "w")
        source = KeyboardSource(limits, fd=slave, echo=echo)
        source.start(board)
        for keys in (b"w", b"w", b"\x1b[D", b"i", b" "):  # forward twice, turn left (arrow), hand +x, stop
            os.write(master, keys)
            time.sleep(0.15)
        seen = [p.command for p in board.history[1:]]
        source.close()
        echo.close()
    finally:
        os.close(master)
        os.close(slave)
    assert [c.forward_m_s for c in seen[:2]] == [pytest.approx(0.1), pytest.approx(0.2)] and seen[0].walking
    assert seen[2].yaw_rate_rad_s == pytest.approx(0.2)
    assert seen[3].hand_offset_m == pytest.approx((0.02, 0.0, 0.0))
    assert not seen[4].walking and not seen[4].moving and seen[4].hand_offset_m == pytest.approx((0.02, 0.0, 0.0))
    with pytest.raises(ConfigError, match="standard input is not one"):
        read, write = os.pipe()
        try:
            KeyboardSource(limits, fd=read)
        finally:
            os.close(read)
            os.close(write)


# ---------------------------------------------------------------------------------------------------- gamepad
class _VanishingPad:
    """A pad at the evdev boundary (no /dev/input here): its fd is a pipe's read end, `read` hands over queued
    evdev events and raises ENODEV once unplugged, as python-evdev does for a removed device."""

    name, path = "Test Pad", "/dev/input/event99"

    def __init__(self, events_at_start):
        self._read, self._write = os.pipe()
        self.fd = self._read
        self.events = list(events_at_start)
        self.unplugged = False
        os.write(self._write, b"x")

    def absinfo(self, code):
        from evdev import AbsInfo

        return AbsInfo(value=0, min=-32768, max=32767, fuzz=0, flat=0, resolution=0)

    def read(self):
        import errno

        if self.unplugged:
            raise OSError(errno.ENODEV, "No such device")
        os.read(self._read, 1)
        events, self.events = self.events, []
        return iter(events)

    def unplug(self):
        self.unplugged = True
        os.write(self._write, b"x")

    def close(self):
        for fd in (self._read, self._write):
            try:
                os.close(fd)
            except OSError:
                pass


def _pad_events():
    evdev = pytest.importorskip("evdev")
    e = evdev.ecodes
    return [evdev.InputEvent(0, 0, e.EV_KEY, e.BTN_START, 1), evdev.InputEvent(0, 0, e.EV_KEY, e.BTN_START, 0),
            evdev.InputEvent(0, 0, e.EV_ABS, e.ABS_Y, -32768), evdev.InputEvent(0, 0, e.EV_ABS, e.ABS_HAT0Y, -1)]


def test_gamepad_events_map_like_the_remote_and_a_vanished_pad_holds_a_stand():
    from wbmpc.operator.gamepad import GamepadSource

    pad = _VanishingPad(_pad_events())
    board = CommandBoard(OperatorCommand(), LIMITS)
    source = GamepadSource(LIMITS, device=pad)
    source.start(board)
    deadline = time.monotonic() + 5
    while board.latest().command.forward_m_s < 0.9 and time.monotonic() < deadline:
        time.sleep(0.02)
    command = board.latest().command
    assert command.walking and command.forward_m_s == pytest.approx(1.0, abs=1e-3)  # stick up: full forward
    assert command.height_offset_m == pytest.approx(0.02)  # D-pad up: +2 cm
    pad.unplug()
    while not board.notices and time.monotonic() < deadline:
        time.sleep(0.02)
    source.close()
    assert "disconnected" in board.notices[0][1] and "stand" in board.notices[0][1]
    assert not board.latest().command.walking and not board.latest().command.moving


def test_no_gamepad_is_a_clear_error():
    pytest.importorskip("evdev")
    from wbmpc.operator.gamepad import find_gamepad

    with pytest.raises(ConfigError, match="--gamepad"):
        find_gamepad("/dev/input/event-none")


# ---------------------------------------------------------------------------------------------------- runs
def _env(**extra):
    return {**os.environ, "PYTHONPATH": SRC, "MPLBACKEND": "Agg", **extra}


def test_bad_command_script_exits_2_before_anything_runs(tmp_path):
    bad = _script(tmp_path, "- {at: 0, walk: true, forward: 9}\n")
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "wbmpc", "run", "stand", "--robot", "a1", "--commands", str(bad),
                             "--out", str(out)], env=_env(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    assert "forward 9 m/s is beyond this robot's range" in result.stderr and not out.exists()
    result = subprocess.run([sys.executable, "-m", "wbmpc", "run", "stand", "--robot", "a1", "--commands",
                             str(tmp_path / "none.yaml")], env=_env(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and "no command script at" in result.stderr


def test_viewer_without_a_display_exits_2_naming_the_replay(tmp_path):
    env = {k: v for k, v in _env().items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run([sys.executable, "-m", "wbmpc", "run", "stand", "--robot", "a1", "--viewer", "--out",
                             str(tmp_path / "run")], env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    assert "--viewer" in result.stderr and "replay" in result.stderr and "DISPLAY is not set" in result.stderr


def test_a_command_script_drives_stand_walk_stop_in_one_run(a1, tmp_path):
    """A standing a1 told to walk at 0.3 m/s then to stop: it walks (planned swings), tracks the speed, stands
    again within two gait periods, and every command reached the MPC at its next step."""
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.scenarios import RunConfig, run_scenario

    script = _script(tmp_path, "duration: 3.5\ncommands:\n  - {at: 0, label: stand}\n"
                     "  - {at: 0.51, label: walk, walk: true, forward: 0.3}\n  - {at: 2.2, label: stop, stop: true}\n")
    config = RunConfig(scenario="stand", nodes=6, operator=OperatorConfig(commands_file=str(script)))
    result = run_scenario(a1, config)
    m = result.metrics
    assert not m["fell"] and m["duration_s"] == pytest.approx(3.5, abs=0.01)
    operator = m["operator"]
    assert operator["command_latency_ms"]["commands"] == 3
    assert 0 < operator["command_latency_ms"]["max"] <= 12.5 + 1e-6  # 0.51 s is between two MPC steps
    assert [t["to"] for t in operator["gait_transitions"]] == ["stand", "walk", "stand"]
    planned = np.array(result.log.planned_contact)
    steps = np.array(result.log.mpc_t)
    assert planned[steps < 0.5].min() == 1 and planned[(steps > 0.6) & (steps < 2.2)].min() == 0  # stood, then stepped
    walk = next(s for s in operator["segments"] if s["label"] == "walk")
    assert walk["base_vel_rmse"] < 0.1
    assert operator["stops"][0]["within_2_periods"]
    assert planned[steps > operator["gait_transitions"][-1]["switched_s"] + 1e-6].min() == 1  # standing to the end
    walking = result.log.command_array()[:, 11]
    assert walking[steps < 0.5].max() == 0 and walking[(steps > 0.6) & (steps < 2.2)].min() == 1


def test_a_gamepad_that_vanishes_mid_run_leaves_the_robot_standing(a1, monkeypatch):
    from wbmpc.operator import gamepad
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.scenarios import RunConfig, run_scenario

    pad = _VanishingPad(_pad_events()[:2])  # start: walk in place
    monkeypatch.setattr(gamepad, "find_gamepad", lambda path=None: pad)
    polls = {"n": 0}

    def stop() -> bool:  # unplug once the run has walked a while (polled every control tick, 500 Hz)
        polls["n"] += 1
        if polls["n"] == 400:
            pad.unplug()
        return False

    result = run_scenario(a1, RunConfig(scenario="stand", nodes=6, duration_s=2.5,
                                        operator=OperatorConfig(gamepad="auto")), stop=stop)
    m = result.metrics
    notices = m["operator"]["notices"]
    assert not m["fell"] and notices and "disconnected" in notices[0]["text"]
    lost_at = notices[0]["t_s"]
    walking = result.log.command_array()[:, 11]
    steps = np.array(result.log.mpc_t)
    assert walking[steps < lost_at].max() == 1 and walking[steps > lost_at + 0.05].max() == 0


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals of Linux")
def test_keyboard_drives_a_run_through_a_pseudo_terminal(tmp_path):
    """`wbmpc run --keyboard` in a pty: g (walk), w (forward 0.1), x (lie down: the run ends, complete)."""
    out = tmp_path / "run"
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "wbmpc", "run", "stand", "--robot", "a1", "--nodes", "4",
                             "--duration", "60", "--keyboard", "--json", "--no-outputs", "--out", str(out)],
                            stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(), text=True)
    os.close(slave)
    try:
        deadline = time.monotonic() + 400
        seen = ""
        while "keys:" not in seen and time.monotonic() < deadline:  # the help line: the terminal is read
            ready, _, _ = select.select([proc.stderr], [], [], 1.0)
            if ready:
                seen += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
        for key in (b"g", b"w", b"x"):
            time.sleep(1.0)
            os.write(master, key)
        stdout, stderr = proc.communicate(timeout=400)
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, seen + stderr
    metrics = json.loads(stdout)
    operator = metrics["operator"]
    assert "lie-down command" in operator["ended_by"] and not metrics["interrupted"]
    commands = [s["command"] for s in operator["segments"] if s["source"] == "keyboard"]
    assert commands[0]["walking"] and commands[1]["forward_m_s"] == pytest.approx(0.1)  # x ended the run at once


def test_live_meshcat_page_draws_states_and_plans(tmp_path, forward_plan):
    """deploy --meshcat's drawing process: it starts a meshcat server, draws what the loop hands over, and reports
    its frames (the rate is a measurement, reported by deploy, not asserted here)."""
    from types import SimpleNamespace

    from wbmpc.viz.live_meshcat import LiveMeshcat

    robot = load_robot("go2")
    live = LiveMeshcat(robot)
    url = live.open()
    try:
        assert url.startswith("http://127.0.0.1:")
        plan = forward_plan(robot)
        start = time.perf_counter()
        while time.perf_counter() - start < 1.5:
            q = robot.q_nominal.copy()
            q[0] = time.perf_counter() - start
            live.on_tick(SimpleNamespace(q=q, plan=plan))
            time.sleep(0.002)
    finally:
        live.close()
    summary = live.summary()
    assert summary["frames"] >= 5 and summary["plan_frames"] >= 5 and summary["rate_hz"] > 0
