"""What breaks whom: the ``aruco`` sensor profile taken apart, one realism axis at a time.

Usage::

    python -m experiments.studies.breaks [--out results/breaks] [--seeds 20] [--workers 2]
                                [--store PATH] [--figures DIR] [--study study_a ...]
                                [--controller ppc ...] [--profile aruco] [--quick]
                                [--max-episode-steps N]

The robustness frontiers (:mod:`experiments.studies.frontiers`) move one axis away from the
ideal sensors at a time. This driver starts from the other end, the shipped profile
(``docs/realism.md``), and asks which of its parts breaks each controller. The profile's fields
are grouped into the axes of :data:`PROFILE_AXES` (camera noise, detection, frame rate,
latency, proximity noise, the acceleration limits, the actuator lag); an axis whose profile
values equal the study's own (ideal) values is inactive and skipped with a note. For each
controller (:data:`experiments.robustness.CONTROLLERS`: the paper's PPC law, the
last-seen baseline of ref. [32], the filtered PPC) and study A, B, C, the conditions
(:func:`conditions`) are

* ``ideal``: the study as shipped (the paper's ideal sensors and drive), for reference;
* ``profile``: the whole profile (``sensor_profile="aruco"``, as the frontiers' profile level);
* ``without`` an axis: the profile with that axis' fields set back to the study's values
  (its ideal), the other axes at the profile's values;
* ``alone``: that axis at the profile's values, everything else ideal;

each for ``--seeds`` seeds. An episode **succeeds** when it ends by truncation without any
violation (every violation cause ends the episode, as in the frontiers). Every episode is one
row of the evaluation store (``OUT/results.sqlite``, or ``--store``) run by the shared grid
runner (:func:`experiments.grid.run_grid`; resumable, identical configurations run once). Its
measure (:func:`episode_row`) is the frontiers' row
(:func:`experiments.robustness.episode_row`: the first violation's cause, time and
follower, the PPC diagnostics) and **where** the failure
happened: the position ``(x, y)`` of the diagnosed follower
(:func:`experiments.robustness.diagnosed_follower`: the rear robot of a robot contact,
else the follower of the first violation) just after the violating step, and its true wall
clearances ``d_W_l``, ``d_W_r`` there. A failure's **place** (:func:`place_of`) is

* ``narrow`` (a narrow passage): walls within the PPC activation distance ``delta`` of the
  follower's disk on both sides, ``d_W_l - r < delta`` and ``d_W_r - r < delta`` (both
  activation terms ``F_l``, ``F_r`` of eq. 12 engage on the follower's own clearances);
* ``wall``: within ``delta`` of a wall on one side only;
* ``open``: on neither side.

Outputs: ``OUT/breaks.csv`` (:data:`CSV_COLUMNS`, an export of the grid's rows);
``OUT/breaks.md``: per study, a table of condition x controller -> successes/seeds [Wilson 95 %
interval], the dominant failure (the most frequent first violation cause) and how many failures
came in the first :data:`STARTUP` s; a table of where and when the profile's failures happen;
and the answer to the start-up question (:func:`startup_answer`); the figures, into ``--figures``
(default ``OUT``): ``breaks_<study>.png``, the map (the workspace's obstacles, the leader's path
and the platoon at its start) with the failure locations, a panel per controller;
``breaks_times.png``, histograms of the failure times.

``--quick`` (a smoke run): 2 seeds (unless ``--seeds`` is given).
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from experiments.axes import profile_overrides
from experiments.cli import add_grid_options, failed_episodes, new_parser
from experiments.grid import Cell, store_file, store_path
from experiments.names import by_name
from experiments.report import write_text_atomic
from experiments.robustness import (
    CONTROLLERS,
    OUTCOME_COLUMNS,
    Point,
    add_study_options,
    diagnosed_follower,
    finish_study_args,
    run_and_export,
    study_grid,
)
from experiments.robustness import episode_row as outcome_row
from experiments.stamp import png_metadata
from platoon_env.config import ScenarioConfig
from platoon_env.geometry.sensing import SENSE_D_WALL_LEFT, SENSE_D_WALL_RIGHT
from platoon_env.rollout import Episode
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.profiles import list_profiles, load_profile
from platoon_env.scenarios.scenario import build_scenario

__all__ = [
    "CONDITION_KINDS",
    "CSV_COLUMNS",
    "KEY_COLUMNS",
    "PLACES",
    "PROFILE_AXES",
    "STARTUP",
    "Condition",
    "ProfileAxis",
    "axis_values",
    "build_grid",
    "condition_overrides",
    "conditions",
    "episode_row",
    "failure_place",
    "main",
    "place_of",
    "startup_answer",
    "summarise",
]

#: A field of a scenario block: its path of keys, e.g. ``("camera", "noise", "position")``.
FieldPath = tuple[str, ...]


@dataclass(frozen=True)
class ProfileAxis:
    """One realism axis of a sensor profile: the scenario fields it sets (paths of keys into
    the ``camera``, ``proximity`` and ``robot`` blocks)."""

    name: str
    label: str
    fields: tuple[FieldPath, ...]


#: The axes a sensor profile is taken apart into; together they hold every realism field a
#: profile may set (:func:`axis_values` refuses a profile field no axis holds).
PROFILE_AXES: dict[str, ProfileAxis] = by_name(
    ProfileAxis(
        "camera_noise",
        "camera position and bearing noise",
        (
            ("camera", "noise", "position"),
            ("camera", "noise", "position_per_m"),
            ("camera", "noise", "bearing"),
        ),
    ),
    ProfileAxis(
        "detection",
        "detection probability and its loss towards the image edge",
        (("camera", "detection"), ("camera", "detection_edge")),
    ),
    ProfileAxis("frame_rate", "camera frame rate", (("camera", "frame_rate"),)),
    ProfileAxis("latency", "camera latency", (("camera", "latency"),)),
    ProfileAxis("proximity_noise", "proximity (LiDAR) noise", (("proximity", "noise"),)),
    ProfileAxis(
        "accel_limits",
        "bounds on the change of the applied u and omega",
        (("robot", "accel_max"), ("robot", "alpha_max")),
    ),
    ProfileAxis("actuator_lag", "first-order actuator lag", (("robot", "lag"),)),
)

#: The kinds of condition, in table order: the study as shipped, the whole profile, the
#: profile with one axis ideal, one axis of the profile alone.
CONDITION_KINDS: tuple[str, ...] = ("ideal", "profile", "without", "alone")

#: Columns that identify a row (one episode); ``axis`` is "" for ``ideal`` and ``profile``.
KEY_COLUMNS: tuple[str, ...] = ("controller", "study", "condition", "axis", "seed")

#: Where a failure happened (:func:`failure_place`).
PLACE_COLUMNS: tuple[str, ...] = ("fail_x", "fail_y", "fail_d_W_l", "fail_d_W_r")

#: Columns of ``breaks.csv``: the key, the frontiers' outcome columns and wall time, the place.
CSV_COLUMNS: tuple[str, ...] = (*KEY_COLUMNS, *OUTCOME_COLUMNS, "wall_time", *PLACE_COLUMNS)

#: The places of :func:`place_of`, in table order.
PLACES: tuple[str, ...] = ("open", "wall", "narrow")

#: The start-up window [s]: a failure before it is an early one.
STARTUP = 2.5

#: The share of a profile's failures in the start-up window above which the start-up
#: transient is said to dominate them.
DOMINANCE = 0.5

DEFAULT_PROFILE = "aruco"
DEFAULT_SEEDS = 20
QUICK_SEEDS = 2

#: The measure of an episode (:func:`episode_row`). The store keys every episode by this
#: string: it must stay byte-identical for the existing stores to match.
MEASURE = "experiments.studies.breaks:episode_row"


# ----------------------------------------------------------------------------------------------
# The profile taken apart
# ----------------------------------------------------------------------------------------------


def _flatten(block: Mapping[str, Any], prefix: FieldPath = ()) -> dict[FieldPath, Any]:
    out: dict[FieldPath, Any] = {}
    for key, value in block.items():
        if isinstance(value, Mapping):
            out.update(_flatten(value, (*prefix, str(key))))
        else:
            out[(*prefix, str(key))] = value
    return out


def _nest(values: Mapping[FieldPath, Any]) -> dict[str, Any]:
    """Nested block options of field paths: ``{("camera", "noise", "position"): 0.01}`` ->
    ``{"camera": {"noise": {"position": 0.01}}}``."""
    out: dict[str, Any] = {}
    for path, value in values.items():
        node = out
        for key in path[:-1]:
            node = node.setdefault(key, {})
        node[path[-1]] = value
    return out


def _field(cfg: ScenarioConfig, path: FieldPath) -> Any:
    node: Any = cfg
    for key in path:
        node = getattr(node, key)
    return node


@cache
def _config(study: str) -> ScenarioConfig:
    return load_config(study)


def axis_values(profile: str) -> dict[str, dict[FieldPath, Any]]:
    """The fields the sensor ``profile`` sets, by axis of :data:`PROFILE_AXES` (axes it does
    not touch are left out). A profile field no axis holds is a ``ValueError`` naming it."""
    owner = {path: a.name for a in PROFILE_AXES.values() for path in a.fields}
    out: dict[str, dict[FieldPath, Any]] = {}
    for path, value in _flatten(load_profile(profile)).items():
        if path not in owner:
            raise ValueError(
                f"sensor profile {profile!r}: field {'.'.join(path)} belongs to no axis of "
                f"PROFILE_AXES ({', '.join(PROFILE_AXES)}); add it to one"
            )
        out.setdefault(owner[path], {})[path] = value
    return {name: out[name] for name in PROFILE_AXES if name in out}


def ideal_values(study: str, axis: str) -> dict[FieldPath, Any]:
    """The study's own values (as shipped: the ideal) of the fields of ``axis``."""
    cfg = _config(study)
    return {path: _field(cfg, path) for path in PROFILE_AXES[axis].fields}


def active_axes(study: str, profile: str) -> tuple[list[str], list[str]]:
    """The axes of ``profile`` that change ``study`` (some field differs from the study's own
    value), and notes on the axes skipped because they do not."""
    active, notes = [], []
    for name, values in axis_values(profile).items():
        ideal = ideal_values(study, name)
        if all(ideal[p] == v for p, v in values.items()):
            shown = ", ".join(f"{'.'.join(p)} = {v}" for p, v in values.items())
            notes.append(
                f"{study}: axis {name} skipped: the profile's {shown} is the study's own value"
            )
        else:
            active.append(name)
    return active, notes


@dataclass(frozen=True)
class Condition:
    """One condition of a study: its kind (:data:`CONDITION_KINDS`) and axis ("" for ``ideal``
    and ``profile``)."""

    kind: str
    axis: str = ""

    def __post_init__(self) -> None:
        if self.kind not in CONDITION_KINDS:
            raise ValueError(f"condition kind {self.kind!r}: expected one of {CONDITION_KINDS}")
        if (self.kind in ("without", "alone")) != bool(self.axis):
            raise ValueError(f"condition {self.kind!r} with axis {self.axis!r}")
        if self.axis and self.axis not in PROFILE_AXES:
            raise ValueError(f"unknown axis {self.axis!r} (expected one of {list(PROFILE_AXES)})")

    def show(self, profile: str) -> str:
        """The condition as a table shows it."""
        if self.kind == "ideal":
            return "ideal (the study as shipped)"
        if self.kind == "profile":
            return f"{profile} (the whole profile)"
        if self.kind == "without":
            return f"{profile} without {self.axis}"
        return f"{self.axis} alone"


def conditions(study: str, profile: str) -> tuple[list[Condition], list[str]]:
    """The conditions of ``study`` (``ideal``, ``profile``, then ``without`` and ``alone`` for
    each active axis) and notes on the skipped axes (:func:`active_axes`)."""
    axes, notes = active_axes(study, profile)
    out = [Condition("ideal"), Condition("profile")]
    out += [Condition("without", a) for a in axes]
    out += [Condition("alone", a) for a in axes]
    return out, notes


def condition_overrides(study: str, condition: Condition, profile: str) -> dict[str, Any]:
    """The ``make`` overrides of a condition (before
    :func:`experiments.robustness.episode_overrides`):

    * ``ideal``: none;
    * ``profile``: ``sensor_profile=profile`` (:func:`experiments.axes.profile_overrides`);
    * ``without``: the profile, and the axis' fields as block options set to the study's own
      values (block options override single fields of a profile);
    * ``alone``: the axis' fields at the profile's values as block options.
    """
    if condition.kind == "ideal":
        return {}
    if condition.kind == "profile":
        return profile_overrides(profile)
    values = axis_values(profile)
    if condition.axis not in values:
        raise ValueError(f"sensor profile {profile!r} sets no field of axis {condition.axis!r}")
    if condition.kind == "without":
        return {**profile_overrides(profile), **_nest(ideal_values(study, condition.axis))}
    return _nest(values[condition.axis])


def build_grid(
    studies: Sequence[str],
    controllers: Sequence[str],
    seeds: int,
    *,
    profile: str = DEFAULT_PROFILE,
    max_episode_steps: int | None = None,
) -> tuple[list[tuple[tuple[str, ...], Cell]], dict[str, list[Condition]], list[str]]:
    """The grid's points as (row key, cell), the conditions of each study, and notes.

    Keys are :data:`KEY_COLUMNS` tuples (all strings). Long episodes (study C) come first, as
    in the frontiers. Conditions with equal overrides share a key in the store and run once.
    """
    unknown = [c for c in controllers if c not in CONTROLLERS]
    if unknown:
        raise ValueError(f"unknown controller(s) {unknown} (expected some of {list(CONTROLLERS)})")
    notes: list[str] = []
    conds: dict[str, list[Condition]] = {}
    for study in studies:
        conds[study], skipped = conditions(study, profile)
        notes += skipped
    points = {
        study: [((c.kind, c.axis), condition_overrides(study, c, profile)) for c in conds[study]]
        for study in studies
    }
    grid = study_grid(
        studies,
        controllers,
        seeds,
        points,
        measure=MEASURE,
        max_episode_steps=max_episode_steps,
    )
    return grid, conds, notes


# ----------------------------------------------------------------------------------------------
# One episode
# ----------------------------------------------------------------------------------------------


def failure_place(ep: Episode) -> dict[str, Any]:
    """Where a failed episode failed (:data:`PLACE_COLUMNS`; "" without a violation): the
    position ``fail_x``, ``fail_y`` [m] of the diagnosed follower
    (:func:`experiments.robustness.diagnosed_follower`) just after the violating step, and its
    true wall clearances ``fail_d_W_l``, ``fail_d_W_r`` [m] there (``d_W_l``, ``d_W_r``: to the
    nearest boundary point on its left and right, clipped to the proximity range)."""
    out: dict[str, Any] = dict.fromkeys(PLACE_COLUMNS, "")
    diag = diagnosed_follower(ep)
    if ep.first_violation is None or diag is None:
        return out
    k = min(ep.first_violation[0] + 1, ep.poses.shape[0] - 1)
    i = diag[0]  # robot index (0 the leader); the sensed rows are the followers 1..N
    out["fail_x"] = float(ep.poses[k, i, 0])
    out["fail_y"] = float(ep.poses[k, i, 1])
    out["fail_d_W_l"] = float(ep.sensed[k, i - 1, SENSE_D_WALL_LEFT])
    out["fail_d_W_r"] = float(ep.sensed[k, i - 1, SENSE_D_WALL_RIGHT])
    return out


def episode_row(ep: Episode) -> dict[str, Any]:
    """The outcome columns of one episode: the frontiers'
    (:func:`experiments.robustness.episode_row`) and :func:`failure_place`."""
    row = outcome_row(ep)
    row.update(failure_place(ep))
    return row


def place_of(row: Mapping[str, str], radius: float, delta: float) -> str:
    """The place of a failure (:data:`PLACES`), from its wall clearances, the robot radius ``r``
    and the PPC activation distance ``delta``: ``narrow`` when ``d_W - r < delta`` on both
    sides, ``wall`` on one, ``open`` on neither; "" for a row without a place."""
    if row.get("fail_d_W_l", "") in ("", "nan") or row.get("fail_d_W_r", "") in ("", "nan"):
        return ""
    near = sum(float(row[c]) - radius < delta for c in ("fail_d_W_l", "fail_d_W_r"))
    return PLACES[near]


# ----------------------------------------------------------------------------------------------
# Tables
# ----------------------------------------------------------------------------------------------

Group = dict[tuple[str, str, str, str], Point]


def _group(rows: Iterable[dict[str, str]]) -> Group:
    """Rows grouped by (controller, study, condition, axis)."""
    groups: Group = {}
    for r in rows:
        key = (r["controller"], r["study"], r["condition"], r["axis"])
        groups.setdefault(key, Point([])).rows.append(r)
    return groups


def _violation_time(row: Mapping[str, str]) -> float:
    """The first violation's time [s] of a failed row (inf without a violation)."""
    text = row.get("violation_time", "")
    return float(text) if text not in ("", "nan") else math.inf


def _timed(fails: Iterable[dict[str, str]]) -> list[dict[str, str]]:
    return [r for r in fails if math.isfinite(_violation_time(r))]


def _early(fails: Iterable[dict[str, str]]) -> list[dict[str, str]]:
    return [r for r in _timed(fails) if _violation_time(r) < STARTUP]


def _delta(study: str) -> float:
    """The PPC activation distance ``delta`` of ``study`` (its ``ppc`` block, after eq. 12)."""
    ppc = _config(study).ppc
    if ppc is None:
        raise ValueError(f"{study}: no ppc block, so no activation distance delta for the places")
    return float(ppc.delta)


def _places(fails: Iterable[dict[str, str]], study: str) -> Counter[str]:
    return Counter(place_of(r, _config(study).robot.radius, _delta(study)) for r in fails)


def _places_text(counter: Counter[str]) -> str:
    return " / ".join(str(counter.get(p, 0)) for p in PLACES)


def _label(ctrl: str) -> str:
    return CONTROLLERS[ctrl].label if ctrl in CONTROLLERS else ctrl


def _value_text(value: Any) -> str:
    return "none" if value is None else f"{value:g}" if isinstance(value, float) else str(value)


def axes_table(studies: Sequence[str], profile: str) -> list[str]:
    """The profile's axes: their fields, the profile's values and the studies' own."""
    out = [
        f"| axis | what | fields | {profile} | ideal (the studies' own) |",
        "|---|---|---|---|---|",
    ]
    for name, values in axis_values(profile).items():
        ideal = {s: ideal_values(s, name) for s in studies}
        shown = []
        for path in values:
            seen = sorted({_value_text(ideal[s][path]) for s in studies})
            shown.append(" or ".join(seen))
        out.append(
            f"| {name} | {PROFILE_AXES[name].label} | "
            f"{', '.join('.'.join(p) for p in values)} | "
            f"{', '.join(_value_text(v) for v in values.values())} | {', '.join(shown)} |"
        )
    return out


def _condition_table(
    groups: Group, study: str, controllers: Sequence[str], conds: Sequence[Condition], profile: str
) -> list[str]:
    head = "| condition |"
    for c in controllers:
        head += f" {_label(c)}: successes [95% CI] | dominant failure | failures < {STARTUP:g} s |"
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for cond in conds:
        line = f"| {cond.show(profile)} |"
        any_rows = False
        for c in controllers:
            pt = groups.get((c, study, cond.kind, cond.axis))
            if pt is None:
                line += " – | – | – |"
                continue
            any_rows = True
            fails = pt.failures
            early = f"{len(_early(fails))}/{len(fails)}" if fails else "–"
            line += f" {pt.cell()} | {pt.dominant()} | {early} |"
        if any_rows:
            out.append(line)
    return out


def _where_when_table(
    groups: Group, studies: Sequence[str], controllers: Sequence[str], profile: str
) -> list[str]:
    out = [
        "| study | controller | conditions | failures | with a violation | "
        f"t < {STARTUP:g} s | early: open / wall / narrow | "
        f"later: open / wall / narrow | median time [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for study in studies:
        for c in controllers:
            sets = (
                (f"{profile}", [("profile", "")]),
                (
                    "all the others but ideal",
                    [(k, a) for (cc, s, k, a) in groups if cc == c and s == study and k in
                     ("without", "alone")],
                ),
            )  # fmt: skip
            for name, keys in sets:
                fails = [r for k in keys for r in groups.get((c, study, *k), Point([])).failures]
                if not fails:
                    continue
                timed = _timed(fails)
                early = _early(fails)
                later = [r for r in timed if _violation_time(r) >= STARTUP]
                times = sorted(_violation_time(r) for r in timed)
                median = f"{float(np.median(times)):.2f}" if times else "–"
                out.append(
                    f"| {study} | {_label(c)} | {name} | {len(fails)} | {len(timed)} | "
                    f"{len(early)} | {_places_text(_places(early, study))} | "
                    f"{_places_text(_places(later, study))} | {median} |"
                )
    return out


def startup_answer(
    groups: Group,
    studies: Sequence[str],
    controllers: Sequence[str],
    conds: Mapping[str, Sequence[Condition]],
    profile: str,
) -> list[str]:
    """The start-up question in generated sentences: per study and controller, how many of the
    profile's failures with a violation came in the first :data:`STARTUP` s, and where, with the
    range and median of their times (a window edge splits a cluster just past it); whether
    the start-up transient dominates them (more than :data:`DOMINANCE` of them early); and, if
    it does, the early failures left with each axis removed (which part of the profile makes the
    transient) and with each axis alone."""
    lines: list[str] = []
    dominated: list[str] = []
    not_dominated: list[str] = []
    for study in studies:
        for c in controllers:
            pt = groups.get((c, study, "profile", ""))
            if pt is None:
                continue
            name = f"{study}, {_label(c)}"
            timed = _timed(pt.failures)
            if not timed:
                lines.append(f"- {name}: no failure with a violation under {profile}.")
                continue
            early = _early(timed)
            share = len(early) / len(timed)
            places = _places(early, study)
            where = ", ".join(f"{p} {places.get(p, 0)}" for p in PLACES)
            verdict = "dominates" if share > DOMINANCE else "does not dominate"
            (dominated if share > DOMINANCE else not_dominated).append(name)
            times = [_violation_time(r) for r in timed]
            text = (
                f"- {name}: {len(early)} of {len(timed)} failures under {profile} in the first "
                f"{STARTUP:g} s ({share:.0%}; {where}; all first violations between "
                f"{min(times):.2f} and {max(times):.2f} s, median {float(np.median(times)):.2f} "
                f"s): the start-up transient {verdict}."
            )
            if share > DOMINANCE:
                for kind, word in (("without", "with it removed"), ("alone", "alone")):
                    parts = []
                    for cond in conds[study]:
                        if cond.kind != kind:
                            continue
                        q = groups.get((c, study, kind, cond.axis))
                        if q is not None:
                            parts.append(f"{cond.axis} {len(_early(q.failures))}/{q.n}")
                    if parts:
                        text += f" Early failures per axis {word}: {', '.join(parts)}."
            lines.append(text)
    lines.append("")
    lines.append(
        f"The start-up transient (more than {DOMINANCE:.0%} of the failures with a violation "
        f"in the first {STARTUP:g} s) dominates the {profile} failures of: "
        f"{'; '.join(dominated) or 'none'}. It does not dominate those of: "
        f"{'; '.join(not_dominated) or 'none'}."
    )
    return lines


def summarise(
    rows: Iterable[dict[str, str]],
    studies: Sequence[str],
    controllers: Sequence[str],
    conds: Mapping[str, Sequence[Condition]],
    *,
    profile: str = DEFAULT_PROFILE,
) -> str:
    """The markdown body of ``breaks.md``: the profile's axes, a table per study, where and
    when the failures happen, and the start-up answer."""
    groups = _group(rows)
    lines = ["### The profile's axes", "", *axes_table(studies, profile), ""]
    for study in studies:
        lines += [f"### {study}", ""]
        lines += _condition_table(groups, study, controllers, conds[study], profile)
        lines.append("")
    lines += [
        "### Where and when",
        "",
        f"Failures (first violations) by time and place: early is before t = {STARTUP:g} s; a "
        "failure's place is where the diagnosed follower was (narrow: walls within the PPC "
        "activation distance delta of its disk on both sides, wall: on one side, open: on "
        "neither); failures without a violation (stopped short) have no time or place.",
        "",
        *_where_when_table(groups, studies, controllers, profile),
        "",
        "### The start-up question",
        "",
        *startup_answer(groups, studies, controllers, conds, profile),
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------

_CAUSE_COLOURS = {
    "collision_robot": "tab:red",
    "collision_obstacle": "tab:brown",
    "occluded": "tab:purple",
    "out_of_fov": "tab:orange",
    "out_of_range": "tab:olive",
}


def plot_map(
    rows: Iterable[dict[str, str]],
    study: str,
    controllers: Sequence[str],
    path: Path,
    *,
    profile: str = DEFAULT_PROFILE,
    metadata: dict[str, str] | None = None,
) -> Path:
    """``breaks_<study>.png``: a panel per controller, the study's map (obstacles, the leader's
    path, the platoon at its start) with the failure locations: under the whole profile large
    markers coloured by the first violation cause (circles before :data:`STARTUP` s, triangles
    after), under the other conditions (without or alone) small grey crosses."""
    from matplotlib.lines import Line2D

    from platoon_env.plots import new_figure, save_figure
    from platoon_env.rendering import draw_scene

    groups = _group(rows)
    scenario = build_scenario(_config(study))
    x0, y0, x1, y1 = scenario.free_space.bounds
    wide = (x1 - x0) / max(y1 - y0, 1e-9) > 1.8
    n = len(controllers)
    nrows, ncols = (n, 1) if wide else (1, n)
    panel_w = 7.0 if wide else 3.6
    panel_h = panel_w * (y1 - y0) / (x1 - x0) + 0.5
    fig = new_figure(panel_w * ncols, panel_h * nrows + 0.6)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    visible = np.ones(scenario.initial_poses.shape[0] - 1, dtype=bool)
    for ax, c in zip(axes, controllers, strict=True):
        draw_scene(ax, scenario.free_space, scenario.config, scenario.initial_poses, visible, 0.0)
        others = [
            r
            for (cc, s, k, _), pt in groups.items()
            if cc == c and s == study and k in ("without", "alone")
            for r in pt.failures
            if r.get("fail_x", "") not in ("", "nan")
        ]
        if others:
            ax.scatter(
                [float(r["fail_x"]) for r in others], [float(r["fail_y"]) for r in others],
                marker="x", s=10, color="0.35", lw=0.7, zorder=20,
            )  # fmt: skip
        pt = groups.get((c, study, "profile", ""))
        fails = [r for r in (pt.failures if pt else []) if r.get("fail_x", "") not in ("", "nan")]
        for r in fails:
            early = _violation_time(r) < STARTUP
            ax.scatter(
                float(r["fail_x"]), float(r["fail_y"]), s=34, marker="o" if early else "^",
                color=_CAUSE_COLOURS.get(r["violation"], "k"), edgecolor="k", lw=0.5, zorder=21,
            )  # fmt: skip
        total = pt.n if pt else 0
        ax.set_title(
            f"{_label(c)}: {len(pt.failures) if pt else 0}/{total} failures under {profile}",
            fontsize=9,
        )
        ax.tick_params(labelsize=7)
    handles = [
        Line2D([], [], ls="", marker="o", color=col, mec="k", label=cause)
        for cause, col in _CAUSE_COLOURS.items()
    ]
    handles += [
        Line2D([], [], ls="", marker="o", color="w", mec="k", label=f"t < {STARTUP:g} s"),
        Line2D([], [], ls="", marker="^", color="w", mec="k", label=f"t >= {STARTUP:g} s"),
        Line2D([], [], ls="", marker="x", color="0.35", label="other conditions"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=4, fontsize=7)
    fig.suptitle(f"{study}: where the first violation happens ({profile} taken apart)")
    return save_figure(fig, path, metadata)


def plot_times(
    rows: Iterable[dict[str, str]],
    studies: Sequence[str],
    controllers: Sequence[str],
    path: Path,
    *,
    profile: str = DEFAULT_PROFILE,
    metadata: dict[str, str] | None = None,
) -> Path:
    """``breaks_times.png``: when the first violation happens, a column per study; top row the
    whole profile's failures, bottom row the other conditions' (without or alone); a step
    histogram per controller on logarithmic time bins, the start-up window :data:`STARTUP`
    marked."""
    from platoon_env.plots import POLICY_COLOURS, new_figure, save_figure

    groups = _group(rows)
    times_all = [_violation_time(r) for pt in groups.values() for r in _timed(pt.failures)]
    times_all = times_all or [STARTUP]
    lo = max(min(min(times_all), STARTUP) * 0.8, 1e-2)
    hi = max(max(times_all), STARTUP) * 1.25
    bins = np.geomspace(lo, hi, 28)
    fig = new_figure(3.6 * len(studies), 5.2)
    panels = fig.subplots(2, len(studies), squeeze=False, sharex=True)
    for col, study in enumerate(studies):
        for row, (name, kinds) in enumerate(
            ((profile, ("profile",)), ("other conditions", ("without", "alone")))
        ):
            ax = panels[row, col]
            for j, c in enumerate(controllers):
                times = [
                    _violation_time(r)
                    for (cc, s, k, _), pt in groups.items()
                    if cc == c and s == study and k in kinds
                    for r in _timed(pt.failures)
                ]
                if times:
                    ax.hist(
                        times, bins=bins, histtype="step", lw=1.4, label=_label(c),
                        color=POLICY_COLOURS[j % len(POLICY_COLOURS)],
                    )  # fmt: skip
            ax.axvline(STARTUP, color="k", ls=":", lw=1.0)
            ax.set_xscale("log")
            ax.set_title(f"{study}: {name}", fontsize=9)
            ax.set_ylabel("failures")
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
            if row == 1:
                ax.set_xlabel("time of the first violation [s]")
    labelled = [ax for ax in panels.ravel() if ax.get_legend_handles_labels()[0]]
    if labelled:
        labelled[0].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"When the first violation happens (dotted: t = {STARTUP:g} s)")
    return save_figure(fig, path, metadata)


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------

_TOOL = "python -m experiments.studies.breaks"


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = new_parser(_TOOL, __doc__, out=Path("results/breaks"))
    add_grid_options(
        parser, seeds=None, seeds_help=f"seeds per condition (default {DEFAULT_SEEDS})", store=None
    )
    parser.add_argument(
        "--store",
        type=Path,
        default=None,
        help="the evaluation store the episodes go to and resume from (a .sqlite file or a "
        "folder holding results.sqlite; default: OUT/results.sqlite)",
    )
    parser.add_argument(
        "--figures", type=Path, default=None, help="folder of the PNGs (default: OUT)"
    )
    add_study_options(parser, quick_help=f"smoke run: {QUICK_SEEDS} seeds (unless --seeds)")
    parser.add_argument(
        "--profile",
        default=DEFAULT_PROFILE,
        choices=[p for p in list_profiles() if p != "ideal"],
        help=f"the sensor profile taken apart (default {DEFAULT_PROFILE})",
    )
    args = parser.parse_args(argv)
    finish_study_args(args, seeds=DEFAULT_SEEDS, quick_seeds=QUICK_SEEDS)
    args.store = store_path(args.out) if args.store is None else store_file(args.store)
    args.figures = args.out if args.figures is None else args.figures
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the grid (resuming), write ``breaks.csv``, ``breaks.md`` and the PNGs; returns the
    exit code (1 if an episode failed, 130 when interrupted)."""
    args = parse_args(argv)
    out: Path = args.out
    grid, conds, notes = build_grid(
        args.study,
        args.controller,
        args.seeds,
        profile=args.profile,
        max_episode_steps=args.max_episode_steps,
    )
    for note in notes:
        print(f"note: {note}")
    run = run_and_export(
        _TOOL,
        grid,
        args.store,
        args,
        argv,
        out / "breaks.csv",
        key_columns=KEY_COLUMNS,
        columns=CSV_COLUMNS,
    )
    if run is None:
        return 130
    result, rows = run.result, run.rows
    meta = png_metadata(run.stamp)
    paths = [
        plot_map(
            rows, s, args.controller, args.figures / f"breaks_{s}.png",
            profile=args.profile, metadata=meta,
        )
        for s in args.study
    ]  # fmt: skip
    paths.append(
        plot_times(
            rows, args.study, args.controller, args.figures / "breaks_times.png",
            profile=args.profile, metadata=meta,
        )
    )  # fmt: skip
    body = summarise(rows, args.study, args.controller, conds, profile=args.profile)
    header = (
        f"The `{args.profile}` sensor profile taken apart: for each controller and study, the "
        "study as shipped (ideal), the whole profile, the profile with one axis set back to "
        "the study's own (ideal) values, and that axis alone at the profile's values; "
        f"{args.seeds} seeds per condition. Success: the episode ends by truncation without "
        "any violation (every violation ends it); cells are successes/seeds [Wilson 95 % "
        "interval]; the dominant failure is the most frequent first violation among the failed "
        f"episodes; failures < {STARTUP:g} s counts those whose first violation came before "
        f"t = {STARTUP:g} s. Controllers: {', '.join(_label(c) for c in args.controller)}. "
        f"{len(rows)} of {len(grid)} rows have a result; wall time of this run "
        f"{result.wall_time:.0f} s ({result.ran} episodes run, {result.reused} reused). "
        f"Figures: {', '.join(f'`{p.name}`' for p in paths)}.\n\n"
        + "".join(f"- note: {n}\n" for n in notes)
        + run.provenance
        + "\n"
    )
    write_text_atomic(out / "breaks.md", header + body + "\n")
    print(body)
    print(f"wrote {out / 'breaks.csv'}, {out / 'breaks.md'}, " + ", ".join(map(str, paths)))
    return failed_episodes(result)


if __name__ == "__main__":
    raise SystemExit(main())
