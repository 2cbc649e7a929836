"""The drive-aware filtered PPC (baselines/filtered_ppc_drive.py), its lookahead option in the
filter (``lookahead_predecessor``) and the search that writes its table
(experiments/studies/tune_filtered.py)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import platoon_env
from baselines.filtered_ppc import FilteredPPCPolicy, FilterParams
from baselines.filtered_ppc_drive import (
    DEFAULT_TABLE,
    DriveAwareFilteredPPCPolicy,
    DriveTableError,
    load_drive_table,
)
from experiments.grid import Cell, resolve_cells, run_cell
from experiments.policies import PolicySpec, build_policy
from experiments.studies import tune_filtered

ARUCO = {"sensor_profile": "aruco"}


def test_predecessor_fraction_moves_only_the_predecessor() -> None:
    """Two copies of one policy state, the same frame: ``phi = 1`` and ``phi = 0`` hand the law
    estimates that differ by the predecessor's motion over the lookahead, ``w^ tau`` (the
    follower's own motion over tau is in both)."""
    env = platoon_env.make("study_b", **ARUCO)
    a = FilteredPPCPolicy(env, lookahead=0.5, lookahead_predecessor=1.0)
    obs, _ = env.reset(seed=0)
    a.reset(seed=0)
    for _ in range(300):  # the predecessors move: the filter has a velocity estimate
        obs, *_ = env.step(a.act(obs))
    b = copy.deepcopy(a)
    b._kernel["lookahead_predecessor"] = 0.0
    a.act(obs)
    b.act(obs)
    sa, sb = a.signals, b.signals
    moved = np.hypot(sa["x_hat"] - sb["x_hat"], sa["y_hat"] - sb["y_hat"])
    assert moved.max() > 0.05  # the predecessor is driving: the fraction matters
    np.testing.assert_allclose(sa["x_hat"] - sb["x_hat"], sa["w_x"] * 0.5, atol=1e-12)
    np.testing.assert_allclose(sa["y_hat"] - sb["y_hat"], sa["w_y"] * 0.5, atol=1e-12)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_predecessor_fraction_is_checked(bad: float) -> None:
    env = platoon_env.make("study_c", **ARUCO)
    with pytest.raises(ValueError, match="lookahead_predecessor"):
        FilteredPPCPolicy(env, lookahead_predecessor=bad)


def test_shipped_table_validates_and_names_its_search() -> None:
    table = load_drive_table()
    assert table.path == DEFAULT_TABLE
    assert table.provenance["command"].startswith(tune_filtered.COMMAND)
    assert table.provenance["scenarios"] == list(tune_filtered.DEFAULT_SCENARIOS)
    grid = yaml.safe_load(DEFAULT_TABLE.read_text())["grid"]
    values = {(g["lookahead_rate_limited"], g["lookahead_predecessor"]): g["value"] for g in grid}
    chosen = (table.lookahead_rate_limited, table.lookahead_predecessor)
    assert tune_filtered.best_point(values) == chosen


def test_rate_limited_drive_gets_the_tables_lookahead() -> None:
    table = load_drive_table()
    env = platoon_env.make("study_b", **ARUCO)
    p = DriveAwareFilteredPPCPolicy(env).params
    lag = env.scenario.config.robot.lag
    assert p.lookahead == pytest.approx(lag + table.lookahead_rate_limited)
    assert p.lookahead_predecessor == table.lookahead_predecessor
    # explicit options win over the table
    q = DriveAwareFilteredPPCPolicy(env, lookahead_rate_limited=0.2, lookahead_predecessor=1.0)
    assert q.params.lookahead == pytest.approx(lag + 0.2) and q.params.lookahead_predecessor == 1
    assert DriveAwareFilteredPPCPolicy(env, lookahead=0.05).params.lookahead == 0.05
    with pytest.raises(ValueError, match="lookahead_rate_limited"):
        DriveAwareFilteredPPCPolicy(env, lookahead_rate_limited=-1.0)


def test_ideal_drive_is_the_filtered_ppc() -> None:
    """Without lag or rate limits there is no lookahead: the same commands as the filtered PPC
    (the aruco camera, an ideal drive)."""
    env = platoon_env.make("study_c", sensor_profile="aruco", robot={"accel_max": None,
                           "alpha_max": None})  # fmt: skip
    a, b = FilteredPPCPolicy(env), DriveAwareFilteredPPCPolicy(env)
    assert a.params == b.params
    obs, _ = env.reset(seed=0)
    for _ in range(200):
        ca, cb = a.act(obs), b.act(obs)
        for k in ca:
            np.testing.assert_array_equal(ca[k], cb[k])
        obs, *_ = env.step(ca)


def _write(path: Path, data: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"params": {"lookahead_rate_limited": 0.5}}, "missing"),
        ({"params": {"lookahead_rate_limited": "x", "lookahead_predecessor": 0}}, "number"),
        ({"params": {"lookahead_rate_limited": -1, "lookahead_predecessor": 0}}, ">= 0"),
        ({"params": {"lookahead_rate_limited": 0.5, "lookahead_predecessor": 2}}, r"\[0, 1\]"),
        ({"extra": 1}, "expected the keys"),
    ],
)
def test_bad_table_names_the_field(tmp_path: Path, edit: dict[str, Any], message: str) -> None:
    data = yaml.safe_load(DEFAULT_TABLE.read_text())
    data.update(edit)
    path = _write(tmp_path / "t.yaml", data)
    with pytest.raises(DriveTableError, match=message):
        load_drive_table(path)


def test_registry_entry_builds_with_a_table(tmp_path: Path) -> None:
    data = yaml.safe_load(DEFAULT_TABLE.read_text())
    data["params"] = {"lookahead_rate_limited": 0.25, "lookahead_predecessor": 0.5}
    path = _write(tmp_path / "t.yaml", data)
    env = platoon_env.make("study_c", **ARUCO)
    policy = build_policy(PolicySpec.of("filtered_ppc_drive", table=str(path)), env)
    assert isinstance(policy, DriveAwareFilteredPPCPolicy)
    assert policy.params.lookahead == pytest.approx(0.25)
    assert policy.params.lookahead_predecessor == 0.5


def test_best_point_ties_go_to_the_filtered_ppcs_rule() -> None:
    values = {(0.5, 0.0): 0.8, (0.1, 1.0): 0.8, (0.1, 0.0): 0.8, (1.0, 0.0): 0.7}
    assert tune_filtered.best_point(values) == (0.1, 1.0)
    values[(0.5, 0.0)] = 0.81
    assert tune_filtered.best_point(values) == (0.5, 0.0)


@pytest.mark.parametrize("scenario", ["study_b", "procedural_medium_test"])
def test_search_refuses_study_maps_and_test_splits(scenario: str, tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        tune_filtered.main(["--scenario", scenario, "--out", str(tmp_path)])


def test_tiny_search_end_to_end(tmp_path: Path) -> None:
    table = tmp_path / "table.yaml"
    code = tune_filtered.main(
        ["--episodes", "1", "--tau-r", "0.1", "0.5", "--phi", "0", "--max-steps", "40",
         "--workers", "1", "--scenario", "procedural_formations_paper_train",
         "--out", str(tmp_path / "out"), "--table", str(table)]
    )  # fmt: skip
    assert code == 0
    written = load_drive_table(table)
    grid = yaml.safe_load(table.read_text())["grid"]
    assert [(g["lookahead_rate_limited"], g["lookahead_predecessor"]) for g in grid] == [
        (0.1, 0.0), (0.5, 0.0)
    ]  # fmt: skip
    assert written.provenance["max_episode_steps"] == 40
    assert "| 0.5 | 0 |" in (tmp_path / "out" / "tune_filtered.md").read_text()


def test_analytic_law_on_a_drawn_formation() -> None:
    """A tier that draws its formation per layout: the law is built on the episode's own
    scenario and the episode records its own followers (both were the first layout's)."""
    cells = resolve_cells(
        [Cell.of(PolicySpec.of("filtered_ppc"), "procedural_formations_paper_train", seed,
                 {**ARUCO, "max_episode_steps": 30}) for seed in (0, 1)]
    )  # fmt: skip
    for rc in cells:
        result = run_cell(rc, keep=True)
        assert result.status == "done", result.error[-600:]
        env = platoon_env.make("procedural_formations_paper_train", **ARUCO)
        env.reset(seed=rc.cell.seed)
        assert result.episode.actions.shape[1] == len(env.agents)
        assert result.episode.poses.shape[1] == len(env.agents) + 1


def test_filter_params_know_the_new_option() -> None:
    assert "lookahead_predecessor" in FilterParams.TUNABLE
    assert FilterParams.lookahead_predecessor == 1.0
