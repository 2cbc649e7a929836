"""The compiled 2D primitives against shapely, on random and on lattice (degenerate) input.

Points are ``(x, y)`` tuples and boxes ``(x0, y0, x1, y1)``. Lattice coordinates make touching,
collinear and zero-length segments frequent, where only exact predicates agree.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import LineString, Point, box

from platoon_env.geometry import primitives


def _segment(a: tuple[float, float], b: tuple[float, float]) -> LineString | Point:
    return Point(a) if a == b else LineString([a, b])


def _points(rng: np.random.Generator, lattice: bool, n: int) -> list[tuple[float, float]]:
    xy = rng.integers(-3, 4, size=(n, 2)).astype(float) if lattice else rng.uniform(-3, 3, (n, 2))
    return [(float(x), float(y)) for x, y in xy]


@pytest.mark.parametrize("lattice", [False, True], ids=["random", "lattice"])
def test_segment_predicates_and_distances_match_shapely(lattice: bool) -> None:
    rng = np.random.default_rng(5)
    for _ in range(3000):
        a, b, c, d = _points(rng, lattice, 4)
        ab, cd = _segment(a, b), _segment(c, d)
        context = f"{a}, {b}, {c}, {d}"
        assert primitives.segments_intersect(a, b, c, d) == ab.intersects(cd), context
        expected = Point(c).distance(ab)
        distance2 = primitives.point_segment_distance2(c, a, b)
        assert distance2 == pytest.approx(expected**2, abs=1e-12), context


def test_boxes_match_shapely() -> None:
    rng = np.random.default_rng(6)
    for _ in range(2000):
        lo = rng.uniform(-3, 3, size=(2, 2))
        size = rng.uniform(0, 2, size=(2, 2)) * (rng.random((2, 1)) < 0.8)  # some are points
        a = (*lo[0], *(lo[0] + size[0]))
        b = (*lo[1], *(lo[1] + size[1]))
        ga, gb = box(*a), box(*b)
        expected = ga.distance(gb)
        assert primitives.box_distance2(a, b) == pytest.approx(expected**2, abs=1e-12)
        assert primitives.boxes_overlap(a, b) == ga.intersects(gb)
        p = (float(lo[0, 0]), float(lo[1, 1]))
        assert primitives.point_box_distance2(p, b) == primitives.box_distance2((*p, *p), b)
        expected = gb.distance(Point(p))
        assert primitives.point_box_distance2(p, b) == pytest.approx(expected**2, abs=1e-12)


def test_cross_and_wrap_angle() -> None:
    assert primitives.cross((1.0, 0.0), (0.0, 1.0)) == 1.0
    assert primitives.cross((0.0, 1.0), (1.0, 0.0)) == -1.0
    assert primitives.cross((2.0, 3.0), (4.0, 6.0)) == 0.0
    assert primitives.wrap_angle(-math.pi) == math.pi
    assert primitives.wrap_angle(0.3) == 0.3
    assert primitives.wrap_angle(0.3 + 4 * math.pi) == pytest.approx(0.3)
