"""The grid runner: policies × scenarios × seeds × overrides, on the evaluation store.

Every experiment of the project (the drivers of :mod:`experiments.studies`: ``platoon-evaluate``,
the comparison, the paper figures, the frontiers, ...) describes what it wants as a list of
:class:`Cell` (:mod:`experiments.cells`, re-exported here with :func:`run_cell` and
:func:`resolve_cells`) and hands it to :func:`run_grid`, which

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
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from experiments.batched_eval import chunk_cells, run_cells
from experiments.cells import (
    DEFAULT_MEASURE,
    Cell,
    CellResult,
    ResolvedCell,
    effective_overrides,
    merge_overrides,
    resolve_cells,
    run_cell,
)
from experiments.store import FINISHED, ClaimTimeout, EpisodeKey, EpisodeRecord, Store

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

#: How often a broken worker pool (a worker killed, out of memory) is replaced before the
#: remaining cells are recorded as failed.
MAX_POOL_RESTARTS = 3
#: How long [s] a run waits for cells another run holds while none of them finishes, before a
#: :class:`~experiments.store.ClaimTimeout`: far longer than one episode of this benchmark, so
#: a live evaluator's cells are waited for, and a claim of a stopped process or of a run on
#: another host (a copied store) ends the wait with the holder's name instead of a hang.
DEFAULT_CLAIM_TIMEOUT = 600.0

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

    own = not isinstance(store, Store)
    db = Store(store) if not isinstance(store, Store) else store
    resolved = _distinct(cells)
    keep = keep or (lambda cell: False)
    start = time.perf_counter()
    run_id = db.begin_run(tool, stamp)
    _register(db, resolved)
    bar = tqdm(
        total=len(resolved),
        desc="episodes",
        unit="ep",
        disable=not progress,
        mininterval=0.5 if sys.stderr.isatty() else 30.0,
    )
    jobs = _Jobs(db, run_id, resolved, keep, workers, bar)
    interrupted = False
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        queue = [rc.key for rc in resolved]
        busy: list[EpisodeKey] = []
        waiting_since: float | None = None  # since when busy cells made no progress
        # Claim a few jobs' cells at a time, so that evaluators sharing the store share the work.
        capacity = max(1, workers)
        per_job = max(1, batch)
        while queue or jobs.pending or busy:
            while queue and len(jobs.pending) < capacity:
                take = (capacity - len(jobs.pending)) * per_job
                chunk, queue = queue[:take], queue[take:]
                if jobs.claim(chunk, per_job, busy):
                    waiting_since = None
            if jobs.pending:
                jobs.collect(poll)
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
        jobs.close(wait_for_workers=not interrupted and status == "finished")
        signal.signal(signal.SIGTERM, previous)
        db.finish_run(run_id, status)
        records = db.episodes([rc.key for rc in resolved])
        if own:
            db.close()
    if not interrupted:
        _rerun_kept(resolved, keep, jobs.kept)
    return GridResult(
        resolved,
        records,
        jobs.kept,
        jobs.ran,
        jobs.reused,
        run_id,
        time.perf_counter() - start,
        interrupted,
    )


def _distinct(cells: Sequence[Cell] | Sequence[ResolvedCell]) -> list[ResolvedCell]:
    """``cells`` resolved (unless they are already), each key once: under the first cell naming
    it (as :func:`resolve_cells`)."""
    resolved: list[ResolvedCell] = [c for c in cells if isinstance(c, ResolvedCell)]
    if len(resolved) != len(cells):
        resolved = resolve_cells(c for c in cells if isinstance(c, Cell))
    first: dict[EpisodeKey, ResolvedCell] = {}
    for rc in resolved:
        first.setdefault(rc.key, rc)
    return list(first.values())


def _register(db: Store, resolved: Sequence[ResolvedCell]) -> None:
    """Record in the store what the cells' fingerprints stand for: the policies, the scenario
    configs and the overrides."""
    db.register(
        {rc.key.policy: (rc.cell.policy.kind, rc.cell.policy.description()) for rc in resolved},
        {rc.key.scenario: rc.config for rc in resolved},
        {rc.key.overrides: effective_overrides(rc.cell) for rc in resolved},
    )


def _rerun_kept(
    resolved: Sequence[ResolvedCell], keep: Callable[[Cell], bool], kept: dict[EpisodeKey, Any]
) -> None:
    """Run again the kept episodes of cells that were already finished (episodes are not
    stored); an episode is a pure function of its cell."""
    missing = [rc for rc in resolved if keep(rc.cell) and rc.key not in kept]
    for rc in tqdm(missing, desc="episodes for figures", unit="ep", disable=not missing):
        result = run_cell(rc, keep=True)
        if result.episode is not None:
            kept[rc.key] = result.episode


class _Jobs:
    """The jobs of one :func:`run_grid`: a job is one cell (:func:`run_cell`) or a chunk of
    cells sharing a batched core (:func:`run_cells`), run in this process (``workers <= 1``)
    or in a pool of spawned workers, each result stored as it arrives. A pool that breaks (a
    worker killed, out of memory) is replaced up to :data:`MAX_POOL_RESTARTS` times."""

    def __init__(
        self,
        db: Store,
        run_id: int,
        resolved: Sequence[ResolvedCell],
        keep: Callable[[Cell], bool],
        workers: int,
        bar: Any,
    ) -> None:
        self.db = db
        self.run_id = run_id
        self.by_key = {rc.key: rc for rc in resolved}
        self.names = {rc.key: rc.names for rc in resolved}
        self.keep = keep
        self.workers = workers
        self.bar = bar
        self.kept: dict[EpisodeKey, Any] = {}
        self.ran = 0
        self.reused = 0
        self.pending: dict[Future[Any], list[ResolvedCell]] = {}
        self.pool: ProcessPoolExecutor | None = None
        self.restarts = 0

    def claim(self, chunk: Sequence[EpisodeKey], per_job: int, busy: list[EpisodeKey]) -> bool:
        """Claim the cells of ``chunk`` in the store and start those this run got, as jobs of
        up to ``per_job`` cells; the cells another live run holds are added to ``busy``. Whether
        some cell was claimed or found finished (progress)."""
        claim = self.db.claim(chunk, self.run_id, self.names)
        self.reused += len(claim.finished)
        self.bar.update(len(claim.finished))
        busy.extend(claim.busy)
        mine = [self.by_key[key] for key in claim.mine]
        jobs = chunk_cells(mine, per_job, self.keep) if per_job > 1 else [[rc] for rc in mine]
        for job in jobs:
            self.start(job)
        return bool(claim.mine or claim.finished)

    def store(self, job: Sequence[ResolvedCell], results: Sequence[CellResult]) -> None:
        """Store each cell's result of a finished job."""
        for rc, result in zip(job, results, strict=True):
            _store_result(self.db, self.run_id, rc, result, self.kept)
            self.ran += 1
            self.bar.update()

    def start(self, job: list[ResolvedCell]) -> None:
        """Run ``job`` here (``workers <= 1``), or submit it to the pool."""
        if self.workers <= 1:
            if len(job) == 1:
                self.store(job, [run_cell(job[0], self.keep(job[0].cell))])
            else:
                self.store(job, run_cells(job))
            return
        pool = self._pool()
        if pool is None:
            for rc in job:
                result = CellResult("failed", {}, f"worker pool broke {self.restarts} times", 0.0)
                _store_result(self.db, self.run_id, rc, result, self.kept)
                self.bar.update()
        elif len(job) == 1:
            self.pending[pool.submit(run_cell, job[0], self.keep(job[0].cell))] = job
        else:
            self.pending[pool.submit(run_cells, job)] = job

    def _pool(self) -> ProcessPoolExecutor | None:
        """The worker pool, started or replaced if broken; None once it broke too often."""
        if self.pool is not None and getattr(self.pool, "_broken", False):
            # a worker died (killed, out of memory): its cells were recorded as failed; a fresh
            # pool runs the rest
            _stop_pool(self.pool, wait_for_workers=False)
            self.pool = None
            self.restarts += 1
        if self.pool is None:
            if self.restarts > MAX_POOL_RESTARTS:
                return None
            self.pool = ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
                initargs=(os.getpid(),),
            )
        return self.pool

    def collect(self, poll: float) -> None:
        """Store the results of the jobs that finish within ``poll`` s."""
        done, _ = wait(self.pending, timeout=poll, return_when=FIRST_COMPLETED)
        for fut in done:
            job = self.pending.pop(fut)
            try:
                outcome = fut.result()
                results = outcome if isinstance(outcome, list) else [outcome]
            except Exception as exc:  # the worker died (a broken pool)
                error = f"worker died: {type(exc).__name__}: {exc}"
                results = [CellResult("failed", {}, error, 0.0) for _ in job]
            self.store(job, results)

    def close(self, wait_for_workers: bool) -> None:
        """Shut the pool down (:func:`_stop_pool`)."""
        if self.pool is not None:
            _stop_pool(self.pool, wait_for_workers=wait_for_workers)


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
