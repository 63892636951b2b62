"""The robot's remote end to end: robot-sim writes a scripted remote into LowState (CRC valid) and onto
rt/wirelesscontroller; deploy decodes it and the MPC walks, turns, stops and lies down on the keys."""

import json
import os
import signal

import numpy as np
import pytest

sdk_mod = pytest.importorskip("wbmpc.hardware.sdk")
try:
    SDK = sdk_mod.load_sdk()
except Exception as exc:  # noqa: BLE001
    pytest.skip(f"Unitree SDK2 not installed: {exc}", allow_module_level=True)

from cli_process import WbmpcProcess  # noqa: E402

from wbmpc.estimation import SensorConfig, Sensors  # noqa: E402
from wbmpc.hardware.mapping import unitree_motor_map  # noqa: E402
from wbmpc.hardware.messages import decode_low_state, encode_low_state  # noqa: E402
from wbmpc.operator.remote import decode_remote  # noqa: E402
from wbmpc.operator.remote_script import RemotePublisher, ScriptedRemote, read_remote_script  # noqa: E402
from wbmpc.robots import load_robot  # noqa: E402
from wbmpc.sim import make_plant  # noqa: E402

DOMAIN = 150 + (os.getpid() + 37) % 80
EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "..", "examples")


def test_robot_sim_writes_the_scripted_remote_into_low_state_with_a_valid_crc(tmp_path):
    robot = load_robot("go2")
    motors = unitree_motor_map(robot)
    plant = make_plant("mujoco", robot)
    plant.reset()
    reading = Sensors(plant, SensorConfig.noiseless()).read()
    script = tmp_path / "remote.yaml"
    script.write_text("remote:\n  - {at: 1.0, press: start}\n  - {at: 2.0, ly: 0.5, rx: -0.25}\n"
                      "  - {at: 3.0, press: [L2, A]}\n")
    publisher = RemotePublisher(ScriptedRemote(read_remote_script(script)), topic=False)
    expected = {0.5: ((), 0.0, 0.0), 1.1: (("start",), 0.0, 0.0), 1.3: ((), 0.0, 0.0), 2.5: ((), 0.5, -0.25),
                3.1: (("L2", "A"), 0.5, -0.25)}
    for t, (keys, ly, rx) in expected.items():
        message = encode_low_state(reading, motors, tick_ms=int(1e3 * t))
        publisher.write(message, t)
        decode_low_state(message, motors)  # the CRC covers the remote's bytes: still valid
        state = decode_remote(message.wireless_remote)
        assert state.key_names == keys and (state.ly, state.rx) == (ly, rx), t
    message.wireless_remote[4] ^= 0x10  # a remote byte changed in transit: the LowState is refused
    with pytest.raises(Exception, match="CRC"):
        decode_low_state(message, motors)
    assert np.isclose(read_remote_script(os.path.join(EXAMPLES, "remote_session.yaml"))[-1].at_s, 16.0)


def _deploy_with_remote(remote_yaml: str, *deploy_args, sim_args=()):
    sim = WbmpcProcess("robot-sim", "--robot", "go2", "--domain", str(DOMAIN), "--idle-exit", "600", "--watchdog-ms", "500",
               "--remote-script", remote_yaml, "--json", *sim_args)
    controller = WbmpcProcess("deploy", "--robot", "go2", "--domain", str(DOMAIN), "--scenario", "stand", "--remote",
                      "--state-timeout-ms", "500", "--max-plan-age-ms", "1000", "--json", *deploy_args)
    try:
        c_out, c_err = controller.communicate(timeout=1500)
        sim.send_signal(signal.SIGINT)
        s_out, _ = sim.communicate(timeout=120)
    finally:
        for proc in (sim, controller):
            if proc.poll() is None:
                proc.kill()
    return json.loads(c_out), json.loads(s_out), c_err


@pytest.mark.slow
def test_real_time_deploy_walks_turns_stops_and_lies_down_on_the_remote(tmp_path):
    """Real time: robot-sim's scripted remote (LowState bytes and the topic) drives deploy's MPC through walk, turn,
    stop and the lie-down key, and the robot stays up."""
    deploy, robot, err = _deploy_with_remote(os.path.join(EXAMPLES, "remote_session.yaml"), "--compiled", "--meshcat")
    assert [p for _, p in deploy["phases"]] == ["stand-up", "hold", "mpc", "lie-down", "damping"], err
    assert deploy["stopped_by"] == "operator" and not deploy["fell"], err
    operator = deploy["operator"]
    commands = [s["command"] for s in operator["segments"]]
    assert any(c["walking"] and c["forward_m_s"] > 0.3 for c in commands)  # the stick forward
    assert any(c["walking"] and c["yaw_rate_rad_s"] < -0.3 for c in commands)  # turning right
    assert [t["to"] for t in operator["gait_transitions"]][-2:] == ["walk", "stand"]
    assert operator["stops"] and operator["stops"][0]["within_2_periods"]  # L2+A: stopped_by operator, above
    assert operator["remote"]["received"]["lowstate"] >= 5 and operator["remote"]["received"]["topic"] >= 5
    assert operator["command_latency_ms"]["max"] <= 12.5 + 2.0  # one MPC period (+ a 2 ms LowState tick)
    assert operator["meshcat"]["rate_hz"] >= 20
    walk = next(s for s in operator["segments"] if s["command"]["forward_m_s"] > 0.3)
    assert walk["base_vel_rmse"] < 0.15  # from the estimated state
    assert robot["fell"] is False or robot["fell_at_s"] > deploy["phases"][3][0]  # a lie-down is flagged as a fall
