r"""The privileged oracle: a receding-horizon planner that uses the simulation itself as its model.

**Privileged.** Unlike every other policy of this package, the oracle does not act on the
followers' sensors. Every replanning period it takes the env's whole true state
(:meth:`platoon_env.PlatoonParallelEnv.snapshot`: every robot's pose and applied velocity, the
leader's progress along its timed future, the perception buffers) and plans in ``K`` copies of
the batched core restored to that moment (:meth:`platoon_env.batched.BatchedPlatoon.restore`).
The model is therefore exact: the same unicycle arcs (eq. 1), actuator model (velocity box,
``accel_max``, ``alpha_max``, ``lag``), control period, leader, free space and constraint rules
(eqs. 4-5, occlusion) as the env. It is an upper reference for what a controller can achieve on a
task (``docs/feasibility.md``), never an entry of the pairwise comparisons: its registry entry,
its board rows and its cards say *privileged*.

**Plan.** Follower ``i``'s command at step ``t`` is a feedback term on its true distance and
bearing to its predecessor plus a planned correction held over a *knot* of ``knot`` control
steps::

    u_i     = k_u (d_i - d_des) cos(beta_i) + c_u[i, k]
    omega_i = k_omega beta_i                + c_omega[i, k]      k = (t - t_plan) // knot

(then clipped to the action box by the env, as any policy's command). The feedback keeps the
followers behind a planning follower reacting to their predecessor inside the rollouts; the
corrections ``c`` (``horizon`` knots per follower) are what is planned. Planning goes
**sequentially down the chain**: follower 1 first, against the leader's exact future; then
follower 2 against follower 1's new plan; and so on (the followers behind the one planning keep
their previous plans, shifted by one replanning period). Each follower's plan is improved by a
cross-entropy search: ``samples`` perturbed correction sequences (the incumbent among them, so a
plan never gets worse than the one it starts from), rolled out in the model for the whole
horizon, the lowest-cost one kept, ``iterations`` times with a shrinking spread. Because the
model is exact and the followers behind never change a follower's own constraints, the executed
trajectory is the planned one.

**Cost** of follower ``i`` over a rollout, per control step (``sensed`` ground truth, margins
normalised so that 1 is comfortable and 0 the constraint's boundary):

* ``w_violation`` for each step with any violation of follower ``i`` (any cause of
  ``VIOLATION_CAUSES``, terminating or not);
* ``w_margin (max(0, m_safe - m))^2`` for each margin ``m`` of: the distance to the collision
  bound ``(d - d_col) / (d_des - d_col)`` and to the range bound ``(d_con - d) / (d_con -
  d_des)`` (eqs. 4-5), the bearing ``1 - |beta| / beta_con`` (eq. 5), the obstacle clearance
  ``(clearance - r) / clearance_scale`` (the clearance to the outline inflated by
  ``safety.inflation``, as the collision rule reads it) and the line of sight's clearance
  ``min(d_l, d_r) / clearance_scale`` (occlusion);
* ``w_track`` times the squared normalised errors ``e_d / (d_con - d_des)`` and ``beta /
  beta_con`` (a formation to hold when nothing binds), and ``w_effort`` times the squared
  corrections.

A follower's plan is scored by its own cost plus ``w_behind`` times the cost of each follower
behind it (which react through their feedback and previous plans): a plan that leaves no way
through for the followers behind is not a good plan. Violations do not end the model's
rollouts (its copies run with ``terminate_on`` empty and no step limit), so that each
follower's cost counts its own violations.

**Speed** (one core, measured by ``experiments/studies/feasibility.py``, see
``docs/feasibility.md``): the ratio of wall time to simulated time is about
``followers * iterations * samples * horizon * knot / (knot * replan)`` model steps per
control step, each a fraction of a microsecond per copy in the compiled core.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines.policy import Followers, PolicyEnv
from platoon_env.batched import BatchedPlatoon
from platoon_env.core import CoreSnapshot
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
)

__all__ = ["OracleParams", "OraclePolicy"]


@dataclass(frozen=True)
class OracleParams:
    """The oracle's planning parameters (see the module docstring).

    Attributes:
        knot: control steps a planned correction is held.
        horizon: knots planned ahead (``horizon * knot * control_period`` seconds).
        replan: knots executed between two plans.
        samples: model copies ``K`` (rollouts per cross-entropy iteration).
        iterations: cross-entropy iterations per follower and plan.
        smooth: knots between the independent draws of a perturbation (linear between).
        sigma_u, sigma_omega: [m/s, rad/s] the first iteration's spread of the corrections;
            each further iteration halves it.
        k_u, k_omega: [1/s] the feedback gains on ``d - d_des`` and ``beta``.
        m_safe: the margin below which the cost grows.
        clearance_scale: [m] the clearance that counts as a margin of 1.
        w_violation, w_margin, w_track, w_effort: the cost's weights.
        w_behind: the weight of each follower behind the planning one in its cost.
    """

    knot: int = 10
    horizon: int = 30
    replan: int = 1
    samples: int = 32
    iterations: int = 2
    smooth: int = 5
    sigma_u: float = 0.3
    sigma_omega: float = 0.8
    k_u: float = 1.0
    k_omega: float = 3.0
    m_safe: float = 0.4
    clearance_scale: float = 0.2
    w_violation: float = 1000.0
    w_margin: float = 10.0
    w_track: float = 0.1
    w_effort: float = 0.01
    w_behind: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise TypeError(f"OracleParams.{f.name} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"OracleParams.{f.name} must be finite and >= 0, got {value}")
        for name in ("knot", "horizon", "replan", "samples", "iterations", "smooth"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"OracleParams.{name} must be an integer >= 1, got {value!r}")
        if self.replan > self.horizon:
            raise ValueError(
                f"OracleParams.replan ({self.replan}) must not exceed horizon ({self.horizon})"
            )


class OraclePolicy:
    """The privileged receding-horizon oracle (module docstring): it reads the env's true state
    through ``env.snapshot()`` and plans in copies of the batched core.

    Args:
        env: the env the policy acts in — the one stepped with its commands (it must offer
            :meth:`~platoon_env.PlatoonParallelEnv.snapshot`).
        **params: :class:`OracleParams` fields.
    """

    #: This policy reads ground truth (the board keeps it out of the comparisons).
    privileged = True

    def __init__(self, env: PolicyEnv, **params: Any) -> None:
        if not callable(getattr(env, "snapshot", None)):
            raise ValueError(
                "the oracle needs the env's true state: env.snapshot() (a PlatoonParallelEnv "
                "or a copy of the batched core)"
            )
        self.params = OracleParams(**params)
        self.env = env
        self.followers = Followers(env.possible_agents, env.scenario.config)
        self._model: BatchedPlatoon | None = None
        self._model_scenario: Any = None
        self._rng = np.random.default_rng(0)
        self._plan = np.zeros((0, 0, 2))
        self._t = 0
        #: Planning statistics of the episode: plans made, model steps simulated.
        self.plans = 0
        self.model_steps = 0

    # ----------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """A new episode: the plan starts at zero corrections; ``seed`` seeds the search."""
        self._rng = np.random.default_rng(seed)
        self._t = 0
        self._plan = np.zeros((self.params.horizon, 0, 2))
        self.plans = 0
        self.model_steps = 0

    def act(self, observations: dict[str, NDArray[Any]]) -> dict[str, NDArray[np.float32]]:
        """The commands of every live follower (the observations are not used: the oracle
        reads the true state)."""
        p = self.params
        snap = self.env.snapshot()  # type: ignore[attr-defined]
        if self._t % (p.knot * p.replan) == 0:
            self._replan(snap)
        k = (self._t % (p.knot * p.replan)) // p.knot
        n = int(snap.params[0]["n_followers"])
        pred_u = self._predecessor_speed(snap.episode["leader_u"], snap.rows["applied"][None], n)
        cmd = (
            self._feedback(
                snap.rows["sensed"][None, :n],
                snap.rows["poses"][None, : n + 1],
                pred_u,
                snap.params[0],
            )[0]
            + self._plan[k, :n]
        )
        self._t += 1
        agents = [a for a in self.env.possible_agents if a in observations] or list(
            self.env.possible_agents[:n]
        )
        return {a: cmd[i].astype(np.float32) for i, a in enumerate(agents)}

    # ----------------------------------------------------------------------------------------
    def _feedback(
        self,
        sensed: NDArray[np.float64],
        poses: NDArray[np.float64],
        pred_u: NDArray[np.float64],
        params: np.void,
    ) -> NDArray[np.float64]:
        """``(K, n, 2)`` feedback commands from ``(K, n, SENSE_SIZE)`` true sensing, the true
        poses ``(K, n + 1, 3)`` and each predecessor's applied speed ``(K, n)`` (privileged: a
        feedforward of the predecessor's speed along the follower's heading)."""
        p = self.params
        d = sensed[..., SENSE_D]
        beta = sensed[..., SENSE_BETA]
        heading = poses[..., 1:, 2] - poses[..., :-1, 2]
        out = np.empty((*d.shape, 2))
        out[..., 0] = pred_u * np.cos(heading) + p.k_u * (d - float(params["d_des"])) * np.cos(beta)
        out[..., 1] = p.k_omega * beta
        return out

    @staticmethod
    def _predecessor_speed(
        leader_u: NDArray[np.float64], applied: NDArray[np.float64], n: int
    ) -> NDArray[np.float64]:
        """``(K, n)`` each follower's predecessor's applied ``u``: the leader's, then the
        followers' ``1 .. n - 1``."""
        return np.concatenate([leader_u[:, None], applied[:, : n - 1, 0]], axis=1)

    def _model_for(self, snap: CoreSnapshot) -> BatchedPlatoon:
        """The ``K`` copies of the core the plans are tried in (built once per scenario)."""
        if self._model is None or self._model_scenario is not snap.scenario:
            self._model = BatchedPlatoon(snap.scenario, self.params.samples)
            self._model_scenario = snap.scenario
        return self._model

    def _replan(self, snap: CoreSnapshot) -> None:
        """Plan every follower's corrections from ``snap``, sequentially down the chain."""
        p = self.params
        n = int(snap.params[0]["n_followers"])
        model = self._model_for(snap)
        start = _planning_snapshot(snap)
        # Warm start: the previous plan shifted by the executed knots, its last knot repeated.
        plan = np.zeros((p.horizon, n, 2))
        if self._plan.shape[1] == n:
            keep = p.horizon - p.replan
            plan[:keep] = self._plan[p.replan :]
            plan[keep:] = self._plan[-1]
        for i in range(n):
            plan[:, i] = self._improve(model, start, plan, i, n)
        self._plan = plan
        self.plans += 1

    def _improve(
        self,
        model: BatchedPlatoon,
        start: CoreSnapshot,
        plan: NDArray[np.float64],
        i: int,
        n: int,
    ) -> NDArray[np.float64]:
        """Follower ``i``'s best correction sequence ``(horizon, 2)`` found by the
        cross-entropy search, the others' plans held."""
        p = self.params
        best = plan[:, i].copy()
        best_cost = math.inf
        sigma = np.array([p.sigma_u, p.sigma_omega])
        for _ in range(p.iterations):
            trials = best[None] + sigma * self._smooth_noise()
            trials[0] = best  # the incumbent: the plan never gets worse
            costs = self._rollout(model, start, plan, i, n, trials)
            k = int(np.argmin(costs))
            if costs[k] < best_cost:
                best, best_cost = trials[k].copy(), float(costs[k])
            sigma = sigma / 2.0
        return best

    def _smooth_noise(self) -> NDArray[np.float64]:
        """``(samples, horizon, 2)`` standard normal perturbations drawn at every ``smooth``-th
        knot and interpolated linearly between (a few degrees of freedom per sequence, so that
        a small population searches a long horizon)."""
        p = self.params
        points = np.arange(0, p.horizon + p.smooth, p.smooth)
        draws = self._rng.standard_normal((p.samples, points.size, 2))
        knots = np.arange(p.horizon)
        out = np.empty((p.samples, p.horizon, 2))
        for c in range(2):
            for s in range(p.samples):
                out[s, :, c] = np.interp(knots, points, draws[s, :, c])
        return out

    def _rollout(
        self,
        model: BatchedPlatoon,
        start: CoreSnapshot,
        plan: NDArray[np.float64],
        i: int,
        n: int,
        trials: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """The cost of each of follower ``i``'s ``K`` correction sequences ``trials``, the
        other followers on ``plan``, from ``start``, over the whole horizon: its own, plus
        ``w_behind`` times each follower's behind it."""
        p = self.params
        model.restore(start)
        prm = start.params[0]
        k_count = trials.shape[0]
        actions = np.zeros((k_count, model.n_followers, 2))
        cost = np.zeros(k_count)
        # Follower i's own cost, and the cost of the followers behind it (w_behind each): a
        # plan that leaves the followers behind no way through is not a good plan.
        weights = np.full(n - i, p.w_behind)
        weights[0] = 1.0
        sensed = start.rows["sensed"][None, :n].repeat(k_count, axis=0)
        poses = start.rows["poses"][None, : n + 1].repeat(k_count, axis=0)
        pred_u = self._predecessor_speed(
            np.full(k_count, float(start.episode[0]["leader_u"])),
            start.rows["applied"][None].repeat(k_count, axis=0),
            n,
        )
        for knot in range(p.horizon):
            corr = np.broadcast_to(plan[knot, :n], (k_count, n, 2)).copy()
            corr[:, i] = trials[:, knot]
            cost += p.w_effort * np.sum(trials[:, knot] ** 2, axis=1) * p.knot
            for _ in range(p.knot):
                actions[:, :n] = self._feedback(sensed, poses, pred_u, prm) + corr
                _, _, _, _, info = model.step(actions)
                sensed = model.sensed[:, :n]
                poses = model.poses[:, : n + 1]
                pred_u = self._predecessor_speed(
                    model.leader_velocity[:, 0], model.applied_velocities, n
                )
                cost += self._step_cost(sensed[:, i:], info["violations"][:, i:n], prm) @ weights
        self.model_steps += p.horizon * p.knot * k_count
        return cost

    def _step_cost(
        self, sensed: NDArray[np.float64], violations: NDArray[np.int64], prm: np.void
    ) -> NDArray[np.float64]:
        """``(K, m)`` the cost of one control step of ``m`` followers from their true sensing
        ``(K, m, SENSE_SIZE)`` and violation masks ``(K, m)`` (the module docstring's terms)."""
        p = self.params
        d_des, d_col, d_con = float(prm["d_des"]), float(prm["d_col"]), float(prm["d_con"])
        beta_con, r = float(prm["beta_con"]), float(prm["radius"])
        d, beta = sensed[..., SENSE_D], sensed[..., SENSE_BETA]
        margins = (
            (d - d_col) / (d_des - d_col),
            (d_con - d) / (d_con - d_des),
            1.0 - np.abs(beta) / beta_con,
            (sensed[..., SENSE_CLEARANCE] - r) / p.clearance_scale,
            np.minimum(sensed[..., SENSE_D_SIGHT_LEFT], sensed[..., SENSE_D_SIGHT_RIGHT])
            / p.clearance_scale,
        )
        cost = p.w_violation * (violations != 0)
        for m in margins:
            cost = cost + p.w_margin * np.maximum(0.0, p.m_safe - m) ** 2
        return cost + p.w_track * (((d - d_des) / (d_con - d_des)) ** 2 + (beta / beta_con) ** 2)

    def describe(self) -> dict[str, Any]:
        """The parameters, as plain data (for cards and provenance)."""
        return asdict(self.params)


def _planning_snapshot(snap: CoreSnapshot) -> CoreSnapshot:
    """``snap`` as the model runs it: without perception (the planner reads the truth), no
    violation ends a rollout (``terminate_on`` empty), and neither does the step limit or the
    leader's settle time (a rollout near the episode's end goes on behind the arrived
    leader)."""
    params = snap.params.copy()
    # The planner reads the ground truth only: the model skips the perception pipeline (noise,
    # dropouts, frames, latency), which changes no pose, no sensing and no violation.
    params["perceive"] = False
    params["random_perception"] = False
    params["terminate_mask"] = 0
    params["max_episode_steps"] = np.iinfo(np.int64).max // 2
    params["settle_time"] = 1e12
    episode = snap.episode.copy()
    episode["terminated"] = False
    episode["truncated"] = False
    return CoreSnapshot(
        scenario=snap.scenario,
        params=params,
        episode=episode,
        rows=snap.rows,
        rng_state=snap.rng_state,
        realism=snap.realism,
    )
