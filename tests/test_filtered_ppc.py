"""The filtered PPC baseline (baselines/filtered_ppc.py): the filter's equations on hand-computed
cases, its compiled kernels against them, its timing model against the env's camera, and the
policy on short rollouts (ideal sensing: the plain law's commands; dropouts; the aruco profile).
"""

from __future__ import annotations

import inspect
import math
from typing import Any

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import baselines
import platoon_env
from baselines import FilteredPPCPolicy, Policy, PPCPolicy
from baselines.filtered_ppc import (
    FILTER_SIGNAL_NAMES,
    FilterParams,
    _covariance,
    _kernel_params,
    _predict,
    _update,
    actuator_step,
    kf_predict,
    kf_update,
    measurement_covariance,
    odometry_step,
    propagate_mean,
    relative_pose,
)
from baselines.last_seen import ego_motion
from baselines.ppc import SIGNAL_NAMES
from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D
from platoon_env.observation import OBS_VISIBLE, OBS_X_REL, OBS_Y_REL
from platoon_env.rollout import run_episode

#: |u|, |omega| difference [m/s, rad/s] allowed between the filtered and the plain law with
#: ideal sensing (measured: 2e-7 over these 500 steps of study C, 2e-4 over whole episodes of
#: the three studies; the filter's measurement-noise floor of 1 um is all that separates them).
IDEAL_TOLERANCE = 1e-5


# ----------------------------------------------------------------------------------------------
# The filter's equations
# ----------------------------------------------------------------------------------------------


def test_predict_hand_computed() -> None:
    # The follower moves 0.1 m straight ahead and turns by pi/2 (R(-a) = [[0, 1], [-1, 0]]);
    # the predecessor at (1, 2) drives at w = (0.5, 0) for dt = 0.1:
    # p' = R(-a) (p + w dt - D) = R(-a) (0.95, 2) = (2, -0.95), w' = R(-a) w = (0, -0.5).
    s = np.array([[1.0, 2.0, 0.5, 0.0]])
    P = np.eye(4)[None]
    s1, P1 = kf_predict(s, P, dx=0.1, dy=0.0, a=math.pi / 2, dt=0.1, q=3.0)
    np.testing.assert_allclose(s1, [[2.0, -0.95, 0.0, -0.5]], atol=1e-12)
    # G P G^T = [[1.01 I, 0.1 I], [0.1 I, I]] with G = [[I, dt I], [0, I]]; the rotation leaves
    # these isotropic blocks alone; Q = 3 [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]
    # = [[0.001 I, 0.015 I], [0.015 I, 0.3 I]]
    eye = np.eye(2)
    expected = np.block([[1.011 * eye, 0.115 * eye], [0.115 * eye, 1.3 * eye]])
    np.testing.assert_allclose(P1[0], expected, atol=1e-12)


def test_update_hand_computed() -> None:
    # P_pp = 4 I, cov(p, w) = 2 I, P_ww = I; R = 4 I: S = 8 I, K = [[I/2], [I/4]];
    # z - p = (2, 0): s = (2, 0, 0.5, 0); P - K S K^T = P - [[2 I, I], [I, I/2]]
    eye = np.eye(2)
    P = np.block([[4 * eye, 2 * eye], [2 * eye, eye]])[None]
    s = np.array([[1.0, 0.0, 0.0, 0.0]])
    s1, P1 = kf_update(s, P, z=[[3.0, 0.0]], R=4 * eye[None])
    np.testing.assert_allclose(s1, [[2.0, 0.0, 0.5, 0.0]], atol=1e-12)
    np.testing.assert_allclose(P1[0], np.block([[2 * eye, eye], [eye, 0.5 * eye]]), atol=1e-12)


def test_measurement_covariance_hand_computed() -> None:
    # z = (3, 4): |z| = 5, sigma = 0.01 + 0.002 * 5 = 0.02; sigma_b = 0.1 adds
    # 0.01 [[y^2, -x y], [-x y, x^2]] = [[0.16, -0.12], [-0.12, 0.09]]
    R = measurement_covariance([[3.0, 4.0]], 0.01, 0.002, 0.1)
    np.testing.assert_allclose(R[0], [[0.0004 + 0.16, -0.12], [-0.12, 0.0004 + 0.09]])
    floored = measurement_covariance([[1.0, 0.0]], 0.0, 0.0, 0.0, sigma_floor=1e-3)
    np.testing.assert_allclose(floored[0], 1e-6 * np.eye(2))


def test_kernels_match_the_pure_functions() -> None:
    rng = np.random.default_rng(1)
    params = FilterParams(
        dt=0.01, latency_steps=0, frame_period=0.0, sigma_0=0.005, sigma_1=0.01, sigma_b=0.01,
        u_max=10, omega_max=10, lag_gain=1.0, du_max=math.inf, dw_max=math.inf,
    )  # fmt: skip
    rec = _kernel_params(params)[0]
    for _ in range(20):
        s = rng.normal(size=4)
        A = rng.normal(size=(4, 4))
        P = A @ A.T + 0.1 * np.eye(4)
        dx, dy, a = rng.normal(scale=0.05, size=3)
        s_ref, P_ref = kf_predict(s[None], P[None], dx, dy, a, 0.01, 0.7)
        s_k, P_k = s.copy(), P.copy()
        _predict(s_k, P_k, dx, dy, a, 0.01, 0.7)
        np.testing.assert_allclose(s_k, s_ref[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(P_k, P_ref[0], rtol=1e-12, atol=1e-12)
        z = rng.normal(size=2)
        R = measurement_covariance(z[None], 0.005, 0.01, 0.01)
        np.testing.assert_allclose(_covariance(z[0], z[1], rec), R[0], rtol=1e-12)
        s_ref, P_ref = kf_update(s_k[None], P_k[None], z[None], R)
        _update(s_k, P_k, z[0], z[1], R[0])
        np.testing.assert_allclose(s_k, s_ref[0], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(P_k, P_ref[0], rtol=1e-10, atol=1e-12)


def test_odometry_moves_a_fixed_point_as_the_last_seen_baseline_does() -> None:
    # a world-fixed point (w = 0) seen from the odometry's relative pose == ego_motion's arc
    pose = odometry_step(np.zeros((3, 3)), [0.3, 0.5, -0.2], [0.0, 1.5, -2.0], 0.2)
    dx, dy, a = relative_pose(np.zeros((3, 3)), pose)
    point = np.array([[1.0, 0.2, 0.0, 0.0], [0.8, -0.3, 0.0, 0.0], [1.2, 0.0, 0.0, 0.0]])
    p, _ = propagate_mean(point, dx, dy, a, np.zeros(3))
    ex, ey = ego_motion(point[:, 0], point[:, 1], [0.3, 0.5, -0.2], [0.0, 1.5, -2.0], 0.2)
    np.testing.assert_allclose(p, np.stack([ex, ey], -1), atol=1e-12)


def test_actuator_step_is_the_lag_then_the_rate_limit() -> None:
    # lag gain 0.5 halves the gap to the command; the rate limit 0.3 caps u's change, not omega's
    applied = np.array([[1.0, -1.0]])
    out = actuator_step(applied, [[2.0, 0.0]], 0.5, [0.3, 1.0])
    np.testing.assert_array_equal(out, [[1.3, -0.5]])
    np.testing.assert_array_equal(actuator_step(applied, [[2.0, 0.0]], 1.0, [np.inf] * 2), [[2, 0]])


def test_kernels_take_at_most_eight_arguments() -> None:
    """Every compiled function of the baselines reads its parameters from named records or
    arrays, not from long positional lists."""
    kernels = [
        (f"{module.__name__}.{name}", value)
        for module in (baselines.ppc, baselines.filtered_ppc, baselines.last_seen)
        for name, value in vars(module).items()
        if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__
    ]
    assert len(kernels) >= 8
    long = {n: len(inspect.signature(k.py_func).parameters) for n, k in kernels}
    assert all(v <= 8 for v in long.values()), long


# ----------------------------------------------------------------------------------------------
# The policy
# ----------------------------------------------------------------------------------------------


def test_policy_interface_and_defaults() -> None:
    env = platoon_env.make("study_c")
    policy = FilteredPPCPolicy(env)
    assert isinstance(policy, Policy)
    # ideal sensing and drive: no margins, no lookahead, raw clearances
    p = policy.params
    assert (p.d_col_margin, p.beta_margin, p.range_margin, p.lookahead) == (0, 0, 0, 0)
    assert p.clearance_tau == 0
    obs, _ = env.reset(seed=0)
    actions = policy.act(obs)
    assert set(actions) == set(env.possible_agents)
    assert all(a.dtype == np.float32 and a.shape == (2,) for a in actions.values())
    assert set(policy.signals) == set(SIGNAL_NAMES) | set(FILTER_SIGNAL_NAMES)
    # a subset of the followers keeps the others' state
    first = env.possible_agents[0]
    assert set(policy.act({first: obs[first]})) == {first}
    policy.reset()
    assert policy.steps == 0 and not policy.signals["tracked"].any()
    with pytest.raises(TypeError, match="unknown"):
        FilteredPPCPolicy(env, not_an_option=1.0)


def test_margins_and_lookahead_come_from_the_sensor_and_drive_model() -> None:
    env = platoon_env.make("study_c", sensor_profile="aruco")
    cfg = env.scenario.config
    p = FilteredPPCPolicy(env).params
    cam = cfg.camera.noise
    kappa = p.margin_sigmas
    assert p.d_col_margin == pytest.approx(kappa * (cam.position + cam.position_per_m * 0.3))
    assert p.beta_margin == pytest.approx(
        kappa * (cam.bearing + (cam.position + cam.position_per_m * 1.0) / 1.0)
    )
    assert p.lookahead == pytest.approx(cfg.robot.lag + FilterParams.LOOKAHEAD_RATE_LIMITED)
    assert p.latency_steps == round(cfg.camera.latency / env.control_period)
    inner = FilteredPPCPolicy(env).ppc.params
    assert inner.d_col == pytest.approx(cfg.safety.d_col + p.d_col_margin)
    assert inner.beta_con == pytest.approx(cfg.camera.half_angle - p.beta_margin)
    with pytest.raises(ValueError, match="tightened"):
        FilteredPPCPolicy(env, beta_margin=0.35)


def test_ideal_sensing_gives_the_plain_laws_commands() -> None:
    env = platoon_env.make("study_c")
    ppc, filtered = PPCPolicy(env), FilteredPPCPolicy(env)
    obs, _ = env.reset(seed=0)
    ppc.reset(seed=0)
    filtered.reset(seed=0)
    worst = 0.0
    for _ in range(500):
        a, b = ppc.act(obs), filtered.act(obs)
        worst = max(worst, max(float(np.max(np.abs(a[k] - b[k]))) for k in a))
        obs, *_ = env.step(a)
    assert worst < IDEAL_TOLERANCE


def _track(env: Any, policy: FilteredPPCPolicy, steps: int, blind: range = range(0)) -> Any:
    """Run ``steps`` steps; at the steps in ``blind`` the policy is shown no detection.
    Returns the largest error of the estimate (the law's x^, y^) while tracked, and the
    commands of the last step."""
    obs, _ = env.reset(seed=3)
    policy.reset(seed=3)
    worst = 0.0
    actions: dict[str, Any] = {}
    for k in range(steps):
        if k in blind:
            obs = {a: np.where(np.arange(o.size) < 3, 0.0, o) for a, o in obs.items()}
        actions = policy.act(obs)
        sig = policy.signals
        sensed = env.sensed
        x = sensed[:, SENSE_D] * np.cos(sensed[:, SENSE_BETA])
        y = sensed[:, SENSE_D] * np.sin(sensed[:, SENSE_BETA])
        if k >= 20:
            err = np.hypot(sig["x_hat"] - x, sig["y_hat"] - y)[sig["tracked"]]
            worst = max(worst, float(np.max(err, initial=0.0)))
        obs, *_ = env.step(actions)
    return worst, actions


def test_timing_model_matches_the_env_camera() -> None:
    # a noise-free camera at 30 Hz with 50 ms latency: the re-propagated estimate is the truth
    # up to the predecessor's change of velocity since the frame
    env = platoon_env.make("study_c", camera={"frame_rate": 30.0, "latency": 0.05})
    worst, _ = _track(env, FilteredPPCPolicy(env), 300)
    assert worst < 5e-3


def test_predicts_through_a_dropout_and_stops_after_max_coast() -> None:
    env = platoon_env.make("study_c", camera={"frame_rate": 30.0, "latency": 0.05})
    policy = FilteredPPCPolicy(env, max_coast=0.5)
    # 0.3 s without a detection: still tracked, finite, and the estimate stays close
    worst, actions = _track(env, policy, 300, blind=range(250, 280))
    assert policy.signals["tracked"].all()
    assert all(np.all(np.isfinite(a)) for a in actions.values())
    assert worst < 0.02
    # blind from step 200 on: after max_coast the law is told "not visible" and stops
    worst, actions = _track(env, policy, 300, blind=range(200, 300))
    assert not policy.signals["tracked"].any()
    assert all(np.all(a == 0) for a in actions.values())
    assert np.all(np.isfinite(policy.signals["x_hat"]))
    # never a detection: the law stops from the start, nothing is NaN
    env2 = platoon_env.make("study_c")
    policy2 = FilteredPPCPolicy(env2)
    obs, _ = env2.reset(seed=0)
    for _ in range(5):
        blind_obs = {a: np.concatenate([[0.0, 0.0, 0.0], o[3:]]) for a, o in obs.items()}
        assert all(np.all(a == 0) for a in policy2.act(blind_obs).values())
    assert policy2.untracked_steps.tolist() == [5, 5]
    assert np.all(np.isfinite(policy2.signals["x_hat"]))


def test_aruco_study_c_short_rollout_has_no_violation() -> None:
    # the plain law leaves the field of view after 3.9-6.7 s on this profile (12 seeds)
    env = platoon_env.make("study_c", sensor_profile="aruco")
    policy = FilteredPPCPolicy(env)
    ep = run_episode(env, policy, seed=0, max_steps=700, record_signals=False)
    assert ep.steps == 700
    assert ep.first_violation is None
    assert policy.updates.min() > 150  # ~30 Hz x 7 s x 0.95, minus the latency
    assert np.isfinite(ep.actions).all()


def test_observation_rows_handed_to_the_law() -> None:
    env = platoon_env.make("study_c", sensor_profile="aruco")
    policy = FilteredPPCPolicy(env)
    obs, _ = env.reset(seed=0)
    policy.act(obs)
    sig = policy.signals
    for i, agent in enumerate(env.possible_agents):
        if obs[agent][OBS_VISIBLE] > 0.5:  # the first frame starts the filter at z
            assert sig["tracked"][i]
            assert sig["x_hat"][i] == pytest.approx(float(obs[agent][OBS_X_REL]), abs=1e-6)
            assert sig["y_hat"][i] == pytest.approx(float(obs[agent][OBS_Y_REL]), abs=1e-6)
            assert sig["d"][i] == pytest.approx(math.hypot(sig["x_hat"][i], sig["y_hat"][i]))


def test_drive_model_is_the_envs_actuators_and_arc() -> None:
    """With a lagged, rate-limited drive the policy's model of its applied velocity is the env's
    to the bit (the same rule on the same commands), and its odometry moves the follower as the
    env does (the same arc, integrated in one piece instead of sub-steps)."""
    env = platoon_env.make(
        "study_c", robot={"lag": 0.05, "accel_max": 1.0, "alpha_max": 3.0}, terminate_on=()
    )
    policy = FilteredPPCPolicy(env)
    obs, _ = env.reset(seed=0)
    policy.reset(seed=0)
    ring = policy._state.odometry.shape[0]
    for k in range(120):
        before = env.poses[1:].copy()
        obs, *_ = env.step(policy.act(obs))
        np.testing.assert_array_equal(policy.applied, env.applied_velocities)
        o = policy._state.odometry
        dx, dy, a = relative_pose(o[k % ring], o[(k + 1) % ring])
        tx, ty, ta = relative_pose(before, env.poses[1:])
        np.testing.assert_allclose(np.stack([dx, dy, a]), np.stack([tx, ty, ta]), atol=1e-12)
