"""Sensing and actuation realism (docs/realism.md): each model against its specification."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.core import params_of
from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D, SENSE_SIZE, SENSE_VISIBLE
from platoon_env.observation import OBS_SIZE
from platoon_env.perception import capture, frame_due
from platoon_env.records import new_episode
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.options import apply_overrides

N_DRAWS = 20_000


def _params(**blocks: Any) -> np.ndarray:
    cfg = apply_overrides(load_config("study_c"), blocks)
    out = np.zeros(1, dtype=params_of(cfg, 100).dtype)
    out[0] = params_of(cfg, 100)
    return out


def _draws(params: np.ndarray, d: float, beta: float, n: int = N_DRAWS) -> np.ndarray:
    """``n`` frames ``(visible, x, y)`` of a predecessor at ``(d, beta)``, truly visible."""
    sensed = np.zeros(SENSE_SIZE)
    sensed[SENSE_D], sensed[SENSE_BETA], sensed[SENSE_VISIBLE] = d, beta, 1.0
    obs = np.zeros(OBS_SIZE, dtype=np.float32)
    obs[0] = 1.0
    ep = new_episode(1)
    ep[0]["noise_state"] = 12345
    return np.array([capture(sensed, obs, ep[0], params[0]) for _ in range(n)])


@pytest.mark.parametrize("d", [0.5, 1.2])
def test_position_noise_statistics(d: float) -> None:
    """Mean ~ 0; std = position + position_per_m * d per axis, within 3 %."""
    params = _params(camera={"noise": {"position": 0.005, "position_per_m": 0.01}})
    frames = _draws(params, d, 0.1)
    err = frames[:, 1:] - [d * math.cos(0.1), d * math.sin(0.1)]
    sigma = 0.005 + 0.01 * d
    assert np.all(frames[:, 0] == 1.0)
    assert np.all(np.abs(err.mean(axis=0)) < 4 * sigma / math.sqrt(N_DRAWS))
    np.testing.assert_allclose(err.std(axis=0), sigma, rtol=0.03)
    assert abs(np.corrcoef(err.T)[0, 1]) < 0.03  # independent axes


def test_bearing_noise_rotates_the_position() -> None:
    params = _params(camera={"noise": {"bearing": 0.02}})
    frames = _draws(params, 1.0, 0.2)
    np.testing.assert_allclose(np.hypot(frames[:, 1], frames[:, 2]), 1.0, rtol=1e-12)
    angle = np.arctan2(frames[:, 2], frames[:, 1]) - 0.2
    assert abs(angle.mean()) < 4 * 0.02 / math.sqrt(N_DRAWS)
    assert angle.std() == pytest.approx(0.02, rel=0.03)


def test_dropout_fraction_matches_detection() -> None:
    frames = _draws(_params(camera={"detection": 0.8}), 1.0, 0.0)
    assert frames[:, 0].mean() == pytest.approx(0.8, abs=0.01)
    assert np.all(frames[frames[:, 0] == 0.0] == 0.0)  # a dropped frame reports nothing
    # Edge falloff: at |beta| = beta_con / sqrt(2) the probability is detection (1 - edge / 2).
    params = _params(camera={"detection": 0.9, "detection_edge": 0.6})
    beta = 0.4 / math.sqrt(2.0)
    assert _draws(params, 1.0, beta)[:, 0].mean() == pytest.approx(0.9 * 0.7, abs=0.012)


def test_invisible_predecessor_is_never_reported() -> None:
    params = _params(camera={"noise": {"position": 0.05}})
    sensed = np.zeros(SENSE_SIZE)
    sensed[SENSE_D] = 1.0
    ep = new_episode(1)
    assert capture(sensed, np.zeros(OBS_SIZE, dtype=np.float32), ep[0], params[0]) == (0, 0, 0)


def _camera_trace(steps: int, seed: int = 0, **blocks: Any) -> tuple[np.ndarray, np.ndarray]:
    """Camera part (visible, x~, y~) and clearances of follower 1 over a PPC-free rollout."""
    env = platoon_env.make("study_c", terminate_on=(), **blocks)
    obs, _ = env.reset(seed=seed)
    cams, clear = [obs["follower_1"][:3]], [obs["follower_1"][3:]]
    act = {a: np.array([0.25, 0.02]) for a in env.agents}
    for _ in range(steps):
        obs = env.step(act)[0]
        cams.append(obs["follower_1"][:3])
        clear.append(obs["follower_1"][3:])
    return np.array(cams), np.array(clear)


def test_latency_shifts_the_camera_by_whole_control_periods() -> None:
    ideal, ideal_clear = _camera_trace(60)
    late, late_clear = _camera_trace(60, camera={"latency": 0.05})
    np.testing.assert_array_equal(late[5:], ideal[:-5])
    np.testing.assert_array_equal(late[:5], np.repeat(ideal[:1], 5, axis=0))  # the reset frame
    np.testing.assert_array_equal(late_clear, ideal_clear)  # the proximity sensor is not late


def test_frames_are_held_between_frame_times() -> None:
    ideal, _ = _camera_trace(60)
    held, _ = _camera_trace(60, camera={"frame_rate": 25.0})  # a frame every 4 steps
    for k in range(61):
        np.testing.assert_array_equal(held[k], ideal[4 * (k // 4)], err_msg=str(k))
    p = _params(camera={"frame_rate": 30.0})[0]
    due = [frame_due(k, p) for k in range(31)]
    assert sum(due[1:]) == 9 and due[0]  # 30 Hz over 0.3 s of 0.01-s steps: 9 new frames


def test_proximity_noise_is_clipped_to_the_sensor_range() -> None:
    _, ideal = _camera_trace(200)
    _, noisy = _camera_trace(200, proximity={"noise": 0.3})
    prox = load_config("study_c").proximity_range
    assert np.all((noisy >= 0) & (noisy <= np.float32(prox)))
    inside = (ideal > 0.5) & (ideal < prox - 0.5)
    err = (noisy - ideal)[inside]
    assert err.std() == pytest.approx(0.3, rel=0.1)


def _applied_u(steps: int, command: float, **robot: Any) -> np.ndarray:
    env = platoon_env.make("study_c", terminate_on=(), robot=robot)
    env.reset(seed=0, options={"perturb": False})
    out = []
    for _ in range(steps):
        env.step({a: np.array([command, 0.0]) for a in env.agents})
        out.append(env.applied_velocities[0, 0])
    return np.array(out)


def test_acceleration_bound_and_lag() -> None:
    dt = 0.01
    u = _applied_u(50, 0.4, accel_max=1.0)
    k = np.arange(1, 51)
    np.testing.assert_allclose(u, np.minimum(0.4, 1.0 * dt * k), rtol=1e-12)
    u = _applied_u(50, 0.4, lag=0.1)
    np.testing.assert_allclose(u, 0.4 * (1.0 - np.exp(-k * dt / 0.1)), rtol=1e-9)
    both = _applied_u(50, 0.4, lag=0.05, accel_max=0.5)
    assert np.all(np.diff(np.concatenate([[0.0], both])) <= 0.5 * dt + 1e-15)
    assert np.all(both <= 0.4 * (1.0 - np.exp(-k * dt / 0.05)) + 1e-12)


def test_realism_keeps_safety_and_reward_exact() -> None:
    """Noisy observations, same ground truth: poses, info and rewards are those of the ideal
    env while the actuators are ideal (the follower's own actions are the same)."""
    blocks = {
        "camera": {"noise": {"position": 0.05}, "detection": 0.7},
        "proximity": {"noise": 0.1},
    }
    ideal = platoon_env.make("study_c", terminate_on=())
    noisy = platoon_env.make("study_c", terminate_on=(), **blocks)
    ideal.reset(seed=4)
    noisy.reset(seed=4)
    act = {a: np.array([0.25, 0.05]) for a in ideal.possible_agents}
    differs = False
    for _ in range(100):
        o1, r1, _, _, i1 = ideal.step(act)
        o2, r2, _, _, i2 = noisy.step(act)
        assert r1 == r2 and i1 == i2
        np.testing.assert_array_equal(ideal.poses, noisy.poses)
        differs |= not np.array_equal(o1["follower_1"], o2["follower_1"])
    assert differs


REALISM: dict[str, Any] = {
    "camera": {
        "noise": {"position": 0.005, "position_per_m": 0.01, "bearing": 0.01},
        "detection": 0.9,
        "detection_edge": 0.5,
        "frame_rate": 30.0,
        "latency": 0.03,
    },
    "proximity": {"noise": 0.01},
    "robot": {"accel_max": 2.0, "alpha_max": 5.0, "lag": 0.05},
}


def test_realism_is_deterministic_and_seeded() -> None:
    a, _ = _camera_trace(80, seed=1, **REALISM)
    b, _ = _camera_trace(80, seed=1, **REALISM)
    c, _ = _camera_trace(80, seed=2, **REALISM)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("n_threads", [1, 2])
def test_batched_equals_single_envs_with_realism(n_threads: int) -> None:
    from test_batched import _compare_rollout

    # Every step's observations, rewards, flags and poses are compared inside.
    _compare_rollout("study_c", [0, 1, 2], 200, n_threads=n_threads, **REALISM)
    # Envs with other seeds perceive other noise.
    obs = BatchedPlatoon("study_c", 2, **REALISM).reset([7, 8])
    assert not np.array_equal(obs[0], obs[1])
