"""The batched core and its SB3 VecEnv reproduce the single env bit for bit.

Same seeds and same actions must give identical observations, rewards, terminations,
truncations and poses, through episode ends and automatic resets, with one or two threads.
"""

from __future__ import annotations

import pickle
from typing import Any

import numba
import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.env import PlatoonParallelEnv
from platoon_env.geometry.sensing import sense
from platoon_env.initial import InitialSampler
from platoon_env.records import constraint_params
from platoon_env.scenarios.scenario import initial_violations


def _stack(d: dict[str, Any], agents: list[str]) -> np.ndarray:
    return np.stack([np.asarray(d[a]) for a in agents])


def _random_actions(rng: np.random.Generator, b: int, n: int) -> np.ndarray:
    return rng.uniform([-0.5, -2.0], [1.5, 2.0], size=(b, n, 2)).astype(np.float32)


def _compare_rollout(
    scenario: Any, seeds: list[int], steps: int, n_threads: int = 1, **kwargs: Any
) -> int:
    """Step a BatchedPlatoon (auto-reset) and one env per seed in lockstep; returns episodes."""
    batch = BatchedPlatoon(scenario, len(seeds), n_threads=n_threads, auto_reset=True, **kwargs)
    envs = [PlatoonParallelEnv(scenario, **kwargs) for _ in seeds]
    agents = envs[0].possible_agents
    obs = batch.reset(seeds)
    for b, (env, seed) in enumerate(zip(envs, seeds, strict=True)):
        env_obs, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs[b], _stack(env_obs, agents))
        np.testing.assert_array_equal(batch.poses[b], env.poses)
    rng = np.random.default_rng(0)
    episodes = 0
    for t in range(steps):
        actions = _random_actions(rng, len(seeds), len(agents))
        obs, rewards, terminated, truncated, info = batch.step(actions)
        for b, env in enumerate(envs):
            e_obs, e_rew, e_term, e_trunc, _ = env.step(
                {a: actions[b, i] for i, a in enumerate(agents)}
            )
            where = f"step {t}, env {b}"
            assert terminated[b] == e_term[agents[0]], where
            assert truncated[b] == e_trunc[agents[0]], where
            np.testing.assert_array_equal(rewards[b], [e_rew[a] for a in agents], err_msg=where)
            np.testing.assert_array_equal(info["violations"][b], env.violation_masks, err_msg=where)
            if terminated[b] or truncated[b]:
                episodes += 1
                np.testing.assert_array_equal(
                    info["final_observation"][b], _stack(e_obs, agents), err_msg=where
                )
                e_obs, _ = env.reset()  # the env's own RNG continues, as in the batch
            np.testing.assert_array_equal(obs[b], _stack(e_obs, agents), err_msg=where)
            np.testing.assert_array_equal(batch.poses[b], env.poses, err_msg=where)
    return episodes


@pytest.mark.parametrize("scenario", ["study_a", "study_c"])
def test_batched_matches_single_env(scenario: str) -> None:
    _compare_rollout(scenario, [0, 1, 2], 150)


def test_batched_matches_through_episode_ends(corridor: dict[str, Any]) -> None:
    """Random actions in a narrow corridor end episodes often (violations and time limits)."""
    episodes = _compare_rollout(corridor, [5, 6, 7, 8], 300, control_period=0.05)
    assert episodes >= 4
    episodes = _compare_rollout(corridor, [1, 2], 120, max_episode_steps=25, terminate_on=())
    assert episodes >= 4


@pytest.mark.skipif(
    numba.config.NUMBA_NUM_THREADS < 2,  # type: ignore[attr-defined]
    reason="numba's thread pool has one thread on this machine",
)
@pytest.mark.parametrize("n_threads", [1, 2])
def test_procedural_batch_matches_single_envs(n_threads: int) -> None:
    """Each env of a procedural batch draws its own layouts from its own seed, exactly as a
    single env does: time limits and violations end episodes often, so many layouts are seen."""
    seeds = [3, 4, 5]
    episodes = _compare_rollout(
        "procedural_train", seeds, 160, n_threads=n_threads, max_episode_steps=30
    )
    assert episodes >= 3 * len(seeds)
    batch = BatchedPlatoon("procedural_train", 4, max_episode_steps=30)
    batch.reset(0)
    layouts = [sc.layout_index for sc in batch.scenarios]
    assert len(set(layouts)) == 4, layouts


def test_two_threads_match_one(corridor: dict[str, Any]) -> None:
    episodes = _compare_rollout(corridor, list(range(9)), 120, n_threads=2, control_period=0.05)
    assert episodes >= 1


def test_reset_subset_and_seeds(corridor: dict[str, Any]) -> None:
    batch = BatchedPlatoon(corridor, 3)
    first = batch.reset(10)
    again = batch.reset([10, 11, 12])
    np.testing.assert_array_equal(first, again)
    env = platoon_env.make(corridor)
    env_obs, _ = env.reset(seed=11)
    np.testing.assert_array_equal(first[1], _stack(env_obs, env.possible_agents))
    moved = batch.step(np.full((3, 2, 2), 0.3, dtype=np.float32))[0]
    after = batch.reset([11], envs=[1])
    np.testing.assert_array_equal(after[1], first[1])
    np.testing.assert_array_equal(after[0], moved[0])
    assert batch.steps.tolist() == [1, 0, 1]
    unperturbed = batch.reset(0, perturb=False)
    np.testing.assert_array_equal(unperturbed[0], unperturbed[2])


def test_invalid_use(corridor: dict[str, Any]) -> None:
    batch = BatchedPlatoon(corridor, 2, terminate_on=())
    actions = np.zeros((2, 2, 2))
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(actions)
    batch.reset(0)
    poses = batch.poses
    bad = actions.copy()
    bad[1, 0, 1] = np.nan
    with pytest.raises(ValueError, match="env 1, 'follower_1'"):
        batch.step(bad)
    np.testing.assert_array_equal(batch.poses, poses)
    with pytest.raises(ValueError, match="shape"):
        batch.step(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="n_threads"):
        BatchedPlatoon(corridor, 2, n_threads=0)
    with pytest.raises(ValueError, match="batch_size"):
        BatchedPlatoon(corridor, 0)


def test_finished_envs_need_a_reset(corridor: dict[str, Any]) -> None:
    batch = BatchedPlatoon(corridor, 2, max_episode_steps=3, terminate_on=())
    batch.reset(0)
    for _ in range(3):
        _, _, terminated, truncated, _ = batch.step(np.zeros((2, 2, 2)))
    assert truncated.all() and not terminated.any()
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(np.zeros((2, 2, 2)))


def test_pickle_round_trip(corridor: dict[str, Any]) -> None:
    batch = BatchedPlatoon(corridor, 2, auto_reset=True)
    batch.reset(3)
    batch.step(np.full((2, 2, 2), 0.2))
    clone = pickle.loads(pickle.dumps(batch))
    actions = np.full((2, 2, 2), 0.25)
    for _ in range(5):
        a = batch.step(actions)
        b = clone.step(actions)
        for x, y in zip(a[:4], b[:4], strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("scenario", ["study_a", "study_b"])
def test_initial_sampler_decides_as_initial_violations(scenario: str) -> None:
    """The compiled feasibility test takes the decisions of ``initial_violations``."""
    sc = platoon_env.load_scenario(scenario)
    sampler = InitialSampler(sc)
    rng = np.random.default_rng(0)
    n = sc.config.followers
    decisions = []
    for scale in (0.05, 0.3, 1.0):
        for _ in range(60):
            cand = sampler.base.copy()
            cand[1:, :2] += rng.uniform(-1, 1, size=(n, 2)) * scale
            cand[1:, 2] += rng.uniform(-1, 1, size=n) * scale
            expected = not initial_violations(sc.config, sc.workspace, cand)
            assert sampler.feasible(cand) == expected
            decisions.append(expected)
    assert any(decisions) and not all(decisions)


# --------------------------------------------------------------------------------------------
# The SB3 VecEnv


def test_vec_env_matches_platoon_vec_env() -> None:
    from training.batched_vec_env import BatchedPlatoonVecEnv
    from training.vec_env import ActionRange, PlatoonVecEnv

    kwargs: dict[str, Any] = {"control_period": 0.05, "max_episode_steps": 40}
    action_range = ActionRange()
    reference = PlatoonVecEnv(
        [lambda: platoon_env.make("study_c", **kwargs) for _ in range(3)],
        action_range=action_range,
    )
    batched = BatchedPlatoonVecEnv("study_c", 3, action_range=action_range, **kwargs)
    assert batched.num_envs == reference.num_envs == 6
    assert batched.observation_space == reference.observation_space
    assert batched.action_space == reference.action_space
    reference.seed(5)
    batched.seed(5)
    np.testing.assert_array_equal(batched.reset(), reference.reset())
    rng = np.random.default_rng(1)
    ends = 0
    for t in range(200):
        actions = rng.uniform(-1, 1, size=(6, 2)).astype(np.float32)
        obs_r, rew_r, done_r, info_r = reference.step(actions)
        obs_b, rew_b, done_b, info_b = batched.step(actions)
        np.testing.assert_array_equal(obs_b, obs_r, err_msg=str(t))
        np.testing.assert_array_equal(rew_b, rew_r, err_msg=str(t))
        assert rew_b.dtype == rew_r.dtype and obs_b.dtype == obs_r.dtype
        np.testing.assert_array_equal(done_b, done_r, err_msg=str(t))
        for k in range(6):
            for key in ("violation", "violations", "cost", "TimeLimit.truncated"):
                assert info_b[k].get(key) == info_r[k].get(key), (t, k, key)
            if done_r[k]:
                np.testing.assert_array_equal(
                    info_b[k]["terminal_observation"], info_r[k]["terminal_observation"]
                )
        ends += int(done_r.sum())
    assert ends > 0
    assert batched.get_attr("n_followers") == [2] * 6
    assert batched.slot_env(5) == 2 and list(batched.env_slots(1)) == [2, 3]
    with pytest.raises(ValueError, match="perturb"):
        batched.set_options({"poses": None})


def test_vec_env_trains_ppo() -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from training.batched_vec_env import BatchedPlatoonVecEnv
    from training.vec_env import ActionRange

    venv = VecMonitor(
        BatchedPlatoonVecEnv("study_c", 2, action_range=ActionRange(), control_period=0.05)
    )
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=64)
    assert model.num_timesteps >= 64


@pytest.mark.parametrize("scenario", ["study_a", "study_b", "study_c"])
def test_simulated_steps_do_not_depend_on_culling(scenario: str) -> None:
    """Random actions, no termination: the core with the edge grid and with one cell (every
    edge visited) gives the same steps, and its sensing is that of :func:`sense` (with the
    scenario's proximity sector, study B's ±130 deg, and its inflation)."""
    culled = BatchedPlatoon(scenario, 1, terminate_on=())
    brute = BatchedPlatoon(scenario, 1, terminate_on=(), grid_cell_size=0.0)
    culled.reset(0)
    brute.reset(0)
    params = constraint_params(culled.scenario.config)[0]
    edges = culled.scenario.workspace.edges
    rng = np.random.default_rng(0)
    n = culled.n_followers
    for t in range(300):
        act = rng.uniform([-0.3, -1.5], [1.0, 1.5], size=(1, n, 2))
        _, _, _, _, info_a = culled.step(act)
        _, _, _, _, info_b = brute.step(act)
        np.testing.assert_array_equal(info_a["violations"], info_b["violations"], err_msg=str(t))
        np.testing.assert_array_equal(culled.poses, brute.poses, err_msg=str(t))
        np.testing.assert_allclose(culled.sensed, brute.sensed, rtol=0, atol=1e-12)
        direct = sense(culled.poses[0], edges, params)
        np.testing.assert_allclose(culled.sensed[0], direct, rtol=0, atol=1e-12, err_msg=str(t))
