"""Scene objects for loco-manipulation (section VI-C) and what they measure.

Each object adds MuJoCo bodies (`bodies_mjcf`), optional model edits (`edit_spec`: tendons, sites
on the robot), an optional scripted action before every physics step (`before_step`) and a
measurement after it (`measure`): the force the end-effector applies ON the object, in world
coordinates, which the MPC never sees (it treats the arm force as a fixed input, eq. 7; with
`--object-model` it plans that force and reads the object's measured state instead).

- `CableLoad`: a box on the floor with its own friction, tied to the end-effector by a massless
  cable (a MuJoCo spatial tendon with a length limit: it pulls, never pushes). Measured: the
  cable tension and the force along the cable.
- `BoxAtWall`: a free box on the floor standing against a fixed wall. Measured: contact force of
  the end-effector sphere on the box.
- `FreeBox`: a free box on the floor to push along a path. Measured: the end-effector's contact force
  on it and its planar state (`planar_state`: x, y, yaw, vx, vy, wz), which `--object-model` feeds to the MPC.
- `Board`: a fixed board (vertical like a whiteboard, or horizontal like a table) with its own
  friction. Measured: contact force of the end-effector sphere on the board.
- `FixedBox`: a box fixed in the world (a post to reach around). Measured: whether the robot touches it.
- `ExternalHand`: a scripted hand moving the end-effector through a capped spring-damper (a
  person pushing the gripper). Measured: the force the hand applies.

`Scene` groups objects, turns them into a `MujocoPlantConfig` and records every measurement;
`Scene.replay_objects()` gives the objects' boxes and lines over the run for the HTML replay
(`wbmpc.viz.replay`): {"name", "kind": "box", "color", "half_size_m", "position_m", "rotation"}
(static, or with "t" and one pose per time) and {"name", "kind": "line", "color", "t", "points_m"}.
"""

from wbmpc.sim.objects.board import Board
from wbmpc.sim.objects.box_at_wall import BoxAtWall
from wbmpc.sim.objects.cable_load import CableLoad
from wbmpc.sim.objects.common import EE_SITE, SceneObject, ee_body, planar_box_state
from wbmpc.sim.objects.compliant_pad import CompliantPad
from wbmpc.sim.objects.external_hand import ExternalHand, HandPush
from wbmpc.sim.objects.fixed_box import FixedBox, contact_count
from wbmpc.sim.objects.free_box import FreeBox
from wbmpc.sim.objects.scene import Scene, SceneRecording

__all__ = ["EE_SITE", "Board", "BoxAtWall", "CableLoad", "CompliantPad", "ExternalHand", "FixedBox", "FreeBox", "HandPush", "Scene", "SceneObject", "SceneRecording", "contact_count", "ee_body", "planar_box_state"]
