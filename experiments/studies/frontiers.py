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
follower, the step count, the minimum obstacle clearance and, for the PPC laws, the signals that
explain a failure (:func:`experiments.robustness.ppc_diagnostics`): which funnel saturated first
and when, and the normalised errors just before the violation, as perceived and as true. Each
episode is written in its own transaction as it finishes; a re-run with the same ``--out`` runs
only what the store lacks (keys are content fingerprints, so another ``--max-episode-steps`` or
edited study runs anew beside the old rows), and two runs into one ``--out`` share the work.
Identical configurations (the ideal level shared by every axis) have one key and run once per
seed. ``OUT/frontiers.csv`` (:data:`CSV_COLUMNS`) is an export of the grid's rows.

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
from pathlib import Path
from typing import Any

import numpy as np

from experiments.axes import AXES, Axis, level_key
from experiments.cli import add_grid_options, failed_episodes, new_parser
from experiments.grid import Cell, store_path
from experiments.report import wilson, write_text_atomic
from experiments.robustness import (
    CONTROLLERS,
    OUTCOME_COLUMNS,
    Point,
    add_study_options,
    episode_row,
    finish_study_args,
    run_and_export,
    study_grid,
)
from experiments.stamp import png_metadata
from experiments.suites import STUDIES
from platoon_env.scenarios.profiles import load_profile

__all__ = [
    "AXES",
    "CONTROLLERS",
    "CSV_COLUMNS",
    "KEY_COLUMNS",
    "STUDIES",
    "Axis",
    "build_grid",
    "episode_row",
    "level_key",
    "main",
    "summarise",
    "wilson_interval",
]


#: Columns that identify a row (one episode); a resumed run skips the keys already written.
KEY_COLUMNS: tuple[str, ...] = ("controller", "study", "axis", "level", "seed")

#: Columns of ``frontiers.csv``.
CSV_COLUMNS: tuple[str, ...] = (*KEY_COLUMNS, *OUTCOME_COLUMNS, "wall_time")

DEFAULT_SEEDS = 10
QUICK_SEEDS = 2


# ----------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------

#: The measure of a frontier episode (:func:`experiments.robustness.episode_row`, imported
#: here). The store keys every episode by this string, so it names this module, where the
#: function was first defined, and must stay byte-identical for the existing stores to match;
#: the workers resolve it through this module's ``episode_row``.
MEASURE = "experiments.studies.frontiers:episode_row"


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
    is left out with a note. Long episodes (study C) come first (:func:`study_grid`).
    """
    notes: list[str] = []
    points: list[tuple[tuple[str, str], dict[str, Any]]] = []  # (axis, level key), overrides
    for name in axes:
        axis = AXES[name]
        for level in axis.quick if quick else axis.levels:
            try:
                level_overrides = axis.overrides(level)
            except Exception as exc:
                notes.append(f"{name}={level_key(level)} skipped: {type(exc).__name__}: {exc}")
                continue
            points.append(((name, level_key(level)), level_overrides))
    grid = study_grid(
        studies,
        controllers,
        seeds,
        dict.fromkeys(studies, points),
        measure=MEASURE,
        max_episode_steps=max_episode_steps,
    )
    return grid, notes


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
# Command line
# ----------------------------------------------------------------------------------------------

_TOOL = "python -m experiments.studies.frontiers"


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
        for name in AXES["profile"].levels:
            blocks = json.dumps(load_profile(str(name)), sort_keys=True)
            notes.append(f"profile {name}: the shipped profile's blocks {blocks}")
    for note in notes:
        print(f"note: {note}")
    keys = [k for k, _ in grid]
    run = run_and_export(
        _TOOL,
        grid,
        store_path(out),
        args,
        argv,
        out / "frontiers.csv",
        key_columns=KEY_COLUMNS,
        columns=CSV_COLUMNS,
    )
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
