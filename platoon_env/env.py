"""The PettingZoo ``ParallelEnv`` of the platoon (``docs/api.md``).

The class coordinates: it is the simulation core (:class:`platoon_env.core.PlatoonCore`) at
``B = 1`` plus PettingZoo's dicts, the infos and rendering. The physics, sensing, safety, reward
and the episode rules live in their own modules and run as one compiled call
(:mod:`platoon_env.simulator`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from platoon_env.config import ScenarioError
from platoon_env.core import CoreSnapshot, PlatoonCore, compiled_entry
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_OCCLUDED,
    SENSE_PROXIMITY,
    SENSE_SIZE,
    SENSE_VISIBLE,
)
from platoon_env.observation import ACT_SIZE, action_space, observation_space
from platoon_env.realism import add_realism_info
from platoon_env.reward import REWARD_TERMS
from platoon_env.scenarios.options import OVERRIDE_OPTIONS, check_bool, unexpected_keyword
from platoon_env.scenarios.scenario import Scenario
from platoon_env.scenarios.source import SourceLike, scenario_source
from platoon_env.simulator import step_serial
from platoon_env.violations import VIOLATION_INFO, VIOLATION_NUMERIC_INFO, first_cause

# _infos unpacks a row of the sensing array in its column order (picking the columns by name
# instead cost about 2 us of a step of 7 followers, measured) ...
_SENSE_ROW = (SENSE_D, SENSE_BETA, SENSE_VISIBLE, SENSE_OCCLUDED, *SENSE_PROXIMITY, SENSE_CLEARANCE)
if _SENSE_ROW != tuple(range(SENSE_SIZE)):  # pragma: no cover - guards a refactoring mistake
    raise ImportError("env._infos expects the sensing columns in the order of SENSE_NAMES")

#: The sensing columns that ``info[agent]`` reports under their own names (``diagnostics``).
SENSE_INFO_KEYS: tuple[str, ...] = ("d", "beta", "d_W_l", "d_W_r", "d_l", "d_r", "clearance")
#: ``info[agent]``'s keys, in order, in the rich view: the violation entries, then (with
#: ``diagnostics``) the sensing, its errors ``e_d = d - d_des`` and ``e_beta = beta``,
#: ``visible`` and the reward terms (a dict by :data:`~platoon_env.reward.REWARD_TERMS`).
#: The one table of the info's names: the numeric view's and the vector env's derive from it.
INFO_KEYS: tuple[str, ...] = (
    "violation",
    "violations",
    "cost",
    "d",
    "beta",
    "e_d",
    "e_beta",
    *SENSE_INFO_KEYS[2:],
    "visible",
    "reward_terms",
)
#: How many leading :data:`INFO_KEYS` are the violation entries (all there is without
#: ``diagnostics``).
N_VIOLATION_INFO = 3
#: ``info[agent]``'s keys, in order, in the numeric view: the rich view's, with the causes as
#: ``violation_mask`` and the reward terms flat (``reward_<term>``).
NUMERIC_INFO_KEYS: tuple[str, ...] = (
    *("violation_mask" if key == "violations" else key for key in INFO_KEYS[:-1]),
    *(f"reward_{term}" for term in REWARD_TERMS),
)


#: The views of ``info`` (``make(..., info_view=...)``): ``"rich"`` (the default: PettingZoo's
#: dicts, cause names, None when nothing happened) and ``"numeric"`` (every value a number, the
#: same keys at reset and at every step, for array-minded libraries such as TorchRL).
INFO_VIEWS: tuple[str, ...] = ("rich", "numeric")


def steps_per_second(control_period: float) -> float:
    """``metadata["render_fps"]`` of an env that steps every ``control_period`` seconds: its steps
    per second (an ``int`` when whole: 100 for the shipped 0.01 s), so that a video of one frame
    per step (``gymnasium.wrappers.RecordVideo``) plays in real time, not in slow motion."""
    fps = 1.0 / control_period
    return int(fps) if fps.is_integer() else fps


#: The keywords of ``make()`` that configure the env rather than its scenario (the scenario's
#: are :data:`~platoon_env.scenarios.options.OVERRIDE_OPTIONS`).
ENV_OPTIONS: tuple[str, ...] = ("render_mode", "diagnostics", "info_view")

#: Attributes of PlatoonParallelEnv that are views of its core's arrays (see ``_views``).
_VIEW_NAMES = (
    "_poses",
    "_actions",
    "_violations",
    "_sensed",
    "_obs",
    "_terms",
    "_rewards",
    "_episode",
    "_run_args",
    "_step",
    "_d_des",
)


def refuse_unknown_keywords(
    where: str, overrides: Mapping[str, Any], own: Sequence[str], passed: Sequence[str] = ()
) -> None:
    """Raise Python's ``TypeError`` ("``where`` got an unexpected keyword argument ...") for an
    override that is neither a scenario option nor one of ``passed`` (keywords handed on to
    another env, which checks them), listing the scenario's options and the caller's ``own``
    keywords. None values are ignored, as ``apply_overrides`` ignores them."""
    known = (*OVERRIDE_OPTIONS, *passed)
    unknown = [k for k, v in overrides.items() if v is not None and k not in known]
    if unknown:
        raise unexpected_keyword(where, unknown, (*OVERRIDE_OPTIONS, *own))


def check_env_keywords(
    where: str, overrides: Mapping[str, Any], own: Sequence[str], info_view: Any
) -> None:
    """The checks ``make()`` and ``make_vec()`` share on their keywords: an override that is no
    scenario option (:func:`refuse_unknown_keywords`, listing the caller's ``own`` keywords);
    an ``info_view`` that is not one of :data:`INFO_VIEWS` is a ``ScenarioError``."""
    refuse_unknown_keywords(where, overrides, own)
    if info_view not in INFO_VIEWS:
        raise ScenarioError(
            f"{where}: info_view: expected one of {', '.join(map(repr, INFO_VIEWS))}, "
            f"got {info_view!r}"
        )


def read_actions(actions: Mapping[str, Any], agents: Sequence[str]) -> np.ndarray:
    """The live ``agents``' actions as an ``(N, 2)`` array of real numbers (what
    :meth:`PlatoonParallelEnv.step` applies), or an error naming the misuse: not a dict
    (``TypeError``), an unknown or missing agent (``KeyError``), not real numbers
    (``TypeError``), another shape (``ValueError``). NaN and inf pass: the core rejects them.
    The batched evaluator (:mod:`experiments.batched_eval`) reads each copy's actions with it.
    """
    # Fast path (every step): a dict holding exactly the live agents' well-shaped actions.
    try:
        if len(actions) != len(agents):
            raise KeyError
        act = np.array([actions[a] for a in agents])
        # Real numbers only: numpy would read "0.3" as 0.3 and drop an imaginary part.
        if act.shape == (len(agents), ACT_SIZE) and act.dtype.kind in "fiu":
            return act
    except (KeyError, TypeError, ValueError, IndexError):
        pass
    if not isinstance(actions, Mapping):
        raise TypeError(f"actions must be a dict agent -> [u, omega], got {type(actions)}")
    if len(actions) != len(agents) or any(a not in actions for a in agents):
        for agent in actions:
            if agent not in agents:
                raise KeyError(
                    f"unknown or finished agent {agent!r}; live agents: {', '.join(agents)}"
                )
        missing = [a for a in agents if a not in actions]
        raise KeyError(f"missing action for agent {missing[0]!r}")
    for agent in agents:
        kind = np.asarray(actions[agent]).dtype.kind
        if kind not in "fiu":
            raise TypeError(
                f"action of {agent!r} must be real numbers [u, omega], got "
                f"{actions[agent]!r} ({np.asarray(actions[agent]).dtype})"
            )
    try:
        out = np.array([actions[a] for a in agents], dtype=np.float64)
    except (ValueError, TypeError):
        out = np.empty(0)
    if out.shape != (len(agents), ACT_SIZE):
        for agent in agents:
            shape = np.shape(actions[agent])
            if shape != (ACT_SIZE,):
                raise ValueError(
                    f"action of {agent!r} must have shape ({ACT_SIZE},) [u, omega], "
                    f"got shape {shape}"
                )
        raise ValueError("actions must be numeric arrays of shape (2,) [u, omega]")
    return out


class PlatoonParallelEnv(ParallelEnv):  # type: ignore[misc]
    """A leader-follower platoon of unicycle robots in a cluttered 2D workspace.

    **Agents**: ``follower_1 .. follower_N``; follower ``i`` tracks robot ``i - 1`` (robot 0 is
    the scripted leader, which follows ``leader.path`` by pure pursuit or replays
    ``leader.trajectory`` exactly; see :mod:`platoon_env.dynamics.leader`). A scenario that
    draws its formation (``generator.formation.followers`` a range) has ``N`` = the range's
    upper end in :attr:`possible_agents` and each episode's ``n`` in :attr:`agents` (the first
    ``n``; :attr:`variable_followers`, ``docs/api.md``).

    **Action space** (per agent): ``Box([-u_max, -omega_max], [u_max, omega_max], float32)``:
    linear speed ``u`` [m/s] and turn rate ``omega`` [rad/s] of eq. 1. Values outside the box are
    clipped; NaN or infinite values raise ``ValueError`` and leave the state untouched.

    **Observation space** (per agent): ``Box`` float32 of length 7 — see
    :mod:`platoon_env.observation`: ``[visible, x~, y~, d_W_l, d_W_r, d_l, d_r]``, only from the
    follower's own camera and proximity sensor; with ``observation={"task_aware": True}`` 13:
    those, then ``d_des``, ``d_col``, ``d_con``, ``beta_con``, ``r`` over fixed scales and the
    time since the predecessor was last perceived (``t_unseen``), each in ``[0, 1]``.

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
    rarely read them. With ``info_view="numeric"`` every value is a number and the keys are
    the same at reset and at every step (for TorchRL): ``violation`` is an integer code
    (index into :data:`~platoon_env.violations.VIOLATION_CODE_NAMES`, 0 = none),
    ``violation_mask`` the causes' bit mask, ``cost``; with diagnostics also the ground truth
    above (``visible`` as 0/1) and each reward term flat as ``reward_<term>`` (0.0 at reset).

    **Ground truth** (for tests and plots, not policies): :attr:`poses`, :attr:`scenario`
    (``scenario.free_space`` is a shapely polygon), :attr:`sim_time`.

    **Arguments**: see :func:`platoon_env.make`.

    **Version history**: v0 — initial release.
    """

    #: ``render_fps`` here is the shipped scenarios' rate (0.01 s steps); each instance holds
    #: its own copy with its scenario's :func:`steps_per_second`.
    metadata: dict[str, Any] = {
        "name": "platoon_v0",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 100,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        scenario: SourceLike = "study_c",
        *,
        render_mode: str | None = None,
        diagnostics: bool = True,
        info_view: str = "rich",
        **overrides: Any,
    ) -> None:
        check_env_keywords("make()", overrides, ENV_OPTIONS, info_view)
        #: The view of ``info``: ``"rich"`` or ``"numeric"`` (see :data:`INFO_VIEWS`).
        self.info_view = info_view
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        #: Whether ``info`` carries the ground-truth diagnostics and reward terms.
        self.diagnostics = check_bool("diagnostics", diagnostics, "make()")
        self.source = scenario_source(scenario, overrides)
        self._core = core = PlatoonCore(self.source, 1)
        cfg = core.config
        self._renderer: Any = None
        self.render_mode = render_mode
        self.n_followers = core.n_followers
        self.possible_agents = [f"follower_{i}" for i in range(1, core.n_followers + 1)]
        self.agents: list[str] = []
        self.control_period = cfg.simulation.control_period
        # One frame per step: render_fps is this scenario's steps per second (a copy of the
        # class's metadata, so that envs of different control periods do not share one).
        self.metadata = {**self.metadata, "render_fps": steps_per_second(self.control_period)}
        self.physics_substeps = cfg.simulation.physics_substeps
        self.terminate_on = frozenset(cfg.safety.terminate_on)
        # One space object per agent: seeding one agent's space must not seed another's.
        self.observation_spaces = {a: observation_space(cfg) for a in self.possible_agents}
        self.action_spaces = {a: action_space(cfg) for a in self.possible_agents}
        xmin, ymin, xmax, ymax = self.source.bounds
        n1 = core.n_followers + 1
        n = core.n_followers
        act = self.action_spaces[self.possible_agents[0]]
        #: Bounds of :meth:`state` (its layout is documented there).
        self.state_space = spaces.Box(
            low=np.concatenate(
                [np.tile(np.array([xmin, ymin, -math.pi]), n1), np.tile(act.low, n), [0.0, 0.0]]
            ).astype(np.float32),
            high=np.concatenate(
                [np.tile(np.array([xmax, ymax, math.pi]), n1), np.tile(act.high, n), [1.0, 1.0]]
            ).astype(np.float32),
            dtype=np.float32,
        )
        self._state_low = self.state_space.low[: 3 * n1].reshape(n1, 3)
        self._state_high = self.state_space.high[: 3 * n1].reshape(n1, 3)
        self._views()

    def _views(self) -> None:
        """Env 0's rows of the core's arrays (views, so reading them costs no copy): the
        episode's own followers (all ``N``, unless a drawn formation has fewer; then
        :attr:`agents` is the first ``n`` of :attr:`possible_agents`)."""
        core = self._core
        n = self._n_live = int(core.params[0]["n_followers"])
        self._poses = core.poses[0, : n + 1]
        self._actions = core.actions[0, :n]
        self._violations = core.violations[0, :n]
        self._sensed = core.sensed[0, :n]
        self._obs = core.obs[0, :n]
        self._terms = core.terms[0, :n]
        self._rewards = core.rewards[0, :n]
        self._episode = core.episode
        self._run_args = (np.ones(1, dtype=bool), self.physics_substeps, *core.step_args)
        self._step = compiled_entry(step_serial, self._run_args)
        self._d_des = float(core.params[0]["d_des"])

    # ----------------------------------------------------------------------------------------
    # PettingZoo API
    # ----------------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        """The (cached) observation space of ``agent``."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        """The (cached) action space of ``agent``."""
        return self.action_spaces[agent]

    @property
    def scenario(self) -> Scenario:
        """The current episode's scenario (for a procedural source: the layout drawn on reset)."""
        return self._core.scenarios[0]

    @property
    def variable_followers(self) -> bool:
        """Whether episodes may have fewer followers than :attr:`possible_agents` (the
        scenario draws its formation, ``generator.formation.followers`` a range): then
        :attr:`agents` is the episode's first ``n`` after each reset."""
        return bool(self._core.variable)

    @property
    def layout_index(self) -> int | None:
        """The procedural layout number of the current episode (None for a fixed workspace)."""
        return self.scenario.layout_index if self.source.procedural else None

    @property
    def np_random(self) -> np.random.Generator:
        """This env's own RNG (seeded by ``reset(seed)``)."""
        return self._core.rngs[0]

    @np_random.setter
    def np_random(self, rng: np.random.Generator) -> None:
        self._core.rngs[0] = rng

    @property
    def sim_time(self) -> float:
        """Simulated time of the episode [s]."""
        return float(self._episode[0]["sim_time"])

    @property
    def steps(self) -> int:
        """Steps taken in the episode."""
        return int(self._episode[0]["steps"])

    @property
    def max_episode_steps(self) -> int:
        """The current episode's step limit."""
        return int(self._core.params[0]["max_episode_steps"])

    @property
    def poses(self) -> np.ndarray:
        """Ground-truth poses ``(N+1, 3)`` ``[x, y, theta]``, leader first (a copy)."""
        return self._poses.copy()

    @property
    def leader_arrived(self) -> bool:
        """Whether the leader has reached the end of its path."""
        return bool(self._episode[0]["leader_arrived"])

    @property
    def leader_velocity(self) -> np.ndarray:
        """The leader's ``[u, omega]`` (2,) in the last physics sub-step (ground truth): pure
        pursuit's command, or the velocity that a timed trajectory's interpolation implies,
        times the episode's speed factor; zeros at reset and once the leader has arrived."""
        ep = self._episode[0]
        return np.array([ep["leader_u"], ep["leader_omega"]], dtype=np.float64)

    @property
    def leader_speed_factor(self) -> float:
        """This episode's leader speed factor ``f`` (``leader.speed_variation``, drawn at
        reset; 1 without variation)."""
        return float(self._episode[0]["leader_speed_factor"])

    @property
    def violation_masks(self) -> np.ndarray:
        """Violation bit masks (N,) of the last step: bit k is ``VIOLATION_CAUSES[k]``."""
        return self._violations.copy()

    @property
    def applied_velocities(self) -> np.ndarray:
        """The ``[u, omega]`` (N, 2) the followers' actuators applied in the last step (the
        clipped commands, unless ``robot.lag``/``accel_max``/``alpha_max`` are set; a copy)."""
        return self._core.applied[0, : self._n_live].copy()

    @property
    def sensed(self) -> np.ndarray:
        """Ground-truth sensing ``(N, 9)`` of the last step (``SENSE_*`` columns; a copy)."""
        return self._sensed.copy()

    def state(self) -> np.ndarray:
        """Global state for centralised critics (float32, within :attr:`state_space`).

        Layout, ``N`` followers: ``[x_0, y_0, theta_0, ..., x_N, y_N, theta_N]`` every robot's
        pose, leader first (positions clipped to the workspace bounds, headings wrapped to
        ``[-pi, pi]``); ``[u_1, omega_1, ..., u_N, omega_N]`` the velocities each follower's
        actuators applied in the last step; the leader's progress along its path (arc length
        over path length, in ``[0, 1]``); the episode's time over its limit
        (``sim_time / (max_episode_steps * control_period)``, in ``[0, 1]``). Ground truth:
        for critics and analysis, never for a policy's input.
        """
        poses = self._core.poses[0].copy()  # every slot: the state's layout is fixed
        poses[:, 2] = np.mod(poses[:, 2] + math.pi, 2 * math.pi) - math.pi
        poses = np.clip(poses, self._state_low, self._state_high)
        ep = self._episode[0]
        length = float(self.scenario.path_s[-1])
        horizon = self.max_episode_steps * self.control_period
        tail = [
            min(1.0, max(0.0, float(ep["leader_progress"]) / length)),
            min(1.0, float(ep["sim_time"]) / horizon),
        ]
        return np.concatenate([poses.ravel(), self._core.applied[0].ravel(), tail]).astype(
            np.float32
        )

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode. ``seed`` reseeds this env's own RNG.

        ``options``: ``{"perturb": bool}`` overrides the scenario's seeded perturbation of the
        initial configuration; ``{"poses": array (N+1, 3)}`` starts from given poses (they must
        satisfy every constraint, else ``ScenarioError`` names the follower and constraint, and
        the env is left as it was).
        """
        options = dict(options or {})
        unknown = set(options) - {"perturb", "poses"}
        if unknown:
            # Gymnasium/PettingZoo envs ignore options they do not know (the official test
            # kit passes one); say so rather than fail.
            warnings.warn(
                f"reset(): ignoring unknown option(s) {', '.join(sorted(map(str, unknown)))}",
                stacklevel=2,
            )
        perturb = options.get("perturb")
        if perturb is not None:
            perturb = check_bool("options['perturb']", perturb, "reset()")
        if seed is not None:
            seed = _check_seed(seed)
        had_map = self.scenario
        self._core.reset_env(0, seed, perturb=perturb, poses=options.get("poses"))
        if self._core.maps is not self._run_args[4] or self.scenario is not had_map:
            self._views()  # a bigger layout reallocated the bank, or d_des may differ
        if self.scenario is not had_map and self._renderer is not None:
            self.close()  # the map changed: redraw from scratch
        self.agents = self.possible_agents[: self._n_live]
        # Zero-duration step: sensing of the initial configuration.
        self._core.run(None, 0)
        obs = self._obs.copy()
        infos = self._infos([0] * self._n_live, None)
        add_realism_info(infos, self._core.realism[0], self.info_view == "numeric")
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
        # The core clips the actions and rejects NaN or inf before any state changes.
        act = read_actions(actions, agents)
        self._actions[:] = act
        # The compiled step through its entry (PlatoonCore.run's, without the type dispatch),
        # then the core's rule after it.
        ended = self._core.after_step(None, self.physics_substeps, self._step(*self._run_args))
        if ended < 0:  # nothing changed
            raise ValueError(
                f"action of {agents[-1 - ended]!r} contains NaN or inf: {act[-1 - ended].tolist()}"
            )
        terminated = truncated = bool(ended)
        if ended:
            terminated = bool(self._episode[0]["terminated"])
            truncated = not terminated
        # zip without strict=True: the lengths are equal by construction, and the strict check
        # costs about 0.5 us per dict here (this runs every step).
        observations = dict(zip(agents, self._obs.copy()))  # noqa: B905
        rewards = dict(zip(agents, self._rewards.tolist()))  # noqa: B905
        terminations = dict.fromkeys(agents, terminated)
        truncations = dict.fromkeys(agents, truncated)
        infos = self._infos(self._violations.tolist(), self._terms.tolist())
        add_realism_info(infos, self._core.realism[0], self.info_view == "numeric")
        if ended:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def snapshot(self) -> CoreSnapshot:
        """The env's whole state now (:class:`~platoon_env.core.CoreSnapshot`: poses, applied
        velocities, the leader's progress and time, perception buffers, RNG): :meth:`restore`
        it here or into any env of the same scenario (also a
        :class:`~platoon_env.batched.BatchedPlatoon` row) and the episode continues exactly as
        from this moment, fed the same actions."""
        return self._core.snapshot(0)

    def restore(self, snapshot: CoreSnapshot) -> dict[str, np.ndarray]:
        """Continue from ``snapshot`` (:meth:`snapshot`); returns the observations at it (an
        ended episode's snapshot leaves the env needing a reset, as the original)."""
        had_map = self.scenario
        self._core.restore(0, snapshot)
        self._views()
        if self.scenario is not had_map and self._renderer is not None:
            self.close()
        self.agents = [] if snapshot.ended else self.possible_agents[: self._n_live]
        obs = self._obs.copy()
        return {a: obs[i] for i, a in enumerate(self.possible_agents[: self._n_live])}

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
                bounds=self.source.bounds,
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
        # The row views would unpickle as copies detached from the core: rebuilt on load.
        for name in _VIEW_NAMES:
            state.pop(name, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._views()

    # ----------------------------------------------------------------------------------------
    # Internals
    # ----------------------------------------------------------------------------------------
    def _infos(
        self, masks: list[int], terms: list[list[float]] | None
    ) -> dict[str, dict[str, Any]]:
        """``info[agent]`` of every live agent.

        Built as literals in one loop: this runs every step and is about a third of its cost
        (``reward_terms`` lists :data:`~platoon_env.reward.REWARD_TERMS` in order); only the
        violation entries without :attr:`diagnostics`. The numeric view is :meth:`_numeric_infos`.
        """
        if self.info_view == "numeric":
            return self._numeric_infos(masks, terms)
        infos: dict[str, dict[str, Any]] = {}
        if not self.diagnostics:
            for agent, mask in zip(self.agents, masks):  # noqa: B905 - equal lengths
                infos[agent] = dict(zip(INFO_KEYS, VIOLATION_INFO[mask]))  # noqa: B905
            return infos
        d_des = self._d_des
        rows = zip(self.agents, self._sensed.tolist(), masks)  # noqa: B905 - equal lengths
        for i, (agent, row, mask) in enumerate(rows):
            d, beta, visible, _, wall_l, wall_r, sight_l, sight_r, clearance = row
            first, causes, cost = VIOLATION_INFO[mask]
            reward_terms = {} if terms is None else dict(zip(REWARD_TERMS, terms[i]))  # noqa: B905
            infos[agent] = dict(
                zip(  # noqa: B905 - one value per key of INFO_KEYS
                    INFO_KEYS,
                    (
                        first,
                        causes,
                        cost,
                        d,
                        beta,
                        d - d_des,
                        beta,
                        wall_l,
                        wall_r,
                        sight_l,
                        sight_r,
                        clearance,
                        visible > 0.0,
                        reward_terms,
                    ),
                )
            )
        return infos

    def _numeric_infos(
        self, masks: list[int], terms: list[list[float]] | None
    ) -> dict[str, dict[str, np.generic]]:
        """``info[agent]`` of every live agent in the numeric view (``info_view="numeric"``).

        The rich view's content as numpy scalars (``int64``, ``float64``: they carry a
        ``dtype``, which TorchRL's ``GymEnv`` info reader reads) under fixed keys: the first
        violation as its code (:data:`~platoon_env.violations.VIOLATION_CODE_NAMES`), all
        causes as ``violation_mask`` (bit ``k`` = ``VIOLATION_CAUSES[k]``), ``visible`` as 0/1
        and the reward terms flat, 0.0 at reset (no step yet), so that a library which sizes
        its buffers from the reset's infos (TorchRL's ``PettingZooWrapper``) gets every later
        step's keys.
        """
        i64, f64 = np.int64, np.float64
        infos: dict[str, dict[str, np.generic]] = {}
        if not self.diagnostics:
            for agent, mask in zip(self.agents, masks):  # noqa: B905 - equal lengths
                code, _, cost = VIOLATION_NUMERIC_INFO[mask]
                infos[agent] = dict(
                    zip(NUMERIC_INFO_KEYS, (i64(code), i64(mask), i64(cost)))  # noqa: B905
                )
            return infos
        d_des = self._d_des
        no_terms = [0.0] * len(REWARD_TERMS)
        rows = zip(self.agents, self._sensed.tolist(), masks)  # noqa: B905 - equal lengths
        for i, (agent, row, mask) in enumerate(rows):
            d, beta, visible, _, wall_l, wall_r, sight_l, sight_r, clearance = row
            code, _, cost = VIOLATION_NUMERIC_INFO[mask]
            values = (
                i64(code),
                i64(mask),
                i64(cost),
                f64(d),
                f64(beta),
                f64(d - d_des),
                f64(beta),
                f64(wall_l),
                f64(wall_r),
                f64(sight_l),
                f64(sight_r),
                f64(clearance),
                i64(1 if visible > 0.0 else 0),
                *(f64(t) for t in (no_terms if terms is None else terms[i])),
            )
            infos[agent] = dict(zip(NUMERIC_INFO_KEYS, values, strict=True))
        return infos


def _check_seed(seed: Any) -> int:
    """``seed`` as a Python int (numpy integers accepted), or a clear error."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise TypeError(f"seed must be an integer or None, got {seed!r}")
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    return int(seed)
