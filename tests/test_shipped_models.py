"""Every shipped configuration: five seeds, each model loadable, suited to its training env,
small, with its learning curve and its card."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

import platoon_env
from experiments.configs import CONFIGS, DEFAULT_SEEDS, SHIPPED
from training.curves import read_progress
from training.policies import LearnedPolicy

REPO = Path(__file__).resolve().parent.parent
MODELS = REPO / "models"
RUNS = sorted(p.parent for p in MODELS.glob("*/model.zip"))


def test_every_configuration_ships_five_seeds_and_nothing_else() -> None:
    names = {p.name for p in RUNS}
    expected = {f"{c}_s{s}" for c in SHIPPED for s in DEFAULT_SEEDS}
    assert names == expected
    assert set(SHIPPED) <= set(CONFIGS)


@pytest.mark.parametrize("run", RUNS, ids=lambda p: p.name)
def test_a_shipped_run_loads_suits_its_env_and_has_its_files(run: Path) -> None:
    config, seed = re.fullmatch(r"(.+)_s(\d+)", run.name).groups()  # type: ignore[union-attr]
    meta = json.loads((run / "model.json").read_text())
    assert meta["seed"] == int(seed) and meta["git_dirty"] is False
    assert meta["timesteps"] >= meta["timesteps_requested"] and not meta["interrupted"]
    assert (run / "model.zip").stat().st_size < 1_000_000  # kept small
    policy = LearnedPolicy.load(run / "model.zip")
    cfg = meta["config"]
    scale_free = bool(cfg.get("scale_free_observations", False))
    # the task-aware layout: 13 values, 15 scale-free (docs/observations.md)
    assert policy.task_aware and policy.observation_size == (15 if scale_free else 13)
    observation = {"task_aware": True, "scale_free": True} if scale_free else {"task_aware": True}
    preset = cfg.get("realism_preset")  # the realism drawn per episode in training
    env = platoon_env.make(
        meta["scenario"],
        control_period=policy.control_period,
        sensor_profile=cfg["sensor_profile"],
        observation=observation,
        **({"realism": {"preset": preset}} if preset else {}),
    )
    notes = policy.check_env(env)
    assert all("not held out" in n for n in notes)  # the training env itself
    obs, _ = env.reset(seed=0)
    if meta.get("residual"):
        with pytest.raises(RuntimeError, match="bind"):
            policy.act(obs)  # a residual policy acts on its law, which bind() builds
        policy.bind(env)
    policy.reset(seed=0)
    actions = policy.act(obs)
    assert set(actions) == set(env.agents)
    curve = read_progress(run / "progress.csv")
    assert curve["timesteps"][-1] == meta["timesteps"]
    card = (run / "README.md").read_text()
    assert f"`{run.name}`" in card and f"**`{config}`**" in card
    assert "| paper: study_a/aruco |" in card and "| heldout: hard/aruco |" in card
