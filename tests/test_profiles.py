"""Sensor profiles (platoon_env.scenarios.profiles): shipped names, files, and their checks."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import pytest

import platoon_env.scenarios.profiles as profiles_module
from platoon_env.scenarios.loader import list_scenarios, load_config
from platoon_env.scenarios.options import OVERRIDE_OPTIONS, apply_overrides
from platoon_env.scenarios.profiles import PROFILE_BLOCKS, list_profiles, load_profile
from platoon_env.scenarios.schema import ScenarioConfig, ScenarioError, has_realism

ROOT = Path(__file__).resolve().parents[1]
FOLDER = resources.files("platoon_env.scenarios").joinpath("profiles")


def _write(tmp_path: Path, text: str, name: str = "mine.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _assert_merged(cfg: ScenarioConfig, blocks: dict[str, dict[str, Any]]) -> None:
    """Every field a profile sets has its value in the merged config."""
    for name, block in blocks.items():
        section = getattr(cfg, name)
        for key, value in block.items():
            if isinstance(value, dict):
                for sub, subvalue in value.items():
                    assert getattr(getattr(section, key), sub) == subvalue, f"{name}.{key}.{sub}"
            else:
                assert getattr(section, key) == value, f"{name}.{key}"


# --------------------------------------------------------------------------------------------
# Shipped profiles
# --------------------------------------------------------------------------------------------


def test_list_profiles_names_the_shipped_files() -> None:
    names = list_profiles()
    assert names == sorted(names)
    assert {"aruco", "ideal"} <= set(names)
    files = sorted(p.name[: -len(".yaml")] for p in FOLDER.iterdir() if p.name.endswith(".yaml"))
    assert names == files


def test_the_module_is_not_shadowed_by_the_data_folder() -> None:
    # An __init__.py in profiles/ would make the folder a package that hides profiles.py.
    assert Path(profiles_module.__file__).name == "profiles.py"
    assert not FOLDER.joinpath("__init__.py").is_file()


def test_profiles_are_package_data() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    package_data = config["tool"]["setuptools"]["package-data"]
    assert "*.yaml" in package_data["platoon_env.scenarios.profiles"]


def test_ideal_is_the_schema_defaults() -> None:
    assert load_profile("ideal") == {"camera": {}, "proximity": {}, "robot": {}}


def test_aruco_sets_only_realism_fields() -> None:
    blocks = load_profile("aruco")
    assert set(blocks) == set(PROFILE_BLOCKS) - {"leader"}
    realism = {
        "camera": {"noise", "detection", "detection_edge", "frame_rate", "latency"},
        "proximity": {"noise"},
        "robot": {"accel_max", "alpha_max", "lag"},
    }
    for name, block in blocks.items():
        assert set(block) <= realism[name], name
    assert set(blocks["camera"]["noise"]) == {"position", "position_per_m", "bearing"}


@pytest.mark.parametrize("scenario", list_scenarios())
@pytest.mark.parametrize("profile", list_profiles())
def test_every_profile_merges_into_every_shipped_scenario(scenario: str, profile: str) -> None:
    base = load_config(scenario)
    blocks = load_profile(profile)
    drive = blocks.get("leader", {}).get("drive", "free")
    cfg = apply_overrides(base, blocks)
    _assert_merged(cfg, blocks)
    # A profile changes only the blocks it names; the geometry and the rest stay (the
    # leader's motion too, unless it is slowed to the profile's drive).
    for name in ("workspace", "safety", "formation", "simulation", "reward"):
        assert getattr(cfg, name) == getattr(base, name)
    if drive == "free":
        assert cfg.leader == base.leader
    else:
        assert cfg.leader.drive == drive and cfg.leader.path == base.leader.path
        assert cfg.leader.trajectory[1:] == base.leader.trajectory[1:] or not base.leader.trajectory
    assert cfg.camera.half_angle == base.camera.half_angle
    assert cfg.camera.range == base.camera.range
    if profile == "ideal":
        assert cfg == base
    if profile == "aruco":
        assert has_realism(cfg)


def test_load_profile_returns_a_fresh_copy() -> None:
    first = load_profile("aruco")
    first["camera"]["noise"]["position"] = 99.0
    first["robot"].clear()
    again = load_profile("aruco")
    assert again["camera"]["noise"]["position"] != 99.0
    assert again["robot"]


@pytest.mark.skipif(
    "sensor_profile" not in OVERRIDE_OPTIONS, reason="make(sensor_profile=...) not wired in yet"
)
def test_sensor_profile_option_equals_merging_the_blocks() -> None:
    base = load_config("study_b")
    via_option = apply_overrides(base, {"sensor_profile": "aruco"})
    assert via_option == apply_overrides(base, load_profile("aruco"))
    # A block option beside the profile overrides one field of it and keeps the rest.
    tweaked = apply_overrides(base, {"sensor_profile": "aruco", "camera": {"latency": 0.1}})
    assert tweaked.camera.latency == 0.1
    assert tweaked.camera.noise == via_option.camera.noise


# --------------------------------------------------------------------------------------------
# Profiles from files
# --------------------------------------------------------------------------------------------


def test_load_profile_from_a_path(tmp_path: Path) -> None:
    text = "camera:\n  noise: {position: 0.02}\n  latency: 0.03\nrobot: {lag: 0.1}\n"
    path = _write(tmp_path, text)
    expected = {"camera": {"noise": {"position": 0.02}, "latency": 0.03}, "robot": {"lag": 0.1}}
    assert load_profile(path) == expected
    assert load_profile(str(path)) == expected
    assert load_profile(_write(tmp_path, text, "other.yml")) == expected
    cfg = apply_overrides(load_config("study_c"), load_profile(path))
    assert cfg.camera.noise.position == 0.02
    assert cfg.camera.noise.bearing == 0.0
    assert cfg.robot.lag == 0.1


def test_a_file_may_set_some_blocks_only(tmp_path: Path) -> None:
    assert load_profile(_write(tmp_path, "proximity: {noise: 0.05}\n")) == {
        "proximity": {"noise": 0.05}
    }
    assert load_profile(_write(tmp_path, "{}\n")) == {}


# --------------------------------------------------------------------------------------------
# Errors name the profile and the problem
# --------------------------------------------------------------------------------------------


def test_unknown_name_lists_the_shipped_profiles() -> None:
    with pytest.raises(ScenarioError) as err:
        load_profile("arucoo")
    message = str(err.value)
    assert "'arucoo'" in message
    assert "not a shipped profile name nor a YAML file" in message
    assert ", ".join(list_profiles()) in message


def test_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.yaml"
    with pytest.raises(ScenarioError, match="no such file") as err:
        load_profile(missing)
    assert str(missing) in str(err.value)
    assert "aruco" in str(err.value)


@pytest.mark.parametrize(
    ("text", "got"),
    [
        ("- camera\n- robot\n", "['camera', 'robot']"),
        ("0.5\n", "0.5"),
        ("", "an empty file"),
        ("# only a comment\n", "an empty file"),
    ],
)
def test_content_must_be_a_mapping(tmp_path: Path, text: str, got: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ScenarioError) as err:
        load_profile(path)
    message = str(err.value)
    assert str(path) in message
    assert "expected a mapping of blocks (some of camera, proximity, robot, leader)" in message
    assert got in message


@pytest.mark.parametrize("block", ["workspace", "safety", "ppc", "lidar"])
def test_unknown_block(tmp_path: Path, block: str) -> None:
    path = _write(tmp_path, f"camera: {{}}\n{block}: {{}}\n")
    with pytest.raises(ScenarioError) as err:
        load_profile(path)
    message = str(err.value)
    assert f"unknown block {block!r}" in message
    assert "a profile may set only camera, proximity, robot, leader" in message
    assert str(path) in message


@pytest.mark.parametrize(
    ("text", "where"),
    [
        # an unknown key, with the keys it could be
        ("camera: {nosie: {position: 0.01}}\n", "camera.nosie: unknown key (expected one of"),
        ("camera: {noise: {pos: 0.01}}\n", "camera.noise.pos: unknown key (expected one of"),
        ("proximity: {std: 0.01}\n", "proximity.std: unknown key (expected one of"),
        ("robot: {accel: 1.0}\n", "robot.accel: unknown key (expected one of"),
        # a block that is not a mapping
        ("camera: 0.5\n", "camera: expected a mapping of camera keys, got 0.5"),
        ("robot:\n", "robot: expected a mapping of robot keys, got None"),
        ("camera: {noise: 0.01}\n", "camera.noise: expected a mapping of camera.noise keys"),
    ],
)
def test_a_bad_key_or_block_is_named(tmp_path: Path, text: str, where: str) -> None:
    with pytest.raises(ScenarioError) as err:
        load_profile(_write(tmp_path, text))
    assert where in str(err.value)


def test_malformed_yaml_names_file_and_line(tmp_path: Path) -> None:
    path = _write(tmp_path, "camera:\n  noise: {position: 0.01\nrobot: {}\n")
    with pytest.raises(ScenarioError, match="malformed YAML") as err:
        load_profile(path)
    assert f"{path}:" in str(err.value)


def test_python_tags_are_rejected_not_run(tmp_path: Path) -> None:
    path = _write(tmp_path, "camera: !!python/object/apply:os.getcwd []\n")
    with pytest.raises(ScenarioError, match="malformed YAML"):
        load_profile(path)


@pytest.mark.parametrize("value", [3, None, {"camera": {}}, ["aruco"]])
def test_profile_must_be_a_name_or_a_path(value: Any) -> None:
    with pytest.raises(TypeError, match="sensor profile must be a name or a path"):
        load_profile(value)


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("camera: {latency: 0.015}\n", "camera.latency"),  # not a whole number of 0.01 s
        ("camera: {frame_rate: 200.0}\n", "camera.frame_rate"),  # above 1 / control_period
        ("camera: {detection: 1.5}\n", "camera.detection"),
        ("camera: {noise: {bearing: -0.1}}\n", "camera.noise.bearing"),
        ("proximity: {noise: -0.01}\n", "proximity.noise"),
        ("robot: {accel_max: 0.0}\n", "robot.accel_max"),
        ("robot: {lag: fast}\n", "robot.lag"),
    ],
)
def test_bad_values_fail_when_merged(tmp_path: Path, text: str, where: str) -> None:
    # load_profile checks the form; the values are checked by the scenario's own rules.
    blocks = load_profile(_write(tmp_path, text))
    with pytest.raises(ScenarioError) as err:
        apply_overrides(load_config("study_b"), blocks)
    assert where in str(err.value)
