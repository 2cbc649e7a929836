"""The model cards' usage snippet (experiments/studies/cards.py) matches the model's env."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest

import platoon_env
from experiments.studies.cards import (
    _curve_end,
    _end_cost,
    _observation_option,
    _profile,
    _training_summary,
    core_hours,
    cost_budget,
    training_cores,
)
from platoon_env.observation import OBS_NAMES, OBS_NAMES_SCALE_FREE, OBS_NAMES_TASK


@pytest.mark.parametrize(
    ("layout", "profile", "size"),
    [(OBS_NAMES_SCALE_FREE, None, 15), (OBS_NAMES_TASK, "aruco", 13), (OBS_NAMES, None, 7)],
)
def test_the_snippet_makes_the_env_the_model_reads(
    layout: tuple[str, ...], profile: str | None, size: int
) -> None:
    meta = {"observation_layout": list(layout), "config": {"sensor_profile": profile}}
    observation = ast.literal_eval(_observation_option(meta))
    sensor_profile = ast.literal_eval(_profile(meta))
    assert sensor_profile == profile
    env = platoon_env.make(
        "study_c", control_period=0.025, observation=observation, sensor_profile=sensor_profile
    )
    assert env.observation_space(env.possible_agents[0]).shape == (size,)


def test_the_training_lines_name_the_trainer_and_the_residual_law() -> None:
    base = {"algo": "ppo", "versions": {"stable_baselines3": "2.9.2"}, "timesteps": 10}
    sb3 = _training_summary({**base, "config": {"n_envs": 4}})
    assert sb3[0] == "- algorithm: `ppo` (Stable-Baselines3 2.9.2)" and "4 env copies" in sb3[2]
    fast = _training_summary(
        {**base, "trainer": "training.fast_ppo", "residual": "ppc", "config": {"n_envs": 64}}
    )
    assert "trained by `training.fast_ppo`" in fast[0] and "residual on the `ppc` law" in fast[0]
    assert "64 env copies" in fast[2]


def test_core_hours_count_every_core_a_run_occupied() -> None:
    fast = {"wall_time_s": 1800.0, "config": {"env_threads": 2, "torch_threads": 1}}
    assert training_cores(fast["config"]) == 2 and core_hours(fast) == pytest.approx(1.0)
    rllib = {"engine": "rllib", "num_env_runners": 3, "num_learners": 1, "torch_threads": 1}
    assert training_cores(rllib) == 4
    assert training_cores({}) == 1
    assert math.isnan(core_hours({"config": {}}))
    line = _training_summary(
        {"algo": "ppo", "timesteps": 10, "wall_time_s": 7200.0, "config": {"n_envs": 4}}
    )[2]
    assert "2.00 core-hours on 1 core(s)" in line


def test_a_lagrangian_card_says_whether_the_end_of_its_curve_is_within_its_budget(
    tmp_path: Path,
) -> None:
    progress = tmp_path / "progress.csv"
    rows = ["timesteps,wall_time_s,episodes,return_mean,success_rate,cost_mean,lambda"]
    # the last five windows' mean cost: (0.2 + 0.1 + 0.1 + 0.1 + 0.1) / 5 = 0.12
    for k, cost in enumerate([0.5, 0.2, 0.1, 0.1, 0.1, 0.1]):
        rows.append(f"{(k + 1) * 100},{k},10,1.0,0.5,{cost},{3.0 + k}")
    progress.write_text("\n".join(rows) + "\n")
    assert cost_budget({"algo": "ppo", "config": {"cost_budget": 0.05}}) is None
    budget = cost_budget({"algo": "ppo_lagrangian", "config": {"cost_budget": 0.15}})
    assert budget == pytest.approx(0.15)
    line = _curve_end(progress, budget)
    assert "follower episode cost 0.120 (within its budget 0.15)" in line
    assert line.endswith("multiplier λ 8.000")
    assert "(above its budget 0.1)" in _curve_end(progress, 0.1)
    assert "budget" not in _curve_end(progress)
    assert _end_cost(progress, 0.1) == "0.120 (above 0.1)"
    assert _end_cost(progress, None) == "0.120"
    assert _end_cost(tmp_path / "missing.csv", 0.1) == "–"
