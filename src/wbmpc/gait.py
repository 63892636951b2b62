"""Gait schedules sampled on any time grid, and the swing-foot vertical velocity spline (eq. 6).

A gait is periodic: foot i is in stance while its phase (t / period + offset_i) mod 1 is below
the duty factor, in swing otherwise. The MPC samples the schedule on its (non-uniform) node
times; the swing reference v_z^ref is the derivative of a cubic height profile through lift-off,
apex and touch-down, with the lift-off and touch-down velocities as boundary conditions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wbmpc.errors import ConfigError, check_number, unknown_name

SWITCH_TOLERANCE_S = 1e-7  # contact switches closer than this are one (a trot's pairs), checked this far either side


@dataclass(frozen=True)
class Gait:
    """Periodic contact pattern for feet in `robot.feet` order (FL, FR, RL, RR for quadrupeds)."""

    name: str
    period_s: float
    duty_factor: float  # share of the period in stance
    phase_offsets: tuple[float, ...]  # per foot, in periods

    def __post_init__(self):
        check_number("period_s", self.period_s, low=0.0, high=10.0, low_open=True, unit="s")
        if not 0 < self.duty_factor <= 1:
            raise ConfigError(f"gait duty factor must be in (0, 1], got {self.duty_factor}")
        object.__setattr__(self, "_offsets", np.asarray(self.phase_offsets, dtype=float)[None, :])  # (read by `phase`)
        # the cycle phases (in [0, 1)) of the touchdowns and lift-offs (read by `switch_times`)
        object.__setattr__(self, "_switch_phases", tuple(sorted({float((-o) % 1.0) for o in self.phase_offsets} |
                                                                {float((self.duty_factor - o) % 1.0)
                                                                 for o in self.phase_offsets})))

    @property
    def swing_duration_s(self) -> float:
        return (1 - self.duty_factor) * self.period_s

    def cycles(self, times_s: np.ndarray) -> np.ndarray:
        """Gait cycles elapsed at each time (phase before the per-foot offsets, not wrapped)."""
        return np.asarray(times_s, dtype=float) / self.period_s

    def phase(self, times_s: np.ndarray) -> np.ndarray:
        """(len(times), n_feet) phase of each foot in [0, 1): stance below the duty factor."""
        cycles = np.atleast_1d(self.cycles(times_s))[:, None]
        return np.mod(cycles + self._offsets, 1.0)

    def swing_phase(self, times_s: np.ndarray) -> np.ndarray:
        """(len(times), n_feet) progress through swing in [0, 1), or -1 where the foot is in stance."""
        phase = self.phase(times_s)
        if self.duty_factor >= 1:
            return -np.ones_like(phase)
        progress = (phase - self.duty_factor) / (1 - self.duty_factor)
        return np.where(phase < self.duty_factor, -1.0, progress)

    def contact(self, times_s: np.ndarray) -> np.ndarray:
        """(len(times), n_feet) 1.0 where the foot is in stance."""
        return (self.swing_phase(times_s) < 0).astype(float)

    @property
    def anchors(self) -> list[tuple[float, float, float]]:
        """(from t, cycles there, period) of each piece of the clock: one piece for a fixed gait."""
        return [(0.0, 0.0, self.period_s)]

    def switch_times(self, start_s: float, end_s: float) -> np.ndarray:
        """The sorted times in (start_s, end_s) at which some foot's contact changes (touchdown: phase 0, lift-off:
        the duty factor), each once (a trot's pairs switch together). Solved on each linear piece of the clock (in
        Python floats: a few per step); with standing intervals kept where `contact` changes across it."""
        if self.duty_factor >= 1 or not end_s > start_s:
            return np.zeros(0)
        anchors, events = self.anchors, self._switch_phases
        first = next((i for i in range(len(anchors) - 1, -1, -1) if anchors[i][0] <= start_s), 0)
        found = []
        for i in range(first, len(anchors)):  # cycles = c0 + (t - t0) / period from t0 to the next anchor
            t0, c0, period = anchors[i]
            lo, hi = max(start_s, t0), min(end_s, anchors[i + 1][0]) if i + 1 < len(anchors) else end_s
            if lo >= end_s:
                break
            for whole in range(math.floor(c0 + (lo - t0) / period) - 1, math.ceil(c0 + (hi - t0) / period) + 1):
                for event in events:
                    time_s = t0 + ((whole + event) - c0) * period
                    if lo <= time_s < hi and time_s > start_s:  # (a piece may start on one)
                        found.append(time_s)
        found.sort()
        times = np.array([t for k, t in enumerate(found) if k == 0 or t - found[k - 1] > SWITCH_TOLERANCE_S])
        if times.size and getattr(self, "stand_intervals", None):
            before, after = self.contact(times - SWITCH_TOLERANCE_S), self.contact(times + SWITCH_TOLERANCE_S)
            times = times[(before != after).any(axis=1)]
        return times


@dataclass(frozen=True)
class SwingProfile:
    """Cubic-spline swing height: apex height, lift-off and touch-down vertical velocities."""

    apex_height_m: float = 0.08
    liftoff_velocity_m_s: float = 0.0
    touchdown_velocity_m_s: float = 0.0

    def vertical_velocity(self, progress: np.ndarray, swing_duration_s: float) -> np.ndarray:
        """v_z^ref at swing progress s in [0, 1) (eq. 6); zero where progress < 0 (stance).

        Two cubic pieces: 0 -> apex on s in [0, 0.5] and apex -> 0 on [0.5, 1], each with zero
        vertical velocity at the apex and the given lift-off / touch-down velocities.
        """
        s = np.asarray(progress, dtype=float)
        T = swing_duration_s / 2  # duration of one piece
        h = self.apex_height_m
        # both pieces in one pass over the array (the MPC samples this every step): x in [0, 1) on each piece, and
        # _cubic_velocity's terms that are not zero on it (up: lift-off slope and apex; down: apex and touch-down)
        down = s >= 0.5
        x = np.where(down, (s - 0.5) / 0.5, s / 0.5)
        x2 = x**2
        up_velocity = (3 * x2 - 4 * x + 1) * (self.liftoff_velocity_m_s * T) + (-6 * x2 + 6 * x) * h
        down_velocity = (6 * x2 - 6 * x) * h + (3 * x2 - 2 * x) * (self.touchdown_velocity_m_s * T)
        # divided where a foot swings only: a standing gait (no swing, T = 0) gives zeros, not 0 / 0
        return np.divide(np.where(down, down_velocity, up_velocity), T, out=np.zeros_like(s), where=s >= 0)

    def height(self, progress: np.ndarray) -> np.ndarray:
        """Reference swing height above the ground at swing progress s (for plots)."""
        s = np.asarray(progress, dtype=float)
        h = self.apex_height_m
        out = np.zeros_like(s)
        up = (s >= 0) & (s < 0.5)
        down = s >= 0.5
        out[up] = _cubic_position(s[up] / 0.5, 0.0, h, 0.0, 0.0)
        out[down] = _cubic_position((s[down] - 0.5) / 0.5, h, 0.0, 0.0, 0.0)
        return out


def swing_between(progress: np.ndarray, swing_duration_s: float, lift_off_m, apex_m, touch_down_m,
                  apex_share=0.5, liftoff_velocity_m_s: float = 0.0,
                  touchdown_velocity_m_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Height and v_z of eq. (6)'s spline between unequal heights (terrain): from `lift_off_m` up to `apex_m` over
    the first `apex_share` of the swing, down to `touch_down_m` over the rest, each a cubic with zero vertical
    velocity at the apex and the lift-off / touch-down velocities at its ends. Every argument broadcasts against
    `progress` (s in [0, 1]; s < 0, stance: height and velocity 0). With equal heights of 0 and apex_share 0.5
    it is `SwingProfile`'s."""
    s = np.asarray(progress, dtype=float)
    h0, apex, h1, share = (np.broadcast_to(np.asarray(a, dtype=float), s.shape) for a in
                           (lift_off_m, apex_m, touch_down_m, apex_share))
    up = (s >= 0) & (s < share)
    down = s >= share
    t_up, t_down = share * swing_duration_s, (1.0 - share) * swing_duration_s
    x_up = np.where(up, s / np.maximum(share, 1e-9), 0.0)
    x_down = np.where(down, (s - share) / np.maximum(1.0 - share, 1e-9), 0.0)
    m_up, m_down = liftoff_velocity_m_s * t_up, touchdown_velocity_m_s * t_down
    height = np.where(up, _cubic_position(x_up, h0, apex, m_up, 0.0),
                      np.where(down, _cubic_position(x_down, apex, h1, 0.0, m_down), 0.0))
    velocity = np.where(up, _cubic_velocity(x_up, h0, apex, m_up, 0.0) / np.maximum(t_up, 1e-9),
                        np.where(down, _cubic_velocity(x_down, apex, h1, 0.0, m_down) / np.maximum(t_down, 1e-9), 0.0))
    return height, velocity


class GaitClock(Gait):
    """A gait whose period can change while it runs, with every foot's phase continuous (`retime`), and
    that can stop and start on command (`follow`: stand <-> walk at a phase where the feet allow it).

    The MPC shortens the period after a push (faster steps, more foot placements within the
    horizon) and restores it later; the state estimator reads the same clock for its stance feet.
    Standing is a set of time intervals in which every foot is in stance (its phase held at mid-stance,
    so foot-placement and estimator code reading `phase` sees a planted foot); a stop starts at the
    first time no foot is past lift-off (`next_all_stance_time`: the swings in progress land first),
    a start ends the interval `start_lead_s` after the request with the pattern resuming at its first
    lift-off. The clock is piecewise in time (one anchor per retime or start), so past times keep the
    phases they had.
    """

    def __init__(self, gait: Gait, start_lead_s: float | None = None):
        super().__init__(gait.name, gait.period_s, gait.duty_factor, gait.phase_offsets)
        object.__setattr__(self, "nominal_period_s", gait.period_s)
        if start_lead_s is None:
            start_lead_s = self.double_support_s
        check_number("start_lead_s", start_lead_s, low=0.0, high=10.0, unit="s")
        object.__setattr__(self, "start_lead_s", float(start_lead_s))
        self.reset()

    def reset(self) -> None:
        """The nominal period, in phase with t = 0, walking (no standing interval)."""
        object.__setattr__(self, "period_s", self.nominal_period_s)
        object.__setattr__(self, "_anchors", [(0.0, 0.0, self.nominal_period_s)])  # (from t, cycles there, period)
        object.__setattr__(self, "_stand", [])  # [start, end) intervals with every foot in stance
        object.__setattr__(self, "walking", True)  # the mode last asked for (`follow`)
        object.__setattr__(self, "transitions", [])  # (t requested, t switched, "stand" | "walk")

    # ------------------------------------------------------------------ time -> cycles
    @property
    def anchors(self) -> list[tuple[float, float, float]]:
        """(from t, cycles there, period) of each piece of the clock (a new list after each change)."""
        return self._anchors

    @property
    def stand_intervals(self) -> list[list[float]]:
        """[start, end) of each standing interval."""
        return self._stand

    def cycles(self, times_s: np.ndarray) -> np.ndarray:
        times = np.asarray(times_s, dtype=float)
        anchors = self._anchors
        if len(anchors) == 1:
            t0, c0, period = anchors[0]
            return c0 + (times - t0) / period
        starts = np.array([a[0] for a in anchors])
        k = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(anchors) - 1)
        t0, c0, period = (np.array([a[i] for a in anchors])[k] for i in range(3))
        return c0 + (times - t0) / period

    def _insert_anchor(self, t_s: float, cycles: float, period_s: float) -> None:
        anchors = [a for a in self._anchors if a[0] != t_s]
        anchors.append((float(t_s), float(cycles), float(period_s)))
        anchors.sort(key=lambda a: a[0])
        object.__setattr__(self, "_anchors", anchors)

    def retime(self, t_s: float, period_s: float) -> None:
        """From time t_s on, cycle with `period_s`; the phases at t_s are kept (a swing in progress
        goes on from where it is, at the new pace). A start already scheduled later keeps its phase there;
        a stop scheduled later is moved to where the retimed swings land."""
        check_number("period_s", period_s, low=0.0, high=10.0, low_open=True, unit="s")
        self._insert_anchor(t_s, float(self.cycles(t_s)), period_s)
        object.__setattr__(self, "_anchors", [a if a[0] <= t_s else (a[0], a[1], float(period_s))
                                              for a in self._anchors])
        object.__setattr__(self, "period_s", float(period_s))
        for interval in self._stand:
            if interval[0] > t_s:  # a stop not started yet, timed on the old pace
                interval[0] = np.inf
                interval[0] = self._landing_time(t_s)

    # ------------------------------------------------------------------ standing intervals
    def standing_at(self, times_s: np.ndarray) -> np.ndarray:
        """Whether each time lies in a standing interval (every foot in stance by command)."""
        times = np.atleast_1d(np.asarray(times_s, dtype=float))
        out = np.zeros(times.shape, dtype=bool)
        for start, end in self._stand:  # a start computed as a landing time may carry rounding: 1 ns of slack
            out |= (times >= start - 1e-9) & (times < end - 1e-9)
        return out

    def phase(self, times_s: np.ndarray) -> np.ndarray:
        phase = super().phase(times_s)
        if self._stand:
            phase[self.standing_at(times_s)] = 0.5 * min(self.duty_factor, 1.0)  # planted: mid-stance
        return phase

    @property
    def double_support_s(self) -> float:
        """The longest stretch of the pattern with every foot in stance (a biped's double support; 0 for a trot)."""
        if self.duty_factor >= 1:
            return 0.0
        offsets = np.asarray(self.phase_offsets)
        bounds = np.unique(np.mod(np.r_[-offsets, self.duty_factor - offsets], 1.0))  # lift-offs and landings
        pieces = np.diff(np.r_[bounds, bounds[0] + 1.0])
        middles = bounds + 0.5 * pieces
        down = np.all(np.mod(middles[:, None] + offsets[None, :], 1.0) < self.duty_factor, axis=1)
        longest = run = 0.0
        for is_down, length in zip(np.r_[down, down], np.r_[pieces, pieces]):  # around the cycle's end
            run = run + length if is_down else 0.0
            longest = max(longest, run)
        return float(min(longest, 1.0) * self.nominal_period_s)

    def _first_lift_cycle(self) -> float:
        """The cycle value (in [0, 1)) of the pattern's first lift-off: every foot in stance just before it."""
        lifts = np.mod(self.duty_factor - np.asarray(self.phase_offsets), 1.0)
        for lift in np.sort(lifts):  # a lift-off with no other foot in swing at that instant
            phases = np.mod(lift - 1e-9 + np.asarray(self.phase_offsets), 1.0)
            if np.all(phases < self.duty_factor):
                return float(lift)
        return float(np.min(lifts))

    def _landing_time(self, t_s: float) -> float:
        """The first time >= t_s at which no foot is past lift-off: every swing in progress has landed."""
        t = float(t_s)
        for _ in range(4 * len(self.phase_offsets) + 4):
            progress = self.swing_phase(np.array([t]))[0]
            swinging = (progress > 1e-6) & (progress < 1.0 - 1e-6)  # lifted and not yet landed
            if not swinging.any():
                return t
            # the swings in progress land (at the current pace) before any new one starts
            t += float(np.max(1.0 - progress[swinging])) * self.swing_duration_s
        return t

    def next_all_stance_time(self, t_s: float) -> float:
        """When a stop asked for at t_s can start: `t_s` if no foot is past lift-off, else the landing of the
        swings in progress."""
        if self.duty_factor >= 1 or self.standing_at(t_s)[0]:
            return float(t_s)
        return self._landing_time(t_s)

    def stand_from(self, t_s: float) -> float:
        """Stop walking: every foot in stance from the first time >= t_s the feet allow; returns that time."""
        open_interval = next((i for i in self._stand if i[1] == np.inf), None)
        pending_start = next((i for i in self._stand if i[1] != np.inf and i[1] > t_s and i[0] <= t_s), None)
        if open_interval is not None:
            return open_interval[0]
        if pending_start is not None:  # a start not reached yet: cancel it, keep standing
            object.__setattr__(self, "_anchors", [a for a in self._anchors if a[0] <= t_s] or self._anchors[:1])
            pending_start[1] = np.inf
            self.transitions.append((float(t_s), float(t_s), "stand"))
            return float(t_s)
        start = self.next_all_stance_time(t_s)
        self._stand.append([start, np.inf])
        self._stand[:] = [i for i in self._stand if i[1] > t_s - 60.0]  # keep the last minute
        self.transitions.append((float(t_s), float(start), "stand"))
        return start

    def walk_from(self, t_s: float) -> float:
        """Start walking: the standing interval ends `start_lead_s` after t_s and the pattern resumes at its
        first lift-off; a stop not started yet is cancelled. Returns the switch time."""
        if self.duty_factor >= 1:
            raise ConfigError(f"the '{self.name}' gait has no swing: build the MPC with a walking gait "
                              f"(trot on four feet, walk on two) to start walking on command")
        open_interval = next((i for i in self._stand if i[1] == np.inf), None)
        if open_interval is None:
            return float(t_s)
        if open_interval[0] > t_s:  # the stop has not started: keep walking
            self._stand.remove(open_interval)
            self.transitions.append((float(t_s), float(t_s), "walk"))
            return float(t_s)
        end = float(t_s) + self.start_lead_s
        open_interval[1] = end
        cycles = float(np.floor(self.cycles(end))) + 1.0 + self._first_lift_cycle()
        self._insert_anchor(end, cycles, self.period_s)
        self.transitions.append((float(t_s), end, "walk"))
        return end

    def follow(self, t_s: float, walking: bool | None) -> None:
        """The mode commanded at t_s (None: no change): switch when it differs from the last one asked for."""
        if walking is None or bool(walking) == self.walking:
            return
        if walking:
            self.walk_from(t_s)
        else:
            self.stand_from(t_s)
        object.__setattr__(self, "walking", bool(walking))


def _hermite(x, p0, p1, m0, m1):
    h00 = 2 * x**3 - 3 * x**2 + 1
    h10 = x**3 - 2 * x**2 + x
    h01 = -2 * x**3 + 3 * x**2
    h11 = x**3 - x**2
    return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1


def _cubic_position(x, p0, p1, m0, m1):
    return _hermite(x, p0, p1, m0, m1)


def _cubic_velocity(x, p0, p1, m0, m1):
    """d/dx of the cubic Hermite segment (per unit of normalised time)."""
    d00 = 6 * x**2 - 6 * x
    d10 = 3 * x**2 - 4 * x + 1
    d01 = -6 * x**2 + 6 * x
    d11 = 3 * x**2 - 2 * x
    return d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1


# biped walking by dynamic similarity (equal Froude number v^2 / (g l) walks alike): the gait period scales
# with sqrt(leg length / g), the leg measured from the hip's first joint to the foot frame (as
# control/tuning.RobotScale does). 4.0 is the human cycle (1.1-1.15 s on 0.75-0.8 m hip-to-ankle legs) and
# gives g1 (0.65 m) 1.03 s and TALOS (0.75 m) 1.10 s. 40 % of the period in double support (two 20 % phases; humans 20-30 %): with g1's
# 0.8 s period and 20 % the 0.08 s double support is too short to move the CoM towards the next stance foot
# and its closed-loop OCPs fail from the second step on
BIPED_FROUDE_PERIOD = 4.0
BIPED_DOUBLE_SUPPORT_SHARE = 0.4


def biped_walk_timing(leg_length_m: float, gravity_m_s2: float = 9.81) -> tuple[float, float]:
    """(period_s, double_support_share) of a biped's walk from its leg length (Froude similarity).

    The one place with the biped gait defaults; the robot-derived settings (control/tuning.py) call it."""
    check_number("leg_length_m", leg_length_m, low=0.05, high=5.0, unit="m")
    return BIPED_FROUDE_PERIOD * float(np.sqrt(leg_length_m / gravity_m_s2)), BIPED_DOUBLE_SUPPORT_SHARE


def biped_walk(period_s: float, double_support_share: float = BIPED_DOUBLE_SUPPORT_SHARE) -> Gait:
    """Two feet in alternation: each swings for (1 - share) / 2 of the period, both stand in between
    (two double-support phases of share / 2 each), left foot first."""
    if not 0 <= double_support_share < 1:
        raise ConfigError(f"double support share must be in [0, 1), got {double_support_share}")
    return Gait("walk", period_s, 0.5 + 0.5 * double_support_share, (0.5, 0.0))


def gaits_for(n_feet: int) -> tuple[str, ...]:
    """Gait names a robot with n_feet can run."""
    return {4: GAIT_NAMES, 2: BIPED_GAIT_NAMES}.get(n_feet, ("stand",))


def natural_gait(n_feet: int) -> str:
    """The gait of `walk-in-place`/`walk-forward` and of tasks that move the feet: trot on four feet,
    walk on two."""
    return "walk" if n_feet == 2 else "trot"


def make_gait(name: str, n_feet: int, period_s: float | None = None, leg_length_m: float | None = None) -> Gait:
    """Named gaits: `stand`, `trot` (diagonal pairs, 0.8 s), `walk` (one foot at a time, 1.2 s; on two feet
    alternating single support with double support, its period from `leg_length_m`, `biped_walk_timing`).

    `period_s=None` takes the gait's default period; any other value is checked (0 is refused)."""
    if period_s is not None:
        check_number("gait_period_s", period_s, low=0.0, high=10.0, low_open=True, unit="s")
    if name == "stand":
        return Gait("stand", 1.0 if period_s is None else period_s, 1.0, tuple([0.0] * n_feet))
    if n_feet == 2 and name == "walk":
        default_s, share = biped_walk_timing(leg_length_m) if leg_length_m is not None else (0.8, BIPED_DOUBLE_SUPPORT_SHARE)
        return biped_walk(default_s if period_s is None else period_s, share)
    if n_feet != 4 and name in ("trot", "walk"):
        raise ConfigError(f"gait '{name}' is defined for 4 feet; this robot has {n_feet} and runs: "
                          f"{', '.join(gaits_for(n_feet))}")
    if name == "trot":  # FL+RR, FR+RL
        return Gait("trot", 0.8 if period_s is None else period_s, 0.5, (0.0, 0.5, 0.5, 0.0))
    if name == "walk":  # lateral-sequence walk: RL, FL, RR, FR
        return Gait("walk", 1.2 if period_s is None else period_s, 0.75, (0.5, 0.0, 0.75, 0.25))
    raise ConfigError(unknown_name("gait", name, GAIT_NAMES))


GAIT_NAMES = ("stand", "trot", "walk")
BIPED_GAIT_NAMES = ("stand", "walk")
