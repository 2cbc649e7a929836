"""Experiments: the evaluation store, the policy registry and the grid runner every driver
shares (``platoon-evaluate``, ``baselines.comparison``, ``baselines.paper_figures``,
``baselines.frontiers``).

* :mod:`experiments.store` — :class:`Store`, one SQLite database of episodes keyed by content
  fingerprints, safe under crashes and concurrent evaluators;
* :mod:`experiments.policies` — :class:`PolicySpec` and :data:`REGISTRY`, every runnable policy;
* :mod:`experiments.grid` — :class:`Cell` and :func:`run_grid`, policies × scenarios × seeds ×
  overrides on the store, in worker processes that die with their parent;
* :mod:`experiments.stamp` — :func:`metadata_stamp`, the code/versions/command of a run;
* :mod:`experiments.report` — statistics and the exports (CSV, markdown provenance);
* :mod:`experiments.suites` — the named benchmark suites (``paper``, ``heldout``,
  ``robustness``); :mod:`experiments.stats` — rliable aggregates over seeds or episodes;
* :mod:`experiments.leaderboard` — every policy on the ``paper`` and ``heldout`` suites, the
  tables, figures and goal check; :mod:`experiments.cards` — the model cards it writes.
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
