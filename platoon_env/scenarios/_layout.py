"""Pieces shared by the procedural layout kinds (internal to :mod:`~platoon_env.scenarios`).

:mod:`~platoon_env.scenarios.procedural` orchestrates; the kinds
(:mod:`~platoon_env.scenarios.corridor_layouts`, :mod:`~platoon_env.scenarios.room_layouts`)
sample. Both sides use what is here: the generator's parameters derived from the template
(:class:`Params`), the difficulty parameters of the layouts (:class:`Difficulty`: the
untiered :data:`DEFAULT_DIFFICULTY` and the tiers' :data:`TIERS`), the sampled result
(:class:`Layout`), the layout box and clearances,
rounding a polyline's corners into the leader path, and the last steps of every sampler
(:func:`fit_in_bounds`, :func:`path_is_clear`). Nothing here draws from a random stream except
where an ``rng`` is passed in, and each function draws in a fixed order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from platoon_env.scenarios.schema import ScenarioConfig

#: ``(xmin, ymin, xmax, ymax)``: every generated free space lies inside this box [m].
LAYOUT_BOUNDS: tuple[float, float, float, float] = (0.0, 0.0, 40.0, 40.0)
#: The leader's path keeps at least ``r + PATH_CLEARANCE`` from every wall [m].
PATH_CLEARANCE = 0.25
#: Gap between a layout and the edge of :data:`LAYOUT_BOUNDS` [m].
BOUNDS_MARGIN = 0.5
#: Free-standing obstacles and pillars keep at least ``r + this`` from the leader's path [m].
OBSTACLE_PATH_CLEARANCE = 0.35

_PATH_LENGTH = (15.0, 40.0)  # [m] usual range of the leader path's length
_ARC_STEP = 0.1  # [rad] angular step of the points sampling a rounded corner


@dataclass(frozen=True)
class Difficulty:
    """The parameters of a family of layouts that set how hard it is to follow the leader.

    Ranges ``(lo, hi)`` are drawn uniformly; integer ranges are ``rng.integers(lo, hi)``, so
    ``hi`` is excluded. Angles are in radians, lengths in metres; a *clearance* is a half-width
    minus the robot radius ``r`` (how far a robot centred on the path is from the wall).
    :data:`DEFAULT_DIFFICULTY` is the family of the untiered scenarios (no ``generator.tier``),
    :data:`TIERS` the ``easy``, ``medium`` and ``hard`` tiers.
    """

    # corridor layouts
    segments: tuple[int, int]  # number of straight segments (corners = segments - 1)
    sharp_fraction: float  # probability that a corner is sharp (at least one always is)
    sharp_turn: tuple[float, float]  # turn magnitude of a sharp corner
    gentle_turn: tuple[float, float]  # turn magnitude of the other corners
    radius_factor: tuple[float, float]  # corner radius = min_radius times this
    bearing_fraction: float  # min_radius keeps a follower on the path within this * beta_con
    wide_clearance: tuple[float, float]  # clearance of a wide corridor piece
    narrow_clearance: tuple[float, float]  # clearance of a narrow piece (capped below delta)
    narrow_fraction: float  # probability that a piece is narrow (at least one always is)
    pillars: int  # attempts at a pillar in a wide piece (needs a clearance of 1 m)
    pillar_fraction: float  # probability of each attempt
    # rooms layouts
    rooms: tuple[int, int]  # number of rooms
    door_clearance: tuple[float, float]  # clearance in a doorway (its half-width minus r)
    obstacles: tuple[int, int]  # free-standing obstacles (at least ``obstacles[0]`` placed)
    obstacle_size: tuple[float, float]  # size of an obstacle's bounding square
    obstacle_beside: float  # probability that an obstacle is placed beside the path
    obstacle_offset: tuple[float, float]  # extra gap of an obstacle beside the path


#: The untiered family (no ``generator.tier``): the layouts of ``procedural_train`` and
#: ``procedural_test``, unchanged since they were first shipped.
DEFAULT_DIFFICULTY = Difficulty(
    segments=(4, 9),
    sharp_fraction=0.5,
    sharp_turn=(math.radians(30.0), math.radians(100.0)),
    gentle_turn=(math.radians(8.0), math.radians(30.0)),
    radius_factor=(1.0, 1.3),
    bearing_fraction=0.8,
    wide_clearance=(0.5, 1.2),
    narrow_clearance=(0.3, 0.45),
    narrow_fraction=0.35,
    pillars=1,
    pillar_fraction=0.5,
    rooms=(2, 5),
    door_clearance=(0.3, 0.85),
    obstacles=(2, 6),
    obstacle_size=(0.9, 2.2),
    obstacle_beside=0.7,
    obstacle_offset=(0.0, 1.2),
)

#: The difficulty tiers (``generator.tier``, named by
#: :data:`~platoon_env.scenarios.schema.GENERATOR_TIERS`), each harder than the one before in
#: every parameter that sets difficulty (``docs/scenarios.md#difficulty-tiers``).
TIERS: dict[str, Difficulty] = {
    "easy": Difficulty(
        segments=(4, 7),
        sharp_fraction=0.3,
        sharp_turn=(math.radians(30.0), math.radians(60.0)),
        gentle_turn=(math.radians(5.0), math.radians(25.0)),
        radius_factor=(1.2, 1.6),
        bearing_fraction=0.6,
        wide_clearance=(0.7, 1.4),
        narrow_clearance=(0.4, 0.45),
        narrow_fraction=0.2,
        pillars=1,
        pillar_fraction=0.2,
        rooms=(2, 4),
        door_clearance=(0.6, 1.0),
        obstacles=(2, 4),
        obstacle_size=(0.9, 1.8),
        obstacle_beside=0.5,
        obstacle_offset=(0.6, 1.5),
    ),
    "medium": Difficulty(
        segments=(4, 9),
        sharp_fraction=0.5,
        sharp_turn=(math.radians(45.0), math.radians(100.0)),
        gentle_turn=(math.radians(8.0), math.radians(30.0)),
        radius_factor=(1.0, 1.3),
        bearing_fraction=0.8,
        wide_clearance=(0.5, 1.2),
        narrow_clearance=(0.3, 0.4),
        narrow_fraction=0.4,
        pillars=1,
        pillar_fraction=0.5,
        rooms=(2, 5),
        door_clearance=(0.35, 0.7),
        obstacles=(3, 6),
        obstacle_size=(0.9, 2.2),
        obstacle_beside=0.7,
        obstacle_offset=(0.0, 1.0),
    ),
    "hard": Difficulty(
        segments=(5, 10),
        sharp_fraction=0.7,
        sharp_turn=(math.radians(70.0), math.radians(120.0)),
        gentle_turn=(math.radians(10.0), math.radians(35.0)),
        radius_factor=(1.0, 1.1),
        bearing_fraction=0.9,
        wide_clearance=(0.45, 1.3),
        narrow_clearance=(0.26, 0.33),
        narrow_fraction=0.55,
        pillars=2,
        pillar_fraction=0.9,
        rooms=(3, 6),
        door_clearance=(0.27, 0.45),
        obstacles=(4, 8),
        obstacle_size=(1.0, 2.4),
        obstacle_beside=0.85,
        obstacle_offset=(0.0, 0.5),
    ),
}


@dataclass(frozen=True)
class SharpDifficulty:
    """The parameters of a family of layouts with the paper studies' geometry: sharp corners
    inside narrow passages, doors followed by a turn (:mod:`~platoon_env.scenarios.sharp_layouts`).

    The leader's path is a polyline with sharp vertices, which the leader takes as a robot
    would (pure pursuit with a small ``leader.lookahead`` turns on a radius of about
    ``u / leader.max_turn_rate``; with ``timed_rooms``, a rooms layout's leader stops and turns
    in place, a planner's ``leader.trajectory``). Ranges are drawn as in :class:`Difficulty`.
    Widths are *gaps*: the width minus the robot's diameter ``2 r``, so that a gap means the same
    room to manoeuvre for any robot; lengths along the path scale with ``d_des``.
    """

    # corridor layouts: a passage along a polyline with sharp corners
    corners: tuple[int, int]  # number of sharp corners
    corner_turn: tuple[float, float]  # [rad] turn magnitude of each corner
    leg: tuple[float, float]  # length of a leg between two corners, in units of d_des
    passage_gap: tuple[float, float]  # [m] passage width minus 2 r
    # rooms layouts: rooms in a row, a door in each wall, the path turning right after it
    rooms: tuple[int, int]  # number of rooms
    door_gap: tuple[float, float]  # [m] door width minus 2 r
    door_turn: tuple[float, float]  # [rad] the turn right after a door (at most 90 deg)
    door_turn_after: tuple[float, float]  # [m] from the wall to that turn, beyond r + 0.3 m
    obstacles: tuple[int, int]  # free-standing obstacles (at least ``obstacles[0]`` placed)
    obstacle_size: tuple[float, float]  # size of an obstacle's bounding square
    obstacle_beside: float  # probability that an obstacle is placed beside the path
    obstacle_offset: tuple[float, float]  # extra gap of an obstacle beside the path
    timed_rooms: bool  # rooms: the leader drives a stop-and-turn timed trajectory


#: The tiers with the paper studies' geometry (``generator.tier``), after the three of
#: :data:`TIERS` (``docs/scenarios.md#tiers-with-the-studies-geometry``). For study C's robots
#: (``r = 0.15``) ``sharp`` has passages of 1.2-1.4 m and doors of 0.9-1.0 m, ``paper``
#: passages of 1.0-1.2 m, doors of 0.8-0.9 m and, in rooms, a leader that stops and turns in
#: place.
SHARP_TIERS: dict[str, SharpDifficulty] = {
    "sharp": SharpDifficulty(
        corners=(3, 6),
        corner_turn=(math.radians(75.0), math.radians(95.0)),
        leg=(2.0, 3.5),
        passage_gap=(0.9, 1.1),
        rooms=(2, 4),
        door_gap=(0.6, 0.7),
        door_turn=(math.radians(75.0), math.radians(90.0)),
        door_turn_after=(0.15, 0.5),
        obstacles=(2, 4),
        obstacle_size=(0.9, 1.8),
        obstacle_beside=0.6,
        obstacle_offset=(0.3, 1.0),
        timed_rooms=False,
    ),
    "paper": SharpDifficulty(
        corners=(4, 8),
        corner_turn=(math.radians(75.0), math.radians(110.0)),
        leg=(1.6, 3.0),
        passage_gap=(0.7, 0.9),
        rooms=(3, 5),
        door_gap=(0.5, 0.6),
        door_turn=(math.radians(75.0), math.radians(90.0)),
        door_turn_after=(0.05, 0.35),
        obstacles=(3, 6),
        obstacle_size=(1.0, 2.2),
        obstacle_beside=0.8,
        obstacle_offset=(0.0, 0.6),
        timed_rooms=True,
    ),
}


def difficulty(tier: str | None) -> Difficulty | SharpDifficulty:
    """The parameters of ``tier`` (:data:`DEFAULT_DIFFICULTY` for None); ``ValueError`` for an
    unknown tier."""
    if tier is None:
        return DEFAULT_DIFFICULTY
    if tier in SHARP_TIERS:
        return SHARP_TIERS[tier]
    if tier not in TIERS:
        names = ", ".join([*TIERS, *SHARP_TIERS])
        raise ValueError(f"generator.tier must be one of {names} (or absent), got {tier!r}")
    return TIERS[tier]


@dataclass(frozen=True)
class Params:
    """What the generator needs from the template (robot size, platoon length, sensors) and
    the difficulty of its family (``generator.tier``)."""

    r: float  # robot radius
    d_des: float  # desired inter-robot distance (chord)
    start_len: float  # straight start stretch that holds the platoon
    min_radius: float  # minimum radius of the leader path's rounded corners
    delta: float  # PPC activation distance: "narrow" means clearance - r < delta
    len_min: float  # leader-path length range
    len_max: float
    difficulty: Difficulty = DEFAULT_DIFFICULTY

    @classmethod
    def from_template(cls, template: ScenarioConfig) -> Params:
        """Derive the generator's parameters from ``template`` (``ValueError`` for an unknown
        ``generator.tier``)."""
        gen = template.generator
        level = difficulty(None if gen is None else gen.tier)
        if not isinstance(level, Difficulty):
            raise ValueError(
                "generator.tier: a tier with the studies' geometry has its own parameters "
                "(platoon_env.scenarios.sharp_layouts.SharpParams)"
            )
        r = template.robot.radius
        d_des = template.formation.d_des
        beta_con = template.camera.half_angle
        leader = template.leader
        start_len = template.followers * d_des + 1.0
        # A follower on an arc of radius R sees its predecessor (chord d_des ahead) at
        # |beta| = asin(d_des / 2R): keep that below bearing_fraction * beta_con (0.8 untiered).
        # The leader must also be able to turn that tightly (u / omega_max) and pure pursuit
        # should not cut the corner.
        min_radius = max(
            d_des / (2.0 * math.sin(level.bearing_fraction * beta_con)),
            1.2 * leader.speed / leader.max_turn_rate,
            leader.lookahead,
        )
        delta = template.ppc.delta if template.ppc is not None else 0.5
        len_min = max(_PATH_LENGTH[0], start_len + 6.0)
        len_max = max(_PATH_LENGTH[1], start_len + 25.0)
        return cls(r, d_des, start_len, min_radius, delta, len_min, len_max, level)


@dataclass(frozen=True)
class Layout:
    """A sampled layout before it becomes a config: free space, leader path, kind."""

    kind: str
    free_space: Polygon
    path: np.ndarray  # (M, 2) leader path
    #: (T, 4) ``[t, x, y, theta]``: a timed trajectory the leader replays along ``path``
    #: (``leader.trajectory``; its first sample is where the leader starts); None: pure pursuit
    trajectory: np.ndarray | None = None


@dataclass(frozen=True)
class Corner:
    """A rounded corner of a polyline: the arc replacing vertex ``vertex``."""

    vertex: np.ndarray  # the polyline's vertex
    t_in: np.ndarray  # tangent point on the incoming segment
    t_out: np.ndarray  # tangent point on the outgoing segment
    arc: np.ndarray  # (K, 2) points from t_in to t_out inclusive
    turn: float  # signed turn angle [rad], > 0 to the left
    tangent: float  # |vertex - t_in| = |t_out - vertex|


def unit(angle: float) -> np.ndarray:
    """The unit vector at ``angle`` [rad] from the x axis."""
    return np.array([math.cos(angle), math.sin(angle)])


def round_corners(points: np.ndarray, radii: np.ndarray) -> list[Corner]:
    """Replace every interior vertex of the polyline ``points`` by a circular arc.

    ``radii[k]`` is the radius at vertex ``k + 1``. The arcs are tangent to both segments; the
    caller checks that consecutive tangent points do not overlap.
    """
    corners: list[Corner] = []
    for k in range(1, points.shape[0] - 1):
        p = points[k]
        u_in = p - points[k - 1]
        u_in = u_in / np.hypot(*u_in)
        u_out = points[k + 1] - p
        u_out = u_out / np.hypot(*u_out)
        turn = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
        radius = float(radii[k - 1])
        if abs(turn) < 1e-9:
            corners.append(Corner(p, p, p, p[None, :], 0.0, 0.0))
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
        corners.append(Corner(p, t_in, t_out, arc, turn, tangent))
    return corners


def rounded_path(points: np.ndarray, corners: list[Corner]) -> np.ndarray:
    """The polyline with its corners replaced by their arcs (consecutive duplicates removed)."""
    parts = [points[:1], *[c.arc for c in corners], points[-1:]]
    path = np.concatenate(parts, axis=0)
    keep = np.ones(path.shape[0], dtype=bool)
    keep[1:] = np.hypot(*np.diff(path, axis=0).T) > 1e-9
    return path[keep]


def path_length(path: np.ndarray) -> float:
    """The length of the polyline ``path`` [m]."""
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def beside(rng: np.random.Generator, line: LineString, offset: float) -> np.ndarray:
    """A random point at distance ``offset`` to the left or right of a random point of
    ``line`` (measured along the line's normal there)."""
    s = float(rng.uniform(0.1, line.length - 0.1))
    a = np.array(line.interpolate(s - 0.1).coords[0])
    b = np.array(line.interpolate(s + 0.1).coords[0])
    t = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
    side = 1.0 if rng.random() < 0.5 else -1.0
    return np.asarray(0.5 * (a + b) + side * offset * np.array([-t[1], t[0]]))


def fit_in_bounds(
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
    lo = np.array([bx0 + BOUNDS_MARGIN - xmin, by0 + BOUNDS_MARGIN - ymin])
    hi = np.array([bx1 - BOUNDS_MARGIN - xmax, by1 - BOUNDS_MARGIN - ymax])
    if np.any(hi < lo):
        return None
    shift = rng.uniform(lo, hi)
    free = shapely.transform(free, lambda xy: xy + shift)
    return free, path + shift


def path_is_clear(free: Polygon, path: np.ndarray, r: float) -> bool:
    """Whether the path lies in ``free`` with clearance >= ``r + PATH_CLEARANCE`` (exact)."""
    line = LineString(path)
    return bool(free.covers(line) and line.distance(free.boundary) >= r + PATH_CLEARANCE + 1e-3)
