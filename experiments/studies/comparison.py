"""PPC against the last-seen baseline of ref. [32] on studies B and C (paper §4.2, §4.3).

Usage::

    python -m experiments.studies.comparison [--out docs/figures] [--seeds 20] [--workers 2]
                                   [--store results/comparison/results.sqlite]

The policies (:data:`POLICIES`: :class:`baselines.PPCPolicy`, :class:`baselines.LastSeenPolicy`
— ref. [32] as the paper describes it — and its variant :class:`baselines.LastSeenFOVPolicy`
with this project's field-of-view slow-down) run from the same initial configuration (the same
``reset`` seed) behind the same scripted leader, with ``terminate_on`` limited to collisions,
so that a lost predecessor does not end the episode but
is counted (:func:`comparison_metrics`): follower-steps without visibility, and the separate
*intervals* of lost sight (maximal runs of such steps of one follower) with their durations —
the paper's "violates periodically".

The episodes run through the shared grid runner (:func:`experiments.grid.run_grid`) into the
evaluation store ``--store``: a re-run resumes, and only new seeds or changed inputs run.

Figures, from the seed-0 episodes, for each study (``OUT/<study>_vs_last_seen_*.png``):

* ``_trajectories`` — the platoon's traces under each policy (Fig. 8, 12);
* ``_distances`` — ``d``, ``beta`` and the obstacle distance ``d_W = min(d_W_l, d_W_r)`` of every
  follower under both policies, the constraints ``d_col``, ``d_con``, ``±beta_con`` and ``r``
  dashed, steps without visibility shaded (Fig. 9);
* ``_commands`` — the velocity commands ``u``, ``omega`` of both (Figs. 10, 11);

and ``OUT/study_c_last_seen_trace.png``: the traces under the last-seen controller in study C
with the points where sight of the predecessor was lost and where it was last seen (Fig. 15).

Then both studies × both policies over ``--seeds`` seeds: a markdown table of visibility
breaks, collisions and successes (with 95 % intervals), written to ``OUT/comparison.md`` under
the run's metadata stamp, and printed.

``--fig15`` runs, instead, the paper's Fig. 15 (§4.3): study C with **one follower**
(:data:`FIG15_OVERRIDES`: ``make("study_c", followers=1)`` with ``terminate_on`` limited to
collisions), PPC and the last-seen controller (:data:`FIG15_POLICIES`) over ``--seeds`` seeds.
Its measure (:func:`fig15_metrics`) adds to :func:`comparison_metrics` the first loss of sight
(:func:`first_loss`: when, where, what broke it, whether and when sight came back, whether the
follower reached the last-seen point while still blind). It writes
``OUT/fig15_one_follower.md`` under the run's stamp — table 1 the comparison's columns
(:func:`comparison_table`), table 2 the first loss per policy (:func:`first_loss_table`, with
the corner of the leader's path nearest the follower when it lost sight), table 3 every episode
(:func:`first_loss_rows`), then a list of what the tables show (:func:`fig15_findings`) — and
``OUT/study_c_last_seen_trace_one_follower.png``, Fig. 15 from the seed-0 one-follower episode
of the last-seen controller, the leader path's corners numbered. The two-follower figure
``study_c_last_seen_trace.png`` is the default run's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import platoon_env
from experiments.cli import add_grid_options, failed_episodes, new_parser, open_store
from experiments.grid import Cell, GridResult, run_grid
from experiments.policies import PolicySpec, analytic_policies, build_policy
from experiments.report import mean_ci, provenance_markdown, wilson, write_text_atomic
from experiments.stamp import metadata_stamp, png_metadata
from experiments.store import Store
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_D,
    SENSE_D_WALL_LEFT,
    SENSE_D_WALL_RIGHT,
    SENSE_VISIBLE,
)
from platoon_env.rollout import Episode, episode_metrics, run_episode
from platoon_env.safety import causes_to_mask, mask_to_causes
from platoon_env.scenarios.schema import VIOLATION_CAUSES

__all__ = [
    "COLLISIONS",
    "FIG15_OVERRIDES",
    "FIG15_POLICIES",
    "FIG15_STUDY",
    "POLICIES",
    "STUDIES",
    "break_intervals",
    "comparison_metrics",
    "comparison_table",
    "fig15_cells",
    "fig15_findings",
    "fig15_metrics",
    "first_loss",
    "first_loss_rows",
    "first_loss_table",
    "leader_corners",
    "make_env",
    "plot_distances",
    "plot_last_seen_trace",
    "run",
    "visibility_breaks",
]

#: The studies of the paper's comparison with ref. [32].
STUDIES: tuple[str, ...] = ("study_b", "study_c")
#: Violation causes that end an episode here: only collisions, so lost sight is counted.
COLLISIONS: tuple[str, ...] = ("collision_robot", "collision_obstacle")
_COLLISION_MASK = causes_to_mask(COLLISIONS)
#: The make() overrides of every comparison episode.
OVERRIDES: dict[str, Any] = {"terminate_on": list(COLLISIONS)}
#: The measure of a comparison episode (:func:`comparison_metrics`).
MEASURE = "experiments.studies.comparison:comparison_metrics"
_TOOL = "python -m experiments.studies.comparison"
#: The default ``--store``: the episodes of every run, so that a re-run resumes.
_STORE = Path("results/comparison/results.sqlite")

#: Display name -> the registered policy: those whose ``studies`` include the comparison
#: (:func:`experiments.policies.analytic_policies`).
POLICIES: dict[str, PolicySpec] = {
    kind.label: PolicySpec.of(name, kind.label)
    for name, kind in analytic_policies("comparison").items()
}


#: Fig. 15 (``--fig15``, paper §4.3): the study, ...
FIG15_STUDY = "study_c"
#: ... its ``make()`` overrides: one follower, ``terminate_on`` limited to collisions ...
FIG15_OVERRIDES: dict[str, Any] = {**OVERRIDES, "followers": 1}
#: ... and its policies (keys of :data:`POLICIES`).
FIG15_POLICIES: tuple[str, ...] = ("PPC", "last-seen [32]")
#: The measure of a Fig. 15 episode (:func:`fig15_metrics`).
FIG15_MEASURE = "experiments.studies.comparison:fig15_metrics"
#: The markdown ``--fig15`` writes under ``--out``.
FIG15_FILE = "fig15_one_follower.md"
#: The violation causes that make a predecessor not visible (the camera's, eq. 5).
_SIGHT_CAUSES: tuple[str, ...] = ("out_of_range", "out_of_fov", "occluded")


def make_env(study: str) -> platoon_env.PlatoonParallelEnv:
    """The study's env with ``terminate_on`` limited to collisions."""
    return platoon_env.make(study, **OVERRIDES)


def run(study: str, policy: str, seed: int, *, record_signals: bool = True) -> Episode:
    """One episode of ``policy`` (a key of :data:`POLICIES`) on ``study`` from ``reset(seed)``."""
    env = make_env(study)
    return run_episode(
        env, build_policy(POLICIES[policy], env), seed=seed, record_signals=record_signals
    )


def visibility_breaks(ep: Episode) -> tuple[np.ndarray, np.ndarray]:
    """Per follower: steps after which the predecessor was not visible, and the number of
    visible -> not-visible transitions (the initial configuration counts as the first sample).
    """
    vis = ep.sensed[:, :, SENSE_VISIBLE] > 0
    return np.sum(~vis[1:], axis=0), np.sum(vis[:-1] & ~vis[1:], axis=0)


def break_intervals(ep: Episode) -> list[tuple[int, int, int]]:
    """The intervals of lost sight: ``(follower, first step, steps)`` for every maximal run of
    consecutive steps after which follower ``i`` (1-based) did not see its predecessor."""
    lost = ~(ep.sensed[1:, :, SENSE_VISIBLE] > 0)
    out = []
    for i in range(lost.shape[1]):
        col = np.concatenate([[False], lost[:, i], [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(col))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            out.append((i + 1, int(start) + 1, int(stop - start)))
    return out


def comparison_metrics(ep: Episode) -> dict[str, Any]:
    """The metrics of one comparison episode: :func:`~platoon_env.rollout.episode_metrics`,
    and the visibility breaks — ``break_steps`` (follower-steps without sight),
    ``break_intervals`` (their separate intervals), ``break_durations`` [s] (each interval's),
    ``transitions`` (visible -> not-visible switches; an interval open from the start is not
    one) — the collision flag and the follower-steps per violation cause."""
    steps, trans = visibility_breaks(ep)
    intervals = break_intervals(ep)
    cause_steps: dict[str, int] = {}
    for mask in ep.violations[ep.violations != 0].tolist():
        for cause in mask_to_causes(int(mask)):
            cause_steps[cause] = cause_steps.get(cause, 0) + 1
    return {
        **episode_metrics(ep),
        "control_period": float(ep.control_period),
        "break_steps": int(steps.sum()),
        "break_intervals": len(intervals),
        "break_durations": [n * float(ep.control_period) for _, _, n in intervals],
        "transitions": int(trans.sum()),
        "collision": bool(np.any(ep.violations & _COLLISION_MASK)),
        "completed": bool(ep.leader_arrived and ep.first_violation is None),
        "cause_steps": cause_steps,
    }


def first_loss(ep: Episode) -> dict[str, Any]:
    """The first loss of sight of an episode: the earliest interval of
    :func:`break_intervals` (on a tie, the lowest follower), as JSON-able metrics.

    ``first_loss`` (whether sight was ever lost); then, or ``None`` if not: ``first_loss_follower``
    ``i`` (1-based), ``first_loss_step`` ``k`` (the first sample without sight) and
    ``first_loss_time`` ``t_k`` [s]; ``first_loss_position``, follower ``R_i``'s ``[x, y]`` at
    ``k``; ``first_loss_last_seen``, its predecessor ``R_{i-1}``'s ``[x, y]`` at ``k - 1`` (the
    last-seen point of the leader-loss mode); ``first_loss_causes``, the camera constraints of
    eq. 5 the step into ``k`` violated (``out_of_range``: ``d_i >= d_con``, ``out_of_fov``:
    ``|beta_i| >= beta_con``, ``occluded``: ``d_l,i`` or ``d_r,i`` <= 0, the line of sight
    blocked); ``first_loss_duration`` [s] (the interval's); ``first_loss_regained`` (sight back
    before the episode ended); ``first_loss_reached_blind`` (from the policy's ``arrived``
    signal, :class:`baselines.LastSeenPolicy`: the follower reached the last-seen point during
    the interval, still without sight; ``None`` for a policy without that signal or an episode
    run without signals).

    For the whole episode: ``loss_positions``, the follower's ``[x, y]`` at the first sample of
    every interval (in order of time), ``ends_blind`` (some follower is without sight at the
    last sample) and ``reached_blind_intervals`` (the intervals in which the follower reached
    the last-seen point without sight; ``None`` without the ``arrived`` signal).
    """
    intervals = sorted(break_intervals(ep), key=lambda iv: (iv[1], iv[0]))
    last = int(ep.times.size) - 1
    arrived = ep.signals.get("arrived")
    out: dict[str, Any] = {
        "first_loss": bool(intervals),
        "loss_positions": [[float(v) for v in ep.poses[k, i, :2]] for i, k, _ in intervals],
        "ends_blind": any(k + n > last for _, k, n in intervals),
        "reached_blind_intervals": None
        if arrived is None
        else sum(bool(np.any(arrived[k : k + n, i - 1])) for i, k, n in intervals),
    }
    keys = "follower step time position last_seen causes duration regained reached_blind"
    if not intervals:
        return {**out, **{f"first_loss_{key}": None for key in keys.split()}}
    i, k, n = intervals[0]
    causes = mask_to_causes(int(ep.violations[k - 1, i - 1]))
    return {
        **out,
        "first_loss_follower": i,
        "first_loss_step": k,
        "first_loss_time": float(ep.times[k]),
        "first_loss_position": [float(v) for v in ep.poses[k, i, :2]],
        "first_loss_last_seen": [float(v) for v in ep.poses[k - 1, i - 1, :2]],
        "first_loss_causes": [c for c in _SIGHT_CAUSES if c in causes],
        "first_loss_duration": n * float(ep.control_period),
        "first_loss_regained": k + n <= last,
        "first_loss_reached_blind": None
        if arrived is None
        else bool(np.any(arrived[k : k + n, i - 1])),
    }


def fig15_metrics(ep: Episode) -> dict[str, Any]:
    """The metrics of one Fig. 15 episode: :func:`comparison_metrics`, the number of
    ``followers`` ``N`` and the first loss of sight (:func:`first_loss`)."""
    return {**comparison_metrics(ep), "followers": int(ep.poses.shape[1]) - 1, **first_loss(ep)}


def leader_corners(config: Any) -> list[tuple[float, float]]:
    """The corners of the scripted leader's path (its polyline's interior vertices, in driving
    order: corner 1 is the first sharp corner the leader turns); a ``ValueError`` if the
    scenario's leader has no path with a corner."""
    path = getattr(config.leader, "path", None)
    if path is None or len(path) < 3:
        raise ValueError(
            f"scenario {config.name!r}: the leader has no path with a corner (a polyline of at "
            "least 3 vertices); the first-loss tables name corners of that path"
        )
    return [(float(x), float(y)) for x, y in path[1:-1]]


def _nearest_corner(
    position: Sequence[float], corners: Sequence[tuple[float, float]]
) -> tuple[int, float]:
    """(1-based index, distance [m]) of the corner nearest ``position``."""
    d = np.hypot(*(np.asarray(corners, dtype=float) - np.asarray(position, dtype=float)).T)
    j = int(np.argmin(d))
    return j + 1, float(d[j])


def _xy(p: Sequence[float]) -> str:
    return f"({p[0]:.2f}, {p[1]:.2f})"


def _corner(j: int, corners: Sequence[tuple[float, float]]) -> str:
    return f"{j} ({corners[j - 1][0]:g}, {corners[j - 1][1]:g})"


def _corner_counts(
    positions: Sequence[Sequence[float]], corners: Sequence[tuple[float, float]]
) -> str:
    """``corner: count, ...`` of the corners nearest ``positions``, in driving order."""
    near = [_nearest_corner(p, corners)[0] for p in positions]
    return ", ".join(f"{_corner(j, corners)}: {near.count(j)}" for j in sorted(set(near)))


def _yes_no(value: bool | None) -> str:
    return "–" if value is None else ("yes" if value else "no")


def _count(ms: Sequence[Mapping[str, Any]], key: str) -> str:
    """``k/n`` of the episodes whose ``key`` is true among those where it is known; ``–`` if
    it is known in none."""
    known = [bool(m[key]) for m in ms if m.get(key) is not None]
    return f"{sum(known)}/{len(known)}" if known else "–"


def first_loss_table(
    groups: Mapping[tuple[str, str], Sequence[Mapping[str, Any]]],
    corners: Sequence[tuple[float, float]],
) -> str:
    """The markdown table of the first loss of sight: one line per study × policy from its
    episodes' :func:`fig15_metrics`, the corner of the leader's path (:func:`leader_corners`)
    nearest the follower when it lost sight counted per corner (for the first loss of each
    episode, and for every interval of lost sight)."""
    lines = [
        "The first loss of sight of each episode (the earliest interval; the follower's "
        "position at its first sample without sight, the nearest corner of the leader's path "
        "numbered in driving order: corner 1 is the first sharp corner). Regained: sight "
        "back before the episode's end. Reached blind: the follower arrived at the last-seen "
        "point (within `arrive_radius`) while still without sight, as the paper says of "
        "Fig. 15 (known only for the last-seen controller's `arrived` signal). The fractions "
        "count the episodes with a loss.",
        "",
        "| study | policy | followers | episodes | episodes with a loss of sight | "
        "first loss t [s] median (min–max) | nearest corner of the first loss: episodes | "
        "follower to that corner max [m] | constraint broken at the first loss: episodes | "
        "nearest corner of every loss: intervals | "
        "first loss regained | first interval median / max [s] | "
        "reached the last-seen point blind (first loss) | episodes ending without sight |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (study, policy), ms in groups.items():
        lost = [m for m in ms if m["first_loss"]]
        followers = ", ".join(str(f) for f in sorted({int(m["followers"]) for m in ms}))
        cells = ["–"] * 5
        if lost:
            t = [float(m["first_loss_time"]) for m in lost]
            near = [_nearest_corner(m["first_loss_position"], corners) for m in lost]
            causes = {c: sum(c in m["first_loss_causes"] for m in lost) for c in _SIGHT_CAUSES}
            dur = [float(m["first_loss_duration"]) for m in lost]
            cells = [
                f"{np.median(t):.2f} ({min(t):.2f}–{max(t):.2f})",
                _corner_counts([m["first_loss_position"] for m in lost], corners),
                f"{max(d for _, d in near):.2f}",
                ", ".join(f"{c} {k}" for c, k in causes.items() if k) or "none",
                _corner_counts([p for m in lost for p in m["loss_positions"]], corners),
            ]
            regain = f"{np.median(dur):.2f} / {max(dur):.2f}"
        else:
            regain = "–"
        lines.append(
            f"| {study} | {policy} | {followers} | {len(ms)} | {len(lost)} | "
            f"{' | '.join(cells)} | {_count(lost, 'first_loss_regained')} | {regain} | "
            f"{_count(lost, 'first_loss_reached_blind')} | "
            f"{sum(bool(m['ends_blind']) for m in ms)} |"
        )
    return "\n".join(lines)


def first_loss_rows(
    rows: Sequence[tuple[str, int, Mapping[str, Any]]], corners: Sequence[tuple[float, float]]
) -> str:
    """The markdown table of every episode: ``rows`` of (policy, seed, :func:`fig15_metrics`),
    one line each, in the given order."""
    lines = [
        "Every episode: its first loss of sight (the follower's position, its predecessor's "
        "last-seen position, the nearest corner of the leader's path and the follower's "
        "distance to it), how long it lasted, and the episode's totals.",
        "",
        "| policy | seed | first loss t [s] | follower at | predecessor last seen at | "
        "nearest corner (distance [m]) | constraint broken | first interval [s] | regained | "
        "reached the last-seen point blind | intervals | ends without sight | collision | "
        "success |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for policy, seed, m in rows:
        if m["first_loss"]:
            j, d = _nearest_corner(m["first_loss_position"], corners)
            loss = (
                f"{m['first_loss_time']:.2f} | {_xy(m['first_loss_position'])} | "
                f"{_xy(m['first_loss_last_seen'])} | {_corner(j, corners)} ({d:.2f}) | "
                f"{', '.join(m['first_loss_causes']) or 'none'} | "
                f"{m['first_loss_duration']:.2f} | {_yes_no(m['first_loss_regained'])} | "
                f"{_yes_no(m['first_loss_reached_blind'])}"
            )
        else:
            loss = " | ".join(["–"] * 8)
        lines.append(
            f"| {policy} | {seed} | {loss} | {m['break_intervals']} | "
            f"{_yes_no(m['ends_blind'])} | {_yes_no(m['collision'])} | "
            f"{_yes_no(m['completed'])} |"
        )
    return "\n".join(lines)


def fig15_findings(
    groups: Mapping[tuple[str, str], Sequence[Mapping[str, Any]]],
    corners: Sequence[tuple[float, float]],
) -> str:
    """A markdown list, one item per study × policy, saying in words what the tables show: how
    many episodes lost sight, when and at which corner first, whether it came back, whether the
    follower reached the last-seen point blind, and the collisions and successes."""
    items = []
    for (_study, policy), ms in groups.items():
        n = len(ms)
        lost = [m for m in ms if m["first_loss"]]
        ok = sum(bool(m["completed"]) for m in ms)
        tail = (
            f"{sum(bool(m['collision']) for m in ms)} collision(s); {ok}/{n} successes "
            f"[{', '.join(f'{v:.2f}' for v in wilson(ok, n))}]."
        )
        if not lost:
            items.append(f"- **{policy}**: sight never lost in {n} episodes; {tail}")
            continue
        t = [float(m["first_loss_time"]) for m in lost]
        near = [_nearest_corner(m["first_loss_position"], corners)[0] for m in lost]
        first = sum(j == 1 for j in near)
        regained = sum(bool(m["first_loss_regained"]) for m in lost)
        blind = [m["first_loss_reached_blind"] for m in lost]
        reached = (
            ""
            if any(b is None for b in blind)
            else f"; the follower reached the last-seen point still blind in {sum(blind)} of them"
        )
        intervals = sum(int(m["break_intervals"]) for m in ms)
        every = _corner_counts([p for m in lost for p in m["loss_positions"]], corners)
        items.append(
            f"- **{policy}**: sight lost in {len(lost)} of {n} episodes, first at "
            f"t = {min(t):.1f}–{max(t):.1f} s, nearest corner 1 {_xy(corners[0])} (the first "
            f"sharp corner) in {first} of them; the first loss regained in {regained} of "
            f"{len(lost)}{reached}; {intervals} interval(s) of lost sight in all "
            f"({intervals / n:.1f} per episode; nearest corner, intervals: {every}); "
            f"{sum(bool(m['ends_blind']) for m in ms)} episode(s) end without sight; {tail}"
        )
    return "\n".join(items)


def comparison_table(groups: Mapping[tuple[str, str], Sequence[Mapping[str, Any]]]) -> str:
    """The markdown table: one line per study × policy from its episodes' metrics."""
    lines = [
        "Visibility breaks with `terminate_on` = collisions only. A break step is a "
        "follower-step after which the predecessor is not visible; an interval is a maximal "
        "run of break steps of one follower (its duration in seconds); violation steps count "
        "the follower-steps with a violation of each cause (checked after every physics "
        "sub-step); a success is an episode where the leader reached its path's end without "
        "any violation. Intervals per episode: mean ± 95 % half-width; successes: Wilson 95 %.",
        "",
        "| study | policy | control period [s] | episodes | episodes with a visibility break | "
        "intervals (per episode) | interval duration median / max [s] | "
        "visibility-break steps | violation steps by cause | collisions | successes [95% CI] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (study, policy), ms in groups.items():
        n = len(ms)
        steps: dict[str, int] = {}
        for m in ms:
            for cause, k in m["cause_steps"].items():
                steps[cause] = steps.get(cause, 0) + int(k)
        causes = ", ".join(f"{c} {steps[c]}" for c in VIOLATION_CAUSES if c in steps) or "none"
        durations = [d for m in ms for d in m["break_durations"]]
        dur = f"{np.median(durations):.2f} / {max(durations):.2f}" if durations else "–"
        ok = sum(bool(m["completed"]) for m in ms)
        lo, hi = wilson(ok, n)
        lines.append(
            f"| {study} | {policy} | {ms[0]['control_period']:g} | {n} | "
            f"{sum(m['break_steps'] > 0 for m in ms)} | "
            f"{sum(m['break_intervals'] for m in ms)} "
            f"({mean_ci([float(m['break_intervals']) for m in ms])}) | {dur} | "
            f"{sum(m['break_steps'] for m in ms)} | {causes} | "
            f"{sum(bool(m['collision']) for m in ms)} | {ok}/{n} [{lo:.2f}, {hi:.2f}] |"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------


def plot_distances(
    fig: Any, scenario: Any, episodes: Sequence[Episode], labels: Sequence[str]
) -> None:
    """Fig. 9: ``d_i``, ``beta_i`` and ``d_W,i = min(d_W_l,i + m, d_W_r,i + m)`` per follower
    (rows), one colour per episode, with the constraints dashed: ``d_col``, ``d_con`` (eq. 4-5),
    ``±beta_con`` and the robot radius ``r``. With an obstacle inflation ``m``
    (``safety.inflation``; the paper's study B: 0.1 m) the readings are to the inflated outline,
    and, as the paper's Fig. 9 does, ``d_W`` adds ``m`` back: the distance to the true
    obstacles, with the collision limit ``r + m`` dotted beside ``r``.

    The values are ground truth (also while the predecessor is not visible); the steps without
    visibility are shaded in the episode's colour.
    """
    from platoon_env.plots import POLICY_COLOURS

    cfg = scenario.config
    n = cfg.followers
    inflation = float(cfg.safety.inflation)
    axes = fig.subplots(n, 3, squeeze=False, sharex=True)
    for j, ep in enumerate(episodes):
        colour = POLICY_COLOURS[j % len(POLICY_COLOURS)]
        t = ep.times
        s = ep.sensed
        vis = s[:, :, SENSE_VISIBLE] > 0
        d_w = np.minimum(s[:, :, SENSE_D_WALL_LEFT], s[:, :, SENSE_D_WALL_RIGHT]) + inflation
        for i in range(n):
            label = labels[j] if i == 0 and j < len(labels) else None
            axes[i, 0].plot(t, s[:, i, SENSE_D], color=colour, lw=0.9, label=label)
            axes[i, 1].plot(t, s[:, i, SENSE_BETA], color=colour, lw=0.9)
            axes[i, 2].plot(t, d_w[:, i], color=colour, lw=0.9)
            if np.any(~vis[:, i]):
                for ax in axes[i]:
                    ax.fill_between(
                        t,
                        0,
                        1,
                        where=~vis[:, i],
                        transform=ax.get_xaxis_transform(),
                        color=colour,
                        alpha=0.15,
                        lw=0,
                        label="not visible" if ax is axes[i, 0] and i == 0 else None,
                    )
    b = cfg.camera.half_angle
    for i in range(n):
        for lim in (cfg.safety.d_col, cfg.camera.range):
            axes[i, 0].axhline(lim, color="k", ls="--", lw=0.8)
        for lim in (-b, b):
            axes[i, 1].axhline(lim, color="k", ls="--", lw=0.8)
        axes[i, 2].axhline(cfg.robot.radius, color="k", ls="--", lw=0.8)
        if inflation > 0:
            axes[i, 2].axhline(cfg.robot.radius + inflation, color="k", ls=":", lw=0.8)
        axes[i, 0].set_ylabel(f"$d_{i + 1}$ [m]")
        axes[i, 1].set_ylabel(f"$\\beta_{i + 1}$ [rad]")
        axes[i, 2].set_ylabel(f"$d_{{W,{i + 1}}}$ [m]")
        axes[i, 1].set_ylim(-1.6 * b, 1.6 * b)
        axes[i, 2].set_ylim(0.0, (cfg.proximity_range + inflation) * 1.05)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    axes[0, 0].legend(loc="upper right", fontsize=7)


def plot_last_seen_trace(
    ax: Any,
    scenario: Any,
    ep: Episode,
    *,
    corners: Sequence[tuple[float, float]] | None = None,
    label: str | None = None,
) -> str:
    """Fig. 15: the traces of all robots under the last-seen controller (leader blue, follower
    1 black, follower 2 purple, ...), the final configuration, and for every loss of sight the
    follower's position (red x) and its predecessor's last-seen position (red circle).

    ``scenario`` must have the episode's team (``scenario.config.followers`` = ``N``);
    ``corners`` (:func:`leader_corners`), if given, are numbered in grey; ``label`` names the
    run in the title (default: the scenario's name).

    Returns a one-line description of the losses (used as the title).
    """
    from platoon_env.plots import draw_episode_at

    if scenario.config.followers != ep.poses.shape[1] - 1:
        raise ValueError(
            f"the scenario has {scenario.config.followers} follower(s), the episode "
            f"{ep.poses.shape[1] - 1}: draw it on the scenario it ran on"
        )
    draw_episode_at(ax, scenario, ep, ep.times.size - 1)
    for j, (x, y) in enumerate(corners or (), start=1):
        ax.annotate(
            str(j), (x, y), xytext=(4, 4), textcoords="offset points", color="0.35",
            fontsize=7, zorder=9,
        )  # fmt: skip
    colours = ("tab:blue", "black", "tab:purple", "tab:olive", "tab:cyan", "tab:brown")
    for i in range(ep.poses.shape[1]):
        name = "leader" if i == 0 else f"follower {i}"
        ax.plot(
            ep.poses[:, i, 0], ep.poses[:, i, 1], color=colours[i % len(colours)], lw=1.0,
            label=name, zorder=4.5,
        )  # fmt: skip
    vis = ep.sensed[:, :, SENSE_VISIBLE] > 0
    notes: list[str] = []
    for i in range(vis.shape[1]):
        lost = np.flatnonzero(vis[:-1, i] & ~vis[1:, i]) + 1  # first sample without sight
        if lost.size == 0:
            continue
        ax.plot(
            ep.poses[lost, i + 1, 0], ep.poses[lost, i + 1, 1], "x", color="tab:red", ms=9,
            mew=2, zorder=8, label="sight lost (follower)" if not notes else None,
        )  # fmt: skip
        ax.plot(
            ep.poses[lost - 1, i, 0], ep.poses[lost - 1, i, 1], "o", mfc="none",
            color="tab:red", ms=9, mew=1.5, zorder=8,
            label="last seen (predecessor)" if not notes else None,
        )  # fmt: skip
        times = ", ".join(f"{ep.times[k]:.1f}" for k in lost[:4])
        times += ", ..." if lost.size > 4 else ""
        notes.append(f"follower {i + 1} lost sight {lost.size}x (t = {times} s)")
    ax.legend(loc="upper left", fontsize=7)
    text = "; ".join(notes) if notes else "no loss of sight"
    name = scenario.config.name if label is None else label
    ax.set_title(f"{name}, last-seen controller [32], seed {ep.seed}: {text}", fontsize=9)
    return text


def figures(
    study: str, episodes: dict[str, Episode], out: Path, metadata: dict[str, str] | None = None
) -> list[Path]:
    """The comparison figures of one study from one episode per policy; returns their paths
    (``metadata``: the PNG text fields, e.g. the run's stamp)."""
    from platoon_env.plots import new_figure, plot_commands, plot_snapshots, save_figure

    names = list(episodes)
    eps = [episodes[k] for k in names]
    sc = make_env(study).scenario
    n = sc.config.followers
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    aspect = (ymax - ymin) / (xmax - xmin)
    width = 7.0 if aspect > 0.8 else 10.0
    fig = new_figure(width * len(names), width * aspect + 0.6)
    for k, (name, ep) in enumerate(zip(names, eps, strict=True)):
        plot_snapshots(
            fig.add_subplot(1, len(names), k + 1), sc, ep, n_snapshots=6,
            title=f"{study}, seed {ep.seed}: {name}",
        )  # fmt: skip
    paths = [save_figure(fig, out / f"{study}_vs_last_seen_trajectories.png", metadata)]
    fig = new_figure(11, 1.0 + 1.8 * n)
    plot_distances(fig, sc, eps, names)
    fig.suptitle(
        f"{study}, seed {eps[0].seed} (Fig. 9): distance, angle of view and obstacle distance; "
        "constraints dashed, shaded: predecessor not visible",
        fontsize=10,
    )
    paths.append(save_figure(fig, out / f"{study}_vs_last_seen_distances.png", metadata))
    fig = new_figure(10, 1.0 + 1.5 * n)
    plot_commands(fig, sc, eps, labels=names)
    fig.suptitle(f"{study}, seed {eps[0].seed} (Figs. 10, 11): velocity commands", fontsize=10)
    paths.append(save_figure(fig, out / f"{study}_vs_last_seen_commands.png", metadata))
    return paths


def trace_figure(
    episode: Episode,
    out: Path,
    metadata: dict[str, str] | None = None,
    *,
    scenario: Any = None,
    suffix: str = "",
    label: str | None = None,
) -> Path:
    """Fig. 15 from a study C episode of the last-seen controller:
    ``OUT/<study>_last_seen_trace<suffix>.png``. ``scenario``: the one the episode ran on
    (default: the study's, :func:`make_env`); with ``suffix`` the leader path's corners are
    numbered (:func:`leader_corners`); ``label``: the run's name in the title."""
    from platoon_env.plots import new_figure, save_figure

    sc = make_env(episode.scenario).scenario if scenario is None else scenario
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    fig = new_figure(8.5, 8.5 * (ymax - ymin) / (xmax - xmin) + 0.5)
    corners = leader_corners(sc.config) if suffix else None
    plot_last_seen_trace(fig.add_subplot(), sc, episode, corners=corners, label=label)
    return save_figure(fig, out / f"{episode.scenario}_last_seen_trace{suffix}.png", metadata)


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def fig15_cells(seeds: int) -> list[Cell]:
    """The cells of Fig. 15: :data:`FIG15_POLICIES` on :data:`FIG15_STUDY` with
    :data:`FIG15_OVERRIDES` (one follower), seeds ``0 .. seeds - 1``, measured by
    :func:`fig15_metrics` with the policies' signals recorded (the ``arrived`` flag)."""
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    return [
        Cell.of(
            POLICIES[name],
            FIG15_STUDY,
            seed,
            FIG15_OVERRIDES,
            measure=FIG15_MEASURE,
            record_signals=True,
        )
        for seed in range(seeds)
        for name in FIG15_POLICIES
    ]


def main(argv: Sequence[str] | None = None) -> str:
    """Run the comparison; write the figures and ``comparison.md``; return the table. With
    ``--fig15``: the one-follower run of Fig. 15 instead (:func:`fig15_cells`); write its
    figure and ``fig15_one_follower.md``; return that file's text."""
    parser = new_parser(_TOOL, __doc__, out=Path("docs/figures"))
    add_grid_options(parser, seeds=20, seeds_help="seeds per study and policy", store=_STORE)
    parser.add_argument(
        "--fig15",
        action="store_true",
        help=f"run Fig. 15 instead: {FIG15_STUDY} with one follower, "
        f"{' and '.join(FIG15_POLICIES)}; write {FIG15_FILE} and the one-follower trace figure",
    )
    args = parser.parse_args(argv)
    if args.fig15:
        return _fig15(args.seeds, args.workers, args.store, args.out, argv)
    out: Path = args.out
    cells = [
        Cell.of(spec, study, seed, OVERRIDES, measure=MEASURE)
        for study in STUDIES
        for seed in range(args.seeds)
        for spec in POLICIES.values()
    ]
    stamp = metadata_stamp(_TOOL, {"seeds": args.seeds, "overrides": OVERRIDES}, argv)
    with open_store(_TOOL, args.store) as store:
        result = run_grid(
            store, cells, tool=_TOOL, stamp=stamp, workers=args.workers,
            keep=lambda cell: cell.seed == 0,
        )  # fmt: skip
        if result.interrupted:
            raise SystemExit(130)
        header = _header(result, store)
    out.mkdir(parents=True, exist_ok=True)
    first: dict[str, dict[str, Episode]] = {s: {} for s in STUDIES}
    for rc in result.cells:
        if rc.key in result.episodes:
            first[rc.cell.scenario][rc.cell.policy.name] = result.episodes[rc.key]
    for study in STUDIES:
        for path in figures(study, first[study], out, png_metadata(stamp)):
            tqdm.write(f"wrote {path}")
    trace = trace_figure(first["study_c"]["last-seen [32]"], out, png_metadata(stamp))
    tqdm.write(f"wrote {trace}")
    table = comparison_table(_groups(result))
    write_text_atomic(out / "comparison.md", header + table + "\n")
    print(table)
    if failed_episodes(result):
        raise SystemExit(1)
    return table


def _fig15(
    seeds: int, workers: int, store_path: Path, out: Path, argv: Sequence[str] | None
) -> str:
    """``--fig15``: run the cells, write the figure and the markdown, return its text."""
    env = platoon_env.make(FIG15_STUDY, **FIG15_OVERRIDES)
    scenario = env.scenario
    corners = leader_corners(scenario.config)
    cells = fig15_cells(seeds)
    config = {"fig15": True, "seeds": seeds, "overrides": FIG15_OVERRIDES}
    config["policies"] = list(FIG15_POLICIES)
    stamp = metadata_stamp(_TOOL, config, argv)
    trace_policy = POLICIES[FIG15_POLICIES[-1]].name
    with open_store(_TOOL, store_path) as store:
        result = run_grid(
            store, cells, tool=_TOOL, stamp=stamp, workers=workers,
            keep=lambda cell: cell.seed == 0 and cell.policy.name == trace_policy,
        )  # fmt: skip
        if result.interrupted:
            raise SystemExit(130)
        header = _header(result, store, title=_FIG15_TITLE)
    out.mkdir(parents=True, exist_ok=True)
    traced = [result.episodes[rc.key] for rc in result.cells if rc.key in result.episodes]
    if traced:
        path = trace_figure(
            traced[0], out, png_metadata(stamp), scenario=scenario, suffix="_one_follower",
            label=f"{FIG15_STUDY}, 1 follower",
        )  # fmt: skip
        tqdm.write(f"wrote {path}")
    groups = _groups(result)
    rows = [(rc.cell.policy.name, rc.cell.seed, rec.metrics) for rc, rec in result.finished()]
    rows.sort(key=lambda r: (FIG15_POLICIES.index(r[0]), r[1]))
    text = (
        f"{header}{comparison_table(groups)}\n\n{first_loss_table(groups, corners)}\n\n"
        f"{first_loss_rows(rows, corners)}\n\nWhat the tables show:\n\n"
        f"{fig15_findings(groups, corners)}\n"
    )
    write_text_atomic(out / FIG15_FILE, text)
    tqdm.write(f"wrote {out / FIG15_FILE}")
    print(text, end="")
    if failed_episodes(result):
        raise SystemExit(1)
    return text


_FIG15_TITLE = (
    f"Fig. 15: {FIG15_STUDY} with one follower, PPC against the last-seen controller of ref. [32]"
)


def _groups(result: GridResult) -> dict[tuple[str, str], list[dict[str, Any]]]:
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rc, rec in result.finished():
        groups.setdefault((rc.cell.scenario, rc.cell.policy.name), []).append(rec.metrics)
    return groups


def _header(
    result: GridResult,
    store: Store,
    title: str = "PPC against the last-seen controller of ref. [32]",
) -> str:
    records = list(result.records.values())
    return (
        f"# {title}\n\n"
        f"{len(result.finished())} episodes ({result.ran} run now, {result.reused} from the "
        f"store {store.path.name}); {len(result.failed)} failed.\n\n"
        f"{provenance_markdown(store, records, result.run_id)}\n"
    )


if __name__ == "__main__":
    main()
