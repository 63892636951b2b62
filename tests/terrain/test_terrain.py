"""Terrain as data (`wbmpc.terrain`) against the MuJoCo geometry it builds, its files and their errors, safe footholds,
and what the MPC takes from it: the swing spline over a step, the cones about the ground's normal, the start pose."""

from __future__ import annotations

import casadi as ca
import mujoco
import numpy as np
import pytest
import yaml

from wbmpc.control.terrain_references import APEX_SHARES, TerrainReferences
from wbmpc.gait import SwingProfile, make_gait, swing_between
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.sim.mujoco_scene import MujocoPlantConfig, build_model
from wbmpc.sim.terrain_geoms import check_start_pose, geom_name
from wbmpc.terrain import (
    Box,
    FootholdConfig,
    FootholdMap,
    Heightmap,
    Ramp,
    Terrain,
    TerrainError,
    load_terrain,
    save_terrain,
    stairs,
    stepping_stones,
)


@pytest.fixture(scope="module")
def go2():
    return load_robot("go2")


def mixed_terrain(rng) -> Terrain:
    """Every kind of piece: stairs, a turned box, ramps up and down, a random heightmap, over a lowered floor."""
    return Terrain(stairs(3, 0.1, 0.3, 0.5).pieces + (
        Box((-1.5, 1.2), (0.4, 0.25), 0.15, yaw_deg=30.0, name="turned"),
        Ramp((-2.5, -0.5, 0.0), (-1.2, -0.5, 0.35), 0.8, name="up"),
        Ramp((0.0, -2.0, 0.3), (0.0, -3.0, 0.05), 0.6, name="down"),
        Heightmap(rng.uniform(0.0, 0.12, (9, 13)), 0.07, origin_m=(3.0, -0.3), name="rubble"),
    ), floor_m=-0.05, name="mixed")


def ray_heights(model, data, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Heights, normals and geom names where vertical rays from above hit MuJoCo's geometry first."""
    heights, normals, names = [], [], []
    gid = np.zeros(1, np.int32)
    for x, y in xy:
        normal = np.zeros(3)
        distance = mujoco.mj_ray(model, data, np.array([x, y, 3.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, gid, normal)
        heights.append(3.0 - distance)
        normals.append(normal)
        names.append(model.geom(int(gid[0])).name)
    return np.array(heights), np.array(normals), names


def test_heights_and_normals_match_the_mujoco_geometry_they_build(go2, rng):
    """Ray casts straight down at random points (away from the robot standing at the origin) hit MuJoCo's boxes,
    wedge meshes and height field where `Terrain.height_normal` says, with its normal."""
    terrain = mixed_terrain(rng)
    model = build_model(go2, MujocoPlantConfig(terrain=terrain))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    points = np.column_stack([rng.uniform(-3.0, 3.5, 3000), rng.uniform(-3.2, 1.6, 3000)])
    points = points[np.hypot(*points.T) > 0.6]  # rays on the robot would hit it
    heights, normals, names = ray_heights(model, data, points)
    expected_h, expected_n = terrain.height_normal(points)
    np.testing.assert_allclose(heights, expected_h, atol=1e-6)
    assert {geom_name(p.name) for p in terrain.pieces} | {"floor"} <= set(names)  # every piece was hit
    # normals: away from the pieces' edges, where a ray can graze a side face
    around = points[:, None] + np.array([[0.0, 0.0], [0.01, 0.0], [-0.01, 0.0], [0.0, 0.01], [0.0, -0.01]])
    pieces = np.array([terrain.piece_at(p) for p in around])
    interior = np.all(pieces == pieces[:, :1], axis=1)
    assert interior.sum() > 1000
    np.testing.assert_allclose(normals[interior], expected_n[interior], atol=1e-6)
    tilted = interior & (expected_n[:, 2] < 0.999)
    assert tilted.sum() > 50  # ramps and the heightmap's triangles were among them


def test_terrain_files_round_trip_and_heightmap_images(tmp_path, rng):
    from PIL import Image

    pixels = (rng.uniform(0, 255, (6, 9))).astype(np.uint8)
    Image.fromarray(pixels, mode="L").save(tmp_path / "bumps.png")
    np.save(tmp_path / "bumps.npy", rng.uniform(0.0, 0.1, (4, 5)))
    (tmp_path / "course.yaml").write_text(yaml.safe_dump({
        "name": "course", "floor": 0.0,
        "boxes": [{"name": "step", "centre": [1.0, 0.0], "size": [0.3, 1.0], "top": 0.1}],
        "ramps": [{"start": [2.0, 0.0, 0.0], "end": [3.0, 0.0, 0.2], "width": 1.0}],
        "heightmaps": [{"name": "image", "file": "bumps.png", "resolution": 0.05, "origin": [4.0, 0.0],
                        "height_range": [0.0, 0.2]},
                       {"name": "array", "file": "bumps.npy", "resolution": 0.1, "origin": [-2.0, 0.0]}]}))
    terrain = load_terrain(tmp_path / "course.yaml")
    assert [p.name for p in terrain.pieces] == ["step", "ramp 1", "image", "array"]
    image = terrain.pieces[2]
    # the image's top row is the largest y: pixel (row 0, column 3) at y = (rows - 1) resolution
    assert image.heights_m[-1, 3] == pytest.approx(0.2 * pixels[0, 3] / 255)
    assert terrain.height([4.0 + 3 * 0.05, 5 * 0.05]) == pytest.approx(0.2 * pixels[0, 3] / 255)
    saved = load_terrain(save_terrain(terrain, tmp_path / "saved.yaml"))
    points = rng.uniform([-2.5, -0.5], [4.5, 0.8], (500, 2))
    np.testing.assert_allclose(saved.height(points), terrain.height(points))


@pytest.mark.parametrize("content, message", [
    ({"boxes": [{"name": "step 1", "centre": [1.0, 0.0], "size": [0.3, 1.0], "top": 0.1},
                {"name": "step 2", "centre": [1.2, 0.0], "size": [0.3, 1.0], "top": 0.2}]},
     "box 'step 1' and box 'step 2' overlap by 10.0 cm"),
    ({"heightmaps": [{"name": "flat", "heights": [0.0, 0.1, 0.2], "resolution": 0.1}]},
     "heightmap 'flat': the heights must be a 2D array"),
    ({"heightmaps": [{"name": "ragged", "heights": [[0.0, 0.1], [0.2]], "resolution": 0.1}]}, "rows of equal length"),
    ({"boxes": [{"centre": [1.0, 0.0], "size": [0.3, 1.0]}]}, "boxes[0]: missing top"),
    ({"boxes": [{"centre": [1.0, 0.0], "size": [0.3, 1.0], "top": 0.1, "hieght": 2}]}, "unknown key(s) hieght"),
    ({"stairs": []}, "unknown key(s) stairs"),
    ({"ramps": [{"start": [0, 0, -0.1], "end": [1, 0, 0.1], "width": 1}]}, "below the floor"),
])
def test_bad_terrain_files_are_refused_naming_the_file_and_the_piece(tmp_path, content, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(content))
    with pytest.raises(TerrainError) as error:
        load_terrain(path)
    assert message in str(error.value) and str(path) in str(error.value)


def test_a_heightmap_file_that_is_not_2d_is_refused(tmp_path):
    np.save(tmp_path / "cube.npy", np.zeros((3, 4, 2)))
    (tmp_path / "t.yaml").write_text("heightmaps:\n  - {name: cube, file: cube.npy, resolution: 0.1}\n")
    with pytest.raises(TerrainError, match=r"heightmaps\[0\] \(cube\).*2D array.*\(3, 4, 2\)"):
        load_terrain(tmp_path / "t.yaml")
    with pytest.raises(TerrainError, match="does not exist"):
        load_terrain(tmp_path / "missing.yaml")


def test_footholds_keep_out_of_the_band_at_every_edge():
    terrain = stairs(3, 0.12, 0.3, 0.5)
    footholds = FootholdMap(terrain, FootholdConfig(keep_out_m=0.07))
    edges = np.array([0.5, 0.8, 1.1])  # risers (up 1, up 2, landing)
    for x in np.linspace(0.3, 1.3, 101):
        moved = footholds.adapt(np.array([x, 0.1]))
        distance = np.min(np.abs(moved[0] - edges))
        if np.min(np.abs(x - edges)) > 0.09:  # beyond the band and the raster's 1 cm cells
            assert moved[0] == x  # safe targets stay where they are
        elif np.min(np.abs(x - edges)) < 0.07:
            assert distance >= 0.07  # ... unsafe ones land outside the band
            assert abs(moved[0] - x) <= 0.09  # on the nearer side
    stones = FootholdMap(stepping_stones(0.1, 0.6), FootholdConfig(keep_out_m=0.05))
    landed = stones.adapt(np.random.default_rng(0).uniform([0.6, -0.6], [3.4, 0.6], (400, 2)))
    assert np.all(stepping_stones(0.1, 0.6).height(landed) == 0.0)  # never in a gap


@pytest.mark.parametrize("riser_share", [0.2, 0.35, 0.5, 0.65, 0.8])
def test_the_swing_spline_clears_a_step_of_known_height(go2, riser_share):
    """From the floor onto a 12 cm step whose riser lies anywhere between lift-off and landing: the planned
    foot (eq. 6's spline between the two heights, apex the swing height above the top, the xy path's 6 s (1 - s)
    profile) stays above the terrain under it by the foot's radius all along, and lands on the step's top."""
    length, rise = 0.25, 0.12
    terrain = Terrain((Box((riser_share * length + 0.5, 0.0), (1.0, 1.0), rise, name="step"),))
    swing = SwingProfile(apex_height_m=0.06)
    references = TerrainReferences(go2, terrain, swing, FootholdConfig(keep_out_m=0.0))
    start, target = np.array([0.0, 0.0]), np.array([length, 0.0])
    h0, apex, h1, share = references._swing_heights(0, start, target)
    radius = go2.foot_radius_m
    assert (h0, h1, apex) == pytest.approx((radius, rise + radius, rise + radius + 0.06))
    progress = np.linspace(0.0, 1.0, 2001)
    height, velocity = swing_between(progress, 0.3, h0, apex, h1, share)
    xy = start + np.outer(3 * progress**2 - 2 * progress**3, target - start)
    ground = terrain.height(xy + [radius, 0.0])  # the sphere's front: over the riser first
    assert np.all(height - radius >= ground - 1e-9)
    assert height[-1] == pytest.approx(h1) and velocity[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.trapezoid(velocity, progress * 0.3) == pytest.approx(h1 - h0, abs=1e-6)  # v_z integrates to the rise
    assert share in APEX_SHARES
    if riser_share >= 0.5:
        assert share == 0.5  # eq. (6)'s midway apex where it clears


def test_swing_references_land_on_the_step_and_cones_tilt_with_the_ramp(go2):
    """One MPC step's terrain data for go2 trotting towards a ramp: the swing feet land on safe cells, the normals
    of the nodes after a landing on the ramp are its normal, the swing v_z integrate to the landing heights."""
    angle = np.deg2rad(15.0)
    ramp = Ramp((0.25, 0.0, 0.0), (1.75, 0.0, 1.5 * np.tan(angle)), 3.0, name="ramp")
    terrain = Terrain((ramp,))
    gait = make_gait("trot", 4, 0.65)
    references = TerrainReferences(go2, terrain, SwingProfile(apex_height_m=0.05))
    q = go2.q_nominal.copy()
    q[0] = 0.05
    feet = np.array([go2.frame_trajectories(q, [f])[f][0] for f in go2.feet])
    node_times = np.linspace(0.0, 0.56, 15)
    t = 0.65 * 0.5 - 0.01  # the FR/RL pair is about to swing... both pairs swing within the horizon
    step = references.step(gait, t, node_times, q, np.array([0.3, 0.0, 0.0]), np.array([0.3, 0.0, 0.0]), 0.0, feet)
    on_ramp = step.footholds_m[-1, :, 0] > 0.25  # the ramp meets the floor without an edge: no keep-out band
    assert on_ramp[:2].all() and not on_ramp[2:].any()  # the front feet land on it, the rear ones before it
    normals = step.contact_normal.T.reshape(len(node_times) - 1, 4, 3)
    np.testing.assert_allclose(normals[-1, on_ramp], np.tile(ramp.normal(np.zeros((1, 2)))[0], (on_ramp.sum(), 1)),
                               atol=1e-12)
    assert np.all(references.footholds.is_safe(step.footholds_m[-1, :, :2]))
    np.testing.assert_allclose(step.footholds_m[-1, :, 2],
                               terrain.height(step.footholds_m[-1, :, :2]) + go2.foot_radius_m)


def test_swing_plans_are_kept_within_a_raster_cell_and_planned_again_beyond(go2):
    """go2 trotting towards stairs: a base moved 4 mm keeps the swings' landings and heights of the step before (the
    landings on safe cells); moved 3 cm, every swing is planned again: the same data as a fresh plan (no kept ones)."""
    import copy

    terrain = stairs(3, 0.08, 0.25, 0.45)
    gait = make_gait("trot", 4, 0.65)
    references = TerrainReferences(go2, terrain, SwingProfile(apex_height_m=0.05))
    q = go2.q_nominal.copy()
    q[0] = 0.1
    node_times = np.linspace(0.0, 0.56, 15)
    velocity = np.array([0.3, 0.0, 0.0])

    def step(refs, dx):
        moved = q.copy()
        moved[0] += dx
        feet = np.array([go2.frame_trajectories(moved, [f])[f][0] for f in go2.feet])
        return refs.step(gait, 0.3, node_times, moved, velocity, velocity, 0.0, feet)

    first = step(references, 0.0)
    kept = step(references, 0.004)
    swinging = np.isfinite(first.apex_m)
    assert swinging.any(axis=0).sum() >= 2
    np.testing.assert_array_equal(kept.footholds_m[-1, :, :2][swinging.any(axis=0)],
                                  first.footholds_m[-1, :, :2][swinging.any(axis=0)])
    np.testing.assert_array_equal(kept.apex_m[swinging], first.apex_m[swinging])
    assert np.all(references.footholds.is_safe(kept.footholds_m[-1, :, :2]))
    fresh = copy.deepcopy(references)
    fresh._plans.clear()
    again, new = step(references, 0.03), step(fresh, 0.03)
    assert np.abs(again.footholds_m[-1, :, 0] - first.footholds_m[-1, :, 0]).max() > 0.01
    np.testing.assert_array_equal(again.footholds_m, new.footholds_m)
    np.testing.assert_array_equal(again.swing_vz_m_s, new.swing_vz_m_s)


def test_a_bipeds_base_target_moves_with_a_landing_moved_onto_a_step():
    """g1 walking up to a step whose near edge is where Raibert's point would land: the landings move onto the tread's
    safe band (against the same walk before a box far away), and the base's xy target ramps forward with them, by at
    least half the first one's move and at most the largest; the walk on a terrain is 1.4 times slower than on
    the floor. A quadruped's base is left on its path."""
    from wbmpc.control.biped import BIPED_TERRAIN_PERIOD_SCALE
    from wbmpc.control.policy import MpcChoices, TaskNeeds, mpc_config

    g1 = load_robot("g1")
    terrain = stairs(1, 0.1, 0.3, 0.2, landing_m=1.0, direction="up")
    flat = mpc_config(g1, TaskNeeds(gait="walk"), MpcChoices())
    on_stairs = mpc_config(g1, TaskNeeds(gait="walk", terrain=terrain), MpcChoices())
    assert on_stairs.gait_period_s == pytest.approx(BIPED_TERRAIN_PERIOD_SCALE * flat.gait_period_s)
    gait = make_gait("walk", 2, on_stairs.gait_period_s)
    feet = np.array([g1.frame_trajectories(g1.q_nominal, [f])[f][0] for f in g1.feet])
    node_times = np.linspace(0.0, 1.2, 25)
    velocity = np.array([0.2, 0.0, 0.0])

    def step(ground):
        references = TerrainReferences(g1, ground, on_stairs.swing, support_lead_s=on_stairs.references.support_lead_s)
        return references, references.step(gait, 0.0, node_times, g1.q_nominal, velocity, velocity, 0.0, feet)

    references, up = step(terrain)
    _, far = step(Terrain((Box((5.0, 0.0), (0.5, 0.5), 0.1, name="far"),)))
    moves = up.footholds_m[-1, :, 0] - far.footholds_m[-1, :, 0]
    assert moves.min() >= -1e-9 and moves.max() > 0.05 and np.all(up.footholds_m[-1, :, 2] > 0.05)  # up, forward
    assert np.all(references.footholds.is_safe(up.footholds_m[-1, :, :2]))
    assert np.allclose(far.support_shift_m, 0.0)
    shift_x = up.support_shift_m[:, 0]
    assert shift_x[0] == pytest.approx(0.0) and 0.5 * moves[0] <= shift_x.max() <= moves.max() + 1e-9
    assert np.all(np.diff(shift_x[: np.argmax(shift_x) + 1]) >= -1e-12)  # ramped in (then back as the other lands)
    a1 = load_robot("a1")
    assert TerrainReferences(a1, terrain, SwingProfile()).step(
        make_gait("trot", 4, 0.5), 0.0, node_times, a1.q_nominal, velocity, velocity, 0.0,
        np.array([a1.frame_trajectories(a1.q_nominal, [f])[f][0] for f in a1.feet])).support_shift_m is None


def cone_rows(robot, normal, force, mu=0.5):
    """The friction / wrench cone rows of a first-node stage with every foot's force `force` (world, N) and the
    ground normal `normal` for every foot."""
    problem = OcpProblem(robot, OcpConfig(formulation="wb_inverse"))
    function, tags = problem.stage_function(1)
    names = [tag for tag, _ in tags]
    tag = "wrench_cone" if problem.surface_feet else "cone"
    start = sum(size for _, size in tags[: names.index(tag)])
    size = dict(tags)[tag]
    stage_p = ca.Function("p_k", [problem.nlp["p"]], [problem.stage_parameters(problem.nlp["p"], 1)])
    values = {name: np.zeros(problem.params.shape(name)) for name in problem.params.names}
    values.update(q_ref=robot.q_nominal, rot_ref=np.eye(3), mu=mu,
                  contact_normal=np.tile(normal, (problem.N, problem.n_feet)).T)
    scales = problem.formulation.variable_scales()
    forces = np.zeros(problem.nf)
    for i in range(problem.n_feet):
        forces[3 * i : 3 * i + 3] = force
    u = np.zeros(function.size1_in(1))
    u[problem.idx["F"][1] - problem.stage_slices[1][1].start] = forces / scales["F"]
    _, rows, _ = function(np.zeros(problem.nx), u, stage_p(problem.params.pack(values)))
    return np.array(rows).ravel()[start : start + size] * scales["F"][2], problem


def test_friction_cones_are_taken_about_the_ground_normal(go2):
    """A force along a tilted normal is well inside the cone; one at mu off the normal (in the tilted plane) is on
    its boundary, one beyond it outside; world-z cones would judge the same forces differently."""
    angle = np.deg2rad(20.0)
    normal = np.array([-np.sin(angle), 0.0, np.cos(angle)])
    tangent = np.array([np.cos(angle), 0.0, np.sin(angle)])
    mu = 0.5
    along, _ = cone_rows(go2, normal, 100.0 * normal, mu)
    np.testing.assert_allclose(along, mu * 100.0, rtol=1e-4)  # mu f_n - |f_t| (smoothing: eps scale)
    boundary, _ = cone_rows(go2, normal, 100.0 * normal + mu * 100.0 * tangent, mu)
    np.testing.assert_allclose(boundary, 0.0, atol=0.2)
    outside, _ = cone_rows(go2, normal, 100.0 * normal + 1.2 * mu * 100.0 * tangent, mu)
    assert np.all(outside < -5.0)
    flat, _ = cone_rows(go2, np.array([0.0, 0.0, 1.0]), 100.0 * normal + 1.2 * mu * 100.0 * tangent, mu)
    assert np.all(flat > 0.0)  # about world z the same force would pass


def test_flat_feet_wrench_cones_are_taken_about_the_ground_normal():
    g1 = load_robot("g1")
    angle = np.deg2rad(15.0)
    normal = np.array([0.0, -np.sin(angle), np.cos(angle)])  # a slope across the heading
    across = np.cross(normal, [np.cos(angle) * 0 + 1.0, 0.0, 0.0])  # unused: the pyramid's own tangents below
    del across
    mu = 0.6
    rows, _ = cone_rows(g1, normal, 100.0 * normal, mu)
    pyramid = rows.reshape(2, 10)[:, :4]
    np.testing.assert_allclose(pyramid, mu * 100.0, rtol=1e-9)  # no tangential force: every side at mu f_n
    second = np.cross(normal, np.array([normal[2], 0.0, -normal[0]]) / np.hypot(normal[0], normal[2]))
    rows, _ = cone_rows(g1, normal, 100.0 * normal + mu * 100.0 * second, mu)
    np.testing.assert_allclose(rows.reshape(2, 10)[:, 2:4], [[0.0, 2 * mu * 100.0]] * 2, atol=1e-9)


def test_flat_floor_normals_give_the_world_z_cone_exactly(go2):
    """With the normal world z the rows are those of the paper's cone, mu F_z - sqrt(F_x^2 + F_y^2 + eps^2) + eps."""
    force = np.array([30.0, -20.0, 80.0])
    rows, problem = cone_rows(go2, np.array([0.0, 0.0, 1.0]), force, 0.7)
    scale = problem.formulation.variable_scales()["F"][2]
    unit = force / scale
    eps = 1e-3
    expected = (0.7 * unit[2] - np.sqrt(unit[0] ** 2 + unit[1] ** 2 + eps**2) + eps) * scale
    assert np.all(rows == expected)


def test_a_start_pose_inside_the_terrain_is_refused_naming_where(go2):
    q = go2.q_nominal
    with pytest.raises(TerrainError, match=r"start pose puts (FL|FR)_foot .* inside the terrain \('step'\) at x 0\.1"):
        check_start_pose(go2, Terrain((Box((0.3, 0.0), (0.4, 1.0), 0.05, name="step"),)), q)
    with pytest.raises(TerrainError, match=r"base_box .* inside the terrain \('block'\)"):
        check_start_pose(go2, Terrain((Box((0.0, 0.0), (0.1, 0.1), 0.3, name="block"),)), q)
    with pytest.raises(TerrainError, match=r"leaves (RL|RR)_foot .* above the terrain"):
        check_start_pose(go2, Terrain((Box((0.3, 0.0), (0.5, 1.0), 0.05, name="step"),)),
                         q + np.r_[0.0, 0.0, 0.05, np.zeros(go2.nq - 3)])
    check_start_pose(go2, stairs(5, 0.08, 0.25, 0.4), q)  # on the floor before the stairs: fine
