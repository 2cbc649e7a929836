"""Gymnasium single-agent view: one follower behind the scripted leader.

Registered on ``import platoon_env`` (see :data:`GYM_IDS`) as
``platoon_env/SingleFollower-<Scenario>-v1`` and, with the ``aruco`` sensor profile,
``platoon_env/SingleFollower-<Scenario>-Aruco-v1``, where ``<Scenario>`` is the shipped
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

**Episode length.** The env ends its own episodes (``truncated`` when the leader has arrived
and settled, or at the scenario's step limit). ``gymnasium.spec(id).max_episode_steps`` is
:data:`GYM_STEP_LIMITS`: for a study, its step limit; for a procedural family (each layout
has its own limit, from its path's length), the limit of the longest path it draws (40 m) at
its slowest leader, at or above every layout's own limit, so that libraries that read the
spec get a horizon. ``gymnasium.make(id)`` therefore adds Gymnasium's ``TimeLimit`` at that
value: it ends no episode earlier than the env does with the id's own options (a study: the
same step; ``tests/test_gym_vector_wrappers.py``). Options that make episodes longer in steps
(a shorter ``control_period``, a slower ``leader``) may need ``gymnasium.make(id,
max_episode_steps=-1)`` (no ``TimeLimit``) or a larger ``max_episode_steps``, as for any
Gymnasium id. ``gymnasium.make_vec(id)`` (the vector entry point) keeps each episode's own
limit: the ids' kwargs hold ``max_episode_steps=None``, which stops ``make_vec`` passing the
spec's limit on as a scenario option.

**Rendering.** ``metadata["render_fps"]`` is the env's steps per second
(:func:`~platoon_env.env.steps_per_second`: 100 for 0.01 s steps), per instance, so that a
video of one frame per step (``gymnasium.wrappers.RecordVideo``) plays in real time.
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


#: The version every Gymnasium id ends in. A change of what an id's episode gives for the same
#: seed and actions (dynamics, sensing, observations, rewards, episode end, spaces, metadata
#: that wrappers read) bumps it (docs/versioning.md); an older id is not registered, so
#: ``gymnasium.make`` refuses it with Gymnasium's ``DeprecatedEnv`` naming the current one.
ENV_VERSION = "v1"

#: ``(id version, package version, what changed)``, newest first: the env pages' version history.
VERSION_HISTORY: tuple[tuple[str, str, str], ...] = (
    (
        "v1",
        "0.2.0",
        "the vector env (`make_vec`) autoresets next step by default (was same step); "
        "`metadata['render_fps']` is the steps per second (100 at the shipped 0.01 s, was 25); "
        "every spec has `max_episode_steps`; a noisy camera reading is clipped to the "
        "observation space; and the changes of the env since 0.1.0 that "
        "kept the v0 ids (metrics, procedural maps and tiers, task-aware and scale-free "
        "observations, realism profiles: CHANGELOG.md)",
    ),
    ("v0", "0.1.0", "the first release"),
)

#: Gymnasium id -> keyword arguments of :class:`SingleFollowerEnv`: the shipped scenario the
#: single follower drives in (:data:`GYM_SCENARIOS`), with ideal sensors or the ``aruco``
#: sensor profile (``docs/realism.md``).
GYM_IDS: dict[str, dict[str, Any]] = {
    f"platoon_env/SingleFollower-{_camel(scenario)}{suffix}-{ENV_VERSION}": {
        "scenario": scenario,
        **({} if profile is None else {"sensor_profile": profile}),
    }
    for scenario in GYM_SCENARIOS
    for suffix, profile in (("", None), ("-Aruco", "aruco"))
}


#: The ``max_episode_steps`` of every Gymnasium id of a shipped scenario (``gymnasium.spec(id)``;
#: its ``-Aruco`` id's too, the profile does not change it), with one follower and the
#: scenario's own options. A study: its step limit (``Scenario.max_episode_steps``: twice the
#: slowest leader's driving time, its settle time and 10 s). A procedural family: that rule at
#: its longest path (40 m, ``platoon_env.scenarios._layout``) and its slowest leader (the
#: drawn speed range's low end, times ``1 - speed_variation``); a layout's own limit is at or
#: below it, and its episode ends (arrival and settle) long before. Constants, so that
#: ``import platoon_env`` builds no scenario; ``tests/test_gym_vector_wrappers.py`` recomputes
#: them.
GYM_STEP_LIMITS: dict[str, int] = {
    "study_a": 28700,
    "study_b": 20175,
    "study_c": 42050,
    **{
        f"procedural_{tier}_{split}": 33200
        for tier in ("easy", "medium", "hard")
        for split in GENERATOR_SPLITS
    },
    **{
        f"procedural_{tier}_{split}": 41200
        for tier in ("sharp", "paper")
        for split in GENERATOR_SPLITS
    },
    **{f"procedural_formations_{split}": 33200 for split in GENERATOR_SPLITS},
    **{
        f"procedural_formations_{tier}_{split}": 41200
        for tier in ("sharp", "paper")
        for split in GENERATOR_SPLITS
    },
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
    ``reset(seed, options)`` as the parallel env's (options ``perturb``, ``poses``). The info
    is the rich view by default (cause names, None when nothing happened, ``reward_terms`` a
    dict); libraries that turn infos into tensors fail on it deep inside (TorchRL's ``GymEnv``
    with an info reader: "'NoneType' object has no attribute 'dtype'"; ``torch.as_tensor``:
    "Could not infer dtype of NoneType"): pass ``info_view="numeric"`` (numbers only, the same
    keys at reset and every step).

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

    #: ``render_fps``: the shipped scenarios' steps per second; each instance holds its own copy
    #: with its scenario's (the parallel env's, :func:`~platoon_env.env.steps_per_second`).
    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 100}

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
        self.metadata = {**self.metadata, "render_fps": self.parallel.metadata["render_fps"]}

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
    (:class:`~platoon_env.gym_vector.SingleFollowerVectorEnv`) and its scenario's
    :data:`GYM_STEP_LIMITS` as ``max_episode_steps``.

    The kwargs add ``max_episode_steps=None`` (a scenario option left as it is): without the
    key, ``gymnasium.make_vec`` would pass the spec's limit to the vector env as a scenario
    option, fixing every procedural layout's limit to it; ``gymnasium.make`` takes its own
    ``max_episode_steps`` (the ``TimeLimit``) before the kwargs reach the env.
    """
    for env_id, kwargs in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="platoon_env.gym_env:SingleFollowerEnv",
                vector_entry_point="platoon_env.gym_vector:SingleFollowerVectorEnv",
                kwargs={**kwargs, "max_episode_steps": None},
                max_episode_steps=GYM_STEP_LIMITS[kwargs["scenario"]],
            )
