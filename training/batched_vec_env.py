"""An SB3 ``VecEnv`` on the batched core (:class:`platoon_env.batched.BatchedPlatoon`).

The drop-in, faster counterpart of :class:`training.vec_env.PlatoonVecEnv`: the same slot
layout (every follower of every env is one slot; slot ``k`` is follower ``k - N j + 1`` of env
``j``), the same fixed observation normalisation and action rescaling (:class:`ActionRange`,
:func:`observation_scale`), the same ``terminal_observation`` / ``TimeLimit.truncated`` and
seeding semantics, and bit-for-bit the same observations, rewards and dones for the same seeds
and actions (``tests/test_batched.py``). All envs step in one compiled call, with no Python loop
over envs; only envs whose episode ended are reset from Python.

Differences from :class:`PlatoonVecEnv`:

* per-slot ``infos`` carry ``violation`` (first cause or None), ``violations`` (all causes) and
  ``cost`` (0/1) only, not the env's ground-truth diagnostics (``d``, ``beta``, ...); read
  those from :attr:`BatchedPlatoonVecEnv.core` (e.g. ``core.sensed``) if needed;
* ``reset_infos`` are empty dicts;
* only fixed-workspace scenarios (the batched core rejects procedural ones);
* ``get_attr`` / ``set_attr`` / ``env_method`` act on the one batched core (results repeated per
  slot); no rendering.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices

from platoon_env.batched import BatchedPlatoon
from platoon_env.observation import ACT_SIZE
from platoon_env.scenarios.loader import ScenarioLike
from platoon_env.violations import VIOLATION_INFO
from training.vec_env import ActionRange, SlotVecEnv, refuse_variable_followers, slot_spaces

__all__ = ["BatchedPlatoonVecEnv"]


class BatchedPlatoonVecEnv(SlotVecEnv):
    """Parameter-sharing SB3 ``VecEnv`` over ``n_envs`` batched copies of one scenario.

    Args:
        scenario: a shipped name, YAML path, dict or :class:`~platoon_env.Scenario`.
        n_envs: number of envs (``num_envs = n_envs * N`` slots).
        action_range: the physical range of the normalised action (the action space is then
            ``Box(-1, 1, (2,))``); ``None`` passes physical actions through.
        normalize_observations: divide observations by
            :func:`~training.vec_env.observation_scale`.
        n_threads: numba threads stepping the envs (see :class:`BatchedPlatoon`).
        **env_kwargs: overrides as :func:`platoon_env.make` (``control_period``,
            ``max_episode_steps``, ``terminate_on``, ...).
    """

    observation_space: spaces.Box
    action_space: spaces.Box

    def __init__(
        self,
        scenario: ScenarioLike = "study_c",
        n_envs: int = 1,
        *,
        action_range: ActionRange | None = None,
        normalize_observations: bool = True,
        n_threads: int = 1,
        **env_kwargs: Any,
    ) -> None:
        self.core = BatchedPlatoon(
            scenario, n_envs, n_threads=n_threads, auto_reset=False, **env_kwargs
        )
        refuse_variable_followers(
            self.core.variable_followers, self.core.scenario.name, "BatchedPlatoonVecEnv"
        )
        self.n_followers = self.core.n_followers
        self.action_range = action_range
        self.obs_scale, observation_space, action_space = slot_spaces(
            self.core.single_observation_space,
            {"the env": self.core.single_action_space},
            normalize_observations=normalize_observations,
            action_range=action_range,
        )
        self._env_seeds: list[int | None] = [None] * self.n_envs
        self._env_perturb: list[bool | None] = [None] * self.n_envs
        self._actions: NDArray[np.float32] | None = None
        super().__init__(self.n_envs * self.n_followers, observation_space, action_space)

    # ----------------------------------------------------------------------------------------
    # Slots
    # ----------------------------------------------------------------------------------------
    @property
    def envs(self) -> list[BatchedPlatoon]:
        """``[core]``: for code written against ``PlatoonVecEnv.envs[0]``, which reads the
        episode settings (``control_period``, ``physics_substeps``, ``max_episode_steps``,
        ``terminate_on``, ``n_followers``); the batched core has the same attributes."""
        return [self.core]

    @property
    def n_envs(self) -> int:
        """Number of batched envs (``num_envs`` counts follower slots)."""
        return self.core.batch_size

    def env_slots(self, j: int) -> range:
        """The slot indices of env ``j``'s followers."""
        return range(j * self.n_followers, (j + 1) * self.n_followers)

    def slot_env(self, k: int) -> int:
        """The index of the env owning slot ``k``."""
        self._check_slot(k)
        return k // self.n_followers

    def _normalise(self, obs: np.ndarray) -> np.ndarray:
        flat = obs.reshape(-1, obs.shape[-1])
        return flat / self.obs_scale if self.obs_scale is not None else flat

    # ----------------------------------------------------------------------------------------
    # VecEnv API
    # ----------------------------------------------------------------------------------------
    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        """Options for each env's next reset (one dict for all, or one per env).

        Only ``{"perturb": bool}`` is supported by the batched core.
        """
        if options is None:
            options = {}
        per_env = [options] * self.n_envs if isinstance(options, dict) else list(options)
        if len(per_env) != self.n_envs:
            raise ValueError(f"need one options dict per env ({self.n_envs})")
        for o in per_env:
            unknown = set(o) - {"perturb"}
            if unknown:
                raise ValueError(
                    f"BatchedPlatoonVecEnv supports only the 'perturb' reset option, got "
                    f"{', '.join(sorted(map(str, unknown)))}"
                )
        self._env_perturb = [o.get("perturb") for o in per_env]

    def reset(self) -> np.ndarray:
        """Reset every env (with the pending seeds/options) and return the observations."""
        obs = self._reset_envs(np.arange(self.n_envs))
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._normalise(obs).astype(np.float32, copy=False)

    def _reset_envs(self, idx: np.ndarray) -> np.ndarray:
        """Reset envs ``idx`` with their pending seeds/options; returns every env's observation."""
        obs = np.empty(0)
        # Envs with the same perturb option are reset together; seeds stay per env.
        for perturb in dict.fromkeys(self._env_perturb[j] for j in idx.tolist()):
            group = [j for j in idx.tolist() if self._env_perturb[j] == perturb]
            obs = self.core.reset([self._env_seeds[j] for j in group], envs=group, perturb=perturb)
        for j in idx.tolist():
            self._env_seeds[j] = None
            self._env_perturb[j] = None
        return obs

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Step every env once (one compiled call); reset the envs whose episode ended."""
        actions = self._take_actions()
        n = self.n_followers
        obs, rew, terminated, truncated, info = self.core.step(
            actions.reshape(self.n_envs, n, ACT_SIZE)
        )
        final = self._normalise(obs)
        rewards = rew.reshape(-1).astype(np.float32)
        ended = terminated | truncated
        dones = np.repeat(ended, n)
        table = VIOLATION_INFO
        infos: list[dict[str, Any]] = []
        for m in info["violations"].reshape(-1).tolist():
            first, causes, cost = table[m]
            infos.append({"violation": first, "violations": causes, "cost": cost})
        if ended.any():
            idx = np.flatnonzero(ended)
            for j in idx.tolist():
                time_limit = bool(truncated[j] and not terminated[j])
                for k in range(j * n, (j + 1) * n):
                    infos[k]["terminal_observation"] = final[k].copy()
                    infos[k]["TimeLimit.truncated"] = time_limit
            out = self._normalise(self._reset_envs(idx)).astype(np.float32, copy=False)
        else:
            out = final.astype(np.float32, copy=False)
        return out, rewards, dones, infos

    def close(self) -> None:
        """Nothing to release (no renderer, no subprocess)."""

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """``getattr(core, attr_name)`` once per slot (all slots share the batched core)."""
        value = getattr(self.core, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set ``attr_name`` on the batched core (shared by every slot)."""
        setattr(self.core, attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        """Call ``method_name`` once on the batched core; the result repeated per slot."""
        result = getattr(self.core, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        """Always False: there are no Gymnasium envs to wrap."""
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """No rendering in the batched core."""
        return [None for _ in range(self.num_envs)]
