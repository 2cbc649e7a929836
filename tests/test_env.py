"""The ParallelEnv: conformance, safety causes, determinism, pickling, actions, truncation."""

from __future__ import annotations

import copy
import math
import pickle
from typing import Any

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test

import platoon_env
from platoon_env.observation import OBS_SIZE
from platoon_env.scenarios.schema import VIOLATION_CAUSES

SCENARIOS = platoon_env.list_scenarios()


def _still(env: platoon_env.PlatoonParallelEnv) -> dict[str, np.ndarray]:
    return {a: np.zeros(2, dtype=np.float32) for a in env.agents}


def _run_until_done(
    env: platoon_env.PlatoonParallelEnv, action: dict[str, Any], max_steps: int = 5000
) -> dict[str, Any]:
    for _ in range(max_steps):
        _, _, term, trunc, infos = env.step(action)
        if any(term.values()) or any(trunc.values()):
            return {"term": term, "trunc": trunc, "infos": infos}
    raise AssertionError("episode did not end")


@pytest.mark.parametrize("scenario", [*SCENARIOS, "corridor"])
def test_parallel_api(scenario: str, corridor: dict[str, Any]) -> None:
    env = platoon_env.parallel_env(corridor if scenario == "corridor" else scenario)
    parallel_api_test(env, num_cycles=200)


@pytest.mark.parametrize("scenario", [*SCENARIOS, "corridor"])
def test_aec_api(scenario: str, corridor: dict[str, Any]) -> None:
    env = platoon_env.env(corridor if scenario == "corridor" else scenario)
    api_test(env, num_cycles=100)


def test_spaces_are_cached_and_bounded(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        space = env.observation_space(agent)
        assert space.shape == (OBS_SIZE,) and space.dtype == np.float32
        assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
        assert env.action_space(agent).dtype == np.float32
    # One space object per agent: seeding one agent's space leaves the others' alone.
    first, second = env.possible_agents[:2]
    assert env.action_space(first) is not env.action_space(second)
    env.action_space(first).seed(0)
    env.action_space(second).seed(0)
    a = env.action_space(first).sample()
    env.action_space(first).seed(0)
    np.testing.assert_array_equal(env.action_space(first).sample(), a)
    assert env.observation_space(first) is not env.observation_space(second)


def test_observation_matches_ground_truth(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    obs, infos = env.reset(seed=3)
    poses = env.poses
    for i, agent in enumerate(env.possible_agents, start=1):
        rel = poses[i - 1, :2] - poses[i, :2]
        th = poses[i, 2]
        body = np.array(
            [
                math.cos(th) * rel[0] + math.sin(th) * rel[1],
                -math.sin(th) * rel[0] + math.cos(th) * rel[1],
            ]
        )
        assert obs[agent][0] == 1.0
        np.testing.assert_allclose(obs[agent][1:3], body, rtol=1e-6, atol=1e-6)
        assert infos[agent]["d"] == pytest.approx(np.hypot(*rel))


# ------------------------------------------------------------------------------------------
# Each violation cause from a constructed situation
# ------------------------------------------------------------------------------------------


def test_collision_robot(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor, followers=1, perturb=False)
    env.reset(seed=0)
    out = _run_until_done(env, {"follower_1": np.array([5.0, 0.0])})
    info = out["infos"]["follower_1"]
    assert info["violation"] == "collision_robot" and info["cost"] == 1
    assert out["term"]["follower_1"] and not env.agents
    assert info["d"] <= 0.3 + 5.0 * env.control_period / env.physics_substeps


def test_out_of_range(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor, followers=1, perturb=False)
    env.reset(seed=0)
    out = _run_until_done(env, _still(env))
    info = out["infos"]["follower_1"]
    assert info["violation"] == "out_of_range"
    assert info["d"] >= 1.5 and not info["visible"]


def test_out_of_fov(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor, followers=1, perturb=False)
    env.reset(seed=0)
    out = _run_until_done(env, {"follower_1": np.array([0.0, 2.0])})
    info = out["infos"]["follower_1"]
    assert info["violation"] == "out_of_fov"
    assert abs(info["beta"]) >= 0.4


def test_occluded() -> None:
    scenario = {
        "name": "occlusion",
        "workspace": {
            "bounds": [-1.0, -1.0, 9.0, 5.0],
            "obstacles": [[[3.0, 0.5], [5.0, 0.5], [5.0, 2.0], [3.0, 2.0]]],
        },
        "leader": {"path": [[0.0, 0.0], [6.0, 0.0], [6.0, 4.0]], "speed": 0.5},
        "followers": 1,
        "robot": {"radius": 0.15},
        "camera": {"half_angle": 1.5, "range": 20.0},
        "safety": {"d_col": 0.3},
        "formation": {"d_des": 1.0},
    }
    env = platoon_env.make(scenario, perturb=False)
    env.reset(seed=0)
    out = _run_until_done(env, _still(env))
    info = out["infos"]["follower_1"]
    assert info["violation"] == "occluded"
    assert info["d_l"] == 0.0 and info["d_r"] == 0.0 and not info["visible"]
    leader = env.poses[0]
    assert leader[0] > 5.0 and leader[1] > 0.4  # the leader has gone round the box's corner


def test_collision_obstacle(corridor: dict[str, Any]) -> None:
    scenario = copy.deepcopy(corridor)
    scenario["leader"]["path"] = [[1.0, -1.5], [20.0, -1.5]]
    scenario["camera"] = {"half_angle": 1.5, "range": 20.0}
    env = platoon_env.make(
        scenario, followers=1, perturb=False, terminate_on=["collision_obstacle"]
    )
    env.reset(seed=0)
    out = _run_until_done(env, {"follower_1": np.array([1.0, -2.0])})
    info = out["infos"]["follower_1"]
    assert "collision_obstacle" in info["violations"]
    assert info["clearance"] <= 0.15 + 1.0 * env.control_period
    assert out["term"]["follower_1"]


def test_terminate_on_subset_keeps_running(corridor: dict[str, Any]) -> None:
    """With collisions only, losing sight is reported but does not end the episode."""
    env = platoon_env.make(
        corridor, followers=1, perturb=False, terminate_on=["collision_robot", "collision_obstacle"]
    )
    env.reset(seed=0)
    seen = set()
    for _ in range(500):
        _, _, term, _trunc, infos = env.step(_still(env))
        assert not term["follower_1"]
        seen.update(infos["follower_1"]["violations"])
    assert "out_of_range" in seen


def test_unknown_cause_rejected(corridor: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="unknown"):
        platoon_env.make(corridor, terminate_on=["bumped"])


def test_truncation_after_leader_arrives(corridor: dict[str, Any]) -> None:
    scenario = copy.deepcopy(corridor)
    scenario["leader"] = {"path": [[0.5, 0.0], [3.0, 0.0]], "speed": 0.5, "settle_time": 1.0}
    env = platoon_env.make(scenario, followers=1, perturb=False, terminate_on=[])
    env.reset(seed=0)
    out = _run_until_done(env, _still(env))
    assert out["trunc"]["follower_1"] and not out["term"]["follower_1"]
    assert env.leader_arrived
    np.testing.assert_allclose(env.poses[0, :2], [3.0, 0.0], atol=1e-3)


def test_max_episode_steps(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor, max_episode_steps=7, terminate_on=[])
    env.reset(seed=0)
    for _k in range(7):
        _, _, _, trunc, _ = env.step(_still(env))
    assert all(trunc.values()) and env.steps == 7
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


# ------------------------------------------------------------------------------------------
# Determinism, seeding, pickling
# ------------------------------------------------------------------------------------------


def _rollout(env: platoon_env.PlatoonParallelEnv, seed: int, steps: int) -> list[Any]:
    rng = np.random.default_rng(1234)
    obs, _ = env.reset(seed=seed)
    trace: list[Any] = [obs]
    for _ in range(steps):
        if not env.agents:
            obs, _ = env.reset()
            trace.append(obs)
        actions = {a: rng.uniform([-0.2, -0.5], [0.6, 0.5]).astype(np.float32) for a in env.agents}
        trace.append(env.step(actions))
        trace.append(env.poses)
    return trace


def _assert_same(a: Any, b: Any) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b


@pytest.mark.parametrize("scenario", [*SCENARIOS, "corridor"])
def test_determinism_two_envs(scenario: str, corridor: dict[str, Any]) -> None:
    """Same seed and actions → bit-identical observations, rewards, flags, infos, poses."""
    spec = corridor if scenario == "corridor" else scenario
    a = _rollout(platoon_env.make(spec, terminate_on=["collision_robot"]), seed=7, steps=300)
    b = _rollout(platoon_env.make(spec, terminate_on=["collision_robot"]), seed=7, steps=300)
    _assert_same(a, b)


def test_seed_changes_initial_configuration(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    env.reset(seed=1)
    p1 = env.poses
    env.reset(seed=2)
    p2 = env.poses
    env.reset(seed=1)
    assert not np.array_equal(p1, p2)
    np.testing.assert_array_equal(p1, env.poses)
    env.reset(seed=1, options={"perturb": False})
    np.testing.assert_array_equal(env.poses, env.scenario.initial_poses)


def test_pickle_mid_episode(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor, terminate_on=[])
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(50):
        env.step({a: rng.uniform(-0.5, 0.5, 2) for a in env.agents})
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(100):
        act = {a: rng.uniform(-0.5, 0.5, 2) for a in env.agents}
        _assert_same(env.step(act), clone.step(act))
    np.testing.assert_array_equal(env.poses, clone.poses)
    assert env.sim_time == clone.sim_time


# ------------------------------------------------------------------------------------------
# Actions
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "bad,error,match",
    [
        (np.array([np.nan, 0.0]), ValueError, "NaN or inf"),
        (np.array([0.0, np.inf]), ValueError, "NaN or inf"),
        (np.array([0.0, 0.0, 0.0]), ValueError, "shape"),
        (np.array([[0.0, 0.0]]), ValueError, "shape"),
        (["0.3", "0.0"], TypeError, "real numbers"),
        (np.array([0.3 + 1j, 0.0]), TypeError, "real numbers"),
    ],
)
def test_bad_actions_raise_and_change_nothing(
    corridor: dict[str, Any], bad: np.ndarray, error: type, match: str
) -> None:
    env = platoon_env.make(corridor)
    env.reset(seed=0)
    before = (env.poses, env.sim_time, env.steps)
    actions = _still(env)
    actions["follower_2"] = bad
    with pytest.raises(error, match=match) as exc:
        env.step(actions)
    if match == "NaN or inf":
        assert "follower_2" in str(exc.value)
    np.testing.assert_array_equal(before[0], env.poses)
    assert (env.sim_time, env.steps) == before[1:]


def test_an_array_is_not_an_action_dict(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    env.reset(seed=0)
    with pytest.raises(TypeError, match="dict"):
        env.step(np.zeros((2, 2)))  # type: ignore[arg-type]


def test_numpy_integer_seeds(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    a, _ = env.reset(seed=np.int64(3))
    b, _ = env.reset(seed=3)
    np.testing.assert_array_equal(a["follower_1"], b["follower_1"])
    with pytest.raises(TypeError, match="seed"):
        env.reset(seed=3.0)  # type: ignore[arg-type]


def test_unknown_and_missing_agents(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    env.reset(seed=0)
    actions = _still(env)
    actions["follower_9"] = np.zeros(2)
    with pytest.raises(KeyError, match="follower_9"):
        env.step(actions)
    with pytest.raises(KeyError, match="follower_2"):
        env.step({"follower_1": np.zeros(2)})


def test_out_of_bounds_actions_are_clipped(corridor: dict[str, Any]) -> None:
    a = platoon_env.make(corridor, u_max=0.5, omega_max=0.2, terminate_on=[])
    b = platoon_env.make(corridor, u_max=0.5, omega_max=0.2, terminate_on=[])
    a.reset(seed=0)
    b.reset(seed=0)
    for _ in range(20):
        a.step({ag: np.array([9.0, -9.0]) for ag in a.agents})
        space = b.action_space("follower_1")
        b.step({ag: np.array([space.high[0], space.low[1]]) for ag in b.agents})
    np.testing.assert_array_equal(a.poses, b.poses)


def test_render_rgb_array(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame is not None and frame.dtype == np.uint8 and frame.ndim == 3
    env.close()


def test_info_has_every_cause_name(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    _, infos = env.reset(seed=0)
    for info in infos.values():
        assert info["violation"] is None and info["cost"] == 0
        assert set(VIOLATION_CAUSES) >= set(info["violations"])


def test_info_diagnostics_and_reward_terms(corridor: dict[str, Any]) -> None:
    """info matches env.sensed, reward_terms follow the formulas of platoon_env.reward in the
    order of REWARD_TERMS, and each reward is the sum of its terms — with and without
    violations (the followers turn away until they lose their predecessor)."""
    from platoon_env.geometry.sensing import SENSE_NAMES
    from platoon_env.reward import REWARD_TERMS

    env = platoon_env.make(corridor, terminate_on=[])
    cfg = env.scenario.config
    w = cfg.reward
    d_des, beta_con = cfg.formation.d_des, cfg.camera.half_angle
    # The platoon starts along the lower wall (y = -2): follower 2 is 0.1 m beyond r from it.
    env.reset(seed=0, options={"poses": [[3.0, -1.7, 0.0], [2.0, -1.7, 0.0], [1.0, -1.75, 0.0]]})
    seen_violation = seen_clean = seen_wall = False
    for t in range(150):
        act = {
            a: np.array([0.3, 0.8 if k % 2 else -0.8 * (t % 3)]) for k, a in enumerate(env.agents)
        }
        _, rewards, _, _, infos = env.step(act)
        sensed = env.sensed
        for k, agent in enumerate(env.possible_agents):
            info = infos[agent]
            for c, name in enumerate(SENSE_NAMES):
                if name == "occluded":
                    continue
                expected = sensed[k, c] > 0 if name == "visible" else sensed[k, c]
                assert info[name] == expected, name
            assert info["e_d"] == pytest.approx(info["d"] - d_des)
            assert info["e_beta"] == info["beta"]
            terms = info["reward_terms"]
            assert list(terms) == list(REWARD_TERMS)
            ed = min(2.0, max(-2.0, info["e_d"] / (cfg.camera.range - d_des)))
            eb = min(2.0, max(-2.0, info["e_beta"] / beta_con))
            u, omega = np.clip(act[agent], [-cfg.robot.u_max, -cfg.robot.omega_max],
                               [cfg.robot.u_max, cfg.robot.omega_max])  # fmt: skip
            violated = bool(info["violations"])
            assert info["cost"] == int(violated)
            assert (info["violation"] is None) == (not violated)
            seen_violation |= violated
            seen_clean |= not violated
            assert terms["distance"] == pytest.approx(-w.distance * ed * ed)
            assert terms["bearing"] == pytest.approx(-w.bearing * eb * eb)
            assert terms["effort"] == pytest.approx(-w.effort * (u * u + omega * omega), rel=1e-6)
            assert terms["alive"] == (0.0 if violated else w.alive)
            assert terms["violation"] == (-w.violation if violated else 0.0)
            near = min(1.0, max(0.0, 1.0 - (info["clearance"] - cfg.robot.radius) / w.wall_margin))
            assert terms["wall"] == pytest.approx(-w.wall * near * near)
            seen_wall |= 0.0 > terms["wall"] > -w.wall
            assert rewards[agent] == pytest.approx(sum(terms.values()))
    assert seen_violation and seen_clean and seen_wall


def test_reward_buffer_of_the_wrong_size_is_refused() -> None:
    """Compiled code does not check bounds: a short buffer must raise, not be overwritten."""
    from platoon_env.core import params_of
    from platoon_env.reward import REWARD_TERMS, reward_terms_into

    sensed, actions = np.zeros((2, 9)), np.zeros((2, 2))
    masks = np.zeros(2, dtype=np.int64)
    scenario = platoon_env.make("study_c").scenario
    p = params_of(scenario.config, scenario.max_episode_steps)
    args = (sensed, actions, masks, p)
    reward_terms_into(*args, np.zeros((2, len(REWARD_TERMS))))
    for shape in [(2, len(REWARD_TERMS) - 1), (1, len(REWARD_TERMS))]:
        with pytest.raises(ValueError, match="REWARD_TERMS"):
            reward_terms_into(*args, np.zeros(shape))


def test_info_without_diagnostics(corridor: dict[str, Any]) -> None:
    """diagnostics=False: info keeps only the violation entries, equal to the full info's, and
    nothing else in the step changes (observations, rewards, flags, poses)."""
    full = platoon_env.make(corridor, terminate_on=[])
    lean = platoon_env.make(corridor, terminate_on=[], diagnostics=False)
    keys = {"violation", "violations", "cost"}
    full.reset(seed=2)
    _, lean_infos = lean.reset(seed=2)
    assert all(set(info) == keys for info in lean_infos.values())
    seen_violation = False
    for _ in range(120):
        act = {a: np.array([0.4, 1.2 * (k % 2) - 0.3]) for k, a in enumerate(full.agents)}
        a, b = full.step(act), lean.step(act)
        for agent in full.possible_agents:
            np.testing.assert_array_equal(a[0][agent], b[0][agent])
            assert a[1][agent] == b[1][agent] and a[2][agent] == b[2][agent]
            assert a[3][agent] == b[3][agent]
            assert set(b[4][agent]) == keys
            assert {k: a[4][agent][k] for k in keys} == b[4][agent]
            seen_violation |= b[4][agent]["cost"] == 1
    np.testing.assert_array_equal(full.poses, lean.poses)
    assert seen_violation
    parallel_api_test(platoon_env.make(corridor, diagnostics=False), num_cycles=50)


def test_state_for_centralised_critics(corridor: dict[str, Any]) -> None:
    """``state()``: poses, applied velocities, leader progress and time, inside ``state_space``."""
    env = platoon_env.make(corridor, terminate_on=(), robot={"accel_max": 1.0})
    env.reset(seed=0)
    n = env.n_followers
    assert env.state_space.shape == (3 * (n + 1) + 2 * n + 2,)
    previous = env.state()
    for _ in range(120):
        env.step({a: np.array([0.6, 0.3]) for a in env.agents})
        state = env.state()
        assert env.state_space.contains(state)
        poses = env.poses
        np.testing.assert_allclose(state[: 3 * (n + 1) : 3], poses[:, 0], rtol=1e-6)
        np.testing.assert_allclose(state[3 * (n + 1) : -2], env.applied_velocities.ravel())
        assert state[-2] >= previous[-2] and state[-1] > previous[-1]
        previous = state
    assert previous[3 * (n + 1)] == pytest.approx(0.6)  # u reached its command at 1 m/s^2
    assert 0.0 < previous[-1] < 1.0


@pytest.mark.parametrize("speed", [0.5, 3.0, 10.0])
def test_walls_stay_solid_when_collisions_are_only_reported(
    corridor: dict[str, Any], speed: float
) -> None:
    """terminate_on=(): a follower driven at a wall never leaves the free space (even fast
    enough to cross a wall within one sub-step), is reported in collision on every step in
    contact, and its clearance is never positive outside."""
    from shapely.geometry import Point

    env = platoon_env.make(corridor, terminate_on=[])
    env.reset(seed=0)
    free = env.scenario.free_space
    r = env.scenario.config.robot.radius
    contact_steps = 0
    for t in range(700):
        # Follower 1 turns left, then drives straight into the corridor's wall; the others stand.
        act = {a: np.zeros(2) for a in env.agents}
        act["follower_1"] = np.array([speed, 3.0 if t < 50 else 0.0])
        _, _, _, _, infos = env.step(act)
        x, y = env.poses[1, :2]
        assert free.covers(Point(x, y)), (x, y)
        clearance = infos["follower_1"]["clearance"]
        if clearance <= r:
            contact_steps += 1
            assert "collision_obstacle" in infos["follower_1"]["violations"]
    assert contact_steps > 50


def test_a_failed_reset_changes_nothing() -> None:
    """reset(options={"poses": infeasible}) on a procedural env: the error leaves the episode,
    its layout and the RNG as they were (the next reset draws what it would have drawn)."""
    from platoon_env.scenarios.schema import ScenarioError

    env = platoon_env.make("procedural_train")
    twin = platoon_env.make("procedural_train")
    env.reset(seed=5)
    twin.reset(seed=5)
    layout, poses = env.layout_index, env.poses
    env.step({a: np.array([0.1, 0.0]) for a in env.agents})
    twin.step({a: np.array([0.1, 0.0]) for a in twin.agents})
    stacked = np.zeros_like(poses)  # every robot on one spot: infeasible anywhere
    with pytest.raises(ScenarioError, match="infeasible"):
        env.reset(options={"poses": stacked})
    assert env.layout_index == layout and env.agents
    np.testing.assert_array_equal(env.poses, twin.poses)
    a, _ = env.reset()
    b, _ = twin.reset()
    assert env.layout_index == twin.layout_index
    np.testing.assert_array_equal(a["follower_1"], b["follower_1"])
