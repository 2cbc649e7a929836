"""The sensing model (``docs/sensing.md``, paper §2): camera and proximity sensor of every
follower.

One compiled kernel computes, for all followers at once, from the ground-truth poses and the
obstacle-boundary edges ``∂W_f``:

* ``d_i = |p_{i-1} - p_i|`` (eq. 2) and ``beta_i = wrap(atan2(y~, x~) - theta_i)`` (eq. 3);
* ``occluded``: the line of sight ``L_i = [p_i, p_{i-1}]`` touches ``∂W_f``;
* ``visible``: ``d_i < d_con``, ``|beta_i| < beta_con`` and not occluded;
* ``d_W_l,i``, ``d_W_r,i``: distance from ``p_i`` to the nearest boundary point left / right of
  ``L_i``; ``d_l,i``, ``d_r,i``: distance from the segment ``L_i`` to the nearest boundary point
  left / right. A point ``b`` is left when ``cross(p_{i-1} - p_i, b - p_i) > 0``; edges that cross
  the line through ``L_i`` are split at it; points on the line count for both sides.
* the proximity range ``R_p`` (paper §2: the sensor perceives the outline "up to distance
  ``d_con``" of the robot, and eqs. 4-5 constrain the four distances it computes from what it
  perceives): a boundary point ``b`` enters any of the four only when
  ``|b - p_i| <= R_p`` — the disk around the *follower*, also for ``d_l``, ``d_r`` (a wall near
  the predecessor's end of ``L_i`` but beyond ``R_p`` from ``p_i`` is not sensed). All four are
  capped at ``R_p`` (their value when nothing is sensed on that side). Hence occluded ⇒
  ``d_l = d_r = 0`` whenever ``d_i <= R_p`` (the crossing is sensed), and, without inflation,
  ``d_l = d_r = 0`` ⇒ occluded.
* the proximity sector (``proximity.half_angle`` = ``alpha``, default ``pi``: all around): the
  four clearances see only the boundary points ``b`` whose bearing from ``p_i`` relative to
  ``theta_i`` lies in ``[-alpha, alpha]`` (closed; ``p_i`` itself included), i.e. the boundary
  clipped to a wedge with apex ``p_i`` (for ``alpha > pi/2`` the complement of a blind cone
  behind the robot, which can cut one edge into two sensed pieces). Occluded ⇒
  ``d_l = d_r = 0`` then holds when the predecessor's bearing lies in the sector (the crossing
  is sensed); otherwise ``d_l``, ``d_r`` come from the sensed boundary like the others.
* ``clearance``: distance from ``p_i`` to ``∂W_f``, uncapped (collision iff ``clearance <= r``),
  all around whatever the sector: the sector limits what a policy senses, not physics.
* the obstacle inflation ``m`` (``safety.inflation``, default 0; the paper's study B augmented
  the obstacles' boundary by 0.1 m, §4.2): the sensor perceives the outline inflated by ``m``,
  up to ``R_p``: each of the four is the reading of the true boundary within ``R_p + m`` of
  ``p_i``, less ``m``, clipped to ``[0, R_p]``; ``clearance`` is the true one less ``m`` (the
  distance to the inflated outline, negative inside the margin). The camera's line of sight
  (``occluded``, ``visible``) is physical: the margin does not block it. With ``m = 0`` every
  value is the true one, bit for bit.

The same edge arrays and primitives serve the collision checks in :mod:`platoon_env.safety`, so
no sensor sees a wall the robot could drive through. Tests compare against a shapely oracle.

The kernels take points as ``(x, y)`` tuples and poses as ``(x, y, theta)``, the workspace as a
:class:`~platoon_env.records.Walls` (its edges, their boxes and the edge grid) and the
parameters as one :data:`~platoon_env.records.PARAMS_DTYPE` record ``p``, read by name:
``p.d_con``, ``p.beta_con`` (eq. 5), ``p.proximity_range``, ``p.proximity_half_angle`` and
``p.inflation``.

Cost: each follower only visits the edges that a static grid (:mod:`platoon_env.geometry.grid`)
lists within its sensed range or near its line of sight, and skips those whose bounding box
cannot improve a current minimum or lies beyond the sensed range; distances are compared
squared, with one square root per output. The uncapped clearance falls back to a widening
grid search when no edge lies within the sensed range. The brute-force entry points
(:func:`sense_into` without culling, :func:`sense` without a grid) visit every edge and give
the same results. With a sector, each left / right part of an edge is clipped to it before its
distances are taken (a clipped part is never nearer, so the culling bounds stay valid); without
one (``alpha = pi``) none of that code runs. For ``d_l``, ``d_r`` a part reaching beyond the
sensed range is clipped to its disk as well (only when an end lies outside it).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.grid import (
    EdgeGrid,
    covers_grid,
    edge_boxes,
    grid_candidates,
    nearest_edge_distance2,
)
from platoon_env.geometry.primitives import (
    Point,
    box_distance2,
    boxes_overlap,
    cross,
    point_box_distance2,
    point_segment_distance2,
    segments_intersect,
    wrap_angle,
)
from platoon_env.records import PARAMS_DTYPE, Walls

__all__ = [
    "SENSE_BETA",
    "SENSE_CLEARANCE",
    "SENSE_D",
    "SENSE_D_SIGHT_LEFT",
    "SENSE_D_SIGHT_RIGHT",
    "SENSE_D_WALL_LEFT",
    "SENSE_D_WALL_RIGHT",
    "SENSE_NAMES",
    "SENSE_OCCLUDED",
    "SENSE_PROXIMITY",
    "SENSE_SIZE",
    "SENSE_VISIBLE",
    "edge_boxes",
    "reported_clearance",
    "sense",
    "sense_candidates",
    "sense_follower_grid",
    "sense_into",
    "sensing_params",
]

SENSE_D = 0
SENSE_BETA = 1
SENSE_VISIBLE = 2
SENSE_OCCLUDED = 3
SENSE_D_WALL_LEFT = 4
SENSE_D_WALL_RIGHT = 5
SENSE_D_SIGHT_LEFT = 6
SENSE_D_SIGHT_RIGHT = 7
SENSE_CLEARANCE = 8
SENSE_SIZE = 9
#: The proximity sensor's four clearance columns ``d_W_l, d_W_r, d_l, d_r``, in this order: for
#: the code that treats the four alike or reads them together.
SENSE_PROXIMITY = (SENSE_D_WALL_LEFT, SENSE_D_WALL_RIGHT, SENSE_D_SIGHT_LEFT, SENSE_D_SIGHT_RIGHT)
SENSE_NAMES: tuple[str, ...] = (
    "d",
    "beta",
    "visible",
    "occluded",
    "d_W_l",
    "d_W_r",
    "d_l",
    "d_r",
    "clearance",
)

#: A pose ``(x, y, theta)`` [m, m, rad].
Pose = tuple[float, float, float]
#: The line of sight ``L_i`` as the part kernels read it: ``(p, q, q - p, 1 / |q - p|², R²)``
#: (the fourth 0 when ``p = q``; ``R`` the sensed range, ``R_p + m``).
Sight = tuple[Point, Point, Point, float, float]
#: The proximity sector: ``(sectored, convex, r-, r+)``: whether it is narrower than all around,
#: whether it is convex (half-angle ``<= pi/2``) and the unit directions of its two rays.
Sector = tuple[bool, bool, Point, Point]

#: Relative and absolute padding of query boxes, so that rounding never culls an edge that lies
#: exactly at the proximity range.
_PAD_REL = 1e-9
_PAD_ABS = 1e-9
#: The disk of sensed boundary points is closed, of radius ``R (1 + RANGE_PAD_REL)``: a point
#: exactly at the range (lattice inputs put crossings and vertices there) is never lost to the
#: rounding of a clipped or split point. Readings are still capped at ``R`` itself.
RANGE_PAD_REL = 1e-12


# Inlined into its callers (as numba IR): a call would pass the Walls and the candidate slice
# through memory for every follower, measurably slower than the former scalar arguments.
@njit(cache=True, inline="always")
def sense_candidates(
    pose: Pose,
    pred: Point,
    prev: Point,
    check_motion: bool,
    walls: Walls,
    cand: np.ndarray,
    p: np.record,
    out: np.ndarray,
) -> tuple[float, bool]:
    """Sense one follower at ``pose = (x, y, theta)`` behind its predecessor at ``pred``
    (eqs. 2-3).

    Visits the edges ``cand`` only (they must include every edge within the sensed range
    ``R = p.proximity_range + p.inflation`` of ``p_i``, every edge whose box overlaps ``L_i``'s
    and, with ``check_motion``, every edge whose box overlaps the motion's); writes the
    ``SENSE_*`` columns into ``out``. The four clearances see only the boundary within ``R`` of
    ``p_i`` (the proximity range, paper §2) and inside the proximity sector
    ``theta ± p.proximity_half_angle`` (``>= pi``: all around), inflated by ``p.inflation``.
    Returns ``(clearance², motion_hit)``: the squared true clearance (to the boundary itself,
    not inflated) over the visited edges (exact whenever it is ``<= R²`` or every edge was
    visited) and, when ``check_motion``, whether the motion segment ``[prev, p_i]`` of the last
    sub-step touches an edge (the tunnelling check of :mod:`platoon_env.safety`).
    """
    edges, boxes = walls.edges, walls.boxes
    proximity_range = p.proximity_range
    inflation = p.inflation
    # The sensor perceives the outline inflated by m up to R_p: the true boundary within
    # R_p + m of p_i, each distance less m (_reading). m = 0: exactly R_p.
    sensed_range = proximity_range + inflation
    half_angle = p.proximity_half_angle
    px, py, theta = pose
    qx, qy = pred
    ox, oy = prev
    pt = (px, py)
    dx = qx - px
    dy = qy - py
    d = math.sqrt(dx * dx + dy * dy)  # as in safety.pose_violation
    beta = wrap_angle(math.atan2(dy, dx) - theta)
    # Direction that defines left/right; degenerate only when the robots coincide.
    line = (dx, dy)
    if d == 0.0:
        line = (math.cos(theta), math.sin(theta))
    inv_d2 = 1.0 / (dx * dx + dy * dy) if d > 0.0 else 0.0
    sight_bounds = (min(px, qx), min(py, qy), max(px, qx), max(py, qy))
    motion_bounds = (min(px, ox), min(py, oy), max(px, ox), max(py, oy))
    cap2 = sensed_range * sensed_range
    # The disk of the sensed boundary points (closed, padded against rounding).
    disk_range = sensed_range * (1.0 + RANGE_PAD_REL)
    disk2 = disk_range * disk_range
    sight = (pt, pred, (dx, dy), inv_d2, disk2)
    # A predecessor beyond the sensed range: only the part [p_i, sensed_end] of L_i is within
    # it, and only a crossing there is a sensed boundary point on L_i.
    sight_truncated = d > disk_range
    sensed_end = pred
    if sight_truncated:
        k_end = disk_range / d
        sensed_end = (px + k_end * dx, py + k_end * dy)
    wall_l = cap2
    wall_r = cap2
    sight_l = cap2
    sight_r = cap2
    clear2 = math.inf
    occluded = False
    # d_l = d_r = 0: a sensed boundary point lies on L_i (an occluding crossing within the
    # sensed range and sector)
    sight_zero = False
    motion_hit = False
    # The proximity sector: the closed half-planes left of the ray theta - alpha (cross(r-, v)
    # >= 0) and right of the ray theta + alpha (cross(v, r+) >= 0), v = b - p; their
    # intersection for alpha <= pi/2, their union (the complement of the blind cone behind the
    # robot) beyond. alpha >= pi: all around, and none of this runs.
    sectored = half_angle < math.pi
    convex = half_angle <= 0.5 * math.pi
    ray_minus, ray_plus = (0.0, 0.0), (0.0, 0.0)
    # Occluded => d_l = d_r = 0 as long as L_i's crossing point is sensed, i.e. L_i lies in the
    # sector (and the crossing within the sensed range); otherwise the sight clearances come
    # from the sensed boundary like the others.
    occlusion_zeroes_sight = True
    if sectored:
        ray_minus = (math.cos(theta - half_angle), math.sin(theta - half_angle))
        ray_plus = (math.cos(theta + half_angle), math.sin(theta + half_angle))
        in_minus = cross(ray_minus, (dx, dy)) >= 0.0
        in_plus = cross((dx, dy), ray_plus) >= 0.0
        occlusion_zeroes_sight = (in_minus and in_plus) if convex else (in_minus or in_plus)
    sector = (sectored, convex, ray_minus, ray_plus)
    for k in range(cand.shape[0]):
        e = cand[k]
        ebox = (boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3])
        a = (edges[e, 0], edges[e, 1])
        b = (edges[e, 2], edges[e, 3])
        lb_point = point_box_distance2(pt, ebox)
        if lb_point < clear2:
            clear2 = min(clear2, point_segment_distance2(pt, a, b))
        if (
            check_motion
            and not motion_hit
            and boxes_overlap(motion_bounds, ebox)
            and segments_intersect(prev, pt, a, b)
        ):
            motion_hit = True
        sight_box = boxes_overlap(sight_bounds, ebox)
        if (
            sight_box
            and not sight_zero
            and (not occluded or sight_truncated)
            and segments_intersect(pt, pred, a, b)
        ):
            occluded = True
            if occlusion_zeroes_sight and (
                not sight_truncated or segments_intersect(pt, sensed_end, a, b)
            ):
                sight_zero = True
        # Once d_l = d_r = 0, only the wall clearances remain to be found. An edge wholly
        # beyond the sensed range of p_i adds nothing to d_l, d_r (nor to d_W_l, d_W_r).
        lb_sight = 0.0
        need_sight = False
        if not sight_zero and lb_point <= disk2:
            if not sight_box:
                lb_sight = box_distance2(sight_bounds, ebox)
            need_sight = lb_sight < max(sight_l, sight_r)
        if not (need_sight or lb_point < max(wall_l, wall_r)):
            continue
        ax, ay = a
        bx, by = b
        if sectored and lb_point == 0.0 and cross((bx - ax, by - ay), (px - ax, py - ay)) == 0.0:
            # p lies on the edge (the test of segments_intersect): the sector's apex is a
            # sensed boundary point on L_i, so all four clearances are 0. Clipping alone could
            # lose it to rounding when both directions along the edge are blind.
            wall_l = wall_r = sight_l = sight_r = 0.0
            continue
        sa = cross(line, (ax - px, ay - py))
        sb = cross(line, (bx - px, by - py))
        # Split point on the line through L_i (only used when the edge straddles it).
        split = a
        if (sa > 0.0 and sb < 0.0) or (sa < 0.0 and sb > 0.0):
            t = sa / (sa - sb)
            split = (ax + t * (bx - ax), ay + t * (by - ay))
        # Left part: the edge's points in the closed half-plane cross >= 0.
        has_left = True
        if sa >= 0.0 and sb >= 0.0:
            c, f = a, b
        elif sa > 0.0:  # sb < 0: straddles
            c, f = a, split
        elif sb > 0.0:  # sa < 0: straddles
            c, f = split, b
        elif sa == 0.0:  # sb < 0: only the endpoint a lies on the line
            c, f = a, a
        elif sb == 0.0:  # sa < 0: only b
            c, f = b, b
        else:
            has_left = False
        if has_left and (lb_point < wall_l or (need_sight and lb_sight < sight_l)):
            near, far = _sensed_part_distances2(
                sight, c, f, need_sight and lb_sight < sight_l, sector
            )
            wall_l = min(wall_l, near)
            sight_l = min(sight_l, far)
        # Right part: the closed half-plane cross <= 0.
        has_right = True
        if sa <= 0.0 and sb <= 0.0:
            c, f = a, b
        elif sa < 0.0:  # sb > 0: straddles
            c, f = a, split
        elif sb < 0.0:  # sa > 0: straddles
            c, f = split, b
        elif sa == 0.0:  # sb > 0
            c, f = a, a
        elif sb == 0.0:  # sa > 0
            c, f = b, b
        else:
            has_right = False
        if has_right and (lb_point < wall_r or (need_sight and lb_sight < sight_r)):
            near, far = _sensed_part_distances2(
                sight, c, f, need_sight and lb_sight < sight_r, sector
            )
            wall_r = min(wall_r, near)
            sight_r = min(sight_r, far)
    out[SENSE_D] = d
    out[SENSE_BETA] = beta
    out[SENSE_OCCLUDED] = 1.0 if occluded else 0.0
    out[SENSE_VISIBLE] = 1.0 if (d < p.d_con and abs(beta) < p.beta_con and not occluded) else 0.0
    out[SENSE_D_WALL_LEFT] = _reading(wall_l, cap2, sensed_range, p)
    out[SENSE_D_WALL_RIGHT] = _reading(wall_r, cap2, sensed_range, p)
    out[SENSE_D_SIGHT_LEFT] = 0.0 if sight_zero else _reading(sight_l, cap2, sensed_range, p)
    out[SENSE_D_SIGHT_RIGHT] = 0.0 if sight_zero else _reading(sight_r, cap2, sensed_range, p)
    out[SENSE_CLEARANCE] = reported_clearance(clear2, p)
    return clear2, motion_hit


@njit(cache=True, inline="always")
def _clamped_foot2(w: Point, u: Point, inv_u: float) -> float:
    """``|w - t u|²`` for ``t = clamp(w·u / |u|², 0, 1)``: the squared distance from a point to
    a segment, ``w`` the point relative to the segment's start, ``u`` the segment's vector and
    ``inv_u = 1 / |u|²`` (0 for a point)."""
    wx, wy = w
    ux, uy = u
    t = min(1.0, max(0.0, (wx * ux + wy * uy) * inv_u))
    wx -= t * ux
    wy -= t * uy
    return wx * wx + wy * wy


@njit(cache=True, inline="always")
def _disk_interval(v: Point, u: Point, lu: float, range2: float) -> tuple[float, float]:
    """The parameters ``t in [0, 1]`` where ``|v + t u|² <= range2``, as ``(lo, hi)``.

    ``v``: a segment's start relative to the disk's centre, ``u`` its vector, ``lu = |u|²``.
    Empty: ``lo > hi``. A start inside the disk gives ``lo = 0`` exactly.
    """
    cc = v[0] * v[0] + v[1] * v[1] - range2
    if lu <= 0.0:
        return (0.0, 1.0) if cc <= 0.0 else (1.0, 0.0)
    half_b = v[0] * u[0] + v[1] * u[1]
    disc = half_b * half_b - lu * cc
    if disc < 0.0:
        return 1.0, 0.0
    # The roots of lu t² + 2 half_b t + cc, in the form that does not cancel.
    root = -(half_b + math.copysign(math.sqrt(disc), half_b))
    if root == 0.0:
        return 0.0, 0.0
    t0, t1 = root / lu, cc / root
    if t0 > t1:
        t0, t1 = t1, t0
    return max(0.0, t0), min(1.0, t1)


@njit(cache=True, inline="always")
def _part_distances2(sight: Sight, c: Point, e: Point, with_sight: bool) -> tuple[float, float]:
    """Squared distances from ``p`` and (if ``with_sight``) from ``L_i = [p, q]`` to ``[c, e]``.

    ``sight = (p, q, q - p, 1 / |q - p|², R²)`` (the fourth 0 when ``p = q``). The second
    distance sees only the points of ``[c, e]`` within ``R`` of ``p`` (the proximity range, a
    disk around the follower): the part is clipped to that disk first. (The first needs no
    clipping: the point of the part nearest to ``p`` is within ``R`` whenever any is, and the
    capped reading is ``R`` otherwise.) The segments are known not to cross when the second
    distance matters (a crossing means occluded, and then ``d_l = d_r = 0`` anyway), so it is
    attained at one of the four endpoints. Returns ``(near², sight²)``, ``sight² = inf``
    without ``with_sight`` or when no point of the part lies within ``R``.
    """
    (px, py), (qx, qy), dq, inv_d2, range2 = sight
    cx, cy = c
    ex, ey = e
    u = (ex - cx, ey - cy)
    lu = u[0] * u[0] + u[1] * u[1]
    inv_u = 1.0 / lu if lu > 0.0 else 0.0
    near = _clamped_foot2((px - cx, py - cy), u, inv_u)
    if not with_sight or near > range2:
        return near, math.inf
    vc = (cx - px, cy - py)
    ve = (ex - px, ey - py)
    if vc[0] * vc[0] + vc[1] * vc[1] > range2 or ve[0] * ve[0] + ve[1] * ve[1] > range2:
        lo, hi = _disk_interval(vc, u, lu, range2)
        if lo > hi:
            return near, math.inf
        cx, cy = _point_at(c, e, lo)
        ex, ey = _point_at(c, e, hi)
        u = (ex - cx, ey - cy)
        lu = u[0] * u[0] + u[1] * u[1]
        inv_u = 1.0 / lu if lu > 0.0 else 0.0
    # p (on L_i) to the part: near, attained within R.
    best = near
    # q to the part.
    best = min(best, _clamped_foot2((qx - cx, qy - cy), u, inv_u))
    # The part's endpoints to L_i.
    best = min(best, _clamped_foot2((cx - px, cy - py), dq, inv_d2))
    return near, min(best, _clamped_foot2((ex - px, ey - py), dq, inv_d2))


@njit(cache=True, inline="always")
def _half_plane_interval(g0: float, g1: float) -> tuple[float, float]:
    """The parameters ``t in [0, 1]`` where ``g0 + t (g1 - g0) >= 0``, as ``(lo, hi)``.

    ``g0``, ``g1``: a linear function's values at ``t = 0, 1``. Empty: ``(1, 0)`` (``lo > hi``).
    """
    if g0 >= 0.0:
        if g1 >= 0.0:
            return 0.0, 1.0
        return 0.0, g0 / (g0 - g1)
    if g1 >= 0.0:
        return g0 / (g0 - g1), 1.0
    return 1.0, 0.0


@njit(cache=True, inline="always")
def _coordinate_at(c: float, e: float, t: float) -> float:
    """``c + t (e - c)``, exactly ``c`` at ``t = 0`` and ``e`` at ``t = 1``."""
    if t == 0.0:
        return c
    if t == 1.0:
        return e
    return c + t * (e - c)


@njit(cache=True, inline="always")
def _point_at(c: Point, e: Point, t: float) -> Point:
    """The point ``c + t (e - c)`` of ``[c, e]``, exactly ``c`` at ``t = 0`` and ``e`` at
    ``t = 1``."""
    return _coordinate_at(c[0], e[0], t), _coordinate_at(c[1], e[1], t)


@njit(cache=True)
def _sector_part_distances2(
    sight: Sight, c: Point, e: Point, with_sight: bool, sector: Sector
) -> tuple[float, float]:
    """:func:`_part_distances2` over the points of ``[c, e]`` inside the proximity sector.

    The sector (``(sectored, convex, r-, r+)``) is the intersection (``convex``, half-angle
    ``<= pi/2``) or union of the closed half-planes ``cross(r-, b - p) >= 0`` and
    ``cross(b - p, r+) >= 0``, ``r-`` / ``r+`` the directions of its two rays from ``p``. Each
    gives an interval of the part's parameter; the part's sensed points are one interval, or two
    when the part crosses the blind cone. Returns ``(inf, inf)`` when none is sensed. The sensed
    pieces never cross ``L_i`` where :func:`_part_distances2` needs that (see
    :func:`sense_candidates`).
    """
    _, convex, ray_minus, ray_plus = sector
    px, py = sight[0]
    vc = (c[0] - px, c[1] - py)
    ve = (e[0] - px, e[1] - py)
    lo1, hi1 = _half_plane_interval(cross(ray_minus, vc), cross(ray_minus, ve))
    lo2, hi2 = _half_plane_interval(cross(vc, ray_plus), cross(ve, ray_plus))
    if convex:
        lo1, hi1 = max(lo1, lo2), min(hi1, hi2)
        lo2, hi2 = 1.0, 0.0
    elif lo1 > hi1:
        lo1, hi1 = lo2, hi2
        lo2, hi2 = 1.0, 0.0
    elif lo2 <= hi2 and lo2 <= hi1 and lo1 <= hi2:  # overlapping: one piece
        lo1, hi1 = min(lo1, lo2), max(hi1, hi2)
        lo2, hi2 = 1.0, 0.0
    near, far = math.inf, math.inf
    if lo1 <= hi1:
        near, far = _part_distances2(sight, _point_at(c, e, lo1), _point_at(c, e, hi1), with_sight)
    if lo2 <= hi2:
        near2, far2 = _part_distances2(
            sight, _point_at(c, e, lo2), _point_at(c, e, hi2), with_sight
        )
        near, far = min(near, near2), min(far, far2)
    return near, far


@njit(cache=True, inline="always")
def _sensed_part_distances2(
    sight: Sight, c: Point, e: Point, with_sight: bool, sector: Sector
) -> tuple[float, float]:
    """:func:`_part_distances2` of the part ``[c, e]``, clipped to the proximity sector when it
    is narrower than all around (:func:`_sector_part_distances2`); the arguments are theirs."""
    if sector[0]:
        return _sector_part_distances2(sight, c, e, with_sight, sector)
    return _part_distances2(sight, c, e, with_sight)


@njit(cache=True, inline="always")
def _reading(value2: float, cap2: float, cap: float, p: np.record) -> float:
    """A proximity reading from its squared distance to the true boundary within the sensed
    range ``cap = R_p + m`` (``cap2 = cap²``): ``sqrt(value2)`` capped at ``cap``, then, with an
    inflation ``m = p.inflation > 0``, less ``m`` and clipped to ``[0, R_p]`` (the distance to
    the outline inflated by ``m``; nothing sensed reads exactly ``R_p``)."""
    value = cap if value2 >= cap2 else math.sqrt(value2)
    if p.inflation > 0.0:
        value = min(p.proximity_range, max(0.0, value - p.inflation))
    return value


@njit(cache=True, inline="always")
def reported_clearance(clear2: float, p: np.record) -> float:
    """The reported ``clearance`` of a follower whose squared true clearance is ``clear2``: the
    distance to the outline inflated by ``m = p.inflation`` (``sqrt(clear2) - m``; negative when
    the robot's centre is within the margin)."""
    return math.sqrt(clear2) - p.inflation


@njit(cache=True)
def sense_follower_grid(
    pose: Pose,
    pred: Point,
    prev: Point,
    check_motion: bool,
    walls: Walls,
    cand: np.ndarray,
    p: np.record,
    out: np.ndarray,
) -> tuple[float, bool]:
    """:func:`sense_candidates` over the edges the grid lists near ``L_i`` (and ``[prev, p_i]``).

    ``cand`` is scratch space for at least ``E`` edge indices. The query box holds the disk of
    the sensed range ``R_p + m`` around ``p_i``, ``L_i`` and the motion (what
    :func:`sense_candidates` needs). The clearance is exact: when no edge lies within the
    sensed range, a widening grid search finds the nearest one.
    """
    px, py, _ = pose
    sensed_range = p.proximity_range + p.inflation
    reach = sensed_range * (1.0 + _PAD_REL) + _PAD_ABS
    query = (
        min(px - reach, min(pred[0], prev[0])),
        min(py - reach, min(pred[1], prev[1])),
        max(px + reach, max(pred[0], prev[0])),
        max(py + reach, max(pred[1], prev[1])),
    )
    n = grid_candidates(walls, query, cand)
    clear2, hit = sense_candidates(pose, pred, prev, check_motion, walls, cand[:n], p, out)
    if clear2 > sensed_range * sensed_range and not covers_grid(walls.grid, query):
        clear2 = nearest_edge_distance2(walls, (px, py), reach, cand)
        out[SENSE_CLEARANCE] = reported_clearance(clear2, p)
    return clear2, hit


@njit(cache=True)
def sense_into(
    poses: np.ndarray, walls: Walls, p: np.record, out: np.ndarray, culled: bool
) -> None:
    """Sense every follower ``i = 1..N`` of ``poses`` ((N+1) x 3) into ``out`` (N x SENSE_SIZE).

    ``culled``: each follower visits the edges the grid of ``walls`` lists near it
    (:func:`sense_follower_grid`); otherwise brute force over every edge (:func:`sense_candidates`,
    the grid is not read). The same results. The proximity sector is
    ``theta_i ± p.proximity_half_angle``.
    """
    # Brute force reads these indices; culling overwrites them as its scratch.
    cand = np.arange(walls.edges.shape[0])
    for i in range(1, poses.shape[0]):
        pose = (poses[i, 0], poses[i, 1], poses[i, 2])
        pred = (poses[i - 1, 0], poses[i - 1, 1])
        here = (poses[i, 0], poses[i, 1])
        if culled:
            sense_follower_grid(pose, pred, here, False, walls, cand, p, out[i - 1])
        else:
            sense_candidates(pose, pred, here, False, walls, cand, p, out[i - 1])


def sensing_params(
    *,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    proximity_half_angle: float = math.pi,
    inflation: float = 0.0,
) -> np.record:
    """A :data:`~platoon_env.records.PARAMS_DTYPE` record holding only the fields the sensing
    reads (every other field 0): the camera's ``d_con``, ``beta_con`` (eq. 5), the proximity
    range ``R_p``, its sector's half-angle (default ``pi``: all around) and the obstacle
    inflation ``m`` [m] (``safety.inflation``; default 0). For :func:`sense` where no scenario
    gives the record (:func:`platoon_env.records.constraint_params` does for a config)."""
    params = np.zeros(1, dtype=PARAMS_DTYPE)
    params["d_con"] = d_con
    params["beta_con"] = beta_con
    params["proximity_range"] = proximity_range
    params["proximity_half_angle"] = proximity_half_angle
    params["inflation"] = inflation
    return params[0]


def sense(
    poses: np.ndarray, edges: np.ndarray, params: np.record, grid: EdgeGrid | None = None
) -> np.ndarray:
    """Sense all followers; returns an ``(N, SENSE_SIZE)`` float64 array of ``SENSE_*`` columns.

    Convenience entry point for tests and plots; the env calls the compiled kernel directly.
    ``params`` is a :data:`~platoon_env.records.PARAMS_DTYPE` record, read by name as the
    compiled step reads it: ``d_con``, ``beta_con``, ``proximity_range``,
    ``proximity_half_angle`` (the sector ``theta_i ± proximity_half_angle``; ``pi``: all
    around) and ``inflation`` (``m``) — :func:`sensing_params` builds one,
    :func:`platoon_env.records.constraint_params` gives a scenario's. ``grid`` (built over the
    same ``edges``) culls distant edges; without it every edge is visited. Both give the same
    result.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    edges = np.ascontiguousarray(edges, dtype=np.float64).reshape(-1, 4)
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 2:
        raise ValueError(f"poses must have shape (N+1, 3) with N >= 1, got {poses.shape}")
    if getattr(params, "dtype", None) != PARAMS_DTYPE or np.ndim(params) != 0:
        raise TypeError(f"params must be one PARAMS_DTYPE record, got {params!r}")
    half_angle = float(params["proximity_half_angle"])
    if not 0.0 < half_angle:
        raise ValueError(f"proximity_half_angle must be > 0, got {half_angle}")
    inflation = float(params["inflation"])
    if not (math.isfinite(inflation) and inflation >= 0.0):
        raise ValueError(f"inflation must be finite and >= 0, got {inflation}")
    out = np.empty((poses.shape[0] - 1, SENSE_SIZE), dtype=np.float64)
    if grid is None:
        sense_into(poses, EdgeGrid.single_cell(edges).walls, params, out, False)
    else:
        if grid.n_edges != edges.shape[0]:
            raise ValueError(f"grid indexes {grid.n_edges} edges, got {edges.shape[0]}")
        sense_into(poses, grid.walls, params, out, True)
    return out
