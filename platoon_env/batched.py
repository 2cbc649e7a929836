"""The batched array API: ``B`` copies of one scenario stepped by one compiled call.

:class:`BatchedPlatoon` holds the state of ``B`` independent envs as arrays and steps all of
them with one numba call (``prange`` over envs, ``n_threads`` threads). Every env runs exactly
the physics, sensing, safety and reward of :class:`platoon_env.env.PlatoonParallelEnv` (the same
compiled kernel, :func:`platoon_env.simulator.platoon_step`) and draws its initial configuration
the same way (:class:`platoon_env.initial.InitialSampler` with its own
``gymnasium.utils.seeding.np_random`` generator), so env ``b`` reset with seed ``s`` and fed the
same actions follows the single env's trajectory bit for bit (see ``tests/test_batched.py``).

Arrays, with ``B`` envs of ``N`` followers (follower ``i`` is ``possible_agents[i]``):

======================  ==============  =======================================================
name                    shape, dtype    meaning
======================  ==============  =======================================================
actions                 (B, N, 2)       ``[u, omega]`` [m/s, rad/s]; clipped to the action Box
observations            (B, N, 7) f32   as :mod:`platoon_env.observation`
rewards                 (B, N) f64      summed reward terms (:mod:`platoon_env.reward`)
terminated, truncated   (B,) bool       as the env's (the same for all followers of an env)
info["violations"]      (B, N) int64    violation bit masks (bit k: ``VIOLATION_CAUSES[k]``)
info["substeps"]        (B,) int64      physics sub-steps simulated (fewer after a violation)
======================  ==============  =======================================================

With ``auto_reset=True`` an env whose episode ended is reset within the same :meth:`step`: its
row of the returned observations is the first observation of the next episode, and
``info["final_observation"]`` (present when some env ended) holds the last one of the ended
episode (rows of other envs are unspecified); ``info["reset"]`` marks those envs. Its RNG
continues (no reseeding).

Procedural scenarios (a new workspace on every reset) are not supported here.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numba
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from numba import njit, prange

from platoon_env.env import PlatoonParallelEnv
from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import SENSE_SIZE
from platoon_env.initial import InitialSampler
from platoon_env.observation import ACT_SIZE, OBS_SIZE
from platoon_env.reward import REWARD_TERMS
from platoon_env.safety import causes_to_mask
from platoon_env.scenarios.loader import ScenarioLike
from platoon_env.simulator import (
    L_ARRIVED,
    L_PROGRESS,
    L_SIZE,
    P_SUBSTEP,
    kernel_params,
    platoon_step,
)

__all__ = ["BatchedPlatoon"]


@njit(cache=True)
def _step_env(
    b: int,
    n_substeps: int,
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    params: np.ndarray,
    terminate_mask: int,
    violations: np.ndarray,
    sensed: np.ndarray,
    obs: np.ndarray,
    terms: np.ndarray,
    rewards: np.ndarray,
    substeps: np.ndarray,
    sim_time: np.ndarray,
    steps: np.ndarray,
    arrival: np.ndarray,
    max_steps: int,
    settle_time: float,
    terminated: np.ndarray,
    truncated: np.ndarray,
) -> None:
    """Env ``b``'s step (or, with ``n_substeps = 0``, its reset sensing) and episode bookkeeping,
    in the order and arithmetic of ``PlatoonParallelEnv.step``."""
    done = platoon_step(
        poses[b],
        actions[b],
        leader[b],
        path,
        cum,
        edges,
        boxes,
        grid_params,
        cell_start,
        cell_edges,
        edge_cell,
        params,
        n_substeps,
        terminate_mask,
        violations[b],
        sensed[b],
        obs[b],
        terms[b],
        rewards[b],
    )
    substeps[b] = done
    if n_substeps == 0:
        terminated[b] = False
        truncated[b] = False
        return
    sim_time[b] += done * params[P_SUBSTEP]
    steps[b] += 1
    if leader[b, L_ARRIVED] != 0.0 and np.isnan(arrival[b]):
        arrival[b] = sim_time[b]
    term = False
    for i in range(violations.shape[1]):
        if violations[b, i] & terminate_mask:
            term = True
    terminated[b] = term
    truncated[b] = not term and (
        steps[b] >= max_steps
        or (not np.isnan(arrival[b]) and sim_time[b] - arrival[b] >= settle_time - 1e-9)
    )


@njit(cache=True)
def _count_ended(active: np.ndarray, terminated: np.ndarray, truncated: np.ndarray) -> int:
    """Number of active envs whose episode ended in this call."""
    ended = 0
    for b in range(active.shape[0]):
        if active[b] and (terminated[b] or truncated[b]):
            ended += 1
    return ended


# Two drivers with the same body: numba caches a function per source location, so the serial
# and the parallel variant must be distinct functions.
@njit(cache=True)
def _step_batch_serial(
    active: np.ndarray,
    n_substeps: int,
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    params: np.ndarray,
    terminate_mask: int,
    violations: np.ndarray,
    sensed: np.ndarray,
    obs: np.ndarray,
    terms: np.ndarray,
    rewards: np.ndarray,
    substeps: np.ndarray,
    sim_time: np.ndarray,
    steps: np.ndarray,
    arrival: np.ndarray,
    max_steps: int,
    settle_time: float,
    terminated: np.ndarray,
    truncated: np.ndarray,
) -> int:
    for b in range(active.shape[0]):
        if active[b]:
            _step_env(
                b,
                n_substeps,
                poses,
                actions,
                leader,
                path,
                cum,
                edges,
                boxes,
                grid_params,
                cell_start,
                cell_edges,
                edge_cell,
                params,
                terminate_mask,
                violations,
                sensed,
                obs,
                terms,
                rewards,
                substeps,
                sim_time,
                steps,
                arrival,
                max_steps,
                settle_time,
                terminated,
                truncated,
            )
    return _count_ended(active, terminated, truncated)


@njit(cache=True, parallel=True)
def _step_batch_parallel(
    active: np.ndarray,
    n_substeps: int,
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    params: np.ndarray,
    terminate_mask: int,
    violations: np.ndarray,
    sensed: np.ndarray,
    obs: np.ndarray,
    terms: np.ndarray,
    rewards: np.ndarray,
    substeps: np.ndarray,
    sim_time: np.ndarray,
    steps: np.ndarray,
    arrival: np.ndarray,
    max_steps: int,
    settle_time: float,
    terminated: np.ndarray,
    truncated: np.ndarray,
) -> int:
    for b in prange(active.shape[0]):
        if active[b]:
            _step_env(
                b,
                n_substeps,
                poses,
                actions,
                leader,
                path,
                cum,
                edges,
                boxes,
                grid_params,
                cell_start,
                cell_edges,
                edge_cell,
                params,
                terminate_mask,
                violations,
                sensed,
                obs,
                terms,
                rewards,
                substeps,
                sim_time,
                steps,
                arrival,
                max_steps,
                settle_time,
                terminated,
                truncated,
            )
    return _count_ended(active, terminated, truncated)


@njit(cache=True)
def _first_bad_action(actions: np.ndarray) -> int:
    """``b * N + i`` of the first action row holding NaN or inf, else -1 (``platoon_step``
    clips the finite ones)."""
    n = actions.shape[1]
    for b in range(actions.shape[0]):
        for i in range(n):
            for j in range(actions.shape[2]):
                if not np.isfinite(actions[b, i, j]):
                    return b * n + i
    return -1


class BatchedPlatoon:
    """``batch_size`` independent envs of one scenario, stepped together (see the module doc).

    Args:
        scenario: a shipped name, a YAML path, a dict or a :class:`~platoon_env.Scenario`.
        batch_size: number of envs ``B``.
        n_threads: numba threads stepping the envs (``prange``); 1 runs a serial loop. At most
            ``numba.config.NUMBA_NUM_THREADS`` (the ``NUMBA_NUM_THREADS`` environment variable,
            default: the number of cores).
        auto_reset: reset an env within :meth:`step` when its episode ends.
        grid_cell_size: side [m] of the cells of the edge grid
            (:class:`~platoon_env.geometry.grid.EdgeGrid`); None: half the proximity range;
            0: one cell (no culling, for comparisons). Results do not depend on it.
        **overrides: as :func:`platoon_env.make` (``control_period``, ``physics_substeps``,
            ``max_episode_steps``, ``terminate_on``, ``followers``, ``perturb``, ``u_max``,
            ``omega_max``); ``render_mode`` is not supported.

    Raises:
        ValueError: for a procedural scenario, a non-positive batch size or thread count.
    """

    def __init__(
        self,
        scenario: ScenarioLike = "study_c",
        batch_size: int = 1,
        *,
        n_threads: int = 1,
        auto_reset: bool = False,
        grid_cell_size: float | None = None,
        control_period: float | None = None,
        physics_substeps: int | None = None,
        max_episode_steps: int | None = None,
        terminate_on: Iterable[str] | None = None,
        followers: int | None = None,
        perturb: bool | None = None,
        u_max: float | None = None,
        omega_max: float | None = None,
    ) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        # One env validates the scenario and the overrides exactly as make() does.
        template = PlatoonParallelEnv(
            scenario,
            control_period=control_period,
            physics_substeps=physics_substeps,
            max_episode_steps=max_episode_steps,
            terminate_on=terminate_on,
            followers=followers,
            perturb=perturb,
            u_max=u_max,
            omega_max=omega_max,
        )
        cfg = template.scenario.config
        if cfg.generator is not None:
            raise ValueError(
                f"scenario {cfg.name!r} is procedural (a new workspace on every reset), which "
                "BatchedPlatoon does not support; use PlatoonParallelEnv (training.vec_env) or a "
                "fixed-workspace scenario"
            )
        self.scenario = template.scenario
        self.batch_size = int(batch_size)
        self.n_followers = cfg.followers
        self.possible_agents: list[str] = list(template.possible_agents)
        agent = self.possible_agents[0]
        #: Per-follower spaces (the same Box objects as the env's).
        self.single_observation_space: spaces.Box = template.observation_space(agent)
        self.single_action_space: spaces.Box = template.action_space(agent)
        self.control_period = template.control_period
        self.physics_substeps = template.physics_substeps
        self.max_episode_steps = int(template.max_episode_steps)
        self.terminate_on = frozenset(template.terminate_on)
        self.auto_reset = bool(auto_reset)
        #: No rendering in the batched core (SB3's VecEnv reads this attribute).
        self.render_mode: str | None = None
        self.n_threads = 1
        self.set_threads(n_threads)

        self._terminate_mask = causes_to_mask(self.terminate_on)
        self._settle_time = float(cfg.leader.settle_time)
        self._params = kernel_params(cfg)
        # Own writable copies: numba types read-only array arguments more slowly on every call.
        self._path = np.array(self.scenario.leader_path, dtype=np.float64)
        self._cum = np.array(self.scenario.path_s, dtype=np.float64)
        self.grid = EdgeGrid.build(
            self.scenario.workspace.edges, grid_cell_size, reach=cfg.proximity_range
        )
        self._sampler = InitialSampler(self.scenario)
        self._default_perturb = bool(cfg.initial.perturb)

        b, n = self.batch_size, self.n_followers
        self._poses = np.zeros((b, n + 1, 3))
        self._poses[:] = self._sampler.base
        self._leader = np.zeros((b, L_SIZE))
        self._actions = np.zeros((b, n, ACT_SIZE))
        self._violations = np.zeros((b, n), dtype=np.int64)
        self._sensed = np.zeros((b, n, SENSE_SIZE))
        self._obs = np.zeros((b, n, OBS_SIZE), dtype=np.float32)
        self._terms = np.zeros((b, n, len(REWARD_TERMS)))
        self._rewards = np.zeros((b, n))
        self._substeps = np.zeros(b, dtype=np.int64)
        self._sim_time = np.zeros(b)
        self._steps = np.zeros(b, dtype=np.int64)
        self._arrival = np.full(b, np.nan)
        self._terminated = np.zeros(b, dtype=bool)
        self._truncated = np.zeros(b, dtype=bool)
        #: Envs that need a reset before they can step (all, until the first reset).
        self._finished = np.ones(b, dtype=bool)
        self._needs_reset = True
        self._all = np.ones(b, dtype=bool)
        self._rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(b)]
        # The kernel's state and scenario arguments: always these same array objects.
        self._kernel_args: tuple[Any, ...] = (
            self._poses,
            self._actions,
            self._leader,
            self._path,
            self._cum,
            *self.grid.arrays,
            self._params,
            self._terminate_mask,
            self._violations,
            self._sensed,
            self._obs,
            self._terms,
            self._rewards,
            self._substeps,
            self._sim_time,
            self._steps,
            self._arrival,
        )

    # ----------------------------------------------------------------------------------------
    # Configuration
    # ----------------------------------------------------------------------------------------
    def set_threads(self, n_threads: int) -> None:
        """Use ``n_threads`` numba threads in :meth:`step` (1: a serial loop)."""
        limit = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
        if not 1 <= n_threads <= limit:
            raise ValueError(
                f"n_threads must be in [1, {limit}] (numba's thread pool; set the environment "
                f"variable NUMBA_NUM_THREADS before importing numba for more), got {n_threads}"
            )
        self.n_threads = int(n_threads)

    # ----------------------------------------------------------------------------------------
    # State (copies)
    # ----------------------------------------------------------------------------------------
    @property
    def poses(self) -> np.ndarray:
        """Ground-truth poses ``(B, N+1, 3)``, leader first (a copy)."""
        return self._poses.copy()

    @property
    def sensed(self) -> np.ndarray:
        """Ground-truth sensing ``(B, N, SENSE_SIZE)`` of the last step (a copy)."""
        return self._sensed.copy()

    @property
    def reward_terms(self) -> np.ndarray:
        """Reward terms ``(B, N, len(REWARD_TERMS))`` of the last step (a copy)."""
        return self._terms.copy()

    @property
    def sim_time(self) -> np.ndarray:
        """Simulated time [s] of each env's episode (a copy)."""
        return self._sim_time.copy()

    @property
    def steps(self) -> np.ndarray:
        """Steps taken in each env's episode (a copy)."""
        return self._steps.copy()

    @property
    def leader_arrived(self) -> np.ndarray:
        """Whether each env's leader has reached its path's end."""
        return self._leader[:, L_ARRIVED] != 0.0

    # ----------------------------------------------------------------------------------------
    # API
    # ----------------------------------------------------------------------------------------
    def reset(
        self,
        seeds: int | Sequence[int | None] | None = None,
        *,
        envs: Sequence[int] | np.ndarray | None = None,
        perturb: bool | None = None,
    ) -> np.ndarray:
        """Start new episodes; returns the observations ``(B, N, 7)`` of every env (a copy).

        Args:
            seeds: ``None`` continues each env's own RNG; an int ``s`` seeds env ``b`` (the
                ``k``-th reset env) with ``s + k``; a sequence gives one seed (or None) per reset
                env.
            envs: indices of the envs to reset (default: all).
            perturb: override the scenario's seeded perturbation of the initial configuration.
        """
        idx = np.arange(self.batch_size) if envs is None else np.asarray(envs, dtype=np.int64)
        if idx.ndim != 1 or np.any(idx < 0) or np.any(idx >= self.batch_size):
            raise ValueError(f"envs must be indices in [0, {self.batch_size}), got {envs}")
        if seeds is None:
            seed_list: list[int | None] = [None] * len(idx)
        elif isinstance(seeds, int | np.integer):
            seed_list = [int(seeds) + k for k in range(len(idx))]
        else:
            seed_list = list(seeds)
            if len(seed_list) != len(idx):
                raise ValueError(f"need one seed per reset env ({len(idx)}), got {len(seed_list)}")
        self._reset_envs(idx, seed_list, self._default_perturb if perturb is None else perturb)
        return self._obs.copy()

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every env by one control period.

        Args:
            actions: ``(B, N, 2)`` ``[u, omega]``; clipped to the action Box. NaN or inf raise
                ``ValueError`` (naming env and agent) before any state changes.

        Returns:
            ``(observations (B, N, 7), rewards (B, N), terminated (B,), truncated (B,), info)``
            (fresh arrays), ``info`` as in the module docstring.

        Raises:
            RuntimeError: an env's episode ended and it was not reset (without ``auto_reset``).
        """
        act = np.asarray(actions)
        if act.shape != self._actions.shape:
            raise ValueError(
                f"actions must have shape {self._actions.shape} (B, N, [u, omega]), got {act.shape}"
            )
        if self._needs_reset:
            bad = np.flatnonzero(self._finished)
            raise RuntimeError(
                f"env(s) {bad[:10].tolist()} finished their episode; call reset() first "
                "(or construct with auto_reset=True)"
            )
        np.copyto(self._actions, act)
        row = _first_bad_action(self._actions)
        if row >= 0:
            b, i = divmod(row, self.n_followers)
            raise ValueError(
                f"action of env {b}, {self.possible_agents[i]!r} contains NaN or inf: "
                f"{act[b, i].tolist()}"
            )
        n_ended = self._run(self._all, self.physics_substeps)
        terminated = self._terminated.copy()
        truncated = self._truncated.copy()
        info: dict[str, np.ndarray] = {
            "violations": self._violations.copy(),
            "substeps": self._substeps.copy(),
        }
        rewards = self._rewards.copy()
        if n_ended:
            ended = terminated | truncated
            if self.auto_reset:
                info["final_observation"] = self._obs.copy()
                idx = np.flatnonzero(ended)
                self._reset_envs(idx, [None] * len(idx), self._default_perturb)
            else:
                self._finished |= ended
                self._needs_reset = True
        if self.auto_reset:
            info["reset"] = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, info

    # ----------------------------------------------------------------------------------------
    # Internals
    # ----------------------------------------------------------------------------------------
    def _reset_envs(self, idx: np.ndarray, seeds: list[int | None], perturb: bool) -> None:
        for b, seed in zip(idx.tolist(), seeds, strict=True):
            if seed is not None:
                self._rngs[b] = seeding.np_random(seed)[0]
            self._poses[b] = self._sampler.sample(self._rngs[b], bool(perturb))
        self._leader[idx, L_PROGRESS] = self.scenario.initial_progress
        self._leader[idx, L_ARRIVED] = 0.0
        self._sim_time[idx] = 0.0
        self._steps[idx] = 0
        self._arrival[idx] = np.nan
        self._actions[idx] = 0.0
        self._finished[idx] = False
        self._needs_reset = bool(self._finished.any())
        active = np.zeros(self.batch_size, dtype=bool)
        active[idx] = True
        self._run(active, 0)

    def _run(self, active: np.ndarray, n_substeps: int) -> int:
        """Step (or, with 0 sub-steps, sense) the active envs; returns how many ended."""
        args = (
            active,
            n_substeps,
            *self._kernel_args,
            self.max_episode_steps,
            self._settle_time,
            self._terminated,
            self._truncated,
        )
        if self.n_threads == 1 or self.batch_size == 1:
            return int(_step_batch_serial(*args))
        previous = numba.get_num_threads()
        numba.set_num_threads(self.n_threads)
        try:
            return int(_step_batch_parallel(*args))
        finally:
            numba.set_num_threads(previous)

    def __repr__(self) -> str:
        return (
            f"BatchedPlatoon({self.scenario.name!r}, batch_size={self.batch_size}, "
            f"followers={self.n_followers}, n_threads={self.n_threads}, "
            f"auto_reset={self.auto_reset})"
        )
