"""Procedural layouts with the paper studies' geometry (the ``sharp`` and ``paper`` tiers).

The three studies' difficulty is the corners: a leader path that turns by 90 deg inside a
passage a few robot diameters wide (study A's L- and Z-shaped passages, study C's meander) and
right after a door (study B's flat). The other tiers round every corner on a radius that keeps a
follower on the path within ``0.8 beta_con`` of its predecessor, so they have none of these.
Here the leader's path is a polyline with sharp vertices, which the leader takes as the studies'
leader does: by pure pursuit with a small ``leader.lookahead`` (it turns on a radius of about
``u / leader.max_turn_rate``, 0.17-0.2 m for study C's leader), or, in the ``paper`` tier's
rooms, by a planner's timed trajectory that stops and turns in place at every sharp vertex
(:func:`~platoon_env.scenarios.leader_planner.follow`, study B's local planner, replayed as
``leader.trajectory``).

``corridor`` (:func:`sample_sharp_corridor`)
    A passage along a polyline: a straight start stretch for the platoon, then
    :attr:`~platoon_env.scenarios._layout.SharpDifficulty.corners` sharp corners, legs of
    ``leg * d_des`` between them; each piece of the passage has a width of ``2 r`` plus a gap
    in :attr:`~platoon_env.scenarios._layout.SharpDifficulty.passage_gap`. Every wall corner is
    sharp (mitred), the inner ones included, as in the studies.
``rooms`` (:func:`sample_sharp_rooms`)
    Rooms in a row, a door of ``2 r`` plus a gap in ``door_gap`` in each wall; the leader's path
    crosses each door straight and turns by ``door_turn`` right after it (the turn's vertex
    ``r + 0.3 m + door_turn_after`` from the wall), runs to the height of the next door, turns
    back and approaches it straight. Free-standing non-convex obstacles off the path, as in the
    other rooms layouts (:func:`~platoon_env.scenarios.room_layouts.place_obstacles`).

The geometry is parametrised by the formation: widths are ``2 r`` plus a gap, the legs and the
start stretch scale with ``d_des`` (and the number of followers); :class:`SharpParams` rejects a
template whose leader cannot take the corners (``ScenarioError`` naming the field). Every layout
keeps the guarantees of :mod:`~platoon_env.scenarios.procedural`: the path keeps ``r +
PATH_CLEARANCE`` from every wall, the default start is feasible, the layout fits
:data:`~platoon_env.scenarios._layout.LAYOUT_BOUNDS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely.geometry import LineString, Polygon

from platoon_env.scenarios._layout import (
    _PATH_LENGTH,
    BOUNDS_MARGIN,
    LAYOUT_BOUNDS,
    PATH_CLEARANCE,
    Layout,
    SharpDifficulty,
    fit_in_bounds,
    path_is_clear,
    path_length,
    unit,
)
from platoon_env.scenarios.corridor_layouts import corridor_polygon
from platoon_env.scenarios.leader_planner import Limits, PlannerParams, follow
from platoon_env.scenarios.room_layouts import (
    place_obstacles,
    random_orientation,
    rooms_free_space,
)
from platoon_env.scenarios.schema import ScenarioConfig, ScenarioError

__all__ = ["SharpParams", "sample_sharp_corridor", "sample_sharp_rooms"]

#: [m] a door's turn vertex is at least ``r`` plus this from the wall's face: its leg along the
#: wall (a 90 deg turn) keeps the path's clearance from the wall, and 5 cm more
DOOR_TURN_BASE = PATH_CLEARANCE + 0.05
#: [s] sampling period of a generated timed trajectory (study B's planner runs at 0.1 s; twice
#: that keeps a reset fast, and the replay interpolates between samples)
TRAJECTORY_PERIOD = 0.2
#: [m] a room's height range; its walls hold the doors
_ROOM_HEIGHT = (6.0, 10.0)
#: [m] a door's jambs: every door keeps this much wall on each side of it
_JAMB = 0.8
#: [m] straight approach to a door, before the wall
_APPROACH = (0.8, 1.6)


@dataclass(frozen=True)
class SharpParams:
    """What the sharp layouts need from the template, and the tier's parameters."""

    r: float  # robot radius
    d_des: float  # desired inter-robot distance
    followers: int  # N
    start_len: float  # straight start stretch that holds the platoon
    len_min: float  # leader-path length range
    len_max: float
    level: SharpDifficulty
    #: the timed trajectory's planner (``level.timed_rooms``), else None
    planner: PlannerParams | None

    @classmethod
    def from_template(cls, template: ScenarioConfig, level: SharpDifficulty) -> SharpParams:
        """Derive the parameters from ``template``; ``ScenarioError`` naming the field when its
        leader cannot take the tier's corners or its robots do not fit the tier's doors."""
        r = template.robot.radius
        d_des = template.formation.d_des
        lead = template.leader
        # Pure pursuit cuts a sharp vertex by a fraction of its lookahead and swings out on its
        # turning radius: both must stay within the narrowest passage's clearance beyond r.
        room = 0.5 * level.passage_gap[0]
        if lead.lookahead > room:
            raise ScenarioError(
                f"scenario.leader.lookahead: {lead.lookahead:g} m is too long for the sharp "
                f"corners of generator.tier's passages (at most half their narrowest gap, "
                f"{room:g} m)"
            )
        fastest = lead.speed * (1.0 + lead.speed_variation)
        if fastest / lead.max_turn_rate > room:
            raise ScenarioError(
                f"scenario.leader.max_turn_rate: {lead.max_turn_rate:g} rad/s turns the leader "
                f"at {fastest:g} m/s on a radius of {fastest / lead.max_turn_rate:.3g} m, wider "
                f"than the {room:g} m a sharp corner of generator.tier's passages leaves"
            )
        door = 2.0 * r + level.door_gap[1]
        if door + 2.0 * _JAMB > _ROOM_HEIGHT[0]:
            raise ScenarioError(
                f"scenario.robot.radius: generator.tier cannot place a door for robots of radius "
                f"{r:g} m: a {door:g} m door and its jambs do not fit a {_ROOM_HEIGHT[0]:g} m wall"
            )
        start_len = template.followers * d_des + 1.0
        span = LAYOUT_BOUNDS[2] - LAYOUT_BOUNDS[0] - 2.0 * BOUNDS_MARGIN
        if start_len + 2.0 * (_APPROACH[1] + door) > span:
            raise ScenarioError(
                f"scenario.followers: a platoon needing a {start_len:g} m start stretch leaves "
                f"no room for generator.tier's rooms in {LAYOUT_BOUNDS}"
            )
        planner = None
        if level.timed_rooms:
            if fastest > template.robot.u_max:
                raise ScenarioError(
                    f"scenario.robot.u_max: the leader's {fastest:g} m/s (speed times 1 + "
                    f"speed_variation) exceeds it"
                )
            planner = PlannerParams(
                speed=lead.speed,
                turn_rate=lead.max_turn_rate / (1.0 + lead.speed_variation),
                period=TRAJECTORY_PERIOD,
                lookahead=lead.lookahead,
            )
        len_min = max(_PATH_LENGTH[0], start_len + 6.0)
        len_max = max(_PATH_LENGTH[1], start_len + 25.0)
        return cls(r, d_des, template.followers, start_len, len_min, len_max, level, planner)


def _signs(rng: np.random.Generator, n: int) -> np.ndarray:
    """Turn directions: the first at random, then mostly alternating (a meander)."""
    signs = np.empty(n)
    signs[0] = 1.0 if rng.random() < 0.5 else -1.0
    for k in range(1, n):
        signs[k] = -signs[k - 1] if rng.random() < 0.6 else signs[k - 1]
    return signs


def sample_sharp_corridor(rng: np.random.Generator, p: SharpParams) -> Layout | None:
    """One passage with sharp corners, or None when the draw does not fit."""
    level = p.level
    n = int(rng.integers(*level.corners))
    turns = _signs(rng, n) * rng.uniform(*level.corner_turn, n)
    gaps = np.empty(n + 2)  # pieces: the start, one per corner, the end
    gaps[0] = rng.uniform(*level.passage_gap)
    for k in range(1, n + 2):
        gaps[k] = gaps[k - 1] if rng.random() < 0.5 else rng.uniform(*level.passage_gap)
    half = p.r + 0.5 * gaps
    legs = np.concatenate(
        [[p.start_len + float(rng.uniform(0.3, 1.0))], p.d_des * rng.uniform(*level.leg, n)]
    )
    deficit = p.len_min - float(legs.sum())
    if deficit > 0.0:  # long enough: the legs after the start share what is missing
        legs[1:] += deficit / n
    if legs.sum() > p.len_max:
        return None
    # A leg holds the inner wall corners of the turns at both its ends (each reaches
    # h tan(|turn| / 2) along it) and a straight stretch between them.
    reach = np.concatenate([[0.0], half[1 : n + 1] * np.tan(0.5 * np.abs(turns)), [0.0]])
    if np.any(legs[1:] < reach[1:-1] + reach[2:] + 0.3):
        return None
    headings = float(rng.uniform(-math.pi, math.pi)) + np.concatenate([[0.0], np.cumsum(turns)])
    pts = np.zeros((n + 2, 2))
    for k in range(n + 1):
        pts[k + 1] = pts[k] + legs[k] * unit(float(headings[k]))
    # a split in every leg, where the width may change
    splits = [pts[k] + float(rng.uniform(0.3, 0.7)) * (pts[k + 1] - pts[k]) for k in range(n + 1)]
    start_ext = pts[0] - (p.r + 0.45) * unit(float(headings[0]))
    end_ext = pts[-1] + (p.r + float(rng.uniform(0.5, 1.0))) * unit(float(headings[-1]))
    lines = [[start_ext, splits[0]]]
    lines += [[splits[k - 1], pts[k], splits[k]] for k in range(1, n + 1)]
    lines.append([splits[-1], end_ext])
    built = corridor_polygon(lines, half, headings, [None] * (n + 2))
    if built is None:
        return None
    corridor = built[0].simplify(1e-6, preserve_topology=True)
    fitted = fit_in_bounds(rng, corridor, pts)
    if fitted is None or not path_is_clear(*fitted, p.r):
        return None
    return Layout("corridor", *fitted)


def sample_sharp_rooms(rng: np.random.Generator, p: SharpParams) -> Layout | None:
    """One row of rooms whose doors are followed by a turn, or None when the draw does not fit.

    With ``level.timed_rooms`` the layout carries the leader's timed trajectory: it starts at
    the head of the platoon's straight (``followers * d_des`` along the path) and stops and
    turns in place at every vertex.
    """
    level, r = p.level, p.r
    n_rooms = int(rng.integers(*level.rooms))
    height = float(rng.uniform(*_ROOM_HEIGHT))
    wall = float(rng.uniform(0.15, 0.3))
    door_half = r + 0.5 * rng.uniform(*level.door_gap, n_rooms - 1)
    turn = rng.uniform(*level.door_turn, n_rooms - 1)
    after = r + DOOR_TURN_BASE + rng.uniform(*level.door_turn_after, n_rooms - 1)
    approach = rng.uniform(*_APPROACH, n_rooms - 1)
    lo_y, hi_y = r + _JAMB, height - r - _JAMB  # the path keeps off the outer walls
    rise = max(1.0, 0.8 * p.d_des)  # the least height change between two doors

    def level_after(y: float, lo: float, hi: float) -> float | None:
        """A height in [lo, hi] at least ``rise`` above or below ``y`` (None if none)."""
        spans = [(lo, y - rise), (y + rise, hi)]
        spans = [(a, b) for a, b in spans if b > a]
        if not spans:
            return None
        a, b = spans[int(rng.integers(len(spans)))]
        return float(rng.uniform(a, b))

    # the first door, in line with the start stretch
    x0 = r + float(rng.uniform(0.4, 0.8))
    y = float(rng.uniform(_JAMB + door_half[0], height - _JAMB - door_half[0]))
    walls_x = [x0 + p.start_len + float(rng.uniform(0.5, 2.5)) + approach[0] + 0.5 * wall]
    door_y = [y]
    pts = [np.array([x0, y])]
    for k in range(n_rooms - 1):  # through door k, turn right after it, on to door k + 1
        x_turn = walls_x[k] + 0.5 * wall + after[k]
        last = k == n_rooms - 2
        if last:
            y_next = level_after(y, lo_y, hi_y)
        else:
            h = float(door_half[k + 1])
            y_next = level_after(y, _JAMB + h, height - _JAMB - h)
        if y_next is None:
            return None
        x_back = x_turn + abs(y_next - y) / math.tan(float(turn[k]))
        pts += [np.array([x_turn, y]), np.array([x_back, y_next])]
        y = y_next
        if last:
            pts.append(np.array([x_back + float(rng.uniform(1.0, 2.5)), y]))
        else:
            walls_x.append(x_back + approach[k + 1] + 0.5 * wall + float(rng.uniform(0.0, 1.5)))
            door_y.append(y)
    path = np.array(pts)
    total_width = float(path[-1, 0]) + r + float(rng.uniform(0.6, 1.2))
    span = LAYOUT_BOUNDS[2] - LAYOUT_BOUNDS[0] - 2.0 * BOUNDS_MARGIN
    if total_width > span or not p.len_min <= path_length(path) <= p.len_max:
        return None
    free = rooms_free_space(walls_x, door_y, door_half, wall, total_width, height)
    if not isinstance(free, Polygon) or not path_is_clear(free, path, r):
        return None
    placed = place_obstacles(rng, free, LineString(path), level, r, (total_width, height))
    if placed is None:
        return None
    fitted = fit_in_bounds(rng, placed, path, random_orientation(rng))
    if fitted is None:
        return None
    free, path = fitted
    if p.planner is None:
        return Layout("rooms", free, path)
    return Layout("rooms", free, path, _timed(path, p))


def _timed(path: np.ndarray, p: SharpParams) -> np.ndarray:
    """The leader's timed trajectory along ``path`` from the head of the platoon's straight:
    study B's local planner, stopping and turning in place at every sharp vertex."""
    planner = p.planner
    assert planner is not None
    first = path[1] - path[0]
    heading = math.atan2(first[1], first[0])
    start = path[0] + p.followers * p.d_des * unit(heading)
    last = path[-1] - path[-2]
    limits = Limits(planner.speed, planner.turn_rate, planner.accel_max, planner.alpha_max)
    route = np.vstack([start, path[1:]])
    samples = follow(route, heading, math.atan2(last[1], last[0]), limits, planner)
    samples[:, 3] = np.arctan2(np.sin(samples[:, 3]), np.cos(samples[:, 3]))
    return samples
