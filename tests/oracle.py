"""A slow, independent shapely reference for the sensing model (``docs/sensing.md``).

This is the test oracle for :func:`platoon_env.geometry.sensing.sense`. It shares no code with
the kernel (only its interface: the params record it reads by field name and the columns of the
result): it works on the free space ``W_f`` as a shapely geometry and answers every question
with shapely operations (``intersects``, ``intersection``, ``distance``), so that an agreement
between the two on random states is evidence that both implement the spec, not the same bug.

The sensing model, for follower ``i`` at ``p_i`` with heading ``theta_i`` behind ``p_{i-1}``:

- ``d_i = |p_{i-1} - p_i|`` (eq. 2) and ``beta_i = wrap(atan2(y~, x~) - theta_i)`` in
  ``(-pi, pi]`` (eq. 3), with ``(x~, y~) = p_{i-1} - p_i`` in the world frame;
- the line of sight ``L_i = [p_i, p_{i-1}]`` is *occluded* iff it intersects the boundary
  ``dW_f`` (touching counts);
- *visible* iff ``d_i < d_con``, ``|beta_i| < beta_con`` and not occluded;
- a boundary point ``b`` is on the left of ``L_i`` when ``cross(p_{i-1} - p_i, b - p_i) >= 0``
  and on the right when ``<= 0`` (closed half-planes: points on the line belong to both);
- the proximity range ``R_p`` is a disk around the *follower* (the paper's sensor perceives the
  outline "up to distance d_con" of the robot): only boundary points ``b`` with
  ``|b - p_i| <= R_p`` are sensed, for all four clearances;
- ``d_W_l`` / ``d_W_r``: distance from ``p_i`` to the sensed boundary in the left / right
  half-plane, ``d_l`` / ``d_r``: distance from the segment ``L_i`` to it; all four capped at the
  proximity range, which is also their value when a side holds no sensed boundary at all;
- ``clearance``: distance from ``p_i`` to ``dW_f``, uncapped (the collision check is
  ``clearance <= r``);
- if ``d_i == 0`` the follower's heading replaces ``p_{i-1} - p_i`` for left and right;
- with a proximity sector of half-angle ``alpha < pi``, the four clearances see only the
  boundary points ``b`` whose bearing from ``p_i`` relative to ``theta_i`` lies in
  ``[-alpha, alpha]`` (and ``p_i`` itself): the boundary is clipped to that closed wedge
  before the left/right split; ``clearance`` and the camera columns ignore the sector.

The half-planes are big polygons: the line through ``L_i`` splits a box much larger than the
workspace. Their shared side runs through ``p_i`` and ``p_{i-1}`` themselves (exact input
coordinates), so that boundary points lying exactly on ``L_i`` land in both halves under GEOS's
robust predicates. The wedge is a polygon too: apex ``p_i``, its two rays exactly along
``theta_i ± alpha`` and, in between, vertices going round the front far beyond the proximity
range (a non-convex polygon when ``alpha > pi/2``). The disk of the proximity range is not a
polygon (a buffered point would be off by its chords): each sensed side's segments are clipped to
it exactly, by solving the segment's quadratic in closed form (:func:`_clip_to_disk`), before
shapely measures ``d_l`` / ``d_r``. ``d_W_l`` / ``d_W_r`` need no clipping: the capped distance
from ``p_i`` is the same with or without the points beyond ``R_p``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

from platoon_env.geometry.sensing import SENSE_NAMES, SENSE_SIZE, sense
from platoon_env.geometry.workspace import boundary_edges

#: The result's columns are the kernel's (``SENSE_NAMES``, in ``SENSE_*`` order: the layout is
#: shared, the values are computed independently). :func:`named` reads them by name.
READING_DTYPE = np.dtype([(name, np.float64) for name in SENSE_NAMES])


def named(readings: NDArray[np.float64]) -> NDArray[np.void]:
    """Readings ``(..., SENSE_SIZE)`` (the kernel's or the oracle's) as records whose fields are
    the columns' names: ``named(out)["d_l"]`` (a view; a row of ``N`` followers gives ``N``
    records, one follower's row a 0-d array of one)."""
    return np.ascontiguousarray(readings, dtype=np.float64).view(READING_DTYPE)[..., 0]


#: Absolute tolerance on distances [m] (relative beyond 1 m) and on the angle of view [rad].
DIST_TOL = 1e-9
ANGLE_TOL = 1e-12
#: The disk of the proximity range is closed and its radius padded by this relative amount, as
#: the spec allows, so that a boundary point at exactly the range (lattice inputs put crossings
#: there) is sensed whatever the rounding of a split point.
RANGE_PAD_REL = 1e-12


def wrap_angle(angle: float) -> float:
    """Wrap an angle into ``(-pi, pi]``; an angle already in range is returned untouched."""
    if -math.pi < angle <= math.pi:
        return angle
    wrapped = math.remainder(angle, 2.0 * math.pi)  # in [-pi, pi]
    return math.pi if wrapped <= -math.pi else wrapped


def _half_plane(
    origin: tuple[float, float],
    ahead: tuple[float, float],
    direction: tuple[float, float],
    side: float,
    reach: float,
) -> Polygon:
    """The closed half-plane left (``side=+1``) or right (``side=-1``) of a line, as a polygon.

    The line passes through ``origin`` and ``ahead`` (``ahead - origin`` is parallel to
    ``direction``; they coincide when there is no predecessor to look at). The polygon's side on
    the line runs through both points exactly and extends ``reach`` beyond them; its far side is
    ``reach`` away from the line.
    """
    ox, oy = origin
    ax, ay = ahead
    dx, dy = direction
    length = math.hypot(dx, dy)
    # A power of two keeps k * direction exact, so lattice inputs give lattice vertices.
    k = 2.0 ** math.ceil(math.log2(reach / length))
    ex, ey = k * dx, k * dy  # along the line
    nx, ny = -side * ey, side * ex  # towards the requested side
    back = (ox - ex, oy - ey)
    front = (ax + ex, ay + ey)
    chain = [back, (ox, oy)]
    if (ax, ay) != (ox, oy):
        chain.append((ax, ay))
    chain.append(front)
    far = [(front[0] + nx, front[1] + ny), (back[0] + nx, back[1] + ny)]
    polygon = Polygon(chain + far)
    if not polygon.is_valid:  # pragma: no cover - a guard on the oracle itself
        raise AssertionError(f"oracle built an invalid half-plane polygon: {polygon.wkt}")
    return polygon


def _sector(apex: tuple[float, float], heading: float, half_angle: float, reach: float) -> Polygon:
    """The closed wedge of bearings ``heading ± half_angle`` from ``apex``, out to ``> reach``.

    Its rays end at ``apex + R (cos(heading ± half_angle), sin(heading ± half_angle))`` and the
    vertices between them go round the front in steps of at most ``pi/2``, so every chord lies
    at least ``R cos(pi/4) > reach`` from the apex (``R = 2 reach``).
    """
    px, py = apex
    radius = 2.0 * reach
    steps = max(1, math.ceil(2.0 * half_angle / (math.pi / 2)))
    angles = [heading - half_angle]
    angles += [heading - half_angle + 2.0 * half_angle * k / steps for k in range(1, steps)]
    angles.append(heading + half_angle)
    ring = [(px, py)] + [(px + radius * math.cos(a), py + radius * math.sin(a)) for a in angles]
    polygon = Polygon(ring)
    if not polygon.is_valid:  # pragma: no cover - a guard on the oracle itself
        raise AssertionError(f"oracle built an invalid sector polygon: {polygon.wkt}")
    return polygon


def _clip_to_disk(
    side_boundary: BaseGeometry, centre: tuple[float, float], radius: float
) -> BaseGeometry:
    """The points of a (multi)line / point geometry within ``radius`` of ``centre`` (closed).

    Every straight piece ``a + t (b - a)``, ``t in [0, 1]``, keeps the ``t`` where
    ``|a + t (b - a) - centre|² <= radius²`` (an interval: the roots of a quadratic); a piece
    that keeps a single point becomes a point. Returns a shapely collection (possibly empty).
    """
    cx, cy = centre
    r2 = radius * radius
    everything = shapely.get_coordinates(side_boundary)
    if len(everything) == 0 or np.all(np.sum((everything - centre) ** 2, axis=1) <= r2):
        return side_boundary  # the disk is convex: all of it is inside
    kept: list[BaseGeometry] = []
    for part in shapely.get_parts(side_boundary):
        coords = shapely.get_coordinates(part)
        if len(coords) == 1:
            x, y = coords[0]
            if (x - cx) ** 2 + (y - cy) ** 2 <= r2:
                kept.append(Point(x, y))
            continue
        for (ax, ay), (bx, by) in itertools.pairwise(coords):
            ux, uy = bx - ax, by - ay
            wx, wy = ax - cx, ay - cy
            qa = ux * ux + uy * uy
            qb = 2.0 * (wx * ux + wy * uy)
            qc = wx * wx + wy * wy - r2
            if qa == 0.0:
                if qc <= 0.0:
                    kept.append(Point(ax, ay))
                continue
            disc = qb * qb - 4.0 * qa * qc
            if disc < 0.0:
                continue
            root = math.sqrt(disc)
            lo = max(0.0, (-qb - root) / (2.0 * qa))
            hi = min(1.0, (-qb + root) / (2.0 * qa))
            if lo > hi:
                continue
            # Endpoints inside the disk are kept exactly (t = 0 or 1).
            start = (ax, ay) if lo == 0.0 else (ax + lo * ux, ay + lo * uy)
            end = (bx, by) if hi == 1.0 else (ax + hi * ux, ay + hi * uy)
            kept.append(Point(start) if start == end else LineString([start, end]))
    return shapely.GeometryCollection(kept)


def _capped_distance(geometry: BaseGeometry, side_boundary: BaseGeometry, cap: float) -> float:
    """``min(distance(geometry, side_boundary), cap)``; ``cap`` when the side holds no boundary."""
    if side_boundary.is_empty:
        return cap
    return min(float(geometry.distance(side_boundary)), cap)


def oracle_sense_follower(
    boundary: BaseGeometry,
    follower: NDArray[np.float64],
    predecessor: NDArray[np.float64],
    params: np.void,
    reach: float,
) -> NDArray[np.float64]:
    """The nine sensed quantities of one follower, as a length-9 float64 array.

    ``boundary`` is ``dW_f`` (a shapely line geometry), ``follower`` is ``[x, y, theta]`` and
    ``predecessor`` is ``[x, y, ...]``; ``params`` the sensors, as in :func:`oracle_sense`.
    ``reach`` is a length beyond which no boundary lies from the follower (it sizes the
    half-plane and wedge polygons).
    """
    d_con, beta_con = float(params["d_con"]), float(params["beta_con"])
    proximity_range = float(params["proximity_range"])
    proximity_half_angle = float(params["proximity_half_angle"])
    px, py, theta = float(follower[0]), float(follower[1]), float(follower[2])
    qx, qy = float(predecessor[0]), float(predecessor[1])
    rel_x, rel_y = qx - px, qy - py
    d = math.hypot(rel_x, rel_y)
    beta = wrap_angle(math.atan2(rel_y, rel_x) - theta)

    p = Point(px, py)
    if d == 0.0:
        # Degenerate (the robots collided): L_i is a point, the heading orients left/right.
        line_of_sight: BaseGeometry = p
        direction = (math.cos(theta), math.sin(theta))
    else:
        line_of_sight = LineString([(px, py), (qx, qy)])
        direction = (rel_x, rel_y)

    occluded = bool(line_of_sight.intersects(boundary))
    visible = d < d_con and abs(beta) < beta_con and not occluded

    sensed = boundary
    if proximity_half_angle < math.pi:
        sensed = boundary.intersection(_sector((px, py), theta, proximity_half_angle, reach))
    sides = []
    for side in (1.0, -1.0):
        half_plane = _half_plane((px, py), (qx, qy), direction, side, reach)
        side_boundary = sensed.intersection(half_plane)
        sides.append(side_boundary)
    left, right = sides

    row = np.empty(SENSE_SIZE, dtype=np.float64)
    out = named(row)
    out["d"] = d
    out["beta"] = beta
    out["visible"] = 1.0 if visible else 0.0
    out["occluded"] = 1.0 if occluded else 0.0
    out["d_W_l"] = _capped_distance(p, left, proximity_range)
    out["d_W_r"] = _capped_distance(p, right, proximity_range)
    # d_l, d_r see only the boundary within the proximity range of the follower.
    disk = proximity_range * (1.0 + RANGE_PAD_REL)
    in_range = [_clip_to_disk(side, (px, py), disk) for side in (left, right)]
    out["d_l"] = _capped_distance(line_of_sight, in_range[0], proximity_range)
    out["d_r"] = _capped_distance(line_of_sight, in_range[1], proximity_range)
    out["clearance"] = float(p.distance(boundary))
    return row


def oracle_sense(
    free_space: BaseGeometry, poses: NDArray[np.float64], params: np.void
) -> NDArray[np.float64]:
    """Reference sensing of every follower: an ``(N, 9)`` float64 array.

    Args:
        free_space: ``W_f`` as a shapely ``Polygon`` or ``MultiPolygon``; its boundary (every
            exterior and interior ring) is ``dW_f``.
        poses: ``(N + 1, 3)`` array of ``[x, y, theta]``, the leader ``R_0`` first; row ``i``
            (``i >= 1``) is follower ``i``, whose predecessor is row ``i - 1``.
        params: the sensors, a record with the fields of ``PARAMS_DTYPE``
            (``platoon_env.records``) that the sensing reads, by name: ``d_con`` (visibility
            needs ``d_i < d_con``), ``beta_con`` (and ``|beta_i| < beta_con``),
            ``proximity_range`` (the radius around each follower within which the boundary is
            sensed, and the cap of ``d_W_l, d_W_r, d_l, d_r``), ``proximity_half_angle`` (those
            four see only the boundary at bearings within ``±`` it of the follower's heading;
            ``pi``: all around) and ``inflation``, which must be 0 (the oracle models the true
            boundary only).

    Returns:
        Row ``i - 1`` holds follower ``i``'s ``[d, beta, visible, occluded, d_W_l, d_W_r, d_l,
        d_r, clearance]`` (``visible`` and ``occluded`` as 0.0 / 1.0), in the column order of
        ``SENSE_NAMES`` (:func:`named` reads them by name).
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 1:
        raise ValueError(f"poses must have shape (N + 1, 3), got {poses.shape}")
    if params["inflation"] != 0.0:
        raise ValueError(f"the oracle models no inflation, got {params['inflation']}")
    boundary = free_space.boundary
    xmin, ymin, xmax, ymax = free_space.bounds
    # Any length exceeding every distance between a pose and the boundary will do.
    extent = max(
        xmax - xmin,
        ymax - ymin,
        float(np.max(np.abs(poses[:, :2] - [xmin, ymin]))),
        float(np.max(np.abs(poses[:, :2] - [xmax, ymax]))),
        1.0,
    )
    reach = 8.0 * extent
    rows = [
        oracle_sense_follower(boundary, poses[i], poses[i - 1], params, reach)
        for i in range(1, poses.shape[0])
    ]
    if not rows:
        return np.zeros((0, SENSE_SIZE), dtype=np.float64)
    return np.vstack(rows)


def mirror_geometry(geometry: BaseGeometry) -> BaseGeometry:
    """Reflect a geometry in the x-axis (``y -> -y``), exactly (a sign flip per coordinate)."""
    return shapely.transform(geometry, lambda xy: xy * np.array([1.0, -1.0]))


def mirror_poses(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Reflect poses in the x-axis: ``(x, y, theta) -> (x, -y, -theta)``."""
    return np.asarray(poses, dtype=np.float64) * np.array([1.0, -1.0, -1.0])


# --------------------------------------------------------------------------------------------
# Comparing a sensing function with the oracle


def angle_difference(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``|a - b|`` on the circle (so that ``pi`` and ``-pi`` are 0 apart)."""
    diff = np.remainder(np.asarray(a) - np.asarray(b) + math.pi, 2.0 * math.pi) - math.pi
    return np.abs(diff)


def disagreements(
    kernel: NDArray[np.float64], reference: NDArray[np.float64]
) -> list[tuple[int, str, float, float]]:
    """Every ``(row, column name, kernel value, reference value)`` outside tolerance."""
    found: list[tuple[int, str, float, float]] = []
    for col, name in enumerate(SENSE_NAMES):
        k, r = kernel[:, col], reference[:, col]
        if name in ("visible", "occluded"):
            bad = k != r
        elif name == "beta":
            bad = ~(angle_difference(k, r) <= ANGLE_TOL)
        else:
            bad = ~(np.abs(k - r) <= DIST_TOL * max(1.0, float(np.max(np.abs(r)))))
        found.extend((int(row), name, float(k[row]), float(r[row])) for row in np.flatnonzero(bad))
    return found


def kernel_sense(
    free_space: BaseGeometry, poses: NDArray[np.float64], params: np.void
) -> NDArray[np.float64]:
    """The kernel under test (:func:`platoon_env.geometry.sensing.sense`, every edge visited),
    taking a shapely free space like :func:`oracle_sense` does."""
    return sense(poses, boundary_edges(free_space), params)


def assert_agree(kernel: NDArray[np.float64], reference: NDArray[np.float64], context: str) -> None:
    """Assert kernel and reference agree in every column, naming the disagreements."""
    assert kernel.shape == reference.shape, f"{context}: shape {kernel.shape} != {reference.shape}"
    assert kernel.dtype == np.float64, f"{context}: dtype {kernel.dtype}"
    found = disagreements(kernel, reference)
    assert not found, f"{context}: (follower row, column, kernel, oracle) = {found}"
