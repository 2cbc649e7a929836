"""The ``corridor`` kind of procedural layout.

A corridor (the free space's outer polygon, sometimes with a small pillar as a hole) along a
random polyline of 4-8 segments: a straight start stretch that holds the platoon, then turns of
which at least one is sharp, and pieces of varying width, at least one narrow enough that the
followers' clearance terms engage on both sides (see :mod:`~platoon_env.scenarios.procedural`
for the numbers; the ranges are those of the template's
:class:`~platoon_env.scenarios._layout.Difficulty`). :func:`sample_corridor` is called by
:func:`~platoon_env.scenarios.procedural.generate_scenario`; the pillars are the small shapes
of :mod:`~platoon_env.scenarios.room_layouts`.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from platoon_env.scenarios._layout import (
    OBSTACLE_PATH_CLEARANCE,
    Layout,
    Params,
    beside,
    fit_in_bounds,
    path_is_clear,
    round_corners,
    rounded_path,
    unit,
)
from platoon_env.scenarios.room_layouts import SMALL_SHAPES, place

# The turn, width and pillar ranges are the Difficulty's (p.difficulty).
_MIN_CLEARANCE = 0.25  # [m] a corridor is never narrower than 2 (r + this)
_WALL_GAP = 0.5  # [m] minimum wall thickness between non-adjacent parts of a corridor
_PILLAR_GAP = 0.3  # [m] a corridor's pillar keeps this gap to the corridor's walls
_PILLAR_CLEARANCE = 1.0  # [m] a pillar goes only into a piece at least this wide (beyond r)


def _corridor_clearances(rng: np.random.Generator, n: int, p: Params) -> np.ndarray:
    """Half-width minus ``r`` of ``n`` consecutive corridor pieces; at least one is narrow."""
    level = p.difficulty
    narrow_hi = max(_MIN_CLEARANCE, min(level.narrow_clearance[1], p.delta - 0.05))
    narrow_lo = max(_MIN_CLEARANCE, min(level.narrow_clearance[0], narrow_hi))

    def draw() -> float:
        if rng.random() < level.narrow_fraction:
            return float(rng.uniform(narrow_lo, narrow_hi))
        return float(rng.uniform(*level.wide_clearance))

    out = np.empty(n)
    out[0] = draw()
    for k in range(1, n):
        out[k] = out[k - 1] if rng.random() < 0.25 else draw()
    if not np.any(out < p.delta):
        out[int(rng.integers(n))] = rng.uniform(narrow_lo, narrow_hi)
    return out


def corridor_polygon(
    lines: list[list[np.ndarray]],
    half: np.ndarray,
    headings: np.ndarray,
    pockets: list[list[np.ndarray] | None],
) -> tuple[Polygon, list[Polygon]] | None:
    """The corridor around the polylines ``lines`` (piece ``k`` runs from split ``k - 1`` to
    split ``k`` at half-width ``half[k]``; segment ``k`` of the corridor's centre line has
    heading ``headings[k]``), each piece joined with the buffer of ``pockets[k]`` (if any), and
    the pieces; None when the corridor would run into itself or is not one simple polygon.

    Flat caps and mitred joins: every wall corner is sharp. At each split the narrower piece
    reaches a little into its neighbour, so that the union has no crack along the common cap.
    """
    overlap = 0.05
    for k in range(len(lines) - 1):
        u = unit(float(headings[k])) * overlap
        if half[k] <= half[k + 1]:
            lines[k][-1] = lines[k][-1] + u
        else:
            lines[k + 1][0] = lines[k + 1][0] - u
    buf = {"cap_style": "flat", "join_style": "mitre", "mitre_limit": 10.0}
    pieces = []
    for k, pts_k in enumerate(lines):
        piece = LineString(pts_k).buffer(half[k], **buf)
        if pockets[k] is not None:
            piece = piece.union(LineString(pockets[k]).buffer(half[k], **buf))
        pieces.append(piece)
    for i in range(len(pieces)):
        for j in range(i + 2, len(pieces)):
            if pieces[i].distance(pieces[j]) < _WALL_GAP:
                return None  # the corridor would run into itself
    corridor = shapely.union_all(pieces)
    if not isinstance(corridor, Polygon) or len(corridor.interiors) > 0:
        return None
    return corridor, pieces


def sample_corridor(rng: np.random.Generator, p: Params) -> Layout | None:
    """One corridor layout, or None when the draw does not fit (self-contact, too large)."""
    level = p.difficulty
    n_seg = int(rng.integers(*level.segments))
    n_corner = n_seg - 1
    sharp = rng.random(n_corner) < level.sharp_fraction
    if not sharp.any():
        sharp[int(rng.integers(n_corner))] = True
    magnitude = np.where(
        sharp,
        rng.uniform(*level.sharp_turn, n_corner),
        rng.uniform(*level.gentle_turn, n_corner),
    )
    signs = np.empty(n_corner)
    signs[0] = 1.0 if rng.random() < 0.5 else -1.0
    for k in range(1, n_corner):
        signs[k] = -signs[k - 1] if rng.random() < 0.6 else signs[k - 1]
    turns = signs * magnitude
    # Pieces 0..n_seg; piece k (1 <= k < n_seg) holds corner k; 0 and n_seg are the two ends.
    clear = _corridor_clearances(rng, n_seg + 1, p)
    half = p.r + clear
    radii = p.min_radius * rng.uniform(*level.radius_factor, n_corner)
    radii = np.maximum(radii, half[1:n_seg] + 0.3)  # inner wall keeps a positive radius
    tangents = radii * np.tan(np.abs(turns) / 2.0)
    arc_len = float(np.sum(radii * np.abs(turns)))
    # Straight parts of the segments: the first holds the platoon, the rest share the length.
    first = p.start_len + float(rng.uniform(0.2, 1.5))
    min_straight = 0.8
    target = float(rng.uniform(p.len_min, p.len_max - 5.0))
    rest = target - first - arc_len - min_straight * (n_seg - 1)
    if rest <= 0.0:
        return None
    straights = np.concatenate(
        [[first], min_straight + rest * rng.dirichlet(np.full(n_seg - 1, 3.0))]
    )
    heading = float(rng.uniform(-math.pi, math.pi))
    headings = heading + np.concatenate([[0.0], np.cumsum(turns)])
    pts = np.zeros((n_seg + 1, 2))
    for k in range(n_seg):
        length = straights[k]
        length += tangents[k - 1] if k >= 1 else 0.0
        length += tangents[k] if k < n_corner else 0.0
        pts[k + 1] = pts[k] + length * unit(float(headings[k]))
    corners = round_corners(pts, radii)
    path = rounded_path(pts, corners)
    # Split point of each segment's straight part, where the width may change.
    splits = []
    for k in range(n_seg):
        a = pts[0] if k == 0 else corners[k - 1].t_out
        b = pts[-1] if k == n_seg - 1 else corners[k].t_in
        splits.append(a + float(rng.uniform(0.3, 0.7)) * (b - a))
    start_ext = pts[0] - (p.r + 0.45) * unit(float(headings[0]))
    end_ext = pts[-1] + (p.r + float(rng.uniform(0.5, 1.0))) * unit(float(headings[-1]))
    lines: list[list[np.ndarray]] = [[start_ext, splits[0]]]
    for k in range(1, n_seg):
        lines.append([splits[k - 1], *corners[k - 1].arc, splits[k]])
    lines.append([splits[-1], end_ext])
    # the sharp outer corner of each turn
    turns_at = [[splits[k - 1], c.vertex, splits[k]] for k, c in enumerate(corners, 1)]
    pockets: list[list[np.ndarray] | None] = [None, *turns_at, None]
    built = corridor_polygon(lines, half, headings, pockets)
    if built is None:
        return None
    corridor, pieces = built
    corridor = corridor.simplify(1e-6, preserve_topology=True)
    for _ in range(level.pillars):
        if rng.random() < level.pillar_fraction:
            corridor = _add_pillar(rng, corridor, path, p, pieces, clear)
    fitted = fit_in_bounds(rng, corridor, path)
    if fitted is None:
        return None
    free, path = fitted
    if not path_is_clear(free, path, p.r):
        return None
    return Layout("corridor", free, path)


def _add_pillar(
    rng: np.random.Generator,
    corridor: Polygon,
    path: np.ndarray,
    p: Params,
    pieces: list[Polygon],
    clear: np.ndarray,
) -> Polygon:
    """Put a small pillar (a hole) beside the path in a wide piece, if one fits (apart from
    the corridor's walls and its other pillars)."""
    wide = [k for k in range(1, len(pieces)) if clear[k] >= _PILLAR_CLEARANCE]
    if not wide:
        return corridor
    line = LineString(path)
    for _ in range(4):
        piece = pieces[wide[int(rng.integers(len(wide)))]]
        inside = line.intersection(piece)
        if not isinstance(inside, LineString) or inside.length < 0.5:
            continue
        size = float(rng.uniform(0.2, 0.35))
        offset = p.r + OBSTACLE_PATH_CLEARANCE + 0.6 * size + float(rng.uniform(0.0, 0.2))
        centre = beside(rng, inside, offset)
        shape = SMALL_SHAPES[int(rng.integers(len(SMALL_SHAPES)))](rng, size)
        pillar = place(shape, centre, float(rng.uniform(0.0, 2.0 * math.pi)))
        if (
            corridor.contains(pillar)
            and pillar.distance(corridor.exterior) >= _PILLAR_GAP
            and all(pillar.distance(h) >= _PILLAR_GAP for h in corridor.interiors)
            and pillar.distance(line) >= p.r + OBSTACLE_PATH_CLEARANCE
        ):
            holes = [*(h.coords for h in corridor.interiors), pillar.exterior.coords]
            return Polygon(corridor.exterior.coords, holes)
    return corridor
