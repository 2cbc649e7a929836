"""The ``rooms`` kind of procedural layout, and the obstacle shapes of both kinds.

A rectangle divided into 2-4 rooms by interior walls with doorways, with 2-5 free-standing
non-convex obstacles (:data:`_OBSTACLE_SHAPES`: L-, U-, T-shapes, irregular stars) placed off
the path (these counts, the doorways' widths and the obstacles' sizes and places are the
ranges of the template's :class:`~platoon_env.scenarios._layout.Difficulty`, shown here for
the untiered family); the leader's path runs straight through each doorway and joins random
waypoints with rounded corners. :func:`sample_rooms` is called by
:func:`~platoon_env.scenarios.procedural.generate_scenario`; the corridor kind
(:mod:`~platoon_env.scenarios.corridor_layouts`) borrows :data:`SMALL_SHAPES` and :func:`place`
for its pillars.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon, box
from shapely.geometry.base import BaseGeometry

from platoon_env.scenarios._layout import (
    BOUNDS_MARGIN,
    LAYOUT_BOUNDS,
    OBSTACLE_PATH_CLEARANCE,
    Layout,
    Params,
    beside,
    fit_in_bounds,
    path_is_clear,
    path_length,
    round_corners,
    rounded_path,
)

_OBSTACLE_GAP = 0.4  # [m] free-standing obstacles keep this gap to walls and to each other


def rooms_free_space(
    walls_x: Sequence[float] | np.ndarray,
    door_y: Sequence[float] | np.ndarray,
    door_half: Sequence[float] | np.ndarray,
    wall: float,
    width: float,
    height: float,
) -> BaseGeometry:
    """A ``width`` × ``height`` row of rooms: a wall of thickness ``wall`` at each ``walls_x``
    with a door centred at ``door_y`` of half-width ``door_half`` [m]."""
    walls = []
    for wx, wy, wh in zip(walls_x, door_y, door_half, strict=True):
        walls.append(box(wx - wall / 2, 0.0, wx + wall / 2, wy - wh))
        walls.append(box(wx - wall / 2, wy + wh, wx + wall / 2, height))
    return box(0.0, 0.0, width, height).difference(shapely.union_all(walls))


def _l_shape(rng: np.random.Generator, size: float) -> np.ndarray:
    a = size * float(rng.uniform(0.25, 0.45))
    h = size * float(rng.uniform(0.7, 1.0))
    return np.array([[0, 0], [size, 0], [size, a], [a, a], [a, h], [0, h]], dtype=np.float64)


def _u_shape(rng: np.random.Generator, size: float) -> np.ndarray:
    a = size * float(rng.uniform(0.2, 0.32))
    h = size * float(rng.uniform(0.6, 1.0))
    return np.array(
        [[0, 0], [size, 0], [size, h], [size - a, h], [size - a, a], [a, a], [a, h], [0, h]],
        dtype=np.float64,
    )


def _t_shape(rng: np.random.Generator, size: float) -> np.ndarray:
    a = size * float(rng.uniform(0.22, 0.4))
    h = size * float(rng.uniform(0.7, 1.0))
    c = size / 2.0
    return np.array(
        [
            [c - a / 2, 0],
            [c + a / 2, 0],
            [c + a / 2, h - a],
            [size, h - a],
            [size, h],
            [0, h],
            [0, h - a],
            [c - a / 2, h - a],
        ],
        dtype=np.float64,
    )


def _star(rng: np.random.Generator, size: float) -> np.ndarray:
    n = int(rng.integers(5, 8))
    ang = (np.arange(2 * n) + rng.uniform(-0.25, 0.25, 2 * n)) * (math.pi / n)
    outer = 0.5 * size * rng.uniform(0.75, 1.0, n)
    inner = outer * rng.uniform(0.35, 0.6, n)
    rad = np.column_stack([outer, inner]).ravel()
    return np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])


def _square(rng: np.random.Generator, size: float) -> np.ndarray:
    w = size * float(rng.uniform(0.6, 1.0))
    return np.array([[0, 0], [size, 0], [size, w], [0, w]], dtype=np.float64)


def _triangle(rng: np.random.Generator, size: float) -> np.ndarray:
    return np.array([[0, 0], [size, 0], [size * float(rng.uniform(0.2, 0.8)), size]])


_ShapeFn = Callable[[np.random.Generator, float], np.ndarray]
#: Non-convex obstacles of the rooms layouts.
_OBSTACLE_SHAPES: tuple[_ShapeFn, ...] = (_l_shape, _u_shape, _t_shape, _star)
#: Small pillars of the corridor layouts.
SMALL_SHAPES: tuple[_ShapeFn, ...] = (_square, _triangle, _l_shape)


def place(shape: np.ndarray, centre: np.ndarray, angle: float) -> Polygon:
    """The polygon ``shape`` rotated by ``angle`` about its centroid, moved to ``centre``."""
    xy = shape - shape.mean(axis=0)
    c, s = math.cos(angle), math.sin(angle)
    xy = xy @ np.array([[c, s], [-s, c]]) + centre
    return Polygon(xy)


class ObstacleRanges(Protocol):
    """Where a family of layouts draws its free-standing obstacles (a
    :class:`~platoon_env.scenarios._layout.Difficulty` or a
    :class:`~platoon_env.scenarios._layout.SharpDifficulty`)."""

    @property
    def obstacles(self) -> tuple[int, int]: ...  # how many (at least the first placed)
    @property
    def obstacle_size(self) -> tuple[float, float]: ...  # size of the bounding square [m]
    @property
    def obstacle_beside(self) -> float: ...  # probability of a place beside the path
    @property
    def obstacle_offset(self) -> tuple[float, float]: ...  # extra gap beside the path [m]


def place_obstacles(
    rng: np.random.Generator,
    free: Polygon,
    line: LineString,
    level: ObstacleRanges,
    r: float,
    size: tuple[float, float],
) -> Polygon | None:
    """``free`` (a rooms layout of ``size = (width, height)`` from the origin) with
    free-standing non-convex obstacles (:data:`_OBSTACLE_SHAPES`) as holes, off the leader's
    path ``line`` by ``r + OBSTACLE_PATH_CLEARANCE`` and :data:`_OBSTACLE_GAP` apart from the
    walls and each other; None when fewer than ``level.obstacles[0]`` fit."""
    total_width, height = size
    n_obstacles = int(rng.integers(*level.obstacles))
    placed = 0
    for _ in range(12 * n_obstacles):
        if placed == n_obstacles:
            break
        shape_fn = _OBSTACLE_SHAPES[int(rng.integers(len(_OBSTACLE_SHAPES)))]
        size_k = float(rng.uniform(*level.obstacle_size))
        shape = shape_fn(rng, size_k)
        if rng.random() < level.obstacle_beside:  # mostly beside the path, where it matters
            extra = float(rng.uniform(*level.obstacle_offset))
            offset = r + OBSTACLE_PATH_CLEARANCE + 0.6 * size_k + extra
            centre = beside(rng, line, offset)
        else:
            centre = rng.uniform([0.5, 0.5], [total_width - 0.5, height - 0.5])
        obstacle = place(shape, centre, float(rng.uniform(0.0, 2.0 * math.pi)))
        if (
            free.contains(obstacle)
            and obstacle.distance(line) >= r + OBSTACLE_PATH_CLEARANCE
            and obstacle.distance(free.boundary) >= _OBSTACLE_GAP
        ):
            free = Polygon(
                free.exterior.coords,
                [*(h.coords for h in free.interiors), obstacle.exterior.coords],
            )
            placed += 1
    if placed < level.obstacles[0]:
        return None
    return free


def random_orientation(rng: np.random.Generator) -> np.ndarray:
    """A quarter turn times 0..3, mirrored with even odds: the linear map of a rooms layout."""
    q = int(rng.integers(4))
    c, s = round(math.cos(q * math.pi / 2)), round(math.sin(q * math.pi / 2))
    matrix = np.array([[c, -s], [s, c]], dtype=np.float64)
    if rng.random() < 0.5:
        matrix = matrix @ np.diag([1.0, -1.0])
    return matrix


def sample_rooms(rng: np.random.Generator, p: Params) -> Layout | None:
    """One rooms layout, or None when the draw does not fit (tight corner, blocked door)."""
    r = p.r
    level = p.difficulty
    n_rooms = int(rng.integers(*level.rooms))
    height = float(rng.uniform(6.0, 12.0))
    wall = float(rng.uniform(0.15, 0.3))
    door_half = r + rng.uniform(*level.door_clearance, n_rooms - 1)  # doorways' half-widths
    reach = rng.uniform(0.9, 1.6, n_rooms - 1)  # straight run on each side of a doorway
    start_x = r + float(rng.uniform(0.4, 0.8))
    first = start_x + p.start_len + reach[0] + float(rng.uniform(1.5, 4.0))
    others = rng.uniform(4.5, 8.5, n_rooms - 1)
    deficit = p.len_min + 4.5 - first - float(others.sum())
    if deficit > 0.0:  # long enough for the minimum path length
        others += deficit / (n_rooms - 1)
    widths = np.concatenate([[first], others])
    total_width = float(widths.sum())
    limit = min(LAYOUT_BOUNDS[2] - LAYOUT_BOUNDS[0], LAYOUT_BOUNDS[3] - LAYOUT_BOUNDS[1])
    if total_width > limit - 2.0 * BOUNDS_MARGIN:
        return None
    walls_x = np.cumsum(widths)[:-1]
    lo_y, hi_y = r + 0.8, height - r - 0.8

    def toward(y0: float, dx: float, slope: float, lo: float, hi: float) -> float | None:
        """A height in [lo, hi] reachable from y0 over dx with a slope of at most ``slope``."""
        a, b = max(lo, y0 - slope * dx), min(hi, y0 + slope * dx)
        return float(rng.uniform(a, b)) if a <= b else None

    x, y = start_x, float(rng.uniform(lo_y, hi_y))
    waypoints = [np.array([x, y])]
    door_y: list[float] = []  # centres of the doorways
    for k in range(n_rooms):
        room_hi = walls_x[k] - reach[k] if k < n_rooms - 1 else total_width - r - 0.8
        slope = 0.5 if k == 0 else 1.0  # the first segment is mostly the platoon's straight
        room_end = room_hi - (1.5 if k < n_rooms - 1 else 2.5)
        if k >= 1 and rng.random() < 0.5 and room_end - x > 1.5:  # a waypoint inside the room
            x_new = float(rng.uniform(x + 1.5, room_end))
            y_new = toward(y, x_new - x, slope, lo_y, hi_y)
            if y_new is None:
                return None
            x, y = x_new, y_new
            waypoints.append(np.array([x, y]))
        if k < n_rooms - 1:  # straight through the doorway
            h = float(door_half[k])
            y_new = toward(y, room_hi - x, slope, 0.8 + h, height - 0.8 - h)
            if y_new is None:
                return None
            y = y_new
            door_y.append(y)
            waypoints.append(np.array([room_hi, y]))
            x = float(walls_x[k] + reach[k])
            waypoints.append(np.array([x, y]))
        else:  # the end point
            if x + 2.0 > room_hi:
                return None
            x_new = float(rng.uniform(max(x + 2.0, room_hi - 3.0), room_hi))
            y_new = toward(y, x_new - x, slope, lo_y, hi_y)
            if y_new is None:
                return None
            waypoints.append(np.array([x_new, y_new]))
    pts = np.array(waypoints)
    seg = np.hypot(*np.diff(pts, axis=0).T)
    if np.any(seg < 0.3):
        return None
    radii = p.min_radius * rng.uniform(1.0, 1.3, pts.shape[0] - 2)
    corners = round_corners(pts, radii)
    if any(abs(c.turn) > math.radians(110.0) for c in corners):
        return None
    tan = np.array([0.0, *[c.tangent for c in corners], 0.0])
    straight = seg - tan[:-1] - tan[1:]
    if straight[0] < p.start_len or np.any(straight < 0.05):
        return None  # the rounded corners would overlap, or no room for the platoon
    path = rounded_path(pts, corners)
    length = path_length(path)
    if not p.len_min <= length <= p.len_max:
        return None
    free = rooms_free_space(walls_x, door_y, door_half, wall, total_width, height)
    if not isinstance(free, Polygon) or not path_is_clear(free, path, r):
        return None
    free = place_obstacles(rng, free, LineString(path), level, r, (total_width, height))
    if free is None:
        return None
    matrix = random_orientation(rng)
    fitted = fit_in_bounds(rng, free, path, matrix)
    if fitted is None:
        return None
    return Layout("rooms", *fitted)
