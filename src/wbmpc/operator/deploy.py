"""An operator in the loop of `wbmpc deploy`: the robot's remote (`--remote`), a script, the keyboard or a
gamepad drive the MPC phase through the same session as a run; `--meshcat` serves the live page.

The deploy loop tells this module every tick (`on_tick`: robot time, MPC time, the LowState, the estimate and the
plan): it moves the board's clock to MPC time (-1 before the MPC phase: commands given while the robot stands
up wait for it), polls the script, samples the estimated base at 100 Hz for the per-segment figures, and a
lie-down command (the remote's L2+A, `x`, a script's `lie_down`) ends the MPC phase with the lie-down.
"""

from __future__ import annotations

import sys

import numpy as np

from wbmpc.operator.command import OperatorCommand, OperatorLimits
from wbmpc.operator.config import OperatorConfig
from wbmpc.operator.script import ScriptSource, read_script
from wbmpc.operator.session import OperatorSession
from wbmpc.operator.shaper import RampLimits

SAMPLE_PERIOD_S = 0.01


class DeployOperator:
    def __init__(self, robot, config: OperatorConfig, scenario, remote: bool = False, meshcat: bool = False,
                 echo=None):
        """Checks the sources now (script, terminal, gamepad, the SDK's remote topic), before anything is built."""
        self.robot, self.config, self.scenario = robot, config, scenario
        self.limits = OperatorLimits.for_robot(robot)
        self.echo = echo if echo is not None else sys.stderr
        base = scenario.commands(robot)(0.0, robot.q_nominal, np.zeros(robot.nv))
        self.initial = OperatorCommand(forward_m_s=float(base.base_velocity_m_s[0]),
                                       lateral_m_s=float(base.base_velocity_m_s[1]),
                                       yaw_rate_rad_s=float(base.base_yaw_rate_rad_s), walking=scenario.gait != "stand")
        self.sources, self.script = [], None
        if config.commands_file:
            self.script = read_script(config.commands_file, self.limits, self.initial)
            self.sources.append(ScriptSource(self.script))
        if remote:
            from wbmpc.operator.remote_source import RemoteSource, wireless_controller_type

            wireless_controller_type()  # the SDK's remote message type is there
            self.remote = RemoteSource(self.limits)
            self.sources.append(self.remote)
        else:
            self.remote = None
        if config.keyboard:
            from wbmpc.operator.keyboard import KeyboardSource

            self.sources.append(KeyboardSource(self.limits))
        if config.gamepad:
            from wbmpc.operator.gamepad import GamepadSource

            self.sources.append(GamepadSource(self.limits, path=None if config.gamepad == "auto" else config.gamepad))
        self.active = bool(self.sources)
        self.meshcat = None
        if meshcat:
            from wbmpc.viz.live_meshcat import LiveMeshcat

            self.meshcat = LiveMeshcat(robot)
        self.session: OperatorSession | None = None
        self._samples: list[tuple] = []
        self._next_sample = 0.0

    @property
    def duration_s(self) -> float | None:
        return self.script.duration_s if self.script is not None else None

    def attach(self, controller) -> None:
        """Tick listeners on the controller; the session follows the controller's gait clock (the estimator's)."""
        if self.active:
            self.session = OperatorSession(self.robot, self.limits, self.sources, self.initial,
                                           base_commands=self.scenario.commands(self.robot),
                                           ramp=RampLimits(linear_accel_m_s2=self.config.max_accel_m_s2,
                                                           yaw_accel_rad_s2=self.config.max_yaw_accel_rad_s2),
                                           gait_mirror=controller.gait)
            self.session.board.add_listener(self._say)
            self.session.board.set_time(-1.0)
            controller.tick_listeners.append(self.on_tick)
            if self.remote is not None:
                controller.tick_listeners.append(self.remote.on_tick)
        if self.meshcat is not None:
            url = self.meshcat.open()
            print(f"wbmpc: live view of the estimated state and the plan at {url}", file=self.echo, flush=True)
            controller.tick_listeners.append(self.meshcat.on_tick)

    def start(self) -> None:
        if self.session is not None:
            self.session.start()

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
        if self.meshcat is not None:
            self.meshcat.close()

    @property
    def commands(self):
        return self.session if self.session is not None else self.scenario.commands(self.robot)

    def stop(self) -> bool:
        return self.session is not None and self.session.lie_down_requested

    def on_tick(self, tick) -> None:
        t = tick.t_mpc_s
        if t is None:
            return
        self.session.poll(t)
        if t >= self._next_sample and tick.phase == "mpc":
            planted = tick.plan is not None and bool(np.min(np.asarray(tick.plan.contact)[0]) > 0.5)
            self._samples.append((t, np.array(tick.q), np.array(tick.v), planted))
            self._next_sample = t + SAMPLE_PERIOD_S

    def _say(self, item) -> None:
        text = item if isinstance(item, str) else f"{item.stamp_s:7.2f} s {item.note or item.source}: " \
            f"{item.command.describe()}"
        print(f"wbmpc: {text}", file=self.echo, flush=True)

    def metrics(self, controller) -> dict:
        """"operator" of the deploy report: the session's figures from the estimated state (100 Hz), the remote's
        counters and the live page's rate."""
        out = {}
        if self.session is not None and len(self._samples) > 2:
            from wbmpc.operator.metrics import operator_metrics

            t = np.array([s[0] for s in self._samples])
            arrays = {"t": t, "q": np.array([s[1] for s in self._samples]), "v": np.array([s[2] for s in self._samples]),
                      "mpc_t": t, "planned_contact": np.array([[1.0] if s[3] else [0.0] for s in self._samples])}
            gait = controller.mpc.gait if controller.mpc is not None else controller.gait
            out = operator_metrics(self.robot, arrays, self.session, gait.nominal_period_s, transitions=gait.transitions,
                                   mpc_period_s=1.0 / controller.config.mpc_rate_hz)
            out["state"] = "estimated (100 Hz)"
        elif self.session is not None:
            out = {"posts": len(self.session.posts())}
        if self.remote is not None:
            out["remote"] = {"received": dict(self.remote.received), "rejected": self.remote.rejected}
        if self.meshcat is not None:
            out["meshcat"] = self.meshcat.summary()
        return {"operator": out} if out else {}

    @staticmethod
    def summary_lines(operator: dict | None) -> list[str]:
        """The deploy summary's operator lines: commands, latency, segments, remote and live page."""
        if not operator:
            return []
        lines = []
        latency = operator.get("command_latency_ms") or {}
        if latency.get("commands"):
            lines.append(f"  operator: {latency['commands']} commands, latency max {latency['max']:.1f} ms (MPC period "
                         f"{latency['mpc_period_ms']:.1f} ms); gait switches {len(operator.get('gait_transitions', []))}")
        for segment in operator.get("segments", []):
            if segment.get("base_vel_rmse") is not None:
                lines.append(f"    {segment['start_s']:6.2f}-{segment['end_s']:6.2f} s {segment['label']}: base velocity "
                             f"RMSE {segment['base_vel_rmse']:.3f} m/s, yaw rate {segment['yaw_rate_rmse']:.3f} rad/s "
                             "(estimated)")
        if operator.get("remote"):
            lines.append(f"  remote: {operator['remote']['received']} changes received, {operator['remote']['rejected']} "
                         "rejected")
        if operator.get("meshcat"):
            page = operator["meshcat"]
            lines.append(f"  live page {page['url']}: {page['frames']} frames, {page['rate_hz'] or 0:.1f} Hz")
        return lines
