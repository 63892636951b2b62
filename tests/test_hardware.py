"""Robot interface: CRC and message checks, and loopback DDS runs bounded in time (robot-sim + deploy)."""

import json
import os
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest

sdk_mod = pytest.importorskip("wbmpc.hardware.sdk")
try:
    SDK = sdk_mod.load_sdk()
except Exception as exc:  # noqa: BLE001
    pytest.skip(f"Unitree SDK2 not installed: {exc}", allow_module_level=True)

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
SRC = os.path.join(os.path.dirname(__file__), "..", "src")


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
    assert msg.crc == _sdk_reference_crc(crc._words(crc.pack_low_cmd(msg)))
    assert len(crc.pack_low_cmd(msg)) == 812 and len(crc.pack_low_state(SDK.new_low_state())) == 1180


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
        decode_low_state(encode_low_state(reading, motors, 0), front_legs)


def test_clamps_keep_targets_and_torques_in_limits(go2):
    n = go2.n_joints
    q = go2.q_nominal[7:]
    wild = MotorCommand(q + 10.0, np.zeros(n), np.full(n, 1e4), np.full(n, 1e3), np.full(n, 1e3))
    safe = clamp_command(go2, wild, q, np.zeros(n), SafetyConfig())
    assert np.all(safe.q_rad <= go2.model.upperPositionLimit[7:])
    assert np.all(safe.kp <= 500) and np.all(safe.kd <= 50)
    assert np.all(np.abs(safe.torque(q, np.zeros(n))) <= go2.tau_max + 1e-9)


# ---------------------------------------------------------------------------- loopback DDS
class _Cli(subprocess.Popen):
    """A `wbmpc` child whose output goes to temporary files, not pipes: a pipe this test reads only at
    the end can fill (robot-sim's report holds its trajectory), block the child and, through its
    stalled DDS reader, this process's DataWriter.write; the suite hung on that once."""

    def __init__(self, *args):
        env = dict(os.environ, PYTHONPATH=os.path.abspath(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self._stdout_file, self._stderr_file = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")
        super().__init__([sys.executable, "-m", "wbmpc.cli", *args], env=env, stdout=self._stdout_file, stderr=self._stderr_file,
                         text=True)

    def communicate(self, input=None, timeout=None):
        self.wait(timeout)
        return self.read_output(), self.read_errors()

    def read_output(self) -> str:
        self._stdout_file.seek(0)
        return self._stdout_file.read()

    def read_errors(self) -> str:
        self._stderr_file.seek(0)
        return self._stderr_file.read()


def _cli(*args):
    return _Cli(*args)


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
    sim = _cli("robot-sim", "--robot", "b1_z1", "--arm", "none", "--domain", str(DOMAIN), "--idle-exit", "60", "--json")
    try:
        proc = _cli("deploy", "--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
                    "--scenario", "stand", "--lockstep", "--nodes", "4")
        _, err = proc.communicate(timeout=120)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.communicate(timeout=60)
    assert proc.returncode == 1 and "the Z1 arm sent no valid state within 2.0 s" in err, err
    assert heard == []


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
    sim = _cli("robot-sim", "--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
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
    sim = _cli("robot-sim", "--robot", "go2", "--domain", str(DOMAIN), "--mode", "lockstep", "--duration", "9",
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
def test_ctrl_c_lies_the_robot_down_then_damps(dds):
    heard = dds
    heard.clear()
    sim = _cli("robot-sim", "--robot", "go2", "--domain", str(DOMAIN), "--mode", "lockstep", "--duration", "8",
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


@pytest.mark.slow
def test_real_time_deploy_trots_b1_z1_with_the_arm_over_udp(dds):
    """Real time (no lock-step): legs over DDS, the Z1 over UDP, MPC in its own process; a short trot in place."""
    sim = _cli("robot-sim", "--robot", "b1_z1", "--arm", "z1", "--z1-ports", Z1_PORTS, "--domain", str(DOMAIN),
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
