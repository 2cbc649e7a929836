"""Gymnasium single-agent view: one follower behind the scripted leader.

Registered on ``import platoon_env`` (see :data:`GYM_IDS`) as
``platoon_env/SingleFollower-<Scenario>-v0`` and, with the ``aruco`` sensor profile,
``platoon_env/SingleFollower-<Scenario>-Aruco-v0``, where ``<Scenario>`` is the shipped
scenario's name in CamelCase: the paper's studies (``StudyA``, ``StudyB``, ``StudyC``) and the
procedural difficulty tiers, each split (``ProceduralEasyTrain``, ``ProceduralEasyTest``, ...,
``ProceduralHardTest``: a new layout of that tier and split on every reset, built for the one
follower), and ``ProceduralFormationsTrain``/``ProceduralFormationsTest`` (each layout also draws
its formation, ``docs/scenarios.md``; here always with one follower). Observation and action
are those of the one follower of the parallel env; the reward is its reward; ``terminated``
and ``truncated`` follow the parallel env.

Every id also has a vector entry point: ``gymnasium.make_vec(id, num_envs)`` builds a
:class:`~platoon_env.gym_vector.SingleFollowerVectorEnv` (the batched core: all envs stepped by
one compiled call). ``normalize_actions=True`` (both forms) makes the action space
``Box(-1, 1, (2,))``, mapped to ``[u, omega]`` by an :class:`~platoon_env.action_range.ActionRange`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from platoon_env.action_range import (
    ActionRange,
    action_range_of,
    normalised_action_space,
    physical_actions,
)
from platoon_env.env import ENV_OPTIONS, PlatoonParallelEnv, refuse_unknown_keywords
from platoon_env.observation import ACT_SIZE
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.schema import GENERATOR_SPLITS, GENERATOR_TIERS, ScenarioConfig
from platoon_env.scenarios.source import FixedSource, ProceduralSource, SourceLike

#: The shipped scenarios with a Gymnasium id: the paper's studies, then every split of every
#: procedural difficulty tier (``procedural_<tier>_<split>``).
GYM_SCENARIOS: tuple[str, ...] = (
    "study_a",
    "study_b",
    "study_c",
    *(f"procedural_{tier}_{split}" for tier in GENERATOR_TIERS for split in GENERATOR_SPLITS),
    *(f"procedural_formations_{split}" for split in GENERATOR_SPLITS),
    *(
        f"procedural_formations_{tier}_{split}"
        for tier in ("sharp", "paper")
        for split in GENERATOR_SPLITS
    ),
)


#: The keywords of :class:`SingleFollowerEnv` (``gymnasium.make(id, ...)``) that configure the
#: env rather than its scenario: :func:`platoon_env.make`'s, then the normalised actions'.
GYM_OPTIONS: tuple[str, ...] = (*ENV_OPTIONS, "normalize_actions", "action_range")


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


def single_follower(
    overrides: dict[str, Any], scenario: SourceLike | None = None
) -> dict[str, Any]:
    """``overrides`` with one follower: the Gymnasium views drive ``follower_1`` only. A
    ``scenario`` that draws its formation (``generator.formation.followers``, e.g.
    ``procedural_formations_train``) draws it with one follower (the other ranges stay)."""
    out = {**overrides, "followers": 1}
    if _draws_followers(scenario, overrides):
        generator = dict(out.get("generator") or {})
        formation = dict(generator.get("formation") or {})
        generator["formation"] = {**formation, "followers": [1, 1]}
        out["generator"] = generator
    return out


def _draws_followers(scenario: SourceLike | None, overrides: Mapping[str, Any]) -> bool:
    """Whether ``scenario`` (with ``overrides``' generator block) draws its number of
    followers per episode."""
    if isinstance(scenario, ProceduralSource | FixedSource):
        cfg = scenario.config
    elif isinstance(scenario, str | Path | Mapping | ScenarioConfig):
        cfg = load_config(scenario)
    else:
        return False
    gen = cfg.generator
    given = overrides.get("generator")
    if isinstance(given, Mapping) and isinstance(given.get("formation"), Mapping):
        if "followers" in given["formation"]:
            return True
    return gen is not None and gen.formation is not None and gen.formation.followers is not None


class SingleFollowerEnv(gym.Env[np.ndarray, np.ndarray]):
    """One follower (``follower_1``) tracking the scripted leader of ``scenario``.

    **Action space**: the follower's ``Box([-u_max, -omega_max], [u_max, omega_max])``
    ``[u, omega]`` [m/s, rad/s] (values outside are clipped), or with ``normalize_actions``
    ``Box(-1, 1, (2,), float32)``, mapped by ``action_range`` (clipped to ``[-1, 1]`` first).
    NaN or inf raise ``ValueError`` and change nothing.

    **Observation**, **reward**, **episode end**, **info**: the follower's in
    :class:`~platoon_env.env.PlatoonParallelEnv` (``terminated``: a violation in
    ``terminate_on``; ``truncated``: the leader arrived and settled, or ``max_episode_steps``).
    ``reset(seed, options)`` as the parallel env's (options ``perturb``, ``poses``).

    Args:
        scenario: as :func:`platoon_env.make`.
        normalize_actions: act in ``[-1, 1]^2`` instead of the actuator Box.
        action_range: with ``normalize_actions``, the :class:`ActionRange` (or a mapping of
            its fields) that ``[-1, 1]^2`` covers; None: ``ActionRange()`` (u in
            [-0.5, 1.5] m/s, omega in +-2 rad/s). It must lie within the actuator Box.
        **overrides: as :func:`platoon_env.make` (``render_mode``, ``diagnostics``, the
            scenario options); ``followers`` is forced to 1. Any other keyword is a
            ``TypeError`` worded as Python words it, listing the valid ones (with
            :data:`GYM_OPTIONS`).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}

    def __init__(
        self,
        scenario: SourceLike = "study_c",
        *,
        normalize_actions: bool = False,
        action_range: ActionRange | Mapping[str, float] | None = None,
        **overrides: Any,
    ) -> None:
        # make()'s check, listing this env's keywords too (make() knows only its own).
        refuse_unknown_keywords("make()", overrides, GYM_OPTIONS, passed=ENV_OPTIONS)
        self.parallel = PlatoonParallelEnv(scenario, **single_follower(overrides, scenario))
        self.agent = self.parallel.possible_agents[0]
        self.observation_space = self.parallel.observation_space(self.agent)
        physical = self.parallel.action_space(self.agent)
        #: The map of normalised actions to ``[u, omega]`` (None: actions are physical).
        self.action_range = action_range_of(
            normalize_actions, action_range, physical, "SingleFollowerEnv"
        )
        self.action_space = physical if self.action_range is None else normalised_action_space()
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
        if self.action_range is not None:
            action = physical_actions(action, (ACT_SIZE,), self.action_range, "action")
        obs, rew, term, trunc, infos = self.parallel.step({self.agent: action})
        a = self.agent
        return obs[a], rew[a], term[a], trunc[a], infos[a]

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        return self.parallel.render()

    def close(self) -> None:
        self.parallel.close()


def register_gym_ids() -> None:
    """Register :data:`GYM_IDS` with Gymnasium (idempotent), each with its vector entry point
    (:class:`~platoon_env.gym_vector.SingleFollowerVectorEnv`)."""
    for env_id, kwargs in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="platoon_env.gym_env:SingleFollowerEnv",
                vector_entry_point="platoon_env.gym_vector:SingleFollowerVectorEnv",
                kwargs=dict(kwargs),
                max_episode_steps=None,
            )
