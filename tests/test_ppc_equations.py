"""Unit tests of the PPC law (paper section 3, eqs. 7 and 10-14) in ``baselines.ppc``.

The env is replaced by a ``SimpleNamespace`` stand-in with study C's parameters (docs/scenarios.md):
r = 0.15, d_des = 1, d_col = 0.3, d_con = 1.5, beta_con = 0.4, lambda = 0.5, rho_d_inf = 0.05,
rho_beta_inf = 0.1, k_d = 1, k_beta = 2, delta = 0.5, epsilon = 0.75, dt = 0.01.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from baselines import Policy, PPCPolicy
from baselines.ppc import (
    CLEARANCE_FLOOR,
    EPS_MAX,
    PPC_KERNEL_DTYPE,
    PPC_SET_DTYPE,
    RHO_NAMES,
    SIGNAL_NAMES,
    F,
    S,
    _ppc_step,
    angular_velocity,
    clearance_margin,
    compensation,
    initial_rho,
    linear_velocity,
    outside_funnel,
    performance_sets,
    projection,
    rho_dot,
    transformed_error,
)
from platoon_env.scenarios.schema import ObservationConfig, PPCConfig

R, D_DES, D_COL, D_CON, BETA_CON = 0.15, 1.0, 0.3, 1.5, 0.4
LAM, RHO_D_INF, RHO_B_INF, K_D, K_B, DELTA, EPS, DT = 0.5, 0.05, 0.1, 1.0, 2.0, 0.5, 0.75, 0.01
STUDY_C_PPC = PPCConfig(
    lambda_=LAM,
    rho_d_inf=RHO_D_INF,
    rho_beta_inf=RHO_B_INF,
    k_d=K_D,
    k_beta=K_B,
    delta=DELTA,
    epsilon=EPS,
)
RHO_MIN, RHO_MAX = performance_sets(D_DES, D_COL, D_CON, BETA_CON, RHO_D_INF, RHO_B_INF)
FAR = D_CON  # clearances capped at the proximity range: no obstacle nearby


def make_env(n: int = 2, ppc: PPCConfig | None = STUDY_C_PPC, dt: float = DT) -> Any:
    config = SimpleNamespace(
        name="study_c_stand_in",
        ppc=ppc,
        formation=SimpleNamespace(d_des=D_DES),
        safety=SimpleNamespace(d_col=D_COL),
        camera=SimpleNamespace(range=D_CON, half_angle=BETA_CON),
        robot=SimpleNamespace(radius=R),
        observation=ObservationConfig(),  # the 7-vector in metres
    )
    return SimpleNamespace(
        possible_agents=[f"follower_{i + 1}" for i in range(n)],
        control_period=dt,
        scenario=SimpleNamespace(config=config),
    )


def obs_vec(
    d: float = D_DES,
    beta: float = 0.0,
    walls: tuple[float, float] = (FAR, FAR),
    sight: tuple[float, float] = (FAR, FAR),
    visible: bool = True,
) -> np.ndarray:
    """[visible, x_rel, y_rel, d_W_l, d_W_r, d_l, d_r] as the env reports it."""
    if not visible:
        return np.array([0.0, 0.0, 0.0, *walls, *sight], dtype=np.float32)
    x, y = d * math.cos(beta), d * math.sin(beta)
    return np.array([1.0, x, y, *walls, *sight], dtype=np.float32)


def all_obs(policy: PPCPolicy, vec: np.ndarray) -> dict[str, np.ndarray]:
    return {a: vec.copy() for a in policy.agents}


def converged_policy(n: int = 2) -> PPCPolicy:
    """A policy whose performance functions have converged to -+rho_inf (30 s, no obstacles)."""
    policy = PPCPolicy(make_env(n))
    obs = all_obs(policy, obs_vec())
    for _ in range(3000):
        policy.act(obs)
    return policy


# ---------------------------------------------------------------------------------------------
# Pure functions, hand-computed values
# ---------------------------------------------------------------------------------------------


def test_S_hand_values() -> None:
    assert float(S(0.0, 0.5)) == pytest.approx(1.0)
    assert float(S(0.1, 0.5)) == pytest.approx(0.8)
    assert float(S(0.25, 0.5)) == pytest.approx(0.5)
    assert float(S(0.5, 0.5)) == 0.0  # [delta, inf) -> 0
    assert float(S(3.0, 0.5)) == 0.0


def test_F_hand_values() -> None:
    # m = min(d_l - r, d_W_l - r) = min(0.4, 0.3) - 0.15 = 0.15
    m = float(clearance_margin(0.4, 0.3, R))
    assert m == pytest.approx(0.15)
    assert float(F(m, DELTA)) == pytest.approx((1 - 0.15 / 0.5) / 0.15)  # 4.6667
    assert float(F(0.25, DELTA)) == pytest.approx(2.0)  # S = 0.5, / 0.25
    assert float(F(0.1, DELTA)) == pytest.approx(8.0)  # S = 0.8, / 0.1


def test_F_vanishes_beyond_delta_and_grows_as_clearance_closes() -> None:
    assert np.all(F(np.linspace(DELTA, 2.0, 20), DELTA) == 0.0)
    m = np.linspace(DELTA, CLEARANCE_FLOOR, 200)  # the clearance closes
    values = F(m, DELTA)
    assert values[0] == 0.0
    assert np.all(np.diff(values) > 0.0)
    # at and beyond contact (m <= 0) the margin is floored: F is finite and maximal
    top = 1.0 / CLEARANCE_FLOOR - 1.0 / DELTA
    assert np.allclose(F(np.array([CLEARANCE_FLOOR, 0.0, -0.2]), DELTA), top)


def test_initial_values_and_sets_eq12() -> None:
    np.testing.assert_allclose(initial_rho(D_DES, D_COL, D_CON, BETA_CON), [-0.7, 0.5, -0.4, 0.4])
    np.testing.assert_allclose(RHO_MIN, [-0.7, -0.6, -0.4, -0.2])
    np.testing.assert_allclose(RHO_MAX, [0.4, 0.5, 0.2, 0.4])


def test_rho_dot_hand_values_eq12() -> None:
    rho = np.array([-0.7, 0.5, -0.4, 0.4])
    # F_l = 2, F_r = 1
    got = rho_dot(rho, 2.0, 1.0, LAM, RHO_D_INF, RHO_B_INF)
    expected = [
        -0.5 * (-0.7 + 0.05) - 1 - 2,  # 12a
        -0.5 * (0.5 - 0.05) - 1 - 2,  # 12b
        -0.5 * (-0.4 + 0.1) - 1 + 2,  # 12c
        -0.5 * (0.4 - 0.1) - 1 + 2,  # 12d
    ]
    np.testing.assert_allclose(got, expected)


def test_projection_hand_values() -> None:
    # set [0, 1], epsilon = 0.75: at rho = 0.95, x = 0.9, f = (0.81 - 0.5625)/0.4375
    f = (0.81 - 0.5625) / 0.4375
    assert float(projection(1.0, 0.95, 0.0, 1.0, EPS)) == pytest.approx(1.0 - f)  # outward: scaled
    assert float(projection(-1.0, 0.95, 0.0, 1.0, EPS)) == -1.0  # inward: untouched
    assert float(projection(-1.0, 0.05, 0.0, 1.0, EPS)) == pytest.approx(-(1.0 - f))
    assert float(projection(1.0, 0.05, 0.0, 1.0, EPS)) == 1.0
    assert float(projection(5.0, 1.0, 0.0, 1.0, EPS)) == pytest.approx(0.0)  # f = 1 on the bound
    assert float(projection(-5.0, 0.0, 0.0, 1.0, EPS)) == pytest.approx(0.0)
    # at |x| = epsilon, f = 0: still the identity
    assert float(projection(3.0, 0.875, 0.0, 1.0, EPS)) == pytest.approx(3.0)


def test_projection_is_identity_well_inside() -> None:
    rng = np.random.default_rng(1)
    for lo, hi in zip(RHO_MIN, RHO_MAX, strict=True):
        x = rng.uniform(-EPS, EPS, 500)  # normalised position, |x| < epsilon
        rho = (hi + lo) / 2 + x * (hi - lo) / 2
        rd = rng.normal(0.0, 100.0, 500)
        np.testing.assert_array_equal(projection(rd, rho, lo, hi, EPS), rd)


def test_projection_keeps_rho_in_its_set_continuous_time() -> None:
    """The operator alone (no clipping) keeps rho in its set under a large rate, for a step small
    enough to resolve the continuous dynamics (h |rho_dot| < (max - min)(1 - eps^2)/4)."""
    h = 2e-4
    lo = np.repeat(RHO_MIN, 2)
    hi = np.repeat(RHO_MAX, 2)
    rd = np.tile([100.0, -100.0], 4)  # push each of the four functions up and down
    rho = np.repeat(initial_rho(D_DES, D_COL, D_CON, BETA_CON), 2)
    for _ in range(5000):  # 1 s: unprojected, rho would travel 100
        rho = rho + h * projection(rd, rho, lo, hi, EPS)
        assert np.all(rho >= lo) and np.all(rho <= hi)
    np.testing.assert_allclose(rho, np.where(rd > 0, hi, lo), atol=1e-3)  # pushed to the bound


def test_transformed_error_hand_values_and_clamp() -> None:
    assert float(transformed_error(0.1, -0.2, 0.3)) == pytest.approx(math.log(1.5))
    assert float(transformed_error(0.05, -0.2, 0.3)) == pytest.approx(0.0)  # mid-funnel
    assert float(transformed_error(-0.1, -0.2, 0.3)) == pytest.approx(math.log(0.1 / 0.4))
    # out of the funnel (or on a bound): finite, saturated at -+EPS_MAX
    got = transformed_error(np.array([-0.5, -0.2, 0.3, 0.9]), -0.2, 0.3)
    np.testing.assert_array_equal(got, [-EPS_MAX, -EPS_MAX, EPS_MAX, EPS_MAX])
    assert outside_funnel(0.3, -0.2, 0.3) and not outside_funnel(0.29, -0.2, 0.3)


def test_compensation_hand_value() -> None:
    # e = 0.1 in (-0.2, 0.3), lo_dot = 0.4, hi_dot = -0.1
    # C = (lo_dot (hi - e) + hi_dot (e - lo)) / (hi - lo) = (0.4*0.2 - 0.1*0.3)/0.5 = 0.1
    assert float(compensation(0.1, -0.2, 0.3, 0.4, -0.1)) == pytest.approx(0.1)


def test_linear_velocity_eq13_hand_value() -> None:
    eps_d = math.log(1.5)
    u = float(linear_velocity(eps_d, 0.2, 0.1, K_D))
    assert u == pytest.approx((1.0 * math.log(1.5) - 0.1) / math.cos(0.2))
    assert u == pytest.approx(0.311678, abs=1e-6)


def test_angular_velocity_eq14_hand_value() -> None:
    omega = float(angular_velocity(2.0, 1.25, 0.2, 0.3, 0.05, K_B))
    assert omega == pytest.approx(2.0 / 1.25 * math.sin(0.2) + 2.0 * 0.3 - 0.05)
    assert omega == pytest.approx(0.867871, abs=1e-6)


def test_compensation_is_the_derivation_one_finite_differences() -> None:
    """eps_dot = J (e_dot - C) with J = (hi - lo)/((e - lo)(hi - e)) holds for the derivation's
    C = (lo_dot (hi - e) + hi_dot (e - lo))/(hi - lo), not for eqs. 13-14 as printed
    (hi_dot (hi - e) + lo_dot (e - lo))/(hi - lo)."""

    def lo(t: float) -> float:
        return -0.5 + 0.3 * math.sin(t)

    def hi(t: float) -> float:
        return 0.6 + 0.2 * math.cos(2 * t)

    def e(t: float) -> float:
        return 0.1 * math.sin(3 * t)

    def deriv(fn: Any, t: float, h: float = 1e-5) -> float:
        return (fn(t + h) - fn(t - h)) / (2 * h)

    def eps(t: float) -> float:
        return float(transformed_error(e(t), lo(t), hi(t)))

    for t in (0.3, 0.7, 1.9, 2.6):
        assert lo(t) < e(t) < hi(t)
        lo_dot, hi_dot, e_dot = deriv(lo, t), deriv(hi, t), deriv(e, t)
        jac = (hi(t) - lo(t)) / ((e(t) - lo(t)) * (hi(t) - e(t)))
        c_derivation = float(compensation(e(t), lo(t), hi(t), lo_dot, hi_dot))
        c_printed = (hi_dot * (hi(t) - e(t)) + lo_dot * (e(t) - lo(t))) / (hi(t) - lo(t))
        eps_dot = deriv(eps, t)
        assert eps_dot == pytest.approx(jac * (e_dot - c_derivation), rel=1e-6, abs=1e-8)
        assert abs(eps_dot - jac * (e_dot - c_printed)) > 1e-2


# ---------------------------------------------------------------------------------------------
# Update laws (eq. 12) inside the policy
# ---------------------------------------------------------------------------------------------


def test_update_law_without_obstacles_converges_to_rho_inf() -> None:
    policy = converged_policy()
    expected = np.array([-RHO_D_INF, RHO_D_INF, -RHO_B_INF, RHO_B_INF])[:, None]
    np.testing.assert_allclose(policy.rho, np.broadcast_to(expected, (4, 2)), atol=1e-5)
    assert policy.funnel_exits.sum() == 0


def _step_rho(policy: PPCPolicy, vec: np.ndarray, steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
    before = policy.rho
    for _ in range(steps):
        policy.act(all_obs(policy, vec))
    return before, policy.rho


def test_distance_bounds_fall_with_obstacles_on_both_sides() -> None:
    policy = converged_policy()
    vec = obs_vec(walls=(0.4, 0.4), sight=(0.3, 0.3))  # m = 0.15 on both sides
    before, after = _step_rho(policy, vec)
    sig = policy.signals
    assert np.all(sig["F_l"] > 0) and np.allclose(sig["F_l"], sig["F_r"])
    assert np.all(after[0] < before[0]) and np.all(after[1] < before[1])  # rho_d_lo, rho_d_hi
    np.testing.assert_allclose(after[2:], before[2:], atol=1e-9)  # F_l = F_r: angles unmoved
    for _ in range(300):  # they keep falling, inside their sets
        before, after = _step_rho(policy, vec)
        assert np.all(after[:2] <= before[:2] + 1e-15)
        assert np.all(after >= RHO_MIN[:, None]) and np.all(after <= RHO_MAX[:, None])
    assert np.all(after[0] < -RHO_D_INF) and np.all(after[1] < RHO_D_INF)


def test_angle_bounds_increase_with_left_obstacle_and_decrease_with_right() -> None:
    for side, sign in (("left", 1.0), ("right", -1.0)):
        policy = converged_policy()
        sight = (0.3, FAR) if side == "left" else (FAR, 0.3)
        before, after = _step_rho(policy, obs_vec(sight=sight), steps=5)
        sig = policy.signals
        assert (sig["F_l"] > 0).all() == (side == "left")
        assert (sig["F_r"] > 0).all() == (side == "right")
        assert np.all(sign * (after[2] - before[2]) > 0)  # rho_beta_lo
        assert np.all(sign * (after[3] - before[3]) > 0)  # rho_beta_hi
        assert np.all(after[:2] < before[:2])  # a single obstacle also shortens the distance


def test_policy_keeps_rho_in_sets_under_extreme_clearances() -> None:
    """Clearances at and beyond contact (margin floored), alternating sides, many steps."""
    policy = PPCPolicy(make_env(3))
    patterns = [
        obs_vec(walls=(0.0, FAR), sight=(0.0, FAR)),
        obs_vec(walls=(FAR, 0.1), sight=(FAR, 0.0)),
        obs_vec(walls=(0.0, 0.0), sight=(0.0, 0.0)),
        obs_vec(),
    ]
    for k in range(2000):
        policy.act(all_obs(policy, patterns[(k // 100) % 4]))
        rho = policy.rho
        assert np.all(rho >= RHO_MIN[:, None]) and np.all(rho <= RHO_MAX[:, None])
        for value in policy.signals.values():
            assert np.all(np.isfinite(value))
    assert np.all(policy.clearance_floor_hits == 1500)
    sig = policy.signals
    assert np.all(sig["rho_d_lo"] < sig["rho_d_hi"])
    assert np.all(sig["rho_beta_lo"] < sig["rho_beta_hi"])


# ---------------------------------------------------------------------------------------------
# Commands, exits, invisibility, bookkeeping
# ---------------------------------------------------------------------------------------------


def test_first_step_matches_hand_computation() -> None:
    """Fresh policy (eq.-12 initial values), no obstacles, d = 1.1, beta = 0.1."""
    policy = PPCPolicy(make_env(1))
    d, beta = 1.1, 0.1
    out = policy.act({"follower_1": obs_vec(d, beta)})["follower_1"]
    assert out.dtype == np.float32 and out.shape == (2,)
    # rho = (-0.7, 0.5, -0.4, 0.4); unprojected rates -lambda (rho -+ rho_inf):
    rd = np.array([0.325, -0.225, 0.15, -0.15])  # all point inward: projection inactive
    e_d = d - D_DES
    eps_d = math.log((e_d + 0.7) / (0.5 - e_d))
    c_d = (rd[0] * (0.5 - e_d) + rd[1] * (e_d + 0.7)) / 1.2
    u = (K_D * eps_d - c_d) / math.cos(beta)
    eps_b = math.log((beta + 0.4) / (0.4 - beta))
    c_b = (rd[2] * (0.4 - beta) + rd[3] * (beta + 0.4)) / 0.8
    omega = u / d * math.sin(beta) + K_B * eps_b - c_b
    np.testing.assert_allclose(out, [u, omega], rtol=1e-6)
    sig = policy.signals
    assert sig["e_d"][0] == pytest.approx(e_d, abs=1e-6)
    assert sig["eps_beta"][0] == pytest.approx(eps_b, rel=1e-5)
    np.testing.assert_allclose([sig[f"{n}_dot"][0] for n in RHO_NAMES], rd)
    # rho advanced by one Euler step after the command
    np.testing.assert_allclose(policy.rho[:, 0], [-0.7, 0.5, -0.4, 0.4] + DT * rd)


def test_funnel_exit_is_finite_flagged_and_counted() -> None:
    policy = converged_policy()
    for d, sign in ((D_DES + 0.3, 1.0), (D_DES - 0.3, -1.0)):  # e_d beyond rho_d_hi / rho_d_lo
        out = policy.act(all_obs(policy, obs_vec(d=d)))
        sig = policy.signals
        assert np.all(sig["funnel_exit"])
        np.testing.assert_allclose(sig["eps_d"], sign * EPS_MAX)
        for a in out.values():
            assert np.all(np.isfinite(a))
        assert np.all(sign * sig["u"] > 0)  # pushes e_d back: forward when too far
    out = policy.act(all_obs(policy, obs_vec(beta=0.35)))  # e_beta beyond rho_beta_hi
    assert np.all(policy.signals["funnel_exit"])
    np.testing.assert_allclose(policy.signals["eps_beta"], EPS_MAX)
    assert np.all(policy.signals["omega"] > 0)  # turns towards the predecessor
    np.testing.assert_array_equal(policy.funnel_exits, [3, 3])


def test_invisible_predecessor_stops_and_is_recorded() -> None:
    policy = converged_policy()
    obs = {
        "follower_1": obs_vec(visible=False, sight=(0.3, FAR)),
        "follower_2": obs_vec(d=1.02, beta=0.05),
    }
    before = policy.rho
    out = policy.act(obs)
    np.testing.assert_array_equal(out["follower_1"], [0.0, 0.0])
    assert np.all(out["follower_2"] != 0.0)
    sig = policy.signals
    assert list(sig["visible"]) == [False, True]
    assert not sig["funnel_exit"][0]
    for key in ("d", "beta", "e_d", "e_beta", "eps_d", "eps_beta", "C_d", "C_beta"):
        assert sig[key][0] == 0.0
    for value in sig.values():
        assert np.all(np.isfinite(value))
    np.testing.assert_array_equal(policy.invisible_steps, [1, 0])
    assert policy.rho[2, 0] > before[2, 0]  # eq. 12 still runs on the proximity sensor


def test_degenerate_observation_stays_finite() -> None:
    policy = PPCPolicy(make_env(2))
    bad = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)  # visible at d = 0
    side = np.array([1.0, 0.0, 0.8, FAR, FAR, FAR, FAR], dtype=np.float32)  # beta = pi/2
    out = policy.act({"follower_1": bad, "follower_2": side})
    for a in out.values():
        assert np.all(np.isfinite(a))
    assert np.all(policy.signals["funnel_exit"])


def reference_step(
    rho: np.ndarray, ob: np.ndarray
) -> tuple[np.ndarray, float, float, dict[str, float]]:
    """One follower, one step, from the module's scalar equations (no vectorisation)."""
    visible = ob[0] > 0.5
    f_l = float(F(clearance_margin(ob[5], ob[3], R), DELTA))
    f_r = float(F(clearance_margin(ob[6], ob[4], R), DELTA))
    rates = rho_dot(rho, f_l, f_r, LAM, RHO_D_INF, RHO_B_INF)
    pd = np.array(
        [float(projection(rates[k], rho[k], RHO_MIN[k], RHO_MAX[k], EPS)) for k in range(4)]
    )
    u = omega = 0.0
    eps_d = eps_b = 0.0
    if visible:
        d = math.hypot(ob[1], ob[2])
        beta = math.atan2(ob[2], ob[1])
        e_d = d - D_DES
        eps_d = float(transformed_error(e_d, rho[0], rho[1]))
        eps_b = float(transformed_error(beta, rho[2], rho[3]))
        c_d = float(compensation(e_d, rho[0], rho[1], pd[0], pd[1]))
        c_b = float(compensation(beta, rho[2], rho[3], pd[2], pd[3]))
        u = float(linear_velocity(eps_d, beta, c_d, K_D))
        omega = float(angular_velocity(u, d, beta, eps_b, c_b, K_B))
    new_rho = np.clip(rho + DT * pd, RHO_MIN, RHO_MAX)
    return new_rho, u, omega, {"F_l": f_l, "F_r": f_r, "eps_d": eps_d, "eps_beta": eps_b}


def test_vectorised_act_matches_per_follower_computation() -> None:
    n = 7
    policy = PPCPolicy(make_env(n))
    rng = np.random.default_rng(7)
    rho_ref = [initial_rho(D_DES, D_COL, D_CON, BETA_CON) for _ in range(n)]
    for _ in range(300):
        obs = {}
        for a in policy.agents:
            d = rng.uniform(0.35, 1.45)
            beta = rng.uniform(-0.38, 0.38)
            clear = rng.uniform(0.0, 1.0, 4)
            clear[rng.uniform(size=4) < 0.5] = FAR
            obs[a] = obs_vec(
                d, beta, (clear[0], clear[1]), (clear[2], clear[3]), rng.uniform() > 0.1
            )
        out = policy.act(obs)
        sig = policy.signals
        for i, a in enumerate(policy.agents):
            rho_ref[i], u, omega, extra = reference_step(rho_ref[i], obs[a].astype(np.float64))
            np.testing.assert_allclose(
                out[a], np.array([u, omega], dtype=np.float32), rtol=1e-5, atol=1e-5
            )
            assert sig["u"][i] == pytest.approx(u, rel=1e-9, abs=1e-9)
            assert sig["omega"][i] == pytest.approx(omega, rel=1e-9, abs=1e-9)
            for key, value in extra.items():
                assert sig[key][i] == pytest.approx(value, rel=1e-9, abs=1e-9)
        np.testing.assert_allclose(policy.rho, np.array(rho_ref).T, rtol=0, atol=1e-12)


def test_subset_of_agents_keeps_the_others_state() -> None:
    policy = converged_policy(3)
    rho_before = policy.rho
    vec = obs_vec(sight=(0.3, FAR))
    out = policy.act({"follower_3": vec, "follower_1": vec})
    assert list(out) == ["follower_3", "follower_1"]
    rho = policy.rho
    np.testing.assert_array_equal(rho[:, 1], rho_before[:, 1])
    assert np.all(rho[2, [0, 2]] > rho_before[2, [0, 2]])
    sig = policy.signals
    assert sig["F_l"][0] > 0 and sig["F_l"][2] > 0 and sig["F_l"][1] == 0.0
    with pytest.raises(KeyError, match="unknown agent"):
        policy.act({"follower_9": vec})


def test_signals_are_copies_with_the_documented_keys() -> None:
    policy = PPCPolicy(make_env(2))
    assert set(policy.signals) == set(SIGNAL_NAMES)
    np.testing.assert_allclose(policy.signals["rho_d_lo"], [-0.7, -0.7])
    policy.act(all_obs(policy, obs_vec(d=1.1)))
    first = policy.signals
    assert set(first) == set(SIGNAL_NAMES)
    assert all(v.shape == (2,) for v in first.values())
    kept = first["rho_d_lo"].copy()
    first["u"][:] = 123.0
    assert not np.any(policy.signals["u"] == 123.0)
    policy.act(all_obs(policy, obs_vec(d=1.1)))
    np.testing.assert_array_equal(first["rho_d_lo"], kept)  # not overwritten by the next act
    assert np.all(policy.signals["rho_d_lo"] > kept)


def test_reset_restores_initial_values_and_clears_counters() -> None:
    policy = converged_policy()
    policy.act(all_obs(policy, obs_vec(d=D_DES + 0.4, walls=(0.0, 0.0))))
    assert policy.funnel_exits.sum() > 0 and policy.clearance_floor_hits.sum() > 0
    policy.reset(seed=3)
    np.testing.assert_allclose(policy.rho[:, 0], [-0.7, 0.5, -0.4, 0.4])
    assert policy.funnel_exits.sum() == policy.invisible_steps.sum() == 0
    assert policy.clearance_floor_hits.sum() == 0 and policy.steps == 0


def test_construction_parameters_and_errors() -> None:
    assert isinstance(PPCPolicy(make_env()), Policy)
    with pytest.raises(ValueError, match="no ppc block"):
        PPCPolicy(make_env(ppc=None))
    full = {"lambda": 1.0, "rho_d_inf": 0.1, "rho_beta_inf": 0.1, "k_d": 4.0, "k_beta": 4.0}
    policy = PPCPolicy(make_env(ppc=None), delta=0.5, epsilon=0.75, **full)
    assert policy.params.lambda_ == 1.0 and policy.params.k_d == 4.0
    policy = PPCPolicy(make_env(), dt=0.005, k_d=3.0, lambda_=2.0)
    assert policy.params.dt == 0.005 and policy.params.k_d == 3.0 and policy.params.lambda_ == 2.0
    assert policy.params.k_beta == K_B and policy.params.r == R and policy.params.d_con == D_CON
    assert PPCPolicy(make_env(dt=0.02)).params.dt == 0.02
    with pytest.raises(TypeError, match="unknown PPC override"):
        PPCPolicy(make_env(), k_p=1.0)
    with pytest.raises(ValueError, match="epsilon"):
        PPCPolicy(make_env(), epsilon=1.5)


def test_closed_loop_unicycle_pair_stays_in_funnels() -> None:
    """Exact unicycle kinematics (eq. 1), leader driving straight: errors stay in their funnels
    and settle within -+rho_inf (checks the sign conventions of eqs. 8-9 and 13-14)."""
    policy = PPCPolicy(make_env(1))
    leader = np.array([1.2, 0.1, 0.0])
    follower = np.array([0.0, 0.0, 0.15])
    for _ in range(4000):  # 40 s
        rel = leader[:2] - follower[:2]
        c, s = math.cos(follower[2]), math.sin(follower[2])
        ob = obs_vec(walls=(FAR, FAR))
        ob[1], ob[2] = c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1]
        u, omega = policy.act({"follower_1": ob})["follower_1"]
        assert not policy.signals["funnel_exit"][0]
        leader += DT * np.array([0.3, 0.0, 0.0])
        follower += DT * np.array([u * math.cos(follower[2]), u * math.sin(follower[2]), omega])
    sig = policy.signals
    assert abs(sig["e_d"][0]) < RHO_D_INF and abs(sig["e_beta"][0]) < RHO_B_INF
    assert policy.funnel_exits[0] == 0


def test_kernel_constants_by_name() -> None:
    """The compiled core's constants: one PPC_KERNEL_DTYPE record and one PPC_SET_DTYPE record per
    performance function, filled from the parameters."""
    policy = PPCPolicy(make_env(2))
    params, sets = policy._kernel_params, policy._kernel_sets
    assert params.dtype == PPC_KERNEL_DTYPE and params.shape == (1,)
    assert sets.dtype == PPC_SET_DTYPE and sets.shape == (4,)
    p = params[0]
    assert (p["r"], p["d_des"], p["delta"], p["lambda_"]) == (R, D_DES, DELTA, LAM)
    assert (p["k_d"], p["k_beta"], p["dt"]) == (K_D, K_B, DT)
    assert (p["clearance_floor"], p["eps_max"]) == (CLEARANCE_FLOOR, EPS_MAX)
    assert p["f_scale"] == pytest.approx(1 / (1 - EPS**2))
    assert p["f_offset"] == pytest.approx(EPS**2 / (1 - EPS**2))
    np.testing.assert_array_equal(sets["rho_min"], RHO_MIN)
    np.testing.assert_array_equal(sets["rho_max"], RHO_MAX)
    rho_inf = np.array([-RHO_D_INF, RHO_D_INF, -RHO_B_INF, RHO_B_INF])
    np.testing.assert_allclose(sets["lam_target"], LAM * rho_inf)
    # Proj's normalised position x = rho inv_half - mid_inv_half is -1 / +1 on the bounds
    np.testing.assert_allclose(RHO_MIN * sets["inv_half"] - sets["mid_inv_half"], -1.0)
    np.testing.assert_allclose(RHO_MAX * sets["inv_half"] - sets["mid_inv_half"], 1.0)


def test_compiled_core_matches_the_pure_functions() -> None:
    """The compiled per-step core (``_ppc_step``) against the pure-function pipeline on 1,000
    random observations of 1,000 of 1,200 followers, in random order, from random performance
    functions (projection active near the bounds), with invisible predecessors, funnel exits and
    clearances at or beyond contact (margin floored); the other 200 followers are untouched."""
    n_all, n = 1200, 1000
    rng = np.random.default_rng(11)
    policy = PPCPolicy(make_env(n_all))
    # performance functions anywhere in their sets with lo < hi (as the law keeps them; a
    # collapsed funnel makes C ill-conditioned), 10% of them on a bound
    mid, half = (RHO_MAX + RHO_MIN)[:, None] / 2, (RHO_MAX - RHO_MIN)[:, None] / 2
    rho0 = np.empty((4, n_all))
    todo = np.ones(n_all, dtype=bool)
    while todo.any():
        xpos = rng.uniform(-1.0, 1.0, (4, n_all))
        on_bound = rng.uniform(size=xpos.shape) < 0.1
        xpos[on_bound] = rng.choice([-1.0, 1.0], size=on_bound.sum())
        draw = np.clip(mid + xpos * half, RHO_MIN[:, None], RHO_MAX[:, None])
        rho0[:, todo] = draw[:, todo]
        todo = (rho0[1] - rho0[0] < 0.05) | (rho0[3] - rho0[2] < 0.05)
    policy._rho[...] = rho0
    sig_before = policy._sig.copy()
    counts_before = np.array([[3], [5], [7]]) * np.ones((3, n_all), dtype=np.int64)
    policy._counts[...] = counts_before

    idx = rng.permutation(n_all)[:n].astype(np.intp)
    visible = rng.uniform(size=n) > 0.2
    d = rng.uniform(1e-3, 2.0, n)
    beta = rng.uniform(-0.7, 0.7, n)
    behind = rng.uniform(size=n) < 0.02
    beta[behind] = rng.choice([-1.6, 1.6], size=behind.sum())  # cos(beta) < 0: floored
    clear = rng.uniform(0.0, 1.0, (n, 4))
    special = rng.uniform(size=clear.shape)
    clear[special < 0.3] = FAR
    clear[(special >= 0.3) & (special < 0.35)] = R  # at contact: m = 0
    clear[(special >= 0.35) & (special < 0.4)] = R + CLEARANCE_FLOOR / 2  # below the floor
    clear[(special >= 0.4) & (special < 0.45)] = 0.0  # beyond contact: m = -r
    obs = np.zeros((n, 7))
    obs[:, 0] = visible
    obs[:, 1] = np.where(visible, d * np.cos(beta), 0.0)
    obs[:, 2] = np.where(visible, d * np.sin(beta), 0.0)
    obs[:, 3:] = clear

    cmd = _ppc_step(
        obs,
        idx,
        policy._kernel_params,
        policy._kernel_sets,
        policy._rho,
        policy._sig,
        policy._counts,
    )

    # the pure-function pipeline, vectorised over the 1,000 followers
    rho = rho0[:, idx]
    floored = (clearance_margin(obs[:, 5], obs[:, 3], R) < CLEARANCE_FLOOR) | (
        clearance_margin(obs[:, 6], obs[:, 4], R) < CLEARANCE_FLOOR
    )
    f_l = F(clearance_margin(obs[:, 5], obs[:, 3], R), DELTA)
    f_r = F(clearance_margin(obs[:, 6], obs[:, 4], R), DELTA)
    rates = rho_dot(rho, f_l, f_r, LAM, RHO_D_INF, RHO_B_INF)
    pd = projection(rates, rho, RHO_MIN[:, None], RHO_MAX[:, None], EPS)
    d_obs = np.hypot(obs[:, 1], obs[:, 2])
    b_obs = np.arctan2(obs[:, 2], obs[:, 1])
    e_d = np.where(visible, d_obs - D_DES, 0.0)
    e_b = np.where(visible, b_obs, 0.0)
    exits = visible & (outside_funnel(e_d, rho[0], rho[1]) | outside_funnel(e_b, rho[2], rho[3]))
    eps_d = np.where(visible, transformed_error(e_d, rho[0], rho[1]), 0.0)
    eps_b = np.where(visible, transformed_error(e_b, rho[2], rho[3]), 0.0)
    c_d = np.where(visible, compensation(e_d, rho[0], rho[1], pd[0], pd[1]), 0.0)
    c_b = np.where(visible, compensation(e_b, rho[2], rho[3], pd[2], pd[3]), 0.0)
    u = np.where(visible, linear_velocity(eps_d, b_obs, c_d, K_D), 0.0)
    omega = np.where(visible, angular_velocity(u, d_obs, b_obs, eps_b, c_b, K_B), 0.0)
    assert exits.sum() > 100 and (~visible).sum() > 100 and floored.sum() > 100
    assert (visible & (np.cos(b_obs) < 0)).sum() > 0

    # the projection's f is computed in another (algebraically equal) form, so the projected
    # rates and what depends on them agree to a few ulps of the unprojected rates
    rate_scale = np.abs(rates).max(axis=0)
    sig = policy._sig
    expected = {
        **{name: rho[k] for k, name in enumerate(RHO_NAMES)},
        **{f"{name}_dot": pd[k] for k, name in enumerate(RHO_NAMES)},
        "d": np.where(visible, d_obs, 0.0),
        "beta": e_b,
        "e_d": e_d,
        "e_beta": e_b,
        "eps_d": eps_d,
        "eps_beta": eps_b,
        "F_l": f_l,
        "F_r": f_r,
        "C_d": c_d,
        "C_beta": c_b,
        "u": u,
        "omega": omega,
        "visible": visible,
        "funnel_exit": exits,
        "clearance_floored": floored,
    }
    assert set(expected) == set(SIGNAL_NAMES)
    for k, name in enumerate(SIGNAL_NAMES):
        got = sig[k, idx]
        if name in ("visible", "funnel_exit", "clearance_floored"):
            np.testing.assert_array_equal(got != 0.0, expected[name], err_msg=name)
        else:
            scale = 1.0 + np.abs(expected[name])
            if name.endswith("_dot") or name in ("C_d", "C_beta", "u", "omega"):
                scale += rate_scale
            np.testing.assert_array_less(np.abs(got - expected[name]) / scale, 1e-12, err_msg=name)
    # the commands are the u, omega signals (checked above) in float32
    uo = np.stack([sig[SIGNAL_NAMES.index("u"), idx], sig[SIGNAL_NAMES.index("omega"), idx]])
    np.testing.assert_array_equal(cmd, uo.T.astype(np.float32))
    assert cmd.dtype == np.float32 and cmd.shape == (n, 2)
    new_rho = np.clip(rho + DT * pd, RHO_MIN[:, None], RHO_MAX[:, None])
    np.testing.assert_allclose(policy._rho[:, idx], new_rho, rtol=0, atol=1e-12)
    increments = np.stack([exits, ~visible, floored]).astype(np.int64)
    np.testing.assert_array_equal(policy._counts[:, idx], counts_before[:, idx] + increments)
    rest = np.setdiff1d(np.arange(n_all), idx)
    np.testing.assert_array_equal(policy._rho[:, rest], rho0[:, rest])
    np.testing.assert_array_equal(policy._sig[:, rest], sig_before[:, rest])
    np.testing.assert_array_equal(policy._counts[:, rest], counts_before[:, rest])
