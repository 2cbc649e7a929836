"""What the robustness studies share: their controllers, the outcome of one episode with the
signals that explain a failure, and running a grid of them into the store and a CSV.

The robustness frontiers (:mod:`experiments.studies.frontiers`: one realism axis at a time) and
the profile taken apart (:mod:`experiments.studies.breaks`) run the same analytic controllers
(:data:`CONTROLLERS`) on the paper's studies with every violation ending the episode
(:func:`episode_overrides`), and record the same row per episode (:func:`episode_row`: the
outcome, the first violation, the PPC failure diagnostics of :func:`ppc_diagnostics` and the
failure signals of :func:`failure_diagnostics`); each names its own grid and key columns and
adds its own columns. Both drivers import this module, and it imports neither.
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from baselines.ppc import EPS_MAX
from experiments.cli import count, open_store
from experiments.grid import Cell, GridResult, ResolvedCell, resolve_cells, run_grid
from experiments.policies import PolicySpec, analytic_policies
from experiments.report import (
    format_value,
    provenance_markdown,
    wilson,
    write_csv,
    write_csv_stamp,
)
from experiments.stamp import metadata_stamp
from experiments.suites import STUDIES
from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D
from platoon_env.rollout import Episode, episode_metrics
from platoon_env.scenarios.schema import VIOLATION_CAUSES

__all__ = [
    "CONTROLLERS",
    "DIAGNOSTIC_COLUMNS",
    "FAILURE_COLUMNS",
    "OUTCOME_COLUMNS",
    "REFUSED",
    "Controller",
    "GridRun",
    "Point",
    "add_study_options",
    "diagnosed_follower",
    "episode_overrides",
    "episode_row",
    "failure_diagnostics",
    "finish_study_args",
    "ppc_diagnostics",
    "rows_of",
    "run_and_export",
    "study_grid",
]

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

#: The outcome columns of :func:`episode_row`, in the order the CSVs write them (after a
#: study's key columns, before ``wall_time``).
OUTCOME_COLUMNS: tuple[str, ...] = (
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
)

#: The window before a violation over which ``F_max_1s`` and ``unseen_frac_1s`` are taken [s].
DIAGNOSTIC_WINDOW = 1.0


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


def study_grid(
    studies: Sequence[str],
    controllers: Sequence[str],
    seeds: int,
    points: Mapping[str, Sequence[tuple[tuple[str, ...], Mapping[str, Any]]]],
    *,
    measure: str,
    max_episode_steps: int | None = None,
) -> list[tuple[tuple[str, ...], Cell]]:
    """A robustness study's grid as (row key, cell): every seed, study, controller (by name,
    :data:`CONTROLLERS`) and point of the study (``points[study]``: the point's part of the
    key and its overrides, before :func:`episode_overrides`), keyed ``(controller, study,
    *part, seed)`` (all strings), each episode measured by ``measure``; the PPC laws record
    their signals. Long episodes (study C) come first, so that the last worker does not run
    alone for long."""
    order = sorted(studies, key=lambda s: -STUDIES.index(s) if s in STUDIES else 0)
    grid: list[tuple[tuple[str, ...], Cell]] = []
    for seed in range(seeds):
        for study in order:
            for ctrl in controllers:
                c = CONTROLLERS[ctrl]
                for part, ov in points[study]:
                    cell = Cell.of(
                        c.spec, study, seed, episode_overrides(ov, max_episode_steps),
                        measure=measure, record_signals=c.ppc,
                    )  # fmt: skip
                    grid.append(((ctrl, study, *part, str(seed)), cell))
    return grid


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
    key_columns: Sequence[str],
    columns: Sequence[str],
) -> list[dict[str, Any]]:
    """The CSV rows (``columns``) of the grid's points that have a result (``resolved``: the
    grid's cells resolved in order, one per point); each point's key is named by
    ``key_columns`` (each study's grid names its own)."""
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


@dataclass
class Point:
    """The episodes of one point of a study (e.g. controller x study x axis x level), as CSV
    rows."""

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
        lo, hi = wilson(self.successes, self.n)
        return f"{self.successes}/{self.n} [{lo:.2f}, {hi:.2f}]"

    def dominant(self) -> str:
        fails = self.failures
        if not fails:
            return "–"
        cause, count = self.causes().most_common(1)[0]
        return f"{cause} ({count}/{len(fails)})"


# ----------------------------------------------------------------------------------------------
# Options and the run
# ----------------------------------------------------------------------------------------------


def add_study_options(parser: argparse.ArgumentParser, *, quick_help: str) -> None:
    """``--study``, ``--controller``, ``--quick`` (its help ``quick_help``) and
    ``--max-episode-steps``: the options of the drivers that run the analytic controllers on
    the paper's studies (:mod:`experiments.studies.frontiers` and
    :mod:`experiments.studies.breaks`);
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
    key_columns: Sequence[str],
    columns: Sequence[str],
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
