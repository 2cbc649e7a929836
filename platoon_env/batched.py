"""The batched array API: ``B`` envs of one scenario source stepped by one compiled call.

:class:`BatchedPlatoon` is the simulation core (:class:`platoon_env.core.PlatoonCore`) at
``B > 1`` with array I/O: one numba call steps every env (``prange`` over envs, ``n_threads``
threads), with exactly the physics, sensing, safety, reward and episode rules of
:class:`platoon_env.env.PlatoonParallelEnv` (the same core at ``B = 1``), and each env draws its
scenario (a procedural source: its own layouts) and initial configuration from its own
``gymnasium.utils.seeding.np_random`` generator, so env ``b`` reset with seed ``s`` and fed the
same actions follows the single env's trajectory bit for bit (see ``tests/test_batched.py``).

Arrays, with ``B`` envs of ``N`` followers (follower ``i`` is ``possible_agents[i]``):

======================  ==============  =======================================================
name                    shape, dtype    meaning
======================  ==============  =======================================================
actions                 (B, N, 2)       ``[u, omega]`` [m/s, rad/s]; clipped to the action Box
observations            (B, N, K) f32   as :mod:`platoon_env.observation` (K = 7; 13 task-aware;
                                        15 scale-free)
rewards                 (B, N) f64      summed reward terms (:mod:`platoon_env.reward`)
terminated, truncated   (B,) bool       as the env's (the same for all followers of an env)
info["violations"]      (B, N) int64    violation bit masks (bit k: ``VIOLATION_CAUSES[k]``)
info["substeps"]        (B,) int64      physics sub-steps simulated (fewer after a violation)
======================  ==============  =======================================================

**Variable formations** (``generator.formation.followers`` a range, ``docs/api.md``): ``N`` is
the range's upper end, a maximum with masks; env ``b``'s episode has :attr:`BatchedPlatoon.n_active`
``[b]`` followers in slots ``0 .. n - 1`` (:attr:`BatchedPlatoon.live`), the other slots are inert
(zero observation, reward and violation mask; their actions are ignored, never checked).

With ``auto_reset=True`` an env whose episode ended is reset within the same :meth:`step`: its
row of the returned observations is the first observation of the next episode, and
``info["final_observation"]`` (present when some env ended) holds the last one of the ended
episode (rows of other envs are unspecified); ``info["reset"]`` marks those envs. Its RNG
continues (no reseeding). Without it, an ended env must be reset before it is stepped again,
or left out of the step: ``step(actions, envs=...)`` steps only the envs given and leaves the
others exactly as they are (e.g. a batch of evaluation episodes of different lengths, each env
stepped until its own episode ends; :mod:`experiments.batched_eval`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from platoon_env.core import CoreSnapshot, PlatoonCore
from platoon_env.observation import action_space, observation_space
from platoon_env.realism import drawn_keys, realism_table
from platoon_env.scenarios.scenario import Scenario
from platoon_env.scenarios.source import SourceLike, scenario_source

__all__ = ["BatchedPlatoon", "CopyView"]


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
        ValueError: for a non-positive batch size or thread count.
    """

    def __init__(
        self,
        scenario: SourceLike = "study_c",
        batch_size: int = 1,
        *,
        n_threads: int = 1,
        auto_reset: bool = False,
        grid_cell_size: float | None = None,
        **overrides: Any,
    ) -> None:
        self.source = scenario_source(scenario, overrides, where="BatchedPlatoon()")
        self._core = core = PlatoonCore(self.source, batch_size, grid_cell_size=grid_cell_size)
        cfg = core.config
        self.batch_size = core.batch_size
        #: ``N``: the follower slots of every env (a drawn formation's most followers).
        self.n_followers = core.n_followers
        self.possible_agents: list[str] = [f"follower_{i}" for i in range(1, core.n_followers + 1)]
        #: Per-follower spaces (the env's, built from the same config).
        self.single_observation_space: spaces.Box = observation_space(cfg)
        self.single_action_space: spaces.Box = action_space(cfg)
        self.control_period = cfg.simulation.control_period
        self.physics_substeps = cfg.simulation.physics_substeps
        self.terminate_on = frozenset(cfg.safety.terminate_on)
        if not isinstance(auto_reset, bool | np.bool_):
            raise TypeError(f"auto_reset must be True or False, got {auto_reset!r}")
        self.auto_reset = bool(auto_reset)
        #: No rendering in the batched core (SB3's VecEnv reads this attribute).
        self.render_mode: str | None = None
        core.set_threads(n_threads)
        #: Envs that need a reset before they can step (all, until the first reset).
        self._finished = np.ones(self.batch_size, dtype=bool)
        self._needs_reset = True

    # ----------------------------------------------------------------------------------------
    # Configuration
    # ----------------------------------------------------------------------------------------
    @property
    def n_threads(self) -> int:
        """numba threads stepping the envs (1: a serial loop)."""
        return self._core.n_threads

    def set_threads(self, n_threads: int) -> None:
        """Use ``n_threads`` numba threads in :meth:`step` (1: a serial loop)."""
        self._core.set_threads(n_threads)

    @property
    def scenario(self) -> Scenario:
        """Env 0's current scenario (all envs' for a fixed source)."""
        return self._core.scenarios[0]

    @property
    def scenarios(self) -> list[Scenario]:
        """Each env's current scenario (a procedural source draws one per episode)."""
        return list(self._core.scenarios)

    @property
    def max_episode_steps(self) -> int:
        """Env 0's step limit (a procedural layout sets its own)."""
        return int(self._core.params[0]["max_episode_steps"])

    @property
    def step_limits(self) -> np.ndarray:
        """``(B,)`` int64: each env's step limit of its current episode (``max_episode_steps``;
        a procedural layout sets its own, drawn at reset): the env truncates its episode when
        it has taken that many steps. A copy."""
        return self._core.params["max_episode_steps"].astype(np.int64)

    # ----------------------------------------------------------------------------------------
    # State (copies)
    # ----------------------------------------------------------------------------------------
    @property
    def poses(self) -> np.ndarray:
        """Ground-truth poses ``(B, N+1, 3)``, leader first (a copy)."""
        return self._core.poses.copy()

    @property
    def sensed(self) -> np.ndarray:
        """Ground-truth sensing ``(B, N, SENSE_SIZE)`` of the last step (a copy)."""
        return self._core.sensed.copy()

    @property
    def applied_velocities(self) -> np.ndarray:
        """The velocities ``[u, omega]`` ``(B, N, 2)`` each follower's actuators applied in the
        last step (the commands through ``lag``, ``accel_max``, ``alpha_max``; as the env's
        :attr:`~platoon_env.env.PlatoonParallelEnv.applied_velocities`). A copy."""
        return self._core.applied.copy()

    @property
    def reward_terms(self) -> np.ndarray:
        """Reward terms ``(B, N, len(REWARD_TERMS))`` of the last step (a copy)."""
        return self._core.terms.copy()

    @property
    def sim_time(self) -> np.ndarray:
        """Simulated time [s] of each env's episode (a copy)."""
        return self._core.episode["sim_time"].copy()

    @property
    def steps(self) -> np.ndarray:
        """Steps taken in each env's episode (a copy)."""
        return self._core.episode["steps"].copy()

    @property
    def leader_arrived(self) -> np.ndarray:
        """Whether each env's leader has reached its path's end."""
        return self._core.episode["leader_arrived"].copy()

    @property
    def leader_velocity(self) -> np.ndarray:
        """Each env's leader ``[u, omega]`` ``(B, 2)`` in the last physics sub-step (as the
        env's :attr:`~platoon_env.env.PlatoonParallelEnv.leader_velocity`)."""
        ep = self._core.episode
        return np.stack([ep["leader_u"], ep["leader_omega"]], axis=1)

    @property
    def leader_speed_factor(self) -> np.ndarray:
        """Each env's leader speed factor ``f`` of this episode ``(B,)`` (1 without
        ``leader.speed_variation``)."""
        return self._core.episode["leader_speed_factor"].copy()

    @property
    def live(self) -> np.ndarray:
        """``(B, N)`` bool: which follower slots of each env are live in its current episode
        (all, unless the scenario draws its formation with fewer followers than ``N``; the
        rest are inert: zero observation, reward and violation, never moved). A copy."""
        return self._core.live.copy()

    @property
    def n_active(self) -> np.ndarray:
        """``(B,)`` int64: each env's followers in its current episode (``live.sum(1)``)."""
        return self._core.params["n_followers"].copy()

    @property
    def variable_followers(self) -> bool:
        """Whether envs may have fewer followers than ``N`` (``generator.formation.followers``
        is a range): then read :attr:`live`."""
        return self._core.variable

    @property
    def realism_keys(self) -> tuple[str, ...]:
        """The realism fields each episode draws (the scenario's ``realism`` block, in draw
        order; empty without one), the columns of :attr:`realism`."""
        return drawn_keys(self._core.config)

    @property
    def realism(self) -> np.ndarray:
        """Each env's realism of this episode ``(B, len(realism_keys))`` float64, in the
        schema's units (:func:`platoon_env.realism.reported_values`; ``docs/realism.md``)."""
        return realism_table(self._core.params, self._core.config)[1]

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
        """Start new episodes; returns the observations ``(B, N, K)`` of every env (a copy).

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
        self._reset_envs(idx, seed_list, perturb)
        return self._core.obs.copy()

    def step(
        self, actions: np.ndarray, *, envs: Sequence[int] | np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every env (or the ``envs`` given) by one control period.

        Args:
            actions: ``(B, N, 2)`` ``[u, omega]``; clipped to the action Box. NaN or inf raise
                ``ValueError`` (naming env and agent) before any state changes. Only the rows
                of the stepped envs are read.
            envs: the envs to step, a ``(B,)`` bool mask or indices (default: all). The others
                are left exactly as they are (state, RNG, step count; an env whose episode
                ended may stay unstepped without a reset): their rows of the returned arrays
                are their values after their own last step (or reset), ``terminated`` and
                ``truncated`` included. With ``auto_reset``, only stepped envs are reset.

        Returns:
            ``(observations (B, N, K), rewards (B, N), terminated (B,), truncated (B,), info)``
            (fresh arrays), ``info`` as in the module docstring.

        Raises:
            RuntimeError: a stepped env's episode ended and it was not reset (without
                ``auto_reset``).
        """
        core = self._core
        act = np.asarray(actions)
        if act.shape != core.actions.shape:
            raise ValueError(
                f"actions must have shape {core.actions.shape} (B, N, [u, omega]), got {act.shape}"
            )
        active = None if envs is None else self._env_mask(envs)
        if self._needs_reset:
            stale = self._finished if active is None else self._finished & active
            bad = np.flatnonzero(stale)
            if bad.size:
                raise RuntimeError(
                    f"env(s) {bad[:10].tolist()} finished their episode; call reset() first "
                    "(or construct with auto_reset=True)"
                )
        if not np.issubdtype(act.dtype, np.number) or np.iscomplexobj(act):
            raise TypeError(f"actions must be real numbers, got dtype {act.dtype}")
        previous = core.actions.copy()
        if active is None:
            np.copyto(core.actions, act)
        else:
            np.copyto(core.actions, act, where=active[:, None, None])
        n_ended = core.run(active, self.physics_substeps)
        if n_ended < 0:
            np.copyto(core.actions, previous)
            b, i = divmod(-1 - n_ended, self.n_followers)
            raise ValueError(
                f"action of env {b}, {self.possible_agents[i]!r} contains NaN or inf: "
                f"{act[b, i].tolist()}"
            )
        episode = core.episode
        terminated = episode["terminated"].copy()
        truncated = episode["truncated"].copy()
        info: dict[str, np.ndarray] = {
            "violations": core.violations.copy(),
            "substeps": episode["substeps"].copy(),
        }
        rewards = core.rewards.copy()
        if n_ended:
            ended = terminated | truncated
            if active is not None:
                ended &= active
            if self.auto_reset:
                info["final_observation"] = core.obs.copy()
                idx = np.flatnonzero(ended)
                self._reset_envs(idx, [None] * len(idx), None)
            else:
                self._finished |= ended
                self._needs_reset = True
        if self.auto_reset:
            info["reset"] = terminated | truncated
            if active is not None:
                info["reset"] &= active
        return core.obs.copy(), rewards, terminated, truncated, info

    def snapshot(self, env: int = 0) -> CoreSnapshot:
        """Env ``env``'s whole state now (:class:`~platoon_env.core.CoreSnapshot`): restored
        into any env of a ``BatchedPlatoon`` or ``PlatoonParallelEnv`` of the same scenario
        (:meth:`restore`), it continues exactly as ``env`` does, fed the same actions."""
        return self._core.snapshot(env)

    def restore(
        self, snapshot: CoreSnapshot, envs: Sequence[int] | np.ndarray | None = None
    ) -> np.ndarray:
        """Put ``snapshot`` (:meth:`snapshot`) into each of ``envs`` (a ``(B,)`` bool mask or
        indices; default: all): e.g. ``B`` copies of one moment of an episode, to try ``B``
        action sequences from it (:mod:`baselines.oracle`). A snapshot of an ended episode
        leaves those envs needing a reset, as the original. Returns the observations
        ``(B, N, K)`` (a copy)."""
        mask = np.ones(self.batch_size, dtype=bool) if envs is None else self._env_mask(envs)
        for b in np.flatnonzero(mask).tolist():
            self._core.restore(b, snapshot)
        self._finished[mask] = snapshot.ended
        self._needs_reset = bool(self._finished.any())
        return self._core.obs.copy()

    # ----------------------------------------------------------------------------------------
    # Internals
    # ----------------------------------------------------------------------------------------
    def _env_mask(self, envs: Sequence[int] | np.ndarray) -> np.ndarray:
        """``envs`` (a ``(B,)`` bool mask or indices) as a fresh ``(B,)`` bool mask."""
        given = np.asarray(envs)
        if given.dtype == bool:
            if given.shape != (self.batch_size,):
                raise ValueError(
                    f"an envs mask must have shape ({self.batch_size},), got {given.shape}"
                )
            return given.copy()
        if given.size and not np.issubdtype(given.dtype, np.integer):
            raise ValueError(f"envs must be a bool mask or indices, got {envs}")
        idx = given.astype(np.int64)
        if idx.ndim != 1 or np.any(idx < 0) or np.any(idx >= self.batch_size):
            raise ValueError(f"envs must be indices in [0, {self.batch_size}), got {envs}")
        mask = np.zeros(self.batch_size, dtype=bool)
        mask[idx] = True
        return mask

    def _reset_envs(self, idx: np.ndarray, seeds: list[int | None], perturb: bool | None) -> None:
        core = self._core
        for b, seed in zip(idx.tolist(), seeds, strict=True):
            core.reset_env(b, seed, perturb=perturb)
        self._finished[idx] = False
        self._needs_reset = bool(self._finished.any())
        active = np.zeros(self.batch_size, dtype=bool)
        active[idx] = True
        core.run(active, 0)

    def copy_view(self, index: int, env: Any) -> CopyView:
        """Copy ``index`` seen as a :class:`~platoon_env.env.PlatoonParallelEnv`
        (:class:`CopyView`): what an episode changes is the copy's, everything else ``env``'s
        (a ``platoon_env.make`` env of the same scenario and keywords, never reset)."""
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise TypeError(f"index must be an integer, got {index!r}")
        if not 0 <= index < self.batch_size:
            raise ValueError(f"index must be in [0, {self.batch_size}), got {index}")
        return CopyView(env, self, int(index))

    def __repr__(self) -> str:
        return (
            f"BatchedPlatoon({self.scenario.name!r}, batch_size={self.batch_size}, "
            f"followers={self.n_followers}, n_threads={self.n_threads}, "
            f"auto_reset={self.auto_reset})"
        )


class CopyView:
    """Copy ``index`` of a :class:`BatchedPlatoon` seen as the
    :class:`~platoon_env.env.PlatoonParallelEnv` a policy is built on and reset with
    (:meth:`BatchedPlatoon.copy_view`; the batched evaluator, :mod:`experiments.batched_eval`,
    builds one policy per copy on these).

    What an episode changes is copy ``index``'s: :attr:`scenario` (its current layout),
    :attr:`layout_index`, :attr:`agents` (none until :meth:`start`, as an env before its
    reset), :attr:`max_episode_steps`, :attr:`np_random`, :attr:`sim_time`, :attr:`steps`,
    :attr:`poses`, :attr:`sensed`, :attr:`violation_masks`, :attr:`leader_arrived`,
    :attr:`leader_speed_factor`, :attr:`applied_velocities`, :meth:`snapshot`. Every other
    attribute is ``env``'s: an env of the same scenario and ``make()`` keywords, never reset
    (its spaces, source, control period).

    The fast learner's experts are built on :class:`training.experts.ExpertEnv` instead: the
    three fields a law reads at construction, fixed for one episode of a copy whose formation
    no one made env fits.
    """

    def __init__(self, env: Any, core: BatchedPlatoon, index: int) -> None:
        self._env = env
        self._core = core
        self._index = index
        self._started = False

    def __getattr__(self, name: str) -> Any:
        return getattr(self._env, name)

    def start(self) -> None:
        """The copy's episode began (it was reset): :attr:`agents` are its followers."""
        self._started = True

    @property
    def scenario(self) -> Any:
        """The copy's current scenario (a procedural source: the layout its reset drew)."""
        return self._core.scenarios[self._index]

    @property
    def layout_index(self) -> int | None:
        """The copy's procedural layout number (None for a fixed workspace)."""
        return self.scenario.layout_index if self._core.source.procedural else None

    @property
    def agents(self) -> list[str]:
        """The copy's live followers (none before its first reset)."""
        if not self._started:
            return []
        return list(self._core.possible_agents[: int(self._core.n_active[self._index])])

    @property
    def max_episode_steps(self) -> int:
        """The copy's step limit of its current episode."""
        return int(self._core.step_limits[self._index])

    @property
    def np_random(self) -> np.random.Generator:
        """The copy's own RNG."""
        rng: np.random.Generator = self._core._core.rngs[self._index]
        return rng

    @property
    def sim_time(self) -> float:
        """The copy's simulated time [s]."""
        return float(self._core.sim_time[self._index])

    @property
    def steps(self) -> int:
        """Steps taken in the copy's episode."""
        return int(self._core.steps[self._index])

    @property
    def poses(self) -> np.ndarray:
        """The copy's ground-truth poses ``(N+1, 3)`` (a copy)."""
        out: np.ndarray = self._core.poses[self._index]
        return out

    @property
    def sensed(self) -> np.ndarray:
        """The copy's ground-truth sensing ``(N, 9)`` of its last step (a copy)."""
        out: np.ndarray = self._core.sensed[self._index]
        return out

    @property
    def applied_velocities(self) -> np.ndarray:
        """The copy's applied ``[u, omega]`` ``(n, 2)`` of its last step (a copy)."""
        out: np.ndarray = self._core.applied_velocities[self._index, : len(self.agents)]
        return out

    def snapshot(self) -> Any:
        """The copy's whole state (:meth:`~platoon_env.batched.BatchedPlatoon.snapshot`): what
        the privileged oracle (:mod:`baselines.oracle`) plans from."""
        return self._core.snapshot(self._index)

    @property
    def violation_masks(self) -> np.ndarray:
        """The copy's violation bit masks ``(N,)`` of its last step (a copy)."""
        return self._core._core.violations[self._index].copy()  # type: ignore[no-any-return]

    @property
    def leader_arrived(self) -> bool:
        """Whether the copy's leader has reached its path's end."""
        return bool(self._core.leader_arrived[self._index])

    @property
    def leader_speed_factor(self) -> float:
        """The copy's leader speed factor of this episode."""
        return float(self._core.leader_speed_factor[self._index])
