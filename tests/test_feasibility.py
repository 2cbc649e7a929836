"""The feasibility driver (:mod:`experiments.studies.feasibility`): certificates and their rows.

A certificate is the oracle's episode with its slack and witness trajectory; a short task's
certificate regenerates bit-identically in a fresh store. The slack is the minimum of the
normalised margins, computed here independently from the episode's ground truth.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

import platoon_env
from baselines.ppc import PPCPolicy
from experiments.studies import feasibility
from platoon_env.rollout import run_episode

QUICK = [
    "--task",
    "study_c/ideal",
    "--seeds",
    "1",
    "--no-laws",
    "--oracle-param",
    "samples=4",
    "--oracle-param",
    "horizon=3",
    "--oracle-param",
    "knot=5",
    "--max-episode-steps",
    "40",
    "--workers",
    "1",
]


def _rows(store: Path) -> list[tuple[str, str]]:
    with sqlite3.connect(store) as db:
        return sorted(db.execute("SELECT status, metrics FROM episodes").fetchall())


def test_a_short_certificate_regenerates_bit_identically(tmp_path: Path) -> None:
    pages = []
    for name in ("a", "b"):
        store = tmp_path / name / "store.sqlite"
        pages.append(
            feasibility.main([*QUICK, "--store", str(store), "--out", str(tmp_path / name)])
        )
    a, b = _rows(tmp_path / "a" / "store.sqlite"), _rows(tmp_path / "b" / "store.sqlite")
    assert len(a) == 1 and a == b
    assert '"witness"' in a[0][1] and '"slack"' in a[0][1]
    table = pages[0].split("## Provenance")[0]
    assert "study_c/ideal" in table and "0/1" in table  # 40 steps: the leader has not arrived


def test_slack_is_the_least_normalised_margin() -> None:
    env = platoon_env.make("study_c", max_episode_steps=400)
    ep = run_episode(env, PPCPolicy(env), seed=2, record_signals=False)
    row = feasibility.certify(ep)
    cfg = env.scenario.config
    d = ep.sensed[1:, :, 0]
    beta = ep.sensed[1:, :, 1]
    expected = min(
        float(np.min((d - cfg.safety.d_col) / (cfg.formation.d_des - cfg.safety.d_col))),
        float(np.min((cfg.camera.range - d) / (cfg.camera.range - cfg.formation.d_des))),
        float(np.min(1 - np.abs(beta) / cfg.camera.half_angle)),
    )
    assert row["slack"] == pytest.approx(expected, abs=1e-12)
    assert row["binding"] in feasibility.NORMALISED
    assert 1 <= row["binding_follower"] <= cfg.followers
    witness = np.asarray(row["witness"])
    assert witness.shape[1:] == (cfg.followers + 1, 3)
    np.testing.assert_allclose(witness[0], ep.poses[0], atol=1e-4)


def test_a_failed_episode_names_the_follower_that_violated_and_where() -> None:
    env = platoon_env.make("study_b", sensor_profile="aruco")
    ep = run_episode(env, PPCPolicy(env), seed=0, record_signals=False)
    assert ep.first_violation is not None
    step, cause, follower = ep.first_violation
    row = feasibility.certify(ep)
    assert row["violation"] == cause and row["violation_follower"] == follower
    np.testing.assert_allclose(row["violation_xy"], ep.poses[step + 1, follower, :2], atol=1e-3)


def test_a_task_that_cannot_be_built_is_reported_not_run(monkeypatch: pytest.MonkeyPatch) -> None:
    strict = {"robot": {"u_max": 0.1}, "leader": {"drive": "check"}}
    monkeypatch.setitem(feasibility.CONDITIONS, "strict", strict)
    refused = feasibility.refusals(["study_a/strict", "study_b/turtlebot3_waffle_pi"])
    assert list(refused) == ["study_a/strict"]
    assert "leader.speed" in refused["study_a/strict"]


def test_the_oracle_s_base_is_a_named_option() -> None:
    assert feasibility._oracle_param("base=feedback") == ("base", "feedback")
    assert feasibility._oracle_param("base=filtered_ppc") == ("base", "filtered_ppc")
    assert feasibility._oracle_param("samples=8") == ("samples", 8)
    with pytest.raises(Exception, match="base must be"):
        feasibility._oracle_param("base=nothing")


def test_the_summary_file_is_what_the_board_reads(tmp_path: Path) -> None:
    from experiments.board import load_oracle

    feasibility.main([*QUICK, "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path)])
    assert load_oracle(tmp_path / "feasibility.json") == {"study_c/ideal": (0, 1)}
    assert str(tmp_path) not in (tmp_path / "feasibility.json").read_text()  # portable
