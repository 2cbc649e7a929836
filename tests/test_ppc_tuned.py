"""The tuned PPC (baselines/ppc_tuned.py) and its search (experiments/studies/tune_ppc.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

import platoon_env
from baselines.ppc import PPCPolicy
from baselines.ppc_tuned import (
    DEFAULT_TABLE,
    TUNED_KEYS,
    TableError,
    TunedPPCPolicy,
    formation_geometry,
    load_table,
)
from experiments import tuning
from experiments.policies import PolicySpec, build_policy
from experiments.studies import tune_ppc
from experiments.suites import STUDIES


def test_shipped_table_validates_and_covers_the_studies() -> None:
    table = load_table()
    assert [row.name for row in table.formations] == list(STUDIES)
    for key in ("command", "commit", "objective", "trial_budget"):
        assert table.provenance[key]
    for study in STUDIES:
        cfg = platoon_env.make(study).scenario.config
        row = table.lookup(cfg)
        assert row.name == study
        assert row.best_value >= row.baseline_value


def _bad_table(tmp_path: Path, edit: str, value: object) -> Path:
    data = yaml.safe_load(DEFAULT_TABLE.read_text())
    node = data
    *parents, last = edit.split(".")
    for key in parents:
        node = node[key]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("edit", "value", "message"),
    [
        ("formations.study_b.params.k_d", "fast", "formations.study_b.params.k_d: expected"),
        ("formations.study_b.params.k_d", KeyError, "formations.study_b.params.k_d: missing"),
        ("formations.study_c.params.epsilon", 1.5, "formations.study_c.params: PPC parameter"),
        ("formations.study_a.geometry.d_des", float("nan"), "formations.study_a.geometry.d_des"),
        ("formations.study_a.followers", 0, "formations.study_a.followers"),
        ("formations.study_a.gains", {}, "formations.study_a.gains: unknown key"),
        ("provenance", KeyError, "provenance: missing"),
    ],
)
def test_bad_table_names_the_field(tmp_path: Path, edit: str, value: object, message: str) -> None:
    path = _bad_table(tmp_path, edit, value)
    with pytest.raises(TableError, match=message.replace("(", r"\(")) as info:
        load_table(path)
    assert str(path) in str(info.value)


def test_tuned_policy_is_ppc_with_the_tables_parameters() -> None:
    env = platoon_env.make("study_c", sensor_profile="aruco", max_episode_steps=60)
    row = load_table().lookup(env.scenario.config)
    tuned = TunedPPCPolicy(env)
    plain = PPCPolicy(env, **row.params)
    assert tuned.params == plain.params == row.ppc_params(env.control_period)
    assert tuned.formation == "study_c"
    obs, _ = env.reset(seed=3)
    tuned.reset(seed=3)
    plain.reset(seed=3)
    for _ in range(60):
        a, b = tuned.act(obs), plain.act(obs)
        assert a.keys() == b.keys()
        for agent in a:
            np.testing.assert_array_equal(a[agent], b[agent])
        obs, *_ = env.step(a)


def test_unknown_formation_is_refused() -> None:
    env = platoon_env.make("study_c", formation={"d_des": 0.9})
    with pytest.raises(ValueError, match="no gains for the formation"):
        TunedPPCPolicy(env)


def test_registry_entry_builds() -> None:
    env = platoon_env.make("study_b")
    policy = build_policy(PolicySpec.of("ppc_tuned"), env)
    assert isinstance(policy, TunedPPCPolicy)
    assert {k: getattr(policy.params, k) for k in TUNED_KEYS} == dict(
        load_table().lookup(env.scenario.config).params
    )


@pytest.mark.parametrize("scenario", ["study_a", "study_b", "procedural_medium_test"])
def test_search_refuses_study_maps_and_test_splits(scenario: str) -> None:
    with pytest.raises(ValueError, match="refusing to tune"):
        tuning.check_training_scenario(scenario)
    with pytest.raises(ValueError, match="refusing to tune"):
        tune_ppc.search_formation(
            "study_c", scenario=scenario, trials=1, episodes=1, max_steps=10, seed=0, timeout=None
        )
    with pytest.raises(SystemExit):
        tune_ppc.parse_args(["--scenario", scenario])


def test_formation_overrides_carry_the_studys_geometry() -> None:
    for study in STUDIES:
        over = tune_ppc.formation_overrides(study)
        env = platoon_env.make("procedural_medium_train", **over)
        cfg = env.scenario.config
        own = platoon_env.make(study).scenario.config
        assert formation_geometry(cfg) == formation_geometry(own)
        assert cfg.followers == own.followers


def test_objective_value() -> None:
    safe = {"violation": "", "time_to_violation": float("inf")}
    failed = {"violation": "collision_robot", "time_to_violation": 5.0}
    assert tuning.objective_value([safe, failed], horizon=10.0) == pytest.approx(
        0.5 + tuning.TIE_BREAK * 0.75
    )


def test_tiny_search_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "table.yaml"
    code = tune_ppc.main(
        ["--formation", "study_c", "--trials", "2", "--episodes", "1", "--max-steps", "50",
         "--workers", "1", "--out", str(out), "--log", str(tmp_path / "log")]
    )  # fmt: skip
    assert code == 0
    table = load_table(out)
    (row,) = table.formations
    assert row.name == "study_c" and row.trials == 2
    assert table.provenance["scenario"] == "procedural_medium_train"
    assert "trial 1" in (tmp_path / "log").read_text()
