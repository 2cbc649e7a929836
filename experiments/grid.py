"""The grid runner: policies × scenarios × seeds × overrides, on the evaluation store.

Every experiment of the project (the drivers of :mod:`experiments.studies`: ``platoon-evaluate``,
the comparison, the paper figures, the frontiers, ...) describes what it wants as a list of
:class:`Cell` and hands it to :func:`run_grid`, which

1. resolves each cell in this process: the scenario's config with the policy's and the cell's
   overrides, and the fingerprints that key it in the :class:`~experiments.store.Store`
   (identical cells — the same key — run once);
2. claims the unfinished cells (others may be running in another evaluator), runs them in
   ``workers`` spawned processes, and writes each outcome in its own transaction as it
   arrives (a failing cell is recorded as ``failed`` with its traceback, and the rest go on);
   with ``batch`` > 1, the claimed episodes of one policy on one task (differing in seed) run
   as chunks of up to ``batch`` copies of one batched core, a chunk per job
   (:mod:`experiments.batched_eval`; the same metrics, to the bit);
3. waits for the cells another live run holds, and takes over those of a run that died; a
   wait with no progress is bounded (``claim_timeout``): then a
   :class:`~experiments.store.ClaimTimeout` names the holders and how to release them;
4. returns every cell's record, and the episodes it was asked to keep (for figures).

Workers exit when their parent does, however it ends (``SIGKILL`` included): on Linux through
``PR_SET_PDEATHSIG``, elsewhere through a thread that watches the parent's pid. Ctrl-C or
``SIGTERM`` of the parent cancels the pending cells, terminates the workers and releases the
claims; finished cells stay in the store, and the next run resumes.
"""

from __future__ import annotations

import ctypes
import importlib
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from experiments.policies import PolicySpec, build_policy
from experiments.store import FINISHED, ClaimTimeout, EpisodeKey, EpisodeRecord, Store
from platoon_env.scenarios.fingerprint import (
    canonical_json,
    config_fingerprint,
    config_mapping,
    text_sha256,
)

__all__ = [
    "DEFAULT_CLAIM_TIMEOUT",
    "DEFAULT_MEASURE",
    "Cell",
    "CellResult",
    "GridResult",
    "ResolvedCell",
    "merge_overrides",
    "resolve_cells",
    "run_cell",
    "run_grid",
    "store_file",
    "store_path",
]

#: The measure of a cell unless it names another: ``platoon_env.rollout.episode_metrics``.
DEFAULT_MEASURE = "platoon_env.rollout:episode_metrics"
#: How often a broken worker pool (a worker killed, out of memory) is replaced before the
#: remaining cells are recorded as failed.
MAX_POOL_RESTARTS = 3
#: How long [s] a run waits for cells another run holds while none of them finishes, before a
#: :class:`~experiments.store.ClaimTimeout`: far longer than one episode of this benchmark, so
#: a live evaluator's cells are waited for, and a claim of a stopped process or of a run on
#: another host (a copied store) ends the wait with the holder's name instead of a hang.
DEFAULT_CLAIM_TIMEOUT = 600.0
#: Options of ``make()`` that do not change an episode (left out of the fingerprints).
_PRESENTATION_OPTIONS = frozenset({"render_mode", "diagnostics"})


@dataclass(frozen=True)
class Cell:
    """One episode to run: ``policy`` on ``scenario`` (a shipped name or a YAML path) with
    ``overrides`` (JSON of ``platoon_env.make`` keyword arguments), from ``reset(seed)``,
    turned into metrics by ``measure`` (``"module:function"``, called with the
    :class:`~platoon_env.rollout.Episode`); ``record_signals`` keeps the policy's internal
    signals for the measure."""

    policy: PolicySpec
    scenario: str
    seed: int
    overrides: str = "{}"
    measure: str = DEFAULT_MEASURE
    record_signals: bool = False

    @classmethod
    def of(
        cls,
        policy: PolicySpec,
        scenario: str,
        seed: int,
        overrides: Mapping[str, Any] | None = None,
        **options: Any,
    ) -> Cell:
        """A cell with ``overrides`` given as a mapping."""
        return cls(policy, scenario, int(seed), canonical_json(dict(overrides or {})), **options)

    def make_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of ``platoon_env.make`` for this cell: the policy's own
        (:meth:`PolicySpec.env_overrides`: a model's control period and observation) and the
        cell's overrides. An override that contradicts the policy's is a ``ValueError`` naming
        both (a model evaluated at another control period than it was trained at would be
        another policy, stored under its fingerprint)."""
        return merge_overrides(self.policy, json.loads(self.overrides))


def merge_overrides(policy: PolicySpec, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``policy.env_overrides()`` with ``overrides`` added; a key both set to different values
    is a ``ValueError`` naming the policy, the key and both values."""
    own = policy.env_overrides()
    for key in sorted(set(own) & set(overrides)):
        if canonical_json(own[key]) != canonical_json(overrides[key]):
            raise ValueError(
                f"{key}={json.dumps(overrides[key])} contradicts policy {policy.name!r}, which "
                f"runs at {key}={json.dumps(own[key])} (what it was trained with, its "
                "model.json): leave the option out, or evaluate such models separately"
            )
    return {**own, **overrides}


@dataclass(frozen=True)
class ResolvedCell:
    """A cell with its key in the store and the resolved config behind the key."""

    cell: Cell
    key: EpisodeKey
    config: dict[str, Any] = field(repr=False)

    @property
    def names(self) -> tuple[str, str]:
        return (self.cell.policy.name, self.cell.scenario)


def _effective_overrides(cell: Cell) -> dict[str, Any]:
    return {k: v for k, v in json.loads(cell.overrides).items() if k not in _PRESENTATION_OPTIONS}


def resolve_cells(cells: Iterable[Cell], *, unique: bool = True) -> list[ResolvedCell]:
    """Resolve the cells (configs and fingerprints). With ``unique``, a cell whose key an
    earlier cell has is dropped (it would run the same episode); else there is one resolved
    cell per cell, in order. Bad scenarios and overrides raise the schema's errors
    (``ScenarioError``, ``TypeError``, ``OSError``) here, before anything runs."""
    from platoon_env.scenarios.loader import load_config
    from platoon_env.scenarios.options import apply_overrides

    configs: dict[tuple[str, str], tuple[str, dict[str, Any]]] = {}
    out: list[ResolvedCell] = []
    seen: set[EpisodeKey] = set()
    for cell in cells:
        kwargs = {k: v for k, v in cell.make_kwargs().items() if k not in _PRESENTATION_OPTIONS}
        cache_key = (cell.scenario, canonical_json(kwargs))
        if cache_key not in configs:
            cfg = apply_overrides(load_config(cell.scenario), kwargs, where="make()")
            configs[cache_key] = (config_fingerprint(cfg), config_mapping(cfg))
        scenario_fp, mapping = configs[cache_key]
        key = EpisodeKey(
            cell.policy.fingerprint(),
            scenario_fp,
            text_sha256(canonical_json(_effective_overrides(cell))),
            cell.seed,
            cell.measure,
        )
        if unique and key in seen:
            continue
        seen.add(key)
        out.append(ResolvedCell(cell, key, mapping))
    return out


# ----------------------------------------------------------------------------------------------
# One cell, in a worker
# ----------------------------------------------------------------------------------------------


@dataclass
class CellResult:
    """What a worker returns: the status (``done``, ``failed``, ``refused``), the metrics, the
    error text, the wall time [s] and, if asked, the recorded episode."""

    status: str
    metrics: dict[str, Any]
    error: str
    wall_time: float
    episode: Any = None


def measure_of(dotted: str) -> Callable[..., Any]:
    """The function a cell's ``measure`` names (``"module:function"``)."""
    module, _, attr = dotted.partition(":")
    fn: Callable[..., Any] = getattr(importlib.import_module(module), attr)
    return fn


def _plain(value: Any) -> Any:
    """JSON-able Python values of a metrics dict (numpy scalars and arrays converted)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    item = getattr(value, "tolist", None)
    return item() if callable(item) else value


def plain_metrics(measured: Any) -> dict[str, Any]:
    """A measure's result as the store keeps it: a dict of JSON-able Python values (numpy
    scalars and arrays converted); a value JSON cannot hold raises here, not in the store."""
    metrics: dict[str, Any] = _plain(dict(measured))
    canonical_json(metrics)
    return metrics


def check_planned_scenario(resolved: ResolvedCell, config: Any) -> None:
    """A ``RuntimeError`` unless ``config`` (the env's resolved scenario config) has the
    fingerprint the cell was planned (and is keyed) with."""
    actual = config_fingerprint(config)
    if actual != resolved.key.scenario:
        raise RuntimeError(
            f"the env's resolved scenario ({actual[:12]}) is not the planned one "
            f"({resolved.key.scenario[:12]}): did {resolved.cell.scenario!r} change on disk?"
        )


def run_cell(resolved: ResolvedCell, keep: bool = False) -> CellResult:
    """Run one cell (in any process); never raises for the cell's own errors.

    A policy whose constructor raises ``ValueError`` has *refused* the configuration (a
    result); any other exception is a *failure* (retried by the next run).
    """
    import platoon_env
    from platoon_env.rollout import run_episode

    cell = resolved.cell
    start = time.perf_counter()
    try:
        if cell.policy.kind == "model":
            import torch

            torch.set_num_threads(1)
        env = platoon_env.make(cell.scenario, **cell.make_kwargs())
        check_planned_scenario(resolved, env.source.config)
        try:
            # the model's files are checked against the fingerprint the row is keyed by
            policy = build_policy(cell.policy, env, planned=resolved.key.policy)
        except ValueError as exc:
            return CellResult(
                "refused", {}, f"{type(exc).__name__}: {exc}", time.perf_counter() - start
            )
        ep = run_episode(env, policy, seed=cell.seed, record_signals=cell.record_signals or keep)
        metrics = plain_metrics(measure_of(cell.measure)(ep))
    except Exception:
        return CellResult("failed", {}, traceback.format_exc(limit=20), time.perf_counter() - start)
    return CellResult("done", metrics, "", time.perf_counter() - start, ep if keep else None)


# ----------------------------------------------------------------------------------------------
# Workers that die with their parent
# ----------------------------------------------------------------------------------------------

_PR_SET_PDEATHSIG = 1


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(0.5)
        if os.getppid() != parent:  # re-parented: the parent is gone
            os._exit(1)


def _init_worker(parent: int) -> None:
    """In each worker: leave Ctrl-C to the parent, and exit as soon as the parent is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


# ----------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------


@dataclass
class GridResult:
    """The outcome of :func:`run_grid`: a record per resolved cell (in the cells' order),
    the kept episodes by key, how many cells this run ran and found finished, and whether it
    was interrupted."""

    cells: list[ResolvedCell]
    records: dict[EpisodeKey, EpisodeRecord]
    episodes: dict[EpisodeKey, Any]
    ran: int
    reused: int
    run_id: int
    wall_time: float
    interrupted: bool = False

    @property
    def failed(self) -> list[EpisodeRecord]:
        """The cells whose episode raised (their tracebacks are in ``error``)."""
        return [r for r in self.records.values() if r.status == "failed"]

    def finished(self) -> list[tuple[ResolvedCell, EpisodeRecord]]:
        """(cell, record) of every cell with a result (``done`` or ``refused``)."""
        out = []
        for rc in self.cells:
            rec = self.records.get(rc.key)
            if rec is not None and rec.status in FINISHED:
                out.append((rc, rec))
        return out


def run_grid(
    store: Store | str | Path,
    cells: Sequence[Cell] | Sequence[ResolvedCell],
    *,
    tool: str,
    stamp: Mapping[str, Any],
    workers: int = 1,
    keep: Callable[[Cell], bool] | None = None,
    progress: bool = True,
    poll: float = 1.0,
    claim_timeout: float = DEFAULT_CLAIM_TIMEOUT,
    batch: int = 0,
) -> GridResult:
    """Run every unfinished cell of ``cells`` into ``store``; see the module docstring.

    ``keep(cell)`` says which episodes to return (they are run again if the store already
    has them, since episodes are not stored). ``stamp`` (:func:`experiments.stamp.metadata_stamp`)
    is recorded with the run. ``workers <= 1`` runs in this process. Cells held by another
    live run are waited for, polling every ``poll`` s, until ``claim_timeout`` s pass without
    one of them finishing: then :class:`~experiments.store.ClaimTimeout` (after every other
    cell is done and stored), naming the holders and how to release their claims.

    ``batch`` > 1 runs the claimed cells that can share a batched core (one policy, scenario,
    overrides and measure, differing in seed; :func:`experiments.batched_eval.chunk_cells`)
    as chunks of at most ``batch`` episodes, a chunk one job
    (:func:`experiments.batched_eval.run_cells`: the same metrics as :func:`run_cell`, to the
    bit); each cell's result is still stored in its own transaction. 0 or 1: a job per cell.
    """
    from experiments.batched_eval import chunk_cells, run_cells

    own = not isinstance(store, Store)
    db = Store(store) if not isinstance(store, Store) else store
    resolved: list[ResolvedCell] = [c for c in cells if isinstance(c, ResolvedCell)]
    if len(resolved) != len(cells):
        resolved = resolve_cells(c for c in cells if isinstance(c, Cell))
    first: dict[EpisodeKey, ResolvedCell] = {}
    for rc in resolved:  # a key runs once, under the first cell naming it (as resolve_cells)
        first.setdefault(rc.key, rc)
    resolved = list(first.values())
    keep = keep or (lambda cell: False)
    start = time.perf_counter()
    run_id = db.begin_run(tool, stamp)
    by_key = {rc.key: rc for rc in resolved}
    names = {rc.key: rc.names for rc in resolved}
    db.register(
        {rc.key.policy: (rc.cell.policy.kind, rc.cell.policy.description()) for rc in resolved},
        {rc.key.scenario: rc.config for rc in resolved},
        {rc.key.overrides: _effective_overrides(rc.cell) for rc in resolved},
    )
    kept: dict[EpisodeKey, Any] = {}
    ran = 0
    reused = 0
    interrupted = False
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    bar = tqdm(
        total=len(resolved),
        desc="episodes",
        unit="ep",
        disable=not progress,
        mininterval=0.5 if sys.stderr.isatty() else 30.0,
    )
    pool: ProcessPoolExecutor | None = None
    restarts = 0
    # a job: one cell (run_cell) or a chunk of cells sharing a batched core (run_cells)
    pending: dict[Future[Any], list[ResolvedCell]] = {}
    try:
        queue = [rc.key for rc in resolved]
        busy: list[EpisodeKey] = []
        waiting_since: float | None = None  # since when busy cells made no progress
        # Claim a few jobs' cells at a time, so that evaluators sharing the store share the work.
        capacity = max(1, workers)
        per_job = max(1, batch)
        while queue or pending or busy:
            while queue and len(pending) < capacity:
                take = (capacity - len(pending)) * per_job
                chunk, queue = queue[:take], queue[take:]
                claim = db.claim(chunk, run_id, names)
                if claim.mine or claim.finished:
                    waiting_since = None
                reused += len(claim.finished)
                bar.update(len(claim.finished))
                busy.extend(claim.busy)
                mine = [by_key[key] for key in claim.mine]
                jobs = chunk_cells(mine, per_job, keep) if per_job > 1 else [[rc] for rc in mine]
                for job in jobs:
                    if workers <= 1:
                        if len(job) == 1:
                            results = [run_cell(job[0], keep(job[0].cell))]
                        else:
                            results = run_cells(job)
                        for rc, result in zip(job, results, strict=True):
                            _store_result(db, run_id, rc, result, kept)
                            ran += 1
                            bar.update()
                        continue
                    if pool is not None and getattr(pool, "_broken", False):
                        # a worker died (killed, out of memory): its cells were recorded as
                        # failed; a fresh pool runs the rest
                        _stop_pool(pool, wait_for_workers=False)
                        pool = None
                        restarts += 1
                    if pool is None:
                        if restarts > MAX_POOL_RESTARTS:
                            for rc in job:
                                result = CellResult(
                                    "failed", {}, f"worker pool broke {restarts} times", 0.0
                                )
                                _store_result(db, run_id, rc, result, kept)
                                bar.update()
                            continue
                        pool = ProcessPoolExecutor(
                            max_workers=workers,
                            mp_context=multiprocessing.get_context("spawn"),
                            initializer=_init_worker,
                            initargs=(os.getpid(),),
                        )
                    if len(job) == 1:
                        pending[pool.submit(run_cell, job[0], keep(job[0].cell))] = job
                    else:
                        pending[pool.submit(run_cells, job)] = job
            if pending:
                done, _ = wait(pending, timeout=poll, return_when=FIRST_COMPLETED)
                for fut in done:
                    job = pending.pop(fut)
                    try:
                        outcome = fut.result()
                        results = outcome if isinstance(outcome, list) else [outcome]
                    except Exception as exc:  # the worker died (a broken pool)
                        results = [
                            CellResult(
                                "failed", {}, f"worker died: {type(exc).__name__}: {exc}", 0.0
                            )
                            for _ in job
                        ]
                    for rc, result in zip(job, results, strict=True):
                        _store_result(db, run_id, rc, result, kept)
                        ran += 1
                        bar.update()
            elif busy and not queue:
                now = time.monotonic()
                waiting_since = now if waiting_since is None else waiting_since
                if now - waiting_since >= claim_timeout:
                    raise ClaimTimeout(db.holders_message(busy, now - waiting_since))
                bar.set_postfix_str(f"waiting for {len(busy)} held by another run")
                time.sleep(poll)
                queue, busy = busy, []
        status = "finished"
    except KeyboardInterrupt:
        interrupted = True
        status = "interrupted"
    except BaseException:
        status = "failed"
        raise
    finally:
        bar.close()
        if pool is not None:
            _stop_pool(pool, wait_for_workers=not interrupted and status == "finished")
        signal.signal(signal.SIGTERM, previous)
        db.finish_run(run_id, status)
        records = db.episodes([rc.key for rc in resolved])
        if own:
            db.close()
    # Kept episodes of cells that were already finished: run them again (episodes are not
    # stored); an episode is a pure function of its cell.
    if not interrupted:
        missing = [rc for rc in resolved if keep(rc.cell) and rc.key not in kept]
        for rc in tqdm(missing, desc="episodes for figures", unit="ep", disable=not missing):
            result = run_cell(rc, keep=True)
            if result.episode is not None:
                kept[rc.key] = result.episode
    return GridResult(
        resolved, records, kept, ran, reused, run_id, time.perf_counter() - start, interrupted
    )


def _store_result(
    db: Store, run_id: int, rc: ResolvedCell, result: CellResult, kept: dict[EpisodeKey, Any]
) -> None:
    db.record(
        rc.key,
        run_id,
        result.status,
        metrics=result.metrics,
        error=result.error,
        wall_time=result.wall_time,
        names=rc.names,
    )
    if result.status == "failed":
        first = result.error.strip().splitlines()[-1] if result.error.strip() else "?"
        tqdm.write(
            f"episode failed: {rc.cell.policy.name} on {rc.cell.scenario} seed {rc.cell.seed}: "
            f"{first}"
        )
    if result.episode is not None:
        kept[rc.key] = result.episode


def _stop_pool(pool: ProcessPoolExecutor, wait_for_workers: bool) -> None:
    """Shut the pool down; when not waiting, terminate its workers (by pid: ``shutdown``
    forgets them)."""
    if wait_for_workers:
        pool.shutdown(wait=True)
        return
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    for proc in procs:
        proc.join(timeout=5)


#: The file name of the store in an output folder.
STORE_NAME = "results.sqlite"


def store_path(out: str | Path) -> Path:
    """The store of an output folder: ``OUT/results.sqlite``."""
    return Path(out) / STORE_NAME


def store_file(given: str | Path) -> Path:
    """The store a ``--store`` option names: an existing file, or a path ending in ``.sqlite``,
    is the store itself; anything else is a folder holding ``results.sqlite``."""
    path = Path(given)
    return path if path.is_file() or path.suffix == ".sqlite" else store_path(path)
