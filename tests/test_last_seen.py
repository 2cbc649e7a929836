"""The last-seen baseline of ref. [32] (baselines/last_seen.py) and the comparison with PPC."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import platoon_env
from baselines import LastSeenPolicy
from baselines.last_seen import MODE_LOST, MODE_TRACKING, LastSeenFOVPolicy, ego_motion
from experiments.studies.comparison import run, visibility_breaks
from platoon_env.dynamics.unicycle import integrate
from platoon_env.geometry.sensing import SENSE_VISIBLE
from platoon_env.observation import OBS_SIZE

DT = 0.05
FAR = 1.5  # clearances at the proximity range: no wall nearby


def fake_env(n: int = 1, scenario: str = "study_c", dt: float = DT) -> Any:
    """What the policy reads from an env: agents, control period, scenario config."""
    return SimpleNamespace(
        possible_agents=[f"follower_{i}" for i in range(1, n + 1)],
        control_period=dt,
        scenario=platoon_env.load_scenario(scenario),
    )


def obs(x: float = 0.0, y: float = 0.0, visible: bool = True, wall: float = FAR) -> np.ndarray:
    """One follower's observation [visible, x~, y~, d_W_l, d_W_r, d_l, d_r]."""
    return np.array([float(visible), x, y, wall, wall, wall, wall], dtype=np.float32)


def body(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    """``point`` (world) in the body frame of ``pose`` = [x, y, theta]."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = point - pose[:2]
    return np.array([c * dx + s * dy, -s * dx + c * dy])


def test_ego_motion_closed_form() -> None:
    # straight line: the point slides back by u dt
    x, y = ego_motion(1.0, 0.3, 0.4, 0.0, 0.5)
    assert (float(x), float(y)) == pytest.approx((0.8, 0.3), abs=1e-15)
    # turning in place by a: the point rotates by -a
    a = 0.3
    x, y = ego_motion(1.0, 0.3, 0.0, a / 0.5, 0.5)
    expected = (math.cos(a) * 1.0 + math.sin(a) * 0.3, -math.sin(a) * 1.0 + math.cos(a) * 0.3)
    assert (float(x), float(y)) == pytest.approx(expected, abs=1e-15)
    # an arc of radius R = u/omega through angle a: displacement (R sin a, R (1 - cos a))
    u, w, h = 0.5, 0.8, 0.25
    R, a = u / w, w * h
    px, py = 1.0 - R * math.sin(a), 0.3 - R * (1 - math.cos(a))
    x, y = ego_motion(1.0, 0.3, u, w, h)
    expected = (math.cos(a) * px + math.sin(a) * py, -math.sin(a) * px + math.cos(a) * py)
    assert (float(x), float(y)) == pytest.approx(expected, abs=1e-14)


def test_leader_loss_heads_to_last_seen_point_in_own_frame() -> None:
    policy = LastSeenPolicy(fake_env())
    seen = np.array([1.0, 0.3], dtype=np.float32).astype(np.float64)  # as the camera reports
    cmd = policy.act({"follower_1": obs(*seen)})["follower_1"]
    assert policy.signals["mode"][0] == MODE_TRACKING
    pose = np.zeros(3)
    phis, dists = [], []
    for _ in range(8):
        pose = integrate(pose, float(cmd[0]), float(cmd[1]), DT)  # the env's exact arc
        cmd = policy.act({"follower_1": obs(visible=False)})["follower_1"]
        sig = policy.signals
        assert sig["mode"][0] == MODE_LOST
        target = np.array([sig["target_x"][0], sig["target_y"][0]])
        np.testing.assert_allclose(target, body(pose, seen), atol=1e-12)
        phi = math.atan2(target[1], target[0])
        assert cmd[1] > 0.0  # the point is on the left: turn left, towards it
        assert cmd[0] > 0.0  # and drive at it
        phis.append(phi)
        dists.append(float(np.hypot(*target)))
    assert np.all(np.diff(phis) < 0.0) and phis[-1] > 0.0  # heading turns towards it
    assert np.all(np.diff(dists) < 0.0)  # and gets closer
    assert policy.losses[0] == 1 and policy.lost_steps[0] == 8


def test_resumes_tracking_when_predecessor_reappears() -> None:
    policy = LastSeenPolicy(fake_env())
    policy.act({"follower_1": obs(1.0, 0.3)})
    for _ in range(5):
        policy.act({"follower_1": obs(visible=False)})
    assert policy.signals["mode"][0] == MODE_LOST
    cmd = policy.act({"follower_1": obs(1.2, -0.2)})["follower_1"]
    sig = policy.signals
    assert sig["mode"][0] == MODE_TRACKING and bool(sig["visible"][0])
    assert (sig["target_x"][0], sig["target_y"][0]) == pytest.approx((1.2, -0.2), abs=1e-6)
    assert cmd[1] < 0.0  # tracking the new bearing (to the right)
    assert policy.losses[0] == 1 and policy.lost_steps[0] == 5
    policy.act({"follower_1": obs(visible=False)})  # a second loss is counted
    assert policy.losses[0] == 2


def test_stops_at_last_seen_point_and_when_never_seen() -> None:
    env = fake_env()
    policy = LastSeenPolicy(env)
    arrive = policy.params.arrive_radius
    assert arrive == env.scenario.config.safety.d_col
    policy.act({"follower_1": obs(arrive + 0.1, 0.0)})
    for _ in range(200):
        cmd = policy.act({"follower_1": obs(visible=False)})["follower_1"]
        if policy.signals["arrived"][0]:
            break
    else:
        pytest.fail("never reached the last-seen point")
    assert np.all(cmd == 0.0)
    sig = policy.signals
    assert math.hypot(sig["target_x"][0], sig["target_y"][0]) <= arrive
    cmd = policy.act({"follower_1": obs(visible=False)})["follower_1"]
    assert np.all(cmd == 0.0)  # stays stopped
    # blind from the first step: no last-seen point, stop
    policy.reset()
    cmd = policy.act({"follower_1": obs(visible=False)})["follower_1"]
    assert np.all(cmd == 0.0) and bool(policy.signals["arrived"][0])


def test_saturation_and_field_of_view_slowdown() -> None:
    """The law as the paper describes it has no slow-down at the edge of the view; the named
    variant LastSeenFOVPolicy has."""
    policy = LastSeenPolicy(fake_env())
    p = policy.params
    cfg = platoon_env.load_scenario("study_c").config
    assert p.u_max == pytest.approx(2 * cfg.leader.speed) and not p.fov_slowdown
    far = policy.act({"follower_1": obs(1.49, 0.0)})["follower_1"]
    assert far[0] == pytest.approx(p.u_max)  # saturated, not unbounded
    b = 0.99 * p.beta_con
    at_edge = obs(1.49 * math.cos(b), 1.49 * math.sin(b))
    policy.reset()
    edge = policy.act({"follower_1": at_edge})["follower_1"]
    # no slow-down: the distance law alone, k_d (d - d_des) cos(beta), saturated at u_max
    expected_u = min(p.k_d * (1.49 - p.d_des) * math.cos(b), p.u_max)
    assert edge[0] == pytest.approx(expected_u, rel=1e-5)
    assert edge[1] == pytest.approx(min(p.k_beta * b, p.omega_max), rel=1e-5)  # proportional
    fov = LastSeenFOVPolicy(fake_env())
    assert fov.params.fov_slowdown
    slowed = fov.act({"follower_1": at_edge})["follower_1"]
    assert 0.0 <= slowed[0] < 0.05 * p.u_max  # nearly stops at the edge of the view
    assert slowed[1] == pytest.approx(edge[1])
    assert not LastSeenFOVPolicy(fake_env(), fov_slowdown=False).params.fov_slowdown
    with pytest.raises(ValueError, match="fov_slowdown must be a bool"):
        LastSeenPolicy(fake_env(), fov_slowdown=1.0)


def test_no_nan_for_any_input() -> None:
    rng = np.random.default_rng(0)
    n = 4
    policy = LastSeenPolicy(fake_env(n))
    agents = policy.agents
    specials = [0.0, -0.0, 1e-300, -1e-300, 1e30, -1e30, np.nan, np.inf, -np.inf]
    for _ in range(400):
        o = rng.uniform(-3.0, 3.0, size=(n, OBS_SIZE)).astype(np.float32)
        o[:, 0] = rng.integers(0, 2, size=n)
        mask = rng.random(o.shape) < 0.15
        o[mask] = rng.choice(np.array(specials, dtype=np.float32), size=int(mask.sum()))
        if rng.random() < 0.2:
            o[:, 1:3] = 0.0  # predecessor "at" the follower
        out = policy.act(dict(zip(agents, o, strict=True)))
        for a in agents:
            assert out[a].dtype == np.float32 and out[a].shape == (2,)
            assert np.all(np.isfinite(out[a]))
            assert abs(out[a][0]) <= policy.params.u_max + 1e-6
            assert abs(out[a][1]) <= policy.params.omega_max + 1e-6
        for value in policy.signals.values():
            assert np.all(np.isfinite(value.astype(np.float64)))


def test_vectorised_equals_per_follower() -> None:
    rng = np.random.default_rng(1)
    n = 5
    together = LastSeenPolicy(fake_env(n))
    subset = LastSeenPolicy(fake_env(n))  # one agent per act() call
    agents = together.agents
    alone = [LastSeenPolicy(SimpleNamespace(**{**vars(fake_env()), "possible_agents": [a]}))
             for a in agents]  # fmt: skip
    for step in range(300):
        o = np.zeros((n, OBS_SIZE), dtype=np.float32)
        visible = rng.random(n) < (0.2 if 100 <= step < 160 else 0.9)
        d = rng.uniform(0.5, 1.6, size=n)
        b = rng.uniform(-0.5, 0.5, size=n)
        o[:, 0] = visible
        o[:, 1] = np.where(visible, d * np.cos(b), 0.0)
        o[:, 2] = np.where(visible, d * np.sin(b), 0.0)
        o[:, 3:] = rng.uniform(0.1, 1.5, size=(n, 4))
        all_out = together.act(dict(zip(agents, o, strict=True)))
        for i, a in enumerate(agents):
            one = subset.act({a: o[i]})[a]
            single = alone[i].act({a: o[i]})[a]
            np.testing.assert_array_equal(all_out[a], one)
            np.testing.assert_array_equal(all_out[a], single)
        for key, value in together.signals.items():
            np.testing.assert_array_equal(value, subset.signals[key])
            for i in range(n):
                np.testing.assert_array_equal(value[i], alone[i].signals[key][0])
    np.testing.assert_array_equal(together.losses, subset.losses)
    np.testing.assert_array_equal(together.lost_steps, [p.lost_steps[0] for p in alone])
    assert together.losses.sum() > 0


def test_study_c_ppc_keeps_sight_last_seen_loses_it() -> None:
    """Study C, terminate_on collisions only, seed 0: PPC never loses its predecessor, the
    last-seen controller does (and its stored point is the predecessor's last-seen position,
    tracked by odometry alone)."""
    ppc = run("study_c", "PPC", 0, record_signals=False)
    steps, transitions = visibility_breaks(ppc)
    assert steps.sum() == 0 and transitions.sum() == 0
    ls = run("study_c", "last-seen [32]", 0)
    steps, transitions = visibility_breaks(ls)
    assert steps.sum() >= 1 and transitions.sum() >= 1
    # sight is lost first (at the snaky corridor's first sharp corner); a collision may end the
    # episode later (a follower driving to a last-seen point round a 90-degree corner)
    assert ls.first_violation is not None
    assert ls.first_violation[1] in ("out_of_range", "out_of_fov", "occluded")
    # odometry: in leader-loss mode, the target is the predecessor's position at its last
    # visible sample, seen from the follower's current ground-truth pose
    vis = ls.sensed[:, :, SENSE_VISIBLE] > 0
    mode = ls.signals["mode"]  # (T, N), at samples 0..T-1
    vis = vis[: mode.shape[0]]
    lost = ~vis
    assert lost.any() and np.all(mode[lost] == MODE_LOST) and np.all(mode[vis] == MODE_TRACKING)
    k = np.arange(mode.shape[0])
    for i in range(mode.shape[1]):
        last = np.maximum.accumulate(np.where(vis[:, i], k, -1))[lost[:, i]]
        assert np.all(last >= 0)
        point = ls.poses[last, i, :2]  # the predecessor (robot i) when last seen
        pose = ls.poses[k[lost[:, i]], i + 1]  # the follower now (ground truth)
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        dx, dy = (point - pose[:, :2]).T
        expected = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
        target = np.stack(
            [ls.signals["target_x"][lost[:, i], i], ls.signals["target_y"][lost[:, i], i]], axis=-1
        )
        np.testing.assert_allclose(target, expected, atol=1e-6)  # float32 camera rounding


def test_evaluate_knows_last_seen() -> None:
    from experiments.studies.evaluate import PolicySpec, build

    spec = PolicySpec.parse("last_seen")
    assert spec == PolicySpec("last_seen", "last_seen")
    env, policy = build(spec, "study_c")
    assert isinstance(policy, LastSeenPolicy)
    assert env.terminate_on == frozenset(platoon_env.VIOLATION_CAUSES)
