"""The study maps' intended properties (the header comments of study_a/b/c.yaml), and the study B
leader planner (scripts/plan_leader_trajectory.py): deterministic, within the robot's limits.

The measurements are those of ``scripts/check_workspaces.py`` (imported, one source of truth).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import shapely
import yaml
from shapely.geometry import LineString, Point, Polygon

import platoon_env
from platoon_env.scenarios import ScenarioError, load_scenario
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.scenario import initial_violations

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "platoon_env" / "scenarios" / "data"
TRAJECTORY = DATA / "trajectories" / "study_b_trajectory.yaml"


def _script(name: str) -> ModuleType:
    """Import ``scripts/<name>.py`` as a module (the scripts are not a package)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


cw = _script("check_workspaces")
planner = _script("plan_leader_trajectory")


def corners_of(name: str) -> list:
    """The sharp corners (turn >= 45 deg) of a study's leader path, with passage widths."""
    sc = load_scenario(name)
    raw = np.asarray(sc.leader_path, dtype=float)
    pts, s = cw.resample(raw, cw.SAMPLE_STEP)
    width = cw.normal_ray_distances(sc.free_space, pts, cw.tangents(pts)).sum(axis=1)
    return cw.sharp_corners(raw, s, pts, width)


def passage_widths(name: str) -> np.ndarray:
    """The passage width across the leader path at every sample."""
    sc = load_scenario(name)
    pts, _ = cw.resample(np.asarray(sc.leader_path, dtype=float), cw.SAMPLE_STEP)
    return cw.normal_ray_distances(sc.free_space, pts, cw.tangents(pts)).sum(axis=1)


def driven_leader(name: str, **overrides: object) -> np.ndarray:
    """The env's leader driven to its end with the followers standing still, ``(T, 2)``."""
    return cw.drive_leader(platoon_env.make(name, **overrides).scenario).trajectory


@pytest.mark.parametrize("name", ["study_a", "study_b", "study_c"])
def test_start_configuration_is_feasible(name: str) -> None:
    sc = load_scenario(name)
    assert initial_violations(sc.config, sc.workspace, np.asarray(sc.initial_poses)) == []
    if sc.config.leader.trajectory:
        return  # a trajectory (study B): the followers start lined up behind its first pose
    # the path begins with a straight stretch for the whole platoon behind the leader
    path = np.asarray(sc.leader_path)
    first = float(np.hypot(*(path[1] - path[0])))
    assert first >= sc.config.followers * sc.config.formation.d_des


# --------------------------------------------------------------------------------------------
# Study A: narrow passages that turn sharply
# --------------------------------------------------------------------------------------------


def test_study_a_has_sharp_corners_inside_narrow_passages() -> None:
    cfg = load_config("study_a")
    assert cfg.followers == 7 and cfg.formation.d_des == 2.0 and cfg.robot.radius == 0.2
    corners = corners_of("study_a")
    inside = [c for c in corners if c.turn_deg > 85.0 and c.width <= 1.2 + 1e-6]
    # one in the L-shaped passage (1.2 m), two in the Z-shaped one (1.0 m)
    assert len(inside) == 3, corners
    assert sorted(round(c.width, 2) for c in inside) == [1.0, 1.0, 1.2]
    # both passages are narrower than 2 (r + delta): F_l and F_r engage together
    assert cfg.ppc is not None
    both = 2.0 * (cfg.robot.radius + cfg.ppc.delta)
    widths = passage_widths("study_a")
    assert widths.min() == pytest.approx(1.0, abs=1e-6)
    assert np.sum(widths < both) * cw.SAMPLE_STEP > 10.0  # metres of path


# --------------------------------------------------------------------------------------------
# Study C: a snaky corridor with sharp corners, taken tightly by the leader
# --------------------------------------------------------------------------------------------


def test_study_c_snaky_corridor_has_sharp_corners() -> None:
    corners = corners_of("study_c")
    in_corridor = [c for c in corners if c.width <= 1.2 + 0.01]  # the map's mm rounding
    assert sum(c.turn_deg > 85.0 for c in in_corridor) == 6  # the 1.2 m meander
    assert any(55.0 < c.turn_deg < 65.0 for c in in_corridor)  # the zig-zag corridor's 60 deg
    # the first sharp corner comes right after the start stretch
    sc = load_scenario("study_c")
    assert corners[0].turn_deg > 85.0 and corners[0].s - sc.initial_progress < 2.0
    assert passage_widths("study_c").min() == pytest.approx(1.2, abs=1e-6)


def test_study_c_obstacles_are_non_convex() -> None:
    free = load_scenario("study_c").free_space
    holes = [Polygon(h) for h in free.interiors]
    assert len(holes) == 3
    for hole in holes:
        assert hole.area < hole.convex_hull.area - 0.1


def test_study_c_leader_takes_the_corners_tightly() -> None:
    """The env's leader (pure pursuit, small lookahead) passes close to every sharp vertex and
    turns on a radius far below the 1.7-1.8 m arcs of the old map."""
    traj = driven_leader("study_c")
    line = LineString(traj)
    for c in corners_of("study_c"):
        assert line.distance(Point(c.x, c.y)) < 0.1, c
    assert cw.tightest_turn(traj) < 0.3


# --------------------------------------------------------------------------------------------
# Study B: an indoor flat with realistic doors, the leader on the planner's global path
# --------------------------------------------------------------------------------------------

#: Study B's doors (study_b.yaml header): centre on the wall's middle line, wall direction.
STUDY_B_DOORS = {
    "D1 living room / corridor": ((4.975, 4.75), (1.0, 0.0)),
    "D2 corridor / kitchen": ((8.025, 3.25), (1.0, 0.0)),
    "D3 corridor / bedroom": ((9.65, 4.75), (1.0, 0.0)),
    "D4 corridor / bathroom": ((2.35, 3.25), (1.0, 0.0)),
}


def door_width(free: shapely.Geometry, centre: tuple[float, float], along: tuple[float, float]):
    """The free width of a door: from its centre along the wall to the jambs on both sides."""
    c = np.asarray(centre)
    d = np.asarray(along)
    out = 0.0
    for sign in (1.0, -1.0):
        ray = LineString([c, c + sign * 5.0 * d])
        hit = ray.intersection(free.boundary)
        out += Point(c).distance(hit)
    return out


def test_study_b_doors_are_realistic() -> None:
    sc = load_scenario("study_b")
    free = sc.free_space
    for name, (centre, along) in STUDY_B_DOORS.items():
        assert 0.8 - 1e-6 <= door_width(free, centre, along) <= 1.0 + 1e-6, name
    # the leader's path goes through D1 and D2
    path = LineString(sc.leader_path)
    for name in ("D1 living room / corridor", "D2 corridor / kitchen"):
        (x, y), _ = STUDY_B_DOORS[name]
        assert path.distance(Point(x, y)) < 0.05, name
    assert sc.config.proximity_half_angle == pytest.approx(math.radians(130))


def test_study_b_leader_replays_the_planners_trajectory() -> None:
    """Study B's leader is the shipped trajectory (``leader.trajectory_file``), which starts at
    the planner's start (the end of the platoon's straight) and ends at its goal."""
    cfg = load_config("study_b")
    traj = np.asarray(cfg.leader.trajectory)
    assert cfg.leader.path == () and traj.shape[1] == 4
    shipped = np.asarray(yaml.safe_load(TRAJECTORY.read_text()))
    np.testing.assert_array_equal(traj, shipped)
    np.testing.assert_allclose(traj[0, 1:], planner.STUDY_B_START, atol=1e-9)
    np.testing.assert_allclose(traj[-1, 1:3], planner.STUDY_B_GOAL[:2], atol=1e-3)
    sc = load_scenario("study_b")
    np.testing.assert_allclose(sc.initial_poses[0, :2], planner.STUDY_B_START[:2], atol=1e-9)
    assert cfg.safety.inflation == 0.1  # the paper's obstacle augmentation


def test_study_b_is_feasible_with_the_papers_inflation() -> None:
    """The paper augmented the obstacles by 0.1 m (section 4.2): the map, its leader path and
    its start stay valid with ``safety.inflation: 0.1`` (where the option exists)."""
    try:
        env = platoon_env.make("study_b", safety={"inflation": 0.1})
    except (ScenarioError, TypeError) as exc:
        if "inflation" in str(exc) and "unknown" in str(exc):
            pytest.skip("safety.inflation is not available")
        raise
    assert env.scenario.config.safety.inflation == 0.1


# --------------------------------------------------------------------------------------------
# The planner
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def study_b_plan():
    cfg = load_config("study_b")
    return cfg, planner.plan(cfg, planner.STUDY_B_START, planner.STUDY_B_GOAL)


def test_planner_is_deterministic_and_matches_the_shipped_file(study_b_plan) -> None:
    cfg, first = study_b_plan
    again = planner.plan(cfg, planner.STUDY_B_START, planner.STUDY_B_GOAL)
    np.testing.assert_array_equal(first.trajectory, again.trajectory)
    np.testing.assert_array_equal(first.path, again.path)
    shipped = np.asarray(yaml.safe_load(TRAJECTORY.read_text()))
    assert shipped.shape == first.trajectory.shape
    np.testing.assert_allclose(shipped, first.trajectory, atol=2e-4)
    header = TRAJECTORY.read_text().split("\n- [", 1)[0]
    assert "python scripts/plan_leader_trajectory.py" in header


def test_planner_output_is_within_the_limits(study_b_plan) -> None:
    cfg, plan = study_b_plan
    traj, lim, p = plan.trajectory, plan.limits, plan.params
    assert lim.speed == p.speed and lim.turn_rate == p.turn_rate
    # the replay at the fastest speed factor stays within study B's leader limits
    assert lim.turn_rate * (1 + cfg.leader.speed_variation) <= cfg.leader.max_turn_rate + 1e-9
    h = p.period
    np.testing.assert_allclose(np.diff(traj[:, 0]), h, atol=1e-9)
    step = np.diff(traj, axis=0)
    rounding = math.sqrt(2.0) * 10.0**-planner.POSE_DECIMALS / h  # [m/s] from the file's decimals
    speed = np.hypot(step[:, 1], step[:, 2]) / h
    rate = np.arctan2(np.sin(step[:, 3]), np.cos(step[:, 3])) / h
    assert speed.max() <= lim.speed + rounding
    assert np.abs(rate).max() <= lim.turn_rate + rounding
    assert np.abs(np.diff(speed)).max() / h <= lim.accel + 2.0 * rounding / h
    assert np.abs(np.diff(rate)).max() / h <= lim.alpha + 2.0 * rounding / h
    # never backwards: each displacement points along the heading
    forward = step[:, 1] * np.cos(traj[:-1, 3]) + step[:, 2] * np.sin(traj[:-1, 3])
    assert forward.min() >= -1e-3
    # from rest at the start to rest at the goal
    np.testing.assert_allclose(traj[0, 1:], planner.STUDY_B_START, atol=1e-4)
    np.testing.assert_allclose(traj[-1, 1:3], planner.STUDY_B_GOAL[:2], atol=0.01)
    assert speed[0] == 0.0 and speed[-1] == 0.0


def test_planner_keeps_the_inflated_clearance_and_turns_in_place(study_b_plan) -> None:
    cfg, plan = study_b_plan
    traj, p = plan.trajectory, plan.params
    free = load_scenario("study_b").free_space
    need = cfg.robot.radius + p.safety_margin + p.path_margin
    assert LineString(traj[:, 1:3]).distance(free.boundary) >= need - 1e-4
    assert LineString(plan.platoon_path).distance(free.boundary) >= need - 1e-9
    step = np.diff(traj, axis=0)
    still = np.hypot(step[:, 1], step[:, 2]) < 1e-6
    turning = np.abs(np.arctan2(np.sin(step[:, 3]), np.cos(step[:, 3]))) > 1e-3
    assert np.any(still & turning)  # turns in place
    # at every sharp vertex of the global path it stops (slowing down before it) and turns in
    # place; nowhere else does it stand still
    vertices = planner.sharp_vertices(plan.path, p.sharp_turn)
    assert len(vertices) >= 4
    for k in vertices:
        near = np.hypot(*(traj[:-1, 1:3] - plan.path[k]).T) < 0.01
        assert np.any(near & still & turning), plan.path[k]
        before = np.flatnonzero(near)[0]
        assert np.hypot(*step[before - 1, 1:3]) / p.period < 0.5 * plan.limits.speed


def test_planner_on_a_small_corridor() -> None:
    """A* stays at the inflation radius from the walls; an unreachable goal is an error."""
    corridor = Polygon([(0, 0), (4, 0), (4, 4), (3, 4), (3, 1), (0, 1)])
    p = planner.PlannerParams()
    path = planner.global_path(corridor, 0.2, (0.5, 0.5), (3.5, 3.5), p)
    assert LineString(path).distance(corridor.boundary) >= 0.2 + p.safety_margin + p.path_margin
    lim = planner.Limits(speed=0.3, turn_rate=1.0, accel=p.accel_max, alpha=p.alpha_max)
    traj = planner.follow(path, 0.0, math.pi / 2, lim, p)
    np.testing.assert_allclose(traj[-1, 1:3], (3.5, 3.5), atol=0.01)
    with pytest.raises(ValueError, match="clearance"):
        planner.global_path(corridor, 0.45, (0.5, 0.5), (3.5, 3.5), p)


def test_the_readme_table_of_a_study_is_what_check_measures(tmp_path: Path) -> None:
    """``check_workspaces.py --table``: one row per study from the report's own numbers."""
    report = cw.check("study_b", tmp_path)
    sc = load_scenario("study_b")
    assert not report.failures
    n = report.numbers
    assert n["edges"] == len(sc.workspace.edges)
    assert n["path"] == pytest.approx(sc.path_s[-1] - sc.initial_progress)
    assert n["radius"] > 0 and math.isfinite(n["run"]) and n["run"] > 0  # it arrived
    table = cw.summary_table([report]).splitlines()
    assert len(table) == 3 and table[2].startswith(f"| `study_b` | {len(sc.workspace.edges)} | ")
    assert f"{n['run']:.1f}" in table[2]
    rejected = cw.Report("broken", failures=["scenario rejected by the loader: ..."])
    assert cw.summary_table([rejected]).splitlines()[2] == "| `broken` | – | – | – | – | – |"
