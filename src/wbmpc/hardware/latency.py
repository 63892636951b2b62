"""DDS round trip on an interface: LowState out, LowCmd back from an echo process, both CRC-checked.

Ping-pong at up to `rate_hz`: each LowState waits for its answer (up to 1 s) before the next one,
so a slow (CPU-starved) process shows as a long round trip, not as a queue that grows without end.

The echo process decodes each LowState (CRC, motor set) and answers with a LowCmd echoing its
tick, so the figure covers DDS transport plus the message encoding and checks on both sides, and
none of a controller's work (`robot-sim` reports the round trip including the controller). The messages
are the robot's family: unitree_go for quadrupeds, unitree_hg (G1, 35 slots, 2092-byte LowState) for G1.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import threading
import time

import numpy as np

from wbmpc.errors import ConfigError, RunError
from wbmpc.estimation.sensors import SensorConfig, Sensors
from wbmpc.hardware.mapping import G1_MODE_MACHINE, unitree_motor_map
from wbmpc.hardware.messages import (
    MotorCommand,
    command_echo,
    decode_low_cmd,
    decode_low_state,
    encode_low_cmd,
    encode_low_state,
)
from wbmpc.hardware.network import check_interface
from wbmpc.hardware.sdk import load_sdk

_STATE, _CMD = "rt/bench_lowstate", "rt/bench_lowcmd"


def _echo_main(spec, network: str, domain_id: int, ready, stop) -> None:
    from wbmpc.robots import RobotModel

    sdk = load_sdk()
    motors = unitree_motor_map(RobotModel(spec))
    idl = sdk.idl(motors.family)
    sdk.ChannelFactoryInitialize(domain_id, network)
    publisher = sdk.ChannelPublisher(_CMD, idl.LowCmd_)
    publisher.Init()
    damping = MotorCommand.damping(motors.n_motors, 1.0)

    def answer(msg):
        decode_low_state(msg, motors)
        publisher.Write(encode_low_cmd(damping, motors, echo_tick=msg.tick, mode_machine=getattr(msg, "mode_machine", 0)))

    subscriber = sdk.ChannelSubscriber(_STATE, idl.LowState_)
    subscriber.Init(answer, 0)
    ready.set()
    stop.wait(600)
    subscriber.Close()
    publisher.Close()


def dds_round_trip(robot, network: str = "lo", domain_id: int = 0, samples: int = 2000, rate_hz: float = 500.0) -> dict:
    """Round-trip times (ms) of `samples` LowState -> LowCmd exchanges at `rate_hz`."""
    check_interface(network)
    if samples < 10:
        raise ConfigError(f"--samples must be >= 10, got {samples}")
    sdk = load_sdk()
    motors = unitree_motor_map(robot)
    idl = sdk.idl(motors.family)
    reading = _legs_reading(robot, motors)
    context = multiprocessing.get_context("spawn")
    ready, stop = context.Event(), context.Event()
    echo = context.Process(target=_echo_main, args=(robot.spec, network, domain_id, ready, stop), daemon=True)
    echo.start()
    sent: dict[int, float] = {}
    rtt: list[float] = []
    lock = threading.Lock()

    answered = threading.Event()

    def on_cmd(msg):
        now = time.perf_counter()
        decode_low_cmd(msg, motors, mode_machine=G1_MODE_MACHINE if motors.family == "unitree_hg" else None)
        with lock:
            start = sent.pop(command_echo(msg), None)
            if start is not None:
                rtt.append(1e3 * (now - start))
                answered.set()

    try:
        sdk.ChannelFactoryInitialize(domain_id, network)
        subscriber = sdk.ChannelSubscriber(_CMD, idl.LowCmd_)
        subscriber.Init(on_cmd, 0)
        publisher = sdk.ChannelPublisher(_STATE, idl.LowState_)
        publisher.Init()
        if not ready.wait(120):
            raise RunError("the DDS echo process did not start")
        time.sleep(0.5)  # discovery
        period = 1.0 / rate_hz
        next_t = time.perf_counter()
        for k in range(samples + 50):  # ping-pong: the next LowState leaves once the answer is in (or lost)
            message = encode_low_state(reading, motors, tick_ms=k + 1, mode_machine=G1_MODE_MACHINE)
            answered.clear()
            with lock:
                sent[k + 1] = time.perf_counter()
            publisher.Write(message)
            answered.wait(timeout=1.0)
            next_t = max(next_t + period, time.perf_counter())
            time.sleep(max(0.0, next_t - time.perf_counter()))
        time.sleep(0.2)
        subscriber.Close()
        publisher.Close()
    finally:
        stop.set()
        echo.join(timeout=10)
        if echo.is_alive():
            echo.terminate()
    return _round_trip_report(rtt, network, motors.family, samples, rate_hz)


def _legs_reading(robot, motors):
    """A noiseless reading of the standing robot over the LowState's motors (what the benchmark sends)."""
    from wbmpc.sim import make_plant

    reading = Sensors(make_plant("mujoco", robot), SensorConfig.noiseless()).read()
    legs = [robot.joint_names.index(n) for n in motors.joint_names]
    return dataclasses.replace(reading, joint_position_rad=reading.joint_position_rad[legs],
                               joint_velocity_rad_s=reading.joint_velocity_rad_s[legs])


def _round_trip_report(rtt: list[float], network: str, family: str, samples: int, rate_hz: float) -> dict:
    values = np.array(rtt[50:])  # skip the first exchanges (discovery, caches)
    if values.size == 0:
        raise ConfigError(f"no LowCmd came back over {network}: DDS discovery failed on that interface")
    return {"network": network, "family": family, "samples": int(values.size), "sent": samples, "rate_hz": rate_hz,
            "lost_share": float(1 - values.size / samples),
            "rtt_ms_p50": float(np.percentile(values, 50)), "rtt_ms_p90": float(np.percentile(values, 90)),
            "rtt_ms_p99": float(np.percentile(values, 99)), "rtt_ms_max": float(values.max())}
