"""Check the shipped workspaces (study_a/b/c.yaml) and draw one PNG per study.

Every rule applied here is the library's own; the script only measures and draws. For each
scenario (a YAML file or a shipped name) it

* loads and builds it with :func:`platoon_env.scenarios.loader.load_config` and
  :func:`platoon_env.scenarios.scenario.build_scenario`, so every check of the loader applies
  (schema and ranges, valid polygons, a free space in one piece, the leader path's clearance of
  at least ``r + LEADER_PATH_MARGIN`` by :func:`platoon_env.geometry.workspace.check_leader_path`,
  a feasible default initial configuration); a rejected scenario is reported with the loader's
  message. A procedural scenario is checked on its layout 0
  (:func:`platoon_env.scenarios.procedural.generate_scenario`);
* samples the leader path densely and measures its clearance to the obstacle boundary, the
  passage width across the path (perpendicular rays to the left and right), the stretches where
  a robot on the path has ``clearance - r < delta`` on *both* sides (where the PPC ``F_l`` and
  ``F_r`` terms engage together), and the largest turn at a vertex;
* finds the path's *sharp corners* (vertices where the polyline turns by at least
  :data:`SHARP_CORNER_DEG`) and the passage width on either side of each, so that a corner
  inside a narrow passage is seen as one;
* for a follower standing *on* the path, facing along it, with its predecessor on the path a
  chord ``d_des`` ahead, senses the pair with the env's sensing
  (:func:`platoon_env.geometry.sensing.sense`: the bearing ``|beta|``, the line-of-sight
  clearances ``d_l``, ``d_r``) and applies the env's constraints to it
  (:func:`platoon_env.scenarios.scenario.initial_violations`, the rules the env checks after
  every sub-step): the violations a follower that *retraced the leader's path* at ``d_des``
  would commit. This is reported, not required: the studies' corners are sharp on purpose, and
  a follower does not retrace the path (it steers towards its predecessor and, under PPC, closes
  up where walls come near), so whether a map is feasible is shown by running the controllers;
* requires the same for a *closed-up* pair: the follower on the path facing its predecessor, a
  chord ``d_close`` ahead, where ``d_close = d_col + 2 rho_d_inf`` is the closest spacing the PPC
  distance funnel can demand (the least upper bound ``d_des + rho_d_hi``, ``rho_d_hi`` in its
  projection set) (``(d_col + d_des) / 2`` without a ``ppc`` block): a corner so tight that
  even a closed-up pair loses sight there on the path is rejected;
* takes the default initial configuration the library builds (``Scenario.initial_poses``), checks
  it with :func:`platoon_env.scenarios.scenario.initial_violations` and measures its clearances;
* drives the env's own leader: :func:`platoon_env.make` with ``terminate_on=()``, stepped with
  the followers standing still, reading ``env.poses[0]``; reports its run time, its clearance,
  how far it cuts corners and its tightest turn, and checks the driven trajectory with
  ``check_leader_path`` too;

then writes ``<outdir>/<name>.png``. The exit status is 1 if a requirement fails.

Usage::

    python scripts/check_workspaces.py [--outdir /tmp/workspaces] [scenario.yaml | name ...]

With no scenarios, the three shipped studies are checked.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import LineString, Point

import platoon_env
from experiments.report import markdown_table
from experiments.suites import STUDIES
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
    sense,
    sensing_params,
)
from platoon_env.geometry.workspace import LEADER_PATH_MARGIN, check_leader_path
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.procedural import generate_scenario
from platoon_env.scenarios.scenario import (
    Scenario,
    build_scenario,
    initial_violations,
)
from platoon_env.scenarios.schema import ScenarioError

#: The checkout this script belongs to (the scenario data and docs it reads and writes).
REPO = Path(__file__).resolve().parents[1]
DATA_DIR = REPO / "platoon_env" / "scenarios" / "data"

SAMPLE_STEP = 0.02  # [m] spacing of the dense samples along the path (measurement only)
RAY_LENGTH = 10.0  # [m] perpendicular rays for the passage width are cut at this length
#: [deg] a path vertex turning by at least this much is a sharp corner (reported)
SHARP_CORNER_DEG = 45.0
#: [m] the passage width at a corner is the narrowest one measured on the path between these
#: distances before and after the corner's vertex (on the legs: right at the vertex the
#: normals of the two legs would measure the diagonal)
CORNER_WIDTH_WINDOW = (0.3, 1.0)
#: [m] arc-length step at which the driven leader's turning radius is measured
TURN_STEP = 0.05
#: [deg] the studies' defining corner (the ``--tiers`` table): the leader's path turns by at
#: least this much ...
SHARP_TURN_DEG = 75.0
#: [m] ... within this much of path
SHARP_TURN_WINDOW = 0.6
#: [m] a *door* is a short gap in a wall: where the passage across the path is narrower by at
#: least DOOR_STEP than somewhere within DOOR_REACH before it and somewhere within DOOR_REACH
#: after it (so at most 2 DOOR_REACH long: walls are at most 0.3 m thick)
DOOR_STEP = 0.8
DOOR_REACH = 0.35
#: [m] ... and at least this long (the samples at a sharp vertex, whose tangent is neither
#: leg's, are not doors)
DOOR_MIN_LENGTH = 0.06
#: The generated blocks of docs/scenarios.md, each named by the command that writes it.
DOC = REPO / "docs" / "scenarios.md"
TIERS_COMMAND = "python scripts/check_workspaces.py --tiers"
#: Layouts per tier in the ``--tiers`` table (the test split's seeds 0 .. TIER_LAYOUTS - 1).
TIER_LAYOUTS = 50


@dataclass(frozen=True)
class Corner:
    """A sharp corner of the leader's path: a vertex and the passage width beside it."""

    x: float  # [m] the vertex
    y: float  # [m]
    s: float  # [m] arc length of the vertex along the path
    turn_deg: float  # [deg] heading change of the path at the vertex
    width: float  # [m] narrowest passage width on the legs within CORNER_WIDTH_WINDOW of it


@dataclass
class Report:
    """Numbers measured on one scenario and the list of failed requirements."""

    name: str
    values: dict[str, str] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    corners: list[Corner] = field(default_factory=list)
    #: The numbers of the README's scenario table (:func:`summary_table`), by column.
    numbers: dict[str, float] = field(default_factory=dict)

    def add(self, key: str, value: str) -> None:
        self.values[key] = value

    def require(self, ok: bool, message: str) -> None:
        if not ok:
            self.failures.append(message)


@dataclass
class LeaderRun:
    """The env's leader driven to the end of its path (followers standing still)."""

    trajectory: np.ndarray  # (T+1, 2) leader positions, one per control period
    arrival_time: float | None  # [s] sim time at which the leader reached the path's end


# --------------------------------------------------------------------------------------------
# Loading and driving, through the library
# --------------------------------------------------------------------------------------------


def load(source: str) -> tuple[Scenario, str]:
    """The built scenario of ``source`` (layout 0 if procedural) and a note on what it is."""
    cfg = load_config(source)
    if cfg.generator is None:
        return build_scenario(cfg), ""
    gen = cfg.generator
    return generate_scenario(cfg, 0), f"layout 0 of the {gen.kind} generator, {gen.split} split"


def drive_leader(scenario: Scenario) -> LeaderRun:
    """Step the env with every follower standing still and record the leader (``poses[0]``).

    ``terminate_on=()``: the followers' violations (they fall behind) do not end the episode,
    which ends by the env's own truncation (the leader's settle time, or the step limit). A
    procedural layout is passed as the fixed workspace it is (its config without the generator
    block, built on its free space), so that the env does not draw another layout on reset.
    """
    if scenario.config.generator is not None:
        fixed_cfg = dataclasses.replace(scenario.config, generator=None)
        scenario = build_scenario(fixed_cfg, free_space=scenario.free_space)
    env = platoon_env.make(scenario, terminate_on=(), perturb=False)
    env.reset(seed=0)
    still = {agent: np.zeros(2, dtype=np.float32) for agent in env.possible_agents}
    trajectory = [env.poses[0, :2]]
    arrival: float | None = None
    while env.agents:
        env.step(still)
        trajectory.append(env.poses[0, :2])
        if arrival is None and env.leader_arrived:
            arrival = env.sim_time
    env.close()
    return LeaderRun(np.asarray(trajectory), arrival)


# --------------------------------------------------------------------------------------------
# Measurements (geometry only: no rule is decided here)
# --------------------------------------------------------------------------------------------


def resample(path: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along the polyline and their arc lengths."""
    seg = np.diff(path, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    s = np.linspace(0.0, cum[-1], max(2, math.ceil(cum[-1] / step) + 1))
    pts = np.column_stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])])
    return pts, s


def tangents(pts: np.ndarray) -> np.ndarray:
    """Unit tangent at each sample (forward difference, last one repeated)."""
    d = np.diff(pts, axis=0)
    d = np.vstack([d, d[-1:]])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def normal_ray_distances(free: shapely.Geometry, pts: np.ndarray, tan: np.ndarray) -> np.ndarray:
    """Distance from each sample to the boundary along the left and right normals, ``(n, 2)``."""
    boundary = free.boundary
    normals = np.column_stack([-tan[:, 1], tan[:, 0]])
    out = np.full((len(pts), 2), RAY_LENGTH)
    for side, sign in enumerate((1.0, -1.0)):
        ends = pts + sign * RAY_LENGTH * normals
        rays = shapely.linestrings(np.stack([pts, ends], axis=1))
        hits = shapely.intersection(rays, boundary)
        for k, hit in enumerate(hits):
            if not hit.is_empty:
                out[k, side] = Point(pts[k]).distance(hit)
    return out


def chord_partner(pts: np.ndarray, chord: float) -> np.ndarray:
    """For each sample, the index of the first later sample at least ``chord`` away (or -1)."""
    out = np.full(len(pts), -1)
    j = 0
    for i in range(len(pts)):
        j = max(j, i)
        while j < len(pts) and np.hypot(*(pts[j] - pts[i])) < chord:
            j += 1
        if j < len(pts):
            out[i] = j
    return out


def sense_pairs(scenario: Scenario, followers: np.ndarray, predecessors: np.ndarray) -> np.ndarray:
    """The env's sensing (``SENSE_*`` columns) of each follower pose ``[x, y, theta]`` behind the
    predecessor position at the same row, ``(K, SENSE_SIZE)``.

    :func:`sense` senses a chain (row ``i`` behind row ``i - 1``); the pairs are interleaved as
    ``predecessor_0, follower_0, predecessor_1, ...`` and every other output row is kept.
    """
    cfg = scenario.config
    chain = np.zeros((2 * len(followers), 3))
    chain[0::2, :2] = predecessors
    chain[1::2] = followers
    sensors = sensing_params(
        d_con=cfg.camera.range,
        beta_con=cfg.camera.half_angle,
        proximity_range=cfg.proximity_range,
        proximity_half_angle=cfg.proximity_half_angle,
    )
    out = sense(chain, scenario.workspace.edges, sensors)
    return out[0::2]


def pair_problems(scenario: Scenario, follower: np.ndarray, predecessor: np.ndarray) -> list[str]:
    """The constraints a follower at pose ``follower`` violates behind a robot at
    ``predecessor`` (a configuration at rest, judged by the env's own rules)."""
    chain = np.array([[predecessor[0], predecessor[1], 0.0], follower], dtype=np.float64)
    return initial_violations(scenario.config, scenario.workspace, chain)


def sharp_corners(
    raw: np.ndarray, s: np.ndarray, pts: np.ndarray, width: np.ndarray
) -> list[Corner]:
    """The vertices of the polyline ``raw`` turning by at least :data:`SHARP_CORNER_DEG`, each
    with the narrowest of the passage widths ``width`` (measured at the samples ``pts``, arc
    lengths ``s``) on the legs within :data:`CORNER_WIDTH_WINDOW` of it."""
    seg = np.diff(raw, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(length)])
    out = []
    lo, hi = CORNER_WIDTH_WINDOW
    for k in range(1, len(raw) - 1):
        a, b = seg[k - 1], seg[k]
        if length[k - 1] == 0.0 or length[k] == 0.0:
            continue
        turn = abs(math.degrees(math.atan2(a[0] * b[1] - a[1] * b[0], float(np.dot(a, b)))))
        if turn < SHARP_CORNER_DEG - 1e-6:  # a 45.000 deg corner given to the mm is one
            continue
        gap = np.abs(s - cum[k])
        near = (gap >= lo) & (gap <= hi)
        w = float(width[near].min()) if near.any() else float("nan")
        out.append(Corner(float(raw[k, 0]), float(raw[k, 1]), float(cum[k]), turn, w))
    return out


def closest_spacing(scenario: Scenario) -> float:
    """``d_close``: the closest spacing the PPC distance funnel can demand, ``d_col + 2 rho_d_inf``
    (the least value of ``d_des + rho_d_hi`` over ``rho_d_hi``'s projection set), or
    ``(d_col + d_des) / 2`` when the scenario has no ``ppc`` block."""
    cfg = scenario.config
    if cfg.ppc is None:
        return 0.5 * (cfg.safety.d_col + cfg.formation.d_des)
    return cfg.safety.d_col + 2.0 * cfg.ppc.rho_d_inf


def tightest_turn(traj: np.ndarray) -> float:
    """The smallest turning radius [m] of a driven trajectory ``(T, 2)``: the largest heading
    change between its points resampled every :data:`TURN_STEP` metres of travel (a turn in
    place shows as a radius of at most ``TURN_STEP`` over its angle; 0 for 90 deg or more)."""
    step = np.hypot(*np.diff(traj, axis=0).T)
    keep = np.concatenate([[True], step > 1e-9])
    pts, _ = resample(traj[keep], TURN_STEP)
    d = np.diff(pts, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    turn = np.abs(np.diff(heading))
    if not len(turn) or turn.max() <= 0.0:
        return math.inf
    if turn.max() >= 0.5 * math.pi:
        return 0.0
    return float(TURN_STEP / turn.max())


def violation_summary(bad: list[tuple[float, list[str]]], total: int) -> str:
    """``"none"`` or how many of ``total`` samples violate, and the first one's problems."""
    if not bad:
        return "none"
    at, problems = bad[0]
    return f"{len(bad)} of {total} samples, first at s={at:.2f}: {'; '.join(problems)}"


def sharp_turns(path: np.ndarray) -> int:
    """How many times the polyline ``path`` turns by at least :data:`SHARP_TURN_DEG` within
    :data:`SHARP_TURN_WINDOW` of arc length (the studies' sharp corners; consecutive windows
    over one corner count once)."""
    step = np.hypot(*np.diff(path, axis=0).T)
    keep = np.concatenate([[True], step > 1e-9])  # a turn in place repeats the position
    pts, _ = resample(path[keep], SAMPLE_STEP)
    d = np.diff(pts, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    lag = round(SHARP_TURN_WINDOW / SAMPLE_STEP)
    if len(heading) <= lag:
        return 0
    sharp = np.abs(heading[lag:] - heading[:-lag]) >= math.radians(SHARP_TURN_DEG)
    return int(np.sum(sharp[1:] & ~sharp[:-1]) + sharp[0])


def door_samples(sides: np.ndarray) -> np.ndarray:
    """Which samples of the path (one every :data:`SAMPLE_STEP`, with their distances ``sides``
    ``(n, 2)`` to the walls along the left and right normals) are in a door: within
    :data:`DOOR_REACH` before it and within it after it the path is in the open on *both*
    sides (each normal longer than both of the door's by half of :data:`DOOR_STEP`, not only
    one of them, as beside the inside of a sharp corner), over at least
    :data:`DOOR_MIN_LENGTH`."""
    reach = round(DOOR_REACH / SAMPLE_STEP)
    open_both = sides.min(axis=1)
    narrow = sides.max(axis=1)
    n = len(sides)
    door = np.zeros(n, dtype=bool)
    for i in range(1, n - 1):
        before = open_both[max(0, i - reach) : i].max()
        after = open_both[i + 1 : i + reach + 1].max()
        door[i] = min(before, after) >= narrow[i] + 0.5 * DOOR_STEP
    edges = np.flatnonzero(np.diff(np.concatenate([[0], door.astype(int), [0]])))
    for a, b in zip(edges[0::2], edges[1::2], strict=True):  # runs door[a:b]
        if (b - a) * SAMPLE_STEP < DOOR_MIN_LENGTH - 1e-9:
            door[a:b] = False
    return door


@dataclass(frozen=True)
class LayoutProperties:
    """The studies' geometry measured on one workspace and leader path (the ``--tiers`` table)."""

    path_length: float  # [m]
    sharp_turns: int  # :func:`sharp_turns`
    passage_gap: float  # [m] narrowest passage across the path, outside doors, minus 2 r
    door_gap: float  # [m] narrowest door minus 2 r (nan: no door)
    obstacles: int  # free-standing obstacles (holes of W_f)


def layout_properties(scenario: Scenario) -> LayoutProperties:
    """:class:`LayoutProperties` of ``scenario``'s workspace and leader path."""
    raw = np.asarray(scenario.leader_path, dtype=float)
    step = np.hypot(*np.diff(raw, axis=0).T)
    raw = raw[np.concatenate([[True], step > 1e-9])]
    pts, s = resample(raw, SAMPLE_STEP)
    free = scenario.free_space
    sides = normal_ray_distances(free, pts, tangents(pts))
    width = sides.sum(axis=1)
    door = door_samples(sides)
    # Near a sharp vertex a normal ray can cut across the inside of the turn to the other leg's
    # wall: the passage is measured outside clearance * tan(|turn| / 2) of such vertices (the
    # reach of the inner wall corner along each leg, for a path on the passage's centre line).
    seg = np.diff(raw, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    turn = np.abs(np.diff(np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))))
    near_corner = np.zeros(len(s), dtype=bool)
    for k in np.flatnonzero(turn >= math.radians(SHARP_CORNER_DEG)) + 1:
        reach = free.boundary.distance(Point(raw[k])) * math.tan(0.5 * min(turn[k - 1], 2.2))
        near_corner |= np.abs(s - cum[k]) <= reach + 0.05
    diameter = 2.0 * scenario.config.robot.radius
    passage = ~door & ~near_corner
    holes = sum(len(g.interiors) for g in getattr(free, "geoms", [free]))
    return LayoutProperties(
        path_length=float(s[-1]),
        sharp_turns=sharp_turns(raw),
        passage_gap=float(width[passage].min()) - diameter,
        door_gap=float(width[door].min()) - diameter if door.any() else math.nan,
        obstacles=holes,
    )


# --------------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------------


def check(source: str, outdir: Path) -> Report:
    """Load ``source``, measure and check it (module doc) and draw ``outdir/<name>.png``."""
    report = Report(Path(source).stem)
    try:
        scenario, note = load(source)
    except ScenarioError as exc:
        report.failures.append(f"scenario rejected by the loader: {exc}")
        return report
    cfg = scenario.config
    report.name = cfg.name
    if note:
        report.add("procedural", note)
    measure_map(scenario, report)
    raw = np.asarray(scenario.leader_path, dtype=float)
    path = PathSamples.of(raw)
    report.add("path length", f"{scenario.path_s[-1]:.2f} m ({len(raw)} points)")
    clearance, width, both = measure_passages(scenario, path, report)
    measure_corners(raw, path, width, report)
    check_retraced_pairs(scenario, path, report)
    check_closed_up_pairs(scenario, path, report)
    check_initial_configuration(scenario, path, report)
    traj = check_env_leader(scenario, raw, report)
    draw(scenario, path.pts, both, traj, clearance, report, outdir / f"{cfg.name}.png")
    return report


@dataclass(frozen=True)
class PathSamples:
    """The leader path sampled every :data:`SAMPLE_STEP`: the points, their arc length ``s``,
    the unit tangents and the headings along the path."""

    pts: np.ndarray
    s: np.ndarray
    tan: np.ndarray
    heading: np.ndarray

    @classmethod
    def of(cls, raw: np.ndarray) -> PathSamples:
        """The samples of the path polyline ``raw``."""
        pts, s = resample(raw, SAMPLE_STEP)
        tan = tangents(pts)
        return cls(pts, s, tan, np.arctan2(tan[:, 1], tan[:, 0]))


def measure_map(scenario: Scenario, report: Report) -> None:
    """The free area, the boundary edges and the map's size."""
    free = scenario.free_space
    xmin, ymin, xmax, ymax = scenario.workspace.bounds
    report.add("free area", f"{free.area:.1f} m^2")
    report.add("boundary edges", str(len(scenario.workspace.edges)))
    report.numbers["edges"] = len(scenario.workspace.edges)
    report.add("map size", f"{xmax - xmin:.1f} x {ymax - ymin:.1f} m")


def measure_passages(
    scenario: Scenario, path: PathSamples, report: Report
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The path's clearance (the loader has checked it with ``check_leader_path``), the
    passage width across it and where ``F_l`` and ``F_r`` engage together (``clearance - r <
    delta`` on both sides); returns the clearance, the width and that mask per sample."""
    cfg, pts, s = scenario.config, path.pts, path.s
    r = cfg.robot.radius
    delta = cfg.ppc.delta if cfg.ppc is not None else 0.0
    clearance = shapely.distance(scenario.free_space.boundary, shapely.points(pts))
    k_min = int(np.argmin(clearance))
    report.add(
        "min path clearance",
        f"{clearance[k_min]:.3f} m at s={s[k_min]:.2f} ({pts[k_min, 0]:.2f}, {pts[k_min, 1]:.2f})"
        f"; need >= r + {LEADER_PATH_MARGIN} = {r + LEADER_PATH_MARGIN:.2f}",
    )
    sides = normal_ray_distances(scenario.free_space, pts, path.tan)
    width = sides.sum(axis=1)
    k_w = int(np.argmin(width))
    report.add(
        "narrowest passage",
        f"{width[k_w]:.3f} m at s={s[k_w]:.2f} ({pts[k_w, 0]:.2f}, {pts[k_w, 1]:.2f})",
    )
    both = (sides[:, 0] - r < delta) & (sides[:, 1] - r < delta)
    report.add(
        "path with clearance-r < delta on both sides",
        f"{both.sum() * SAMPLE_STEP:.1f} m (passage < 2(r+delta) = {2 * (r + delta):.2f} m)",
    )
    return clearance, width, both


def measure_corners(raw: np.ndarray, path: PathSamples, width: np.ndarray, report: Report) -> None:
    """The path's vertices: the largest turn and the sharp corners, with the passage width on
    the legs either side of each (a corner inside a narrow passage, or one in an open room)."""
    seg = np.diff(raw, axis=0)
    seg = seg[np.hypot(seg[:, 0], seg[:, 1]) > 0.0]
    seg_heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    vertex_turn = np.degrees(np.abs(np.diff(seg_heading)))
    report.add(
        "max turn at a path vertex", f"{vertex_turn.max():.1f} deg" if len(vertex_turn) else "0"
    )
    corners = sharp_corners(raw, path.s, path.pts, width)
    report.corners = corners
    report.add(
        f"sharp corners (turn >= {SHARP_CORNER_DEG:g} deg)",
        "; ".join(
            f"{c.turn_deg:.0f} deg at ({c.x:.2f}, {c.y:.2f}), passage {c.width:.2f} m"
            for c in corners
        )
        or "none",
    )


def check_retraced_pairs(scenario: Scenario, path: PathSamples, report: Report) -> None:
    """A follower on the path, facing along it, its predecessor a chord ``d_des`` ahead: the
    env's sensing (bearing ``|beta|``, line of sight ``min(d_l, d_r)``) and violation rules
    (reported, not required)."""
    cfg, pts, s = scenario.config, path.pts, path.s
    d_des = cfg.formation.d_des
    partner = chord_partner(pts, d_des)
    idx = np.nonzero(partner >= 0)[0]
    on_path = np.column_stack([pts[idx], path.heading[idx]])
    sensed = sense_pairs(scenario, on_path, pts[partner[idx]])
    bearing = np.abs(sensed[:, SENSE_BETA])
    k_b = int(np.argmax(bearing))
    report.add(
        "max on-path bearing",
        f"{bearing[k_b]:.3f} rad at s={s[idx[k_b]]:.2f} (beta_con = {cfg.camera.half_angle:.3f})",
    )
    sight = np.minimum(sensed[:, SENSE_D_SIGHT_LEFT], sensed[:, SENSE_D_SIGHT_RIGHT])
    k_s = int(np.argmin(sight))
    report.add(
        "min on-path line-of-sight clearance min(d_l, d_r)",
        f"{sight[k_s]:.3f} m at s={s[idx[k_s]]:.2f} (chord {d_des} m)",
    )
    bad = [
        (float(s[k]), problems)
        for k, pose in zip(idx, on_path, strict=True)
        if (problems := pair_problems(scenario, pose, pts[partner[k]]))
    ]
    report.add(
        f"a follower retracing the path {d_des} m behind (reported, not required)",
        violation_summary(bad, len(idx)),
    )


def check_closed_up_pairs(scenario: Scenario, path: PathSamples, report: Report) -> None:
    """A closed-up pair on the path, the follower facing its predecessor a chord ``d_close``
    ahead (:func:`closest_spacing`): required to commit no violation."""
    pts, s = path.pts, path.s
    d_close = closest_spacing(scenario)
    partner = chord_partner(pts, d_close)
    idx = np.nonzero(partner >= 0)[0]
    ahead = pts[partner[idx]] - pts[idx]
    facing = np.column_stack([pts[idx], np.arctan2(ahead[:, 1], ahead[:, 0])])
    bad = [
        (float(s[k]), problems)
        for k, pose in zip(idx, facing, strict=True)
        if (problems := pair_problems(scenario, pose, pts[partner[k]]))
    ]
    summary = violation_summary(bad, len(idx))
    report.add(f"a closed-up pair on the path, {d_close:.2f} m apart", summary)
    if bad:
        report.failures.append(
            f"a follower on the path facing its predecessor {d_close:.2f} m ahead (the closest "
            f"spacing the PPC funnel allows) violates a constraint ({summary})"
        )


def check_initial_configuration(scenario: Scenario, path: PathSamples, report: Report) -> None:
    """The default initial configuration (leader first), as the library builds it: feasible
    (required), its clearances, and how straight the start stretch is."""
    cfg, pts = scenario.config, path.pts
    poses = np.asarray(scenario.initial_poses)
    problems = initial_violations(cfg, scenario.workspace, poses)
    for problem in problems:
        report.failures.append(f"initial configuration: {problem}")
    start = sense_pairs(scenario, poses[1:], poses[:-1, :2])
    robot_clear = [scenario.workspace.clearance(*poses[0, :2]), *start[:, SENSE_CLEARANCE]]
    start_sight = np.minimum(start[:, SENSE_D_SIGHT_LEFT], start[:, SENSE_D_SIGHT_RIGHT])
    report.add(
        "initial configuration",
        f"{'feasible' if not problems else 'INFEASIBLE'}; leader starts at "
        f"s={scenario.initial_progress:.2f}; min robot clearance {min(robot_clear):.3f} m "
        f"(need > r = {cfg.robot.radius:.2f})",
    )
    # bearing of follower i if it faced along the path tangent (it faces its predecessor, so
    # this only measures how straight the start stretch is)
    nearest = [int(np.argmin(np.hypot(*(pts - p[:2]).T))) for p in poses[1:]]
    along = np.column_stack([poses[1:, :2], path.heading[nearest]])
    start_bearing = np.abs(sense_pairs(scenario, along, poses[:-1, :2])[:, SENSE_BETA])
    report.add(
        "start stretch",
        f"max bearing w.r.t. path tangent {start_bearing.max():.3f} rad, "
        f"min line-of-sight clearance min(d_l, d_r) {start_sight.min():.3f} m",
    )


def check_env_leader(scenario: Scenario, raw: np.ndarray, report: Report) -> np.ndarray:
    """The env's leader driven to its path's end (required to arrive, its trajectory checked
    with ``check_leader_path``): run time, clearance, corner cutting, tightest turn; returns
    the trajectory."""
    cfg = scenario.config
    boundary = scenario.free_space.boundary
    run = drive_leader(scenario)
    traj = run.trajectory
    lead_clear = shapely.distance(boundary, shapely.points(traj))
    deviation = shapely.distance(LineString(raw), shapely.points(traj)).max()
    if run.arrival_time is None:
        report.failures.append("the env's leader did not reach the end of its path")
    driven = "did not arrive" if run.arrival_time is None else f"run {run.arrival_time:.1f} s"
    report.numbers["path"] = float(scenario.path_s[-1] - scenario.initial_progress)
    report.numbers["run"] = math.nan if run.arrival_time is None else float(run.arrival_time)
    report.numbers["radius"] = float(tightest_turn(traj))
    report.add(
        "env leader",
        f"{driven} at {cfg.leader.speed} m/s, min clearance {lead_clear.min():.3f} m, "
        f"max deviation from path {deviation:.3f} m, tightest turn: radius "
        f"{tightest_turn(traj):.2f} m",
    )
    try:
        check_leader_path(
            scenario.free_space, traj, cfg.robot.radius, where="the env's leader as driven"
        )
    except ScenarioError as exc:
        report.failures.append(str(exc))
    return traj


# --------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------


def draw(
    scenario: Scenario,
    pts: np.ndarray,
    both: np.ndarray,
    traj: np.ndarray,
    clearance: np.ndarray,
    report: Report,
    out: Path,
) -> None:
    """Draw ``scenario`` to ``out``: the workspace, the path sampled at ``pts`` coloured by its
    ``clearance`` (``both``: where ``F_l`` and ``F_r`` engage together), the env leader's
    trajectory ``traj`` and the initial configuration, titled with ``report``'s numbers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xmin, ymin, xmax, ymax = scenario.workspace.bounds
    pad = 0.5
    aspect = (ymax - ymin + 2 * pad) / (xmax - xmin + 2 * pad)
    fig, ax = plt.subplots(figsize=(12, max(4.0, 12 * aspect) + 1.2))
    draw_workspace(ax, scenario, pad)
    sc = ax.scatter(pts[:, 0], pts[:, 1], c=clearance, s=3, cmap="viridis", zorder=3)
    fig.colorbar(sc, ax=ax, shrink=0.6, label="path clearance [m]")
    ax.plot(*np.asarray(scenario.leader_path).T, "o", ms=2, color="tab:blue", zorder=4)
    ax.plot(traj[:, 0], traj[:, 1], "--", color="tab:red", lw=0.8, zorder=4, label="env leader")
    if both.any():
        ax.plot(
            pts[both, 0],
            pts[both, 1],
            "s",
            ms=3,
            color="orange",
            zorder=5,
            label="clearance - r < delta on both sides",
        )
    draw_initial_configuration(ax, scenario)
    ax.annotate("start", pts[0], xytext=(5, -12), textcoords="offset points")
    ax.annotate("end", pts[-1], xytext=(5, 5), textcoords="offset points")
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xticks(np.arange(math.floor(xmin), math.ceil(xmax) + 1, 1.0), minor=True)
    ax.set_yticks(np.arange(math.floor(ymin), math.ceil(ymax) + 1, 1.0), minor=True)
    ax.grid(which="both", lw=0.2, color="0.8")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.06), ncol=3, fontsize=8)
    lines = [
        f"{scenario.config.name}: {report.values['path length']}, "
        f"leader {report.values['env leader']}",
        f"min clearance {report.values['min path clearance']}",
        f"narrowest passage {report.values['narrowest passage']}; "
        f"{len(report.corners)} sharp corners (>= {SHARP_CORNER_DEG:g} deg), "
        f"max turn at a vertex {report.values['max turn at a path vertex']}",
    ]
    ax.set_title("\n".join(lines), fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    report.add("png", str(out))


def draw_workspace(ax: Any, scenario: Scenario, pad: float) -> None:
    """The obstacles (grey, ``pad`` beyond the bounds), the free space (white) and the band of
    width ``r`` along its boundary where a robot centre would collide (pink)."""
    from matplotlib.patches import Polygon as MplPolygon

    free = scenario.free_space
    xmin, ymin, xmax, ymax = scenario.workspace.bounds
    ax.add_patch(
        MplPolygon(
            [
                (xmin - pad, ymin - pad),
                (xmax + pad, ymin - pad),
                (xmax + pad, ymax + pad),
                (xmin - pad, ymax + pad),
            ],
            color="0.55",
        )
    )
    polys = list(getattr(free, "geoms", [free]))
    for poly in polys:
        ax.add_patch(MplPolygon(np.asarray(poly.exterior.coords), color="white"))
    # the band is drawn before the holes, which paint over the inside of the bands around
    # inner obstacles
    band = free.boundary.buffer(scenario.config.robot.radius).intersection(free)
    for g in getattr(band, "geoms", [band]):
        if g.geom_type == "Polygon":
            ax.add_patch(MplPolygon(np.asarray(g.exterior.coords), color="#f4d0d0", lw=0))
            for hole in g.interiors:
                ax.add_patch(MplPolygon(np.asarray(hole.coords), color="white", lw=0))
    for poly in polys:
        for hole in poly.interiors:
            ax.add_patch(
                MplPolygon(np.asarray(hole.coords), facecolor="0.55", edgecolor="k", lw=0.6)
            )
        ax.plot(*poly.exterior.xy, color="k", lw=0.8)


def draw_initial_configuration(ax: Any, scenario: Scenario) -> None:
    """The default initial configuration, leader first; each follower's field of view about
    its heading and its line of sight to its predecessor."""
    from matplotlib.patches import Circle, Wedge

    cfg = scenario.config
    poses = np.asarray(scenario.initial_poses)
    r, beta, rng = cfg.robot.radius, cfg.camera.half_angle, cfg.camera.range
    for i, (x, y, theta) in enumerate(poses):
        ax.add_patch(Circle((x, y), r, color="tab:blue" if i == 0 else "k", zorder=6))
        if i == 0:
            continue
        head = math.degrees(theta)
        ax.add_patch(
            Wedge(
                (x, y),
                rng,
                head - math.degrees(beta),
                head + math.degrees(beta),
                color="tab:green",
                alpha=0.12,
                zorder=2,
            )
        )
        ax.plot(*np.stack([poses[i, :2], poses[i - 1, :2]]).T, color="tab:green", lw=0.8, zorder=6)


# --------------------------------------------------------------------------------------------
# The tiers' table (--tiers): the studies' geometry measured on every tier and every study
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Measured:
    """One layout (or study) with its properties and, for a tier with the studies' geometry,
    the ideal PPC's episode on it."""

    name: str  # scenario
    seed: int  # the episode's seed (a procedural test split: it draws the layout)
    layout: int | None  # the layout number drawn (None: a study)
    properties: LayoutProperties
    turn_radius: float  # [m] the leader's tightest turn (tightest_turn)
    success: (
        bool | None
    )  # the ideal PPC's episode: the leader arrived, no violation (None: not run)
    failure: str  # its first violation: cause, robot, time and place ("" on success)


def measure(job: tuple[str, int, bool]) -> Measured:
    """Measure ``platoon_env.make(name)`` after ``reset(seed)``.

    With ``ppc``, run the ideal PPC (:class:`baselines.PPCPolicy`) from there with
    ``terminate_on=()`` (so that the leader always drives to its end: its turning radius is the
    driven one; ``success`` is still the first violation's absence). Without, the turning radius
    is the driven leader's for a study (:func:`drive_leader`) and the leader path's own for a
    procedural layout (whose rounded arcs pure pursuit follows).
    """
    from baselines import PPCPolicy
    from platoon_env.rollout import episode_metrics, run_episode

    name, seed, ppc = job
    env = platoon_env.make(name, terminate_on=())
    env.reset(seed=seed)
    scenario = env.scenario
    success: bool | None = None
    failure = ""
    if ppc:
        episode = run_episode(env, PPCPolicy(env), seed=seed, record_signals=False)
        if episode.first_violation is not None:
            step, cause, robot = episode.first_violation
            x, y, _ = episode.poses[step + 1, robot]
            t = episode.times[step + 1]
            failure = f"{cause} (follower {robot}, t = {t:.1f} s, at {x:.2f}, {y:.2f})"
        radius = tightest_turn(episode.poses[:, 0, :2])
        success = bool(episode_metrics(episode)["success"])
    elif env.layout_index is None:
        radius = tightest_turn(drive_leader(scenario).trajectory)
    else:
        radius = tightest_turn(np.asarray(scenario.leader_path))
    measured = Measured(
        name=name,
        seed=seed,
        layout=env.layout_index,
        properties=layout_properties(scenario),
        turn_radius=radius,
        success=success,
        failure=failure,
    )
    env.close()
    return measured


def generation_ms(names: list[str], layouts: int) -> dict[str, float]:
    """The median time [ms] to generate one of the first ``layouts`` layouts of each of
    ``names``, the scenarios taken in turn for each layout number (so that a changing load on
    the machine weighs on all alike)."""
    import time

    templates = {name: load_config(name) for name in names}
    times: dict[str, list[float]] = {name: [] for name in names}
    for template in templates.values():
        generate_scenario(template, layouts)  # warm up
    for k in range(layouts):
        for name, template in templates.items():
            start = time.perf_counter()
            generate_scenario(template, k)
            times[name].append(time.perf_counter() - start)
    return {name: 1000.0 * float(np.median(t)) for name, t in times.items()}


def _spread(values: list[float], digits: int = 2) -> str:
    """``min / median / max`` of ``values`` (``-`` when none)."""
    v = np.asarray([x for x in values if not math.isnan(x)])
    if not len(v):
        return "-"
    lo, mid, hi = np.min(v), np.median(v), np.max(v)
    if lo == hi:
        return f"{lo:.{digits}f}"
    return f"{lo:.{digits}f} / {mid:.{digits}f} / {hi:.{digits}f}"


def tiers_table(layouts: int, workers: int) -> str:
    """The ``--tiers`` block: per tier (seeds ``0 .. layouts - 1`` of its test split) and per
    study its measured geometry and the median generation time of a layout; for the tiers with
    the studies' geometry (:data:`~platoon_env.scenarios.procedural.SHARP_TIERS`) the ideal
    PPC's success on every layout. Markdown."""
    from multiprocessing import Pool

    from platoon_env.scenarios.procedural import SHARP_TIERS
    from platoon_env.scenarios.schema import GENERATOR_TIERS

    rows = [(tier, f"procedural_{tier}_test", layouts) for tier in GENERATOR_TIERS]
    rows += [(name, name, 1) for name in STUDIES]
    jobs = [(name, seed, label in SHARP_TIERS) for label, name, n in rows for seed in range(n)]
    with Pool(workers) as pool:
        results = pool.map(measure, jobs, chunksize=1)
    generation = generation_ms([name for label, name, _ in rows if label not in STUDIES], layouts)
    by_name: dict[str, list[Measured]] = {}
    for m in results:
        by_name.setdefault(m.name, []).append(m)
    lines = [
        f"| tier or study | layouts | sharp corners (>= {SHARP_TURN_DEG:g} deg within "
        f"{SHARP_TURN_WINDOW:g} m) per 10 m | narrowest passage - 2r [m] | narrowest door - 2r "
        "[m] | leader's tightest turn radius [m] | free-standing obstacles | ideal PPC success "
        "| median generation [ms] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    failures = []
    for label, name, n in rows:
        ms = by_name[name]
        props = [m.properties for m in ms]
        study = label in STUDIES
        ran = [m.success for m in ms if m.success is not None]
        lines.append(
            "| "
            + " | ".join(
                [
                    f"`{label}`",
                    "the map" if study else f"{len({m.layout for m in ms})} (seeds 0-{n - 1})",
                    _spread([10.0 * q.sharp_turns / q.path_length for q in props], 1),
                    _spread([q.passage_gap for q in props]),
                    _spread([q.door_gap for q in props]),
                    _spread([m.turn_radius for m in ms]),
                    _spread([float(q.obstacles) for q in props], 0),
                    f"{sum(ran)}/{len(ran)}" if ran else "-",
                    "-" if study else f"{generation[name]:.1f}",
                ]
            )
            + " |"
        )
        failures += [
            f"- `{name}` seed {m.seed} (layout {m.layout}): {m.failure}"
            for m in ms
            if m.success is False
        ]
    notes = [
        "",
        "Each cell is min / median / max over the layouts (one value: all equal). The leader's "
        "turn radius is the driven leader's for the studies and the tiers the PPC ran on (a "
        "turn in place shows as a radius below 0.1 m), the leader path's arcs for the others. "
        "The generation time is that of `generate_scenario` on the machine the command ran on, "
        "the tiers taken in turn for each layout number.",
    ]
    if failures:
        notes += ["", "Episodes the ideal PPC failed (first violation):", "", *failures]
    return "\n".join(lines + notes)


def rewrite_block(doc: Path, command: str, text: str) -> None:
    """Replace the text between ``<!-- begin: {command} -->`` and the next ``<!-- end -->`` of
    ``doc`` by ``text`` (``ValueError`` if the markers are missing)."""
    begin, end = f"<!-- begin: {command} -->", "<!-- end -->"
    content = doc.read_text()
    head, sep, rest = content.partition(begin)
    if not sep or end not in rest:
        raise ValueError(f"{doc}: no block {begin} ... {end}")
    tail = rest.split(end, 1)[1]
    doc.write_text(f"{head}{begin}\n{text}\n{end}{tail}")


def summary_table(reports: list[Report]) -> str:
    """The README's table of the checked scenarios: obstacle boundary edges, the leader path
    ahead of the leader's start, the env leader's run time, its tightest turn radius as driven
    and the path's sharp corners (turns of at least :data:`SHARP_CORNER_DEG`)."""
    header = [
        "scenario",
        "boundary edges",
        "leader path from its start [m]",
        "leader's run time [s]",
        "tightest turn radius as driven [m]",
        f"sharp corners (≥ {SHARP_CORNER_DEG:g}°)",
    ]
    rows = []
    for rep in reports:
        n = rep.numbers
        if not {"edges", "path", "run", "radius"} <= n.keys():
            rows.append((f"`{rep.name}`", "–", "–", "–", "–", "–"))  # rejected: see stderr
            continue
        rows.append(
            (
                f"`{rep.name}`",
                int(n["edges"]),
                f"{n['path']:.1f}",
                f"{n['run']:.1f}",
                f"{n['radius']:.2f}",
                len(rep.corners),
            )
        )
    return markdown_table(header, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "files",
        nargs="*",
        help="scenario files or shipped names (default: the shipped study_a/b/c.yaml); a "
        "procedural scenario is checked on its layout 0",
    )
    parser.add_argument(
        "--outdir",
        type=Path,
        default=Path("/tmp/workspaces"),
        help="where the PNGs are written (default: /tmp/workspaces)",
    )
    parser.add_argument(
        "--tiers",
        action="store_true",
        help=f"measure every generator tier ({TIER_LAYOUTS} test layouts each; the ideal PPC on "
        f"each of the sharp and paper tiers') and the studies, and rewrite the block of "
        f"{DOC.relative_to(REPO)} named '{TIERS_COMMAND}'",
    )
    parser.add_argument(
        "--workers", type=int, default=2, help="episodes run at once for --tiers (default 2)"
    )
    parser.add_argument(
        "--table",
        action="store_true",
        help="print only the README's scenario table of the checked scenarios (edges, leader "
        "path, run time, tightest turn, sharp corners); the exit status is still 1 if a "
        "requirement fails",
    )
    args = parser.parse_args(argv)
    if args.tiers:
        table = tiers_table(TIER_LAYOUTS, args.workers)
        rewrite_block(DOC, TIERS_COMMAND, table)
        print(table)
        return 0
    files = args.files or [str(DATA_DIR / f"{name}.yaml") for name in STUDIES]
    failed = False
    reports = []
    for f in files:
        report = check(f, args.outdir)
        reports.append(report)
        failed |= bool(report.failures)
        if args.table:
            continue
        print(f"== {report.name} ({f})")
        for key, value in report.values.items():
            print(f"   {key}: {value}")
        for message in report.failures:
            print(f"   FAIL: {message}")
    if args.table:
        print(summary_table(reports))
        for report in reports:
            for message in report.failures:
                print(f"{report.name}: FAIL: {message}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
