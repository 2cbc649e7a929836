"""PPC against the last-seen baseline of ref. [32] on studies B and C (paper §4.2, §4.3).

Usage::

    python -m baselines.comparison [--out docs/figures] [--seeds 5]

Both policies (:class:`baselines.PPCPolicy` and :class:`baselines.LastSeenPolicy`) run from the
same initial configuration (the same ``reset`` seed) behind the same scripted leader, with
``terminate_on`` limited to collisions, so that a lost predecessor does not end the episode but
is counted: per follower-step without visibility and per visible -> not-visible transition.

Figures, from the seed-0 episodes, for each study (``OUT/<study>_vs_last_seen_*.png``):

* ``_trajectories`` — the platoon's traces under each policy (Fig. 8, 12);
* ``_distances`` — ``d``, ``beta`` and the obstacle distance ``d_W = min(d_W_l, d_W_r)`` of every
  follower under both policies, the constraints ``d_col``, ``d_con``, ``±beta_con`` and ``r``
  dashed, steps without visibility shaded (Fig. 9);
* ``_commands`` — the velocity commands ``u``, ``omega`` of both (Figs. 10, 11);

and ``OUT/study_c_last_seen_trace.png``: the traces under the last-seen controller in study C
with the points where sight of the predecessor was lost and where it was last seen (Fig. 15).

Then both studies × both policies over ``--seeds`` seeds: a markdown table of visibility breaks,
collisions and successes, written to ``OUT/comparison.md`` and printed.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import platoon_env
from baselines.last_seen import LastSeenPolicy
from baselines.ppc import PPCPolicy
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_D,
    SENSE_D_WALL_LEFT,
    SENSE_D_WALL_RIGHT,
    SENSE_VISIBLE,
)
from platoon_env.rollout import Episode, PolicyLike, run_episode
from platoon_env.safety import causes_to_mask, mask_to_causes
from platoon_env.scenarios.schema import VIOLATION_CAUSES

__all__ = [
    "COLLISIONS",
    "POLICIES",
    "STUDIES",
    "Tally",
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

#: Display name -> policy factory.
POLICIES: dict[str, Callable[[platoon_env.PlatoonParallelEnv], PolicyLike]] = {
    "PPC": PPCPolicy,
    "last-seen [32]": LastSeenPolicy,
}


def make_env(study: str) -> platoon_env.PlatoonParallelEnv:
    """The study's env with ``terminate_on`` limited to collisions."""
    return platoon_env.make(study, terminate_on=COLLISIONS)


def run(study: str, policy: str, seed: int, *, record_signals: bool = True) -> Episode:
    """One episode of ``policy`` (a key of :data:`POLICIES`) on ``study`` from ``reset(seed)``."""
    env = make_env(study)
    return run_episode(env, POLICIES[policy](env), seed=seed, record_signals=record_signals)


def visibility_breaks(ep: Episode) -> tuple[np.ndarray, np.ndarray]:
    """Per follower: steps after which the predecessor was not visible, and the number of
    visible -> not-visible transitions (the initial configuration counts as the first sample).
    """
    vis = ep.sensed[:, :, SENSE_VISIBLE] > 0
    return np.sum(~vis[1:], axis=0), np.sum(vis[:-1] & ~vis[1:], axis=0)


@dataclass
class Tally:
    """Counts over the episodes of one study × policy."""

    episodes: int = 0
    with_break: int = 0  # episodes with at least one follower-step without visibility
    break_steps: int = 0  # follower-steps without visibility
    transitions: int = 0  # visible -> not-visible transitions, all followers
    collisions: int = 0  # episodes ended by a collision
    successes: int = 0  # leader reached the end, no violation of any cause
    cause_steps: dict[str, int] = field(default_factory=dict)  # follower-steps per cause
    control_period: float = 0.0  # [s] of the episodes

    def add(self, ep: Episode) -> None:
        """Count one episode."""
        steps, trans = visibility_breaks(ep)
        self.control_period = ep.control_period
        self.episodes += 1
        self.with_break += int(steps.sum() > 0)
        self.break_steps += int(steps.sum())
        self.transitions += int(trans.sum())
        self.collisions += int(bool(np.any(ep.violations & _COLLISION_MASK)))
        self.successes += int(ep.leader_arrived and ep.first_violation is None)
        for mask in ep.violations[ep.violations != 0].tolist():
            for cause in mask_to_causes(int(mask)):
                self.cause_steps[cause] = self.cause_steps.get(cause, 0) + 1


def comparison_table(tallies: dict[tuple[str, str], Tally]) -> str:
    """The markdown table: one line per study × policy."""
    lines = [
        "Visibility breaks with `terminate_on` = collisions only. A break step is a "
        "follower-step after which the predecessor is not visible; transitions count "
        "visible -> not-visible switches; violation steps count the follower-steps with a "
        "violation of each cause (checked after every physics sub-step); a success is an "
        "episode where the leader reached its path's end without any violation.",
        "",
        "| study | policy | control period [s] | episodes | episodes with a visibility break | "
        "visibility-break steps | visible -> not-visible transitions | "
        "violation steps by cause | collisions | successes |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (study, policy), t in tallies.items():
        causes = (
            ", ".join(f"{c} {t.cause_steps[c]}" for c in VIOLATION_CAUSES if c in t.cause_steps)
            or "none"
        )
        lines.append(
            f"| {study} | {policy} | {t.control_period:g} | {t.episodes} | {t.with_break} | "
            f"{t.break_steps} | "
            f"{t.transitions} | {causes} | {t.collisions} | {t.successes} |"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------


def plot_distances(
    fig: Any, scenario: Any, episodes: Sequence[Episode], labels: Sequence[str]
) -> None:
    """Fig. 9: ``d_i``, ``beta_i`` and ``d_W,i = min(d_W_l,i, d_W_r,i)`` per follower (rows),
    one colour per episode, with the constraints dashed: ``d_col``, ``d_con`` (eq. 4-5),
    ``±beta_con`` and the robot radius ``r`` (collision with an obstacle at ``d_W <= r``).

    The values are ground truth (also while the predecessor is not visible); the steps without
    visibility are shaded in the episode's colour.
    """
    from platoon_env.plots import POLICY_COLOURS

    cfg = scenario.config
    n = cfg.followers
    axes = fig.subplots(n, 3, squeeze=False, sharex=True)
    for j, ep in enumerate(episodes):
        colour = POLICY_COLOURS[j % len(POLICY_COLOURS)]
        t = ep.times
        s = ep.sensed
        vis = s[:, :, SENSE_VISIBLE] > 0
        d_w = np.minimum(s[:, :, SENSE_D_WALL_LEFT], s[:, :, SENSE_D_WALL_RIGHT])
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
        axes[i, 0].set_ylabel(f"$d_{i + 1}$ [m]")
        axes[i, 1].set_ylabel(f"$\\beta_{i + 1}$ [rad]")
        axes[i, 2].set_ylabel(f"$d_{{W,{i + 1}}}$ [m]")
        axes[i, 1].set_ylim(-1.6 * b, 1.6 * b)
        axes[i, 2].set_ylim(0.0, cfg.proximity_range * 1.05)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    axes[0, 0].legend(loc="upper right", fontsize=7)


def plot_last_seen_trace(ax: Any, scenario: Any, ep: Episode) -> str:
    """Fig. 15: the traces of all robots under the last-seen controller (leader blue, follower
    1 black, follower 2 purple, ...), the final configuration, and for every loss of sight the
    follower's position (red x) and its predecessor's last-seen position (red circle).

    Returns a one-line description of the losses (used as the title).
    """
    from platoon_env.rendering import draw_scene

    cfg = scenario.config
    k = ep.times.size - 1
    draw_scene(
        ax,
        scenario.free_space,
        cfg,
        ep.poses[k],
        ep.sensed[k, :, SENSE_VISIBLE] > 0,
        float(ep.times[k]),
    )
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
    ax.set_title(f"{cfg.name}, last-seen controller [32], seed {ep.seed}: {text}", fontsize=9)
    return text


def figures(study: str, episodes: dict[str, Episode], out: Path) -> list[Path]:
    """The comparison figures of one study from one episode per policy; returns their paths."""
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
    paths = [save_figure(fig, out / f"{study}_vs_last_seen_trajectories.png")]
    fig = new_figure(11, 1.0 + 1.8 * n)
    plot_distances(fig, sc, eps, names)
    fig.suptitle(
        f"{study}, seed {eps[0].seed} (Fig. 9): distance, angle of view and obstacle distance; "
        "constraints dashed, shaded: predecessor not visible",
        fontsize=10,
    )
    paths.append(save_figure(fig, out / f"{study}_vs_last_seen_distances.png"))
    fig = new_figure(10, 1.0 + 1.5 * n)
    plot_commands(fig, sc, eps, labels=names)
    fig.suptitle(f"{study}, seed {eps[0].seed} (Figs. 10, 11): velocity commands", fontsize=10)
    paths.append(save_figure(fig, out / f"{study}_vs_last_seen_commands.png"))
    return paths


def trace_figure(episode: Episode, out: Path) -> Path:
    """Fig. 15 from a study C episode of the last-seen controller."""
    from platoon_env.plots import new_figure, save_figure

    sc = make_env(episode.scenario).scenario
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    fig = new_figure(8.5, 8.5 * (ymax - ymin) / (xmax - xmin) + 0.5)
    plot_last_seen_trace(fig.add_subplot(), sc, episode)
    return save_figure(fig, out / f"{episode.scenario}_last_seen_trace.png")


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> str:
    """Run the comparison; write the figures and ``comparison.md``; return the table."""
    parser = argparse.ArgumentParser(
        prog="python -m baselines.comparison",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--out", type=Path, default=Path("docs/figures"), help="output folder")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per study and policy")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    tallies = {(s, p): Tally() for s in STUDIES for p in POLICIES}
    first: dict[str, dict[str, Episode]] = {s: {} for s in STUDIES}
    jobs = [(s, p, k) for s in STUDIES for k in range(args.seeds) for p in POLICIES]
    for study, policy, seed in tqdm(jobs, desc="episodes", unit="ep"):
        ep = run(study, policy, seed, record_signals=seed == 0)
        tallies[study, policy].add(ep)
        if seed == 0:
            first[study][policy] = ep
    for study in STUDIES:
        for path in figures(study, first[study], out):
            tqdm.write(f"wrote {path}")
    last_seen = next(p for p in POLICIES if POLICIES[p] is LastSeenPolicy)
    tqdm.write(f"wrote {trace_figure(first['study_c'][last_seen], out)}")
    table = comparison_table(tallies)
    (out / "comparison.md").write_text(table + "\n")
    print(table)
    return table


if __name__ == "__main__":
    main()
