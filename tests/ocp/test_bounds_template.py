"""`OcpProblem.bounds` from its template (constant entries, contact table) against the straightforward computation
it replaced, bit for bit: on the states of a short closed loop and on varied step data (contacts, soft and relaxed
rows, swing placements, measured foot and hand velocities) for point feet with an arm (b1_z1), flat feet (g1) and
a velocity-level formulation; with NumPy and with the compiled step packer (`solvers/step_pack.py`)."""

from dataclasses import replace

import numpy as np
import pytest

from wbmpc.control import MPC, Commands, MpcConfig
from wbmpc.control.tuning import tuning_for
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import (
    BLEND_TIME_S,
    EARLY_NODES,
    INF,
    SWING_YAW_RATE_BAND_RAD_S,
    WRENCH_CONE_ROWS,
    OcpConfig,
    OcpProblem,
    StageBounds,
)
from wbmpc.robots import load_robot
from wbmpc.solvers import step_pack

GRID = TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05)


def reference_blend(self, lbg, ubg, rows, nodes, target, measured, mask=None) -> None:
    """`OcpProblem._blend_from_measurement` as it was (its decay computed per call from the nodes)."""
    decay = np.minimum(np.maximum(1.0 - self.config.grid.node_times_s[nodes] / BLEND_TIME_S, 0.0), 1.0)
    shape = (len(nodes),) + np.shape(target)[1:]
    path = np.broadcast_to(target + decay.reshape((-1,) + (1,) * (len(shape) - 1)) * (measured - target), shape)
    path = (path[mask] if mask is not None else path).ravel()
    lbg[rows] = path
    ubg[rows] = path


def reference_bounds(self, data: StageBounds):
    """`OcpProblem.bounds` as it was written before its template (session 12, main 59aa322)."""
    robot, N, nf = self.robot, self.N, self.n_feet
    rows, row_nodes = self.rows, self.row_nodes  # (properties: read once)
    lbx = np.full(self.n_variables, -INF)
    ubx = np.full(self.n_variables, INF)
    lbg = np.zeros(self.n_constraints)
    ubg = np.zeros(self.n_constraints)
    contact = np.asarray(data.contact, dtype=bool)
    # eq. (8): joint position / velocity limits on nodes 1..N, torque limits on k < 3
    # The first nodes follow from the measurement (dq_1 = v_0 dt_0; velocities change only by
    # a dt): over the first EARLY_NODES nodes the limits are widened to contain the coasting
    # extrapolation of the measured state, or a state past a limit (e.g. after a push) would
    # make the whole OCP infeasible. Later nodes keep the true limits (eq. 8).
    early = slice(0, min(EARLY_NODES, self.N))
    if "dq" in self.idx:
        joint_dq = self.idx["dq"][1:, 6:]
        q_joints = robot.joint_positions(data.q_ref)
        lbx[joint_dq] = robot.q_min - q_joints
        ubx[joint_dq] = robot.q_max - q_joints
        if "v" in self.state_names:  # Euler: dq_{k+1} = dq_k + v_k dt_k
            coasting = np.outer(self.config.grid.node_times_s[1:], data.v0[6:])[early]
            early_dq = joint_dq[early]
            lbx[early_dq] = np.minimum(lbx[early_dq], np.minimum(coasting, 0.0) - 1e-6)
            ubx[early_dq] = np.maximum(ubx[early_dq], np.maximum(coasting, 0.0) + 1e-6)
    # joint velocities: states from node 1 on, inputs (velocity-level formulations) on every node
    for name, columns in (("v", slice(6, None)), ("vj", slice(None))):
        if name in self.idx:
            joint_v = self.idx[name][1:, columns] if name in self.state_names else self.idx[name][:, columns]
            lbx[joint_v] = -robot.v_max
            ubx[joint_v] = robot.v_max
            overspeed = np.maximum(robot.v_max, np.abs(data.v0[6:]))
            lbx[joint_v[early]] = -overspeed
            ubx[joint_v[early]] = overspeed
    # velocity-level formulations: the first input's joint velocities are the measured ones (the
    # base velocity follows from the measured momentum), so the plan starts from the robot's motion
    for name, columns in (("v", slice(6, None)), ("vj", slice(None))):
        if name in self.idx and name not in self.state_names:
            lbx[self.idx[name][0, columns]] = data.v0[6:]
            ubx[self.idx[name][0, columns]] = data.v0[6:]
    slacks = self.slack_index
    lbx[slacks] = 0.0
    ubx[slacks] = INF if data.soft else 0.0
    n_tau = self.config.n_torque_nodes
    if "tau" in self.idx and not rows["torque_limit"].size:
        lbx[self.idx["tau"][:n_tau]] = -robot.tau_max
        ubx[self.idx["tau"][:n_tau]] = robot.tau_max
    if rows["torque_limit"].size:  # the torque limits as (soft) rows
        lbg[rows["torque_limit"]] = -1.0
        ubg[rows["torque_limit"]] = 1.0
    for tag in ("torque", "implied_torque"):  # estimated / implied torques, in their limits
        if rows[tag].size:
            lbg[rows[tag]] = -1.0
            ubg[rows[tag]] = 1.0
    # eq. (6) forces: stance F_z >= 0, swing F = 0; eq. (7): arm force fixed to the command
    if "F" in self.idx:
        feet_f = self.idx["F"][:, : 3 * nf].reshape(N, nf, 3)
        stance = contact[:N]
        lbx[feet_f[..., 2]] = 0.0
        ubx[feet_f] = np.where(stance[..., None], INF, 0.0)
        lbx[feet_f[..., :2]] = np.where(stance[..., None], -INF, 0.0)
        for i in self.surface_feet:  # a flat foot's moments: free in stance (wrench cone rows), zero in swing
            moments = self.idx["F"][:, self.dyn.moment_slice(i)]
            lbx[moments] = np.where(stance[:, i : i + 1], -INF, 0.0)
            ubx[moments] = np.where(stance[:, i : i + 1], INF, 0.0)
        if self.has_arm:
            arm_f = self.idx["F"][:, 3 * nf : 3 * nf + 3]
            force = np.zeros(3) if data.ee_force_on_robot_n is None else data.ee_force_on_robot_n
            lower, upper = (force, force) if self.object is None else self.object.arm_force_bounds()
            lbx[arm_f] = lower
            ubx[arm_f] = upper
    # node 0 = measured state
    x0 = self.initial_state(data.q_ref, data.v0, data.object_state)
    lbg[rows["x0"][0]] = x0
    ubg[rows["x0"][0]] = x0
    # eq. (6) foot velocities on nodes 1..N: stance 0, swing v_z = reference, v_xy free
    foot_nodes = row_nodes["foot_vel"]
    foot_rows = rows["foot_vel"].reshape(len(foot_nodes), nf, 3)
    swing = ~contact[foot_nodes]
    vz = np.where(swing, data.swing_vz_m_s[foot_nodes], 0.0)
    lbg[foot_rows[..., 2]] = vz
    ubg[foot_rows[..., 2]] = vz
    lbg[foot_rows[..., :2]] = np.where(swing[..., None], -INF, 0.0)
    ubg[foot_rows[..., :2]] = np.where(swing[..., None], INF, 0.0)
    if data.swing_vxy_m_s is not None:  # swing feet carried to their placement
        vxy = np.asarray(data.swing_vxy_m_s, dtype=float)[foot_nodes]
        placed = swing[..., None] & np.isfinite(vxy)
        lbg[foot_rows[..., :2][placed]] = vxy[placed]
        ubg[foot_rows[..., :2][placed]] = vxy[placed]
    if data.foot_velocity_m_s is not None:  # stance feet measured sliding (right after a push)
        stance = np.broadcast_to(~swing[..., None], foot_rows.shape)
        reference_blend(self, lbg, ubg, foot_rows[stance], foot_nodes, np.zeros((1, nf, 3)),
                                     np.asarray(data.foot_velocity_m_s)[None], stance)
    if self.surface_feet:  # flat feet: no rotation in stance, roll and pitch rates zero in swing
        ang_rows = rows["foot_ang"].reshape(len(row_nodes["foot_ang"]), len(self.surface_feet), 3)
        swing_ang = ~contact[row_nodes["foot_ang"]][:, self.surface_feet]
        lbg[ang_rows] = 0.0
        ubg[ang_rows] = 0.0
        lbg[ang_rows[..., 2]] = np.where(swing_ang, -INF, 0.0)
        ubg[ang_rows[..., 2]] = np.where(swing_ang, INF, 0.0)
        if data.swing_yaw_rate_rad_s is not None:  # swing soles turned to their landing heading
            yaw_rate = np.asarray(data.swing_yaw_rate_rad_s, dtype=float)[self.row_nodes["foot_ang"]]
            yaw_rate = yaw_rate[:, self.surface_feet]
            turned = swing_ang & np.isfinite(yaw_rate)
            lbg[ang_rows[..., 2][turned]] = yaw_rate[turned] - SWING_YAW_RATE_BAND_RAD_S
            ubg[ang_rows[..., 2][turned]] = yaw_rate[turned] + SWING_YAW_RATE_BAND_RAD_S
        if data.foot_angular_velocity_rad_s is not None:  # stance soles measured rotating (after a push)
            stance_ang = np.broadcast_to(~swing_ang[..., None], ang_rows.shape)
            measured = np.asarray(data.foot_angular_velocity_rad_s)[self.surface_feet]
            reference_blend(self, lbg, ubg, ang_rows[stance_ang], row_nodes["foot_ang"],
                                         np.zeros((1, len(self.surface_feet), 3)), measured[None], stance_ang)
    if self.has_arm:
        velocity = np.zeros(3) if data.ee_velocity_m_s is None else data.ee_velocity_m_s
        lbg[rows["ee_vel"]] = velocity
        ubg[rows["ee_vel"]] = velocity
        if data.ee_velocity_measured_m_s is not None:
            ee_rows = rows["ee_vel"]
            reference_blend(self, lbg, ubg, ee_rows.ravel(), row_nodes["ee_vel"], velocity[None],
                                         np.asarray(data.ee_velocity_measured_m_s)[None])
    if self.collision is not None:
        self._collision_bounds(lbg, ubg, data)
    if self.object is not None:
        self._object_bounds(lbg, ubg, data)
    for tag in data.relaxed_rows:
        if tag not in ("ee_vel", "foot_vel"):
            raise ConfigError(f"relaxed_rows: only ee_vel and foot_vel rows can be relaxed, got {tag!r}")
        lbg[rows[tag]] = -INF
        ubg[rows[tag]] = INF
    # friction cone: active in stance, free in swing
    if rows["cone"].size:
        ubg[rows["cone"]] = INF
        lbg[rows["cone"]] = np.where(contact[:N][:, self.point_feet], 0.0, -INF)
    if rows["wrench_cone"].size:
        wrench_rows = rows["wrench_cone"].reshape(N, len(self.surface_feet), WRENCH_CONE_ROWS)
        ubg[wrench_rows] = INF
        lbg[wrench_rows] = np.where(contact[:N][:, self.surface_feet, None], 0.0, -INF)
    return lbx / self.x_scale, ubx / self.x_scale, lbg, ubg


def _assert_same(problem, data):
    """NumPy's bounds and, where the step packer compiles, C's (`OcpProblem.bounds_packer`) equal the reference."""
    expected = reference_bounds(problem, data)
    for packer in (None, step_pack.library()) if step_pack.library() is not None else (None,):
        problem.bounds_packer = packer
        got = problem.bounds(data)
        for name, a, b in zip(("lbx", "ubx", "lbg", "ubg"), got, expected):
            assert np.array_equal(a, b) and np.array_equal(np.signbit(a), np.signbit(b)), \
                f"{name} differs at {np.flatnonzero(a != b)[:10]} (packer {packer})"
    problem.bounds_packer = None


def _varied(problem, robot, rng, base: StageBounds | None = None) -> list[StageBounds]:
    """Step data around `base` (or the nominal stance): random contacts and swing references, soft and relaxed rows,
    measured velocities, a hand command and force."""
    n, nf = problem.N + 1, len(robot.feet)
    base = base or StageBounds(v0=np.zeros(robot.nv), q_ref=robot.q_nominal.copy(), contact=np.ones((n, nf)),
                               swing_vz_m_s=np.zeros((n, nf)))
    out = [base]
    for k in range(6):
        contact = (rng.uniform(size=(n, nf)) < 0.6).astype(float)
        v0 = rng.normal(scale=[0.3] * 6 + [4.0] * (robot.nv - 6))  # some joints beyond their velocity limits
        q = base.q_ref.copy()
        q[7:] += rng.normal(scale=0.3, size=robot.nq - 7)
        vxy = rng.normal(size=(n, nf, 2))
        vxy[rng.uniform(size=(n, nf, 2)) < 0.3] = np.nan
        yaw = rng.normal(size=(n, nf))
        yaw[rng.uniform(size=(n, nf)) < 0.3] = np.nan
        out.append(replace(base, v0=v0, q_ref=q, contact=contact, swing_vz_m_s=rng.normal(size=(n, nf)),
                           swing_vxy_m_s=vxy if k % 2 else None,
                           swing_yaw_rate_rad_s=yaw if robot.soles and k % 2 else None,
                           ee_velocity_m_s=rng.normal(size=3) if robot.arm_ee else None,
                           ee_force_on_robot_n=rng.normal(scale=20, size=3) if robot.arm_ee else None,
                           foot_velocity_m_s=rng.normal(size=(nf, 3)) if k % 3 else None,
                           ee_velocity_measured_m_s=rng.normal(size=3) if robot.arm_ee and k % 3 else None,
                           foot_angular_velocity_rad_s=rng.normal(size=(nf, 3)) if robot.soles and k % 3 else None,
                           soft=bool(k % 2), relaxed_rows=(("ee_vel",) if robot.arm_ee else ()) + (("foot_vel",) if k == 5 else ())))
    return out



def recording_bounds(problem) -> list:
    """The StageBounds of every `problem.bounds` call from now on (the call itself unchanged)."""
    recorded, bounds = [], problem.bounds

    def spy(data):
        recorded.append(data)
        return bounds(data)

    problem.bounds = spy
    return recorded


def test_bounds_equal_the_straightforward_ones_on_a_closed_loops_states():
    """b1_z1 (point feet, arm, soft rows), 6 steps 60 ms apart of a trot whose base moves: every step's StageBounds as the MPC
    built them, and varied around each."""
    robot = load_robot("b1_z1")
    mpc = MPC(robot, MpcConfig(ocp=OcpConfig(grid=GRID, soft_rows=("ee_vel", "foot_vel"))))
    problem = mpc.problem
    recorded = recording_bounds(problem)
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    for k in range(6):
        solution = mpc.solve(q, v, Commands(base_velocity_m_s=np.array([0.3, 0.0, 0.0])), t_s=0.06 * k)
        q, v = solution.q[1].copy(), solution.v[1].copy()
    del problem.bounds  # the spy off: the class's own method again
    assert len(recorded) >= 6 and len({r.contact.tobytes() for r in recorded}) > 1  # the contacts changed
    rng = np.random.default_rng(0)
    for data in recorded:
        for varied in _varied(problem, robot, rng, data)[:3]:
            _assert_same(problem, varied)


@pytest.mark.parametrize("robot_name, formulation", [("g1", "wb_inverse"), ("go2", "centroidal_vel"),
                                                      ("b1_z1", "wb_forward")])
def test_bounds_equal_the_straightforward_ones_on_varied_steps(robot_name, formulation):
    """Flat feet (sole moments, wrench cones, yaw rows, implied-torque rows), a velocity-level formulation and a
    forward-dynamics one."""
    robot = load_robot(robot_name)
    problem = OcpProblem(robot, OcpConfig(grid=GRID, formulation=formulation, soft_rows=("foot_vel",)))
    rng = np.random.default_rng(1)
    for data in _varied(problem, robot, rng):
        _assert_same(problem, data)


def _counting(monkeypatch) -> list:
    """The compiled packer's calls of `wbsp_bounds_measured` from now on (skips without a C compiler)."""
    packer = step_pack.library()
    if packer is None:
        pytest.skip("no C compiler")
    calls, measured = [], packer.wbsp_bounds_measured
    monkeypatch.setattr(packer, "wbsp_bounds_measured", lambda *args: calls.append(args) or measured(*args))
    return calls


def test_flat_feet_bounds_are_packed_in_one_compiled_call(monkeypatch):
    """g1 (flat feet: sole moments, wrench cones, yaw-rate bands, measured sole rotation): every step's measured entries
    are written by the compiled packer (`wbsp_bounds_measured`), not by the NumPy fallback, and equal it bit for bit."""
    robot = load_robot("g1")
    problem = OcpProblem(robot, OcpConfig(grid=GRID, soft_rows=("foot_vel",)))
    calls = _counting(monkeypatch)
    steps = _varied(problem, robot, np.random.default_rng(3))
    for data in steps:
        _assert_same(problem, data)
    assert len(calls) == len(steps)  # one C call per step: the flat feet's rows did not fall back to NumPy


def test_flat_feet_bounds_equal_numpys_on_a_walks_states(monkeypatch):
    """g1 walking forward while turning on the small grid: the StageBounds the MPC built in double support and in
    swing (swing placements, yaw rates, measured sole rotation), and varied around each, packed by C as by NumPy."""
    robot = load_robot("g1")
    mpc = MPC(robot, tuning_for(robot).apply_to(MpcConfig(ocp=OcpConfig(grid=GRID), gait="walk")))
    problem = mpc.problem
    recorded = recording_bounds(problem)
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    command = Commands(base_velocity_m_s=np.array([0.3, 0.0, 0.0]), base_yaw_rate_rad_s=0.3)
    for t_s in (0.16, 0.26):
        solution = mpc.solve(q, v, command, t_s=t_s)
        q, v = solution.q[1].copy(), solution.v[1].copy()
    del problem.bounds  # the spy off: the class's own method again
    assert len({r.contact.tobytes() for r in recorded}) > 1
    assert all(np.isfinite(r.swing_yaw_rate_rad_s).any() for r in recorded if not r.contact.all())
    calls, steps = _counting(monkeypatch), [varied for data in recorded
                                            for varied in _varied(problem, robot, np.random.default_rng(4), data)[:3]]
    for data in steps:
        _assert_same(problem, data)
    assert len(calls) == len(steps)
