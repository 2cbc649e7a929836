"""The console commands' entry points: each checks the optional extras its tool needs before
importing the tool, so that a plain ``pip install platoon-env`` answers a command it cannot run
with one line naming the extra (exit code 2), not a ``ModuleNotFoundError`` traceback from the
tool's imports.

* ``platoon-evaluate`` needs no extra for the analytic laws (it checks ``[train]`` itself when a
  model is evaluated, and runs without plots when ``[plot]`` is missing);
* ``platoon-train`` needs ``[train]``;
* ``platoon-leaderboard`` needs ``[train]`` (the shipped models), ``[stats]`` (its aggregates)
  and ``[plot]`` (its figures and the learning curves);
* ``platoon-sweep`` needs ``[train]`` for everything but ``--list`` and ``--help``, and
  ``[plot]`` for ``--curves``; it checks those itself when it starts work, so its ``--help`` and
  ``--list`` work on a plain install.

``python -m <module>`` runs a tool without these checks.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

from platoon_env.extras import MissingExtraError, require_extra

__all__ = ["evaluate", "leaderboard", "sweep", "train"]


def _launch(command: str, target: str, extras: tuple[str, ...], purpose: str) -> int:
    """Check ``extras`` (a one-line error and exit code 2 for a missing one), then run
    ``target`` (``module:function``, called with no arguments: it reads ``sys.argv``)."""
    for extra in extras:
        try:
            require_extra(extra, purpose=purpose)
        except MissingExtraError as exc:
            print(f"{command}: error: {exc}", file=sys.stderr)
            return 2
    module, function = target.split(":")
    main: Callable[[], int] = getattr(importlib.import_module(module), function)
    return main()


def evaluate() -> int:
    """``platoon-evaluate`` (:mod:`experiments.studies.evaluate`)."""
    return _launch("platoon-evaluate", "experiments.studies.evaluate:main", (), "")


def train() -> int:
    """``platoon-train`` (:mod:`training.train`)."""
    return _launch("platoon-train", "training.train:main", ("train",), "platoon-train")


def leaderboard() -> int:
    """``platoon-leaderboard`` (:mod:`experiments.studies.leaderboard`)."""
    return _launch(
        "platoon-leaderboard",
        "experiments.studies.leaderboard:main",
        ("train", "stats", "plot"),
        "platoon-leaderboard",
    )


def sweep() -> int:
    """``platoon-sweep`` (:mod:`experiments.studies.sweep`)."""
    return _launch("platoon-sweep", "experiments.studies.sweep:main", (), "")
