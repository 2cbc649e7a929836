"""``safety.inflation``: the obstacles inflated by a margin ``m`` for every rule (issue 13).

The paper's study B "augmented the obstacles' boundary by 0.1 m" (§4.2) and plots the distance
to the true obstacles as ``d_W,i = min(d_W_l,i + 0.1, d_W_r,i + 0.1)``: the measured ``d_W_l``,
``d_W_r`` were to the augmented outline. Here, with ``m > 0``: a follower collides when its
centre comes within ``r + m`` of an obstacle; the reported ``clearance`` is to the inflated
outline (true less ``m``, exactly); the four proximity readings are to the inflated outline
(the readings of a sensor reaching ``R_p + m``, less ``m``, clipped to ``[0, R_p]``); the
camera's line of sight stays physical. ``m = 0`` (default) changes no bit.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest
import shapely
from shapely.geometry import box
from test_golden import rollout_digest

import platoon_env
from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import (
    SENSE_CLEARANCE,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
    SENSE_D_WALL_LEFT,
    SENSE_D_WALL_RIGHT,
    SENSE_OCCLUDED,
    SENSE_SIZE,
    sense,
    sensing_params,
)
from platoon_env.geometry.workspace import boundary_edges
from platoon_env.records import constraint_params
from platoon_env.safety import COLLISION_OBSTACLE, configuration_masks, violation_masks
from platoon_env.scenarios.fingerprint import config_fingerprint
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping, parse_scenario

R = 0.2  # robot radius [m]
SENSOR = [SENSE_D_WALL_LEFT, SENSE_D_WALL_RIGHT, SENSE_D_SIGHT_LEFT, SENSE_D_SIGHT_RIGHT]

#: A 2 m wide corridor along x (walls y = -1, y = 1), one follower.
CORRIDOR: dict[str, Any] = {
    "name": "inflation_corridor",
    "workspace": {"bounds": [0.0, -1.0, 20.0, 1.0]},
    "leader": {"path": [[1.0, 0.0], [19.0, 0.0]], "speed": 0.3},
    "followers": 1,
    "robot": {"radius": R},
    "camera": {"half_angle": 0.7, "range": 2.5},
    "safety": {"d_col": 0.5},
    "formation": {"d_des": 1.0},
}


def _corridor(inflation: float | None = None, **safety: Any) -> dict[str, Any]:
    out = copy.deepcopy(CORRIDOR)
    if inflation is not None:
        out["safety"]["inflation"] = inflation
    out["safety"].update(safety)
    return out


def _near_wall(gap: float) -> np.ndarray:
    """Leader at the corridor's centre line, the follower 1 m behind with its centre
    ``r + gap`` above the wall y = -1 (facing its predecessor)."""
    y = -1.0 + R + gap
    follower = (4.0, y, math.atan2(0.0 - y, 1.0))
    return np.array([[5.0, 0.0, 0.0], follower])


@pytest.mark.parametrize("inflation", [0.0, 0.1])
def test_collision_at_r_plus_five_centimetres(inflation: float) -> None:
    """A robot ``r + 0.05`` from a wall collides with ``m = 0.1`` and not with ``m = 0``: by the
    last sub-step's rule (the sensing's squared clearance) and by the sub-steps' edge tests
    alike."""
    cfg = parse_scenario(_corridor(inflation))
    p = constraint_params(cfg)[0]
    walls = EdgeGrid.build(boundary_edges(box(0.0, -1.0, 20.0, 1.0)), reach=2.5).walls
    poses = _near_wall(0.05)
    sensed, masks = np.empty((1, SENSE_SIZE)), np.zeros(1, dtype=np.int64)
    configuration_masks(poses, walls, p, sensed, masks)
    substep = np.zeros(1, dtype=np.int64)
    violation_masks(poses, poses, walls, p, substep)
    collides = inflation > 0.05
    assert bool(masks[0] & COLLISION_OBSTACLE) == collides
    assert bool(substep[0] & COLLISION_OBSTACLE) == collides
    assert sensed[0, SENSE_CLEARANCE] == pytest.approx(R + 0.05 - inflation, abs=1e-12)


def test_infeasible_start_names_the_inflation() -> None:
    """Starting ``r + 0.05`` from a wall is a valid start without inflation and a clear error
    with ``m = 0.1`` (the configuration checks use the inflated rule)."""
    env = platoon_env.make(_corridor())
    env.reset(options={"poses": _near_wall(0.05)})
    inflated = platoon_env.make(_corridor(0.1))
    with pytest.raises(ScenarioError, match=r"follower_1: clearance 0\.150 to the obstacles "):
        inflated.reset(options={"poses": _near_wall(0.05)})
    with pytest.raises(ScenarioError, match=r"inflated by safety\.inflation = 0\.1 must exceed"):
        inflated.reset(options={"poses": _near_wall(0.05)})
    inflated.reset(options={"poses": _near_wall(0.15)})


def test_clearance_shifts_by_exactly_the_inflation_in_an_episode() -> None:
    """Two envs, ``m = 0`` and ``m = 0.1``, the same actions (the follower veers towards the
    wall, nothing terminates): the same poses, ``clearance`` less exactly ``m``, and
    ``collision_obstacle`` once the true clearance is ``<= r + m`` (resp. ``<= r``)."""
    m = 0.1
    envs = [
        platoon_env.make(_corridor(inflation, terminate_on=[]), physics_substeps=3)
        for inflation in (0.0, m)
    ]
    for env in envs:
        env.reset(seed=0, options={"perturb": False})
    seen_inflated_only = 0
    for _ in range(150):
        infos = []
        for env in envs:
            _, _, _, _, info = env.step({"follower_1": [1.0, -1.0]})
            infos.append(info["follower_1"])
        np.testing.assert_array_equal(envs[0].poses, envs[1].poses)
        true, inflated = infos[0]["clearance"], infos[1]["clearance"]
        assert inflated == true - m
        if true > R + m + 1e-9:
            assert "collision_obstacle" not in infos[1]["violations"]
        if true < R + m - 1e-9:
            assert "collision_obstacle" in infos[1]["violations"]
        assert ("collision_obstacle" in infos[0]["violations"]) == (true <= R)
        if R + 1e-9 < true < R + m - 1e-9:
            seen_inflated_only += 1
    assert seen_inflated_only > 0  # the test did cross the margin


def _random_poses(rng: np.random.Generator, free: shapely.Polygon, n: int) -> np.ndarray:
    lo_x, lo_y, hi_x, hi_y = free.bounds
    out = []
    while len(out) < n:
        x, y = rng.uniform(lo_x, hi_x), rng.uniform(lo_y, hi_y)
        if free.contains(shapely.Point(x, y)):
            out.append((x, y, rng.uniform(-math.pi, math.pi)))
    return np.array(out)


@pytest.mark.parametrize("m", [0.1, 0.35])
def test_readings_are_to_the_inflated_outline(m: float) -> None:
    """The definition (a sensor reaching ``R_p + m``, each reading less ``m``, clipped to
    ``[0, R_p]``; the clearance less ``m``; occlusion unchanged) bit for bit, and its meaning
    against shapely: ``d_W_l``, ``d_W_r`` and the clearance are the distances to the boundary
    of the free space eroded by ``m`` (up to the buffer's polygonal arcs)."""
    room = box(0.0, 0.0, 10.0, 10.0)
    free = room.difference(box(4.0, 4.0, 6.0, 6.0)).difference(box(1.0, 7.0, 1.5, 9.0))
    eroded = free.buffer(-m, quad_segs=256)
    edges = boundary_edges(free)
    rng = np.random.default_rng(13)
    prox = 2.0
    inflated_sensors = sensing_params(d_con=3.0, beta_con=0.7, proximity_range=prox, inflation=m)
    reach_sensors = sensing_params(d_con=3.0, beta_con=0.7, proximity_range=prox + m)
    true_sensors = sensing_params(d_con=3.0, beta_con=0.7, proximity_range=prox)
    for trial in range(200):
        poses = _random_poses(rng, eroded, 3)
        inflated = sense(poses, edges, inflated_sensors)
        reach = sense(poses, edges, reach_sensors)
        true = sense(poses, edges, true_sensors)
        expected = np.clip(reach[:, SENSOR] - m, 0.0, prox)
        np.testing.assert_array_equal(inflated[:, SENSOR], expected, err_msg=str(trial))
        np.testing.assert_array_equal(inflated[:, SENSE_CLEARANCE], true[:, SENSE_CLEARANCE] - m)
        np.testing.assert_array_equal(
            inflated[:, : SENSE_OCCLUDED + 1], true[:, : SENSE_OCCLUDED + 1]
        )
        for i in range(1, 3):
            point = shapely.Point(poses[i, 0], poses[i, 1])
            to_eroded = float(eroded.boundary.distance(point))
            assert inflated[i - 1, SENSE_CLEARANCE] == pytest.approx(to_eroded, abs=1e-4)
            nearest = min(inflated[i - 1, SENSE_D_WALL_LEFT], inflated[i - 1, SENSE_D_WALL_RIGHT])
            assert nearest == pytest.approx(min(to_eroded, prox), abs=1e-4)


def test_zero_inflation_is_the_default_bit_for_bit() -> None:
    """``safety.inflation: 0`` spelled out: the same rollout digest, config mapping and
    fingerprint as leaving it out (the golden digests stay valid)."""
    for name in ("study_c", "study_a"):  # (study B ships with the paper's 0.1 m)
        default = platoon_env.make(name).source.config
        explicit = platoon_env.make(name, safety={"inflation": 0.0}).source.config
        assert explicit == default
        assert "inflation" not in config_to_mapping(default)["safety"]
        assert config_fingerprint(explicit) == config_fingerprint(default)
    assert rollout_digest("study_c", 3, steps=150) == rollout_digest(
        "study_c", 3, steps=150, safety={"inflation": 0.0}
    )
    cfg = parse_scenario(_corridor(0.1))
    assert config_to_mapping(cfg)["safety"]["inflation"] == 0.1
    assert parse_scenario(config_to_mapping(cfg)) == cfg


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (-0.01, "scenario.safety.inflation: must be >= 0"),
        (math.inf, "scenario.safety.inflation: must be finite"),
        (math.nan, "scenario.safety.inflation: must be finite"),
        (2.5, "scenario.safety.inflation: must be below the proximity range 2.5"),
        ("0.1", "scenario.safety.inflation: expected a number"),
    ],
)
def test_bad_inflation_is_rejected(value: Any, message: str) -> None:
    with pytest.raises(ScenarioError, match=message.replace(".", r"\.").replace("(", r"\(")):
        parse_scenario(_corridor(value))


def test_infeasible_inflation_is_an_error_at_load() -> None:
    """An inflation the corridor cannot hold: the leader's path (its centre line, 1 m from each
    wall) must keep ``r + m + 0.05``; the error says so. ``make()`` names the override."""
    with pytest.raises(ScenarioError, match=r"r \+ safety\.inflation \+ 0\.05 = 1\.050 m"):
        platoon_env.make(_corridor(0.8))
    with pytest.raises(ScenarioError, match=r"safety\.inflation"):
        platoon_env.make("study_c", safety={"inflation": 3.0})
    platoon_env.make(_corridor(0.7))  # 0.2 + 0.7 + 0.05 < 1: feasible
