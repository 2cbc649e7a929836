"""Kinematics (eq. 1) against closed forms, and the scripted leader."""

from __future__ import annotations

import math

import numpy as np
import pytest

from platoon_env.dynamics.leader import leader_command, path_arclength, point_at
from platoon_env.dynamics.unicycle import integrate, unicycle_arc
from platoon_env.records import PARAMS_DTYPE


def test_straight_line() -> None:
    x, y, th = unicycle_arc(1.0, 2.0, 0.3, 0.7, 0.0, 2.0)
    assert x == pytest.approx(1.0 + 1.4 * math.cos(0.3), abs=1e-12)
    assert y == pytest.approx(2.0 + 1.4 * math.sin(0.3), abs=1e-12)
    assert th == pytest.approx(0.3)


@pytest.mark.parametrize("u,omega", [(1.0, 0.5), (0.3, -2.0), (-0.5, 1.0), (2.0, 1e-7)])
def test_circle_of_radius_u_over_omega(u: float, omega: float) -> None:
    """The robot stays on the circle of radius u/omega around its initial centre of rotation."""
    pose = np.array([0.5, -1.0, 0.8])
    radius = u / omega
    centre = pose[:2] + radius * np.array([-math.sin(pose[2]), math.cos(pose[2])])
    for h in (0.01, 0.3, 1.7):
        out = integrate(pose, u, omega, h)
        assert np.hypot(*(out[:2] - centre)) == pytest.approx(abs(radius), rel=1e-9)
        assert out[2] == pytest.approx(pose[2] + omega * h)


def test_substeps_compose_exactly() -> None:
    """Exact integration: ten sub-steps equal one step of the same total length."""
    pose = np.array([0.0, 0.0, 0.2])
    one = integrate(pose, 0.8, 1.3, 1.0)
    many = pose
    for _ in range(10):
        many = integrate(many, 0.8, 1.3, 0.1)
    np.testing.assert_allclose(one, many, atol=1e-12)


def test_small_turn_branch_is_continuous() -> None:
    """The Taylor branch for tiny omega agrees with the arc formula at the switch-over."""
    a = integrate(np.array([0.0, 0.0, 1.0]), 1.0, 0.99e-6, 1.0)
    b = integrate(np.array([0.0, 0.0, 1.0]), 1.0, 1.01e-6, 1.0)
    np.testing.assert_allclose(a, b, atol=1e-7)


def test_point_at_and_arclength() -> None:
    path = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]])
    cum = path_arclength(path)
    np.testing.assert_allclose(cum, [0.0, 3.0, 7.0])
    assert point_at(path, cum, 5.0) == pytest.approx((3.0, 2.0))
    assert point_at(path, cum, -1.0) == pytest.approx((0.0, 0.0))
    assert point_at(path, cum, 99.0) == pytest.approx((3.0, 4.0))


def test_leader_follows_path_and_stops_at_end() -> None:
    path = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0]])
    cum = path_arclength(path)
    x, y, th, s = 0.0, 0.0, 0.0, 0.0
    h = 0.01
    p = np.zeros(1, dtype=PARAMS_DTYPE)[0]
    p["leader_speed"], p["lookahead"], p["leader_turn_rate"], p["substep"] = 0.5, 0.5, 1.5, h
    max_dev = 0.0
    arrived = False
    for _ in range(6000):
        u, w, s, arrived = leader_command((path, cum), (x, y, th), s, p)
        if arrived:
            break
        assert abs(w) <= 1.5 + 1e-12
        x, y, th = unicycle_arc(x, y, th, u, w, h)
        dev = min(abs(y) if x <= 5.0 else math.inf, abs(x - 5.0) if y >= 0.0 else math.inf)
        max_dev = max(max_dev, dev)
    assert arrived
    assert math.hypot(x - 5.0, y - 5.0) < 0.01
    assert max_dev < 0.3  # pure pursuit cuts the corner by less than the lookahead
