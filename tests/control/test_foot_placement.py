"""Leg posture references that follow the feet (control/foot_placement.py), checked with pinocchio's forward
kinematics and centre of mass: the centred pose has its CoM over the centre of its feet, and the offsets move
each foot by the displacement the gait and the commanded velocity imply (Raibert's v T_st / 2 at touch-down)."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.foot_placement import StanceReference, swings_in_horizon
from wbmpc.gait import GaitClock, make_gait
from wbmpc.ocp.grid import TimeGrid
from wbmpc.robots import load_robot


def _pose(robot, offsets):
    q = robot.q_nominal.copy()
    q[3:7] = (0.0, 0.0, 0.0, 1.0)
    q[7:] += offsets
    return q


def _feet(robot, q):
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, q)
    return np.array([data.oMf[robot.frame_id(f)].translation.copy() for f in robot.feet]), \
        pin.centerOfMass(model, data, q)


@pytest.mark.parametrize("name", ["a1", "anymal_b_kinova"])  # CoM 3.7 cm behind / 8.5 cm ahead of its feet
def test_in_place_the_feet_are_centred_under_the_com_at_their_nominal_height(name):
    robot = load_robot(name)
    reference = StanceReference(robot)
    gait = make_gait("trot", 4, 0.6)
    offsets = reference.joint_offsets(gait, np.linspace(0, 1.2, 7), np.zeros(3), 0.0)
    assert np.allclose(offsets, offsets[0])  # the same pose at every node
    nominal_feet, _ = _feet(robot, _pose(robot, 0.0))
    feet, com = _feet(robot, _pose(robot, offsets[0]))
    assert np.linalg.norm(feet[:, :2].mean(axis=0) - com[:2]) < 1e-3
    assert np.allclose(feet[:, 2], nominal_feet[:, 2], atol=1e-6)
    assert np.allclose(feet[:, :2] - nominal_feet[:, :2], reference.centring_m, atol=1e-6)  # all feet alike
    assert np.abs(reference.centring_m[0]) > 0.03
    # standing still (duty factor 1): the nominal pose
    assert not np.any(reference.joint_offsets(make_gait("stand", 4), np.zeros(3), np.ones(3), 0.0))


def test_moving_the_feet_land_ahead_by_half_a_stance_and_stance_feet_run_back():
    robot = load_robot("go2")
    reference = StanceReference(robot)
    gait = make_gait("trot", 4, 0.64)  # stance 0.32 s; FL and RR touch down at t = 0, FR and RL at 0.32 s
    velocity = np.array([0.25, 0.05, 0.0])
    times = np.array([0.0, 0.08, 0.16, 0.24])  # FL/RR through their stance, FR/RL through their swing
    offsets = reference.joint_offsets(gait, times, velocity, 0.0)
    centred = reference.joint_offsets(gait, times, np.zeros(3), 0.0)
    centred_feet, _ = _feet(robot, _pose(robot, centred[0]))
    stance_s = 0.32
    for k, t in enumerate(times):
        feet, _ = _feet(robot, _pose(robot, offsets[k]))
        u = t / stance_s  # stance fraction of FL/RR, swing progress of FR/RL
        want = np.array([0.5 - u, u - 0.5, u - 0.5, 0.5 - u])[:, None] * stance_s * velocity[None, :2]
        # first order in the displacement (<= 4 cm here): within 2 mm
        assert np.allclose(feet[:, :2] - centred_feet[:, :2], want, atol=2e-3)
        assert np.allclose(feet[:, 2], centred_feet[:, 2], atol=3e-3)


def test_a_yaw_rate_moves_the_feet_around_the_base():
    robot = load_robot("go2")
    reference = StanceReference(robot)
    gait = make_gait("trot", 4, 0.64)
    offsets = reference.joint_offsets(gait, np.array([0.0]), np.zeros(3), 0.5)  # FL, RR touching down
    centred = reference.joint_offsets(gait, np.array([0.0]), np.zeros(3), 0.0)
    feet, _ = _feet(robot, _pose(robot, offsets[0]))
    centred_feet, _ = _feet(robot, _pose(robot, centred[0]))
    moved = feet[:, :2] - centred_feet[:, :2]
    # counter-clockwise about the base: the left front foot lands back and to the left, the right rear forward
    assert moved[0, 1] > 0.005 and moved[0, 0] < 0 and moved[3, 0] > 0.005


def _swings_reference(gait, t_s, times_s):
    """`swings_in_horizon` as it was (labels by a cumulative sum, one np.unique per foot): the oracle of the faster one."""
    duty = gait.duty_factor
    if duty >= 1:
        return
    swing_s = gait.swing_duration_s
    phase = gait.phase(times_s)
    progress = np.where(phase >= duty, (phase - duty) / (1 - duty), -1.0)
    now_phase = gait.phase(np.array([t_s]))[0]
    for foot in range(phase.shape[1]):
        swinging = progress[:, foot] >= 0
        if not swinging.any():
            continue
        previous = np.r_[-1.0, progress[:-1, foot]]
        labels = np.cumsum(swinging & ((previous < 0) | (progress[:, foot] < previous))) * swinging
        s_now = (now_phase[foot] - duty) / (1 - duty) if now_phase[foot] >= duty else 0.0
        for label in np.unique(labels[labels > 0]):
            nodes = np.flatnonzero(labels == label)
            s = progress[nodes, foot]
            lift_off_t = times_s[nodes[0]] - s[0] * swing_s
            yield foot, nodes, s, lift_off_t, lift_off_t + swing_s, s_now


def test_swings_in_horizon_are_the_labelled_runs_bitwise():
    """The swings of a biped's walk, a trot and a clock that retimes and stands, on the MPC's non-uniform grid and on
    a coarse one whose nodes skip whole stances (a new swing where progress drops): the same nodes and bits as the
    labelled runs."""
    walk, trot = make_gait("walk", 2, leg_length_m=0.75), make_gait("trot", 4, 0.5)
    clock = GaitClock(make_gait("walk", 2, leg_length_m=0.75))
    clock.retime(0.4, 0.7)
    clock.stand_from(1.1)
    grids = (TimeGrid(n_intervals=15).node_times_s, np.linspace(0.0, 2.4, 9), np.linspace(0.0, 0.3, 4))
    count = 0
    for gait in (walk, trot, clock):
        for t_s in np.linspace(0.0, 2.0, 37):
            for grid in grids:
                expected = list(_swings_reference(gait, t_s, t_s + grid))
                got = list(swings_in_horizon(gait, t_s, t_s + grid))
                assert len(got) == len(expected)
                for a, b in zip(got, expected):
                    assert a[0] == b[0] and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
                    assert [float(x) for x in a[3:]] == [float(x) for x in b[3:]]
                count += len(got)
    assert count > 500
