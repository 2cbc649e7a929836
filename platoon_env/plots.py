"""Plots of recorded episodes, as in the paper's figures (needs the ``plot`` extra).

* :func:`plot_snapshots` — the platoon in its workspace at several instants, with fields of view
  and the robots' traces (Fig. 5, 8, 12, 15); :func:`draw_episode_at` — one instant;
* :func:`plot_errors` — ``e_d`` and ``e_beta`` of every follower with the safety limits and, for
  PPC, the performance functions (Fig. 6, 9, 13, 14);
* :func:`plot_commands` — the velocity commands ``u``, ``omega`` (Fig. 7, 10, 11);
* :func:`save_gif` — an animation of an episode.

Every function takes :class:`platoon_env.rollout.Episode` objects; several episodes (e.g. one
per policy) are overlaid with a legend.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

try:
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.axes import Axes
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
except ImportError as exc:  # pragma: no cover - exercised by the install hint only
    raise ImportError("plotting needs matplotlib: pip install 'platoon-env[plot]'") from exc

from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D, SENSE_VISIBLE
from platoon_env.rendering import SceneArtists, draw_scene
from platoon_env.rollout import Episode
from platoon_env.safety import first_cause
from platoon_env.scenarios.scenario import Scenario

#: Line colours for overlaid episodes (one per policy).
POLICY_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")


def new_figure(width: float, height: float, dpi: int = 90) -> Figure:
    """An off-screen figure (Agg canvas attached), safe in worker processes."""
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _violations_at(ep: Episode, k: int) -> list[str | None]:
    if k == 0 or ep.violations.size == 0:
        return []
    return [first_cause(int(m)) for m in ep.violations[min(k, ep.steps) - 1]]


def draw_episode_at(
    ax: Axes,
    scenario: Scenario,
    ep: Episode,
    k: int,
    violations: Sequence[str | None] = (),
    trail: np.ndarray | None = None,
    *,
    background: bool = True,
) -> SceneArtists:
    """The workspace and the platoon of ``ep`` at sample ``k``: its poses, which followers see
    their predecessors and its time (:func:`platoon_env.rendering.draw_scene`)."""
    return draw_scene(
        ax,
        scenario.free_space,
        scenario.config,
        ep.poses[k],
        ep.sensed[k, :, SENSE_VISIBLE] > 0,
        float(ep.times[k]),
        violations,
        trail,
        background=background,
    )


def plot_snapshots(
    ax: Axes, scenario: Scenario, ep: Episode, n_snapshots: int = 6, title: str | None = None
) -> None:
    """The platoon at ``n_snapshots`` evenly spaced instants over its traces (Fig. 5, 12).

    Followers with a violation are drawn red in their snapshot; the causes of every snapshot
    are listed together, with their times, in one box in the corner.
    """
    cfg = scenario.config
    idx = np.unique(np.linspace(0, ep.times.size - 1, n_snapshots).round().astype(int))
    notes: list[str] = []
    for j, k in enumerate(idx):
        violations = _violations_at(ep, int(k))
        artists = draw_episode_at(
            ax,
            scenario,
            ep,
            int(k),
            violations,
            trail=ep.poses[: k + 1, :, :2] if j == len(idx) - 1 else None,
            background=j == 0,
        )
        artists.violation_text.set_visible(False)  # one shared box below, not one per snapshot
        notes += [
            f"t = {ep.times[k]:.1f} s, R{i + 1}: {cause}"
            for i, cause in enumerate(violations)
            if cause is not None
        ]
    if notes:
        artists.violation_text.set_text("\n".join(notes))
        artists.violation_text.set_visible(True)
    ax.set_title(
        title or f"{cfg.name}: snapshots every {ep.times[idx[1]] - ep.times[idx[0]]:.0f} s"
        if len(idx) > 1
        else cfg.name
    )


def _follower_axes(
    fig: Figure, scenario: Scenario, followers: Sequence[int] | None
) -> tuple[list[int], np.ndarray]:
    """The followers a per-follower figure shows (None: all) and its axes, a row each and two
    columns sharing the time axis (labelled under the bottom row)."""
    n = scenario.config.followers
    rows = list(followers) if followers is not None else list(range(1, n + 1))
    axes = fig.subplots(len(rows), 2, squeeze=False, sharex=True)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    return rows, axes


def _overlaid(
    episodes: Sequence[Episode], labels: Sequence[str]
) -> Iterator[tuple[Episode, str, str | None]]:
    """Each overlaid episode with its line colour and legend label (None beyond ``labels``)."""
    for j, ep in enumerate(episodes):
        yield ep, POLICY_COLOURS[j % len(POLICY_COLOURS)], labels[j] if j < len(labels) else None


def plot_errors(
    fig: Figure,
    scenario: Scenario,
    episodes: Sequence[Episode],
    labels: Sequence[str] = (),
    followers: Sequence[int] | None = None,
) -> None:
    """``e_d`` and ``e_beta`` per follower (rows) with limits and funnels (Fig. 6, 13, 14).

    Dashed black: the safety limits ``-(d_des - d_col)``, ``d_con - d_des`` and ``±beta_con``
    (eq. 11). Red: the performance functions, when an episode carries PPC signals (the first
    such episode). Errors are drawn only while the predecessor is visible.
    """
    cfg = scenario.config
    rows, axes = _follower_axes(fig, scenario, followers)
    d_lo, d_hi = -(cfg.formation.d_des - cfg.safety.d_col), cfg.camera.range - cfg.formation.d_des
    b = cfg.camera.half_angle
    funnel_drawn = False
    for ep, colour, label in _overlaid(episodes, labels):
        t = ep.times
        vis = ep.sensed[:, :, SENSE_VISIBLE] > 0
        e_d = np.where(vis, ep.sensed[:, :, SENSE_D] - cfg.formation.d_des, np.nan)
        e_b = np.where(vis, ep.sensed[:, :, SENSE_BETA], np.nan)
        has_rho = not funnel_drawn and "rho_d_lo" in ep.signals and ep.signals["rho_d_lo"].size
        for r, i in enumerate(rows):
            axes[r, 0].plot(t, e_d[:, i - 1], color=colour, lw=1.0, label=label if r == 0 else None)
            axes[r, 1].plot(t, e_b[:, i - 1], color=colour, lw=1.0)
            if has_rho:
                ts = t[: ep.signals["rho_d_lo"].shape[0]]
                for key, col in (
                    ("rho_d_lo", 0),
                    ("rho_d_hi", 0),
                    ("rho_beta_lo", 1),
                    ("rho_beta_hi", 1),
                ):
                    axes[r, col].plot(
                        ts,
                        ep.signals[key][:, i - 1],
                        color="tab:red",
                        lw=0.8,
                        label="performance functions" if (r == 0 and key == "rho_d_lo") else None,
                    )
        funnel_drawn = funnel_drawn or bool(has_rho)
    for r, i in enumerate(rows):
        for lim in (d_lo, d_hi):
            axes[r, 0].axhline(lim, color="k", ls="--", lw=0.8)
        for lim in (-b, b):
            axes[r, 1].axhline(lim, color="k", ls="--", lw=0.8)
        axes[r, 0].set_ylabel(f"$e_{{d_{i}}}$ [m]")
        axes[r, 1].set_ylabel(f"$e_{{\\beta_{i}}}$ [rad]")
        axes[r, 0].set_ylim(d_lo * 1.15, d_hi * 1.15)
        axes[r, 1].set_ylim(-b * 1.15, b * 1.15)
    if any(a.get_legend_handles_labels()[0] for a in axes[0]):
        fig.legend(loc="outside right upper", fontsize=7)


def plot_commands(
    fig: Figure,
    scenario: Scenario,
    episodes: Sequence[Episode],
    labels: Sequence[str] = (),
    followers: Sequence[int] | None = None,
) -> None:
    """Linear and angular velocity commands per follower (Fig. 7, 10, 11)."""
    rows, axes = _follower_axes(fig, scenario, followers)
    for ep, colour, label in _overlaid(episodes, labels):
        t = ep.times[1:]
        for r, i in enumerate(rows):
            axes[r, 0].plot(
                t, ep.actions[:, i - 1, 0], color=colour, lw=0.8, label=label if r == 0 else None
            )
            axes[r, 1].plot(t, ep.actions[:, i - 1, 1], color=colour, lw=0.8)
    for r, i in enumerate(rows):
        axes[r, 0].set_ylabel(f"$u_{i}$ [m/s]")
        axes[r, 1].set_ylabel(f"$\\omega_{i}$ [rad/s]")
    if labels:
        fig.legend(loc="outside right upper", fontsize=7)


def save_figure(fig: Figure, path: str | Path, metadata: dict[str, str] | None = None) -> Path:
    """Write ``fig`` as PNG (parents created) and return the path; ``metadata`` are PNG text
    fields (e.g. :func:`experiments.stamp.png_metadata`: the code and command that made it)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, metadata=metadata)
    return out


def save_gif(
    scenario: Scenario,
    ep: Episode,
    path: str | Path,
    fps: int = 10,
    frame_every: float = 1.0,
    size_px: int = 480,
) -> Path:
    """An animated GIF of ``ep``: one frame every ``frame_every`` seconds of simulated time."""
    import imageio.v2 as imageio

    from platoon_env.rendering import Renderer

    renderer = Renderer(scenario.free_space, scenario.config, "rgb_array", size_px=size_px)
    stride = max(1, round(frame_every / ep.control_period))
    frames: list[Any] = []
    for k in range(0, ep.times.size, stride):
        frame = renderer.render(
            ep.poses[k],
            ep.sensed[k, :, SENSE_VISIBLE] > 0,
            float(ep.times[k]),
            _violations_at(ep, k),
        )
        assert frame is not None
        frames.append(frame)
    renderer.close()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    imageio.mimsave(out, frames, duration=1.0 / fps, loop=0)
    return out
