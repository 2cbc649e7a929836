"""``platoon-train``'s scale-free observation and randomised-realism options, for every engine."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from platoon_env.observation import OBS_NAMES_SCALE_FREE
from training.config import TrainConfig, env_overrides, make_env
from training.fast_ppo import FastPPOConfig, SlotSpec, make_core
from training.train import fast_config, parse_args


def test_the_flags_become_the_scenario_options_of_the_training_envs() -> None:
    cfg = parse_args(
        [
            "--scenario",
            "study_c",
            "--task-aware-observations",
            "--scale-free-observations",
            "--realism-preset",
            "ideal_to_beyond_aruco",
        ]
    )
    overrides = env_overrides(cfg)
    assert overrides["observation"] == {"task_aware": True, "scale_free": True}
    assert overrides["realism"] == {"preset": "ideal_to_beyond_aruco"}
    env = make_env(cfg)
    assert env.scenario.config.observation.scale_free
    obs, infos = env.reset(seed=3)
    assert len(obs["follower_1"]) == len(OBS_NAMES_SCALE_FREE)
    assert "realism" in infos["follower_1"]


def test_without_the_flags_the_envs_are_unchanged() -> None:
    overrides = env_overrides(TrainConfig(task_aware_observations=True))
    assert overrides["observation"] == {"task_aware": True}
    assert "realism" not in overrides


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["--scale-free-observations"], "--scale-free-observations"),
        (["--realism-preset", "no_such_preset"], "--realism-preset"),
    ],
)
def test_bad_combinations_are_usage_errors_naming_the_flag(
    argv: list[str], flag: str, usage_error: Callable[..., str]
) -> None:
    assert flag in usage_error(parse_args, argv)


def test_the_fast_learner_gets_them_and_checks_them() -> None:
    cfg = fast_config(
        parse_args(
            [
                "--engine",
                "fast",
                "--scenario",
                "study_c",
                "--task-aware-observations",
                "--scale-free-observations",
                "--n-envs",
                "2",
            ]
        )
    )
    assert cfg.scale_free_observations and cfg.realism_preset is None
    core, _ = make_core(cfg)
    spec = SlotSpec.of(cfg, core)
    assert spec.obs_scale is not None
    assert spec.obs_scale.shape == (len(OBS_NAMES_SCALE_FREE),)
    assert np.all(np.isfinite(spec.obs_scale))
    with pytest.raises(ValueError, match="scale_free_observations"):
        FastPPOConfig(scale_free_observations=True)  # not task-aware
    with pytest.raises(ValueError, match="realism_preset"):
        FastPPOConfig(realism_preset="nope")
