"""The model cards' usage snippet (experiments/cards.py) matches the model's env."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest

import platoon_env
from experiments.cards import (
    _curve_end,
    _observation_option,
    _profile,
    _training_summary,
    core_hours,
    cost_budget,
    end_cost,
    training_cores,
)
from experiments.report import wilson
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


def test_a_lagrangian_card_says_whether_the_end_of_training_is_within_its_budget(
    tmp_path: Path,
) -> None:
    progress = tmp_path / "progress.csv"
    rows = ["timesteps,wall_time_s,episodes,return_mean,success_rate,cost_mean,lambda"]
    # 20 windows of 100 transitions; the last 10 % (timesteps > 1800): windows 1900 and 2000,
    # 400 + 600 follower episodes with costs 0.1 and 0.2: 40 + 120 = 160 of 1000.
    for k in range(1, 21):
        episodes, cost = {19: (400, 0.1), 20: (600, 0.2)}.get(k, (100, 0.9))
        rows.append(f"{k * 100},{k},{episodes},1.0,0.5,{cost},{3.0 + k}")
    progress.write_text("\n".join(rows) + "\n")
    assert cost_budget({"algo": "ppo", "config": {"cost_budget": 0.05}}) is None
    budget = cost_budget({"algo": "ppo_lagrangian", "config": {"cost_budget": 0.17}})
    assert budget == pytest.approx(0.17)
    lo, hi = wilson(160, 1000)
    interval = f"0.160 [{lo:.3f}, {hi:.3f}] over 1,000 follower episodes"
    assert end_cost(progress) == interval
    assert end_cost(progress, 0.17) == f"{interval}, within its budget 0.17"
    assert end_cost(progress, 0.15) == f"{interval}, not significantly above its budget 0.15"
    assert end_cost(progress, 0.1) == f"{interval}, above its budget 0.1"
    assert end_cost(tmp_path / "missing.csv", 0.1) == "–"
    line = _curve_end(progress, 0.17)
    assert "multiplier λ 23.000; cost at the end of training" in line
    assert line.endswith("within its budget 0.17")
    assert "budget" not in _curve_end(progress)
