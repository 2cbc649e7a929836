"""Property tests of the sensing kernel on random worlds (hypothesis).

Worlds are a box with random simple holes, of two kinds:

- *star* holes: star-shaped polygons from sorted angles and random radii (generic positions);
- *lattice* holes: star-shaped polygons with integer vertices, with robots on the half-integer
  lattice, so that lines of sight through vertices, along edges and robots on walls are common.

On each world and random platoon, the kernel must agree with the shapely oracle and satisfy:
``d_l <= d_W_l`` and ``d_r <= d_W_r`` (the segment ``L_i`` contains ``p_i``);
``min(d_W_l, d_W_r) == min(clearance, proximity_range)`` (the closed halves cover the plane);
occluded with ``d_i <= proximity_range`` ⇒ ``d_l == d_r == 0`` (the crossing is sensed: the
proximity range is a disk around the follower); and mirroring the world (``y -> -y``,
``theta -> -theta``) swaps left and right and leaves everything else unchanged (``beta`` changes
sign).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from oracle import (
    assert_agree,
    kernel_sense,
    mirror_geometry,
    mirror_poses,
    named,
    oracle_sense,
)
from shapely.geometry import Polygon, box
from shapely.geometry.base import BaseGeometry
from workspaces import star_polygon

from platoon_env.geometry.sensing import sensing_params

#: Tolerance of the identities between columns (pure rounding noise).
IDENTITY_TOL = 1e-12
N_FOLLOWERS = 3

PROPERTY_SETTINGS = settings(
    deadline=None,
    max_examples=120,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)


@dataclass(frozen=True)
class Scene:
    """A world, a platoon in it and the sensor parameters."""

    free_space: Polygon
    poses: NDArray[np.float64]
    d_con: float
    beta_con: float
    proximity_range: float

    def params(self) -> np.void:
        """The sensors as the params record both senses read."""
        return sensing_params(
            d_con=self.d_con, beta_con=self.beta_con, proximity_range=self.proximity_range
        )


# --------------------------------------------------------------------------------------------
# Strategies

WORLD_SIZE = 10.0


@st.composite
def star_holes(draw: st.DrawFn) -> list[Polygon]:
    """One to three disjoint star-shaped holes, well inside the ``[0, 10]^2`` box."""
    holes: list[Polygon] = []
    for _ in range(draw(st.integers(1, 3))):
        k = draw(st.integers(3, 9))
        weights = draw(st.lists(st.floats(0.3, 1.0), min_size=k, max_size=k))
        gaps = [2.0 * math.pi * w / sum(weights) for w in weights]
        if max(gaps) >= 0.95 * math.pi:  # keep the centre inside: a simple star polygon
            continue
        start = draw(st.floats(0.0, 2.0 * math.pi))
        angles = [start + sum(gaps[:j]) for j in range(k)]
        radii = draw(st.lists(st.floats(0.2, 1.6), min_size=k, max_size=k))
        centre = (draw(st.floats(1.0, 9.0)), draw(st.floats(1.0, 9.0)))
        hole = star_polygon(centre, angles, radii)
        inner = box(0.05, 0.05, WORLD_SIZE - 0.05, WORLD_SIZE - 0.05)
        if hole.is_valid and inner.contains(hole) and all(hole.distance(h) > 0.05 for h in holes):
            holes.append(hole)
    return holes


@st.composite
def lattice_holes(draw: st.DrawFn) -> list[Polygon]:
    """One to three disjoint star-shaped holes with integer vertices in the ``[0, 10]^2`` box."""
    holes: list[Polygon] = []
    for _ in range(draw(st.integers(1, 3))):
        centre = (draw(st.integers(2, 8)), draw(st.integers(2, 8)))
        offsets = draw(
            st.lists(
                st.tuples(st.integers(-2, 2), st.integers(-2, 2)).filter(lambda o: o != (0, 0)),
                min_size=3,
                max_size=8,
                unique_by=lambda o: math.atan2(o[1], o[0]),
            )
        )
        offsets.sort(key=lambda o: math.atan2(o[1], o[0]))
        angles = [math.atan2(o[1], o[0]) for o in offsets]
        gaps = [b - a for a, b in zip(angles, [*angles[1:], angles[0] + 2 * math.pi], strict=True)]
        if max(gaps) >= math.pi:
            continue
        hole = Polygon([(centre[0] + ox, centre[1] + oy) for ox, oy in offsets])
        inner = box(0.0, 0.0, WORLD_SIZE, WORLD_SIZE)
        if (
            hole.is_valid
            and inner.contains(hole)
            and not hole.touches(inner.exterior)
            and all(hole.distance(h) > 0.0 for h in holes)
        ):
            holes.append(hole)
    return holes


def _world(holes: list[Polygon]) -> Polygon:
    """The box ``[0, 10]^2`` with the given holes."""
    return Polygon(
        box(0.0, 0.0, WORLD_SIZE, WORLD_SIZE).exterior.coords,
        holes=[h.exterior.coords for h in holes],
    )


@st.composite
def generic_platoons(draw: st.DrawFn, free_space: BaseGeometry) -> NDArray[np.float64]:
    """A platoon in the interior of ``free_space``: each follower up to 4 m behind, roughly
    facing its predecessor (coincident robots allowed)."""
    poses = np.empty((N_FOLLOWERS + 1, 3), dtype=np.float64)
    poses[0] = [
        draw(st.floats(0.0, WORLD_SIZE)),
        draw(st.floats(0.0, WORLD_SIZE)),
        draw(st.floats(-math.pi, math.pi)),
    ]
    for i in range(1, N_FOLLOWERS + 1):
        distance = draw(st.floats(0.0, 4.0))
        angle = draw(st.floats(-math.pi, math.pi))
        error = draw(st.floats(-1.5, 1.5))
        poses[i, 0] = poses[i - 1, 0] - distance * math.cos(angle)
        poses[i, 1] = poses[i - 1, 1] - distance * math.sin(angle)
        poses[i, 2] = angle + error
    return poses


@st.composite
def lattice_platoons(draw: st.DrawFn) -> NDArray[np.float64]:
    """A platoon on the half-integer lattice of the box, with random headings."""
    coordinate = st.integers(0, int(2 * WORLD_SIZE)).map(lambda k: k / 2.0)
    rows = [
        [draw(coordinate), draw(coordinate), draw(st.floats(-math.pi, math.pi))]
        for _ in range(N_FOLLOWERS + 1)
    ]
    return np.array(rows, dtype=np.float64)


@st.composite
def scenes(draw: st.DrawFn) -> Scene:
    """A world (star or lattice holes), a platoon in its free space, sensor parameters.

    Generic platoons stay off the walls by more than rounding noise: a robot within 1e-16 m of
    an edge is on it or not depending on whether orientation tests are exact (GEOS) or rounded
    (the kernel), which is no property of the sensing model. Lattice platoons touch walls
    exactly instead (closed free space), where both must agree.
    """
    if draw(st.booleans()):
        free_space = _world(draw(star_holes()))
        poses = draw(generic_platoons(free_space))
        points = shapely.points(poses[:, :2])
        assume(bool(np.all(free_space.contains(points))))
        assume(bool(np.all(shapely.distance(points, free_space.boundary) > 1e-9)))
    else:
        free_space = _world(draw(lattice_holes()))
        poses = draw(lattice_platoons())
        assume(bool(np.all(free_space.covers(shapely.points(poses[:, :2])))))
    d_con = draw(st.sampled_from([1.5, 3.0, 5.0]))
    beta_con = draw(st.sampled_from([0.4, math.pi / 4, 1.3]))
    proximity_range = draw(st.sampled_from([d_con, 0.5, 50.0]))
    return Scene(free_space, poses, d_con, beta_con, proximity_range)


# --------------------------------------------------------------------------------------------
# Properties


@PROPERTY_SETTINGS
@given(scene=scenes())
def test_kernel_matches_oracle(scene: Scene) -> None:
    """The kernel equals the shapely oracle in every column."""
    sensors = (scene.d_con, scene.beta_con, scene.proximity_range)
    assert_agree(
        kernel_sense(scene.free_space, scene.poses, scene.params()),
        oracle_sense(scene.free_space, scene.poses, scene.params()),
        f"poses={scene.poses.tolist()}, sensors={sensors}, world={scene.free_space.wkt}",
    )


def _check_identities(out: NDArray[np.float64], scene: Scene, who: str) -> None:
    """The identities between columns that the definitions imply."""
    prox = scene.proximity_range
    for row in named(out):
        context = f"{who}: row={row}, poses={scene.poses.tolist()}"
        assert row["d_l"] <= row["d_W_l"] + IDENTITY_TOL, context
        assert row["d_r"] <= row["d_W_r"] + IDENTITY_TOL, context
        nearest_side = min(row["d_W_l"], row["d_W_r"])
        assert abs(nearest_side - min(row["clearance"], prox)) <= IDENTITY_TOL, context
        capped = np.array(row[["d_W_l", "d_W_r", "d_l", "d_r"]].tolist())
        assert np.all((capped >= 0.0) & (capped <= prox)), context
        assert -math.pi < row["beta"] <= math.pi, context
        if row["visible"] == 1.0:
            assert row["occluded"] == 0.0, context
            assert row["d"] < scene.d_con and abs(row["beta"]) < scene.beta_con, context


@PROPERTY_SETTINGS
@given(scene=scenes())
def test_sensing_identities(scene: Scene) -> None:
    """``d_l <= d_W_l``, ``d_r <= d_W_r``, ``min(d_W_l, d_W_r) == min(clearance, range)``,
    occluded with the predecessor within the proximity range ⇒ ``d_l == d_r == 0`` (exactly,
    in the kernel); likewise for the oracle. (A crossing beyond the range of the follower is not
    sensed, so a farther predecessor's occluded ``L_i`` may read ``d_l, d_r > 0``.)"""
    kernel = kernel_sense(scene.free_space, scene.poses, scene.params())
    reference = oracle_sense(scene.free_space, scene.poses, scene.params())
    _check_identities(kernel, scene, "kernel")
    _check_identities(reference, scene, "oracle")
    kernel, reference = named(kernel), named(reference)
    in_range = kernel["d"] <= scene.proximity_range
    occluded = (kernel["occluded"] == 1.0) & in_range
    assert np.all(kernel["d_l"][occluded] == 0.0)
    assert np.all(kernel["d_r"][occluded] == 0.0)
    occluded = (reference["occluded"] == 1.0) & in_range
    assert np.all(reference["d_l"][occluded] <= IDENTITY_TOL)
    assert np.all(reference["d_r"][occluded] <= IDENTITY_TOL)


def _mirror_columns(out: NDArray[np.float64]) -> NDArray[np.float64]:
    """What a mirrored world should read: left and right swapped, ``beta`` negated."""
    swapped = out.copy()
    mirrored, original = named(swapped), named(out)
    for left, right in (("d_W_l", "d_W_r"), ("d_l", "d_r")):
        mirrored[left], mirrored[right] = original[right], original[left]
    mirrored["beta"] = -original["beta"]  # assert_agree compares beta on the circle
    return swapped


@PROPERTY_SETTINGS
@given(scene=scenes())
def test_mirrored_world_swaps_left_and_right(scene: Scene) -> None:
    """Mirroring (``y -> -y``, ``theta -> -theta``) swaps the left and right readings."""
    mirrored_world = mirror_geometry(scene.free_space)
    mirrored = kernel_sense(mirrored_world, mirror_poses(scene.poses), scene.params())
    original = kernel_sense(scene.free_space, scene.poses, scene.params())
    assert_agree(mirrored, _mirror_columns(original), f"mirror, poses={scene.poses.tolist()}")


def test_mirror_helpers_are_involutions() -> None:
    """Mirroring twice is the identity (so the mirror test compares like with like)."""
    world = _world([star_polygon((5.0, 5.0), [0.0, 2.0, 4.0], [1.0, 1.5, 0.7])])
    assert mirror_geometry(mirror_geometry(world)).equals_exact(world, 0.0)
    poses = np.array([[1.0, 2.0, 0.3], [4.0, -5.0, -2.0]])
    assert np.array_equal(mirror_poses(mirror_poses(poses)), poses)
