"""Experiments: the engine every driver (:mod:`experiments.studies`) runs on.

* :mod:`experiments.store` — :class:`Store`, one SQLite database of episodes keyed by content
  fingerprints, safe under crashes and concurrent evaluators;
* :mod:`experiments.policies` — :class:`PolicySpec` and :data:`REGISTRY`, every runnable policy
  (each driver's default list is derived from it);
* :mod:`experiments.grid` — :class:`Cell` and :func:`run_grid`, policies × scenarios × seeds ×
  overrides on the store, in worker processes that die with their parent;
* :mod:`experiments.stamp` — :func:`metadata_stamp`, the code/versions/command of a run;
* :mod:`experiments.report` — statistics and the exports (CSV, markdown provenance);
* :mod:`experiments.suites` — the named benchmark suites (``paper``, ``heldout``,
  ``robustness``) and the study list; :mod:`experiments.axes` — the realism axes;
  :mod:`experiments.stats` — rliable aggregates over seeds or episodes;
* what several drivers share: :mod:`experiments.board` and :mod:`experiments.cards` (the
  leaderboard's table and the model cards), :mod:`experiments.configs` (the sweep's
  configurations), :mod:`experiments.robustness` (the frontiers' and breaks' grid and rows),
  :mod:`experiments.tuning` (the tuners' objective).

The drivers and command-line tools (evaluate, leaderboard, sweep, paper figures, comparison,
frontiers, breaks, tuners, feasibility, discretisation) are in :mod:`experiments.studies`, a
layer above this one: nothing here imports them, and no driver imports another.
"""

from experiments.grid import Cell, GridResult, resolve_cells, run_grid
from experiments.policies import REGISTRY, PolicyKind, PolicySpec, register_policy
from experiments.stamp import metadata_stamp
from experiments.store import EpisodeKey, EpisodeRecord, Store, StoreError

__all__ = [
    "REGISTRY",
    "Cell",
    "EpisodeKey",
    "EpisodeRecord",
    "GridResult",
    "PolicyKind",
    "PolicySpec",
    "Store",
    "StoreError",
    "metadata_stamp",
    "register_policy",
    "resolve_cells",
    "run_grid",
]
