"""make() and BatchedPlatoon take the same overrides, validated like YAML, naming the option."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.scenarios.schema import ScenarioError

#: (override, value, text the error must contain besides the option's name)
BAD_OVERRIDES: list[tuple[str, Any, str]] = [
    ("physics_substeps", 1.5, "1.5"),
    ("followers", 2.7, "2.7"),
    ("perturb", "no", "'no'"),
    ("control_period", "0.05", "'0.05'"),
    ("control_period", math.inf, "inf"),
    ("terminate_on", "collision_robo", "collision_robo"),
    ("u_max", math.inf, "inf"),
    ("omega_max", 1e-50, "1e-50"),
]


@pytest.mark.parametrize(("name", "value", "shown"), BAD_OVERRIDES)
def test_bad_override_is_an_error_naming_it(name: str, value: Any, shown: str) -> None:
    for build in (
        lambda: platoon_env.make("study_c", **{name: value}),
        lambda: BatchedPlatoon("study_c", 2, **{name: value}),
    ):
        with pytest.raises(ScenarioError) as err:
            build()
        assert name in str(err.value) and shown in str(err.value), str(err.value)


def test_bad_env_flags() -> None:
    with pytest.raises(ScenarioError, match="diagnostics"):
        platoon_env.make("study_c", diagnostics="no")
    with pytest.raises(TypeError, match="colour"):
        platoon_env.make("study_c", colour="red")
    env = platoon_env.make("study_c")
    with pytest.raises(ScenarioError, match="perturb"):
        env.reset(seed=0, options={"perturb": "no"})


def test_string_terminate_on_is_one_cause() -> None:
    env = platoon_env.make("study_c", terminate_on="collision_robot")
    assert env.terminate_on == frozenset({"collision_robot"})


def test_block_overrides_merge_into_the_scenario() -> None:
    base = platoon_env.make("study_c").scenario.config
    env = platoon_env.make("study_c", camera={"half_angle": 0.35}, formation={"d_des": 0.9})
    cfg = env.scenario.config
    assert cfg.camera.half_angle == 0.35 and cfg.camera.range == base.camera.range
    assert cfg.formation.d_des == 0.9 and cfg.robot == base.robot
    # The observation space follows the merged block; so does the batched core.
    batch = BatchedPlatoon("study_c", 2, robot={"radius": 0.12}, camera={"range": 1.4})
    assert batch.scenario.config.robot.radius == 0.12
    assert batch.single_observation_space.high[1] == np.float32(1.4)
    with pytest.raises(ScenarioError, match="d_des"):
        platoon_env.make("study_c", formation={"d_des": 5.0})
    with pytest.raises(ScenarioError, match="half_angel"):
        platoon_env.make("study_c", camera={"half_angel": 0.3})


def test_overrides_change_the_simulation() -> None:
    """A narrower field of view from make() is what the core checks: the same start and
    actions that keep the predecessor in view at the default beta_con leave it at 0.25 rad."""
    wide = platoon_env.make("study_c", terminate_on=())
    narrow = platoon_env.make("study_c", terminate_on=(), camera={"half_angle": 0.25})
    for env in (wide, narrow):
        env.reset(seed=0, options={"perturb": False})
    turn = {a: np.array([0.0, 1.0]) for a in wide.possible_agents}
    for _ in range(30):
        wide.step(turn)
        _, _, _, _, infos = narrow.step(turn)
    assert "out_of_fov" in infos["follower_1"]["violations"]
    assert "out_of_fov" not in wide.step(turn)[4]["follower_1"]["violations"]
