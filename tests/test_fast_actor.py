"""The deterministic fast path of :class:`training.LearnedPolicy` (``fast_actor`` in
``training.policies``): for an SB3 PPO (Gaussian head, Box actions) it computes ``model.predict(obs,
deterministic=True)`` within float32 rounding without calling ``predict``, each row the same to
the bit whatever the batch (``tests/test_forward.py``); any other model (SAC) goes through
``predict``. A shipped model is loaded weights-only (``LearnedPolicy.load``) and compared with
its SB3 object (``LearnedPolicy.load_pickled``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import gymnasium as gym
import torch
from gymnasium import spaces
from stable_baselines3 import PPO, SAC

from training import LearnedPolicy
from training.policies import fast_actor
from training.vec_env import ActionRange

REPO = Path(__file__).resolve().parents[1]
BATCHES = (1, 2, 7)
#: An asymmetric action box, so that clipping to each dimension's own bounds is checked.
ACT_LOW = np.array([-0.5, -2.0], dtype=np.float32)
ACT_HIGH = np.array([1.5, 2.0], dtype=np.float32)


class BoxEnv(gym.Env[np.ndarray, np.ndarray]):
    """A do-nothing env with a 13-value Box observation and a 2-value Box action."""

    def __init__(self, low: np.ndarray = ACT_LOW, high: np.ndarray = ACT_HIGH) -> None:
        self.observation_space = spaces.Box(-1.0, 1.0, shape=(13,), dtype=np.float32)
        self.action_space = spaces.Box(low, high, dtype=np.float32)
        self._t = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._t = 0
        return np.zeros(13, dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._t += 1
        return np.zeros(13, dtype=np.float32), 0.0, False, self._t >= 8, {}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def observations(n: int, size: int, seed: int) -> np.ndarray:
    """``n`` float32 observations: wide normals, one far outside [-1, 1] per row, and extremes."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(scale=4.0, size=(n, size))
    obs[:, 0] = rng.choice([-1.0, 1.0], size=n) * rng.uniform(20.0, 1e3, size=n)
    if n > 1:
        obs[-1] = 1e4 * np.sign(rng.normal(size=size))
    return obs.astype(np.float32)


def tiny_ppo() -> PPO:
    model = PPO("MlpPolicy", BoxEnv(), n_steps=16, batch_size=16, seed=0, device="cpu")
    # The fresh action head has a gain of 0.01: scale it up so that the means leave the
    # action box and the clipping matters.
    with torch.no_grad():
        model.policy.action_net.weight.mul_(300.0)
        model.policy.action_net.bias.copy_(torch.tensor([0.3, -0.7]))
    return model


def tiny_sac() -> SAC:
    return SAC(
        "MlpPolicy",
        BoxEnv(),
        buffer_size=100,
        learning_starts=0,
        policy_kwargs={"net_arch": [8, 8]},
        seed=0,
        device="cpu",
    )


def shipped_model() -> Path:
    found = sorted(REPO.glob("models/**/ppo_corridors_s0/model.zip"))
    if not found:
        pytest.skip("the shipped ppo_corridors_s0 model is not in models/")
    return found[0]


def policy_of(model: Any) -> LearnedPolicy:
    return LearnedPolicy(model, action_range=None, obs_scale=None, control_period=0.05)


def count_predict(monkeypatch: pytest.MonkeyPatch, model: Any) -> list[int]:
    """Count the calls of ``model.predict`` (still delegating to it)."""
    calls: list[int] = []
    original = model.predict

    def predict(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(model, "predict", predict)
    return calls


def assert_close(fast: np.ndarray, expected: Any) -> None:
    """Within float32 rounding of ``predict`` (float64 sums against torch's float32 ones)."""
    expected = np.asarray(expected, dtype=np.float32).reshape(fast.shape)
    np.testing.assert_allclose(fast, expected, rtol=1e-5, atol=1e-5)


def assert_predict(policy: LearnedPolicy, obs: np.ndarray) -> np.ndarray:
    fast = policy._deterministic(obs)
    expected, _ = policy.model.predict(obs, deterministic=True)
    assert isinstance(fast, np.ndarray)
    assert fast.dtype == np.float32
    assert fast.shape == (len(obs), 2)
    assert_close(fast, expected)
    return fast


@pytest.mark.parametrize("n", BATCHES)
def test_shipped_ppo_fast_path_is_predict(n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    policy = LearnedPolicy.load(shipped_model())
    sb3 = LearnedPolicy.load_pickled(shipped_model()).model  # SB3's own predict
    assert fast_actor(policy.model) is not None
    calls = count_predict(monkeypatch, policy.model)
    obs = observations(n, policy.observation_size, seed=n)
    fast = policy._deterministic(obs)
    assert calls == []  # the fast path does not go through predict
    expected, _ = sb3.predict(obs, deterministic=True)
    assert fast.dtype == np.float32
    assert_close(fast, expected)
    space = sb3.action_space
    assert np.all(fast >= space.low) and np.all(fast <= space.high)
    assert np.any(np.abs(fast) == 1.0)  # some actions were clipped to the box


def test_shipped_ppo_act_matches_predict_through_the_scaling() -> None:
    policy = LearnedPolicy.load(shipped_model())
    sb3 = LearnedPolicy.load_pickled(shipped_model()).model  # SB3's own predict
    obs = observations(2, policy.observation_size, seed=11) * 3.0
    agents = {"follower_0": obs[0], "follower_1": obs[1]}
    actions = policy.act(agents)
    scaled = obs / policy.obs_scale if policy.obs_scale is not None else obs
    normalised, _ = sb3.predict(scaled, deterministic=True)
    assert policy.action_range is not None
    expected = policy.action_range.to_physical(np.asarray(normalised, dtype=np.float32))
    for i, agent in enumerate(agents):
        assert_close(actions[agent], expected[i])


@pytest.mark.parametrize("n", BATCHES)
def test_tiny_ppo_fast_path_is_predict_and_clips(n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    model = tiny_ppo()
    policy = policy_of(model)
    assert policy.observation_size == 13
    obs = observations(n, 13, seed=100 + n)
    calls = count_predict(monkeypatch, model)
    fast = policy._deterministic(obs)
    assert calls == []
    expected, _ = model.predict(obs, deterministic=True)
    assert fast.dtype == np.float32
    assert_close(fast, expected)
    assert np.all(fast >= ACT_LOW) and np.all(fast <= ACT_HIGH)
    # the unclipped means leave the box: the clip to each dimension's bounds was exercised
    with torch.no_grad():
        dist = model.policy.get_distribution(torch.as_tensor(obs))
        mean = dist.distribution.mean.numpy()
    outside = (mean < ACT_LOW) | (mean > ACT_HIGH)
    assert outside.any()
    assert_close(fast[outside], np.clip(mean, ACT_LOW, ACT_HIGH)[outside])


def test_tiny_ppo_fast_path_is_cached_and_follows_training() -> None:
    model = tiny_ppo()
    policy = policy_of(model)
    obs = observations(7, 13, seed=5)
    assert_predict(policy, obs)
    fast = policy._fast
    assert fast is not None and policy._fast_checked
    # weights changed in place after the first call (as by more training): still predict's
    with torch.no_grad():
        for p in model.policy.parameters():
            p.add_(0.05)
    assert_predict(policy, obs)
    assert policy._fast is fast  # the same fast actor, its forward rebuilt from the new weights


def test_sac_has_no_fast_path_and_acts_through_predict(monkeypatch: pytest.MonkeyPatch) -> None:
    model = tiny_sac()
    assert fast_actor(model) is None
    policy = policy_of(model)
    batches = [observations(n, 13, seed=200 + n) for n in BATCHES]
    calls = count_predict(monkeypatch, model)
    outs = [policy._deterministic(obs) for obs in batches]
    assert len(calls) == len(BATCHES)  # every call went through predict
    assert policy._fast_checked and policy._fast is None
    for obs, out in zip(batches, outs, strict=True):
        expected, _ = model.predict(obs, deterministic=True)
        assert out.dtype == np.float32 and out.shape == (len(obs), 2)
        assert np.array_equal(out, np.asarray(expected, dtype=np.float32))


def test_sac_learned_policy_act_goes_through_predict(monkeypatch: pytest.MonkeyPatch) -> None:
    model = tiny_sac()
    policy = LearnedPolicy(
        model,
        action_range=ActionRange(u_low=-0.5, u_high=1.5, omega_high=2.0),
        obs_scale=None,
        control_period=0.05,
    )
    calls = count_predict(monkeypatch, model)
    obs = observations(3, 13, seed=9)
    actions = policy.act({f"follower_{i}": obs[i] for i in range(3)})
    assert len(calls) == 1  # one batched predict for the three followers
    normalised, _ = model.predict(obs, deterministic=True)
    expected = policy.action_range.to_physical(np.asarray(normalised, dtype=np.float32))
    for i in range(3):
        assert np.array_equal(actions[f"follower_{i}"], expected[i])


def test_non_box_or_non_gaussian_models_get_no_fast_path() -> None:
    class Stub:
        policy = object()

    assert fast_actor(Stub()) is None
    assert fast_actor(object()) is None
    gsde = PPO(
        "MlpPolicy",
        BoxEnv(),
        n_steps=16,
        batch_size=16,
        use_sde=True,
        seed=0,
        device="cpu",
    )
    assert fast_actor(gsde) is None  # state-dependent exploration: not a DiagGaussian head
