"""Ray RLlib integration: the platoon as an RLlib ``MultiAgentEnv``, PPO with one shared policy
for every follower (optionally with a MAPPO-style centralised critic), and ``platoon-train
--engine rllib``.

Needs the ``rllib`` extra on top of ``train`` (``docs/rllib.md``)::

    pip install torch==2.13.0 -e ".[train,rllib]"

What this module fixes against wrapping the env in RLlib's ``ParallelPettingZooEnv`` (each
found and checked on RLlib 2.60, see ``docs/rllib.md``):

* **Time limits stay truncations.** RLlib's ``MultiAgentEpisode`` marks an episode
  *terminated* once every agent is done, whatever flag made it done, so a time-limit episode
  reported with per-agent ``truncated=True`` arrives as ``is_terminated=True`` and GAE does
  not bootstrap its last value. :class:`PlatoonMultiAgentEnv` reports a truncation only
  through ``truncateds["__all__"]`` (per-agent flags False): time-limit episodes arrive as
  ``(is_terminated, is_truncated) = (False, True)``, violations as ``(True, False)``.
* **Distinct seeds for every sub-env.** RLlib seeds sub-env ``j`` of env runner ``w`` with
  ``seed + w + j``, so runners replay each other's starts and procedural layouts.
  :func:`seed_sub_envs` (installed by :func:`ppo_config` as the ``on_environment_created``
  callback) gives each sub-env ``derived_seed(seed, w, j, segment=s)``, drawn from
  ``numpy.random.SeedSequence(seed, spawn_key=(s, w, j, evaluation))`` where ``s`` is the
  training segment (0 for a new run, one more per ``--resume``: a resumed run continues with
  fresh streams instead of replaying its first episodes). The rule is the SB3 engine's
  (:mod:`training.seeding`); it changes which layouts a new training run sees, not evaluation.
* **Deterministic agent order** (``possible_agents`` order, not a set's) and a working
  :meth:`~PlatoonMultiAgentEnv.render`.
* **The SB3 adapter's scaling** (:mod:`training.vec_env`): observations divided by their Box
  bound, actions in ``[-1, 1]^2`` mapped by :class:`~training.vec_env.ActionRange` (RLlib's
  own action normalisation would map ``[-1, 1]`` onto the ±10 m/s actuator box).

What ``platoon-train --engine rllib`` adds on top, so its runs read like the SB3 engine's:

* ``--algo ppo_lagrangian``: the driver keeps :class:`training.lagrangian.LagrangeMultiplier`
  and sets it on every env before each iteration; the envs' rewards are ``r - λ c`` (``c`` =
  ``info["cost"]``), and after the iteration ``λ`` takes its dual-ascent step on the costs of
  the follower episodes that ended in it (SB3's ``LagrangianCallback`` rule).
* ``progress.csv`` (:class:`training.curves.ProgressLog`, the SB3 runs' columns, a row once
  ``--log-every`` timesteps have passed, checked after each iteration) and ``tb/`` with SB3's
  scalar names, both from the episodes each env records (:class:`EpisodeOutcome`).
* ``--task-aware-observations`` (and any scenario ``observation`` block): the actor's input is
  the scenario's observation length, not always 7.
* On a cluster (``--address``), :func:`project_runtime_env` ships ``platoon_env`` and
  ``training`` to every node, and ``model.json``'s ``ray`` entry records which node each env
  runner ran on and how many env steps it took (:func:`cluster_metadata`).

The policy is :class:`PlatoonPPOModule`: an MLP actor on the follower's own (normalised)
observation, shared by all followers, and a critic that reads either the same observation
(``critic="local"``) or, MAPPO-style, the follower's observation plus the normalised global
state ``env.state()`` and a one-hot of the follower's index (``critic="central"``). The actor
never sees the state, so a trained policy acts from the follower's sensors alone; it is
exported as plain arrays (``model.zip`` + ``model.json``) that :class:`training.LearnedPolicy`
loads without Ray, so ``platoon-evaluate --policy NAME=DIR`` evaluates it like an SB3 model.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import shutil
import sys
import time
from collections import deque
from collections.abc import Mapping
from contextlib import closing
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import ray  # type: ignore[import-not-found]
import torch
from gymnasium import spaces
from numpy.typing import NDArray
from ray.rllib.algorithms.ppo import PPOConfig  # type: ignore[import-not-found]
from ray.rllib.core.columns import Columns  # type: ignore[import-not-found]
from ray.rllib.core.rl_module.apis.value_function_api import (  # type: ignore[import-not-found]
    ValueFunctionAPI,
)
from ray.rllib.core.rl_module.multi_rl_module import (  # type: ignore[import-not-found]
    MultiRLModuleSpec,
)
from ray.rllib.core.rl_module.rl_module import RLModuleSpec  # type: ignore[import-not-found]
from ray.rllib.core.rl_module.torch import TorchRLModule  # type: ignore[import-not-found]
from ray.rllib.env.multi_agent_env import MultiAgentEnv  # type: ignore[import-not-found]
from ray.tune.registry import register_env  # type: ignore[import-not-found]

import platoon_env
from platoon_env.action_range import ActionRange, check_action_range, normalised_action_space
from platoon_env.env import PlatoonParallelEnv
from platoon_env.observation import ACT_SIZE, OBS_SIZE
from platoon_env.scenarios.schema import VIOLATION_CAUSES
from training.algorithms import has_multiplier, trained_by
from training.config import TrainConfig, checked, env_metadata, env_overrides, net_arch
from training.curves import PROGRESS_FILE, ProgressLog
from training.lagrangian import LagrangeMultiplier
from training.policies import save_exported_policy
from training.run import (
    RLLIB_CHECKPOINT,
    RunPlan,
    Segment,
    finished_run,
    hold_run,
    library_versions,
    open_run,
    report_interrupt,
)
from training.seeding import stream_seed
from training.vec_env import normalised_box, observation_scale

__all__ = [
    "CRITICS",
    "ENV_NAME",
    "LAGRANGIAN_ALGOS",
    "MAX_RECORDED_EPISODES",
    "MODULE_ID",
    "PROJECT_PACKAGES",
    "TRAIN_SCALARS",
    "EpisodeOutcome",
    "PlatoonMultiAgentEnv",
    "PlatoonPPOModule",
    "cluster_metadata",
    "derived_seed",
    "env_config",
    "export_actor",
    "init_ray",
    "ppo_config",
    "project_runtime_env",
    "register",
    "seed_sub_envs",
    "train_rllib",
]

#: The name the env is registered under with Ray (``config.environment(ENV_NAME, ...)``).
ENV_NAME = "platoon_env"
#: The one RLModule every follower maps to (parameter sharing).
MODULE_ID = "shared_follower"
#: What the critic reads: the follower's observation, or MAPPO's observation + global state.
CRITICS = ("local", "central")
#: The ``--algo`` values the RLlib engine trains: PPO, and PPO on rewards penalised by a
#: Lagrange multiplier on ``info["cost"]`` (:mod:`training.lagrangian`'s rule).
LAGRANGIAN_ALGOS = trained_by("rllib")
#: Episode records an env keeps for the driver (:meth:`PlatoonMultiAgentEnv.pop_outcomes`);
#: ``platoon-train`` collects them every iteration, far below this.
MAX_RECORDED_EPISODES = 100_000
#: The project's own packages, shipped to every Ray node by :func:`project_runtime_env`.
PROJECT_PACKAGES = ("platoon_env", "training")


# ------------------------------------------------------------------------------------------------
# Seeds
# ------------------------------------------------------------------------------------------------
def derived_seed(
    seed: int,
    worker_index: int,
    vector_index: int,
    evaluation: bool = False,
    *,
    segment: int = 0,
) -> int:
    """The reset seed of sub-env ``vector_index`` of env runner ``worker_index`` in training
    segment ``segment`` (:mod:`training.seeding`).

    Drawn from ``SeedSequence(seed, spawn_key=(segment, worker_index, vector_index,
    evaluation))``: distinct, well-mixed streams for every (segment, runner, sub-env), unlike
    RLlib's ``seed + worker_index + vector_index``.
    """
    return stream_seed(seed, segment, worker_index, vector_index, int(evaluation))


def seed_sub_envs(
    env_runner: Any = None, env: Any = None, env_context: Any = None, **_: Any
) -> None:
    """RLlib ``on_environment_created`` callback: give each sub-env its :func:`derived_seed`.

    RLlib builds every sub-env of a runner from one ``EnvContext`` (``vector_index`` 0), so
    the sub-env's index is taken from its place in the runner's vector env here.
    """
    config = getattr(env_runner, "config", None)
    seed = getattr(config, "seed", None)
    worker_index = int(getattr(env_runner, "worker_index", 0) or 0)
    evaluation = bool(getattr(config, "in_evaluation", False))
    for j, sub in enumerate(getattr(env, "envs", [env])):
        target = getattr(sub, "unwrapped", sub)
        if isinstance(target, PlatoonMultiAgentEnv):
            target.assign_seed(
                seed, worker_index=worker_index, vector_index=j, evaluation=evaluation
            )


# ------------------------------------------------------------------------------------------------
# The env
# ------------------------------------------------------------------------------------------------
def _state_normaliser(space: spaces.Box) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``(centre, half_width)`` mapping ``space`` affinely onto ``[-1, 1]`` (degenerate: 1)."""
    low = space.low.astype(np.float64)
    high = space.high.astype(np.float64)
    half = (high - low) / 2.0
    half[half <= 0] = 1.0
    return ((low + high) / 2.0).astype(np.float32), half.astype(np.float32)


@dataclasses.dataclass(frozen=True)
class EpisodeOutcome:
    """How one episode of a :class:`PlatoonMultiAgentEnv` ended, per follower (in
    ``possible_agents`` order): the return of the env's reward (before any Lagrangian
    penalty), the cost (the sum of ``info["cost"]``), and the last step's violation cause
    (None: none); ``length`` in env steps."""

    returns: tuple[float, ...]
    costs: tuple[float, ...]
    length: int
    violations: tuple[str | None, ...]

    @property
    def team_success(self) -> bool:
        """No follower had a violation (the ``success_rate`` rule of :mod:`training.curves`)."""
        return all(c == 0 for c in self.costs)


class PlatoonMultiAgentEnv(MultiAgentEnv):  # type: ignore[misc]
    """A platoon ``ParallelEnv`` as an RLlib ``MultiAgentEnv`` (the fixes of the module doc).

    ``config`` (RLlib's ``env_config``, usually an ``EnvContext``): ``scenario`` (name, YAML
    path or dict; default ``study_c``), ``overrides`` (``platoon_env.make`` keyword
    arguments), ``sensor_profile`` (a realism profile name or YAML path, e.g. ``"aruco"``),
    ``render_mode``, ``diagnostics`` (default False: lean infos), ``normalize_observations``
    (default True), ``action_range`` (an :class:`ActionRange` dict; default
    ``ActionRange()``; None for physical actions in the env's box), ``critic`` (``"local"``
    or ``"central"``: the latter appends the normalised ``env.state()`` and a one-hot of the
    follower's index to every observation, for :class:`PlatoonPPOModule`'s critic),
    ``seed_segment`` (default 0: the training segment whose streams :meth:`assign_seed`
    draws, see :func:`derived_seed`).

    Per-agent observation: the follower's normalised observations (the 7-vector, or the
    task-aware layout the scenario's ``observation`` block selects; then, with the central
    critic, the state and the one-hot). Per-agent action: ``[-1, 1]^2``. Reward: the env's,
    minus :attr:`cost_multiplier` times ``info["cost"]``.
    """

    def __init__(self, config: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        cfg = dict(config or {})
        unknown = set(cfg) - {
            "scenario",
            "overrides",
            "sensor_profile",
            "render_mode",
            "diagnostics",
            "normalize_observations",
            "action_range",
            "critic",
            "seed_segment",
        }
        if unknown:
            raise ValueError(f"unknown env_config key(s): {', '.join(sorted(unknown))}")
        overrides = dict(cfg.get("overrides") or {})
        if cfg.get("sensor_profile") is not None:
            overrides["sensor_profile"] = cfg["sensor_profile"]
        self.critic = str(cfg.get("critic", "local"))
        if self.critic not in CRITICS:
            raise ValueError(f"critic must be one of {CRITICS}, got {self.critic!r}")
        self.env: PlatoonParallelEnv = platoon_env.make(
            cfg.get("scenario", "study_c"),
            render_mode=cfg.get("render_mode"),
            diagnostics=bool(cfg.get("diagnostics", False)),
            **overrides,
        )
        self.render_mode = self.env.render_mode
        env = self.env
        self.possible_agents = list(env.possible_agents)
        self.agents: list[str] = []
        self._agent_ids = set(self.possible_agents)
        obs_space = env.observation_space(self.possible_agents[0])
        self.obs_scale: NDArray[np.float32] | None = (
            observation_scale(obs_space) if cfg.get("normalize_observations", True) else None
        )
        act = cfg.get("action_range", ActionRange().to_dict())
        self.action_range: ActionRange | None = None if act is None else ActionRange(**act)
        if self.action_range is not None:
            check_action_range(
                self.action_range, env.action_space(self.possible_agents[0]), "the env"
            )
        scaled = normalised_box(obs_space, self.obs_scale)
        low, high = scaled.low, scaled.high
        n = len(self.possible_agents)
        self._state_centre, self._state_half = _state_normaliser(env.state_space)
        if self.critic == "central":
            extra = env.state_space.shape[0] + n
            low = np.concatenate([low, -np.ones(extra)])
            high = np.concatenate([high, np.ones(extra)])
        self._one_hot = np.eye(n, dtype=np.float32)
        obs_box = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        act_box = (
            normalised_action_space()
            if self.action_range is not None
            else env.action_space(self.possible_agents[0])
        )
        self.observation_spaces: dict[str, spaces.Space[Any]] = {
            a: obs_box for a in self.possible_agents
        }
        self.action_spaces: dict[str, spaces.Space[Any]] = {
            a: act_box for a in self.possible_agents
        }
        self.observation_space = spaces.Dict(self.observation_spaces)
        self.action_space = spaces.Dict(self.action_spaces)
        #: The length of one follower's own observation (7, or 13 task-aware, ...): the
        #: actor's input, the first columns of the per-agent observation.
        self.obs_size = int(obs_space.shape[0])
        #: The Lagrange multiplier ``λ`` (``ppo_lagrangian``): rewards are ``r - λ c`` with
        #: ``c`` = ``info["cost"]``; 0: the env's reward (set by the driver each iteration).
        self.cost_multiplier = 0.0
        #: Episodes that ended since :meth:`pop_outcomes` (unpenalised returns, costs); the
        #: oldest are dropped beyond :data:`MAX_RECORDED_EPISODES` when nobody collects them.
        self.finished: deque[EpisodeOutcome] = deque(maxlen=MAX_RECORDED_EPISODES)
        #: Env steps taken by this env (over all its episodes).
        self.env_steps = 0
        self._episode_return = np.zeros(n)
        self._episode_cost = np.zeros(n)
        self._episode_length = 0
        self._assigned_seed: int | None = None
        self.seed_segment = int(cfg.get("seed_segment", 0))
        self.worker_index, self.vector_index = 0, 0
        #: The seed of the last seeded reset (None: never seeded).
        self.seeded_with: int | None = None

    # -- seeds ---------------------------------------------------------------------------------
    def assign_seed(
        self,
        seed: int | None,
        *,
        worker_index: int,
        vector_index: int,
        evaluation: bool = False,
    ) -> None:
        """Use :func:`derived_seed` (of this env's ``seed_segment``) in place of the seed RLlib
        passes to a seeded reset (``seed`` None: keep RLlib's, which is then None too)."""
        self.worker_index, self.vector_index = worker_index, vector_index
        self._assigned_seed = (
            None
            if seed is None
            else derived_seed(
                seed, worker_index, vector_index, evaluation, segment=self.seed_segment
            )
        )

    # -- MultiAgentEnv API ---------------------------------------------------------------------
    def _observations(self, obs: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[np.float32]]:
        stacked = np.stack([obs[a] for a in self.possible_agents]).astype(np.float32)
        if self.obs_scale is not None:
            stacked /= self.obs_scale
        if self.critic == "central":
            state = (self.env.state() - self._state_centre) / self._state_half
            n = len(self.possible_agents)
            stacked = np.concatenate(
                [stacked, np.broadcast_to(state, (n, state.shape[0])), self._one_hot], axis=1
            ).astype(np.float32)
        return {a: stacked[i] for i, a in enumerate(self.possible_agents)}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, NDArray[np.float32]], dict[str, dict[str, Any]]]:
        """Reset the platoon; a seeded reset from RLlib uses the assigned derived seed."""
        if seed is not None and self._assigned_seed is not None:
            seed = self._assigned_seed
        if seed is not None:
            self.seeded_with = seed
        obs, infos = self.env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._episode_return[:] = 0.0
        self._episode_cost[:] = 0.0
        self._episode_length = 0
        return self._observations(obs), {a: infos.get(a, {}) for a in self.possible_agents}

    def step(self, action_dict: Mapping[str, Any]) -> tuple[dict[str, Any], ...]:
        """Step with normalised actions; a time limit is reported in ``truncateds["__all__"]``
        only (see the module doc), a violation in every agent's ``terminateds``. The rewards
        are the env's minus ``cost_multiplier`` times ``info["cost"]``; an ended episode is
        appended to :attr:`finished` with its unpenalised returns."""
        actions = np.stack(
            [np.asarray(action_dict[a], dtype=np.float32).reshape(ACT_SIZE) for a in self.agents]
        )
        if self.action_range is not None:
            actions = self.action_range.to_physical(actions)
        obs, rew, term, trunc, infos = self.env.step(
            {a: actions[i] for i, a in enumerate(self.agents)}
        )
        terminated = any(term.values())
        truncated = any(trunc.values()) and not terminated
        agents = list(self.agents)
        terminateds: dict[str, bool] = dict.fromkeys(agents, terminated)
        terminateds["__all__"] = terminated
        truncateds: dict[str, bool] = dict.fromkeys(agents, False)
        truncateds["__all__"] = truncated
        raw = np.array([float(rew[a]) for a in agents])
        cost = np.array([float(infos[a].get("cost", 0.0)) for a in agents])
        if not np.all(np.isfinite(cost)):
            raise ValueError("info['cost'] must be finite")
        self._episode_return += raw
        self._episode_cost += cost
        self._episode_length += 1
        self.env_steps += 1
        penalised = raw - self.cost_multiplier * cost if self.cost_multiplier else raw
        if terminated or truncated:
            self.agents = []
            self.finished.append(
                EpisodeOutcome(
                    returns=tuple(self._episode_return.tolist()),
                    costs=tuple(self._episode_cost.tolist()),
                    length=self._episode_length,
                    violations=tuple(infos[a].get("violation") for a in agents),
                )
            )
        rewards = {a: float(penalised[i]) for i, a in enumerate(agents)}
        return self._observations(obs), rewards, terminateds, truncateds, dict(infos)

    def pop_outcomes(self) -> list[EpisodeOutcome]:
        """The episodes that ended since the last call (and forget them)."""
        out = list(self.finished)
        self.finished.clear()
        return out

    def render(self) -> NDArray[np.uint8] | None:
        """The platoon env's frame (``render_mode`` from ``env_config``)."""
        return self.env.render()

    def state(self) -> NDArray[np.float32]:
        """The raw global state of the platoon (:meth:`PlatoonParallelEnv.state`)."""
        return self.env.state()

    def close(self) -> None:
        """Close the platoon env (its renderer)."""
        self.env.close()


def _env_creator(config: Mapping[str, Any]) -> PlatoonMultiAgentEnv:
    return PlatoonMultiAgentEnv(config)


def register(name: str = ENV_NAME) -> str:
    """Register :class:`PlatoonMultiAgentEnv` with Ray under ``name`` (on every process)."""
    register_env(name, _env_creator)
    return name


# ------------------------------------------------------------------------------------------------
# The RLModule
# ------------------------------------------------------------------------------------------------
def _mlp(sizes: list[int], out_gain: float) -> torch.nn.Sequential:
    """Linear/Tanh layers, orthogonally initialised as SB3 does (hidden gain sqrt 2)."""
    layers: list[torch.nn.Module] = []
    for k in range(len(sizes) - 1):
        lin = torch.nn.Linear(sizes[k], sizes[k + 1])
        last = k == len(sizes) - 2
        torch.nn.init.orthogonal_(lin.weight, gain=out_gain if last else math.sqrt(2))
        torch.nn.init.zeros_(lin.bias)
        layers.append(lin)
        if not last:
            layers.append(torch.nn.Tanh())
    return torch.nn.Sequential(*layers)


class PlatoonPPOModule(TorchRLModule, ValueFunctionAPI):  # type: ignore[misc]
    """PPO's actor-critic for the followers: one shared actor, a local or centralised critic.

    ``model_config``: ``hidden`` (layer sizes of both MLPs, default ``[64, 64]``, Tanh),
    ``obs_dim`` (the follower's own observation length, the first columns of the module's
    observation; default 7), ``critic`` (``"local"``: the critic reads those columns;
    ``"central"``: it reads the whole observation, i.e. also the global state and the
    follower's one-hot appended by :class:`PlatoonMultiAgentEnv`), ``log_std_init`` (0).

    The actor reads only the first ``obs_dim`` columns and outputs the Gaussian mean; the
    log standard deviation is a free parameter (state-independent, as in SB3). The greedy
    action is the mean, which is what :func:`export_actor` exports.
    """

    def setup(self) -> None:
        """Build the actor, the log-std parameter and the critic."""
        mc = dict(self.model_config or {})
        hidden = [int(h) for h in mc.get("hidden", [64, 64])]
        self.obs_dim = int(mc.get("obs_dim", OBS_SIZE))
        self.critic_kind = str(mc.get("critic", "local"))
        if self.critic_kind not in CRITICS:
            raise ValueError(f"critic must be one of {CRITICS}, got {self.critic_kind!r}")
        in_dim = int(self.observation_space.shape[0])
        act_dim = int(self.action_space.shape[0])
        self.actor = _mlp([self.obs_dim, *hidden, act_dim], out_gain=0.01)
        self.log_std = torch.nn.Parameter(
            torch.full((act_dim,), float(mc.get("log_std_init", 0.0)))
        )
        critic_in = in_dim if self.critic_kind == "central" else self.obs_dim
        self.critic = _mlp([critic_in, *hidden, 1], out_gain=1.0)

    def _forward(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        mean = self.actor(batch[Columns.OBS][..., : self.obs_dim])
        log_std = self.log_std.expand_as(mean)
        return {Columns.ACTION_DIST_INPUTS: torch.cat([mean, log_std], dim=-1)}

    def compute_values(self, batch: dict[str, Any], embeddings: Any = None) -> torch.Tensor:
        """The critic's value of each row of ``batch[OBS]`` (the central critic reads it all)."""
        obs = batch[Columns.OBS]
        x = obs if self.critic_kind == "central" else obs[..., : self.obs_dim]
        return self.critic(x).squeeze(-1)  # type: ignore[no-any-return]


def export_actor(module_or_weights: Any) -> dict[str, NDArray[np.float32]]:
    """The actor of a :class:`PlatoonPPOModule` (the module or its state dict, e.g. from
    ``LearnerGroup.get_weights``) as arrays ``W0, b0, W1, b1, ...`` (Tanh between layers), the
    form :class:`training.policies.MLPActor` evaluates."""
    state = (
        module_or_weights.state_dict()
        if hasattr(module_or_weights, "state_dict")
        else module_or_weights
    )

    def array(value: Any) -> NDArray[np.float32]:
        if isinstance(value, torch.Tensor):
            value = value.detach().cpu().numpy()
        return np.asarray(value, dtype=np.float32)

    layers = sorted(
        int(k.split(".")[1]) for k in state if k.startswith("actor.") and k.endswith(".weight")
    )
    if not layers:
        raise ValueError("no actor.<i>.weight entries: not a PlatoonPPOModule")
    arrays: dict[str, NDArray[np.float32]] = {}
    for n, i in enumerate(layers):
        arrays[f"W{n}"] = array(state[f"actor.{i}.weight"])
        arrays[f"b{n}"] = array(state[f"actor.{i}.bias"])
    return arrays


def learner_weights(algo: Any) -> Mapping[str, Any]:
    """The shared module's current weights, from the learner group (local or remote)."""
    weights = algo.learner_group.get_weights(module_ids=[MODULE_ID])
    return weights[MODULE_ID] if MODULE_ID in weights else weights


# ------------------------------------------------------------------------------------------------
# Config and training
# ------------------------------------------------------------------------------------------------
def env_config(cfg: TrainConfig, segment: int = 0) -> dict[str, Any]:
    """The ``env_config`` of the training envs of segment ``segment``: the same env as the SB3
    path's."""
    overrides = env_overrides(cfg)
    overrides.pop("sensor_profile", None)
    return {
        "scenario": cfg.scenario,
        "overrides": overrides,
        "sensor_profile": cfg.sensor_profile,
        "normalize_observations": cfg.normalize_observations,
        "action_range": cfg.action_range.to_dict(),
        "critic": cfg.critic,
        "seed_segment": segment,
    }


def _policy_mapping(agent_id: Any, episode: Any = None, **kwargs: Any) -> str:
    return MODULE_ID


def ppo_config(cfg: TrainConfig, segment: int = 0, obs_size: int | None = None) -> PPOConfig:
    """RLlib PPO (new API stack) for ``cfg``: the registered env, ``cfg.num_env_runners``
    runners of ``cfg.n_envs`` sub-envs each, derived seeds (of training segment ``segment``),
    one shared :class:`PlatoonPPOModule`, and SB3's hyper-parameters (``n_steps`` env steps
    per sub-env per rollout, ``batch_size`` follower transitions per minibatch, no KL
    penalty, no value clipping).

    ``cfg.algo`` is ``ppo`` or ``ppo_lagrangian`` (the same PPO: the driver sets the envs'
    :attr:`~PlatoonMultiAgentEnv.cost_multiplier`, :func:`train_rllib`). ``obs_size``: the
    length of a follower's own observation, the actor's input (None: read from one env of
    ``cfg``; 13 with ``--task-aware-observations``)."""
    if cfg.algo not in LAGRANGIAN_ALGOS:
        raise ValueError(
            f"--engine rllib trains {' and '.join(LAGRANGIAN_ALGOS)}, got --algo {cfg.algo}"
        )
    if cfg.num_env_runners < 0 or cfg.n_envs < 1:
        raise ValueError("need --num-env-runners >= 0 and --n-envs >= 1")
    if obs_size is None:
        with closing(PlatoonMultiAgentEnv(env_config(cfg, segment))) as probe:
            obs_size = probe.obs_size
    register()
    runners = max(1, cfg.num_env_runners)
    rollout = cfg.n_steps * cfg.n_envs * runners
    module = RLModuleSpec(
        module_class=PlatoonPPOModule,
        model_config={
            "hidden": net_arch(cfg),
            "obs_dim": int(obs_size),
            "critic": cfg.critic,
        },
    )
    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_config(cfg, segment))
        .framework("torch", torch_compile_learner=False)
        .env_runners(
            num_env_runners=cfg.num_env_runners,
            num_envs_per_env_runner=cfg.n_envs,
            rollout_fragment_length=cfg.n_steps,
            num_cpus_per_env_runner=1,
        )
        .learners(num_learners=cfg.num_learners)
        .multi_agent(policies={MODULE_ID}, policy_mapping_fn=_policy_mapping)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={MODULE_ID: module}))
        .training(
            lr=cfg.learning_rate,
            gamma=cfg.gamma,
            lambda_=cfg.gae_lambda,
            train_batch_size_per_learner=rollout // max(1, cfg.num_learners),
            minibatch_size=cfg.batch_size,
            num_epochs=cfg.n_epochs,
            clip_param=cfg.clip_range,
            entropy_coeff=cfg.ent_coef,
            vf_loss_coeff=cfg.vf_coef,
            grad_clip=cfg.max_grad_norm,
            grad_clip_by="global_norm",
            use_kl_loss=False,
            vf_clip_param=float("inf"),
        )
        .callbacks(on_environment_created=seed_sub_envs)
        .debugging(seed=cfg.seed, log_level="ERROR")
        .reporting(metrics_num_episodes_for_smoothing=20)
    )


def _package_dir(package: Any) -> str:
    """The directory a package was imported from."""
    return str(Path(next(iter(package.__path__))).resolve())


def project_runtime_env() -> dict[str, Any]:
    """The Ray ``runtime_env`` that ships this project's code to every node of a cluster.

    ``py_modules``: the driver's own :data:`PROJECT_PACKAGES` directories (``platoon_env``
    with its scenario and profile data, ``training``). Ray zips them once per content hash,
    uploads them to the cluster and puts them first on every worker's ``sys.path``, so the
    env runners and learners run the driver's code (edits included) and a node needs no
    ``pip install -e .`` of the project. The third-party packages (Ray with RLlib, torch,
    numpy, shapely, numba, gymnasium, pettingzoo, stable-baselines3, PyYAML) must be on the
    nodes, as for any RLlib cluster (``docs/rllib.md``).
    """
    import importlib

    modules = [_package_dir(importlib.import_module(name)) for name in PROJECT_PACKAGES]
    return {"py_modules": modules, "excludes": ["__pycache__", "*.pyc", "*.nbi", "*.nbc"]}


def init_ray(
    address: str | None = None,
    num_cpus: int | None = None,
    runtime_env: Mapping[str, Any] | None = None,
) -> None:
    """Connect to a Ray cluster (``address``: ``auto``, ``HOST:6379`` or ``ray://HOST:10001``)
    or start a local instance without the dashboard; no-op if Ray is already initialised.

    ``runtime_env``: Ray's runtime environment of the job; :func:`train_rllib` passes
    :func:`project_runtime_env` when it joins a cluster (a local instance's workers import the
    driver's installation)."""
    if ray.is_initialized():
        return
    env = dict(runtime_env) if runtime_env else None
    if address:
        ray.init(address=address, log_to_driver=False, runtime_env=env)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, runtime_env=env)


def _atomic_dir(save: Any, path: Path) -> None:
    """``save(tmp_dir)``, then swap ``tmp_dir`` into ``path`` (the old one removed after)."""
    tmp = path.with_name(f".{path.name}.tmp")
    old = path.with_name(f".{path.name}.old")
    for p in (tmp, old):
        shutil.rmtree(p, ignore_errors=True)
    save(tmp)
    if path.exists():
        os.replace(path, old)
    os.replace(tmp, path)
    shutil.rmtree(old, ignore_errors=True)


def _sampled(result: Mapping[str, Any], key: str) -> int:
    """A step count of an iteration's results (per-agent counts summed)."""
    value = result.get("env_runners", {}).get(key, 0)
    if isinstance(value, Mapping):
        return int(sum(float(v) for v in value.values()))
    return int(value or 0)


def train_rllib(cfg: TrainConfig, plan: RunPlan | None = None) -> tuple[Path, bool]:
    """``platoon-train --engine rllib``: train as ``cfg`` says; returns ``(model.zip,
    interrupted)``. ``--timesteps`` counts follower transitions, as for SB3.

    ``plan``: :func:`training.run.plan_run`'s decision for ``--out`` (computed here if None):
    the same ``--out``/``--resume``/``--force`` rules and folder lock as the SB3 engine
    (:mod:`training.run`); a resume restores ``rllib_checkpoint/`` and continues
    ``checkpoint.json``'s counts, segments and Lagrange multiplier, with the env streams of
    its own segment. With ``--address``, the job ships the project's code to the cluster
    (:func:`project_runtime_env`).
    """
    checked(cfg)
    out = cfg.out_dir
    with closing(PlatoonMultiAgentEnv(env_config(cfg))) as probe, hold_run(out):
        plan = open_run(cfg, probe.env, plan)
        if plan.mode == "finished":
            return finished_run(plan)
        torch.set_num_threads(cfg.torch_threads)
        init_ray(
            cfg.address,
            num_cpus=max(2, cfg.num_env_runners + cfg.num_learners),
            runtime_env=project_runtime_env() if cfg.address else None,
        )
        config = ppo_config(cfg, segment=plan.segment_index, obs_size=probe.obs_size)
        algo = config.build_algo()
        try:
            return _train_algo(cfg, plan, algo, probe)
        finally:
            algo.stop()


# ------------------------------------------------------------------------------------------------
# What the driver reads from and sets on the env runners (each call: one round trip per runner)
# ------------------------------------------------------------------------------------------------
def _platoon_envs(runner: Any) -> list[PlatoonMultiAgentEnv]:
    """The platoon sub-envs of an env runner (none on a driver-side runner that samples
    nothing)."""
    env = getattr(runner, "env", None)
    subs = getattr(env, "envs", [] if env is None else [env])
    found = [getattr(sub, "unwrapped", sub) for sub in subs]
    return [e for e in found if isinstance(e, PlatoonMultiAgentEnv)]


def _pop_outcomes(runner: Any) -> list[EpisodeOutcome]:
    return [o for e in _platoon_envs(runner) for o in e.pop_outcomes()]


def _set_multiplier(runner: Any, value: float) -> None:
    for e in _platoon_envs(runner):
        e.cost_multiplier = value


def _runner_place(runner: Any) -> dict[str, Any]:
    """Where an env runner runs and what it did: its index, Ray node, env steps so far and
    the directory it imported ``platoon_env`` from (the runtime env's copy on a cluster)."""
    return {
        "worker_index": int(getattr(runner, "worker_index", 0) or 0),
        "node_id": ray.get_runtime_context().get_node_id(),
        "env_steps": int(sum(e.env_steps for e in _platoon_envs(runner))),
        "platoon_env": _package_dir(platoon_env),
    }


def _on_runners(algo: Any, cfg: TrainConfig, fn: Any) -> list[Any]:
    """``fn(runner)`` on every runner that samples (the driver's own when there are none)."""
    return list(
        algo.env_runner_group.foreach_env_runner(fn, local_env_runner=cfg.num_env_runners == 0)
    )


def cluster_metadata(algo: Any, cfg: TrainConfig) -> dict[str, Any]:
    """``model.json``'s ``ray`` entry: the cluster's alive nodes, the driver's node, and
    :func:`_runner_place` of every sampling env runner."""
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    runners = [p for p in _on_runners(algo, cfg, _runner_place) if p is not None]
    return {
        "address": cfg.address,
        "nodes_alive": sorted(str(n["NodeID"]) for n in nodes),
        "driver_node_id": ray.get_runtime_context().get_node_id(),
        "env_runners": sorted(runners, key=lambda p: int(p["worker_index"])),
    }


def _cluster_record(algo: Any, cfg: TrainConfig) -> dict[str, Any]:
    """:func:`cluster_metadata`, or why it could not be read (a model is saved regardless,
    e.g. after Ctrl-C reached the env runners too)."""
    try:
        return cluster_metadata(algo, cfg)
    except Exception as e:  # any Ray failure: the record is provenance, not the model
        return {"address": cfg.address, "error": f"{type(e).__name__}: {e}"}


# ------------------------------------------------------------------------------------------------
# Logs: progress.csv and TensorBoard, with the SB3 runs' names
# ------------------------------------------------------------------------------------------------
#: SB3's ``train/`` TensorBoard scalars and the RLlib learner results they are read from
#: (``entropy_loss`` is minus the entropy, as SB3 logs it).
TRAIN_SCALARS = {
    "train/policy_gradient_loss": "policy_loss",
    "train/value_loss": "vf_loss",
    "train/entropy_loss": "entropy",
    "train/explained_variance": "vf_explained_var",
    "train/loss": "total_loss",
    "train/learning_rate": "default_optimizer_learning_rate",
}
#: SB3's ``rollout/`` statistics are over the last this many follower episodes.
EPISODE_WINDOW = 100


class _RunLogs:
    """``progress.csv`` (:class:`training.curves.ProgressLog`) and ``tb/`` for an RLlib run.

    After every training iteration, :meth:`iteration` takes the episodes that ended in it
    (:class:`EpisodeOutcome`, one per env copy: a follower episode per follower) and the
    iteration's results. TensorBoard gets SB3's names at the same timesteps: ``rollout/``
    (over the last :data:`EPISODE_WINDOW` follower episodes), ``platoon/violation`` and
    ``platoon/<cause>`` (rates over the iteration's follower episodes), ``train/`` (from the
    learner, :data:`TRAIN_SCALARS`), ``time/fps`` and, for ``ppo_lagrangian``,
    ``lagrangian/lambda`` and ``lagrangian/episode_cost``.
    """

    def __init__(self, cfg: TrainConfig, resume_from: int | None, timesteps: int) -> None:
        from torch.utils.tensorboard import SummaryWriter

        out = cfg.out_dir
        self.progress = ProgressLog(out / PROGRESS_FILE, cfg.log_every, resume_from=resume_from)
        self.progress.start(timesteps)
        # SB3 writes tb/<run name>_1 for a new run and continues its latest folder on resume.
        self.tb = SummaryWriter(str(out / "tb" / f"{cfg.run_name}_1"))
        self._returns: deque[float] = deque(maxlen=EPISODE_WINDOW)
        self._lengths: deque[int] = deque(maxlen=EPISODE_WINDOW)
        self._start = timesteps
        self._clock = time.perf_counter()

    def iteration(
        self,
        timesteps: int,
        outcomes: list[EpisodeOutcome],
        result: Mapping[str, Any],
        multiplier: float | None,
        multiplier_used: float | None,
    ) -> None:
        """Log one iteration that ended at ``timesteps``: ``multiplier_used`` is the ``λ`` its
        rollout was penalised with (the ``lambda`` column, as in SB3), ``multiplier`` its
        update from the iteration's costs (TensorBoard's ``lagrangian/lambda``)."""
        returns = [r for o in outcomes for r in o.returns]
        costs = [c for o in outcomes for c in o.costs]
        self.progress.add(returns=returns, costs=costs, teams=[o.team_success for o in outcomes])
        step = int(timesteps)
        self._returns.extend(returns)
        self._lengths.extend(o.length for o in outcomes for _ in o.returns)
        if self._returns:
            self.tb.add_scalar("rollout/ep_rew_mean", float(np.mean(self._returns)), step)
            self.tb.add_scalar("rollout/ep_len_mean", float(np.mean(self._lengths)), step)
        causes = [v for o in outcomes for v in o.violations]
        if causes:
            self.tb.add_scalar(
                "platoon/violation", float(np.mean([v is not None for v in causes])), step
            )
            for name in VIOLATION_CAUSES:
                self.tb.add_scalar(
                    f"platoon/{name}", float(np.mean([v == name for v in causes])), step
                )
        learner = result.get("learners", {}).get(MODULE_ID, {})
        for tag, key in TRAIN_SCALARS.items():
            if key in learner:
                value = float(learner[key])
                self.tb.add_scalar(tag, -value if key == "entropy" else value, step)
        elapsed = time.perf_counter() - self._clock
        if elapsed > 0:
            self.tb.add_scalar("time/fps", (step - self._start) / elapsed, step)
        if multiplier is not None:
            self.tb.add_scalar("lagrangian/lambda", multiplier, step)
            if costs:
                self.tb.add_scalar("lagrangian/episode_cost", float(np.mean(costs)), step)
        if self.progress.due(step):
            self.progress.write(step, multiplier_used)

    def close(self, timesteps: int, multiplier_used: float | None) -> None:
        """The last row (if any timesteps passed since the previous one), and flush."""
        if timesteps > self.progress.last:
            self.progress.write(timesteps, multiplier_used)
        self.tb.close()


@dataclasses.dataclass
class _Counts:
    """What :func:`_train_algo` carries from one iteration to the next: the agent transitions
    (``timesteps``) and env steps sampled, the multiplier ``λ`` (``ppo_lagrangian``; else
    None), the ``λ`` the last iteration's rewards were shaped with, and its result."""

    timesteps: int = 0
    env_steps: int = 0
    multiplier: LagrangeMultiplier | None = None
    used: float | None = None
    last_result: dict[str, Any] = dataclasses.field(default_factory=dict)


def _train_algo(
    cfg: TrainConfig, plan: RunPlan, algo: Any, probe: PlatoonMultiAgentEnv
) -> tuple[Path, bool]:
    """:func:`train_rllib`'s loop on the built ``algo``, in the prepared ``--out``: an
    iteration at a time, a checkpoint every ``checkpoint_every`` transitions, the model (and a
    last checkpoint) at the end or at Ctrl-C."""
    ckpt_dir = cfg.out_dir / RLLIB_CHECKPOINT
    lagrangian = has_multiplier(cfg.algo)
    counts = _Counts(
        multiplier=LagrangeMultiplier(budget=cfg.cost_budget, lr=cfg.lagrangian_lr)
        if lagrangian
        else None
    )
    if plan.mode == "resume":
        _restore(plan, algo, counts)
    segment = Segment(plan, counts.timesteps)
    resume_from = segment.timesteps_start if plan.mode == "resume" else None
    logs = _RunLogs(cfg, resume_from, counts.timesteps)

    def save(name: str, **extra: Any) -> Path:
        actor = export_actor(learner_weights(algo))
        meta = _rllib_metadata(cfg, algo, probe, segment, counts, **extra)
        return save_exported_policy(actor, cfg.out_dir / f"{name}.zip", meta)

    bar: Any = None
    if cfg.progress_bar:
        from tqdm.auto import tqdm

        bar = tqdm(total=cfg.timesteps, initial=counts.timesteps, unit="step")
    last_ckpt = counts.timesteps
    interrupted = False
    counts.used = None if counts.multiplier is None else counts.multiplier.value
    try:
        while counts.timesteps < cfg.timesteps:
            _iteration(cfg, algo, counts, logs)
            _report(cfg, counts, bar)
            if cfg.checkpoint_every > 0 and counts.timesteps - last_ckpt >= cfg.checkpoint_every:
                last_ckpt = counts.timesteps
                _atomic_dir(lambda p: algo.save_to_path(str(p.resolve())), ckpt_dir)
                save("checkpoint")
    except KeyboardInterrupt:
        interrupted = True
        report_interrupt(counts.timesteps)
    if bar is not None:
        bar.close()
    logs.close(counts.timesteps, counts.used)
    _atomic_dir(lambda p: algo.save_to_path(str(p.resolve())), ckpt_dir)
    save("checkpoint")
    return save("model", interrupted=interrupted), interrupted


def _restore(plan: RunPlan, algo: Any, counts: _Counts) -> None:
    """Continue from the plan's RLlib checkpoint: the algorithm's state, the counts and ``λ``."""
    assert plan.source is not None
    algo.restore_from_path(str(plan.source.resolve()))
    counts.timesteps = plan.timesteps
    counts.env_steps = int(plan.stored.get("env_steps", 0) or 0)
    stored = plan.stored.get("lagrange_multiplier")
    if counts.multiplier is not None and stored is not None:
        counts.multiplier.value = float(stored)
    print(plan.message, file=sys.stderr)


def _iteration(cfg: TrainConfig, algo: Any, counts: _Counts, logs: _RunLogs) -> None:
    """One ``algo.train()`` iteration, ``λ`` sent to the runners before it and updated by dual
    ascent on its follower episodes' costs after it; its counts and logs."""
    multiplier = counts.multiplier
    if multiplier is not None:
        # Every iteration (a restarted runner would start from 0 again).
        counts.used = multiplier.value
        _on_runners(algo, cfg, functools.partial(_set_multiplier, value=counts.used))
    result = algo.train()
    counts.last_result = result
    counts.timesteps += _sampled(result, "num_agent_steps_sampled")
    counts.env_steps += _sampled(result, "num_env_steps_sampled")
    outcomes = [o for batch in _on_runners(algo, cfg, _pop_outcomes) for o in batch or []]
    if multiplier is not None:
        # Dual ascent on the follower episodes' costs, as SB3's LagrangianCallback:
        # the new λ shapes the next iteration's rewards.
        multiplier.update([c for o in outcomes for c in o.costs])
    lam = None if multiplier is None else multiplier.value
    logs.iteration(counts.timesteps, outcomes, result, lam, counts.used)


def _report(cfg: TrainConfig, counts: _Counts, bar: Any) -> None:
    """An iteration's progress: the bar (if any), and (``verbose``) its return and length."""
    if bar is not None:
        bar.n = min(counts.timesteps, cfg.timesteps)
        bar.refresh()
    if cfg.verbose:
        runners = counts.last_result.get("env_runners", {})
        print(
            f"timesteps {counts.timesteps}  return {runners.get('episode_return_mean')}  "
            f"length {runners.get('episode_len_mean')}",
            file=sys.stderr,
        )


def _rllib_metadata(
    cfg: TrainConfig,
    algo: Any,
    probe: PlatoonMultiAgentEnv,
    segment: Segment,
    counts: _Counts,
    **extra: Any,
) -> dict[str, Any]:
    """What a saved point's ``model.json`` records (``extra``: e.g. ``interrupted``)."""
    timesteps, env_steps, multiplier = counts.timesteps, counts.env_steps, counts.multiplier
    timing = segment.metadata(timesteps)
    wall = timing["wall_time_s"]
    lam = {} if multiplier is None else {"lagrange_multiplier": multiplier.value}
    runners = counts.last_result.get("env_runners", {})
    return {
        "engine": "rllib",
        "algo": cfg.algo,
        **env_metadata(cfg, probe.env),
        "sensor_profile": cfg.sensor_profile,
        "observation_normalization": None
        if probe.obs_scale is None
        else {"type": "fixed_scale", "scale": [float(s) for s in probe.obs_scale]},
        "action_range": cfg.action_range.to_dict(),
        "actor": {
            "type": "mlp",
            "activation": "tanh",
            "hidden": net_arch(cfg),
        },
        "critic": cfg.critic,
        "timesteps": timesteps,
        "env_steps": env_steps,
        "timesteps_requested": cfg.timesteps,
        "num_env_runners": cfg.num_env_runners,
        "num_envs_per_env_runner": cfg.n_envs,
        "num_learners": cfg.num_learners,
        "rllib_checkpoint": RLLIB_CHECKPOINT,
        **lam,
        **timing,
        "env_steps_per_s": round(env_steps / wall, 1) if wall > 0 else None,
        "episode_return_mean": runners.get("episode_return_mean"),
        "episode_len_mean": runners.get("episode_len_mean"),
        "ray": _cluster_record(algo, cfg),
        **extra,
        "config": dataclasses.asdict(cfg),
        "versions": library_versions(ray, torch, gym),
        "command": sys.argv,
    }
