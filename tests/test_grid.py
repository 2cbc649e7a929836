"""The static edge grid: queries gather every edge they must, and culling changes no result.

Culling is checked three ways: the grid's candidates against a brute-force box-overlap test, the
culled sensing against the shapely oracle (the same tolerances as ``test_sensing_oracle``) and
against the brute-force kernel, and whole simulated steps with and without the grid.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from oracle import assert_agree, oracle_sense
from shapely.geometry import Polygon, box
from workspaces import (
    Workspace,
    all_workspaces,
    sample_lattice_platoon,
    sample_platoon,
)

import platoon_env
from platoon_env.geometry.grid import EdgeGrid, edge_boxes, grid_candidates
from platoon_env.geometry.sensing import SENSE_SIZE, sense
from platoon_env.geometry.workspace import boundary_edges
from platoon_env.reward import REWARD_TERMS
from platoon_env.simulator import kernel_params, platoon_step, step_kernel

CELL_SIZES = (None, 0.3, 1.0, 7.0)
SECTOR_HALF_ANGLES = (0.5, math.pi / 2, 2.27, 3.0)


def _random_edges(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    a = rng.uniform(-10, 10, size=(n, 2))
    length = np.exp(rng.uniform(math.log(0.01), math.log(8.0), size=(n, 1)))
    angle = rng.uniform(-math.pi, math.pi, size=(n, 1))
    b = a + length * np.hstack([np.cos(angle), np.sin(angle)])
    edges = np.hstack([a, b])
    edges[: n // 10, 2] = edges[: n // 10, 0]  # some vertical edges
    edges[n // 10 : n // 5, 3] = edges[n // 10 : n // 5, 1]  # some horizontal edges
    return np.ascontiguousarray(edges)


@pytest.mark.parametrize("cell_size", [0.25, 1.0, 3.0, 50.0, 0.0])
def test_candidates_are_exactly_the_overlapping_cells(cell_size: float) -> None:
    """Every edge whose box overlaps the query box is gathered, none twice."""
    rng = np.random.default_rng(0)
    edges = _random_edges(rng, 300)
    boxes = edge_boxes(edges)
    grid = EdgeGrid.build(edges, cell_size)
    cand = np.empty(len(edges), dtype=np.int64)
    for _ in range(300):
        x0, y0 = rng.uniform(-14, 14, size=2)
        w, h = np.exp(rng.uniform(math.log(1e-3), math.log(12.0), size=2))
        n = grid_candidates(*grid.index_arrays, x0, y0, x0 + w, y0 + h, cand)
        got = cand[:n]
        assert len(set(got.tolist())) == n, "an edge was gathered twice"
        overlap = (
            (boxes[:, 0] <= x0 + w)
            & (boxes[:, 2] >= x0)
            & (boxes[:, 1] <= y0 + h)
            & (boxes[:, 3] >= y0)
        )
        missing = set(np.flatnonzero(overlap).tolist()) - set(got.tolist())
        assert not missing, f"query ({x0}, {y0}, {w}, {h}) missed edges {sorted(missing)}"


def test_grid_shape_and_single_cell() -> None:
    edges = _random_edges(np.random.default_rng(1), 50)
    grid = EdgeGrid.build(edges, reach=4.0)
    assert grid.cell_size == pytest.approx(2.0)
    assert grid.n_edges == 50
    single = EdgeGrid.single_cell(edges)
    assert single.shape == (1, 1)
    assert math.isinf(single.cell_size)
    assert sorted(single.cell_edges.tolist()) == list(range(50))
    empty = EdgeGrid.build(np.zeros((0, 4)))
    assert empty.n_edges == 0


@pytest.mark.parametrize("workspace", all_workspaces(), ids=lambda w: w.name)
@pytest.mark.parametrize("cell_size", CELL_SIZES)
def test_culled_sensing_matches_oracle_and_brute_force(
    workspace: Workspace, cell_size: float | None
) -> None:
    """Random and lattice platoons: culled sensing agrees with the oracle and the brute force."""
    rng = np.random.default_rng(7)
    edges = boundary_edges(workspace.free_space)
    d_con, beta_con, prox = 1.6, 0.6, 1.2
    grid = EdgeGrid.build(edges, cell_size, reach=prox)
    for trial in range(12):
        if trial % 3 == 2:
            poses = sample_lattice_platoon(workspace.free_space, rng, 3)
        else:
            poses = sample_platoon(workspace.free_space, rng, 3, d_con, beta_con)
        culled = sense(poses, edges, d_con, beta_con, prox, grid=grid)
        brute = sense(poses, edges, d_con, beta_con, prox)
        context = f"{workspace.name} cell {cell_size} trial {trial}"
        assert_agree(
            culled, oracle_sense(workspace.free_space, poses, d_con, beta_con, prox), context
        )
        np.testing.assert_allclose(culled, brute, rtol=0, atol=1e-12, err_msg=context)
        # The same with a proximity sector (convex, half-plane, non-convex).
        half_angle = SECTOR_HALF_ANGLES[trial % len(SECTOR_HALF_ANGLES)]
        culled = sense(poses, edges, d_con, beta_con, prox, grid, proximity_half_angle=half_angle)
        brute = sense(poses, edges, d_con, beta_con, prox, proximity_half_angle=half_angle)
        context = f"{context}, sector ±{half_angle}"
        reference = oracle_sense(workspace.free_space, poses, d_con, beta_con, prox, half_angle)
        assert_agree(culled, reference, context)
        np.testing.assert_allclose(culled, brute, rtol=0, atol=1e-12, err_msg=context)


@pytest.mark.parametrize("cell_size", [None, 0.5])
def test_clearance_beyond_the_proximity_range(cell_size: float | None) -> None:
    """Far from every wall the uncapped clearance comes from the widening grid search."""
    room = box(-50.0, -50.0, 50.0, 50.0).difference(box(0.0, 0.0, 1.0, 1.0))
    edges = boundary_edges(room)
    grid = EdgeGrid.build(edges, cell_size, reach=1.0)
    rng = np.random.default_rng(3)
    for _ in range(20):
        poses = np.zeros((3, 3))
        poses[:, :2] = rng.uniform(-45.0, 45.0, size=(3, 2))
        poses[:, 2] = rng.uniform(-math.pi, math.pi, size=3)
        culled = sense(poses, edges, 4.0, 0.7, 1.0, grid=grid)
        assert_agree(culled, oracle_sense(room, poses, 4.0, 0.7, 1.0), "open room")
        np.testing.assert_allclose(culled, sense(poses, edges, 4.0, 0.7, 1.0), rtol=0, atol=1e-12)


def test_poses_outside_the_grid() -> None:
    """Robots beyond the grid's extent (queries clamp to the border cells) sense correctly."""
    free: Polygon = box(0.0, 0.0, 10.0, 4.0).difference(box(4.0, 1.5, 5.0, 2.5))
    edges = boundary_edges(free)
    grid = EdgeGrid.build(edges, 1.0)
    poses = np.array([[12.0, 2.0, 0.0], [11.0, 2.5, 0.3], [-3.0, -1.0, 0.0], [20.0, 9.0, 1.0]])
    np.testing.assert_allclose(
        sense(poses, edges, 4.0, 0.7, 2.0, grid=grid),
        sense(poses, edges, 4.0, 0.7, 2.0),
        rtol=0,
        atol=1e-12,
    )


@pytest.mark.parametrize("scenario", ["study_a", "study_b", "study_c"])
def test_simulated_steps_do_not_depend_on_culling(scenario: str) -> None:
    """Random actions, no termination: grid and brute-force kernels give the same steps,
    and the sensing of :func:`sense` with the scenario's proximity sector (study B's ±130 deg)."""
    env = platoon_env.make(scenario, terminate_on=())
    env.reset(seed=0)
    cfg = env.scenario.config
    n = env.n_followers
    params = kernel_params(cfg)
    grid = EdgeGrid.build(env.scenario.workspace.edges, reach=cfg.proximity_range)
    edges, boxes = env.scenario.workspace.edges, env.scenario.workspace.boxes
    path = np.ascontiguousarray(env.scenario.leader_path)
    cum = np.ascontiguousarray(env.scenario.path_s)
    state = {key: (env.poses, np.array([env.scenario.initial_progress, 0.0])) for key in ("a", "b")}
    out = {
        key: (
            np.zeros(n, dtype=np.int64),
            np.zeros((n, SENSE_SIZE)),
            np.zeros((n, 7), dtype=np.float32),
        )
        for key in ("a", "b")
    }
    terms, rewards = np.zeros((n, len(REWARD_TERMS))), np.zeros(n)
    rng = np.random.default_rng(0)
    for t in range(300):
        act = rng.uniform([-0.3, -1.5], [1.0, 1.5], size=(n, 2))
        poses, leader = state["a"]
        viol, sensed, obs = out["a"]
        platoon_step(
            poses, act.copy(), leader, path, cum, *grid.arrays, params,
            cfg.simulation.physics_substeps, 0, viol, sensed, obs, terms, rewards,
        )  # fmt: skip
        poses, leader = state["b"]
        viol_b, sensed_b, obs_b = out["b"]
        step_kernel(
            poses, act.copy(), leader, path, cum, edges, boxes, params,
            cfg.simulation.physics_substeps, 0, np.zeros((n + 1, 3)), np.zeros(n, np.int64),
            viol_b, sensed_b, obs_b,
        )  # fmt: skip
        assert np.array_equal(viol, viol_b), t
        np.testing.assert_allclose(sensed, sensed_b, rtol=0, atol=1e-12, err_msg=str(t))
        np.testing.assert_array_equal(state["a"][0], state["b"][0])
        direct = sense(
            state["a"][0], edges, cfg.camera.range, cfg.camera.half_angle,
            cfg.proximity_range, proximity_half_angle=cfg.proximity_half_angle,
        )  # fmt: skip
        np.testing.assert_allclose(sensed, direct, rtol=0, atol=1e-12, err_msg=str(t))


@pytest.mark.parametrize("scenario", ["corridor", "study_a"])
def test_substep_checks_match_brute_force(scenario: str, corridor: dict[str, Any]) -> None:
    """The kernel's sub-step safety masks (grid culling, followers far from walls skipped)
    equal the brute-force :func:`violation_masks` after every sub-step, through collisions."""
    from platoon_env.safety import violation_masks
    from platoon_env.simulator import (
        P_OMEGA_HIGH,
        P_OMEGA_LOW,
        P_U_HIGH,
        P_U_LOW,
        advance_substep,
    )

    env = platoon_env.make(corridor if scenario == "corridor" else scenario, terminate_on=())
    env.reset(seed=1)
    cfg = env.scenario.config
    n, substeps = env.n_followers, 3
    params = kernel_params(cfg)
    radius, d_col = cfg.robot.radius, cfg.safety.d_col
    d_con, beta_con = cfg.camera.range, cfg.camera.half_angle
    grid = EdgeGrid.build(env.scenario.workspace.edges, reach=cfg.proximity_range)
    edges, boxes = grid.edges, grid.boxes
    path = np.ascontiguousarray(env.scenario.leader_path)
    cum = np.ascontiguousarray(env.scenario.path_s)
    poses = env.poses
    leader = np.array([env.scenario.initial_progress, 0.0])
    viol, sensed = np.zeros(n, dtype=np.int64), np.zeros((n, SENSE_SIZE))
    obs, terms = np.zeros((n, 7), dtype=np.float32), np.zeros((n, len(REWARD_TERMS)))
    rewards = np.zeros(n)
    platoon_step(poses, np.zeros((n, 2)), leader, path, cum, *grid.arrays, params, 0, 0,
                 viol, sensed, obs, terms, rewards)  # fmt: skip
    rng = np.random.default_rng(2)
    seen = 0
    for t in range(250):
        act = rng.uniform([-1.0, -3.0], [3.0, 3.0], size=(n, 2))
        act = np.clip(act, params[[P_U_LOW, P_OMEGA_LOW]], params[[P_U_HIGH, P_OMEGA_HIGH]])
        # Reference: the same sub-steps, every edge tested after each.
        ref_poses, ref_leader, prev = poses.copy(), leader.copy(), np.zeros_like(poses)
        expected = np.zeros(n, dtype=np.int64)
        sub = np.zeros(n, dtype=np.int64)
        for _ in range(substeps):
            advance_substep(ref_poses, act, ref_leader, path, cum, params, prev)
            violation_masks(ref_poses, prev, edges, boxes, radius, d_col, d_con, beta_con, sub)
            expected |= sub
        platoon_step(poses, act.copy(), leader, path, cum, *grid.arrays, params, substeps, 0,
                     viol, sensed, obs, terms, rewards)  # fmt: skip
        np.testing.assert_array_equal(poses, ref_poses)
        np.testing.assert_array_equal(viol, expected, err_msg=f"step {t}")
        seen |= int(np.bitwise_or.reduce(expected))
    assert seen & 0b11, "the rollout should include collisions"
