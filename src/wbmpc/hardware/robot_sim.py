"""`wbmpc robot-sim`: MuJoCo standing in for the robot behind Unitree's LowState/LowCmd topics.

At `state_rate_hz` (500 Hz, Unitree's low-level rate) the process samples the simulated IMU and
encoders (`wbmpc.estimation.sensors`), publishes LowState on `rt/lowstate`, and steps the physics
(1 kHz) applying the motor law of the latest valid LowCmd from `rt/lowcmd` at every physics step,
as the motor drivers do. The simulation stays frozen (LowState repeated) until the first valid
LowCmd arrives.

Modes: `realtime` paces ticks by the wall clock (a tick is on time when its work ends before the
next tick is due); `lockstep` waits for the LowCmd answering each LowState (simulated time: the
controller may take as long as its MPC needs), for controllers slower than real time.

Safety on the robot side: a LowCmd with a bad CRC, header, motor set or value is rejected and
counted; no valid LowCmd for `command_timeout_ms` (lock-step: `lockstep_timeout_ms`) switches the
motors to damping (kp = 0, kd = damping_kd, tau = 0) until valid commands come back.

Sport mode: the process serves Unitree's motion switcher (`wbmpc.hardware.motion_switcher`) in mode
`sport_mode` ("normal"); LowCmds are ignored (counted as `sport-mode`) until a client releases it.

Messages follow the model (`wbmpc.hardware.mapping`): unitree_go for quadrupeds, unitree_hg for G1
(35 slots; its LowState reports `mode_machine` (`RobotSimConfig.mode_machine`) and LowCmds that do not
echo it, or use mode_pr AB, are rejected; the motors of joints the model locks report their reference).
`tick` counts the robot's uptime in ms (it advances while the simulation waits for its first LowCmd).

Robot link `sim` imitates Unitree's own simulator (unitree_mujoco's `simulate_python`), so the controller's
`--robot-link sim` is tested without it: LowState with header, CRC, tick, motor modes and temperatures
left at 0, by default at 200 Hz (its 5 ms physics step); each LowCmd's motor law evaluated once, when it
arrives, with the joint readings of that moment, and that torque held until the next one (the PD runs at
the command rate, not at every physics step); LowCmds applied unchecked (no CRC, header or motor-set
check: only non-finite values are refused); no command watchdog, no sport mode service, no lock-step.

Gantry (`gantry`, for humanoids): a strap that is slack while the robot stands and walks and carries it once
it sinks well below its standing height, as on hardware (`wbmpc.hardware.gantry`); after deploy's crouch and
damping the humanoid hangs in it instead of collapsing.

Arm: a Z1 arm of the model (`arm="z1"`, the default for a model with Z1 joints) is not on LowCmd but
behind the Z1's UDP interface (`wbmpc.hardware.z1_udp.Z1Server`, z1_controller's ports): its state goes
out every tick beside LowState, its latest LOWCMD command drives the modelled Z1 joints (joints the
model locks are rigid here), and a silent arm link (`command_timeout_ms`) puts it in PASSIVE (damping).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.estimation.sensors import SensorConfig, Sensors
from wbmpc.hardware.link import check_link
from wbmpc.hardware.mapping import G1_MODE_MACHINE, has_z1_arm, unitree_motor_map, z1_arm_map
from wbmpc.hardware.messages import (
    MessageError,
    MotorCommand,
    command_echo,
    decode_low_cmd,
    encode_low_state,
    leave_unset,
)
from wbmpc.hardware.network import check_interface
from wbmpc.hardware.safety import SafetyConfig, fallen, lying_joint_positions
from wbmpc.hardware.sdk import load_sdk
from wbmpc.hardware.z1_messages import CONTROLLER_PORT, N_Z1_JOINTS, SDK_PORT
from wbmpc.robots import RobotModel

LOW_STATE_TOPIC, LOW_CMD_TOPIC = "rt/lowstate", "rt/lowcmd"
BOOT_TICK_MS = 1000  # the robot's uptime when robot-sim starts publishing: a robot's tick is never 0
UNITREE_SIM_STATE_RATE_HZ = 200.0  # unitree_mujoco publishes LowState every physics step, 5 ms by default


@dataclass(frozen=True)
class RobotSimConfig:
    network: str = "lo"
    domain_id: int = 0
    mode: str = "realtime"  # realtime | lockstep
    duration_s: float | None = None  # simulated seconds after the first command; None: until stopped
    state_rate_hz: float = 500.0
    start: str = "standing"  # standing | lying
    sensors: SensorConfig = field(default_factory=SensorConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    lockstep_timeout_ms: float = 30000.0  # long: a recovery re-solve takes seconds, more on a loaded machine
    idle_exit_s: float | None = None  # exit when no valid LowCmd came for this long (after the first one)
    push_time_s: float | None = None  # base velocity kick at this simulated time
    push_velocity_m_s: tuple[float, float, float] = (0.0, 0.8, 0.0)
    arm: str = "auto"  # "z1": the arm behind the Z1's UDP interface; "auto": z1 when the model has Z1 joints
    z1_ports: tuple[int, int] = (CONTROLLER_PORT, SDK_PORT)  # (this process = the Z1 controller, the SDK's)
    sport_mode: str = "normal"  # the motion switcher's mode at start ("": released)
    refuse_sport_release: bool = False  # a robot that keeps its sport mode (fault injection)
    arm_silent_after_s: float | None = None  # the Z1 stops sending its state at this simulated time (fault injection)
    corrupt_every: int | None = None  # every n-th LowState with a bad CRC and Z1 state with NaN (fault injection)
    robot_link: str = "robot"  # robot | sim: imitate Unitree's simulator (see the module's docstring)
    mode_machine: int = G1_MODE_MACHINE  # unitree_hg robots report it in LowState and expect it back in LowCmd
    gantry: bool = False  # a safety strap above the base (humanoids), slack while standing
    plant_model: str | None = None  # MuJoCo simulates this file of the robot (wbmpc.sim.plant_model); None: the model
    model_errors: object | None = None  # wbmpc.sim.model_errors.ModelErrors of the plant (a payload, a CoM offset)

    def __post_init__(self):
        check_link(self.robot_link)
        if self.robot_link == "sim" and self.mode == "lockstep":
            raise ConfigError("--robot-link sim imitates Unitree's simulator, which runs in real time: --mode realtime")
        if self.arm not in ("auto", "z1", "none"):
            raise ConfigError(f"--arm must be z1 (the arm over the Z1's UDP interface) or none, got {self.arm!r}")
        if self.mode not in ("realtime", "lockstep"):
            raise ConfigError(f"--mode must be realtime or lockstep, got {self.mode!r}")
        if self.start not in ("standing", "lying"):
            raise ConfigError(f"--start must be standing or lying, got {self.start!r}")
        if not self.state_rate_hz > 0:
            raise ConfigError(f"state_rate_hz must be positive, got {self.state_rate_hz}")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError(f"--duration must be positive, got {self.duration_s}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"DDS domain id must be in 0..232, got {self.domain_id}")


@dataclass
class RobotSimReport:
    mode: str
    ticks: int = 0
    ticks_on_time: int = 0
    commands_received: int = 0
    commands_rejected: dict = field(default_factory=dict)
    watchdog_events: list = field(default_factory=list)  # simulated times when damping started
    watchdog_latency_ms: list = field(default_factory=list)  # wall time from the last valid LowCmd to damping
    rtt_ms: list = field(default_factory=list)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    fell: bool = False
    fell_at_s: float | None = None
    start_xy_m: list = field(default_factory=list)
    end_xy_m: list = field(default_factory=list)
    base_height_min_m: float | None = None
    damping_at_end: bool = False
    arm: dict | None = None  # the Z1 link's counters (None: no Z1 arm)
    sport_mode_at_end: str = ""
    sport_calls: list = field(default_factory=list)  # motion switcher calls served, in order
    tick_cpu_ms: list = field(default_factory=list)  # CPU time of the tick loop's own thread per tick
    trajectory: list = field(default_factory=list)  # [t s, x, y, z, tilt deg] every 25 ticks (20 Hz), true base
    gantry: dict | None = None  # when the strap first carried the robot, its largest pull

    def summary(self) -> dict:
        rtt = np.array(self.rtt_ms)
        moved = np.linalg.norm(np.subtract(self.end_xy_m, self.start_xy_m)) if self.start_xy_m else 0.0
        return {
            "mode": self.mode,
            "ticks": self.ticks,
            "ticks_on_time_share": self.ticks_on_time / self.ticks if self.ticks else None,
            "commands_received": self.commands_received,
            "commands_rejected": dict(self.commands_rejected),
            "watchdog_events_s": self.watchdog_events,
            "watchdog_latency_ms": self.watchdog_latency_ms,
            "rtt_ms_p50": float(np.percentile(rtt, 50)) if rtt.size else None,
            "rtt_ms_p99": float(np.percentile(rtt, 99)) if rtt.size else None,
            "rtt_samples": int(rtt.size),
            "sim_time_s": self.sim_time_s,
            "wall_time_s": self.wall_time_s,
            "fell": self.fell,
            "fell_at_s": self.fell_at_s,
            "base_drift_cm_s": float(100 * moved / self.sim_time_s) if self.sim_time_s > 0 else None,
            "base_height_min_m": self.base_height_min_m,
            "damping_at_end": self.damping_at_end,
            "arm": self.arm,
            "sport_mode_at_end": self.sport_mode_at_end,
            "sport_calls": self.sport_calls,
            "tick_cpu_ms_p50": float(np.percentile(self.tick_cpu_ms, 50)) if self.tick_cpu_ms else None,
            "tick_cpu_ms_p99": float(np.percentile(self.tick_cpu_ms, 99)) if self.tick_cpu_ms else None,
            "gantry": self.gantry,
            "trajectory": self.trajectory,
        }

    def drift_cm_s(self, from_s: float, to_s: float) -> float:
        """True base drift (horizontal displacement / time) between two simulated times."""
        traj = np.array(self.trajectory)
        a, b = (np.argmin(np.abs(traj[:, 0] - x)) for x in (from_s, to_s))
        return float(100 * np.linalg.norm(traj[b, 1:3] - traj[a, 1:3]) / max(traj[b, 0] - traj[a, 0], 1e-9))


@dataclass
class _RunClock:
    """A robot-sim run's progress: when the first LowCmd came (simulated s), the uptime waited for it, the wall
    clock's start and next tick, whether it is damping, was pushed, has stood."""

    wall_start: float
    deadline: float
    started_at: float | None = None
    waited_s: float = 0.0
    in_damping: bool = False
    pushed: bool = False
    stood: bool = False


class RobotSimulator:
    """The robot process: MuJoCo + sensors behind LowState/LowCmd."""

    def __init__(self, robot: RobotModel, config: RobotSimConfig = RobotSimConfig()):
        from wbmpc.sim import make_plant

        check_interface(config.network)
        self.robot, self.config = robot, config
        self.motors = unitree_motor_map(robot)
        self._leg_index = np.array([robot.joint_names.index(n) for n in self.motors.joint_names], dtype=int)
        z1 = config.arm == "z1" or (config.arm == "auto" and has_z1_arm(robot))
        if z1 and config.robot_link == "sim":
            raise ConfigError("Unitree's simulator (--robot-link sim) has no Z1 arm interface: pass --arm none")
        if config.start == "lying" and len(robot.feet) == 2:
            raise ConfigError(f"{robot.name} is a biped: it does not stand up from lying by joint PD; --start standing "
                              "(on a robot: from its gantry)")
        self.arm_map = z1_arm_map(robot) if z1 else None
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = MujocoPlantConfig(plant_model=config.plant_model) if config.plant_model else None
        if config.model_errors is not None and not config.model_errors.is_nominal:
            plant_config = config.model_errors.plant_config(robot, plant_config)
        self.plant = make_plant("mujoco", robot, plant_config)
        q0 = robot.q_nominal.copy()
        if config.start == "lying":
            q0[7:] = lying_joint_positions(robot)
            q0[2] = 0.5 * robot.q_nominal[2]
        self.plant.reset(q0)
        if config.start == "lying":  # let it settle on the floor, motors off
            for _ in range(1500):
                q, v = self.plant.state()
                self.plant.step(-config.safety.damping_kd * v[6:])
        self.gantry = None
        if config.gantry:
            from wbmpc.hardware.gantry import Gantry

            self.gantry = Gantry(self.plant, robot)
            self.plant.add_step_hook(self.gantry)
        self.sensors = Sensors(self.plant, config.sensors)
        self._lying_pose = lying_joint_positions(robot)
        self._steps_per_tick = max(1, int(round(1.0 / (config.state_rate_hz * self.plant.dt_s))))
        self._lock = threading.Condition()
        self._command: MotorCommand | None = None
        self._command_echo: int | None = None
        self._command_wall: float | None = None
        self._send_wall: dict[int, float] = {}
        self.report = RobotSimReport(config.mode)
        self._rejected: Counter = Counter()
        self._stop = threading.Event()
        self._switcher = None
        self._z1 = None
        # the leg joints' (q, dq) the sim link's motor law reads when a LowCmd arrives (updated every tick)
        self.joint_readings = (q0[7:][self._leg_index], np.zeros(len(self._leg_index)))
        self.remote = None  # wbmpc.operator.remote_script.RemotePublisher: an operator's remote (scripted or a gamepad)

    def stop(self) -> None:
        self._stop.set()

    @property
    def held_command(self) -> MotorCommand | None:
        """The legs' command applied now: the last accepted LowCmd's (None before the first)."""
        with self._lock:
            return self._command

    @property
    def rejected_counts(self) -> dict[str, int]:
        """LowCmds refused so far, by reason (e.g. {"crc": 3})."""
        with self._lock:
            return dict(self._rejected)

    # ------------------------------------------------------------------ DDS side
    def on_low_cmd(self, msg) -> None:
        """The LowCmd subscriber: check (robot link) or accept (sim link) the message and hold its command."""
        now = time.perf_counter()
        if self._switcher is not None and not self._switcher.released:
            with self._lock:
                self._rejected["sport-mode"] += 1  # the built-in controller owns the motors
            return
        sim_link = self.config.robot_link == "sim"
        try:
            command = decode_low_cmd(msg, self.motors, checked=not sim_link,
                                     mode_machine=self.config.mode_machine if self.motors.family == "unitree_hg" else None)
        except MessageError as exc:
            with self._lock:
                self._rejected.update(exc.reasons)
            return
        if sim_link:  # the motor law once, with the readings of this moment; its torque held until the next LowCmd
            q, dq = self.joint_readings
            n = len(q)
            command = MotorCommand(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), command.torque(q, dq))
        echo = command_echo(msg)
        with self._lock:
            self._command, self._command_echo, self._command_wall = command, echo, now
            sent = self._send_wall.pop(echo, None)
            if sent is not None:
                self.report.rtt_ms.append(1e3 * (now - sent))
            self.report.commands_received += 1
            self._lock.notify_all()

    # ------------------------------------------------------------------ loop
    def _full_command(self, legs: MotorCommand | None) -> MotorCommand:
        """The motor law of every model joint: legs from LowCmd (None: damping), the Z1's modelled joints
        from its latest LOWCMD command (PASSIVE or stale: damping)."""
        full = MotorCommand.damping(self.robot.n_joints, self.config.safety.damping_kd)
        if legs is not None:
            for name, value in zip(("q_rad", "dq_rad_s", "kp", "kd", "tau_nm"),
                                   (legs.q_rad, legs.dq_rad_s, legs.kp, legs.kd, legs.tau_nm)):
                getattr(full, name)[self._leg_index] = value
        if self._z1 is not None:
            arm = self._z1.command()
            if arm is not None:
                k = np.flatnonzero(self.arm_map.driven)
                j = np.array(self.arm_map.model_index)[k]
                full.q_rad[j], full.dq_rad_s[j], full.tau_nm[j] = arm.q_rad[k], arm.dq_rad_s[k], arm.tau_nm[k]
                full.kp[j], full.kd[j] = arm.kp[k], arm.kd[k]
        return full

    def _publish_arm(self, reading, corrupt: bool = False) -> None:
        if self._z1 is None:
            return
        q, dq = np.array(self.arm_map.locked_position_rad), np.zeros(N_Z1_JOINTS)
        k = np.flatnonzero(self.arm_map.driven)
        j = np.array(self.arm_map.model_index)[k]
        q[k], dq[k] = reading.joint_position_rad[j], reading.joint_velocity_rad_s[j]
        if corrupt:
            q[0] = np.nan
        self._z1.publish(q, dq, np.zeros(N_Z1_JOINTS))

    def run(self, progress=None) -> RobotSimReport:
        """Publish LowState at `state_rate_hz` and simulate the commands answered, until `duration_s` after the first
        LowCmd, `idle_exit_s` without one, or `stop()`."""
        from wbmpc.hardware.motion_switcher import MotionSwitcherServer
        from wbmpc.hardware.z1_udp import Z1Server

        sdk = load_sdk()
        cfg = self.config
        sdk.ChannelFactoryInitialize(cfg.domain_id, cfg.network)
        if cfg.robot_link != "sim":  # Unitree's simulator serves no motion switcher
            self._switcher = MotionSwitcherServer(cfg.sport_mode, cfg.refuse_sport_release)
        if self.arm_map is not None:
            self._z1 = Z1Server(own_port=cfg.z1_ports[0], sdk_port=cfg.z1_ports[1],
                                command_timeout_ms=cfg.lockstep_timeout_ms if cfg.mode == "lockstep"
                                else cfg.safety.command_timeout_ms)
        idl = sdk.idl(self.motors.family)
        publisher = sdk.ChannelPublisher(LOW_STATE_TOPIC, idl.LowState_)
        publisher.Init()
        subscriber = sdk.ChannelSubscriber(LOW_CMD_TOPIC, idl.LowCmd_)
        subscriber.Init(self.on_low_cmd, 0)
        run = _RunClock(wall_start=time.perf_counter(), deadline=time.perf_counter())
        try:
            while not self._stop.is_set() and self._tick(publisher, run, progress):
                pass
        finally:
            subscriber.Close()
            publisher.Close()
            if self.remote is not None:
                self.remote.close()
            if self._z1 is not None:
                self._z1.close()
        return self._final_report(run)

    def _tick(self, publisher, run: _RunClock, progress) -> bool:
        """One LowState out and the command it gets simulated for one tick; False: the run ends."""
        cfg, plant, report = self.config, self.plant, self.report
        cpu_start = time.thread_time()
        t = plant.time_s
        tick_ms = BOOT_TICK_MS + int(round(1e3 * (run.waited_s + t)))
        corrupt = cfg.corrupt_every is not None and report.ticks % cfg.corrupt_every == cfg.corrupt_every - 1
        self._publish_state(publisher, run, t, tick_ms, corrupt)
        status, command, command_wall = self._await_command(run, t, tick_ms, corrupt)
        if status != "go":
            return status == "wait"
        timeout_s = (cfg.lockstep_timeout_ms if cfg.mode == "lockstep" else cfg.safety.command_timeout_ms) / 1e3
        stale = time.perf_counter() - command_wall > timeout_s and cfg.robot_link != "sim"  # the simulator holds on
        if stale and not run.in_damping:
            report.watchdog_events.append(t - run.started_at)
            report.watchdog_latency_ms.append(1e3 * (time.perf_counter() - command_wall))
        run.in_damping = stale
        command = self._full_command(None if run.in_damping else command)
        if cfg.idle_exit_s is not None and time.perf_counter() - command_wall > cfg.idle_exit_s:
            return False
        if cfg.push_time_s is not None and not run.pushed and t - run.started_at >= cfg.push_time_s:
            plant.apply_base_velocity_kick(np.array(cfg.push_velocity_m_s, dtype=float))
            run.pushed = True
        for _ in range(self._steps_per_tick):
            q, v = plant.state()
            self.joint_readings = (q[7:][self._leg_index], v[6:][self._leg_index])
            plant.step(command.torque(q[7:], v[6:]))
        self._record_tick(run, command)
        report.tick_cpu_ms.append(1e3 * (time.thread_time() - cpu_start))
        self._pace(run)
        if progress and cfg.duration_s:
            progress((plant.time_s - run.started_at) / cfg.duration_s)
        return not (cfg.duration_s is not None and plant.time_s - run.started_at >= cfg.duration_s - 1e-9)

    def _publish_state(self, publisher, run: _RunClock, t: float, tick_ms: int, corrupt: bool) -> None:
        """This tick's LowState (and the Z1's state unless it went silent), as the robot's link sends them."""
        cfg = self.config
        reading = self.sensors.read()
        foot_force = np.linalg.norm(self.plant.contact_forces(), axis=1)
        if not (cfg.arm_silent_after_s is not None and run.started_at is not None
                and t - run.started_at >= cfg.arm_silent_after_s):
            self._publish_arm(reading, corrupt)
        legs = dataclasses.replace(reading, joint_position_rad=reading.joint_position_rad[self._leg_index],
                                   joint_velocity_rad_s=reading.joint_velocity_rad_s[self._leg_index])
        message = encode_low_state(legs, self.motors, tick_ms, foot_force, cfg.mode_machine)
        if self.remote is not None:  # the operator's remote: LowState's bytes and rt/wirelesscontroller
            self.remote.write(message, None if run.started_at is None else t - run.started_at)
        if cfg.robot_link == "sim":
            leave_unset(message)
        with self._lock:
            self._send_wall[tick_ms] = time.perf_counter()
            if len(self._send_wall) > 2000:
                self._send_wall.pop(next(iter(self._send_wall)))
        if corrupt:
            message.crc ^= 1  # corrupted in transit
        publisher.Write(message)

    def _await_command(self, run: _RunClock, t: float, tick_ms: int, corrupt: bool):
        """("go", command, its wall time): the command to simulate, waited for in lock-step, the latest in real
        time; ("wait", ...) before the first LowCmd (frozen meanwhile); ("stop", ...) idle past `idle_exit_s`."""
        cfg = self.config
        with self._lock:
            if run.started_at is None:
                self._lock.wait(timeout=1.0 / cfg.state_rate_hz)
                run.waited_s += 1.0 / cfg.state_rate_hz
                if self._command is None:
                    run.deadline = time.perf_counter()
                    idle = cfg.idle_exit_s is not None and run.deadline - run.wall_start > cfg.idle_exit_s
                    return ("stop" if idle else "wait"), None, None
                run.started_at = t
                self.report.start_xy_m = self.plant.state()[0][:2].tolist()
                run.wall_start = run.deadline = time.perf_counter()
            elif cfg.mode == "lockstep" and not run.in_damping and not corrupt:  # nobody answers a corrupted one
                self._lock.wait_for(lambda: self._command_echo == tick_ms or self._stop.is_set(),
                                    timeout=cfg.lockstep_timeout_ms / 1e3)
            return "go", self._command, self._command_wall

    def _record_tick(self, run: _RunClock, command: MotorCommand) -> None:
        """The lowest base, a fall (once the robot stood), every 25th tick's base pose and tilt."""
        report, plant = self.report, self.plant
        q, _ = plant.state()
        report.base_height_min_m = float(q[2] if report.base_height_min_m is None else min(q[2], report.base_height_min_m))
        run.stood = run.stood or q[2] > 0.8 * self.robot.q_nominal[2]  # a lying start has not fallen
        low_on_purpose = self._commands_lying(command)  # a commanded lie-down or damping: only a tilt is a fall
        if run.stood and not report.fell and fallen(self.robot, q, self.config.safety, check_height=not low_on_purpose):
            report.fell, report.fell_at_s = True, plant.time_s - run.started_at
        if report.ticks % 25 == 0:
            tilt_deg = np.degrees(np.arccos(np.clip(1 - 2 * (q[3] ** 2 + q[4] ** 2), -1, 1)))
            report.trajectory.append([round(plant.time_s - run.started_at, 4), *np.round(q[:3], 5).tolist(),
                                      round(float(tilt_deg), 2)])
        report.ticks += 1

    def _commands_lying(self, command: MotorCommand) -> bool:
        """The command lets the base down on purpose: damping (no stiffness) or joint targets nearer the lying
        pose than the standing one (the controller's lie-down, as deploy commands it)."""
        if not np.any(command.kp[self._leg_index] > 0):
            return True
        targets = command.q_rad[self._leg_index]
        nominal, lying = self.robot.q_nominal[7:][self._leg_index], self._lying_pose[self._leg_index]
        return bool(np.linalg.norm(targets - lying) < np.linalg.norm(targets - nominal))

    def _pace(self, run: _RunClock) -> None:
        """Real time: sleep until the next tick's wall time (counted on time when there was slack); lock-step: on
        time by definition."""
        report = self.report
        run.deadline += 1.0 / self.config.state_rate_hz
        if self.config.mode == "realtime":
            slack = run.deadline - time.perf_counter()
            if slack >= 0:
                report.ticks_on_time += 1
                time.sleep(slack)
            elif slack < -0.1:  # far behind (machine stalled): re-anchor instead of racing
                run.deadline = time.perf_counter()
        else:
            report.ticks_on_time += 1

    def _final_report(self, run: _RunClock) -> RobotSimReport:
        report, plant = self.report, self.plant
        if self._z1 is not None:
            rtt = np.array(self._z1.rtt_ms)
            report.arm = {"commands_received": self._z1.received, "commands_rejected": dict(self._z1.rejected),
                          "watchdog_events": self._z1.watchdog_events, "passive_at_end": self._z1.command() is None,
                          "watchdog_latency_ms": list(self._z1.watchdog_latency_ms),
                          "rtt_ms_p50": float(np.percentile(rtt, 50)) if rtt.size else None,
                          "rtt_ms_p99": float(np.percentile(rtt, 99)) if rtt.size else None, "rtt_samples": int(rtt.size)}
        report.sport_mode_at_end = self._switcher.mode if self._switcher is not None else ""
        report.sport_calls = list(self._switcher.calls) if self._switcher is not None else []
        report.sim_time_s = plant.time_s - run.started_at if run.started_at is not None else 0.0
        report.wall_time_s = time.perf_counter() - run.wall_start
        report.end_xy_m = plant.state()[0][:2].tolist()
        report.commands_rejected = dict(self._rejected)
        report.damping_at_end = run.in_damping
        if self.gantry is not None:
            report.gantry = self.gantry.summary(run.started_at if run.started_at is not None else 0.0)
        return report
