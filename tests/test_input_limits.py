"""Inputs that used to escape the scenario schema or the YAML reader: each is now a
:class:`ScenarioError` naming the field (or the file and line) and the bound.

Schema bounds (``platoon_env/scenarios/schema.py``): a YAML integer too big for a float, the
settle time, the control period, the physics sub-steps, the number of followers, the step limit
(given or derived from the path), the leader's speed and turn rate, the coordinates.
YAML reading (``platoon_env/scenarios/loader.py``): YAML 1.2 scalars (no sexagesimal ``1:30``),
aliases (alias bombs), nesting depth, file size, duplicate keys, encoding.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

import platoon_env
from platoon_env.scenarios import loader, schema
from platoon_env.scenarios.loader import load_config, load_scenario, read_yaml
from platoon_env.scenarios.schema import ScenarioError, parse_scenario

# The limits as documented; the constants must say the same.
MiB = 1024 * 1024


def _write(tmp_path: Path, data: Any, name: str = "scenario.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _set(data: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    out = copy.deepcopy(data)
    *blocks, key = dotted.split(".")
    target = out
    for block in blocks:
        target = target.setdefault(block, {})
    target[key] = value
    return out


def _file_error(tmp_path: Path, data: Any) -> str:
    path = _write(tmp_path, data)
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    message = str(exc.value)
    assert message.startswith(f"{path}: "), message  # the file is named
    return message


def test_the_limits_are_module_constants() -> None:
    assert schema.MIN_CONTROL_PERIOD == 1e-5 and schema.MAX_CONTROL_PERIOD == 1.0
    assert schema.MAX_PHYSICS_SUBSTEPS == 1000
    assert schema.MAX_FOLLOWERS == 1000
    assert schema.MAX_EPISODE_STEPS == 10**9
    assert schema.MAX_SETTLE_TIME == 1e6
    assert schema.MAX_COORDINATE == 1e6
    assert loader.MAX_YAML_BYTES == 10 * MiB
    assert loader.MAX_YAML_DEPTH == 64


# --- 1. scenario inputs that escaped the schema ---------------------------------------------


def test_yaml_int_too_big_for_a_float_is_not_finite(
    tmp_path: Path, corridor: dict[str, Any]
) -> None:
    """``robot.radius: 10**400``: float() raised OverflowError out of the parser."""
    message = _file_error(tmp_path, _set(corridor, "robot.radius", 10**400))
    assert "scenario.robot.radius: must be finite" in message
    with pytest.raises(ScenarioError, match=r"scenario\.robot\.radius: must be finite"):
        parse_scenario(_set(corridor, "robot.radius", -(10**400)))


BOUNDS = [
    pytest.param("leader.settle_time", 1e308, "at most 1e+06 s (MAX_SETTLE_TIME)", id="settle"),
    pytest.param(
        "simulation.physics_substeps", 10**9, "at most 1000 (MAX_PHYSICS_SUBSTEPS)", id="substeps"
    ),
    pytest.param(
        "simulation.physics_substeps", 1001, "at most 1000 (MAX_PHYSICS_SUBSTEPS)", id="substeps+1"
    ),
    pytest.param(
        "simulation.control_period", 1e-300, "at least 1e-05 s (MIN_CONTROL_PERIOD)", id="dt"
    ),
    pytest.param(
        "simulation.control_period", 9.9e-6, "at least 1e-05 s (MIN_CONTROL_PERIOD)", id="dt-"
    ),
    pytest.param("followers", 1001, "at most 1000 (MAX_FOLLOWERS)", id="followers"),
    pytest.param("followers", 10**400, "at most 1000 (MAX_FOLLOWERS)", id="followers-huge"),
    pytest.param(
        "simulation.max_episode_steps",
        10**9 + 1,
        "at most 1000000000 (MAX_EPISODE_STEPS)",
        id="max-steps",
    ),
    pytest.param(
        "simulation.max_episode_steps",
        2**64,
        "at most 1000000000 (MAX_EPISODE_STEPS)",
        id="max-steps-int64-overflow",
    ),
    pytest.param("leader.speed", 1e-300, "must lie in [1e-06, 1e+06] m/s", id="speed"),
    pytest.param("leader.max_turn_rate", 1e300, "must lie in [1e-06, 1e+06] rad/s", id="turn"),
]


@pytest.mark.parametrize("field,value,reason", BOUNDS)
def test_field_beyond_its_bound_is_named(
    tmp_path: Path, corridor: dict[str, Any], field: str, value: Any, reason: str
) -> None:
    message = _file_error(tmp_path, _set(corridor, field, value))
    assert f"scenario.{field}: " in message
    assert reason in message


def test_coordinates_are_bounded(tmp_path: Path, corridor: dict[str, Any]) -> None:
    message = _file_error(tmp_path, _set(corridor, "leader.path", [[0.5, 0.0], [1e300, 0.0]]))
    assert "scenario.leader.path[1]: coordinates must lie in [-1e+06, 1e+06] m" in message
    bad = _set(corridor, "workspace.obstacles", [[[0.0, 0.0], [1.0, 0.0], [0.0, -2e6]]])
    with pytest.raises(ScenarioError, match=r"scenario\.workspace\.obstacles\[0\]\[2\]"):
        parse_scenario(bad)
    with pytest.raises(ScenarioError, match=r"scenario\.workspace\.bounds: coordinates"):
        parse_scenario(_set(corridor, "workspace.bounds", [0.0, -2.0, 1e7, 2.0]))


def test_huge_settle_time_is_a_scenario_error_not_an_overflow(
    tmp_path: Path, corridor: dict[str, Any]
) -> None:
    """``settle_time: 1e308`` used to parse, then overflow in the default step limit."""
    path = _write(tmp_path, _set(corridor, "leader.settle_time", 1e308))
    with pytest.raises(ScenarioError, match=r"scenario\.leader\.settle_time: must be at most"):
        load_scenario(path)
    with pytest.raises(ScenarioError, match=r"leader\.settle_time"):
        platoon_env.make(corridor, leader={"settle_time": 1e308})


def test_derived_step_limit_is_bounded(corridor: dict[str, Any]) -> None:
    """Without ``max_episode_steps`` the limit follows the path; a slow leader on a long path
    would make it astronomically large: an error naming the field and the bound."""
    slow = _set(corridor, "leader.speed", 1e-6)  # 19.5 m at 1 um/s: 4e9 steps
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(slow)
    assert exc.value.path == "scenario.simulation.max_episode_steps"
    assert "more than 1000000000 (MAX_EPISODE_STEPS)" in str(exc.value)
    given = parse_scenario(_set(slow, "simulation.max_episode_steps", 1000))
    assert given.simulation.max_episode_steps == 1000
    # The longest settle time: (130 s of driving twice + 1e6 + 10) / 0.01 s steps, in bounds;
    # at 1 ms periods it would be 1.00014e9 steps, over the bound.
    edge = _set(corridor, "leader.settle_time", 1e6)
    steps = load_scenario(edge).max_episode_steps
    assert 100_014_000 <= steps <= 100_014_001
    with pytest.raises(ScenarioError, match="MAX_EPISODE_STEPS"):
        parse_scenario(_set(edge, "simulation.control_period", 1e-3))


@pytest.mark.parametrize(
    "field,value",
    [
        ("simulation.control_period", 1e-5),
        ("simulation.control_period", 1e-3),
        ("simulation.control_period", 0.05),
        ("simulation.control_period", 1.0),
        ("simulation.physics_substeps", 1000),
        ("simulation.max_episode_steps", 10**9),
        ("followers", 1000),
        ("leader.speed", 1e6),
        ("leader.path", [[-1e6, 0.0], [1e6, 0.0]]),
    ],
)
def test_values_at_the_bounds_are_valid(corridor: dict[str, Any], field: str, value: Any) -> None:
    data = _set(corridor, "simulation.max_episode_steps", 1000)  # a 2000 km path: set a limit
    cfg = parse_scenario(_set(data, field, value))
    section: Any = cfg
    for part in field.split("."):
        section = getattr(section, part)
    assert section == (tuple(map(tuple, value)) if isinstance(value, list) else value)


def test_sexagesimal_yaml_int_is_rejected(tmp_path: Path, corridor: dict[str, Any]) -> None:
    """YAML 1.1 reads ``followers: 1:30`` as 90 (base 60); the loader reads YAML 1.2."""
    text = yaml.safe_dump(corridor, sort_keys=False).replace("followers: 2", "followers: 1:30")
    path = tmp_path / "sexagesimal.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    assert "scenario.followers: expected an integer, got '1:30'" in str(exc.value)


@pytest.mark.parametrize(
    "text,value",
    [
        ("1:30", "1:30"),  # YAML 1.1: 90
        ("1:30.5", "1:30.5"),  # YAML 1.1: 90.5
        ("017", 17),  # YAML 1.1: octal 15
        ("0o17", 15),
        ("0x1f", 31),
        ("1_000", "1_000"),  # YAML 1.1: 1000
        ("1e-3", 0.001),  # YAML 1.1 (PyYAML): the string '1e-3'
        ("-2.5E+2", -250.0),
        (".inf", float("inf")),
        ("yes", "yes"),  # YAML 1.1: True
        ("off", "off"),  # YAML 1.1: False
        ("true", True),
        ("FALSE", False),
        ("~", None),
        ("2024-01-02", "2024-01-02"),  # YAML 1.1: a date
    ],
)
def test_plain_scalars_resolve_by_yaml_1_2(text: str, value: Any) -> None:
    out = read_yaml(f"key: {text}\n", "x.yaml")["key"]
    assert out == value and type(out) is type(value)


def test_explicit_int_tag_is_checked_too() -> None:
    with pytest.raises(ScenarioError, match=r"x\.yaml:1: malformed YAML: invalid integer '1:30'"):
        read_yaml("followers: !!int 1:30\n", "x.yaml")


def test_integer_with_too_many_digits_is_malformed_yaml() -> None:
    with pytest.raises(ScenarioError, match=r"x\.yaml:1: malformed YAML: invalid integer"):
        read_yaml("followers: " + "9" * 5000 + "\n", "x.yaml")


# --- 2. reading YAML -------------------------------------------------------------------------


def _billion_laughs(levels: int = 9) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, levels):
        refs = ", ".join([f"*a{k - 1}"] * 9)
        lines.append(f"a{k}: &a{k} [{refs}]")
    lines.append(f"name: *a{levels - 1}")
    return "\n".join(lines) + "\n"


def test_alias_bomb_is_refused_at_once(tmp_path: Path) -> None:
    path = tmp_path / "laughs.yaml"
    path.write_text(_billion_laughs())
    start = time.perf_counter()
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    assert time.perf_counter() - start < 1.0
    assert str(exc.value).startswith(f"{path}:2: malformed YAML: found an alias")


def test_quadratic_alias_expansion_is_refused_at_once(
    tmp_path: Path, corridor: dict[str, Any]
) -> None:
    """The schema checks lists of polygons of points, so that is where aliases would expand: a
    polygon of 1500 references to one point and 1500 references to that polygon, 20 kB of
    text, are 2.25 million points to check one by one (the classic nine-level bomb fails the
    schema at its first wrong type; this one is well typed)."""
    n = 1500
    polygon = "&poly [&p [1.0, 1.0]" + ", *p" * (n - 1) + "]"
    obstacles = f"[{polygon}" + ", *poly" * (n - 1) + "]"
    text = yaml.safe_dump(_set(corridor, "workspace.obstacles", []), sort_keys=False)
    assert text.count("obstacles: []\n") == 1
    path = tmp_path / "quadratic.yaml"
    path.write_text(text.replace("obstacles: []\n", f"obstacles: {obstacles}\n"))
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match="found an alias"):
        load_config(path)
    assert time.perf_counter() - start < 1.0


def test_deep_nesting_is_a_scenario_error(tmp_path: Path) -> None:
    path = tmp_path / "deep.yaml"
    path.write_text("followers: " + "[" * 20_000 + "]" * 20_000 + "\n")
    with pytest.raises(ScenarioError, match=r"deep\.yaml:1: malformed YAML: nested deeper than 64"):
        load_config(path)
    with pytest.raises(ScenarioError, match="nested deeper"):
        read_yaml("{a: " * 20_000 + "}" * 20_000, "inline")
    # A scenario's own nesting (blocks, polygons, points) is far below the limit.
    nested = read_yaml("a: " + "[" * 63 + "]" * 63, "ok")["a"]
    for _ in range(62):
        nested = nested[0]
    assert nested == []


def test_file_over_the_size_limit_is_refused(tmp_path: Path, corridor: dict[str, Any]) -> None:
    """A valid scenario padded with comments to just over 10 MiB: refused before parsing."""
    path = _write(tmp_path, corridor, "huge.yaml")
    size = path.stat().st_size
    with path.open("a") as f:
        line = "#" + "x" * 1022 + "\n"
        f.write(line * ((10 * MiB - size) // len(line) + 1))
    assert path.stat().st_size > 10 * MiB
    start = time.perf_counter()
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    assert time.perf_counter() - start < 1.0
    message = str(exc.value)
    assert message.startswith(f"{path}: the file is ") and "10485760 bytes" in message
    with pytest.raises(ScenarioError, match="more than the limit"):
        read_yaml(" " * (10 * MiB + 1), "text")


def test_duplicate_key_names_the_key_and_lines(tmp_path: Path) -> None:
    path = tmp_path / "dup.yaml"
    path.write_text("name: dup\nrobot:\n  radius: 0.1\n  radius: 0.2\nfollowers: 2\n")
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    assert str(exc.value) == (
        f"{path}:4: malformed YAML: found duplicate key 'radius' (first given on line 3)"
    )
    with pytest.raises(ScenarioError, match=r"x:3: .*duplicate key 'followers' .* line 1\)"):
        read_yaml("followers: 2\nname: a\nfollowers: 3\n", "x")
    with pytest.raises(ScenarioError, match=r"duplicate key 1 "):
        read_yaml("{1: a, 0x1: b}", "x")  # equal after resolution


def test_non_utf8_file_names_the_file(tmp_path: Path, corridor: dict[str, Any]) -> None:
    path = tmp_path / "latin1.yaml"
    corridor["description"] = "couloir étroit"
    path.write_bytes(yaml.safe_dump(corridor, allow_unicode=True).encode("latin-1"))
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    message = str(exc.value)
    assert message.startswith(f"{path}:")
    assert "not UTF-8" in message and "0xe9" in message
    # The same file saved as UTF-8 loads.
    path.write_text(yaml.safe_dump(corridor, allow_unicode=True), encoding="utf-8")
    assert load_config(path).description == "couloir étroit"


def test_existing_rules_are_kept(tmp_path: Path) -> None:
    """Errors still name the file and line; tags that would build Python objects are rejected."""
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.yaml"
    path.write_text(f"name: x\nfollowers: !!python/object/apply:os.system ['touch {marker}']\n")
    with pytest.raises(ScenarioError, match=r"evil\.yaml:2: malformed YAML"):
        load_config(path)
    assert not marker.exists()
    with pytest.raises(ScenarioError, match=r"x:2: malformed YAML"):
        read_yaml("a: [1, 2\nb: 3\n", "x")


def test_every_shipped_scenario_still_loads() -> None:
    for name in loader.list_scenarios():
        load_config(name)
