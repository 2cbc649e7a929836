"""The drivers: every study and command-line tool, on top of the experiment engine.

Layers run one way: :mod:`platoon_env` (the env) ← :mod:`baselines` (the analytic policies) ←
:mod:`training` (learners, adapters, run planning) ← :mod:`experiments` (the engine: policy
registry, grid, store, statistics, provenance stamp, suites, realism axes) ← this package. No
module here is imported by a layer below it.

* :mod:`~experiments.studies.evaluate` — ``platoon-evaluate``: any policies on any scenarios and
  suites, the default benchmark (PPC against the shipped models);
* :mod:`~experiments.studies.leaderboard` — ``platoon-leaderboard``: every policy on the
  ``paper`` and ``heldout`` suites; :mod:`~experiments.cards` — the model cards it writes;
* :mod:`~experiments.studies.sweep` — ``platoon-sweep``: the shipped learned configurations
  trained over seeds;
* :mod:`~experiments.studies.paper_figures` — the paper's figures from PPC episodes;
  :mod:`~experiments.studies.comparison` — PPC against the last-seen baselines of ref. [32];
  :mod:`~experiments.studies.frontiers` — success against each realism axis;
  :mod:`~experiments.studies.discretisation` — the control period study;
* :mod:`~experiments.studies.launch` — the console commands' entry points, which check the
  optional extras a command needs before importing it.
"""
