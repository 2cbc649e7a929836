"""The one algorithm table (training/algorithms.py) and the lists derived from it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from training import config, fast_ppo, policies
from training.algorithms import (
    ALGORITHMS,
    clones,
    finetune_algo,
    has_multiplier,
    is_clone,
    trained_by,
)
from training.config import TrainConfig, check_config

DOCS = Path(__file__).resolve().parents[1] / "docs" / "training.md"


def test_the_command_line_offers_the_table_in_its_order() -> None:
    algo = next(f for f in dataclasses.fields(TrainConfig) if f.name == "algo")
    assert algo.metadata["choices"] == tuple(ALGORITHMS)
    assert tuple(ALGORITHMS) == ("ppo", "sac", "ppo_lagrangian", "bc_ppo", "bc_ppo_lagrangian")


def test_the_derived_lists_are_the_ones_written_out_before() -> None:
    assert config.PPO_ALGOS == ("ppo", "ppo_lagrangian")
    assert config.FAST_ALGOS == ("ppo", "ppo_lagrangian", "bc_ppo", "bc_ppo_lagrangian")
    assert config.RLLIB_ALGOS == ("ppo", "ppo_lagrangian")
    assert fast_ppo.ALGOS == ("ppo", "ppo_lagrangian")
    assert list(config.SB3_OPTIONS) == ["ppo", "sac", "ppo_lagrangian"]
    assert config.SB3_OPTIONS["ppo_lagrangian"] == config.SB3_OPTIONS["ppo"]
    assert config.RUN_FIELDS_ALGO["ppo_lagrangian"] == (
        *config.RUN_FIELDS_ALGO["ppo"],
        "cost_budget",
        "lagrangian_lr",
    )
    assert {k: v.__name__ for k, v in policies.ALGORITHMS.items()} == {
        "ppo": "PPO",
        "sac": "SAC",
        "ppo_lagrangian": "PPO",
    }


def test_a_clone_is_a_lookup_not_a_prefix() -> None:
    assert clones() == ("bc_ppo", "bc_ppo_lagrangian")
    assert [is_clone(n) for n in ALGORITHMS] == [False, False, False, True, True]
    assert not is_clone("bc_unknown")
    assert finetune_algo("bc_ppo") == "ppo" and finetune_algo("bc_ppo_lagrangian") == (
        "ppo_lagrangian"
    )
    assert finetune_algo("sac") == "sac"
    assert [has_multiplier(n) for n in ALGORITHMS] == [False, False, True, False, True]
    for name in clones():
        tuned = ALGORITHMS[name].finetune
        assert tuned in trained_by("fast", clones=False)
        assert ALGORITHMS[name].lagrangian == ALGORITHMS[str(tuned)].lagrangian


@pytest.mark.parametrize(
    ("engine", "algo", "message"),
    [
        ("rllib", "sac", "--engine rllib trains ppo and ppo_lagrangian, got 'sac'"),
        ("sb3", "bc_ppo", "bc_ppo trains with --engine fast, got --engine sb3"),
    ],
)
def test_the_engine_checks_read_the_table(engine: str, algo: str, message: str) -> None:
    errors = check_config(TrainConfig(engine=engine, algo=algo, out="x"))
    assert any(message in e for e in errors), errors


def test_a_bc_option_names_the_clones() -> None:
    errors = check_config(TrainConfig(engine="fast", algo="ppo", bc_iterations=2, out="x"))
    assert any("is an option of --algo bc_ppo / bc_ppo_lagrangian, got ppo" in e for e in errors)


def test_the_docs_table_names_every_algorithm() -> None:
    families = DOCS.read_text().split("## Learner families", 1)[1].split("\n## ", 1)[0]
    for name in ALGORITHMS:
        assert f"`{name}`" in families, name
