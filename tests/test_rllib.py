"""The Ray RLlib engine (training/rllib.py): episode flags, seeds, MAPPO critic, training.

Skipped unless Ray RLlib is installed: ``bash scripts/test_rllib.sh`` makes ``.venv-rllib``
(the ``rllib`` extra) and runs this file in it.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("ray")
pytest.importorskip("ray.rllib")

import ray
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner

import platoon_env
from training.config import TrainConfig
from training.policies import LearnedPolicy, MLPActor
from training.rllib import (
    MODULE_ID,
    PlatoonMultiAgentEnv,
    PlatoonPPOModule,
    derived_seed,
    export_actor,
    init_ray,
    ppo_config,
    seed_sub_envs,
)
from training.run import LOCK_FILE
from training.train import cli_args
from training.vec_env import ActionRange, observation_scale

REPO = Path(__file__).resolve().parents[1]
PERIOD = 0.05


def rllib_config(**changes: Any) -> TrainConfig:
    """A small RLlib PPO config (local sampling unless changed)."""
    base: dict[str, Any] = {
        "engine": "rllib",
        "scenario": "study_c",
        "num_env_runners": 0,
        "n_envs": 2,
        "n_steps": 64,
        "batch_size": 128,
        "n_epochs": 2,
        "progress_bar": False,
        "seed": 3,
    }
    return TrainConfig(**(base | changes))


def env(**config: Any) -> PlatoonMultiAgentEnv:
    config.setdefault("overrides", {"control_period": PERIOD})
    return PlatoonMultiAgentEnv(config)


@pytest.fixture
def local_ray() -> Iterator[None]:
    """A local Ray instance (2 CPUs, no dashboard) for the tests that start actors."""
    init_ray(None, num_cpus=2)
    yield
    ray.shutdown()


# ------------------------------------------------------------------------------------------------
# The env
# ------------------------------------------------------------------------------------------------
def test_env_order_spaces_scaling_and_render() -> None:
    e = env(render_mode="rgb_array")
    raw = platoon_env.make("study_c", control_period=PERIOD)
    assert e.possible_agents == raw.possible_agents == ["follower_1", "follower_2"]
    obs, infos = e.reset(seed=0)
    raw_obs, _ = raw.reset(seed=0)
    assert list(obs) == e.possible_agents and list(infos) == e.possible_agents
    scale = observation_scale(raw.observation_space("follower_1"))
    for a in e.possible_agents:
        np.testing.assert_allclose(obs[a], raw_obs[a] / scale, rtol=1e-6)
        assert e.observation_spaces[a].contains(obs[a])
        np.testing.assert_array_equal(e.action_spaces[a].low, [-1, -1])
        np.testing.assert_array_equal(e.action_spaces[a].high, [1, 1])
    # The SB3 adapter's action mapping: [-1, 1]^2 -> [u_low, u_high] x [-omega_high, omega_high].
    action = np.array([1.0, -1.0], dtype=np.float32)
    e.step(dict.fromkeys(e.agents, action))
    np.testing.assert_allclose(
        e.env.applied_velocities, np.tile(ActionRange().to_physical(action), (2, 1))
    )
    frame = e.render()
    assert isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.shape[2] == 3
    with pytest.raises(ValueError, match="unknown env_config"):
        PlatoonMultiAgentEnv({"scenaro": "study_c"})


def test_sensor_profile_reaches_the_env() -> None:
    overrides = {"control_period": 0.025}  # aruco: a 30 Hz camera, 50 ms latency
    e = env(sensor_profile="aruco", overrides=overrides)
    ideal = env(overrides=overrides)
    assert e.env.scenario.config.camera != ideal.env.scenario.config.camera


def _episodes(cfg: TrainConfig, n: int, **sample: Any) -> list[Any]:
    runner = MultiAgentEnvRunner(config=ppo_config(cfg))
    try:
        return list(runner.sample(num_episodes=n, **sample))
    finally:
        runner.stop()


def test_time_limit_episodes_are_truncated_not_terminated() -> None:
    """The initial greedy policy drives straight on for far more than 10 steps."""
    episodes = _episodes(rllib_config(max_episode_steps=10), 3, explore=False)
    assert episodes
    for ep in episodes:
        assert len(ep) == 10
        assert (ep.is_terminated, ep.is_truncated) == (False, True)
        for sa in ep.agent_episodes.values():
            assert (sa.is_terminated, sa.is_truncated) == (False, True)


def test_violation_episodes_are_terminated_not_truncated() -> None:
    """Random actions commit a violation within a few dozen steps."""
    episodes = _episodes(rllib_config(n_envs=1), 3, random_actions=True)
    assert episodes
    for ep in episodes:
        assert (ep.is_terminated, ep.is_truncated) == (True, False)
        for sa in ep.agent_episodes.values():
            assert (sa.is_terminated, sa.is_truncated) == (True, False)
        last = ep.get_infos(-1)
        assert any(info.get("violation") for info in last.values())


# ------------------------------------------------------------------------------------------------
# Seeds
# ------------------------------------------------------------------------------------------------
def test_derived_seeds_are_distinct_where_rllibs_collide() -> None:
    seed, runners, envs = 0, 4, 8
    rllib = [seed + w + j for w in range(1, runners + 1) for j in range(envs)]
    assert len(set(rllib)) < len(rllib)  # RLlib's own: seed + w + j
    ours = [derived_seed(seed, w, j) for w in range(1, runners + 1) for j in range(envs)]
    assert len(set(ours)) == len(ours)
    assert derived_seed(seed, 1, 0) != derived_seed(seed, 1, 0, evaluation=True)
    assert derived_seed(1, 1, 0) != derived_seed(0, 1, 0)
    # a resumed run (segment 1) continues on new streams, not its first segment's
    resumed = [
        derived_seed(seed, w, j, segment=1) for w in range(1, runners + 1) for j in range(envs)
    ]
    assert not set(resumed) & set(ours) and len(set(resumed)) == len(resumed)
    # Runner 1's sub-env 1 and runner 2's sub-env 0 share RLlib's seed (seed + 2) and so the
    # procedural layout; with the derived seeds they start differently.
    a, b = env(scenario="procedural_train"), env(scenario="procedural_train")
    a.reset(seed=seed + 1 + 1)
    b.reset(seed=seed + 2 + 0)
    assert a.env.layout_index == b.env.layout_index
    a.reset(seed=derived_seed(seed, 1, 1))
    b.reset(seed=derived_seed(seed, 2, 0))
    assert a.env.layout_index != b.env.layout_index or not np.array_equal(a.env.poses, b.env.poses)


def test_callback_assigns_seeds_by_place() -> None:
    class Runner:
        worker_index = 2

        class config:  # stands in for an AlgorithmConfig
            seed = 7
            in_evaluation = False

    class Vector:
        envs = [env(), env()]

    seed_sub_envs(env_runner=Runner(), env=Vector())
    for j, sub in enumerate(Vector.envs):
        sub.reset(seed=7 + 2 + j)  # what RLlib passes; replaced by the derived seed
        assert sub.seeded_with == derived_seed(7, 2, j)
        assert (sub.worker_index, sub.vector_index) == (2, j)
    # the envs of a resumed segment (ppo_config(cfg, segment) passes it in env_config)
    config = ppo_config(rllib_config(seed=7), segment=3).env_config
    assert config["seed_segment"] == 3

    class Resumed:
        envs = [PlatoonMultiAgentEnv(config)]

    seed_sub_envs(env_runner=Runner(), env=Resumed())
    Resumed.envs[0].reset(seed=9)
    assert Resumed.envs[0].seeded_with == derived_seed(7, 2, 0, segment=3)


# ------------------------------------------------------------------------------------------------
# The MAPPO critic
# ------------------------------------------------------------------------------------------------
def test_central_observation_carries_the_state() -> None:
    e = env(critic="central")
    local = env()
    obs, _ = e.reset(seed=1)
    local_obs, _ = local.reset(seed=1)
    n_state = e.env.state_space.shape[0]
    space = e.env.state_space
    centre, half = (space.low + space.high) / 2, (space.high - space.low) / 2
    for i, a in enumerate(e.possible_agents):
        assert obs[a].shape == (7 + n_state + 2,)
        np.testing.assert_array_equal(obs[a][:7], local_obs[a])
        np.testing.assert_allclose(obs[a][7 : 7 + n_state], (e.state() - centre) / half, atol=1e-6)
        np.testing.assert_array_equal(obs[a][7 + n_state :], np.eye(2)[i])
        assert e.observation_spaces[a].contains(obs[a])
    # The state moves with the platoon; the state columns follow it.
    for _ in range(5):
        obs, *_ = e.step(dict.fromkeys(e.agents, np.array([0.5, 0.0], dtype=np.float32)))
    np.testing.assert_allclose(
        obs["follower_1"][7 : 7 + n_state], (e.state() - centre) / half, atol=1e-6
    )


def _module(critic: str, e: PlatoonMultiAgentEnv) -> PlatoonPPOModule:
    torch.manual_seed(0)
    return PlatoonPPOModule(
        observation_space=e.observation_spaces["follower_1"],
        action_space=e.action_spaces["follower_1"],
        model_config={"critic": critic, "hidden": [16, 16]},
    )


def test_mappo_critic_reads_the_state_and_the_actor_does_not() -> None:
    e = env(critic="central")
    obs, _ = e.reset(seed=0)
    batch = torch.as_tensor(np.stack(list(obs.values())))
    moved = batch.clone()
    moved[:, 7:-2] += 0.3  # change only the global-state columns
    central = _module("central", e)
    with torch.no_grad():
        v, v_moved = (
            central.compute_values({Columns.OBS: batch}),
            central.compute_values({Columns.OBS: moved}),
        )
        pi = central.forward_inference({Columns.OBS: batch})[Columns.ACTION_DIST_INPUTS]
        pi_moved = central.forward_inference({Columns.OBS: moved})[Columns.ACTION_DIST_INPUTS]
    assert v.shape == (2,) and not torch.allclose(v, v_moved)
    assert torch.equal(pi, pi_moved)
    assert central.critic[0].in_features == batch.shape[1]
    assert central.actor[0].in_features == 7
    local = _module("local", env())
    assert local.critic[0].in_features == 7


def test_exported_actor_matches_the_module() -> None:
    e = env()
    module = _module("local", e)
    with torch.no_grad():
        for lin in module.actor:  # non-trivial weights (the output layer starts near zero)
            if isinstance(lin, torch.nn.Linear):
                lin.weight.normal_()
    actor = MLPActor.from_arrays(export_actor(module))
    obs = np.random.default_rng(0).uniform(-1, 1, (32, 7)).astype(np.float32)
    with torch.no_grad():
        out = module.forward_inference({Columns.OBS: torch.as_tensor(obs)})
    mean = out[Columns.ACTION_DIST_INPUTS][:, :2].numpy()
    np.testing.assert_allclose(actor.predict(obs)[0], mean, rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------------------------------
# Training on env-runner actors
# ------------------------------------------------------------------------------------------------
def test_two_runners_train_with_distinct_seeds_and_the_central_critic(local_ray: None) -> None:
    cfg = rllib_config(num_env_runners=2, scenario="procedural_train", critic="central")
    algo = ppo_config(cfg).build_algo()
    try:
        result = algo.train()
        assert result["env_runners"]["num_env_steps_sampled"] >= 2 * 2 * 64
        places = algo.env_runner_group.foreach_env_runner(
            lambda r: [
                (r.worker_index, e.unwrapped.vector_index, e.unwrapped.seeded_with)
                for e in r.env.envs
            ],
            local_env_runner=False,
        )
        subs = [p for runner in places for p in runner]
        assert sorted((w, j) for w, j, _ in subs) == [(1, 0), (1, 1), (2, 0), (2, 1)]
        seeds = [s for *_, s in subs]
        assert len(set(seeds)) == 4
        assert all(s == derived_seed(cfg.seed, w, j) for w, j, s in subs)
        module = algo.get_module(MODULE_ID)
        assert isinstance(module, PlatoonPPOModule) and module.critic_kind == "central"
    finally:
        algo.stop()


def test_cli_run_checkpoint_evaluates_and_resumes(tmp_path: Path) -> None:
    """``platoon-train --engine rllib`` with 2 runners, then ``platoon-evaluate`` on its model
    and checkpoint (no Ray needed there), then ``--resume`` up to a larger total."""
    from experiments.studies.evaluate import main as evaluate_main

    out = tmp_path / "run"
    cfg = rllib_config(
        num_env_runners=2, n_steps=128, batch_size=256, checkpoint_every=1000, seed=0, out=str(out)
    )
    cmd = [sys.executable, "-m", "training.train", *cli_args(**dataclasses.asdict(cfg))]
    res = subprocess.run(
        [*cmd, "--timesteps", "3000"], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert res.returncode == 0, res.stderr[-3000:]
    meta = json.loads((out / "model.json").read_text())
    assert meta["engine"] == "rllib" and meta["algo"] == "ppo" and meta["critic"] == "local"
    assert meta["timesteps"] >= 3000 and meta["interrupted"] is False
    assert meta["control_period"] == PERIOD and meta["num_env_runners"] == 2
    assert meta["action_range"] == ActionRange().to_dict()
    assert meta["observation_normalization"]["type"] == "fixed_scale"
    assert (out / "rllib_checkpoint").is_dir() and (out / "checkpoint.zip").is_file()
    assert not list(out.glob(".*.tmp"))

    policy = LearnedPolicy.load(out)
    assert isinstance(policy.model, MLPActor) and policy.control_period == PERIOD
    raw = platoon_env.make("study_c", control_period=PERIOD)
    obs, _ = raw.reset(seed=0)
    actions = policy.act(obs)
    assert set(actions) == set(obs) and all(raw.action_space(a).contains(actions[a]) for a in obs)

    # The exported actor is the trained module's greedy policy.
    from ray.rllib.core.rl_module.rl_module import RLModule

    module = RLModule.from_checkpoint(
        out / "rllib_checkpoint" / "learner_group" / "learner" / "rl_module" / MODULE_ID
    )
    norm = np.stack([obs[a] for a in raw.possible_agents]) / np.asarray(
        meta["observation_normalization"]["scale"], dtype=np.float32
    )
    with torch.no_grad():
        dist = module.forward_inference({Columns.OBS: torch.as_tensor(norm, dtype=torch.float32)})
    mean = dist[Columns.ACTION_DIST_INPUTS][:, :2].numpy()
    expected = ActionRange().to_physical(mean)
    np.testing.assert_allclose(
        np.stack([actions[a] for a in raw.possible_agents]), expected, rtol=1e-5, atol=1e-5
    )

    code = evaluate_main(
        [
            "--policy",
            f"rllib={out}",
            "--policy",
            f"rllib_ckpt={out / 'checkpoint.zip'}",
            "--scenario",
            "study_c",
            "--episodes",
            "1",
            "--workers",
            "1",
            "--no-plots",
            "--out",
            str(tmp_path / "eval"),
        ]
    )
    assert code == 0
    summary = (tmp_path / "eval" / "summary.md").read_text()
    assert "| study_c | rllib |" in summary and "| study_c | rllib_ckpt |" in summary

    res = subprocess.run(
        [*cmd, "--timesteps", "5000", "--resume"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "resuming from" in res.stderr
    resumed = json.loads((out / "model.json").read_text())
    assert resumed["timesteps"] >= 5000 and resumed["started_at"] >= meta["started_at"]
    assert len(resumed["segments"]) == 2 and not (out / LOCK_FILE).exists()
