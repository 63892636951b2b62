"""Robot presets from the installed example-robot-data package, and custom-URDF specs."""

from __future__ import annotations

import importlib.metadata
from functools import lru_cache
from pathlib import Path

from wbmpc.errors import ModelError, unknown_name
from wbmpc.robots.model import RobotModel, RobotSpec

QUADRUPED_FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")


@lru_cache(maxsize=1)
def example_robot_data_dir() -> Path:
    """The `robots/` folder of the installed example-robot-data wheel (found through pip metadata)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:
        raise ModelError("example-robot-data is not installed: pip install example-robot-data") from exc
    for candidate in (
        "cmeel.prefix/share/example-robot-data/robots",
        "share/example-robot-data/robots",
    ):
        path = Path(dist.locate_file(candidate))
        if path.is_dir():
            return path
    for file in dist.files or []:
        if str(file).endswith("robots/b1_description/urdf/b1.urdf"):
            return Path(dist.locate_file(file)).parents[2]
    raise ModelError("example-robot-data is installed but its robots/ folder was not found")


def _erd(relative: str) -> Path:
    return example_robot_data_dir() / relative


def _presets() -> dict[str, RobotSpec]:
    b1z1 = dict(
        urdf=_erd("b1_description/urdf/b1-z1.urdf"),
        srdf=_erd("b1_description/srdf/b1-z1.srdf"),
        pose="standing_with_arm_up",
        feet=QUADRUPED_FEET,
        arm_ee="gripperStator",
    )
    return {
        # Paper model: 6 base + 12 legs + 4 arm DoF (section V-B).
        "b1_z1": RobotSpec(name="b1_z1", locked_joints=("joint5", "joint6", "jointGripper"), **b1z1),
        "b1_z1_full": RobotSpec(name="b1_z1_full", locked_joints=("jointGripper",), **b1z1),
        "b1": RobotSpec(
            name="b1",
            urdf=_erd("b1_description/urdf/b1.urdf"),
            srdf=_erd("b1_description/srdf/b1.srdf"),
            pose="standing",
            feet=QUADRUPED_FEET,
        ),
        "go2": RobotSpec(
            name="go2",
            urdf=_erd("go2_description/urdf/go2.urdf"),
            srdf=_erd("go2_description/srdf/go2.srdf"),
            pose="standing",
            feet=QUADRUPED_FEET,
        ),
        "a1": RobotSpec(
            name="a1",
            urdf=_erd("a1_description/urdf/a1.urdf"),
            srdf=_erd("a1_description/srdf/a1.srdf"),
            pose="standing",
            feet=QUADRUPED_FEET,
        ),
    }


PRESET_NAMES = ("b1_z1", "b1_z1_full", "b1", "go2", "a1")


def preset_spec(name: str) -> RobotSpec:
    presets = _presets()
    if name not in presets:
        raise ModelError(unknown_name("robot", name, presets))
    return presets[name]


@lru_cache(maxsize=8)
def load_robot(name: str = "b1_z1") -> RobotModel:
    """Load a preset robot (cached: robots are immutable once built)."""
    return RobotModel(preset_spec(name))


def custom_spec(
    urdf: str,
    feet: list[str],
    arm_ee: str | None = None,
    srdf: str | None = None,
    pose: str | None = None,
    lock: list[str] | None = None,
    name: str | None = None,
) -> RobotSpec:
    """Spec for any legged robot given by the user (CLI --urdf/--srdf/--pose/--feet/--arm-ee/--lock)."""
    return RobotSpec(
        name=name or Path(urdf).stem,
        urdf=Path(urdf),
        srdf=Path(srdf) if srdf else None,
        pose=pose,
        feet=tuple(feet),
        arm_ee=arm_ee,
        locked_joints=tuple(lock or ()),
    )
