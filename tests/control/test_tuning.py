"""Settings derived from the robot (control/tuning.py): the paper robot keeps its settings, a preset and its
--urdf twin get the same ones, a scaled robot gets them scaled as designed, and overrides win."""

import dataclasses
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from wbmpc.cli import build_parser, gains_from_args, main
from wbmpc.control import CostWeights, PushConfig
from wbmpc.control.interpolator import PdGains
from wbmpc.control.tuning import (
    ACCELERATION,
    LEG_POSTURE,
    REFERENCE,
    TUNINGS,
    RobotScale,
    derive,
    tuning_for,
    with_overrides,
)
from wbmpc.gait import SwingProfile
from wbmpc.robots import RobotModel, custom_spec, load_robot, preset_spec
from wbmpc.scenarios import RunConfig, make_scenario
from wbmpc.scenarios.runner import mpc_config_for


def _config(robot):
    return mpc_config_for(make_scenario("trot-in-place", robot, RunConfig().options), RunConfig(), robot)


def test_the_paper_robot_is_the_reference_and_keeps_todays_settings(b1z1):
    assert RobotScale.of(b1z1) == REFERENCE
    tuning = tuning_for(b1z1)
    # the legs' posture weight and the acceleration regularisation depart from the paper's settings (module docstring)
    w = CostWeights()
    paper = dataclasses.replace(w, leg_joint_position=LEG_POSTURE * w.leg_joint_position,
                                acceleration=ACCELERATION * w.acceleration)
    assert (tuning.weights, tuning.gains, tuning.swing) == (paper, PdGains(), SwingProfile())
    assert tuning.gait_period_s == 0.8
    config = _config(b1z1)
    assert config.weights == paper and config.gait_period_s == 0.8
    default = PushConfig()
    assert (config.push.velocity_error_m_s, config.push.hold_s, config.push.cadence_hold_s) == (
        default.velocity_error_m_s, default.hold_s, default.cadence_hold_s)
    assert set(entry["source"] for entry in tuning.report().values()) == {"derived"}


def test_small_robots_get_froude_scaled_steps_near_the_hand_tuned_a1_entry():
    """The issue's hand-tuned A1 entry (5 cm steps at 0.6 s, Kd 3) kept Go2 and Go1 up."""
    for name in ("a1", "go1", "go2"):
        tuning = derive(RobotScale.of(load_robot(name)))
        assert 0.55 <= tuning.gait_period_s <= 0.66
        assert 0.04 <= tuning.swing.apex_height_m <= 0.055
        assert 2.2 <= tuning.gains.kd_leg <= 3.0


def test_a_robot_without_an_arm_holds_its_place_harder_and_the_same_arm_gets_the_same_gains():
    from wbmpc.control.tuning import ANCHOR_WITHOUT_ARM

    b1, b1z1 = tuning_for("b1").weights, tuning_for("b1_z1").weights  # same legs
    assert b1.base_position[:2] == pytest.approx(tuple(ANCHOR_WITHOUT_ARM * x for x in b1z1.base_position[:2]))
    assert b1.base_position[2] == b1z1.base_position[2]
    go2_z1 = tuning_for("go2_z1")
    assert (go2_z1.gains.kp_arm, go2_z1.gains.kd_arm) == (PdGains().kp_arm, PdGains().kd_arm)  # the Z1's own


def test_the_table_only_overrides_and_says_so():
    go1 = tuning_for("go1")
    assert go1.swing.apex_height_m == TUNINGS["go1"]["swing.apex_height_m"]
    assert go1.report()["swing.apex_height_m"]["source"] == "table"
    assert go1.gait_period_s == derive(RobotScale.of(load_robot("go1"))).gait_period_s  # the rest derived


def test_a_preset_and_its_urdf_twin_get_the_same_settings():
    spec = preset_spec("go2")
    twin = RobotModel(custom_spec(str(spec.urdf), list(spec.feet), srdf=str(spec.srdf), pose=spec.pose))
    assert twin.name == "go2"
    renamed = RobotModel(dataclasses.replace(twin.spec, name="my_dog"))
    assert tuning_for(renamed) == tuning_for(twin) == tuning_for("go2")


def _scaled_urdf(source, target, length: float, mass: float) -> None:
    """A copy of a URDF with every length times `length` and every mass times `mass` (inertias follow)."""
    root = ET.parse(source).getroot()
    for origin in root.iter("origin"):
        origin.set("xyz", " ".join(str(length * float(x)) for x in origin.get("xyz", "0 0 0").split()))
    for inertial in root.iter("inertial"):
        m = inertial.find("mass")
        m.set("value", str(mass * float(m.get("value"))))
        inertia = inertial.find("inertia")
        for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
            inertia.set(key, str(mass * length**2 * float(inertia.get(key))))
    for sphere in root.iter("sphere"):
        sphere.set("radius", str(length * float(sphere.get("radius"))))
    for cylinder in root.iter("cylinder"):
        for key in ("radius", "length"):
            cylinder.set(key, str(length * float(cylinder.get(key))))
    for box in root.iter("box"):
        box.set("size", " ".join(str(length * float(x)) for x in box.get("size").split()))
    ET.ElementTree(root).write(target)


@pytest.mark.parametrize("length, mass", [(2.0, 8.0), (1.0, 3.0)])
def test_settings_scale_as_designed_with_the_robots_size_and_mass(tmp_path, length, mass):
    spec = preset_spec("go2")
    _scaled_urdf(spec.urdf, tmp_path / "big.urdf", length, mass)
    big = RobotModel(custom_spec(str(tmp_path / "big.urdf"), list(spec.feet), srdf=str(spec.srdf), pose=spec.pose))
    scale, big_scale = RobotScale.of(load_robot("go2")), RobotScale.of(big)
    assert big_scale.leg_length_m == pytest.approx(length * scale.leg_length_m, rel=1e-9)
    assert big_scale.mass_kg == pytest.approx(mass * scale.mass_kg, rel=1e-9)
    small, large = tuning_for("go2"), tuning_for(big)
    froude = math.sqrt(length)
    assert large.gait_period_s == pytest.approx(froude * small.gait_period_s)  # Froude: time ~ sqrt(L / g)
    assert large.push_hold_s == pytest.approx(froude * small.push_hold_s)
    assert large.push_velocity_error_m_s == pytest.approx(froude * small.push_velocity_error_m_s)  # speed ~ sqrt(g L)
    assert large.swing.apex_height_m == pytest.approx(length * small.swing.apex_height_m)
    assert large.gains.kd_leg == pytest.approx(math.sqrt(mass) * small.gains.kd_leg)  # critical damping ~ sqrt(M)
    w, W = small.weights, large.weights
    assert W.base_position == pytest.approx(tuple(x / length**2 for x in w.base_position))  # per m^2
    assert W.base_orientation == w.base_orientation and W.leg_joint_position == w.leg_joint_position  # angles
    assert W.base_linear_velocity == pytest.approx(w.base_linear_velocity / length)  # per (m/s)^2 ~ 1 / (g L)
    assert W.joint_velocity == pytest.approx(w.joint_velocity * length)  # per (rad/s)^2 ~ L / g
    assert W.acceleration == pytest.approx(w.acceleration * length**2)
    assert (W.contact_force, W.joint_torque) == (w.contact_force, w.joint_torque)  # regularisation, per N^2


def test_table_overrides_and_options_win_and_say_so(monkeypatch):
    monkeypatch.setitem(TUNINGS, "go2", {"gains.kd_leg": 2.0, "gait_period_s": 0.5})
    tuning = tuning_for(load_robot("go2"))
    assert tuning.gains.kd_leg == 2.0 and tuning.gait_period_s == 0.5
    report = tuning.report({"gains.kd_leg": 7.5})
    assert report["gait_period_s"] == {"value": 0.5, "source": "table"}
    assert report["gains.kd_leg"] == {"value": 7.5, "source": "option"}
    assert report["swing.apex_height_m"]["source"] == "derived"
    config = _config(load_robot("go2"))
    assert config.gait_period_s == 0.5
    args = build_parser().parse_args(["run", "trot-in-place", "--robot", "go2", "--kd", "7.5"])
    assert gains_from_args(args, load_robot("go2"), 0.002) == dataclasses.replace(tuning.gains_at(0.002), kd_leg=7.5)
    assert with_overrides(tuning, {"weights.base_position": [1, 2, 3]}).weights.base_position == (1, 2, 3)


def test_derived_settings_reach_the_mpc_config_and_gains():
    robot = load_robot("a1")
    tuning, config = tuning_for(robot), _config(robot)
    assert (config.weights, config.swing, config.gait_period_s) == (tuning.weights, tuning.swing, tuning.gait_period_s)
    assert config.push.velocity_error_m_s == tuning.push_velocity_error_m_s
    assert gains_from_args(build_parser().parse_args(["run", "trot-in-place", "--robot", "a1"]), robot, 0.002) is None


def test_info_prints_every_setting_and_its_source(capsys):
    assert main(["info", "--robot", "go2", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {"robot", "nq", "nv", "n_joints", "mass_kg", "feet", "arm_ee", "joints"} <= set(info)
    assert info["settings"]["gait_period_s"]["source"] == "derived"
    assert info["settings"]["gains.kd_leg"]["value"] == pytest.approx(tuning_for("go2").gains_at().kd_leg)
    assert info["settings"]["gains.kd_leg"]["source"] == "derived"  # Kd T / I = 1.7 at 500 Hz: not capped
    capped = tuning_for("solo12").report()["gains.kd_leg"]
    assert capped["source"].startswith("joint loop: 1.01 capped") and capped["value"] < 0.4
    assert info["scale"]["leg_length_m"] == pytest.approx(RobotScale.of(load_robot("go2")).leg_length_m)


def test_pull_keeps_the_papers_leg_posture_weight_and_other_scenarios_the_derived_one():
    from wbmpc.control.tuning import LEG_POSTURE
    from wbmpc.scenarios import RunConfig, make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    robot = load_robot("b1_z1")
    derived = tuning_for(robot).weights.leg_joint_position
    for name, expected in (("pull", derived / LEG_POSTURE), ("trot-forward", derived), ("push-box", derived)):
        config = mpc_config_for(make_scenario(name, robot), RunConfig(scenario=name), robot)
        assert config.weights.leg_joint_position == pytest.approx(expected), name


def test_the_held_dampers_are_stable_at_the_default_joint_loop_and_derived_from_the_mass():
    """Eq. (10)'s damper held one 500 Hz tick: Kd T / I within the bound on the lightest joint mode of every
    quadruped (I: pinocchio's joint-space inertia, base fixed); the tuned Kd itself follows sqrt(M)."""
    from wbmpc.control.joint_loop import DAMPER_BOUND, joint_mode_inertia
    from wbmpc.control.tuning import DEFAULT_HOLD_S

    for name in ("b1_z1", "b1", "go2", "go1", "a1", "anymal_c", "anymal_b_kinova", "go2_z1", "solo12"):
        robot = load_robot(name)
        tuning = tuning_for(robot)
        inertia = joint_mode_inertia(robot, robot.leg_joint_mask)
        kd = tuning.gains_at(DEFAULT_HOLD_S).kd_leg
        assert kd * DEFAULT_HOLD_S / inertia <= DAMPER_BOUND * (1 + 1e-9) < 2, name
        assert tuning.gains.kd_leg == pytest.approx(PdGains().kd_leg * math.sqrt(robot.mass_kg / REFERENCE.mass_kg))
    b1z1 = tuning_for("b1_z1")
    assert b1z1.gains_at(1 / 200) == b1z1.gains  # the paper's robot keeps its gains at 200 Hz

def test_flat_feet_weigh_their_sole_moments_at_the_soles_lever(b1z1):
    """w_F: contact_force on every force; on flat feet's sole moments (the last three columns per sole)
    contact_force / half width^2 (the force the moment puts on the centre-of-pressure rows), or contact_moment
    when set; point feet have no moments: all contact_force."""
    from wbmpc.symbolic.dynamics import SymbolicDynamics

    g1 = load_robot("g1")
    dyn = SymbolicDynamics(g1)
    weights = CostWeights(contact_force=1e-5)
    w_f = weights.vectors(g1, dyn.n_forces)["w_F"]
    np.testing.assert_array_equal(w_f[: dyn.n_linear_forces], 1e-5)
    for i, foot in enumerate(g1.feet):
        sole = g1.soles[foot]
        np.testing.assert_allclose(w_f[dyn.moment_slice(i)], 1e-5 / sole.half_width_m**2, rtol=1e-12)
    explicit = dataclasses.replace(weights, contact_moment=2e-3).vectors(g1, dyn.n_forces)["w_F"]
    np.testing.assert_array_equal(explicit[dyn.n_linear_forces :], 2e-3)
    np.testing.assert_array_equal(CostWeights().vectors(b1z1, 15)["w_F"], CostWeights().contact_force)
