"""The fast learner (training/fast_ppo.py): it trains, saves a model LearnedPolicy loads and that
acts as the learner's deterministic mode, is deterministic for a seed, gives every env copy its
own stream, resumes on new streams, moves its multiplier the right way and refuses bad options."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from tiny_runs import TINY

import platoon_env
from training.curves import read_progress
from training.fast_ppo import (
    ActorCritic,
    FastPPOConfig,
    _gae,
    make_core,
    scaled_cost_advantages,
    surrogate_advantages,
    train_fast,
)
from training.policies import LearnedPolicy

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def tiny(**changes: Any) -> FastPPOConfig:
    return FastPPOConfig(**{**TINY, **changes})


def state(out: Path, name: str = "model") -> dict[str, torch.Tensor]:
    return torch.load(out / f"{name}.state.pt", weights_only=True)["network"]


def test_trains_saves_and_the_loaded_policy_acts_as_the_learner(tmp_path: Path) -> None:
    cfg = tiny()
    run = train_fast(cfg, tmp_path)
    assert run.timesteps == 1024 and run.path == tmp_path / "model.zip"
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["trainer"] == "training.fast_ppo" and meta["timesteps"] == 1024
    rows = read_progress(tmp_path / "progress.csv")
    assert rows["timesteps"].tolist() == [256, 512, 768, 1024]

    policy = LearnedPolicy.load(tmp_path / "model.zip")
    env = platoon_env.make("study_c", control_period=policy.control_period)
    policy.check_env(env)  # refuses (raises) an env the model cannot act in
    obs, _ = env.reset(seed=3)
    actions = policy.act(obs)

    # The learner's deterministic mode: the mean of the saved network, clipped, then mapped
    # (within float32 rounding: the policy sums in float64 in a fixed order, training.forward).
    net = ActorCritic(7, cfg.net_arch, cfg.log_std_init, cost_head=False)
    net.load_state_dict(state(tmp_path))
    assert policy.obs_scale is not None
    x = np.stack([obs[a] for a in env.possible_agents]).astype(np.float32) / policy.obs_scale
    with torch.no_grad():
        mean, _, _ = net(torch.as_tensor(x))
    expected = cfg.action_range.to_physical(mean.clamp(-1.0, 1.0).numpy())
    for i, agent in enumerate(env.possible_agents):
        np.testing.assert_allclose(actions[agent], expected[i], rtol=1e-5, atol=1e-6)
    env.close()


def test_one_seed_gives_identical_weights(tmp_path: Path) -> None:
    first = train_fast(tiny(timesteps=512), tmp_path / "a")
    second = train_fast(tiny(timesteps=512), tmp_path / "b")
    other = train_fast(tiny(timesteps=512, seed=1), tmp_path / "c")
    a, b, c = (state(r.path.parent) for r in (first, second, other))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_every_env_copy_of_every_seed_draws_its_own_layouts() -> None:
    drawn = []
    for seed in range(5):
        core, _ = make_core(FastPPOConfig(scenario="procedural_medium_train", n_envs=8, seed=seed))
        drawn += [sc.layout_index for sc in core.scenarios]
    assert len(drawn) == 40 and len(set(drawn)) == 40


def test_a_resumed_run_draws_new_episodes(tmp_path: Path) -> None:
    cfg = tiny(scenario="procedural_medium_train", timesteps=512, checkpoint_every=256)
    train_fast(cfg, tmp_path)
    assert (tmp_path / "checkpoint.zip").is_file()
    with pytest.raises(ValueError, match="already holds a run"):
        train_fast(cfg, tmp_path)
    with pytest.raises(ValueError, match=r"gamma: stored 0\.99, given 0\.9"):
        train_fast(tiny(scenario=cfg.scenario, timesteps=1024, gamma=0.9), tmp_path, resume=True)
    run = train_fast(tiny(scenario=cfg.scenario, timesteps=1024), tmp_path, resume=True)
    assert run.timesteps == 1024
    segments = json.loads((tmp_path / "model.json").read_text())["segments"]
    assert [s["env_seed_segment"] for s in segments] == [0, 1]
    assert [s["timesteps_start"] for s in segments] == [0, 512]
    assert not set(segments[0]["first_layouts"]) & set(segments[1]["first_layouts"])
    assert segments[0]["start_poses_sha256"] != segments[1]["start_poses_sha256"]
    rows = read_progress(tmp_path / "progress.csv")
    assert rows["timesteps"].tolist() == [256, 512, 768, 1024]


@pytest.mark.parametrize(
    ("budget", "initial", "direction"),
    [(0.0, 0.0, "rises"), (1.0, 2.0, "falls")],
)
def test_the_multiplier_follows_the_cost_against_the_budget(
    tmp_path: Path, budget: float, initial: float, direction: str
) -> None:
    # An untrained policy violates in about every team episode: each follower's episode cost
    # is 0 or 1, their mean about one half, above a budget of 0 and below one of 1.
    cfg = tiny(algo="ppo_lagrangian", cost_budget=budget, lagrangian_init=initial)
    run = train_fast(cfg, tmp_path)
    assert run.lagrange_multiplier is not None
    lam = read_progress(tmp_path / "progress.csv")["lambda"]
    if direction == "rises":
        assert run.lagrange_multiplier > initial and lam[-1] > lam[0] >= initial
    else:
        assert run.lagrange_multiplier < initial and lam[-1] < lam[0] <= initial
    assert "cost_value_net.weight" in state(tmp_path)
    assert json.loads((tmp_path / "model.json").read_text())["algo"] == "ppo_lagrangian"
    LearnedPolicy.load(tmp_path)  # the cost head is not part of the saved policy


def test_standardised_cost_advantages_keep_the_surrogate_at_scale_for_a_large_multiplier() -> None:
    gen = torch.Generator().manual_seed(0)
    adv = torch.randn(4096, generator=gen)
    # A rare 0/1 cost: small cost advantages (a few large, most near zero).
    cadv = 0.01 * torch.randn(4096, generator=gen)
    cadv[:40] += 1.0
    lam = 100.0
    centred = surrogate_advantages(adv, scaled_cost_advantages(cadv, "centred"), lam)
    standard = surrogate_advantages(adv, scaled_cost_advantages(cadv, "standardised"), lam)
    # Centred: the surrogate shrinks to about std(A_c) ~ 0.1; standardised: about 1.
    assert float(centred.std()) < 0.15
    assert 0.9 < float(standard.std()) < 1.1
    # Either way it points against the cost: the costly samples have the lowest advantages.
    assert float(standard[:40].mean()) < float(standard[40:].mean())
    assert float(centred[:40].mean()) < float(centred[40:].mean())
    # Without a cost it is the standardised reward advantage.
    plain = surrogate_advantages(adv, None, lam)
    assert abs(float(plain.mean())) < 1e-6 and abs(float(plain.std()) - 1.0) < 1e-4
    with pytest.raises(ValueError, match="cost_advantage"):
        scaled_cost_advantages(cadv, "scaled")


def test_the_cost_advantage_option_changes_what_is_learned(tmp_path: Path) -> None:
    nets = {}
    for mode in ("centred", "standardised"):
        cfg = tiny(algo="ppo_lagrangian", cost_budget=0.0, lagrangian_init=5.0, cost_advantage=mode)
        train_fast(cfg, tmp_path / mode)
        nets[mode] = state(tmp_path / mode)
        recorded = json.loads((tmp_path / mode / "model.json").read_text())["config"]
        assert recorded["cost_advantage"] == mode
    assert nets["centred"].keys() == nets["standardised"].keys()
    assert any(
        not torch.equal(nets["centred"][k], nets["standardised"][k]) for k in nets["centred"]
    )


def test_gae_bootstraps_only_where_the_episode_goes_on() -> None:
    cfg = tiny(gamma=0.5, gae_lambda=1.0)
    rewards = torch.tensor([[1.0, 1.0], [1.0, 1.0]])
    values = torch.zeros(2, 2)
    dones = torch.tensor([[0.0, 1.0], [0.0, 0.0]])  # slot 1's episode ends at step 0
    advantages, returns = _gae(rewards, values, dones, torch.tensor([4.0, 4.0]), cfg)
    # Slot 0: 1 + 0.5 (1 + 0.5 * 4); slot 1: 1 (ended), then 1 + 0.5 * 4.
    assert advantages.tolist() == [[2.5, 1.0], [3.0, 3.0]]
    assert torch.equal(returns, advantages)


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("learning_rate", -1e-3),
        ("cost_budget", -0.1),
        ("n_envs", 0),
        ("batch_size", 1),
        ("gamma", 1.5),
        ("clip_range", 0.0),
        ("layout_repeats", 0),
        ("net_arch", ()),
        ("algo", "sac"),
        ("cost_advantage", "scaled"),
        ("device", "tpu"),
    ],
)
def test_bad_options_are_refused_by_name(option: str, value: Any) -> None:
    with pytest.raises(ValueError, match=option):
        FastPPOConfig(**{option: value})


def test_a_minibatch_larger_than_the_rollout_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="batch_size: 512 exceeds the rollout"):
        train_fast(tiny(batch_size=512, n_steps=16), tmp_path)
