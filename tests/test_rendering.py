"""Tests of :mod:`platoon_env.rendering`: off-screen frames, colours where they should be, the
install hint when matplotlib is missing."""

from __future__ import annotations

import importlib
import sys
import types
import warnings
from typing import Any

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

from shapely.geometry import MultiPolygon, Polygon, box  # noqa: E402

from platoon_env.rendering import Renderer, draw_scene, fov_wedges, frame_size  # noqa: E402

# An L-shaped (non-convex) obstacle inside a 10 m x 6 m box.
L_HOLE = [(4.0, 2.0), (6.0, 2.0), (6.0, 4.0), (5.5, 4.0), (5.5, 2.6), (4.0, 2.6)]
OBSTACLE_POINT = (5.75, 3.5)  # inside the L's vertical bar, away from robots and wedges
FREE_POINT = (2.0, 5.0)  # free, away from robots, wedges and the leader path


@pytest.fixture
def free_space() -> Polygon:
    return box(0.0, 0.0, 10.0, 6.0).difference(Polygon(L_HOLE))


def make_config(followers: int = 3) -> types.SimpleNamespace:
    """A stand-in for ScenarioConfig with the attributes rendering reads."""
    return types.SimpleNamespace(
        name="test_scene",
        camera=types.SimpleNamespace(half_angle=np.pi / 4, range=2.0),
        robot=types.SimpleNamespace(radius=0.2),
        leader=types.SimpleNamespace(path=((0.5, 1.0), (8.0, 1.0), (9.0, 5.0))),
        followers=followers,
    )


def platoon(n_followers: int, x_lead: float = 8.5) -> tuple[np.ndarray, np.ndarray]:
    """Robots on the line y = 1, 1 m apart, facing +x; all predecessors visible."""
    poses = np.zeros((n_followers + 1, 3))
    poses[:, 0] = x_lead - np.arange(n_followers + 1)
    poses[:, 1] = 1.0
    return poses, np.ones(n_followers, dtype=bool)


def shifted(poses: np.ndarray, dx: float) -> np.ndarray:
    """The platoon moved by ``dx`` along x."""
    return poses + np.array([dx, 0.0, 0.0])


def is_grey(pixel: np.ndarray) -> bool:
    p = pixel.astype(int)
    return bool(60 <= p.min() and p.max() <= 200 and p.max() - p.min() <= 12)


def is_white(pixel: np.ndarray) -> bool:
    return bool(pixel.min() >= 245)


def world_to_pixel(renderer: Renderer, x: float, y: float) -> tuple[int, int]:
    """``(row, col)`` of the world point ``(x, y)`` in the renderer's ``"rgb_array"`` frames
    (once one has been rendered: the axes' transform then maps metres to pixels)."""
    scene = renderer._scene
    assert scene is not None, "render a frame first"
    scene.ax.apply_aspect()
    px, py = scene.ax.transData.transform((x, y))
    return round(renderer.frame_shape[0] - float(py)), round(float(px))


def test_rgb_array_frame_shape_and_dtype(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(), "rgb_array", size_px=320)
    poses, visible = platoon(3)
    frame = renderer.render(poses, visible, 0.0)
    assert isinstance(frame, np.ndarray)
    assert frame.dtype == np.uint8
    assert frame.shape == renderer.frame_shape == (*frame_size(free_space, 320), 3)
    height, width, _ = frame.shape
    assert width == 320  # the longer side, for a wide workspace
    assert height < width and height % 2 == 0
    renderer.close()


def test_tall_workspace_uses_size_for_height() -> None:
    tall = box(0.0, 0.0, 3.0, 8.0)
    renderer = Renderer(tall, make_config(1), "rgb_array", size_px=400)
    frame = renderer.render(np.array([[1.5, 3.0, 1.57], [1.5, 2.0, 1.57]]), [True], 0.0)
    assert frame is not None
    assert frame.shape == renderer.frame_shape
    assert frame.shape[0] == 400 and frame.shape[1] < 400
    renderer.close()


def test_frames_differ_when_poses_change(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(), "rgb_array", size_px=320)
    poses, visible = platoon(3)
    first = renderer.render(poses, visible, 0.0)
    again = renderer.render(poses, visible, 0.0)
    moved = poses.copy()
    moved[:, 0] -= 0.5
    moved[:, 2] += 0.3
    second = renderer.render(moved, visible, 0.5)
    assert first is not None and second is not None
    assert np.array_equal(first, again)  # the cached figure redraws identically
    assert not np.array_equal(first, second)
    renderer.close()


def test_obstacle_pixel_grey_and_free_pixel_white(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(), "rgb_array")
    poses, visible = platoon(3)
    frame = renderer.render(poses, visible, 0.0)
    assert frame is not None
    assert is_grey(frame[world_to_pixel(renderer, *OBSTACLE_POINT)])
    assert is_white(frame[world_to_pixel(renderer, *FREE_POINT)])
    # The margin beyond the workspace bounds counts as obstacle as well.
    assert is_grey(frame[world_to_pixel(renderer, -0.15, 3.0)])


def test_robot_colours_and_violation(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(), "rgb_array")
    poses, visible = platoon(3)
    visible[2] = False
    frame = renderer.render(poses, visible, 1.0, violations=[None, None, "occluded"])
    assert frame is not None

    def body(k: int) -> np.ndarray:
        # Behind the centre, off the heading tick.
        pixel = world_to_pixel(renderer, poses[k, 0] - 0.1, poses[k, 1] - 0.05)
        return frame[pixel].astype(int)

    leader, follower, violating = body(0), body(1), body(3)
    assert leader[2] > leader[0] + 60  # blue
    assert follower.max() < 90  # dark grey
    assert violating[0] > violating[1] + 80 and violating[0] > violating[2] + 80  # red


@pytest.mark.parametrize("n_followers", [1, 7])
def test_render_various_platoon_sizes(free_space: Polygon, n_followers: int) -> None:
    renderer = Renderer(free_space, make_config(n_followers), "rgb_array", size_px=256)
    poses, visible = platoon(n_followers)
    visible[::2] = False
    violations = [None] * n_followers
    violations[-1] = "out_of_range"
    frame = renderer.render(poses, visible, 2.5, violations)
    assert frame is not None and frame.shape == renderer.frame_shape


def test_render_rejects_bad_shapes(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(), "rgb_array", size_px=128)
    poses, visible = platoon(3)
    with pytest.raises(ValueError, match="visible"):
        renderer.render(poses, visible[:2], 0.0)
    with pytest.raises(ValueError, match="poses"):
        renderer.render(poses[:, :2], visible, 0.0)
    with pytest.raises(ValueError, match="violations"):
        renderer.render(poses, visible, 0.0, violations=[None])
    with pytest.raises(ValueError, match="render_mode"):
        Renderer(free_space, make_config(), "ansi")


def test_close_is_idempotent(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(), "rgb_array", size_px=128)
    renderer.close()  # before any frame
    renderer = Renderer(free_space, make_config(), "rgb_array", size_px=128)
    renderer.render(*platoon(3), 0.0)
    renderer.close()
    renderer.close()
    with pytest.raises(RuntimeError, match="close"):
        renderer.render(*platoon(3), 0.0)


def test_trail_restarts_on_reset(free_space: Polygon) -> None:
    renderer = Renderer(free_space, make_config(1), "rgb_array", size_px=200, trail_length=5)
    poses, visible = platoon(1)
    for k in range(8):
        renderer.render(shifted(poses, 0.1 * k), visible, 0.1 * k)
    assert renderer._scene is not None
    assert len(renderer._scene.trail.get_segments()) == 2
    assert len(renderer._scene.trail.get_segments()[0]) == 5
    renderer.render(poses, visible, 0.0)  # sim time went back: a new episode
    assert len(renderer._scene.trail.get_segments()) == 0


def test_human_mode_returns_none(free_space: Polygon) -> None:
    import matplotlib.pyplot as plt

    renderer = Renderer(free_space, make_config(), "human", fps=1000)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Agg cannot show a window
            assert renderer.render(*platoon(3), 0.0) is None
            assert renderer.render(*platoon(3), 0.1) is None
        assert len(plt.get_fignums()) >= 1
    finally:
        renderer.close()
        renderer.close()
        plt.ioff()
    assert renderer._fig is None


def test_draw_scene_on_pyplot_axes_with_snapshots(free_space: Polygon) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 3))
    ax = fig.add_subplot()
    config = make_config()
    poses, visible = platoon(3, x_lead=4.0)
    trail = np.stack([poses[:, :2] - [0.1 * k, 0.0] for k in range(10, 0, -1)])
    first = draw_scene(ax, free_space, config, poses, visible, 0.0, trail=trail)
    later = draw_scene(ax, free_space, config, shifted(poses, 4.0), visible, 4.0, background=False)
    assert first.robots is not later.robots
    assert ax.get_aspect() == 1.0
    x0, x1 = ax.get_xlim()
    assert x0 < 0.0 and x1 > 10.0
    fig.canvas.draw()
    with pytest.raises(ValueError, match="trail"):
        first.update(poses, visible, 0.0, trail=np.zeros((3, 2, 2)))


def test_fov_wedge_geometry() -> None:
    wedge = fov_wedges(np.array([[1.0, 2.0, np.pi / 2]]), 0.4, 1.5)[0]
    assert np.allclose(wedge[0], [1.0, 2.0])
    arc = wedge[1:]
    assert np.allclose(np.hypot(arc[:, 0] - 1.0, arc[:, 1] - 2.0), 1.5)
    angles = np.arctan2(arc[:, 1] - 2.0, arc[:, 0] - 1.0)
    assert np.isclose(angles.min(), np.pi / 2 - 0.4) and np.isclose(angles.max(), np.pi / 2 + 0.4)


def test_multipolygon_free_space_and_real_config(corridor: dict[str, Any]) -> None:
    """A real ScenarioConfig (the shared corridor's robots and camera) over two rooms."""
    schema = pytest.importorskip("platoon_env.scenarios.schema")
    rooms_scenario = {
        **corridor,
        "name": "two_rooms",
        "workspace": {"bounds": [0, 0, 9, 4]},
        "leader": {"path": [[0.5, 1], [3.5, 1]], "speed": 0.3},
        "followers": 1,
    }
    config = schema.parse_scenario(rooms_scenario)
    rooms = MultiPolygon([box(0, 0, 4, 4), box(5, 0, 9, 4)])
    renderer = Renderer(rooms, config, "rgb_array", size_px=300)
    frame = renderer.render(np.array([[2.5, 1.0, 0.0], [1.5, 1.0, 0.0]]), [True], 0.0)
    assert frame is not None
    assert is_grey(frame[world_to_pixel(renderer, 4.5, 3.0)])  # between the rooms
    assert is_white(frame[world_to_pixel(renderer, 7.0, 3.0)])
    renderer.close()


def test_missing_matplotlib_gives_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.delitem(sys.modules, "platoon_env.rendering", raising=False)
    with pytest.raises(ImportError, match=r"pip install 'platoon-env\[plot\]'"):
        importlib.import_module("platoon_env.rendering")


def test_snapshots_list_every_violation_in_one_box(corridor: dict) -> None:
    """plot_snapshots: one visible violation box listing each snapshot's causes with its time
    (they used to be drawn on top of each other, one box per snapshot)."""
    import platoon_env
    from platoon_env.plots import new_figure, plot_snapshots
    from platoon_env.rollout import run_episode

    class Spin:
        """Followers turn on the spot: they lose their predecessor and keep violating."""

        def reset(self, seed: int | None = None) -> None:
            pass

        def act(self, obs: dict) -> dict:
            return {a: np.array([0.0, 1.0], dtype=np.float32) for a in obs}

    env = platoon_env.make(corridor, terminate_on=[])
    ep = run_episode(env, Spin(), seed=0, max_steps=600, record_signals=False)
    fig = new_figure(8, 3)
    ax = fig.add_subplot()
    plot_snapshots(ax, env.scenario, ep, n_snapshots=4)
    boxes = [t for t in ax.texts if t.get_visible() and "R" in t.get_text()]
    assert len(boxes) == 1
    lines = boxes[0].get_text().splitlines()
    snapshot_times = {line.split(",")[0] for line in lines}
    assert len(lines) >= 4 and len(snapshot_times) >= 2  # several snapshots, both followers
    assert all(": out_of_fov" in line or ": occluded" in line or ": out_of_range" in line
               for line in lines)  # fmt: skip


def test_procedural_env_frames_keep_one_shape() -> None:
    """A new workspace on every reset must not change the frame size (a video writer takes one
    size): the frames show the source's bounds, which hold every layout."""
    import platoon_env

    env = platoon_env.make("procedural_train", render_mode="rgb_array")
    shapes, layouts = set(), set()
    for seed in range(5):
        env.reset(seed=seed)
        frame = env.render()
        assert isinstance(frame, np.ndarray)
        shapes.add(frame.shape)
        layouts.add(env.scenario.free_space.bounds)
    env.close()
    assert len(layouts) > 1  # the workspaces (and their own bounding boxes) did differ
    assert len(shapes) == 1


def test_bounds_fix_frame_shape_and_scale(free_space: Polygon) -> None:
    """With ``bounds`` the frame size and the world-to-pixel map depend only on the bounds, not
    on the workspace drawn inside them."""
    bounds = (0.0, 0.0, 20.0, 10.0)
    small = box(1.0, 1.0, 6.0, 9.0)
    frames, pixels = [], []
    for region in (free_space, small):
        renderer = Renderer(region, make_config(1), "rgb_array", size_px=300, bounds=bounds)
        assert renderer.bounds == bounds
        frame = renderer.render(np.array([[3.0, 5.0, 0.0], [2.0, 5.0, 0.0]]), [True], 0.0)
        assert frame is not None and frame.shape == renderer.frame_shape
        frames.append(frame.shape)
        pixels.append(world_to_pixel(renderer, 15.0, 2.0))
        assert is_grey(frame[world_to_pixel(renderer, 15.0, 5.0)])  # inside bounds, not W_f
        renderer.close()
    assert frames[0] == frames[1] == (*frame_size(bounds, 300), 3)
    assert frames[0][1] == 300  # the wide bounds' longer side
    assert pixels[0] == pixels[1]


def test_procedural_layout_config_defaults_to_the_family_bounds() -> None:
    """Without ``bounds``, a layout of a procedural family (its config keeps the ``generator``
    block) is drawn in the family's LAYOUT_BOUNDS."""
    from platoon_env.scenarios.procedural import LAYOUT_BOUNDS
    from platoon_env.scenarios.source import scenario_source

    source = scenario_source("procedural_train")
    assert source.bounds == LAYOUT_BOUNDS
    shapes = set()
    for index in (0, 1):
        layout = source.layout(index)  # type: ignore[attr-defined]
        renderer = Renderer(layout.free_space, layout.config, "rgb_array", size_px=200)
        assert renderer.bounds == LAYOUT_BOUNDS
        shapes.add(renderer.frame_shape)
    assert shapes == {(*frame_size(LAYOUT_BOUNDS, 200), 3)}


def test_error_and_command_figures_keep_their_legend_beside_the_axes(
    corridor: dict, tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The evaluator's errors and commands figures overlay only ``overlaid`` (the first
    training seed of each configuration) and keep the legend outside the axes: a legend of
    twenty-six policies inside the axes collapsed them to nothing."""
    import platoon_env
    from experiments.studies.evaluate import plot_scenario
    from platoon_env.plots import new_figure, plot_commands, plot_errors
    from platoon_env.rollout import run_episode

    class Straight:
        def reset(self, seed: int | None = None) -> None:
            pass

        def act(self, obs: dict) -> dict:
            return {a: np.array([0.2, 0.0], dtype=np.float32) for a in obs}

    env = platoon_env.make(corridor)
    ep = run_episode(env, Straight(), seed=0, max_steps=40, record_signals=False)
    for plot in (plot_errors, plot_commands):
        fig = new_figure(9, 3)
        plot(fig, env.scenario, [ep, ep], labels=["a", "b"])
        assert [t.get_text() for t in fig.legends[0].get_texts()] == ["a", "b"]
        assert not any(ax.get_legend() for ax in fig.axes)
    import platoon_env.plots as plots

    drawn: list[list[str]] = []

    def spy(fig: Any, scenario: Any, episodes: Any, labels: Any = (), followers: Any = None):
        drawn.append(list(labels))
        return plot_errors(fig, scenario, episodes, labels=labels, followers=followers)

    monkeypatch.setattr(plots, "plot_errors", spy)
    episodes = {f"cfg_s{k}": ep for k in range(5)}
    paths = plot_scenario(corridor, episodes, tmp_path, "c", overlaid=["cfg_s0", "cfg_s3"])
    assert drawn == [["cfg_s0", "cfg_s3"]]
    assert {p.name for p in paths} >= {"c_errors.png", "c_commands.png", "c_trajectories.png"}
