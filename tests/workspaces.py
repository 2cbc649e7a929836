"""Test workspaces (free spaces ``W_f`` as shapely geometries) and random-pose samplers.

The workspaces exercise what the sensing kernel must get right: convex and non-convex holes
(L-, U- and star-shaped), a corridor given as an outer polygon with holes, holes whose rings
carry collinear consecutive vertices, and a free space made of two disjoint rooms.

The samplers draw platoon configurations ``poses`` (``(N + 1, 3)``, leader first) from a seeded
:class:`numpy.random.Generator`, so every test run sees the same states. They place each
follower near its predecessor (so that the camera constraints are sometimes met and sometimes
not) and a share of the robots close to a wall.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import MultiPolygon, Point, Polygon, box
from shapely.geometry.base import BaseGeometry

from platoon_env.geometry.sensing import sensing_params

Coords = Sequence[tuple[float, float]]


@dataclass(frozen=True)
class Workspace:
    """A named free space with camera parameters that suit its size."""

    name: str
    free_space: Polygon | MultiPolygon
    d_con: float  # [m] camera range
    beta_con: float  # [rad] camera half-angle

    def sensors(self, proximity_range: float, proximity_half_angle: float = math.pi) -> np.void:
        """The params record of this camera with a proximity sensor of the given range and
        sector half-angle (``pi``: all around)."""
        return sensing_params(
            d_con=self.d_con,
            beta_con=self.beta_con,
            proximity_range=proximity_range,
            proximity_half_angle=proximity_half_angle,
        )


def _checked(name: str, geometry: Polygon | MultiPolygon) -> Polygon | MultiPolygon:
    """Return ``geometry`` after asserting it is a valid, non-empty areal geometry."""
    if geometry.is_empty or not geometry.is_valid:
        raise AssertionError(
            f"test workspace {name!r} is invalid: {shapely.is_valid_reason(geometry)}"
        )
    return geometry


def star_polygon(
    center: tuple[float, float], angles: Sequence[float], radii: Sequence[float]
) -> Polygon:
    """A star-shaped polygon: vertex ``k`` at ``center + radii[k] * (cos, sin)(angles[k])``.

    With strictly increasing angles spanning less than ``2 pi`` the polygon is simple.
    """
    cx, cy = center
    return Polygon(
        [(cx + r * math.cos(a), cy + r * math.sin(a)) for a, r in zip(angles, radii, strict=True)]
    )


def box_with_convex_hole() -> Workspace:
    """A 12 m x 9 m box with one convex (hexagonal) hole in the middle."""
    hexagon = star_polygon((6.0, 4.5), [k * math.pi / 3 + 0.2 for k in range(6)], [1.8] * 6)
    free = box(0.0, 0.0, 12.0, 9.0).difference(hexagon)
    return Workspace("convex_hole", _checked("convex_hole", free), d_con=3.0, beta_con=0.8)


def box_with_nonconvex_holes() -> Workspace:
    """A 14 m x 10 m box with an L-shaped, a U-shaped and a star-shaped hole."""
    l_shape = Polygon([(1.5, 1.5), (4.5, 1.5), (4.5, 2.5), (2.5, 2.5), (2.5, 5.0), (1.5, 5.0)])
    u_shape = Polygon(
        [
            (7.0, 1.0),
            (11.0, 1.0),
            (11.0, 4.5),
            (10.0, 4.5),
            (10.0, 2.0),
            (8.0, 2.0),
            (8.0, 4.5),
            (7.0, 4.5),
        ]
    )
    star = star_polygon(
        (5.5, 7.5),
        [k * math.pi / 5 for k in range(10)],
        [1.6 if k % 2 == 0 else 0.6 for k in range(10)],
    )
    free = Polygon(
        [(0.0, 0.0), (14.0, 0.0), (14.0, 10.0), (0.0, 10.0)],
        holes=[l_shape.exterior.coords, u_shape.exterior.coords, star.exterior.coords],
    )
    return Workspace("nonconvex_holes", _checked("nonconvex_holes", free), d_con=3.0, beta_con=0.7)


def zigzag_corridor() -> Workspace:
    """A zig-zag corridor (about 2 m wide, sharp corners) with pillars inside it."""
    centre_line = [(0.0, 0.0), (5.0, 4.0), (10.0, 0.0), (15.0, 4.0), (20.0, 0.0)]
    corridor = shapely.LineString(centre_line).buffer(1.1, join_style="mitre", cap_style="flat")
    exterior = shapely.Polygon(corridor.exterior.coords)
    pillars = [
        box(4.6, 3.3, 5.2, 3.9),
        star_polygon((10.0, 0.3), [0.0, 2.0, 4.0], [0.45, 0.45, 0.45]),
        Polygon([(14.2, 3.0), (15.0, 3.2), (15.4, 4.2), (14.8, 3.6)]),
    ]
    free = Polygon(exterior.exterior.coords, holes=[p.exterior.coords for p in pillars])
    return Workspace("zigzag_corridor", _checked("zigzag_corridor", free), d_con=2.5, beta_con=0.6)


def collinear_holes() -> Workspace:
    """A box whose holes repeat collinear vertices along their edges (and one on the outer wall).

    All coordinates are multiples of 0.5, so lattice poses produce exact degeneracies: lines of
    sight through vertices and along edges.
    """
    exterior = [(0.0, 0.0), (5.0, 0.0), (10.0, 0.0), (10.0, 4.0), (10.0, 8.0), (0.0, 8.0)]
    square = [(2.0, 2.0), (3.0, 2.0), (4.0, 2.0), (4.0, 3.0), (4.0, 4.0), (3.0, 4.0), (2.0, 4.0)]
    tee = [
        (6.0, 5.0),
        (7.0, 5.0),
        (8.0, 5.0),
        (8.0, 6.0),
        (7.5, 6.0),
        (7.5, 7.0),
        (6.5, 7.0),
        (6.5, 6.0),
        (6.0, 6.0),
    ]
    diamond = [(7.0, 1.0), (8.0, 2.0), (9.0, 3.0), (8.0, 4.0), (7.0, 3.0), (6.0, 2.0)]
    free = Polygon(exterior, holes=[square, tee, diamond])
    return Workspace("collinear_holes", _checked("collinear_holes", free), d_con=3.0, beta_con=0.9)


def two_rooms() -> Workspace:
    """Two disjoint rooms (a ``MultiPolygon``), one with a hole: crossing rooms is occlusion."""
    west = Polygon(
        [(0.0, 0.0), (4.0, 0.0), (4.0, 5.0), (0.0, 5.0)],
        holes=[[(1.5, 2.0), (2.5, 2.0), (2.0, 3.0)]],
    )
    east = Polygon([(4.5, 0.0), (9.0, 0.0), (9.0, 5.0), (6.0, 5.0), (4.5, 3.0)])
    free = MultiPolygon([west, east])
    return Workspace("two_rooms", _checked("two_rooms", free), d_con=3.0, beta_con=0.8)


def all_workspaces() -> list[Workspace]:
    """Every test workspace."""
    return [
        box_with_convex_hole(),
        box_with_nonconvex_holes(),
        zigzag_corridor(),
        collinear_holes(),
        two_rooms(),
    ]


# --------------------------------------------------------------------------------------------
# Samplers


def sample_free_point(free_space: BaseGeometry, rng: np.random.Generator) -> NDArray[np.float64]:
    """A point drawn uniformly from the interior of the free space (rejection sampling)."""
    xmin, ymin, xmax, ymax = free_space.bounds
    while True:
        candidates = rng.uniform([xmin, ymin], [xmax, ymax], size=(64, 2))
        inside = shapely.contains_xy(free_space, candidates[:, 0], candidates[:, 1])
        if inside.any():
            return candidates[int(np.argmax(inside))]


def sample_near_wall_point(
    free_space: BaseGeometry, rng: np.random.Generator, max_offset: float = 0.4
) -> NDArray[np.float64]:
    """A point of the free space within about ``max_offset`` of the boundary ``dW_f``.

    A boundary point is drawn uniformly by arc length, then pushed off it in a random direction
    by a distance whose logarithm is uniform (from 1e-6 m to ``max_offset``), so that both
    grazing and merely close robots occur; points outside ``W_f`` are rejected.
    """
    boundary = free_space.boundary
    length = boundary.length
    while True:
        anchor = boundary.interpolate(rng.uniform(0.0, length))
        offset = math.exp(rng.uniform(math.log(1e-6), math.log(max_offset)))
        angle = rng.uniform(-math.pi, math.pi)
        x = anchor.x + offset * math.cos(angle)
        y = anchor.y + offset * math.sin(angle)
        if free_space.contains(Point(x, y)):
            return np.array([x, y])


def sample_lattice_point(
    free_space: BaseGeometry, rng: np.random.Generator, spacing: float = 0.5
) -> NDArray[np.float64]:
    """A lattice point (multiples of ``spacing``) of the closed free space, boundary included."""
    xmin, ymin, xmax, ymax = free_space.bounds
    while True:
        i = rng.integers(math.ceil(xmin / spacing), math.floor(xmax / spacing) + 1)
        j = rng.integers(math.ceil(ymin / spacing), math.floor(ymax / spacing) + 1)
        point = np.array([i * spacing, j * spacing], dtype=np.float64)
        if free_space.covers(Point(point)):
            return point


def sample_platoon(
    free_space: BaseGeometry,
    rng: np.random.Generator,
    n_followers: int,
    d_con: float,
    beta_con: float,
    near_wall_probability: float = 0.25,
    max_tries: int = 200,
) -> NDArray[np.float64]:
    """Random poses ``(N + 1, 3)`` of a platoon inside the free space, leader first.

    Each follower is drawn at a distance in ``(0, 1.3 d_con)`` behind its predecessor, in a
    random direction, heading towards it up to an error uniform in ``±1.5 beta_con`` (so that
    range and field-of-view constraints are met about half the time). With probability
    ``near_wall_probability`` a robot is instead placed close to a wall (still facing roughly
    towards its predecessor). Every position lies in the interior of ``W_f``.
    """
    poses = np.empty((n_followers + 1, 3), dtype=np.float64)
    if rng.random() < near_wall_probability:
        poses[0, :2] = sample_near_wall_point(free_space, rng)
    else:
        poses[0, :2] = sample_free_point(free_space, rng)
    poses[0, 2] = rng.uniform(-math.pi, math.pi)
    for i in range(1, n_followers + 1):
        predecessor = poses[i - 1, :2]
        position: NDArray[np.float64] | None = None
        if rng.random() < near_wall_probability:
            position = sample_near_wall_point(free_space, rng)
        else:
            for _ in range(max_tries):
                distance = rng.uniform(0.02, 1.3 * d_con)
                angle = rng.uniform(-math.pi, math.pi)
                candidate = predecessor - distance * np.array([math.cos(angle), math.sin(angle)])
                if free_space.contains(Point(candidate)):
                    position = candidate
                    break
            if position is None:
                position = sample_free_point(free_space, rng)
        towards = math.atan2(predecessor[1] - position[1], predecessor[0] - position[0])
        poses[i, :2] = position
        poses[i, 2] = towards + rng.uniform(-1.5 * beta_con, 1.5 * beta_con)
    return poses


def sample_lattice_platoon(
    free_space: BaseGeometry,
    rng: np.random.Generator,
    n_followers: int,
    spacing: float = 0.5,
    neighbourhood: int = 6,
) -> NDArray[np.float64]:
    """Poses on a lattice of the closed free space: exact collinearities are frequent.

    Each follower sits on a lattice point within ``neighbourhood`` lattice steps of its
    predecessor (boundary points included, so robots touching walls occur), with a random
    heading. Lines of sight then often pass exactly through vertices or along edges of a
    workspace whose vertices lie on the same lattice (e.g. :func:`collinear_holes`).
    """
    poses = np.empty((n_followers + 1, 3), dtype=np.float64)
    poses[0, :2] = sample_lattice_point(free_space, rng, spacing)
    for i in range(1, n_followers + 1):
        for _ in range(500):
            step = rng.integers(-neighbourhood, neighbourhood + 1, size=2) * spacing
            candidate = poses[i - 1, :2] + step
            if free_space.covers(Point(candidate)):
                break
        else:
            candidate = sample_lattice_point(free_space, rng, spacing)
        poses[i, :2] = candidate
    poses[:, 2] = rng.uniform(-math.pi, math.pi, size=n_followers + 1)
    return poses


PlatoonSampler = Callable[[BaseGeometry, np.random.Generator, int], NDArray[np.float64]]


def path_headings(path: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """The unwrapped heading [rad] of a polyline ``path`` (``(K, 2)``) resampled every ``step``
    metres of arc length: entry ``i`` is the direction from sample ``i`` to sample ``i + 1``."""
    d = np.diff(path, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(d[:, 0], d[:, 1]))])
    grid = np.arange(0.0, s[-1], step)
    xy = np.column_stack([np.interp(grid, s, path[:, 0]), np.interp(grid, s, path[:, 1])])
    e = np.diff(xy, axis=0)
    return np.unwrap(np.arctan2(e[:, 1], e[:, 0]))
