"""platoon-evaluate as separate processes: two evaluators into one store, and kill -9 of an
evaluator (its workers die with it; the re-run resumes and loses nothing else, and gives the
results of an uninterrupted run: a ``faults`` test, ``pytest -m faults``)."""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="reads /proc to find the worker processes"
)

REPO = Path(__file__).resolve().parents[1]
# Short study C episodes (PPC, 1,500 steps): a few per second once the workers are up.
GRID = ["--policy", "ppc", "--scenario", "study_c", "--set", "max_episode_steps=1500", "--no-plots"]


def _evaluate(out: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "experiments.studies.evaluate", *GRID, "--out", str(out), *extra],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )


def _counts(out: Path) -> dict[str, int]:
    path = out / "results.sqlite"
    if not path.is_file():
        return {}
    try:
        with sqlite3.connect(path, timeout=30) as db:
            rows = db.execute("SELECT status, COUNT(*) FROM episodes GROUP BY status").fetchall()
    except sqlite3.OperationalError:  # the tables are not created yet
        return {}
    return dict(rows)


def _ran(stdout: str) -> tuple[int, int]:
    """(episodes run, episodes found in the store) from an evaluator's report line."""
    match = re.search(r"(\d+) episode\(s\) run, (\d+) already in the store", stdout)
    assert match, stdout[-2000:]
    return int(match[1]), int(match[2])


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_two_evaluators_share_one_store(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    first = _evaluate(out, "--episodes", "8", "--workers", "1")
    second = _evaluate(out, "--episodes", "8", "--workers", "1")
    results = [p.communicate(timeout=600) for p in (first, second)]
    for proc, (_, stderr) in zip((first, second), results, strict=True):
        assert proc.returncode == 0, stderr[-3000:]
    ran = [_ran(stdout) for stdout, _ in results]
    # Every episode ran exactly once between them, and each is one row.
    assert sum(r for r, _ in ran) == 8, ran
    assert _counts(out) == {"done": 8}
    with sqlite3.connect(out / "results.sqlite") as db:
        seeds = sorted(s for (s,) in db.execute("SELECT seed FROM episodes"))
    assert seeds == list(range(8))
    lines = (out / "results.csv").read_text().splitlines()
    assert len(lines) == 9 and lines[0].startswith("policy,scenario,seed,status")
    assert "8 episodes summarised (seeds 0..7)" in (out / "summary.md").read_text()


def _episodes(out: Path) -> dict[tuple[Any, ...], dict[str, Any]]:
    """Every episode row of ``out``'s store: its key, status and metrics (run ids, times and
    names left out: they differ between runs of the same grid)."""
    with sqlite3.connect(out / "results.sqlite") as db:
        rows = db.execute(
            "SELECT policy, scenario, overrides, seed, measure, status, metrics FROM episodes"
        ).fetchall()
    db.close()
    return {tuple(r[:5]): {"status": r[5], "metrics": json.loads(r[6])} for r in rows}


@pytest.mark.faults
def test_kill_9_then_resume(tmp_path: Path) -> None:
    """kill -9 of an evaluator mid-run, then the same command again: its workers die with it,
    the re-run runs only the missing episodes, each episode is stored once, and the results
    are those of an uninterrupted run of the same grid."""
    uninterrupted = _evaluate(tmp_path / "uninterrupted", "--episodes", "12", "--workers", "2")
    out = tmp_path / "eval"
    proc = _evaluate(out, "--episodes", "12", "--workers", "2")
    deadline = time.monotonic() + 300
    while _counts(out).get("done", 0) < 2:
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "no episode finished in time"
        time.sleep(0.05)
    workers = _children(proc.pid)
    assert workers, "expected worker processes"
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    # The workers die with their parent (no orphans left holding memory).
    deadline = time.monotonic() + 15
    while any(_alive(w) for w in workers):
        assert time.monotonic() < deadline, f"orphaned workers: {[w for w in workers if _alive(w)]}"
        time.sleep(0.1)
    done = _counts(out).get("done", 0)
    assert 2 <= done < 12
    # The re-run takes over the dead run's claims, runs only what is missing.
    again = _evaluate(out, "--episodes", "12", "--workers", "2")
    stdout, stderr = again.communicate(timeout=600)
    assert again.returncode == 0, stderr[-3000:]
    assert _ran(stdout) == (12 - done, done)
    assert _counts(out) == {"done": 12}
    with sqlite3.connect(out / "results.sqlite") as db:
        statuses = dict(db.execute("SELECT run_id, status FROM runs").fetchall())
    assert statuses == {1: "running", 2: "finished"}  # the killed run never finished
    # ... and the summary reports it as killed, not as running
    assert "run 1 (killed: its process is gone" in (out / "summary.md").read_text()
    # The same results as the run that was never interrupted, episode by episode.
    _, stderr = uninterrupted.communicate(timeout=600)
    assert uninterrupted.returncode == 0, stderr[-3000:]
    expected = _episodes(tmp_path / "uninterrupted")
    assert len(expected) == 12 and _episodes(out) == expected
