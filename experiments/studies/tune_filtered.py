r"""Choose the drive-aware filtered PPC's lookahead on training layouts (paper, Remark 3).

Usage::

    python -m experiments.studies.tune_filtered [--out results/tune_filtered] [--episodes 40]
        [--workers 2] [--scenario NAME ...] [--tau-r 0.1 0.2 ...] [--phi 0 1]
        [--table baselines/data/filtered_ppc_drive.yaml] [--max-steps N] [--quick]

:class:`baselines.filtered_ppc_drive.DriveAwareFilteredPPCPolicy` shows the filtered PPC's
inner law the predecessor ``tau = robot.lag + tau_r`` seconds ahead on a rate-limited drive,
moving the predecessor on for ``phi tau`` (module docstring there). This driver runs every
point of the grid ``--tau-r`` x ``--phi`` under the ``aruco`` sensor profile on the same
episodes of each ``--scenario`` (seeds ``0..E-1``: common random numbers across the grid),
through the evaluation store (:func:`experiments.grid.run_grid`: resumable, ``--workers``),
and writes the best point to the table (``--table``, default the shipped
:data:`baselines.filtered_ppc_drive.DEFAULT_TABLE`) with its provenance and every point's
value.

**Training layouts only.** Each scenario must be a procedural ``train`` split
(:func:`experiments.tuning.check_training_scenario` refuses a study map or a test
split). The defaults are the two tiers the residual configurations train on, whose layouts
draw a formation each (1-7 followers, the three studies' geometry ranges): one setting for
every formation, since the residual's base law must run on all of them.

**Objective** (maximised; :func:`experiments.tuning.objective_value`): the fraction
of episodes without a violation, plus ``0.1`` times the mean of
``min(time_to_violation, T) / T`` over the episodes (``T`` the tier's episode length), pooled
over the scenarios. Ties go to the smaller ``tau_r``, then to ``phi = 1`` (the filtered
PPC's own rule), so the filtered PPC's point (``tau_r = 0.1``, ``phi = 1``) wins unless
another is strictly better.

Outputs: the table, and ``OUT/tune_filtered.md`` (the grid: successes per scenario and the
objective per point).

``python -m experiments.studies.tune_filtered report [--seeds 20]`` then evaluates, on the
paper's studies the search never saw (A, B, C; ideal and aruco), the filtered PPC, the
drive-aware one and each half of the change alone (:func:`report_policies`), and writes
``OUT/report.md`` (:func:`run_report`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

import platoon_env
from baselines.filtered_ppc import FilterParams
from baselines.filtered_ppc_drive import DEFAULT_TABLE, TABLE_KEYS, load_drive_table
from experiments.cli import count
from experiments.grid import Cell, GridResult, run_grid, store_path
from experiments.policies import PolicySpec
from experiments.report import write_text_atomic
from experiments.significance import compare, task_rate
from experiments.stamp import metadata_stamp
from experiments.suites import suite
from experiments.tuning import TIE_BREAK, check_training_scenario, objective_value

__all__ = [
    "DEFAULT_SCENARIOS",
    "PROFILE",
    "best_point",
    "grid_cells",
    "main",
    "report_policies",
    "run_report",
    "table_text",
]

#: The residual configurations' training tiers (a formation drawn per layout).
DEFAULT_SCENARIOS: tuple[str, ...] = (
    "procedural_formations_sharp_train",
    "procedural_formations_paper_train",
)
#: The sensor profile the search runs under.
PROFILE = "aruco"
DEFAULT_TAU_R: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)
DEFAULT_PHI: tuple[float, ...] = (0.0, 0.5, 1.0)
COMMAND = "python -m experiments.studies.tune_filtered"


def _spec(tau_r: float, phi: float) -> PolicySpec:
    return PolicySpec.of(
        "filtered_ppc_drive",
        f"tau_r={tau_r:g},phi={phi:g}",
        lookahead_rate_limited=float(tau_r),
        lookahead_predecessor=float(phi),
    )


def _overrides(max_steps: int | None) -> dict[str, Any]:
    """The cells' ``make()`` overrides: :data:`PROFILE`, and a shorter step limit if given."""
    extra = {} if max_steps is None else {"max_episode_steps": int(max_steps)}
    return {"sensor_profile": PROFILE, **extra}


def grid_cells(
    scenarios: Sequence[str],
    tau_r: Sequence[float],
    phi: Sequence[float],
    episodes: int,
    max_steps: int | None = None,
) -> list[Cell]:
    """One cell per grid point, scenario and seed ``0..episodes-1``, under :data:`PROFILE`
    (and ``max_steps`` steps at most, if given)."""
    return [
        Cell.of(_spec(t, f), scenario, seed, _overrides(max_steps))
        for t in tau_r
        for f in phi
        for scenario in scenarios
        for seed in range(episodes)
    ]


def _horizon(scenario: str, max_steps: int | None) -> float:
    """[s] the episode length of ``scenario`` under :data:`PROFILE` (``max_steps``: at most)."""
    env = platoon_env.make(scenario, **_overrides(max_steps))
    return float(env.max_episode_steps * env.control_period)


def best_point(values: dict[tuple[float, float], float]) -> tuple[float, float]:
    """The grid point with the highest value; ties to the smaller ``tau_r``, then ``phi = 1``."""
    return min(values, key=lambda p: (-values[p], p[0], -p[1]))


def table_text(provenance: dict[str, Any], params: dict[str, float], grid: list[Any]) -> str:
    """The YAML of a table, with a header saying how it is made."""
    header = (
        "# The drive-aware filtered PPC's lookahead (baselines/filtered_ppc_drive.py). Written by\n"
        f"# {COMMAND}: do not edit by hand (the provenance would no longer\n"
        "# describe the numbers); re-run the search instead.\n"
    )
    body = {"provenance": provenance, "params": params, "grid": grid}
    return header + yaml.safe_dump(body, sort_keys=False, width=100)


# ----------------------------------------------------------------------------------------------
# The report: the paper's studies, never seen by the search
# ----------------------------------------------------------------------------------------------


def report_policies() -> dict[str, PolicySpec]:
    """The report's columns: the filtered PPC, the drive-aware one (the table's point), and
    the two halves of the change alone (the table's ``tau_r`` with ``phi = 1``; ``phi = 0``
    with the filtered PPC's ``tau_r``)."""
    table = load_drive_table()
    tau_r, phi = table.lookahead_rate_limited, table.lookahead_predecessor
    own = FilterParams.LOOKAHEAD_RATE_LIMITED
    return {
        "filtered PPC": PolicySpec.of("filtered_ppc"),
        "drive-aware filtered PPC": PolicySpec.of("filtered_ppc_drive"),
        f"tau_r = {tau_r:g} s alone (phi = 1)": _spec(tau_r, 1.0),
        f"phi = {phi:g} alone (tau_r = {own:g} s)": _spec(own, phi),
    }


def run_report(args: argparse.Namespace) -> int:
    """Every report policy on the paper suite (studies A, B, C; ideal and aruco), seeds
    ``0..seeds-1``; writes ``OUT/report.md``: successes with Wilson intervals, and the
    drive-aware law against the filtered PPC per task (Fisher's exact test, Holm over the six
    tasks)."""
    specs = report_policies()
    paper = suite("paper")
    cells = {
        (name, f"{scenario}/{cond.label}", seed): Cell.of(spec, scenario, seed, cond.overrides)
        for name, spec in specs.items()
        for cond in paper.conditions
        for scenario in paper.scenarios
        for seed in range(args.seeds)
    }
    stamp = metadata_stamp("tune_filtered report", {"seeds": args.seeds}, None)
    args.out.mkdir(parents=True, exist_ok=True)
    result = run_grid(
        store_path(args.out), list(cells.values()), tool="tune_filtered report", stamp=stamp,
        workers=args.workers, batch=args.batch,
    )  # fmt: skip
    key_of = {rc.cell: rc.key for rc in result.cells}
    counts: dict[str, dict[str, list[int]]] = {}
    for (name, task, _seed), cell in cells.items():
        rec = result.records.get(key_of[cell])
        if rec is None or rec.status != "done":
            continue
        k_n = counts.setdefault(name, {}).setdefault(task, [0, 0])
        k_n[0] += bool(rec.metrics.get("success"))
        k_n[1] += 1
    rates = {n: {t: (k, m) for t, (k, m) in per.items()} for n, per in counts.items()}
    tasks = [f"{s}/{c.label}" for c in paper.conditions for s in paper.scenarios]
    names = list(specs)
    lines = [
        f"The paper's studies, seeds 0..{args.seeds - 1} (made by `{COMMAND} report`; store "
        f"`{store_path(args.out)}`, run {result.run_id}, {result.ran} episodes run now, "
        f"{result.reused} reused). Success: successes/episodes [95 % Wilson interval].",
        "",
        "| task | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for task in tasks:
        row = [str(task_rate(*rates[n][task])) if task in rates.get(n, {}) else "–"
               for n in names]  # fmt: skip
        lines.append(f"| {task} | " + " | ".join(row) + " |")
    a, b = names[1], names[0]
    lines += [
        "",
        f"{a} against {b}, per task: difference in success [95 % Newcombe interval], "
        "Fisher's exact p, Holm-adjusted over the tasks tested (ties at the floor or the "
        "ceiling are flagged, not tested).",
        "",
        "| task | difference | p | p (Holm) | verdict |",
        "|---|---|---|---|---|",
    ]
    for c in compare(rates, [(a, b)]):
        d = c.difference
        lines.append(
            f"| {c.task} | {d.value:+.2f} [{d.low:+.2f}, {d.high:+.2f}] | "
            f"{'–' if c.tie else f'{c.p_value:.2g}'} | {'–' if c.tie else f'{c.p_holm:.2g}'} | "
            f"{c.verdict} |"
        )
    text = "\n".join(lines) + "\n"
    write_text_atomic(args.out / "report.md", text)
    print(text)
    return 1 if result.failed or result.interrupted else 0


def main(argv: Sequence[str] | None = None) -> int:
    given = list(sys.argv[1:] if argv is None else argv)
    if given[:1] == ["report"]:
        return run_report(parse_report_args(given[1:]))
    args = parse_args(argv)
    episodes = args.episodes or (2 if args.quick else 40)
    horizons = {name: _horizon(name, args.max_steps) for name in args.scenario}
    cells = grid_cells(args.scenario, args.tau_r, args.phi, episodes, args.max_steps)
    config = {"episodes": episodes, "scenarios": args.scenario, "tau_r": args.tau_r,
              "phi": args.phi, "max_steps": args.max_steps}  # fmt: skip
    stamp = metadata_stamp("tune_filtered", config, argv)
    args.out.mkdir(parents=True, exist_ok=True)
    result = run_grid(
        store_path(args.out), cells, tool="tune_filtered", stamp=stamp, workers=args.workers
    )
    if result.interrupted or result.failed:
        print(f"{COMMAND}: {len(result.failed)} episode(s) failed or the run was interrupted; "
              "the table is not written", file=sys.stderr)  # fmt: skip
        return 1
    values, grid, lines = score_points(result, args.scenario, horizons, episodes)
    best = best_point(values)
    params = dict(zip(TABLE_KEYS, best, strict=True))
    provenance = {
        "command": " ".join([COMMAND, *(sys.argv[1:] if argv is None else argv)]),
        "commit": stamp.get("commit", ""),
        "uncommitted_changes": sorted(stamp.get("modified") or []),
        "objective": "pooled over the scenarios: fraction of episodes without a violation + "
        f"{TIE_BREAK} x mean min(time_to_violation, T)/T (T the tier's episode length)",
        "sensor_profile": PROFILE,
        "scenarios": list(args.scenario),
        "seeds": f"0..{episodes - 1}",
        "max_episode_steps": args.max_steps,
        "wall_time_s": round(result.wall_time, 1),
    }
    write_text_atomic(args.table, table_text(provenance, params, grid))
    load_drive_table(args.table)  # what was written validates
    summary = (
        f"Grid of the drive-aware filtered PPC under `{PROFILE}` on training layouts "
        f"({episodes} seeds per scenario; made by `{COMMAND}`). Best: tau_r = {best[0]:g} s, "
        f"phi = {best[1]:g}.\n\n" + "\n".join(lines) + "\n"
    )
    write_text_atomic(args.out / "tune_filtered.md", summary)
    print(summary)
    print(f"table written to {args.table}")
    return 0


def parse_report_args(argv: Sequence[str]) -> argparse.Namespace:
    """The options of ``report`` (the arguments after it)."""
    rp = argparse.ArgumentParser(
        prog=f"{COMMAND} report", description=run_report.__doc__, allow_abbrev=False
    )
    rp.add_argument("--out", type=Path, default=Path("results/tune_filtered"))
    rp.add_argument("--seeds", type=count(1), default=20)
    rp.add_argument("--workers", type=count(1), default=2)
    rp.add_argument("--batch", type=count(0), default=20, help="episodes per batched core")
    return rp.parse_args(argv)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The options of the grid search, checked: training scenarios only, ``tau_r >= 0`` and
    ``phi`` in [0, 1] (a usage error otherwise)."""
    ap = argparse.ArgumentParser(
        prog=COMMAND, description=__doc__.split("\n\n")[0], allow_abbrev=False
    )
    ap.add_argument("--out", type=Path, default=Path("results/tune_filtered"))
    ap.add_argument("--episodes", type=count(1), default=None, help="seeds per scenario (40)")
    ap.add_argument("--workers", type=count(1), default=2)
    ap.add_argument("--scenario", nargs="+", default=list(DEFAULT_SCENARIOS))
    ap.add_argument("--tau-r", type=float, nargs="+", default=list(DEFAULT_TAU_R))
    ap.add_argument("--phi", type=float, nargs="+", default=list(DEFAULT_PHI))
    ap.add_argument("--table", type=Path, default=DEFAULT_TABLE, help="the table written")
    ap.add_argument("--max-steps", type=count(1), default=None, help="a shorter step limit (tests)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 2 seeds per scenario")
    args = ap.parse_args(argv)
    for name in args.scenario:
        try:
            check_training_scenario(name)
        except ValueError as exc:
            ap.error(str(exc))
    for t in args.tau_r:
        if not (math.isfinite(t) and t >= 0):
            ap.error(f"--tau-r values must be finite and >= 0, got {t}")
    for f in args.phi:
        if not 0 <= f <= 1:
            ap.error(f"--phi values must be in [0, 1], got {f}")
    return args


def score_points(
    result: GridResult,
    scenarios: Sequence[str],
    horizons: Mapping[str, float],
    episodes: int,
) -> tuple[dict[tuple[float, float], float], list[dict[str, Any]], list[str]]:
    """The objective of each grid point ``(tau_r, phi)`` (:func:`objective_value`, pooled over
    the scenarios, each over its own horizon, weighted by its episodes), the table's ``grid``
    rows, and the markdown table's lines."""
    by_point: dict[tuple[float, float], dict[str, list[dict[str, Any]]]] = {}
    for rc, rec in result.finished():
        spec = json.loads(rc.cell.policy.params)
        point = (spec["lookahead_rate_limited"], spec["lookahead_predecessor"])
        by_point.setdefault(point, {}).setdefault(rc.cell.scenario, []).append(rec.metrics)
    values: dict[tuple[float, float], float] = {}
    grid: list[dict[str, Any]] = []
    lines = ["| tau_r [s] | phi | " + " | ".join(f"{s}: no violation" for s in scenarios)
             + " | objective |", "|---|---|" + "---|" * len(scenarios) + "---|"]  # fmt: skip
    for point in sorted(by_point):
        per = by_point[point]
        # pooled: each scenario's objective over its own horizon, weighted by its episodes
        value = sum(objective_value(per[s], horizons[s]) * len(per[s]) for s in scenarios) / sum(
            len(per[s]) for s in scenarios
        )
        values[point] = value
        safe = {s: sum(m["violation"] == "" for m in per[s]) for s in scenarios}
        grid.append(
            {
                "lookahead_rate_limited": point[0],
                "lookahead_predecessor": point[1],
                "value": round(value, 6),
                "no_violation": safe,
                "episodes": episodes,
            }
        )
        lines.append(f"| {point[0]:g} | {point[1]:g} | "
                     + " | ".join(f"{safe[s]}/{len(per[s])}" for s in scenarios)
                     + f" | {value:.4f} |")  # fmt: skip
    return values, grid, lines


if __name__ == "__main__":
    raise SystemExit(main())
