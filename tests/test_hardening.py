"""Hardening of the evaluation engine: results that cannot lie when files are swapped or edited
mid-run, inputs that cannot escape their folder or hang an evaluator, and inputs that are not
ours (a foreign or damaged database, a bad row, a bad option) refused with a message naming
them, without writing into them."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.grid import Cell, resolve_cells, run_cell, run_grid, store_file, store_path
from experiments.policies import PolicySpec
from experiments.report import file_stem, provenance_markdown
from experiments.store import ClaimTimeout, EpisodeKey, Store, StoreError
from experiments.store import main as store_main

STAMP = {"tool": "test"}
#: A cell of a few steps (PPC on study C): the grid's machinery, not the episode, is tested.
SHORT = {"max_episode_steps": 5}


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _fake_model(folder: Path, content: bytes = b"model one", period: float = 0.05) -> Path:
    """A model folder whose files are hashed but never loaded (the check comes first)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.zip").write_bytes(content)
    (folder / "model.json").write_text(json.dumps({"control_period": period}))
    return folder


def _dead_pid() -> int:
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                          capture_output=True, text=True)  # fmt: skip
    return int(proc.stdout)


# ----------------------------------------------------------------------------------------------
# Wrong results: a model replaced during an evaluation
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("changed", ["model.zip", "model.json"])
def test_a_model_file_replaced_after_planning_fails_its_cell(tmp_path: Path, changed: str) -> None:
    """The worker hashes the files it loads and compares them with the planned fingerprint: a
    swapped file is a failed cell naming the file (retried later), never a result stored
    under the old file's fingerprint, nor a "refused" one (which is a result)."""
    folder = _fake_model(tmp_path / "m")
    spec = PolicySpec.model(folder)
    (rc,) = resolve_cells([Cell.of(spec, "study_c", 0, SHORT)])
    if changed == "model.zip":
        (folder / "model.zip").write_bytes(b"model two")
    else:
        (folder / "model.json").write_text(json.dumps({"control_period": 0.05, "x": 1}))
    result = run_cell(rc)
    assert result.status == "failed", result
    last = result.error.strip().splitlines()[-1]
    assert "PolicyFileChanged" in last and f"{changed} (SHA-256 planned" in last
    assert "changed after the evaluation was planned" in last
    grid = run_grid(tmp_path / "s.sqlite", [rc], tool="t", stamp=STAMP, progress=False)
    (rec,) = grid.records.values()
    assert rec.key == rc.key and rec.status == "failed" and not rec.metrics


def test_an_unloadable_model_is_a_failure_not_a_refusal(tmp_path: Path) -> None:
    """Files that match the plan but do not load (not a model) fail the cell: only the policy
    declining the configuration (``check_env``) is a refusal."""
    spec = PolicySpec.model(_fake_model(tmp_path / "m"))
    (rc,) = resolve_cells([Cell.of(spec, "study_c", 0, SHORT)])
    result = run_cell(rc)
    assert result.status == "failed"
    assert f"{spec.path}: cannot be loaded" in result.error
    assert "platoon-model-" not in result.error  # the private copy's path is not shown


# ----------------------------------------------------------------------------------------------
# Escapes: names that become paths
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name", ["../../../../x", "/etc/passwd", "..", ".", "", "a/b", "a\\b", "x\x00y", "é" * 300]
)
def test_file_stem_never_leaves_its_folder(name: str, tmp_path: Path) -> None:
    stem = file_stem(name)
    assert stem and not stem.startswith(".") and len(stem) <= 80
    assert "/" not in stem and "\\" not in stem and "\x00" not in stem
    assert (tmp_path / f"{stem}.gif").resolve().parent == tmp_path.resolve()
    assert file_stem("study_c") == "study_c"  # a plain name is kept as it is
    assert file_stem("a/b") != file_stem("a_b")  # distinct names, distinct files


def test_a_policy_name_with_a_path_writes_nothing_outside_out(tmp_path: Path) -> None:
    from experiments.studies.evaluate import main

    out = tmp_path / "a" / "b" / "c" / "d" / "out"
    argv = ["--policy", "../../../../x=ppc", "--scenario", "study_c", "--episodes", "1",
            "--workers", "1", "--set", "max_episode_steps=20", "--out", str(out)]  # fmt: skip
    # a NAME holds letters, digits, '_', '.' and '-' only: refused before anything is written
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


# ----------------------------------------------------------------------------------------------
# Hangs: claims that are never finished
# ----------------------------------------------------------------------------------------------


def _held_by_another_run(path: Path, key: EpisodeKey, **run: object) -> int:
    """A run holding ``key`` in the store at ``path``, its ``runs`` row then set to ``run``."""
    with Store(path) as store:
        holder = store.begin_run("platoon-evaluate", STAMP)
        assert store.claim([key], holder, {key: ("ppc", "study_c")}).mine == (key,)
    with sqlite3.connect(path) as db:
        for column, value in run.items():
            db.execute(f"UPDATE runs SET {column} = ? WHERE run_id = ?", (value, holder))
    return holder


def test_a_claim_of_another_host_ends_the_wait_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A copied store: its claims come from a host this one cannot look at. The wait is bounded,
    the error names the run, host and pid and how to release the claims; after the release the
    next run takes the cell."""
    path = tmp_path / "s.sqlite"
    cells = [Cell.of(PolicySpec.of("ppc"), "study_c", s, SHORT) for s in (0, 1)]
    rcs = resolve_cells(cells)
    with Store(path) as store:
        key = rcs[0].key
        store.register({key.policy: ("ppc", {})}, {key.scenario: {}}, {key.overrides: {}})
    holder = _held_by_another_run(path, rcs[0].key, host="elsewhere.example", pid=4242)
    with pytest.raises(ClaimTimeout) as exc:
        run_grid(path, rcs, tool="t", stamp=STAMP, progress=False, poll=0.01, claim_timeout=0.05)
    text = str(exc.value)
    assert f"run {holder} (platoon-evaluate, host elsewhere.example, pid 4242" in text
    assert f"python -m experiments.store {path} --release RUN_ID" in text
    with Store(path) as store:  # the other cell was run before giving up
        statuses = {r.key.seed: r.status for r in store.episodes().values()}
    assert statuses == {0: "running", 1: "done"}
    assert store_main([str(path), "--release", str(holder)]) == 0
    assert f"released 1 claim(s) of run {holder}" in capsys.readouterr().out
    again = run_grid(path, rcs, tool="t", stamp=STAMP, progress=False, claim_timeout=0.05)
    assert again.ran == 1 and again.reused == 1
    with Store(path) as store:
        states = {r["run_id"]: r["state"] for r in store.runs()}
    assert states[holder] == "released"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_claim_of_a_stopped_process_ends_the_wait_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    (rc,) = resolve_cells([Cell.of(PolicySpec.of("ppc"), "study_c", 0, SHORT)])
    with Store(path) as store:
        store.register({rc.key.policy: ("ppc", {})}, {rc.key.scenario: {}}, {rc.key.overrides: {}})
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    try:
        from experiments.store import _proc_start

        os.kill(sleeper.pid, signal.SIGSTOP)
        holder = _held_by_another_run(path, rc.key, pid=sleeper.pid,
                                      proc_start=_proc_start(sleeper.pid))  # fmt: skip
        with pytest.raises(ClaimTimeout) as exc:
            run_grid(path, [rc], tool="t", stamp=STAMP, progress=False, poll=0.01,
                     claim_timeout=0.05)  # fmt: skip
        text = str(exc.value)
        assert f"run {holder} (platoon-evaluate, this host, pid {sleeper.pid}" in text
        assert f"kill -CONT {sleeper.pid}" in text and "--release RUN_ID" in text
    finally:
        sleeper.kill()
        sleeper.wait()
    # Its process gone, the claim is taken over without waiting.
    again = run_grid(path, [rc], tool="t", stamp=STAMP, progress=False, claim_timeout=0.05)
    assert again.ran == 1


def test_a_killed_run_is_reported_as_killed(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        store.register({"p": ("ppc", {})}, {"s": {}}, {"o": {}})
        killed = store.begin_run("t", STAMP)
        key = EpisodeKey("p", "s", "o", 0, "m")
        store.claim([key], killed, {key: ("p", "s")})
        store.record(key, killed, "done", metrics={"x": 1}, names=("p", "s"))
        this = store.begin_run("t", STAMP)
    with sqlite3.connect(path) as db:
        db.execute("UPDATE runs SET pid = ? WHERE run_id = ?", (_dead_pid(), killed))
    with Store(path) as store:
        states = {r["run_id"]: r["state"] for r in store.runs()}
        assert states == {killed: "killed", this: "running"}
        text = provenance_markdown(store, store.episodes().values(), this)
    assert f"run {killed} (killed: its process is gone" in text


# ----------------------------------------------------------------------------------------------
# Inputs that are not ours
# ----------------------------------------------------------------------------------------------


def test_a_foreign_sqlite_file_is_refused_untouched(tmp_path: Path) -> None:
    path = tmp_path / "other.sqlite"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE users (name TEXT)")
        db.execute("INSERT INTO users VALUES ('ada')")
    db.close()
    before = _sha(path)
    with pytest.raises(StoreError, match=r"not an evaluation store .*tables users.*untouched"):
        Store(path)
    assert _sha(path) == before
    with sqlite3.connect(path) as db:
        assert [r[0] for r in db.execute("SELECT name FROM sqlite_master")] == ["users"]
    db.close()
    # A table of our name but another layout is not ours either.
    meta = tmp_path / "meta.sqlite"
    with sqlite3.connect(meta) as db:
        db.execute("CREATE TABLE meta (a INTEGER)")
    db.close()
    with pytest.raises(StoreError, match="not an evaluation store"):
        Store(meta)


def test_a_damaged_store_is_refused_untouched(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        store.register({"p": ("ppc", {})}, {"s": {}}, {"o": {}})
        run = store.begin_run("t", STAMP)
        for seed in range(300):  # a few pages of episodes
            key = EpisodeKey("p", "s", "o", seed, "m")
            store.record(key, run, "done", metrics={"x": "y" * 50}, names=("p", "s"))
    assert not Path(f"{path}-wal").exists()  # the last close checkpointed the journal
    raw = bytearray(path.read_bytes())
    page = 4096
    assert len(raw) > 6 * page
    raw[3 * page : 3 * page + 200] = b"\xff" * 200  # a page of the episodes' b-tree
    path.write_bytes(bytes(raw))
    before = _sha(path)
    with pytest.raises(StoreError, match="damaged"):
        Store(path)
    assert _sha(path) == before


def test_a_row_with_bad_metrics_json_names_the_row(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    key = EpisodeKey("p" * 64, "s", "o", 7, "m")
    with Store(path) as store:
        store.register({key.policy: ("ppc", {})}, {"s": {}}, {"o": {}})
        run = store.begin_run("t", STAMP)
        store.record(key, run, "done", metrics={"x": 1}, names=("ppc", "study_c"))
    with sqlite3.connect(path) as db:
        db.execute("UPDATE episodes SET metrics = '{not json'")
    db.close()
    with Store(path) as store, pytest.raises(StoreError) as exc:
        store.episodes()
    text = str(exc.value)
    assert str(path) in text and "ppc on study_c, seed 7" in text and "not readable JSON" in text


def test_store_options_name_a_file_or_a_folder(tmp_path: Path) -> None:
    assert store_file(tmp_path / "x.sqlite") == tmp_path / "x.sqlite"
    assert store_file(tmp_path) == store_path(tmp_path)
    (tmp_path / "other.db").write_bytes(b"")
    assert store_file(tmp_path / "other.db") == tmp_path / "other.db"  # an existing file


def test_leaderboard_store_file_is_the_store(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--store FILE.sqlite`` is that file (the help says so): a foreign one is refused, named
    and untouched, before any work; no folder is made in its place."""
    from experiments.studies.leaderboard import main

    path = tmp_path / "FILE.sqlite"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE t (x)")
    db.close()
    before = _sha(path)
    models = _fake_model(tmp_path / "models" / "m").parent
    assert main(["--store", str(path), "--models", str(models), "--docs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"--store {path}" in err and "not an evaluation store" in err
    assert _sha(path) == before and sorted(p.name for p in tmp_path.iterdir()) == [
        "FILE.sqlite",
        "models",
    ]


def _usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    from experiments.studies.evaluate import parse_args

    with pytest.raises(SystemExit) as exc:
        parse_args(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "usage: platoon-evaluate" in err and "Traceback" not in err
    return err


def test_a_model_with_another_control_period_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _fake_model(tmp_path / "m", period=0.025)
    argv = ["--policy", f"m={model}", "--scenario", "study_c", "--out", str(tmp_path / "o")]
    err = _usage_error([*argv, "--set", "control_period=0.05"], capsys)
    assert "control_period=0.05 contradicts policy 'm'" in err and "control_period=0.025" in err
    assert not (tmp_path / "o").exists()


def test_an_unwritable_out_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    argv = ["--policy", "ppc", "--scenario", "study_c", "--out", str(blocker / "sub")]
    err = _usage_error(argv, capsys)
    assert f"--out {blocker / 'sub'}: {blocker} is not a folder" in err
    assert blocker.read_text() == "x"


def test_an_unwritable_store_is_a_store_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(StoreError, match="cannot create its folder"):
        Store(blocker / "sub" / "results.sqlite")


def test_a_missing_models_folder_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _usage_error(["--models", str(tmp_path / "nonexistent"), "--out", str(tmp_path)], capsys)
    assert f"--models {tmp_path / 'nonexistent'}: no such folder" in err


def test_a_second_name_for_one_policy_is_noted(capsys: pytest.CaptureFixture[str]) -> None:
    """``--policy a=ppc --policy b=ppc`` is one policy (one fingerprint, the same rows): it runs
    once, under the first name, and the second is not dropped silently."""
    from experiments.studies.evaluate import parse_args

    args = parse_args(["--policy", "a=ppc", "--policy", "b=ppc", "--scenario", "study_c"])
    assert [p.name for p in args.policy] == ["a"]
    assert {rc.cell.policy.name for rc in args.cells} == {"a"}
    out = capsys.readouterr().out
    assert "note: --policy b is the same policy as a" in out and "run once" in out


def test_the_first_cell_of_a_key_names_it(tmp_path: Path) -> None:
    """run_grid keeps the first of several cells with one key, as resolve_cells does."""
    a, b = PolicySpec.of("ppc", "a"), PolicySpec.of("ppc", "b")
    rcs = resolve_cells([Cell.of(p, "study_c", 0, SHORT) for p in (a, b)], unique=False)
    result = run_grid(tmp_path / "s.sqlite", rcs, tool="t", stamp=STAMP, progress=False)
    assert [rc.cell.policy.name for rc in result.cells] == ["a"]
    assert [r.policy_name for r in result.records.values()] == ["a"]


def test_store_cli_lists_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        run = store.begin_run("platoon-evaluate", STAMP)
    assert store_main([str(path)]) == 0
    out = capsys.readouterr().out
    assert f"run {run}: platoon-evaluate running, host {socket.gethostname()}" in out
    assert store_main([str(path), "--release", "99"]) == 2
    assert "no run 99" in capsys.readouterr().err


def test_a_table_redrawn_from_one_earlier_version_is_not_called_mixed(tmp_path: Path) -> None:
    """The mixed-code warning counts the code versions of the rows: a later run at another
    commit that only redraws the tables (0 rows of its own) does not add its own."""
    (rc,) = resolve_cells([Cell.of(PolicySpec.of("ppc"), "study_c", 0, SHORT)])
    metrics = run_cell(rc).metrics
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        store.register({rc.key.policy: ("ppc", {})}, {rc.key.scenario: {}}, {rc.key.overrides: {}})
        first = store.begin_run("t", {"tool": "t", "commit": "a" * 40})
        store.claim([rc.key], first, {rc.key: rc.names})
        store.record(rc.key, first, "done", metrics=metrics, names=rc.names)
        store.finish_run(first, "finished")
        redraw = store.begin_run("t", {"tool": "t", "commit": "b" * 40})
        text = provenance_markdown(store, store.episodes().values(), redraw)
        assert "0 from this run" in text and "warning" not in text
        second = store.begin_run("t", {"tool": "t", "commit": "c" * 40})
        other = EpisodeKey(rc.key.policy, rc.key.scenario, rc.key.overrides, 1, rc.key.measure)
        store.claim([other], second, {other: rc.names})
        store.record(other, second, "done", metrics=metrics, names=rc.names)
        text = provenance_markdown(store, store.episodes().values(), second)
        assert "the rows come from 2 code versions (aaaaaaaaaaaa, cccccccccccc)" in text
