"""Robustness frontiers: success rate of each controller against one realism axis at a time.

Usage::

    python -m experiments.studies.frontiers [--out results/frontiers] [--seeds 10] [--workers 2]
                                  [--study study_c ...] [--controller ppc ...] [--axis latency ...]
                                  [--quick] [--max-episode-steps N]

For each controller (:data:`CONTROLLERS`: the paper's PPC law, the last-seen baseline of ref.
[32] and, when ``baselines/filtered_ppc.py`` exists, the filtered PPC) on the studies A, B and
C, every level of every axis of :data:`AXES` is run alone (the other settings ideal) for
``--seeds`` seeds:

* ``camera_noise``: camera position noise sigma in {0, 0.5, 1, 2, 5, 10} cm;
* ``detection``: detection probability in {1, 0.95, 0.8, 0.5};
* ``latency``: camera latency in {0, 10, 30, 50, 100} ms;
* ``frame_rate``: camera frame rate in {every control step, 30, 15} Hz;
* ``accel_max``: bound on the follower's linear acceleration in {none, 2, 1, 0.5} m/s^2;
* ``profile``: the shipped ``aruco`` sensor profile (skipped, with a message, until
  :func:`platoon_env.scenarios.profiles.load_profile` can load it).

An episode **succeeds** when it ends by truncation (the leader reached its path's end and
settled, or the step limit) without any violation. Every violation cause ends the episode
(``terminate_on`` = all causes), so the first violation is the last step.

Every point (controller, study, axis, level, seed) is one episode of the evaluation store
``OUT/results.sqlite`` (:mod:`experiments.store`), run by the shared grid runner
(:func:`experiments.grid.run_grid`): the outcome, the first violation's cause, time and
follower, the step count, the minimum obstacle clearance and, for the PPC laws, the signals
that explain a failure (:func:`ppc_diagnostics`): which funnel saturated first and when, and the
normalised errors just before the violation, as perceived and as true. Each episode is written
in its own transaction as it finishes; a re-run with the same ``--out`` runs only what the
store lacks (keys are content fingerprints, so another ``--max-episode-steps`` or edited study
runs anew beside the old rows), and two runs into one ``--out`` share the work. Identical
configurations (the ideal level shared by every axis) have one key and run once per seed.
``OUT/frontiers.csv`` (:data:`CSV_COLUMNS`) is an export of the grid's rows.

Then ``OUT/frontiers.md`` holds, per study, a table of level x controller -> successes/seeds
[Wilson 95 % interval] with the dominant failure cause, and the PPC failure diagnostics; and
``OUT/frontier_<study>.png`` a panel per axis: success rate against level, a line per
controller, the 95 % intervals as bands.

``--quick`` (a smoke run): 2 seeds (unless ``--seeds`` is given) and two levels per axis.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from baselines.ppc import EPS_MAX
from experiments.axes import AXES, Axis, level_key
from experiments.cli import add_grid_options, count, failed_episodes, new_parser, open_store
from experiments.grid import Cell, GridResult, ResolvedCell, resolve_cells, run_grid, store_path
from experiments.policies import PolicySpec, analytic_policies
from experiments.report import (
    format_value,
    provenance_markdown,
    wilson,
    write_csv,
    write_csv_stamp,
    write_text_atomic,
)
from experiments.stamp import metadata_stamp, png_metadata
from experiments.suites import STUDIES
from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D
from platoon_env.rollout import Episode, episode_metrics
from platoon_env.scenarios.schema import VIOLATION_CAUSES

__all__ = [
    "AXES",
    "CONTROLLERS",
    "CSV_COLUMNS",
    "KEY_COLUMNS",
    "STUDIES",
    "Axis",
    "Point",
    "build_grid",
    "diagnosed_follower",
    "failure_diagnostics",
    "level_key",
    "main",
    "ppc_diagnostics",
    "rows_of",
    "summarise",
    "wilson_interval",
]


#: Columns that identify a row (one episode); a resumed run skips the keys already written.
KEY_COLUMNS: tuple[str, ...] = ("controller", "study", "axis", "level", "seed")

#: The PPC failure signals of :func:`ppc_diagnostics` (empty for other controllers).
DIAGNOSTIC_COLUMNS: tuple[str, ...] = (
    "first_saturation",
    "first_saturation_time",
    "first_saturation_follower",
    "seen_steps_ago",
    "xi_d",
    "xi_beta",
    "eps_d",
    "eps_beta",
    "xi_d_true",
    "xi_beta_true",
    "F_max_1s",
    "unseen_frac_1s",
)

#: Columns on the diagnosed follower at and before the first violation, for every controller
#: (:func:`failure_diagnostics`).
FAILURE_COLUMNS: tuple[str, ...] = (
    "d_true",
    "beta_true",
    "u_peak_1s",
    "omega_peak_1s",
    "omega_flips_1s",
)

#: Columns of ``frontiers.csv``.
CSV_COLUMNS: tuple[str, ...] = (
    *KEY_COLUMNS,
    "success",
    "truncated",
    "violation",
    "violation_time",
    "violation_follower",
    "contact",
    "diag_follower",
    "steps",
    "sim_time",
    "min_clearance",
    "min_robot_distance",
    "lost_sight_steps",
    "funnel_exits",
    *DIAGNOSTIC_COLUMNS,
    *FAILURE_COLUMNS,
    "wall_time",
)

#: The window before a violation over which ``F_max_1s`` and ``unseen_frac_1s`` are taken [s].
DIAGNOSTIC_WINDOW = 1.0

DEFAULT_SEEDS = 10
QUICK_SEEDS = 2


# ----------------------------------------------------------------------------------------------
# Controllers
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Controller:
    """A controller of the frontier: its display name, its registered policy kind
    (:data:`experiments.policies.REGISTRY`), and whether it is a PPC law (then its signals are
    recorded and diagnosed)."""

    label: str
    kind: str
    ppc: bool

    @property
    def spec(self) -> PolicySpec:
        """The policy of the grid's cells (named by its kind, as in the CSV)."""
        return PolicySpec.of(self.kind)


#: Controller name (the CSV's ``controller``) -> :class:`Controller`: the registered policies
#: whose ``studies`` include the frontiers (:func:`experiments.policies.analytic_policies`).
CONTROLLERS: dict[str, Controller] = {
    name: Controller(kind.label, name, ppc=kind.signals)
    for name, kind in analytic_policies("frontiers").items()
}


# ----------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------

#: The measure of a frontier episode (:func:`episode_row`).
MEASURE = "experiments.studies.frontiers:episode_row"


def episode_overrides(
    level_overrides: Mapping[str, Any], max_episode_steps: int | None = None
) -> dict[str, Any]:
    """The make() overrides of a point: its level's, every violation cause ending the episode,
    the lean info dicts, and the step limit if given."""
    out: dict[str, Any] = {
        **level_overrides,
        "terminate_on": list(VIOLATION_CAUSES),
        "diagnostics": False,
    }
    if max_episode_steps is not None:
        out["max_episode_steps"] = max_episode_steps
    return out


def build_grid(
    studies: Sequence[str],
    controllers: Sequence[str],
    axes: Sequence[str],
    seeds: int,
    *,
    quick: bool = False,
    max_episode_steps: int | None = None,
) -> tuple[list[tuple[tuple[str, ...], Cell]], list[str]]:
    """The grid's points as (row key, cell), and notes on skipped points.

    Keys are :data:`KEY_COLUMNS` tuples (all strings). Points with the same overrides (the
    ideal level of each axis) have equal cells, hence one key in the store: one episode per
    controller, study and seed fills all their rows. A point whose overrides cannot be built
    is left out with a note. Long episodes (study C) come first, so that the last worker does
    not run alone for long.
    """
    notes: list[str] = []
    points: list[tuple[str, str, dict[str, Any]]] = []  # axis, level key, overrides
    for name in axes:
        axis = AXES[name]
        for level in axis.quick if quick else axis.levels:
            try:
                level_overrides = axis.overrides(level)
            except Exception as exc:
                notes.append(f"{name}={level_key(level)} skipped: {type(exc).__name__}: {exc}")
                continue
            points.append((name, level_key(level), level_overrides))
    order = sorted(studies, key=lambda s: -STUDIES.index(s) if s in STUDIES else 0)
    grid: list[tuple[tuple[str, ...], Cell]] = []
    for seed in range(seeds):
        for study in order:
            for ctrl in controllers:
                c = CONTROLLERS[ctrl]
                for axis_name, lk, ov in points:
                    cell = Cell.of(
                        c.spec, study, seed, episode_overrides(ov, max_episode_steps),
                        measure=MEASURE, record_signals=c.ppc,
                    )  # fmt: skip
                    grid.append(((ctrl, study, axis_name, lk, str(seed)), cell))
    return grid, notes


# ----------------------------------------------------------------------------------------------
# One episode
# ----------------------------------------------------------------------------------------------


def _first_saturation(sig: Mapping[str, np.ndarray]) -> tuple[str, int, int] | None:
    """The first (step, follower) at which a transformed error reached its clamp ``EPS_MAX``
    (the error at or beyond a funnel bound), named by the bound: ``d_lo`` (too close),
    ``d_hi`` (too far), ``beta_lo``, ``beta_hi`` (the predecessor off to one side)."""
    vis = np.asarray(sig["visible"], dtype=bool)
    best: tuple[int, int, str] | None = None
    for name, err in (("d", sig["eps_d"]), ("beta", sig["eps_beta"])):
        sat = vis & (np.abs(err) >= EPS_MAX - 1e-9)
        if not np.any(sat):
            continue
        step, i = np.unravel_index(int(np.argmax(sat.ravel())), sat.shape)
        bound = f"{name}_hi" if err[step, i] > 0 else f"{name}_lo"
        cand = (int(step), int(i), bound)
        if best is None or cand[:2] < best[:2]:
            best = cand
    return None if best is None else (best[2], best[0], best[1])


def _xi(e: float, lo: float, hi: float) -> float:
    """Position of ``e`` in its funnel ``(lo, hi)``: -1 at ``lo``, 0 in the middle, +1 at ``hi``
    (beyond +-1 outside)."""
    width = hi - lo
    return (2.0 * e - (hi + lo)) / width if width > 0 else math.nan


def diagnosed_follower(ep: Episode) -> tuple[int, str] | None:
    """The follower (1..N) a failure is diagnosed on, and the robot contact (``"j-k"``, robot
    indices, 0 the leader; "" unless the first violation is ``collision_robot``).

    The first violation names the first follower flagged in its step. For a robot collision
    every robot of the touching pair is flagged, so the follower named is often the one that
    was run into; the diagnosis is then on the rear robot ``k`` of the closest pair after
    that step (the one that closed in: its own predecessor when ``k = j + 1``).
    """
    if ep.first_violation is None:
        return None
    s, cause, k = ep.first_violation
    if cause != "collision_robot":
        return k, ""
    xy = ep.poses[min(s + 1, ep.poses.shape[0] - 1), :, :2]
    dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    dist[np.tril_indices(xy.shape[0])] = np.inf
    j, rear = np.unravel_index(int(np.argmin(dist)), dist.shape)
    return int(rear), f"{int(j)}-{int(rear)}"


def ppc_diagnostics(ep: Episode) -> dict[str, Any]:
    """Why a PPC episode failed, from its recorded signals (:attr:`PPCPolicy.signals`).

    * ``first_saturation`` (``d_lo``/``d_hi``/``beta_lo``/``beta_hi``, "" if none), its time
      [s] and follower: the first transformed error ``eps`` to reach its clamp (the first funnel
      to saturate, whether or not a violation followed);

    and, for a failed episode, for its :func:`diagnosed_follower` at the first violation's step:

    * ``seen_steps_ago``: how many control steps before the violation the predecessor was last
      reported (0: in the observation of that very step; -1: never);
    * ``xi_d``, ``xi_beta``: the perceived errors ``e_d``, ``e_beta`` of that last report as a
      position in their funnels (-1 at ``rho_lo``, +1 at ``rho_hi``), and ``eps_d``,
      ``eps_beta`` the transformed errors;
    * ``xi_d_true``, ``xi_beta_true``: the true errors (ground truth ``d``, ``beta``) at the
      violation step's start, in the funnels of that step;
    * ``F_max_1s``: the largest activation ``F_l``, ``F_r`` (obstacle proximity) over the
      :data:`DIAGNOSTIC_WINDOW` before the violation; ``unseen_frac_1s``: the fraction of its
      steps without a reported predecessor.

    Empty values ("") where a signal does not apply; {} keys if the signals are missing.
    """
    out: dict[str, Any] = dict.fromkeys(DIAGNOSTIC_COLUMNS, "")
    sig = ep.signals
    needed = ("visible", "eps_d", "eps_beta", "e_d", "e_beta", "F_l", "F_r")
    if not all(k in sig for k in (*needed, "rho_d_lo", "rho_d_hi", "rho_beta_lo", "rho_beta_hi")):
        return out
    if sig["visible"].shape[0] == 0:
        return out
    first = _first_saturation(sig)
    if first is not None:
        bound, step, i = first
        out["first_saturation"] = bound
        out["first_saturation_time"] = float(ep.times[step])
        out["first_saturation_follower"] = i + 1
    if ep.first_violation is None:
        return out
    s = ep.first_violation[0]
    i = (diagnosed_follower(ep) or (0, ""))[0] - 1
    vis = np.asarray(sig["visible"][: s + 1, i], dtype=bool)
    seen = np.flatnonzero(vis)
    window = max(1, round(DIAGNOSTIC_WINDOW / ep.control_period))
    lo_s = max(0, s + 1 - window)
    out["F_max_1s"] = float(
        np.max(np.maximum(sig["F_l"][lo_s : s + 1, i], sig["F_r"][lo_s : s + 1, i]))
    )
    out["unseen_frac_1s"] = float(np.mean(~vis[lo_s:]))
    rho = {n: sig[n][:, i] for n in ("rho_d_lo", "rho_d_hi", "rho_beta_lo", "rho_beta_hi")}
    if seen.size:
        j = int(seen[-1])
        out["seen_steps_ago"] = s - j
        out["xi_d"] = _xi(float(sig["e_d"][j, i]), rho["rho_d_lo"][j], rho["rho_d_hi"][j])
        out["xi_beta"] = _xi(
            float(sig["e_beta"][j, i]), rho["rho_beta_lo"][j], rho["rho_beta_hi"][j]
        )
        out["eps_d"] = float(sig["eps_d"][j, i])
        out["eps_beta"] = float(sig["eps_beta"][j, i])
    else:
        out["seen_steps_ago"] = -1
    true_e_d = float(ep.sensed[s, i, SENSE_D]) - ep.d_des
    true_e_b = float(ep.sensed[s, i, SENSE_BETA])
    out["xi_d_true"] = _xi(true_e_d, rho["rho_d_lo"][s], rho["rho_d_hi"][s])
    out["xi_beta_true"] = _xi(true_e_b, rho["rho_beta_lo"][s], rho["rho_beta_hi"][s])
    return out


def failure_diagnostics(ep: Episode) -> dict[str, Any]:
    """The :func:`diagnosed_follower` of a failed episode: its true distance ``d_true`` [m] to
    its predecessor and angle of view ``beta_true`` [rad] at the start of the violation's step,
    and its commands over the :data:`DIAGNOSTIC_WINDOW` up to that step: the peak ``|u|``
    [m/s] and ``|omega|`` [rad/s] and the number of sign changes of ``omega`` (an oscillating
    bearing loop flips often). Empty ("") without a violation."""
    out: dict[str, Any] = dict.fromkeys(FAILURE_COLUMNS, "")
    diag = diagnosed_follower(ep)
    if ep.first_violation is None or diag is None or ep.actions.shape[0] == 0:
        return out
    s = ep.first_violation[0]
    i = diag[0] - 1
    out["d_true"] = float(ep.sensed[s, i, SENSE_D])
    out["beta_true"] = float(ep.sensed[s, i, SENSE_BETA])
    window = max(1, round(DIAGNOSTIC_WINDOW / ep.control_period))
    act = ep.actions[max(0, s + 1 - window) : s + 1, i]
    omega = act[:, 1]
    signs = np.sign(omega[omega != 0])
    out["u_peak_1s"] = float(np.max(np.abs(act[:, 0])))
    out["omega_peak_1s"] = float(np.max(np.abs(omega)))
    out["omega_flips_1s"] = int(np.sum(signs[1:] != signs[:-1]))
    return out


def episode_row(ep: Episode) -> dict[str, Any]:
    """The outcome columns of one episode (without the key and ``wall_time``)."""
    m = episode_metrics(ep)
    first = ep.first_violation
    diag = diagnosed_follower(ep)
    row: dict[str, Any] = {
        "success": bool(ep.truncated and first is None),
        "truncated": bool(ep.truncated),
        "violation": m["violation"],
        "violation_time": m["time_to_violation"],
        "violation_follower": "" if first is None else first[2],
        "contact": "" if diag is None else diag[1],
        "diag_follower": "" if diag is None else diag[0],
        "steps": m["steps"],
        "sim_time": m["sim_time"],
        "min_clearance": m["min_obstacle_clearance"],
        "min_robot_distance": m["min_inter_robot_distance"],
        "lost_sight_steps": m["lost_sight_steps"],
        "funnel_exits": m["funnel_exits"],
    }
    row.update(ppc_diagnostics(ep))
    row.update(failure_diagnostics(ep))
    return row


#: The ``violation`` of an episode the controller refused to run: its constructor raised a
#: ``ValueError`` for the configuration (e.g. the filtered PPC when the constraints tightened by
#: the declared noise leave the PPC law no feasible funnel). It counts as a failure.
REFUSED = "refused"


def rows_of(
    grid: Sequence[tuple[tuple[str, ...], Cell]],
    resolved: Sequence[ResolvedCell],
    result: GridResult,
    *,
    key_columns: Sequence[str] = KEY_COLUMNS,
    columns: Sequence[str] = CSV_COLUMNS,
) -> list[dict[str, Any]]:
    """The CSV rows (``columns``, default :data:`CSV_COLUMNS`) of the grid's points that have a
    result (``resolved``: the grid's cells resolved in order, one per point); each point's key
    is named by ``key_columns`` (default :data:`KEY_COLUMNS`; another study's grid, such as
    :mod:`experiments.studies.breaks`, names its own)."""
    rows = []
    for (key, _), rc in zip(grid, resolved, strict=True):
        rec = result.records.get(rc.key)
        if rec is None or rec.status not in ("done", "refused"):
            continue
        if rec.status == "refused":
            row: dict[str, Any] = dict.fromkeys(columns, "")
            row.update(success=False, truncated=False, violation=REFUSED, steps=0)
        else:
            row = dict(rec.metrics)
        row.update(dict(zip(key_columns, key, strict=True)), wall_time=rec.wall_time)
        rows.append(row)
    return rows


def _key(row: Mapping[str, Any]) -> tuple[str, ...]:
    return tuple(str(row[c]) for c in KEY_COLUMNS)


# ----------------------------------------------------------------------------------------------
# Statistics, tables, plots
# ----------------------------------------------------------------------------------------------


def wilson_interval(successes: int, n: int) -> tuple[float, float]:
    """The 95 % Wilson score interval of a binomial proportion.

    With ``p = successes / n`` and ``z = Φ⁻¹(0.975) ≈ 1.95996``::

        centre = (p + z²/(2n)) / (1 + z²/n)
        half   = z sqrt(p (1 - p)/n + z²/(4n²)) / (1 + z²/n)

    and the interval ``[centre - half, centre + half]``. Unlike the normal approximation it
    stays inside [0, 1] and is not empty at 0/n or n/n: ``wilson_interval(8, 10) ≈ (0.490,
    0.943)``, ``wilson_interval(10, 10) ≈ (0.722, 1)``. ``(nan, nan)`` for ``n = 0``. The one
    implementation is :func:`experiments.report.wilson` (``scipy.stats.binomtest``).
    """
    return wilson(successes, n)


@dataclass
class Point:
    """The episodes of one controller x study x axis x level."""

    rows: list[dict[str, str]]

    @property
    def n(self) -> int:
        return len(self.rows)

    @property
    def successes(self) -> int:
        return sum(r["success"] == "True" for r in self.rows)

    @property
    def failures(self) -> list[dict[str, str]]:
        return [r for r in self.rows if r["success"] != "True"]

    def causes(self) -> Counter[str]:
        """Failures by first violation cause (``no truncation``: stopped without one)."""
        return Counter(r["violation"] or "no truncation" for r in self.failures)

    def cell(self) -> str:
        lo, hi = wilson_interval(self.successes, self.n)
        return f"{self.successes}/{self.n} [{lo:.2f}, {hi:.2f}]"

    def dominant(self) -> str:
        fails = self.failures
        if not fails:
            return "–"
        cause, count = self.causes().most_common(1)[0]
        return f"{cause} ({count}/{len(fails)})"


def _group(
    rows: Iterable[dict[str, str]], keys: Iterable[tuple[str, ...]]
) -> dict[tuple[str, str, str, str], Point]:
    """Rows of the grid ``keys`` grouped by (controller, study, axis, level)."""
    wanted = set(keys)
    groups: dict[tuple[str, str, str, str], Point] = {}
    for r in rows:
        k = _key(r)
        if k in wanted:
            groups.setdefault((k[0], k[1], k[2], k[3]), Point([])).rows.append(r)
    return groups


def _median(values: Iterable[str]) -> float:
    vals = [float(v) for v in values if v not in ("", "nan")]
    return statistics.median(vals) if vals else math.nan


def _levels(axes: Sequence[str], quick: bool) -> list[tuple[str, str, str]]:
    """(axis, level key, shown level) in grid order."""
    out = []
    for name in axes:
        axis = AXES[name]
        for level in axis.quick if quick else axis.levels:
            out.append((name, level_key(level), axis.show(level)))
    return out


def summarise(
    rows: Iterable[dict[str, str]],
    keys: Iterable[tuple[str, ...]],
    studies: Sequence[str],
    controllers: Sequence[str],
    axes: Sequence[str],
    *,
    quick: bool = False,
) -> str:
    """The markdown of ``frontiers.md``: per study, the frontier table and the PPC diagnostics."""
    groups = _group(rows, keys)
    levels = _levels(axes, quick)
    lines: list[str] = []
    for study in studies:
        lines += [f"## {study}", ""]
        head = "| axis | level |"
        for c in controllers:
            label = CONTROLLERS[c].label if c in CONTROLLERS else c
            head += f" {label}: successes [95% CI] | {label}: dominant failure |"
        lines += [head, "|" + "---|" * (head.count("|") - 1)]
        for axis, lk, shown in levels:
            line = f"| {axis} | {shown} |"
            any_rows = False
            for c in controllers:
                pt = groups.get((c, study, axis, lk))
                if pt is None:
                    line += " – | – |"
                else:
                    any_rows = True
                    line += f" {pt.cell()} | {pt.dominant()} |"
            if any_rows:
                lines.append(line)
        lines += ["", *_diagnostics_table(groups, study, controllers, levels), ""]
    return "\n".join(lines)


def _diagnostics_table(
    groups: Mapping[tuple[str, str, str, str], Point],
    study: str,
    controllers: Sequence[str],
    levels: Sequence[tuple[str, str, str]],
) -> list[str]:
    """Per PPC-law failing point: the causes, the first funnel to saturate and the normalised
    errors before the violation (medians over the failed episodes)."""
    head = (
        "| controller | axis | level | failures | causes | first saturated funnel | "
        "median lead time [s] | median seen steps ago | median xi_d, xi_beta (perceived) | "
        "median xi_d, xi_beta (true) | median F_max 1 s | median unseen 1 s | "
        "median omega flips 1 s | median peak u, omega 1 s | robot contacts | median d_true [m] |"
    )
    out = [
        f"PPC failure diagnostics ({study}): the first funnel whose transformed error "
        "saturated (count over the failed episodes), its lead time before the violation, and "
        "the errors' positions xi in their funnels (-1 at rho_lo, +1 at rho_hi) at the last "
        "report before the violation (perceived) and at the violation step (true), the largest "
        "obstacle activation F and the fraction of steps without a report over the last "
        "second, the sign changes and peaks of the commands over that second, the robot "
        "pairs in contact (j-k, 0 the leader) in robot collisions and the true distance d to "
        "the predecessor; all for the diagnosed follower (the rear robot of a contact, else "
        "the follower of the first violation).",
        "",
        head,
        "|" + "---|" * (head.count("|") - 1),
    ]
    n0 = len(out)
    for c in controllers:
        if c not in CONTROLLERS or not CONTROLLERS[c].ppc:
            continue
        for axis, lk, shown in levels:
            pt = groups.get((c, study, axis, lk))
            if pt is None or not pt.failures:
                continue
            fails = pt.failures
            causes = ", ".join(f"{k} {v}" for k, v in pt.causes().most_common())
            sat = Counter(r["first_saturation"] or "none" for r in fails)
            sat_text = ", ".join(f"{k} {v}" for k, v in sat.most_common())
            pairs = Counter(r["contact"] for r in fails if r["contact"])
            contacts = ", ".join(f"{k} {v}" for k, v in pairs.most_common()) or "–"
            lead = _median(
                str(float(r["violation_time"]) - float(r["first_saturation_time"]))
                for r in fails
                if r["first_saturation_time"] not in ("",) and r["violation_time"] != "inf"
            )
            out.append(
                f"| {CONTROLLERS[c].label} | {axis} | {shown} | {len(fails)}/{pt.n} | {causes} | "
                f"{sat_text} | {lead:.2f} | {_median(r['seen_steps_ago'] for r in fails):.0f} | "
                f"{_median(r['xi_d'] for r in fails):+.2f}, "
                f"{_median(r['xi_beta'] for r in fails):+.2f} | "
                f"{_median(r['xi_d_true'] for r in fails):+.2f}, "
                f"{_median(r['xi_beta_true'] for r in fails):+.2f} | "
                f"{_median(r['F_max_1s'] for r in fails):.2f} | "
                f"{_median(r['unseen_frac_1s'] for r in fails):.2f} | "
                f"{_median(r['omega_flips_1s'] for r in fails):.0f} | "
                f"{_median(r['u_peak_1s'] for r in fails):.2f}, "
                f"{_median(r['omega_peak_1s'] for r in fails):.2f} | {contacts} | "
                f"{_median(r['d_true'] for r in fails):.3f} |"
            )
    if len(out) == n0:
        return [f"PPC failure diagnostics ({study}): no PPC failures."]
    return out


def plot_study(
    rows: Iterable[dict[str, str]],
    keys: Iterable[tuple[str, ...]],
    study: str,
    controllers: Sequence[str],
    axes: Sequence[str],
    path: Path,
    *,
    quick: bool = False,
    metadata: dict[str, str] | None = None,
) -> Path:
    """``frontier_<study>.png``: a panel per axis, success rate against level, a line per
    controller, the Wilson 95 % intervals as bands (and error bars); ``metadata`` are the PNG
    text fields (the run's stamp)."""
    from platoon_env.plots import POLICY_COLOURS, new_figure, save_figure

    groups = _group(rows, keys)
    ncols = min(3, len(axes))
    nrows = math.ceil(len(axes) / ncols)
    fig = new_figure(4.2 * ncols, 3.2 * nrows + 0.5)
    panels = fig.subplots(nrows, ncols, squeeze=False)
    for idx, name in enumerate(axes):
        ax = panels[idx // ncols, idx % ncols]
        axis = AXES[name]
        levels = axis.quick if quick else axis.levels
        x = np.arange(len(levels), dtype=float)
        for j, c in enumerate(controllers):
            colour = POLICY_COLOURS[j % len(POLICY_COLOURS)]
            rate, lo, hi = [], [], []
            for level in levels:
                pt = groups.get((c, study, name, level_key(level)))
                if pt is None or pt.n == 0:
                    rate.append(math.nan)
                    lo.append(math.nan)
                    hi.append(math.nan)
                    continue
                ci_lo, ci_hi = wilson_interval(pt.successes, pt.n)
                rate.append(pt.successes / pt.n)
                lo.append(ci_lo)
                hi.append(ci_hi)
            r, a, b = np.array(rate), np.array(lo), np.array(hi)
            label = CONTROLLERS[c].label if c in CONTROLLERS else c
            shift = (j - (len(controllers) - 1) / 2) * 0.04
            ax.plot(x + shift, r, "o-", color=colour, lw=1.4, ms=4, label=label)
            ax.fill_between(x + shift, a, b, color=colour, alpha=0.15, lw=0)
            ax.errorbar(
                x + shift, r, yerr=[np.abs(r - a), np.abs(b - r)], fmt="none", ecolor=colour,
                elinewidth=0.8, capsize=2,
            )  # fmt: skip
        ax.set_xticks(x, [axis.show(level) for level in levels])
        ax.set_xlim(-0.5, len(levels) - 0.5)
        ax.set_ylim(-0.03, 1.03)
        ax.set_xlabel(axis.label)
        ax.set_ylabel("success rate")
        ax.grid(alpha=0.3)
    for idx in range(len(axes), nrows * ncols):
        panels[idx // ncols, idx % ncols].set_visible(False)
    panels[0, 0].legend(loc="lower left", fontsize=8)
    fig.suptitle(f"{study}: success rate against each realism axis (95 % Wilson intervals)")
    return save_figure(fig, path, metadata)


# ----------------------------------------------------------------------------------------------
# Workers
# ----------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------

_TOOL = "python -m experiments.studies.frontiers"


def add_study_options(parser: argparse.ArgumentParser, *, quick_help: str) -> None:
    """``--study``, ``--controller``, ``--quick`` (its help ``quick_help``) and
    ``--max-episode-steps``: the options of the drivers that run the analytic controllers on
    the paper's studies (this one and :mod:`experiments.studies.breaks`);
    :func:`finish_study_args` fills their defaults after parsing."""
    parser.add_argument("--study", action="append", choices=STUDIES, help="default: all three")
    parser.add_argument(
        "--controller",
        action="append",
        choices=sorted(CONTROLLERS),
        help=f"default: all available ({', '.join(CONTROLLERS)})",
    )
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument(
        "--max-episode-steps",
        type=count(1, "steps"),
        default=None,
        help="override every study's episode limit (for smoke tests; default: the study's)",
    )


def finish_study_args(args: argparse.Namespace, *, seeds: int, quick_seeds: int) -> None:
    """The defaults of :func:`add_study_options`' options: ``--seeds`` ``quick_seeds`` with
    ``--quick``, else ``seeds`` (the driver's defaults); every study and controller, each
    named once."""
    if args.seeds is None:
        args.seeds = quick_seeds if args.quick else seeds
    args.study = list(dict.fromkeys(args.study or STUDIES))
    args.controller = list(dict.fromkeys(args.controller or CONTROLLERS))


@dataclass
class GridRun:
    """What :func:`run_and_export` ran: the grid runner's result, the CSV rows (formatted), the
    provenance markdown of the run and its stamp (for the figures' metadata)."""

    result: GridResult
    rows: list[dict[str, str]]
    provenance: str
    stamp: dict[str, Any]


def run_and_export(
    tool: str,
    grid: Sequence[tuple[tuple[str, ...], Cell]],
    store_file: Path,
    args: argparse.Namespace,
    argv: Sequence[str] | None,
    csv_path: Path,
    *,
    key_columns: Sequence[str] = KEY_COLUMNS,
    columns: Sequence[str] = CSV_COLUMNS,
) -> GridRun | None:
    """Run ``grid``'s distinct episodes in ``store_file`` (resuming; ``args.workers``
    workers, stamped with ``tool`` and ``args``), then write its rows (:func:`rows_of`) to
    ``csv_path`` with the store's stamp beside it. None when interrupted (the finished
    episodes stay in the store; the message is printed)."""
    resolved = resolve_cells([cell for _, cell in grid], unique=False)
    unique = list({rc.key: rc for rc in resolved}.values())
    print(
        f"{store_file}: {len(grid)} rows in the grid, {len(unique)} distinct episodes, "
        f"on {args.workers} worker(s)"
    )
    stamp = metadata_stamp(tool, {k: str(v) for k, v in vars(args).items()}, argv)
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    with open_store(tool, store_file) as store:
        result = run_grid(store, unique, tool=tool, stamp=stamp, workers=args.workers)
        print(f"{result.ran} episode(s) run, {result.reused} already in the store")
        if result.interrupted:
            print(f"\ninterrupted: finished episodes are in {store.path}; re-run to resume")
            return None
        provenance = provenance_markdown(store, result.records.values(), result.run_id)
        raw = rows_of(grid, resolved, result, key_columns=key_columns, columns=columns)
        rows = [{k: format_value(v) for k, v in r.items()} for r in raw]
        write_csv(csv_path, columns, rows)
        write_csv_stamp(csv_path, store, result.records.values(), result.run_id)
    return GridRun(result, rows, provenance, stamp)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = new_parser(_TOOL, __doc__, out=Path("results/frontiers"))
    add_grid_options(
        parser, seeds=None, seeds_help=f"seeds per point (default {DEFAULT_SEEDS})", store=None
    )
    add_study_options(
        parser,
        quick_help=f"smoke run: {QUICK_SEEDS} seeds (unless --seeds) and two levels per axis",
    )
    parser.add_argument("--axis", action="append", choices=list(AXES), help="default: all")
    args = parser.parse_args(argv)
    finish_study_args(args, seeds=DEFAULT_SEEDS, quick_seeds=QUICK_SEEDS)
    args.axis = list(dict.fromkeys(args.axis or AXES))
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the grid (resuming), write ``frontiers.csv``, ``.md`` and the PNGs; returns the exit
    code (1 if an episode failed, 130 when interrupted)."""
    args = parse_args(argv)
    out: Path = args.out
    grid, notes = build_grid(
        args.study,
        args.controller,
        args.axis,
        args.seeds,
        quick=args.quick,
        max_episode_steps=args.max_episode_steps,
    )
    if "profile" in args.axis and not any(n.startswith("profile=") for n in notes):
        from platoon_env.scenarios.profiles import load_profile

        for name in AXES["profile"].levels:
            blocks = json.dumps(load_profile(str(name)), sort_keys=True)
            notes.append(f"profile {name}: the shipped profile's blocks {blocks}")
    for note in notes:
        print(f"note: {note}")
    keys = [k for k, _ in grid]
    run = run_and_export(_TOOL, grid, store_path(out), args, argv, out / "frontiers.csv")
    if run is None:
        return 130
    result, rows, provenance = run.result, run.rows, run.provenance
    table = summarise(rows, keys, args.study, args.controller, args.axis, quick=args.quick)
    header = (
        "# Robustness frontiers\n\n"
        f"Success (the episode ends by truncation without any violation; every violation ends "
        f"it) over {args.seeds} seeds per point, each realism axis alone; cells are "
        "successes/seeds [Wilson 95 % interval]; the dominant failure is the most frequent "
        "first violation among the failed episodes. Controllers: "
        f"{', '.join(CONTROLLERS[c].label for c in args.controller)}. "
        f"{len(rows)} of {len(grid)} rows have a result; wall time of this run "
        f"{result.wall_time:.0f} s.\n\n"
        + "".join(f"- note: {n}\n" for n in notes)
        + provenance
        + "\n"
    )
    write_text_atomic(out / "frontiers.md", header + table + "\n")
    paths = [
        plot_study(
            rows,
            keys,
            s,
            args.controller,
            args.axis,
            out / f"frontier_{s}.png",
            quick=args.quick,
            metadata=png_metadata(run.stamp),
        )
        for s in args.study
    ]
    print(table)
    print(f"wrote {out / 'frontiers.csv'}, {out / 'frontiers.md'}, " + ", ".join(map(str, paths)))
    return failed_episodes(result)


if __name__ == "__main__":
    raise SystemExit(main())
