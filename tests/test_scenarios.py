"""Scenario files: shipped ones load; bad input gets a clear error naming the field."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env

import platoon_env
from platoon_env.scenarios import ScenarioError, load_scenario, scenario_source
from platoon_env.scenarios.loader import load_config

SCENARIOS = platoon_env.list_scenarios()


def test_paper_studies_are_shipped() -> None:
    assert {"study_a", "study_b", "study_c"} <= set(SCENARIOS)


@pytest.mark.parametrize(
    "name,n,r,d_des,d_col,d_con,beta_con",
    [
        ("study_a", 7, 0.2, 2.0, 0.5, 4.0, math.pi / 4),
        ("study_b", 2, 0.3, 1.0, 0.6, 2.5, 0.785),
        ("study_c", 2, 0.15, 1.0, 0.3, 1.5, 0.4),
    ],
)
def test_paper_parameters(
    name: str, n: int, r: float, d_des: float, d_col: float, d_con: float, beta_con: float
) -> None:
    """The paper's parameters (docs/scenarios.md, shipped scenarios)."""
    cfg = load_config(name)
    assert cfg.followers == n and cfg.robot.radius == r
    assert cfg.formation.d_des == d_des and cfg.safety.d_col == d_col
    assert cfg.camera.range == d_con
    assert cfg.camera.half_angle == pytest.approx(beta_con, abs=1e-9)
    assert cfg.ppc is not None


@pytest.mark.parametrize("name", SCENARIOS)
def test_shipped_scenarios_build(name: str) -> None:
    sc = scenario_source(name).initial()  # a procedural one: its layout 0
    assert sc.free_space.is_valid and sc.free_space.area > 0
    assert sc.workspace.edges.shape[1] == 4
    assert sc.initial_poses.shape == (sc.config.followers + 1, 3)


def test_load_by_name_path_and_dict(tmp_path: Path, corridor: dict[str, Any]) -> None:
    path = tmp_path / "corridor.yaml"
    path.write_text(yaml.safe_dump(corridor))
    a = load_scenario(corridor)
    b = load_scenario(str(path))
    c = load_scenario(path)
    for other in (b, c):
        np.testing.assert_array_equal(a.workspace.edges, other.workspace.edges)
        np.testing.assert_array_equal(a.initial_poses, other.initial_poses)
    assert platoon_env.make(path).n_followers == 2


def _error(data: dict[str, Any]) -> str:
    with pytest.raises(ScenarioError) as exc:
        load_scenario(data)
    return str(exc.value)


def test_unknown_key_names_its_path(corridor: dict[str, Any]) -> None:
    corridor["leader"]["sped"] = 1.0
    assert "scenario.leader.sped" in _error(corridor)
    del corridor["leader"]["sped"]
    corridor["extra"] = 1
    assert "scenario.extra" in _error(corridor)


def test_missing_and_mistyped(corridor: dict[str, Any]) -> None:
    bad = copy.deepcopy(corridor)
    del bad["formation"]
    assert "scenario.formation" in _error(bad)
    bad = copy.deepcopy(corridor)
    bad["robot"]["radius"] = "big"
    assert "scenario.robot.radius" in _error(bad)
    bad = copy.deepcopy(corridor)
    bad["followers"] = 2.5
    assert "scenario.followers" in _error(bad)
    bad = copy.deepcopy(corridor)
    bad["camera"]["range"] = float("nan")
    assert "scenario.camera.range" in _error(bad)


@pytest.mark.parametrize(
    "section,key,value,field",
    [
        ("formation", "d_des", 0.2, "formation.d_des"),  # below d_col
        ("formation", "d_des", 1.5, "formation.d_des"),  # at d_con
        ("camera", "half_angle", math.pi / 2, "camera.half_angle"),
        ("camera", "half_angle", 0.0, "camera.half_angle"),
        ("safety", "d_col", 0.2, "safety.d_col"),  # < 2r
        ("robot", "radius", -0.1, "robot.radius"),
        ("ppc", "epsilon", 1.0, "ppc.epsilon"),
        ("reward", "wall_margin", 0.0, "reward.wall_margin"),
        ("reward", "wall", math.inf, "reward.wall"),
        ("reward", "distance", math.nan, "reward.distance"),
        ("proximity", "half_angle", 0.0, "proximity.half_angle"),
        ("proximity", "half_angle", -0.5, "proximity.half_angle"),
        ("proximity", "half_angle", math.pi + 1e-9, "proximity.half_angle"),
        ("proximity", "half_angle", math.inf, "proximity.half_angle"),
    ],
)
def test_parameter_ranges(
    corridor: dict[str, Any], section: str, key: str, value: float, field: str
) -> None:
    corridor.setdefault(section, {})[key] = value
    assert field in _error(corridor)


def test_proximity_sector(corridor: dict[str, Any]) -> None:
    """``proximity.half_angle``: optional (all around, pi, by default), any value in (0, pi];
    study B uses the paper's +-130 deg and the kernel receives it."""
    from platoon_env.core import params_of

    assert load_config(corridor).proximity.half_angle is None
    assert load_config(corridor).proximity_half_angle == math.pi
    for value in (1e-3, 1.0, math.pi):
        corridor["proximity"] = {"half_angle": value}
        assert load_config(corridor).proximity_half_angle == value
    study_b = load_config("study_b")
    assert study_b.proximity_half_angle == math.radians(130)
    assert params_of(study_b, 1)["proximity_half_angle"] == math.radians(130)
    for name in ("study_a", "study_c"):
        assert load_config(name).proximity.half_angle is None


def test_self_intersecting_and_empty_polygons(corridor: dict[str, Any]) -> None:
    bad = copy.deepcopy(corridor)
    bad["workspace"]["obstacles"] = [[[13, 1], [15, -1], [15, 1], [13, -1]]]  # bow tie
    msg = _error(bad)
    assert "obstacles[0]" in msg and "Self-intersection" in msg
    bad = copy.deepcopy(corridor)
    bad["workspace"]["obstacles"] = [[[13, 1], [14, 1]]]
    assert "obstacles[0]" in _error(bad)
    bad = copy.deepcopy(corridor)
    bad["workspace"]["obstacles"] = [[[13, 1], [14, 1], [15, 1]]]  # zero area
    assert "obstacles[0]" in _error(bad)
    bad = copy.deepcopy(corridor)
    del bad["workspace"]["bounds"]
    assert "bounds" in _error(bad)


def test_leader_path_too_close_says_where(corridor: dict[str, Any]) -> None:
    corridor["leader"]["path"] = [[0.5, 0.0], [9.0, 0.0], [11.0, 0.7], [20.0, 0.7]]
    msg = _error(corridor)
    assert "leader.path" in msg and "within" in msg and "(" in msg


def test_leader_path_leaving_free_space(corridor: dict[str, Any]) -> None:
    corridor["leader"]["path"] = [[0.5, 0.0], [11.0, 0.0], [11.0, 1.5]]
    assert "leaves the free space" in _error(corridor)


def test_infeasible_initial_configuration_names_follower(corridor: dict[str, Any]) -> None:
    # A sharp turn round a box at the start: the box hides the leader from follower_1.
    corridor["workspace"]["obstacles"] = [[[0.5, 0.25], [2.05, 0.25], [2.05, 1.9], [0.5, 1.9]]]
    corridor["leader"]["path"] = [[0.5, 0.0], [2.3, 0.0], [2.3, 1.7]]
    msg = _error(corridor)
    assert "infeasible" in msg and "follower_1: the line of sight" in msg


def test_infeasible_reset_poses(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    poses = env.scenario.initial_poses.copy()
    poses[2, 2] += 1.0  # follower_2 looks away from follower_1
    with pytest.raises(ScenarioError, match=r"follower_2: \|beta_2\|"):
        env.reset(options={"poses": poses})


def test_malformed_yaml_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nleader: {path: [[0, 0], [1, 1]\nfollowers: 2\n")
    with pytest.raises(ScenarioError, match=r"broken\.yaml:\d+: malformed YAML"):
        load_scenario(path)


def test_unsafe_yaml_tag_is_never_executed(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.yaml"
    path.write_text(f"name: !!python/object/apply:os.system ['touch {marker}']\n")
    with pytest.raises(ScenarioError, match="malformed YAML"):
        load_scenario(path)
    assert not marker.exists()


@pytest.mark.parametrize("char", ["\x00", "\x01", "\x07", "\x1b", "\x7f", "\ufffe"])
def test_control_characters_are_an_error_naming_the_file(tmp_path: Path, char: str) -> None:
    """YAML allows printable characters, tab, line feed and carriage return only: any other
    (a stray control character, say) is a ScenarioError naming the file, the line and the
    character, not PyYAML's ReaderError."""
    path = tmp_path / "control.yaml"
    path.write_text(f"name: x\ndescription: a{char}b\nfollowers: 2\n", encoding="utf-8")
    with pytest.raises(
        ScenarioError,
        match=rf"control\.yaml:2: malformed YAML: character U\+{ord(char):04X} is not allowed",
    ):
        load_scenario(path)


def test_control_characters_in_a_trajectory_file_name_that_file(tmp_path: Path) -> None:
    (tmp_path / "t.yaml").write_text("- [0, 0, 0, 0]\n- [1, 0.3, 0, 0\x01]\n", encoding="utf-8")
    path = tmp_path / "s.yaml"
    path.write_text("name: x\nleader: {trajectory_file: t.yaml}\n", encoding="utf-8")
    message = r"s\.yaml -> t\.yaml:2: malformed YAML: character U\+0001"
    with pytest.raises(ScenarioError, match=message):
        load_config(path)


def test_unknown_scenario_name() -> None:
    with pytest.raises(ScenarioError, match="unknown scenario"):
        load_scenario("study_z")


@pytest.mark.parametrize("env_id", sorted(platoon_env.GYM_IDS))
def test_gymnasium_check_env(env_id: str) -> None:
    env = gym.make(env_id)
    check_env(env.unwrapped)
    env.close()


def test_gymnasium_rollout() -> None:
    env = gym.make("platoon_env/SingleFollower-StudyC-v1")
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, _reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
    assert isinstance(terminated, bool) and isinstance(truncated, bool)
    assert "violation" in info
