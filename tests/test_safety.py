"""The safety rules (eqs. 4-5, ``docs/safety.md``): a configuration's masks and their messages.

:func:`~platoon_env.safety.configuration_masks` (the rules of the last sub-step of a step,
applied to a configuration at rest) must give the brute-force
:func:`~platoon_env.safety.violation_masks` of the same poses without motion, and its sensing
that of :func:`~platoon_env.geometry.sensing.sense`; :func:`~platoon_env.safety.describe_masks`
words every violated constraint.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray
from shapely.geometry import box
from workspaces import Workspace, all_workspaces, sample_lattice_platoon, sample_platoon

from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_OCCLUDED,
    SENSE_SIZE,
    sense,
    sensing_params,
)
from platoon_env.geometry.workspace import boundary_edges
from platoon_env.records import PARAMS_DTYPE
from platoon_env.safety import (
    COLLISION_OBSTACLE,
    COLLISION_ROBOT,
    OCCLUDED,
    OUT_OF_FOV,
    OUT_OF_RANGE,
    configuration_masks,
    configuration_problems,
    describe_masks,
    sensed_violation,
    violation_masks,
)


def _params(*, radius: float, d_col: float, **sensors: float) -> NDArray[np.void]:
    """A ``(1,)`` params array of what the constraint rules read: the robot radius ``r``,
    ``d_col`` and the sensors (:func:`~platoon_env.geometry.sensing.sensing_params`)."""
    params = np.zeros(1, dtype=PARAMS_DTYPE)
    params[0] = sensing_params(**sensors)
    params["radius"], params["d_col"] = radius, d_col
    return params


#: The corridor tests' robots and sensors.
CORRIDOR_PARAMS = {
    "radius": 0.1,
    "d_col": 0.3,
    "d_con": 1.5,
    "beta_con": 0.5,
    "proximity_range": 1.0,
}


@pytest.mark.parametrize("workspace", all_workspaces(), ids=lambda w: w.name)
@pytest.mark.parametrize("half_angle", [math.pi, 2.27])
def test_configuration_masks_are_the_substep_rules(workspace: Workspace, half_angle: float) -> None:
    """Random and lattice platoons (robots on walls, on each other): the masks equal the
    brute-force sub-step masks without motion, and the sensing equals :func:`sense`."""
    rng = np.random.default_rng(11)
    edges = boundary_edges(workspace.free_space)
    params = _params(
        radius=0.2,
        d_col=0.45,
        d_con=workspace.d_con,
        beta_con=workspace.beta_con,
        proximity_range=1.2,
        proximity_half_angle=half_angle,
    )
    p = params[0]
    grid = EdgeGrid.build(edges, reach=1.2)
    seen = 0
    for trial in range(150):
        if trial % 3 == 2:
            poses = sample_lattice_platoon(workspace.free_space, rng, 3)
        else:
            poses = sample_platoon(
                workspace.free_space, rng, 3, workspace.d_con, workspace.beta_con
            )
        sensed, masks = np.zeros((3, SENSE_SIZE)), np.zeros(3, dtype=np.int64)
        configuration_masks(poses, grid.walls, p, sensed, masks)
        expected = np.zeros(3, dtype=np.int64)
        violation_masks(poses, poses, grid.walls, p, expected)
        context = f"{workspace.name} trial {trial}, poses={poses.tolist()}"
        np.testing.assert_array_equal(masks, expected, err_msg=context)
        np.testing.assert_array_equal(sensed, sense(poses, edges, p), err_msg=context)
        seen |= int(np.bitwise_or.reduce(masks))
    assert seen == 0b11111, f"every cause should occur, saw {seen:#b}"


def _corridor_problems(poses: list[list[float]], **overrides: float) -> list[str]:
    """The messages for ``poses`` in a 20 m x 2 m corridor with a post at x in [10, 11]."""
    free = box(0.0, -1.0, 20.0, 1.0).difference(box(10.0, -1.0, 11.0, 0.2))
    grid = EdgeGrid.build(boundary_edges(free), reach=1.0)
    params = _params(**(CORRIDOR_PARAMS | overrides))
    return configuration_problems(np.array(poses, dtype=np.float64), grid.walls, params)


def test_feasible_configuration_has_no_problem() -> None:
    assert _corridor_problems([[3.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 0.1]]) == []


def test_messages_name_the_follower_and_the_constraint() -> None:
    """Each violated constraint gives today's message of the scenario checks."""
    assert _corridor_problems([[3.0, 0.0, 0.0], [2.75, 0.0, 0.0], [1.0, 0.0, 0.0]]) == [
        "follower_1: d_1 = 0.250 must exceed d_col = 0.3",
        "follower_2: d_2 = 1.750 must be below d_con = 1.5",
    ]
    assert _corridor_problems([[3.0, 0.0, 0.0], [2.0, 0.0, 1.0], [1.0, 0.95, -0.75]]) == [
        "follower_1: |beta_1| = 1.000 must be below beta_con = 0.5",
        "follower_2: clearance 0.050 to the obstacles must exceed r = 0.1",
    ]
    assert _corridor_problems([[11.5, 0.0, 0.0], [9.5, 0.0, 0.0]], d_con=3.0) == [
        "follower_1: the line of sight to robot 0 crosses an obstacle",
    ]


def test_contacts_of_any_two_robots() -> None:
    """Robots 0 and 2 touch (``|p_0 - p_2| <= 2r``); follower 2 is then in collision."""
    problems = _corridor_problems(
        [[3.0, 0.0, 0.0], [2.0, 0.5, -0.2], [3.0, 0.15, 1.0]], beta_con=3.0, d_con=2.0
    )
    assert problems == ["robots 0 and 2 overlap"]
    assert _corridor_problems([[3.0, 0.0, 0.0], [2.85, 0.0, 0.0]]) == [
        "follower_1: d_1 = 0.150 must exceed d_col = 0.3",
        "robots 0 and 1 overlap",
    ]


def test_describe_masks_without_poses_and_motion() -> None:
    """Without poses a contact is reported per follower; an obstacle hit with clearance left
    is the tunnelling check of a step."""
    params = _params(**CORRIDOR_PARAMS)
    sensed = np.zeros((2, SENSE_SIZE))
    sensed[:, SENSE_D] = 1.0
    sensed[:, SENSE_CLEARANCE] = 0.5
    masks = np.array([COLLISION_ROBOT, COLLISION_OBSTACLE])
    expected = [
        "follower_1: its disk touches another robot's",
        "follower_2: its motion over the sub-step crossed an obstacle",
    ]
    assert describe_masks(masks, sensed, params) == expected
    assert describe_masks(masks, sensed, params[0]) == expected
    assert describe_masks(np.zeros(2, dtype=np.int64), sensed, params) == []


def test_sensed_violation_reads_the_row() -> None:
    """``d`` and ``beta`` come from the row, the squared clearance and the tunnelling check
    from the sensing call, the occlusion from the row's flag."""
    p = _params(**CORRIDOR_PARAMS)[0]
    row = np.zeros(SENSE_SIZE)
    row[SENSE_D], row[SENSE_BETA] = 1.0, 0.2
    assert sensed_violation(row, 1.0, False, p) == 0
    assert sensed_violation(row, 0.01, False, p) == COLLISION_OBSTACLE
    assert sensed_violation(row, 1.0, True, p) == COLLISION_OBSTACLE
    row[SENSE_OCCLUDED] = 1.0
    assert sensed_violation(row, 1.0, False, p) == OCCLUDED
    row[SENSE_OCCLUDED], row[SENSE_D], row[SENSE_BETA] = 0.0, 1.5, -0.5
    assert sensed_violation(row, 1.0, False, p) == OUT_OF_RANGE | OUT_OF_FOV
    row[SENSE_D] = 0.3
    assert sensed_violation(row, 1.0, False, p) == COLLISION_ROBOT | OUT_OF_FOV
