"""Hardening, round 4: every row the evaluation store reads back is validated before it is
trusted (one :class:`~experiments.store.StoreError` naming the file, the row and the field), and
every wait on another process is bounded and names the holder."""

from __future__ import annotations

import math
import os
import socket
import sqlite3
import time
from pathlib import Path
from typing import Any

import pytest

from experiments.store import (
    EPISODE_METRICS,
    EPISODE_METRICS_MEASURES,
    FOREIGN_CLAIM_STALE,
    EpisodeKey,
    Store,
    StoreError,
)
from experiments.store import main as store_main

MEASURE = "platoon_env.rollout:episode_metrics"
KEY = EpisodeKey("a" * 64, "b" * 64, "c" * 64, 3, MEASURE)
STAMP = {"tool": "test", "commit": "0" * 40}
#: Metrics of the default measure as :func:`platoon_env.rollout.episode_metrics` writes them.
GOOD: dict[str, Any] = {
    **{field: 1.5 for field, kind in EPISODE_METRICS.items() if kind == "number"},
    **{field: 2 for field, kind in EPISODE_METRICS.items() if kind == "count"},
    "success": True,
    "leader_arrived": True,
    "violation": "",
    "time_to_violation": math.inf,
}


def _store(tmp_path: Path, metrics: dict[str, Any] | None = None) -> tuple[Path, int]:
    """A store with one finished episode (``KEY``) of run 1."""
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        store.register({KEY.policy: ("ppc", {})}, {KEY.scenario: {}}, {KEY.overrides: {}})
        run = store.begin_run("platoon-evaluate", STAMP)
        store.claim([KEY], run, {KEY: ("ppc", "study_c")})
        store.record(
            KEY, run, "done", metrics=GOOD if metrics is None else metrics, names=("ppc", "study_c")
        )
        store.finish_run(run, "finished")
    return path, run


def _sql(path: Path, statement: str, *params: Any) -> None:
    db = sqlite3.connect(path)
    db.execute(statement, params)
    db.commit()
    db.close()


def test_a_valid_row_reads_back(tmp_path: Path) -> None:
    path, _ = _store(tmp_path)
    with Store(path) as store:
        (record,) = store.episodes().values()
        assert record.metrics == GOOD and record.status == "done"
        assert [r["state"] for r in store.runs()] == ["finished"]


EPISODE_ROWS = [
    pytest.param(
        "metrics",
        "{}",
        "metrics.success must be true or false (the field is missing)",
        id="metrics-empty",
    ),
    pytest.param(
        "metrics", '{"success": true}', "metrics.violation must be a string", id="metrics-partial"
    ),
    pytest.param("metrics", "[1]", "metrics must be a JSON object", id="metrics-list"),
    pytest.param("metrics", '"text"', "metrics must be a JSON object", id="metrics-string"),
    pytest.param(
        "metrics", '{"a":' * 100_000 + "1" + "}" * 100_000, "nested too deep", id="metrics-deep"
    ),
    pytest.param("seed", "abc", "seed must be an integer", id="seed-text"),
    pytest.param("seed", 1.5, "seed must be an integer", id="seed-float"),
    pytest.param("run_id", "x", "run_id must be a run number", id="run-id-text"),
    pytest.param(
        "policy_name", "\x1b[31mred", "policy_name must be printable text", id="name-escape"
    ),
    pytest.param("scenario_name", "a\nb", "scenario_name must be printable text", id="name-nl"),
    pytest.param("updated", "yesterday", "updated must be a time", id="updated-text"),
    pytest.param("wall_time", -1.0, "wall_time must be empty or a duration", id="wall-negative"),
    pytest.param("wall_time", "1s", "wall_time must be empty or a duration", id="wall-text"),
    pytest.param("error", b"\xff", "error must be empty or text", id="error-blob"),
]


@pytest.mark.parametrize(("column", "value", "reason"), EPISODE_ROWS)
def test_a_bad_episode_row_is_one_error_naming_file_row_and_field(
    tmp_path: Path, column: str, value: Any, reason: str
) -> None:
    path, _ = _store(tmp_path)
    _sql(path, f"UPDATE episodes SET {column} = ?", value)
    with Store(path) as store, pytest.raises(StoreError) as exc:
        store.episodes()
    text = str(exc.value)
    assert text.startswith(f"{path}: ") and reason in text
    assert "policy aaaaaaaaaaaa, scenario bbbbbbbbbbbb, overrides cccccccccccc" in text
    assert f"measure {MEASURE}" in text
    assert "\x1b" not in text and "\n" not in text


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("rms_e_d", "abc", 'metrics.rms_e_d must be a number (or "inf", "-inf", "nan")'),
        ("rms_e_d", True, "metrics.rms_e_d must be a number"),
        ("success", 1, "metrics.success must be true or false"),
        ("steps", 2.5, "metrics.steps must be an integer >= 0"),
        ("lost_sight_steps", -1, "metrics.lost_sight_steps must be an integer >= 0"),
        ("violation", None, "metrics.violation must be a string"),
    ],
)
def test_a_metric_of_the_wrong_type_is_refused(
    tmp_path: Path, field: str, value: Any, reason: str
) -> None:
    path, _ = _store(tmp_path, {**GOOD, field: value})
    with Store(path) as store, pytest.raises(StoreError, match="episodes row") as exc:
        store.episodes()
    assert reason in str(exc.value) and "ppc on study_c, seed 3" in str(exc.value)


def test_other_measures_and_unfinished_rows_are_checked_for_shape_only(tmp_path: Path) -> None:
    """Only a measure's own code knows its fields: a row of a measure outside
    EPISODE_METRICS_MEASURES needs a JSON object; a failed row needs no metrics."""
    path = tmp_path / "s.sqlite"
    other = KEY._replace(measure="my.module:my_measure")
    failed = KEY._replace(seed=4)
    with Store(path) as store:
        store.register({KEY.policy: ("ppc", {})}, {KEY.scenario: {}}, {KEY.overrides: {}})
        run = store.begin_run("t", STAMP)
        names = {other: ("ppc", "study_c"), failed: ("ppc", "study_c")}
        store.claim(list(names), run, names)
        store.record(other, run, "done", metrics={"x": "y"}, names=("ppc", "study_c"))
        store.record(failed, run, "failed", error="Traceback ...", names=("ppc", "study_c"))
        got = store.episodes()
    assert got[other].metrics == {"x": "y"} and got[failed].metrics == {}


@pytest.mark.parametrize(
    ("column", "value", "reason"),
    [
        ("stamp", "[1]", "stamp must be a JSON object"),
        ("stamp", '"text"', "stamp must be a JSON object"),
        ("pid", "abc", "pid must be a process id"),
        ("pid", 2**40, "pid must be a process id"),
        ("pid", 0, "pid must be a process id"),
        ("status", "bogus", "status must be one of running, finished"),
        ("host", b"\xff", "host must be a host name"),
        ("started", "now", "started must be a time"),
        ("proc_start", "12abc", "proc_start must be empty or a process start time"),
    ],
)
def test_a_bad_runs_row_is_one_error_naming_the_run_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], column: str, value: Any, reason: str
) -> None:
    path, run = _store(tmp_path)
    _sql(
        path,
        f"UPDATE runs SET {column} = ?, status = 'running'"
        if column != "status"
        else "UPDATE runs SET status = ?",
        value,
    )
    with Store(path) as store, pytest.raises(StoreError) as exc:
        store.runs()
    text = str(exc.value)
    assert text.startswith(f"{path}: the runs row of run {run}: its {column}") and reason in text
    # The store's own listing: one line and exit 2, no traceback.
    assert store_main([str(path)]) == 2
    err = capsys.readouterr().err
    assert reason in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_a_claim_is_not_decided_on_a_bad_runs_row(tmp_path: Path) -> None:
    """The pid of the run holding a claim is checked before it is used (a pid past the OS's
    range raised OverflowError from os.kill; a text pid ValueError)."""
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        store.register({KEY.policy: ("ppc", {})}, {KEY.scenario: {}}, {KEY.overrides: {}})
        holder = store.begin_run("t", STAMP)
        store.claim([KEY], holder, {KEY: ("ppc", "study_c")})
    _sql(path, "UPDATE runs SET pid = ? WHERE run_id = ?", 2**40, holder)
    with Store(path) as store:
        run = store.begin_run("t", STAMP)
        with pytest.raises(StoreError, match=rf"the runs row of run {holder}: its pid"):
            store.claim([KEY], run, {KEY: ("ppc", "study_c")})


def test_a_scenario_config_that_is_not_an_object_is_refused(tmp_path: Path) -> None:
    path, _ = _store(tmp_path)
    _sql(path, "UPDATE scenarios SET config = '[1]'")
    with Store(path) as store, pytest.raises(StoreError) as exc:
        store.scenario_config(KEY.scenario)
    assert f"the scenarios row of {KEY.scenario}: its config must be a JSON object" in str(
        exc.value
    )


def test_finish_run_takes_a_known_status(tmp_path: Path) -> None:
    with Store(tmp_path / "s.sqlite") as store:
        run = store.begin_run("t", STAMP)
        with pytest.raises(ValueError, match="status must be one of finished"):
            store.finish_run(run, "done")


def test_the_metric_table_is_what_the_measures_write(tmp_path: Path) -> None:
    """EPISODE_METRICS lists exactly the fields of episode_metrics, with their types, and the
    measures that extend it are named; a real episode's row reads back."""
    from experiments.cells import DEFAULT_MEASURE, Cell, resolve_cells, run_cell
    from experiments.policies import PolicySpec
    from experiments.studies import comparison

    assert {DEFAULT_MEASURE, comparison.MEASURE, comparison.FIG15_MEASURE} == set(
        EPISODE_METRICS_MEASURES
    )
    (rc,) = resolve_cells([Cell.of(PolicySpec.of("ppc"), "study_c", 0, {"max_episode_steps": 5})])
    result = run_cell(rc)
    assert result.status == "done", result.error
    assert set(result.metrics) == set(EPISODE_METRICS)
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        store.register({rc.key.policy: ("ppc", {})}, {rc.key.scenario: {}}, {rc.key.overrides: {}})
        run = store.begin_run("t", STAMP)
        store.claim([rc.key], run, {rc.key: rc.names})
        store.record(rc.key, run, "done", metrics=result.metrics, names=rc.names)
        assert store.episodes()[rc.key].metrics == result.metrics


# --- bounded waits ------------------------------------------------------------------------------


def test_a_lock_held_too_long_names_the_running_runs(tmp_path: Path) -> None:
    """SQLite's busy wait is bounded (``timeout``); then the error names the runs marked running
    (the likely holders: run, tool, host, pid) and what to do, not "database is locked"."""
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        run = store.begin_run("platoon-evaluate", STAMP)
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    try:
        start = time.monotonic()
        with pytest.raises(StoreError) as exc:
            Store(path, timeout=0.2)
        assert time.monotonic() - start < 10
        text = str(exc.value)
        assert text.startswith(f"{path}: could not lock the store within 0.2 s")
        assert f"run {run} (platoon-evaluate, this host, pid {os.getpid()})" in text
        assert "Wait for that run to finish" in text and "not an evaluation store" not in text
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    with Store(path, timeout=0.2) as store:
        other = sqlite3.connect(path, isolation_level=None)
        other.execute("BEGIN IMMEDIATE")
        try:
            with pytest.raises(StoreError, match=r"(?s)within 0\.2 s .*run \d+ \(platoon-evaluate"):
                store.begin_run("t", STAMP)
        finally:
            other.execute("ROLLBACK")
            other.close()


def _foreign_claim(path: Path, age: float) -> int:
    """A run of another host holding KEY, that last wrote ``age`` seconds ago."""
    with Store(path) as store:
        store.register({KEY.policy: ("ppc", {})}, {KEY.scenario: {}}, {KEY.overrides: {}})
        holder = store.begin_run("platoon-evaluate", STAMP)
        store.claim([KEY], holder, {KEY: ("ppc", "study_c")})
    then = time.time() - age
    _sql(
        path,
        "UPDATE runs SET host = 'elsewhere.example', pid = 4242, started = ? WHERE run_id = ?",
        then,
        holder,
    )
    _sql(path, "UPDATE episodes SET updated = ?", then)
    return holder


def test_a_silent_claim_of_another_host_is_taken_over(tmp_path: Path) -> None:
    """A copied store: the claims of a run on another host that has written nothing for
    FOREIGN_CLAIM_STALE seconds are taken over at once, instead of a wait."""
    path = tmp_path / "s.sqlite"
    holder = _foreign_claim(path, FOREIGN_CLAIM_STALE + 60)
    with Store(path) as store:
        assert {r["run_id"]: r["state"] for r in store.runs()}[holder] == "stale"
        run = store.begin_run("t", STAMP)
        claim = store.claim([KEY], run, {KEY: ("ppc", "study_c")})
    assert claim.mine == (KEY,) and claim.busy == ()


def test_a_recent_claim_of_another_host_is_waited_for_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    holder = _foreign_claim(path, 10.0)
    assert socket.gethostname() != "elsewhere.example"
    with Store(path) as store:
        run = store.begin_run("t", STAMP)
        assert store.claim([KEY], run, {KEY: ("ppc", "study_c")}).busy == (KEY,)
        text = store.holders_message([KEY], 600.0)
    assert f"run {holder} (platoon-evaluate, host elsewhere.example, pid 4242" in text
    assert "it last wrote 1" in text and f"after {FOREIGN_CLAIM_STALE:.0f} s of silence" in text


def test_rows_written_before_the_graded_metrics_are_still_valid(tmp_path: Path) -> None:
    """A row without the later fields (EPISODE_METRICS_LATER) reads back; one that holds them
    must hold numbers."""
    from experiments.store import EPISODE_METRICS_LATER, _check_metrics

    assert EPISODE_METRICS_LATER <= set(EPISODE_METRICS)
    measure = sorted(EPISODE_METRICS_MEASURES)[0]
    old = {k: v for k, v in GOOD.items() if k not in EPISODE_METRICS_LATER}
    _check_metrics(old, "done", measure)
    with pytest.raises(Exception, match="path_fraction"):
        _check_metrics({**old, "path_fraction": "far"}, "done", measure)
    with pytest.raises(Exception, match="rms_e_d"):
        _check_metrics({k: v for k, v in old.items() if k != "rms_e_d"}, "done", measure)
