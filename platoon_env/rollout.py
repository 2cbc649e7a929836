"""Run a policy for one episode, record what happened, and measure it (``docs/metrics.md``).

One evaluation path serves every policy: anything with ``reset(seed=None)`` and
``act(observations) -> actions`` (:class:`baselines.Policy`) — the PPC law, the last-seen
baseline, a learned model. The metrics are computed from ground truth (poses, the env's
sensing), never from what the policy saw.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from platoon_env.env import PlatoonParallelEnv
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
    SENSE_VISIBLE,
)
from platoon_env.safety import first_cause

#: Errors are scored after this initial transient [s] (the funnels start wide, eq. 12).
DEFAULT_TRANSIENT = 5.0

#: Columns of :func:`episode_metrics`, in the order of ``results.csv``.
METRIC_NAMES: tuple[str, ...] = (
    "success",
    "violation",
    "time_to_violation",
    "rms_e_d",
    "rms_e_beta",
    "max_abs_e_d",
    "max_abs_e_beta",
    "min_inter_robot_distance",
    "min_obstacle_clearance",
    "control_effort",
    "peak_u",
    "peak_omega",
    "command_rate_u",
    "command_rate_omega",
    "steps",
    "sim_time",
    "leader_arrived",
    "lost_sight_steps",
    "funnel_exits",
    "path_fraction",
    "min_margin_distance",
    "min_margin_bearing",
    "min_margin_clearance",
    "min_margin_sight",
)


class PolicyLike(Protocol):
    """The shared policy interface (see :class:`baselines.Policy`)."""

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]: ...


@dataclass
class Episode:
    """What happened in one episode (ground truth), step by step.

    ``times`` (T+1,), ``poses`` (T+1, N+1, 3), ``sensed`` (T+1, N, 9) with the ``SENSE_*``
    columns, ``actions`` (T, N, 2) as applied (after clipping), ``violations`` (T, N) masks,
    ``signals`` the policy's internal signals per step (e.g. PPC's performance functions),
    stacked to arrays (T, N) per name. ``d_col``, ``d_con``, ``beta_con``, ``radius`` are the
    episode's constraints (eqs. 4-5: the collision distance, the camera's range and half field
    of view) and the robots' radius, ``path_length`` the leader's path's length [m]
    (:func:`constraint_margins`, the graded metrics; NaN where not recorded).
    """

    scenario: str
    seed: int | None
    control_period: float
    d_des: float
    times: np.ndarray
    poses: np.ndarray
    sensed: np.ndarray
    actions: np.ndarray
    violations: np.ndarray
    terminated: bool
    truncated: bool
    leader_arrived: bool
    first_violation: tuple[int, str, int] | None  # (step, cause, follower index 1..N)
    signals: dict[str, np.ndarray] = field(default_factory=dict)
    funnel_exits: int = 0
    d_col: float = math.nan
    d_con: float = math.nan
    beta_con: float = math.nan
    radius: float = math.nan
    path_length: float = math.nan

    @property
    def steps(self) -> int:
        """Number of env steps taken."""
        return int(self.actions.shape[0])


def first_violation(
    step: int, mask: np.ndarray, first: tuple[int, str, int] | None
) -> tuple[int, str, int] | None:
    """The episode's first violation after ``step`` (0-based) with violation masks ``mask``
    (N,): ``first`` if there was one already, else ``(step, cause, follower 1..N)`` of the
    lowest follower violating now (its first cause, :func:`~platoon_env.safety.first_cause`),
    else None."""
    if first is None and mask.any():
        k = int(np.flatnonzero(mask)[0])
        return (step, str(first_cause(int(mask[k]))), k + 1)
    return first


class EpisodeRecorder:
    """The step-by-step record of one episode, kept as :func:`run_episode` keeps it, and the
    :class:`Episode` it becomes: whoever steps the env (:func:`run_episode`; the batched
    evaluator :mod:`experiments.batched_eval`, one recorder per env copy) records through this.

    Args:
        agents: the episode's followers (``env.agents`` after the reset: ``possible_agents``
            unless a drawn formation has fewer), the order of the action rows.
        act_low, act_high: the action Box's bounds (the recorded actions are clipped to them,
            as the env applies them).
        sim_time, poses, sensed: the env's state after its reset (``env.sim_time``,
            ``env.poses``, ``env.sensed``).
    """

    def __init__(
        self,
        agents: Sequence[str],
        act_low: np.ndarray,
        act_high: np.ndarray,
        sim_time: float,
        poses: np.ndarray,
        sensed: np.ndarray,
    ) -> None:
        self.agents = tuple(agents)
        self._low = act_low
        self._high = act_high
        self.times: list[float] = [sim_time]
        self.poses: list[np.ndarray] = [poses]
        self.sensed: list[np.ndarray] = [sensed]
        self.actions: list[np.ndarray] = []
        self.masks: list[np.ndarray] = []
        self.signals: dict[str, list[np.ndarray]] = {}
        #: ``(step, cause, follower 1..N)`` of the first violation so far (None: none yet).
        self.first: tuple[int, str, int] | None = None

    @property
    def steps(self) -> int:
        """Steps recorded so far."""
        return len(self.actions)

    def record_signals(self, policy: Any) -> None:
        """Keep a copy of ``policy.signals`` (a dict of arrays), if it has them (call after
        its ``act``)."""
        if hasattr(policy, "signals"):
            for key, value in policy.signals.items():
                self.signals.setdefault(key, []).append(np.asarray(value).copy())

    def record_step(
        self,
        step: int,
        cmd: Mapping[str, Any],
        mask: np.ndarray,
        sim_time: float,
        poses: np.ndarray,
        sensed: np.ndarray,
    ) -> None:
        """Record env step ``step`` (0-based): the commands ``cmd`` the policy gave (stored
        clipped to the action Box, as applied), the violation masks ``mask`` (N,) and the
        env's ``sim_time``, ``poses`` and ``sensed`` after it."""
        applied = np.array([cmd[a] for a in self.agents], dtype=np.float64)
        # np.clip's own rule (minimum of maximum; NaN propagates), without its wrapper's cost
        self.actions.append(np.minimum(np.maximum(applied, self._low), self._high))
        self.first = first_violation(step, mask, self.first)
        self.masks.append(mask)
        self.times.append(sim_time)
        self.poses.append(poses)
        self.sensed.append(sensed)

    def episode(
        self,
        policy: Any,
        *,
        scenario: Any,
        seed: int | None,
        control_period: float,
        terminated: bool,
        truncated: bool,
        leader_arrived: bool,
    ) -> Episode:
        """The recorded :class:`Episode` of ``policy`` (its ``funnel_exits``, if it counts
        them) on ``scenario`` (the episode's :class:`~platoon_env.Scenario`: its name and
        ``d_des``), from ``reset(seed)``, with the env's ``control_period`` and how it ended."""
        n = len(self.agents)
        funnel = getattr(policy, "funnel_exits", None)
        cfg = scenario.config
        return Episode(
            scenario=scenario.name,
            seed=seed,
            control_period=control_period,
            d_des=scenario.config.formation.d_des,
            times=np.asarray(self.times),
            poses=np.asarray(self.poses),
            sensed=np.asarray(self.sensed),
            actions=np.asarray(self.actions).reshape(-1, n, 2),
            violations=np.asarray(self.masks).reshape(-1, n),
            terminated=terminated,
            truncated=truncated,
            leader_arrived=leader_arrived,
            first_violation=self.first,
            signals={k: np.asarray(v) for k, v in self.signals.items()},
            funnel_exits=int(np.sum(funnel)) if funnel is not None else 0,
            d_col=cfg.safety.d_col,
            d_con=cfg.camera.range,
            beta_con=cfg.camera.half_angle,
            radius=cfg.robot.radius,
            path_length=float(scenario.path_s[-1]),
        )


def run_episode(
    env: PlatoonParallelEnv,
    policy: PolicyLike,
    seed: int | None = None,
    *,
    max_steps: int | None = None,
    record_signals: bool = True,
    options: dict[str, Any] | None = None,
) -> Episode:
    """Roll ``policy`` out in ``env`` from ``reset(seed)`` until the episode ends.

    Args:
        max_steps: stop after this many steps even if the episode goes on (None: the env's
            own truncation rules decide).
        record_signals: also store ``policy.signals`` (a dict of arrays) after every step.
    """
    obs, _ = env.reset(seed=seed, options=options)
    policy.reset(seed=seed)
    space = env.action_space(env.possible_agents[0])
    # the episode's own followers: a drawn formation may have fewer than possible_agents
    rec = EpisodeRecorder(env.agents, space.low, space.high, env.sim_time, env.poses, env.sensed)
    terminated = truncated = False
    limit = max_steps if max_steps is not None else env.max_episode_steps
    for step in range(limit):
        cmd = policy.act(obs)
        if record_signals:
            rec.record_signals(policy)
        obs, _, terms, truncs, _infos = env.step(cmd)
        rec.record_step(step, cmd, env.violation_masks, env.sim_time, env.poses, env.sensed)
        terminated = any(terms.values())
        truncated = any(truncs.values())
        if terminated or truncated:
            break
    return rec.episode(
        policy,
        scenario=env.scenario,
        seed=seed,
        control_period=env.control_period,
        terminated=terminated,
        truncated=truncated,
        leader_arrived=env.leader_arrived,
    )


#: The constraints of :func:`constraint_margins`, in the order of the ``min_margin_*`` metrics.
MARGINS: tuple[str, ...] = ("distance_collision", "distance_range", "bearing", "clearance", "sight")


def constraint_margins(ep: Episode) -> dict[str, np.ndarray]:
    """Each constraint's normalised margin ``(T, N)`` after every step of ``ep`` (ground
    truth; 0 at the constraint's bound, negative beyond it):

    * ``distance_collision`` ``(d - d_col) / (d_des - d_col)`` and ``distance_range``
      ``(d_con - d) / (d_con - d_des)`` (eq. 4-5's distance bounds; 1 at the set point);
    * ``bearing`` ``(beta_con - |beta|) / beta_con`` (eq. 5; 1 straight ahead);
    * ``clearance`` ``(c - r) / r``: the clearance to the (inflated) obstacles beyond the
      robot's radius, in radii;
    * ``sight`` ``min(d_l, d_r) / r``: the line of sight's clearance to the obstacles on its
      left and right (0: occluded), in radii.
    """
    s = ep.sensed[1:]
    d, beta = s[..., SENSE_D], s[..., SENSE_BETA]
    r = ep.radius
    return {
        "distance_collision": (d - ep.d_col) / (ep.d_des - ep.d_col),
        "distance_range": (ep.d_con - d) / (ep.d_con - ep.d_des),
        "bearing": (ep.beta_con - np.abs(beta)) / ep.beta_con,
        "clearance": (s[..., SENSE_CLEARANCE] - r) / r,
        "sight": np.minimum(s[..., SENSE_D_SIGHT_LEFT], s[..., SENSE_D_SIGHT_RIGHT]) / r,
    }


def path_fraction(ep: Episode) -> float:
    """The fraction of the leader's path completed before the first violation (to the episode's
    end without one): 1 when the leader arrived with no violation, else the leader's travelled
    distance up to the violating step over the path's length, at most 1 (a pure-pursuit leader
    that cuts its corners travels a little less than its path)."""
    first = ep.first_violation
    if ep.leader_arrived and first is None:
        return 1.0
    end = ep.poses.shape[0] if first is None else first[0] + 2
    xy = ep.poses[:end, 0, :2]
    travelled = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
    return min(1.0, travelled / ep.path_length) if ep.path_length > 0 else math.nan


def episode_metrics(ep: Episode, transient: float = DEFAULT_TRANSIENT) -> dict[str, Any]:
    """The ``docs/metrics.md`` metrics of one episode.

    * ``success``: the leader reached its path's end and no violation occurred;
    * ``violation``: the first violation's cause ("" if none); ``time_to_violation`` [s]
      (``inf`` if none);
    * ``rms_e_d``, ``rms_e_beta``, ``max_abs_e_d``, ``max_abs_e_beta``: over followers and the
      steps after ``transient`` seconds (the whole episode if it is shorter), while visible;
    * ``min_inter_robot_distance`` (any two robots), ``min_obstacle_clearance`` (followers);
    * ``control_effort``: mean over followers of the time integral of ``u² + omega²``;
      ``peak_u``, ``peak_omega``: the largest ``|u|``, ``|omega|`` commanded;
      ``command_rate_u`` [m/s²], ``command_rate_omega`` [rad/s²]: the mean over followers and
      consecutive steps of ``|Δu| / control_period``, ``|Δomega| / control_period`` (how fast the
      commands change: a command that switches between its bounds every step is large here,
      a smooth one small; 0 for an episode of one step);
    * ``lost_sight_steps``: follower-steps without visibility; ``funnel_exits`` (PPC only);
    * the graded metrics, which show how far an episode got where success is binary:
      ``path_fraction`` (:func:`path_fraction`), and ``min_margin_distance`` (the smaller of the
      two distance margins), ``min_margin_bearing``, ``min_margin_clearance``,
      ``min_margin_sight``: each constraint's smallest normalised margin over followers and
      steps (:func:`constraint_margins`; negative: the bound was crossed).
    """
    dt = ep.control_period
    sensed = ep.sensed[1:]  # after each step
    times = ep.times[1:]
    # An episode that ends before the transient is over is scored over all of its steps (not
    # over its last step only, which a threshold of min(transient, end) would keep).
    ended_early = not times.size or times[-1] < transient
    after = np.ones(times.shape, dtype=bool) if ended_early else times >= transient
    visible = sensed[:, :, SENSE_VISIBLE] > 0
    sel = after[:, None] & visible
    e_d = sensed[:, :, SENSE_D] - ep.d_des
    e_b = sensed[:, :, SENSE_BETA]
    if np.any(sel):
        rms_e_d = float(np.sqrt(np.mean(e_d[sel] ** 2)))
        rms_e_b = float(np.sqrt(np.mean(e_b[sel] ** 2)))
        max_e_d = float(np.max(np.abs(e_d[sel])))
        max_e_b = float(np.max(np.abs(e_b[sel])))
    else:
        rms_e_d = rms_e_b = max_e_d = max_e_b = math.inf
    xy = ep.poses[:, :, :2]
    diff = xy[:, :, None, :] - xy[:, None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    iu = np.triu_indices(xy.shape[1], k=1)
    min_pair = float(np.min(dist[:, iu[0], iu[1]]))
    u = ep.actions[:, :, 0]
    w = ep.actions[:, :, 1]
    steps = u.shape[0] - 1  # consecutive pairs of commands
    first = ep.first_violation
    m = {k: float(np.min(v)) if v.size else math.nan for k, v in constraint_margins(ep).items()}
    return {
        "success": bool(ep.leader_arrived and first is None),
        "violation": "" if first is None else first[1],
        "time_to_violation": math.inf if first is None else float(ep.times[first[0] + 1]),
        "rms_e_d": rms_e_d,
        "rms_e_beta": rms_e_b,
        "max_abs_e_d": max_e_d,
        "max_abs_e_beta": max_e_b,
        "min_inter_robot_distance": min_pair,
        "min_obstacle_clearance": float(np.min(ep.sensed[:, :, SENSE_CLEARANCE])),
        "control_effort": float(np.mean(np.sum(u**2 + w**2, axis=0) * dt)) if u.size else 0.0,
        "peak_u": float(np.max(np.abs(u))) if u.size else 0.0,
        "peak_omega": float(np.max(np.abs(w))) if w.size else 0.0,
        "command_rate_u": float(np.mean(np.abs(np.diff(u, axis=0)))) / dt if steps > 0 else 0.0,
        "command_rate_omega": (
            float(np.mean(np.abs(np.diff(w, axis=0)))) / dt if steps > 0 else 0.0
        ),
        "steps": ep.steps,
        "sim_time": float(ep.times[-1]),
        "leader_arrived": bool(ep.leader_arrived),
        "lost_sight_steps": int(np.sum(~visible)),
        "funnel_exits": ep.funnel_exits,
        "path_fraction": path_fraction(ep),
        "min_margin_distance": min(m["distance_collision"], m["distance_range"]),
        "min_margin_bearing": m["bearing"],
        "min_margin_clearance": m["clearance"],
        "min_margin_sight": m["sight"],
    }
