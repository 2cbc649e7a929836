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

**Plan.** Follower ``i``'s command at step ``t`` is a *base* command plus a planned correction
held over a *knot* of ``knot`` control steps::

    [u_i, omega_i] = base_i(t) + [c_u[i, k], c_omega[i, k]]      k = (t - t_plan) // knot

(then clipped to the action box by the env, as any policy's command). Two bases
(``OracleParams.base``):

* **guided** (the default, ``base`` a law of :data:`BASE_LAWS`, ``filtered_ppc_drive``): the
  base is a law acting on the followers' own sensors, as it does on the board. Each replanning
  period the oracle first rolls the *incumbent* (the law plus the previous plan's shifted
  corrections, zero where none are left) out in the model, a copy of the law with its state of
  now acting on the copy's own observations (the model keeps the env's perception, so its
  noise, frames and latency are the env's own). When no follower violates a constraint over
  the horizon the incumbent is kept: where the law is safe the oracle *is* the law, command
  for command. Otherwise the corrections are searched (below). So the guided oracle completes
  every episode its law completes, and more;
* **feedback** (``base="feedback"``): a privileged feedback on the true distance and bearing,
  with the predecessor's true speed as a feedforward,
  ``u_i = u_{i-1} cos(theta_{i-1} - theta_i) + k_u (d_i - d_des) cos(beta_i)``,
  ``omega_i = k_omega beta_i``, corrected every replanning period (the first oracle; it
  completes fewer study B episodes than the laws, ``docs/feasibility.md``).

The corrections ``c`` (``horizon`` knots per follower) are what is planned. Planning goes
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
rollouts (its copies run with ``terminate_on`` empty), so that each follower's cost counts its
own violations; the feedback oracle's rollouts also run past the step limit and the leader's
arrival, the guided oracle's stop where the env's episode would.

**Speed** (one core; ``docs/feasibility.md`` gives the measured ratio of wall time to
simulated time per task): the feedback oracle simulates ``followers * iterations * samples *
horizon / replan`` model steps per control step; the guided one ``horizon / replan`` while the
law is safe (one rollout per plan, each model step a law call of some microseconds and a
compiled core step) and the feedback oracle's count where it searches.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines.filtered_ppc import FilteredPPCPolicy
from baselines.filtered_ppc_drive import DriveAwareFilteredPPCPolicy
from baselines.policy import Policy, PolicyEnv
from baselines.ppc import PPCPolicy
from baselines.ppc_tuned import TunedPPCPolicy
from platoon_env.batched import BatchedPlatoon
from platoon_env.core import CoreSnapshot
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
)

__all__ = ["BASE_LAWS", "FEEDBACK", "OracleParams", "OraclePolicy"]

#: ``OracleParams.base`` of the unguided oracle: the privileged feedback on ``d`` and ``beta``.
FEEDBACK = "feedback"
#: The laws a guided oracle can add its corrections to (their registry names; each acts on the
#: followers' own sensors, as on the board).
BASE_LAWS: dict[str, type] = {
    "ppc": PPCPolicy,
    "ppc_tuned": TunedPPCPolicy,
    "filtered_ppc": FilteredPPCPolicy,
    "filtered_ppc_drive": DriveAwareFilteredPPCPolicy,
}


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
        base: the command the corrections are added to: ``"feedback"`` (the privileged
            feedback on the true ``d``, ``beta``) or a law of :data:`BASE_LAWS` acting on the
            followers' own sensors (*guided*: the law's commands are kept, uncorrected, as long
            as the exact model shows them safe over the horizon).
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
    base: str = "filtered_ppc_drive"

    def __post_init__(self) -> None:
        if self.base != FEEDBACK and self.base not in BASE_LAWS:
            raise ValueError(
                f"OracleParams.base must be {FEEDBACK!r} or one of {sorted(BASE_LAWS)}, "
                f"got {self.base!r}"
            )
        for f in fields(self):
            if f.name == "base":
                continue
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
        #: The guided oracle's base law (None: the privileged feedback).
        self.law: Policy | None = (
            None if self.params.base == FEEDBACK else BASE_LAWS[self.params.base](env)
        )
        self._model: BatchedPlatoon | None = None
        self._model_scenario: Any = None
        self._rng = np.random.default_rng(0)
        self._plan = np.zeros((0, 0, 2))
        self._t = 0
        self._interp = _interpolation(self.params.horizon, self.params.smooth)
        #: Planning statistics of the episode: plans made, model steps simulated, and (guided)
        #: the plans whose check found the incumbent unsafe and searched for corrections.
        self.plans = 0
        self.model_steps = 0
        self.searches = 0

    # ----------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """A new episode: the plan starts at zero corrections; ``seed`` seeds the search (and
        resets the base law)."""
        self._rng = np.random.default_rng(seed)
        self._t = 0
        self._plan = np.zeros((self.params.horizon, 0, 2))
        self.plans = 0
        self.model_steps = 0
        self.searches = 0
        if self.law is not None:
            self.law.reset(seed)

    def act(self, observations: dict[str, NDArray[Any]]) -> dict[str, NDArray[np.float32]]:
        """The commands of every live follower (the feedback oracle does not use the
        observations: it reads the true state; the guided oracle's base law acts on them)."""
        p = self.params
        snap = self.env.snapshot()  # type: ignore[attr-defined]
        n = int(snap.params[0]["n_followers"])
        agents = [a for a in self.env.possible_agents if a in observations] or list(
            self.env.possible_agents[:n]
        )
        if self._t % (p.knot * p.replan) == 0:
            if self.law is None:
                self._replan(snap)
            else:
                self._replan_guided(snap, agents[:n])
        k = (self._t % (p.knot * p.replan)) // p.knot
        if self.law is None:
            pred_u = self._predecessor_speed(
                snap.episode["leader_u"], snap.rows["applied"][None], n
            )
            base = self._feedback(
                snap.rows["sensed"][None, :n],
                snap.rows["poses"][None, : n + 1],
                pred_u,
                snap.params[0],
            )[0]
        else:
            cmd = self.law.act(observations)
            base = np.array([cmd[a] for a in agents[:n]], dtype=np.float64)
        out = base + self._plan[k, :n]
        self._t += 1
        return {a: out[i].astype(np.float32) for i, a in enumerate(agents)}

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

    def _shifted_plan(self, n: int) -> NDArray[np.float64]:
        """The previous plan shifted by the executed knots (the warm start): the feedback
        oracle repeats its last knot, the guided one falls back to the law (zeros)."""
        p = self.params
        plan = np.zeros((p.horizon, n, 2))
        if self._plan.shape[1] == n:
            keep = p.horizon - p.replan
            plan[:keep] = self._plan[p.replan :]
            if self.law is None:
                plan[keep:] = self._plan[-1]
        return plan

    def _replan(self, snap: CoreSnapshot) -> None:
        """Plan every follower's corrections from ``snap``, sequentially down the chain."""
        n = int(snap.params[0]["n_followers"])
        model = self._model_for(snap)
        start = _planning_snapshot(snap)
        plan = self._shifted_plan(n)
        for i in range(n):
            plan[:, i], _ = self._improve(model, start, plan, i, n)
        self._plan = plan
        self.plans += 1

    def _replan_guided(self, snap: CoreSnapshot, agents: list[str]) -> None:
        """The guided oracle's plan: the incumbent (the base law plus the shifted corrections)
        rolled out once in the exact model; kept when no follower violates a constraint over
        the horizon. Else the corrections are searched up the chain from the first follower
        that violates (its own corrections first, then its predecessors': no follower's
        corrections change the constraints of those ahead of it), until a plan is clean."""
        n = len(agents)
        model = self._model_for(snap)
        start = _guided_snapshot(snap)
        plan = self._shifted_plan(n)
        self.plans += 1
        _, violated = self._rollout_guided(model, start, agents, plan, 0, plan[None, :, 0])
        if not violated[0].any():
            self._plan = plan
            return
        self.searches += 1
        for i in range(int(np.argmax(violated[0])), -1, -1):
            plan[:, i], clean = self._improve(model, start, plan, i, n, agents)
            if clean:
                break
        self._plan = plan

    def _improve(
        self,
        model: BatchedPlatoon,
        start: CoreSnapshot,
        plan: NDArray[np.float64],
        i: int,
        n: int,
        agents: list[str] | None = None,
    ) -> tuple[NDArray[np.float64], bool]:
        """Follower ``i``'s best correction sequence ``(horizon, 2)`` found by the
        cross-entropy search, the others' plans held (``agents``: the guided oracle's
        followers, whose search stops at the first iteration that finds a plan without a
        violation), and whether that plan has none (the feedback oracle: False)."""
        p = self.params
        best = plan[:, i].copy()
        best_cost = math.inf
        clean = False
        sigma = np.array([p.sigma_u, p.sigma_omega])
        for _ in range(p.iterations):
            trials = best[None] + sigma * self._smooth_noise()
            trials[0] = best  # the incumbent: the plan never gets worse
            if agents is None:
                costs = self._rollout(model, start, plan, i, n, trials)
            else:
                costs, violated = self._rollout_guided(model, start, agents, plan, i, trials)
            k = int(np.argmin(costs))
            if costs[k] < best_cost:
                best, best_cost = trials[k].copy(), float(costs[k])
                clean = agents is not None and not violated[k].any()
            if clean:
                break
            sigma = sigma / 2.0
        return best, clean

    def _smooth_noise(self) -> NDArray[np.float64]:
        """``(samples, horizon, 2)`` standard normal perturbations drawn at every ``smooth``-th
        knot and interpolated linearly between (a few degrees of freedom per sequence, so that
        a small population searches a long horizon)."""
        draws = self._rng.standard_normal((self.params.samples, self._interp.shape[1], 2))
        out: NDArray[np.float64] = np.einsum("hp,spc->shc", self._interp, draws)
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
        weights = self._weights(i, n)
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

    def _rollout_guided(
        self,
        model: BatchedPlatoon,
        start: CoreSnapshot,
        agents: list[str],
        plan: NDArray[np.float64],
        i: int,
        trials: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """As :meth:`_rollout`, for the guided oracle: in each of the first ``len(trials)``
        copies a copy of the base law (its state now) acts on the copy's own observations
        (the model keeps the env's perception: same noise, frames and latency), plus the
        corrections. Returns each trial's cost and whether any follower violated a
        constraint. A copy stops where the episode would end by the leader's arrival or the
        step limit."""
        p = self.params
        assert self.law is not None
        n = len(agents)
        k_count = trials.shape[0]
        active = np.zeros(model.batch_size, dtype=bool)
        active[:k_count] = True
        obs = model.restore(start, envs=active)
        prm = start.params[0]
        laws = [copy.deepcopy(self.law) for _ in range(k_count)]
        actions = np.zeros((model.batch_size, model.n_followers, 2))
        cost = np.zeros(k_count)
        violated = np.zeros((k_count, n - i), dtype=bool)
        weights = self._weights(i, n)
        steps = 0
        for knot in range(p.horizon):
            corr = np.broadcast_to(plan[knot, :n], (k_count, n, 2)).copy()
            corr[:, i] = trials[:, knot]
            cost += p.w_effort * np.sum(trials[:, knot] ** 2, axis=1) * p.knot
            for _ in range(p.knot):
                live = np.flatnonzero(active[:k_count])
                if not live.size or violated.any(axis=1).all():
                    break
                for k in live.tolist():
                    cmd = laws[k].act({a: obs[k, j] for j, a in enumerate(agents)})
                    actions[k, :n] = [cmd[a] for a in agents]
                actions[:k_count, :n] += corr
                obs, _, terminated, truncated, info = model.step(actions, envs=active)
                steps += live.size
                bad = info["violations"][live, i:n] != 0
                violated[live] |= bad
                step_cost = self._step_cost(model.sensed[live, i:n], bad, prm)
                cost[live] += step_cost @ weights
                active[live] &= ~(terminated[live] | truncated[live])
        self.model_steps += steps
        return cost, violated

    def _weights(self, i: int, n: int) -> NDArray[np.float64]:
        """Follower ``i``'s own cost (1) and ``w_behind`` for each follower behind it: a plan
        that leaves the followers behind no way through is not a good plan."""
        weights = np.full(n - i, self.params.w_behind)
        weights[0] = 1.0
        return weights

    def _step_cost(
        self, sensed: NDArray[np.float64], violations: NDArray[Any], prm: np.void
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


def _interpolation(horizon: int, smooth: int) -> NDArray[np.float64]:
    """``(horizon, points)``: linear interpolation from draws at every ``smooth``-th knot (the
    last point at or past the horizon) to every knot."""
    points = np.arange(0, horizon + smooth, smooth)
    out = np.zeros((horizon, points.size))
    for h in range(horizon):
        j = min(h // smooth, points.size - 2)
        w = (h - points[j]) / smooth
        out[h, j] = 1.0 - w
        out[h, j + 1] = w
    return out


def _planning_snapshot(snap: CoreSnapshot) -> CoreSnapshot:
    """``snap`` as the feedback oracle's model runs it: without perception (the planner reads
    the truth), no violation ends a rollout (``terminate_on`` empty), and neither does the step
    limit or the leader's settle time (a rollout near the episode's end goes on behind the
    arrived leader)."""
    params = snap.params.copy()
    # The planner reads the ground truth only: the model skips the perception pipeline (noise,
    # dropouts, frames, latency), which changes no pose, no sensing and no violation.
    params["perceive"] = False
    params["random_perception"] = False
    params["terminate_mask"] = 0
    params["max_episode_steps"] = np.iinfo(np.int64).max // 2
    params["settle_time"] = 1e12
    return _with_params(snap, params)


def _guided_snapshot(snap: CoreSnapshot) -> CoreSnapshot:
    """``snap`` as the guided oracle's model runs it: the env's own perception (its base law
    acts on the observations it would get) and its own end (the leader's arrival, the step
    limit), but no violation ends a rollout, so that each one's cost counts them all."""
    params = snap.params.copy()
    params["terminate_mask"] = 0
    return _with_params(snap, params)


def _with_params(snap: CoreSnapshot, params: NDArray[Any]) -> CoreSnapshot:
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
