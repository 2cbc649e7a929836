"""The store under concurrency: several processes claiming and writing the same cells (every
cell exactly once, none lost), and writers killed while holding claims or in the middle of a
transaction (their claims recovered, nothing half-written, the store not left locked).

The cells are synthetic keys (no episodes are run), so the family is fast."""

from __future__ import annotations

import multiprocessing
import os
import signal
import sqlite3
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from experiments.store import EpisodeKey, Store

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="forks writers and reads /proc"
)

STAMP = {"tool": "test"}
CELLS = 24


def _keys(n: int = CELLS) -> list[EpisodeKey]:
    return [EpisodeKey("p", "s", "o", seed, "m") for seed in range(n)]


def _names(keys: list[EpisodeKey]) -> dict[EpisodeKey, tuple[str, str]]:
    return {k: ("p", "s") for k in keys}


def _new_store(path: Path) -> None:
    with Store(path) as store:
        store.register({"p": ("ppc", {})}, {"s": {}}, {"o": {}})


def _writer(path: str, chunk: int, results: Any) -> None:
    """A run claiming ``chunk`` cells at a time and writing each (as run_grid does), until every
    cell is finished; reports the seeds it wrote."""
    keys = _keys()
    wrote: list[int] = []
    with Store(path, timeout=60) as store:
        run = store.begin_run("writer", STAMP)
        todo = list(keys)
        while todo:
            claim = store.claim(todo[:chunk], run, _names(keys))
            for key in claim.mine:
                if store.record(key, run, "done", metrics={"run": run}, names=("p", "s")):
                    wrote.append(key.seed)
            todo = todo[chunk:] + list(claim.busy)  # held by another live writer: later
            if not claim.mine:
                time.sleep(0.01)
        store.finish_run(run, "finished")
    results.put((run, wrote))


@pytest.mark.parametrize("writers, chunk", [(4, 3), (3, 1)])
def test_concurrent_writers_write_every_cell_exactly_once(
    tmp_path: Path, writers: int, chunk: int
) -> None:
    path = tmp_path / "s.sqlite"
    _new_store(path)
    ctx = multiprocessing.get_context("fork")
    results = ctx.Queue()
    procs = [ctx.Process(target=_writer, args=(str(path), chunk, results)) for _ in range(writers)]
    for p in procs:
        p.start()
    reports = [results.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    written = sorted(seed for _, wrote in reports for seed in wrote)
    assert written == list(range(CELLS))  # each cell written by exactly one writer
    with Store(path) as store:
        rows = store.episodes()
        assert sorted(k.seed for k in rows) == list(range(CELLS))
        assert {r.status for r in rows.values()} == {"done"}
        by_run = {run: set(wrote) for run, wrote in reports}
        for rec in rows.values():  # the row is the one its writer wrote
            assert rec.metrics == {"run": rec.run_id} and rec.key.seed in by_run[rec.run_id]
        assert {r["state"] for r in store.runs()} == {"finished"}


def _claim_then_die(path: str, n: int, ready: Any) -> None:
    """A writer killed (SIGKILL) while it holds claims on ``n`` cells and has finished one."""
    keys = _keys(n)
    with Store(path) as store:
        run = store.begin_run("killed", STAMP)
        store.claim(keys, run, _names(keys))
        store.record(keys[0], run, "done", metrics={"run": run}, names=("p", "s"))
        ready.send(run)  # a pipe: sent before the kill (a Queue's feeder thread might not be)
        os.kill(os.getpid(), signal.SIGKILL)


def _die_in_transaction(path: str, n: int, ready: Any) -> None:
    """A writer killed in the middle of a write transaction (rows inserted, not committed)."""
    keys = _keys(n)
    with Store(path) as store:
        run = store.begin_run("killed", STAMP)
        ready.send(run)
        with store.transaction() as db:
            for key in keys:
                db.execute(
                    "INSERT INTO episodes (policy, scenario, overrides, seed, measure, status, "
                    "run_id, policy_name, scenario_name, updated) "
                    "VALUES (?, ?, ?, ?, ?, 'done', ?, 'p', 's', 0)",
                    (*key, run),
                )
            os.kill(os.getpid(), signal.SIGKILL)


def _run_killed(target: Any, path: Path, n: int) -> int:
    ctx = multiprocessing.get_context("fork")
    receiver, sender = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=target, args=(str(path), n, sender))
    proc.start()
    assert receiver.poll(120), "the writer never started"
    run: int = receiver.recv()
    proc.join(timeout=60)
    assert proc.exitcode == -signal.SIGKILL
    return run


def test_a_killed_writers_claims_are_recovered(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    _new_store(path)
    killed = _run_killed(_claim_then_die, path, 10)
    keys = _keys(10)
    with Store(path) as store:
        assert {r["run_id"]: r["state"] for r in store.runs()} == {killed: "killed"}
        run = store.begin_run("next", STAMP)
        claim = store.claim(keys, run, _names(keys))
        # its finished cell is kept, the nine it held are taken over at once (no waiting)
        assert claim.finished == (keys[0],) and claim.mine == tuple(keys[1:]) and not claim.busy
        assert store.episodes([keys[0]])[keys[0]].run_id == killed


def test_a_writer_killed_mid_transaction_leaves_nothing_half_written(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    _new_store(path)
    killed = _run_killed(_die_in_transaction, path, 10)
    with Store(path, timeout=5) as store:
        assert store.episodes() == {}  # the transaction never committed
        run = store.begin_run("next", STAMP)  # and the write lock died with the writer
        keys = _keys(10)
        assert store.claim(keys, run, _names(keys)).mine == tuple(keys)
        assert {r["run_id"]: r["state"] for r in store.runs()}[killed] == "killed"
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    db.close()
