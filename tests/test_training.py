"""Tests of the learning side: the parameter-sharing VecEnv, LearnedPolicy and platoon-train."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import torch

import platoon_env
from baselines.policy import Policy
from training import ActionRange, LearnedPolicy, PlatoonVecEnv
from training.policies import save_model
from training.seeding import env_seeds
from training.train import (
    TrainConfig,
    build_model,
    build_vec_env,
    cli_args,
    parse_args,
    run_metadata,
)

REPO = Path(__file__).resolve().parents[1]
PERIOD = 0.05  # [s] the training default


def make_venv(n_envs: int = 1, **overrides: Any) -> PlatoonVecEnv:
    """``n_envs`` study C envs (2 followers each) with the default rescaling."""
    overrides.setdefault("control_period", PERIOD)
    return PlatoonVecEnv(
        [lambda: platoon_env.make("study_c", **overrides) for _ in range(n_envs)],
        action_range=ActionRange(),
    )


def tiny_config(**changes: Any) -> TrainConfig:
    """A PPO config whose first rollout is 256 timesteps (1 env x 2 followers x 128)."""
    base: dict[str, Any] = {
        "n_envs": 1,
        "n_steps": 128,
        "batch_size": 64,
        "n_epochs": 2,
        "progress_bar": False,
        "seed": 3,
    }
    return TrainConfig(**(base | changes))


pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ------------------------------------------------------------------------------------------------
# PlatoonVecEnv
# ------------------------------------------------------------------------------------------------
def test_slots_spaces_and_dtypes() -> None:
    venv = make_venv(n_envs=3)
    assert venv.num_envs == 3 * 2 and venv.n_envs == 3
    assert venv.action_space.shape == (2,)
    np.testing.assert_array_equal(venv.action_space.low, [-1, -1])
    np.testing.assert_array_equal(venv.action_space.high, [1, 1])
    venv.seed(0)
    obs = venv.reset()
    assert obs.shape == (6, 7) and obs.dtype == np.float32
    assert all(venv.observation_space.contains(o) for o in obs)
    obs, rewards, dones, infos = venv.step(np.zeros((6, 2), dtype=np.float32))
    assert obs.shape == (6, 7) and obs.dtype == np.float32
    assert rewards.shape == (6,) and dones.shape == (6,) and dones.dtype == bool
    assert len(infos) == 6 and all("violation" in i for i in infos)
    assert [venv.slot_env(k) for k in range(6)] == [0, 0, 1, 1, 2, 2]
    assert list(venv.env_slots(1)) == [2, 3]


def test_attribute_access_and_methods() -> None:
    venv = make_venv(n_envs=2)
    assert venv.get_attr("n_followers") == [2, 2, 2, 2]
    assert venv.get_attr("control_period", indices=[3]) == [PERIOD]
    venv.set_attr("tag", "x", indices=[2, 3])
    assert not hasattr(venv.envs[0], "tag") and venv.envs[1].tag == "x"
    venv.seed(0)
    venv.reset()
    states = venv.env_method("state", indices=[0, 1, 2])
    assert len(states) == 3 and np.array_equal(states[0], states[1])
    assert venv.env_is_wrapped(object) == [False] * 4  # type: ignore[arg-type]


def test_action_rescaling() -> None:
    rng = ActionRange(u_low=-0.5, u_high=1.5, omega_high=2.0)
    np.testing.assert_allclose(rng.to_physical(np.array([-1.0, -1.0])), [-0.5, -2.0])
    np.testing.assert_allclose(rng.to_physical(np.array([1.0, 1.0])), [1.5, 2.0])
    np.testing.assert_allclose(
        rng.to_physical(np.array([[-0.5, 0.0], [3.0, -7.0]])),
        [
            [0.0, 0.0],
            [1.5, -2.0],
        ],
    )
    with pytest.raises(ValueError, match="actuator limits"):
        PlatoonVecEnv([lambda: platoon_env.make("study_c", u_max=1.0)], action_range=rng)
    with pytest.raises(ValueError):
        ActionRange(u_low=1.0, u_high=0.0)


def test_truncation_flags_and_auto_reset() -> None:
    """A max_episode_steps truncation: flags on the last step only, then the reset obs."""
    steps = 5
    venv = make_venv(max_episode_steps=steps)
    reference = platoon_env.make("study_c", control_period=PERIOD, max_episode_steps=steps)
    scale = venv.obs_scale
    assert scale is not None
    (seed,) = venv.seed(11)  # env 0's own seed of SeedSequence(11)
    obs = venv.reset()
    ref_obs, _ = reference.reset(seed=seed)
    np.testing.assert_array_equal(obs[0], ref_obs["follower_1"] / scale)
    stand_still = np.tile(np.array([-0.5, 0.0], dtype=np.float32), (2, 1))  # u = 0, omega = 0
    physical = {a: np.zeros(2, dtype=np.float32) for a in reference.possible_agents}
    for t in range(1, steps + 1):
        obs, _, dones, infos = venv.step(stand_still)
        ref_obs, _, ref_term, ref_trunc, _ = reference.step(physical)
        if t < steps:
            assert not dones.any()
            assert all("terminal_observation" not in i for i in infos)
            assert all("TimeLimit.truncated" not in i for i in infos)
    assert all(ref_trunc.values()) and not any(ref_term.values())
    assert dones.all()
    for k, agent in enumerate(reference.possible_agents):
        assert infos[k]["TimeLimit.truncated"] is True
        np.testing.assert_array_equal(infos[k]["terminal_observation"], ref_obs[agent] / scale)
    # auto-reset: the env continues its own RNG, as a plain reset() of the reference does
    assert venv.envs[0].agents == venv.envs[0].possible_agents and venv.envs[0].steps == 0
    ref_reset, _ = reference.reset()
    np.testing.assert_array_equal(obs, np.stack([ref_reset[a] for a in ref_reset]) / scale)


def test_termination_flags() -> None:
    """A violation: terminal_observation present exactly when done, TimeLimit.truncated False."""
    venv = make_venv(max_episode_steps=1000)
    venv.seed(0)
    venv.reset()
    spin = np.tile(np.array([-0.5, 1.0], dtype=np.float32), (2, 1))  # u = 0, omega = 2 rad/s
    for _ in range(100):
        _, _, dones, infos = venv.step(spin)
        for done, info in zip(dones, infos, strict=True):
            assert ("terminal_observation" in info) == bool(done)
        if dones.any():
            break
    assert dones.all(), "spinning in place must break the field of view"
    assert all(i["TimeLimit.truncated"] is False for i in infos)
    assert any(i["violation"] is not None for i in infos)
    assert all(i["terminal_observation"].shape == (7,) for i in infos)


def test_seeded_reproducibility() -> None:
    """Same seed + same actions -> identical observations; env j is reset with its own seed of
    ``SeedSequence(seed)`` (training.seeding)."""
    rng = np.random.default_rng(5)
    actions = rng.uniform(-1, 1, size=(150, 4, 2)).astype(np.float32)
    runs = []
    for _ in range(2):
        venv = make_venv(n_envs=2, max_episode_steps=40)
        venv.seed(123)
        trace = [venv.reset()]
        for a in actions:
            obs, rewards, dones, _ = venv.step(a)
            trace += [obs, rewards[:, None].repeat(7, axis=1), dones[:, None].repeat(7, axis=1)]
        runs.append(np.stack(trace))
    np.testing.assert_array_equal(runs[0], runs[1])
    venv = make_venv(n_envs=2)
    scale = venv.obs_scale
    assert scale is not None
    assert list(venv.seed(123)) == env_seeds(123, 2)
    obs = venv.reset()
    for j in range(2):
        ref, _ = platoon_env.make("study_c", control_period=PERIOD).reset(seed=env_seeds(123, 2)[j])
        np.testing.assert_array_equal(obs[2 * j], ref["follower_1"] / scale)
    assert not np.array_equal(obs[0:2], obs[2:4])  # the seeded perturbations differ


# ------------------------------------------------------------------------------------------------
# Training and LearnedPolicy
# ------------------------------------------------------------------------------------------------
def test_parse_args_matches_config() -> None:
    assert parse_args([]) == TrainConfig()
    cfg = parse_args(
        [
            "--algo",
            "sac",
            "--net-arch",
            "32",
            "32",
            "--no-progress-bar",
            "--control-period",
            "0.02",
            "--max-episode-steps",
            "100",
        ]
    )
    assert cfg.algo == "sac" and cfg.net_arch == [32, 32] and cfg.progress_bar is False
    assert cfg.control_period == 0.02 and cfg.max_episode_steps == 100


def test_numbers_are_read_as_yaml_writes_them(capsys: pytest.CaptureFixture[str]) -> None:
    """Integer options take an integral number in exponent form (``2e3``), floats ``5e-2``;
    a fractional value of an integer option is an argparse error naming it."""
    cfg = parse_args(["--timesteps", "2e3", "--checkpoint-every", "1.5E3", "--cost-budget", "5e-2"])
    assert cfg.timesteps == 2000 and type(cfg.timesteps) is int
    assert cfg.checkpoint_every == 1500 and cfg.cost_budget == 0.05
    assert parse_args(["--timesteps", "1e12"]).timesteps == 10**12  # the largest, exactly
    for bad in ("2.5", "1e-3", "nan", "inf", "ten"):
        with pytest.raises(SystemExit) as info:
            parse_args(["--timesteps", bad])
        assert info.value.code == 2
        assert "argument --timesteps: expected an integer" in capsys.readouterr().err


def test_cli_args_is_the_inverse_of_parse_args() -> None:
    cfg = TrainConfig(
        algo="sac",
        seed=7,
        out="runs/x",
        net_arch=[32, 16],
        progress_bar=False,
        batched=True,
        control_period=0.02,
        max_episode_steps=300,
        learning_rate=5e-4,
    )
    assert parse_args(cli_args(**dataclasses.asdict(cfg))) == cfg
    assert cli_args(seed=0, net_arch=[16, 16], progress_bar=False, out=None) == [
        "--seed",
        "0",
        "--net-arch",
        "16",
        "16",
        "--no-progress-bar",
    ]
    with pytest.raises(TypeError, match="no_such_option"):
        cli_args(no_such_option=1)


def _tiny_ppo_params(cfg: TrainConfig) -> dict[str, torch.Tensor]:
    venv = build_vec_env(cfg)
    model = build_model(cfg, venv)
    model.learn(256)
    assert model.num_timesteps == 256
    return {k: v.clone() for k, v in model.policy.state_dict().items()}


def test_ppo_seeded_runs_identical() -> None:
    cfg = tiny_config()
    first, second = _tiny_ppo_params(cfg), _tiny_ppo_params(cfg)
    assert first.keys() == second.keys()
    for key in first:
        assert torch.equal(first[key], second[key]), key
    other = _tiny_ppo_params(tiny_config(seed=4))
    assert any(not torch.equal(first[k], other[k]) for k in first)


def test_metadata_step_limit() -> None:
    """model.json records a fixed workspace's step limit, and none for procedural layouts
    (each layout derives its own) unless one was set."""
    fixed = platoon_env.make("study_c", control_period=tiny_config().control_period)
    for scenario, limit, expected in [
        ("study_c", None, fixed.max_episode_steps),
        ("procedural_train", None, None),
        ("procedural_train", 500, 500),
    ]:
        cfg = tiny_config(scenario=scenario, max_episode_steps=limit)
        venv = build_vec_env(cfg)
        meta = run_metadata(cfg, venv, build_model(cfg, venv))
        assert meta["max_episode_steps"] == expected, scenario


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_learned_policy_round_trip(tmp_path: Path, algo: str) -> None:
    cfg = tiny_config(algo=algo, learning_starts=64, batch_size=64, net_arch=[32, 32])
    venv = build_vec_env(cfg)
    model = build_model(cfg, venv)
    model.learn(256)
    path = save_model(model, tmp_path / "model.zip", run_metadata(cfg, venv, model))
    assert path.is_file() and (tmp_path / "model.json").is_file()
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["algo"] == algo and meta["control_period"] == PERIOD

    policy = LearnedPolicy.load(tmp_path / "model.zip")
    assert isinstance(policy, Policy)
    assert policy.control_period == PERIOD and policy.scenario == "study_c"
    env = platoon_env.make("study_c", control_period=policy.control_period)
    obs, _ = env.reset(seed=0)
    policy.reset(seed=0)
    for _ in range(20):
        actions = policy.act(obs)
        assert set(actions) == set(obs)
        for a in actions.values():
            assert a.shape == (2,) and a.dtype == np.float32
            assert cfg.u_low <= a[0] <= cfg.u_high and abs(a[1]) <= cfg.omega_high
        again = policy.act(obs)
        assert all(np.array_equal(actions[k], again[k]) for k in actions)
        # the same normalisation and rescaling as in training
        stacked = np.stack([obs[k] for k in obs])
        raw, _ = model.predict(stacked / venv.obs_scale, deterministic=True)
        expected = cfg.action_range.to_physical(raw)
        np.testing.assert_allclose(np.stack([actions[k] for k in obs]), expected, atol=1e-6)
        obs, *_ = env.step(actions)
        if not env.agents:
            obs, _ = env.reset()


def test_learned_policy_needs_metadata(tmp_path: Path) -> None:
    cfg = tiny_config()
    model = build_model(cfg, build_vec_env(cfg))
    model.save(tmp_path / "model.zip")
    with pytest.raises(FileNotFoundError, match=r"model\.json"):
        LearnedPolicy.load(tmp_path / "model.zip")


def _train_cmd(out: Path, *extra: str) -> list[str]:
    options = cli_args(algo="ppo", scenario="study_c", seed=0, out=out)
    return [sys.executable, "-m", "training.train", *options, *extra]


def test_train_cli_smoke(tmp_path: Path) -> None:
    out = tmp_path / "run"
    res = subprocess.run(
        _train_cmd(out, "--timesteps", "2048"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert (out / "model.zip").is_file() and (out / "model.json").is_file()
    meta = json.loads((out / "model.json").read_text())
    assert meta["algo"] == "ppo" and meta["scenario"] == "study_c" and meta["seed"] == 0
    assert meta["timesteps"] >= 2048 and meta["interrupted"] is False
    assert meta["action_range"] == ActionRange().to_dict()
    assert meta["observation_normalization"]["type"] == "fixed_scale"
    assert "git_commit" in meta and meta["wall_time_s"] > 0
    assert any((out / "tb").rglob("events.out.tfevents.*"))
    assert not list(out.glob(".*.tmp"))
    LearnedPolicy.load(out)


def test_train_cli_ctrl_c_saves(tmp_path: Path) -> None:
    """SIGINT mid-run: the last checkpoint survives and the model so far is saved."""
    out = tmp_path / "run"
    proc = subprocess.Popen(
        _train_cmd(
            out, "--timesteps", "10000000", "--checkpoint-every", "4096", "--no-progress-bar"
        ),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # pytest-xdist workers ignore SIGINT and children inherit that: restore the default so
        # that Python installs its KeyboardInterrupt handler in the trainer.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        # Generous: a fresh clone compiles the numba kernels on first use.
        deadline = time.monotonic() + 300
        while not (out / "checkpoint.json").is_file():
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            assert time.monotonic() < deadline, "no checkpoint written"
            time.sleep(0.2)
        os.kill(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, stderr[-2000:]
    meta = json.loads((out / "model.json").read_text())
    assert meta["interrupted"] is True and 0 < meta["timesteps"] < 10_000_000
    assert (out / "checkpoint.zip").is_file()
    LearnedPolicy.load(out / "checkpoint.zip")


def test_train_resume_continues_to_the_total(tmp_path: Path) -> None:
    """--resume picks up the checkpoint and trains up to --timesteps in total."""
    from training.train import main as train_main

    out = tmp_path / "run"
    common = cli_args(**dataclasses.asdict(tiny_config(checkpoint_every=256, seed=0, out=str(out))))
    assert train_main([*common, "--timesteps", "512"]) == 0
    first = json.loads((out / "model.json").read_text())["timesteps"]
    assert train_main([*common, "--timesteps", "1024", "--resume"]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert first >= 512 and meta["timesteps"] >= 1024
    LearnedPolicy.load(out)
