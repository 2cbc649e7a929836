"""An SB3 ``VecEnv`` over platoon ``ParallelEnv``\\ s with parameter sharing.

Every follower of every env is one slot of the vectorised env, so one shared policy acts for
all of them: with ``n_envs`` envs of ``N`` followers, ``num_envs = n_envs * N``, and slot
``k`` is follower ``k - offset_j + 1`` of env ``j`` (slots of env ``j`` are contiguous, in
``possible_agents`` order).

Two fixed transformations sit between SB3 and the env, so that a saved policy can reproduce
them from a handful of numbers (see :mod:`training.policies`):

* **Observation normalisation** (fixed, not running): ``obs / observation_scale`` where
  ``observation_scale`` is the upper bound of the env's observation Box
  (``[1, d_con, d_con, prox, prox, prox, prox]``; with task-aware observations six 1s follow,
  for values already in ``[0, 1]``), so every component lies in ``[-1, 1]``.
* **Action rescaling**: the policy acts in ``[-1, 1]^2``, mapped affinely to the physical range
  ``[u_low, u_high] x [-omega_high, omega_high]`` (see :class:`ActionRange`, the rule of
  :mod:`platoon_env.action_range`, shared with the Gymnasium ids' ``normalize_actions``).

Seeds: :meth:`SlotVecEnv.seed` gives env ``j`` its own stream of
``numpy.random.SeedSequence(seed)`` (:func:`training.seeding.env_seeds`, keyed by the
adapter's :attr:`~SlotVecEnv.seed_segment`), not ``seed + j`` as before, so two training seeds
share no env and a resumed run does not replay its first episodes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices

from platoon_env.action_range import ActionRange, check_action_range, normalised_action_space
from platoon_env.env import PlatoonParallelEnv
from platoon_env.observation import ACT_SIZE
from training.seeding import env_seeds

__all__ = [
    "ActionRange",
    "PlatoonVecEnv",
    "normalised_box",
    "observation_scale",
    "refuse_variable_followers",
    "slot_spaces",
]


def refuse_variable_followers(variable: bool, scenario: str, where: str) -> None:
    """``ValueError`` when an SB3 adapter is asked to wrap a scenario whose episodes draw their
    number of followers (``generator.formation.followers`` a range).

    Why: an SB3 ``VecEnv`` has a fixed number of sub-envs (here: follower slots), and every
    sub-env's step is a sample of the rollout: an inert slot (an episode with fewer followers
    than the slots) would be trained on as a follower that sees nothing and earns nothing.
    :mod:`training.fast_ppo` masks those slots out (``BatchedPlatoon.live``)."""
    if variable:
        raise ValueError(
            f"{where}: scenario {scenario!r} draws its number of followers per episode "
            "(generator.formation.followers is a range): an SB3 VecEnv has a fixed number of "
            "follower slots and would train on the inert ones. Train it with training.fast_ppo "
            "(which masks them), or pin the count: generator={'formation': {'followers': [n, n]}}"
        )


def observation_scale(space: spaces.Box) -> NDArray[np.float32]:
    """The fixed normalisation divisor of an observation Box: ``max(|low|, |high|)``."""
    scale = np.maximum(np.abs(space.low), np.abs(space.high)).astype(np.float32)
    if not np.all(np.isfinite(scale)) or np.any(scale <= 0):
        raise ValueError(f"observation bounds must be finite and non-degenerate, got {space}")
    return scale


def normalised_box(space: spaces.Box, scale: NDArray[np.float32] | None) -> spaces.Box:
    """``space`` divided by ``scale`` (None: ``space`` itself), as a float32 Box."""
    if scale is None:
        return spaces.Box(space.low, space.high, dtype=np.float32)
    return spaces.Box(low=space.low / scale, high=space.high / scale, dtype=np.float32)


def slot_spaces(
    observation: spaces.Box,
    actuators: Mapping[str, spaces.Box],
    *,
    normalize_observations: bool,
    action_range: ActionRange | None,
) -> tuple[NDArray[np.float32] | None, spaces.Box, spaces.Box]:
    """``(obs_scale, observation_space, action_space)`` of a slot, for both adapters.

    ``observation``: a follower's observation Box; ``actuators``: the physical action Box of
    each env (by the name an error gives it), checked against ``action_range``. With
    ``normalize_observations`` the observations are divided by :func:`observation_scale`;
    with an ``action_range`` the policy acts in ``Box(-1, 1, (2,))``, else in the first
    env's own action Box.
    """
    scale = observation_scale(observation) if normalize_observations else None
    if action_range is None:
        return scale, normalised_box(observation, scale), next(iter(actuators.values()))
    for what, physical in actuators.items():
        check_action_range(action_range, physical, what)
    return scale, normalised_box(observation, scale), normalised_action_space()


class SlotVecEnv(VecEnv):
    """What both platoon adapters share: one slot per follower, env ``j`` on its own stream
    (:meth:`seed`).

    Subclasses define :attr:`n_envs` and keep ``_env_seeds`` (one pending seed per env),
    ``action_range`` and ``_actions`` (the physical actions stored by :meth:`step_async`).
    """

    _env_seeds: list[int | None]
    action_range: ActionRange | None
    _actions: NDArray[np.float32] | None
    #: The training segment whose env streams :meth:`seed` gives (0: a new run; ``platoon-train
    #: --resume`` sets the number of segments before it, see :mod:`training.seeding`).
    seed_segment: int = 0

    @property
    def n_envs(self) -> int:  # pragma: no cover - defined by every subclass
        """Number of envs (``num_envs`` counts follower slots)."""
        raise NotImplementedError

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Step every env once (defined by every subclass)."""
        raise NotImplementedError  # pragma: no cover

    def step_async(self, actions: np.ndarray) -> None:
        """Store the slots' actions ``(num_envs, 2)`` for :meth:`step_wait`."""
        actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, ACT_SIZE)
        self._actions = (
            self.action_range.to_physical(actions) if self.action_range is not None else actions
        )

    def _take_actions(self) -> NDArray[np.float32]:
        """The actions stored by :meth:`step_async` (once); raises if there are none."""
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        actions, self._actions = self._actions, None
        return actions

    def _check_slot(self, k: int) -> None:
        if not 0 <= k < self.num_envs:
            raise IndexError(f"slot {k} out of range [0, {self.num_envs})")

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed env ``j`` with ``env_seeds(seed, n_envs, segment=seed_segment)[j]`` (its own
        stream of ``SeedSequence(seed)``, :mod:`training.seeding`) at the next :meth:`reset`;
        returns those seeds. ``None``: a run seed drawn from fresh entropy."""
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1, dtype=np.uint32)[0])
        self._env_seeds = list(env_seeds(seed, self.n_envs, segment=self.seed_segment))
        return list(self._env_seeds)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """:meth:`step_async` then :meth:`step_wait` (narrower return type than ``VecEnv``)."""
        self.step_async(actions)
        return self.step_wait()


class PlatoonVecEnv(SlotVecEnv):
    """Parameter-sharing SB3 ``VecEnv`` adapter for one or more platoon ``ParallelEnv``\\ s.

    * ``step_async``/``step_wait`` gather each env's per-follower actions from the slots and
      step every env once. When an env's episode ends (all its followers terminate or truncate
      together), each of its slots gets ``infos[k]["terminal_observation"]`` (the final,
      normalised observation) and ``infos[k]["TimeLimit.truncated"] = truncated and not
      terminated``; the env is reset at once and the slots return the reset observation.
      ``dones[k] = terminated or truncated``.
    * :meth:`seed`: env ``j`` is reset with its own seed drawn from ``SeedSequence(seed)``
      (:mod:`training.seeding`) on the first :meth:`reset` after it; later auto-resets
      continue each env's own RNG (so a seeded run is reproducible).
    * ``get_attr``/``set_attr``/``env_method`` take *slot* indices and act on the envs owning
      those slots, each env once; results are returned per slot.

    Args:
        env_fns: callables building the envs (or the envs themselves). All must share the same
            observation space (the normalisation is one fixed vector).
        normalize_observations: divide observations by :func:`observation_scale`.
        action_range: the physical range of the normalised action (the adapter's action space
            is then ``Box(-1, 1, (2,))``); ``None`` passes physical actions through, with the
            env's own action space.
    """

    observation_space: spaces.Box
    action_space: spaces.Box

    def __init__(
        self,
        env_fns: Iterable[Callable[[], PlatoonParallelEnv] | PlatoonParallelEnv],
        *,
        normalize_observations: bool = True,
        action_range: ActionRange | None = None,
    ) -> None:
        self.envs: list[PlatoonParallelEnv] = [
            fn if isinstance(fn, PlatoonParallelEnv) else fn() for fn in env_fns
        ]
        if not self.envs:
            raise ValueError("PlatoonVecEnv needs at least one env")
        first = self.envs[0]
        for env in self.envs:
            variable = bool(getattr(env, "variable_followers", False))
            refuse_variable_followers(variable, env.scenario.name, "PlatoonVecEnv")
        obs_space = first.observation_space(first.possible_agents[0])
        for j, env in enumerate(self.envs):
            for agent in env.possible_agents:
                other = env.observation_space(agent)
                if not (
                    np.array_equal(other.low, obs_space.low)
                    and np.array_equal(other.high, obs_space.high)
                ):
                    raise ValueError(
                        f"env {j} ({agent}) has observation space {other}, expected {obs_space}; "
                        "parameter sharing needs one observation space"
                    )
        self.action_range = action_range
        self.obs_scale, observation_space, action_space = slot_spaces(
            obs_space,
            {
                f"env {j}": env.action_space(env.possible_agents[0])
                for j, env in enumerate(self.envs)
            },
            normalize_observations=normalize_observations,
            action_range=action_range,
        )
        self._offsets = np.cumsum([0] + [len(e.possible_agents) for e in self.envs]).tolist()
        num_slots = int(self._offsets[-1])
        self._env_seeds: list[int | None] = [None] * len(self.envs)
        self._env_options: list[dict[str, Any]] = [{} for _ in self.envs]
        self._obs = np.zeros((num_slots, *observation_space.shape), dtype=np.float32)
        self._actions: NDArray[np.float32] | None = None
        super().__init__(num_slots, observation_space, action_space)

    # ----------------------------------------------------------------------------------------
    # Slots
    # ----------------------------------------------------------------------------------------
    @property
    def n_envs(self) -> int:
        """Number of wrapped ``ParallelEnv``\\ s (``num_envs`` counts follower slots)."""
        return len(self.envs)

    def env_slots(self, j: int) -> range:
        """The slot indices of env ``j``'s followers."""
        return range(self._offsets[j], self._offsets[j + 1])

    def slot_env(self, k: int) -> int:
        """The index of the env owning slot ``k``."""
        self._check_slot(k)
        return int(np.searchsorted(self._offsets, k, side="right")) - 1

    def _normalise(self, obs: Mapping[str, NDArray[Any]], env: PlatoonParallelEnv) -> np.ndarray:
        stacked = np.stack([obs[a] for a in env.possible_agents]).astype(np.float32)
        return stacked / self.obs_scale if self.obs_scale is not None else stacked

    # ----------------------------------------------------------------------------------------
    # VecEnv API
    # ----------------------------------------------------------------------------------------
    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        """Options for each env's next :meth:`reset` (one dict for all, or one per env)."""
        if options is None:
            options = {}
        if isinstance(options, dict):
            self._env_options = [dict(options) for _ in self.envs]
        else:
            if len(options) != self.n_envs:
                raise ValueError(f"need one options dict per env ({self.n_envs})")
            self._env_options = [dict(o) for o in options]

    def reset(self) -> np.ndarray:
        """Reset every env (with the pending seeds/options) and return the stacked observations."""
        for j, env in enumerate(self.envs):
            obs, infos = env.reset(seed=self._env_seeds[j], options=self._env_options[j] or None)
            slots = self.env_slots(j)
            self._obs[slots.start : slots.stop] = self._normalise(obs, env)
            for k, agent in zip(slots, env.possible_agents, strict=True):
                self.reset_infos[k] = infos.get(agent, {})
        self._env_seeds = [None] * self.n_envs
        self._env_options = [{} for _ in self.envs]
        return self._obs.copy()

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Step every env once; auto-reset the envs whose episode ended."""
        actions = self._take_actions()
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for j, env in enumerate(self.envs):
            slots = self.env_slots(j)
            agents = env.possible_agents
            env_actions = {a: actions[k] for k, a in zip(slots, agents, strict=True)}
            obs, rew, term, trunc, env_infos = env.step(env_actions)
            stacked = self._normalise(obs, env)
            terminated = any(term.values())
            truncated = any(trunc.values())
            done = terminated or truncated
            for i, (k, agent) in enumerate(zip(slots, agents, strict=True)):
                rewards[k] = rew[agent]
                info = dict(env_infos.get(agent, {}))
                if done:
                    info["terminal_observation"] = stacked[i].copy()
                    info["TimeLimit.truncated"] = truncated and not terminated
                infos[k] = info
            dones[slots.start : slots.stop] = done
            if done:
                obs, reset_infos = env.reset(
                    seed=self._env_seeds[j], options=self._env_options[j] or None
                )
                self._env_seeds[j] = None
                self._env_options[j] = {}
                stacked = self._normalise(obs, env)
                for k, agent in zip(slots, agents, strict=True):
                    self.reset_infos[k] = reset_infos.get(agent, {})
            self._obs[slots.start : slots.stop] = stacked
        return self._obs.copy(), rewards, dones, infos

    def close(self) -> None:
        """Close every env."""
        for env in self.envs:
            env.close()

    def _env_indices(self, indices: VecEnvIndices) -> list[int]:
        """Distinct env indices owning the given slots, in first-seen order."""
        return list(dict.fromkeys(self.slot_env(k) for k in self._get_indices(indices)))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """``getattr(env, attr_name)`` of the env owning each slot (one entry per slot)."""
        return [getattr(self.envs[self.slot_env(k)], attr_name) for k in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set ``attr_name`` on every env owning one of the slots (each env once)."""
        for j in self._env_indices(indices):
            setattr(self.envs[j], attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        """Call ``method_name`` once on each env owning one of the slots; results per slot."""
        results = {
            j: getattr(self.envs[j], method_name)(*method_args, **method_kwargs)
            for j in self._env_indices(indices)
        }
        return [results[self.slot_env(k)] for k in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        """Always False: the envs are PettingZoo envs, never Gymnasium wrappers."""
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One ``rgb_array`` frame per slot (the owning env's frame), if render_mode allows."""
        if self.render_mode != "rgb_array":
            return [None for _ in range(self.num_envs)]
        frames = [env.render() for env in self.envs]
        return [frames[self.slot_env(k)] for k in range(self.num_envs)]
