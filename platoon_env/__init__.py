"""platoon_env: safe leader-follower coordination of unicycle robots under sensing limits.

Research code uses:

* :func:`make` / :func:`parallel_env` — the PettingZoo ``ParallelEnv``; :func:`env` — its AEC form;
* :func:`list_scenarios`, :func:`load_scenario` — shipped workspaces, YAML files or dicts;
* Gymnasium ids ``platoon_env/SingleFollower-Study{A,B,C}[-Aruco]-v1`` and the procedural
  tiers ``...-Procedural{Easy,Medium,Hard}{Train,Test}[-Aruco]-v1``, registered on import, each
  with a vector entry point (``gymnasium.make_vec``: the batched core,
  :mod:`platoon_env.gym_vector`) and ``normalize_actions=True`` for actions in ``[-1, 1]``.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.env import AECEnv

# First of the package's modules: keys numba's kernel cache on the source (see the module).
import platoon_env._numba_cache  # noqa: F401
from platoon_env.core import CoreSnapshot
from platoon_env.env import PlatoonParallelEnv
from platoon_env.gym_env import GYM_IDS, SingleFollowerEnv, register_gym_ids
from platoon_env.scenarios import (
    VIOLATION_CAUSES,
    Scenario,
    ScenarioConfig,
    ScenarioError,
    list_scenarios,
    load_scenario,
)
from platoon_env.scenarios.source import SourceLike

__version__ = "0.2.0"


def make(scenario: SourceLike = "study_c", **overrides: Any) -> PlatoonParallelEnv:
    """Build the PettingZoo ``ParallelEnv`` for ``scenario``.

    Args:
        scenario: a shipped name (see :func:`list_scenarios`), a YAML path, a dict in the
            scenario schema (``docs/scenarios.md``), a built :class:`Scenario` or a
            :class:`~platoon_env.scenarios.source.ScenarioSource`.
        **overrides: validated by the scenario schema's own rules (a bad value is a
            :class:`ScenarioError` naming the option; an unknown name a ``TypeError``):

            * shortcuts (:data:`~platoon_env.scenarios.options.SCENARIO_OPTIONS`):
              ``control_period`` [s], ``physics_substeps``, ``max_episode_steps``,
              ``terminate_on`` (one cause or an iterable of the causes that end an episode;
              default all of :data:`VIOLATION_CAUSES`), ``followers``, ``perturb`` (seeded
              perturbation of the initial configuration on reset), ``u_max`` [m/s] and
              ``omega_max`` [rad/s] (the action-space bounds);
            * blocks (:data:`~platoon_env.scenarios.options.BLOCK_OPTIONS`): a mapping merged
              into that block of the scenario, e.g. ``camera={"half_angle": 0.5}``,
              ``formation={"d_des": 1.5}``, ``robot={"radius": 0.2}``;
            * env options: ``render_mode`` (``"rgb_array"``, ``"human"`` or None),
              ``diagnostics`` (default True; False keeps only ``violation``, ``violations``
              and ``cost`` in ``info``, for speed).
    """
    return PlatoonParallelEnv(scenario, **overrides)


def parallel_env(scenario: SourceLike = "study_c", **overrides: Any) -> PlatoonParallelEnv:
    """Alias of :func:`make`, as PettingZoo environment modules provide."""
    return make(scenario, **overrides)


def env(scenario: SourceLike = "study_c", **overrides: Any) -> AECEnv:
    """The AEC form of the env (agents act in turn; the step happens after the last one)."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(make(scenario, **overrides))


register_gym_ids()

__all__ = [
    "GYM_IDS",
    "VIOLATION_CAUSES",
    "CoreSnapshot",
    "PlatoonParallelEnv",
    "Scenario",
    "ScenarioConfig",
    "ScenarioError",
    "SingleFollowerEnv",
    "env",
    "list_scenarios",
    "load_scenario",
    "make",
    "parallel_env",
]
