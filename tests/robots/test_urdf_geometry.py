"""Reference poses (SRDF) and collision primitives (URDF) read through pinocchio's own parsers give
the values the earlier ElementTree readers gave, on every preset; a URDF whose mesh files are missing
keeps its primitives; bad SRDF values are still refused by name."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.errors import ModelError
from wbmpc.robots import load_robot
from wbmpc.robots.model import RobotModel
from wbmpc.robots.presets import PRESET_NAMES, preset_spec
from wbmpc.robots.urdf_geometry import collision_primitives
from wbmpc.sim.shapes import urdf_primitives

# preset: (sum |q_ref| of the SRDF pose, foot radius m, URDF primitives kept, sum of their sizes and
# |positions|), as the ElementTree readers gave them before the move to pinocchio
PREVIOUS = {
    "b1_z1": (11.673560000, 0.04, 33, 9.027200000),
    "b1_z1_full": (11.673560000, 0.04, 33, 8.908000000),
    "go2_z1": (10.507000000, 0.02, 8, 1.873700000),
    "b1": (11.150000000, 0.04, 25, 6.770500000),
    "go1": (11.872000000, 0.02, 25, 4.066450000),
    "go2": (10.507000000, 0.02, 0, 0.000000000),
    "a1": (11.700000000, 0.02, 17, 2.884500000),
    "laikago": (1.000000000, 0.0265, 17, 3.675300000),
    "anymal_b": (8.679200000, 0.031, 37, 12.001150000),
    "anymal_b_kinova": (20.198373063, 0.031, 39, 12.819684000),
    "anymal_c": (8.728000000, 0.03, 37, 13.113689243),
    "hyq": (11.377500000, 0.02175, 4, 1.464000000),
    "solo8": (10.835000000, 0.02, 0, 0.000000000),
    "solo12": (11.235000000, 0.02, 0, 0.000000000),
    "quadruped": (1.000000000, 0.025, 9, 1.805000000),
    "centauro": (27.787589000, 0.02, 6, 1.052394789),
    "bolt": (6.667263150, 0.02, 0, 0.000000000),
    "alexander": (3.926800000, 0.02, 0, 0.000000000),
    "talos": (7.581191000, 0.02, 5, 0.734100000),
    "talos_full": (7.581191000, 0.02, 5, 0.734100000),
    "romeo": (12.892526600, 0.02, 0, 0.000000000),
    "icub": (5.525100000, 0.02, 0, 0.000000000),
    "icub_full": (5.525100000, 0.02, 0, 0.000000000),
    "g1": (1.000000000, 0.005, 4, 0.426000000),
    "simple_humanoid": (6.410516000, 0.02, 1, 1.500000000),
}


def test_every_preset_is_listed():
    assert set(PREVIOUS) == set(PRESET_NAMES)


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_pose_foot_radius_and_primitives_are_the_previous_ones(name):
    spec = preset_spec(name)
    q_sum, foot_radius, n_shapes, shape_sum = PREVIOUS[name]
    full = pin.buildModelFromUrdf(str(spec.urdf), pin.JointModelFreeFlyer())
    assert np.abs(RobotModel.reference_configuration(full, spec)).sum() == pytest.approx(q_sum, abs=1e-9)
    robot = load_robot(name)
    assert robot.foot_radius_m == pytest.approx(foot_radius, abs=1e-12)
    shapes = [s for group in urdf_primitives(robot).values() for s in group]
    assert len(shapes) == n_shapes
    assert sum(sum(s.size) + np.abs(s.pos).sum() for s in shapes) == pytest.approx(shape_sum, abs=1e-9)


def test_pose_is_pinocchios_reference_configuration():
    spec = preset_spec("b1_z1")
    full = pin.buildModelFromUrdf(str(spec.urdf), pin.JointModelFreeFlyer())
    ours = RobotModel.reference_configuration(full, spec)
    pin.loadReferenceConfigurations(full, str(spec.srdf), False)
    np.testing.assert_array_equal(ours, full.referenceConfigurations[spec.pose])


def test_a_urdf_without_its_mesh_files_keeps_its_primitives(tmp_path):
    """pinocchio's parser fails on the first missing mesh: the primitives are then read without it."""
    robot = load_robot("b1_z1")  # box, cylinder and sphere collisions, and two meshes (the gripper)
    text = Path(robot.spec.urdf).read_text()
    broken = tmp_path / "b1_z1.urdf"
    broken.write_text(re.sub(r'filename="[^"]*"', 'filename="missing/mesh.dae"', text))
    with pytest.raises((RuntimeError, ValueError)):
        pin.buildGeomFromUrdf(robot.model, str(broken), pin.GeometryType.COLLISION)
    expected = {(p.name, p.kind, p.size) for p in collision_primitives(robot.model, robot.spec.urdf)}
    got = collision_primitives(robot.model, broken)
    assert {(p.name, p.kind, p.size) for p in got} == expected
    placements = {p.name: p.placement for p in collision_primitives(robot.model, robot.spec.urdf)}
    for p in got:
        assert np.allclose(p.placement.homogeneous, placements[p.name].homogeneous)


def test_collision_checking_capsule_is_read_as_a_capsule():
    """simple_humanoid's URDF asks (<collision_checking><capsule/>) for its body cylinder as a capsule:
    pinocchio honours that, the ElementTree reader gave a cylinder."""
    robot = load_robot("simple_humanoid")
    (body,) = [p for p in collision_primitives(robot.model, robot.spec.urdf) if p.link == "BODY"]
    assert body.kind == "capsule" and body.size == (1.0, 0.5)


def test_bad_srdf_values_are_refused_by_name(tmp_path):
    spec = preset_spec("go2")
    text = Path(spec.srdf).read_text()
    full = pin.buildModelFromUrdf(str(spec.urdf), pin.JointModelFreeFlyer())
    for value, words in (("abc", "non-numeric"), ("inf", "non-finite"), ("0.1 0.2", "needs 1 values")):
        bad = tmp_path / "bad.srdf"
        bad.write_text(re.sub(r'(<joint name="FL_hip_joint" value=")[^"]*"', rf'\g<1>{value}"', text, count=1))
        with pytest.raises(ModelError, match=words):
            RobotModel.reference_configuration(full, type(spec)(**{**spec.__dict__, "srdf": bad}))
