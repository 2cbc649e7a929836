r"""Tune the PPC law's parameters per formation under the ``aruco`` profile (paper, Remark 3).

``python -m experiments.studies.tune_ppc`` searches, for each formation of the paper's studies
(:data:`experiments.suites.STUDIES`), the seven parameters of eqs. 12-14 (``lambda_``,
``rho_d_inf``, ``rho_beta_inf`` of eq. 12, ``k_d`` of eq. 13, ``k_beta`` of eq. 14, ``delta``
and ``epsilon`` after eq. 12) with Optuna's seeded TPE sampler and a fixed trial budget, and
writes the table :data:`baselines.ppc_tuned.DEFAULT_TABLE` with its provenance.

**Where it tunes: training layouts only.** Each trial runs the same few episodes (seeds
``0..E-1``, so trials are compared on common random numbers) of a procedural ``train`` split
(default ``procedural_medium_train``), never a study map nor a ``test`` split
(:func:`experiments.tuning.check_training_scenario` refuses both), with

* the formation overridden to the study's (:func:`formation_overrides`): ``followers``, the
  robots' radius and velocity bounds, the camera's and proximity sensor's geometry, the safety
  block, ``formation`` and the study's own ``ppc`` block, and the study leader's (mean) speed;
  the generator sizes each layout for the platoon it gets (a start stretch of
  ``followers * d_des + 1`` m, corridor widths from ``r``), so study A's 7 followers at
  ``d_des = 2`` m fit;
* ``sensor_profile="aruco"`` (30 Hz frames, 50 ms latency, noise, acceleration limits);
* ``max_episode_steps`` shortened (default 4000 steps = 40 s): PPC's failures under aruco come
  within seconds, and the shortened horizon keeps the search within its compute budget.

**Objective** (maximised; :func:`experiments.tuning.objective_value`): the fraction of
episodes without any violation within the horizon, plus a tie-break of ``0.1`` times the mean
of ``min(time_to_violation, T) / T`` (``T`` the horizon), which orders trials that fail
equally often by how long they last. Trial 0 is the study's own gains (``enqueue_trial``), so
the best value is never below theirs on these episodes (``baseline_value`` in the table).

Each formation's search runs in its own process (``--workers``, default 2), its trials one
after another; progress goes to ``--log``. ``--timeout`` bounds each formation's search in wall
time (the table records the trials actually run).

``python -m experiments.studies.tune_ppc report`` evaluates ``ppc`` and ``ppc_tuned`` through
the evaluation store (:func:`experiments.grid.run_grid`): the paper suite (studies A, B, C,
ideal and aruco) and a sweep on study B over camera latency × ``accel_max`` on top of the
aruco camera and proximity models, and rewrites the generated block of ``docs/realism.md``
named :data:`REPORT_COMMAND`.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import platoon_env
from baselines.ppc import PPCPolicy
from baselines.ppc_tuned import (
    DEFAULT_TABLE,
    TUNED_KEYS,
    formation_geometry,
    load_table,
    table_text,
)
from experiments.cli import count, number
from experiments.grid import Cell, run_grid, store_path
from experiments.policies import REGISTRY, PolicySpec
from experiments.report import write_text_atomic
from experiments.significance import task_rate
from experiments.stamp import REPO_ROOT, metadata_stamp
from experiments.suites import STUDIES, suite
from experiments.tuning import TIE_BREAK, check_training_scenario, objective_value
from platoon_env.rollout import episode_metrics, run_episode
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.profiles import load_profile
from platoon_env.scenarios.schema import ScenarioConfig, config_to_mapping

__all__ = [
    "DOC",
    "REPORT_COMMAND",
    "SEARCH_COMMAND",
    "formation_overrides",
    "main",
    "search_formation",
    "sweep_conditions",
]

#: The command of the search (named in the table's provenance).
SEARCH_COMMAND = "python -m experiments.studies.tune_ppc"
#: The command that writes the generated block of :data:`DOC`.
REPORT_COMMAND = "python -m experiments.studies.tune_ppc report"
#: The page the report block is in.
DOC = REPO_ROOT / "docs" / "realism.md"
#: Sweep on study B: camera latencies [s] × bounds on the applied linear acceleration [m/s^2]
#: (None: no bound), on top of the aruco camera and proximity models.
SWEEP_LATENCIES: tuple[float, ...] = (0.0, 0.03, 0.05)
SWEEP_ACCEL: tuple[float | None, ...] = (None, 1.0)
#: The policies the report compares.
REPORT_POLICIES: tuple[str, ...] = ("ppc", "ppc_tuned")


# ----------------------------------------------------------------------------------------------
# What the search runs
# ----------------------------------------------------------------------------------------------


def formation_overrides(study: str) -> dict[str, Any]:
    """The ``make()`` overrides that put ``study``'s platoon (not its map) on another scenario:
    followers, robot radius and velocity bounds, camera and proximity geometry, the safety,
    formation and ppc blocks, and the leader's (mean) speed."""
    cfg = load_config(study)
    data = config_to_mapping(cfg)
    out: dict[str, Any] = {
        "followers": cfg.followers,
        "robot": {
            "radius": cfg.robot.radius,
            "u_max": cfg.robot.u_max,
            "omega_max": cfg.robot.omega_max,
        },
        "camera": {"half_angle": cfg.camera.half_angle, "range": cfg.camera.range},
        "safety": data["safety"],
        "formation": data["formation"],
        "ppc": data["ppc"],
        "leader": {"speed": cfg.leader.speed},
    }
    proximity = {k: v for k, v in data.get("proximity", {}).items() if k in ("half_angle", "range")}
    if proximity:
        out["proximity"] = proximity
    return out


def _suggest(trial: Any, cfg: ScenarioConfig) -> dict[str, float]:
    """One trial's parameters, in ranges inside PPCParams' rules for the formation ``cfg``
    (``2 rho_d_inf < min(d_des - d_col, d_con - d_des)``, ``2 rho_beta_inf < beta_con``)."""
    g = formation_geometry(cfg)
    room = min(g["d_des"] - g["d_col"], g["d_con"] - g["d_des"])
    return {
        "lambda_": trial.suggest_float("lambda_", 0.1, 3.0, log=True),
        "rho_d_inf": trial.suggest_float("rho_d_inf", 0.02, 0.45 * room),
        "rho_beta_inf": trial.suggest_float("rho_beta_inf", 0.02, 0.45 * g["beta_con"]),
        "k_d": trial.suggest_float("k_d", 0.05, 5.0, log=True),
        "k_beta": trial.suggest_float("k_beta", 0.05, 5.0, log=True),
        "delta": trial.suggest_float("delta", 0.1, 1.0),
        "epsilon": trial.suggest_float("epsilon", 0.3, 0.95),
    }


def _log(path: Path | None, text: str) -> None:
    line = f"{time.strftime('%H:%M:%S')} {text}"
    if path is None:
        print(line, flush=True)
        return
    with path.open("a") as fh:
        fh.write(line + "\n")


def search_formation(
    study: str,
    *,
    scenario: str,
    trials: int,
    episodes: int,
    max_steps: int,
    seed: int,
    timeout: float | None,
    log: Path | None = None,
) -> dict[str, Any]:
    """Run the search for ``study``'s formation; returns its table row (see
    :func:`baselines.ppc_tuned.load_table`) and the wall time."""
    import optuna

    check_training_scenario(scenario)
    overrides = {**formation_overrides(study), "max_episode_steps": max_steps}
    env = platoon_env.make(scenario, sensor_profile="aruco", **overrides)
    cfg = env.scenario.config
    horizon = max_steps * float(env.control_period)
    own = {k: float(getattr(PPCPolicy(env).params, k)) for k in TUNED_KEYS}

    def objective(trial: Any) -> float:
        policy = PPCPolicy(env, **_suggest(trial, cfg))
        metrics = [episode_metrics(run_episode(env, policy, seed=s, record_signals=False))
                   for s in range(episodes)]  # fmt: skip
        value = objective_value(metrics, horizon)
        _log(log, f"{study} trial {trial.number}: {value:.3f} {trial.params}")
        return value

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study_ = optuna.create_study(
        direction="maximize", sampler=optuna.samplers.TPESampler(seed=seed)
    )
    study_.enqueue_trial(own)  # trial 0: the study's own gains
    start = time.perf_counter()
    study_.optimize(objective, n_trials=trials, timeout=timeout)
    values = [float(t.value) for t in study_.trials if t.value is not None]
    best = study_.best_trial
    assert best.value is not None  # the best of the finished trials
    _log(log, f"{study} done: {len(values)} trials, best {best.value:.3f} (trial {best.number})")
    return {
        "name": study,
        "row": {
            "geometry": formation_geometry(cfg),
            "params": {k: float(best.params[k]) for k in TUNED_KEYS},
            "followers": cfg.followers,
            "best_value": float(best.value),
            "baseline_value": values[0],
            "trials": len(values),
        },
        "wall_time": time.perf_counter() - start,
    }


def _commit() -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        )
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return out.stdout.strip()


def run_search(args: argparse.Namespace, argv: Sequence[str]) -> int:
    """The search of every formation; writes the table."""
    check_training_scenario(args.scenario)
    kwargs = {
        "scenario": args.scenario,
        "trials": args.trials,
        "episodes": args.episodes,
        "max_steps": args.max_steps,
        "seed": args.seed,
        "timeout": args.timeout,
        "log": args.log,
    }
    start = time.perf_counter()
    _log(
        args.log, f"search: {args.formation} on {args.scenario}, {json.dumps(kwargs, default=str)}"
    )
    if args.workers <= 1:
        results = [search_formation(s, **kwargs) for s in args.formation]
    else:
        with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(search_formation, s, **kwargs) for s in args.formation]
            results = [f.result() for f in futures]
    wall = time.perf_counter() - start
    command = " ".join([SEARCH_COMMAND, *argv])
    provenance = {
        "command": command,
        "commit": _commit(),
        "objective": (
            "mean over the trial's episodes of [no violation within the horizon] + "
            f"{TIE_BREAK} x mean min(time_to_violation, T)/T; sensor_profile aruco; "
            f"{args.scenario} (train layouts) with each study's formation"
        ),
        "sampler": f"optuna {_optuna_version()} TPESampler(seed={args.seed}); trial 0 = the "
        "study's own gains",
        "scenario": args.scenario,
        "sensor_profile": "aruco",
        "episodes_per_trial": args.episodes,
        "seeds": f"0..{args.episodes - 1}",
        "max_episode_steps": args.max_steps,
        "trial_budget": args.trials,
        "timeout_per_formation_s": args.timeout,
        "wall_time_s": round(wall, 1),
    }
    rows = {r["name"]: r["row"] for r in results}
    write_text_atomic(args.out, table_text(provenance, rows))
    _log(args.log, f"wrote {args.out} ({wall:.0f} s)")
    return 0


def _optuna_version() -> str:
    import optuna

    return str(optuna.__version__)


# ----------------------------------------------------------------------------------------------
# The report
# ----------------------------------------------------------------------------------------------


def sweep_conditions() -> dict[str, dict[str, Any]]:
    """The study-B sweep: label -> ``make()`` overrides. The aruco profile's camera (noise,
    detection, 30 Hz frames) and proximity noise, with the camera latency and the linear
    acceleration bound of the sweep; no angular acceleration bound and no lag."""
    profile = load_profile("aruco")
    out: dict[str, dict[str, Any]] = {}
    for latency in SWEEP_LATENCIES:
        for accel in SWEEP_ACCEL:
            over: dict[str, Any] = {
                "camera": {**profile["camera"], "latency": latency},
                "proximity": dict(profile["proximity"]),
            }
            if accel is not None:
                over["robot"] = {"accel_max": accel}
            label = f"latency {latency * 1000:.0f} ms, accel_max {accel or 'none'}"
            out[label] = over
    return out


def _rates(
    result: Any, cells: Sequence[tuple[str, str, str, Cell]]
) -> dict[tuple[str, str, str], tuple[int, int]]:
    """(successes, episodes) per (policy, scenario, condition) of the finished cells."""
    by_cell = {rc.cell: rc.key for rc in result.cells}
    out: dict[tuple[str, str, str], list[int]] = {}
    for policy, scenario, label, cell in cells:
        key = by_cell.get(cell)
        rec = result.records.get(key) if key is not None else None
        if rec is None or rec.status != "done":
            continue
        k_n = out.setdefault((policy, scenario, label), [0, 0])
        k_n[0] += bool(rec.metrics.get("success"))
        k_n[1] += 1
    return {k: (v[0], v[1]) for k, v in out.items()}


def _table(
    rates: Mapping[tuple[str, str, str], tuple[int, int]],
    rows: Sequence[tuple[str, str]],
    header: str,
) -> list[str]:
    labels = [REGISTRY[p].label for p in REPORT_POLICIES]
    lines = [f"| {header} | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for scenario, label in rows:
        cells = []
        for p in REPORT_POLICIES:
            k_n = rates.get((p, scenario, label))
            cells.append("–" if k_n is None else str(task_rate(*k_n)))
        lines.append(f"| {scenario}, {label} | " + " | ".join(cells) + " |")
    return lines


def _table_summary() -> list[str]:
    table = load_table()
    p = table.provenance
    lines = [
        f"The table `baselines/data/ppc_tuned.yaml` (made by `{p.get('command')}` at commit "
        f"`{str(p.get('commit'))[:12]}`, {p.get('sampler')}; {p.get('episodes_per_trial')} "
        f"episodes of {p.get('scenario')} a trial, {p.get('max_episode_steps')} steps, "
        f"{p.get('wall_time_s')} s wall):",
        "",
        "| formation | trials | objective: own gains → best | " + " | ".join(TUNED_KEYS) + " |",
        "|---|---|---|" + "---|" * len(TUNED_KEYS),
    ]
    for row in table.formations:
        values = " | ".join(f"{row.params[k]:.3g}" for k in TUNED_KEYS)
        lines.append(
            f"| {row.name} | {row.trials} | {row.baseline_value:.3f} → {row.best_value:.3f} | "
            f"{values} |"
        )
    return lines


def run_report(args: argparse.Namespace) -> int:
    """Evaluate the policies (paper suite and the study-B sweep) and rewrite the doc block."""
    specs = {p: PolicySpec.of(p) for p in REPORT_POLICIES}
    paper = suite("paper")
    seeds = range(args.episodes)
    cells: list[tuple[str, str, str, Cell]] = [
        (p, s, cond.label, Cell.of(spec, s, seed, cond.overrides))
        for cond in paper.conditions
        for s in paper.scenarios
        for p, spec in specs.items()
        for seed in seeds
    ]
    sweep = sweep_conditions()
    cells += [
        (p, "study_b", label, Cell.of(spec, "study_b", seed, over))
        for label, over in sweep.items()
        for p, spec in specs.items()
        for seed in seeds
    ]
    stamp = metadata_stamp(REPORT_COMMAND, {"episodes": args.episodes}, None)
    result = run_grid(
        store_path(args.store), [c for *_, c in cells], tool=REPORT_COMMAND, stamp=stamp,
        workers=args.workers,
    )  # fmt: skip
    rates = _rates(result, cells)
    paper_rows = [(s, c.label) for c in paper.conditions for s in paper.scenarios]
    sweep_rows = [("study_b", label) for label in sweep]
    lines = [
        *_table_summary(),
        "",
        f"Success, successes/episodes [95 % Wilson interval], seeds 0..{args.episodes - 1}; "
        f"store `{store_path(args.store)}` (run {result.run_id}, {result.ran} episodes run "
        f"now, {result.reused} reused):",
        "",
        *_table(rates, paper_rows, "paper suite"),
        "",
        "Study B sweep (aruco camera noise, detection and 30 Hz frames, proximity noise; the "
        "camera latency and `robot.accel_max` as given; no `alpha_max`):",
        "",
        *_table(rates, sweep_rows, "study B"),
    ]
    if not args.no_doc:
        _rewrite_block(DOC, REPORT_COMMAND, "\n".join(lines))
    print("\n".join(lines))
    return 1 if result.failed else 0


def _rewrite_block(doc: Path, command: str, text: str) -> None:
    """Put ``text`` between ``<!-- begin: command -->`` and the next ``<!-- end -->``."""
    begin, end = f"<!-- begin: {command} -->", "<!-- end -->"
    head, found, rest = doc.read_text().partition(begin)
    if not found or end not in rest:
        raise ValueError(f"{doc}: no block {begin} ... {end}")
    write_text_atomic(doc, head + begin + "\n" + text + "\n" + end + rest.split(end, 1)[1])


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=SEARCH_COMMAND, description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("command", nargs="?", choices=("search", "report"), default="search")
    parser.add_argument(
        "--scenario",
        default="procedural_medium_train",
        help="a procedural *_train split (default %(default)s)",
    )
    parser.add_argument(
        "--formation",
        action="append",
        choices=STUDIES,
        default=None,
        help="a study whose formation to tune (repeatable; default: all)",
    )
    parser.add_argument("--trials", type=count(1, "count"), default=30)
    parser.add_argument(
        "--episodes",
        type=count(1, "count"),
        default=None,
        help="episodes a trial (search, default 3) or seeds a cell (report, default 10)",
    )
    parser.add_argument("--max-steps", type=count(1, "count"), default=4000)
    parser.add_argument("--seed", type=count(0, "seed"), default=0)
    parser.add_argument(
        "--timeout",
        type=number,
        default=None,
        help="wall seconds per formation's search (default: none)",
    )
    parser.add_argument("--workers", type=count(1, "count"), default=2)
    parser.add_argument("--log", type=Path, default=None, help="progress log (default: stdout)")
    parser.add_argument("--out", type=Path, default=DEFAULT_TABLE, help="the table to write")
    parser.add_argument(
        "--store",
        type=Path,
        default=Path("results/ppc_tuned"),
        help="report: the evaluation store's folder",
    )
    parser.add_argument("--no-doc", action="store_true", help="report: do not rewrite the doc")
    args = parser.parse_args(argv)
    args.formation = list(dict.fromkeys(args.formation or STUDIES))
    if args.episodes is None:
        args.episodes = 3 if args.command == "search" else 10
    if args.timeout is not None and not (math.isfinite(args.timeout) and args.timeout > 0):
        parser.error(f"--timeout must be > 0 s, got {args.timeout}")
    try:
        check_training_scenario(args.scenario)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))
    return args


def main(argv: Sequence[str] | None = None) -> int:
    given = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(given)
    return run_report(args) if args.command == "report" else run_search(args, given)


if __name__ == "__main__":
    raise SystemExit(main())
