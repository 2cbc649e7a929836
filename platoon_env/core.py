"""The one simulation core: the state of ``B`` envs, their maps, RNGs and resets.

:class:`PlatoonCore` owns every array the compiled step (:mod:`platoon_env.simulator`) reads and
writes — the records of :mod:`platoon_env.records` — and does what compiled code cannot: drawing
each env's scenario from its :class:`~platoon_env.scenarios.source.ScenarioSource` and its
initial configuration from its own seeded RNG, writing new maps into the map bank. The
PettingZoo env (:class:`platoon_env.env.PlatoonParallelEnv`) is this core at ``B = 1`` plus
dict I/O, infos and rendering; :class:`platoon_env.batched.BatchedPlatoon` is the same core at
``B > 1`` with array I/O. Neither restates an episode rule.

Task-aware observations (``observation.task_aware``, :mod:`platoon_env.observation`) are this
core's too, in NumPy around the compiled step: the compiled kernels write the first
:data:`~platoon_env.observation.OBS_SIZE` columns of each observation row, the core the task
features (once per scenario, :meth:`PlatoonCore._install`) and ``t_unseen`` (after every call,
:meth:`PlatoonCore.observe_task`); without the option nothing of this runs.

Map slots: a fixed scenario's ``B`` envs share slot 0; a procedural source gives every env a
slot of its own, rewritten when the env draws a new layout. Slots are padded to the largest map
seen so far (the arrays grow when a bigger layout arrives).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from gymnasium.utils import seeding

from platoon_env.config import realism_values, stage_flags
from platoon_env.dynamics.actuators import lag_gain
from platoon_env.dynamics.leader import trajectory_velocities
from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.primitives import wrap_angle
from platoon_env.geometry.sensing import SENSE_SIZE
from platoon_env.initial import InitialSampler
from platoon_env.observation import (
    ACT_SIZE,
    OBS_D_DES,
    OBS_RADIUS,
    OBS_T_UNSEEN,
    OBS_VISIBLE,
    UNSEEN_HORIZON,
    action_space,
    observation_size,
    task_features,
)
from platoon_env.realism import draw_realism, max_latency_steps
from platoon_env.records import (
    FRAME_SIZE,
    MAP_INFO_DTYPE,
    PARAMS_DTYPE,
    PATH_SIZE,
    PATH_T,
    PATH_THETA,
    PATH_X,
    PATH_Y,
    Buffers,
    constraint_params,
    new_episode,
)
from platoon_env.reward import REWARD_TERMS
from platoon_env.safety import causes_to_mask
from platoon_env.scenarios.fingerprint import config_fingerprint
from platoon_env.scenarios.scenario import Scenario
from platoon_env.scenarios.schema import (
    ScenarioConfig,
    ScenarioError,
    latency_steps,
    trajectory_route,
)
from platoon_env.scenarios.source import ScenarioSource
from platoon_env.simulator import step_parallel, step_serial


def compiled_entry(dispatcher: Any, args: tuple[Any, ...]) -> Any:
    """The compiled function that ``dispatcher`` runs for arguments of exactly the types of
    ``args``, called without numba's per-call type resolution (about 0.9 µs of the single env's
    step, measured). Only for arguments that keep these types on every call (the env's own
    arrays); the dispatcher itself when numba does not expose the compiled entry.
    """
    try:
        signature = tuple(dispatcher.typeof_pyval(a) for a in args)
        if signature not in dispatcher.overloads:
            dispatcher.compile(signature)
        return dispatcher.overloads[signature].entry_point
    except (AttributeError, KeyError, TypeError):
        return dispatcher


def params_of(cfg: ScenarioConfig, max_episode_steps: int) -> np.void:
    """The :data:`~platoon_env.records.PARAMS_DTYPE` record of a scenario's config.

    ``max_episode_steps`` is the scenario's resolved step limit (``Scenario.max_episode_steps``).
    """
    p = constraint_params(cfg)[0]
    # Actuator limits exactly as the float32 action Box holds them.
    space = action_space(cfg)
    p["u_low"], p["omega_low"] = space.low.astype(np.float64)
    p["u_high"], p["omega_high"] = space.high.astype(np.float64)
    p["terminate_mask"] = causes_to_mask(cfg.safety.terminate_on)
    p["leader_replay"] = bool(cfg.leader.trajectory)
    p["leader_speed"] = cfg.leader.speed
    p["leader_speed_bound"] = cfg.leader.speed
    if cfg.leader.trajectory:
        # The replayed leader is never faster than its fastest segment.
        u, _ = trajectory_velocities(trajectory_route(cfg.leader.trajectory))
        p["leader_speed_bound"] = float(np.max(np.abs(u)))
    p["lookahead"] = cfg.leader.lookahead
    p["leader_turn_rate"] = cfg.leader.max_turn_rate
    # A pure-pursuit leader that keeps the robots' drive (leader.drive): its rate limits.
    rob = cfg.robot
    limited = cfg.leader.drive != "free" and not cfg.leader.trajectory
    limited = limited and (rob.accel_max is not None or rob.alpha_max is not None)
    p["leader_rate_limited"] = limited
    # (inf unless limited: the records of a free leader do not depend on the robot's drive)
    p["leader_accel"] = math.inf if not limited or rob.accel_max is None else rob.accel_max
    p["leader_alpha"] = math.inf if not limited or rob.alpha_max is None else rob.alpha_max
    p["d_des"] = cfg.formation.d_des
    # The distance error is normalised by d_con - d_des, the bearing error by beta_con.
    p["reward_d_scale"] = cfg.camera.range - cfg.formation.d_des
    p["wall_margin"] = cfg.reward.wall_margin
    for term in REWARD_TERMS:
        p[f"w_{term}"] = getattr(cfg.reward, term)
    dt = cfg.simulation.control_period
    p["control_period"] = dt
    p["substep"] = dt / cfg.simulation.physics_substeps
    p["physics_substeps"] = cfg.simulation.physics_substeps
    p["max_episode_steps"] = max_episode_steps
    p["settle_time"] = cfg.leader.settle_time
    cam, rob = cfg.camera, cfg.robot
    p["noise_position"] = cam.noise.position
    p["noise_position_per_m"] = cam.noise.position_per_m
    p["noise_bearing"] = cam.noise.bearing
    p["detection"] = cam.detection
    p["detection_edge"] = cam.detection_edge
    p["frame_period"] = 0.0 if cam.frame_rate is None else 1.0 / cam.frame_rate
    p["latency_steps"] = latency_steps(cfg)
    p["proximity_noise"] = cfg.proximity.noise
    flags = stage_flags(realism_values(cfg), rob.lag)
    p["random_perception"], p["perceive"] = flags.random_perception, flags.perceive
    p["lag_gain"] = lag_gain(rob.lag, dt)
    p["accel_max"] = math.inf if rob.accel_max is None else rob.accel_max
    p["alpha_max"] = math.inf if rob.alpha_max is None else rob.alpha_max
    p["actuate"] = flags.actuate
    p["scale_free"] = cfg.observation.scale_free
    p["n_followers"] = cfg.followers
    return p


#: The per-env rows of :class:`PlatoonCore` that a :class:`CoreSnapshot` copies (row ``b`` of
#: each): the buffers, the perception frames, the ``t_unseen`` counts and the live slots.
_SNAPSHOT_ROWS = (
    "poses",
    "actions",
    "applied",
    "violations",
    "sensed",
    "obs",
    "terms",
    "rewards",
    "frames",
    "unseen",
    "live",
)


@dataclass(frozen=True, eq=False)
class CoreSnapshot:
    """One env's whole state at one moment (:meth:`PlatoonCore.snapshot`): what
    :meth:`PlatoonCore.restore` writes back into any env of a core of the same source, so that
    planners (the privileged oracle, :mod:`baselines.oracle`) and curricula can branch from any
    moment of an episode.

    Attributes:
        scenario: the env's scenario (the object, shared, not copied: scenarios are immutable).
        params: ``(1,)`` :data:`~platoon_env.records.PARAMS_DTYPE`, the env's parameters.
        episode: ``(1,)`` :data:`~platoon_env.records.EPISODE_DTYPE`: the leader's progress,
            speed factor and last velocity, time, steps, arrival, the last step's outcome and
            the perception noise stream's state (its map slot is the restoring env's own).
        rows: the env's row of each array in :data:`_SNAPSHOT_ROWS` (poses, commands, applied
            velocities, violation masks, ground-truth sensing, observations, reward terms and
            rewards, camera frames in flight, ``t_unseen`` counts, live follower slots).
        rng_state: the state of the env's RNG (``bit_generator.state``).
        realism: the realism drawn at the episode's reset.
    """

    scenario: Scenario
    params: np.ndarray
    episode: np.ndarray
    rows: dict[str, np.ndarray]
    rng_state: dict[str, Any]
    realism: dict[str, float]

    @property
    def ended(self) -> bool:
        """Whether the episode had ended (terminated or truncated) at the snapshot."""
        ep = self.episode[0]
        return bool(ep["terminated"] or ep["truncated"])

    @property
    def sim_time(self) -> float:
        """[s] The episode's time at the snapshot."""
        return float(self.episode[0]["sim_time"])


class _MapSlots:
    """The padded arrays of a :class:`~platoon_env.records.MapBank` and the writes into them."""

    def __init__(self, n_slots: int) -> None:
        self.n_slots = n_slots
        self.info = np.zeros(n_slots, dtype=MAP_INFO_DTYPE)
        self._alloc(edges=1, cells=1, cell_edges=1, path=2)

    def _alloc(self, edges: int, cells: int, cell_edges: int, path: int) -> None:
        m = self.n_slots
        old = getattr(self, "arrays", None)
        self.edges = np.zeros((m, edges, 4))
        self.boxes = np.zeros((m, edges, 4))
        self.cell_start = np.zeros((m, cells + 1), dtype=np.int64)
        self.cell_edges = np.zeros((m, cell_edges), dtype=np.int64)
        self.edge_cell = np.zeros((m, edges, 2), dtype=np.int64)
        self.path = np.zeros((m, path, PATH_SIZE))
        self.path_s = np.zeros((m, path))
        if old is not None:  # keep the slots already written
            for new, prev in zip(self._fields(), old[1:], strict=True):
                new[tuple(slice(0, k) for k in prev.shape)] = prev
        #: What the compiled step takes: the info records as bytes, then the padded arrays.
        self.arrays: tuple[np.ndarray, ...] = (self.info.view(np.uint8), *self._fields())

    def _fields(self) -> tuple[np.ndarray, ...]:
        return (
            self.edges,
            self.boxes,
            self.cell_start,
            self.cell_edges,
            self.edge_cell,
            self.path,
            self.path_s,
        )

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        # A view unpickles as a copy: the byte view of the info must alias it again.
        self.arrays = (self.info.view(np.uint8), *self._fields())

    def write(self, slot: int, scenario: Scenario, grid: EdgeGrid) -> None:
        """Put ``scenario``'s boundary edges, edge grid and leader route (its path, and a timed
        trajectory's sample times and headings) into ``slot``."""
        walls = grid.walls
        n_e = walls.edges.shape[0]
        n_c = walls.cell_start.shape[0] - 1
        n_k = walls.cell_edges.shape[0]
        n_p = scenario.leader_path.shape[0]
        need = (n_e, n_c, n_k, n_p)
        have = (
            self.edges.shape[1],
            self.cell_start.shape[1] - 1,
            self.cell_edges.shape[1],
            self.path.shape[1],
        )
        if any(n > h for n, h in zip(need, have, strict=True)):
            # Grow by half again, so that a stream of procedural layouts reallocates rarely.
            sizes = [max(h, n + n // 2) if n > h else h for n, h in zip(need, have, strict=True)]
            self._alloc(*sizes)
        info = self.info[slot]
        info["n_edges"], info["n_cells"], info["n_cell_edges"], info["n_path"] = need
        for name in ("x0", "y0", "inv_cell", "nx", "ny"):
            info[name] = walls.grid[name]
        self.edges[slot, :n_e] = walls.edges
        self.boxes[slot, :n_e] = walls.boxes
        self.cell_start[slot, : n_c + 1] = walls.cell_start
        self.cell_edges[slot, :n_k] = walls.cell_edges
        self.edge_cell[slot, :n_e] = walls.edge_cell
        self.path[slot, :n_p, PATH_X : PATH_Y + 1] = scenario.leader_path
        self.path_s[slot, :n_p] = scenario.path_s
        timed = scenario.leader_times is not None and scenario.leader_headings is not None
        self.path[slot, :n_p, PATH_T] = scenario.leader_times if timed else 0.0
        self.path[slot, :n_p, PATH_THETA] = scenario.leader_headings if timed else 0.0


class PlatoonCore:
    """``batch_size`` envs of one scenario source: their state, maps and RNGs.

    Args:
        source: where each env's scenario comes from (fixed, or a procedural generator).
        batch_size: number of envs ``B``.
        grid_cell_size: side [m] of the edge grid's cells (None: half the proximity range; 0:
            one cell, no culling). Results do not depend on it.

    Attributes (arrays shared with the compiled core; read them, do not replace them):
        params: ``(B,)`` :data:`~platoon_env.records.PARAMS_DTYPE`; episode: ``(B,)``
        :data:`~platoon_env.records.EPISODE_DTYPE`; poses, actions, violations, sensed, obs,
        terms, rewards: the per-follower arrays of :class:`~platoon_env.records.Buffers`
        (``obs`` has :func:`~platoon_env.observation.observation_size` columns);
        rngs: each env's ``numpy.random.Generator``; scenarios: each env's current scenario;
        task_aware: ``observation.task_aware``; live: ``(B, N)`` bool, each env's live
        follower slots (all, unless a drawn formation has fewer than ``N``); variable: whether
        they may differ; unseen: ``(B, N)`` int64, the control steps
        since each follower last perceived its predecessor (kept only when task-aware).
    """

    def __init__(
        self, source: ScenarioSource, batch_size: int = 1, *, grid_cell_size: float | None = None
    ) -> None:
        if isinstance(batch_size, bool) or not isinstance(batch_size, int | np.integer):
            raise TypeError(f"batch_size must be an integer, got {batch_size!r}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        if grid_cell_size is not None and not math.isfinite(grid_cell_size):
            raise ValueError(f"grid_cell_size must be finite or None, got {grid_cell_size}")
        self.source = source
        self.batch_size = b = int(batch_size)
        self.grid_cell_size = grid_cell_size
        first = source.initial()
        cfg = first.config
        self.config: ScenarioConfig = cfg
        # The buffers hold the most followers any episode can have (a drawn formation:
        # generator.formation.followers' upper end); env b's own are params[b].n_followers.
        lo, hi = getattr(source, "followers_range", (cfg.followers, cfg.followers))
        self.n_followers = n = int(hi)
        #: Whether the envs' follower counts may differ from ``N`` (a drawn formation).
        self.variable = int(lo) != n
        self.physics_substeps = cfg.simulation.physics_substeps

        self.params = np.zeros(b, dtype=PARAMS_DTYPE)
        self.episode = new_episode(b)
        self._params_bytes = self.params.view(np.uint8)
        self._episode_bytes = self.episode.view(np.uint8)
        self.poses = np.zeros((b, n + 1, 3))
        self.actions = np.zeros((b, n, ACT_SIZE))
        self.applied = np.zeros((b, n, ACT_SIZE))
        self.violations = np.zeros((b, n), dtype=np.int64)
        self.sensed = np.zeros((b, n, SENSE_SIZE))
        self.obs = np.zeros((b, n, observation_size(cfg)), dtype=np.float32)
        self.task_aware = bool(cfg.observation.task_aware)
        self.unseen = np.zeros((b, n), dtype=np.int64)
        #: ``(B, N)`` bool: follower slot ``i`` of env ``b`` is live in its current episode.
        self.live = np.ones((b, n), dtype=bool)
        self._slot_index = np.arange(n)
        # Each env's control period over the horizon, a column: what t_unseen grows by per step.
        self._unseen_rate = np.zeros((b, 1))
        self._lost = np.zeros((b, n), dtype=bool)
        self._task_views()
        self.terms = np.zeros((b, n, len(REWARD_TERMS)))
        self.rewards = np.zeros((b, n))
        # The camera frames in flight: a ring of latency + 1 frames and the one last delivered.
        self.frames = np.zeros((b, n, max_latency_steps(cfg) + 2, FRAME_SIZE))
        self.buffers = tuple(
            Buffers(
                self.poses,
                self.actions,
                self.applied,
                self.violations,
                self.sensed,
                self.obs,
                self.terms,
                self.rewards,
                self.frames,
            )
        )
        self._slots = _MapSlots(b if source.procedural else 1)
        self.rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(b)]
        self.scenarios: list[Scenario] = [first] * b
        #: Each env's realism drawn at its last reset (``realism`` block; empty without).
        self.realism: list[dict[str, float]] = [{} for _ in range(b)]
        self._samplers: list[InitialSampler] = []
        sampler = self._install(0, first)
        self._samplers = [sampler] * b
        for k in range(1, b):
            if source.procedural:
                self._samplers[k] = self._install(k, first)
            else:
                self.params[k] = self.params[0]
                self._task_install(k, cfg)
        self.poses[:, : first.config.followers + 1] = first.initial_poses
        self._all = np.ones(b, dtype=bool)
        self.n_threads = 1

    # ----------------------------------------------------------------------------------------
    @property
    def maps(self) -> tuple[np.ndarray, ...]:
        """The :class:`~platoon_env.records.MapBank` arrays as the plain tuple the step takes."""
        return self._slots.arrays

    @property
    def step_args(self) -> tuple[Any, ...]:
        """The arguments of :func:`~platoon_env.simulator.step_serial` after ``active`` and
        ``n_substeps``: the records as bytes, the map bank and the buffers (why: the drivers'
        docstring, ``platoon_env.simulator._driver``)."""
        return (self._params_bytes, self._episode_bytes, self._slots.arrays, self.buffers)

    def set_threads(self, n_threads: int) -> None:
        """Use ``n_threads`` numba threads in :meth:`run` (1: a serial loop)."""
        limit = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
        if isinstance(n_threads, bool) or not isinstance(n_threads, int | np.integer):
            raise TypeError(f"n_threads must be an integer, got {n_threads!r}")
        if not 1 <= n_threads <= limit:
            raise ValueError(
                f"n_threads must be in [1, {limit}] (numba's thread pool; set the environment "
                f"variable NUMBA_NUM_THREADS before importing numba for more), got {n_threads}"
            )
        self.n_threads = int(n_threads)

    def _install(
        self,
        b: int,
        scenario: Scenario,
        grid: EdgeGrid | None = None,
        sampler: InitialSampler | None = None,
    ) -> InitialSampler:
        """Make ``scenario`` env ``b``'s: its map in the env's slot, its parameters. ``grid``
        and ``sampler``: the scenario's, when the caller built them already (a reset's
        candidate), else built here."""
        cfg = scenario.config
        if grid is None:
            grid = EdgeGrid.build(
                scenario.workspace.edges, self.grid_cell_size, reach=cfg.proximity_range
            )
        slot = b if self.source.procedural else 0
        self._slots.write(slot, scenario, grid)
        self.episode[b]["map_slot"] = slot
        self.params[b] = params_of(cfg, scenario.max_episode_steps)
        self.scenarios[b] = scenario
        self._live_install(b, cfg.followers)
        self._task_install(b, cfg)
        if sampler is not None:
            return sampler
        return InitialSampler(scenario, grid.walls, self.params[b : b + 1])

    def _live_install(self, b: int, n_live: int) -> None:
        """Env ``b``'s live followers: rows ``0 .. n_live - 1`` (:attr:`live`); the rows beyond
        (a drawn formation smaller than the buffers) are zeroed, and the compiled step never
        touches them (it reads ``params[b].n_followers``): no motion, no sensing, no
        violation, zero observation and reward."""
        self.live[b] = self._slot_index < n_live
        if n_live < self.n_followers:
            self.poses[b, n_live + 1 :] = 0.0
            # every per-follower buffer after the poses (which hold the leader's row too)
            for rows in (*self.buffers[1:], self.unseen):
                rows[b, n_live:] = 0

    def _task_install(self, b: int, cfg: ScenarioConfig) -> None:
        """Env ``b``'s task features (columns ``OBS_D_DES .. OBS_RADIUS`` of every follower's
        row, which the compiled kernels never write) and control period, when task-aware."""
        if self.task_aware:
            self.obs[b, : cfg.followers, OBS_D_DES : OBS_RADIUS + 1] = task_features(cfg)
            self._unseen_rate[b, 0] = cfg.simulation.control_period / UNSEEN_HORIZON

    def _task_views(self) -> None:
        """The ``visible`` and ``t_unseen`` columns of :attr:`obs` (views, for
        :meth:`observe_task`)."""
        self._visible = self.obs[:, :, OBS_VISIBLE]
        self._t_unseen = self.obs[:, :, OBS_T_UNSEEN] if self.task_aware else None

    def observe_task(self, active: np.ndarray | None, stepped: bool) -> None:
        """``t_unseen`` of the ``active`` envs (None: all) after a call of the compiled step:
        each follower's count of steps since it last perceived its predecessor (the perceived
        ``visible`` flag of its new observation) is reset to 0 where it did and grows by one
        where it did not; after a reset (``stepped`` False) it is 0 (the start counts as
        visible). The column is ``min(1, count * (control_period / UNSEEN_HORIZON))`` in
        float32 (:mod:`platoon_env.observation`). Only for a task-aware core.

        Few NumPy calls on preallocated arrays and views: this runs after every step.
        """
        unseen, t = self.unseen, self._t_unseen
        assert t is not None, "observe_task() of a core without task-aware observations"
        if active is None:
            if stepped:
                unseen += 1
                np.less_equal(self._visible, 0.0, out=self._lost)
                if self.variable:  # an inert follower never counts as unseen
                    np.logical_and(self._lost, self.live, out=self._lost)
                unseen *= self._lost
            else:
                unseen.fill(0)
            np.multiply(unseen, self._unseen_rate, out=t)
            np.minimum(t, 1.0, out=t)
            return
        if stepped:
            lost = self._visible[active] <= 0.0
            unseen[active] = (unseen[active] + 1) * (lost & self.live[active])
        else:
            unseen[active] = 0
        t[active] = np.minimum(unseen[active] * self._unseen_rate[active], 1.0)

    # ----------------------------------------------------------------------------------------
    def reset_env(
        self,
        b: int,
        seed: int | None = None,
        *,
        perturb: bool | None = None,
        poses: np.ndarray | None = None,
    ) -> None:
        """Start env ``b``'s next episode (the caller then senses it with :meth:`run`).

        ``seed`` reseeds the env's RNG; the scenario is drawn from the source, then the initial
        configuration: ``poses`` (validated against the constraints, else ``ScenarioError``; with
        a timed leader trajectory the leader's row must be its first sample), or the scenario's
        default one, perturbed unless ``perturb`` is False; then, with
        ``leader.speed_variation`` ``v > 0``, the episode's leader speed factor ``f = 1 + v
        U(-1, 1)`` (one draw; none without variation, so episodes draw exactly as before). A
        failed reset changes nothing (not even the RNG's state).
        """
        if seed is not None:
            rng = seeding.np_random(int(seed))[0]
        else:
            rng = self.rngs[b]
        state = rng.bit_generator.state
        try:
            if self.source.procedural:
                scenario = self.source.sample(rng)
            else:
                scenario = self.scenarios[b]
            sampler = self._samplers[b]
            grid = None
            if scenario is not self.scenarios[b]:
                # Build the candidate's sampler without touching env b's map slot yet.
                grid = EdgeGrid.build(
                    scenario.workspace.edges,
                    self.grid_cell_size,
                    reach=scenario.config.proximity_range,
                )
                sampler = InitialSampler(
                    scenario,
                    grid.walls,
                    np.array([params_of(scenario.config, scenario.max_episode_steps)]),
                )
            if poses is not None:
                start = np.array(poses, dtype=np.float64)
                shape = (scenario.config.followers + 1, 3)
                if start.shape != shape or not np.all(np.isfinite(start)):
                    raise ValueError(f"options['poses'] must be finite with shape {shape}")
                if scenario.leader_times is not None:
                    _check_replay_start(start, scenario)
                    start[0] = scenario.initial_poses[0]  # the sample, bit for bit
                problems = sampler.violations(start)
                if problems:
                    raise ScenarioError("initial poses are infeasible: " + "; ".join(problems))
            else:
                default = scenario.config.initial.perturb
                start = sampler.sample(rng, default if perturb is None else bool(perturb))
            variation = scenario.config.leader.speed_variation
            factor = 1.0
            if variation > 0.0:
                factor = 1.0 + variation * float(rng.uniform(-1.0, 1.0))
        except BaseException:
            rng.bit_generator.state = state
            raise
        self.rngs[b] = rng
        if scenario is not self.scenarios[b]:
            self._samplers[b] = self._install(b, scenario, grid, sampler)
        ep = self.episode[b]
        self.realism[b] = draw_realism(self.params[b], scenario.config, rng)  # none: no draw
        if self.params[b]["random_perception"]:
            # Drawn only with realism on, so that ideal episodes draw exactly as before.
            ep["noise_state"] = rng.integers(0, 2**63, dtype=np.uint64)
        self.poses[b, : start.shape[0]] = start
        ep["leader_progress"] = scenario.initial_progress
        ep["leader_arrived"] = False
        ep["leader_speed_factor"] = factor
        ep["leader_substeps"] = 0
        ep["leader_u"] = 0.0
        ep["leader_omega"] = 0.0
        ep["sim_time"] = 0.0
        ep["steps"] = 0
        ep["arrival_time"] = math.nan
        self.actions[b] = 0.0
        self.applied[b] = 0.0

    def run(self, active: np.ndarray | None, n_substeps: int) -> int:
        """Step (``n_substeps`` > 0) or sense (0) the ``active`` envs (None: all).

        Returns how many envs ended, or ``-1 - (b * N + i)`` for a NaN/inf action of follower
        ``i`` of env ``b`` (then nothing changed).
        """
        mask = self._all if active is None else active
        args = (mask, n_substeps, *self.step_args)
        # A reset's sensing (n_substeps = 0) of some envs runs serially: one env's sensing is
        # microseconds, and waking numba's thread pool after the Python of a reset (drawing a
        # layout) costs milliseconds. Results do not depend on the driver.
        if self.n_threads == 1 or self.batch_size == 1 or (active is not None and not n_substeps):
            ended = int(step_serial(*args))
        else:
            previous = numba.get_num_threads()
            numba.set_num_threads(self.n_threads)
            try:
                ended = int(step_parallel(*args))
            finally:
                numba.set_num_threads(previous)
        return self.after_step(active, n_substeps, ended)

    def after_step(self, active: np.ndarray | None, n_substeps: int, ended: int) -> int:
        """The core's rule after every call of the compiled step on the ``active`` envs (None:
        all), whoever made it (:meth:`run`, or the env calling its compiled entry directly):
        unless the call was refused (``ended < 0``: nothing changed), a task-aware core's
        ``t_unseen`` (:meth:`observe_task`; ``n_substeps = 0``: a reset). Returns ``ended``.
        """
        if self.task_aware and ended >= 0:
            self.observe_task(active, n_substeps > 0)
        return ended

    # ----------------------------------------------------------------------------------------
    def snapshot(self, b: int) -> CoreSnapshot:
        """Env ``b``'s whole state at this moment (:class:`CoreSnapshot`, a deep copy): restored
        into any env of a core of the same scenario source (:meth:`restore`), it continues
        exactly as env ``b`` does from here, bit for bit, fed the same actions."""
        b = self._check_env(b)
        return CoreSnapshot(
            scenario=self.scenarios[b],
            params=self.params[b : b + 1].copy(),
            episode=self.episode[b : b + 1].copy(),
            rows={name: getattr(self, name)[b].copy() for name in _SNAPSHOT_ROWS},
            rng_state=copy.deepcopy(dict(self.rngs[b].bit_generator.state)),
            realism=dict(self.realism[b]),
        )

    def restore(self, b: int, snap: CoreSnapshot) -> None:
        """Make env ``b``'s state ``snap``'s (:meth:`snapshot`, of this core or another of the
        same scenario source): its scenario (a procedural env installs the snapshot's layout in
        its own map slot), parameters, episode record, per-follower buffers, perception frames,
        ``t_unseen`` counts and its RNG (a fresh generator in the snapshot's state: the copies
        never share one). ``ValueError`` for a snapshot of another scenario source or buffer
        shape; nothing changes then."""
        b = self._check_env(b)
        if not isinstance(snap, CoreSnapshot):
            raise TypeError(f"restore() takes a CoreSnapshot, got {type(snap).__name__}")
        for name in _SNAPSHOT_ROWS:
            have, got = getattr(self, name)[b].shape, snap.rows[name].shape
            if have != got:
                raise ValueError(
                    f"snapshot does not fit this core: its {name} row has shape {got}, this "
                    f"core's {have} (another scenario, formation or realism)"
                )
        if snap.scenario is not self.scenarios[b]:
            if self.source.procedural:
                self._samplers[b] = self._install(b, snap.scenario)
            elif config_fingerprint(snap.scenario.config) != config_fingerprint(
                self.scenarios[b].config
            ):
                raise ValueError(
                    f"snapshot of scenario {snap.scenario.name!r} cannot be restored into a "
                    f"core of scenario {self.scenarios[b].name!r} (fingerprints differ)"
                )
        slot = self.episode[b]["map_slot"]
        self.params[b] = snap.params[0]
        self.episode[b] = snap.episode[0]
        self.episode[b]["map_slot"] = slot
        for name in _SNAPSHOT_ROWS:
            getattr(self, name)[b] = snap.rows[name]
        rng = np.random.Generator(type(self.rngs[b].bit_generator)())
        rng.bit_generator.state = copy.deepcopy(snap.rng_state)
        self.rngs[b] = rng
        self.realism[b] = dict(snap.realism)

    def _check_env(self, b: Any) -> int:
        if isinstance(b, bool) or not isinstance(b, int | np.integer):
            raise TypeError(f"env index must be an integer, got {b!r}")
        if not 0 <= b < self.batch_size:
            raise ValueError(f"env index must be in [0, {self.batch_size}), got {b}")
        return int(b)

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        # Views unpickle as copies: the byte views must alias the records again.
        self._params_bytes = self.params.view(np.uint8)
        self._episode_bytes = self.episode.view(np.uint8)
        self._task_views()


#: [m, rad] How far a given start's leader row may be from a timed trajectory's first sample.
REPLAY_START_TOLERANCE = 1e-9


def _check_replay_start(start: np.ndarray, scenario: Scenario) -> None:
    """A given start of a timed leader trajectory must put the leader at its first sample (the
    replay drives it from there at once); ``ScenarioError`` otherwise."""
    first = scenario.initial_poses[0]
    gap = math.hypot(start[0, 0] - first[0], start[0, 1] - first[1])
    turn = abs(wrap_angle(float(start[0, 2] - first[2])))
    if gap > REPLAY_START_TOLERANCE or turn > REPLAY_START_TOLERANCE:
        raise ScenarioError(
            "initial poses are infeasible: leader: with a timed trajectory the leader starts "
            f"at its first sample {np.asarray(first).tolist()} (scenario.leader.trajectory[0]), "
            f"got {start[0].tolist()}"
        )
