"""Policies that read their own previous command (``--previous-command``; training/fast_ppo.py,
training/policies.py).

The policy's input is the (scaled) observation followed by the follower's previous command as
it was sent, normalised and clipped to ``[-1, 1]``; at an episode's start, the normalised
standstill ``[0 m/s, 0 rad/s]``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tiny_runs import TINY

import platoon_env
from training.config import TrainConfig, check_config
from training.experts import to_normalised
from training.fast_ppo import FastPPOConfig, train_fast
from training.policies import LearnedPolicy

#: A tiny run on study C whose policy reads its previous command.
PREVIOUS = {**TINY, "previous_command": True}


@pytest.fixture(scope="module")
def run_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return train_fast(FastPPOConfig(**PREVIOUS), tmp_path_factory.mktemp("prev") / "r").path


def recorded_inputs(policy: LearnedPolicy) -> list[np.ndarray]:
    """Make ``policy`` record the inputs of its model (a copy per call)."""
    seen: list[np.ndarray] = []
    inner = policy._deterministic

    def spy(obs: Any) -> Any:
        seen.append(np.array(obs, copy=True))
        return inner(obs)

    policy._deterministic = spy  # type: ignore[method-assign]
    return seen


def test_the_model_reads_the_observation_and_its_previous_command(run_path: Path) -> None:
    meta = json.loads(run_path.with_suffix(".json").read_text())
    assert meta["previous_command"] is True and meta["config"]["previous_command"] is True
    policy = LearnedPolicy.load(run_path)
    assert policy.previous_command
    assert policy.input_size == policy.observation_size + 2
    assert policy.model.observation_space.shape == (policy.input_size,)
    assert policy.action_range is not None
    standstill, _ = to_normalised(np.zeros(2), policy.action_range)
    env = platoon_env.make("study_c", control_period=policy.control_period)
    seen = recorded_inputs(policy)
    obs, _ = env.reset(seed=1)
    policy.reset(seed=1)
    sent: list[np.ndarray] = []
    for _ in range(5):
        actions = policy.act(obs)
        normalised, _ = to_normalised(np.stack(list(actions.values())), policy.action_range)
        sent.append(normalised)
        obs, *_ = env.step(actions)
    k = policy.observation_size
    # the first step reads the standstill, every later one the command sent before it
    np.testing.assert_array_equal(seen[0][:, k:], np.stack([standstill] * len(env.agents)))
    for t in range(1, 5):
        np.testing.assert_allclose(seen[t][:, k:], sent[t - 1], rtol=0, atol=1e-6)
    assert not np.allclose(sent[0], sent[4])  # the input changes: it is not a constant
    # a new episode starts from the standstill again
    env.reset(seed=2)
    policy.reset(seed=2)
    policy.act(env.reset(seed=2)[0])
    np.testing.assert_array_equal(seen[-1][:, k:], np.stack([standstill] * len(env.agents)))


def test_a_plain_model_is_unchanged(tmp_path: Path) -> None:
    run = train_fast(FastPPOConfig(**TINY), tmp_path / "r")
    meta = json.loads(run.path.with_suffix(".json").read_text())
    assert "previous_command" not in meta and meta["config"]["previous_command"] is False
    policy = LearnedPolicy.load(run.path)
    assert not policy.previous_command and policy.input_size == policy.observation_size


def test_a_model_json_that_disagrees_with_the_model_is_refused(tmp_path: Path) -> None:
    run = train_fast(FastPPOConfig(**TINY), tmp_path / "r")
    meta_file = run.path.with_suffix(".json")
    meta = json.loads(meta_file.read_text())
    meta_file.write_text(json.dumps({**meta, "previous_command": True}))
    with pytest.raises(ValueError, match="previous command"):
        LearnedPolicy.load(run.path)
    meta_file.write_text(json.dumps({**meta, "previous_command": "yes"}))
    with pytest.raises(ValueError, match="previous_command must be true or false"):
        LearnedPolicy.load(run.path)


def test_an_older_run_without_the_option_resumes(tmp_path: Path) -> None:
    out = tmp_path / "r"
    train_fast(FastPPOConfig(**TINY), out)
    meta_file = out / "model.json"
    meta = json.loads(meta_file.read_text())
    del meta["config"]["previous_command"]  # as a run made before the option existed
    meta_file.write_text(json.dumps(meta))
    run = train_fast(FastPPOConfig(**{**TINY, "timesteps": 2048}), out, resume=True)
    assert run.timesteps >= 2048
    with pytest.raises(ValueError, match="previous_command: stored False, given True"):
        train_fast(FastPPOConfig(**{**PREVIOUS, "timesteps": 4096}), out, resume=True)


def test_the_option_belongs_to_the_fast_engine() -> None:
    problems = check_config(TrainConfig(previous_command=True, out="x", scenario="study_c"))
    assert any("previous-command" in p and "--engine fast" in p for p in problems)
    problems = check_config(
        TrainConfig(engine="fast", algo="bc_ppo", previous_command=True, out="x")
    )
    assert any("previous-command" in p and "bc_ppo" in p for p in problems)
    with pytest.raises(ValueError, match="previous_command must be True or False"):
        FastPPOConfig(**{**TINY, "previous_command": 1})


def test_act_group_keeps_each_policys_previous_command(run_path: Path) -> None:
    """Copies acting through ``act_group`` (the batched evaluator's one network call) send and
    remember the same commands, to the bit, as copies acting alone."""
    import copy

    template = LearnedPolicy.load(run_path)
    envs = [platoon_env.make("study_c", control_period=template.control_period) for _ in range(3)]
    obs = [env.reset(seed=seed)[0] for seed, env in enumerate(envs)]
    grouped = [copy.deepcopy(template) for _ in envs]
    alone = [copy.deepcopy(template) for _ in envs]
    for p in (*grouped, *alone):
        p.reset()
    for _ in range(20):
        together = LearnedPolicy.act_group(grouped, obs)
        for k in range(3):
            single = alone[k].act(obs[k])
            for agent in single:
                assert np.array_equal(together[k][agent], single[agent])
            assert grouped[k]._sent.keys() == alone[k]._sent.keys()
            for agent in single:
                assert np.array_equal(grouped[k]._sent[agent], alone[k]._sent[agent])
        obs = [env.step(cmd)[0] for env, cmd in zip(envs, together, strict=True)]
        if not all(obs):
            break
