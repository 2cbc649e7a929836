"""The tiny fast-learner run (training/fast_ppo.py) the training tests share."""

from __future__ import annotations

from typing import Any

#: A tiny run: 4 copies of study C (8 follower slots), rollouts of 32 steps (256 transitions).
TINY: dict[str, Any] = {
    "scenario": "study_c",
    "n_envs": 4,
    "n_steps": 32,
    "batch_size": 64,
    "n_epochs": 2,
    "timesteps": 1024,
    "log_every": 256,
    "checkpoint_every": 0,
    "progress_bar": False,
}
