"""Train one shared policy for all followers with Stable-Baselines3 (``platoon-train``).

Usage::

    platoon-train --algo ppo --scenario study_c --timesteps 1000000 --seed 0 --out runs/ppo_c
    platoon-train --engine rllib --num-env-runners 2 --scenario study_c --out runs/rllib_c
    platoon-train --algo ppo_lagrangian --cost-budget 0.05 --scenario study_c --out runs/lag_c
    python -m training.train --help        # every option, with its default

``--algo`` is ``ppo``, ``sac`` or ``ppo_lagrangian`` (SB3's PPO on rewards penalised by a
Lagrange multiplier on ``info["cost"]``, updated by dual ascent against ``--cost-budget``:
:mod:`training.lagrangian`).

``--engine sb3`` (the default) trains with Stable-Baselines3 in this process, as described
below; ``--engine rllib`` trains PPO with Ray RLlib on ``--num-env-runners`` env-runner actors
(locally, or on the cluster at ``--address``) through :mod:`training.rllib`, with the same
env, scaling and hyper-parameters, and writes the same ``model.zip`` + ``model.json`` (see
``docs/rllib.md``).

Each follower of each of ``--n-envs`` copies of the scenario is one slot of a
:class:`training.vec_env.PlatoonVecEnv` (parameter sharing), so ``--timesteps`` counts
*follower transitions*: ``env steps = timesteps / (n_envs * N)``. The policy sees the
observation divided by its Box bound and acts in ``[-1, 1]^2``, mapped to ``[u_low, u_high] x
[-omega_high, omega_high]``; the env's reward and its default ``terminate_on`` (every violation
cause) are used.

Control period: the env's default is 0.01 s (chosen for the PPC law), which makes an episode
thousands of steps long; training uses ``--control-period`` (default 0.05 s). The period is
recorded in ``model.json`` and exposed as ``LearnedPolicy.control_period``; evaluate at that
period unless you mean to test the policy at another one.

Every option is range-checked before anything is written (:func:`check_config`, then
:func:`check_scenario` against the resolved scenario): a bad value is an ``argparse`` error
naming the option (exit status 2), e.g. ``--timesteps`` below 1, ``--gamma`` outside [0, 1], a
``--device`` that is not available, an action range beyond the scenario's actuator limits or a
PPO ``--batch-size`` larger than its rollout.

Outputs in ``--out DIR``:

* ``model.zip`` + ``model.json`` — the final model and its description; see
  :mod:`training.policies`. Load with ``LearnedPolicy.load("DIR/model.zip")``.
* ``checkpoint.zip`` + ``checkpoint.json`` — the latest periodic checkpoint, replaced atomically,
  so an interrupted run keeps its last one. On Ctrl-C the model so far is saved as
  ``model.zip`` (``"interrupted": true`` in ``model.json``) before exiting with status 130.
* ``progress.csv`` — the learning curve, a row every ``--log-every`` timesteps: mean return,
  success rate and cost of the follower episodes that ended in the window
  (:mod:`training.curves`).
* ``tb/`` — TensorBoard logs (``tensorboard --logdir DIR/tb``): SB3's losses, per-follower
  episode return/length (``rollout/``) and how follower episodes end (``platoon/``).

One run per directory: ``--out``, ``--resume``, ``--force``
-----------------------------------------------------------

A directory *holds a run* when it has any of :data:`RUN_FILES` (``model.zip``/``.json``,
``checkpoint.zip``/``.json``, ``rllib_checkpoint/``, ``tb/``); an empty or missing one does not.
Every refusal below is an ``argparse``-style error (exit status 2) with nothing written.

* Without ``--resume`` or ``--force``, a ``--out`` that holds a run is refused: training into it
  would overwrite the earlier model, or mix two runs' checkpoints and logs.
* ``--force`` starts over: it says so, removes the earlier run's :data:`RUN_FILES` (nothing
  else in the directory) once the new run's options are checked, and trains from scratch.
* ``--resume`` continues the run in ``--out``. The stored config must match the given one on
  everything that defines the run (:func:`run_fields`: engine, algo, seed, ``--n-envs``, the
  action range and normalisation, every hyper-parameter of the algorithm, the RLlib runners,
  learners and critic) and on the *resolved* scenario (its fingerprint: the scenario content
  after ``--control-period``, ``--physics-substeps``, ``--max-episode-steps``,
  ``--sensor-profile`` and ``--task-aware-observations``, so ``./x.yaml`` and ``x.yaml`` are
  one scenario and an edited ``x.yaml`` is another); else the error names each differing
  field, stored vs given. ``--timesteps`` may differ: it is the new total. What does not
  define the run may change too: ``--device``, ``--torch-threads``,
  ``--batched``/``--env-threads`` (same trajectories), ``--checkpoint-every``,
  ``--progress-bar``, ``--verbose``, ``--address``.
  It continues from the newer (more timesteps; a tie: ``model.zip``) of ``checkpoint.zip`` and
  ``model.zip`` (the final or Ctrl-C model), each only if its JSON's ``zip_sha256`` matches. If
  that already has ``--timesteps`` (a finished run), nothing is trained and nothing written:
  it says so and exits 0. With neither a checkpoint nor a model to continue from, it is an
  error. ``--resume --force`` together is an error.

``model.json`` (and ``checkpoint.json``) fields
-----------------------------------------------

``format``/``format_version`` (2), ``engine``, ``algo``, ``zip_sha256`` (of the zip beside
it: :meth:`LearnedPolicy.load <training.policies.LearnedPolicy.load>` refuses a pair that does
not match), ``scenario`` (as given), ``scenario_fingerprint`` and ``scenario_config`` (the
resolved scenario config of the training env and its SHA-256:
:func:`platoon_env.scenarios.fingerprint.config_fingerprint`), ``seed``, ``control_period``,
``physics_substeps``, ``max_episode_steps`` (None for procedural layouts, each of which derives
its own), ``terminate_on``, ``n_followers``, ``observation_layout``/``action_layout``,
``observation_normalization``, ``action_range``, ``timesteps`` (trained),
``timesteps_requested``, ``git_commit``/``git_dirty`` (of this segment), ``started_at`` (of the
first segment), ``wall_time_s`` (the total over every segment that led to this model),
``timesteps_per_s`` (timesteps / total wall time), ``segments`` (one entry per invocation:
``started_at``, ``wall_time_s``, ``timesteps_start``/``timesteps_end``, ``resumed_from``,
``git_commit``, ``git_dirty``), ``interrupted`` (model.json only), ``config`` (every option),
``versions``, ``command``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import platform
import shutil
import subprocess
import sys
import time
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba
import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecMonitor

import platoon_env
from platoon_env.env import PlatoonParallelEnv
from platoon_env.observation import observation_names
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping
from platoon_env.scenarios.schema import (
    ACTION_BOUND_RANGE,
    MAX_CONTROL_PERIOD,
    MAX_EPISODE_STEPS,
    MAX_PHYSICS_SUBSTEPS,
    MIN_CONTROL_PERIOD,
    VIOLATION_CAUSES,
    ScenarioError,
)
from training.batched_vec_env import BatchedPlatoonVecEnv
from training.curves import PROGRESS_FILE, LearningCurveCallback
from training.lagrangian import LagrangeMultiplier, LagrangianCallback, LagrangianVecEnv
from training.policies import (
    ACTION_LAYOUT,
    ALGORITHMS,
    adapter_metadata,
    save_model,
    scenario_differences,
    zip_mismatch,
)
from training.vec_env import ActionRange, PlatoonVecEnv

__all__ = [
    "RUN_FILES",
    "RunError",
    "RunPlan",
    "TrainConfig",
    "build_model",
    "build_vec_env",
    "check_config",
    "check_scenario",
    "main",
    "parse_args",
    "plan_run",
    "run_fields",
    "train",
]

#: What marks ``--out`` as holding a run (and what ``--force`` removes).
RUN_FILES = (
    "model.zip",
    "model.json",
    "checkpoint.zip",
    "checkpoint.json",
    "rllib_checkpoint",
    "tb",
    "progress.csv",
)


def _opt(default: Any, help: str, **argparse_kwargs: Any) -> Any:
    """A dataclass field carrying its command-line help (and extra argparse settings)."""
    return field(default=default, metadata={"help": help, **argparse_kwargs})


@dataclass
class TrainConfig:
    """Every option of ``platoon-train``; the command-line flag is the field name with dashes."""

    # --- run ---
    engine: str = _opt(
        "sb3", "training engine: Stable-Baselines3, or Ray RLlib (PPO)", choices=("sb3", "rllib")
    )
    algo: str = _opt(
        "ppo",
        "learning algorithm (ppo_lagrangian: PPO with a Lagrange multiplier on info['cost'], "
        "see training/lagrangian.py)",
        choices=("ppo", "sac", "ppo_lagrangian"),
    )
    scenario: str = _opt("study_c", "shipped scenario name or YAML path to train on")
    timesteps: int = _opt(1_000_000, "total follower transitions (SB3 timesteps) to train for")
    seed: int = _opt(0, "seed of python/numpy/torch, the policy and the envs (env j: seed + j)")
    out: str | None = _opt(None, "output directory (default: runs/<algo>_<scenario>_s<seed>)")
    n_envs: int = _opt(4, "copies of the scenario stepped in lockstep (slots = n_envs * N)")
    batched: bool = _opt(
        False,
        "step the copies with the batched core in one compiled call (BatchedPlatoonVecEnv; "
        "fixed-workspace scenarios only); same trajectories as the default adapter",
    )
    env_threads: int = _opt(1, "numba threads of the batched core (with --batched)")
    # --- Ray RLlib (--engine rllib) ---
    num_env_runners: int = _opt(
        2,
        "rllib: env-runner actors sampling in parallel, each with --n-envs copies (0: sample "
        "in the driver)",
    )
    num_learners: int = _opt(0, "rllib: learner actors (0: one learner in the driver)")
    address: str | None = _opt(
        None,
        "rllib: Ray cluster to join ('auto', HOST:6379 or ray://HOST:10001; default: start a "
        "local Ray instance)",
    )
    critic: str = _opt(
        "local",
        "rllib: what the critic reads: the follower's observation, or (central, MAPPO-style) "
        "also the global state env.state()",
        choices=("local", "central"),
    )
    # --- env ---
    control_period: float = _opt(
        0.05, "[s] env control period for training (env default 0.01); saved in model.json"
    )
    physics_substeps: int | None = _opt(None, "physics sub-steps per env step (env default)")
    max_episode_steps: int | None = _opt(None, "truncate episodes after this many env steps")
    sensor_profile: str | None = _opt(
        None, "realism profile of the training envs (a shipped name such as aruco, or a YAML)"
    )
    task_aware_observations: bool = _opt(
        False,
        "train on task-aware observations (the scenario option observation.task_aware: the "
        "7-vector, then d_des, d_col, d_con, beta_con, r over fixed scales and the time since "
        "the predecessor was last perceived; 13 values, recorded in model.json)",
    )
    # --- action rescaling / observation normalisation ---
    u_low: float = _opt(-0.5, "[m/s] linear speed at normalised action -1")
    u_high: float = _opt(1.5, "[m/s] linear speed at normalised action +1")
    omega_high: float = _opt(2.0, "[rad/s] turn rate at normalised action +-1")
    normalize_observations: bool = _opt(
        True, "divide observations by their Box bound (fixed scale, saved in model.json)"
    )
    # --- shared hyper-parameters ---
    learning_rate: float = _opt(3e-4, "Adam learning rate")
    gamma: float = _opt(0.99, "discount factor")
    batch_size: int = _opt(256, "minibatch size (PPO) / replay batch size (SAC)")
    net_arch: list[int] | None = field(
        default=None,
        metadata={"help": "hidden layer sizes of actor and critic (PPO: 64 64, SAC: 256 256)"},
    )
    # --- PPO ---
    n_steps: int = _opt(512, "PPO: rollout length per slot (rollout = n_steps * slots)")
    n_epochs: int = _opt(10, "PPO: optimisation epochs per rollout")
    gae_lambda: float = _opt(0.95, "PPO: GAE lambda")
    clip_range: float = _opt(0.2, "PPO: policy clip range")
    ent_coef: float = _opt(0.0, "PPO: entropy bonus coefficient")
    vf_coef: float = _opt(0.5, "PPO: value loss coefficient")
    max_grad_norm: float = _opt(0.5, "PPO: gradient clipping norm")
    # --- PPO-Lagrangian ---
    cost_budget: float = _opt(
        0.05,
        "ppo_lagrangian: allowed expected cost per follower episode (the probability of a "
        "violation, with every cause terminating)",
    )
    lagrangian_lr: float = _opt(0.05, "ppo_lagrangian: step size of the multiplier's update")
    # --- SAC ---
    buffer_size: int = _opt(300_000, "SAC: replay buffer size (transitions)")
    learning_starts: int = _opt(10_000, "SAC: transitions collected before learning starts")
    tau: float = _opt(0.005, "SAC: target network soft-update rate")
    train_freq: int = _opt(1, "SAC: update every this many vectorised env steps")
    gradient_steps: int = _opt(
        2, "SAC: gradient steps per update (-1: one per transition collected)"
    )
    # --- bookkeeping ---
    checkpoint_every: int = _opt(100_000, "timesteps between checkpoints (0: none)")
    log_every: int = _opt(
        10_000, "timesteps between rows of the learning curve DIR/progress.csv (training.curves)"
    )
    resume: bool = _opt(
        False,
        "continue the run in --out (same config and resolved scenario; --timesteps may be "
        "raised) from the newer of checkpoint.zip and model.zip, up to --timesteps in total; a "
        "finished run is left as is (SAC restarts with an empty replay buffer; a resumed run "
        "is not bit-identical to an uninterrupted one)",
    )
    force: bool = _opt(
        False, "start over in an --out that holds an earlier run (its model, checkpoints, logs)"
    )
    progress_bar: bool = _opt(True, "show a progress bar (tqdm + rich)")
    torch_threads: int = _opt(1, "torch intra-op threads (1 is fastest for these small MLPs)")
    device: str = _opt("cpu", "torch device (cpu, cuda, cuda:N, mps, auto); must be available")
    verbose: int = _opt(0, "SB3 verbosity", choices=(0, 1, 2))

    @property
    def run_name(self) -> str:
        """``<algo>_<scenario>_s<seed>`` (scenario paths reduced to their stem), prefixed
        ``rllib_`` for the RLlib engine."""
        prefix = "rllib_" if self.engine == "rllib" else ""
        return f"{prefix}{self.algo}_{Path(self.scenario).stem}_s{self.seed}"

    @property
    def out_dir(self) -> Path:
        """The output directory (``out`` or ``runs/<run_name>``)."""
        return Path(self.out) if self.out is not None else Path("runs") / self.run_name

    @property
    def action_range(self) -> ActionRange:
        """The physical range of the policy's normalised action."""
        return ActionRange(u_low=self.u_low, u_high=self.u_high, omega_high=self.omega_high)


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def _base_type(tp: Any) -> tuple[Any, bool]:
    """``(T, optional)`` for ``T`` or ``T | None``."""
    args = typing.get_args(tp)
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        inner = [a for a in args if a is not type(None)]
        return inner[0], len(inner) < len(args)
    return tp, False


def build_parser() -> argparse.ArgumentParser:
    """An ``argparse`` parser with one flag per :class:`TrainConfig` field."""
    parser = argparse.ArgumentParser(
        prog="platoon-train",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    hints = typing.get_type_hints(TrainConfig)
    for f in dataclasses.fields(TrainConfig):
        tp, _ = _base_type(hints[f.name])
        kwargs: dict[str, Any] = dict(f.metadata)
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        kwargs["default"] = default
        if tp is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        elif typing.get_origin(tp) is list:
            kwargs["type"] = typing.get_args(tp)[0]
            kwargs["nargs"] = "+"
        else:
            kwargs["type"] = tp
        parser.add_argument("--" + f.name.replace("_", "-"), dest=f.name, **kwargs)
    return parser


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


@dataclass(frozen=True)
class Bound:
    """The closed (or, with ``*_open``, open) interval an option must lie in."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def __contains__(self, value: float) -> bool:
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)

    def __str__(self) -> str:
        if self.high is None:
            return f"{'>' if self.low_open else '>='} {self.low:g}"
        left = "(" if self.low_open else "["
        right = ")" if self.high_open else "]"
        return f"in {left}{self.low:g}, {self.high:g}{right}"


#: Largest --n-envs (copies stepped in lockstep; the slots' buffers grow with it).
MAX_N_ENVS = 4096
#: Largest --timesteps: 10**12 follower transitions, years at this machine's rate.
MAX_TIMESTEPS = 10**12
#: Seeds are numpy/torch/python seeds, below 2**32; env j gets seed + j.
MAX_SEED = 2**32 - 1
_U_MAX = ACTION_BOUND_RANGE[1]

#: The range of every numeric option (None values of optional ones are not checked).
BOUNDS: dict[str, Bound] = {
    "timesteps": Bound(1, MAX_TIMESTEPS),
    "seed": Bound(0, MAX_SEED),
    "n_envs": Bound(1, MAX_N_ENVS),
    "env_threads": Bound(1),  # and at most numba's thread pool (check_config)
    "num_env_runners": Bound(0, 1024),
    "num_learners": Bound(0, 1024),
    "control_period": Bound(MIN_CONTROL_PERIOD, MAX_CONTROL_PERIOD),
    "physics_substeps": Bound(1, MAX_PHYSICS_SUBSTEPS),
    "max_episode_steps": Bound(1, MAX_EPISODE_STEPS),
    "u_low": Bound(-_U_MAX, _U_MAX),
    "u_high": Bound(-_U_MAX, _U_MAX),
    "omega_high": Bound(0, _U_MAX, low_open=True),
    "learning_rate": Bound(0, 1, low_open=True),
    "gamma": Bound(0, 1),
    "batch_size": Bound(1, 10**9),  # PPO: >= 2 and at most the rollout (check_scenario)
    "n_steps": Bound(1, 10**9),
    "n_epochs": Bound(1, 10**6),
    "gae_lambda": Bound(0, 1),
    "clip_range": Bound(0, 1, low_open=True),
    "ent_coef": Bound(0),
    "vf_coef": Bound(0),
    "max_grad_norm": Bound(0, low_open=True),
    "cost_budget": Bound(0),
    "lagrangian_lr": Bound(0, low_open=True),
    "buffer_size": Bound(1, 10**9),
    "learning_starts": Bound(0),
    "tau": Bound(0, 1, low_open=True),
    "train_freq": Bound(1),
    "gradient_steps": Bound(1),  # or -1 (one per transition collected)
    "checkpoint_every": Bound(0),
    "log_every": Bound(1),
    "torch_threads": Bound(1, 1024),
}
#: Largest layer of --net-arch.
MAX_LAYER = 65536


def device_error(name: str) -> str | None:
    """Why torch device ``name`` cannot be used here, or None (``auto``: SB3's choice)."""
    if name == "auto":
        return None
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError, ValueError):
        return f"unknown torch device {name!r} (cpu, cuda, cuda:N, mps, auto)"
    if device.type == "cpu":
        return None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            built = "with" if torch.backends.cuda.is_built() else "without"
            return (
                f"{name!r}: no CUDA device is available (torch {torch.__version__}, built "
                f"{built} CUDA)"
            )
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            return f"{name!r}: there are {count} CUDA device(s)"
        return None
    if device.type == "mps":
        return None if torch.backends.mps.is_available() else f"{name!r}: MPS is not available"
    return f"{name!r}: device type {device.type!r} is not supported (cpu, cuda, mps)"


def check_config(cfg: TrainConfig) -> list[str]:
    """Every problem with ``cfg`` that needs no scenario, each as an ``argparse`` message
    naming its option (``argument --gamma: must be in [0, 1], got 5.0``); empty when fine.

    Numbers must lie in :data:`BOUNDS` (floats finite), ``--u-low < --u-high``, ``seed + n_envs
    - 1`` must be a valid seed, ``--gradient-steps`` is ``-1`` or ``>= 1``, PPO needs
    ``--batch-size >= 2`` and SAC ``--batch-size <= --buffer-size``; ``--device`` must be
    available; ``--engine rllib`` trains PPO without ``--batched``; ``--resume`` and
    ``--force`` exclude each other; ``--out`` must not be a file.
    """
    errors: list[str] = []

    def bad(name: str, message: str) -> None:
        errors.append(f"argument {_flag(name)}: {message}")

    for name, bound in BOUNDS.items():
        value = getattr(cfg, name)
        if value is None:
            continue
        if name == "gradient_steps" and value == -1:
            continue
        if isinstance(value, bool) or not isinstance(value, int | float):
            bad(name, f"must be a number, got {value!r}")
        elif not math.isfinite(value):
            bad(name, f"must be a finite number, got {value!r}")
        elif value not in bound:
            extra = " or -1" if name == "gradient_steps" else ""
            bad(name, f"must be {bound}{extra}, got {value!r}")
    threads = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    if cfg.env_threads > threads:
        bad("env_threads", f"must be at most numba's {threads} threads, got {cfg.env_threads}")
    if not errors:
        if not cfg.u_low < cfg.u_high:
            bad("u_high", f"must be > --u-low = {cfg.u_low:g}, got {cfg.u_high:g}")
        if cfg.seed + cfg.n_envs - 1 > MAX_SEED:
            bad("seed", "seed + n_envs - 1 must be <= 2**32 - 1 (env j is seeded with seed + j)")
        if cfg.algo in PPO_ALGOS and cfg.batch_size < 2:
            bad(
                "batch_size",
                f"PPO needs at least 2 (advantage normalisation), got {cfg.batch_size}",
            )
        if cfg.algo == "sac" and cfg.batch_size > cfg.buffer_size:
            bad("batch_size", f"must be <= --buffer-size = {cfg.buffer_size}, got {cfg.batch_size}")
    if cfg.net_arch is not None and not all(1 <= h <= MAX_LAYER for h in cfg.net_arch):
        bad("net_arch", f"layer sizes must be in [1, {MAX_LAYER}], got {cfg.net_arch}")
    if not str(cfg.scenario).strip():
        bad("scenario", "must name a scenario or a YAML file")
    reason = device_error(cfg.device)
    if reason is not None:
        bad("device", reason)
    if cfg.engine == "rllib" and cfg.algo != "ppo":
        bad("algo", f"--engine rllib trains PPO only, got {cfg.algo!r}")
    if cfg.engine == "rllib" and cfg.batched:
        bad("batched", "--engine rllib samples with its own env runners, not --batched")
    if cfg.engine == "rllib" and cfg.task_aware_observations:
        bad(
            "task_aware_observations",
            "--engine rllib builds its actor on the 7-vector (training/rllib.py reads OBS_SIZE "
            "columns); train task-aware policies with --engine sb3",
        )
    if cfg.resume and cfg.force:
        bad("force", "--resume continues the run in --out, --force discards it: pass one")
    if cfg.out_dir.exists() and not cfg.out_dir.is_dir():
        bad("out", f"{cfg.out_dir} exists and is not a directory")
    return errors


def check_scenario(cfg: TrainConfig, env: Any) -> list[str]:
    """The problems of ``cfg`` against its resolved training env ``env`` (one
    :func:`make_env`, or a batched core: anything with ``source``), as :func:`check_config`
    words them: an action range beyond the scenario's actuator limits, a PPO
    ``--batch-size`` larger than the rollout (``n_steps * n_envs * followers`` follower
    transitions; SB3 engine)."""
    errors: list[str] = []
    resolved = env.source.config
    u_max, omega_max = float(resolved.robot.u_max), float(resolved.robot.omega_max)
    followers = int(resolved.followers)
    tol = 1e-6
    if cfg.u_high > u_max + tol:
        errors.append(
            f"argument --u-high: {cfg.u_high:g} m/s exceeds the scenario's robot.u_max = {u_max:g}"
        )
    if cfg.u_low < -u_max - tol:
        errors.append(
            f"argument --u-low: {cfg.u_low:g} m/s exceeds the scenario's robot.u_max = {u_max:g}"
        )
    if cfg.omega_high > omega_max + tol:
        errors.append(
            f"argument --omega-high: {cfg.omega_high:g} rad/s exceeds the scenario's "
            f"robot.omega_max = {omega_max:g}"
        )
    if cfg.engine == "sb3" and cfg.algo in PPO_ALGOS:
        rollout = cfg.n_steps * cfg.n_envs * followers
        if cfg.batch_size > rollout:
            errors.append(
                f"argument --batch-size: {cfg.batch_size} exceeds the PPO rollout n_steps * "
                f"n_envs * followers = {cfg.n_steps} * {cfg.n_envs} * {followers} = {rollout}"
            )
    return errors


def _scenario_option(error: ScenarioError) -> str:
    """The option a scenario error is about (the env options map to their flags)."""
    path = error.path or ""
    for name in ("control_period", "physics_substeps", "max_episode_steps"):
        if path.endswith("simulation." + name):
            return _flag(name)
    text = str(error)
    if text.startswith("sensor profile") or "sensor_profile" in text:
        return "--sensor-profile"
    return "--scenario"


def parse_args(argv: Sequence[str] | None = None) -> TrainConfig:
    """Parse the command line into a :class:`TrainConfig`; a value out of range (see
    :func:`check_config`) is an ``argparse`` error (``SystemExit(2)``, the message on stderr)."""
    parser = build_parser()
    cfg = TrainConfig(**vars(parser.parse_args(argv)))
    errors = check_config(cfg)
    if errors:
        parser.error("; ".join(errors))
    return cfg


# ------------------------------------------------------------------------------------------------
# Building blocks (also used by the tests)
# ------------------------------------------------------------------------------------------------
def env_overrides(cfg: TrainConfig) -> dict[str, Any]:
    """The ``platoon_env.make`` overrides of the training envs: the training control period and
    whatever sub-steps, step limit, sensor profile and observation ``cfg`` sets (default
    termination)."""
    overrides: dict[str, Any] = {"control_period": cfg.control_period}
    if cfg.physics_substeps is not None:
        overrides["physics_substeps"] = cfg.physics_substeps
    if cfg.max_episode_steps is not None:
        overrides["max_episode_steps"] = cfg.max_episode_steps
    if cfg.sensor_profile is not None:
        overrides["sensor_profile"] = cfg.sensor_profile
    if cfg.task_aware_observations:
        overrides["observation"] = {"task_aware": True}
    return overrides


def make_env(cfg: TrainConfig) -> PlatoonParallelEnv:
    """One training env with :func:`env_overrides`.

    Its ``info`` holds only the violation entries (``diagnostics=False``): training reads
    nothing else, and the full dicts cost about a third of an env step.
    """
    return platoon_env.make(cfg.scenario, diagnostics=False, **env_overrides(cfg))


def build_vec_env(cfg: TrainConfig) -> PlatoonVecEnv | BatchedPlatoonVecEnv:
    """``n_envs`` copies of the scenario behind one parameter-sharing :class:`PlatoonVecEnv`
    (or, with ``cfg.batched``, a :class:`BatchedPlatoonVecEnv`)."""
    if cfg.n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {cfg.n_envs}")
    if cfg.batched:
        return BatchedPlatoonVecEnv(
            cfg.scenario,
            cfg.n_envs,
            n_threads=cfg.env_threads,
            normalize_observations=cfg.normalize_observations,
            action_range=cfg.action_range,
            **env_overrides(cfg),
        )
    fns: list[Callable[[], PlatoonParallelEnv]] = [lambda: make_env(cfg)] * cfg.n_envs
    return PlatoonVecEnv(
        fns, normalize_observations=cfg.normalize_observations, action_range=cfg.action_range
    )


def lagrangian_env(cfg: TrainConfig, venv: Any, multiplier: float | None = None) -> Any:
    """``venv`` with the rewards penalised by the Lagrange multiplier (``ppo_lagrangian``;
    ``multiplier``: its value to resume from), else ``venv`` itself."""
    if cfg.algo != "ppo_lagrangian":
        return venv
    lam = LagrangeMultiplier(budget=cfg.cost_budget, lr=cfg.lagrangian_lr)
    if multiplier is not None:
        lam.value = float(multiplier)
    return LagrangianVecEnv(venv, lam)


def build_model(cfg: TrainConfig, venv: Any, tensorboard_log: str | None = None) -> BaseAlgorithm:
    """The SB3 model for ``cfg.algo`` on ``venv``, seeded with ``cfg.seed`` (``ppo_lagrangian``
    is SB3's PPO on :func:`lagrangian_env`'s penalised rewards)."""
    if cfg.algo in PPO_ALGOS:
        arch = cfg.net_arch or [64, 64]
        return PPO(
            "MlpPolicy",
            lagrangian_env(cfg, venv),
            learning_rate=cfg.learning_rate,
            n_steps=cfg.n_steps,
            batch_size=cfg.batch_size,
            n_epochs=cfg.n_epochs,
            gamma=cfg.gamma,
            gae_lambda=cfg.gae_lambda,
            clip_range=cfg.clip_range,
            ent_coef=cfg.ent_coef,
            vf_coef=cfg.vf_coef,
            max_grad_norm=cfg.max_grad_norm,
            policy_kwargs={"net_arch": {"pi": list(arch), "vf": list(arch)}},
            tensorboard_log=tensorboard_log,
            seed=cfg.seed,
            device=cfg.device,
            verbose=cfg.verbose,
        )
    if cfg.algo == "sac":
        arch = cfg.net_arch or [256, 256]
        return SAC(
            "MlpPolicy",
            venv,
            learning_rate=cfg.learning_rate,
            buffer_size=cfg.buffer_size,
            learning_starts=cfg.learning_starts,
            batch_size=cfg.batch_size,
            tau=cfg.tau,
            gamma=cfg.gamma,
            train_freq=cfg.train_freq,
            gradient_steps=cfg.gradient_steps,
            policy_kwargs={"net_arch": list(arch)},
            tensorboard_log=tensorboard_log,
            seed=cfg.seed,
            device=cfg.device,
            verbose=cfg.verbose,
        )
    raise ValueError(f"unknown algo {cfg.algo!r}; expected 'ppo', 'sac' or 'ppo_lagrangian'")


def git_commit() -> dict[str, Any]:
    """The repository's commit and whether the work tree is dirty (None when unavailable)."""
    repo = Path(__file__).resolve().parents[1]

    def git(*args: str) -> str | None:
        try:
            res = subprocess.run(
                ["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=10
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return res.stdout.strip() if res.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"git_commit": commit, "git_dirty": None if status is None else bool(status)}


def env_metadata(cfg: TrainConfig, env: Any) -> dict[str, Any]:
    """What ``model.json`` records of the training env, for every engine: scenario (as given,
    and the resolved config with its fingerprint), seed, time step, step limit, episode-ending
    causes, the number of followers and the observation/action layout (the resolved
    scenario's: the 7-vector, or the 13 task-aware values)."""
    # A procedural source's layouts each derive the limit from their own path: record only a
    # set one.
    procedural = env.source.procedural
    resolved = env.source.config
    return {
        "scenario": cfg.scenario,
        "scenario_fingerprint": config_fingerprint(resolved),
        "scenario_config": config_mapping(resolved),
        "seed": cfg.seed,
        "control_period": env.control_period,
        "physics_substeps": env.physics_substeps,
        "max_episode_steps": cfg.max_episode_steps if procedural else env.max_episode_steps,
        "terminate_on": sorted(env.terminate_on),
        "n_followers": env.n_followers,
        "observation_layout": list(observation_names(resolved)),
        "action_layout": list(ACTION_LAYOUT),
    }


def run_metadata(
    cfg: TrainConfig,
    venv: PlatoonVecEnv | BatchedPlatoonVecEnv,
    model: BaseAlgorithm,
    **extra: Any,
) -> dict[str, Any]:
    """The ``model.json`` content for ``model`` trained by ``cfg`` on ``venv`` (with
    ``ppo_lagrangian``: the multiplier's value, to resume from)."""
    penalised = model.get_env()
    if isinstance(penalised, LagrangianVecEnv):
        extra = {"lagrange_multiplier": penalised.multiplier.value, **extra}
    return {
        "algo": cfg.algo,
        **env_metadata(cfg, venv.envs[0]),
        **adapter_metadata(venv),
        "timesteps": int(model.num_timesteps),
        "timesteps_requested": cfg.timesteps,
        **extra,
        "config": dataclasses.asdict(cfg),
        "versions": {
            "platoon_env": platoon_env.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "torch": torch.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "command": sys.argv,
    }


# ------------------------------------------------------------------------------------------------
# Callbacks
# ------------------------------------------------------------------------------------------------
class CheckpointCallback(BaseCallback):
    """Every ``every`` timesteps, atomically replace ``DIR/checkpoint.zip`` (+ ``.json``)."""

    def __init__(self, path: Path, every: int, metadata: Callable[[], dict[str, Any]]) -> None:
        super().__init__()
        self.path = path
        self.every = every
        self.metadata = metadata
        self._last = 0

    def _on_training_start(self) -> None:
        # A resumed run counts on from its restored timesteps: the next checkpoint is due
        # ``every`` after them, not at the first step.
        self._last = self.num_timesteps

    def _on_step(self) -> bool:
        if self.every > 0 and self.num_timesteps - self._last >= self.every:
            self._last = self.num_timesteps
            save_model(self.model, self.path, self.metadata())
        return True


class EpisodeEndCallback(BaseCallback):
    """Log how follower episodes end: ``platoon/violation`` and ``platoon/<cause>`` rates."""

    def _on_step(self) -> bool:
        for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
            if not done:
                continue
            cause = info.get("violation")
            self.logger.record_mean("platoon/violation", float(cause is not None))
            for name in VIOLATION_CAUSES:
                self.logger.record_mean(f"platoon/{name}", float(cause == name))
        return True


class TqdmProgressBar(BaseCallback):
    """A plain ``tqdm`` progress bar, used when ``rich`` (needed by SB3's own bar) is missing."""

    def __init__(self, total: int) -> None:
        super().__init__()
        self.total = total
        self.bar: Any = None

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(total=self.total, initial=self.num_timesteps, unit="step")

    def _on_step(self) -> bool:
        self.bar.n = self.num_timesteps
        self.bar.refresh()
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


def _sb3_progress_bar_available() -> bool:
    """SB3's progress bar needs both tqdm and rich."""
    try:
        import rich  # noqa: F401
        import tqdm  # noqa: F401
    except ImportError:
        return False
    return True


# ------------------------------------------------------------------------------------------------
# Training
# ------------------------------------------------------------------------------------------------
class RunError(ValueError):
    """A refused ``--out``/``--resume``/``--force`` (``platoon-train`` exits 2 with it)."""


#: The algorithms trained by SB3's PPO (with their rollout-size rules).
PPO_ALGOS = ("ppo", "ppo_lagrangian")

#: The options that define a run, for every algorithm and engine (:func:`run_fields`).
RUN_FIELDS_COMMON = (
    "engine",
    "algo",
    "seed",
    "n_envs",
    "u_low",
    "u_high",
    "omega_high",
    "normalize_observations",
    "learning_rate",
    "gamma",
    "batch_size",
    "net_arch",
)
#: The options that define a run of one algorithm.
RUN_FIELDS_ALGO: dict[str, tuple[str, ...]] = {
    "ppo": (
        "n_steps",
        "n_epochs",
        "gae_lambda",
        "clip_range",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
    ),
    "sac": ("buffer_size", "learning_starts", "tau", "train_freq", "gradient_steps"),
}
RUN_FIELDS_ALGO["ppo_lagrangian"] = (*RUN_FIELDS_ALGO["ppo"], "cost_budget", "lagrangian_lr")
#: The options that define a run of one engine.
RUN_FIELDS_ENGINE: dict[str, tuple[str, ...]] = {
    "sb3": (),
    "rllib": ("num_env_runners", "num_learners", "critic"),
}
#: The options that shape the training env: compared through the resolved scenario.
ENV_FIELDS = (
    "scenario",
    "control_period",
    "physics_substeps",
    "max_episode_steps",
    "sensor_profile",
    "task_aware_observations",
)


def run_fields(cfg: TrainConfig) -> tuple[str, ...]:
    """The options of ``cfg`` that define its run: ``--resume`` requires them unchanged (the
    env options are compared through the resolved scenario's fingerprint instead)."""
    return (
        RUN_FIELDS_COMMON
        + RUN_FIELDS_ALGO.get(cfg.algo, ())
        + RUN_FIELDS_ENGINE.get(cfg.engine, ())
    )


def default_net_arch(algo: str, engine: str) -> list[int]:
    """The hidden layers ``--net-arch`` defaults to: SB3's SAC 256 256, else 64 64."""
    return [256, 256] if algo == "sac" and engine == "sb3" else [64, 64]


def config_differences(
    cfg: TrainConfig, stored: Mapping[str, Any], fingerprint: str, scenario: Mapping[str, Any]
) -> list[str]:
    """How ``cfg`` (whose training env resolves to ``scenario`` with ``fingerprint``) differs
    from the run that wrote ``stored`` (a ``model.json``/``checkpoint.json``), on what defines a
    run: ``"--gamma: stored 0.99, given 0.9"``, and the scenario fields that differ."""
    stored_cfg = stored.get("config") if isinstance(stored.get("config"), Mapping) else {}
    assert isinstance(stored_cfg, Mapping)
    defaults = TrainConfig()

    def old(name: str) -> Any:  # a field the writer did not have yet had its default
        if name == "engine" and "engine" in stored:
            return stored["engine"]
        return stored_cfg.get(name, getattr(defaults, name))

    diffs: list[str] = []
    for name in run_fields(cfg):
        before, now = old(name), getattr(cfg, name)
        if name == "net_arch":
            before = default_net_arch(old("algo"), old("engine")) if before is None else before
            now = default_net_arch(cfg.algo, cfg.engine) if now is None else now
            before, now = [int(h) for h in before], [int(h) for h in now]
        if before != now:
            diffs.append(f"{_flag(name)}: stored {before!r}, given {now!r}")
    recorded = stored.get("scenario_fingerprint")
    if recorded is not None:
        if recorded != fingerprint:
            trained = stored.get("scenario_config")
            fields = (
                scenario_differences(trained, scenario, labels=("stored", "given"))
                if isinstance(trained, Mapping)
                else []
            )
            diffs.append(
                f"the resolved scenario (--scenario {cfg.scenario!r} with the env options): "
                f"fingerprint stored {str(recorded)[:12]}, given {fingerprint[:12]}"
                + (" (" + "; ".join(fields) + ")" if fields else "")
            )
    else:  # written before the fingerprint was recorded: compare the options themselves
        for name in ENV_FIELDS:
            before, now = old(name), getattr(cfg, name)
            if before != now:
                diffs.append(f"{_flag(name)}: stored {before!r}, given {now!r}")
    return diffs


@dataclass(frozen=True)
class RunPlan:
    """What :func:`plan_run` decided for ``--out``.

    ``mode``: ``"new"`` (train from scratch; ``discard``: what ``--force`` removes first),
    ``"resume"`` (continue from ``source``, whose JSON is ``stored``) or ``"finished"``
    (nothing to train: ``source`` is the model that already has ``--timesteps``; ``message``
    says so).
    """

    mode: str
    out: Path
    source: Path | None = None
    stored: Mapping[str, Any] = field(default_factory=dict)
    discard: tuple[Path, ...] = ()
    message: str = ""

    @property
    def timesteps(self) -> int:
        """Timesteps already trained (0 for a new run)."""
        return int(self.stored.get("timesteps", 0) or 0)

    @property
    def segments(self) -> list[dict[str, Any]]:
        """The training segments that led to ``source`` (empty for a new run)."""
        return previous_segments(self.stored)


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise RunError(f"{path} is unreadable ({e}); pass --force to start over") from None
    if not isinstance(data, dict):
        raise RunError(f"{path} is not a model description; pass --force to start over")
    return data


@dataclass(frozen=True)
class _Saved:
    name: str  # "model" or "checkpoint"
    meta: dict[str, Any]
    resume_from: Path | None  # what the engine restores (None: not resumable)

    @property
    def timesteps(self) -> int:
        return int(self.meta.get("timesteps", 0) or 0)


def _saved_points(cfg: TrainConfig, out: Path) -> tuple[list[_Saved], list[str]]:
    """The model and checkpoint in ``out`` whose zip matches its JSON, and why others were
    left out."""
    points: list[_Saved] = []
    skipped: list[str] = []
    for name in ("model", "checkpoint"):
        zip_path, meta = out / f"{name}.zip", _read_json(out / f"{name}.json")
        if meta is None or not zip_path.is_file():
            continue
        reason = zip_mismatch(zip_path, meta)
        if reason is not None:
            skipped.append(f"{name}.zip ({reason})")
            continue
        if cfg.engine == "rllib":  # restored from the full RLlib checkpoint beside it
            ckpt = out / "rllib_checkpoint"
            resume_from = ckpt if name == "checkpoint" and ckpt.is_dir() else None
        else:
            resume_from = zip_path
        points.append(_Saved(name, meta, resume_from))
    return points, skipped


def plan_run(cfg: TrainConfig, env: Any) -> RunPlan:
    """Decide what training ``cfg`` does in ``--out`` (the rules of the module doc), given its
    resolved training env ``env``; raises :class:`RunError` for a refusal. Writes nothing."""
    out = cfg.out_dir
    if out.exists() and not out.is_dir():
        raise RunError(f"argument --out: {out} exists and is not a directory")
    present = tuple(out / name for name in RUN_FILES if (out / name).exists())
    if cfg.resume and cfg.force:
        raise RunError("argument --force: --resume continues the run in --out, --force discards it")
    if not cfg.resume:
        if present and not cfg.force:
            raise RunError(
                f"argument --out: {out} already holds a run "
                f"({', '.join(p.name for p in present)}); "
                "pass --resume to continue it (same options, --timesteps may be raised) or "
                "--force to discard it and start over"
            )
        return RunPlan("new", out, discard=present if cfg.force else ())
    points, skipped = _saved_points(cfg, out)
    note = f" (left out: {'; '.join(skipped)})" if skipped else ""
    if not points:
        found = ", ".join(p.name for p in present) or "nothing"
        raise RunError(
            f"argument --resume: nothing to resume in {out}: no checkpoint and no model "
            f"(found: {found}){note}"
        )
    fingerprint = config_fingerprint(env.source.config)
    scenario = config_mapping(env.source.config)
    for point in points:
        diffs = config_differences(cfg, point.meta, fingerprint, scenario)
        if diffs:
            raise RunError(
                f"argument --resume: the options differ from the run in {out} "
                f"({point.name}.json) on what defines it: "
                + "; ".join(diffs)
                + ". Give the stored options, or --force to start over"
            )
    model = next((p for p in points if p.name == "model"), None)
    if model is not None and model.timesteps >= cfg.timesteps:
        how = "saved on Ctrl-C" if model.meta.get("interrupted") else "finished"
        return RunPlan(
            "finished",
            out,
            source=out / "model.zip",
            stored=model.meta,
            message=(
                f"{out}: nothing to do: model.zip ({how}) already has {model.timesteps} "
                f"timesteps >= --timesteps {cfg.timesteps}; left unchanged (raise --timesteps "
                "to train on)"
            ),
        )
    resumable = [p for p in points if p.resume_from is not None]
    if not resumable:
        raise RunError(
            f"argument --resume: nothing to resume in {out}: "
            + ("no rllib_checkpoint/ beside checkpoint.json" if cfg.engine == "rllib" else "")
            + note
        )
    best = max(resumable, key=lambda p: (p.timesteps, p.name == "model"))
    return RunPlan(
        "resume",
        out,
        source=best.resume_from,
        stored=best.meta,
        message=f"resuming from {best.resume_from} at {best.timesteps} timesteps{note}",
    )


def start_run(cfg: TrainConfig, plan: RunPlan) -> None:
    """Prepare ``--out`` for ``plan`` (not ``"finished"``): with ``--force``, say so and remove
    the earlier run's files; create the directory."""
    if cfg.force:
        if plan.discard:
            names = ", ".join(p.name for p in plan.discard)
            print(
                f"--force: discarding the earlier run in {plan.out} ({names}); starting over",
                file=sys.stderr,
            )
        else:
            print(f"--force: {plan.out} holds no earlier run; starting a new one", file=sys.stderr)
        for path in plan.discard:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
    plan.out.mkdir(parents=True, exist_ok=True)


def previous_segments(stored: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The training segments recorded in a ``model.json``/``checkpoint.json`` (one per
    invocation of ``platoon-train``); a file written before segments were recorded gives one
    segment from its ``wall_time_s``, which then covers only its last segment."""
    if not stored:
        return []
    segments = stored.get("segments")
    if isinstance(segments, list):
        return [dict(s) for s in segments]
    return [
        {
            "started_at": stored.get("started_at"),
            "wall_time_s": stored.get("wall_time_s"),
            "timesteps_start": None,
            "timesteps_end": stored.get("timesteps"),
            "resumed_from": None,
            "git_commit": stored.get("git_commit"),
            "git_dirty": stored.get("git_dirty"),
            "note": "recorded before segments were: the wall time of its last segment only",
        }
    ]


def segment_metadata(
    *,
    started_at: str,
    wall_time_s: float,
    timesteps_start: int,
    timesteps_end: int,
    resumed_from: str | None,
    commit: Mapping[str, Any],
) -> dict[str, Any]:
    """One entry of ``segments``: one invocation's share of the training."""
    done = timesteps_end - timesteps_start
    return {
        "started_at": started_at,
        "wall_time_s": round(wall_time_s, 3),
        "timesteps_start": timesteps_start,
        "timesteps_end": timesteps_end,
        "timesteps_per_s": round(done / wall_time_s, 1) if wall_time_s > 0 else None,
        "resumed_from": resumed_from,
        **commit,
        "command": list(sys.argv),
    }


def timing_metadata(segments: list[dict[str, Any]], timesteps: int) -> dict[str, Any]:
    """``started_at`` (the first segment's), ``wall_time_s`` (the sum over ``segments``),
    ``timesteps_per_s`` (``timesteps`` over that) and ``segments``."""
    total = sum(float(s.get("wall_time_s") or 0.0) for s in segments)
    return {
        "started_at": segments[0].get("started_at") if segments else None,
        "wall_time_s": round(total, 3),
        "timesteps_per_s": round(timesteps / total, 1) if total > 0 else None,
        "segments": segments,
    }


def settle_plan(cfg: TrainConfig, env: Any, plan: RunPlan | None) -> RunPlan:
    """``plan``, or what :func:`plan_run` decides for ``--out``, once ``cfg`` is checked
    against its resolved training env (:func:`check_scenario`); raises ``ValueError`` or
    :class:`RunError` before anything is written. Shared by both engines."""
    errors = check_scenario(cfg, env)
    if errors:
        raise ValueError("; ".join(errors))
    return plan if plan is not None else plan_run(cfg, env)


def finished_run(plan: RunPlan) -> tuple[Path, bool]:
    """What a ``--resume`` of a finished run returns (it says so, and changes nothing)."""
    print(plan.message, file=sys.stderr)
    assert plan.source is not None
    return plan.source, False


def train(cfg: TrainConfig, plan: RunPlan | None = None) -> tuple[Path, bool]:
    """Train as ``cfg`` says; returns ``(path of model.zip, interrupted)``.

    ``plan``: :func:`plan_run`'s decision for ``--out`` (computed here if None). Raises
    ``ValueError`` for an option out of range and :class:`RunError` for a refused ``--out``,
    both before anything is written. A finished run (``--resume``) is left as it is.
    """
    errors = check_config(cfg)
    if errors:
        raise ValueError("; ".join(errors))
    out = cfg.out_dir
    torch.set_num_threads(cfg.torch_threads)
    set_random_seed(cfg.seed)
    venv = build_vec_env(cfg)
    try:
        plan = settle_plan(cfg, venv.envs[0], plan)
    except BaseException:
        venv.close()
        raise
    if plan.mode == "finished":
        venv.close()
        return finished_run(plan)
    start_run(cfg, plan)
    start_from = plan.source if plan.mode == "resume" else None
    if start_from is not None:
        stored = _stored_multiplier(start_from)
        model = ALGORITHMS[cfg.algo].load(
            start_from,
            env=lagrangian_env(cfg, VecMonitor(venv), stored),
            device=cfg.device,
            tensorboard_log=str(out / "tb"),
        )
        print(plan.message, file=sys.stderr)
    else:
        model = build_model(cfg, VecMonitor(venv), tensorboard_log=str(out / "tb"))
    commit = git_commit()
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    previous = plan.segments
    first_timestep = int(model.num_timesteps)

    def metadata(**extra: Any) -> dict[str, Any]:
        segment = segment_metadata(
            started_at=started,
            wall_time_s=time.perf_counter() - t0,
            timesteps_start=first_timestep,
            timesteps_end=int(model.num_timesteps),
            resumed_from=None if start_from is None else start_from.name,
            commit=commit,
        )
        return run_metadata(
            cfg,
            venv,
            model,
            **commit,
            **timing_metadata([*previous, segment], int(model.num_timesteps)),
            **extra,
        )

    callback_list: list[BaseCallback] = [
        CheckpointCallback(out / "checkpoint.zip", cfg.checkpoint_every, metadata),
        EpisodeEndCallback(),
    ]
    penalised = model.get_env()
    if isinstance(penalised, LagrangianVecEnv):
        callback_list.append(LagrangianCallback(penalised))
    callback_list.append(
        LearningCurveCallback(
            out / PROGRESS_FILE,
            cfg.log_every,
            resume_from=first_timestep if start_from is not None else None,
            multiplier=_multiplier_reader(penalised),
        )
    )
    sb3_bar = cfg.progress_bar and _sb3_progress_bar_available()
    if cfg.progress_bar and not sb3_bar:
        callback_list.append(TqdmProgressBar(cfg.timesteps))
    interrupted = False
    try:
        model.learn(
            total_timesteps=max(0, cfg.timesteps - model.num_timesteps),
            reset_num_timesteps=start_from is None,
            callback=CallbackList(callback_list),
            tb_log_name=cfg.run_name,
            progress_bar=sb3_bar,
        )
    except KeyboardInterrupt:
        interrupted = True
        print(
            f"\ninterrupted after {model.num_timesteps} timesteps; saving the model so far",
            file=sys.stderr,
        )
    path = save_model(model, out / "model.zip", metadata(interrupted=interrupted))
    venv.close()
    return path, interrupted


def _multiplier_reader(venv: Any) -> Callable[[], float] | None:
    """A callable reading the Lagrange multiplier of ``venv`` (None if it is not penalised)."""
    if not isinstance(venv, LagrangianVecEnv):
        return None
    lam = venv.multiplier
    return lambda: lam.value


def _stored_multiplier(model_path: Path) -> float | None:
    """The Lagrange multiplier recorded beside a model or checkpoint (None if absent)."""
    try:
        meta = json.loads(model_path.with_suffix(".json").read_text())
    except (OSError, ValueError):
        return None
    value = meta.get("lagrange_multiplier")
    return None if value is None else float(value)


def _fail(parser: argparse.ArgumentParser, message: str) -> typing.NoReturn:
    parser.error(message)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``platoon-train``; returns the exit status (130 after Ctrl-C).

    Every refusal (an option out of range, a scenario that does not resolve, a used
    ``--out``, a ``--resume`` that does not match) exits with status 2 and an ``argparse``
    message before anything is written; a ``--resume`` of a finished run exits 0 untouched.
    """
    parser = build_parser()
    cfg = parse_args(argv)
    if cfg.engine == "rllib":
        try:
            from training.rllib import train_rllib
        except ImportError as e:
            _fail(
                parser,
                f"argument --engine: rllib needs Ray RLlib ({e}); install the extra: "
                'pip install torch==2.13.0 -e ".[train,rllib]"',
            )
    try:
        probe = make_env(cfg)
    except ScenarioError as e:
        _fail(parser, f"argument {_scenario_option(e)}: {e}")
    except (OSError, TypeError, ValueError) as e:
        _fail(parser, f"argument --scenario: {e}")
    try:
        errors = check_scenario(cfg, probe)
        if errors:
            _fail(parser, "; ".join(errors))
        plan = plan_run(cfg, probe)
    except RunError as e:
        _fail(parser, str(e))
    finally:
        probe.close()
    if plan.mode == "finished":
        print(plan.message)
        return 0
    if cfg.engine == "rllib":
        path, interrupted = train_rllib(cfg, plan)
    else:
        path, interrupted = train(cfg, plan)
    print(f"saved {path} and {path.with_suffix('.json')}")
    return 130 if interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
