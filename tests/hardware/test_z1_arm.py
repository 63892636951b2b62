"""The Z1 arm link (byte layouts of Unitree's z1_sdk structs, UDP loopback), the motion switcher, the
deploy's MPC configuration against `wbmpc run`'s, and damping on every fault exit of deploy (a fake robot
in this process: LowState through a stand-in of the SDK's channels, the Z1 through its real UDP link)."""

import os
import struct
import threading
import time

import numpy as np
import pytest

sdk_mod = pytest.importorskip("wbmpc.hardware.sdk")
try:
    SDK = sdk_mod.load_sdk()
except Exception as exc:  # noqa: BLE001
    pytest.skip(f"Unitree SDK2 not installed: {exc}", allow_module_level=True)

from wbmpc.hardware import z1_messages as zm  # noqa: E402
from wbmpc.hardware.messages import MessageError  # noqa: E402
from wbmpc.hardware.z1_udp import ArmNotAnsweringError, Z1Client, Z1Server  # noqa: E402
from wbmpc.robots import load_robot  # noqa: E402

PORT_BASE = 20000 + 4 * (os.getpid() % 2000)  # ports of their own: parallel runs do not hear each other

# Offsets, C types and field names written from arm_common.h (#pragma pack(1)): SendCmd is uint8 head[2],
# ArmFSMState state (4-byte enum), bool track, then the union's JointCmd jointCmd[7] {float T, W, Pos, K_P, K_W};
# RecvState is head[2], state, JointState jointState[7] {float T, W, Acc, Pos; Motor_State state[2] {int8
# temperature; uint8 error; uint8 isConnected}}, Posture cartesianState {double roll, pitch, yaw, x, y, z}.
SEND_CMD_FIELDS = [("head0", 0, "B"), ("head1", 1, "B"), ("state", 2, "i"), ("track", 6, "?")] + [
    (f"jointCmd{j}.{f}", 7 + 20 * j + 4 * i, "f") for j in range(7) for i, f in enumerate(("T", "W", "Pos", "K_P", "K_W"))]
RECV_STATE_FIELDS = [("head0", 0, "B"), ("head1", 1, "B"), ("state", 2, "i")] + [
    (f"jointState{j}.{f}", 6 + 22 * j + 4 * i, "f") for j in range(7) for i, f in enumerate(("T", "W", "Acc", "Pos"))] + [
    (f"jointState{j}.temperature", 6 + 22 * j + 16, "b") for j in range(7)] + [
    (f"cartesianState.{f}", 160 + 8 * i, "d") for i, f in enumerate(("roll", "pitch", "yaw", "x", "y", "z"))]


def test_z1_messages_have_unitrees_byte_layout_and_round_trip():
    assert (zm.SEND_CMD.size, zm.RECV_STATE.size, zm.JOINT_CMD.size, zm.JOINT_STATE.size) == (147, 208, 20, 22)
    rng = np.random.default_rng(0)
    q, dq, tau = rng.normal(size=(3, 7))
    kp, kd = np.linspace(100, 700, 7), np.linspace(1, 30, 7)
    data = zm.encode_send_cmd(zm.Z1Command(zm.ArmFsmState.LOWCMD, q, dq, tau, kp, kd, track=True))
    fields = {name: struct.unpack_from("<" + fmt, data, offset)[0] for name, offset, fmt in SEND_CMD_FIELDS}
    assert (fields["head0"], fields["head1"], fields["state"], fields["track"]) == (0xFE, 0xFF, 16, True)
    for j in range(7):
        assert fields[f"jointCmd{j}.Pos"] == pytest.approx(q[j], abs=1e-6)
        assert fields[f"jointCmd{j}.W"] == pytest.approx(dq[j], abs=1e-6)
        assert fields[f"jointCmd{j}.T"] == pytest.approx(tau[j], abs=1e-6)
        assert fields[f"jointCmd{j}.K_P"] == pytest.approx(kp[j] / 25.6, rel=1e-6)  # the controller's units
        assert fields[f"jointCmd{j}.K_W"] == pytest.approx(kd[j] / 0.0128, rel=1e-6)
    back = zm.decode_send_cmd(data)
    np.testing.assert_allclose([back.q_rad, back.dq_rad_s, back.tau_nm], [q, dq, tau], atol=1e-6)
    np.testing.assert_allclose([back.kp, back.kd], [kp, kd], rtol=1e-6)

    state = zm.Z1State(zm.ArmFsmState.PASSIVE, q, dq, tau / 2, tau, np.arange(30, 37), np.zeros(7, int), np.arange(6.0))
    data = zm.encode_recv_state(state)
    fields = {name: struct.unpack_from("<" + fmt, data, offset)[0] for name, offset, fmt in RECV_STATE_FIELDS}
    assert fields["state"] == 1 and fields["cartesianState.z"] == 5.0 and fields["jointState6.temperature"] == 36
    assert [fields[f"jointState{j}.Pos"] for j in range(7)] == pytest.approx(q, abs=1e-6)
    assert [fields[f"jointState{j}.Acc"] for j in range(7)] == pytest.approx(tau / 2, abs=1e-6)
    back = zm.decode_recv_state(data)
    np.testing.assert_allclose([back.q_rad, back.dq_rad_s, back.tau_nm], [q, dq, tau], atol=1e-6)

    with pytest.raises(MessageError, match="bytes"):
        zm.decode_send_cmd(data)  # a RecvState is no SendCmd
    with pytest.raises(MessageError, match="non-finite"):
        zm.decode_recv_state(zm.encode_recv_state(zm.Z1State(zm.ArmFsmState.LOWCMD, np.full(7, np.nan), *(np.zeros(7),) * 5,
                                                              np.zeros(6))))
    bad_head = bytearray(zm.encode_send_cmd(zm.Z1Command.switch(zm.ArmFsmState.PASSIVE)))
    bad_head[1] = 0xEF
    with pytest.raises(MessageError, match="head"):
        zm.decode_send_cmd(bytes(bad_head))


def test_z1_arm_map_holds_the_joints_the_model_locks():
    from wbmpc.hardware.mapping import unitree_motor_map, z1_arm_map

    robot = load_robot("b1_z1")  # locks joint5, joint6 and the gripper
    arm = z1_arm_map(robot)
    assert [i >= 0 for i in arm.model_index] == [True] * 4 + [False] * 3
    assert [robot.joint_names[i] for i in arm.model_index[:4]] == ["joint1", "joint2", "joint3", "joint4"]
    assert unitree_motor_map(robot).n_motors == 12  # the arm is not on LowCmd


def test_z1_link_on_loopback_switches_to_lowcmd_rejects_bad_datagrams_and_falls_back_to_passive():
    import socket

    ctrl, sdk = PORT_BASE, PORT_BASE + 1
    server = Z1Server(sdk_port=sdk, own_port=ctrl, command_timeout_ms=500)  # long enough for a loaded machine's pauses
    client = Z1Client(controller_port=ctrl, own_port=sdk)
    stop = threading.Event()

    def controller():  # z1_controller's loop: state out every 2 ms
        while not stop.is_set():
            server.publish(np.full(7, 0.3), np.zeros(7), np.zeros(7))
            server.command()
            time.sleep(0.002)

    thread = threading.Thread(target=controller, daemon=True)
    thread.start()
    try:
        state = client.enter_lowcmd(2.0, np.full(7, 100.0), np.full(7, 2.0))
        assert state.state == zm.ArmFsmState.LOWCMD and state.q_rad == pytest.approx(np.full(7, 0.3))
        client.send(zm.Z1Command(zm.ArmFsmState.LOWCMD, np.ones(7), np.zeros(7), np.zeros(7), np.full(7, 50.0), np.ones(7)))
        time.sleep(0.02)
        assert server.command().kp == pytest.approx(np.full(7, 50.0))
        forger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        nan = bytearray(zm.encode_send_cmd(zm.Z1Command(zm.ArmFsmState.LOWCMD, np.full(7, np.nan), *(np.zeros(7),) * 4)))
        for datagram in (b"\x00" * 20, bytes(nan)):
            forger.sendto(datagram, ("127.0.0.1", ctrl))
        forger.close()
        time.sleep(0.05)
        assert server.rejected["length"] == 1 and server.rejected["malformed"] == 1
        assert server.command().q_rad == pytest.approx(np.ones(7))  # the forged ones were not used
        time.sleep(1.0)  # the SDK went silent for twice the timeout
        assert server.command() is None and server.fsm == zm.ArmFsmState.PASSIVE and server.watchdog_events == 1
    finally:
        stop.set()
        thread.join()
        client.close()
        server.close()
    silent = Z1Client(controller_port=ctrl + 2, own_port=ctrl + 3)
    try:
        with pytest.raises(ArmNotAnsweringError, match="no valid state within 0.2 s"):
            silent.enter_lowcmd(0.2, np.zeros(7), np.zeros(7))
    finally:
        silent.close()


def test_sport_mode_released_restored_and_a_refusal_is_an_error():
    from wbmpc.hardware.motion_switcher import MotionSwitcherServer, SportModeError, SportModeRelease

    SDK.ChannelFactoryInitialize(100 + os.getpid() % 100, "lo")
    server = MotionSwitcherServer("normal")
    client = SportModeRelease(timeout_s=1.0)
    assert client.release() == "normal" and server.released
    assert client.restore() and server.mode == "normal"
    server.refuse = True
    with pytest.raises(SportModeError, match="refused to release its sport mode 'normal'"):
        client.release()


@pytest.mark.parametrize("robot_name", ["go2", "b1_z1"])
def test_deploy_builds_the_mpc_configuration_run_builds(robot_name):
    from wbmpc.hardware.commands import deploy_mpc_config
    from wbmpc.scenarios import RunConfig, make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    robot = load_robot(robot_name)
    for name in ("trot-in-place", "stand", "arm-track")[: 3 if robot.arm_ee else 2]:
        scenario = make_scenario(name, robot)
        run = mpc_config_for(scenario, RunConfig(scenario=name, delay_mode="realtime", state="estimated"), robot)
        deploy = deploy_mpc_config(robot, scenario.needs(robot), nodes=15, compiled=False, solver="fatrop",
                                   lockstep=False)
        assert deploy == run
        lockstep = deploy_mpc_config(robot, scenario.needs(robot), nodes=15, compiled=False, solver="fatrop",
                                     lockstep=True)
        assert lockstep == mpc_config_for(scenario, RunConfig(scenario=name, state="estimated"), robot)


# ---------------------------------------------------------------------------- deploy's exits, fake robot
class _FakeRobot:
    """LowState from a standing reading, every 50 ms until the first LowCmd, then one per LowCmd (lock-step), through
    stand-ins of the SDK's channels; the Z1 through a real `Z1Server` on loopback. Records every LowCmd and Z1
    command."""

    def __init__(self, robot, ports, stop_after: int | None = None, arm_silent_after: int | None = None,
                 corrupt_every: int | None = None):
        from wbmpc.estimation import SensorConfig, Sensors
        from wbmpc.hardware.mapping import unitree_motor_map
        from wbmpc.hardware.messages import encode_low_state
        from wbmpc.sim import make_plant

        plant = make_plant("mujoco", robot)
        plant.reset()
        self.reading = Sensors(plant, SensorConfig.noiseless()).read()
        self.motors = unitree_motor_map(robot)
        legs = [robot.joint_names.index(n) for n in self.motors.joint_names]
        self._legs_reading = self.reading.__class__(**{**self.reading.__dict__,
                                                      "joint_position_rad": self.reading.joint_position_rad[legs],
                                                      "joint_velocity_rad_s": self.reading.joint_velocity_rad_s[legs]})
        self._encode = encode_low_state
        self.z1 = Z1Server(sdk_port=ports[1], own_port=ports[0], command_timeout_ms=5000)
        self.low_cmds, self.arm_commands = [], []
        self.stop_after, self.arm_silent_after, self.corrupt_every = stop_after, arm_silent_after, corrupt_every
        self.tick = 0
        self.callback = None
        self._stop = threading.Event()
        self._arm_thread = threading.Thread(target=self._arm_loop, daemon=True)
        self._arm_thread.start()

    def _arm_loop(self):
        while not self._stop.is_set():
            if self.arm_silent_after is None or len(self.low_cmds) < self.arm_silent_after:
                corrupt = self.corrupt_every is not None and len(self.low_cmds) % self.corrupt_every == 1
                self.z1.publish(np.full(7, np.nan if corrupt else 0.0), np.zeros(7), np.zeros(7))
            command = self.z1.command()
            if command is not None and (not self.arm_commands or self.arm_commands[-1] is not command):
                self.arm_commands.append(command)
            time.sleep(0.002)

    def publish_until_commanded(self):
        """Before the first LowCmd a LowState every 50 ms (a robot publishes on its own; two timed ones raced the
        controller's start on a loaded machine: both came before it read the first)."""
        while not self._stop.wait(0.05) and not self.low_cmds:
            self.publish_state()

    def publish_state(self):
        if self.stop_after is not None and self.tick >= self.stop_after:
            return
        msg = self._encode(self._legs_reading, self.motors, 2 * self.tick + 2)  # a robot's tick is never 0
        self.tick += 1
        if self.corrupt_every is not None and self.tick % self.corrupt_every == 0:
            msg.crc ^= 1  # corrupted in transit: deploy must not answer it; the robot publishes on anyway
            threading.Timer(0.002, self.publish_state).start()
        self.callback(msg)

    def sdk(self):
        from wbmpc.hardware.messages import decode_low_cmd
        from wbmpc.hardware.sdk import Sdk

        fake = self

        class Publisher:
            def __init__(self, *args):
                pass

            def Init(self):
                pass

            def Write(self, msg):
                fake.low_cmds.append(decode_low_cmd(msg, fake.motors))
                threading.Timer(0.0005, fake.publish_state).start()

            def Close(self):
                pass

        class Subscriber:
            def __init__(self, *args):
                pass

            def Init(self, callback, depth):
                fake.callback = callback
                threading.Thread(target=fake.publish_until_commanded, daemon=True).start()

            def Close(self):
                pass

        return Sdk(lambda *a: None, Publisher, Subscriber, SDK.LowState_, SDK.LowCmd_, SDK.new_low_state, SDK.new_low_cmd)

    def close(self):
        self._stop.set()
        self._arm_thread.join()
        self.z1.close()


class _FakeMpc:
    """Solves instantly: a plan that holds the nominal pose; `fail_after` solves on, failures; `raise_at` a crash."""

    def __init__(self, robot, mpc_config, fail_after=None, raise_at=None):
        from wbmpc.gait import make_gait

        self.robot, self.solves = robot, 0
        self.fail_after, self.raise_at = fail_after, raise_at
        self.gait = make_gait("stand", len(robot.feet))
        self.config = mpc_config

    def solve(self, q, v, command, t):
        from types import SimpleNamespace

        self.solves += 1
        if self.raise_at is not None and self.solves >= self.raise_at:
            raise RuntimeError("solver crashed")
        n = self.robot.n_joints
        times = np.array([0.0, 0.01, 0.02, 0.03])
        q_plan = np.tile(self.robot.q_nominal, (4, 1))
        ok = self.fail_after is None or self.solves <= self.fail_after
        return SimpleNamespace(t_s=t, node_times_s=times, q=q_plan, v=np.zeros((4, self.robot.nv)),
                               a=np.zeros((3, self.robot.nv)), tau=np.zeros((3, n)), success=ok,
                               q_joints=np.tile(self.robot.q_nominal[7:], (4, 1)), stats=SimpleNamespace(status="fake"))


def _deploy_with_fake_robot(monkeypatch, stop_after=None, arm_silent_after=None, corrupt_every=None, solver_process=None,
                            **fake_mpc):
    from wbmpc.control import MpcConfig
    from wbmpc.hardware import deploy as deploy_mod
    from wbmpc.hardware.deploy import Controller, DeployConfig
    from wbmpc.hardware.safety import SafetyConfig

    robot = load_robot("b1_z1")
    ports = (PORT_BASE + 2, PORT_BASE + 3)
    fake = _FakeRobot(robot, ports, stop_after, arm_silent_after, corrupt_every)
    monkeypatch.setattr(deploy_mod, "load_sdk", fake.sdk)
    safety = SafetyConfig(stand_up_s=0.1, lie_down_s=0.1, state_timeout_ms=300)
    config = DeployConfig(lockstep=solver_process is None, duration_s=0.2, hold_s=0.02, safety=safety, sport_release=False,
                          z1_ports=ports, arm_state_timeout_ms=200, max_plan_age_s=0.05)
    mpc = _FakeMpc(robot, MpcConfig(gait="stand"), **fake_mpc)
    controller = Controller(robot, MpcConfig(gait="stand"), config, mpc=mpc if solver_process is None else None,
                            solver_process=solver_process and (lambda robot, mpc_config: solver_process(mpc)))
    try:
        try:
            controller.run()
            error = None
        except Exception as exc:  # noqa: BLE001
            error = exc
        # the arm's UDP server runs in its own thread: its last packets (damping, PASSIVE) may still be on their
        # way when deploy returns on a loaded machine
        deadline = time.monotonic() + 2.0
        while fake.z1.fsm != zm.ArmFsmState.PASSIVE and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)
    finally:
        fake.close()
    return controller.report, fake, error


def _damped(fake, kd=5.0):
    last_legs, last_arm = fake.low_cmds[-1], fake.z1.latest()  # the last LowCmd, the last LOWCMD of the arm
    legs = np.all(last_legs.kp == 0) and np.allclose(last_legs.kd, kd) and np.all(last_legs.tau_nm == 0)
    arm = np.all(last_arm.kp == 0) and np.allclose(last_arm.kd, kd) and np.all(last_arm.tau_nm == 0)
    return bool(legs and arm and fake.z1.fsm == zm.ArmFsmState.PASSIVE)  # damping in LOWCMD, then PASSIVE


def test_deploy_ends_in_damping_on_every_exit(monkeypatch):
    from wbmpc.hardware.deploy import DeployFailure

    report, fake, error = _deploy_with_fake_robot(monkeypatch, corrupt_every=25)  # bad CRCs and NaN arm states
    assert error is None and report.stopped_by == "done", report.error
    assert [p for _, p in report.phases] == ["stand-up", "hold", "mpc", "lie-down", "damping"]
    assert _damped(fake) and len(fake.arm_commands) > 10
    assert report.states_rejected["CRC mismatch"] >= 5 and report.arm["states_rejected"]["malformed"] >= 1
    assert report.commands_sent < fake.tick  # nothing answered the rejected LowStates

    report, fake, error = _deploy_with_fake_robot(monkeypatch, fail_after=3)  # solves fail: the plan ages
    assert isinstance(error, DeployFailure) and report.stopped_by == "stale-plan" and _damped(fake)

    report, fake, error = _deploy_with_fake_robot(monkeypatch, raise_at=4)  # an exception mid-run
    assert isinstance(error, DeployFailure) and "solver crashed" in str(error)
    assert report.stopped_by == "exception" and _damped(fake)

    report, fake, error = _deploy_with_fake_robot(monkeypatch, stop_after=80)  # LowState stops mid stand-up
    assert isinstance(error, DeployFailure) and report.stopped_by == "state-watchdog" and _damped(fake)

    report, fake, error = _deploy_with_fake_robot(monkeypatch, arm_silent_after=60)  # the arm goes silent
    assert isinstance(error, DeployFailure) and report.stopped_by == "arm-state-lost" and _damped(fake)

    report, fake, error = _deploy_with_fake_robot(monkeypatch, fail_after=0)  # the first solve never succeeds
    assert isinstance(error, DeployFailure) and report.stopped_by == "mpc-failed"
    assert report.first_solve_failures == 3 and "mpc" not in [p for _, p in report.phases] and _damped(fake)


class _FakeSolverProcess:
    """A real-time deploy's solver process that solves at once, noting the controller thread's CPUs and policy and
    each request's budget."""

    def __init__(self, mpc):
        self.mpc, self.answer, self.seen, self.budgets = mpc, None, [], []

    def request(self, q, v, command, t, delay_s=0.0, budget_s=None, **_):
        self.seen.append((os.sched_getaffinity(0), os.sched_getscheduler(0)))
        self.budgets.append(budget_s)
        self.answer = self.mpc.solve(q, v, command, t)
        self.answer.held_previous, self.answer.wall_time_s = False, 0.0

    def ready(self):
        return self.answer is not None

    def receive(self):
        answer, self.answer = self.answer, None
        return answer

    def close(self):
        pass


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="CPU affinity is Linux's")
def test_real_time_deploy_runs_its_loop_on_the_cpu_plan_and_gives_it_back():
    """The controller loop of a real-time deploy takes the simulated real-time loop's plan (`CpuPlan`): FIFO where
    permitted, pinned to the plan's loop core while it runs; the report says what was granted; afterwards the
    caller's CPUs and policy are back. Each request after the first (cold) one carries a step budget below the MPC
    period, as in the simulated real-time loop."""
    from wbmpc.control.loop import REALTIME_MARGIN_S
    from wbmpc.hardware.deploy_config import MPC_RATE_HZ

    monkeypatch = pytest.MonkeyPatch()
    workers = []

    def solver(mpc):
        workers.append(_FakeSolverProcess(mpc))
        return workers[-1]

    cpus = os.sched_getaffinity(0)
    try:
        report, fake, error = _deploy_with_fake_robot(monkeypatch, solver_process=solver)
    finally:
        monkeypatch.undo()
    assert error is None and report.stopped_by == "done", report.error
    scheduling = report.scheduling
    plan = scheduling["cpu_plan"]
    assert scheduling["realtime_priority"] in ("fifo 10", "nice -10", "default")
    if len(cpus) >= 2:
        assert set(plan["loop"]) | set(plan["solver"]) == cpus and len(plan["loop"]) == 1
        assert {frozenset(a) for a, _ in workers[0].seen} == {frozenset(plan["loop"])}  # the loop on its core
        shares = scheduling["realtime_priority"].startswith("fifo")
        assert (set(plan["helpers"]) == set(plan["loop"])) == shares  # the helpers below a FIFO loop, else apart
    if scheduling["realtime_priority"].startswith("fifo"):
        reset_on_fork = getattr(os, "SCHED_RESET_ON_FORK", 0)
        assert {policy & ~reset_on_fork for _, policy in workers[0].seen} == {os.SCHED_FIFO}
    assert os.sched_getaffinity(0) == cpus and os.sched_getscheduler(0) == os.SCHED_OTHER
    budgets = workers[0].budgets
    assert len(budgets) >= 3 and budgets[0] is None
    assert all(REALTIME_MARGIN_S <= b <= 1.0 / MPC_RATE_HZ - REALTIME_MARGIN_S for b in budgets[1:])
