"""What the robot's contacts with the terrain were in MuJoCo: steps climbed, slips, edge contacts, shin/knee hits.

`TerrainContactMonitor` is a step hook of `MujocoPlant` (after every physics step) that reads MuJoCo's contacts
between the robot's geoms and the terrain's (`sim/terrain_geoms.py`, named `terrain:<piece>`, and the floor):

- stood on: the pieces each foot has touched; a piece every foot has touched counts as climbed;
- edge contacts: a foot touching the terrain with the contact's normal more than EDGE_ANGLE_DEG off the terrain's
  normal there (a toe on a riser, a foot on a step's nose) or within EDGE_DISTANCE_M of an edge of the terrain;
  each touch counted once (per foot, when it starts);
- slips: a loaded foot (normal force over SLIP_LOAD_SHARE of the weight shared over the feet) whose contact point
  slides faster than SLIP_SPEED_M_S along the surface for SLIP_MIN_S or longer (not the brief slide of a
  touch-down); counted once per slide, with the distance slid;
- body contacts: any other robot geom touching the terrain (a shin or a knee on a step's edge), per touch, by geom.
"""

from __future__ import annotations

import mujoco
import numpy as np

from wbmpc.robots import GRAVITY_M_S2, RobotModel
from wbmpc.sim.mujoco_scene import is_robot_geom
from wbmpc.sim.terrain_geoms import TERRAIN_PREFIX
from wbmpc.terrain import FootholdConfig, FootholdMap, Terrain

EDGE_ANGLE_DEG = 30.0
EDGE_DISTANCE_M = 0.01
SLIP_SPEED_M_S = 0.1
SLIP_LOAD_SHARE = 0.1
SLIP_MIN_S = 0.01


class TerrainContactMonitor:
    """Counts a run's contacts with the terrain (see the module docstring); `metrics()` reports them."""

    def __init__(self, model: mujoco.MjModel, robot: RobotModel, terrain: Terrain):
        self.robot, self.terrain = robot, terrain
        self._pieces = {}  # geom id -> piece name ("floor" for the floor plane)
        for g in range(model.ngeom):
            name = model.geom(g).name
            if name.startswith(TERRAIN_PREFIX):
                self._pieces[g] = name[len(TERRAIN_PREFIX):]
            elif name == "floor":
                self._pieces[g] = "floor"
        self._robot = is_robot_geom(model)
        self._feet = {int(model.geom(f).id): k for k, f in enumerate(robot.feet)}
        self._edges = FootholdMap(terrain, FootholdConfig(keep_out_m=0.0)) if terrain.pieces else None
        self._raster = terrain.raster()  # normals and edge distances looked up on its 1 cm cells (every step)
        self._load_n = SLIP_LOAD_SHARE * robot.mass_kg * GRAVITY_M_S2 / len(robot.feet)
        self._force = np.zeros(6)
        self._velocity = np.zeros(6)
        n_feet = len(robot.feet)
        self.stood_on: list[set[str]] = [set() for _ in range(n_feet)]
        self.edge_contacts = np.zeros(n_feet, dtype=int)
        self.slips = np.zeros(n_feet, dtype=int)
        self.slip_distance_m = np.zeros(n_feet)
        self.body_contacts: dict[str, int] = {}
        self.body_contact_time_s = 0.0
        self._on_edge = np.zeros(n_feet, dtype=bool)
        self._slipping = np.zeros(n_feet, dtype=bool)
        self._sliding_s = np.zeros(n_feet)  # how long each foot has been sliding
        self._slid_m = np.zeros(n_feet)  # ... and how far
        self._body_touching: set[str] = set()
        self.first_body_contact: dict | None = None

    def before_step(self, plant) -> None:
        pass

    def after_step(self, plant) -> None:
        m, d = plant.model, plant.data
        n = d.ncon
        on_edge = np.zeros_like(self._on_edge)
        slipping = np.zeros_like(self._slipping)
        body = set()
        if n:
            geoms = d.contact.geom[:n]
            for c in np.flatnonzero(self._robot[geoms[:, 0]] ^ self._robot[geoms[:, 1]]):
                g1, g2 = int(geoms[c, 0]), int(geoms[c, 1])
                mine, other = (g1, g2) if self._robot[g1] else (g2, g1)
                piece = self._pieces.get(other)
                if piece is None:  # a scene object, not the terrain
                    continue
                foot = self._feet.get(mine)
                if foot is None:
                    body.add(f"{m.geom(mine).name} / {piece}")
                    continue
                self.stood_on[foot].add(piece)
                frame = d.contact.frame[c].reshape(3, 3)
                position = d.contact.pos[c]
                normal = frame[0] if mine == g2 else -frame[0]  # pointing from the terrain to the foot
                i, j, inside = self._raster.cell(position[:2])
                terrain_normal = self._raster.normals[i, j] if inside else np.array([0.0, 0.0, 1.0])
                tilted = float(normal @ terrain_normal) < np.cos(np.deg2rad(EDGE_ANGLE_DEG))
                near_edge = self._edges is not None and inside and self._edges.edge_distance_m[i, j] < EDGE_DISTANCE_M
                on_edge[foot] |= tilted or near_edge
                mujoco.mj_contactForce(m, d, c, self._force)
                if self._force[0] > self._load_n:
                    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_GEOM, mine, self._velocity, 0)
                    linear = self._velocity[3:] + np.cross(self._velocity[:3], position - d.geom_xpos[mine])
                    sliding = linear - (linear @ normal) * normal
                    speed = float(np.linalg.norm(sliding))
                    if speed > SLIP_SPEED_M_S and not slipping[foot]:
                        slipping[foot] = True
                        self._slid_m[foot] += speed * plant.dt_s
        self.edge_contacts += on_edge & ~self._on_edge
        self._sliding_s = np.where(slipping, self._sliding_s + plant.dt_s, 0.0)
        long_enough = self._sliding_s >= SLIP_MIN_S - 1e-9
        self.slips += long_enough & ~self._slipping
        self.slip_distance_m += np.where(long_enough, self._slid_m, 0.0)
        self._slid_m = np.where(slipping & ~long_enough, self._slid_m, 0.0)
        self._on_edge, self._slipping = on_edge, long_enough
        for name in body - self._body_touching:
            self.body_contacts[name] = self.body_contacts.get(name, 0) + 1
            if self.first_body_contact is None:
                self.first_body_contact = {"t_s": float(plant.time_s), "contact": name}
        if body:
            self.body_contact_time_s += plant.dt_s
        self._body_touching = body

    def metrics(self) -> dict:
        pieces = [p.name for p in self.terrain.pieces]
        climbed = [p for p in pieces if all(p in feet for feet in self.stood_on)]
        return {
            "terrain": self.terrain.name,
            "steps_total": len(pieces),
            "steps_climbed": len(climbed),  # pieces every foot stood on
            "pieces_climbed": climbed,
            "pieces_stood_on": len({p for feet in self.stood_on for p in feet if p in pieces}),  # by any foot
            "foot_floor_touches": int(sum("floor" in feet for feet in self.stood_on)),  # feet that touched the floor
            "foot_slips": int(self.slips.sum()),
            "foot_slip_distance_m": float(self.slip_distance_m.sum()),
            "edge_contacts": int(self.edge_contacts.sum()),
            "edge_contacts_per_foot": {f: int(c) for f, c in zip(self.robot.feet, self.edge_contacts)},
            "body_terrain_contacts": int(sum(self.body_contacts.values())),
            "body_terrain_contact_time_s": float(self.body_contact_time_s),
            "body_terrain_contact_pairs": dict(sorted(self.body_contacts.items(), key=lambda item: -item[1])),
            "first_body_terrain_contact": self.first_body_contact,
        }

