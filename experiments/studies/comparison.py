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
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import platoon_env
from experiments.cli import add_grid_options, new_parser, open_store
from experiments.grid import Cell, GridResult, run_grid
from experiments.policies import PolicySpec, analytic_policies, build_policy
from experiments.report import mean_ci, provenance_markdown, wilson
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
    "POLICIES",
    "STUDIES",
    "break_intervals",
    "comparison_metrics",
    "comparison_table",
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


def plot_last_seen_trace(ax: Any, scenario: Any, ep: Episode) -> str:
    """Fig. 15: the traces of all robots under the last-seen controller (leader blue, follower
    1 black, follower 2 purple, ...), the final configuration, and for every loss of sight the
    follower's position (red x) and its predecessor's last-seen position (red circle).

    Returns a one-line description of the losses (used as the title).
    """
    from platoon_env.plots import draw_episode_at

    draw_episode_at(ax, scenario, ep, ep.times.size - 1)
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
    ax.set_title(
        f"{scenario.config.name}, last-seen controller [32], seed {ep.seed}: {text}", fontsize=9
    )
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


def trace_figure(episode: Episode, out: Path, metadata: dict[str, str] | None = None) -> Path:
    """Fig. 15 from a study C episode of the last-seen controller."""
    from platoon_env.plots import new_figure, save_figure

    sc = make_env(episode.scenario).scenario
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    fig = new_figure(8.5, 8.5 * (ymax - ymin) / (xmax - xmin) + 0.5)
    plot_last_seen_trace(fig.add_subplot(), sc, episode)
    return save_figure(fig, out / f"{episode.scenario}_last_seen_trace.png", metadata)


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> str:
    """Run the comparison; write the figures and ``comparison.md``; return the table."""
    parser = new_parser(_TOOL, __doc__, out=Path("docs/figures"))
    add_grid_options(parser, seeds=20, seeds_help="seeds per study and policy", store=_STORE)
    args = parser.parse_args(argv)
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
    (out / "comparison.md").write_text(header + table + "\n")
    print(table)
    if result.failed:
        print(f"{len(result.failed)} episode(s) failed; re-run to retry them", file=sys.stderr)
        raise SystemExit(1)
    return table


def _groups(result: GridResult) -> dict[tuple[str, str], list[dict[str, Any]]]:
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rc, rec in result.finished():
        groups.setdefault((rc.cell.scenario, rc.cell.policy.name), []).append(rec.metrics)
    return groups


def _header(result: GridResult, store: Store) -> str:
    records = list(result.records.values())
    return (
        "# PPC against the last-seen controller of ref. [32]\n\n"
        f"{len(result.finished())} episodes ({result.ran} run now, {result.reused} from the "
        f"store {store.path.name}); {len(result.failed)} failed.\n\n"
        f"{provenance_markdown(store, records, result.run_id)}\n"
    )


if __name__ == "__main__":
    main()
