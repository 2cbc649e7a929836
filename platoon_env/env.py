"""The PettingZoo ``ParallelEnv`` of the platoon (DESIGN §6).

The class coordinates; the physics, sensing, safety and reward live in their own modules and
one compiled call (:func:`platoon_env.simulator.platoon_step`) does the whole step.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import SENSE_NAMES, SENSE_SIZE, SENSE_VISIBLE
from platoon_env.initial import InitialSampler
from platoon_env.observation import ACT_SIZE, OBS_SIZE, action_space, observation_space
from platoon_env.reward import REWARD_TERMS
from platoon_env.safety import CAUSES_OF_MASK, causes_to_mask, first_cause
from platoon_env.scenarios.loader import ScenarioLike, load_config, load_scenario
from platoon_env.scenarios.scenario import Scenario, build_scenario, initial_violations
from platoon_env.scenarios.schema import VIOLATION_CAUSES, ScenarioError
from platoon_env.simulator import (
    L_ARRIVED,
    L_PROGRESS,
    L_SIZE,
    P_SUBSTEP,
    kernel_params,
    platoon_step,
)


def _apply_overrides(scenario: ScenarioLike, overrides: Mapping[str, Any]) -> Scenario:
    """Load ``scenario`` and apply the keyword overrides of :func:`platoon_env.make`."""
    if not overrides:
        return load_scenario(scenario)
    cfg = load_config(scenario)
    sim = cfg.simulation
    sim_changes = {
        k: overrides[k]
        for k in ("control_period", "physics_substeps", "max_episode_steps")
        if overrides.get(k) is not None
    }
    if sim_changes:
        cfg = dataclasses.replace(cfg, simulation=dataclasses.replace(sim, **sim_changes))
    if overrides.get("terminate_on") is not None:
        causes = tuple(overrides["terminate_on"])
        causes_to_mask(causes)  # validates the names
        cfg = dataclasses.replace(cfg, safety=dataclasses.replace(cfg.safety, terminate_on=causes))
    if overrides.get("followers") is not None:
        cfg = dataclasses.replace(cfg, followers=int(overrides["followers"]))
    if overrides.get("perturb") is not None:
        cfg = dataclasses.replace(
            cfg, initial=dataclasses.replace(cfg.initial, perturb=bool(overrides["perturb"]))
        )
    robot_changes = {
        k: overrides[k] for k in ("u_max", "omega_max") if overrides.get(k) is not None
    }
    if robot_changes:
        cfg = dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, **robot_changes))
    free_space = scenario.free_space if isinstance(scenario, Scenario) else None
    return build_scenario(cfg, free_space=free_space)


# _infos unpacks a row of the sensing array in this column order (faster than indexing by name).
_UNPACKED_SENSE_NAMES = (
    "d",
    "beta",
    "visible",
    "occluded",
    "d_W_l",
    "d_W_r",
    "d_l",
    "d_r",
    "clearance",
)
if SENSE_NAMES != _UNPACKED_SENSE_NAMES:  # pragma: no cover - guards a refactoring mistake
    raise ImportError(f"env._infos expects sensing columns {_UNPACKED_SENSE_NAMES}")
# ... and the reward terms in this order.
_UNPACKED_REWARD_TERMS = ("distance", "bearing", "effort", "alive", "violation", "wall")
if REWARD_TERMS != _UNPACKED_REWARD_TERMS:  # pragma: no cover - guards a refactoring mistake
    raise ImportError(f"env._infos expects reward terms {_UNPACKED_REWARD_TERMS}")


#: ``(info["violation"], info["violations"], info["cost"])`` of every violation mask.
_VIOLATION_INFO: tuple[tuple[str | None, tuple[str, ...], int], ...] = tuple(
    (first_cause(mask), causes, 1 if causes else 0) for mask, causes in enumerate(CAUSES_OF_MASK)
)

#: The mask of every violation cause (the default ``terminate_on``).
ALL_CAUSES_MASK = causes_to_mask(VIOLATION_CAUSES)


class PlatoonParallelEnv(ParallelEnv):  # type: ignore[misc]
    """A leader-follower platoon of unicycle robots in a cluttered 2D workspace.

    **Agents**: ``follower_1 .. follower_N``; follower ``i`` tracks robot ``i - 1`` (robot 0 is
    the scripted leader, which follows ``leader.path`` by pure pursuit).

    **Action space** (per agent): ``Box([-u_max, -omega_max], [u_max, omega_max], float32)``:
    linear speed ``u`` [m/s] and turn rate ``omega`` [rad/s] of eq. 1. Values outside the box are
    clipped; NaN or infinite values raise ``ValueError`` and leave the state untouched.

    **Observation space** (per agent): ``Box`` float32 of length 7 — see
    :mod:`platoon_env.observation`: ``[visible, x~, y~, d_W_l, d_W_r, d_l, d_r]``, only from the
    follower's own camera and proximity sensor.

    **Rewards**: the named terms of :mod:`platoon_env.reward`; ``info[agent]["reward_terms"]``
    gives each term.

    **Episode end**: *termination* of all agents when any follower commits a violation whose
    cause is in ``terminate_on`` (default: all five of ``VIOLATION_CAUSES``), checked after every
    physics sub-step; *truncation* when the leader has reached its path's end and
    ``leader.settle_time`` has passed, or after ``max_episode_steps`` steps.

    **Info** (per agent): ``violation`` (the cause, or None), ``violations`` (all causes this
    step), ``cost`` (0/1, as in Safety-Gymnasium), ground-truth diagnostics ``d``, ``beta``,
    ``e_d``, ``e_beta``, ``d_W_l``, ``d_W_r``, ``d_l``, ``d_r``, ``clearance``, ``visible``,
    and ``reward_terms``. With ``diagnostics=False`` only ``violation``, ``violations`` and
    ``cost``: building the full dicts is about a third of a step's cost, and training loops
    rarely read them.

    **Ground truth** (for tests and plots, not policies): :attr:`poses`, :attr:`scenario`
    (``scenario.free_space`` is a shapely polygon), :attr:`sim_time`.

    **Arguments**: see :func:`platoon_env.make`.

    **Version history**: v0 — initial release.
    """

    metadata: dict[str, Any] = {
        "name": "platoon_v0",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 25,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        scenario: ScenarioLike = "study_c",
        *,
        control_period: float | None = None,
        physics_substeps: int | None = None,
        max_episode_steps: int | None = None,
        terminate_on: Iterable[str] | None = None,
        render_mode: str | None = None,
        followers: int | None = None,
        perturb: bool | None = None,
        u_max: float | None = None,
        omega_max: float | None = None,
        diagnostics: bool = True,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        overrides = {
            "control_period": control_period,
            "physics_substeps": physics_substeps,
            "max_episode_steps": max_episode_steps,
            "terminate_on": None if terminate_on is None else tuple(terminate_on),
            "followers": followers,
            "perturb": perturb,
            "u_max": u_max,
            "omega_max": omega_max,
        }
        self.scenario: Scenario = _apply_overrides(
            scenario, {k: v for k, v in overrides.items() if v is not None}
        )
        cfg = self.scenario.config
        self._renderer: Any = None
        self.render_mode = render_mode
        #: Whether ``info`` carries the ground-truth diagnostics and reward terms.
        self.diagnostics = bool(diagnostics)
        self.n_followers = cfg.followers
        self.possible_agents = [f"follower_{i}" for i in range(1, cfg.followers + 1)]
        self.agents: list[str] = []
        self.control_period = cfg.simulation.control_period
        self.physics_substeps = cfg.simulation.physics_substeps
        self.max_episode_steps = self.scenario.max_episode_steps
        self.terminate_on = frozenset(cfg.safety.terminate_on)
        self._terminate_mask = causes_to_mask(self.terminate_on)
        obs_space = observation_space(cfg)
        act_space = action_space(cfg)
        self.observation_spaces = {a: obs_space for a in self.possible_agents}
        self.action_spaces = {a: act_space for a in self.possible_agents}
        self._act_low = act_space.low.astype(np.float64)
        self._act_high = act_space.high.astype(np.float64)
        xmin, ymin, xmax, ymax = self.scenario.workspace.bounds
        if cfg.generator is not None:
            from platoon_env.scenarios.procedural import LAYOUT_BOUNDS

            xmin, ymin, xmax, ymax = LAYOUT_BOUNDS
        n1 = cfg.followers + 1
        self.state_space = spaces.Box(
            low=np.tile(np.array([xmin, ymin, -math.pi], dtype=np.float32), n1),
            high=np.tile(np.array([xmax, ymax, math.pi], dtype=np.float32), n1),
            dtype=np.float32,
        )
        # Kernel inputs (float64, contiguous) and scratch buffers, allocated once.
        self._params = kernel_params(cfg)
        self._substep = float(self._params[P_SUBSTEP])  # [s] as a Python float, for sim_time
        #: The procedural template (None for a fixed workspace) and the current layout number.
        self._template = cfg if cfg.generator is not None else None
        self.layout_index: int | None = 0 if cfg.generator is not None else None
        self._use_scenario(self.scenario)
        n = cfg.followers
        self._poses = np.array(self.scenario.initial_poses, dtype=np.float64)
        self._leader = np.zeros(L_SIZE)
        self._actions = np.zeros((n, ACT_SIZE))
        self._violations = np.zeros(n, dtype=np.int64)
        self._sensed = np.zeros((n, SENSE_SIZE))
        self._obs = np.zeros((n, OBS_SIZE), dtype=np.float32)
        self._terms = np.zeros((n, len(REWARD_TERMS)))
        self._rewards = np.zeros(n)
        self.sim_time = 0.0
        self.steps = 0
        self._arrival_time: float | None = None
        self.np_random, self._np_random_seed = seeding.np_random(None)

    # ----------------------------------------------------------------------------------------
    # PettingZoo API
    # ----------------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        """The (shared, cached) observation space of ``agent``."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        """The (shared, cached) action space of ``agent``."""
        return self.action_spaces[agent]

    @property
    def poses(self) -> np.ndarray:
        """Ground-truth poses ``(N+1, 3)`` ``[x, y, theta]``, leader first (a copy)."""
        return self._poses.copy()

    @property
    def leader_arrived(self) -> bool:
        """Whether the leader has reached the end of its path."""
        return bool(self._leader[L_ARRIVED])

    @property
    def violation_masks(self) -> np.ndarray:
        """Violation bit masks (N,) of the last step: bit k is ``VIOLATION_CAUSES[k]``."""
        return self._violations.copy()

    @property
    def sensed(self) -> np.ndarray:
        """Ground-truth sensing ``(N, 9)`` of the last step (``SENSE_*`` columns; a copy)."""
        return self._sensed.copy()

    def state(self) -> np.ndarray:
        """Global state for centralised critics: all poses with wrapped headings (float32)."""
        s = self._poses.copy()
        s[:, 2] = np.mod(s[:, 2] + math.pi, 2 * math.pi) - math.pi
        return s.astype(np.float32).ravel()

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode. ``seed`` reseeds this env's own RNG.

        ``options``: ``{"perturb": bool}`` overrides the scenario's seeded perturbation of the
        initial configuration; ``{"poses": array (N+1, 3)}`` starts from given poses (they must
        satisfy every constraint, else ``ScenarioError`` names the follower and constraint).
        """
        if seed is not None:
            self.np_random, self._np_random_seed = seeding.np_random(seed)
        options = dict(options or {})
        if self._template is not None:
            from platoon_env.scenarios.procedural import LAYOUTS_PER_SPLIT, generate_scenario

            self.layout_index = int(self.np_random.integers(LAYOUTS_PER_SPLIT))
            self._use_scenario(generate_scenario(self._template, self.layout_index))
        unknown = set(options) - {"perturb", "poses"}
        if unknown:
            # Gymnasium/PettingZoo envs ignore options they do not know (the official test
            # kit passes one); say so rather than fail.
            warnings.warn(
                f"reset(): ignoring unknown option(s) {', '.join(sorted(map(str, unknown)))}",
                stacklevel=2,
            )
        cfg = self.scenario.config
        if options.get("poses") is not None:
            poses = np.array(options["poses"], dtype=np.float64)
            if poses.shape != self._poses.shape or not np.all(np.isfinite(poses)):
                raise ValueError(f"options['poses'] must be finite with shape {self._poses.shape}")
            problems = initial_violations(cfg, self.scenario.workspace, poses)
            if problems:
                raise ScenarioError("initial poses are infeasible: " + "; ".join(problems))
        else:
            perturb = options.get("perturb", cfg.initial.perturb)
            poses = self._sampler.sample(self.np_random, bool(perturb))
        self._poses[:] = poses
        self._leader[L_PROGRESS] = self.scenario.initial_progress
        self._leader[L_ARRIVED] = 0.0
        self.sim_time = 0.0
        self.steps = 0
        self._arrival_time = None
        self.agents = list(self.possible_agents)
        self._actions[:] = 0.0
        # Zero-duration step: sensing of the initial configuration.
        self._step_kernel(n_substeps=0)
        obs = self._obs.copy()
        infos = self._infos([0] * self.n_followers, None)
        return {a: obs[i] for i, a in enumerate(self.agents)}, infos

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """Advance by one control period with every live agent's ``[u, omega]``."""
        agents = self.agents
        if not agents:
            raise RuntimeError("step() called on a finished episode; call reset() first")
        # The actions as a float64 (N, 2) array. Fast path (this runs every step, so it is
        # inlined): a dict holding exactly the live agents' well-shaped actions; anything else
        # goes through the checks of _read_actions, which name the misuse. The kernel clips
        # the actions and rejects NaN or inf before any state changes.
        try:
            if len(actions) != len(agents):
                raise KeyError
            act = np.array([actions[a] for a in agents], dtype=np.float64)
            if act.shape != self._actions.shape:
                raise ValueError
        except (KeyError, TypeError, ValueError):
            act = self._read_actions(actions)
        done = platoon_step(
            self._poses, act, self._leader, self._path, self._cum, *self._grid_arrays,
            self._params, self.physics_substeps, self._terminate_mask, self._violations,
            self._sensed, self._obs, self._terms, self._rewards,
        )  # fmt: skip
        if done < 0:  # nothing changed
            raise ValueError(
                f"action of {agents[-1 - done]!r} contains NaN or inf: {act[-1 - done].tolist()}"
            )
        self._actions = act
        self.sim_time += done * self._substep
        self.steps += 1
        masks = self._violations.tolist()
        if self._terminate_mask == ALL_CAUSES_MASK:  # the default: any violation ends it
            terminated = any(masks)
        elif self._terminate_mask:
            terminated = any(m & self._terminate_mask for m in masks)
        else:  # terminate_on=(): violations are only reported
            terminated = False
        if self._arrival_time is None and self._leader[L_ARRIVED]:
            self._arrival_time = self.sim_time
        truncated = not terminated and (
            self.steps >= self.max_episode_steps
            or (
                self._arrival_time is not None
                and self.sim_time - self._arrival_time >= self._settle_time - 1e-9
            )
        )
        # zip without strict=True: the lengths are equal by construction, and the strict check
        # costs about 0.5 us per dict here (this runs every step).
        observations = dict(zip(agents, self._obs.copy()))  # noqa: B905
        rewards = dict(zip(agents, self._rewards.tolist()))  # noqa: B905
        terminations = dict.fromkeys(agents, terminated)
        truncations = dict.fromkeys(agents, truncated)
        infos = self._infos(masks, self._terms.tolist())
        if terminated or truncated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def render(self) -> np.ndarray | None:
        """Draw the workspace, robots, fields of view and lines of sight (``render_mode``)."""
        if self.render_mode is None:
            warnings.warn(
                "render() called without a render_mode; pass render_mode to make()", stacklevel=2
            )
            return None
        if self._renderer is None:
            from platoon_env.rendering import Renderer

            self._renderer = Renderer(
                self.scenario.free_space,
                self.scenario.config,
                self.render_mode,
                fps=self.metadata["render_fps"],
            )
        names = [first_cause(int(m)) for m in self._violations]
        return self._renderer.render(  # type: ignore[no-any-return]
            self._poses, self._sensed[:, SENSE_VISIBLE] > 0, self.sim_time, names
        )

    def close(self) -> None:
        """Release the renderer's resources."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None  # figures are not picklable; redrawn on demand
        return state

    # ----------------------------------------------------------------------------------------
    # Internals
    # ----------------------------------------------------------------------------------------
    def _use_scenario(self, scenario: Scenario) -> None:
        """Point the kernel at ``scenario``'s path and edges (same N and parameters)."""
        self.scenario = scenario
        # Own writable copies: numba types read-only array arguments more slowly on every call.
        self._path = np.array(scenario.leader_path, dtype=np.float64)
        self._cum = np.array(scenario.path_s, dtype=np.float64)
        self._edges = scenario.workspace.edges
        self._boxes = scenario.workspace.boxes
        self._grid = EdgeGrid.build(self._edges, reach=scenario.config.proximity_range)
        self._grid_arrays = self._grid.arrays
        self._sampler = InitialSampler(scenario)
        self.max_episode_steps = scenario.max_episode_steps
        self._settle_time = scenario.config.leader.settle_time
        self._d_des = scenario.config.formation.d_des
        if self._renderer is not None:  # the map changed: redraw from scratch
            self.close()

    def _step_kernel(self, n_substeps: int, actions: np.ndarray | None = None) -> int:
        return int(
            platoon_step(
                self._poses,
                self._actions if actions is None else actions,
                self._leader,
                self._path,
                self._cum,
                *self._grid_arrays,
                self._params,
                n_substeps,
                self._terminate_mask,
                self._violations,
                self._sensed,
                self._obs,
                self._terms,
                self._rewards,
            )
        )

    def _read_actions(self, actions: Mapping[str, Any]) -> np.ndarray:
        """The live agents' actions as a float64 (N, 2) array, or an error naming the misuse
        (not a dict, unknown or missing agent, wrong shape). :meth:`step` inlines the fast path
        and calls this when it does not apply."""
        if not isinstance(actions, Mapping):
            raise TypeError(f"actions must be a dict agent -> [u, omega], got {type(actions)}")
        if len(actions) != len(self.agents) or any(a not in actions for a in self.agents):
            for agent in actions:
                if agent not in self.agents:
                    raise KeyError(
                        f"unknown or finished agent {agent!r}; "
                        f"live agents: {', '.join(self.agents)}"
                    )
            missing = [a for a in self.agents if a not in actions]
            raise KeyError(f"missing action for agent {missing[0]!r}")
        try:
            out = np.array([actions[a] for a in self.agents], dtype=np.float64)
        except (ValueError, TypeError):
            out = np.empty(0)
        if out.shape != (len(self.agents), ACT_SIZE):
            for agent in self.agents:
                shape = np.shape(actions[agent])
                if shape != (ACT_SIZE,):
                    raise ValueError(
                        f"action of {agent!r} must have shape ({ACT_SIZE},) [u, omega], "
                        f"got shape {shape}"
                    )
            raise ValueError("actions must be numeric arrays of shape (2,) [u, omega]")
        return out

    def _infos(
        self, masks: list[int], terms: list[list[float]] | None
    ) -> dict[str, dict[str, Any]]:
        """``info[agent]`` of every live agent.

        Built as literals in one loop: this runs every step and is about a third of its cost
        (``reward_terms`` lists :data:`~platoon_env.reward.REWARD_TERMS` in order); only the
        violation entries without :attr:`diagnostics`.
        """
        infos: dict[str, dict[str, Any]] = {}
        if not self.diagnostics:
            for agent, mask in zip(self.agents, masks):  # noqa: B905 - equal lengths
                first, causes, cost = _VIOLATION_INFO[mask]
                infos[agent] = {"violation": first, "violations": causes, "cost": cost}
            return infos
        d_des = self._d_des
        rows = zip(self.agents, self._sensed.tolist(), masks)  # noqa: B905 - equal lengths
        for i, (agent, row, mask) in enumerate(rows):
            d, beta, visible, _, wall_l, wall_r, sight_l, sight_r, clearance = row
            first, causes, cost = _VIOLATION_INFO[mask]
            if terms is None:
                reward_terms = {}
            else:
                distance, bearing, effort, alive, violation, wall = terms[i]
                reward_terms = {
                    "distance": distance,
                    "bearing": bearing,
                    "effort": effort,
                    "alive": alive,
                    "violation": violation,
                    "wall": wall,
                }
            infos[agent] = {
                "violation": first,
                "violations": causes,
                "cost": cost,
                "d": d,
                "beta": beta,
                "e_d": d - d_des,
                "e_beta": beta,
                "d_W_l": wall_l,
                "d_W_r": wall_r,
                "d_l": sight_l,
                "d_r": sight_r,
                "clearance": clearance,
                "visible": visible > 0.0,
                "reward_terms": reward_terms,
            }
        return infos
