r"""A fast training path: PPO and PPO-Lagrangian straight on the batched core, at simulator speed.

Stable-Baselines3 (:mod:`training.train`) steps a vector env of follower slots through Python
objects and updates on minibatches of 256, orders of magnitude slower than the batched core
(:class:`platoon_env.batched.BatchedPlatoon`) simulates. This module is one learner written
top to bottom (in the manner of CleanRL) that keeps closer to the simulator's pace
(``benchmarks/train_speed.py`` measures both):

* **Collection**: ``n_envs`` copies of one scenario source step in one compiled call per
  control period (``auto_reset=True``); the policy acts for every follower slot of every copy
  in one batched forward of the actor; the values and log-probabilities of the rollout are
  computed after it in one large batch (the policy does not change during a rollout).
  Followers are independent agents sharing one policy (parameter sharing, as
  :class:`training.vec_env.PlatoonVecEnv`): each follower slot is a sample. A mask of the live
  slots of each copy (all of them while every copy has the template's ``N`` followers) is
  what the samples, counts and team outcomes read.
* **PPO** (Schulman et al., 2017): the clipped surrogate
  ``L = E[min(ρ A, clip(ρ, 1 - ε, 1 + ε) A)]``, ``ρ = π(a|o) / π_old(a|o)``, GAE(γ, λ_GAE)
  advantages, a squared-error value loss, an entropy bonus, Adam, the global gradient norm
  clipped, ``n_epochs`` passes of large minibatches over each rollout of ``n_steps * n_envs *
  N`` transitions. At a time limit (``truncated and not terminated``) the value of
  ``info["final_observation"]`` is bootstrapped into the last reward (``r + γ V(o_T)``, and
  ``c + γ V_c(o_T)``), as SB3 does with ``TimeLimit.truncated``; a terminated episode (a
  violation) is not bootstrapped. Torch runs ``torch_threads`` threads (default 1: on this
  project's shared 2-core machines a second thread made the 64-wide layers slower).
* **PPO-Lagrangian** (``algo="ppo_lagrangian"``): the constrained problem ``max J_r`` s.t.
  ``J_c <= b`` of :mod:`training.lagrangian`, in its two-critic form: a **cost critic**
  ``V_c`` (a second head on the value trunk) learns the discounted per-step cost ``c_t``, the
  followers' violation cost ``info["cost"]`` of the adapters (1 at a step with a violation of
  any cause: :data:`platoon_env.violations.VIOLATION_INFO`); cost advantages ``A_c`` come from
  GAE on it, and the policy maximises the surrogate of ``(A_r - λ A_c) / (1 + λ)`` (``A_r``
  standardised per minibatch, ``A_c`` centred, as OmniSafe's PPOLag does; with
  ``cost_advantage="standardised"`` ``A_c`` is first scaled to unit standard deviation over the
  rollout, so the surrogate keeps its scale as ``λ`` grows). The multiplier is
  updated by **gradient (dual) ascent**, the rule of
  :class:`training.lagrangian.LagrangeMultiplier`: after each rollout,
  ``λ ← clip(λ + η (Ĵ_c - b), 0, λ_max)`` with ``Ĵ_c`` the mean cost of the follower episodes
  that ended in it (the probability that a follower's episode has a violation, with the default
  ``terminate_on``), before the update on that rollout. With ``λ`` unbounded by the reward
  scale (``λ_max = 100``), the objective tends to ``-A_c`` as ``λ`` grows, so a run whose budget
  is feasible can meet it.
* **The model it saves is an ordinary SB3 model**: the network has exactly the layers and
  parameter names of SB3's ``MlpPolicy`` (``net_arch`` for both trunks, Tanh, a state-independent
  ``log_std``), so ``model.zip`` is a ``PPO`` whose policy weights are copied from it
  (:func:`sb3_model`; the cost head is not part of the policy and is kept in the learner state
  only). :meth:`training.policies.LearnedPolicy.load` loads it like any ``platoon-train`` model,
  and acts as this learner's deterministic mode does (the mean, clipped to ``[-1, 1]^2``, then
  :class:`~training.vec_env.ActionRange`): the same layers on the same inputs.
* **The observation and action conventions are the SB3 adapters'**: observations divided by
  :func:`training.vec_env.observation_scale` of the follower's Box; a Gaussian in
  ``[-1, 1]^2`` sampled unclipped (its log-probability is that of the unclipped sample), clipped
  to ``[-1, 1]`` and mapped by :class:`~training.vec_env.ActionRange` to ``[u, omega]``.

Seeds (:mod:`training.seeding`, the rule of every training path): env copy ``b`` of segment
``s`` is reset with ``env_seeds(seed, n_envs, segment=s)[b]``, a stream of
``numpy.random.SeedSequence(seed)`` (never ``seed + b``); the network's initialisation, the
action noise and the minibatch order come from ``process_seed(seed, s)``. A segment is one call
of :func:`train_fast` for the run (0, then one more per resume), so a resumed run draws new
episodes rather than replaying the first segment's.

Layouts: a procedural source builds a new layout for every episode (about 10-15 ms each,
against about 0.1 ms for a reset on a layout already built), and with an untrained policy an
episode lasts some 17 steps, so generating layouts bounds every training path at first.
``layout_repeats = R > 1`` lets each copy keep its layout for ``R`` consecutive episodes (new
start, new leader speed factor), dividing that cost by ``R``; each episode's layout is still a
uniform draw of the split, consecutive episodes of one copy share it. The default, 1, is the
env's own rule.

Files in ``out`` (a directory holding one run):

* ``model.zip`` + ``model.json`` — the final model (:mod:`training.policies`' format, an SB3
  zip, so no ``engine`` entry; ``"trainer": "training.fast_ppo"`` says what trained it,
  ``config`` is this module's :class:`FastPPOConfig`, each entry of ``segments`` also records
  its ``env_seed_segment``, the first layouts drawn and a digest of the first starts);
  ``model.state.pt`` — the learner's state beside it (network with the cost head, optimiser,
  ``λ``), so that a finished run can be continued to more timesteps;
* ``checkpoint.zip`` + ``.json`` + ``.state.pt`` — the latest checkpoint (every
  ``checkpoint_every`` transitions, at the end of a rollout), replaced whole (the three files
  written beside them, then renamed into place, the JSON last: :func:`training.run.save_point`),
  the JSON recording both other files' SHA-256;
* ``progress.csv`` — the learning curve, :data:`training.curves.PROGRESS_COLUMNS`, a row every
  ``log_every`` follower transitions (team success rate, mean return, mean cost, ``λ``).

Use::

    from training.fast_ppo import FastPPOConfig, train_fast
    cfg = FastPPOConfig(scenario="procedural_medium_train", task_aware_observations=True,
                        algo="ppo_lagrangian", cost_budget=0.05, timesteps=20_000_000)
    run = train_fast(cfg, "runs/fast_lag")                   # runs/fast_lag/model.zip
    run = train_fast(cfg, "runs/fast_lag", resume=True)      # continue (e.g. more timesteps)
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime as dt
import hashlib
import io
import json
import math
import os
import pickle
import sys
import time
import warnings
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numba
import numpy as np
import stable_baselines3
import torch
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3 import PPO
from torch import nn
from tqdm.auto import tqdm

from platoon_env.batched import BatchedPlatoon
from platoon_env.realism import REALISM_PRESETS
from platoon_env.scenarios.fingerprint import file_sha256
from platoon_env.scenarios.scenario import Scenario
from platoon_env.scenarios.source import ScenarioSource, scenario_source
from platoon_env.violations import VIOLATION_INFO
from training.algorithms import has_multiplier, trained_by
from training.config import (
    BOUNDS,
    COST_ADVANTAGES,
    ENV_FIELDS,
    FAST_ONLY,
    MAX_LAYER,
    SB3_OPTIONS,
    Bound,
    TrainConfig,
    device_error,
    env_metadata,
)
from training.config import env_overrides as train_env_overrides
from training.curves import PROGRESS_COLUMNS, PROGRESS_FILE, read_rows
from training.experts import EXPERTS, BatchedExpert, to_normalised
from training.lagrangian import LagrangeMultiplier
from training.policies import adapter_metadata, save_model, zip_mismatch
from training.run import (
    git_commit,
    library_versions,
    save_point,
    segment_metadata,
    timing_metadata,
)
from training.seeding import env_seeds, process_seed
from training.vec_env import ActionRange, slot_spaces

__all__ = [
    "ALGOS",
    "FILES",
    "TRAINER",
    "ActorCritic",
    "FastPPOConfig",
    "FastRun",
    "RepeatedLayouts",
    "initial_weights",
    "make_core",
    "sb3_model",
    "scaled_cost_advantages",
    "surrogate_advantages",
    "train_fast",
]

#: What :func:`train_fast` trains: PPO, or PPO with a cost critic and a Lagrange multiplier
#: (the fast engine's algorithms but the clones, which :mod:`training.bc` trains).
ALGOS = trained_by("fast", clones=False)
#: What ``model.json`` names as the trainer of this module's models.
TRAINER = "training.fast_ppo"
#: The two saved points of a run: the final model and the latest checkpoint.
POINTS = ("model", "checkpoint")
#: The files that mark ``out`` as holding a run.
FILES = (
    *(f"{p}{ext}" for p in POINTS for ext in (".zip", ".json", ".state.pt")),
    PROGRESS_FILE,
)
#: The cost of each violation bit mask (``info["cost"]`` of the adapters: 1 for any cause).
COST_OF_MASK: NDArray[np.float32] = np.array([c for _, _, c in VIOLATION_INFO], dtype=np.float32)
#: ``log sqrt(2 pi)``, of the Gaussian log-density.
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


# ------------------------------------------------------------------------------------------------
# Options
# ------------------------------------------------------------------------------------------------
#: ``platoon-train``'s defaults: the options both trainers have default to the same values.
_TRAIN = TrainConfig()


@dataclass(frozen=True)
class FastPPOConfig:
    """Every option of :func:`train_fast`; invalid values raise ``ValueError`` naming the option.

    The env and action options mean what ``platoon-train``'s options of the same name mean
    (:class:`training.config.TrainConfig`) and are range-checked by the same bounds.

    Run: ``scenario`` (shipped name, YAML path or mapping), ``algo`` (:data:`ALGOS`),
    ``timesteps`` (follower transitions in total), ``seed``, ``n_envs`` (env copies ``B``;
    ``B * N`` slots), ``env_threads`` (numba threads of the core), ``layout_repeats``
    (episodes a copy keeps a procedural layout for; module doc).

    Env: ``control_period`` [s], ``physics_substeps``, ``max_episode_steps``,
    ``sensor_profile``, ``task_aware_observations``; ``u_low``/``u_high`` [m/s] and
    ``omega_high`` [rad/s] (the :class:`~training.vec_env.ActionRange`),
    ``normalize_observations``.

    PPO: ``learning_rate`` (Adam), ``gamma`` (γ, also of the cost), ``gae_lambda`` (λ_GAE),
    ``n_steps`` (rollout length per slot), ``n_epochs``, ``batch_size`` (minibatch),
    ``clip_range`` (ε), ``ent_coef``, ``vf_coef`` (of the value and the cost-value losses),
    ``max_grad_norm``, ``net_arch`` (hidden layers of both trunks), ``log_std_init`` (the
    policy's initial ``log σ``).

    Start: ``init_from`` (None: SB3's initialisation; else an SB3 ``PPO`` zip of the same
    observation size and ``net_arch``, e.g. the cloned model of :mod:`training.bc`, whose
    policy parameters, all but ``log_std``, the network starts from; ``log_std`` starts at
    ``log_std_init``), ``value_warmup`` (the first rollouts of a run in which only the critic
    learns: a critic not trained with the actor it starts from gives noise for advantages),
    ``anchor_coef`` (``c_a >= 0``; needs ``init_from``: the update's loss gains
    ``c_a * E ||mu_theta(o) - mu_0(o)||^2``, the squared distance of the policy's mean action
    (normalised, before clipping) from that of the frozen network it started from, over the
    minibatch: for Gaussians of one ``sigma`` this is ``2 sigma^2`` times their KL divergence.
    It keeps a fine-tuned clone near the law it copies, a behaviour-cloning regulariser as in
    DAPG; 0: none), ``residual`` (None, or an analytic law of :data:`training.experts.EXPERTS`:
    a residual policy, as in residual reinforcement learning (Johannink et al., 2019; Silver
    et al., 2018). The policy's mean is ``a_law(o) + mu_theta(o)``, the law's command for the
    copy (:class:`~training.experts.BatchedExpert`, its own clock and state per episode)
    normalised and clipped to ``[-1, 1]``, plus the network's output; the actor's last layer
    starts at zero, so training starts from the clipped law. With ``anchor_coef`` and no
    ``init_from``, the anchor pulls ``mu_theta`` towards zero, i.e. the policy towards the law).

    Input: ``previous_command`` (the policy reads, after the observation, its own previous
    command ``a_{t-1}`` as it was sent: normalised and clipped to ``[-1, 1]^2``; at an
    episode's start the normalised standstill ``[0 m/s, 0 rad/s]``. Proprioception, not
    sensing: under acceleration limits and latency the applied velocity lags the command, and
    a memoryless policy cannot tell how far; ``model.json`` records ``previous_command``).

    PPO-Lagrangian: ``cost_budget`` (``b``, expected cost per follower episode),
    ``lagrangian_lr`` (``η`` per rollout; a rollout here is tens of thousands of transitions,
    so larger than ``platoon-train``'s 0.05 per 4096), ``lagrangian_init`` (``λ`` at the
    start), ``lagrangian_max`` (``λ_max``), ``cost_advantage`` (how ``A_c`` is scaled before
    it enters the surrogate: :data:`training.config.COST_ADVANTAGES`).

    Bookkeeping: ``log_every`` (transitions between rows of ``progress.csv``),
    ``checkpoint_every`` (transitions between checkpoints; 0: none), ``torch_threads``,
    ``device`` (``cpu``, ``cuda``, ``cuda:N``), ``progress_bar`` (tqdm).
    """

    # --- run ---
    scenario: str | Mapping[str, Any] = _TRAIN.scenario
    algo: str = "ppo"
    timesteps: int = _TRAIN.timesteps
    seed: int = _TRAIN.seed
    n_envs: int = 512
    env_threads: int = 1
    layout_repeats: int = 1
    # --- env (platoon-train's defaults) ---
    control_period: float = _TRAIN.control_period
    physics_substeps: int | None = _TRAIN.physics_substeps
    max_episode_steps: int | None = _TRAIN.max_episode_steps
    sensor_profile: str | None = _TRAIN.sensor_profile
    task_aware_observations: bool = _TRAIN.task_aware_observations
    scale_free_observations: bool = _TRAIN.scale_free_observations
    realism_preset: str | None = _TRAIN.realism_preset
    # --- action rescaling / observation normalisation (platoon-train's defaults) ---
    u_low: float = _TRAIN.u_low
    u_high: float = _TRAIN.u_high
    omega_high: float = _TRAIN.omega_high
    normalize_observations: bool = _TRAIN.normalize_observations
    # --- PPO (large rollouts and minibatches: fewer epochs, a larger step than SB3's) ---
    learning_rate: float = 1e-3
    gamma: float = _TRAIN.gamma
    gae_lambda: float = _TRAIN.gae_lambda
    n_steps: int = 64
    n_epochs: int = 5
    batch_size: int = 8192
    clip_range: float = _TRAIN.clip_range
    ent_coef: float = _TRAIN.ent_coef
    vf_coef: float = _TRAIN.vf_coef
    max_grad_norm: float = _TRAIN.max_grad_norm
    net_arch: tuple[int, ...] = (64, 64)
    log_std_init: float = 0.0
    # --- start ---
    init_from: str | None = None
    value_warmup: int = 0
    anchor_coef: float = 0.0
    residual: str | None = None
    # --- input ---
    previous_command: bool = _TRAIN.previous_command
    # --- PPO-Lagrangian ---
    cost_budget: float = _TRAIN.cost_budget
    lagrangian_lr: float = 0.5
    lagrangian_init: float = 0.0
    lagrangian_max: float = 100.0
    cost_advantage: str = "centred"
    # --- bookkeeping ---
    log_every: int = 100_000
    checkpoint_every: int = 1_000_000
    torch_threads: int = 1
    device: str = "cpu"
    progress_bar: bool = True

    def __post_init__(self) -> None:
        # A list given for net_arch is stored as a tuple (the config is frozen and compared).
        object.__setattr__(self, "net_arch", tuple(self.net_arch))
        problems = config_problems(self)
        if problems:
            raise ValueError("FastPPOConfig: " + "; ".join(problems))

    @property
    def action_range(self) -> ActionRange:
        """The physical range of the policy's normalised action."""
        return ActionRange(u_low=self.u_low, u_high=self.u_high, omega_high=self.omega_high)

    @property
    def lagrangian(self) -> bool:
        """Whether the run has a cost critic and a multiplier."""
        return has_multiplier(self.algo)


#: The bounds of this learner's own options (the shared ones are :data:`training.config.BOUNDS`).
FAST_BOUNDS: dict[str, Bound] = {
    **{
        name: BOUNDS[name]
        for name in FAST_ONLY
        if name not in ("init_from", "residual", "cost_advantage")
    },
    "batch_size": Bound(2, 10**9),  # advantage standardisation needs two samples
}
#: The options of :class:`FastPPOConfig` checked against :data:`training.config.BOUNDS`.
SHARED_BOUNDS = (
    "timesteps",
    "seed",
    "n_envs",
    "env_threads",
    "control_period",
    "physics_substeps",
    "max_episode_steps",
    "u_low",
    "u_high",
    "omega_high",
    "learning_rate",
    "gamma",
    "gae_lambda",
    "n_steps",
    "n_epochs",
    "clip_range",
    "ent_coef",
    "vf_coef",
    "max_grad_norm",
    "cost_budget",
    "lagrangian_lr",
    "log_every",
    "checkpoint_every",
    "torch_threads",
)
#: Options that may change when a run is resumed (they do not change what is learned).
RESUMABLE_CHANGES = (
    "timesteps",
    "env_threads",
    "log_every",
    "checkpoint_every",
    "torch_threads",
    "device",
    "progress_bar",
)


def config_problems(cfg: FastPPOConfig) -> list[str]:
    """Every problem of ``cfg`` that needs no scenario, each naming its option."""
    problems: list[str] = []
    bounds = {**{name: BOUNDS[name] for name in SHARED_BOUNDS}, **FAST_BOUNDS}
    for name, bound in bounds.items():
        value = getattr(cfg, name)
        if value is None and name in ("physics_substeps", "max_episode_steps"):
            continue
        if isinstance(value, bool) or not isinstance(value, int | float):
            problems.append(f"{name} must be a number, got {value!r}")
        elif not math.isfinite(value):
            problems.append(f"{name} must be finite, got {value!r}")
        elif value not in bound:
            problems.append(f"{name} must be {bound}, got {value!r}")
    for name in (
        "task_aware_observations",
        "normalize_observations",
        "progress_bar",
        "previous_command",
    ):
        if not isinstance(getattr(cfg, name), bool):
            problems.append(f"{name} must be True or False, got {getattr(cfg, name)!r}")
    if cfg.scale_free_observations is not False and not (
        cfg.scale_free_observations is True and cfg.task_aware_observations
    ):
        problems.append(
            "scale_free_observations must be True (with task_aware_observations) or False, got "
            f"{cfg.scale_free_observations!r}"
        )
    if cfg.realism_preset is not None and cfg.realism_preset not in REALISM_PRESETS:
        problems.append(
            f"realism_preset must be one of {sorted(REALISM_PRESETS)}, got {cfg.realism_preset!r}"
        )
    if cfg.algo not in ALGOS:
        problems.append(f"algo must be one of {ALGOS}, got {cfg.algo!r}")
    if cfg.cost_advantage not in COST_ADVANTAGES:
        problems.append(
            f"cost_advantage must be one of {COST_ADVANTAGES}, got {cfg.cost_advantage!r}"
        )
    if not problems and not cfg.u_low < cfg.u_high:
        problems.append(f"u_high must be > u_low = {cfg.u_low:g}, got {cfg.u_high:g}")
    if not problems and cfg.lagrangian_init > cfg.lagrangian_max:
        problems.append(
            f"lagrangian_init must be <= lagrangian_max = {cfg.lagrangian_max:g}, got "
            f"{cfg.lagrangian_init:g}"
        )
    threads = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    if isinstance(cfg.env_threads, int) and cfg.env_threads > threads:
        problems.append(f"env_threads must be at most numba's {threads} threads")
    if not cfg.net_arch or not all(
        isinstance(h, int) and 1 <= h <= MAX_LAYER for h in cfg.net_arch
    ):
        problems.append(f"net_arch must be layer sizes in [1, {MAX_LAYER}], got {cfg.net_arch}")
    if cfg.residual is not None and cfg.residual not in EXPERTS:
        problems.append(f"residual must be None or one of {tuple(EXPERTS)}, got {cfg.residual!r}")
    if isinstance(cfg.scenario, str) and not cfg.scenario.strip():
        problems.append("scenario must name a scenario or a YAML file")
    if cfg.init_from is not None and (
        not isinstance(cfg.init_from, str) or not cfg.init_from.endswith(".zip")
    ):
        problems.append(f"init_from must be the path of a model .zip, got {cfg.init_from!r}")
    reason = device_error(cfg.device) if isinstance(cfg.device, str) else "not a string"
    if reason is not None or cfg.device == "auto":
        problems.append(f"device: {reason or 'name one (cpu, cuda, cuda:N)'}")
    return problems


def _train_view(cfg: FastPPOConfig) -> TrainConfig:
    """``cfg``'s env options as ``platoon-train`` options, for the env rules shared with it
    (:func:`training.config.env_overrides`, :func:`training.config.env_metadata`)."""
    # the options that shape the env (training.config.ENV_FIELDS; a mapping is a scenario too)
    env = {name: getattr(cfg, name) for name in ENV_FIELDS}
    return TrainConfig(seed=cfg.seed, n_envs=cfg.n_envs, **env)


# ------------------------------------------------------------------------------------------------
# Envs
# ------------------------------------------------------------------------------------------------
class RepeatedLayouts:
    """A procedural source whose every env copy keeps a layout for ``repeats`` episodes.

    The core asks its source for each episode's scenario with the copy's own generator
    (:meth:`platoon_env.core.PlatoonCore.reset_env`), so the generator tells the copies apart: a
    copy's ``k``-th call returns the layout of its call ``repeats * (k // repeats)``, which was
    built by the wrapped source from the same stream. A reseeded copy (a new generator) starts a
    new layout. The wrapper keeps a reference to each generator it has seen, so their ids are
    not reused while it lives.
    """

    def __init__(self, source: ScenarioSource, repeats: int) -> None:
        if repeats < 1:
            raise ValueError(f"repeats must be >= 1, got {repeats}")
        self.inner = source
        self.repeats = int(repeats)
        self._held: dict[int, tuple[np.random.Generator, Scenario, int]] = {}

    @property
    def config(self) -> Any:
        """The wrapped source's template."""
        return self.inner.config

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """The wrapped source's bounds."""
        return self.inner.bounds

    @property
    def procedural(self) -> bool:
        """The wrapped source's (True for a procedural family)."""
        return self.inner.procedural

    @property
    def followers_range(self) -> tuple[int, int]:
        """The wrapped source's (a drawn formation's least and most followers)."""
        n = self.inner.config.followers
        return tuple(getattr(self.inner, "followers_range", (n, n)))  # type: ignore[return-value]

    def initial(self) -> Scenario:
        """The wrapped source's representative scenario."""
        return self.inner.initial()

    def sample(self, rng: np.random.Generator) -> Scenario:
        """The copy's current layout, or (every ``repeats`` episodes) a new one from ``rng``."""
        held = self._held.get(id(rng))
        if held is not None and held[0] is rng and held[2] < self.repeats:
            self._held[id(rng)] = (rng, held[1], held[2] + 1)
            return held[1]
        scenario = self.inner.sample(rng)
        self._held[id(rng)] = (rng, scenario, 1)
        return scenario


def make_core(cfg: FastPPOConfig, segment: int = 0) -> tuple[BatchedPlatoon, NDArray[np.float32]]:
    """The ``n_envs`` auto-resetting copies of ``cfg``'s scenario, reset with segment
    ``segment``'s seeds (:func:`training.seeding.env_seeds`), and their first observations
    ``(B, N, K)``."""
    source = scenario_source(
        cfg.scenario, train_env_overrides(_train_view(cfg)), where="FastPPOConfig.scenario"
    )
    if source.procedural and cfg.layout_repeats > 1:
        source = RepeatedLayouts(source, cfg.layout_repeats)
    core = BatchedPlatoon(source, cfg.n_envs, n_threads=cfg.env_threads, auto_reset=True)
    obs = core.reset(env_seeds(cfg.seed, cfg.n_envs, segment=segment))
    return core, obs


@dataclass
class SlotSpec:
    """What a follower slot of the core is to the policy: the spaces SB3 records in the model
    and the fixed normalisation and action range (what :func:`adapter_metadata` reads)."""

    obs_scale: NDArray[np.float32] | None
    action_range: ActionRange | None
    observation_space: spaces.Box
    action_space: spaces.Box

    @classmethod
    def of(cls, cfg: FastPPOConfig, core: BatchedPlatoon) -> SlotSpec:
        """The adapters' rule (:func:`training.vec_env.slot_spaces`) for ``core``'s slots;
        ``ValueError`` for an action range beyond the scenario's actuator limits. With
        ``cfg.previous_command`` the policy's input is the observation and the previous
        normalised command (two more entries in ``[-1, 1]``)."""
        scale, obs_space, act_space = slot_spaces(
            core.single_observation_space,
            {"the scenario": core.single_action_space},
            normalize_observations=cfg.normalize_observations,
            action_range=cfg.action_range,
        )
        if cfg.previous_command:
            ones = np.ones(2, dtype=np.float32)
            obs_space = spaces.Box(
                np.concatenate([obs_space.low, -ones]),
                np.concatenate([obs_space.high, ones]),
                dtype=np.float32,
            )
        return cls(scale, cfg.action_range, obs_space, act_space)


# ------------------------------------------------------------------------------------------------
# Network
# ------------------------------------------------------------------------------------------------
def _trunk(n_in: int, hidden: tuple[int, ...]) -> nn.Sequential:
    """``Linear, Tanh, Linear, Tanh, ...``: SB3's ``MlpExtractor`` branch."""
    layers: list[nn.Module] = []
    for h in hidden:
        layers += [nn.Linear(n_in, h), nn.Tanh()]
        n_in = h
    return nn.Sequential(*layers)


class _Extractor(nn.Module):
    """The two trunks under SB3's names (``mlp_extractor.policy_net`` / ``.value_net``)."""

    def __init__(self, n_in: int, hidden: tuple[int, ...]) -> None:
        super().__init__()
        self.policy_net = _trunk(n_in, hidden)
        self.value_net = _trunk(n_in, hidden)


class ActorCritic(nn.Module):
    """SB3's ``MlpPolicy`` for a Box action (separate actor and critic trunks of ``hidden``
    layers with Tanh, a linear mean, a state-independent ``log_std``, a linear value), with the
    same parameter names, plus (``cost_head``) a cost value ``V_c`` on the value trunk.

    Initialised as SB3 initialises it (orthogonal: gain ``sqrt 2`` in the trunks, 0.01 for the
    mean, 1 for the values; zero biases).
    """

    def __init__(
        self, n_obs: int, hidden: tuple[int, ...], log_std_init: float, cost_head: bool
    ) -> None:
        super().__init__()
        self.mlp_extractor = _Extractor(n_obs, hidden)
        self.action_net = nn.Linear(hidden[-1], 2)
        self.value_net = nn.Linear(hidden[-1], 1)
        self.log_std = nn.Parameter(torch.full((2,), float(log_std_init)))
        self.cost_value_net = nn.Linear(hidden[-1], 1) if cost_head else None
        gains: list[tuple[nn.Module, float]] = [
            (self.mlp_extractor, math.sqrt(2.0)),
            (self.action_net, 0.01),
            (self.value_net, 1.0),
        ]
        if self.cost_value_net is not None:
            gains.append((self.cost_value_net, 1.0))
        for module, gain in gains:
            for layer in module.modules():
                if isinstance(layer, nn.Linear):
                    nn.init.orthogonal_(layer.weight, gain=gain)
                    nn.init.zeros_(layer.bias)

    def actor_parameters(self) -> list[nn.Parameter]:
        """The parameters of the action mean (the actor trunk and ``action_net``)."""
        return [*self.mlp_extractor.policy_net.parameters(), *self.action_net.parameters()]

    def actor(self, obs: torch.Tensor) -> torch.Tensor:
        """The action mean ``(M, 2)`` of normalised observations ``(M, K)``."""
        return self.action_net(self.mlp_extractor.policy_net(obs))

    def critics(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(V (M,), V_c (M,) or None)`` of normalised observations ``(M, K)``."""
        latent = self.mlp_extractor.value_net(obs)
        value = self.value_net(latent).squeeze(-1)
        cost = None if self.cost_value_net is None else self.cost_value_net(latent).squeeze(-1)
        return value, cost

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """``(mean (M, 2), V (M,), V_c (M,) or None)`` of normalised observations ``(M, K)``."""
        return (self.actor(obs), *self.critics(obs))

    def sb3_state_dict(self) -> dict[str, torch.Tensor]:
        """The parameters SB3's ``ActorCriticPolicy`` has (everything but the cost head)."""
        return {k: v for k, v in self.state_dict().items() if not k.startswith("cost_value_net.")}


def gaussian_log_prob(x: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """``log π(x)`` of the diagonal Gaussian, summed over the action dimensions."""
    z = (x - mean) * torch.exp(-log_std)
    return (-0.5 * z * z - log_std - _LOG_SQRT_2PI).sum(-1)


class _SlotEnv(gym.Env[np.ndarray, np.ndarray]):
    """An env that only has a slot's spaces: what SB3 needs to build the ``PPO`` object the
    learned weights are saved in. It is never stepped."""

    def __init__(self, spec: SlotSpec) -> None:
        self.observation_space = spec.observation_space
        self.action_space = spec.action_space

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        raise RuntimeError("the fast learner's save object is not an env to step")

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        raise RuntimeError("the fast learner's save object is not an env to step")


def sb3_model(cfg: FastPPOConfig, spec: SlotSpec, rollout: int) -> PPO:
    """The SB3 ``PPO`` (``MlpPolicy`` with ``cfg.net_arch`` for both trunks) that the learned
    weights are copied into and saved as, on the CPU. Its hyper-parameters are ``cfg``'s, its
    ``n_steps`` the whole ``rollout`` (one vector env of one slot in SB3's terms)."""
    arch = list(cfg.net_arch)
    with warnings.catch_warnings():
        # SB3 warns when its rollout is not a multiple of the minibatch: it never trains here.
        warnings.simplefilter("ignore", UserWarning)
        options = {name: getattr(cfg, name) for name in SB3_OPTIONS["ppo"]}
        return PPO(
            "MlpPolicy",
            _SlotEnv(spec),
            **{**options, "n_steps": rollout},
            policy_kwargs={
                "net_arch": {"pi": arch, "vf": arch},
                "log_std_init": cfg.log_std_init,
            },
            device="cpu",
        )


# ------------------------------------------------------------------------------------------------
# Run directory: saved points, resume, progress
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FastRun:
    """What :func:`train_fast` returns: the model's path, the transitions trained in total,
    whether Ctrl-C stopped it, and the multiplier (``ppo_lagrangian``; else None)."""

    path: Path
    timesteps: int
    interrupted: bool = False
    lagrange_multiplier: float | None = None


@dataclass(frozen=True)
class _Stored:
    """A saved point (model or checkpoint) whose three files belong together."""

    name: str
    meta: dict[str, Any]
    state: dict[str, Any]

    @property
    def timesteps(self) -> int:
        return int(self.meta["timesteps"])


def _atomic_torch_save(obj: Any, path: Path) -> str:
    """``torch.save`` to a temporary file beside ``path``, renamed into place; its SHA-256."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        torch.save(obj, tmp)
        digest = file_sha256(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return digest


def _read_point(out: Path, name: str) -> _Stored | None:
    """The saved point ``name`` of ``out`` if its JSON, zip and learner state match (else
    None: missing, or a save cut off between its files)."""
    meta_file, zip_file, state_file = (out / f"{name}{e}" for e in (".json", ".zip", ".state.pt"))
    if not (meta_file.is_file() and zip_file.is_file() and state_file.is_file()):
        return None
    meta = json.loads(meta_file.read_text())
    if zip_mismatch(zip_file, meta) is not None:
        return None
    if file_sha256(state_file) != meta.get("learner_state_sha256"):
        return None
    state = torch.load(state_file, map_location="cpu", weights_only=True)
    return _Stored(name, meta, state)


def _resume_point(cfg: FastPPOConfig, out: Path) -> _Stored:
    """The newer of ``out``'s model and checkpoint to continue ``cfg`` from (a tie: the model);
    ``ValueError`` when there is none, or when the run was made with other options."""
    points = [p for p in (_read_point(out, n) for n in POINTS) if p is not None]
    if not points:
        raise ValueError(f"resume: nothing to resume in {out} (no complete model or checkpoint)")
    best = max(points, key=lambda p: (p.timesteps, p.name == "model"))
    stored = best.meta.get("config", {})
    given = json_config(cfg)
    # an option added after a run was made is missing from its record: it had its default
    defaults = {f.name: f.default for f in dataclasses.fields(FastPPOConfig)}
    diffs = [
        f"{k}: stored {stored.get(k, defaults[k])!r}, given {v!r}"
        for k, v in given.items()
        if k not in RESUMABLE_CHANGES and stored.get(k, defaults[k]) != v
    ]
    if diffs:
        raise ValueError(
            f"resume: the options differ from the run in {out} on what defines it: "
            + "; ".join(diffs)
        )
    return best


def json_config(cfg: FastPPOConfig) -> dict[str, Any]:
    """``cfg`` as ``model.json`` records it (tuples as lists)."""
    out = dataclasses.asdict(cfg)
    out["net_arch"] = list(cfg.net_arch)
    return out


class _Progress:
    """The rows of ``progress.csv`` (:mod:`training.curves`): about the follower episodes (and
    the team episodes: all followers of a copy) that ended since the last row."""

    def __init__(self, path: Path, every: int, start: int, keep: bool) -> None:
        self.path, self.every, self.last = path, every, start
        kept = []
        if keep and path.exists():
            kept = [r for r in read_rows(path) if int(r["timesteps"]) <= start]
        with path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=PROGRESS_COLUMNS)
            writer.writeheader()
            writer.writerows(kept)
        self.t0 = time.perf_counter()
        self.returns: list[NDArray[np.float64]] = []
        self.costs: list[NDArray[np.float64]] = []
        self.teams: list[NDArray[np.bool_]] = []

    def add(self, returns: NDArray[Any], costs: NDArray[Any], teams: NDArray[np.bool_]) -> None:
        """Ended follower episodes' returns and costs; ended team episodes' successes."""
        self.returns.append(returns)
        self.costs.append(costs)
        self.teams.append(teams)

    def maybe_write(self, timesteps: int, lam: float | None, force: bool = False) -> None:
        """Write a row if ``every`` transitions passed since the last (or ``force``, if any)."""
        if timesteps - self.last < self.every and not (force and timesteps > self.last):
            return
        self.last = timesteps
        r, c, s = (
            np.concatenate(x) if x else np.zeros(0) for x in (self.returns, self.costs, self.teams)
        )
        row = {
            "timesteps": timesteps,
            "wall_time_s": f"{time.perf_counter() - self.t0:.1f}",
            "episodes": len(c),
            "return_mean": f"{r.mean():.6g}" if len(r) else "",
            "success_rate": f"{s.mean():.6g}" if len(s) else "",
            "cost_mean": f"{c.mean():.6g}" if len(c) else "",
            "lambda": "" if lam is None else f"{lam:.6g}",
        }
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=PROGRESS_COLUMNS).writerow(row)
        self.returns, self.costs, self.teams = [], [], []


@contextlib.contextmanager
def _torch_threads(n: int) -> Iterator[None]:
    """``torch.set_num_threads(n)`` for the duration (restored afterwards)."""
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


# ------------------------------------------------------------------------------------------------
# The learner
# ------------------------------------------------------------------------------------------------
def train_fast(
    config: FastPPOConfig,
    out: str | os.PathLike[str],
    *,
    resume: bool = False,
    trainer: str = TRAINER,
) -> FastRun:
    """Train ``config`` into the directory ``out``; returns the model's path and counts.

    A new run needs an ``out`` that holds no run (:data:`FILES`); ``resume=True`` continues
    the run in ``out`` from the newer of its model and checkpoint (``ValueError`` if there is
    none, or if an option that defines the run differs: all but :data:`RESUMABLE_CHANGES`),
    as segment ``len(segments)`` with that segment's env streams; a run that already has
    ``timesteps`` is returned unchanged. See the module doc for the algorithm and the files.
    ``trainer`` is what ``model.json`` names as the trainer (:mod:`training.bc` fine-tunes
    through this function).
    """
    cfg = config
    out = Path(out)
    stored: _Stored | None = None
    if resume:
        stored = _resume_point(cfg, out)
        if stored.name == "model" and stored.timesteps >= cfg.timesteps:
            print(f"{out}: the model already has {stored.timesteps} timesteps", file=sys.stderr)
            return FastRun(out / "model.zip", stored.timesteps, False, stored.state.get("lambda"))
    else:
        present = [name for name in FILES if (out / name).exists()]
        if present:
            raise ValueError(
                f"out: {out} already holds a run ({', '.join(present)}); pass resume=True to "
                "continue it, or choose another directory"
            )
    previous: list[dict[str, Any]] = list(stored.meta.get("segments", [])) if stored else []
    segment = len(previous)
    with _torch_threads(cfg.torch_threads):
        return _learn(cfg, out, stored, previous, segment, trainer)


def initial_weights(path: str | os.PathLike[str], net: ActorCritic) -> dict[str, Any]:
    """Load the policy parameters of the SB3 ``PPO`` zip ``path`` into ``net``, all but
    ``log_std`` (``init_from``); returns what ``model.json`` records of the file (its path
    and SHA-256). ``ValueError`` naming ``init_from`` if it is missing or does not fit.

    Only the zip's ``policy.pth`` is read, with ``torch.load(weights_only=True)``: tensors,
    never pickled code (the zip's ``data`` entry, which SB3 fills with cloudpickled objects, is
    not read)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"init_from: no model at {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            raw = archive.read("policy.pth")
        policy = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except KeyError:
        raise ValueError(f"init_from: {path} holds no SB3 policy parameters") from None
    except (zipfile.BadZipFile, OSError, RuntimeError, pickle.UnpicklingError) as exc:
        raise ValueError(f"init_from: {path} is not a readable SB3 model zip ({exc})") from None
    if not isinstance(policy, Mapping):
        raise ValueError(f"init_from: {path} holds no SB3 policy parameters")
    mine = net.sb3_state_dict()
    wanted = {k: v for k, v in policy.items() if k != "log_std"}
    missing = sorted(set(mine) - set(wanted) - {"log_std"})
    extra = sorted(set(wanted) - set(mine))
    shapes = [
        f"{k}: {tuple(v.shape)} in the file, {tuple(mine[k].shape)} here"
        for k, v in wanted.items()
        if k in mine and tuple(v.shape) != tuple(mine[k].shape)
    ]
    if missing or extra or shapes:
        raise ValueError(
            f"init_from: {path} does not fit this network (observation size "
            f"{net.mlp_extractor.policy_net[0].in_features}, net_arch): "
            + "; ".join(
                ([f"missing {missing}"] if missing else [])
                + ([f"unexpected {extra}"] if extra else [])
                + shapes
            )
        )
    with torch.no_grad():
        for name, value in wanted.items():
            net.get_parameter(name).copy_(value)
    return {"path": str(path), "zip_sha256": file_sha256(path)}


def _learn(
    cfg: FastPPOConfig,
    out: Path,
    stored: _Stored | None,
    previous: list[dict[str, Any]],
    segment: int,
    trainer: str,
) -> FastRun:
    """The learner, top to bottom: set up, then collect / advantages / multiplier / update,
    a checkpoint every ``checkpoint_every`` transitions, the model at the end (or at Ctrl-C)."""
    device = torch.device(cfg.device)
    seed = process_seed(cfg.seed, segment)
    torch.manual_seed(seed)
    gen = torch.Generator(device=device)
    gen.manual_seed(seed)

    core, first_obs = make_core(cfg, segment)
    spec = SlotSpec.of(cfg, core)
    slots = _Slots.of(cfg, core, spec, device)
    learner = _new_learner(cfg, slots, stored, gen)
    expert = None if cfg.residual is None else BatchedExpert(core, cfg.residual)
    if stored is not None:
        learner.restore(stored.state, cfg)
    saver = sb3_model(cfg, spec, slots.T * slots.n_live)
    out.mkdir(parents=True, exist_ok=True)
    progress = _Progress(
        out / PROGRESS_FILE, cfg.log_every, learner.timesteps, keep=stored is not None
    )
    record = _Record.start(
        cfg, out, core, spec, saver, stored, previous, segment, trainer, learner.timesteps
    )
    buf = _Rollout.start(cfg, slots, core, first_obs)

    bar = None
    if cfg.progress_bar:
        bar = tqdm(total=cfg.timesteps, initial=learner.timesteps, unit="step", dynamic_ncols=True)
    last_checkpoint = learner.timesteps
    interrupted = False
    try:
        while learner.timesteps < cfg.timesteps:
            learner.net.eval()
            with torch.no_grad():  # collect T steps, then log π_old, the values and GAE
                rollout_costs, finals = _collect(
                    cfg, slots, core, expert, learner, buf, progress, bar
                )
                behaviour = _behaviour(cfg, slots, learner.net, buf, finals)
            lam = 0.0  # the multiplier moves on the rollout's costs before the update
            if learner.multiplier is not None:
                lam = _dual_ascent(learner.multiplier, rollout_costs)
            _update(cfg, learner, _live_samples(cfg, slots, buf, behaviour), lam)
            if cfg.checkpoint_every > 0 and (
                learner.timesteps - last_checkpoint >= cfg.checkpoint_every
            ):
                last_checkpoint = learner.timesteps
                record.save(learner, "checkpoint")
    except KeyboardInterrupt:
        interrupted = True
        print(
            f"\ninterrupted after {learner.timesteps} timesteps; saving the model so far",
            file=sys.stderr,
        )
    finally:
        if bar is not None:
            bar.close()
    progress.maybe_write(learner.timesteps, learner.lam(), force=True)
    path = record.save(learner, "model", interrupted)
    return FastRun(path, learner.timesteps, interrupted, learner.lam())


# --- set-up ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Slots:
    """The samples of a rollout: ``B`` env copies of ``N`` follower slots (``S = B * N``
    slots), ``T`` steps each; ``K`` the env's observation size, ``n_in`` the policy's input
    size (``K``, or ``K + 2`` with ``previous_command``), ``scale`` the fixed observation
    scale. The live slots of each copy (:attr:`BatchedPlatoon.live`) are all of them unless the
    scenario draws formations with fewer followers than ``N`` (``variable``); then they change
    at every reset, and samples, counts and team outcomes read the slots live when each sample
    was observed. ``live_flat`` and ``n_live`` are the fixed formation's live slots."""

    device: torch.device
    B: int
    N: int
    S: int
    T: int
    K: int
    n_in: int
    variable: bool
    live_flat: torch.Tensor
    n_live: int
    scale: torch.Tensor

    @classmethod
    def of(
        cls, cfg: FastPPOConfig, core: BatchedPlatoon, spec: SlotSpec, device: torch.device
    ) -> _Slots:
        """``core``'s slots for ``cfg``; ``ValueError`` if a minibatch exceeds a rollout."""
        B, N = core.batch_size, core.n_followers
        live = core.live
        n_live = int(live.sum())
        if cfg.batch_size > cfg.n_steps * n_live:
            raise ValueError(
                f"batch_size: {cfg.batch_size} exceeds the rollout n_steps * n_envs * followers "
                f"= {cfg.n_steps} * {B} * {N} = {cfg.n_steps * n_live}"
            )
        scale = torch.as_tensor(
            spec.obs_scale
            if spec.obs_scale is not None
            else np.ones(core.single_observation_space.shape, np.float32),
            device=device,
        )
        return cls(
            device=device,
            B=B,
            N=N,
            S=B * N,
            T=cfg.n_steps,
            K=int(core.single_observation_space.shape[0]),
            n_in=int(spec.observation_space.shape[0]),
            variable=core.variable_followers,
            live_flat=torch.as_tensor(live.reshape(-1), device=device),
            n_live=n_live,
            scale=scale,
        )

    def policy_input(
        self, cfg: FastPPOConfig, obs: NDArray[np.float32], sent: torch.Tensor
    ) -> torch.Tensor:
        """The policy's input ``(M, n_in)``: ``o_t / scale``, then (``previous_command``) the
        slot's previous command ``a_{t-1}`` as sent."""
        scaled = torch.as_tensor(obs, device=self.device).reshape(-1, self.K) / self.scale
        return torch.cat([scaled, sent], dim=1) if cfg.previous_command else scaled


@dataclass
class _Learner:
    """What is trained and what a saved point holds: the network, its optimiser, the
    multiplier ``λ`` (PPO-Lagrangian), the frozen network the anchor term pulls the actor's
    mean towards (``anchor_coef > 0``), the noise and minibatch generator, the transitions
    and the rollouts trained on in the run (the value warm-up counts them)."""

    net: ActorCritic
    optimizer: torch.optim.Optimizer
    multiplier: LagrangeMultiplier | None
    anchor: ActorCritic | None
    gen: torch.Generator
    initialised_from: dict[str, Any] | None
    timesteps: int = 0
    rollouts: int = 0

    def lam(self) -> float | None:
        """``λ`` now (None without a multiplier)."""
        return None if self.multiplier is None else self.multiplier.value

    def restore(self, state: Mapping[str, Any], cfg: FastPPOConfig) -> None:
        """Continue from a saved point's learner state."""
        self.net.load_state_dict(state["network"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.multiplier is not None:
            self.multiplier.value = float(state["lambda"])
        self.timesteps = int(state["timesteps"])
        self.rollouts = int(state.get("rollouts", cfg.value_warmup))

    def state(self) -> dict[str, Any]:
        """The learner state a saved point's ``.state.pt`` holds."""
        return {
            "network": {k: v.detach().cpu() for k, v in self.net.state_dict().items()},
            "optimizer": self.optimizer.state_dict(),
            "lambda": self.lam(),
            "timesteps": self.timesteps,
            "rollouts": self.rollouts,
        }


def _new_learner(
    cfg: FastPPOConfig, slots: _Slots, stored: _Stored | None, gen: torch.Generator
) -> _Learner:
    """The network (SB3's initialisation, ``init_from``'s weights, or a residual policy's zero
    output layer), Adam, the multiplier and the anchor network of a run (before a resumed
    run's state is restored)."""
    device, n_in = slots.device, slots.n_in
    net = ActorCritic(n_in, cfg.net_arch, cfg.log_std_init, cost_head=cfg.lagrangian).to(device)
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.learning_rate, eps=1e-5)
    multiplier = (
        LagrangeMultiplier(
            budget=cfg.cost_budget,
            lr=cfg.lagrangian_lr,
            initial=cfg.lagrangian_init,
            max_value=cfg.lagrangian_max,
        )
        if cfg.lagrangian
        else None
    )
    initialised_from = None
    if stored is None and cfg.init_from is not None:
        initialised_from = initial_weights(cfg.init_from, net)
    elif stored is not None:
        initialised_from = stored.meta.get("initialised_from")
    anchor: ActorCritic | None = None
    if cfg.anchor_coef > 0 and (cfg.init_from is not None or cfg.residual is None):
        if cfg.init_from is None:
            raise ValueError(
                "anchor_coef: needs init_from (the network the policy is kept near) or residual "
                "(then the policy is kept near the law)"
            )
        anchor = ActorCritic(n_in, cfg.net_arch, cfg.log_std_init, cost_head=False).to(device)
        initial_weights(cfg.init_from, anchor)
        anchor.requires_grad_(False)
        anchor.eval()
    # A residual policy starts as the clipped law: the actor's output layer is zero.
    if cfg.residual is not None and stored is None and cfg.init_from is None:
        with torch.no_grad():
            net.action_net.weight.zero_()
            net.action_net.bias.zero_()
    return _Learner(net, optimizer, multiplier, anchor, gen, initialised_from)


# --- saved points ---------------------------------------------------------------------------
@dataclass
class _Record:
    """What ``model.json`` records of this segment beside the learner state, and the SB3
    ``PPO`` object the weights are saved in; :meth:`save` writes a saved point."""

    cfg: FastPPOConfig
    out: Path
    spec: SlotSpec
    saver: PPO
    stored: _Stored | None
    previous: list[dict[str, Any]]
    trainer: str
    commit: dict[str, Any]
    started: str
    clock: float
    first_episodes: dict[str, Any]
    env_meta: dict[str, Any]
    start_timesteps: int

    @classmethod
    def start(
        cls,
        cfg: FastPPOConfig,
        out: Path,
        core: BatchedPlatoon,
        spec: SlotSpec,
        saver: PPO,
        stored: _Stored | None,
        previous: list[dict[str, Any]],
        segment: int,
        trainer: str,
        start_timesteps: int,
    ) -> _Record:
        """The record of segment ``segment`` (from ``start_timesteps``), its clock started
        now."""
        commit = git_commit()
        started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
        clock = time.perf_counter()
        first_episodes = {
            "env_seed_segment": segment,
            "first_layouts": [sc.layout_index for sc in core.scenarios]
            if core.source.procedural
            else None,
            "start_poses_sha256": _digest(core.poses),
        }
        env_meta = env_metadata(_train_view(cfg), core)
        return cls(
            cfg=cfg,
            out=out,
            spec=spec,
            saver=saver,
            stored=stored,
            previous=previous,
            trainer=trainer,
            commit=commit,
            started=started,
            clock=clock,
            first_episodes=first_episodes,
            env_meta=env_meta,
            start_timesteps=start_timesteps,
        )

    def save(self, learner: _Learner, name: str, interrupted: bool = False) -> Path:
        """Save ``learner`` as the point ``name`` (``model`` or ``checkpoint``), its three files
        whole (:func:`training.run.save_point`): the learner state, the SB3 zip and its JSON
        (:func:`training.policies.save_model`)."""
        return save_point(
            self.out / f"{name}.zip", lambda tmp: self._write(learner, tmp, interrupted)
        )

    def _write(self, learner: _Learner, path: Path, interrupted: bool) -> Path:
        """Write ``learner``'s point as ``path`` (``NAME.zip``), ``NAME.json`` and
        ``NAME.state.pt``."""
        cfg, stored, timesteps = self.cfg, self.stored, learner.timesteps
        state_file = path.with_suffix(".state.pt")
        digest = _atomic_torch_save(learner.state(), state_file)
        sb3_state = learner.net.sb3_state_dict()
        self.saver.policy.load_state_dict({k: v.detach().cpu() for k, v in sb3_state.items()})
        self.saver.num_timesteps = timesteps
        this = segment_metadata(
            started_at=self.started,
            wall_time_s=time.perf_counter() - self.clock,
            timesteps_start=self.start_timesteps,
            timesteps_end=timesteps,
            resumed_from=None if stored is None else f"{stored.name}.zip",
            commit=self.commit,
        )
        this.update(self.first_episodes)
        multiplier, initialised_from = learner.multiplier, learner.initialised_from
        meta: dict[str, Any] = {
            "algo": cfg.algo,
            "trainer": self.trainer,
            **({"residual": cfg.residual} if cfg.residual is not None else {}),
            **({"previous_command": True} if cfg.previous_command else {}),
            **({"initialised_from": initialised_from} if initialised_from else {}),
            **self.env_meta,
            **adapter_metadata(self.spec),
            "timesteps": timesteps,
            "timesteps_requested": cfg.timesteps,
            **({"lagrange_multiplier": multiplier.value} if multiplier is not None else {}),
            **self.commit,
            **timing_metadata([*self.previous, this], timesteps),
            "learner_state": state_file.name,
            "learner_state_sha256": digest,
            "config": json_config(cfg),
            "versions": library_versions(stable_baselines3, torch),
        }
        if path.stem == "model":
            meta["interrupted"] = interrupted
        return save_model(self.saver, path, meta)


# --- collection -----------------------------------------------------------------------------
@dataclass
class _Rollout:
    """The rollout storage (device tensors, time-major: ``[t, slot]``) and what collection
    carries from one rollout to the next: the env's last observation (raw, and as the
    policy's input), each slot's last command as sent, the live slots and the returns and
    costs of the episodes under way."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    done: torch.Tensor
    #: the law's normalised, clipped command of a residual policy (zeros otherwise)
    base: torch.Tensor
    cost: torch.Tensor | None
    #: the live samples
    live_samples: torch.Tensor
    raw_obs: NDArray[np.float32]
    next_obs: torch.Tensor
    #: previous_command: each slot's last command as sent (normalised, clipped), the
    #: standstill at an episode's start
    sent: torch.Tensor
    standstill: torch.Tensor
    live: NDArray[np.bool_]
    live_slots: NDArray[np.bool_]
    episode_return: NDArray[np.float64]
    episode_cost: NDArray[np.float64]

    @classmethod
    def start(
        cls, cfg: FastPPOConfig, slots: _Slots, core: BatchedPlatoon, first_obs: NDArray[Any]
    ) -> _Rollout:
        """Empty storage, and the copies at their first observations."""
        T, S, device = slots.T, slots.S, slots.device

        def zeros(*shape: int) -> torch.Tensor:
            return torch.zeros((T, *shape), dtype=torch.float32, device=device)

        obs, act, rew, done = zeros(S, slots.n_in), zeros(S, 2), zeros(S), zeros(S)
        base = zeros(S, 2)
        cost = zeros(S) if cfg.lagrangian else None
        live = core.live
        live_samples = torch.ones((T, S), dtype=torch.bool, device=device)
        standstill_np = to_normalised(np.zeros(2), cfg.action_range)[0]
        standstill = torch.as_tensor(standstill_np, device=device)
        sent = standstill.repeat(S, 1)
        return cls(
            obs=obs,
            act=act,
            rew=rew,
            done=done,
            base=base,
            cost=cost,
            live_samples=live_samples,
            raw_obs=first_obs,
            next_obs=slots.policy_input(cfg, first_obs, sent),
            sent=sent,
            standstill=standstill,
            live=live,
            live_slots=live.reshape(-1),
            episode_return=np.zeros(S),
            episode_cost=np.zeros(S),
        )


#: A time-limited end of some slots at step ``t``: their indices and the policy's input at
#: their final observations (bootstrapped: ``r + γ V(o_T)``).
_Final = tuple[int, NDArray[np.int64], torch.Tensor]


def _collect(
    cfg: FastPPOConfig,
    slots: _Slots,
    core: BatchedPlatoon,
    expert: BatchedExpert | None,
    learner: _Learner,
    buf: _Rollout,
    progress: _Progress,
    bar: tqdm | None,
) -> tuple[list[NDArray[np.float64]], list[_Final]]:
    """Collect ``T`` steps of every slot: one forward of the actor, one env call per step
    (under ``torch.no_grad``). Only the actor runs per step; the values and
    log-probabilities of the behaviour policy (unchanged during the rollout) are computed
    after it in one large batch (:func:`_behaviour`). Returns the costs of the follower
    episodes that ended, and the time-limited ends to bootstrap."""
    rollout_costs: list[NDArray[np.float64]] = []
    finals: list[_Final] = []
    net, gen, device = learner.net, learner.gen, slots.device
    std = torch.exp(net.log_std)
    for t in range(slots.T):
        mean = net.actor(buf.next_obs)
        if expert is not None:
            base, _ = to_normalised(expert.act(buf.raw_obs), cfg.action_range)
            buf.base[t] = torch.as_tensor(base, device=device).reshape(slots.S, 2)
            mean = mean + buf.base[t]
        action = mean + std * torch.randn(mean.shape, generator=gen, device=device)
        buf.obs[t] = buf.next_obs
        buf.act[t] = action
        if slots.variable:
            buf.live_samples[t] = torch.as_tensor(buf.live_slots, device=device)
        # SB3 clips the sample to the action Box before the adapter maps it.
        buf.sent = action.clamp(-1.0, 1.0)
        physical = cfg.action_range.to_physical(buf.sent.cpu().numpy())
        obs, reward, terminated, truncated, info = core.step(physical.reshape(slots.B, slots.N, 2))
        reward = reward.reshape(slots.S)
        cost = COST_OF_MASK[info["violations"]].reshape(slots.S)
        buf.episode_return += reward
        buf.episode_cost += cost
        ended = terminated | truncated
        slot_ended = np.repeat(ended, slots.N)
        buf.raw_obs = obs
        if ended.any():
            if expert is not None:  # the laws of the copies that reset start over
                expert.restart(ended)
            final = _time_limited(cfg, slots, buf, t, terminated, truncated, info)
            if final is not None:
                finals.append(final)
            rollout_costs.append(_episodes_ended(slots, buf, progress, ended, slot_ended))
        buf.rew[t] = torch.as_tensor(reward, device=device)
        buf.done[t] = torch.as_tensor(slot_ended, device=device)
        if buf.cost is not None:
            buf.cost[t] = torch.as_tensor(cost, device=device)
        buf.next_obs = slots.policy_input(cfg, obs, buf.sent)
        learner.timesteps += int(buf.live_slots.sum()) if slots.variable else slots.n_live
        if slots.variable:  # the envs that reset drew new formations
            buf.live = core.live
            buf.live_slots = buf.live.reshape(-1)
        progress.maybe_write(learner.timesteps, learner.lam())
        if bar is not None:
            bar.update(int(buf.live_samples[t].sum()) if slots.variable else slots.n_live)
    return rollout_costs, finals


def _time_limited(
    cfg: FastPPOConfig,
    slots: _Slots,
    buf: _Rollout,
    t: int,
    terminated: NDArray[np.bool_],
    truncated: NDArray[np.bool_],
    info: Mapping[str, Any],
) -> _Final | None:
    """The slots whose episode hit its time limit at step ``t`` (``truncated and not
    terminated``) and the policy's input at their final observations (None: no such slot)."""
    limit = np.repeat(truncated & ~terminated, slots.N)
    if not limit.any():
        return None
    index = np.flatnonzero(limit)
    final = info["final_observation"].reshape(slots.S, slots.K)[limit]
    where = torch.as_tensor(index, device=slots.device)
    return t, index, slots.policy_input(cfg, final, buf.sent[where])


def _episodes_ended(
    slots: _Slots,
    buf: _Rollout,
    progress: _Progress,
    ended: NDArray[np.bool_],
    slot_ended: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """Close the episodes of the copies that ``ended``: their slots start over (standstill
    sent, return and cost zero), the live followers' returns and costs and the teams'
    successes go to ``progress``; returns the follower episodes' costs."""
    # the slots that start over have sent nothing yet
    buf.sent[torch.as_tensor(slot_ended, device=slots.device)] = buf.standstill
    done = slot_ended & buf.live_slots
    costs = buf.episode_cost[done].copy()
    team = (buf.episode_cost.reshape(slots.B, slots.N) == 0) | ~buf.live
    progress.add(buf.episode_return[done].copy(), costs, team.all(1)[ended])
    buf.episode_return[slot_ended] = 0.0
    buf.episode_cost[slot_ended] = 0.0
    return costs


# --- advantages -----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Behaviour:
    """The behaviour policy's ``log π(a_t|o_t)`` ``(T, S)`` and the GAE advantages and returns
    of the reward (and of the cost: PPO-Lagrangian)."""

    logp: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor
    cost_advantages: torch.Tensor | None
    cost_returns: torch.Tensor | None


def _behaviour(
    cfg: FastPPOConfig, slots: _Slots, net: ActorCritic, buf: _Rollout, finals: list[_Final]
) -> _Behaviour:
    """The behaviour policy's ``log π`` and values of the rollout, the time-limit bootstraps
    (``r + γ V(o_T)``, ``c + γ V_c(o_T)``, added to the stored rewards and costs), then
    GAE(γ, λ_GAE) of the reward and of the cost (under ``torch.no_grad``)."""
    T, S, n_in, device = slots.T, slots.S, slots.n_in, slots.device
    mean = net.actor(buf.obs.reshape(T * S, n_in)) + buf.base.reshape(T * S, 2)
    logp = gaussian_log_prob(buf.act.reshape(T * S, 2), mean, net.log_std).reshape(T, S)
    values, cvalues = net.critics(buf.obs.reshape(T * S, n_in))
    val_buf = values.reshape(T, S)
    cval_buf = None if cvalues is None else cvalues.reshape(T, S)
    next_value, next_cvalue = net.critics(buf.next_obs)
    if finals:
        final_obs = torch.cat([f for _, _, f in finals])
        v_final, c_final = net.critics(final_obs)
        at = 0
        for t, index, _ in finals:
            rows = slice(at, at + len(index))
            where = torch.as_tensor(index, device=device)
            buf.rew[t, where] += cfg.gamma * v_final[rows]
            if buf.cost is not None and c_final is not None:
                buf.cost[t, where] += cfg.gamma * c_final[rows]
            at += len(index)

    advantages, returns = _gae(buf.rew, val_buf, buf.done, next_value, cfg)
    cost_adv = cost_returns = None
    if buf.cost is not None and cval_buf is not None and next_cvalue is not None:
        cost_adv, cost_returns = _gae(buf.cost, cval_buf, buf.done, next_cvalue, cfg)
    return _Behaviour(logp, advantages, returns, cost_adv, cost_returns)


def _dual_ascent(multiplier: LagrangeMultiplier, rollout_costs: list[NDArray[np.float64]]) -> float:
    """The multiplier's dual ascent on the rollout's follower-episode costs, before the update:
    ``λ ← clip(λ + η (Ĵ_c - b), 0, λ_max)``; returns the new ``λ``."""
    costs_all = np.concatenate(rollout_costs) if rollout_costs else np.zeros(0)
    return multiplier.update(costs_all)


# --- the PPO update -------------------------------------------------------------------------
@dataclass(frozen=True)
class _Samples:
    """A rollout's live samples, flattened: the policy's inputs, the actions, the law's part
    of the mean (zero unless residual), ``log π_old``, the advantages and returns (and the cost
    advantages, scaled by ``cost_advantage``, and cost returns)."""

    obs: torch.Tensor
    act: torch.Tensor
    base: torch.Tensor
    logp: torch.Tensor
    adv: torch.Tensor
    ret: torch.Tensor
    cadv: torch.Tensor | None
    cret: torch.Tensor | None


def _live_samples(
    cfg: FastPPOConfig, slots: _Slots, buf: _Rollout, behaviour: _Behaviour
) -> _Samples:
    """The live samples of the rollout: the slots live when each was observed."""

    def flat(x: torch.Tensor) -> torch.Tensor:
        if slots.variable:
            return x[buf.live_samples]  # (samples, ...): the slots live when observed
        x = x if slots.n_live == slots.S else x[:, slots.live_flat]
        return x.reshape(-1, *x.shape[2:])

    b_obs, b_act, b_logp = flat(buf.obs), flat(buf.act), flat(behaviour.logp)
    b_base = flat(buf.base)
    b_adv, b_ret = flat(behaviour.advantages), flat(behaviour.returns)
    b_cadv = b_cret = None
    if behaviour.cost_advantages is not None and behaviour.cost_returns is not None:
        b_cadv, b_cret = flat(behaviour.cost_advantages), flat(behaviour.cost_returns)
        b_cadv = scaled_cost_advantages(b_cadv, cfg.cost_advantage)
    return _Samples(b_obs, b_act, b_base, b_logp, b_adv, b_ret, b_cadv, b_cret)


def _update(cfg: FastPPOConfig, learner: _Learner, b: _Samples, lam: float) -> None:
    """PPO's update: ``n_epochs`` passes over minibatches of the live samples, each a step of
    Adam on ``-L + c_v (value losses) - c_e H (+ c_a drift)``, the gradient norm clipped. The
    first ``value_warmup`` rollouts of the run train the critic(s) alone."""
    net, optimizer, gen = learner.net, learner.optimizer, learner.gen
    n = b.obs.shape[0]
    warmup = learner.rollouts < cfg.value_warmup
    learner.rollouts += 1
    net.train()
    for _epoch in range(cfg.n_epochs):
        order = torch.randperm(n, generator=gen, device=b.obs.device)
        for start in range(0, n, cfg.batch_size):
            idx = order[start : start + cfg.batch_size]
            if len(idx) < 2:
                continue  # no standardised advantage of one sample
            loss = _minibatch_loss(cfg, learner, b, idx, lam, warmup)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), cfg.max_grad_norm)
            optimizer.step()


def _minibatch_loss(
    cfg: FastPPOConfig,
    learner: _Learner,
    b: _Samples,
    idx: torch.Tensor,
    lam: float,
    warmup: bool,
) -> torch.Tensor:
    """The loss of the minibatch ``idx``: the clipped surrogate ``L = E[min(ρ A, clip(ρ, 1 -
    ε, 1 + ε) A)]`` (``A`` of :func:`surrogate_advantages`), the squared-error value losses,
    the entropy bonus and the anchor's drift ``c_a E ||mu_theta(o) - mu_0(o)||^2``; in the
    value warm-up, the value losses alone (no gradient reaches the actor or ``log_std``)."""
    net, anchor = learner.net, learner.anchor
    own, value, cvalue = net(b.obs[idx])
    mean = own + b.base[idx]  # b.base is zero unless residual
    logp = gaussian_log_prob(b.act[idx], mean, net.log_std)
    ratio = torch.exp(logp - b.logp[idx])
    adv = surrogate_advantages(b.adv[idx], None if b.cadv is None else b.cadv[idx], lam)
    clipped = torch.clamp(ratio, 1.0 - cfg.clip_range, 1.0 + cfg.clip_range)
    policy_loss = -torch.min(adv * ratio, adv * clipped).mean()
    value_loss = ((value - b.ret[idx]) ** 2).mean()
    if cvalue is not None and b.cret is not None:
        value_loss = value_loss + ((cvalue - b.cret[idx]) ** 2).mean()
    entropy = (0.5 + _LOG_SQRT_2PI + net.log_std).sum()
    loss = policy_loss - cfg.ent_coef * entropy + cfg.vf_coef * value_loss
    if cfg.anchor_coef > 0:
        # to the start network's output, or (residual, no start) to zero
        if anchor is not None:
            with torch.no_grad():
                target = anchor.actor(b.obs[idx])
            own = own - target
        drift = (own**2).sum(-1).mean()
        loss = loss + cfg.anchor_coef * drift
    if warmup:  # no gradient reaches the actor or log_std
        loss = cfg.vf_coef * value_loss
    return loss


def _digest(array: NDArray[Any]) -> str:
    """The SHA-256 of an array's bytes."""
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()


def scaled_cost_advantages(cost_advantages: torch.Tensor, mode: str) -> torch.Tensor:
    """A rollout's cost advantages ``A_c`` as ``cost_advantage`` ``mode`` has them: unchanged
    (``centred``: :func:`surrogate_advantages` centres each minibatch's) or standardised over
    the rollout (``standardised``: zero mean, unit standard deviation)."""
    if mode == "centred":
        return cost_advantages
    if mode == "standardised":
        return (cost_advantages - cost_advantages.mean()) / (cost_advantages.std() + 1e-8)
    raise ValueError(f"cost_advantage must be one of {COST_ADVANTAGES}, got {mode!r}")


def surrogate_advantages(
    advantages: torch.Tensor, cost_advantages: torch.Tensor | None, lam: float
) -> torch.Tensor:
    """A minibatch's advantages in PPO's clipped surrogate: ``Â_r``, ``A_r`` standardised over
    the minibatch, and with cost advantages (PPO-Lagrangian) ``(Â_r - λ (A_c - mean A_c)) /
    (1 + λ)``."""
    adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    if cost_advantages is None:
        return adv
    return (adv - lam * (cost_advantages - cost_advantages.mean())) / (1.0 + lam)


def _gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    dones: torch.Tensor,
    next_value: torch.Tensor,
    cfg: FastPPOConfig,
) -> tuple[torch.Tensor, torch.Tensor]:
    """GAE advantages and returns ``(T, S)``: ``δ_t = r_t + γ V_{t+1} (1 - d_t) - V_t``,
    ``A_t = δ_t + γ λ_GAE (1 - d_t) A_{t+1}``, ``d_t`` the end of an episode at step ``t``."""
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(rewards.shape[0])):
        following = next_value if t == rewards.shape[0] - 1 else values[t + 1]
        alive = 1.0 - dones[t]
        delta = rewards[t] + cfg.gamma * following * alive - values[t]
        last = delta + cfg.gamma * cfg.gae_lambda * alive * last
        advantages[t] = last
    return advantages, advantages + values
