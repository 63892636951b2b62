"""The contact schedule following measured touch-down (issue 37, item 2): early and late feet.

The gait clock says when each foot lands; a plant that differs from the model lands it earlier (a floor
higher than planned, a foot that swung low) or later (a heavier leg, a lower floor). Where the plant
measures its foot contacts (foot force sensors; MuJoCo's contact forces in simulation), `follow_touchdown`
corrects the schedule of one MPC step before the OCP is built:

- early: a foot the gait has in the descending half of its swing that already carries load is in stance on
  the nodes up to its planned touch-down (no swing row pulls it back up, and the plan may load it);
- late: a foot the gait has in stance for less than `late_window` of a swing duration that carries no load
  stays in swing on the nodes within that window, reaching down at the touch-down velocity of the swing
  profile (at least `min_reach_m_s`) until it finds the ground; later nodes keep the gait's stance.

Off by default (`ReferenceConfig.touchdown_events`): it is switched on where it measured better (docs/design/reality-gap.md).
"""

from __future__ import annotations

import numpy as np

from wbmpc.gait import Gait

LATE_WINDOW = 0.25  # share of a swing duration a late foot may keep reaching down
MIN_REACH_M_S = 0.1  # the downward velocity a late foot reaches with, at least


def follow_touchdown(gait: Gait, t_s: float, node_times_s: np.ndarray, contact: np.ndarray, swing_vz: np.ndarray,
                     measured: np.ndarray, touchdown_velocity_m_s: float = 0.0,
                     late_window: float = LATE_WINDOW, min_reach_m_s: float = MIN_REACH_M_S) -> tuple[np.ndarray, np.ndarray]:
    """(contact, swing_vz) of the horizon at `t_s` corrected by `measured` (one bool per foot: loaded now)."""
    contact, swing_vz = np.array(contact, dtype=float), np.array(swing_vz, dtype=float)
    measured = np.asarray(measured, dtype=bool)
    swing = gait.swing_duration_s
    if swing <= 0:
        return contact, swing_vz
    now = gait.swing_phase(np.array([t_s]))[0]  # progress through swing, -1 in stance
    phase = gait.phase(np.array([t_s]))[0]
    times = t_s + np.asarray(node_times_s, dtype=float)
    for i, loaded in enumerate(measured):
        if now[i] >= 0.5 and loaded:  # early: down before the gait says so
            landing = t_s + (1.0 - now[i]) * swing  # the planned touch-down
            nodes = times < landing - 1e-9
            contact[nodes, i] = 1.0
            swing_vz[nodes, i] = 0.0
        elif now[i] < 0 and not loaded:  # in stance by the gait: late if it landed less than the window ago
            since_landing = ((phase[i] % 1.0) * gait.period_s)  # stance starts at phase 0
            if since_landing < late_window * swing:
                nodes = times < t_s + (late_window * swing - since_landing) - 1e-9
                contact[nodes, i] = 0.0
                swing_vz[nodes, i] = -max(abs(touchdown_velocity_m_s), min_reach_m_s)
    return contact, swing_vz


def measured_contacts(forces_world_n: np.ndarray, weight_n: float, share: float = 0.05) -> np.ndarray:
    """Feet carrying more than `share` of the robot's weight (normal force), from world-frame foot forces (n, 3)."""
    return np.asarray(forces_world_n, dtype=float)[:, 2] > share * weight_n
