"""Residual policies on an analytic law (``--residual ppc``; training/fast_ppo.py, policies.py).

The policy's mean action is the law's command, normalised and clipped to the action range,
plus the network's output; the network's output layer starts at zero.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from tiny_runs import TINY

import platoon_env
from baselines.ppc import PPCPolicy
from training.config import TrainConfig, check_config
from training.experts import to_normalised
from training.fast_ppo import FastPPOConfig, train_fast
from training.policies import LearnedPolicy

#: A tiny residual run on study C at a 20 ms control period.
RESIDUAL = {**TINY, "residual": "ppc", "control_period": 0.02}


def clipped_law_actions(env: object, policy: LearnedPolicy, steps: int) -> None:
    """Step ``env`` with ``policy`` and a PPC law beside it, asserting at every step that the
    policy's command is the law's command mapped into the action range and back."""
    law = PPCPolicy(env)  # type: ignore[arg-type]
    obs, _ = env.reset(seed=3)  # type: ignore[attr-defined]
    policy.reset(seed=3)
    law.reset(seed=3)
    assert policy.action_range is not None
    for _ in range(steps):
        mine = policy.act(obs)
        theirs = law.act(obs)
        for agent, command in theirs.items():
            normalised, _ = to_normalised(np.asarray(command), policy.action_range)
            expected = policy.action_range.to_physical(normalised)
            np.testing.assert_allclose(mine[agent], expected, rtol=0, atol=1e-5)
        obs, *_ = env.step(mine)  # type: ignore[attr-defined]


def test_an_untrained_residual_policy_is_the_clipped_law(tmp_path: Path) -> None:
    # value_warmup beyond the run: only the critic learns, the zero output layer stays zero
    run = train_fast(FastPPOConfig(**{**RESIDUAL, "value_warmup": 100}), tmp_path / "r")
    meta = json.loads(run.path.with_suffix(".json").read_text())
    assert meta["residual"] == "ppc" and meta["config"]["residual"] == "ppc"
    policy = LearnedPolicy.load(run.path)
    assert policy.residual == "ppc"
    env = platoon_env.make("study_c", control_period=policy.control_period)
    with pytest.raises(RuntimeError, match="bind"):
        policy.reset()
    policy.bind(env)
    clipped_law_actions(env, policy, 200)


def test_training_moves_the_residual_away_from_zero(tmp_path: Path) -> None:
    run = train_fast(FastPPOConfig(**RESIDUAL), tmp_path / "r")
    state = torch.load(run.path.with_suffix(".state.pt"), weights_only=False)["network"]
    assert float(state["action_net.weight"].abs().max()) > 0.0
    policy = LearnedPolicy.load(run.path)
    env = platoon_env.make("study_c", control_period=policy.control_period)
    policy.bind(env)
    obs, _ = env.reset(seed=0)
    policy.reset(seed=0)
    actions = policy.act(obs)
    assert all(np.all(np.isfinite(a)) for a in actions.values())


def test_a_residual_policy_without_its_env_says_so(tmp_path: Path) -> None:
    run = train_fast(FastPPOConfig(**{**RESIDUAL, "value_warmup": 100}), tmp_path / "r")
    policy = LearnedPolicy.load(run.path)
    env = platoon_env.make("study_c", control_period=policy.control_period)
    obs, _ = env.reset(seed=0)
    with pytest.raises(RuntimeError, match=r"bind\(env\)"):
        policy.act(obs)


def test_bad_residual_options_are_refused() -> None:
    with pytest.raises(ValueError, match="residual must be None or one of"):
        FastPPOConfig(**{**RESIDUAL, "residual": "pid"})
    problems = check_config(
        TrainConfig(engine="fast", algo="bc_ppo", residual="ppc", out="x", scenario="study_c")
    )
    assert any("residual" in p for p in problems)
    problems = check_config(TrainConfig(residual="ppc", out="x", scenario="study_c"))
    assert any("residual" in p and "--engine fast" in p for p in problems)
