"""Robustness frontiers: success rate of each controller against one realism axis at a time.

Usage::

    python -m baselines.frontiers [--out results/frontiers] [--seeds 10] [--workers 2]
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

Every episode is one row of ``OUT/frontiers.csv`` (:data:`CSV_COLUMNS`), keyed by
(controller, study, axis, level, seed): the outcome, the first violation's cause, time and
follower, the step count, the minimum obstacle clearance and, for the PPC laws, the signals
that explain a failure (:func:`ppc_diagnostics`): which funnel saturated first and when, and the
normalised errors just before the violation, as perceived and as true. Rows are appended and
fsync'ed as episodes finish; a re-run with the same ``--out`` skips the rows already there (a
torn last line, from a killed run, is dropped), so the grid can be interrupted and restarted.
Identical configurations (the ideal level shared by every axis) run once per seed and fill
every row they stand for.

Then ``OUT/frontiers.md`` holds, per study, a table of level x controller -> successes/seeds
[Wilson 95 % interval] with the dominant failure cause, and the PPC failure diagnostics; and
``OUT/frontier_<study>.png`` a panel per axis: success rate against level, a line per
controller, the 95 % intervals as bands.

``--quick`` (a smoke run): 2 seeds (unless ``--seeds`` is given) and two levels per axis.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import multiprocessing
import os
import signal
import statistics
import sys
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import platoon_env
from baselines.last_seen import LastSeenPolicy
from baselines.ppc import EPS_MAX, PPCPolicy
from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D
from platoon_env.rollout import Episode, PolicyLike, episode_metrics, run_episode
from platoon_env.scenarios.schema import VIOLATION_CAUSES

__all__ = [
    "AXES",
    "CONTROLLERS",
    "CSV_COLUMNS",
    "KEY_COLUMNS",
    "STUDIES",
    "Axis",
    "Job",
    "build_grid",
    "diagnosed_follower",
    "failure_diagnostics",
    "level_key",
    "main",
    "ppc_diagnostics",
    "read_rows",
    "run_job",
    "summarise",
    "wilson_interval",
]

#: The paper's three studies.
STUDIES: tuple[str, ...] = ("study_a", "study_b", "study_c")

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
    """A controller of the frontier: its display name, its factory, whether it is a PPC law
    (then its signals are recorded and diagnosed)."""

    label: str
    factory: Callable[[platoon_env.PlatoonParallelEnv], PolicyLike]
    ppc: bool


def _controllers() -> tuple[dict[str, Controller], str]:
    """The available controllers, and why the filtered PPC is missing ("" if it is not)."""
    out = {
        "ppc": Controller("PPC", PPCPolicy, ppc=True),
        "last_seen": Controller("last-seen [32]", LastSeenPolicy, ppc=False),
    }
    try:  # written concurrently: the frontier runs without it until it lands
        from baselines.filtered_ppc import FilteredPPCPolicy
    except Exception as exc:
        return out, f"baselines.filtered_ppc not available ({type(exc).__name__}: {exc})"
    out["filtered_ppc"] = Controller("filtered PPC", FilteredPPCPolicy, ppc=True)
    return out, ""


#: Controller name (the CSV's ``controller``) -> :class:`Controller`; the filtered PPC only
#: when ``baselines.filtered_ppc`` imports (:data:`FILTERED_PPC_MISSING` says why not).
CONTROLLERS, FILTERED_PPC_MISSING = _controllers()


# ----------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------

Level = float | str | None


def level_key(level: Level) -> str:
    """The CSV form of a level: ``"none"`` for None, ``f"{x:g}"`` for a number, else the text."""
    if level is None:
        return "none"
    if isinstance(level, str):
        return level
    return f"{float(level):g}"


@dataclass(frozen=True)
class Axis:
    """One realism axis: its levels (in the unit shown, from ideal to harsh) and how a level
    becomes ``platoon_env.make`` overrides."""

    name: str
    label: str  # axis title with its unit
    levels: tuple[Level, ...]
    quick: tuple[Level, ...]  # the levels of a --quick run
    to_overrides: Callable[[Any], dict[str, Any]]
    none_label: str = "none"  # how the level None is shown

    def show(self, level: Level) -> str:
        """A level as shown in tables and on plots."""
        return self.none_label if level is None else level_key(level)

    def overrides(self, level: Level) -> dict[str, Any]:
        """The ``make`` keyword overrides of ``level`` ({} for the ideal level)."""
        return self.to_overrides(level)


def _noise(cm: float) -> dict[str, Any]:
    return {"camera": {"noise": {"position": cm / 100.0}}} if cm else {}


def _detection(p: float) -> dict[str, Any]:
    return {"camera": {"detection": p}} if p != 1 else {}


def _latency(ms: float) -> dict[str, Any]:
    return {"camera": {"latency": ms / 1000.0}} if ms else {}


def _frame_rate(hz: float | None) -> dict[str, Any]:
    return {} if hz is None else {"camera": {"frame_rate": hz}}


def _accel(a: float | None) -> dict[str, Any]:
    return {} if a is None else {"robot": {"accel_max": a}}


def profile_overrides(name: str) -> dict[str, Any]:
    """The ``make`` overrides of a shipped sensor profile: ``sensor_profile=name`` when
    ``make`` takes it, else the blocks :func:`platoon_env.scenarios.profiles.load_profile`
    returns. Raises (ImportError, ScenarioError, ...) while the profile is not available."""
    from platoon_env.scenarios import options

    try:
        from platoon_env.scenarios.profiles import load_profile
    except ImportError as exc:
        raise ImportError(f"platoon_env.scenarios.profiles not available: {exc}") from None
    blocks = load_profile(name)  # fails if the profile is missing or invalid
    if getattr(options, "PROFILE_OPTION", None) in options.OVERRIDE_OPTIONS:
        return {"sensor_profile": name}
    if not isinstance(blocks, Mapping):
        raise TypeError(f"load_profile({name!r}) returned {type(blocks).__name__}, not blocks")
    return {str(k): dict(v) for k, v in blocks.items()}


#: The realism axes of the frontier, each run alone (:func:`build_grid`).
AXES: dict[str, Axis] = {
    a.name: a
    for a in (
        Axis(
            "camera_noise",
            "camera position noise sigma [cm]",
            (0.0, 0.5, 1.0, 2.0, 5.0, 10.0),
            (0.0, 5.0),
            _noise,
        ),
        Axis("detection", "detection probability", (1.0, 0.95, 0.8, 0.5), (1.0, 0.5), _detection),
        Axis(
            "latency", "camera latency [ms]", (0.0, 10.0, 30.0, 50.0, 100.0), (0.0, 50.0), _latency
        ),
        Axis(
            "frame_rate",
            "camera frame rate [Hz]",
            (None, 30.0, 15.0),
            (None, 15.0),
            _frame_rate,
            none_label="every step",
        ),
        Axis("accel_max", "accel_max [m/s²]", (None, 2.0, 1.0, 0.5), (None, 0.5), _accel),
        Axis("profile", "sensor profile", ("aruco",), ("aruco",), profile_overrides),
    )
}


@dataclass(frozen=True)
class Job:
    """One episode to run: a controller on a study with the overrides of some (axis, level)
    points (identical configurations share one episode), from ``reset(seed)``."""

    controller: str
    study: str
    seed: int
    overrides: str  # JSON of the make overrides
    points: tuple[tuple[str, str], ...]  # (axis, level key) rows this episode fills
    max_episode_steps: int | None = None


def build_grid(
    studies: Sequence[str],
    controllers: Sequence[str],
    axes: Sequence[str],
    seeds: int,
    *,
    quick: bool = False,
    done: Iterable[tuple[str, ...]] = (),
    max_episode_steps: int | None = None,
) -> tuple[list[tuple[str, ...]], list[Job], list[str]]:
    """The grid's row keys, the jobs still to run, and notes on skipped points.

    Keys are :data:`KEY_COLUMNS` tuples (all strings). Jobs skip keys in ``done``; points with
    the same overrides (the ideal level of each axis) share one job per controller, study and
    seed. A point whose overrides cannot be built (the aruco profile before it exists) is left
    out with a note.
    """
    done_set = set(done)
    keys: list[tuple[str, ...]] = []
    notes: list[str] = []
    points: list[tuple[str, str, str]] = []  # axis, level key, overrides JSON
    for name in axes:
        axis = AXES[name]
        for level in axis.quick if quick else axis.levels:
            try:
                level_overrides = axis.overrides(level)
            except Exception as exc:
                notes.append(f"{name}={level_key(level)} skipped: {type(exc).__name__}: {exc}")
                continue
            points.append((name, level_key(level), json.dumps(level_overrides, sort_keys=True)))
    groups: dict[tuple[str, str, int, str], list[tuple[str, str]]] = defaultdict(list)
    for study in studies:
        for ctrl in controllers:
            for seed in range(seeds):
                for axis_name, lk, ov in points:
                    key = (ctrl, study, axis_name, lk, str(seed))
                    keys.append(key)
                    if key not in done_set:
                        groups[ctrl, study, seed, ov].append((axis_name, lk))
    jobs = [
        Job(ctrl, study, seed, ov, tuple(pts), max_episode_steps)
        for (ctrl, study, seed, ov), pts in groups.items()
    ]
    # Long episodes first (study C), so that the last worker does not run alone for long.
    jobs.sort(key=lambda j: (-STUDIES.index(j.study) if j.study in STUDIES else 0, j.seed))
    return keys, jobs, notes


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


def make_env(
    study: str, overrides: Mapping[str, Any], max_episode_steps: int | None = None
) -> platoon_env.PlatoonParallelEnv:
    """The study's env with ``overrides``, every violation cause ending the episode."""
    extra: dict[str, Any] = {"terminate_on": VIOLATION_CAUSES, "diagnostics": False}
    if max_episode_steps is not None:
        extra["max_episode_steps"] = max_episode_steps
    return platoon_env.make(study, **overrides, **extra)


#: The ``violation`` of an episode the controller refused to run: its constructor raised a
#: ``ValueError`` for the configuration (e.g. the filtered PPC when the constraints tightened by
#: the declared noise leave the PPC law no feasible funnel). It counts as a failure.
REFUSED = "refused"


def run_job(job: Job) -> list[dict[str, Any]]:
    """Run one :class:`Job`; return a CSV row (:data:`CSV_COLUMNS`) per point it stands for.

    A controller that refuses the configuration (a ``ValueError`` from its constructor) gives
    a failed row with ``violation`` = :data:`REFUSED` and no steps.
    """
    start = time.perf_counter()
    ctrl = CONTROLLERS[job.controller]
    env = make_env(job.study, json.loads(job.overrides), job.max_episode_steps)
    try:
        policy = ctrl.factory(env)
    except ValueError:
        row: dict[str, Any] = dict.fromkeys(CSV_COLUMNS, "")
        row.update(success=False, truncated=False, violation=REFUSED, steps=0)
    else:
        row = episode_row(run_episode(env, policy, seed=job.seed, record_signals=ctrl.ppc))
    row["wall_time"] = time.perf_counter() - start
    return [
        {
            "controller": job.controller,
            "study": job.study,
            "axis": axis,
            "level": level,
            "seed": job.seed,
            **row,
        }
        for axis, level in job.points
    ]


# ----------------------------------------------------------------------------------------------
# The CSV: append, fsync, resume
# ----------------------------------------------------------------------------------------------


def _format(value: Any) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return ("inf" if value > 0 else "-inf") if math.isinf(value) else f"{value:.6g}"
    return str(value)


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of ``path`` ([] if absent), after dropping a torn last line.

    A run killed while writing leaves a last line without its newline; it is cut off the file
    (so the next append starts on a fresh line) and its episode runs again. A file with other
    columns than :data:`CSV_COLUMNS` is an error (another version's output: use another --out).
    """
    if not path.is_file():
        return []
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        cut = data.rfind(b"\n") + 1
        with path.open("r+b") as f:
            f.truncate(cut)
            f.flush()
            os.fsync(f.fileno())
        data = data[:cut]
    if not data:
        return []
    lines = data.decode().splitlines()
    reader = csv.DictReader(lines)
    if tuple(reader.fieldnames or ()) != CSV_COLUMNS:
        raise SystemExit(
            f"{path}: its columns {reader.fieldnames} are not {list(CSV_COLUMNS)}; "
            "use another --out"
        )
    return [r for r in reader if None not in r and None not in r.values()]


def _key(row: Mapping[str, Any]) -> tuple[str, ...]:
    return tuple(str(row[c]) for c in KEY_COLUMNS)


class RowWriter:
    """Appends rows to the CSV (header first if the file is new), flushing and fsync'ing each."""

    def __init__(self, path: Path) -> None:
        new = not path.is_file() or path.stat().st_size == 0
        self._file = path.open("a", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=CSV_COLUMNS, lineterminator="\n")
        if new:
            self._writer.writeheader()
            self._sync()

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def write(self, row: Mapping[str, Any]) -> None:
        self._writer.writerow({k: _format(row.get(k, "")) for k in CSV_COLUMNS})
        self._sync()

    def close(self) -> None:
        self._file.close()


# ----------------------------------------------------------------------------------------------
# Statistics, tables, plots
# ----------------------------------------------------------------------------------------------


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % for ``z = 1.96``).

    With ``p = successes / n``::

        centre = (p + z²/(2n)) / (1 + z²/n)
        half   = z sqrt(p (1 - p)/n + z²/(4n²)) / (1 + z²/n)

    and the interval ``[centre - half, centre + half]`` (clipped to [0, 1] against rounding).
    Unlike the normal approximation it stays inside [0, 1] and is not empty at 0/n or n/n:
    ``wilson_interval(8, 10) ≈ (0.490, 0.943)``, ``wilson_interval(10, 10) ≈ (0.722, 1)``.
    ``(nan, nan)`` for ``n = 0``.
    """
    if n <= 0:
        return (math.nan, math.nan)
    if not 0 <= successes <= n:
        raise ValueError(f"successes must lie in [0, n = {n}], got {successes}")
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z2 / (4.0 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


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
) -> Path:
    """``frontier_<study>.png``: a panel per axis, success rate against level, a line per
    controller, the Wilson 95 % intervals as bands (and error bars)."""
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
    return save_figure(fig, path)


# ----------------------------------------------------------------------------------------------
# Workers
# ----------------------------------------------------------------------------------------------


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent:  # the parent died: this worker was re-parented
            os._exit(1)


def _init_worker(parent: int) -> None:
    """In each worker: leave Ctrl-C to the parent (it shuts the pool down) and exit as soon as
    the parent is gone, however it died."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _failed(job: Job, exc: BaseException) -> str:
    return (
        f"episode failed: {job.controller} {job.study} seed {job.seed} "
        f"{', '.join(f'{a}={lv}' for a, lv in job.points)}: {type(exc).__name__}: {exc}"
    )


def _run_all(jobs: Sequence[Job], writer: RowWriter, workers: int) -> tuple[bool, int]:
    """Run ``jobs``, writing each row as it finishes; returns (finished, number of failed jobs).

    ``finished`` is False if interrupted (Ctrl-C or SIGTERM): the pending jobs are cancelled and
    the workers this pool started are terminated. A job that raises is reported and skipped
    (its rows are not written, so a re-run retries it).
    """
    progress = tqdm(
        total=len(jobs),
        desc="episodes",
        unit="ep",
        mininterval=0.5 if sys.stderr.isatty() else 30.0,
        smoothing=0.05,
    )
    errors = 0
    try:
        if workers <= 1:
            for job in jobs:
                try:
                    rows = run_job(job)
                except Exception as exc:
                    errors += 1
                    tqdm.write(_failed(job, exc))
                else:
                    for row in rows:
                        writer.write(row)
                progress.update()
            return True, errors
        ctx = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(os.getpid(),)
        )
        try:
            futures: dict[Future[list[dict[str, Any]]], Job] = {
                pool.submit(run_job, job): job for job in jobs
            }
            for fut in as_completed(futures):
                try:
                    rows = fut.result()
                except Exception as exc:  # a worker that died breaks the pool: all fail here
                    errors += 1
                    tqdm.write(_failed(futures[fut], exc))
                else:
                    for row in rows:
                        writer.write(row)
                progress.update()
        except BaseException:
            # the workers this pool started (shutdown forgets them), to terminate them by pid
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                if proc.is_alive():
                    proc.terminate()
            for proc in procs:
                proc.join(timeout=5)
            raise
        pool.shutdown(wait=True)
        return True, errors
    except KeyboardInterrupt:
        return False, errors
    finally:
        progress.close()


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def _code_version() -> dict[str, Any]:
    """The git commit of the source tree and its uncommitted files (read only; {} outside a
    checkout), recorded per run in ``runs.jsonl``: rows of a resumed grid may come from runs on
    different code."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        status = subprocess.run(
            ["git", "status", "--porcelain", "--", "platoon_env", "baselines"],
            cwd=root,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return {}
    return {"commit": commit, "modified": [line[3:] for line in status.splitlines()]}


def _settings(args: argparse.Namespace) -> dict[str, Any]:
    return {"max_episode_steps": args.max_episode_steps}


def _runs(out: Path) -> list[str]:
    """The runs that wrote rows into ``out`` (``runs.jsonl``), one line each."""
    path = out / "runs.jsonl"
    if not path.is_file():
        return []
    lines = []
    for text in path.read_text().splitlines():
        try:
            run = json.loads(text)
        except ValueError:
            continue
        modified = ", ".join(run.get("modified", [])) or "none"
        lines.append(
            f"{run.get('start')}, {run.get('to_run')} rows to run, commit "
            f"{str(run.get('commit', '?'))[:10]}, uncommitted changes: {modified}"
        )
    return lines


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m baselines.frontiers",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--out", type=Path, default=Path("results/frontiers"), help="output folder")
    parser.add_argument(
        "--seeds", type=int, default=None, help=f"seeds per point (default {DEFAULT_SEEDS})"
    )
    parser.add_argument("--workers", type=int, default=2, help="parallel worker processes")
    parser.add_argument("--study", action="append", choices=STUDIES, help="default: all three")
    parser.add_argument(
        "--controller",
        action="append",
        choices=sorted(CONTROLLERS),
        help=f"default: all available ({', '.join(CONTROLLERS)})",
    )
    parser.add_argument("--axis", action="append", choices=list(AXES), help="default: all")
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"smoke run: {QUICK_SEEDS} seeds (unless --seeds) and two levels per axis",
    )
    parser.add_argument(
        "--max-episode-steps",
        type=int,
        default=None,
        help="override every study's episode limit (for smoke tests; default: the study's)",
    )
    args = parser.parse_args(argv)
    if args.seeds is None:
        args.seeds = QUICK_SEEDS if args.quick else DEFAULT_SEEDS
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    if args.workers < 1:
        parser.error("--workers must be >= 1")
    if args.max_episode_steps is not None and args.max_episode_steps < 1:
        parser.error("--max-episode-steps must be >= 1")
    args.study = list(dict.fromkeys(args.study or STUDIES))
    args.controller = list(dict.fromkeys(args.controller or CONTROLLERS))
    args.axis = list(dict.fromkeys(args.axis or AXES))
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the grid (resuming), write ``frontiers.csv``, ``.md`` and the PNGs; returns the exit
    code (130 when interrupted)."""
    args = parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    settings_path = out / "settings.json"
    settings = _settings(args)
    if settings_path.is_file():
        old = json.loads(settings_path.read_text())
        if old != settings:
            raise SystemExit(
                f"{out} holds episodes run with {old}, not {settings}; use another --out"
            )
    else:
        settings_path.write_text(json.dumps(settings, indent=2) + "\n")
    csv_path = out / "frontiers.csv"
    rows_before = read_rows(csv_path)
    done = {_key(r) for r in rows_before}
    keys, jobs, notes = build_grid(
        args.study,
        args.controller,
        args.axis,
        args.seeds,
        quick=args.quick,
        done=done,
        max_episode_steps=args.max_episode_steps,
    )
    if FILTERED_PPC_MISSING:
        notes.append(f"filtered PPC left out: {FILTERED_PPC_MISSING}")
    if "profile" in args.axis and not any(n.startswith("profile=") for n in notes):
        from platoon_env.scenarios.profiles import load_profile

        for name in AXES["profile"].levels:
            blocks = json.dumps(load_profile(str(name)), sort_keys=True)
            notes.append(f"profile {name}: the shipped profile's blocks {blocks}")
    for note in notes:
        print(f"note: {note}")
    todo = sum(len(j.points) for j in jobs)
    print(
        f"{csv_path}: {len(keys)} rows in the grid, {len(keys) - todo} done, {todo} to run "
        f"in {len(jobs)} episodes on {args.workers} worker(s)"
    )
    run_info = {
        "start": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "rows_before": len(rows_before),
        "to_run": todo,
        **_code_version(),
    }
    with (out / "runs.jsonl").open("a") as f:
        f.write(json.dumps(run_info) + "\n")
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    start = time.perf_counter()
    writer = RowWriter(csv_path)
    try:
        finished, errors = _run_all(jobs, writer, args.workers)
    finally:
        writer.close()
        signal.signal(signal.SIGTERM, previous)
    if not finished:
        print(f"\ninterrupted: finished episodes are in {csv_path}; re-run to resume")
        return 130
    rows = read_rows(csv_path)
    table = summarise(rows, keys, args.study, args.controller, args.axis, quick=args.quick)
    header = (
        "# Robustness frontiers\n\n"
        f"Success (the episode ends by truncation without any violation; every violation ends "
        f"it) over {args.seeds} seeds per point, each realism axis alone; cells are "
        "successes/seeds [Wilson 95 % interval]; the dominant failure is the most frequent "
        "first violation among the failed episodes. Controllers: "
        f"{', '.join(CONTROLLERS[c].label for c in args.controller)}. "
        f"platoon_env {platoon_env.__version__}; wall time of this run "
        f"{time.perf_counter() - start:.0f} s.\n\n"
        + "".join(f"- note: {n}\n" for n in notes)
        + "".join(f"- run: {line}\n" for line in _runs(out))
        + ("\n" if notes else "")
    )
    (out / "frontiers.md").write_text(header + table + "\n")
    paths = [
        plot_study(
            rows, keys, s, args.controller, args.axis, out / f"frontier_{s}.png", quick=args.quick
        )
        for s in args.study
    ]
    print(table)
    print(f"wrote {csv_path}, {out / 'frontiers.md'}, " + ", ".join(str(p) for p in paths))
    if errors:
        print(f"{errors} episode(s) failed (see above); re-run to retry them")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
