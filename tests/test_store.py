"""The evaluation store (experiments.store) and the grid runner (experiments.grid) in-process:
claims, finished rows kept, failed rows retried, dead owners taken over, schema checks,
fingerprints, a failing cell recorded while the rest are kept."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.grid import Cell, resolve_cells, run_grid
from experiments.policies import REGISTRY, PolicyKind, PolicySpec
from experiments.report import seed_ranges, wilson, write_csv
from experiments.store import SCHEMA_VERSION, EpisodeKey, Store, StoreError

STAMP = {"tool": "test"}


def _key(seed: int = 0, policy: str = "p") -> EpisodeKey:
    return EpisodeKey(policy, "s", "o", seed, "m")


def _registered(store: Store) -> None:
    store.register({"p": ("ppc", {}), "q": ("ppc", {})}, {"s": {}}, {"o": {}})


def test_claim_record_and_finished_rows_are_kept(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    _registered(store)
    run = store.begin_run("t", STAMP)
    names = {_key(k): ("p", "s") for k in range(3)}
    claim = store.claim(list(names), run, names)
    assert claim.mine == tuple(names) and not claim.finished and not claim.busy
    assert store.record(_key(0), run, "done", metrics={"x": 1.5}, names=("p", "s"))
    assert store.record(_key(1), run, "failed", error="boom", names=("p", "s"))
    assert store.record(_key(2), run, "refused", error="no funnel", names=("p", "s"))
    # A finished row is never overwritten (a second evaluator's copy of the episode).
    other = store.begin_run("t", STAMP)
    assert not store.record(_key(0), other, "done", metrics={"x": 9.0}, names=("p", "s"))
    rows = store.episodes()
    assert rows[_key(0)].metrics == {"x": 1.5} and rows[_key(0)].run_id == run
    # The next claim: done and refused are finished, failed is claimed again.
    claim = store.claim(list(names), other, names)
    assert claim.mine == (_key(1),) and set(claim.finished) == {_key(0), _key(2)}
    with pytest.raises(ValueError, match="status"):
        store.record(_key(1), other, "running")


def test_live_claims_are_busy_dead_ones_taken_over(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    store = Store(path)
    _registered(store)
    names = {_key(0): ("p", "s")}
    # A live owner: a run of this process still running.
    mine = store.begin_run("t", STAMP)
    assert store.claim([_key(0)], mine, names).mine == (_key(0),)
    other = store.begin_run("t", STAMP)
    assert store.claim([_key(0)], other, names).busy == (_key(0),)
    # An owner whose process is gone: its claim is taken over.
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                          capture_output=True, text=True)  # fmt: skip
    dead_pid = int(proc.stdout)
    with sqlite3.connect(path) as db:
        db.execute("UPDATE runs SET pid = ? WHERE run_id = ?", (dead_pid, mine))
    assert store.claim([_key(0)], other, names).mine == (_key(0),)
    # finish_run releases the unfinished claims of a run.
    store.finish_run(other, "interrupted")
    assert _key(0) not in store.episodes()


def test_schema_version_and_not_a_store(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    Store(path).close()
    with sqlite3.connect(path) as db:
        db.execute("UPDATE meta SET value = '999' WHERE key = 'schema_version'")
    with pytest.raises(
        StoreError, match=f"schema version 999, this code reads version {SCHEMA_VERSION}"
    ):
        Store(path)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError, match="not an evaluation store"):
        Store(junk)
    with pytest.raises(StoreError, match="not a file"):
        Store(tmp_path)


def test_fingerprints_follow_content_not_names(tmp_path: Path) -> None:
    """./x.yaml and x.yaml are one scenario; an edited file another; the same seed twice is
    one cell; the scenario's fingerprint covers the overrides."""
    import yaml

    from platoon_env.scenarios.loader import load_config
    from platoon_env.scenarios.schema import config_to_mapping

    text = yaml.safe_dump(config_to_mapping(load_config("study_c")))
    (tmp_path / "x.yaml").write_text(text)
    ppc = PolicySpec.of("ppc")
    cells = [
        Cell.of(ppc, str(tmp_path / "x.yaml"), 0),
        Cell.of(ppc, str(tmp_path / "." / "x.yaml"), 0),
        Cell.of(ppc, "study_c", 0),
        Cell.of(ppc, "study_c", 0),
    ]
    resolved = resolve_cells(cells)
    assert len(resolved) == 1  # all four are the same episode
    (tmp_path / "x.yaml").write_text(text.replace("speed: 0.25", "speed: 0.3"))
    edited = resolve_cells([Cell.of(ppc, str(tmp_path / "x.yaml"), 0)])[0]
    assert edited.key.scenario != resolved[0].key.scenario
    period = resolve_cells([Cell.of(ppc, "study_c", 0, {"control_period": 0.02})])[0]
    assert period.key.scenario != resolved[0].key.scenario
    assert period.key.overrides != resolved[0].key.overrides
    # Policies: the parameters are part of the fingerprint; the display name is not.
    assert PolicySpec.of("ppc", "A").fingerprint() == PolicySpec.of("ppc", "B").fingerprint()
    assert PolicySpec.of("ppc").fingerprint() != PolicySpec.of("ppc", k_d=2.0).fingerprint()


def test_model_fingerprint_is_the_file(tmp_path: Path) -> None:
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "model.json").write_text(json.dumps({"control_period": 0.05}))
    (tmp_path / "a" / "model.zip").write_bytes(b"model one")
    (tmp_path / "b" / "model.zip").write_bytes(b"model one")
    a, b = PolicySpec.model(tmp_path / "a"), PolicySpec.model(tmp_path / "b", name="a")
    assert a.fingerprint() == b.fingerprint()  # the same files elsewhere
    (tmp_path / "b" / "model.zip").write_bytes(b"model two")
    assert PolicySpec.model(tmp_path / "b", name="a").fingerprint() != a.fingerprint()
    assert a.env_overrides() == {"control_period": 0.05}
    with pytest.raises(ValueError, match="no model file"):
        PolicySpec.model(tmp_path / "c")


class _FailingOnSeed1:
    """A policy whose episode raises on seed 1 (a bug in one cell of a grid)."""

    def __init__(self, env: object) -> None:
        from baselines.ppc import PPCPolicy

        self._ppc = PPCPolicy(env)  # type: ignore[arg-type]
        self._seed: int | None = None

    def reset(self, seed: int | None = None) -> None:
        self._seed = seed
        self._ppc.reset(seed)

    def act(self, obs: dict) -> dict:  # type: ignore[type-arg]
        if self._seed == 1:
            raise RuntimeError("policy bug on seed 1")
        return self._ppc.act(obs)


def test_failing_cell_is_recorded_and_the_rest_kept(tmp_path: Path) -> None:
    REGISTRY["_test_failing"] = PolicyKind(f"{__name__}:_FailingOnSeed1", "test")
    try:
        bad = PolicySpec.of("_test_failing")
        cells = [
            Cell.of(p, "study_c", s, {"max_episode_steps": 50})
            for p in (bad, PolicySpec.of("ppc"))
            for s in (0, 1)
        ]
        result = run_grid(tmp_path / "s.sqlite", cells, tool="t", stamp=STAMP, progress=False)
    finally:
        del REGISTRY["_test_failing"]
    statuses = sorted((r.policy_name, r.key.seed, r.status) for r in result.records.values())
    assert statuses == [
        ("_test_failing", 0, "done"),
        ("_test_failing", 1, "failed"),
        ("ppc", 0, "done"),
        ("ppc", 1, "done"),
    ]
    (failed,) = result.failed
    assert "RuntimeError: policy bug on seed 1" in failed.error
    assert result.ran == 4 and result.reused == 0


class _Refusing:
    """A policy that declines the configuration, as the filtered PPC does when the constraints
    tightened by the declared noise leave no feasible funnel."""

    def __init__(self, env: object) -> None:
        raise ValueError("no feasible funnel")


def test_refused_configuration_is_a_result(tmp_path: Path) -> None:
    """A policy whose constructor raises ValueError gives a row with status ``refused`` (a
    result, not retried), not a crash."""
    REGISTRY["_test_refusing"] = PolicyKind(f"{__name__}:_Refusing", "test")
    try:
        cells = [Cell.of(PolicySpec.of("_test_refusing"), "study_c", 0)]
        path = tmp_path / "s.sqlite"
        result = run_grid(path, cells, tool="t", stamp=STAMP, progress=False)
        (rec,) = result.records.values()
        assert rec.status == "refused" and "ValueError: no feasible funnel" in rec.error
        again = run_grid(path, cells, tool="t", stamp=STAMP, progress=False)
        assert again.ran == 0 and again.reused == 1
    finally:
        del REGISTRY["_test_refusing"]


def test_report_helpers(tmp_path: Path) -> None:
    assert seed_ranges([4, 0, 1, 2, 7, 9, 10]) == "0..2, 4, 7, 9..10"
    assert seed_ranges([]) == "none"
    lo, hi = wilson(5, 5)
    assert hi == 1.0 and 0.5 < lo < 0.6
    with pytest.raises(ValueError):
        wilson(6, 5)
    path = tmp_path / "x.csv"
    assert write_csv(path, ("a", "b"), [{"a": float("inf"), "b": None}, {"a": 0.1234567}]) == 2
    assert path.read_text().splitlines() == ["a,b", "inf,", "0.123457,"]
    assert not list(tmp_path.glob(".*.tmp"))


class _DiesOnSeed1:
    """A policy whose worker process dies (``os._exit``) on seed 1: a segfault, the OOM killer."""

    def __init__(self, env: object) -> None:
        self._seed: int | None = None

    def reset(self, seed: int | None = None) -> None:
        import os

        if seed == 1:
            os._exit(3)

    def act(self, obs: dict) -> dict:  # type: ignore[type-arg]
        import numpy as np

        return {a: np.zeros(2, dtype=np.float32) for a in obs}


@pytest.mark.slow  # two pools of spawned workers, each importing the package (minutes on 2 cores)
def test_a_dead_worker_is_recorded_and_the_pool_replaced(tmp_path: Path) -> None:
    """Spawned workers build a policy registered at run time (the spec carries its factory);
    a worker that dies fails its cell (and any cell in flight with it), a fresh pool runs the
    rest."""
    REGISTRY["_test_dies"] = PolicyKind(f"{__name__}:_DiesOnSeed1", "test")
    try:
        spec = PolicySpec.of("_test_dies")
        cells = [Cell.of(spec, "study_c", s, {"max_episode_steps": 20}) for s in range(6)]
        result = run_grid(tmp_path / "s.sqlite", cells, tool="t", stamp=STAMP, workers=2,
                          progress=False)  # fmt: skip
    finally:
        del REGISTRY["_test_dies"]
    status = {r.key.seed: r.status for r in result.records.values()}
    assert len(status) == 6 and status[1] == "failed"
    assert "worker died" in next(r.error for r in result.records.values() if r.key.seed == 1)
    # at most the cells in flight with it (2 workers) failed; the later ones ran
    assert sum(s == "done" for s in status.values()) >= 4 - 1
    assert status[5] == "done"
