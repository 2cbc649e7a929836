"""``build_free_space``: the obstacles are cut out of the region in one difference with their
union, so building a workspace costs about n log n in the number of obstacles (one difference
per obstacle made ``make()`` quadratic: 2,000 small obstacles took 12 s); the result is the
region minus every obstacle, as before."""

from __future__ import annotations

from typing import Any

import pytest
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from platoon_env.config import FreeSpaceConfig, ScenarioError, WorkspaceConfig
from platoon_env.geometry.workspace import build_free_space


def squares(
    n: int, size: float = 0.1, pitch: float = 0.5
) -> tuple[tuple[tuple[float, float], ...], ...]:
    """``n`` disjoint squares in rows, inside ``[0, 50]^2``."""
    out = []
    for k in range(n):
        i, j = divmod(k, 40)
        x, y = 1.0 + i * pitch, 1.0 + j * pitch
        out.append(((x, y), (x + size, y), (x + size, y + size), (x, y + size)))
    return tuple(out)


def workspace(obstacles: Any) -> WorkspaceConfig:
    return WorkspaceConfig(bounds=(0.0, 0.0, 50.0, 50.0), obstacles=obstacles)


@pytest.mark.parametrize("n", [1, 10, 400])
def test_one_difference_whatever_the_number_of_obstacles(
    n: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []
    difference = BaseGeometry.difference

    def counted(self: BaseGeometry, *args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return difference(self, *args, **kwargs)

    monkeypatch.setattr(BaseGeometry, "difference", counted)
    free = build_free_space(workspace(squares(n)))
    assert len(calls) == 1
    assert len(free.interiors) == n


def test_overlapping_obstacles_give_the_region_minus_each_of_them() -> None:
    # an L of two overlapping rectangles, a square touching the boundary, a free-standing one
    obstacles = (
        ((2.0, 2.0), (6.0, 2.0), (6.0, 3.0), (2.0, 3.0)),
        ((5.0, 2.0), (6.0, 2.0), (6.0, 7.0), (5.0, 7.0)),
        ((0.0, 10.0), (2.0, 10.0), (2.0, 12.0), (0.0, 12.0)),
        ((20.0, 20.0), (21.0, 20.0), (21.0, 21.0), (20.0, 21.0)),
    )
    free = build_free_space(workspace(obstacles))
    expected = shapely.box(0.0, 0.0, 50.0, 50.0)
    for o in obstacles:
        expected = expected.difference(Polygon(o))
    assert free.equals(shapely.normalize(expected))
    assert free.area == pytest.approx(expected.area)


def test_without_obstacles_the_region_itself() -> None:
    exterior = ((0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0))
    free = build_free_space(WorkspaceConfig(free_space=FreeSpaceConfig(exterior=exterior)))
    assert free.equals(Polygon(exterior))


def test_an_invalid_obstacle_is_still_named() -> None:
    bowtie = ((1.0, 1.0), (2.0, 2.0), (2.0, 1.0), (1.0, 2.0))
    with pytest.raises(ScenarioError, match=r"obstacles\[1\]"):
        build_free_space(workspace((squares(1)[0], bowtie)))
