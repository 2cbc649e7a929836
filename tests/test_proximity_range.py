"""The proximity range is a disk around the follower, also for ``d_l``, ``d_r`` (issue 13, rule 1).

The paper's follower "is equipped with proximity sensors that enable it to perceive the
unoccluded outline of nearby obstacles up to distance ``d_con``" (§2): a boundary point enters
``d_W_l``, ``d_W_r``, ``d_l``, ``d_r`` only when it lies within the proximity range ``R_p`` of
the follower ``p_i`` (and in its sector). Before, ``d_l``, ``d_r`` used every wall within
``R_p`` of the line of sight ``L_i``: a wall 2.61 m from a study-B follower (``R_p = 2.5``),
near its predecessor, read ``d_l = 0.283``. Each case is checked against closed forms, and
against the shapely oracle (:mod:`oracle`, which implements the same rule independently).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracle import assert_agree, named, oracle_sense
from shapely.geometry import Polygon, box

import platoon_env
from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import sense, sensing_params
from platoon_env.geometry.workspace import boundary_edges

#: Study B's sensors (paper §4.2): camera range and half-angle, the proximity sensor's range
#: (d_con) and its ±130° sector.
D_CON, BETA_CON, RANGE, SECTOR = 2.5, 0.785, 2.5, math.radians(130.0)


def _both(free: Polygon, poses: np.ndarray, prox: float, half_angle: float) -> np.void:
    """The kernel's readings of follower 1 (brute force and grid-culled, which must agree bit
    for bit; an :func:`oracle.named` record), after checking them against the oracle's."""
    edges = boundary_edges(free)
    params = sensing_params(
        d_con=D_CON, beta_con=BETA_CON, proximity_range=prox, proximity_half_angle=half_angle
    )
    brute = sense(poses, edges, params)
    culled = sense(poses, edges, params, EdgeGrid.build(edges, reach=prox))
    np.testing.assert_array_equal(brute, culled)
    assert_agree(brute, oracle_sense(free, poses, params), "oracle")
    return named(brute)[0]


def _example_world() -> tuple[Polygon, np.ndarray, tuple[float, float]]:
    """The reported case: a study-B follower at the origin facing +x, its predecessor 2.45 m
    ahead; an obstacle whose nearest corner ``b`` is 2.61 m from the follower and 0.283 m from
    the predecessor (``L_i``'s nearest point), on the left."""
    q = np.array([2.45, 0.0])
    gap, far = 0.283, 2.61
    # b = q + gap (cos phi, sin phi) with |b| = far
    cos_phi = (far**2 - q[0] ** 2 - gap**2) / (2.0 * q[0] * gap)
    phi = math.acos(cos_phi)
    b = (q[0] + gap * math.cos(phi), gap * math.sin(phi))
    room: Polygon = box(-5.0, -5.0, 10.0, 10.0)
    free = room.difference(box(b[0], b[1], b[0] + 1.0, b[1] + 1.0))
    poses = np.array([[q[0], q[1], 0.0], [0.0, 0.0, 0.0]])
    return free, poses, b


@pytest.mark.parametrize("half_angle", [SECTOR, math.pi], ids=["130deg", "all-around"])
def test_wall_beyond_range_of_the_follower_but_near_the_segment_is_not_sensed(
    half_angle: float,
) -> None:
    """The reported example: the corner is within 0.283 m of ``L_i`` but 2.61 m from the
    follower, beyond ``R_p = 2.5``: nothing is sensed on the left (``d_l = d_W_l = R_p``).
    With a range reaching it (2.7 m) it reads 0.283 (the corner's distance to ``L_i``)."""
    free, poses, b = _example_world()
    assert math.hypot(*b) == pytest.approx(2.61, abs=1e-12)
    out = _both(free, poses, RANGE, half_angle)
    assert out["visible"] == 1.0 and out["occluded"] == 0.0
    assert out["d_l"] == RANGE
    assert out["d_W_l"] == RANGE
    assert out["d_r"] == out["d_W_r"] == RANGE  # the room's walls: 5 m
    wide = _both(free, poses, 2.7, half_angle)
    assert wide["d_l"] == pytest.approx(0.283, abs=1e-12)
    assert wide["d_W_l"] == pytest.approx(2.61, abs=1e-12)


def test_wall_within_range_of_the_follower_is_sensed() -> None:
    """The same obstacle moved 0.2 m towards the follower (its corner 2.41 m away, within
    range): ``d_l`` is its distance to ``L_i`` as before the rule."""
    free, poses, b = _example_world()
    room: Polygon = box(-5.0, -5.0, 10.0, 10.0)
    bx, by = b[0] - 0.2, b[1]
    free = room.difference(box(bx, by, bx + 1.0, by + 1.0))
    out = _both(free, poses, RANGE, SECTOR)
    # The corner now lies above L_i (0 <= bx <= 2.45): its distance to L_i is its height.
    assert 0.0 <= bx <= poses[0, 0] and math.hypot(bx, by) < RANGE
    assert out["d_l"] == pytest.approx(by, abs=1e-12)


def test_a_wall_leaving_the_range_is_sensed_up_to_it() -> None:
    """A straight wall ``y = 1 - x / 4`` approaching ``L_i = [(0, 0), (3, 0)]``; ``R_p = 2``:
    only its stretch within 2 m of the follower is sensed, which ends where
    ``x² + (1 - x/4)² = 4``; ``d_l`` is that end's height (the wall descends towards ``L_i``).
    Without the rule it would be the distance from the predecessor to the wall's line."""
    edges = np.array([[-2.0, 1.5, 3.8, 0.05]])  # on y = 1 - x/4
    poses = np.array([[3.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    x_end = (0.5 + math.sqrt(0.25 + 4.0 * 1.0625 * 3.0)) / (2.0 * 1.0625)
    assert x_end**2 + (1.0 - x_end / 4.0) ** 2 == pytest.approx(4.0, abs=1e-12)
    near = sensing_params(d_con=4.0, beta_con=0.5, proximity_range=2.0)
    out = named(sense(poses, edges, near))[0]
    assert out["d_l"] == pytest.approx(1.0 - x_end / 4.0, abs=1e-12)
    assert out["d_W_l"] == pytest.approx(1.0 / math.hypot(1.0, 0.25), abs=1e-12)
    old_rule = 0.25 / math.hypot(1.0, 0.25)  # q = (3, 0) to the wall's line
    assert out["d_l"] > old_rule + 0.25
    far = sensing_params(d_con=4.0, beta_con=0.5, proximity_range=5.0)
    wide = named(sense(poses, edges, far))[0]
    assert wide["d_l"] == pytest.approx(old_rule, abs=1e-12)


@pytest.mark.parametrize(
    ("wall_x", "zeroed"), [(1.5, True), (2.5, False)], ids=["crossing-in-range", "beyond"]
)
def test_occluding_crossing_counts_only_within_range(wall_x: float, zeroed: bool) -> None:
    """A predecessor 3 m ahead behind a thin wall crossing ``L_i``; ``R_p = 2``. The camera is
    occluded either way; ``d_l = d_r = 0`` only when the crossing (a boundary point on
    ``L_i``) is within the range of the follower. Beyond it the wall's sensed stretch (within
    2 m) is what ``d_l``, ``d_r`` see: none, as the wall is 2.5 m away."""
    room: Polygon = box(-10.0, -10.0, 10.0, 10.0)
    free = room.difference(box(wall_x, -0.5, wall_x + 0.05, 0.5))
    poses = np.array([[3.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    edges = boundary_edges(free)
    params = sensing_params(d_con=4.0, beta_con=0.5, proximity_range=2.0)
    readings = sense(poses, edges, params)
    assert_agree(readings, oracle_sense(free, poses, params), "oracle")
    out = named(readings)[0]
    assert out["occluded"] == 1.0 and out["visible"] == 0.0
    sight = out[["d_l", "d_r"]].tolist()
    if zeroed:
        assert sight == (0.0, 0.0)
    else:
        assert sight == (2.0, 2.0)
        assert out["d_W_l"] == out["d_W_r"] == 2.0


def test_env_reports_the_rule() -> None:
    """Through the env: a follower whose predecessor stands beside a post that lies beyond the
    follower's proximity range reads the range, not the post's distance to ``L_i``."""
    free, poses, b = _example_world()
    start = np.array([poses[0], poses[1]])  # leader (the predecessor), follower
    scenario = {
        "name": "range_rule",
        "workspace": {
            "bounds": [-5.0, -5.0, 10.0, 10.0],
            "obstacles": [[[b[0], b[1]], [b[0] + 1, b[1]], [b[0] + 1, b[1] + 1], [b[0], b[1] + 1]]],
        },
        "leader": {"path": [[-3.0, 0.0], [2.45, 0.0]], "speed": 0.3},
        "followers": 1,
        "robot": {"radius": 0.2},
        "camera": {"half_angle": BETA_CON, "range": D_CON},
        "proximity": {"half_angle": SECTOR},
        "safety": {"d_col": 0.5},
        "formation": {"d_des": 2.0},
    }
    env = platoon_env.make(scenario)
    _, infos = env.reset(options={"poses": start})
    info = infos["follower_1"]
    assert info["d_l"] == RANGE and info["d_W_l"] == RANGE
    assert info["visible"] and info["violation"] is None
    assert env.scenario.free_space.symmetric_difference(free).area == pytest.approx(0.0)
