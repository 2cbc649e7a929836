"""The static edge grid: queries gather every edge they must, and culling changes no result.

Culling is checked three ways: the grid's candidates against a brute-force box-overlap test, the
culled sensing against the shapely oracle (the same tolerances as ``test_sensing_oracle``) and
against the brute-force kernel, and rollouts of sub-steps through collisions, whose sensing and
safety masks (with the grid) equal the brute-force kernels' after every sub-step.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
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

from platoon_env.dynamics.unicycle import unicycle_arc
from platoon_env.geometry.grid import EdgeGrid, edge_boxes, grid_candidates
from platoon_env.geometry.sensing import (
    SENSE_SIZE,
    sense,
    sense_candidates,
    sense_follower_grid,
    sensing_params,
)
from platoon_env.geometry.workspace import boundary_edges
from platoon_env.records import constraint_params
from platoon_env.safety import (
    robot_contacts,
    sensed_violation,
    violation_masks,
    violation_masks_grid,
)
from platoon_env.scenarios.loader import load_scenario
from platoon_env.scenarios.scenario import Scenario

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
        n = grid_candidates(grid.walls, (x0, y0, x0 + w, y0 + h), cand)
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
        params = sensing_params(d_con=d_con, beta_con=beta_con, proximity_range=prox)
        culled = sense(poses, edges, params, grid=grid)
        brute = sense(poses, edges, params)
        context = f"{workspace.name} cell {cell_size} trial {trial}"
        assert_agree(culled, oracle_sense(workspace.free_space, poses, params), context)
        np.testing.assert_allclose(culled, brute, rtol=0, atol=1e-12, err_msg=context)
        # The same with a proximity sector (convex, half-plane, non-convex).
        half_angle = SECTOR_HALF_ANGLES[trial % len(SECTOR_HALF_ANGLES)]
        params["proximity_half_angle"] = half_angle
        culled = sense(poses, edges, params, grid)
        brute = sense(poses, edges, params)
        context = f"{context}, sector ±{half_angle}"
        reference = oracle_sense(workspace.free_space, poses, params)
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
        params = sensing_params(d_con=4.0, beta_con=0.7, proximity_range=1.0)
        culled = sense(poses, edges, params, grid=grid)
        assert_agree(culled, oracle_sense(room, poses, params), "open room")
        np.testing.assert_allclose(culled, sense(poses, edges, params), rtol=0, atol=1e-12)


def test_poses_outside_the_grid() -> None:
    """Robots beyond the grid's extent (queries clamp to the border cells) sense correctly."""
    free: Polygon = box(0.0, 0.0, 10.0, 4.0).difference(box(4.0, 1.5, 5.0, 2.5))
    edges = boundary_edges(free)
    grid = EdgeGrid.build(edges, 1.0)
    poses = np.array([[12.0, 2.0, 0.0], [11.0, 2.5, 0.3], [-3.0, -1.0, 0.0], [20.0, 9.0, 1.0]])
    params = sensing_params(d_con=4.0, beta_con=0.7, proximity_range=2.0)
    np.testing.assert_allclose(
        sense(poses, edges, params, grid=grid),
        sense(poses, edges, params),
        rtol=0,
        atol=1e-12,
    )


def _rollout(
    scenario: Scenario,
    steps: int,
    substeps: int,
    low: tuple[float, float],
    high: tuple[float, float],
    seed: int,
) -> Iterator[tuple[int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]:
    """Each follower holds a random ``[u, omega]`` for a control period of exact arcs (eq. 1),
    the leader drives straight on at its speed, no termination. Yields
    ``(k, prev, poses, travel)`` after each sub-step ``k`` (``substeps - 1``: the last of its
    period): the poses before and after it, and how far each robot can have moved since the
    period began (``sum |u| h``)."""
    h = scenario.config.simulation.control_period / substeps
    rng = np.random.default_rng(seed)
    poses = np.array(scenario.initial_poses, dtype=np.float64)
    for _ in range(steps):
        act = rng.uniform(low, high, size=(poses.shape[0], 2))
        act[0] = scenario.config.leader.speed, 0.0
        travel = np.zeros(poses.shape[0])
        for k in range(substeps):
            prev = poses.copy()
            for r in range(poses.shape[0]):
                poses[r] = unicycle_arc(*prev[r], act[r, 0], act[r, 1], h)
                travel[r] += abs(act[r, 0]) * h
            yield k, prev, poses.copy(), travel.copy()


def _sensed_masks(
    poses: NDArray[np.float64],
    prev: NDArray[np.float64],
    grid: EdgeGrid,
    p: np.record,
    culled: bool,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The last sub-step's masks and sensing as the simulator derives them: sensing with the
    tunnelling check, then :func:`sensed_violation` and :func:`robot_contacts`; with the grid
    (``culled``) or over every edge (:func:`sense_candidates`)."""
    n = poses.shape[0] - 1
    masks, sensed = np.zeros(n, dtype=np.int64), np.zeros((n, SENSE_SIZE))
    cand = np.empty(grid.n_edges, dtype=np.int64)
    every = np.arange(grid.n_edges)
    for i in range(1, n + 1):
        args = (
            (poses[i, 0], poses[i, 1], poses[i, 2]),
            (poses[i - 1, 0], poses[i - 1, 1]),
            (prev[i, 0], prev[i, 1]),
            True,
            grid.walls,
            cand if culled else every,
            p,
            sensed[i - 1],
        )
        clear2, hit = (sense_follower_grid if culled else sense_candidates)(*args)
        masks[i - 1] = sensed_violation(sensed[i - 1], clear2, hit, p)
    robot_contacts(poses, float(p["radius"]), masks)
    return masks, sensed


@pytest.mark.parametrize("scenario", ["study_a", "study_b", "study_c"])
def test_simulated_steps_do_not_depend_on_culling(scenario: str) -> None:
    """Random actions, no termination: the grid and brute-force kernels give the same masks and
    sensing at the end of every control period, and :func:`sense` agrees with the scenario's
    proximity sector (study B's ±130 deg)."""
    sc = load_scenario(scenario)
    cfg = sc.config
    params = constraint_params(sc.config)
    p = params[0]
    grid = EdgeGrid.build(sc.workspace.edges, reach=cfg.proximity_range)
    edges = sc.workspace.edges
    substeps = cfg.simulation.physics_substeps
    for t, (k, prev, poses, _) in enumerate(
        _rollout(sc, 300, substeps, (-0.3, -1.5), (1.0, 1.5), seed=0)
    ):
        if k != substeps - 1:
            continue
        viol, sensed = _sensed_masks(poses, prev, grid, p, culled=True)
        viol_b, sensed_b = _sensed_masks(poses, prev, grid, p, culled=False)
        assert np.array_equal(viol, viol_b), t
        np.testing.assert_allclose(sensed, sensed_b, rtol=0, atol=1e-12, err_msg=str(t))
        brute = np.zeros_like(viol)
        violation_masks(poses, prev, grid.walls, p, brute)
        np.testing.assert_array_equal(viol, brute, err_msg=str(t))
        direct = sense(poses, edges, p)
        np.testing.assert_allclose(sensed, direct, rtol=0, atol=1e-12, err_msg=str(t))


@pytest.mark.parametrize("scenario", ["corridor", "study_a"])
def test_substep_checks_match_brute_force(scenario: str, corridor: dict[str, Any]) -> None:
    """The sub-step safety masks (grid culling, followers far from walls skipped by the bounds
    of the period's starting sensing) and the last sub-step's masks read off the sensing equal
    the brute-force :func:`violation_masks` after every sub-step, through collisions."""
    sc = load_scenario(corridor if scenario == "corridor" else scenario)
    params = constraint_params(sc.config)
    p = params[0]
    grid = EdgeGrid.build(sc.workspace.edges, reach=sc.config.proximity_range)
    n, substeps = sc.initial_poses.shape[0] - 1, 3
    start = sense(sc.initial_poses, grid.edges, p, grid)
    cand = np.empty(grid.n_edges, dtype=np.int64)
    seen = 0
    got, expected = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    sub, ref = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    for t, (k, prev, poses, travel) in enumerate(
        _rollout(sc, 600, substeps, (-1.0, -3.0), (3.0, 3.0), seed=2)
    ):
        if k == 0:
            got[:], expected[:] = 0, 0
        # Reference: every edge tested after each sub-step.
        violation_masks(poses, prev, grid.walls, p, ref)
        if k < substeps - 1:
            violation_masks_grid(poses, prev, grid.walls, cand, p, sub, start, travel)
        else:
            sub, start = _sensed_masks(poses, prev, grid, p, culled=True)
        np.testing.assert_array_equal(sub, ref, err_msg=f"sub-step {t}")
        got |= sub
        expected |= ref
        if k == substeps - 1:
            np.testing.assert_array_equal(got, expected, err_msg=f"step {t // substeps}")
            seen |= int(np.bitwise_or.reduce(expected))
    assert seen & 0b11, "the rollout should include collisions"
