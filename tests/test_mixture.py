"""Mixtures of scenario families (``"a+b"``) and the fast learner's anchor to its start."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from test_fast_ppo import TINY

from platoon_env.batched import BatchedPlatoon
from platoon_env.config import ScenarioError
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.source import MixtureSource, ProceduralSource, scenario_source
from training.fast_ppo import FastPPOConfig, train_fast

SHARP = "procedural_formations_sharp_train"
PAPER = "procedural_formations_paper_train"


def test_a_plus_name_is_a_mixture_drawing_each_family_from_the_env_stream() -> None:
    source = scenario_source(f"{SHARP}+{PAPER}")
    assert isinstance(source, MixtureSource)
    assert source.names == (SHARP, PAPER)
    assert source.followers_range == (1, 7)
    tiers = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        first = int(np.random.default_rng(seed).integers(2))
        scenario = source.sample(rng)
        assert scenario.config.generator is not None
        tiers.append(scenario.config.generator.tier)
        # the component is the stream's first draw; the layout is that component's own draw
        assert tiers[-1] == ("sharp", "paper")[first]
    assert set(tiers) == {"sharp", "paper"}


def test_a_mixture_is_deterministic_and_feeds_the_batched_core() -> None:
    core = BatchedPlatoon(f"{SHARP}+{PAPER}", 6, auto_reset=True)
    core.reset([1, 2, 3, 4, 5, 6])
    again = BatchedPlatoon(f"{SHARP}+{PAPER}", 6, auto_reset=True)
    again.reset([1, 2, 3, 4, 5, 6])
    assert [s.name for s in core.scenarios] == [s.name for s in again.scenarios]
    assert np.array_equal(core.poses, again.poses)
    assert core.n_followers == 7


def test_a_mixture_refuses_families_of_other_observation_layouts() -> None:
    scale_free = load_config(SHARP)
    plain = scenario_source(SHARP, {"observation": {"task_aware": True}})
    with pytest.raises(ScenarioError, match="'observation' block"):
        MixtureSource([ProceduralSource(scale_free), plain])
    with pytest.raises(ValueError, match="at least two"):
        MixtureSource([plain])


def actor_keys(state: dict[str, torch.Tensor]) -> list[str]:
    return [k for k in state if k.startswith(("mlp_extractor.policy_net", "action_net"))]


def drift(start: dict[str, torch.Tensor], end: dict[str, torch.Tensor]) -> float:
    return sum(float(((end[k] - start[k]) ** 2).sum()) for k in actor_keys(start))


def test_the_anchor_keeps_the_actor_near_its_start(tmp_path: Path, one_torch_thread: None) -> None:
    del one_torch_thread
    train_fast(FastPPOConfig(**{**TINY, "timesteps": 2048}), tmp_path / "start")
    start = torch.load(tmp_path / "start" / "model.state.pt", weights_only=True)["network"]
    init = str(tmp_path / "start" / "model.zip")
    moved = {}
    for coef in (0.0, 10.0):
        out = tmp_path / f"anchor_{coef:g}"
        train_fast(
            FastPPOConfig(**{**TINY, "timesteps": 2048}, init_from=init, anchor_coef=coef), out
        )
        end = torch.load(out / "model.state.pt", weights_only=True)["network"]
        moved[coef] = drift(start, end)
        assert json.loads((out / "model.json").read_text())["config"]["anchor_coef"] == coef
    assert moved[10.0] < 0.5 * moved[0.0]


def test_the_anchor_needs_a_start_and_a_non_negative_weight(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="anchor_coef"):
        FastPPOConfig(**TINY, anchor_coef=-1.0)
    with pytest.raises(ValueError, match="anchor_coef: needs init_from"):
        train_fast(FastPPOConfig(**TINY, anchor_coef=1.0), tmp_path)
