"""A built scenario: the parsed config plus its validated geometry and initial configuration."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely.geometry import Polygon

from platoon_env.config import ScenarioConfig, ScenarioError
from platoon_env.dynamics.leader import path_arclength, point_at
from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.workspace import Workspace, build_free_space, check_leader_path
from platoon_env.records import PATH_T, PATH_THETA, PATH_X, PATH_Y, constraint_params
from platoon_env.safety import configuration_problems
from platoon_env.scenarios.trajectory import trajectory_route
from platoon_env.scenarios.validate import check_ranges, default_max_steps


@dataclass(frozen=True, eq=False)
class Scenario:
    """A scenario ready to simulate (``env.scenario``).

    Attributes:
        config: the typed scenario (``docs/scenarios.md``).
        workspace: the free space and its boundary-edge arrays.
        leader_path: ``(M, 2)`` polyline of the leader; ``path_s`` its cumulative arc length.
            With a timed trajectory: the samples' positions (the linear interpolation drives
            the leader exactly along it).
        initial_poses: ``(N+1, 3)`` default initial configuration ``[x, y, theta]``, leader first.
        initial_progress: the leader's arc length along its path in that configuration.
        layout_index: for a layout of a procedural scenario (built by
            :func:`~platoon_env.scenarios.procedural.generate_scenario`), its number in the
            template's split; None for a fixed workspace.
        leader_times, leader_headings: ``(M,)`` the trajectory's sample times [s] and headings
            [rad] (``leader.trajectory``; None for a pure-pursuit path).
    """

    config: ScenarioConfig
    workspace: Workspace
    leader_path: np.ndarray
    path_s: np.ndarray
    initial_poses: np.ndarray
    initial_progress: float
    layout_index: int | None = None
    leader_times: np.ndarray | None = None
    leader_headings: np.ndarray | None = None

    @property
    def name(self) -> str:
        """The scenario's name."""
        return self.config.name

    @property
    def free_space(self) -> Polygon:
        """The free space ``W_f`` as a shapely polygon (ground truth, for tests and plots)."""
        return self.workspace.free_space

    @property
    def max_episode_steps(self) -> int:
        """The step limit: ``simulation.max_episode_steps``, or :func:`default_max_steps`."""
        sim = self.config.simulation
        if sim.max_episode_steps is not None:
            return sim.max_episode_steps
        return default_max_steps(self.config, float(self.path_s[-1]))

    @property
    def n_followers(self) -> int:
        """Number of followers ``N``."""
        return self.config.followers


def default_initial_poses(
    cfg: ScenarioConfig, path: np.ndarray, cum: np.ndarray
) -> tuple[np.ndarray, float]:
    """The default initial configuration (``docs/scenarios.md``).

    The last follower stands at the path's first point; walking forward along the path, each
    next robot stands where the chord to the previous one first reaches ``d_des``; the leader is
    furthest along and faces along the path; each follower faces its predecessor.
    Returns the poses (leader first) and the leader's arc-length progress.
    """
    n = cfg.followers
    d_des = cfg.formation.d_des
    total = float(cum[-1])
    step = min(0.01, d_des / 50.0)
    s_robot = [0.0]
    for k in range(n):
        s0 = s_robot[-1]
        x0, y0 = point_at(path, cum, s0)
        s = s0
        while True:
            s_next = s + step
            if s_next > total:
                raise ScenarioError(
                    f"scenario.leader.path: too short for the platoon: robot {n - k - 1} "
                    f"cannot be placed {d_des} m ahead of the next one along the path"
                )
            x, y = point_at(path, cum, s_next)
            if math.hypot(x - x0, y - y0) >= d_des:
                lo, hi = s, s_next
                for _ in range(60):
                    mid = 0.5 * (lo + hi)
                    xm, ym = point_at(path, cum, mid)
                    if math.hypot(xm - x0, ym - y0) >= d_des:
                        hi = mid
                    else:
                        lo = mid
                s_robot.append(hi)
                break
            s = s_next
    s_robot.reverse()  # leader first
    xy = np.array([point_at(path, cum, s) for s in s_robot])
    poses = np.zeros((n + 1, 3))
    poses[:, :2] = xy
    ahead = np.array(point_at(path, cum, min(total, s_robot[0] + 1e-3)))
    behind = np.array(point_at(path, cum, max(0.0, s_robot[0] - 1e-3)))
    tangent = ahead - behind
    poses[0, 2] = math.atan2(tangent[1], tangent[0])
    for i in range(1, n + 1):
        dx, dy = xy[i - 1] - xy[i]
        poses[i, 2] = math.atan2(dy, dx)
    return poses, float(s_robot[0])


def trajectory_initial_poses(cfg: ScenarioConfig) -> np.ndarray:
    """The default initial configuration of a timed trajectory (``docs/scenarios.md``): the
    leader at the first sample's pose, each follower ``d_des`` behind its predecessor along the
    leader's initial heading, facing it (the platoon lined up behind the leader)."""
    _, x0, y0, theta0 = cfg.leader.trajectory[0]
    n, d_des = cfg.followers, cfg.formation.d_des
    back = np.arange(n + 1, dtype=np.float64) * d_des
    poses = np.empty((n + 1, 3))
    poses[:, 0] = x0 - back * math.cos(theta0)
    poses[:, 1] = y0 - back * math.sin(theta0)
    poses[:, 2] = theta0
    poses[0] = x0, y0, theta0  # exactly the sample
    return poses


def leader_clear(cfg: ScenarioConfig, workspace: Workspace, xy: tuple[float, float]) -> bool:
    """Whether a leader at ``xy`` keeps a clearance above ``r + m`` (its disk clear of the
    obstacles inflated by ``safety.inflation``): the leader's part of a feasible start."""
    return workspace.clearance(float(xy[0]), float(xy[1])) > cfg.obstacle_reach


def initial_violations(cfg: ScenarioConfig, workspace: Workspace, poses: np.ndarray) -> list[str]:
    """Which constraints of the initial configuration (after Problem 1) ``poses`` violates.

    The followers' rules are the env's own (:func:`platoon_env.safety.configuration_masks`,
    applied after every sub-step of a step, with the obstacles inflated by
    ``safety.inflation``); the leader, which the rules do not cover, must keep a clearance
    above ``r + m`` (:func:`leader_clear`). Returns messages naming the robot and the
    constraint; empty when feasible.
    """
    walls = EdgeGrid.build(workspace.edges, reach=cfg.proximity_range).walls
    problems = configuration_problems(poses, walls, constraint_params(cfg))
    if not leader_clear(cfg, workspace, (poses[0, 0], poses[0, 1])):
        clearance = workspace.clearance(float(poses[0, 0]), float(poses[0, 1]))
        margin = f"r + safety.inflation = {cfg.obstacle_reach:g}"
        if cfg.safety.inflation == 0:
            margin = f"r = {cfg.robot.radius}"
        problems.append(f"leader: clearance {clearance:.3f} to the obstacles must exceed {margin}")
    return problems


def build_scenario(cfg: ScenarioConfig, free_space: Polygon | None = None) -> Scenario:
    """Validate a fixed scenario's ``cfg``; build its geometry and default initial configuration.

    ``free_space``, when given, is used instead of building ``cfg.workspace`` again (it must be
    the polygon that ``cfg.workspace`` describes, e.g. the ``free_space`` of a scenario built from
    the same workspace).

    Raises :class:`ScenarioError` for bad geometry, an unsafe leader path, or an infeasible
    initial configuration (naming the follower and the constraint), and for a procedural config
    (one with a ``generator`` block): it has no single workspace to build.
    :func:`platoon_env.scenarios.source.scenario_source` gives its
    :class:`~platoon_env.scenarios.source.ProceduralSource`, which draws a layout per episode;
    :func:`platoon_env.scenarios.procedural.generate_scenario` builds one numbered layout.
    """
    if cfg.generator is not None:
        raise ScenarioError(
            f"scenario {cfg.name!r} is procedural (it has a 'generator' block), so it has no "
            "single workspace to build: use platoon_env.scenarios.scenario_source(...) (a "
            "ProceduralSource, which draws a layout per episode), or "
            "platoon_env.scenarios.procedural.generate_scenario(cfg, index) for one layout"
        )
    check_ranges(cfg)
    if free_space is None:
        free_space = build_free_space(cfg.workspace)
    workspace = Workspace.from_free_space(free_space)
    times: np.ndarray | None = None
    headings: np.ndarray | None = None
    if cfg.leader.trajectory:
        # The interpolation drives the leader along the samples' polyline exactly: its
        # clearance is that polyline's.
        route, cum = trajectory_route(cfg.leader.trajectory)
        path = np.ascontiguousarray(route[:, PATH_X : PATH_Y + 1])
        times = np.ascontiguousarray(route[:, PATH_T])
        headings = np.ascontiguousarray(route[:, PATH_THETA])
        check_leader_path(
            free_space,
            path,
            cfg.robot.radius,
            "scenario.leader.trajectory",
            inflation=cfg.safety.inflation,
        )
        poses, progress = trajectory_initial_poses(cfg), 0.0
    else:
        path = np.asarray(cfg.leader.path, dtype=np.float64)
        check_leader_path(free_space, path, cfg.robot.radius, inflation=cfg.safety.inflation)
        cum = path_arclength(path)
        if cum[-1] <= 0.0:
            raise ScenarioError("scenario.leader.path: the path has zero length")
        poses, progress = default_initial_poses(cfg, path, cum)
    problems = initial_violations(cfg, workspace, poses)
    if problems:
        raise ScenarioError(
            "scenario: the default initial configuration is infeasible: " + "; ".join(problems)
        )
    for array in (path, cum, poses, times, headings):
        if array is not None:
            array.setflags(write=False)
    return Scenario(
        config=cfg,
        workspace=workspace,
        leader_path=path,
        path_s=cum,
        initial_poses=poses,
        initial_progress=progress,
        leader_times=times,
        leader_headings=headings,
    )
