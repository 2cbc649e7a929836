"""Drawing of the platoon in its workspace: the env's ``render()`` and the paper's figures.

This module is imported only when rendering is requested (STYLE principle 5): matplotlib is an
optional extra, ``pip install 'platoon-env[plot]'``.

Two layers:

* :func:`draw_scene` draws one configuration onto any matplotlib ``Axes`` and returns the
  :class:`SceneArtists` it created, whose :meth:`SceneArtists.update` moves them to a new
  configuration. Plotting scripts use it for trajectories with fields of view at snapshots
  (Figs. 5, 12 of the paper).
* :class:`Renderer` owns one cached figure and renders frames for the env: ``"rgb_array"``
  draws off-screen with Agg (a ``Figure`` with its own ``FigureCanvasAgg``, never pyplot, so it
  is safe in threads and worker processes and never opens a window); ``"human"`` reuses one
  interactive pyplot window.

What is drawn: the obstacles (the complement of the free space ``W_f`` inside its bounding box
and the margin around it, opaque grey, above the fields of view since a camera does not see into
walls), the leader's path (dashed), the robots ``R_0..R_N`` as disks of radius ``r`` with a
heading tick (leader blue, followers dark grey, a follower with a violation red), each
follower's camera field of view ``F_i`` (a sector of radius ``d_con`` and half-angle
``beta_con`` centred on its heading) and each line of sight ``L_i = [p_i, p_{i-1}]`` (green when
the predecessor is visible, red dashed when not).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, Self

import numpy as np

try:
    # First and on its own: a missing matplotlib must fail here, even when some of its
    # submodules are already in ``sys.modules``.
    import matplotlib  # noqa: F401
    from matplotlib.axes import Axes
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import to_rgba
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path
    from matplotlib.text import Text
except ImportError as exc:  # pragma: no cover - exercised by a test that hides matplotlib
    raise ImportError(
        "Rendering platoon_env needs matplotlib, an optional extra. "
        "Install it with: pip install 'platoon-env[plot]'"
    ) from exc

__all__ = [
    "RENDER_MODES",
    "Renderer",
    "SceneArtists",
    "SceneConfig",
    "draw_scene",
    "fov_wedges",
    "frame_size",
    "free_space_path",
    "legend_handles",
    "obstacle_path",
]


class _CameraLike(Protocol):
    @property
    def half_angle(self) -> float: ...  # [rad] beta_con
    @property
    def range(self) -> float: ...  # [m] d_con


class _RobotLike(Protocol):
    @property
    def radius(self) -> float: ...  # [m] r


class _LeaderLike(Protocol):
    @property
    def path(self) -> Sequence[Sequence[float]]: ...  # polyline [[x, y], ...]

    @property
    def trajectory(self) -> Sequence[Sequence[float]]: ...  # timed samples [[t, x, y, theta]]


class SceneConfig(Protocol):
    """What rendering reads from a scenario: satisfied by
    :class:`platoon_env.scenarios.schema.ScenarioConfig` (and by any object with these
    attributes, e.g. a ``types.SimpleNamespace`` in a plotting script)."""

    @property
    def name(self) -> str: ...
    @property
    def camera(self) -> _CameraLike: ...
    @property
    def robot(self) -> _RobotLike: ...
    @property
    def leader(self) -> _LeaderLike: ...


#: Render modes the :class:`Renderer` supports (Gymnasium's names).
RENDER_MODES: tuple[str, ...] = ("human", "rgb_array")

# Colours. The leader is blue, followers dark grey, anything wrong red.
_OBSTACLE = "#9a9a9a"
_FREE = "#ffffff"
_BOUNDARY = "#404040"
_LEADER = "#1f77b4"
_FOLLOWER = "#303030"
_VIOLATION = "#d62728"
_SIGHT_OK = "#2ca02c"
_SIGHT_LOST = "#d62728"
_FOV_FACE = to_rgba("#f5a623", 0.18)
_FOV_EDGE = to_rgba("#c77d00", 0.55)
_TRAIL_FOLLOWER = "#7f7f7f"

# Drawing order, bottom to top.
_Z_PATH = 1.0
_Z_TRAIL = 1.5
_Z_FOV = 2.0
_Z_OBSTACLES = 3.0
_Z_SIGHT = 4.0
_Z_ROBOTS = 5.0
_Z_HEADINGS = 6.0
_Z_TEXT = 7.0

_DPI = 100
_TITLE_PX = 26  # [px] band above the axes for the title
_PAD_PX = 4  # [px] padding around the axes
_ARC_POINTS = 25  # vertices on the arc of a field-of-view wedge
_DISK_POINTS = 28  # vertices of a robot disk
_UNIT_CIRCLE = np.stack(
    [
        np.cos(np.linspace(0.0, 2.0 * math.pi, _DISK_POINTS, endpoint=False)),
        np.sin(np.linspace(0.0, 2.0 * math.pi, _DISK_POINTS, endpoint=False)),
    ],
    axis=-1,
)


# --------------------------------------------------------------------------------------------
# Geometry helpers (pure numpy; shapely only to walk the free space's rings)
# --------------------------------------------------------------------------------------------


def _polygons(geometry: Any) -> Iterator[Any]:
    """The polygons of a shapely Polygon, MultiPolygon or GeometryCollection."""
    if hasattr(geometry, "exterior"):
        if not geometry.is_empty:
            yield geometry
    elif hasattr(geometry, "geoms"):
        for part in geometry.geoms:
            yield from _polygons(part)
    else:
        raise TypeError(f"free space must be a shapely (Multi)Polygon, got {type(geometry)!r}")


def _ring(coords: Any, ccw: bool) -> np.ndarray:
    """A closed ring's vertices (closing point dropped), oriented counter-clockwise or not."""
    xy = np.asarray(coords, dtype=float)[:-1, :2]
    x, y = xy[:, 0], xy[:, 1]
    signed_area = 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))
    if (signed_area > 0) != ccw:
        xy = xy[::-1]
    return xy


def _rings_path(rings: list[np.ndarray]) -> Path:
    vertices: list[np.ndarray] = []
    codes: list[np.ndarray] = []
    for ring in rings:
        ring_codes = np.full(len(ring) + 1, Path.LINETO, dtype=Path.code_type)
        ring_codes[0] = Path.MOVETO
        ring_codes[-1] = Path.CLOSEPOLY
        vertices.append(np.vstack([ring, ring[:1]]))
        codes.append(ring_codes)
    return Path(np.concatenate(vertices), np.concatenate(codes))


def _free_space_rings(free_space: Any, ccw: bool) -> list[np.ndarray]:
    rings: list[np.ndarray] = []
    for poly in _polygons(free_space):
        rings.append(_ring(poly.exterior.coords, ccw=ccw))
        rings += [_ring(hole.coords, ccw=not ccw) for hole in poly.interiors]
    if not rings:
        raise ValueError("free space is empty")
    return rings


def free_space_path(free_space: Any) -> Path:
    """A matplotlib ``Path`` of the free space ``W_f``, holes included.

    Exteriors are counter-clockwise and holes clockwise, so the path fills correctly under
    both the non-zero and the even-odd rule.
    """
    return _rings_path(_free_space_rings(free_space, ccw=True))


def obstacle_path(free_space: Any, extent: tuple[float, float, float, float]) -> Path:
    """A matplotlib ``Path`` of the obstacles: the rectangle ``extent`` minus ``W_f``.

    ``extent`` is ``(xmin, ymin, xmax, ymax)`` and must contain the free space. The rectangle
    is counter-clockwise and the free space's rings are reversed, so the free space is a hole
    and the free space's own holes (obstacles inside it) are filled again.
    """
    x0, y0, x1, y1 = extent
    outer = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    return _rings_path([outer, *_free_space_rings(free_space, ccw=False)])


def fov_wedges(poses: np.ndarray, half_angle: float, radius: float) -> np.ndarray:
    """Polygons of the camera fields of view ``F_i`` of robots at ``poses``.

    Args:
        poses: ``(M, 3)`` array of ``[x, y, theta]``.
        half_angle: ``beta_con`` [rad].
        radius: ``d_con`` [m].

    Returns:
        ``(M, 1 + _ARC_POINTS, 2)`` vertices: the apex ``p_i`` followed by the arc from
        ``theta_i - beta_con`` to ``theta_i + beta_con``.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    offsets = np.linspace(-half_angle, half_angle, _ARC_POINTS)
    angles = poses[:, 2:3] + offsets[None, :]
    arc = poses[:, None, :2] + radius * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    return np.concatenate([poses[:, None, :2], arc], axis=1)


Bounds = tuple[float, float, float, float]  # (xmin, ymin, xmax, ymax) [m]


def _bounds_of(region: Any) -> Bounds:
    """``(xmin, ymin, xmax, ymax)`` of a shapely geometry or of a 4-sequence taken as such."""
    box = region.bounds if hasattr(region, "bounds") else region
    xmin, ymin, xmax, ymax = (float(v) for v in box)
    if not (xmin <= xmax and ymin <= ymax):
        raise ValueError(f"bounds must be (xmin, ymin, xmax, ymax), got {tuple(box)!r}")
    return xmin, ymin, xmax, ymax


def _union(a: Bounds, b: Bounds) -> Bounds:
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


def _scene_limits(region: Any) -> Bounds:
    """Axis limits: the bounding box of ``region`` (a geometry, or ``(xmin, ymin, xmax,
    ymax)``) plus a margin of 3 % of its larger side."""
    xmin, ymin, xmax, ymax = _bounds_of(region)
    margin = 0.03 * max(xmax - xmin, ymax - ymin, 1e-9)
    return xmin - margin, ymin - margin, xmax + margin, ymax + margin


def frame_size(free_space: Any, size_px: int = 640) -> tuple[int, int]:
    """``(height, width)`` in pixels of the frames a :class:`Renderer` returns.

    ``free_space`` is the workspace (a shapely geometry) or the box ``(xmin, ymin, xmax, ymax)``
    the frames show (a :class:`Renderer`'s ``bounds``). The longer side of the figure is
    ``size_px``; the other follows the box's aspect ratio (clamped to 1:3 .. 3:1) plus a band
    for the title, rounded to an even number of pixels so the frames can be encoded as H.264
    video.
    """
    xmin, ymin, xmax, ymax = _scene_limits(free_space)
    aspect = min(max((ymax - ymin) / (xmax - xmin), 1.0 / 3.0), 3.0)  # height / width
    width: float
    height: float
    if aspect <= 1.0:
        width = size_px
        height = aspect * (width - 2 * _PAD_PX) + 2 * _PAD_PX + _TITLE_PX
    else:
        height = size_px
        width = (height - 2 * _PAD_PX - _TITLE_PX) / aspect + 2 * _PAD_PX
    return 2 * round(height / 2), 2 * round(width / 2)


# --------------------------------------------------------------------------------------------
# Scene: the artists of one configuration, created once and updated per frame
# --------------------------------------------------------------------------------------------


@dataclass
class SceneArtists:
    """The per-frame artists :func:`draw_scene` created on an ``Axes``.

    :meth:`update` moves them to a new configuration without creating new artists, which is
    what makes a cached :class:`Renderer` frame cheap.
    """

    ax: Axes
    robot_radius: float  # [m] r
    half_angle: float  # [rad] beta_con
    camera_range: float  # [m] d_con
    name: str
    robots: PolyCollection
    headings: LineCollection
    fov: PolyCollection
    sight_visible: LineCollection
    sight_lost: LineCollection
    trail: LineCollection
    title: Text
    violation_text: Text

    def update(
        self,
        poses: np.ndarray,
        visible: np.ndarray,
        sim_time: float,
        violations: Sequence[str | None] = (),
        trail: np.ndarray | None = None,
    ) -> None:
        """Move the artists to a new configuration (arguments as in :func:`draw_scene`)."""
        poses, visible, violations = _check_frame(poses, visible, violations)
        n_followers = len(poses) - 1
        xy = poses[:, :2]
        heading = np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=-1)
        r = self.robot_radius

        self.robots.set_verts(list(xy[:, None, :] + r * _UNIT_CIRCLE[None, :, :]))
        colours = [_LEADER] + [
            _VIOLATION if violations[i] is not None else _FOLLOWER for i in range(n_followers)
        ]
        self.robots.set_facecolor(colours)
        self.headings.set_segments(list(np.stack([xy, xy + r * heading], axis=1)))

        self.fov.set_verts(list(fov_wedges(poses[1:], self.half_angle, self.camera_range)))
        # L_i runs from follower i to its predecessor i-1.
        sight = np.stack([xy[1:], xy[:-1]], axis=1)
        self.sight_visible.set_segments(list(sight[visible]))
        self.sight_lost.set_segments(list(sight[~visible]))

        if trail is None or len(trail) == 0:
            self.trail.set_segments([])
        else:
            trail = np.asarray(trail, dtype=float)
            if trail.ndim != 3 or trail.shape[1:] != (len(poses), 2):
                raise ValueError(f"trail must have shape (T, {len(poses)}, 2), got {trail.shape}")
            self.trail.set_segments([trail[:, k, :] for k in range(trail.shape[1])])
            self.trail.set_color([_LEADER] + [_TRAIL_FOLLOWER] * n_followers)

        self.title.set_text(f"{self.name}   t = {sim_time:.2f} s")
        lines = [f"R{i + 1}: {cause}" for i, cause in enumerate(violations) if cause is not None]
        self.violation_text.set_text("\n".join(lines))
        self.violation_text.set_visible(bool(lines))


def _check_frame(
    poses: np.ndarray, visible: np.ndarray, violations: Sequence[str | None]
) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 1:
        raise ValueError(f"poses must have shape (N+1, 3), got {poses.shape}")
    n_followers = poses.shape[0] - 1
    visible = np.asarray(visible, dtype=bool).reshape(-1)
    if visible.shape != (n_followers,):
        raise ValueError(f"visible must have shape ({n_followers},), got {visible.shape}")
    violations = list(violations)
    if not violations:
        violations = [None] * n_followers
    if len(violations) != n_followers:
        raise ValueError(f"violations must have {n_followers} entries, got {len(violations)}")
    return poses, visible, violations


def draw_scene(
    ax: Axes,
    free_space: Any,
    config: SceneConfig,
    poses: np.ndarray,
    visible: np.ndarray,
    sim_time: float,
    violations: Sequence[str | None] = (),
    trail: np.ndarray | None = None,
    *,
    background: bool = True,
    bounds: Any = None,
) -> SceneArtists:
    """Draw the workspace and one platoon configuration onto a matplotlib ``Axes``.

    Args:
        ax: any matplotlib ``Axes`` (pyplot's or an off-screen ``Figure``'s).
        free_space: the free space ``W_f`` as a shapely ``Polygon`` or ``MultiPolygon``;
            obstacles are its holes and whatever of its bounding box it does not cover.
        config: the scenario (a ``ScenarioConfig``, or any object with ``name``,
            ``camera.half_angle`` (``beta_con``), ``camera.range`` (``d_con``),
            ``robot.radius`` (``r``) and ``leader.path``).
        poses: ``(N+1, 3)`` array of ``[x, y, theta]``, leader ``R_0`` first.
        visible: ``(N,)`` bool, whether follower ``i`` sees its predecessor.
        sim_time: simulated time [s], shown in the title.
        violations: per follower, the violation cause or ``None`` (empty: no violations).
            A follower with a violation is drawn red and its cause is listed in a corner.
        trail: optional ``(T, N+1, 2)`` past positions, drawn as thin lines.
        background: draw the obstacles and the leader's path and set the axis limits and equal
            aspect. Pass ``False`` to overlay further snapshots on an axes already drawn.
        bounds: ``(xmin, ymin, xmax, ymax)`` [m] the axes show (with a 3 % margin), e.g. a box
            holding every workspace of a procedural family, so that all are drawn to one scale;
            None: the free space's bounding box. The free space is always shown whole.

    Returns:
        The per-frame artists; :meth:`SceneArtists.update` redraws them for another
        configuration.
    """
    if background:
        _draw_background(ax, free_space, config, bounds)
    # The per-frame collections, by their SceneArtists field (update() fills them); each is
    # added to the axes once.
    collections: dict[str, Any] = {
        "trail": LineCollection([], linewidths=0.8, alpha=0.8, zorder=_Z_TRAIL),
        "fov": PolyCollection(
            [], facecolors=[_FOV_FACE], edgecolors=[_FOV_EDGE], linewidths=0.6, zorder=_Z_FOV
        ),
        "sight_visible": LineCollection([], colors=_SIGHT_OK, linewidths=1.3, zorder=_Z_SIGHT),
        "sight_lost": LineCollection(
            [], colors=_SIGHT_LOST, linewidths=1.3, linestyles="--", zorder=_Z_SIGHT
        ),
        "robots": PolyCollection([], edgecolors="black", linewidths=0.5, zorder=_Z_ROBOTS),
        "headings": LineCollection([], colors="white", linewidths=1.5, zorder=_Z_HEADINGS),
    }
    for collection in collections.values():
        ax.add_collection(collection, autolim=False)
    artists = SceneArtists(
        ax=ax,
        robot_radius=float(config.robot.radius),
        half_angle=float(config.camera.half_angle),
        camera_range=float(config.camera.range),
        name=str(config.name),
        **collections,
        title=ax.set_title("", fontsize=11),
        violation_text=ax.text(
            0.01,
            0.01,
            "",
            transform=ax.transAxes,
            fontsize=8,
            color=_VIOLATION,
            ha="left",
            va="bottom",
            zorder=_Z_TEXT,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.5},
        ),
    )
    artists.update(poses, visible, sim_time, violations, trail)
    return artists


def legend_handles() -> list[Any]:
    """Labelled legend entries for what :func:`draw_scene` draws (its colours and line
    styles): one legend for a figure of many scenes, ``fig.legend(handles=legend_handles())``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    def disk(colour: str, label: str) -> Line2D:
        return Line2D([], [], marker="o", linestyle="none", markersize=8, label=label,
                      markerfacecolor=colour, markeredgecolor="black")  # fmt: skip

    return [
        disk(_LEADER, "leader"),
        disk(_FOLLOWER, "follower"),
        disk(_VIOLATION, "follower in violation"),
        Patch(facecolor=_FOV_FACE, edgecolor=_FOV_EDGE, label="camera field of view"),
        Line2D([], [], color=_SIGHT_OK, linewidth=1.3, label="predecessor in sight"),
        Line2D([], [], color=_SIGHT_LOST, linewidth=1.3, linestyle="--", label="predecessor lost"),
        Line2D([], [], color=_LEADER, alpha=0.6, linestyle="--", marker="x", label="leader's path"),
        Line2D([], [], color=_TRAIL_FOLLOWER, linewidth=0.8, label="traces"),
        Patch(facecolor=_OBSTACLE, edgecolor=_BOUNDARY, label="obstacle"),
    ]


def _draw_background(ax: Axes, free_space: Any, config: SceneConfig, bounds: Any = None) -> None:
    """Free space, obstacles, leader path, limits and aspect: what never changes."""
    box = _bounds_of(free_space)
    extent = _scene_limits(box if bounds is None else _union(_bounds_of(bounds), box))
    # The obstacles are drawn opaque above the fields of view: a camera does not see into walls.
    ax.add_patch(
        PathPatch(free_space_path(free_space), facecolor=_FREE, edgecolor="none", zorder=0.5)
    )
    ax.add_patch(
        PathPatch(
            obstacle_path(free_space, extent),
            facecolor=_OBSTACLE,
            edgecolor=_BOUNDARY,
            linewidth=1.0,
            zorder=_Z_OBSTACLES,
        )
    )
    # the leader's route: its path, or the positions of its timed trajectory
    route = config.leader.path or tuple(sample[1:3] for sample in config.leader.trajectory)
    path = np.asarray(route, dtype=float).reshape(-1, 2)
    style: dict[str, Any] = {"color": _LEADER, "alpha": 0.6, "zorder": _Z_PATH}
    ax.plot(path[:, 0], path[:, 1], linestyle="--", linewidth=1.0, **style)
    ax.plot(path[-1, 0], path[-1, 1], marker="x", markersize=6, **style)
    ax.set_xlim(extent[0], extent[2])
    ax.set_ylim(extent[1], extent[3])
    ax.set_aspect("equal", adjustable="box")


# --------------------------------------------------------------------------------------------
# Renderer: one cached figure per env
# --------------------------------------------------------------------------------------------


class Renderer:
    """Renders frames of a platoon env with a figure created once and updated per frame.

    Args:
        free_space: the free space ``W_f`` (shapely ``Polygon`` or ``MultiPolygon``).
        config: the scenario (see :func:`draw_scene` for the attributes used).
        render_mode: ``"rgb_array"`` (off-screen Agg; :meth:`render` returns an
            ``(H, W, 3)`` uint8 frame of shape :attr:`frame_shape`) or ``"human"`` (one
            interactive pyplot window, reused; :meth:`render` returns ``None``).
        size_px: the longer side of the frame [px]; see :func:`frame_size`.
        fps: frames per second; ``"human"`` mode waits so as not to exceed it.
        trail_length: keep the positions of the last ``trail_length`` rendered frames and draw
            them as trails (0: no trails). The trail restarts when ``sim_time`` goes back (a
            reset).
        bounds: ``(xmin, ymin, xmax, ymax)`` [m], a box holding every workspace this renderer's
            env can draw (``env.source.bounds``). The frame size (:func:`frame_size`) and the
            axes follow it, so every frame of the env has one shape and one scale even when each
            episode has a new workspace (a video writer needs one frame size). None: for a
            config with a ``generator`` block (a layout of a procedural family), the family's
            :data:`~platoon_env.scenarios.procedural.LAYOUT_BOUNDS`; otherwise the free space's
            own bounding box.
    """

    def __init__(
        self,
        free_space: Any,
        config: SceneConfig,
        render_mode: str,
        size_px: int = 640,
        fps: int = 30,
        trail_length: int = 0,
        *,
        bounds: Any = None,
    ) -> None:
        if render_mode not in RENDER_MODES:
            raise ValueError(
                f"render_mode must be one of {', '.join(RENDER_MODES)}, got {render_mode!r}"
            )
        if size_px < 64:
            raise ValueError(f"size_px must be >= 64, got {size_px}")
        if fps <= 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.free_space = free_space
        self.config = config
        self.render_mode = render_mode
        self.fps = fps
        self.trail_length = int(trail_length)
        if bounds is None and getattr(config, "generator", None) is not None:
            from platoon_env.scenarios.procedural import LAYOUT_BOUNDS

            bounds = LAYOUT_BOUNDS
        #: ``(xmin, ymin, xmax, ymax)`` [m] the frames show (see the ``bounds`` argument).
        self.bounds: Bounds = _bounds_of(free_space if bounds is None else bounds)
        height, width = frame_size(self.bounds, size_px)
        self._height, self._width = height, width
        self._trail: deque[np.ndarray] = deque(maxlen=max(self.trail_length, 1))
        self._last_time = -math.inf
        self._last_wall = 0.0
        self._closed = False
        self._plt: Any = None
        self._fig: Figure | None = None
        self._scene: SceneArtists | None = None
        if render_mode == "human":
            import matplotlib.pyplot as plt  # only the interactive mode needs pyplot

            self._plt = plt

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape ``(H, W, 3)`` of the frames returned in ``"rgb_array"`` mode."""
        return self._height, self._width, 3

    def _build(
        self,
        poses: np.ndarray,
        visible: np.ndarray,
        sim_time: float,
        violations: Sequence[str | None],
        trail: np.ndarray | None,
    ) -> None:
        # A hair over the integer size: Agg truncates figsize * dpi to int.
        figsize = ((self._width + 1e-3) / _DPI, (self._height + 1e-3) / _DPI)
        if self.render_mode == "human":
            plt = self._plt
            plt.ion()
            fig = plt.figure(figsize=figsize, dpi=_DPI)
            manager = fig.canvas.manager
            if manager is not None:
                manager.set_window_title(f"platoon_env: {self.config.name}")
        else:
            fig = Figure(figsize=figsize, dpi=_DPI)
            FigureCanvasAgg(fig)
        pad_x, pad_y = _PAD_PX / self._width, _PAD_PX / self._height
        top = 1.0 - _TITLE_PX / self._height
        ax = fig.add_axes((pad_x, pad_y, 1.0 - 2 * pad_x, top - pad_y))
        ax.set_xticks([])
        ax.set_yticks([])
        self._fig = fig
        self._scene = draw_scene(
            ax,
            self.free_space,
            self.config,
            poses,
            visible,
            sim_time,
            violations,
            trail,
            bounds=self.bounds,
        )

    def _window_closed(self) -> bool:
        return self._fig is not None and not self._plt.fignum_exists(self._fig.number)

    def render(
        self,
        poses: np.ndarray,
        visible: np.ndarray,
        sim_time: float,
        violations: Sequence[str | None] = (),
    ) -> np.ndarray | None:
        """Draw one frame.

        Args:
            poses: ``(N+1, 3)`` ``[x, y, theta]``, leader first.
            visible: ``(N,)`` bool per follower.
            sim_time: simulated time [s].
            violations: per follower, the violation cause or ``None`` (empty: none).

        Returns:
            In ``"rgb_array"`` mode an ``(H, W, 3)`` uint8 array (:attr:`frame_shape`); in
            ``"human"`` mode ``None``.
        """
        if self._closed:
            raise RuntimeError("Renderer.render() called after close()")
        poses, visible, violations = _check_frame(poses, visible, violations)
        trail = self._record_trail(poses, sim_time)
        if self._fig is None or (self.render_mode == "human" and self._window_closed()):
            self._build(poses, visible, sim_time, violations, trail)
        else:
            assert self._scene is not None
            self._scene.update(poses, visible, sim_time, violations, trail)
        assert self._fig is not None
        if self.render_mode == "rgb_array":
            canvas = self._fig.canvas
            assert isinstance(canvas, FigureCanvasAgg)
            canvas.draw()
            return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
        # human: keep the window responsive and the frame rate at most fps.
        wait = 1.0 / self.fps - (time.perf_counter() - self._last_wall)
        self._fig.canvas.draw_idle()
        self._plt.pause(max(wait, 0.001))
        self._last_wall = time.perf_counter()
        return None

    def _record_trail(self, poses: np.ndarray, sim_time: float) -> np.ndarray | None:
        if self.trail_length <= 0:
            return None
        if sim_time < self._last_time or (self._trail and len(self._trail[0]) != len(poses)):
            self._trail.clear()  # a new episode
        self._last_time = sim_time
        self._trail.append(poses[:, :2].copy())
        return np.stack(self._trail) if len(self._trail) > 1 else None

    def close(self) -> None:
        """Release the figure (and close the window in ``"human"`` mode). Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._fig is not None and self.render_mode == "human":
            self._plt.close(self._fig)
        self._fig = None
        self._scene = None
        self._trail.clear()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
