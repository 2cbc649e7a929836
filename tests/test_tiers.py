"""Difficulty tiers of the procedural layouts: ordered properties, disjoint seeds, the shipped
tier scenarios, their Gymnasium ids and the ``heldout`` suite."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
from functools import cache

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from layouts import same_layout
from shapely.geometry import LineString, box
from workspaces import path_headings

import platoon_env
from platoon_env.scenarios._layout import Params
from platoon_env.scenarios.loader import list_scenarios, load_config
from platoon_env.scenarios.procedural import (
    DEFAULT_DIFFICULTY,
    LAYOUT_BOUNDS,
    LAYOUTS_PER_SPLIT,
    PATH_CLEARANCE,
    SHARP_TIERS,
    SPLIT_OFFSETS,
    TIERS,
    generate_scenario,
    layout_seed,
    seed_range,
)
from platoon_env.scenarios.scenario import Scenario, initial_violations
from platoon_env.scenarios.schema import (
    GENERATOR_SPLITS,
    GENERATOR_TIERS,
    GeneratorConfig,
    ScenarioConfig,
    ScenarioError,
    config_to_mapping,
    parse_scenario,
)

BASE = load_config("procedural_test")
assert BASE.ppc is not None
DELTA = BASE.ppc.delta
#: Layouts per tier and kind in the property samples.
SAMPLE = 30
#: The three ordered tiers (easy to hard); the tiers with the studies' geometry (SHARP_TIERS)
#: follow them in GENERATOR_TIERS and are tested in test_sharp_layouts.py.
ORDERED = tuple(TIERS)
#: Every (tier, split) pair; tier None is the untiered family.
PAIRS = [(tier, split) for tier in (None, *GENERATOR_TIERS) for split in GENERATOR_SPLITS]


def _template(tier: str | None, kind: str = "mixed", split: str = "test") -> ScenarioConfig:
    return dataclasses.replace(BASE, generator=GeneratorConfig(kind=kind, split=split, tier=tier))


@cache
def _sample(tier: str, kind: str) -> tuple[Scenario, ...]:
    return tuple(generate_scenario(_template(tier, kind), k) for k in range(SAMPLE))


def _clearance(sc: Scenario) -> float:
    """The leader path's clearance beyond ``r`` (a corridor's narrowest piece, a rooms
    layout's narrowest doorway or closest obstacle)."""
    line = LineString(sc.leader_path)
    return float(line.distance(sc.free_space.boundary)) - sc.config.robot.radius


def _max_turn(path: np.ndarray, window: float = 3.0, step: float = 0.05) -> float:
    """The largest heading change of the path over ``window`` metres of arc length [rad]."""
    heading = path_headings(path, step)
    lag = int(window / step)
    return float(np.max(np.abs(heading[lag:] - heading[:-lag])))


def _mean(values: list[float]) -> float:
    return float(np.mean(values))


def _strictly_increasing(values: list[float]) -> bool:
    return all(a < b for a, b in itertools.pairwise(values))


# ------------------------------------------------------------------------------------------
# The tiers' parameters and their measured effect
# ------------------------------------------------------------------------------------------


def test_tier_names_and_default() -> None:
    assert ORDERED == GENERATOR_TIERS[:3] == ("easy", "medium", "hard")
    assert GENERATOR_TIERS == (*TIERS, *SHARP_TIERS) == (*ORDERED, "sharp", "paper")
    assert Params.from_template(BASE).difficulty is DEFAULT_DIFFICULTY  # untiered
    for tier in ORDERED:
        assert Params.from_template(_template(tier)).difficulty is TIERS[tier]
    assert len({TIERS[t] for t in ORDERED} | {DEFAULT_DIFFICULTY}) == 4


def test_tier_parameters_are_ordered() -> None:
    """From easy to hard every range moves towards the harder end (none moves back)."""
    easy, medium, hard = (TIERS[t] for t in ORDERED)
    harder_when_larger = (
        "sharp_fraction",
        "sharp_turn",
        "gentle_turn",
        "bearing_fraction",
        "narrow_fraction",
        "pillars",
        "pillar_fraction",
        "rooms",
        "obstacles",
        "obstacle_size",
        "obstacle_beside",
        "segments",
    )
    harder_when_smaller = ("radius_factor", "narrow_clearance", "door_clearance", "obstacle_offset")
    fields = {f.name for f in dataclasses.fields(DEFAULT_DIFFICULTY)}
    assert fields == {*harder_when_larger, *harder_when_smaller, "wide_clearance"}
    for name in harder_when_larger + harder_when_smaller:
        a, b, c = (np.asarray(getattr(d, name), dtype=float) for d in (easy, medium, hard))
        if name in harder_when_smaller:
            a, b, c = -a, -b, -c
        assert np.all(a <= b) and np.all(b <= c), name
        assert np.any(a < c), name
    # The wide pieces: narrower at the low end (hard's top end leaves room for its pillars).
    assert easy.wide_clearance[0] > medium.wide_clearance[0] > hard.wide_clearance[0]
    # Solvable in principle: a follower on the path keeps its predecessor in view.
    assert all(0.0 < d.bearing_fraction < 1.0 for d in TIERS.values())
    assert all(d.narrow_clearance[0] > PATH_CLEARANCE for d in TIERS.values())
    assert all(d.door_clearance[0] > PATH_CLEARANCE for d in TIERS.values())


def test_measured_properties_are_ordered() -> None:
    """Over samples of layouts: narrower corridors and doorways, sharper turns and more
    obstacles from easy to hard."""
    corridor_clear, turns, room_clear, obstacles = [], [], [], []
    for tier in ORDERED:
        corridors, rooms = _sample(tier, "corridor"), _sample(tier, "rooms")
        corridor_clear.append(_mean([_clearance(sc) for sc in corridors]))
        turns.append(_mean([_max_turn(sc.leader_path) for sc in corridors]))
        room_clear.append(_mean([_clearance(sc) for sc in rooms]))
        both = corridors + rooms
        obstacles.append(_mean([len(sc.free_space.interiors) for sc in both]))
    assert _strictly_increasing([-c for c in corridor_clear]), corridor_clear
    assert _strictly_increasing(turns), turns
    assert _strictly_increasing([-c for c in room_clear]), room_clear
    assert _strictly_increasing(obstacles), obstacles
    # ... by clear margins, not by noise.
    assert corridor_clear[0] - corridor_clear[2] > 0.1
    assert turns[2] - turns[0] > math.radians(30.0)
    assert obstacles[2] - obstacles[0] > 1.5


@pytest.mark.parametrize("tier", ORDERED)
def test_every_tier_layout_is_valid(tier: str) -> None:
    """The guarantees of every layout hold in every tier (feasible start, path clearance)."""
    level = TIERS[tier]
    for kind in ("corridor", "rooms"):
        for k, sc in enumerate(_sample(tier, kind)):
            cfg = sc.config
            assert sc.layout_index == k and cfg.generator == _template(tier, kind).generator
            assert box(*LAYOUT_BOUNDS).covers(sc.free_space) and sc.free_space.is_valid
            assert LineString(sc.leader_path).within(sc.free_space)
            assert _clearance(sc) >= PATH_CLEARANCE - 1e-3, (tier, kind, k)
            assert initial_violations(cfg, sc.workspace, np.asarray(sc.initial_poses)) == []
            assert 15.0 - 1e-6 <= sc.path_s[-1] <= 40.0 + 1e-6
            assert sc.path_s[1] >= cfg.followers * cfg.formation.d_des
            if kind == "corridor":  # a narrow piece: the PPC clearance terms engage
                assert _clearance(sc) < DELTA, (tier, k)
            else:  # no fallback corridor: the tier's obstacles are there
                assert len(sc.free_space.interiors) >= level.obstacles[0], (tier, k)


# ------------------------------------------------------------------------------------------
# Seeds, determinism, validation
# ------------------------------------------------------------------------------------------


def test_seed_blocks_are_disjoint() -> None:
    """No two (tier, split) pairs share a layout seed: not train and test of one tier, not
    two tiers, not a tier and the untiered family."""
    ranges = {pair: seed_range(pair[1], pair[0]) for pair in PAIRS}
    assert all(len(r) == LAYOUTS_PER_SPLIT for r in ranges.values())
    for (p, a), (q, b) in itertools.combinations(ranges.items(), 2):
        assert max(a.start, b.start) >= min(a.stop, b.stop), (p, q)  # empty intersection
    # The untiered family keeps its seeds.
    for split in GENERATOR_SPLITS:
        assert seed_range(split) == range(SPLIT_OFFSETS[split], SPLIT_OFFSETS[split] + 10**6)
        assert layout_seed(split, 7) == SPLIT_OFFSETS[split] + 7
    # layout_seed maps the indices onto the pair's block, one to one.
    for tier, split in PAIRS:
        block = ranges[(tier, split)]
        first, last = layout_seed(split, 0, tier), layout_seed(split, LAYOUTS_PER_SPLIT - 1, tier)
        assert (first, last) == (block[0], block[-1])


#: sha256 of the edges and leader paths of layouts 0, 1, 2 and 999 999 of both splits of the
#: untiered family and of easy, medium and hard (kind mixed), as shipped before the tiers with
#: the studies' geometry were added: those layouts, and results stored for them, stay valid.
LAYOUTS_DIGEST = "40574b7ea588eae2c7a645f0b8af171376057fa8f2228421672c926fd7e87f7f"


def test_existing_tiers_are_unchanged() -> None:
    digest = hashlib.sha256()
    for tier in (None, *ORDERED):
        for split in GENERATOR_SPLITS:
            template = _template(tier, split=split)
            for k in (0, 1, 2, LAYOUTS_PER_SPLIT - 1):
                sc = generate_scenario(template, k)
                digest.update(np.ascontiguousarray(sc.workspace.edges).tobytes())
                digest.update(np.ascontiguousarray(sc.leader_path).tobytes())
    assert digest.hexdigest() == LAYOUTS_DIGEST
    # and their seed blocks: the new tiers come after them
    assert [seed_range("train", t).start for t in GENERATOR_TIERS] == [
        2 * LAYOUTS_PER_SPLIT * (k + 1) for k in range(len(GENERATOR_TIERS))
    ]


def test_shipped_files_use_disjoint_seed_blocks() -> None:
    procedural_names = [n for n in list_scenarios() if load_config(n).generator is not None]
    blocks: dict[tuple[str | None, str], list[str]] = {}
    for name in procedural_names:
        gen = load_config(name).generator
        assert gen is not None
        blocks.setdefault((gen.tier, gen.split), []).append(name)
    for tier in GENERATOR_TIERS:
        for split in GENERATOR_SPLITS:
            # the tier's own file, and the files that draw a formation per layout on its seeds
            # (the formation is drawn first from the layout's stream: other layouts)
            own, *others = sorted(blocks[(tier, split)], key=lambda n: "formations" in n)
            assert own == f"procedural_{tier}_{split}"
            assert all(load_config(n).generator.formation is not None for n in others)  # type: ignore[union-attr]
    # Every test split's seeds are disjoint from every train split's.
    test = [seed_range("test", t) for t, s in blocks if s == "test"]
    train = [seed_range("train", t) for t, s in blocks if s == "train"]
    assert all(max(a.start, b.start) >= min(a.stop, b.stop) for a in test for b in train)


@pytest.mark.parametrize("tier", ORDERED)
def test_shipped_tier_files(tier: str) -> None:
    for split in GENERATOR_SPLITS:
        name = f"procedural_{tier}_{split}"
        cfg = load_config(name)
        assert cfg.name == name
        assert cfg.generator == GeneratorConfig(kind="mixed", split=split, tier=tier)
        # Study C's robots, sensors and PPC, as procedural_test.
        same = dataclasses.replace(cfg, name=BASE.name, description=BASE.description)
        assert same == dataclasses.replace(BASE, generator=cfg.generator)
        mapping = {"kind": "mixed", "split": split, "tier": tier}
        assert config_to_mapping(cfg)["generator"] == mapping


def test_untiered_mapping_is_unchanged() -> None:
    """No tier, no ``tier`` key: the untiered scenarios keep their mapping (fingerprint)."""
    assert config_to_mapping(BASE)["generator"] == {"kind": "mixed", "split": "test"}


def test_determinism() -> None:
    a = generate_scenario(_template("hard"), 321)
    b = generate_scenario(load_config("procedural_hard_test"), 321)
    assert same_layout(a, b)
    np.testing.assert_array_equal(a.initial_poses, b.initial_poses)
    # Another index, split or tier is another layout (and so is the untiered one).
    others = [
        generate_scenario(_template("hard"), 322),
        generate_scenario(_template("hard", split="train"), 321),
        generate_scenario(_template("medium"), 321),
        generate_scenario(_template(None), 321),
    ]
    assert not any(same_layout(a, o) for o in others)
    env = platoon_env.make("procedural_medium_test")
    env.reset(seed=7)
    index, edges = env.layout_index, env.scenario.workspace.edges.copy()
    assert index is not None
    assert same_layout(env.scenario, generate_scenario(_template("medium"), index))
    env.reset(seed=8)
    env.reset(seed=7)
    assert env.layout_index == index
    np.testing.assert_array_equal(env.scenario.workspace.edges, edges)


@pytest.mark.parametrize("tier", ["extreme", "Easy", ""])
def test_bad_tier_is_rejected(tier: str) -> None:
    data = config_to_mapping(BASE)
    data["generator"] = {"kind": "mixed", "split": "test", "tier": tier}
    with pytest.raises(ScenarioError, match=r"generator\.tier.*easy, medium, hard"):
        parse_scenario(data)
    with pytest.raises(ScenarioError, match=r"generator\.tier"):
        platoon_env.make("procedural_easy_test", generator={"tier": tier})
    # A config built in code, unchecked: the generator refuses it too.
    bad = dataclasses.replace(BASE, generator=GeneratorConfig(tier=tier))
    with pytest.raises(ValueError, match=r"generator\.tier"):
        generate_scenario(bad, 0)
    with pytest.raises(ValueError, match=r"generator\.tier"):
        layout_seed("test", 0, tier)


def test_tier_must_be_a_string() -> None:
    data = config_to_mapping(BASE)
    data["generator"] = {"tier": 2}
    with pytest.raises(ScenarioError, match=r"generator\.tier.*expected a string"):
        parse_scenario(data)
    data["generator"] = {"tier": None}  # explicit null: untiered
    assert parse_scenario(data).generator == GeneratorConfig()
    with pytest.raises(ValueError, match="split"):
        seed_range("validation", "easy")


# ------------------------------------------------------------------------------------------
# Gymnasium ids and the heldout suite
# ------------------------------------------------------------------------------------------


def test_gym_ids_of_the_tiers() -> None:
    for tier in GENERATOR_TIERS:
        for split in GENERATOR_SPLITS:
            stem = f"platoon_env/SingleFollower-Procedural{tier.capitalize()}{split.capitalize()}"
            name = f"procedural_{tier}_{split}"
            assert platoon_env.GYM_IDS[f"{stem}-v1"] == {"scenario": name}
            aruco = {"scenario": name, "sensor_profile": "aruco"}
            assert platoon_env.GYM_IDS[f"{stem}-Aruco-v1"] == aruco
            assert f"{stem}-v1" in gym.registry and f"{stem}-Aruco-v1" in gym.registry


@pytest.mark.parametrize(
    ("env_id", "tier", "split"),
    [
        ("platoon_env/SingleFollower-ProceduralEasyTest-v1", "easy", "test"),
        ("platoon_env/SingleFollower-ProceduralMediumTrain-v1", "medium", "train"),
        ("platoon_env/SingleFollower-ProceduralHardTest-Aruco-v1", "hard", "test"),
    ],
)
def test_gym_make_and_check_env(env_id: str, tier: str, split: str) -> None:
    env = gym.make(env_id)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    inner = env.unwrapped.parallel  # type: ignore[attr-defined]
    template = inner.source.config
    assert inner.n_followers == 1 and template.followers == 1
    assert template.generator == GeneratorConfig(kind="mixed", split=split, tier=tier)
    # The layout is one of the tier's family, sized for the one follower.
    assert same_layout(inner.scenario, generate_scenario(template, inner.layout_index))
    env.close()


def test_heldout_suite_runs_every_tier() -> None:
    from experiments.suites import SUITES, suite

    heldout = suite("heldout")
    assert heldout.scenarios == tuple(f"procedural_{t}_test" for t in GENERATOR_TIERS)
    assert heldout.seeds >= 200
    assert [c.label for c in heldout.conditions] == ["ideal", "aruco"]
    assert dict(heldout.conditions[1].overrides) == {"sensor_profile": "aruco"}
    assert "heldout" in SUITES
    generators = {name: load_config(name).generator for name in list_scenarios()}
    train = [seed_range(g.split, g.tier) for g in generators.values() if g and g.split == "train"]
    # untiered, corridors and formations (both untiered), the tiers, formations on sharp and paper
    assert len(train) == 3 + len(GENERATOR_TIERS) + 2
    for name in heldout.scenarios:
        gen = generators[name]
        assert gen is not None and gen.split == "test"
        block = seed_range("test", gen.tier)
        assert all(max(block.start, t.start) >= min(block.stop, t.stop) for t in train)


def test_procedural_source_repr_names_the_tier() -> None:
    import platoon_env

    tiered = repr(platoon_env.make("procedural_hard_test").source)
    assert "split='test'" in tiered and "tier='hard'" in tiered
    assert "tier=" not in repr(platoon_env.make("procedural_test").source)
