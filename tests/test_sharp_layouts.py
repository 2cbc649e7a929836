"""The tiers with the paper studies' geometry (``sharp``, ``paper``): their measured properties
are within their definitions, their leaders take sharp corners as the studies' do, their seeds
are their own, bad templates are errors naming the field.

The measurements are those of ``scripts/check_workspaces.py`` (imported, one source of truth),
which measures the studies the same way.
"""

from __future__ import annotations

import dataclasses
import math
from functools import cache

import numpy as np
import pytest
from layouts import same_layout
from shapely.geometry import LineString, box
from test_studies_maps import cw

import platoon_env
from platoon_env.config import (
    GENERATOR_SPLITS,
    GENERATOR_TIERS,
    GeneratorConfig,
    ScenarioConfig,
    ScenarioError,
)
from platoon_env.scenarios.leader_planner import sharp_vertices
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.procedural import (
    LAYOUT_BOUNDS,
    PATH_CLEARANCE,
    SHARP_TIERS,
    generate_scenario,
    seed_range,
)
from platoon_env.scenarios.scenario import Scenario, initial_violations
from platoon_env.scenarios.sharp_layouts import DOOR_TURN_BASE

#: Layouts per tier and kind in the property samples.
SAMPLE = 8
#: How far the measured gaps may differ from the drawn ones (the rays sample every 2 cm, the
#: coordinates are rounded to 0.1 mm).
GAP_TOLERANCE = 0.01


def _template(tier: str, kind: str = "mixed", split: str = "test") -> ScenarioConfig:
    cfg = load_config(f"procedural_{tier}_{split}")
    return dataclasses.replace(cfg, generator=GeneratorConfig(kind=kind, split=split, tier=tier))


@cache
def _sample(tier: str, kind: str) -> tuple[Scenario, ...]:
    return tuple(generate_scenario(_template(tier, kind), k) for k in range(SAMPLE))


@cache
def _properties(tier: str, kind: str) -> tuple[cw.LayoutProperties, ...]:
    return tuple(cw.layout_properties(sc) for sc in _sample(tier, kind))


def test_the_new_tiers_follow_the_three_others() -> None:
    assert GENERATOR_TIERS[:3] == ("easy", "medium", "hard")
    assert set(SHARP_TIERS) == {"sharp", "paper"} <= set(GENERATOR_TIERS)
    # the paper tier is the harder one: narrower, more corners, a stopping leader in rooms
    sharp, paper = SHARP_TIERS["sharp"], SHARP_TIERS["paper"]
    assert paper.passage_gap[1] <= sharp.passage_gap[0]
    assert paper.door_gap[1] <= sharp.door_gap[0]
    assert paper.corners[0] >= sharp.corners[0] and paper.corners[1] >= sharp.corners[1]
    assert paper.timed_rooms and not sharp.timed_rooms
    for level in SHARP_TIERS.values():
        # the corners are the studies' (at least 75 deg), a door's turn at most 90 deg
        assert level.corner_turn[0] >= math.radians(cw.SHARP_TURN_DEG) - 1e-12
        assert level.door_turn[1] <= math.pi / 2
        # the path on a door's or a passage's centre line keeps r + PATH_CLEARANCE
        assert 0.5 * min(level.door_gap[0], level.passage_gap[0]) >= PATH_CLEARANCE


@pytest.mark.parametrize("tier", sorted(SHARP_TIERS))
@pytest.mark.parametrize("kind", ["corridor", "rooms"])
def test_every_layout_is_valid(tier: str, kind: str) -> None:
    for k, sc in enumerate(_sample(tier, kind)):
        cfg = sc.config
        assert sc.layout_index == k and cfg.generator == _template(tier, kind).generator
        assert box(*LAYOUT_BOUNDS).covers(sc.free_space) and sc.free_space.is_valid
        line = LineString(sc.leader_path)
        assert line.within(sc.free_space)
        clearance = line.distance(sc.free_space.boundary) - cfg.robot.radius
        assert clearance >= PATH_CLEARANCE - 1e-3, (tier, kind, k)
        assert initial_violations(cfg, sc.workspace, np.asarray(sc.initial_poses)) == []
        # a short corridor is stretched to 15 m exactly, then its coordinates rounded to 0.1 mm;
        # a timed trajectory starts at the head of the platoon's straight, not behind it
        length = sc.path_s[-1]
        if cfg.leader.trajectory:
            length += cfg.followers * cfg.formation.d_des
        assert 15.0 - 1e-3 <= length <= 40.0 + 1e-3


@pytest.mark.parametrize("tier", sorted(SHARP_TIERS))
def test_corridors_have_sharp_corners_inside_narrow_passages(tier: str) -> None:
    level = SHARP_TIERS[tier]
    for sc, props in zip(_sample(tier, "corridor"), _properties(tier, "corridor"), strict=True):
        path = np.asarray(sc.leader_path)
        vertices = sharp_vertices(path, math.radians(cw.SHARP_TURN_DEG) - 1e-3)
        assert len(vertices) == len(path) - 2  # every vertex is a sharp corner ...
        assert level.corners[0] <= len(vertices) < level.corners[1]
        assert props.sharp_turns == len(vertices)  # ... at least 75 deg within 0.6 m
        lo, hi = level.passage_gap
        assert lo - GAP_TOLERANCE <= props.passage_gap <= hi + GAP_TOLERANCE, props
        assert math.isnan(props.door_gap) and props.obstacles == 0


@pytest.mark.parametrize("tier", sorted(SHARP_TIERS))
def test_rooms_have_doors_followed_by_a_turn(tier: str) -> None:
    level = SHARP_TIERS[tier]
    for sc, props in zip(_sample(tier, "rooms"), _properties(tier, "rooms"), strict=True):
        r = sc.config.robot.radius
        lo, hi = level.door_gap
        assert lo - GAP_TOLERANCE <= props.door_gap <= hi + GAP_TOLERANCE, props
        assert props.obstacles >= level.obstacles[0]
        # after every door (as measured) the path turns by door_turn within the turn's reach
        raw = np.asarray(sc.leader_path, dtype=float)
        step = np.hypot(*np.diff(raw, axis=0).T)
        raw = raw[np.concatenate([[True], step > 1e-9])]
        pts, s = cw.resample(raw, cw.SAMPLE_STEP)
        door = cw.door_samples(cw.normal_ray_distances(sc.free_space, pts, cw.tangents(pts)))
        starts = np.flatnonzero(door[1:] & ~door[:-1]) + 1
        assert len(starts) >= level.rooms[0] - 1
        d = np.diff(pts, axis=0)
        heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        reach = 0.15 + r + DOOR_TURN_BASE + level.door_turn_after[1] + 0.5  # wall, vertex, arc
        for i in starts:
            ahead = (s > s[i]) & (s <= s[i] + reach)
            turned = np.max(np.abs(heading[ahead[: len(heading)]] - heading[i]))
            assert turned >= level.door_turn[0] - 0.05, (tier, s[i])


def test_paper_rooms_leader_stops_and_turns_in_place() -> None:
    """The paper tier's rooms leader is a timed trajectory (study B's planner): at every
    vertex of its route it stands still and turns; a corridor's leader is pure pursuit."""
    for sc in _sample("paper", "rooms"):
        samples = np.asarray(sc.config.leader.trajectory)
        assert len(samples) > 10 and not sc.config.leader.path
        step = np.diff(samples, axis=0)
        still = np.hypot(step[:, 1], step[:, 2]) == 0.0
        turning = np.abs(np.arctan2(np.sin(step[:, 3]), np.cos(step[:, 3]))) > 1e-3
        assert np.sum(np.diff((still & turning).astype(int)) == 1) >= 2  # turns in place
        assert samples[0, 0] == 0.0 and np.all(np.diff(samples[:, 0]) > 0.0)
    for tier, kind in [("paper", "corridor"), ("sharp", "rooms")]:
        assert all(not sc.config.leader.trajectory for sc in _sample(tier, kind))


def test_the_leader_takes_the_corners_tightly() -> None:
    """Driven by the env (pure pursuit, study C's 0.2 m lookahead and 1.5 rad/s), the leader
    turns on the studies' radius at the corners and keeps off the walls."""
    sc = _sample("paper", "corridor")[0]
    traj = cw.drive_leader(sc).trajectory
    assert 0.1 < cw.tightest_turn(traj) < 0.3
    clearance = LineString(traj).distance(sc.free_space.boundary) - sc.config.robot.radius
    assert clearance > 0.15


@pytest.mark.parametrize("tier", sorted(SHARP_TIERS))
def test_seeds_and_determinism(tier: str) -> None:
    train, test = (seed_range(split, tier) for split in GENERATOR_SPLITS)
    assert max(train.start, test.start) >= min(train.stop, test.stop)
    for other in (None, *(t for t in GENERATOR_TIERS if t != tier)):
        for split in GENERATOR_SPLITS:
            block = seed_range(split, other)
            assert max(block.start, test.start) >= min(block.stop, test.stop)
    a = generate_scenario(_template(tier), 123)
    b = generate_scenario(load_config(f"procedural_{tier}_test"), 123)
    assert same_layout(a, b) and a.config.leader == b.config.leader
    np.testing.assert_array_equal(a.initial_poses, b.initial_poses)
    assert not same_layout(a, generate_scenario(_template(tier), 124))
    assert not same_layout(a, generate_scenario(_template(tier, split="train"), 123))


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"leader": {"lookahead": 0.5}}, r"leader\.lookahead"),
        ({"leader": {"max_turn_rate": 0.5}}, r"leader\.max_turn_rate"),
        (
            {
                "robot": {"radius": 2.6},
                "safety": {"d_col": 5.2},
                "formation": {"d_des": 6.0},
                "camera": {"range": 8.0},
            },
            r"robot\.radius",  # no door of 2 r + door_gap fits the rooms' walls
        ),
        ({"followers": 35}, r"scenario\.followers"),  # no room left for rooms
    ],
)
def test_inconsistent_templates_are_errors_naming_the_field(
    overrides: dict[str, object], field: str
) -> None:
    from platoon_env.scenarios.options import apply_overrides

    cfg = apply_overrides(load_config("procedural_paper_test"), overrides)
    with pytest.raises(ScenarioError, match=field):
        generate_scenario(cfg, 0)


@pytest.mark.parametrize("split", GENERATOR_SPLITS)
@pytest.mark.parametrize("tier", sorted(SHARP_TIERS))
def test_shipped_files_and_gym_ids(tier: str, split: str) -> None:
    name = f"procedural_{tier}_{split}"
    cfg = load_config(name)
    assert cfg.generator == GeneratorConfig(kind="mixed", split=split, tier=tier)
    study_c = load_config("study_c")
    for block in ("robot", "camera", "safety", "formation", "ppc"):
        assert getattr(cfg, block) == getattr(study_c, block), block
    assert dataclasses.replace(cfg.leader, speed=0.25) == dataclasses.replace(
        study_c.leader, path=(), speed=0.25
    )
    stem = f"platoon_env/SingleFollower-Procedural{tier.capitalize()}{split.capitalize()}"
    assert platoon_env.GYM_IDS[f"{stem}-v1"] == {"scenario": name}
    env = platoon_env.make(name)
    env.reset(seed=1)
    assert same_layout(env.scenario, generate_scenario(cfg, env.layout_index))
    env.close()
