"""An operator in the loop of `wbmpc run`: the sources, the session and the live viewer around one closed-loop run.

`prepare(robot, config, scenario)` checks everything that can be wrong before anything is built (the script, the
terminal, the gamepad, the display) and `OperatorRun.attach(mpc, plant, loop)` wires the session into the run:
the loop's command source, its stop condition (a lie-down command, the viewer closed), the board's clock and
the viewer as plant step hooks, the plans as they come.
"""

from __future__ import annotations

import sys
from typing import Callable

import numpy as np

from wbmpc.control.loop import MPC_RATE_HZ
from wbmpc.gait import natural_gait
from wbmpc.operator.command import OperatorCommand, OperatorLimits
from wbmpc.operator.config import OperatorConfig
from wbmpc.operator.script import ScriptSource, read_script
from wbmpc.operator.session import OperatorSession
from wbmpc.operator.shaper import RampLimits
from wbmpc.robots import RobotModel


class _BoardClock:
    """A plant step hook that keeps the board's clock on simulated time (a live key's timestamp)."""

    def __init__(self, board):
        self.board = board

    def before_step(self, plant) -> None:
        self.board.set_time(plant.time_s)

    def after_step(self, plant) -> None:
        pass


class OperatorRun:
    """See the module docstring; inactive (the scenario's commands as they are) without operator options."""

    def __init__(self, robot: RobotModel, config: OperatorConfig, scenario, sources: list, script=None,
                 initial: OperatorCommand | None = None, echo=None):
        self.robot, self.config, self.scenario, self.script = robot, config, scenario, script
        self.limits = OperatorLimits.for_robot(robot)
        self.sources = sources
        self.initial = initial or OperatorCommand()
        self.echo = echo if echo is not None else sys.stderr
        self.session: OperatorSession | None = None
        self.viewer = None
        self.ended_by: str | None = None

    @property
    def active(self) -> bool:
        return self.config.active

    @property
    def duration_s(self) -> float | None:
        return self.script.duration_s if self.script is not None else None

    def attach(self, mpc, plant, loop, stop: Callable[[], bool]) -> tuple[Callable, Callable[[], bool]]:
        """The loop's (command source, stop condition) for this run."""
        base = self.scenario.commands(self.robot)
        if not self.active:
            return base, stop
        self.session = OperatorSession(self.robot, self.limits, self.sources, self.initial, base_commands=base,
                                       ramp=RampLimits(linear_accel_m_s2=self.config.max_accel_m_s2,
                                                       yaw_accel_rad_s2=self.config.max_yaw_accel_rad_s2),
                                       gait_mirror=mpc.gait, passthrough_motion=not self.config.sources_given)
        board = self.session.board
        board.add_listener(self._say)
        if self.script is not None and self.script.ignored:
            board.notice(f"{self.robot.name} has no arm: the script's {', '.join(self.script.ignored)} commands are "
                         "ignored")
        plant.add_step_hook(_BoardClock(board))
        if self.config.viewer:
            from wbmpc.viz.live_viewer import LiveViewer

            self.viewer = LiveViewer(self.robot, plant, self.session)
            plant.add_step_hook(self.viewer)
            loop.solution_listeners.append(self.viewer.on_plan)

        def stopped() -> bool:
            if stop():
                return True
            if self.session.lie_down_requested:
                self.ended_by = f"lie-down command at {board.now_s:.2f} s"
                return True
            if self.viewer is not None and not self.viewer.is_running():
                self.ended_by = f"viewer closed at {board.now_s:.2f} s"
                return True
            return False

        return self.session, stopped

    def plant_config(self, plant_config):
        """The plant's MuJoCo settings with the viewer's draggable hand target (a robot with an arm)."""
        if not self.config.viewer or self.robot.arm_ee is None:
            return plant_config
        import dataclasses

        from wbmpc.sim.base import PlantConfig, specialised_config
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig
        from wbmpc.viz.live_viewer import hand_target_mjcf

        config = specialised_config(plant_config or PlantConfig(), MujocoPlantConfig)
        home = self.robot.frame_trajectories(self.robot.q_nominal[None, :], [self.robot.arm_ee])[self.robot.arm_ee][0]
        return dataclasses.replace(config, extra_bodies_mjcf=(*config.extra_bodies_mjcf, hand_target_mjcf(home)))

    def __enter__(self) -> "OperatorRun":
        return self

    def start(self) -> None:
        if self.session is not None:
            if self.viewer is not None:
                self.viewer.open()
            self.session.start()

    def __exit__(self, *exc) -> None:
        if self.session is not None:
            self.session.close()
        if self.viewer is not None:
            self.viewer.close()

    def _say(self, item) -> None:
        """Live posts and notices on stderr (a script's run prints its entries, a keyboard run its keys)."""
        text = item if isinstance(item, str) else f"{item.stamp_s:7.2f} s {item.note or item.source}: " \
            f"{item.command.describe()}"
        print(f"wbmpc: {text}", file=self.echo, flush=True)

    def finish(self, log, mpc) -> dict:
        """The session's metrics (`metrics.json` "operator"); the viewer's pushes joined to the log's events. A run
        ended by a lie-down command or a closed viewer is complete, not interrupted."""
        if self.session is None:
            return {}
        from wbmpc.operator.metrics import operator_metrics

        if self.viewer is not None:
            log.events.extend(self.viewer.events)
            log.events.sort(key=lambda e: e[0])
        if self.ended_by is not None:
            log.interrupted = False
        labels = {}
        if self.script is not None:
            by_note = {f"script: {e.label}": e.label for e in self.script.entries}
            labels = {p.seq: by_note[p.note] for p in self.session.posts() if p.note in by_note}
        arrays = log.arrays(("t", "q", "v", "mpc_t", "planned_contact"))
        metrics = operator_metrics(self.robot, arrays, self.session, mpc.gait.nominal_period_s,
                                   transitions=mpc.gait.transitions, labels=labels,
                                   mpc_period_s=1.0 / (log.mpc_rate_hz or MPC_RATE_HZ))
        metrics["ended_by"] = self.ended_by
        metrics["script"] = self.script.path if self.script is not None else None
        if self.viewer is not None:
            metrics["viewer"] = self.viewer.summary()
        return {"operator": metrics}


def prepare(robot: RobotModel, config: OperatorConfig, scenario) -> OperatorRun:
    """Read and check the sources before anything is built: the script against the robot's ranges, a terminal
    for the keyboard, a gamepad, a display for the viewer. Moves a standing scenario onto the robot's walking
    gait (it starts standing: the operator decides when it walks)."""
    if not config.active:
        return OperatorRun(robot, config, scenario, [])
    limits = OperatorLimits.for_robot(robot)
    if config.viewer:
        from wbmpc.viz.live_viewer import check_display

        check_display()
    base = scenario.commands(robot)(0.0, robot.q_nominal, np.zeros(robot.nv))
    walking = scenario.gait != "stand"
    initial = OperatorCommand(forward_m_s=float(base.base_velocity_m_s[0]), lateral_m_s=float(base.base_velocity_m_s[1]),
                              yaw_rate_rad_s=float(base.base_yaw_rate_rad_s), walking=walking)
    if config.sources_given and scenario.gait == "stand":
        scenario.gait = natural_gait(len(robot.feet))
    sources, script = [], None
    if config.commands_file:
        script = read_script(config.commands_file, limits, initial)
        sources.append(ScriptSource(script))
    if config.keyboard:
        from wbmpc.operator.keyboard import KeyboardSource

        sources.append(KeyboardSource(limits))
    if config.gamepad:
        from wbmpc.operator.gamepad import GamepadSource

        sources.append(GamepadSource(limits, path=None if config.gamepad == "auto" else config.gamepad))
    return OperatorRun(robot, config, scenario, sources, script, initial)
