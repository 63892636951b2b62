"""Robot interface: CRC and message checks, and loopback DDS runs bounded in time (robot-sim + deploy)."""

import dataclasses
import json
import os
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

sdk_mod = pytest.importorskip("wbmpc.hardware.sdk")
try:
    SDK = sdk_mod.load_sdk()
except Exception as exc:  # noqa: BLE001
    pytest.skip(f"Unitree SDK2 not installed: {exc}", allow_module_level=True)

from cli_process import WbmpcProcess  # noqa: E402

from wbmpc.estimation import SensorConfig, Sensors  # noqa: E402
from wbmpc.hardware import crc  # noqa: E402
from wbmpc.hardware.mapping import unitree_motor_map  # noqa: E402
from wbmpc.hardware.messages import (  # noqa: E402
    MessageError,
    MotorCommand,
    decode_low_cmd,
    decode_low_state,
    encode_low_cmd,
    encode_low_state,
)
from wbmpc.hardware.safety import SafetyConfig, clamp_command  # noqa: E402
from wbmpc.robots import load_robot  # noqa: E402
from wbmpc.sim import make_plant  # noqa: E402

DOMAIN = 150 + os.getpid() % 80  # a domain of its own: parallel test runs do not hear each other
Z1_PORTS = f"{30000 + 2 * (os.getpid() % 1000)},{30001 + 2 * (os.getpid() % 1000)}"  # UDP ports of their own
SRC = os.path.join(os.path.dirname(__file__), "..", "..", "src")


@pytest.fixture(scope="module")
def go2():
    return load_robot("go2")


def _sdk_reference_crc(words):
    from unitree_sdk2py.utils.crc import CRC

    return CRC.__new__(CRC)._crc_py(list(words))  # the SDK's own bitwise CRC (its .so is not in the wheel)


def test_crc_matches_the_sdk_reference(go2):
    rng = np.random.default_rng(1)
    words = rng.integers(0, 2**32, 64, dtype=np.uint64).tolist()
    assert crc.crc32_core(words) == _sdk_reference_crc(words)
    motors = unitree_motor_map(go2)
    n = go2.n_joints
    msg = encode_low_cmd(MotorCommand(rng.normal(size=n), rng.normal(size=n), np.full(n, 20.0), np.ones(n),
                                      rng.normal(size=n)), motors, echo_tick=42)
    assert msg.crc == _sdk_reference_crc(crc.payload_words(crc.pack_low_cmd(msg)))
    assert len(crc.pack_low_cmd(msg)) == 812 and len(crc.pack_low_state(SDK.new_low_state())) == 1180


def test_sdk_reader_errors_go_to_stderr(capsys):
    """The SDK's DDS reader threads print their errors: not on stdout, where `--json` prints one JSON object."""
    from unitree_sdk2py.core import channel

    channel.print("[Reader] take sample error")
    captured = capsys.readouterr()
    assert captured.out == "" and "take sample error" in captured.err


def test_messages_round_trip_and_bad_input_is_rejected(go2):
    motors = unitree_motor_map(go2)
    assert motors.slots[:3] == (3, 4, 5) and motors.slots[3:6] == (0, 1, 2)  # FL -> Unitree slots 3-5, FR -> 0-2
    plant = make_plant("mujoco", go2)
    plant.reset()
    reading = Sensors(plant, SensorConfig.noiseless()).read()
    state = decode_low_state(encode_low_state(reading, motors, tick_ms=1234), motors)
    np.testing.assert_allclose(state.joint_position_rad, reading.joint_position_rad, atol=1e-6)
    np.testing.assert_allclose(state.quaternion_xyzw, reading.quaternion_xyzw, atol=1e-6)
    assert state.time_s == pytest.approx(1.234)
    command = MotorCommand(go2.q_nominal[7:], np.zeros(12), np.full(12, 30.0), np.ones(12), np.zeros(12))
    msg = encode_low_cmd(command, motors)
    np.testing.assert_allclose(decode_low_cmd(msg, motors).q_rad, go2.q_nominal[7:], atol=1e-6)
    msg.motor_cmd[3].q += 0.1  # corrupted in transit: CRC no longer matches
    with pytest.raises(MessageError, match="CRC"):
        decode_low_cmd(msg, motors)
    bad = encode_low_cmd(MotorCommand(*(np.full(12, np.nan),) * 5), motors)
    with pytest.raises(MessageError, match="non-finite"):
        decode_low_cmd(bad, motors)
    from wbmpc.hardware.mapping import MotorMap

    front_legs = MotorMap(motors.joint_names[:6], motors.slots[:6])  # a model without hind legs
    with pytest.raises(MessageError, match="missing on the robot: none; extra on the robot: RR_hip_joint"):
        decode_low_state(encode_low_state(reading, motors, 1), front_legs)


# ---------------------------------------------------------------------------- unitree_hg (G1)
@pytest.fixture(scope="module")
def g1():
    return load_robot("g1")


def _bitwise_crc32(data: bytes) -> int:
    """CRC-32 from its definition: polynomial 0x04C11DB7, register 0xFFFFFFFF, bits most significant first, no
    reflection, no final xor (CRC-32/MPEG-2)."""
    register = 0xFFFFFFFF
    for byte in data:
        for bit in range(7, -1, -1):
            top = (register >> 31) ^ ((byte >> bit) & 1)
            register = ((register << 1) & 0xFFFFFFFF) ^ (0x04C11DB7 if top else 0)
    return register


def _words_crc(packed: bytes) -> int:
    """Unitree's CRC of a message packed in its C layout: the little-endian 32-bit words but the last (the crc
    field), each fed most significant bit first."""
    words = struct.unpack(f"<{len(packed) // 4}I", packed)[:-1]
    return _bitwise_crc32(b"".join(w.to_bytes(4, "big") for w in words))


def _hg_low_cmd_bytes(msg) -> bytes:
    """unitree_hg LowCmd_ in its C layout, written here from the struct: uint8 mode_pr, mode_machine (+2 pad);
    35 x {uint8 mode (+3 pad), float q, dq, tau, kp, kd, uint32 reserve}; uint32 reserve[4], crc."""
    out = struct.pack("<BBxx", msg.mode_pr, msg.mode_machine)
    for m in msg.motor_cmd:
        out += struct.pack("<Bxxx", m.mode) + struct.pack("<5f", m.q, m.dq, m.tau, m.kp, m.kd) + struct.pack("<I", m.reserve)
    return out + struct.pack("<5I", *msg.reserve, msg.crc)


def _hg_low_state_bytes(msg) -> bytes:
    """unitree_hg LowState_ in its C layout: uint32 version[2]; uint8 mode_pr, mode_machine (+2 pad); uint32 tick;
    IMU {float quaternion[4], gyroscope[3], accelerometer[3], rpy[3]; int16 temperature (+2 pad)}; 35 x {uint8 mode
    (+3 pad), float q, dq, ddq, tau_est; int16 temperature[2]; float vol; uint32 sensor[2], motorstate, reserve[4]};
    uint8 wireless_remote[40]; uint32 reserve[4], crc."""
    imu = msg.imu_state
    out = struct.pack("<2IBBxxI", *msg.version, msg.mode_pr, msg.mode_machine, msg.tick)
    out += struct.pack("<13fhxx", *imu.quaternion, *imu.gyroscope, *imu.accelerometer, *imu.rpy, imu.temperature)
    for m in msg.motor_state:
        out += struct.pack("<Bxxx4f2hf", m.mode, m.q, m.dq, m.ddq, m.tau_est, *m.temperature, m.vol)
        out += struct.pack("<7I", *m.sensor, m.motorstate, *m.reserve)
    return out + bytes(msg.wireless_remote) + struct.pack("<5I", *msg.reserve, msg.crc)


def _g1_reading(g1, motors):
    plant = make_plant("mujoco", g1)
    plant.reset()
    reading = Sensors(plant, SensorConfig.noiseless()).read()
    index = [g1.joint_names.index(n) for n in motors.joint_names]
    return dataclasses.replace(reading, joint_position_rad=reading.joint_position_rad[index],
                               joint_velocity_rad_s=reading.joint_velocity_rad_s[index])


def test_unitree_hg_crc_against_a_bitwise_crc32_and_the_sdk_packing(g1, monkeypatch):
    assert _bitwise_crc32(b"123456789") == 0x0376E6E7  # the catalogued check value of CRC-32/MPEG-2
    import ctypes
    import types

    from unitree_sdk2py.utils.crc import CRC

    # Unitree's own packing and bitwise CRC; the wheel lacks the C library its constructor loads
    monkeypatch.setattr(ctypes, "CDLL", lambda path: types.SimpleNamespace(crc32_core=types.SimpleNamespace()))
    sdk_crc = CRC.__new__(CRC)
    sdk_crc.__init__()
    motors = unitree_motor_map(g1)
    n = g1.n_joints
    rng = np.random.default_rng(7)
    command = MotorCommand(rng.normal(size=n), rng.normal(size=n), np.full(n, 40.0), np.full(n, 2.0), rng.normal(size=n))
    held = MotorCommand(np.full(6, 0.1), np.zeros(6), np.full(6, 10.0), np.ones(6), np.zeros(6))
    low_cmd = encode_low_cmd(command, motors, echo_tick=1234, mode_machine=5, held=held)
    packed = _hg_low_cmd_bytes(low_cmd)
    assert len(packed) == 1004 and packed == crc.pack_hg_low_cmd(low_cmd)
    assert low_cmd.crc == _words_crc(packed) == sdk_crc._crc_py(sdk_crc._CRC__PackHGLowCmd(low_cmd))
    low_state = encode_low_state(_g1_reading(g1, motors), motors, tick_ms=98765, mode_machine=5)
    packed = _hg_low_state_bytes(low_state)
    assert len(packed) == 2092 and packed == crc.pack_hg_low_state(low_state)
    assert low_state.crc == _words_crc(packed) == sdk_crc._crc_py(sdk_crc._CRC__PackHGLowState(low_state))
    low_cmd.motor_cmd[22].kp += 1.0  # one gain changed in transit
    assert crc.low_cmd_crc(low_cmd) == _words_crc(_hg_low_cmd_bytes(low_cmd)) != low_cmd.crc


def test_g1_messages_on_unitree_hg_follow_unitree_motor_order(g1):
    from wbmpc.hardware.mapping import G1_MOTOR_ORDER

    motors = unitree_motor_map(g1)
    assert motors.family == "unitree_hg" and len(G1_MOTOR_ORDER) == 29
    slot = dict(zip(motors.joint_names, motors.slots))
    # Unitree's G1 order: legs left then right (hip pitch, roll, yaw, knee, ankle pitch, roll), waist yaw, roll,
    # pitch, arms left then right (shoulder pitch, roll, yaw, elbow, wrist roll, pitch, yaw)
    assert (slot["left_hip_pitch_joint"], slot["left_knee_joint"], slot["right_hip_pitch_joint"],
            slot["right_ankle_roll_joint"], slot["waist_yaw_joint"], slot["waist_pitch_joint"],
            slot["left_shoulder_pitch_joint"], slot["left_elbow_joint"], slot["right_shoulder_pitch_joint"],
            slot["right_elbow_joint"]) == (0, 3, 6, 11, 12, 14, 15, 18, 22, 25)
    assert {h.joint_name: h.slot for h in motors.held} == {  # g1 locks its wrists: held at their reference
        "left_wrist_roll_joint": 19, "left_wrist_pitch_joint": 20, "left_wrist_yaw_joint": 21,
        "right_wrist_roll_joint": 26, "right_wrist_pitch_joint": 27, "right_wrist_yaw_joint": 28}
    reading = _g1_reading(g1, motors)
    msg = encode_low_state(reading, motors, tick_ms=5000, mode_machine=5)
    assert msg.motor_state[3].q == pytest.approx(reading.joint_position_rad[3], abs=1e-6)  # left knee
    assert sorted(i for i, m in enumerate(msg.motor_state) if m.temperature[0] > 0) == list(range(29))
    state = decode_low_state(msg, motors)
    np.testing.assert_allclose(state.joint_position_rad, reading.joint_position_rad, atol=1e-6)
    assert state.time_s == pytest.approx(5.0)
    n = g1.n_joints
    command = MotorCommand(g1.q_nominal[7:], np.zeros(n), np.full(n, 50.0), np.ones(n), np.zeros(n))
    low_cmd = encode_low_cmd(command, motors, mode_machine=5)
    assert low_cmd.mode_pr == 0 and low_cmd.mode_machine == 5
    np.testing.assert_allclose(decode_low_cmd(low_cmd, motors, mode_machine=5).q_rad, g1.q_nominal[7:], atol=1e-6)
    with pytest.raises(MessageError, match="mode_machine 5 is not the robot's \\(4"):
        decode_low_cmd(low_cmd, motors, mode_machine=4)
    low_cmd.mode_pr = 1  # AB: the ankles' parallel motors, not the model's joints
    low_cmd.crc = crc.low_cmd_crc(low_cmd)
    with pytest.raises(MessageError, match="mode_pr 1"):
        decode_low_cmd(low_cmd, motors)


def test_g1_crouches_on_joint_pd_and_its_gantry_catches_it_in_damping(g1):
    """Posture: G1 holds its stance and crouches on joint PD (no MPC); damped, it sinks into robot-sim's gantry
    strap, which stayed slack until then; without the strap, damping lays it on its back."""
    from wbmpc.hardware.gantry import Gantry
    from wbmpc.hardware.safety import Posture, fallen, lying_joint_positions

    def run(gantry: bool):
        plant = make_plant("mujoco", g1)
        plant.reset()
        strap = Gantry(plant, g1) if gantry else None
        if strap is not None:
            plant.add_step_hook(strap)
        posture, crouch, nominal = Posture(g1, SafetyConfig()), lying_joint_positions(g1), g1.q_nominal[7:]
        heights = []
        for k in range(4000):  # 1 ms steps: hold 0.5 s, crouch 1.5 s, damping 2 s
            q, v = plant.state()
            t = k * plant.dt_s
            command = (posture.command(nominal, nominal, 1.0, 0.0) if t < 0.5 else
                       posture.command(nominal, crouch, t - 0.5, 1.5) if t < 2.0 else None)
            plant.step(command.torque(q[7:], v[6:]) if command else -5.0 * v[6:])
            heights.append(q[2])
            if t < 2.0:
                assert not fallen(g1, q, SafetyConfig()), t
        return strap, heights, fallen(g1, plant.state()[0], SafetyConfig())

    strap, heights, fell = run(gantry=True)
    assert heights[1999] < 0.85 * g1.q_nominal[2] and not fell  # crouched, then hanging in the strap
    assert strap.taut_since_s is not None and strap.taut_since_s > 2.0 and strap.max_force_n > 200
    assert run(gantry=False)[2]


# ---------------------------------------------------------------------------- robot link
@pytest.mark.parametrize("name", ["go2", "g1"])
def test_unset_low_states_are_refused_on_the_robot_link_and_accepted_on_sim(name, go2, g1):
    """What Unitree's simulator publishes (header, CRC, tick and temperatures left at 0): the strict link rejects each
    and its error counts and names them; the sim link accepts them and reads time from the receive clock."""
    from wbmpc.hardware.link import LowStateLink
    from wbmpc.hardware.messages import leave_unset

    robot = go2 if name == "go2" else g1
    motors = unitree_motor_map(robot)
    plant = make_plant("mujoco", robot)
    plant.reset()
    reading = Sensors(plant, SensorConfig.noiseless()).read()
    index = [robot.joint_names.index(n) for n in motors.joint_names]
    reading = dataclasses.replace(reading, joint_position_rad=reading.joint_position_rad[index],
                                  joint_velocity_rad_s=reading.joint_velocity_rad_s[index])
    unset = ["CRC 0", "tick 0", "motor temperatures 0"] if name == "g1" else ["header [0, 0]", "CRC 0", "tick 0",
                                                                              "motor temperatures 0"]
    strict, sim = LowStateLink(motors, "robot"), LowStateLink(motors, "sim")
    for k in range(7):
        msg = encode_low_state(reading, motors, tick_ms=1000 + 2 * k, mode_machine=5)
        leave_unset(msg)
        with pytest.raises(MessageError) as rejected:
            strict.reading(msg, 50.0 + 0.005 * k)
        assert list(rejected.value.reasons) == unset
        state = sim.reading(msg, 50.0 + 0.005 * k)
        assert state.time_s == pytest.approx(0.005 * k)  # the receive clock, from the first LowState
        np.testing.assert_allclose(state.joint_position_rad, reading.joint_position_rad, atol=1e-6)
    message = strict.all_rejected_message("rt/lowstate", 2.0)
    assert message.startswith("7 LowStates received on 'rt/lowstate' within 2.0 s, all rejected: ")
    assert all(f"{field} (7)" in message for field in unset) and message.endswith("run with --robot-link sim")
    assert sim.summary()["time_source"] == "receive clock" and sim.summary()["accepted_unset"] == dict.fromkeys(unset, 7)
    msg.crc = 12345  # a CRC that is set must be right, on either link
    with pytest.raises(MessageError, match="CRC mismatch"):
        sim.reading(msg, 51.0)
    good = encode_low_state(reading, motors, tick_ms=3000, mode_machine=5)  # a robot's LowState
    assert strict.reading(good, 52.0).time_s == pytest.approx(3.0)
    with pytest.raises(MessageError, match="does not advance"):
        strict.reading(good, 52.002)  # the same tick again


@pytest.mark.parametrize("speed", [1.0, 0.6])
def test_the_link_measures_the_robots_clock_against_its_own(go2, speed):
    """A simulator at `speed` x the wall clock behind the receive clock: joint motion (position change against the
    reported velocity) tells the rate; on a robot's tick clock it reads 1."""
    from wbmpc.estimation.sensors import SensorReadings
    from wbmpc.hardware.link import LowStateLink
    from wbmpc.hardware.messages import leave_unset

    motors = unitree_motor_map(go2)
    sim, robot = LowStateLink(motors, "sim"), LowStateLink(motors, "robot")
    rng = np.random.default_rng(3)
    for k in range(400):
        received_s = 0.005 * k
        t = speed * received_s  # the robot's time
        phase = 2 * np.pi * 2.0 * t + np.arange(12)
        q = go2.q_nominal[7:] + 0.3 * np.sin(phase)
        dq = 0.3 * 2 * np.pi * 2.0 * np.cos(phase) + rng.normal(0, 0.02, 12)  # Unitree-like velocity noise
        reading = SensorReadings(t, np.array([0, 0, 0, 1.0]), np.zeros(3), np.array([0, 0, 9.81]), q, dq, np.full(4, np.nan))
        msg = encode_low_state(reading, motors, tick_ms=1000 + round(1e3 * t))
        robot.reading(msg, received_s)
        leave_unset(msg)
        sim.reading(msg, received_s)
    assert sim.clock_rate == pytest.approx(speed, rel=0.03) and robot.clock_rate == pytest.approx(1.0, rel=0.03)


def test_unitree_simulator_link_has_no_lock_step():
    from wbmpc.errors import ConfigError
    from wbmpc.hardware.deploy import DeployConfig
    from wbmpc.hardware.robot_sim import RobotSimConfig

    with pytest.raises(ConfigError, match="drop --lockstep"):
        DeployConfig(robot_link="sim", lockstep=True)
    with pytest.raises(ConfigError, match="--mode realtime"):
        RobotSimConfig(robot_link="sim", mode="lockstep")
    with pytest.raises(ConfigError, match="--robot-link must be robot"):
        DeployConfig(robot_link="mujoco")


def test_robot_sim_imitating_unitree_simulator_holds_each_low_cmd_torque(go2):
    """robot-sim --robot-link sim: a LowCmd's motor law is evaluated once, with the joints of that moment, and that
    torque is held while the robot moves; no CRC or header check (a forged CRC is applied, as unitree_mujoco does)."""
    from wbmpc.hardware.robot_sim import RobotSimConfig, RobotSimulator

    sim = RobotSimulator(go2, RobotSimConfig(robot_link="sim"))
    motors = sim.motors
    n = go2.n_joints
    target = go2.q_nominal[7:] + 0.1
    msg = encode_low_cmd(MotorCommand(target, np.zeros(n), np.full(n, 20.0), np.full(n, 0.5), np.full(n, 1.0)), motors)
    msg.crc ^= 1  # unchecked on this link
    q_now, dq_now = go2.q_nominal[7:].copy(), np.full(n, 0.2)
    sim.joint_readings = (q_now, dq_now)
    sim.on_low_cmd(msg)
    held = sim.held_command
    expected = 1.0 + 20.0 * (target - q_now) + 0.5 * (0.0 - dq_now)
    np.testing.assert_allclose(held.torque(q_now + 0.3, dq_now - 1.0), expected, atol=1e-5)  # held as the robot moves
    assert sim.report.commands_received == 1 and sim.rejected_counts == {}
    strict = RobotSimulator(go2, RobotSimConfig())
    strict.on_low_cmd(msg)
    assert strict.held_command is None and strict.rejected_counts == {"crc": 1}


def test_clamps_keep_targets_and_torques_in_limits(go2):
    n = go2.n_joints
    q = go2.q_nominal[7:]
    wild = MotorCommand(q + 10.0, np.zeros(n), np.full(n, 1e4), np.full(n, 1e3), np.full(n, 1e3))
    safe = clamp_command(go2, wild, q, np.zeros(n), SafetyConfig())
    assert np.all(safe.q_rad <= go2.model.upperPositionLimit[7:])
    assert np.all(safe.kp <= 500) and np.all(safe.kd <= 50)
    assert np.all(np.abs(safe.torque(q, np.zeros(n))) <= go2.tau_max + 1e-9)


# ---------------------------------------------------------------------------- loopback DDS
def _cli(*args):
    return WbmpcProcess(*args)


def _robot_sim(*args, family: str = "unitree_go", timeout_s: float = 300.0):
    """`wbmpc robot-sim ARGS`, returned once its first LowState is heard on the test domain: it builds its MuJoCo
    scene first (seconds on a loaded machine), and deploy's 2 s wait for a first LowState is meant for the link, not
    for robot-sim's start. Needs the test domain (`dds_domain`)."""
    import threading

    heard = threading.Event()
    listener = SDK.ChannelSubscriber("rt/lowstate", SDK.idl(family).LowState_)
    listener.Init(lambda msg: heard.set(), 0)
    sim = _cli("robot-sim", *args)
    try:
        started = heard.wait(timeout_s)
    finally:
        listener.Close()
    if not started:
        sim.kill()
        out, err = sim.communicate(timeout=60)
        raise AssertionError(f"robot-sim published no LowState within {timeout_s:.0f} s: {err}")
    return sim


@pytest.fixture(scope="module")
def dds_domain():
    SDK.ChannelFactoryInitialize(DOMAIN, "lo")
    return DOMAIN


@pytest.fixture
def dds(dds_domain):
    """The LowCmds heard on the test domain (this process only listens: forged commands come from a child)."""
    heard = []
    sub = SDK.ChannelSubscriber("rt/lowcmd", SDK.LowCmd_)
    sub.Init(lambda msg: heard.append(msg), 0)
    yield heard
    sub.Close()


def test_no_low_state_means_exit_without_commanding(dds):
    heard = dds
    heard.clear()
    proc = _cli("deploy", "--robot", "go2", "--domain", str(DOMAIN), "--scenario", "stand", "--lockstep", "--nodes", "4")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1  # the run failed (nothing was commanded); not bad input
    assert "no LowState" in err and "Nothing was commanded" in err
    assert heard == []
    proc = _cli("deploy", "--robot", "go2", "--network", "nosuchif0")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "unknown network interface 'nosuchif0'" in err and "lo" in err


def test_a_silent_arm_means_exit_before_any_leg_command(dds):
    heard = dds
    heard.clear()
    sim = _robot_sim("--robot", "b1_z1", "--arm", "none", "--domain", str(DOMAIN), "--idle-exit", "60", "--json")
    try:
        proc = _cli("deploy", "--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
                    "--scenario", "stand", "--lockstep", "--nodes", "4")
        _, err = proc.communicate(timeout=120)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.communicate(timeout=60)
    assert proc.returncode == 1 and "the Z1 arm sent no valid state within 2.0 s" in err, err
    assert heard == []


def test_unitree_simulator_low_states_are_refused_by_name_on_the_robot_link(dds):
    """robot-sim --robot-link sim publishes as Unitree's simulator does: the strict deploy hears it, rejects every
    LowState, says how many and why, points to --robot-link sim and commands nothing."""
    heard = dds
    heard.clear()
    sim = _robot_sim("--robot", "go2", "--robot-link", "sim", "--domain", str(DOMAIN), "--idle-exit", "60", "--json")
    try:
        proc = _cli("deploy", "--robot", "go2", "--domain", str(DOMAIN), "--no-sport-release", "--scenario", "stand")
        _, err = proc.communicate(timeout=120)
    finally:
        sim.send_signal(signal.SIGINT)
        out, sim_err = sim.communicate(timeout=60)
    assert proc.returncode == 2, err
    line = next(x for x in err.splitlines() if "LowStates received" in x)
    count = int(line.split("error: ")[1].split(" LowStates")[0])
    assert count > 0 and "within 2.0 s, all rejected: " in line
    assert all(f"{field} ({count})" in line for field in ("header [0, 0]", "CRC 0", "tick 0", "motor temperatures 0"))
    assert "--robot-link sim" in line and "Nothing was commanded" in line
    assert heard == [] and json.loads(out)["commands_received"] == 0, sim_err


def test_dds_bench_speaks_unitree_hg_for_g1(dds_domain):
    proc = _cli("bench", "dds", "--robot", "g1", "--domain", str(DOMAIN), "--samples", "60", "--rate", "200", "--json")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    result = json.loads(out)
    assert result["family"] == "unitree_hg" and result["samples"] > 0 and result["rtt_ms_p50"] > 0


_FORGER = """
import sys, time
from wbmpc.hardware.sdk import load_sdk
from wbmpc.hardware.mapping import unitree_motor_map
from wbmpc.hardware.messages import MotorCommand, encode_low_cmd
from wbmpc.robots import load_robot
sdk = load_sdk()
sdk.ChannelFactoryInitialize(int(sys.argv[1]), "lo")
robot = load_robot("go2")
forged = encode_low_cmd(MotorCommand.damping(robot.n_joints, 1.0), unitree_motor_map(robot))
forged.crc ^= 1
pub = sdk.ChannelPublisher("rt/lowcmd", sdk.LowCmd_)
pub.Init()
time.sleep(0.5)  # discovery
for _ in range(int(sys.argv[2])):
    pub.Write(forged)
    time.sleep(0.005)
time.sleep(0.5)
"""


def _publish_bad_crc_commands(count: int) -> None:
    """LowCmds with a wrong CRC, from a process of their own: a DataWriter.write that blocks (it hung this
    test process twice, holding the GIL) can then be ended by the timeout."""
    env = dict(os.environ, PYTHONPATH=os.path.abspath(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    subprocess.run([sys.executable, "-c", _FORGER, str(DOMAIN), str(count)], env=env, timeout=120, check=True,
                   capture_output=True)


def test_watchdog_fires_when_the_controller_is_killed_and_bad_crc_is_rejected(go2, dds):
    """b1_z1: legs over DDS, the Z1 over UDP (robot-sim --arm z1); both go to damping when deploy is killed."""
    heard = dds
    heard.clear()
    sim = _robot_sim("--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
                     "--idle-exit", "120", "--watchdog-ms", "300", "--json")  # 300 ms: a loaded 2-core machine stalls
    controller = _cli("deploy", "--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
                      "--scenario", "stand", "--lockstep", "--nodes", "4", "--duration", "30")
    try:
        deadline = time.monotonic() + 300  # b1_z1 builds slower than go2 on a loaded machine
        while len(heard) < 200 and time.monotonic() < deadline:  # MPC built, robot being stood up over DDS
            time.sleep(0.1)
        assert controller.poll() is None and len(heard) >= 200, controller.read_errors()
        _publish_bad_crc_commands(count=20)
        time.sleep(0.5)
        controller.send_signal(signal.SIGKILL)
        time.sleep(1.0)
        sim.send_signal(signal.SIGINT)  # robot-sim stops cleanly on Ctrl-C and prints its report
        out, err = sim.communicate(timeout=60)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    report = json.loads(out)
    assert report["commands_received"] > 100, err
    assert report["commands_rejected"].get("crc", 0) >= 10
    assert report["watchdog_events_s"], "the robot never went to damping"
    assert report["damping_at_end"]  # after the kill the motors stayed in damping
    arm = report["arm"]
    assert arm["commands_received"] > 100 and arm["watchdog_events"] >= 1 and arm["passive_at_end"], arm
    assert report["sport_mode_at_end"] == "", report["sport_calls"]  # released (killed before restoring it)


@pytest.mark.slow
def test_loop_closes_through_dds_and_the_robot_stays_up(dds):
    sim = _robot_sim("--robot", "go2", "--domain", str(DOMAIN), "--mode", "lockstep", "--duration", "9",
                     "--idle-exit", "60", "--json")
    controller = _cli("deploy", "--robot", "go2", "--domain", str(DOMAIN), "--scenario", "stand", "--lockstep",
                      "--nodes", "6", "--duration", "2", "--json")
    try:
        c_out, c_err = controller.communicate(timeout=900)
        s_out, _ = sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    deploy, robot = json.loads(c_out), json.loads(s_out)
    assert [p for _, p in deploy["phases"]] == ["stand-up", "hold", "mpc", "lie-down", "damping"], c_err
    assert deploy["mpc_solves"] >= 150 and not deploy["fell"]
    assert robot["commands_received"] > 1000 and not robot["watchdog_events_s"][:-1]
    standing = [row for row in robot["trajectory"] if 2.5 <= row[0] <= 4.5]  # the MPC phase, robot time
    assert min(row[3] for row in standing) > 0.8 * 0.33 and max(row[4] for row in standing) < 10


@pytest.mark.slow
def test_deploy_identifies_a_payload_the_model_does_not_know(dds):
    """robot-sim carries 2 kg at the base origin that the controller's model lacks; deploy --identify-mass estimates
    it from the estimated state and the motor law's torques (lock-step, trot in place)."""
    sim = _cli("robot-sim", "--robot", "go2", "--domain", str(DOMAIN), "--mode", "lockstep", "--duration", "12",
               "--plant-payload-kg", "2.0", "--idle-exit", "600", "--json")
    controller = _cli("deploy", "--robot", "go2", "--domain", str(DOMAIN), "--scenario", "trot-in-place", "--lockstep",
                      "--nodes", "6", "--duration", "5", "--identify-mass", "--json")
    try:
        c_out, c_err = controller.communicate(timeout=1800)
        sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    deploy = json.loads(c_out)
    assert not deploy["fell"] and "mpc" in [p for _, p in deploy["phases"]], c_err
    assert deploy["payload_estimate_kg"] == pytest.approx(2.0, abs=0.5), deploy["inertial_estimate_history"][-5:]
    assert np.linalg.norm(deploy["base_com_offset_estimate_m"][:2]) < 0.02
    assert deploy["joint_loop"]["kd_leg"] == pytest.approx(2.5694, rel=1e-3)  # a robot link: the tuned Kd


@pytest.mark.slow
def test_ctrl_c_lies_the_robot_down_then_damps(go2, dds):
    heard = dds
    heard.clear()
    sim = _robot_sim("--robot", "go2", "--domain", str(DOMAIN), "--mode", "lockstep", "--duration", "8",
                     "--idle-exit", "30", "--json")
    controller = _cli("deploy", "--robot", "go2", "--domain", str(DOMAIN), "--scenario", "stand", "--lockstep",
                      "--nodes", "4", "--duration", "30", "--json")
    try:
        deadline = time.monotonic() + 300
        while len(heard) < 600 and time.monotonic() < deadline:  # a second into the stand-up
            time.sleep(0.1)
        controller.send_signal(signal.SIGINT)
        c_out, c_err = controller.communicate(timeout=300)
        sim.send_signal(signal.SIGINT)
        s_out, _ = sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    deploy, robot = json.loads(c_out), json.loads(s_out)
    assert deploy["stopped_by"] == "ctrl-c", c_err
    assert [p for _, p in deploy["phases"]][-2:] == ["lie-down", "damping"]
    assert max(row[4] for row in robot["trajectory"]) < 30  # lay down, did not tip over
    assert not robot["fell"] and robot["base_height_min_m"] < 0.6 * go2.q_nominal[2]  # low on purpose is no fall


@pytest.mark.slow
def test_real_time_deploy_trots_b1_z1_with_the_arm_over_udp(dds):
    """Real time (no lock-step): legs over DDS, the Z1 over UDP, MPC in its own process; a short trot in place."""
    sim = _robot_sim("--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
                     "--idle-exit", "600", "--watchdog-ms", "500", "--json")  # idle from the start: the build is slow
    # timeouts for a loaded 2-core machine (the defaults, 100 ms and 250 ms, are for the robot's computer)
    controller = _cli("deploy", "--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
                      "--scenario", "trot-in-place", "--nodes", "8", "--duration", "3", "--state-timeout-ms", "500",
                      "--max-plan-age-ms", "1000", "--json")
    try:
        c_out, c_err = controller.communicate(timeout=900)
        sim.send_signal(signal.SIGINT)
        s_out, _ = sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    deploy, robot = json.loads(c_out), json.loads(s_out)
    assert [p for _, p in deploy["phases"]] == ["stand-up", "hold", "mpc", "lie-down", "damping"], c_err
    assert not deploy["fell"] and deploy["arm"]["commands_sent"] > 1000 and deploy["sport_mode"]["restored"]
    assert robot["arm"]["commands_received"] > 1000 and robot["arm"]["rtt_ms_p50"] is not None
    assert robot["rtt_ms_p50"] is not None and robot["sport_mode_at_end"] == "normal"


@pytest.mark.slow
def test_deploy_runs_on_the_unitree_simulator_link(dds):
    """deploy --robot-link sim against robot-sim imitating Unitree's simulator (unset fields, 200 Hz, the motor law
    once per LowCmd, held): every LowState accepted with its unset fields counted, time from the receive clock;
    the robot applies every LowCmd. Real time (the simulator has no lock-step): timeouts for a loaded machine, where
    the robot process falls behind the wall clock that the controller reads (standing up is not asserted)."""
    sim = _robot_sim("--robot", "go2", "--robot-link", "sim", "--domain", str(DOMAIN), "--idle-exit", "600",
                     "--json")
    controller = _cli("deploy", "--robot", "go2", "--robot-link", "sim", "--domain", str(DOMAIN), "--no-sport-release",
                      "--scenario", "stand", "--nodes", "6", "--duration", "1", "--state-timeout-ms", "1000",
                      "--max-plan-age-ms", "2000", "--json")
    try:
        c_out, c_err = controller.communicate(timeout=900)
        sim.send_signal(signal.SIGINT)
        s_out, _ = sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    deploy, robot = json.loads(c_out), json.loads(s_out)
    assert deploy["phases"][0][1] == "stand-up" and deploy["states_received"] > 0, c_err  # commanding (a loaded
    # machine starves the robot process: the motor law held for tens of ms may tip the robot before the MPC)
    assert deploy["robot_link"] == "sim" and deploy["time_source"] == "receive clock" and deploy["states_rejected"] == {}
    accepted = deploy["states_received"] + 1  # and the first one, checked before the MPC build
    assert deploy["accepted_unset"] == dict.fromkeys(["header [0, 0]", "CRC 0", "tick 0", "motor temperatures 0"], accepted)
    assert robot["commands_received"] == deploy["commands_sent"] > 0 and robot["commands_rejected"] == {}
    assert robot["sport_calls"] == [] and not robot["watchdog_events_s"]  # no motion switcher, no watchdog


@pytest.mark.slow
def test_g1_stands_crouches_and_damps_over_unitree_hg(dds):
    """G1 over unitree_hg in lock-step: stand-up on joint PD, MPC, the crouch, damping; its mode_machine echoed,
    no LowCmd rejected, the wrists held, no fall."""
    sim = _robot_sim("--robot", "g1", "--domain", str(DOMAIN), "--mode", "lockstep", "--duration", "6",
                     "--idle-exit", "120", "--gantry", "--json", family="unitree_hg")
    controller = _cli("deploy", "--robot", "g1", "--domain", str(DOMAIN), "--scenario", "stand", "--lockstep",
                      "--nodes", "4", "--duration", "0.5", "--json")
    try:
        c_out, c_err = controller.communicate(timeout=900)
        sim.send_signal(signal.SIGINT)
        s_out, _ = sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    deploy, robot = json.loads(c_out), json.loads(s_out)
    assert [p for _, p in deploy["phases"]] == ["stand-up", "hold", "mpc", "lie-down", "damping"], c_err
    assert not deploy["fell"] and deploy["mode_machine"] == 5 and deploy["mpc_failures"] == 0
    assert robot["commands_received"] > 2000 and robot["commands_rejected"] == {} and not robot["fell"]
    crouch = [row for row in robot["trajectory"] if 4.9 <= row[0] <= 5.2]  # the lie-down's end, robot time
    assert max(row[4] for row in robot["trajectory"]) < 15 and max(row[3] for row in crouch) < 0.7
    damping = deploy["phases"][-1][0] - deploy["phases"][0][0]  # robot time from the first LowCmd
    assert robot["gantry"]["taut_since_s"] is None or robot["gantry"]["taut_since_s"] > damping  # slack until then
