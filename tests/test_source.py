"""Scenario sources: a fixed workspace and the procedural generator behind one interface."""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from gymnasium.utils import seeding
from shapely.geometry import box

import platoon_env
from platoon_env import config
from platoon_env.scenarios import (
    FixedSource,
    ProceduralSource,
    Scenario,
    ScenarioConfig,
    ScenarioError,
    ScenarioSource,
    build_scenario,
    list_scenarios,
    load_config,
    load_scenario,
    scenario_source,
    schema,
    trajectory,
    validate,
)
from platoon_env.scenarios import source as source_module
from platoon_env.scenarios.procedural import LAYOUT_BOUNDS, LAYOUTS_PER_SPLIT, generate_scenario

SCENARIOS = list_scenarios()
PROCEDURAL = [n for n in SCENARIOS if load_config(n).generator is not None]
FIXED = [n for n in SCENARIOS if n not in PROCEDURAL]
SCENARIOS_DIR = Path(platoon_env.__file__).parent / "scenarios"


def _same_layout(a: Scenario, b: Scenario) -> bool:
    return (
        np.array_equal(a.workspace.edges, b.workspace.edges)
        and np.array_equal(a.leader_path, b.leader_path)
        and np.array_equal(a.initial_poses, b.initial_poses)
    )


def test_shipped_names_split_both_ways() -> None:
    assert {"study_a", "study_b", "study_c"} <= set(FIXED)
    assert {"procedural_train", "procedural_test"} <= set(PROCEDURAL)


# ------------------------------------------------------------------------------------------
# Every shipped scenario
# ------------------------------------------------------------------------------------------


#: The shipped scenarios that draw their formation per layout (generator.formation).
DRAWN = (
    "procedural_formations_train",
    "procedural_formations_test",
    "procedural_formations_sharp_train",
    "procedural_formations_sharp_test",
    "procedural_formations_paper_train",
    "procedural_formations_paper_test",
)


@pytest.mark.parametrize("name", SCENARIOS)
def test_every_shipped_name(name: str) -> None:
    source = scenario_source(name)
    assert isinstance(source, ScenarioSource)
    assert source.config == load_config(name)
    assert source.procedural == (name in PROCEDURAL)
    assert isinstance(source, ProceduralSource if source.procedural else FixedSource)
    first = source.initial()
    assert first is source.initial()  # cached / the one scenario
    # every episode's followers lie in the source's range (a drawn formation: its range)
    lo, hi = source.followers_range
    assert lo <= first.config.followers <= hi
    assert (lo, hi) == ((source.config.followers,) * 2 if name not in DRAWN else (1, 7))
    assert box(*source.bounds).covers(first.free_space)
    sc = source.sample(np.random.default_rng(0))
    assert sc.name == name and box(*source.bounds).covers(sc.free_space)
    assert scenario_source(source) is source  # a source, no overrides: as is
    assert scenario_source(source, {}) is source
    assert name in repr(source)


# ------------------------------------------------------------------------------------------
# Fixed
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", FIXED)
def test_fixed_source_never_draws(name: str) -> None:
    source = scenario_source(name)
    rng = np.random.default_rng(123)
    state = rng.bit_generator.state
    scenarios = [source.sample(rng) for _ in range(3)]
    assert rng.bit_generator.state == state  # the stream is untouched
    assert all(sc is source.initial() for sc in scenarios)
    assert isinstance(source, FixedSource) and source.scenario is scenarios[0]
    assert scenarios[0].layout_index is None
    assert source.bounds == scenarios[0].workspace.bounds


def test_fixed_source_from_every_form(tmp_path: Path, corridor: dict[str, Any]) -> None:
    path = tmp_path / "corridor.yaml"
    path.write_text(yaml.safe_dump(corridor))
    built = load_scenario(corridor)
    sources = [
        scenario_source(corridor),
        scenario_source(path),
        scenario_source(str(path)),
        scenario_source(load_config(corridor)),
        scenario_source(built),
    ]
    for source in sources:
        assert isinstance(source, FixedSource)
        assert _same_layout(source.initial(), built)
    assert sources[-1].initial() is built  # a built scenario is wrapped, not rebuilt
    assert sources[0].bounds == (0.0, -2.0, 30.0, 2.0)


def test_bad_arguments() -> None:
    with pytest.raises(TypeError, match="scenario must be"):
        scenario_source(3)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="Scenario"):
        FixedSource(load_config("study_c"))  # type: ignore[arg-type]
    with pytest.raises(ScenarioError, match="no 'generator' block"):
        ProceduralSource(load_config("study_c"))
    with pytest.raises(ScenarioError, match="unknown scenario"):
        scenario_source("study_z")


# ------------------------------------------------------------------------------------------
# Procedural
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", PROCEDURAL)
def test_procedural_source_draws_as_the_env_did(name: str) -> None:
    """Same seed, same layouts as the env's former ``rng.integers`` + generate_scenario draw."""
    template = load_config(name)
    source = scenario_source(name)
    rng, _ = seeding.np_random(5)  # as env.reset(seed=5)
    old, _ = seeding.np_random(5)
    for _ in range(3):
        sc = source.sample(rng)
        index = int(old.integers(LAYOUTS_PER_SPLIT))
        assert sc.layout_index == index
        assert _same_layout(sc, generate_scenario(template, index))
        assert sc.config.generator == template.generator and sc.name == name
    assert rng.bit_generator.state == old.bit_generator.state  # exactly one draw per sample
    again = [source.sample(np.random.default_rng(9)).layout_index for _ in range(2)]
    assert again[0] == again[1]


def test_procedural_initial_is_layout_zero_without_a_draw() -> None:
    source = scenario_source("procedural_train")
    first = source.initial()
    assert first.layout_index == 0
    assert _same_layout(first, generate_scenario(load_config("procedural_train"), 0))
    assert isinstance(source, ProceduralSource)
    assert _same_layout(source.layout(17), generate_scenario(source.config, 17))


def test_procedural_bounds() -> None:
    source = scenario_source("procedural_test")
    assert source.bounds == LAYOUT_BOUNDS
    rng = np.random.default_rng(1)
    for _ in range(4):
        assert box(*source.bounds).covers(source.sample(rng).free_space)


def test_built_layout_is_a_template_unless_pinned() -> None:
    """A layout passed where a scenario is expected stands for its family (as ``make()`` has
    always treated it); :class:`FixedSource` pins it."""
    layout = generate_scenario(load_config("procedural_train"), 9)
    source = scenario_source(layout)
    assert isinstance(source, ProceduralSource) and source.config is layout.config
    pinned = FixedSource(layout)
    rng = np.random.default_rng(0)
    assert pinned.sample(rng) is layout and not pinned.procedural
    assert pinned.bounds == layout.workspace.bounds


# ------------------------------------------------------------------------------------------
# Procedural templates are not fixed scenarios
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", PROCEDURAL)
def test_build_and_load_refuse_a_procedural_template(name: str) -> None:
    cfg = load_config(name)
    with pytest.raises(ScenarioError, match=r"procedural.*scenario_source"):
        build_scenario(cfg)
    with pytest.raises(ScenarioError, match=r"procedural.*scenario_source"):
        load_scenario(name)
    layout = generate_scenario(cfg, 3)  # a layout's config still names its family
    with pytest.raises(ScenarioError, match="procedural"):
        build_scenario(layout.config)
    assert load_scenario(layout) is layout  # a built scenario is returned as is


def test_with_overrides_is_gone() -> None:
    assert not hasattr(Scenario, "with_overrides")


# ------------------------------------------------------------------------------------------
# Overrides (the options module is stubbed: only the factory's use of it is tested here)
# ------------------------------------------------------------------------------------------


@pytest.fixture
def fake_options(monkeypatch: pytest.MonkeyPatch) -> list[tuple[dict[str, Any], str]]:
    calls: list[tuple[dict[str, Any], str]] = []

    def apply_overrides(
        cfg: ScenarioConfig, overrides: Mapping[str, Any], *, where: str = "make()"
    ) -> ScenarioConfig:
        calls.append((dict(overrides), where))
        return dataclasses.replace(cfg, **overrides)

    monkeypatch.setattr(source_module, "apply_overrides", apply_overrides)
    return calls


def test_no_overrides_no_options_call(fake_options: list[Any]) -> None:
    scenario_source("study_c")
    scenario_source("procedural_train", {})
    scenario_source("study_c", None)
    assert fake_options == []


def test_overrides_on_a_built_scenario_reuse_its_free_space(fake_options: list[Any]) -> None:
    built = load_scenario("study_c")
    source = scenario_source(built, {"followers": 1}, where="BatchedPlatoon()")
    assert fake_options == [({"followers": 1}, "BatchedPlatoon()")]
    sc = source.initial()
    assert sc.config.followers == 1 and sc.initial_poses.shape == (2, 3)
    assert sc.free_space is built.free_space  # the workspace is unchanged: not rebuilt
    again = scenario_source(FixedSource(built), {"followers": 1}).initial()
    assert again.free_space is built.free_space and again.config.followers == 1
    by_name = scenario_source("study_c", {"followers": 1}).initial()
    assert _same_layout(by_name, sc)


def test_overrides_on_a_procedural_template(fake_options: list[Any]) -> None:
    source = scenario_source("procedural_train", {"followers": 1})
    assert isinstance(source, ProceduralSource) and source.config.followers == 1
    assert source.initial().config.followers == 1
    again = scenario_source(source, {"followers": 2})
    assert isinstance(again, ProceduralSource) and again.config.followers == 2
    pinned = FixedSource(generate_scenario(load_config("procedural_train"), 4))
    pinned1 = scenario_source(pinned, {"followers": 1})
    assert isinstance(pinned1, FixedSource)  # still that one layout
    assert pinned1.initial().layout_index == 4 and pinned1.initial().config.followers == 1
    assert pinned1.initial().free_space is pinned.scenario.free_space


class _Custom:
    """A user's own source (only the protocol's members)."""

    def __init__(self) -> None:
        self._sc = load_scenario("study_c")

    @property
    def config(self) -> ScenarioConfig:
        return self._sc.config

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return self._sc.workspace.bounds

    @property
    def procedural(self) -> bool:
        return False

    def initial(self) -> Scenario:
        return self._sc

    def sample(self, rng: np.random.Generator) -> Scenario:
        return self._sc


def test_custom_source(fake_options: list[Any]) -> None:
    custom = _Custom()
    assert isinstance(custom, ScenarioSource)
    assert scenario_source(custom) is custom
    with pytest.raises(TypeError, match="overrides"):
        scenario_source(custom, {"followers": 1})


# ------------------------------------------------------------------------------------------
# Imports run one way: plain types (platoon_env.config) -> geometry, dynamics, records ->
# the trajectory rules and the validator -> scenario building -> procedural/source
# ------------------------------------------------------------------------------------------

_ISOLATED_IMPORT = """
import importlib.util, sys, types
# Bare parent packages, so that their __init__ (which imports the env and every source) does
# not run: only what the module itself imports is loaded.
root = importlib.util.find_spec("platoon_env").submodule_search_locations[0]
for name, path in (("platoon_env", root), ("platoon_env.scenarios", root + "/scenarios")):
    pkg = types.ModuleType(name)
    pkg.__path__ = [path]
    sys.modules[name] = pkg
import {module}
print(sorted(m for m in sys.modules if m.startswith("platoon_env.")))
"""


def _loaded_by(module: str) -> set[str]:
    """The package's modules that importing ``module`` alone loads."""
    out = subprocess.run(
        [sys.executable, "-c", _ISOLATED_IMPORT.format(module=module)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return set(ast.literal_eval(out.strip())) - {"platoon_env.scenarios"}  # the bare package


@pytest.mark.parametrize("module", ["scenario", "loader"])
def test_scenario_does_not_import_procedural(module: str) -> None:
    loaded = _loaded_by(f"platoon_env.scenarios.{module}")
    assert f"platoon_env.scenarios.{module}" in loaded
    for other in ("procedural", "source", "_layout", "corridor_layouts", "room_layouts"):
        assert f"platoon_env.scenarios.{other}" not in loaded, other


@pytest.mark.parametrize(
    "module",
    [
        "platoon_env.config",
        "platoon_env.geometry.workspace",
        "platoon_env.records",
        "platoon_env.dynamics.leader",
    ],
)
def test_plain_types_geometry_and_dynamics_import_no_scenario_module(module: str) -> None:
    """The layers below scenario building reach none of it (the config types and the error
    they need are in platoon_env.config, which imports nothing of the package but the
    violation causes)."""
    loaded = _loaded_by(module)
    assert module in loaded
    assert not {m for m in loaded if m.startswith("platoon_env.scenarios")}, module
    if module == "platoon_env.config":
        assert loaded == {"platoon_env.config", "platoon_env.violations"}


@pytest.mark.parametrize("module", ["trajectory", "validate", "schema"])
def test_the_schema_does_not_import_scenario_building(module: str) -> None:
    loaded = _loaded_by(f"platoon_env.scenarios.{module}")
    for upper in ("scenario", "loader", "options", "profiles", "procedural", "source"):
        assert f"platoon_env.scenarios.{upper}" not in loaded, (module, upper)


def test_plain_import_of_scenario_works() -> None:
    subprocess.run([sys.executable, "-c", "import platoon_env.scenarios.scenario"], check=True)


def _imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, at module level or inside functions."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


@pytest.mark.parametrize(
    "module",
    [
        "scenario",
        "loader",
        "schema",
        "validate",
        "trajectory",
        "_layout",
        "corridor_layouts",
        "room_layouts",
    ],
)
def test_no_module_imports_upwards(module: str) -> None:
    """Neither at module level nor in a function (which would hide a cycle)."""
    imported = _imported_modules(SCENARIOS_DIR / f"{module}.py")
    for upper in ("procedural", "source"):
        assert f"platoon_env.scenarios.{upper}" not in imported, (module, upper)


def _local_imports(path: Path) -> list[str]:
    """``line: statement`` of every import that is neither at module level nor under ``if
    TYPE_CHECKING:`` (an import in a function, which would hide a cycle)."""
    tree = ast.parse(path.read_text())
    allowed: list[ast.stmt] = []
    for stmt in tree.body:
        type_checking = isinstance(stmt, ast.If) and ast.unparse(stmt.test) == "TYPE_CHECKING"
        allowed.extend(stmt.body if type_checking else [stmt])  # type: ignore[attr-defined]
    top = {id(n) for n in allowed if isinstance(n, (ast.Import, ast.ImportFrom))}
    return [
        f"{node.lineno}: {ast.unparse(node)}"
        for node in ast.walk(tree)
        if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in top
    ]


_LAYER_FILES = sorted(
    [
        *SCENARIOS_DIR.glob("*.py"),
        *(SCENARIOS_DIR.parent / name for name in ("config.py", "records.py")),
        SCENARIOS_DIR.parent / "geometry" / "workspace.py",
        SCENARIOS_DIR.parent / "dynamics" / "leader.py",
    ]
)


@pytest.mark.parametrize("path", _LAYER_FILES, ids=lambda p: p.name)
def test_no_function_local_imports(path: Path) -> None:
    assert _local_imports(path) == []


def test_schema_reexports_every_name_it_exported() -> None:
    """``platoon_env.scenarios.schema`` stays the public home of the schema: every name it
    exported before the split, as the same object as in the module that defines it."""
    names = {
        config: "CameraConfig CameraNoiseConfig FormationConfig FreeSpaceConfig GeneratorConfig "
        "GENERATOR_KINDS GENERATOR_SPLITS GENERATOR_TIERS InitialConfig LeaderConfig "
        "ObservationConfig Point Polygon PPCConfig ProximityConfig RewardConfig RobotConfig "
        "SafetyConfig ScenarioConfig ScenarioError SimulationConfig TrajectorySample "
        "WorkspaceConfig field_error has_realism latency_steps VIOLATION_CAUSES",
        validate: "ACTION_BOUND_RANGE MAX_CONTROL_PERIOD MAX_COORDINATE MAX_EPISODE_STEPS "
        "MAX_FOLLOWERS MAX_LATENCY_STEPS MAX_PHYSICS_SUBSTEPS MAX_SETTLE_TIME MAX_SPEED_VARIATION "
        "MIN_CONTROL_PERIOD check_ranges",
        trajectory: "MAX_TRAJECTORY_DURATION MAX_TRAJECTORY_SAMPLES MIN_TRAJECTORY_INTERVAL "
        "TRAJECTORY_LIMIT_TOLERANCE check_trajectory_times trajectory_mean_speed "
        "trajectory_route",
        schema: "config_to_mapping parse_scenario parse_section",
    }
    for home, listed in names.items():
        for name in listed.split():
            assert getattr(schema, name) is getattr(home, name), name
            assert name in schema.__all__, name
