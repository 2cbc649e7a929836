"""Keyword overrides (platoon_env.scenarios.options): checked by the same rules as a file."""

from __future__ import annotations

import copy
import dataclasses
import math
import pickle
from typing import Any

import numpy as np
import pytest
import yaml

from platoon_env.scenarios.loader import list_scenarios, load_config
from platoon_env.scenarios.options import (
    BLOCK_OPTIONS,
    OVERRIDE_OPTIONS,
    PROFILE_OPTION,
    SCENARIO_OPTIONS,
    apply_overrides,
    check_bool,
)
from platoon_env.scenarios.schema import (
    VIOLATION_CAUSES,
    ScenarioConfig,
    ScenarioError,
    config_to_mapping,
    parse_scenario,
)

STUDY_C = load_config("study_c")

#: Shortcut option -> its field's path in the file.
FILE_PATH = {
    "control_period": ("simulation", "control_period"),
    "physics_substeps": ("simulation", "physics_substeps"),
    "max_episode_steps": ("simulation", "max_episode_steps"),
    "terminate_on": ("safety", "terminate_on"),
    "followers": ("followers",),
    "perturb": ("initial", "perturb"),
    "u_max": ("robot", "u_max"),
    "omega_max": ("robot", "omega_max"),
}


def _error(overrides: dict[str, Any], cfg: ScenarioConfig = STUDY_C) -> str:
    with pytest.raises(ScenarioError) as exc:
        apply_overrides(cfg, overrides)
    return str(exc.value)


def test_option_name_tuples() -> None:
    assert set(SCENARIO_OPTIONS) == set(FILE_PATH)
    assert set(BLOCK_OPTIONS) == {
        "leader",
        "robot",
        "camera",
        "proximity",
        "safety",
        "formation",
        "simulation",
        "reward",
        "initial",
        "ppc",
        "workspace",
        "generator",
        "observation",
        "realism",
    }
    assert OVERRIDE_OPTIONS == (*SCENARIO_OPTIONS, *BLOCK_OPTIONS, PROFILE_OPTION)


# --- the bad overrides of the issue, one each -----------------------------------------------

BAD_SHORTCUTS = [
    pytest.param("physics_substeps", 1.5, "expected an integer", id="substeps-1.5"),
    pytest.param("physics_substeps", 2.0, "expected an integer", id="substeps-2.0"),
    pytest.param("followers", 2.7, "expected an integer", id="followers-2.7"),
    # 2.0 is rejected too, as YAML `followers: 2.0` is: an int field takes only integers.
    pytest.param("followers", 2.0, "expected an integer", id="followers-2.0"),
    pytest.param("followers", True, "expected an integer", id="followers-bool"),
    pytest.param("perturb", "no", "expected a boolean", id="perturb-no"),
    pytest.param("perturb", 1, "expected a boolean", id="perturb-1"),
    pytest.param("control_period", "0.05", "expected a number", id="period-str"),
    pytest.param("control_period", math.inf, "must be finite", id="period-inf"),
    pytest.param("control_period", math.nan, "must be finite", id="period-nan"),
    pytest.param("control_period", 0.0, "must lie in (0, 1] s", id="period-0"),
    pytest.param("control_period", 2.0, "must lie in (0, 1] s", id="period-2"),
    pytest.param("max_episode_steps", 0, "must be >= 1", id="max-steps-0"),
    pytest.param("u_max", math.inf, "must be finite", id="u_max-inf"),
    pytest.param("u_max", 0.0, "must lie in [1e-06, 1e+06]", id="u_max-0"),
    pytest.param("u_max", 1e39, "must lie in [1e-06, 1e+06]", id="u_max-float32-overflow"),
    pytest.param("omega_max", 1e-50, "must lie in [1e-06, 1e+06]", id="omega_max-1e-50"),
    pytest.param("omega_max", -1.0, "must lie in [1e-06, 1e+06]", id="omega_max-negative"),
]


@pytest.mark.parametrize("option,value,reason", BAD_SHORTCUTS)
def test_bad_shortcut_names_option_and_value(option: str, value: Any, reason: str) -> None:
    message = _error({option: value})
    assert message.startswith(f"make(): {option}: ")
    assert repr(value) in message
    assert reason in message
    assert "(scenario." + ".".join(FILE_PATH[option]) + ")" in message


@pytest.mark.parametrize("option,value,reason", BAD_SHORTCUTS)
def test_bad_shortcut_is_rejected_by_the_file_rules_too(
    option: str, value: Any, reason: str
) -> None:
    """The override and a file with the same value fail for the same reason."""
    data = config_to_mapping(STUDY_C)
    *blocks, key = FILE_PATH[option]
    target = data
    for block in blocks:
        target = target.setdefault(block, {})
    target[key] = value
    with pytest.raises(ScenarioError) as from_file:
        parse_scenario(data)
    with pytest.raises(ScenarioError) as from_override:
        apply_overrides(STUDY_C, {option: value})
    assert from_file.value.reason == from_override.value.reason
    assert (
        from_file.value.path
        == from_override.value.path
        == "scenario." + ".".join(FILE_PATH[option])
    )


def test_diagnostics_no_is_rejected() -> None:
    with pytest.raises(ScenarioError) as exc:
        check_bool("diagnostics", "no", "make()")
    assert str(exc.value) == "make(): diagnostics: expected True or False, got 'no'"


@pytest.mark.parametrize("value", [1, 0, None, "True", 1.0])
def test_check_bool_rejects_non_bools(value: Any) -> None:
    with pytest.raises(ScenarioError, match="diagnostics") as exc:
        check_bool("diagnostics", value, "BatchedPlatoon()")
    assert str(exc.value).startswith("BatchedPlatoon(): diagnostics: ")
    assert repr(value) in str(exc.value)


@pytest.mark.parametrize("value", [True, False, np.bool_(True), np.bool_(False)])
def test_check_bool_accepts_bools(value: Any) -> None:
    out = check_bool("diagnostics", value, "make()")
    assert type(out) is bool and out == bool(value)


@pytest.mark.parametrize(
    "option,value",
    [
        ("control_period", 0.01),
        ("control_period", 0.05),
        ("control_period", 0.1),
        ("control_period", 1e-5),
        ("control_period", 1.0),
        ("physics_substeps", 1),
        ("max_episode_steps", 100),
        ("followers", 1),
        ("perturb", False),
        ("u_max", 1e-6),
        ("u_max", 0.5),
        ("omega_max", 1e6),
    ],
)
def test_valid_shortcut_sets_its_field(option: str, value: Any) -> None:
    new = apply_overrides(STUDY_C, {option: value})
    field = new
    for part in FILE_PATH[option]:
        field = getattr(field, part)
    assert field == value
    assert type(field) is type(value)


def test_numpy_scalars_become_python_values() -> None:
    new = apply_overrides(
        STUDY_C, {"followers": np.int64(3), "u_max": np.float32(2.5), "perturb": np.bool_(False)}
    )
    assert type(new.followers) is int and new.followers == 3
    assert type(new.robot.u_max) is float and new.robot.u_max == 2.5
    assert new.initial.perturb is False


# --- terminate_on ---------------------------------------------------------------------------


def test_terminate_on_string_is_one_cause() -> None:
    new = apply_overrides(STUDY_C, {"terminate_on": "collision_robot"})
    assert new.safety.terminate_on == ("collision_robot",)


def test_terminate_on_unknown_string_names_the_cause() -> None:
    message = _error({"terminate_on": "collision_robt"})
    assert message.startswith("make(): terminate_on: unknown cause 'collision_robt'")
    assert "'c'" not in message


@pytest.mark.parametrize(
    "value,expected",
    [
        (["occluded", "collision_robot"], ("occluded", "collision_robot")),
        (("out_of_fov",), ("out_of_fov",)),
        ((c for c in ["out_of_range"]), ("out_of_range",)),
        ({"out_of_fov", "collision_robot"}, ("collision_robot", "out_of_fov")),
        ([], ()),
    ],
)
def test_terminate_on_iterables(value: Any, expected: tuple[str, ...]) -> None:
    assert apply_overrides(STUDY_C, {"terminate_on": value}).safety.terminate_on == expected


@pytest.mark.parametrize("value", [5, b"occluded", {"occluded": True}, 1.5])
def test_terminate_on_non_iterable_is_rejected(value: Any) -> None:
    message = _error({"terminate_on": value})
    assert message.startswith("make(): terminate_on: expected a cause name or an iterable")
    assert repr(value) in message


def test_terminate_on_element_must_be_a_string() -> None:
    message = _error({"terminate_on": ["occluded", 3]})
    assert message.startswith("make(): terminate_on[1]: expected a string, got 3")


# --- block overrides ------------------------------------------------------------------------


def test_camera_half_angle_changes_only_that_field() -> None:
    new = apply_overrides(STUDY_C, {"camera": {"half_angle": 0.5}})
    assert new.camera == dataclasses.replace(STUDY_C.camera, half_angle=0.5)
    assert dataclasses.replace(new, camera=STUDY_C.camera) == STUDY_C


def test_formation_d_des_block() -> None:
    new = apply_overrides(STUDY_C, {"formation": {"d_des": 1.2}})
    assert new == dataclasses.replace(
        STUDY_C, formation=dataclasses.replace(STUDY_C.formation, d_des=1.2)
    )


def test_robot_radius_block_keeps_the_other_robot_fields() -> None:
    new = apply_overrides(STUDY_C, {"robot": {"radius": 0.12}})
    assert new.robot == dataclasses.replace(STUDY_C.robot, radius=0.12)
    assert new.robot.u_max == STUDY_C.robot.u_max


def test_block_and_shortcuts_together() -> None:
    new = apply_overrides(
        STUDY_C, {"robot": {"radius": 0.12}, "u_max": 2.0, "simulation": {"physics_substeps": 4}}
    )
    assert (new.robot.radius, new.robot.u_max) == (0.12, 2.0)
    assert new.simulation.physics_substeps == 4


def test_block_cross_field_rule_names_the_field() -> None:
    message = _error({"formation": {"d_des": 2.0}})  # above camera.range = 1.5
    assert message.startswith("make(): formation.d_des: d_des must lie in (d_col, d_con)")
    assert "got 2" in message


def test_cross_field_rule_on_an_untouched_field_names_the_field_and_overrides() -> None:
    message = _error({"robot": {"radius": 0.2}})  # d_col = 0.3 < 2 r
    assert message.startswith("make(): scenario.safety.d_col: d_col must be >= r_i + r_(i-1)")
    assert "(with the overrides robot)" in message


def test_unknown_key_in_block_is_named() -> None:
    message = _error({"camera": {"half_anlge": 0.5}})
    assert message.startswith("make(): camera.half_anlge: unknown key")
    assert "half_angle" in message  # the valid keys are listed


def test_wrong_type_in_block_is_named() -> None:
    message = _error({"camera": {"range": "far"}})
    assert message.startswith("make(): camera.range: expected a number, got 'far'")


def test_non_mapping_block_is_rejected() -> None:
    message = _error({"camera": 0.5})
    assert message.startswith("make(): camera: expected a mapping")
    assert "0.5" in message


def test_shortcut_and_block_field_conflict() -> None:
    message = _error({"u_max": 2.0, "robot": {"u_max": 3.0}})
    assert "u_max is given twice" in message
    assert "u_max=2.0" in message and "robot.u_max=3.0" in message


def test_none_shortcut_does_not_conflict_with_its_block() -> None:
    new = apply_overrides(STUDY_C, {"u_max": None, "robot": {"u_max": 3.0}})
    assert new.robot.u_max == 3.0


def test_block_none_value_clears_an_optional_field() -> None:
    cfg = apply_overrides(STUDY_C, {"max_episode_steps": 50})
    assert apply_overrides(cfg, {"simulation": {"max_episode_steps": None}}) == STUDY_C


def test_absent_optional_block_is_built_from_the_override() -> None:
    bare = dataclasses.replace(STUDY_C, ppc=None)
    message = _error({"ppc": {"lambda": 0.5}}, bare)
    assert message.startswith("make(): ppc.rho_d_inf: required key is missing")
    assert STUDY_C.ppc is not None
    full = {**config_to_mapping(STUDY_C)["ppc"]}
    assert apply_overrides(bare, {"ppc": full}) == STUDY_C


def test_ppc_block_uses_the_file_key_lambda() -> None:
    new = apply_overrides(STUDY_C, {"ppc": {"lambda": 0.7}})
    assert new.ppc is not None and new.ppc.lambda_ == 0.7
    assert "ppc.lambda_: unknown key" in _error({"ppc": {"lambda_": 0.7}})


@pytest.mark.parametrize("name", ["u_maxx", "diagnostics", "render_mode", "name"])
def test_unknown_option_is_a_type_error_listing_valid_ones(name: str) -> None:
    with pytest.raises(TypeError) as exc:
        apply_overrides(STUDY_C, {name: 1})
    message = str(exc.value)
    assert message.startswith(f"make() got an unexpected keyword argument {name!r}")
    assert all(option in message for option in OVERRIDE_OPTIONS)


def test_where_prefixes_messages() -> None:
    with pytest.raises(ScenarioError, match=r"^BatchedPlatoon\(\): followers: "):
        apply_overrides(STUDY_C, {"followers": 0}, where="BatchedPlatoon()")


def test_no_override_returns_an_equal_config() -> None:
    assert apply_overrides(STUDY_C, {}) == STUDY_C
    assert apply_overrides(STUDY_C, dict.fromkeys(OVERRIDE_OPTIONS)) == STUDY_C


def test_procedural_scenario_overrides() -> None:
    cfg = load_config("procedural_train")
    new = apply_overrides(cfg, {"generator": {"split": "test"}, "followers": 3})
    assert new.generator is not None and new.generator.split == "test"
    assert new.followers == 3 and new.leader.path == ()
    assert "generator.split" in _error({"generator": {"split": "dev"}}, cfg)


# --- config_to_mapping ----------------------------------------------------------------------


@pytest.mark.parametrize("name", list_scenarios())
def test_config_to_mapping_round_trip(name: str) -> None:
    cfg = load_config(name)
    data = config_to_mapping(cfg)
    assert parse_scenario(data) == cfg
    # ... also through YAML text: the mapping holds only plain values.
    assert parse_scenario(yaml.safe_load(yaml.safe_dump(data))) == cfg
    assert parse_scenario(copy.deepcopy(data)) == cfg


def test_config_to_mapping_form() -> None:
    data = config_to_mapping(STUDY_C)
    assert "lambda" in data["ppc"] and "lambda_" not in data["ppc"]
    assert isinstance(data["leader"]["path"], list) and isinstance(data["leader"]["path"][0], list)
    assert isinstance(data["safety"]["terminate_on"], list)
    assert "generator" not in data  # None-valued optional blocks are omitted
    assert "max_episode_steps" not in data["simulation"]
    bare = dataclasses.replace(STUDY_C, ppc=None)
    assert "ppc" not in config_to_mapping(bare)
    assert parse_scenario(config_to_mapping(bare)) == bare
    assert "path" in config_to_mapping(load_config("procedural_train"))["leader"]
    assert list(VIOLATION_CAUSES) == config_to_mapping(STUDY_C)["safety"]["terminate_on"]


def test_config_to_mapping_unwraps_numpy_scalars() -> None:
    cfg = dataclasses.replace(
        STUDY_C, robot=dataclasses.replace(STUDY_C.robot, u_max=np.float64(2))
    )
    data = config_to_mapping(cfg)
    assert type(data["robot"]["u_max"]) is float
    yaml.safe_dump(data)


def test_scenario_error_keeps_path_and_reason_through_pickle() -> None:
    with pytest.raises(ScenarioError) as exc:
        apply_overrides(STUDY_C, {"u_max": 0.0})
    again = pickle.loads(pickle.dumps(exc.value))
    assert str(again) == str(exc.value)
    assert again.path == "scenario.robot.u_max"
    assert again.reason is not None and again.reason.startswith("must lie in")
