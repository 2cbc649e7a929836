"""Procedural workspaces: determinism, disjoint splits, validity of every layout, env use."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import shapely
from pettingzoo.test import parallel_api_test
from shapely.geometry import LineString, box
from workspaces import path_headings

import platoon_env
from platoon_env.scenarios import corridor_layouts, procedural, room_layouts
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.procedural import (
    LAYOUT_BOUNDS,
    LAYOUTS_PER_SPLIT,
    SPLIT_OFFSETS,
    generate_scenario,
    layout_kind,
)
from platoon_env.scenarios.scenario import Scenario, initial_violations
from platoon_env.scenarios.schema import GeneratorConfig, ScenarioConfig, ScenarioError
from platoon_env.scenarios.source import scenario_source

TEMPLATE = load_config("procedural_train")
#: 30 layout numbers spread over the whole index range.
INDICES = [0, 1, 2, *range(7, LAYOUTS_PER_SPLIT, LAYOUTS_PER_SPLIT // 27)][:30]


def _template(kind: str = "mixed", split: str = "train") -> ScenarioConfig:
    return dataclasses.replace(TEMPLATE, generator=GeneratorConfig(kind=kind, split=split))


def _same_layout(a: Scenario, b: Scenario) -> bool:
    return np.array_equal(a.workspace.edges, b.workspace.edges) and np.array_equal(
        a.leader_path, b.leader_path
    )


def _max_turn(path: np.ndarray, window: float = 6.0, step: float = 0.05) -> float:
    """Largest heading change of the path within ``window`` metres of arc length [rad]."""
    heading = path_headings(path, step)
    lag = int(window / step)
    return float(
        max(np.max(np.abs(heading[k:] - heading[:-k])) for k in range(1, min(lag, len(heading))))
    )


def _side_distances(sc: Scenario, step: float = 0.1, reach: float = 3.0) -> np.ndarray:
    """Distance from points along the path to the first wall along the left and right normals
    (``(K, 2)``; inf when no wall within ``reach``)."""
    line = LineString(sc.leader_path)
    s = np.arange(step, line.length - step, step)
    pts = shapely.line_interpolate_point(line, s)
    ahead = shapely.line_interpolate_point(line, s + 0.01)
    xy = shapely.get_coordinates(pts)
    t = shapely.get_coordinates(ahead) - xy
    t /= np.hypot(t[:, :1], t[:, 1:])
    normal = np.column_stack([-t[:, 1], t[:, 0]])
    out = np.empty((len(s), 2))
    for k, sign in enumerate((1.0, -1.0)):
        rays = shapely.linestrings(np.stack([xy, xy + sign * reach * normal], axis=1))
        hits = shapely.intersection(rays, sc.free_space.boundary)
        out[:, k] = np.nan_to_num(shapely.distance(pts, hits), nan=np.inf)
    return out


# ------------------------------------------------------------------------------------------
# The contract
# ------------------------------------------------------------------------------------------


def test_split_seed_ranges_are_disjoint() -> None:
    assert set(SPLIT_OFFSETS) == {"train", "test"}
    ranges = sorted((off, off + LAYOUTS_PER_SPLIT) for off in SPLIT_OFFSETS.values())
    assert ranges[0][1] <= ranges[1][0]
    assert procedural.layout_seed("test", 0) == procedural.layout_seed("train", 0) + (
        SPLIT_OFFSETS["test"] - SPLIT_OFFSETS["train"]
    )


@pytest.mark.parametrize("name,split", [("procedural_train", "train"), ("procedural_test", "test")])
def test_shipped_procedural_files(name: str, split: str) -> None:
    cfg = load_config(name)
    assert cfg.name == name
    assert cfg.generator == GeneratorConfig(kind="mixed", split=split)
    assert cfg.leader.path == () and cfg.workspace.free_space is None
    assert cfg.followers == 2 and cfg.robot.radius == 0.15 and cfg.formation.d_des == 1.0
    assert cfg.ppc is not None and cfg.ppc.delta == 0.5 and cfg.leader.speed == 0.25
    sc = scenario_source(name).initial()  # layout number 0 of its split
    assert sc.layout_index == 0
    assert _same_layout(sc, generate_scenario(cfg, 0))
    with pytest.raises(ScenarioError, match=r"procedural.*scenario_source"):
        platoon_env.load_scenario(name)  # no single workspace to build


@pytest.mark.parametrize("index", [-1, LAYOUTS_PER_SPLIT, 2.0, True, "3"])
def test_index_is_validated(index: object) -> None:
    with pytest.raises(ValueError, match="index"):
        generate_scenario(TEMPLATE, index)  # type: ignore[arg-type]


def test_numpy_integer_index_and_bad_split() -> None:
    assert _same_layout(generate_scenario(TEMPLATE, np.int64(5)), generate_scenario(TEMPLATE, 5))
    bad = dataclasses.replace(TEMPLATE, generator=GeneratorConfig(split="validation"))
    with pytest.raises(ValueError, match="split"):
        generate_scenario(bad, 0)


def test_determinism_and_distinct_layouts() -> None:
    a = generate_scenario(_template(split="train"), 123)
    b = generate_scenario(_template(split="train"), 123)
    assert _same_layout(a, b)
    np.testing.assert_array_equal(a.initial_poses, b.initial_poses)
    # A template that already carries a workspace and a path (as the env passes it) is the same.
    c = generate_scenario(generate_scenario(_template(split="train"), 9).config, 123)
    assert _same_layout(a, c)
    others = [generate_scenario(_template(split="train"), k) for k in (124, 125, 999_999)]
    assert not any(_same_layout(a, o) for o in others)
    for k in (0, 123, 999_999):
        train = generate_scenario(_template(split="train"), k)
        test = generate_scenario(_template(split="test"), k)
        assert not _same_layout(train, test)


def test_mixed_draws_both_kinds() -> None:
    kinds = [layout_kind(_template("mixed"), k) for k in range(40)]
    assert {"corridor", "rooms"} == set(kinds)
    assert layout_kind(_template("rooms"), 3) == "rooms"


# ------------------------------------------------------------------------------------------
# Every layout is valid
# ------------------------------------------------------------------------------------------


def _check_layout(sc: Scenario) -> None:
    cfg = sc.config
    r = cfg.robot.radius
    free = sc.free_space
    assert free.is_valid and free.area > 0
    assert box(*LAYOUT_BOUNDS).covers(free)
    line = LineString(sc.leader_path)
    assert free.covers(line)
    assert line.distance(free.boundary) >= r + 0.05
    assert initial_violations(cfg, sc.workspace, np.asarray(sc.initial_poses)) == []
    assert 20 <= sc.workspace.edges.shape[0] <= 200
    assert 15.0 - 1e-6 <= sc.path_s[-1] <= 40.0 + 1e-6
    # The platoon starts on a straight stretch: every robot on the path's first segment.
    assert sc.path_s[1] >= cfg.followers * cfg.formation.d_des


@pytest.mark.parametrize("split", ["train", "test"])
@pytest.mark.parametrize("kind", ["corridor", "rooms", "mixed"])
def test_layouts_are_valid(kind: str, split: str) -> None:
    template = _template(kind, split)
    delta = 0.5
    for index in INDICES:
        sc = generate_scenario(template, index)
        _check_layout(sc)
        assert sc.config.generator == template.generator
        assert sc.layout_index == index
        if kind == "corridor":
            assert _max_turn(sc.leader_path) >= math.radians(30.0) - 1e-6, index
            side = _side_distances(sc) - sc.config.robot.radius
            assert np.any(np.all(side < delta, axis=1)), index  # narrow on both sides
            assert np.all(side > 0.25 - 1e-3), index  # never narrower than 2 (r + 0.25)
        elif kind == "rooms":
            assert len(sc.free_space.interiors) >= 2, index  # the non-convex obstacles


def test_fallback_when_sampling_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(corridor_layouts, "sample_corridor", lambda rng, p: None)
    monkeypatch.setattr(room_layouts, "sample_rooms", lambda rng, p: None)
    sc = generate_scenario(TEMPLATE, 42)
    assert sc.layout_index == 42 and sc.config.generator == TEMPLATE.generator
    assert box(*LAYOUT_BOUNDS).covers(sc.free_space)
    assert initial_violations(sc.config, sc.workspace, np.asarray(sc.initial_poses)) == []
    assert sc.path_s[-1] >= 15.0


def test_other_study_parameters() -> None:
    """Larger platoons and robots (studies A and B) get layouts sized for them."""
    for study in ("study_a", "study_b"):
        cfg = load_config(study)
        # Study B's leader replays a timed trajectory; a procedural leader follows its path.
        leader = dataclasses.replace(cfg.leader, trajectory=())
        template = dataclasses.replace(cfg, leader=leader, generator=GeneratorConfig())
        for index in range(5):
            sc = generate_scenario(template, index)
            cfg = sc.config
            assert box(*LAYOUT_BOUNDS).covers(sc.free_space)
            line = LineString(sc.leader_path)
            assert line.distance(sc.free_space.boundary) >= cfg.robot.radius + 0.05
            assert sc.path_s[1] >= cfg.followers * cfg.formation.d_des


# ------------------------------------------------------------------------------------------
# In the env
# ------------------------------------------------------------------------------------------


def test_env_resets_to_seeded_layouts() -> None:
    env = platoon_env.make("procedural_test", terminate_on=())
    env.reset(seed=3)
    index, edges = env.layout_index, env.scenario.workspace.edges.copy()
    assert index is not None and 0 <= index < LAYOUTS_PER_SPLIT
    assert _same_layout(env.scenario, generate_scenario(_template(split="test"), index))
    assert env.scenario.layout_index == index
    env.reset(seed=4)
    env.reset(seed=3)
    assert env.layout_index == index
    np.testing.assert_array_equal(env.scenario.workspace.edges, edges)
    layouts = set()
    for seed in range(8):
        env.reset(seed=seed)
        layouts.add(env.layout_index)
        assert box(*LAYOUT_BOUNDS).covers(env.scenario.free_space)
    assert len(layouts) >= 7
    env.reset(seed=11)
    for _ in range(300):  # zero actions: the leader drives off, violations do not terminate
        obs, _, term, trunc, infos = env.step(
            {a: np.zeros(2, dtype=np.float32) for a in env.agents}
        )
        assert not any(term.values()) and not any(trunc.values())
        for agent, o in obs.items():
            assert env.observation_space(agent).contains(o)
            assert infos[agent]["cost"] in (0, 1)
        assert env.state_space.contains(env.state())
    assert env.steps == 300 and env.sim_time > 0.0


def test_parallel_api() -> None:
    parallel_api_test(platoon_env.make("procedural_train"), num_cycles=100)
