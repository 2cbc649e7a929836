"""A static uniform grid over the obstacle-boundary edges, so a query visits only nearby edges.

Sensing and the safety checks only care about boundary edges within the proximity range of a
follower and its line of sight. The grid lists, for every square cell, the edges whose bounding
box overlaps the cell (CSR layout: ``cell_start`` offsets into ``cell_edges``). A query for an
axis-aligned box gathers the edges registered in the cells the box overlaps, each edge once, so
the per-step cost depends on the local density of edges, not on the size of the map.

Exactness: the same compiled cell-index function registers edges and maps queries, and it is
monotone, so an edge whose bounding box overlaps the query box is always gathered. The kernels
then apply their own exact tests; culling never changes a result (the tests compare culled and
brute-force sensing against the shapely oracle).

The kernels read a workspace's boundary and its grid as one :class:`~platoon_env.records.Walls`
(all arrays contiguous, built once per workspace and read-only afterwards):

* ``edges`` ``(E, 4)`` ``[ax, ay, bx, by]`` and their bounding ``boxes`` ``(E, 4)``
  ``[x0, y0, x1, y1]``;
* ``grid``: a :data:`~platoon_env.records.MAP_INFO_DTYPE` record, read by name: the origin
  ``x0, y0`` [m], ``inv_cell`` = 1 / cell side [1/m] and the cells per axis ``nx, ny`` (and the
  sizes ``n_edges``, ``n_cells`` = ``nx * ny``, ``n_cell_edges``; ``n_path`` = 0 here);
* ``cell_start`` int64 ``(nx * ny + 1,)``; cell ``(i, j)`` is number ``j * nx + i``;
* ``cell_edges`` int64: edge indices, cell after cell;
* ``edge_cell`` int64 ``(E, 2)``: the lowest cell ``(i, j)`` of each edge's bounding box, used to
  report an edge once per query although it is registered in several cells.

:class:`EdgeGrid` keeps its own copy of the edges and their boxes, so that
:attr:`EdgeGrid.walls` is the whole argument of the kernels. The arrays are left writable (numba
types a read-only array argument through a slower path on every call) but are never written
after the build.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from platoon_env.geometry.primitives import (
    Box,
    Point,
    point_box_distance2,
    point_segment_distance2,
)
from platoon_env.records import MAP_INFO_DTYPE, Walls

#: Upper bound on the number of cells of a default grid (memory stays a few MB).
MAX_CELLS = 1 << 18


@njit(cache=True, inline="always")
def _cell_index(v: float, origin: float, inv_cell: float, n: int) -> int:
    """The cell index of coordinate ``v`` along one axis, clamped to ``[0, n - 1]`` (monotone)."""
    f = (v - origin) * inv_cell
    if f >= n:
        return n - 1
    if f >= 1.0:
        return int(f)
    return 0  # also for NaN


@njit(cache=True)
def cell_range(g: np.record, box: Box) -> tuple[int, int, int, int]:
    """Cells ``(i0, j0, i1, j1)`` (inclusive) of grid ``g`` overlapped by ``box``
    ``(x0, y0, x1, y1)``."""
    return (
        _cell_index(box[0], g.x0, g.inv_cell, g.nx),
        _cell_index(box[1], g.y0, g.inv_cell, g.ny),
        _cell_index(box[2], g.x0, g.inv_cell, g.nx),
        _cell_index(box[3], g.y0, g.inv_cell, g.ny),
    )


@njit(cache=True)
def grid_candidates(walls: Walls, box: Box, out: np.ndarray) -> int:
    """Write the edges registered in the cells overlapping ``box`` ``(x0, y0, x1, y1)`` to
    ``out``.

    Each edge is reported once: in the first query cell (lowest ``i``, then ``j``) that its own
    bounding box covers. Returns the number of edges written. ``out`` needs room for every edge.
    """
    i0, j0, i1, j1 = cell_range(walls.grid, box)
    nx = walls.grid.nx
    cell_start, cell_edges, edge_cell = walls.cell_start, walls.cell_edges, walls.edge_cell
    n = 0
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            c = j * nx + i
            for k in range(cell_start[c], cell_start[c + 1]):
                e = cell_edges[k]
                if (i == i0 or i == edge_cell[e, 0]) and (j == j0 or j == edge_cell[e, 1]):
                    out[n] = e
                    n += 1
    return n


@njit(cache=True)
def covers_grid(g: np.record, box: Box) -> bool:
    """Whether ``box`` overlaps every cell of grid ``g`` (a query over it gathers every edge)."""
    i0, j0, i1, j1 = cell_range(g, box)
    return i0 == 0 and j0 == 0 and i1 == g.nx - 1 and j1 == g.ny - 1


@njit(cache=True)
def nearest_edge_distance2(walls: Walls, p: Point, reach: float, cand: np.ndarray) -> float:
    """Squared distance from ``p`` to the nearest edge, known to be farther than ``reach``.

    Searches boxes of half-side ``2 reach, 4 reach, ...`` until the nearest edge found lies
    within the box's inscribed disk (then no edge outside can be nearer) or the box covers the
    grid. ``cand`` is scratch space for ``E`` indices. ``inf`` when there is no edge.
    """
    edges, boxes = walls.edges, walls.boxes
    px, py = p
    r = max(reach, 1e-6)
    best = math.inf
    for _ in range(128):
        r *= 2.0
        query = (px - r, py - r, px + r, py + r)
        n = grid_candidates(walls, query, cand)
        best = math.inf
        for k in range(n):
            e = cand[k]
            lb = point_box_distance2(p, (boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]))
            if lb < best:
                best = min(
                    best,
                    point_segment_distance2(
                        p, (edges[e, 0], edges[e, 1]), (edges[e, 2], edges[e, 3])
                    ),
                )
        if best <= r * r or covers_grid(walls.grid, query):
            return best
    # Unreachable for finite coordinates; a full scan keeps the result exact regardless.
    best = math.inf
    for e in range(edges.shape[0]):
        best = min(
            best, point_segment_distance2(p, (edges[e, 0], edges[e, 1]), (edges[e, 2], edges[e, 3]))
        )
    return best


@njit(cache=True)
def _build(boxes: np.ndarray, g: np.record) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    nx = g.nx
    ny = g.ny
    n_edges = boxes.shape[0]
    edge_cell = np.zeros((n_edges, 2), dtype=np.int64)
    counts = np.zeros(nx * ny + 1, dtype=np.int64)
    for e in range(n_edges):
        i0, j0, i1, j1 = cell_range(g, (boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]))
        edge_cell[e, 0] = i0
        edge_cell[e, 1] = j0
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                counts[j * nx + i + 1] += 1
    cell_start = np.cumsum(counts)
    fill = cell_start[:-1].copy()
    cell_edges = np.empty(cell_start[-1], dtype=np.int64)
    for e in range(n_edges):
        i0, j0, i1, j1 = cell_range(g, (boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]))
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                c = j * nx + i
                cell_edges[fill[c]] = e
                fill[c] += 1
    return cell_start, cell_edges, edge_cell


def edge_boxes(edges: np.ndarray) -> np.ndarray:
    """Bounding box ``[xmin, ymin, xmax, ymax]`` of every edge ``[ax, ay, bx, by]``."""
    edges = np.asarray(edges, dtype=np.float64).reshape(-1, 4)
    return np.ascontiguousarray(
        np.stack(
            [
                np.minimum(edges[:, 0], edges[:, 2]),
                np.minimum(edges[:, 1], edges[:, 3]),
                np.maximum(edges[:, 0], edges[:, 2]),
                np.maximum(edges[:, 1], edges[:, 3]),
            ],
            axis=1,
        )
    )


@dataclass(frozen=True, eq=False)
class EdgeGrid:
    """The static grid of a workspace's boundary edges (see the module docstring).

    Build it with :meth:`build`; pass :attr:`walls` to the compiled kernels. ``info`` is a
    ``(1,)`` :data:`~platoon_env.records.MAP_INFO_DTYPE` array (``n_path`` = 0).
    """

    edges: np.ndarray
    boxes: np.ndarray
    info: np.ndarray
    cell_start: np.ndarray
    cell_edges: np.ndarray
    edge_cell: np.ndarray

    @classmethod
    def build(
        cls, edges: np.ndarray, cell_size: float | None = None, *, reach: float = 4.0
    ) -> EdgeGrid:
        """Grid over ``edges`` ``(E, 4)`` with square cells of ``cell_size`` metres.

        ``cell_size=None`` picks ``reach / 2`` (``reach``: the typical query radius, e.g. the
        proximity range), enlarged if needed so that the grid has at most :data:`MAX_CELLS`
        cells. A non-positive ``cell_size`` gives a single cell (brute force).
        """
        edges = np.array(edges, dtype=np.float64).reshape(-1, 4)  # an own, writable copy
        boxes = edge_boxes(edges)
        if boxes.shape[0] == 0:
            x0 = y0 = 0.0
            width = height = 1.0
        else:
            x0, y0 = float(boxes[:, 0].min()), float(boxes[:, 1].min())
            width = max(float(boxes[:, 2].max()) - x0, 1e-9)
            height = max(float(boxes[:, 3].max()) - y0, 1e-9)
        if cell_size is None:
            if not reach > 0:
                raise ValueError(f"reach must be positive, got {reach}")
            cell_size = 0.5 * reach
            cell_size = max(cell_size, math.sqrt(width * height / MAX_CELLS))
        if cell_size <= 0:
            nx = ny = 1
            inv = 0.0
        else:
            nx = max(1, min(math.ceil(width / cell_size), MAX_CELLS))
            ny = max(1, min(math.ceil(height / cell_size), MAX_CELLS // nx))
            inv = 1.0 / cell_size
        info = np.zeros(1, dtype=MAP_INFO_DTYPE)
        g = info[0]
        g["x0"], g["y0"], g["inv_cell"], g["nx"], g["ny"] = x0, y0, inv, nx, ny
        cell_start, cell_edges, edge_cell = _build(boxes, g)
        g["n_edges"] = edges.shape[0]
        g["n_cells"] = nx * ny
        g["n_cell_edges"] = cell_edges.shape[0]
        g["n_path"] = 0
        return cls(edges, boxes, info, cell_start, cell_edges, edge_cell)

    @classmethod
    def single_cell(cls, edges: np.ndarray) -> EdgeGrid:
        """One cell holding every edge: queries return all edges (no culling)."""
        return cls.build(edges, cell_size=0.0)

    @property
    def walls(self) -> Walls:
        """The :class:`~platoon_env.records.Walls` of the kernels (views, no copy)."""
        return Walls(
            self.edges, self.boxes, self.info[0], self.cell_start, self.cell_edges, self.edge_cell
        )

    @property
    def shape(self) -> tuple[int, int]:
        """Number of cells ``(nx, ny)``."""
        return int(self.info[0]["nx"]), int(self.info[0]["ny"])

    @property
    def cell_size(self) -> float:
        """Side of a cell [m] (``inf`` for a single-cell grid)."""
        inv = float(self.info[0]["inv_cell"])
        return math.inf if inv == 0.0 else 1.0 / inv

    @property
    def n_edges(self) -> int:
        """Number of edges the grid indexes."""
        return int(self.edge_cell.shape[0])
