"""The named closed-loop scenarios (`SCENARIOS`) and `make_scenario`, which fits one to a robot.

Locomotion (`scenarios/locomotion.py`), arm tracking (`scenarios/arm_track.py`) and the loco-manipulation tasks of
section VI-C (`pull`, `push-box`, `wipe`, `compliant`, one module each), the terrain courses (`stairs`, `slope`,
`stepping-stones`: `scenarios/terrain.py`).
"""

from __future__ import annotations

from wbmpc.errors import ConfigError, unknown_name
from wbmpc.gait import gaits_for, natural_gait
from wbmpc.robots import RobotModel
from wbmpc.scenarios.arm_track import ArmTrack
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.compliant import Compliant
from wbmpc.scenarios.locomotion import Push, Stand, TrotForward, TrotInPlace, WalkForward, WalkInPlace
from wbmpc.scenarios.pull import Pull
from wbmpc.scenarios.push_box import PushBox
from wbmpc.scenarios.terrain import Slope, Stairs, SteppingStones
from wbmpc.scenarios.wipe import Wipe

SCENARIOS = {cls(ScenarioOptions()).name: cls for cls in (Stand, TrotInPlace, TrotForward, WalkInPlace, WalkForward,
                                                                 Push, ArmTrack, Pull, PushBox, Wipe, Compliant, Stairs,
                                                                 Slope, SteppingStones)}
TROT_SCENARIOS = ("trot-in-place", "trot-forward")  # trot by name: refused on robots without a trot


def make_scenario(name: str, robot: RobotModel | None, options: ScenarioOptions | None = None) -> Scenario:
    """The scenario `name` for `robot` (its gait fitted to the robot's feet, checked against it); with no
    robot, the scenario as declared (configuration tests)."""
    if name not in SCENARIOS:
        raise ConfigError(unknown_name("scenario", name, SCENARIOS))
    scenario = SCENARIOS[name](options or ScenarioOptions())
    if robot is None:
        return scenario
    gaits = gaits_for(len(robot.feet))
    if scenario.gait not in gaits:
        if name in TROT_SCENARIOS or (options is not None and options.gait is not None):
            raise ConfigError(f"scenario '{name}' runs the {scenario.gait} gait, which {robot.name} "
                              f"({len(robot.feet)} feet) does not have; its gaits: {', '.join(gaits)}"
                              + (" (walk-in-place / walk-forward walk it)" if "walk" in gaits else ""))
        scenario.gait = natural_gait(len(robot.feet))  # tasks that step: the robot's own gait
    if scenario.needs_arm and robot.arm_ee is None:
        raise ConfigError(f"scenario '{name}' needs a robot with an arm (--arm-ee); {robot.name} has none")
    scenario.check(robot)
    return scenario
