r"""Plan study B's leader trajectory the way a navigation stack would, and write it as data.

The paper's study B (section 4.2) drove the leader with "the ROS Navigation Stack [45] to steer
the leader towards a predefined goal configuration", in Gazebo, with the obstacles "augmented
by 0.1 m" for safety. This script is a small, deterministic stand-in for that stack, in its two
classic layers:

1. **Global planner** (navfn / global_planner style). An occupancy grid of the workspace at
   :attr:`PlannerParams.resolution`; a cell is lethal when its centre lies outside ``W_f`` or
   within the *inflation radius* ``r_infl = r + safety_margin + path_margin`` of an obstacle
   boundary: the robot radius, the paper's 0.1 m, and the 0.05 m the env demands of a leader's
   path beyond ``r + safety.inflation``
   (:data:`~platoon_env.geometry.workspace.LEADER_PATH_MARGIN`), so that the plan is valid with
   ``safety.inflation: 0.1``. Free cells carry the inflation layer's cost
   ``1 + cost_weight exp(-cost_scaling (c - r_infl))`` (``c`` the cell's clearance), which keeps
   the path off walls where there is room (the middle of a corridor or a door). A* on the
   8-connected grid (no diagonal step past a lethal cell; step cost = length x mean cell cost,
   Euclidean heuristic, ties broken by insertion order, so the result is deterministic), then
   the grid path is simplified (Douglas-Peucker, :attr:`PlannerParams.simplify_tolerance`,
   keeping every segment at least ``r_infl`` from the boundary).
2. **Local planner**: :func:`platoon_env.scenarios.leader_planner.follow` (shared with the
   procedural ``paper`` tier's rooms layouts), a regulated pure pursuit (after Nav2's
   ``RegulatedPurePursuitController``) at :attr:`PlannerParams.period` (10 Hz) that slows down
   for the next *sharp* vertex (turn above :attr:`PlannerParams.sharp_turn`) and the goal,
   stops there and **turns in place**, within ``PlannerParams.speed``, ``turn_rate``,
   ``accel_max`` and ``alpha_max``.

The trajectory is sampled once per period, ``[t, x, y, theta]``, ``t`` from 0 at the leader's
start pose (at rest), and written as a YAML list with a header saying how it was made; the
global path is what ``study_b.yaml``'s ``leader.path`` holds (prefixed by the straight stretch on
which the followers stand behind the leader at the start, ``2 d_des`` long).

Usage::

    python scripts/plan_leader_trajectory.py   # writes data/trajectories/study_b_trajectory.yaml
    python scripts/plan_leader_trajectory.py --print-path      # also prints leader.path
    python scripts/plan_leader_trajectory.py --out /tmp/traj.yaml --scenario my_flat.yaml \
        --start 3.2 7.15 0 --goal 6.2 1.65 3.14159

Nothing is random: the same inputs give the same file.
"""

from __future__ import annotations

import argparse
import heapq
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry
from shapely.ops import nearest_points

from platoon_env.geometry.workspace import build_free_space
from platoon_env.scenarios.leader_planner import (
    Limits,
    PlannerParams,
    follow,
    sharp_vertices,
)
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.schema import ScenarioConfig

FloatArray = NDArray[np.float64]

#: The local planner's names, used here and by the tests through this script.
__all__ = ["Limits", "PlannerParams", "follow", "sharp_vertices"]

#: The checkout this script belongs to (the scenario data and docs it reads and writes).
REPO = Path(__file__).resolve().parents[1]
DATA_DIR = REPO / "platoon_env" / "scenarios" / "data"
DEFAULT_SCENARIO = DATA_DIR / "study_b.yaml"
#: Not in ``DATA_DIR`` itself: every ``*.yaml`` there is listed as a shipped scenario
#: (:func:`platoon_env.list_scenarios`), and a trajectory is not one.
DEFAULT_OUT = DATA_DIR / "trajectories" / "study_b_trajectory.yaml"

#: Study B's leader start pose ``(x, y, theta)``: in the living room, facing east, with the
#: two followers behind it on a 2 m straight (``leader.path`` begins there).
STUDY_B_START: tuple[float, float, float] = (3.2, 7.15, 0.0)
#: Study B's goal configuration: in the kitchen, facing west.
STUDY_B_GOAL: tuple[float, float, float] = (6.2, 1.65, math.pi)

#: decimals of ``t`` [s] and of ``x``, ``y`` [m], ``theta`` [rad] in the file (0.1 mm, 0.1 mrad:
#: the rounding changes a sampled speed by at most 0.0015 m/s).
TIME_DECIMALS = 2
POSE_DECIMALS = 4


# --------------------------------------------------------------------------------------------
# Global planner
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Grid:
    """The occupancy grid: cell ``(i, j)`` has its centre at ``(xs[i], ys[j])``."""

    xs: FloatArray
    ys: FloatArray
    clearance: FloatArray  # (nx, ny) [m] centre's distance to the boundary; 0 outside W_f
    lethal: NDArray[np.bool_]  # (nx, ny)
    cost: FloatArray  # (nx, ny) cost per metre (inf where lethal)

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        res = float(self.xs[1] - self.xs[0])
        i = round((x - self.xs[0]) / res)
        j = round((y - self.ys[0]) / res)
        return min(max(i, 0), len(self.xs) - 1), min(max(j, 0), len(self.ys) - 1)


def occupancy_grid(free_space: BaseGeometry, inflation: float, p: PlannerParams) -> Grid:
    """The inflated occupancy grid of ``free_space`` with the inflation-layer costs."""
    xmin, ymin, xmax, ymax = free_space.bounds
    res = p.resolution
    xs = xmin + res * (0.5 + np.arange(math.floor((xmax - xmin) / res)))
    ys = ymin + res * (0.5 + np.arange(math.floor((ymax - ymin) / res)))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    inside = shapely.contains_xy(free_space, gx, gy)
    clearance = np.where(inside, shapely.distance(free_space.boundary, shapely.points(gx, gy)), 0)
    lethal = ~inside | (clearance < inflation)
    cost = 1.0 + p.cost_weight * np.exp(-p.cost_scaling * (clearance - inflation))
    return Grid(xs, ys, clearance, lethal, np.where(lethal, np.inf, cost))


_MOVES = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]


def astar(grid: Grid, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]]:
    """The cheapest 8-connected cell path from ``start`` to ``goal`` (A*, deterministic)."""
    nx, ny = grid.lethal.shape
    for name, cell in (("start", start), ("goal", goal)):
        if grid.lethal[cell]:
            raise ValueError(f"the {name} cell {cell} is within the inflation radius of a wall")
    res = float(grid.xs[1] - grid.xs[0])
    cost = grid.cost
    lethal = grid.lethal
    gi, gj = goal
    best = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap: list[tuple[float, int, tuple[int, int]]] = [(0.0, 0, start)]
    counter = 0
    closed: set[tuple[int, int]] = set()
    while heap:
        _, _, cell = heapq.heappop(heap)
        if cell in closed:
            continue
        if cell == goal:
            break
        closed.add(cell)
        i, j = cell
        g = best[cell]
        for di, dj in _MOVES:
            a, b = i + di, j + dj
            if not (0 <= a < nx and 0 <= b < ny) or lethal[a, b]:
                continue
            if di and dj and (lethal[i + di, j] or lethal[i, j + dj]):
                continue  # no diagonal step past a lethal cell
            step = res * (math.sqrt(2.0) if di and dj else 1.0)
            g_new = g + step * 0.5 * (cost[i, j] + cost[a, b])
            if g_new < best.get((a, b), math.inf):
                best[(a, b)] = g_new
                parent[(a, b)] = cell
                counter += 1
                h = res * math.hypot(a - gi, b - gj)
                heapq.heappush(heap, (g_new + h, counter, (a, b)))
    if goal not in parent and goal != start:
        raise ValueError("no path: the goal is not reachable on the inflated grid")
    cells = [goal]
    while cells[-1] != start:
        cells.append(parent[cells[-1]])
    return cells[::-1]


def simplify(points: FloatArray, boundary: BaseGeometry, tol: float, clear: float) -> FloatArray:
    """Douglas-Peucker on ``points`` that also keeps every segment ``clear`` from ``boundary``."""
    keep = np.zeros(len(points), dtype=bool)
    keep[[0, -1]] = True
    stack = [(0, len(points) - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        pa, pb = points[a], points[b]
        d = pb - pa
        mid = points[a + 1 : b]
        dev = np.abs(d[0] * (mid[:, 1] - pa[1]) - d[1] * (mid[:, 0] - pa[0])) / max(
            float(np.hypot(*d)), 1e-12
        )
        k = a + 1 + int(np.argmax(dev))
        if dev.max() <= tol and LineString([pa, pb]).distance(boundary) >= clear:
            continue
        keep[k] = True
        stack.extend([(a, k), (k, b)])
    return points[keep]


def global_path(
    free_space: BaseGeometry,
    radius: float,
    start: tuple[float, float],
    goal: tuple[float, float],
    p: PlannerParams,
) -> FloatArray:
    """The simplified global path ``(M, 2)`` from ``start`` to ``goal`` (both exact)."""
    inflation = radius + p.safety_margin + p.path_margin
    grid = occupancy_grid(free_space, inflation, p)
    for name, (x, y) in (("start", start), ("goal", goal)):
        c = free_space.boundary.distance(Point(x, y))
        if not free_space.covers(Point(x, y)) or c < inflation:
            raise ValueError(f"the {name} ({x}, {y}) has clearance {c:.3f} < r_infl {inflation}")
    cells = astar(grid, grid.cell_of(*start), grid.cell_of(*goal))
    pts = np.array([[grid.xs[i], grid.ys[j]] for i, j in cells], dtype=np.float64)
    # the exact start and goal replace the cells within a lookahead of them (whose centres are
    # up to a cell off, and whose first steps follow the cost gradient away from a nearby wall:
    # both would make a jog of the path there)
    near = max(2.0 * p.resolution, p.lookahead)
    keep = (np.hypot(*(pts - start).T) > near) & (np.hypot(*(pts - goal).T) > near)
    pts = np.vstack([start, pts[keep], goal])
    return simplify(pts, free_space.boundary, p.simplify_tolerance, inflation)


# --------------------------------------------------------------------------------------------
# The plan for a scenario, and the file
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Plan:
    """The planner's output for one scenario."""

    path: FloatArray  # (M, 2) global path, leader start to goal
    platoon_path: FloatArray  # (M + 1, 2) the path with the platoon's start stretch in front
    trajectory: FloatArray  # (T, 4) [t, x, y, theta], rounded as written
    limits: Limits
    params: PlannerParams


def plan(
    cfg: ScenarioConfig,
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    p: PlannerParams | None = None,
) -> Plan:
    """Plan the leader of ``cfg`` from ``start`` to ``goal`` (poses ``(x, y, theta)``)."""
    p = p or PlannerParams()
    free = build_free_space(cfg.workspace)
    lim = Limits(
        speed=p.speed,
        turn_rate=p.turn_rate,
        accel=p.accel_max,
        alpha=p.alpha_max,
    )
    radius = float(cfg.robot.radius)
    path = global_path(free, radius, start[:2], goal[:2], p)
    traj = follow(path, start[2], goal[2], lim, p)
    need = radius + p.safety_margin + p.path_margin
    driven = LineString(traj[:, 1:3])
    if driven.distance(free.boundary) < need - 1e-9:
        near, _ = nearest_points(driven, free.boundary)
        raise RuntimeError(
            f"the local planner came within {driven.distance(free.boundary):.3f} m of a wall "
            f"near ({near.x:.3f}, {near.y:.3f}); the plan needs {need:.3f} m"
        )
    traj[:, 3] = np.arctan2(np.sin(traj[:, 3]), np.cos(traj[:, 3]))
    traj[:, 0] = np.round(traj[:, 0], TIME_DECIMALS)
    traj[:, 1:] = np.round(traj[:, 1:], POSE_DECIMALS)
    back = cfg.followers * float(cfg.formation.d_des)
    tail = np.array(start[:2]) - back * np.array([math.cos(start[2]), math.sin(start[2])])
    stretch = LineString([tail, start[:2]])
    if not free.covers(stretch) or stretch.distance(free.boundary) < need - 1e-9:
        raise ValueError(
            f"the platoon's start stretch {tail.round(3).tolist()} -> {list(start[:2])} comes "
            f"within {stretch.distance(free.boundary):.3f} m of a wall; it needs {need:.3f} m"
        )
    return Plan(path, np.vstack([tail, path]), traj, lim, p)


def _num(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def trajectory_yaml(result: Plan, command: str, scenario: str) -> str:
    """The file's text: a header of comments and the list of ``[t, x, y, theta]``."""
    traj, lim, p = result.trajectory, result.limits, result.params
    step = np.diff(traj, axis=0)
    speed = np.hypot(step[:, 1], step[:, 2]) / p.period
    rate = np.abs(np.arctan2(np.sin(step[:, 3]), np.cos(step[:, 3]))) / p.period
    settings = ", ".join(f"{k} = {v:g}" for k, v in asdict(p).items())
    tail = float(np.hypot(*(result.platoon_path[1] - result.platoon_path[0])))
    lines = [
        "# Study B's leader trajectory: [t, x, y, theta] in [s, m, m, rad], one sample every",
        f"# {p.period:g} s from t = 0 at the leader's start pose (at rest) to the goal (at rest).",
        "# Replayed exactly by leader.trajectory (linear interpolation of x, y and shortest-angle",
        "# interpolation of theta between samples).",
        "#",
        "# Made by a navigation-stack-like planner (the paper's study B, section 4.2, made its",
        "# leader's trajectory with the ROS Navigation Stack), deterministically, by",
        f"#   {command}",
        f"# from {scenario}",
        "# (its workspace, robot.radius, followers, d_des; speed and turn-rate limits below).",
        "# Global plan: A* on an occupancy grid inflated by r + 0.1 m (the paper's margin)",
        "# + 0.05 m (the env's margin for a leader's path), with an inflation-layer cost,",
        "# simplified by Douglas-Peucker. Local plan: a regulated pure pursuit that slows down",
        "# for the next sharp vertex and the goal and turns in place there.",
        "# See scripts/plan_leader_trajectory.py.",
        "# Settings:",
        *_wrapped(settings, "#   "),
        f"# Limits: speed <= {lim.speed:g} m/s, |omega| <= {lim.turn_rate:g} rad/s, "
        f"|du/dt| <= {lim.accel:g} m/s^2, |domega/dt| <= {lim.alpha:g} rad/s^2.",
        f"# Start {_pose(traj[0])}, goal {_pose(traj[-1])}. The leader's initial pose ends the",
        f"# {tail:g} m straight (followers x d_des) on which the followers stand at the start, the",
        "# first segment of the scenario's leader.path (the global plan).",
        f"# Result: {len(traj)} samples, {traj[-1, 0]:g} s, path "
        f"{float(np.sum(np.hypot(step[:, 1], step[:, 2]))):.2f} m; sampled max speed "
        f"{speed.max():.4f} m/s, max |omega| {rate.max():.4f} rad/s.",
    ]
    rows = [
        f"- [{_num(t, TIME_DECIMALS)}, {_num(x, POSE_DECIMALS)}, {_num(y, POSE_DECIMALS)}, "
        f"{_num(th, POSE_DECIMALS)}]"
        for t, x, y, th in traj
    ]
    return "\n".join([*lines, *rows]) + "\n"


def _pose(row: FloatArray) -> str:
    return f"({row[1]:.3f}, {row[2]:.3f}, {row[3]:.4f})"


def _wrapped(text: str, prefix: str, width: int = 96) -> list[str]:
    """``text``, a ``", "``-separated list, as comment lines of at most ``width`` characters."""
    out, line = [], prefix
    for item in text.split(", "):
        if len(line) + len(item) + 2 > width and line.strip("# "):
            out.append(line.rstrip())
            line = prefix
        line += item + ", "
    out.append(line.rstrip(", "))
    return out


def path_yaml(points: FloatArray) -> str:
    """``leader.path`` as YAML flow lists, one point a line (3 decimals)."""
    return "\n".join(f"    - [{_num(x, 3)}, {_num(y, 3)}]" for x, y in points)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default=str(DEFAULT_SCENARIO), help="scenario YAML")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="trajectory file to write")
    parser.add_argument("--start", type=float, nargs=3, default=STUDY_B_START, metavar="X")
    parser.add_argument("--goal", type=float, nargs=3, default=STUDY_B_GOAL, metavar="X")
    parser.add_argument(
        "--print-path", action="store_true", help="print leader.path (platoon stretch + plan)"
    )
    args = parser.parse_args(argv)
    cfg = load_config(args.scenario)
    result = plan(cfg, tuple(args.start), tuple(args.goal))
    command = "python scripts/plan_leader_trajectory.py" + "".join(
        f" {a}" for a in (argv if argv is not None else sys.argv[1:])
    )
    try:
        shown = Path(args.scenario).resolve().relative_to(REPO)
    except ValueError:
        shown = Path(args.scenario)
    args.out.write_text(trajectory_yaml(result, command, str(shown)))
    print(f"wrote {args.out}: {len(result.trajectory)} samples, {result.trajectory[-1, 0]:g} s")
    if args.print_path:
        print(path_yaml(result.platoon_path))
    return 0


if __name__ == "__main__":
    sys.exit(main())
