"""The cost-constrained learner (training/lagrangian.py): the multiplier's dual-ascent update
on hand-computed cases, the penalised rewards, and a short PPO run that moves the multiplier."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from training.lagrangian import LagrangeMultiplier, LagrangianCallback, LagrangianVecEnv


def test_multiplier_update_hand_case() -> None:
    lam = LagrangeMultiplier(budget=0.05, lr=0.1)
    assert lam.value == 0.0
    # mean cost 0.25 > budget: λ = 0 + 0.1 (0.25 - 0.05) = 0.02
    assert lam.update([1.0, 0.0, 0.0, 0.0]) == pytest.approx(0.02)
    # mean cost 1: λ = 0.02 + 0.1 (1 - 0.05) = 0.115
    assert lam.update([1.0, 1.0]) == pytest.approx(0.115)
    # no finished episode: unchanged
    assert lam.update([]) == pytest.approx(0.115)
    # under budget: λ decreases, and never below 0
    assert lam.update([0.0]) == pytest.approx(0.11)
    for _ in range(100):
        lam.update([0.0])
    assert lam.value == 0.0
    capped = LagrangeMultiplier(budget=0.0, lr=10.0, max_value=3.0)
    assert capped.update([1.0]) == 3.0
    for bad in ({"budget": -0.1}, {"budget": 0.1, "lr": 0.0}, {"budget": float("nan")}):
        with pytest.raises(ValueError):
            LagrangeMultiplier(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="finite"):
        lam.update([float("nan")])


class _ToyVecEnv(VecEnv):
    """Two slots; cost 1 on every step of slot 0, episodes of 3 steps; reward 1."""

    def __init__(self) -> None:
        super().__init__(
            2, spaces.Box(-1, 1, (1,), np.float32), spaces.Box(-1, 1, (1,), np.float32)
        )
        self.t = 0

    def reset(self):  # type: ignore[no-untyped-def]
        self.t = 0
        return np.zeros((2, 1), np.float32)

    def step_async(self, actions):  # type: ignore[no-untyped-def]
        pass

    def step_wait(self):  # type: ignore[no-untyped-def]
        self.t += 1
        done = self.t % 3 == 0
        infos = [{"cost": 1.0}, {"cost": 0.0}]
        return np.zeros((2, 1), np.float32), np.ones(2, np.float32), np.array([done, done]), infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name, indices=None):  # type: ignore[no-untyped-def]
        return [None, None]

    def set_attr(self, attr_name, value, indices=None) -> None:  # type: ignore[no-untyped-def]
        pass

    def env_method(self, method_name, *args, indices=None, **kwargs):  # type: ignore[no-untyped-def]
        return [None, None]

    def env_is_wrapped(self, wrapper_class, indices=None):  # type: ignore[no-untyped-def]
        return [False, False]


def test_penalised_rewards_and_episode_costs() -> None:
    lam = LagrangeMultiplier(budget=0.5, lr=0.1, initial=0.25)
    venv = LagrangianVecEnv(_ToyVecEnv(), lam)
    venv.reset()
    for _ in range(3):
        venv.step_async(np.zeros((2, 1)))
        _, rewards, dones, infos = venv.step_wait()
        np.testing.assert_allclose(rewards, [1.0 - 0.25, 1.0])
        assert [i["reward_unpenalised"] for i in infos] == [1.0, 1.0]
    assert dones.all() and venv.pop_episode_costs() == [3.0, 0.0]
    assert venv.pop_episode_costs() == []


def test_short_ppo_run_moves_the_multiplier() -> None:
    """On study C with the adapter, a violating early policy raises λ above 0."""
    import torch
    from stable_baselines3 import PPO

    import platoon_env
    from training.vec_env import ActionRange, PlatoonVecEnv

    torch.set_num_threads(1)
    env = platoon_env.make("study_c", control_period=0.05, max_episode_steps=40)
    inner = PlatoonVecEnv([env], action_range=ActionRange())
    inner.seed(0)
    venv = LagrangianVecEnv(inner, LagrangeMultiplier(budget=0.0, lr=0.5))
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, verbose=0)
    callback = LagrangianCallback(venv)
    model.learn(256, callback=callback)
    assert len(callback.history) == 2  # 256 / (64 steps x 2 slots)
    finished = [(lam, cost) for _, lam, cost in callback.history if not np.isnan(cost)]
    assert finished, "no episode finished"
    # the multiplier follows the rule from the observed costs
    lam = 0.0
    for _, new_lam, cost in callback.history:
        if not np.isnan(cost):
            lam = max(0.0, lam + 0.5 * cost)
        assert new_lam == pytest.approx(lam)
    assert lam > 0.0  # the random early policy violates: the multiplier rose


def test_platoon_train_ppo_lagrangian_records_and_resumes_the_multiplier(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import json

    from training.policies import LearnedPolicy
    from training.train import main as train_main

    out = tmp_path / "run"
    base = ["--algo", "ppo_lagrangian", "--scenario", "study_c", "--n-envs", "1",
            "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1", "--seed", "0",
            "--max-episode-steps", "40", "--cost-budget", "0", "--lagrangian-lr", "0.5",
            "--out", str(out), "--no-progress-bar", "--checkpoint-every", "0"]  # fmt: skip
    assert train_main([*base, "--timesteps", "256"]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["algo"] == "ppo_lagrangian" and meta["lagrange_multiplier"] > 0.0
    first = meta["lagrange_multiplier"]
    assert meta["config"]["cost_budget"] == 0.0 and meta["config"]["lagrangian_lr"] == 0.5
    policy = LearnedPolicy.load(out)  # an SB3 PPO zip
    assert policy.control_period == meta["control_period"]
    # Resume continues from the stored multiplier (it only grows with budget 0).
    assert train_main([*base, "--timesteps", "512", "--resume"]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["timesteps"] >= 512 and meta["lagrange_multiplier"] > first  # not restarted
    # Another budget is another run: resume refuses it, naming the field.
    with pytest.raises(SystemExit) as exc:
        train_main([*base, "--timesteps", "768", "--resume", "--cost-budget", "0.1"])
    assert exc.value.code == 2
