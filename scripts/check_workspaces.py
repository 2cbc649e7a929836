"""Check the shipped workspaces (study_a/b/c.yaml) and draw one PNG per study.

For each scenario file this script

* parses it with :func:`platoon_env.scenarios.schema.parse_scenario` (unknown keys, ranges),
* builds the free space with shapely (``free_space`` exterior/holes and/or ``bounds``, minus
  ``obstacles``) and checks that every polygon is valid and the free space is one piece,
* samples the leader path densely and measures its clearance to the obstacle boundary, the
  passage width across the path (perpendicular rays to the left and right), the stretches where
  a robot on the path has ``clearance - r < delta`` on *both* sides (where the PPC ``F_l`` and
  ``F_r`` terms engage together), and the path curvature,
* for a chain driving *on* the path with chord ``d_des`` between neighbours, measures the bearing
  ``|beta|`` a follower would see (angle between the path tangent and the chord to its
  predecessor) and the clearance of that line of sight,
* places the default initial configuration (DESIGN §5: last follower at the path's first point,
  consecutive robots ``d_des`` apart as chords, the leader furthest along) and checks its
  clearances, lines of sight and distances,
* simulates a pure-pursuit leader (lookahead and turn-rate bound from the file; an approximation
  of the env's leader, good enough to see how much it cuts corners) and reports its clearance and
  the run time,

then writes ``<outdir>/<name>.png``. The exit status is 1 if a hard requirement fails.

Usage::

    python scripts/check_workspaces.py [--outdir /tmp/workspaces] [scenario.yaml ...]

With no files, the three shipped studies are checked.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
import yaml
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union
from shapely.validation import explain_validity

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from platoon_env.scenarios.schema import ScenarioConfig, parse_scenario  # noqa: E402

DATA_DIR = REPO / "platoon_env" / "scenarios" / "data"
STUDIES = ("study_a", "study_b", "study_c")

PATH_MARGIN = 0.15  # [m] the leader path keeps clearance >= r + PATH_MARGIN
START_MARGIN = 0.10  # [m] robots of the initial configuration keep clearance >= r + START_MARGIN
SAMPLE_STEP = 0.02  # [m] spacing of the dense samples along the path
RAY_LENGTH = 10.0  # [m] perpendicular rays for the passage width are cut at this length


@dataclass
class Report:
    """Numbers measured on one scenario and the list of failed hard requirements."""

    name: str
    values: dict[str, str] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)

    def add(self, key: str, value: str) -> None:
        self.values[key] = value

    def require(self, ok: bool, message: str) -> None:
        if not ok:
            self.failures.append(message)


# --------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------


def build_free_space(cfg: ScenarioConfig, report: Report) -> shapely.Geometry:
    """``W_f``: (free_space polygon ∩ bounds box) minus the union of the obstacles."""
    ws = cfg.workspace
    parts: list[shapely.Geometry] = []
    if ws.free_space is not None:
        poly = Polygon(ws.free_space.exterior, list(ws.free_space.holes))
        report.require(poly.is_valid, f"free_space invalid: {explain_validity(poly)}")
        parts.append(poly)
    if ws.bounds is not None:
        parts.append(box(*ws.bounds))
    report.require(bool(parts), "workspace has neither bounds nor free_space")
    region = parts[0] if len(parts) == 1 else parts[0].intersection(parts[1])
    for k, coords in enumerate(ws.obstacles):
        obstacle = Polygon(coords)
        report.require(obstacle.is_valid, f"obstacles[{k}] invalid: {explain_validity(obstacle)}")
        report.require(obstacle.area > 0, f"obstacles[{k}] has zero area")
    if ws.obstacles:
        region = region.difference(unary_union([Polygon(c) for c in ws.obstacles]))
    report.require(region.is_valid, f"free space invalid: {explain_validity(region)}")
    pieces = list(getattr(region, "geoms", [region]))
    report.require(len(pieces) == 1, f"free space has {len(pieces)} disconnected pieces")
    n_edges = sum(len(ring.coords) - 1 for ring in _rings(region))
    report.add("free area", f"{region.area:.1f} m^2")
    report.add("boundary edges", str(n_edges))
    return region


def _rings(region: shapely.Geometry) -> list[shapely.LinearRing]:
    rings = []
    for poly in getattr(region, "geoms", [region]):
        rings.append(poly.exterior)
        rings.extend(poly.interiors)
    return rings


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


def place_initial(pts: np.ndarray, n_robots: int, chord: float) -> np.ndarray:
    """Robots on the path, last follower at its start, consecutive chords ``chord`` (tail first)."""
    out = [pts[0]]
    i = 0
    for _ in range(n_robots - 1):
        while i < len(pts) and np.hypot(*(pts[i] - out[-1])) < chord:
            i += 1
        if i >= len(pts):
            raise ValueError("path too short for the initial configuration")
        # refine between samples i-1 and i so that the chord is exact
        a, b = pts[i - 1], pts[i]
        lo, hi = 0.0, 1.0
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if np.hypot(*(a + mid * (b - a) - out[-1])) < chord:
                lo = mid
            else:
                hi = mid
        out.append(a + hi * (b - a))
    return np.array(out)


def simulate_pure_pursuit(
    pts: np.ndarray, s: np.ndarray, s0: float, cfg: ScenarioConfig, dt: float = 0.01
) -> np.ndarray:
    """Unicycle at constant speed steering at the path point ``lookahead`` ahead of its projection.

    Starts at arc length ``s0`` facing along the path; stops within ``speed * dt`` of the end.
    Returns the trajectory ``(n, 2)``.
    """
    lead = cfg.leader
    k0 = int(np.searchsorted(s, s0))
    pos = pts[k0].astype(float).copy()
    tan = tangents(pts)
    theta = math.atan2(tan[k0, 1], tan[k0, 0])
    k = k0
    traj = [pos.copy()]
    max_steps = int(10 * (s[-1] - s0) / lead.speed / dt) + 1000
    for _ in range(max_steps):
        lo, hi = k, min(len(pts), k + int(2.0 / SAMPLE_STEP))
        k = lo + int(np.argmin(np.hypot(*(pts[lo:hi] - pos).T)))
        if np.hypot(*(pts[-1] - pos)) < lead.speed * dt or k == len(pts) - 1:
            break
        target_s = s[k] + lead.lookahead
        if target_s >= s[-1]:
            target = pts[-1]
        else:
            target = pts[int(np.searchsorted(s, target_s))]
        alpha = math.atan2(target[1] - pos[1], target[0] - pos[0]) - theta
        alpha = (alpha + math.pi) % (2 * math.pi) - math.pi
        dist = max(np.hypot(*(target - pos)), 1e-6)
        omega = float(
            np.clip(
                2 * lead.speed * math.sin(alpha) / dist, -lead.max_turn_rate, lead.max_turn_rate
            )
        )
        if abs(omega) < 1e-9:
            pos += lead.speed * dt * np.array([math.cos(theta), math.sin(theta)])
        else:
            rad = lead.speed / omega
            pos += rad * np.array(
                [
                    math.sin(theta + omega * dt) - math.sin(theta),
                    -math.cos(theta + omega * dt) + math.cos(theta),
                ]
            )
        theta += omega * dt
        traj.append(pos.copy())
    return np.array(traj)


# --------------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------------


def check(path_yaml: Path, outdir: Path) -> Report:
    data = yaml.safe_load(path_yaml.read_text())
    cfg = parse_scenario(data)
    report = Report(cfg.name)
    free = build_free_space(cfg, report)
    boundary = free.boundary
    r = cfg.robot.radius
    n_f = cfg.followers
    d_des = cfg.formation.d_des
    beta_con = cfg.camera.half_angle
    delta = cfg.ppc.delta if cfg.ppc is not None else 0.0

    xmin, ymin, xmax, ymax = free.bounds
    report.add("map size", f"{xmax - xmin:.1f} x {ymax - ymin:.1f} m")

    raw = np.asarray(cfg.leader.path, dtype=float)
    seg_len = np.hypot(*np.diff(raw, axis=0).T)
    report.require(bool(np.all(seg_len > 1e-9)), "leader.path has repeated points")
    pts, s = resample(raw, SAMPLE_STEP)
    tan = tangents(pts)
    report.add("path length", f"{s[-1]:.2f} m ({len(raw)} points)")

    # --- clearance of the path itself
    inside = shapely.contains_xy(free, pts[:, 0], pts[:, 1])
    if not inside.all():
        report.failures.append(f"path leaves the free space near {pts[~inside][0]}")
    clearance = shapely.distance(boundary, shapely.points(pts))
    k_min = int(np.argmin(clearance))
    report.add(
        "min path clearance",
        f"{clearance[k_min]:.3f} m at s={s[k_min]:.2f} ({pts[k_min, 0]:.2f}, {pts[k_min, 1]:.2f})"
        f"; need >= r + {PATH_MARGIN} = {r + PATH_MARGIN:.2f}",
    )
    report.require(
        clearance[k_min] >= r + PATH_MARGIN - 1e-9,
        f"path clearance {clearance[k_min]:.3f} < r + {PATH_MARGIN} at s={s[k_min]:.2f}",
    )

    # --- passage width across the path and where F_l and F_r engage together
    sides = normal_ray_distances(free, pts, tan)
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

    # --- curvature: circle through each vertex and its two neighbours (exact on sampled arcs),
    # and the heading change at each vertex (a kink between long straights shows up there)
    a, b, c = raw[:-2], raw[1:-1], raw[2:]
    cross = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    sides_abc = np.hypot(*(b - a).T) * np.hypot(*(c - b).T) * np.hypot(*(c - a).T)
    kappa = 2.0 * cross / np.maximum(sides_abc, 1e-12)
    k_k = int(np.argmax(kappa)) if len(kappa) else 0
    report.add(
        "max curvature",
        f"{kappa[k_k]:.3f} 1/m (radius {1 / max(kappa[k_k], 1e-9):.2f} m) at "
        f"({b[k_k, 0]:.2f}, {b[k_k, 1]:.2f})"
        if len(kappa)
        else "0 (a single segment)",
    )
    seg_heading = np.unwrap(np.arctan2(*np.diff(raw, axis=0).T[::-1]))
    vertex_turn = np.degrees(np.abs(np.diff(seg_heading)))
    report.add(
        "max turn at a path vertex", f"{vertex_turn.max():.1f} deg" if len(vertex_turn) else "0"
    )

    # --- a chain driving on the path: bearing and line of sight of a follower d_des behind
    partner = chord_partner(pts, d_des)
    idx = np.nonzero(partner >= 0)[0]
    chords = pts[partner[idx]] - pts[idx]
    bearing = np.arctan2(chords[:, 1], chords[:, 0]) - np.arctan2(tan[idx, 1], tan[idx, 0])
    bearing = np.abs((bearing + np.pi) % (2 * np.pi) - np.pi)
    k_b = int(np.argmax(bearing))
    report.add(
        "max on-path bearing",
        f"{bearing[k_b]:.3f} rad at s={s[idx[k_b]]:.2f} (beta_con = {beta_con:.3f})",
    )
    report.require(
        bearing[k_b] < beta_con,
        f"a follower on the path would see its predecessor at {bearing[k_b]:.3f} rad >= beta_con",
    )
    sight = shapely.linestrings(np.stack([pts[idx], pts[partner[idx]]], axis=1))
    sight_clear = shapely.distance(boundary, sight)
    sight_clear[~shapely.within(sight, free)] = 0.0
    k_s = int(np.argmin(sight_clear))
    report.add(
        "min on-path line-of-sight clearance",
        f"{sight_clear[k_s]:.3f} m at s={s[idx[k_s]]:.2f} (chord {d_des} m)",
    )
    report.require(sight_clear[k_s] > 0.05, "a line of sight along the path touches an obstacle")

    # --- default initial configuration
    robots = place_initial(pts, n_f + 1, d_des)  # tail first, leader last
    s_leader0 = s[int(np.argmin(np.hypot(*(pts - robots[-1]).T)))]
    start_clear = shapely.distance(boundary, shapely.points(robots))
    report.add(
        "initial configuration",
        f"leader starts at s={s_leader0:.2f}; min robot clearance {start_clear.min():.3f} m "
        f"(need >= {r + START_MARGIN:.2f})",
    )
    report.require(
        bool(np.all(start_clear >= r + START_MARGIN))
        and bool(shapely.contains_xy(free, robots[:, 0], robots[:, 1]).all()),
        "a robot of the initial configuration is too close to an obstacle",
    )
    los = shapely.linestrings(np.stack([robots[:-1], robots[1:]], axis=1))
    los_clear = shapely.distance(boundary, los)
    report.require(
        bool(np.all(shapely.within(los, free))) and bool(np.all(los_clear > 0.05)),
        "a line of sight of the initial configuration touches an obstacle",
    )
    pair = np.hypot(*(robots[:, None, :] - robots[None, :, :]).transpose(2, 0, 1))
    pair[np.diag_indices(len(robots))] = np.inf
    report.require(pair.min() > cfg.safety.d_col, "two robots start closer than d_col")
    # bearing of follower i if it faced along the path tangent (it faces its predecessor in the
    # env, so this is only a measure of how straight the start stretch is)
    start_bearing = []
    for j in range(n_f):
        k = int(np.argmin(np.hypot(*(pts - robots[j]).T)))
        chord = robots[j + 1] - robots[j]
        angle = math.atan2(chord[1], chord[0]) - math.atan2(tan[k, 1], tan[k, 0])
        start_bearing.append(abs((angle + math.pi) % (2 * math.pi) - math.pi))
    report.add(
        "start stretch",
        f"max bearing w.r.t. path tangent {max(start_bearing):.3f} rad, "
        f"min line-of-sight clearance {los_clear.min():.3f} m",
    )
    report.require(max(start_bearing) < beta_con, "the start stretch is not straight enough")

    # --- pure-pursuit leader
    traj = simulate_pure_pursuit(pts, s, s_leader0, cfg)
    lead_clear = shapely.distance(boundary, shapely.points(traj))
    duration = (len(traj) - 1) * 0.01
    deviation = shapely.distance(LineString(raw), shapely.points(traj)).max()
    report.add(
        "pure-pursuit leader",
        f"run {duration:.1f} s at {cfg.leader.speed} m/s, min clearance {lead_clear.min():.3f} m, "
        f"max deviation from path {deviation:.3f} m",
    )
    report.require(
        lead_clear.min() >= r + PATH_MARGIN - 0.05,
        f"the pure-pursuit leader's clearance drops to {lead_clear.min():.3f} m",
    )

    draw(cfg, free, pts, both, robots, traj, clearance, report, outdir / f"{cfg.name}.png")
    return report


# --------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------


def draw(cfg, free, pts, both, robots, traj, clearance, report: Report, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Wedge
    from matplotlib.patches import Polygon as MplPolygon

    xmin, ymin, xmax, ymax = free.bounds
    pad = 0.5
    aspect = (ymax - ymin + 2 * pad) / (xmax - xmin + 2 * pad)
    fig, ax = plt.subplots(figsize=(12, max(4.0, 12 * aspect) + 1.2))
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
    # the band of width r along the boundary where a robot centre would collide (drawn before
    # the holes, which paint over the inside of the bands around inner obstacles)
    band = free.boundary.buffer(cfg.robot.radius).intersection(free)
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
    sc = ax.scatter(pts[:, 0], pts[:, 1], c=clearance, s=3, cmap="viridis", zorder=3)
    fig.colorbar(sc, ax=ax, shrink=0.6, label="path clearance [m]")
    ax.plot(*np.asarray(cfg.leader.path).T, "o", ms=2, color="tab:blue", zorder=4)
    ax.plot(
        traj[:, 0], traj[:, 1], "--", color="tab:red", lw=0.8, zorder=4, label="pure-pursuit leader"
    )
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
    r, beta, rng = cfg.robot.radius, cfg.camera.half_angle, cfg.camera.range
    for j, p in enumerate(robots):
        leader = j == len(robots) - 1
        ax.add_patch(Circle(p, r, color="tab:blue" if leader else "k", zorder=6))
        if not leader:
            head = math.degrees(math.atan2(*(robots[j + 1] - p)[::-1]))
            ax.add_patch(
                Wedge(
                    p,
                    rng,
                    head - math.degrees(beta),
                    head + math.degrees(beta),
                    color="tab:green",
                    alpha=0.12,
                    zorder=2,
                )
            )
            ax.plot(*np.stack([p, robots[j + 1]]).T, color="tab:green", lw=0.8, zorder=6)
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
        f"{cfg.name}: {report.values['path length']}, {report.values['pure-pursuit leader']}",
        f"min clearance {report.values['min path clearance']}",
        f"narrowest passage {report.values['narrowest passage']}; "
        f"max curvature {report.values['max curvature']}",
    ]
    ax.set_title("\n".join(lines), fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    report.add("png", str(out))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "files", nargs="*", type=Path, help="scenario files (default: the shipped study_a/b/c.yaml)"
    )
    parser.add_argument(
        "--outdir",
        type=Path,
        default=Path("/tmp/workspaces"),
        help="where the PNGs are written (default: /tmp/workspaces)",
    )
    args = parser.parse_args(argv)
    files = args.files or [DATA_DIR / f"{name}.yaml" for name in STUDIES]
    failed = False
    for f in files:
        report = check(f, args.outdir)
        print(f"== {report.name} ({f})")
        for key, value in report.values.items():
            print(f"   {key}: {value}")
        for message in report.failures:
            print(f"   FAIL: {message}")
        failed |= bool(report.failures)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
