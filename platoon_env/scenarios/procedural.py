"""Procedural workspaces: a fresh, seeded workspace and leader path on every reset.

A procedural scenario (one with a ``generator`` block, see
:class:`~platoon_env.scenarios.schema.GeneratorConfig`) keeps the robots, sensors, safety limits,
formation and PPC parameters of its file, and draws the workspace and the leader's path from a
numbered family of layouts. :func:`generate_scenario` builds layout number ``index`` of the
template's ``split``:

* the layout's random stream is ``np.random.default_rng(SPLIT_OFFSETS[split] + index)`` and
  nothing else (no global state), so the same template and index always give the same
  :class:`~platoon_env.scenarios.scenario.Scenario`, bit for bit;
* ``train`` uses the seeds ``0 .. LAYOUTS_PER_SPLIT - 1`` and ``test`` the next
  ``LAYOUTS_PER_SPLIT``: the two splits never share a layout seed, so evaluation on ``test``
  uses workspaces that were never seen in training on ``train``.

Kinds of layout (``generator.kind``):

``corridor``
    A corridor (the free space's outer polygon, sometimes with a small pillar as a hole) along a
    random polyline of 4-8 segments: a straight start stretch with room for the platoon
    (``followers * d_des + 1`` m), then turns of which at least one is sharp (30°-100°), and
    pieces of varying width, at least one narrow enough (clearance beyond ``r`` below the PPC's
    ``delta``) that the followers' clearance terms engage on both sides. Outer corners are
    sharp; the leader's path follows the centreline with circular arcs whose radius is at least
    ``d_des / (2 sin(0.8 beta_con))``, so that a follower on the path at chord ``d_des`` keeps
    its predecessor within ``0.8 beta_con`` of its heading.
``rooms``
    A rectangle divided into 2-4 rooms by interior walls with doorways, with 2-5 free-standing
    non-convex obstacles (L-, U-, T-shapes, irregular stars) placed off the path; the leader's
    path runs straight through each doorway and joins random waypoints with rounded corners.
``mixed``
    Each layout draws ``corridor`` or ``rooms`` (even odds) from its own random stream.

Every layout lies inside :data:`LAYOUT_BOUNDS`, its leader path is 15-40 m long (longer only when
the platoon itself needs it) and keeps a clearance of at least ``r + 0.25`` m from every wall,
and its default initial configuration is feasible: :func:`generate_scenario` resamples (from the
same stream) until :func:`~platoon_env.scenarios.scenario.build_scenario` accepts a layout, and
after a bounded number of attempts returns a straight, wide corridor that is always feasible.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon, box

from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.schema import (
    GENERATOR_KINDS,
    FreeSpaceConfig,
    GeneratorConfig,
    ScenarioConfig,
    ScenarioError,
    WorkspaceConfig,
)

#: Number of distinct layouts in each split (valid indices are ``0 .. LAYOUTS_PER_SPLIT - 1``).
LAYOUTS_PER_SPLIT: int = 1_000_000
#: Layout seed = ``SPLIT_OFFSETS[split] + index``: the splits use disjoint seed ranges.
SPLIT_OFFSETS: dict[str, int] = {"train": 0, "test": LAYOUTS_PER_SPLIT}
#: ``(xmin, ymin, xmax, ymax)``: every generated free space lies inside this box [m].
LAYOUT_BOUNDS: tuple[float, float, float, float] = (0.0, 0.0, 40.0, 40.0)

#: The leader's path keeps at least ``r + PATH_CLEARANCE`` from every wall [m].
PATH_CLEARANCE = 0.25
#: Attempts at sampling a feasible layout before the straight-corridor fallback.
MAX_ATTEMPTS = 40

_BOUNDS_MARGIN = 0.5  # [m] gap between a layout and the edge of LAYOUT_BOUNDS
_PATH_LENGTH = (15.0, 40.0)  # [m] usual range of the leader path's length
_COORD_DECIMALS = 4  # coordinates are rounded to 0.1 mm in the generated config
_ARC_STEP = 0.1  # [rad] angular step of the points sampling a rounded corner
_SHARP_TURN = (math.radians(30.0), math.radians(100.0))
_GENTLE_TURN = (math.radians(8.0), math.radians(30.0))
_WIDE_CLEARANCE = (0.5, 1.2)  # [m] half-width minus r of a wide corridor piece
_NARROW_CLEARANCE = (0.3, 0.45)  # [m] half-width minus r of a narrow piece (capped below delta)
_MIN_CLEARANCE = 0.25  # [m] a corridor is never narrower than 2 (r + this)
_WALL_GAP = 0.5  # [m] minimum wall thickness between non-adjacent parts of a corridor
_OBSTACLE_GAP = 0.4  # [m] free-standing obstacles keep this gap to walls and to each other
_OBSTACLE_PATH_CLEARANCE = 0.35  # [m] obstacles keep >= r + this from the leader's path
_PILLAR_GAP = 0.3  # [m] a corridor's pillar keeps this gap to the corridor's walls


@dataclass(frozen=True)
class _Params:
    """What the generator needs from the template (robot size, platoon length, sensors)."""

    r: float  # robot radius
    d_des: float  # desired inter-robot distance (chord)
    start_len: float  # straight start stretch that holds the platoon
    min_radius: float  # minimum radius of the leader path's rounded corners
    delta: float  # PPC activation distance: "narrow" means clearance - r < delta
    len_min: float  # leader-path length range
    len_max: float

    @classmethod
    def from_template(cls, template: ScenarioConfig) -> _Params:
        """Derive the generator's parameters from ``template``."""
        r = template.robot.radius
        d_des = template.formation.d_des
        beta_con = template.camera.half_angle
        leader = template.leader
        start_len = template.followers * d_des + 1.0
        # A follower on an arc of radius R sees its predecessor (chord d_des ahead) at
        # |beta| = asin(d_des / 2R): keep that below 0.8 beta_con. The leader must also be able
        # to turn that tightly (u / omega_max) and pure pursuit should not cut the corner.
        min_radius = max(
            d_des / (2.0 * math.sin(0.8 * beta_con)),
            1.2 * leader.speed / leader.max_turn_rate,
            leader.lookahead,
        )
        delta = template.ppc.delta if template.ppc is not None else 0.5
        len_min = max(_PATH_LENGTH[0], start_len + 6.0)
        len_max = max(_PATH_LENGTH[1], start_len + 25.0)
        return cls(r, d_des, start_len, min_radius, delta, len_min, len_max)


@dataclass(frozen=True)
class _Layout:
    """A sampled layout before it becomes a config: free space, leader path, kind."""

    kind: str
    free_space: Polygon
    path: np.ndarray  # (M, 2) leader path


@dataclass(frozen=True)
class _Corner:
    """A rounded corner of a polyline: the arc replacing vertex ``vertex``."""

    vertex: np.ndarray  # the polyline's vertex
    t_in: np.ndarray  # tangent point on the incoming segment
    t_out: np.ndarray  # tangent point on the outgoing segment
    arc: np.ndarray  # (K, 2) points from t_in to t_out inclusive
    turn: float  # signed turn angle [rad], > 0 to the left
    tangent: float  # |vertex - t_in| = |t_out - vertex|


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def layout_seed(split: str, index: int) -> int:
    """The seed of layout ``index`` of ``split`` (``SPLIT_OFFSETS[split] + index``).

    Raises ``ValueError`` for an unknown split or an index outside ``[0, LAYOUTS_PER_SPLIT)``.
    """
    if split not in SPLIT_OFFSETS:
        raise ValueError(
            f"generator.split must be one of {', '.join(SPLIT_OFFSETS)}, got {split!r}"
        )
    if isinstance(index, bool) or not isinstance(index, numbers.Integral):
        raise ValueError(f"layout index must be an integer, got {index!r}")
    if not 0 <= int(index) < LAYOUTS_PER_SPLIT:
        raise ValueError(f"layout index must satisfy 0 <= index < {LAYOUTS_PER_SPLIT}, got {index}")
    return SPLIT_OFFSETS[split] + int(index)


def layout_kind(template: ScenarioConfig, index: int) -> str:
    """The kind (``"corridor"`` or ``"rooms"``) drawn for layout ``index`` of ``template``.

    For ``kind: mixed`` this is the layout's first random draw; for the other kinds it is the
    kind itself. (In the rare case that no sampled layout is feasible, the layout is the
    straight-corridor fallback whatever its kind.)
    """
    gen = _generator(template)
    rng = np.random.default_rng(layout_seed(gen.split, index))
    return _draw_kind(rng, gen.kind)


def generate_scenario(template: ScenarioConfig, index: int) -> Scenario:
    """Build procedural layout number ``index`` of ``template.generator.split``.

    Deterministic: the layout depends only on the split, the kind and ``index`` (and on the
    template's robot, formation, camera, PPC and leader parameters, which size it); any workspace
    or leader path already in ``template`` is ignored. The returned scenario keeps every other
    field of ``template`` (name, robots, sensors, safety, PPC, simulation, generator block).

    Raises ``ValueError`` for an index outside ``[0, LAYOUTS_PER_SPLIT)`` or an unknown split or
    kind, and :class:`ScenarioError` only if even the straight-corridor fallback is infeasible
    for the template (e.g. a platoon too long to fit in :data:`LAYOUT_BOUNDS`).
    """
    gen = _generator(template)
    seed = layout_seed(gen.split, index)
    if gen.kind not in GENERATOR_KINDS:
        raise ValueError(
            f"generator.kind must be one of {', '.join(GENERATOR_KINDS)}, got {gen.kind!r}"
        )
    params = _Params.from_template(template)
    rng = np.random.default_rng(seed)
    kind = _draw_kind(rng, gen.kind)
    sampler = _sample_corridor if kind == "corridor" else _sample_rooms
    for _ in range(MAX_ATTEMPTS):
        layout = sampler(rng, params)
        if layout is None:
            continue
        try:
            return build_scenario(_layout_config(template, layout))
        except ScenarioError:
            continue
    return build_scenario(_layout_config(template, _straight_corridor(params)))


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _generator(template: ScenarioConfig) -> GeneratorConfig:
    return template.generator if template.generator is not None else GeneratorConfig()


def _draw_kind(rng: np.random.Generator, kind: str) -> str:
    if kind == "mixed":
        return "corridor" if rng.random() < 0.5 else "rooms"
    return kind


def _unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def _round_corners(points: np.ndarray, radii: np.ndarray) -> list[_Corner]:
    """Replace every interior vertex of the polyline ``points`` by a circular arc.

    ``radii[k]`` is the radius at vertex ``k + 1``. The arcs are tangent to both segments; the
    caller checks that consecutive tangent points do not overlap.
    """
    corners: list[_Corner] = []
    for k in range(1, points.shape[0] - 1):
        p = points[k]
        u_in = p - points[k - 1]
        u_in = u_in / np.hypot(*u_in)
        u_out = points[k + 1] - p
        u_out = u_out / np.hypot(*u_out)
        turn = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
        radius = float(radii[k - 1])
        if abs(turn) < 1e-9:
            corners.append(_Corner(p, p, p, p[None, :], 0.0, 0.0))
            continue
        tangent = radius * math.tan(abs(turn) / 2.0)
        t_in = p - tangent * u_in
        t_out = p + tangent * u_out
        normal = np.array([-u_in[1], u_in[0]]) * math.copysign(1.0, turn)
        centre = t_in + radius * normal
        a0 = math.atan2(t_in[1] - centre[1], t_in[0] - centre[0])
        n = max(2, math.ceil(abs(turn) / _ARC_STEP))
        ang = a0 + np.linspace(0.0, turn, n + 1)
        arc = centre + radius * np.column_stack([np.cos(ang), np.sin(ang)])
        arc[0], arc[-1] = t_in, t_out
        corners.append(_Corner(p, t_in, t_out, arc, turn, tangent))
    return corners


def _rounded_path(points: np.ndarray, corners: list[_Corner]) -> np.ndarray:
    """The polyline with its corners replaced by their arcs (consecutive duplicates removed)."""
    parts = [points[:1], *[c.arc for c in corners], points[-1:]]
    path = np.concatenate(parts, axis=0)
    keep = np.ones(path.shape[0], dtype=bool)
    keep[1:] = np.hypot(*np.diff(path, axis=0).T) > 1e-9
    return path[keep]


def _path_length(path: np.ndarray) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def _fit_in_bounds(
    rng: np.random.Generator, free: Polygon, path: np.ndarray, matrix: np.ndarray | None = None
) -> tuple[Polygon, np.ndarray] | None:
    """Apply the linear map ``matrix`` (if any), then shift to a random place inside
    :data:`LAYOUT_BOUNDS` (keeping a margin); None if the layout is too large."""
    if matrix is not None:
        m = matrix
        free = shapely.transform(free, lambda xy: xy @ m.T)
        path = path @ m.T
    xmin, ymin, xmax, ymax = free.bounds
    bx0, by0, bx1, by1 = LAYOUT_BOUNDS
    lo = np.array([bx0 + _BOUNDS_MARGIN - xmin, by0 + _BOUNDS_MARGIN - ymin])
    hi = np.array([bx1 - _BOUNDS_MARGIN - xmax, by1 - _BOUNDS_MARGIN - ymax])
    if np.any(hi < lo):
        return None
    shift = rng.uniform(lo, hi)
    free = shapely.transform(free, lambda xy: xy + shift)
    return free, path + shift


def _path_is_clear(free: Polygon, path: np.ndarray, r: float) -> bool:
    """Whether the path lies in ``free`` with clearance >= ``r + PATH_CLEARANCE`` (exact)."""
    line = LineString(path)
    return bool(free.covers(line) and line.distance(free.boundary) >= r + PATH_CLEARANCE + 1e-3)


def _layout_config(template: ScenarioConfig, layout: _Layout) -> ScenarioConfig:
    """``template`` with the layout's free space and leader path (coordinates rounded)."""

    def ring(coords: object) -> tuple[tuple[float, float], ...]:
        xy = np.round(np.asarray(coords, dtype=np.float64)[:-1], _COORD_DECIMALS)
        return tuple((float(x), float(y)) for x, y in xy.tolist())

    free = layout.free_space
    workspace = WorkspaceConfig(
        free_space=FreeSpaceConfig(
            exterior=ring(free.exterior.coords),
            holes=tuple(ring(h.coords) for h in free.interiors),
        )
    )
    path = np.round(layout.path, _COORD_DECIMALS)
    keep = np.ones(path.shape[0], dtype=bool)
    keep[1:] = np.any(np.diff(path, axis=0) != 0.0, axis=1)
    leader = dataclasses.replace(
        template.leader, path=tuple((float(x), float(y)) for x, y in path[keep].tolist())
    )
    return dataclasses.replace(template, workspace=workspace, leader=leader)


# --------------------------------------------------------------------------------------------
# Corridors
# --------------------------------------------------------------------------------------------


def _corridor_clearances(rng: np.random.Generator, n: int, p: _Params) -> np.ndarray:
    """Half-width minus ``r`` of ``n`` consecutive corridor pieces; at least one is narrow."""
    narrow_hi = max(_MIN_CLEARANCE, min(_NARROW_CLEARANCE[1], p.delta - 0.05))
    narrow_lo = max(_MIN_CLEARANCE, min(_NARROW_CLEARANCE[0], narrow_hi))

    def draw() -> float:
        if rng.random() < 0.35:
            return float(rng.uniform(narrow_lo, narrow_hi))
        return float(rng.uniform(*_WIDE_CLEARANCE))

    out = np.empty(n)
    out[0] = draw()
    for k in range(1, n):
        out[k] = out[k - 1] if rng.random() < 0.25 else draw()
    if not np.any(out < p.delta):
        out[int(rng.integers(n))] = rng.uniform(narrow_lo, narrow_hi)
    return out


def _sample_corridor(rng: np.random.Generator, p: _Params) -> _Layout | None:
    """One corridor layout, or None when the draw does not fit (self-contact, too large)."""
    n_seg = int(rng.integers(4, 9))
    n_corner = n_seg - 1
    sharp = rng.random(n_corner) < 0.5
    if not sharp.any():
        sharp[int(rng.integers(n_corner))] = True
    magnitude = np.where(
        sharp, rng.uniform(*_SHARP_TURN, n_corner), rng.uniform(*_GENTLE_TURN, n_corner)
    )
    signs = np.empty(n_corner)
    signs[0] = 1.0 if rng.random() < 0.5 else -1.0
    for k in range(1, n_corner):
        signs[k] = -signs[k - 1] if rng.random() < 0.6 else signs[k - 1]
    turns = signs * magnitude
    # Pieces 0..n_seg; piece k (1 <= k < n_seg) holds corner k; 0 and n_seg are the two ends.
    clear = _corridor_clearances(rng, n_seg + 1, p)
    half = p.r + clear
    radii = p.min_radius * rng.uniform(1.0, 1.3, n_corner)
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
        pts[k + 1] = pts[k] + length * _unit(float(headings[k]))
    corners = _round_corners(pts, radii)
    path = _rounded_path(pts, corners)
    # Split point of each segment's straight part, where the width may change.
    splits = []
    for k in range(n_seg):
        a = pts[0] if k == 0 else corners[k - 1].t_out
        b = pts[-1] if k == n_seg - 1 else corners[k].t_in
        splits.append(a + float(rng.uniform(0.3, 0.7)) * (b - a))
    start_ext = pts[0] - (p.r + 0.45) * _unit(float(headings[0]))
    end_ext = pts[-1] + (p.r + float(rng.uniform(0.5, 1.0))) * _unit(float(headings[-1]))
    # Piece k runs from split k - 1 to split k. At each split the narrower piece reaches a
    # little into its neighbour, so that the union has no crack along the common cap.
    overlap = 0.05
    lines: list[list[np.ndarray]] = [[start_ext, splits[0]]]
    for k in range(1, n_seg):
        lines.append([splits[k - 1], *corners[k - 1].arc, splits[k]])
    lines.append([splits[-1], end_ext])
    for k in range(n_seg):
        u = _unit(float(headings[k])) * overlap
        if half[k] <= half[k + 1]:
            lines[k][-1] = lines[k][-1] + u
        else:
            lines[k + 1][0] = lines[k + 1][0] - u
    buf = {"cap_style": "flat", "join_style": "mitre", "mitre_limit": 10.0}
    pieces = []
    for k, pts_k in enumerate(lines):
        piece = LineString(pts_k).buffer(half[k], **buf)
        if 1 <= k < n_seg:  # the sharp outer corner of the turn
            c = corners[k - 1]
            pocket = LineString([splits[k - 1], c.vertex, splits[k]]).buffer(half[k], **buf)
            piece = piece.union(pocket)
        pieces.append(piece)
    for i in range(len(pieces)):
        for j in range(i + 2, len(pieces)):
            if pieces[i].distance(pieces[j]) < _WALL_GAP:
                return None  # the corridor would run into itself
    corridor = shapely.union_all(pieces)
    if not isinstance(corridor, Polygon) or len(corridor.interiors) > 0:
        return None
    corridor = corridor.simplify(1e-6, preserve_topology=True)
    if rng.random() < 0.5:
        corridor = _add_pillar(rng, corridor, path, p, pieces, clear)
    fitted = _fit_in_bounds(rng, corridor, path)
    if fitted is None:
        return None
    free, path = fitted
    if not _path_is_clear(free, path, p.r):
        return None
    return _Layout("corridor", free, path)


def _add_pillar(
    rng: np.random.Generator,
    corridor: Polygon,
    path: np.ndarray,
    p: _Params,
    pieces: list[Polygon],
    clear: np.ndarray,
) -> Polygon:
    """Put a small pillar (a hole) beside the path in a wide piece, if one fits."""
    wide = [k for k in range(1, len(pieces)) if clear[k] >= 1.0]
    if not wide:
        return corridor
    line = LineString(path)
    for _ in range(4):
        piece = pieces[wide[int(rng.integers(len(wide)))]]
        inside = line.intersection(piece)
        if not isinstance(inside, LineString) or inside.length < 0.5:
            continue
        size = float(rng.uniform(0.2, 0.35))
        offset = p.r + _OBSTACLE_PATH_CLEARANCE + 0.6 * size + float(rng.uniform(0.0, 0.2))
        centre = _beside(rng, inside, offset)
        shape = _SMALL_SHAPES[int(rng.integers(len(_SMALL_SHAPES)))](rng, size)
        pillar = _place(shape, centre, float(rng.uniform(0.0, 2.0 * math.pi)))
        if (
            corridor.contains(pillar)
            and pillar.distance(corridor.exterior) >= _PILLAR_GAP
            and pillar.distance(line) >= p.r + _OBSTACLE_PATH_CLEARANCE
        ):
            return Polygon(corridor.exterior.coords, [pillar.exterior.coords])
    return corridor


def _beside(rng: np.random.Generator, line: LineString, offset: float) -> np.ndarray:
    """A random point at distance ``offset`` to the left or right of a random point of
    ``line`` (measured along the line's normal there)."""
    s = float(rng.uniform(0.1, line.length - 0.1))
    a = np.array(line.interpolate(s - 0.1).coords[0])
    b = np.array(line.interpolate(s + 0.1).coords[0])
    t = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
    side = 1.0 if rng.random() < 0.5 else -1.0
    return np.asarray(0.5 * (a + b) + side * offset * np.array([-t[1], t[0]]))


def _straight_corridor(p: _Params) -> _Layout:
    """The fallback: a straight corridor, ``r + 1`` m of clearance on each side, in the middle
    of :data:`LAYOUT_BOUNDS`. Feasible for any template whose platoon fits in the box."""
    bx0, by0, bx1, by1 = LAYOUT_BOUNDS
    span = bx1 - bx0 - 2.0 * _BOUNDS_MARGIN
    ext = p.r + 0.5
    length = min(max(p.len_min, p.start_len + 2.0), span - 2.0 * ext)
    if length < p.start_len:
        raise ScenarioError(
            f"scenario.followers: a platoon needing a {p.start_len:g} m start stretch does not "
            f"fit in the procedural layout bounds {LAYOUT_BOUNDS}"
        )
    y = 0.5 * (by0 + by1)
    x0 = 0.5 * (bx0 + bx1) - 0.5 * length
    half = p.r + 1.0
    free = box(x0 - ext, y - half, x0 + length + ext, y + half)
    path = np.array([[x0, y], [x0 + length, y]])
    return _Layout("corridor", free, path)


# --------------------------------------------------------------------------------------------
# Rooms
# --------------------------------------------------------------------------------------------


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
_SMALL_SHAPES: tuple[_ShapeFn, ...] = (_square, _triangle, _l_shape)


def _place(shape: np.ndarray, centre: np.ndarray, angle: float) -> Polygon:
    """The polygon ``shape`` rotated by ``angle`` about its centroid, moved to ``centre``."""
    xy = shape - shape.mean(axis=0)
    c, s = math.cos(angle), math.sin(angle)
    xy = xy @ np.array([[c, s], [-s, c]]) + centre
    return Polygon(xy)


def _sample_rooms(rng: np.random.Generator, p: _Params) -> _Layout | None:
    """One rooms layout, or None when the draw does not fit (tight corner, blocked door)."""
    r = p.r
    n_rooms = int(rng.integers(2, 5))
    height = float(rng.uniform(6.0, 12.0))
    wall = float(rng.uniform(0.15, 0.3))
    door_half = r + rng.uniform(0.3, 0.85, n_rooms - 1)  # half-widths of the doorways
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
    if total_width > limit - 2.0 * _BOUNDS_MARGIN:
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
    corners = _round_corners(pts, radii)
    if any(abs(c.turn) > math.radians(110.0) for c in corners):
        return None
    tan = np.array([0.0, *[c.tangent for c in corners], 0.0])
    straight = seg - tan[:-1] - tan[1:]
    if straight[0] < p.start_len or np.any(straight < 0.05):
        return None  # the rounded corners would overlap, or no room for the platoon
    path = _rounded_path(pts, corners)
    length = _path_length(path)
    if not p.len_min <= length <= p.len_max:
        return None
    walls = []
    for wx, wy, wh in zip(walls_x, door_y, door_half, strict=True):
        walls.append(box(wx - wall / 2, 0.0, wx + wall / 2, wy - wh))
        walls.append(box(wx - wall / 2, wy + wh, wx + wall / 2, height))
    free = box(0.0, 0.0, total_width, height).difference(shapely.union_all(walls))
    if not isinstance(free, Polygon) or not _path_is_clear(free, path, r):
        return None
    line = LineString(path)
    n_obstacles = int(rng.integers(2, 6))
    placed = 0
    for _ in range(12 * n_obstacles):
        if placed == n_obstacles:
            break
        shape_fn = _OBSTACLE_SHAPES[int(rng.integers(len(_OBSTACLE_SHAPES)))]
        size = float(rng.uniform(0.9, 2.2))
        shape = shape_fn(rng, size)
        if rng.random() < 0.7:  # mostly beside the path, where it matters to the platoon
            offset = r + _OBSTACLE_PATH_CLEARANCE + 0.6 * size + float(rng.uniform(0.0, 1.2))
            centre = _beside(rng, line, offset)
        else:
            centre = rng.uniform([0.5, 0.5], [total_width - 0.5, height - 0.5])
        obstacle = _place(shape, centre, float(rng.uniform(0.0, 2.0 * math.pi)))
        if (
            free.contains(obstacle)
            and obstacle.distance(line) >= r + _OBSTACLE_PATH_CLEARANCE
            and obstacle.distance(free.boundary) >= _OBSTACLE_GAP
        ):
            free = Polygon(
                free.exterior.coords,
                [*(h.coords for h in free.interiors), obstacle.exterior.coords],
            )
            placed += 1
    if placed < 2:
        return None
    # Orientation: a quarter turn times 0..3, possibly mirrored.
    q = int(rng.integers(4))
    c, s = round(math.cos(q * math.pi / 2)), round(math.sin(q * math.pi / 2))
    matrix = np.array([[c, -s], [s, c]], dtype=np.float64)
    if rng.random() < 0.5:
        matrix = matrix @ np.diag([1.0, -1.0])
    fitted = _fit_in_bounds(rng, free, path, matrix)
    if fitted is None:
        return None
    return _Layout("rooms", *fitted)
