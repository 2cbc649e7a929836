"""platoon_env: safe leader-follower coordination of unicycle robots under sensing limits.

Research code uses:

* :func:`make` / :func:`parallel_env` — the PettingZoo ``ParallelEnv``; :func:`env` — its AEC form;
* :func:`list_scenarios`, :func:`load_scenario` — shipped workspaces, YAML files or dicts;
* Gymnasium ids ``platoon_env/SingleFollower-Study{A,B,C}-v0``, registered on import.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.env import AECEnv

# First of the package's modules: keys numba's kernel cache on the source (see the module).
import platoon_env._numba_cache  # noqa: F401
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
from platoon_env.scenarios.loader import ScenarioLike

__version__ = "0.1.0"


def make(scenario: ScenarioLike = "study_c", **overrides: Any) -> PlatoonParallelEnv:
    """Build the PettingZoo ``ParallelEnv`` for ``scenario``.

    Args:
        scenario: a shipped name (see :func:`list_scenarios`), a YAML path, or a dict in the
            scenario schema.
        **overrides: ``control_period`` [s], ``physics_substeps``, ``max_episode_steps``,
            ``terminate_on`` (iterable of violation causes that end an episode; default all of
            :data:`VIOLATION_CAUSES`), ``render_mode`` (``"rgb_array"``, ``"human"`` or None),
            ``followers`` (number of followers), ``perturb`` (seeded perturbation of the
            initial configuration on reset), ``u_max`` [m/s] and ``omega_max`` [rad/s]
            (actuator limits: the action-space bounds), ``diagnostics`` (default True; False
            keeps only ``violation``, ``violations`` and ``cost`` in ``info``, for speed).
    """
    return PlatoonParallelEnv(scenario, **overrides)


def parallel_env(scenario: ScenarioLike = "study_c", **overrides: Any) -> PlatoonParallelEnv:
    """Alias of :func:`make`, as PettingZoo environment modules provide."""
    return make(scenario, **overrides)


def env(scenario: ScenarioLike = "study_c", **overrides: Any) -> AECEnv:
    """The AEC form of the env (agents act in turn; the step happens after the last one)."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(make(scenario, **overrides))


register_gym_ids()

__all__ = [
    "GYM_IDS",
    "VIOLATION_CAUSES",
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
