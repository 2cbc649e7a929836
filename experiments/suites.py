"""Named benchmark suites: which scenarios, under which conditions, for how many seeds.

A suite is what a results table is "on": a list of scenarios, a list of **conditions** (a
label and the ``make()`` overrides that realise it: ideal sensing, the ``aruco`` profile, one
level of one realism axis) and a default number of seeds. ``platoon-evaluate --suite NAME``
runs every policy on every scenario × condition × seed, through the evaluation store.

* ``paper`` — the paper's studies A, B and C, ideal and with the ``aruco`` profile, 20 seeds.
* ``heldout`` — the held-out procedural layouts of every difficulty tier
  (``procedural_easy_test``, ``procedural_medium_test``, ``procedural_hard_test``: layout seeds
  disjoint from every training split and from each other), ideal and ``aruco``, 200 seeds per
  tier (200 layouts each: seed ``s`` of an episode draws its layout number).
* ``robustness`` — the studies under each level of each realism axis of the robustness
  frontier (:data:`experiments.axes.AXES`, one axis at a time), 10 seeds.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from experiments.axes import AXES, level_key
from platoon_env.scenarios.schema import GENERATOR_TIERS

__all__ = ["HELDOUT", "LEADERBOARD_SUITES", "STUDIES", "SUITES", "Condition", "Suite", "suite"]


@dataclass(frozen=True)
class Condition:
    """A label and the ``make()`` overrides of one condition (e.g. ``aruco``)."""

    label: str
    overrides: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Suite:
    """A named suite: ``scenarios`` × ``conditions`` × ``seeds`` seeds (from 0)."""

    name: str
    description: str
    scenarios: tuple[str, ...]
    conditions: tuple[Condition, ...]
    seeds: int


IDEAL = Condition("ideal")
ARUCO = Condition("aruco", {"sensor_profile": "aruco"})
#: The paper's three studies (``study_a``, ``study_b``, ``study_c``): every driver reads this.
STUDIES: tuple[str, ...] = ("study_a", "study_b", "study_c")
#: The test split of every procedural difficulty tier, easiest first.
HELDOUT = tuple(f"procedural_{tier}_test" for tier in GENERATOR_TIERS)


def _robustness_conditions() -> tuple[Condition, ...]:
    out: list[Condition] = [IDEAL]
    for name, axis in AXES.items():
        for level in axis.levels:
            overrides = axis.overrides(level)
            if overrides:  # the ideal level of every axis is IDEAL
                out.append(Condition(f"{name}={level_key(level)}", overrides))
    return tuple(out)


def suite(name: str) -> Suite:
    """The suite called ``name`` (a ``KeyError`` listing the names if there is none)."""
    if name == "paper":
        return Suite(
            "paper",
            "the paper's studies A, B, C; ideal sensing and the aruco profile",
            STUDIES,
            (IDEAL, ARUCO),
            20,
        )
    if name == "heldout":
        return Suite(
            "heldout",
            "held-out procedural layouts of each difficulty tier (easy, medium, hard test "
            "splits); ideal and aruco",
            HELDOUT,
            (IDEAL, ARUCO),
            200,
        )
    if name == "robustness":
        return Suite(
            "robustness",
            "the studies under each level of each realism axis of the robustness frontier",
            STUDIES,
            _robustness_conditions(),
            10,
        )
    raise KeyError(f"no suite {name!r}; the suites are {', '.join(SUITES)}")


#: The suite names (built on demand by :func:`suite`).
SUITES: tuple[str, ...] = ("paper", "heldout", "robustness")
#: The suites of the leaderboard (:mod:`experiments.studies.leaderboard`), in its column order.
LEADERBOARD_SUITES: tuple[str, ...] = ("paper", "heldout")
