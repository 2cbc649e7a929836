"""Gymnasium single-agent view: one follower behind the scripted leader.

Registered on ``import platoon_env`` (see :data:`GYM_IDS`) as
``platoon_env/SingleFollower-<Scenario>-v0`` and, with the ``aruco`` sensor profile,
``platoon_env/SingleFollower-<Scenario>-Aruco-v0``, where ``<Scenario>`` is the shipped
scenario's name in CamelCase: the paper's studies (``StudyA``, ``StudyB``, ``StudyC``) and the
procedural difficulty tiers, each split (``ProceduralEasyTrain``, ``ProceduralEasyTest``, ...,
``ProceduralHardTest``: a new layout of that tier and split on every reset, built for the one
follower). Observation and action are those of the one follower of the parallel env; the
reward is its reward; ``terminated`` and ``truncated`` follow the parallel env.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from platoon_env.env import PlatoonParallelEnv
from platoon_env.scenarios.schema import GENERATOR_SPLITS, GENERATOR_TIERS
from platoon_env.scenarios.source import SourceLike

#: The shipped scenarios with a Gymnasium id: the paper's studies, then every split of every
#: procedural difficulty tier (``procedural_<tier>_<split>``).
GYM_SCENARIOS: tuple[str, ...] = (
    "study_a",
    "study_b",
    "study_c",
    *(f"procedural_{tier}_{split}" for tier in GENERATOR_TIERS for split in GENERATOR_SPLITS),
)


def _camel(name: str) -> str:
    """``procedural_easy_train`` -> ``ProceduralEasyTrain``."""
    return "".join(part.capitalize() for part in name.split("_"))


#: Gymnasium id -> keyword arguments of :class:`SingleFollowerEnv`: the shipped scenario the
#: single follower drives in (:data:`GYM_SCENARIOS`), with ideal sensors or the ``aruco``
#: sensor profile (``docs/realism.md``).
GYM_IDS: dict[str, dict[str, Any]] = {
    f"platoon_env/SingleFollower-{_camel(scenario)}{suffix}-v0": {
        "scenario": scenario,
        **({} if profile is None else {"sensor_profile": profile}),
    }
    for scenario in GYM_SCENARIOS
    for suffix, profile in (("", None), ("-Aruco", "aruco"))
}


class SingleFollowerEnv(gym.Env[np.ndarray, np.ndarray]):
    """One follower (``follower_1``) tracking the scripted leader of ``scenario``.

    Arguments are those of :func:`platoon_env.make`; ``followers`` is forced to 1.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}

    def __init__(self, scenario: SourceLike = "study_c", **overrides: Any) -> None:
        overrides["followers"] = 1
        self.parallel = PlatoonParallelEnv(scenario, **overrides)
        self.agent = self.parallel.possible_agents[0]
        self.observation_space = self.parallel.observation_space(self.agent)
        self.action_space = self.parallel.action_space(self.agent)
        self.render_mode = self.parallel.render_mode

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        obs, infos = self.parallel.reset(seed=seed, options=options)
        return obs[self.agent], infos[self.agent]

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, rew, term, trunc, infos = self.parallel.step({self.agent: action})
        a = self.agent
        return obs[a], rew[a], term[a], trunc[a], infos[a]

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        return self.parallel.render()

    def close(self) -> None:
        self.parallel.close()


def register_gym_ids() -> None:
    """Register :data:`GYM_IDS` with Gymnasium (idempotent)."""
    for env_id, kwargs in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="platoon_env.gym_env:SingleFollowerEnv",
                kwargs=dict(kwargs),
                max_episode_steps=None,
            )
