"""The Ray RLlib engine (training/rllib.py): episode flags, seeds, MAPPO critic, training,
the cost penalty and episode records, progress.csv/TensorBoard, PPO-Lagrangian, task-aware
observations. The two-node cluster run is in scripts/test_rllib.sh.

Skipped unless Ray RLlib is installed: ``bash scripts/test_rllib.sh`` makes ``.venv-rllib``
(the ``rllib`` extra) and runs this file in it.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("ray")
pytest.importorskip("ray.rllib")

import ray
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner

import platoon_env
from platoon_env.observation import OBS_SIZE_TASK
from training.config import TrainConfig
from training.curves import PROGRESS_COLUMNS, PROGRESS_FILE
from training.lagrangian import LagrangeMultiplier
from training.policies import LearnedPolicy, MLPActor
from training.rllib import (
    MODULE_ID,
    TRAIN_SCALARS,
    PlatoonMultiAgentEnv,
    PlatoonPPOModule,
    _on_runners,
    _pop_outcomes,
    cluster_metadata,
    derived_seed,
    export_actor,
    init_ray,
    ppo_config,
    project_runtime_env,
    seed_sub_envs,
    train_rllib,
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
        box = e.action_spaces[a]
        assert isinstance(box, gym.spaces.Box)
        np.testing.assert_array_equal(box.low, [-1, -1])
        np.testing.assert_array_equal(box.high, [1, 1])
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


def test_cost_penalty_and_episode_records() -> None:
    """With a multiplier, each reward is the env's minus lambda * info["cost"]; the episode
    record keeps the unpenalised returns, the costs and the causes."""
    lam = 2.5
    penalised, plain = env(), env()
    penalised.cost_multiplier = lam
    penalised.reset(seed=4)
    plain.reset(seed=4)
    rng = np.random.default_rng(0)
    returns = np.zeros(2)
    costs = np.zeros(2)
    steps = 0
    while penalised.agents:
        action = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in penalised.agents}
        _, rew, term, _, infos = penalised.step(action)
        _, raw, *_ = plain.step(action)
        cost = np.array([infos[a]["cost"] for a in plain.possible_agents], dtype=float)
        for i, a in enumerate(plain.possible_agents):
            assert rew[a] == pytest.approx(raw[a] - lam * cost[i])
            returns[i] += raw[a]
        costs += cost
        steps += 1
        assert steps < 10_000
    assert term["__all__"] and costs.sum() >= 1  # random actions end in a violation
    (outcome,) = penalised.pop_outcomes()
    assert penalised.pop_outcomes() == []
    np.testing.assert_allclose(outcome.returns, returns)
    np.testing.assert_array_equal(outcome.costs, costs)
    assert outcome.length == steps == penalised.env_steps
    assert outcome.violations == tuple(infos[a]["violation"] for a in plain.possible_agents)
    assert not outcome.team_success
    assert plain.pop_outcomes()[0].returns == outcome.returns


def test_project_runtime_env_ships_the_packages() -> None:
    runtime_env = project_runtime_env()
    dirs = [Path(d) for d in runtime_env["py_modules"]]
    assert [d.name for d in dirs] == ["platoon_env", "training"]
    assert all((d / "__init__.py").is_file() for d in dirs)
    assert (dirs[1] / "rllib.py").is_file()
    # the runtime env is what Ray validates and ships
    from ray.runtime_env import RuntimeEnv

    assert RuntimeEnv(**runtime_env)["py_modules"] == runtime_env["py_modules"]


def test_ppo_config_refuses_other_algorithms() -> None:
    with pytest.raises(ValueError, match="ppo and ppo_lagrangian"):
        ppo_config(rllib_config(algo="sac"))


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
        # The episodes each runner recorded reach the driver; the "ray" entry of model.json
        # places both runners (on this one-node instance: the driver's node).
        outcomes = [o for batch in _on_runners(algo, cfg, _pop_outcomes) for o in batch]
        assert result["env_runners"]["num_episodes"] == len(outcomes) > 0
        assert all(len(o.returns) == 2 and o.length > 0 for o in outcomes)
        assert _on_runners(algo, cfg, _pop_outcomes) == [[], []]
        placed = cluster_metadata(algo, cfg)
        assert [r["worker_index"] for r in placed["env_runners"]] == [1, 2]
        assert all(r["env_steps"] >= 2 * 64 for r in placed["env_runners"])
        assert {r["node_id"] for r in placed["env_runners"]} == {placed["driver_node_id"]}
        assert placed["nodes_alive"] == [placed["driver_node_id"]]
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


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames or ()) == PROGRESS_COLUMNS
        return list(reader)


def _float(text: str) -> float:
    return math.nan if text == "" else float(text)


def test_lagrangian_task_aware_run_logs_like_sb3(tmp_path: Path, local_ray: None) -> None:
    """``--algo ppo_lagrangian --task-aware-observations`` sampled in the driver: the actor
    reads the 13 task-aware values, progress.csv has the SB3 columns with a row per
    ``--log-every``, its ``lambda`` column follows the dual-ascent rule on its ``cost_mean``,
    TensorBoard has SB3's tags at the same timesteps, and a resume continues the multiplier."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "lag"
    budget, lr = 0.05, 0.5
    cfg = rllib_config(
        algo="ppo_lagrangian",
        task_aware_observations=True,
        n_steps=32,
        batch_size=64,
        n_epochs=1,
        timesteps=500,  # 4 iterations of 32 * 2 envs * 2 followers = 128 transitions
        log_every=100,
        cost_budget=budget,
        lagrangian_lr=lr,
        checkpoint_every=0,
        control_period=PERIOD,
        out=str(out),
    )
    path, interrupted = train_rllib(cfg)
    assert not interrupted
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["algo"] == "ppo_lagrangian" and len(meta["observation_layout"]) == OBS_SIZE_TASK
    assert len(meta["observation_normalization"]["scale"]) == OBS_SIZE_TASK
    assert meta["ray"]["env_runners"][0]["worker_index"] == 0
    # the env steps RLlib counted, plus the one step its env checker takes in each sub-env
    assert meta["ray"]["env_runners"][0]["env_steps"] == meta["env_steps"] + 2

    rows = _rows(out / PROGRESS_FILE)
    steps = [int(r["timesteps"]) for r in rows]
    # log_every 100 < one iteration (about 32 * 2 envs * 2 followers): a row after each
    assert len(steps) == 4 and steps[-1] == meta["timesteps"]
    assert all(b - a >= cfg.log_every for a, b in zip([0, *steps], steps, strict=False))
    # lambda of row k is the multiplier iteration k trained with: 0, then dual ascent on
    # the costs of the follower episodes of the row before (every row has episodes here).
    rule = LagrangeMultiplier(budget=budget, lr=lr)
    for row in rows:
        assert int(row["episodes"]) > 0
        assert _float(row["lambda"]) == pytest.approx(rule.value, rel=1e-4, abs=1e-6)
        assert 0 <= _float(row["success_rate"]) <= 1 and _float(row["cost_mean"]) >= 0
        # the rule's update from the row's mean cost (n equal weights: the mean)
        rule.update([_float(row["cost_mean"])])
    assert meta["lagrange_multiplier"] == pytest.approx(rule.value, rel=1e-4, abs=1e-6)
    assert rule.value > 0  # random-ish early policies violate far above the budget

    (tb,) = (out / "tb").iterdir()
    assert tb.name == f"{cfg.run_name}_1"
    events = EventAccumulator(str(tb))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    want = {
        "rollout/ep_rew_mean",
        "rollout/ep_len_mean",
        "platoon/violation",
        "lagrangian/lambda",
        "lagrangian/episode_cost",
        "time/fps",
        *TRAIN_SCALARS,
    }
    assert want <= tags, want - tags
    assert [e.step for e in events.Scalars("train/value_loss")] == steps
    lam_tb = [e.value for e in events.Scalars("lagrangian/lambda")]
    assert lam_tb[-1] == pytest.approx(meta["lagrange_multiplier"], rel=1e-5)

    policy = LearnedPolicy.load(out)
    raw = platoon_env.make("study_c", control_period=PERIOD, observation={"task_aware": True})
    obs, _ = raw.reset(seed=0)
    assert obs["follower_1"].shape == (OBS_SIZE_TASK,)
    actions = policy.act(obs)
    assert all(raw.action_space(a).contains(actions[a]) for a in obs)

    # --resume: the rows up to the checkpoint are kept and the multiplier continues from it
    resumed, _ = train_rllib(dataclasses.replace(cfg, timesteps=700, resume=True))
    after = json.loads(resumed.with_suffix(".json").read_text())
    rows = _rows(out / PROGRESS_FILE)
    again = [int(r["timesteps"]) for r in rows]
    assert again[: len(steps)] == steps and again[-1] == after["timesteps"] >= 700
    assert len(again) > len(steps) and again[len(steps)] > steps[-1]
    assert _float(rows[len(steps)]["lambda"]) == pytest.approx(
        meta["lagrange_multiplier"], rel=1e-4, abs=1e-6
    )
    assert len(after["segments"]) == 2
