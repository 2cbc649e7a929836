"""leader.trajectory_file: a scenario file names its timed trajectory's data file."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping


def _scenario_with_file(tmp_path: Path, name: str, samples: object = None) -> Path:
    mapping = config_to_mapping(load_config("study_b"))
    mapping["leader"] = {
        k: v for k, v in mapping["leader"].items() if k not in ("trajectory", "speed")
    }
    mapping["leader"]["trajectory_file"] = name
    if samples is not None:
        (tmp_path / "traj").mkdir(exist_ok=True)
        (tmp_path / "traj" / "t.yaml").write_text(yaml.safe_dump(samples))
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(mapping))
    return path


def test_a_file_names_its_trajectory(tmp_path: Path) -> None:
    shipped = load_config("study_b")
    samples = [list(s) for s in shipped.leader.trajectory]
    cfg = load_config(_scenario_with_file(tmp_path, "traj/t.yaml", samples))
    assert cfg.leader.trajectory == shipped.leader.trajectory
    assert cfg == shipped  # the same resolved scenario as the shipped one
    # the resolved mapping holds the samples themselves (it round-trips without the file)
    assert "trajectory_file" not in config_to_mapping(cfg)["leader"]


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("/etc/passwd", "must be a path inside the scenario's folder"),
        ("../t.yaml", "must be a path inside the scenario's folder"),
        ("traj/missing.yaml", "no such file"),
        ("", "must be a relative file path"),
    ],
)
def test_bad_trajectory_files(tmp_path: Path, name: str, message: str) -> None:
    with pytest.raises(ScenarioError, match=message):
        load_config(_scenario_with_file(tmp_path, name))


def test_only_files_name_trajectory_files(tmp_path: Path) -> None:
    mapping = config_to_mapping(load_config("study_b"))
    mapping["leader"]["trajectory_file"] = "x.yaml"
    with pytest.raises(ScenarioError, match="give trajectory or trajectory_file, not both"):
        load_config(mapping)
    del mapping["leader"]["trajectory"]
    with pytest.raises(ScenarioError, match="only a scenario file can name a trajectory file"):
        load_config(mapping)
