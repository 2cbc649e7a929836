"""Workspace geometry: the free space ``W_f`` built and validated once with shapely.

The per-step code never touches shapely: it works on :attr:`Workspace.edges`, the array of
boundary segments of ``W_f`` (outer ring and every hole), and their bounding boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Point, Polygon, box
from shapely.ops import nearest_points
from shapely.validation import explain_validity

from platoon_env.config import ScenarioError, WorkspaceConfig
from platoon_env.geometry.sensing import edge_boxes

#: Extra clearance beyond ``r`` that the leader's path must keep from every obstacle.
LEADER_PATH_MARGIN = 0.05


def _polygon(points: object, where: str, holes: object = ()) -> Polygon:
    pts = list(points)  # type: ignore[call-overload]
    if len(pts) < 3:
        raise ScenarioError(f"{where}: a polygon needs at least 3 points, got {len(pts)}")
    try:
        poly = Polygon(pts, [list(h) for h in holes])  # type: ignore[attr-defined]
    except (ValueError, TypeError) as exc:
        raise ScenarioError(f"{where}: not a polygon ({exc})") from exc
    if not poly.is_valid:
        raise ScenarioError(f"{where}: invalid polygon: {explain_validity(poly)}")
    if poly.area <= 0.0:
        raise ScenarioError(f"{where}: polygon has zero area")
    return poly


def build_free_space(cfg: WorkspaceConfig, path: str = "scenario.workspace") -> Polygon:
    """Build ``W_f`` = (``free_space`` ∩ ``bounds``) minus ``obstacles`` and validate it.

    Raises :class:`ScenarioError` naming the offending polygon for self-intersecting, empty or
    degenerate input, and when nothing or more than one connected piece remains.
    """
    region: Polygon | None = None
    if cfg.free_space is not None:
        fs = cfg.free_space
        for k, hole in enumerate(fs.holes):
            _polygon(hole, f"{path}.free_space.holes[{k}]")
        region = _polygon(fs.exterior, f"{path}.free_space.exterior", fs.holes)
    if cfg.bounds is not None:
        xmin, ymin, xmax, ymax = cfg.bounds
        if not (xmin < xmax and ymin < ymax):
            raise ScenarioError(f"{path}.bounds: expected [xmin, ymin, xmax, ymax] with min < max")
        bounds_box = box(xmin, ymin, xmax, ymax)
        region = bounds_box if region is None else region.intersection(bounds_box)
    if region is None:
        raise ScenarioError(f"{path}: give 'bounds' and/or 'free_space'")
    obstacles = [_polygon(o, f"{path}.obstacles[{k}]") for k, o in enumerate(cfg.obstacles)]
    # One difference with the obstacles' union (a cascaded union, about n log n) rather than one
    # difference per obstacle, whose cost grows with the free space cut so far (quadratic:
    # 2,000 small obstacles took 12 s, 5,000 about a minute).
    free = region.difference(shapely.union_all(obstacles)) if obstacles else region
    free = shapely.make_valid(free)
    if isinstance(free, MultiPolygon):
        pieces = [g for g in free.geoms if g.area > 1e-12]
        if len(pieces) != 1:
            raise ScenarioError(
                f"{path}: the obstacles split the free space into {len(pieces)} disconnected pieces"
            )
        free = pieces[0]
    if not isinstance(free, Polygon) or free.is_empty or free.area <= 0.0:
        raise ScenarioError(f"{path}: the free space is empty")
    return shapely.normalize(free)


def boundary_edges(free_space: Polygon | MultiPolygon) -> np.ndarray:
    """All boundary segments of ``free_space`` as an ``(E, 4)`` float64 array ``[ax, ay, bx, by]``.

    Every ring (exterior and holes) contributes its edges; zero-length edges are dropped.
    """
    polys = list(free_space.geoms) if isinstance(free_space, MultiPolygon) else [free_space]
    rows: list[np.ndarray] = []
    for poly in polys:
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords, dtype=np.float64)
            seg = np.concatenate([xy[:-1], xy[1:]], axis=1)
            keep = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > 0.0
            rows.append(seg[keep])
    edges = np.concatenate(rows, axis=0) if rows else np.zeros((0, 4))
    return np.ascontiguousarray(edges, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Workspace:
    """The free space ``W_f`` and the precomputed arrays the per-step kernels use."""

    free_space: Polygon
    edges: np.ndarray  # (E, 4) boundary segments [ax, ay, bx, by]
    boxes: np.ndarray  # (E, 4) their bounding boxes [xmin, ymin, xmax, ymax]

    @classmethod
    def from_free_space(cls, free_space: Polygon) -> Workspace:
        """Precompute the edge arrays of a validated free space."""
        edges = boundary_edges(free_space)
        edges.setflags(write=False)
        boxes = edge_boxes(edges)
        boxes.setflags(write=False)
        return cls(free_space=free_space, edges=edges, boxes=boxes)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """Bounding box ``(xmin, ymin, xmax, ymax)`` of the free space."""
        xmin, ymin, xmax, ymax = self.free_space.bounds
        return float(xmin), float(ymin), float(xmax), float(ymax)

    def clearance(self, x: float, y: float) -> float:
        """Distance from ``(x, y)`` to ∂W_f, negative outside ``W_f`` (shapely; not for steps)."""
        pt = Point(x, y)
        dist = float(self.free_space.boundary.distance(pt))
        return dist if self.free_space.covers(pt) else -dist


def check_leader_path(
    free_space: Polygon,
    path_xy: np.ndarray,
    radius: float,
    where: str = "scenario.leader.path",
    *,
    inflation: float = 0.0,
) -> None:
    """Reject a leader path that leaves ``W_f`` or comes closer than ``r`` + margin to ∂W_f.

    ``inflation``: the obstacles' margin ``m`` (``safety.inflation``): the path must then keep
    ``r + m + LEADER_PATH_MARGIN``. The message gives the point of the path where it happens
    and the clearance there.
    """
    line = LineString(path_xy)
    required = radius + inflation + LEADER_PATH_MARGIN
    if not free_space.covers(line):
        outside = line.difference(free_space)
        pt = outside.representative_point() if not outside.is_empty else Point(path_xy[0])
        raise ScenarioError(
            f"{where}: the leader's path leaves the free space near ({pt.x:.3f}, {pt.y:.3f})"
        )
    dist = float(line.distance(free_space.boundary))
    if dist < required:
        on_path, on_wall = nearest_points(line, free_space.boundary)
        needs = f"r + {LEADER_PATH_MARGIN}"
        if inflation > 0:
            needs = f"r + safety.inflation + {LEADER_PATH_MARGIN}"
        raise ScenarioError(
            f"{where}: the leader's path comes within {dist:.3f} m of an obstacle at "
            f"({on_path.x:.3f}, {on_path.y:.3f}) (wall point ({on_wall.x:.3f}, {on_wall.y:.3f})); "
            f"it needs at least {needs} = {required:.3f} m"
        )
