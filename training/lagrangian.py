r"""A cost-constrained learner: PPO with a Lagrange multiplier on the env's ``cost`` signal.

The constrained problem (a CMDP) is

.. math::  \max_\pi J_r(\pi) \quad \text{s.t.} \quad J_c(\pi) \le b,

with ``J_c`` the expected **cost per episode** (the env's ``info["cost"]``: 1 at a step with a
safety violation, else 0; with the default ``terminate_on`` every violation ends the episode,
so ``J_c`` is the probability that an episode has a violation) and ``b`` the **budget**. Its
Lagrangian relaxation ``min_{λ ≥ 0} max_π J_r(π) - λ (J_c(π) - b)`` is solved by alternating:

* a PPO update on the penalised reward ``r_t - λ c_t`` (:class:`LagrangianVecEnv` subtracts
  it in the vector env, so SB3's PPO itself is unchanged);
* dual ascent on the multiplier after each rollout (:class:`LagrangeMultiplier`):
  ``λ ← max(0, λ + η (Ĵ_c - b))``, ``Ĵ_c`` the mean cost of the episodes that ended in the
  rollout; without a finished episode ``λ`` is left as it is.

This is the reward-penalty form of PPO-Lagrangian (Ray, Achiam and Amodei, *Benchmarking Safe
Exploration in Deep Reinforcement Learning*, 2019), with one critic for the penalised return
rather than separate reward and cost critics. The maintained libraries that implement the
two-critic form do not resolve with this project's stack: ``omnisafe`` 0.5 requires
``safety-gymnasium``, which pins ``gymnasium==0.28.1`` (this project needs Gymnasium >= 1.0).

Use: ``platoon-train --algo ppo_lagrangian --cost-budget 0.05 --lagrangian-lr 0.05``, or wrap a
vector env and add the callback by hand::

    venv = LagrangianVecEnv(vec_env, LagrangeMultiplier(budget=0.05, lr=0.05))
    model = PPO("MlpPolicy", venv)
    model.learn(100_000, callback=LagrangianCallback(venv))

The multiplier is logged to TensorBoard (``lagrangian/lambda``, ``lagrangian/episode_cost``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

__all__ = ["LagrangeMultiplier", "LagrangianCallback", "LagrangianVecEnv"]


@dataclass
class LagrangeMultiplier:
    """The multiplier ``λ`` and its dual-ascent rule.

    Args:
        budget: ``b``, the allowed expected cost per episode (>= 0).
        lr: ``η``, the dual step size (> 0).
        initial: ``λ`` at the start (>= 0).
        max_value: an upper bound on ``λ`` (keeps the penalised reward bounded).
    """

    budget: float
    lr: float = 0.05
    initial: float = 0.0
    max_value: float = 100.0
    value: float = field(init=False)

    def __post_init__(self) -> None:
        for name, lo, strict in (
            ("budget", 0.0, False),
            ("lr", 0.0, True),
            ("initial", 0.0, False),
        ):
            v = getattr(self, name)
            if not math.isfinite(v) or v < lo or (strict and v == lo):
                raise ValueError(
                    f"{name} must be finite and {'>' if strict else '>='} {lo}, got {v!r}"
                )
        if not (math.isfinite(self.max_value) and self.max_value >= self.initial):
            raise ValueError(f"max_value must be finite and >= initial, got {self.max_value!r}")
        self.value = float(self.initial)

    def update(self, episode_costs: np.ndarray | list[float]) -> float:
        """One dual-ascent step from the costs of the episodes that ended; returns ``λ``.

        ``λ ← clip(λ + η (mean(costs) - b), 0, max_value)``; no episodes: unchanged.
        """
        costs = np.asarray(episode_costs, dtype=np.float64)
        if costs.size == 0:
            return self.value
        if not np.all(np.isfinite(costs)):
            raise ValueError("episode costs must be finite")
        step = self.lr * (float(costs.mean()) - self.budget)
        self.value = float(min(max(self.value + step, 0.0), self.max_value))
        return self.value


class LagrangianVecEnv(VecEnvWrapper):
    """A vector env whose rewards are ``r - λ c`` (``c`` = ``info["cost"]`` of each slot), and
    which collects the cost of every finished episode for the multiplier's update.

    The unpenalised reward and the cost stay in each slot's info (``reward_unpenalised``,
    ``cost``), so episode statistics can report both.
    """

    def __init__(self, venv: VecEnv, multiplier: LagrangeMultiplier) -> None:
        super().__init__(venv)
        self.multiplier = multiplier
        self._episode_cost = np.zeros(self.num_envs)
        #: Costs of the episodes finished since :meth:`pop_episode_costs`.
        self.finished_costs: list[float] = []

    def reset(self) -> Any:
        self._episode_cost[:] = 0.0
        return self.venv.reset()

    def step_wait(self) -> tuple[Any, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs, rewards, dones, infos = self.venv.step_wait()
        costs = np.array([float(info.get("cost", 0.0)) for info in infos])
        if not np.all(np.isfinite(costs)):
            raise ValueError("info['cost'] must be finite")
        penalised = rewards - self.multiplier.value * costs
        self._episode_cost += costs
        for k, info in enumerate(infos):
            info["reward_unpenalised"] = float(rewards[k])
            if dones[k]:
                self.finished_costs.append(float(self._episode_cost[k]))
                self._episode_cost[k] = 0.0
        return obs, penalised.astype(rewards.dtype, copy=False), dones, infos

    def pop_episode_costs(self) -> list[float]:
        """The costs of the episodes finished since the last call (and forget them)."""
        out, self.finished_costs = self.finished_costs, []
        return out


class LagrangianCallback(BaseCallback):
    """Updates the multiplier of ``venv`` at the end of every rollout, and logs it.

    SB3 calls ``_on_rollout_end`` after a rollout is collected (its rewards already penalised
    with the old ``λ``) and before the PPO update on it, so a new ``λ`` shapes the rewards of
    the *next* rollout.
    """

    def __init__(self, venv: LagrangianVecEnv, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.venv = venv
        #: (timesteps, λ, mean episode cost or NaN) after each rollout.
        self.history: list[tuple[int, float, float]] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        costs = self.venv.pop_episode_costs()
        mean = float(np.mean(costs)) if costs else math.nan
        lam = self.venv.multiplier.update(costs)
        self.history.append((int(self.num_timesteps), lam, mean))
        self.logger.record("lagrangian/lambda", lam)
        if costs:
            self.logger.record("lagrangian/episode_cost", mean)
