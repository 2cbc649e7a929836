"""The sensing model (``docs/sensing.md``) against closed forms and against the shapely oracle.

Three layers, as STYLE principle 6 asks:

1. the oracle (:mod:`oracle`) against closed forms: distances to a unit square, a follower in
   a straight corridor, wrapping of the angle of view;
2. the compiled kernel :func:`platoon_env.geometry.sensing.sense` against the oracle on
   thousands of random platoon states over five workspaces (every column asserted), including
   lattice states where lines of sight pass exactly through vertices and along edges;
3. both against hand-computed values on constructed degenerate cases: a line of sight through a
   vertex, an edge crossing the line through ``L_i`` beyond the segment, a line of sight along a
   wall, a follower touching a wall, a predecessor exactly on the edge of the field of view.

Both take the sensors as a params record (:func:`~platoon_env.geometry.sensing.sensing_params`)
and both results are read by column name (:func:`oracle.named`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest
import shapely
from numpy.typing import NDArray
from oracle import (
    ANGLE_TOL,
    angle_difference,
    assert_agree,
    kernel_sense,
    named,
    oracle_sense,
    wrap_angle,
)
from shapely.geometry import MultiPolygon, Polygon, box
from workspaces import (
    Workspace,
    all_workspaces,
    collinear_holes,
    sample_lattice_platoon,
    sample_platoon,
    two_rooms,
)

from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import SENSE_NAMES, SENSE_SIZE, sense, sensing_params
from platoon_env.geometry.workspace import boundary_edges

# --------------------------------------------------------------------------------------------
# Helpers


def sensors(d_con: float, proximity_range: float, proximity_half_angle: float = math.pi) -> np.void:
    """The sensors of most cases here: a camera of range ``d_con`` and half-angle 0.5 rad, and
    a proximity sensor of the given range and sector."""
    return sensing_params(
        d_con=d_con,
        beta_con=0.5,
        proximity_range=proximity_range,
        proximity_half_angle=proximity_half_angle,
    )


def corridor(half_width: float, length: float = 40.0) -> Polygon:
    """A straight corridor ``[0, length] x [-half_width, half_width]``."""
    return box(0.0, -half_width, length, half_width)


def unit_square_world() -> Polygon:
    """A big room (100 m square) with the unit square ``[0, 1]^2`` as its only obstacle."""
    return box(-50.0, -50.0, 50.0, 50.0).difference(box(0.0, 0.0, 1.0, 1.0))


# --------------------------------------------------------------------------------------------
# 1. The oracle against closed forms


@pytest.mark.parametrize(
    ("point", "distance"),
    [
        ((2.0, 0.5), 1.0),
        ((0.5, -3.0), 3.0),
        ((2.0, 3.0), math.sqrt(5.0)),
        ((-1.0, -1.0), math.sqrt(2.0)),
        ((1.5, 0.5), 0.5),
        ((0.5, 1.25), 0.25),
        ((-0.75, 0.3), 0.75),
    ],
)
@pytest.mark.parametrize("square_on_left", [True, False])
def test_oracle_distance_to_unit_square(
    point: tuple[float, float], distance: float, square_on_left: bool
) -> None:
    """A follower outside the unit square, looking past it: the square is all on one side.

    The predecessor is 1 m away, perpendicular to the direction of the square's centre, so the
    whole square lies on one side of ``L_i``; the far walls (>= 48 m) lie beyond the proximity
    range, so the other side reads the range.
    """
    proximity = 5.0
    px, py = point
    to_centre = np.array([0.5 - px, 0.5 - py])
    # Left normal of v is (-v_y, v_x); choose v so that it points at the square (or away).
    v = np.array([to_centre[1], -to_centre[0]]) / np.linalg.norm(to_centre)
    if not square_on_left:
        v = -v
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float) - [px, py]
    cross = v[0] * corners[:, 1] - v[1] * corners[:, 0]
    assert np.all(cross > 0) if square_on_left else np.all(cross < 0)
    poses = np.array([[px + v[0], py + v[1], 0.0], [px, py, math.atan2(v[1], v[0])]])
    out = named(oracle_sense(unit_square_world(), poses, sensors(4.0, proximity)))[0]
    near, far = ("d_W_l", "d_W_r")[:: 1 if square_on_left else -1]
    assert out[near] == pytest.approx(distance, abs=1e-12)
    assert out[far] == proximity
    assert out["clearance"] == pytest.approx(distance, abs=1e-12)
    assert out["d"] == pytest.approx(1.0, abs=1e-12)
    assert out["beta"] == pytest.approx(0.0, abs=1e-12)
    assert out["occluded"] == 0.0
    assert out["visible"] == 1.0


def test_oracle_sight_parallel_to_square_side() -> None:
    """Line of sight parallel to the square's right side at 1 m: ``d_l = 1``, ``d_r`` capped."""
    poses = np.array([[2.0, 2.5, 0.0], [2.0, -0.5, math.pi / 2]])
    out = named(oracle_sense(unit_square_world(), poses, sensors(4.0, 5.0)))[0]
    assert out["d_l"] == pytest.approx(1.0, abs=1e-12)
    assert out["d_r"] == 5.0
    assert out["d_W_l"] == pytest.approx(math.hypot(1.0, 0.5), abs=1e-12)
    assert out["clearance"] == pytest.approx(math.hypot(1.0, 0.5), abs=1e-12)


def _point_to_segment(
    point: tuple[float, float], a: tuple[float, float], b: tuple[float, float]
) -> float:
    """Distance from a point to the segment ``[a, b]`` (closed form)."""
    ux, uy = b[0] - a[0], b[1] - a[1]
    t = ((point[0] - a[0]) * ux + (point[1] - a[1]) * uy) / (ux * ux + uy * uy)
    t = min(1.0, max(0.0, t))
    return math.hypot(point[0] - a[0] - t * ux, point[1] - a[1] - t * uy)


def _sight_to_sensed_wall(
    p: tuple[float, float], q: tuple[float, float], wall_y: float, proximity: float
) -> float:
    """``L = [p, q]``'s distance to the points of the horizontal wall ``y = wall_y`` within
    ``proximity`` of ``p`` (a chord of the disk; ``L`` does not reach the wall), capped."""
    gap = abs(wall_y - p[1])
    if gap > proximity:
        return proximity
    half = math.sqrt(proximity * proximity - gap * gap)
    a, b = (p[0] - half, wall_y), (p[0] + half, wall_y)
    # Two segments that do not cross: the distance is attained at one of the four endpoints.
    best = min(_point_to_segment(p, a, b), _point_to_segment(q, a, b))
    best = min(best, _point_to_segment(a, p, q), _point_to_segment(b, p, q))
    return min(best, proximity)


@pytest.mark.parametrize("offset", [-0.6, -0.1, 0.0, 0.35, 0.7])
@pytest.mark.parametrize("rise", [-0.15, 0.0, 0.1])
@pytest.mark.parametrize("heading_error", [0.0, 0.3])
@pytest.mark.parametrize("proximity", [5.0, 0.5])
def test_oracle_straight_corridor(
    offset: float, rise: float, heading_error: float, proximity: float
) -> None:
    """A follower in a corridor of half-width ``w``, looking along it at ``(2, rise)`` ahead.

    Left is the ``+y`` wall: ``d_W_l = w - y``, ``d_W_r = w + y``. The line of sight's
    clearances come from the stretch of each wall within the proximity range of the follower
    (not of ``L_i``): with the long range, the whole wall, so they are set by ``L_i``'s higher /
    lower end; with the short one only ``|x - 20| <= sqrt(R² - gap²)``. All four are capped at
    the proximity range.
    """
    w = 1.0
    y0, y1 = offset, offset + rise
    poses = np.array([[22.0, y1, 0.0], [20.0, y0, heading_error]])
    out = named(oracle_sense(corridor(w), poses, sensors(3.0, proximity)))[0]
    assert out["d_W_l"] == pytest.approx(min(w - y0, proximity), abs=1e-12)
    assert out["d_W_r"] == pytest.approx(min(w + y0, proximity), abs=1e-12)
    left = _sight_to_sensed_wall((20.0, y0), (22.0, y1), w, proximity)
    right = _sight_to_sensed_wall((20.0, y0), (22.0, y1), -w, proximity)
    assert out["d_l"] == pytest.approx(left, abs=1e-12)
    assert out["d_r"] == pytest.approx(right, abs=1e-12)
    if proximity == 5.0:  # the whole stretch beside L_i is in range
        assert left == pytest.approx(min(w - max(y0, y1), proximity), abs=1e-12)
        assert right == pytest.approx(min(w + min(y0, y1), proximity), abs=1e-12)
    assert out["clearance"] == pytest.approx(w - abs(y0), abs=1e-12)
    assert out["d"] == pytest.approx(math.hypot(2.0, rise), abs=1e-12)
    assert out["beta"] == pytest.approx(math.atan2(rise, 2.0) - heading_error, abs=1e-12)
    assert out["occluded"] == 0.0
    assert out["visible"] == 1.0


def test_oracle_corridor_looking_back_swaps_sides() -> None:
    """Facing ``-x`` in the corridor, left is the ``-y`` wall."""
    poses = np.array([[18.0, 0.25, math.pi], [20.0, 0.25, math.pi]])
    out = named(oracle_sense(corridor(1.0), poses, sensors(3.0, 5.0)))[0]
    assert out["d_W_l"] == pytest.approx(1.25, abs=1e-12)
    assert out["d_W_r"] == pytest.approx(0.75, abs=1e-12)
    assert out["d_l"] == pytest.approx(1.25, abs=1e-12)
    assert out["d_r"] == pytest.approx(0.75, abs=1e-12)
    assert out["beta"] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(
    ("direction", "heading", "beta"),
    [
        (0.0, math.pi / 2, -math.pi / 2),
        (-3 * math.pi / 4, 3 * math.pi / 4, math.pi / 2),
        (3 * math.pi / 4, -3 * math.pi / 4, -math.pi / 2),
        (-math.pi / 2, math.pi / 2, math.pi),  # exactly -pi before wrapping: reported as +pi
        (0.1, 0.1 + 2 * math.pi, 0.0),
    ],
)
def test_oracle_angle_of_view_wraps(direction: float, heading: float, beta: float) -> None:
    """``beta = wrap(atan2(y~, x~) - theta)`` lies in ``(-pi, pi]`` (eq. 3)."""
    follower = np.array([20.0, 0.0])
    ahead = follower + 0.5 * np.array([math.cos(direction), math.sin(direction)])
    poses = np.array([[ahead[0], ahead[1], 0.0], [follower[0], follower[1], heading]])
    out = named(oracle_sense(corridor(1.0), poses, sensors(3.0, 5.0)))[0]
    assert out["beta"] == pytest.approx(beta, abs=1e-12)
    assert -math.pi < out["beta"] <= math.pi


def test_wrap_angle() -> None:
    """``wrap_angle`` maps onto ``(-pi, pi]`` and keeps in-range angles bit for bit."""
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)
    assert wrap_angle(0.3) == 0.3
    assert wrap_angle(0.3 - 4 * math.pi) == pytest.approx(0.3)


def test_oracle_thin_wall_occludes() -> None:
    """A wall between follower and predecessor: occluded, not visible, ``d_l = d_r = 0``."""
    free = box(0.0, 0.0, 10.0, 10.0).difference(box(4.9, 3.0, 5.1, 7.0))
    poses = np.array([[6.0, 5.0, 0.0], [4.0, 5.0, 0.0]])
    out = named(oracle_sense(free, poses, sensors(4.0, 4.0)))[0]
    assert out["occluded"] == 1.0
    assert out["visible"] == 0.0
    assert out["d_l"] == 0.0
    assert out["d_r"] == 0.0
    assert out["d_W_l"] == pytest.approx(0.9, abs=1e-12)
    assert out["d_W_r"] == pytest.approx(0.9, abs=1e-12)


def test_oracle_rejects_bad_shape() -> None:
    """Poses must be ``(N + 1, 3)``."""
    with pytest.raises(ValueError, match="shape"):
        oracle_sense(corridor(1.0), np.zeros((3, 2)), sensors(3.0, 3.0))


def test_oracle_refuses_inflation() -> None:
    """The oracle models the true boundary: a record with an inflation is an error, not a
    silent answer for another sensor."""
    poses = np.array([[22.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    inflated = sensing_params(d_con=3.0, beta_con=0.5, proximity_range=3.0, inflation=0.1)
    with pytest.raises(ValueError, match="inflation"):
        oracle_sense(corridor(1.0), poses, inflated)


# --------------------------------------------------------------------------------------------
# 2. The kernel against the oracle


def test_kernel_columns_are_the_documented_ones() -> None:
    """The sensing columns (``env.sensed``, ``docs/sensing.md``), in the documented order; the
    tests read them by these names (:func:`oracle.named`)."""
    assert " ".join(SENSE_NAMES) == "d beta visible occluded d_W_l d_W_r d_l d_r clearance"


@pytest.mark.parametrize("workspace", all_workspaces(), ids=lambda w: w.name)
def test_boundary_edges_cover_every_ring(workspace: Workspace) -> None:
    """``boundary_edges`` lists each ring's edges once: they rebuild ``dW_f`` exactly."""
    edges = boundary_edges(workspace.free_space)
    assert edges.dtype == np.float64 and edges.ndim == 2 and edges.shape[1] == 4
    boundary = workspace.free_space.boundary
    n_segments = sum(len(ring.coords) - 1 for ring in shapely.get_parts(boundary))
    assert edges.shape[0] == n_segments
    rebuilt = shapely.union_all(shapely.linestrings(edges.reshape(-1, 2, 2)))
    assert rebuilt.equals(boundary)
    assert math.isclose(
        float(np.sum(np.hypot(edges[:, 2] - edges[:, 0], edges[:, 3] - edges[:, 1]))),
        boundary.length,
        rel_tol=1e-12,
    )


RANDOM_STATES_PER_WORKSPACE = 700
LATTICE_STATES_PER_WORKSPACE = 400
N_FOLLOWERS = 3


def _proximity_range(workspace: Workspace, k: int) -> float:
    """Cycle the proximity range: the camera range (default), short (often capped), huge."""
    return (workspace.d_con, 0.6, 100.0)[k % 3]


def random_states(workspace: Workspace) -> Iterator[tuple[int, NDArray[np.float64], float]]:
    """The random platoon states of a workspace: ``(k, poses, proximity range)``."""
    rng = np.random.default_rng(sum(map(ord, workspace.name)))
    for k in range(RANDOM_STATES_PER_WORKSPACE):
        poses = sample_platoon(
            workspace.free_space, rng, N_FOLLOWERS, workspace.d_con, workspace.beta_con
        )
        yield k, poses, _proximity_range(workspace, k)


#: Added to the camera range for the lattice states: the circle of the proximity range is kept
#: off the lattice. A wall tangent to it is ill-conditioned for ``d_l``, ``d_r`` (the sensed
#: chord's half-length is ``sqrt(R² - h²)``, so a rounding error ``e`` of ``h²`` moves its ends
#: by ``sqrt(e)``, ~1e-8 m), and lattice walls at lattice distances would hit it exactly.
LATTICE_RANGE_OFFSET = 0.0123


def _lattice_proximity_range(workspace: Workspace, k: int) -> float:
    """:func:`_proximity_range` with the camera range moved off the lattice."""
    return (workspace.d_con + LATTICE_RANGE_OFFSET, 0.6, 100.0)[k % 3]


def lattice_states(workspace: Workspace) -> Iterator[tuple[int, NDArray[np.float64], float]]:
    """The lattice platoon states of a workspace: ``(k, poses, proximity range)``."""
    rng = np.random.default_rng(7 + sum(map(ord, workspace.name)))
    for k in range(LATTICE_STATES_PER_WORKSPACE):
        poses = sample_lattice_platoon(workspace.free_space, rng, N_FOLLOWERS)
        yield k, poses, _lattice_proximity_range(workspace, k)


LATTICE_WORKSPACES = [collinear_holes(), two_rooms(), all_workspaces()[1]]


def _check_states(
    workspace: Workspace, states: Iterator[tuple[int, NDArray[np.float64], float]], kind: str
) -> None:
    """Kernel and oracle agree in every column on each of ``states`` (of :func:`random_states`
    or :func:`lattice_states`)."""
    for k, poses, prox in states:
        params = workspace.sensors(prox)
        assert_agree(
            kernel_sense(workspace.free_space, poses, params),
            oracle_sense(workspace.free_space, poses, params),
            f"{workspace.name} {kind} {k}, prox={prox}, poses={poses.tolist()}",
        )


@pytest.mark.parametrize("workspace", all_workspaces(), ids=lambda w: w.name)
def test_kernel_matches_oracle_random_states(workspace: Workspace) -> None:
    """Random platoons (N = 3, a quarter of the robots near walls): every column agrees."""
    _check_states(workspace, random_states(workspace), "state")


@pytest.mark.parametrize("workspace", LATTICE_WORKSPACES, ids=lambda w: w.name)
def test_kernel_matches_oracle_lattice_states(workspace: Workspace) -> None:
    """Poses on the workspace's own 0.5 m lattice: exact collinear and touching configurations.

    Lines of sight run exactly through vertices and along edges, robots sit exactly on walls
    and occasionally on each other; the closed half-planes must agree with the oracle's.
    """
    _check_states(workspace, lattice_states(workspace), "lattice state")


# --------------------------------------------------------------------------------------------
# 3. Constructed cases, checked against hand-computed values (oracle and kernel)


@dataclass(frozen=True)
class Case:
    """One follower behind its predecessor in a small world, with its expected readings."""

    name: str
    free_space: Polygon | MultiPolygon
    predecessor: tuple[float, float]
    follower: tuple[float, float, float]  # x, y, theta
    d_con: float
    beta_con: float
    proximity_range: float
    #: The readings checked, by column name (``SENSE_NAMES``); the others are not.
    expected: dict[str, float]

    def poses(self) -> NDArray[np.float64]:
        """The ``(2, 3)`` poses array: predecessor (as leader), then the follower."""
        return np.array([[*self.predecessor, 0.0], list(self.follower)], dtype=np.float64)

    def sensors(self) -> np.void:
        """The case's sensors as the params record both senses read."""
        return sensing_params(
            d_con=self.d_con, beta_con=self.beta_con, proximity_range=self.proximity_range
        )


def _room_with(obstacle: Polygon, bounds: tuple[float, float, float, float]) -> Polygon:
    """A rectangular room minus one obstacle."""
    return box(*bounds).difference(obstacle)


# fmt: off
# A table, a case a few lines: the formatter would put every field on a line of its own.
CASES: list[Case] = [
    # The line x + y = 8 touches the square [4, 6]^2 only at its vertex (4, 4). The vertex
    # is on the line, so it belongs to both sides: d_W_r is |(3, 5) - (4, 4)| = sqrt 2.
    Case("sight_through_vertex", _room_with(box(4.0, 4.0, 6.0, 6.0), (0.0, 0.0, 10.0, 10.0)),
         predecessor=(5.0, 3.0), follower=(3.0, 5.0, -math.pi / 4),
         d_con=4.0, beta_con=0.5, proximity_range=4.0,
         expected=dict(d=2 * math.sqrt(2.0), beta=0.0, visible=0.0, occluded=1.0, d_W_l=1.0,
                       d_W_r=math.sqrt(2.0), d_l=0.0, d_r=0.0, clearance=1.0)),
    # The sight line y = 5 meets the triangle's edge (4, 7)-(6, 3) at (5, 5), beyond L_i.
    # Split there: its left part is nearest at (4.6, 5.8) / (4.4, 6.2), its right part
    # only at the split point (5, 5).
    Case("edge_crosses_line_beyond_segment",
         _room_with(Polygon([(4.0, 7.0), (6.0, 3.0), (7.0, 3.0)]), (-10.0, -10.0, 20.0, 20.0)),
         predecessor=(3.0, 5.0), follower=(2.0, 5.0, 0.0),
         d_con=4.0, beta_con=0.5, proximity_range=4.0,
         expected=dict(d=1.0, beta=0.0, visible=1.0, occluded=0.0, d_W_l=math.sqrt(7.2),
                       d_W_r=3.0, d_l=math.sqrt(3.2), d_r=2.0, clearance=math.sqrt(7.2))),
    # Same, but the follower looks the other way: the sides swap.
    Case("edge_crosses_line_behind_follower",
         _room_with(Polygon([(4.0, 7.0), (6.0, 3.0), (7.0, 3.0)]), (-10.0, -10.0, 20.0, 20.0)),
         predecessor=(1.0, 5.0), follower=(2.0, 5.0, math.pi),
         d_con=4.0, beta_con=0.5, proximity_range=4.0,
         expected=dict(d=1.0, visible=1.0, occluded=0.0, d_W_l=3.0, d_W_r=math.sqrt(7.2), d_l=3.0,
                       d_r=math.sqrt(7.2), clearance=math.sqrt(7.2))),
    # The hole's bottom edge (5, 5)-(7, 5) lies on the line through L_i, beyond it: on both
    # sides, not an occlusion.
    Case("edge_on_line_beyond_segment",
         _room_with(box(5.0, 5.0, 7.0, 6.0), (-10.0, -10.0, 20.0, 20.0)),
         predecessor=(3.0, 5.0), follower=(2.0, 5.0, 0.0),
         d_con=4.0, beta_con=0.5, proximity_range=4.0,
         expected=dict(visible=1.0, occluded=0.0, d_W_l=3.0, d_W_r=3.0, d_l=2.0, d_r=2.0,
                       clearance=3.0)),
    # Both robots on the corridor's lower wall: L_i lies along it, which is touching.
    Case("sight_along_wall", corridor(1.0),
         predecessor=(12.0, -1.0), follower=(10.0, -1.0, 0.0),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(d=2.0, beta=0.0, visible=0.0, occluded=1.0, d_W_l=0.0, d_W_r=0.0, d_l=0.0,
                       d_r=0.0, clearance=0.0)),
    # Parallel to the lower wall, 0.25 m above it.
    Case("sight_parallel_to_wall", corridor(1.0),
         predecessor=(12.0, -0.75), follower=(10.0, -0.75, 0.1),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(d=2.0, beta=-0.1, visible=1.0, occluded=0.0, d_W_l=1.75, d_W_r=0.25,
                       d_l=1.75, d_r=0.25, clearance=0.25)),
    # A robot of radius r = 0.25 touching the upper wall: clearance == r exactly.
    Case("follower_touching_wall", corridor(1.0),
         predecessor=(11.5, 0.75), follower=(10.0, 0.75, 0.0),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(visible=1.0, occluded=0.0, d_W_l=0.25, d_W_r=1.75, d_l=0.25, d_r=1.75,
                       clearance=0.25)),
    # atan2(1, 1) - 0 == pi/4 == beta_con exactly: on the edge of the field of view.
    Case("predecessor_on_fov_edge_left", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(6.0, 6.0), follower=(5.0, 5.0, 0.0),
         d_con=3.0, beta_con=math.pi / 4, proximity_range=3.0,
         expected=dict(beta=math.pi / 4, visible=0.0, occluded=0.0)),
    Case("predecessor_on_fov_edge_right", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(6.0, 4.0), follower=(5.0, 5.0, 0.0),
         d_con=3.0, beta_con=math.pi / 4, proximity_range=3.0,
         expected=dict(beta=-math.pi / 4, visible=0.0, occluded=0.0)),
    Case("predecessor_just_inside_fov", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(6.0, 6.0 - 1e-9), follower=(5.0, 5.0, 0.0),
         d_con=3.0, beta_con=math.pi / 4, proximity_range=3.0,
         expected=dict(visible=1.0, occluded=0.0)),
    # |(3, 4)| == 5 == d_con exactly: out of range.
    Case("predecessor_on_range_edge", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(5.0, 6.0), follower=(2.0, 2.0, math.atan2(4.0, 3.0)),
         d_con=5.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(d=5.0, visible=0.0, occluded=0.0)),
    Case("predecessor_just_inside_range", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(5.0, 6.0 - 1e-9), follower=(2.0, 2.0, math.atan2(4.0, 3.0)),
         d_con=5.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(visible=1.0, occluded=0.0)),
    # atan2(-1, 0) - pi/2 == -pi exactly, which wraps to +pi.
    Case("predecessor_right_behind", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(5.0, 4.0), follower=(5.0, 5.0, math.pi / 2),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(d=1.0, beta=math.pi, visible=0.0, occluded=0.0)),
    # Robots on top of each other: the heading (+x) orients left (+y) and right.
    Case("coincident_robots_facing_east", corridor(1.0),
         predecessor=(20.0, 0.25), follower=(20.0, 0.25, 0.0),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(d=0.0, beta=0.0, visible=1.0, occluded=0.0, d_W_l=0.75, d_W_r=1.25,
                       d_l=0.75, d_r=1.25, clearance=0.75)),
    Case("coincident_robots_facing_west", corridor(1.0),
         predecessor=(20.0, 0.25), follower=(20.0, 0.25, math.pi),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(d=0.0, beta=math.pi, visible=0.0, occluded=0.0, d_W_l=1.25, d_W_r=0.75,
                       d_l=1.25, d_r=0.75, clearance=0.75)),
    # Predecessor in the other room of a two-room free space.
    Case("predecessor_in_other_room", two_rooms().free_space,
         predecessor=(5.5, 1.0), follower=(3.5, 1.0, 0.0),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(visible=0.0, occluded=1.0, d_l=0.0, d_r=0.0, clearance=0.5)),
    # Out of contract (the follower is outside W_f), but defined: nothing lies on the
    # right of the line x = 100 looking north, so the right side reads the range.
    Case("empty_side_reads_range", box(0.0, 0.0, 10.0, 10.0),
         predecessor=(100.0, 2.0), follower=(100.0, 1.0, math.pi / 2),
         d_con=3.0, beta_con=0.5, proximity_range=3.0,
         expected=dict(occluded=0.0, d_W_l=3.0, d_W_r=3.0, d_l=3.0, d_r=3.0, clearance=90.0)),
]
# fmt: on


def _check_expected(out: np.void, case: Case, who: str) -> None:
    """Assert one follower's readings (a :func:`oracle.named` record) match the case's
    hand-computed values."""
    for name, value in case.expected.items():
        got = float(out[name])
        if name in ("visible", "occluded"):
            assert got == value, f"{who}, {case.name}: {name} = {got}, expected {value}"
        elif name == "beta":
            assert angle_difference(np.array(got), np.array(value)) <= ANGLE_TOL, (
                f"{who}, {case.name}: beta = {got!r}, expected {value!r}"
            )
            assert -math.pi < got <= math.pi, f"{who}, {case.name}: beta = {got!r} not wrapped"
        else:
            assert abs(got - value) <= 1e-12, (
                f"{who}, {case.name}: {name} = {got!r}, expected {value!r}"
            )


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_oracle_constructed_case(case: Case) -> None:
    """The oracle reproduces the hand-computed readings."""
    out = oracle_sense(case.free_space, case.poses(), case.sensors())
    assert out.shape == (1, SENSE_SIZE)
    _check_expected(named(out)[0], case, "oracle")


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_kernel_constructed_case(case: Case) -> None:
    """The kernel reproduces the hand-computed readings, and the oracle in every column."""
    out = kernel_sense(case.free_space, case.poses(), case.sensors())
    assert out.shape == (1, SENSE_SIZE)
    _check_expected(named(out)[0], case, "kernel")
    assert_agree(out, oracle_sense(case.free_space, case.poses(), case.sensors()), case.name)


def test_kernel_touching_wall_is_a_collision() -> None:
    """``clearance <= r`` holds for a robot of radius ``r`` exactly touching a wall."""
    radius = 0.25
    poses = np.array([[11.5, 0.75, 0.0], [10.0, 0.75, 0.0], [10.0, -0.75, 0.0]])
    out = named(kernel_sense(corridor(1.0), poses, sensors(3.0, 3.0)))
    assert np.all(out["clearance"] <= radius)


def test_zero_length_edges_change_nothing() -> None:
    """A zero-length edge (a point on the boundary) changes no reading; boundary_edges drops it."""
    free = box(0, 0, 10, 10).difference(box(4, 4, 6, 6))
    edges = boundary_edges(free)
    points = np.array([[x, y, x, y] for x, y in np.asarray(free.interiors[0].coords)[:-1]])
    rng = np.random.default_rng(3)
    params = sensors(4.0, 4.0)
    for _ in range(200):
        poses = np.column_stack(
            [rng.uniform(0.5, 9.5, 3), rng.uniform(0.5, 9.5, 3), rng.uniform(-np.pi, np.pi, 3)]
        )
        a = sense(poses, edges, params)
        b = sense(poses, np.concatenate([edges, points]), params)
        np.testing.assert_array_equal(a, b)
    # A repeated vertex makes a zero-length edge in the ring; it is not exported.
    ring = Polygon([(0, 0), (5, 0), (5, 0), (5, 5), (0, 5)])
    assert np.all(np.hypot(*(boundary_edges(ring)[:, 2:] - boundary_edges(ring)[:, :2]).T) > 0)


# --------------------------------------------------------------------------------------------
# 4. The proximity sector: the four clearances see only the boundary within ±alpha of the
#    heading; the camera columns and the clearance do not change.

#: Convex sectors (0.5, pi/2), non-convex ones (2.27, 3.0: a blind cone behind) and all around.
SECTOR_HALF_ANGLES = (0.5, math.pi / 2, 2.27, 3.0, math.pi)
#: The proximity sensor's four clearances, and what the sector does not change.
PROXIMITY = ["d_W_l", "d_W_r", "d_l", "d_r"]
GROUND_TRUTH = ["d", "beta", "visible", "occluded", "clearance"]


def _check_sector_state(
    workspace: Workspace,
    poses: NDArray[np.float64],
    prox: float,
    half_angle: float,
    context: str,
) -> None:
    """Kernel and oracle agree with the sector; only the four clearances may change."""
    params = workspace.sensors(prox, half_angle)
    kernel = kernel_sense(workspace.free_space, poses, params)
    context = f"{context}, half_angle={half_angle}, prox={prox}, poses={poses.tolist()}"
    assert_agree(kernel, oracle_sense(workspace.free_space, poses, params), context)
    everywhere = kernel_sense(workspace.free_space, poses, workspace.sensors(prox))
    np.testing.assert_array_equal(
        named(kernel)[GROUND_TRUTH], named(everywhere)[GROUND_TRUTH], err_msg=context
    )


@pytest.mark.parametrize("workspace", all_workspaces(), ids=lambda w: w.name)
def test_sector_kernel_matches_oracle_random_states(workspace: Workspace) -> None:
    """The random states of the tests above, each with one sector (cycling the half-angles)."""
    for k, poses, prox in random_states(workspace):
        half_angle = SECTOR_HALF_ANGLES[k % len(SECTOR_HALF_ANGLES)]
        _check_sector_state(workspace, poses, prox, half_angle, f"{workspace.name} state {k}")


@pytest.mark.parametrize("workspace", LATTICE_WORKSPACES, ids=lambda w: w.name)
def test_sector_kernel_matches_oracle_lattice_states(workspace: Workspace) -> None:
    """The lattice states (robots exactly on walls, the apex of the sector on an edge)."""
    for k, poses, prox in lattice_states(workspace):
        half_angle = SECTOR_HALF_ANGLES[k % len(SECTOR_HALF_ANGLES)]
        context = f"{workspace.name} lattice state {k}"
        _check_sector_state(workspace, poses, prox, half_angle, context)


def test_sector_of_pi_is_all_around() -> None:
    """A half-angle of ``pi`` or more is all around: ``pi`` and ``2 pi`` read the same bit for
    bit, brute force and with the grid."""
    for workspace in all_workspaces():
        edges = boundary_edges(workspace.free_space)
        states = [*random_states(workspace)][:100]
        for k, poses, prox in states:
            everywhere, beyond = workspace.sensors(prox, math.pi), workspace.sensors(prox, 6.0)
            grid = EdgeGrid.build(edges, reach=prox)
            context = f"{workspace.name} state {k}"
            np.testing.assert_array_equal(
                sense(poses, edges, beyond), sense(poses, edges, everywhere), context
            )
            np.testing.assert_array_equal(
                sense(poses, edges, beyond, grid), sense(poses, edges, everywhere, grid), context
            )


def _room(*obstacles: Polygon) -> Polygon:
    """A 20 m square room with the given obstacles (its walls beyond every proximity range)."""
    free: Polygon = box(0.0, 0.0, 20.0, 20.0)
    for obstacle in obstacles:
        free = free.difference(obstacle)
    return free


def _sense_both(
    free_space: Polygon, poses: NDArray[np.float64], prox: float, half_angle: float, name: str
) -> np.void:
    """The kernel's reading of follower 1 (a :func:`oracle.named` record) after checking it
    against the oracle's."""
    params = sensors(4.0, prox, half_angle)
    kernel = kernel_sense(free_space, poses, params)
    assert_agree(kernel, oracle_sense(free_space, poses, params), name)
    return named(kernel)[0]


def test_sector_hides_a_wall_behind() -> None:
    """A post 1 m straight behind the robot (all of it at bearings beyond 153 deg): seen all
    around, unseen with study B's ±130 deg; the clearance still reports it."""
    free = _room(box(3.0, 9.5, 4.0, 10.5))
    poses = np.array([[6.0, 10.0, 0.0], [5.0, 10.0, 0.0]])
    everywhere = _sense_both(free, poses, 3.0, math.pi, "all around")
    assert everywhere[PROXIMITY].tolist() == (1.0, 1.0, 1.0, 1.0)
    sector = _sense_both(free, poses, 3.0, math.radians(130), "±130 deg")
    assert sector[PROXIMITY].tolist() == (3.0, 3.0, 3.0, 3.0)
    assert sector["clearance"] == everywhere["clearance"] == 1.0
    assert sector["visible"] == everywhere["visible"] == 1.0


def test_sector_splits_an_edge_crossing_the_blind_cone() -> None:
    """A wall x = 4 behind a robot at (5, 10) heading 0.1 rad, predecessor at (5, 9): the whole
    wall lies right of ``L_i``, and the blind cone (beyond ±130 deg) cuts it into two sensed
    pieces, which end where the sector's rays meet it. The upper piece is nearest to ``p``
    (``d_W_r``), the lower one to ``L_i`` (``d_r``)."""
    theta, alpha = 0.1, math.radians(130)
    free = _room(box(3.0, 7.0, 4.0, 12.0))
    poses = np.array([[5.0, 9.0, 0.0], [5.0, 10.0, theta]])
    out = _sense_both(free, poses, 3.0, alpha, "blind cone")
    upper_y = 10.0 - math.tan(theta + alpha)  # where the ray theta + alpha meets x = 4
    lower_y = 10.0 - math.tan(theta - alpha)
    assert 7.0 < lower_y < 9.0 and 10.0 < upper_y < 12.0
    assert out["d_W_r"] == pytest.approx(math.hypot(1.0, upper_y - 10.0), abs=1e-12)
    assert out["d_r"] == pytest.approx(math.hypot(1.0, 9.0 - lower_y), abs=1e-12)
    assert out["d_W_l"] == out["d_l"] == 3.0
    everywhere = _sense_both(free, poses, 3.0, math.pi, "all around")
    assert everywhere["d_W_r"] == everywhere["d_r"] == 1.0


@pytest.mark.parametrize("half_angle", [0.5, 2.27])
@pytest.mark.parametrize("lift", [0.0, 1e-9])
def test_point_on_a_sector_ray_is_sensed(half_angle: float, lift: float) -> None:
    """A triangle in the blind region touching the ray ``theta + alpha`` (exactly +x, as
    ``theta = -alpha``) with one vertex, 1 m from the robot: that vertex is sensed (closed
    sector), on the left of ``L_i``; lifted 1e-9 m off the ray, nothing is."""
    px, py = 5.0, 5.0
    theta = -half_angle
    triangle = Polygon([(px + 1.0, py + lift), (px + 2.0, py + 0.5), (px + 1.2, py + 1.0)])
    poses = np.array([[px + math.cos(theta), py + math.sin(theta), 0.0], [px, py, theta]])
    out = _sense_both(_room(triangle), poses, 3.0, half_angle, "ray")
    # L_i (1 m along theta) is alpha away from the ray: its nearest point to the vertex is its
    # foot when alpha < pi/2, else p.
    sight = math.sin(half_angle) if half_angle < math.pi / 2 else 1.0
    assert out["d_W_l"] == pytest.approx(1.0 if lift == 0.0 else 3.0, abs=1e-12)
    assert out["d_l"] == pytest.approx(sight if lift == 0.0 else 3.0, abs=1e-12)
    assert out["d_W_r"] == out["d_r"] == 3.0
    assert out["clearance"] == pytest.approx(math.hypot(1.0, lift), abs=1e-12)


@pytest.mark.parametrize(
    ("predecessor", "theta"), [((0.0, 4.0), math.pi), ((0.3, 3.1), 3.0)], ids=["along", "across"]
)
def test_sector_apex_on_a_wall(predecessor: tuple[float, float], theta: float) -> None:
    """A robot exactly on the wall x = 0 at 0.4 of its edge, facing it with a ±0.5 rad sector
    (both directions along the wall are blind): its own position is a sensed boundary point
    on ``L_i``, so all four read 0 (clipping alone would lose that point to rounding)."""
    free = box(0.0, 0.0, 10.0, 10.0)
    poses = np.array([[*predecessor, 0.0], [0.0, 3.0, theta]])
    out = _sense_both(free, poses, 3.0, 0.5, "apex")
    assert out[PROXIMITY].tolist() == (0.0, 0.0, 0.0, 0.0)
    assert out["occluded"] == 1.0 and out["clearance"] == 0.0


def test_occlusion_behind_the_sector() -> None:
    """The predecessor 3 m behind the robot, beyond a post, outside a ±90 deg sector: the
    camera reports the occlusion, but the post is not sensed, so ``d_l``, ``d_r`` are the
    distances to the sensed boundary (a box ahead on the right; nothing on the left), not 0."""
    free = _room(box(3.0, 9.0, 4.0, 11.0), box(7.0, 11.5, 8.0, 12.5))
    poses = np.array([[2.0, 10.0, 0.0], [5.0, 10.0, 0.0]])  # looking back along -x: +y is right
    everywhere = _sense_both(free, poses, 3.0, math.pi, "all around")
    assert everywhere["occluded"] == 1.0 and everywhere["visible"] == 0.0
    assert everywhere[PROXIMITY].tolist() == (1.0, 1.0, 0.0, 0.0)
    out = _sense_both(free, poses, 3.0, math.pi / 2, "±90 deg")
    assert out["occluded"] == 1.0 and out["visible"] == 0.0
    corner = math.hypot(2.0, 1.5)  # p to the box's corner (7, 11.5)
    assert out[PROXIMITY].tolist() == pytest.approx((3.0, corner, 3.0, corner), abs=1e-12)
