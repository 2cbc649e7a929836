"""What a ``platoon-train`` run is: its options, their checks, its env and what defines it.

Shared by both engines (:mod:`training.train` for Stable-Baselines3, :mod:`training.rllib` for
Ray RLlib) and by the run planning (:mod:`training.run`):

* :class:`TrainConfig` — every option; the command-line flag is the field name with dashes
  (:func:`flag`);
* :func:`check_config` / :func:`check_scenario` — the range checks, each problem an
  ``argparse``-style message naming its option (:data:`BOUNDS`);
* :func:`env_overrides` / :func:`make_env` / :func:`env_metadata` — the training env and what
  ``model.json`` records of it;
* :func:`run_fields` / :func:`config_differences` — what defines a run, so ``--resume`` can
  refuse options that would make it another one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba
import torch

import platoon_env
from platoon_env.env import PlatoonParallelEnv
from platoon_env.observation import observation_names
from platoon_env.realism import REALISM_PRESETS
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping
from platoon_env.scenarios.schema import (
    ACTION_BOUND_RANGE,
    MAX_CONTROL_PERIOD,
    MAX_EPISODE_STEPS,
    MAX_PHYSICS_SUBSTEPS,
    MIN_CONTROL_PERIOD,
    ScenarioError,
)
from platoon_env.scenarios.source import MixtureSource
from training.algorithms import ALGORITHMS, clones, is_clone, trained_by
from training.experts import EXPERTS
from training.policies import ACTION_LAYOUT, scenario_differences
from training.vec_env import ActionRange

__all__ = [
    "BOUNDS",
    "COST_ADVANTAGES",
    "ENGINES",
    "ENV_FIELDS",
    "FAST_ALGOS",
    "FAST_ONLY",
    "PPO_ALGOS",
    "RLLIB_ALGOS",
    "Bound",
    "TrainConfig",
    "auto_device",
    "check_config",
    "check_scenario",
    "checked",
    "config_differences",
    "default_net_arch",
    "device_error",
    "env_metadata",
    "env_overrides",
    "flag",
    "make_env",
    "net_arch",
    "run_fields",
    "sb3_options",
    "scenario_option",
]

#: The algorithms trained by SB3's PPO (with their rollout-size rules): the table's PPO
#: learners that are not clones.
PPO_ALGOS = tuple(a.name for a in ALGORITHMS.values() if a.sb3_class == "ppo" and not a.clone)
#: The algorithms of ``--engine fast`` (:mod:`training.fast_ppo`; ``bc_*``: :mod:`training.bc`,
#: behaviour cloning of the PPC law with DAgger, then that PPO fine-tuning).
FAST_ALGOS = trained_by("fast")
#: The algorithms of ``--engine rllib`` (:mod:`training.rllib`).
RLLIB_ALGOS = trained_by("rllib")
#: How PPO-Lagrangian scales the cost advantages ``A_c`` (``cost_advantage``): ``centred`` per
#: minibatch only (OmniSafe's PPOLag), or ``standardised`` over the rollout first (unit
#: standard deviation), so that the penalised surrogate ``(Â_r - λ Â_c) / (1 + λ)`` keeps the
#: scale of PPO's for every ``λ``. Centred, ``A_c`` is small beside the standardised ``A_r`` (a
#: violation is a rare 0/1 cost): as ``λ`` grows the surrogate's gradient shrinks, and a fixed
#: regulariser (``anchor_coef``) then wins over it.
COST_ADVANTAGES = ("centred", "standardised")
#: The engines of ``--engine``.
ENGINES = ("sb3", "rllib", "fast")


def _opt(default: Any, help: str, **argparse_kwargs: Any) -> Any:
    """A dataclass field carrying its command-line help (and extra argparse settings)."""
    return field(default=default, metadata={"help": help, **argparse_kwargs})


@dataclass
class TrainConfig:
    """Every option of ``platoon-train``; the command-line flag is the field name with dashes."""

    # --- run ---
    engine: str = _opt(
        "sb3",
        "training engine: Stable-Baselines3, Ray RLlib (PPO), or fast (training/fast_ppo.py: "
        "PPO on the batched core at simulator speed; options it has and not given here take "
        "its own defaults, e.g. --n-envs 512)",
        choices=ENGINES,
    )
    algo: str = _opt(
        "ppo",
        "learning algorithm (ppo_lagrangian: PPO with a Lagrange multiplier on info['cost'], "
        f"see training/lagrangian.py; {', '.join(clones())} (--engine fast): clone the PPC "
        "law with DAgger, then fine-tune, training/bc.py)",
        choices=tuple(ALGORITHMS),
    )
    scenario: str = _opt("study_c", "shipped scenario name or YAML path to train on")
    timesteps: int = _opt(1_000_000, "total follower transitions (SB3 timesteps) to train for")
    seed: int = _opt(
        0,
        "seed of python/numpy/torch, the policy and the envs (each env its own stream of "
        "numpy's SeedSequence(seed), new on every --resume: training/seeding.py)",
    )
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
    scale_free_observations: bool = _opt(
        False,
        "with --task-aware-observations: express positions and clearances over d_con and the "
        "bearing over beta_con (the scenario option observation.scale_free; 15 values, one "
        "policy's inputs in fixed bounds across formations; recorded in model.json)",
    )
    realism_preset: str | None = _opt(
        None,
        "draw each training episode's sensing and actuation from a preset's ranges (the "
        "scenario option realism: {preset: NAME}, e.g. ideal_to_beyond_aruco; "
        "platoon_env/realism.py)",
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
    # --- the fast engine (--engine fast; None: training.fast_ppo.FastPPOConfig's default) ---
    layout_repeats: int | None = _opt(
        None, "fast: episodes an env copy keeps a procedural layout for (FastPPOConfig's default)"
    )
    log_std_init: float | None = _opt(
        None,
        "fast: initial log std of the policy's Gaussian (FastPPOConfig's; bc_*: "
        "training.bc.FINETUNE)",
    )
    lagrangian_init: float | None = _opt(None, "fast, ppo_lagrangian: initial multiplier")
    lagrangian_max: float | None = _opt(None, "fast, ppo_lagrangian: bound of the multiplier")
    cost_advantage: str | None = _opt(
        None,
        "fast, ppo_lagrangian: scaling of the cost advantages in the surrogate: centred "
        "(FastPPOConfig's default, OmniSafe's) or standardised over the rollout "
        "(COST_ADVANTAGES in training.config)",
        choices=COST_ADVANTAGES,
    )
    init_from: str | None = _opt(
        None,
        "fast: start the network from this SB3 PPO model.zip (same observation size and "
        "--net-arch; all policy parameters but log_std)",
    )
    value_warmup: int | None = _opt(
        None,
        "fast: first rollouts in which only the critic learns (FastPPOConfig's; bc_*: "
        "training.bc.FINETUNE)",
    )
    anchor_coef: float | None = _opt(
        None,
        "fast: weight of the squared distance of the policy's mean action from the network it "
        "started from (--init-from; bc_*: the clone); 0: none (FastPPOConfig's default)",
    )
    residual: str | None = _opt(
        None,
        "fast: a residual policy on this analytic law: the action's mean is the law's command "
        "(normalised, clipped to the action range) plus the network's output, which starts at "
        "zero (training.fast_ppo; ppo or ppo_lagrangian)",
        choices=tuple(EXPERTS),
    )
    previous_command: bool = _opt(
        False,
        "fast: the policy also reads its own previous command (normalised, as sent; the "
        "standstill at an episode's start): proprioception for actuators that lag the command "
        "(recorded in model.json as previous_command)",
    )
    # --- behaviour cloning (--algo bc_*; None: training.bc.BCConfig's default) ---
    bc_expert: str | None = _opt(None, "bc: the analytic law cloned (ppc)", choices=tuple(EXPERTS))
    bc_iterations: int | None = _opt(None, "bc: DAgger iterations (iteration 0: the expert's)")
    bc_steps_per_iteration: int | None = _opt(
        None, "bc: control steps of every env copy per DAgger iteration"
    )
    bc_beta_decay: float | None = _opt(
        None, "bc: the expert acts with probability beta_decay**i in iteration i"
    )
    bc_epochs: int | None = _opt(None, "bc: passes over the aggregated data per iteration")
    bc_batch_size: int | None = _opt(None, "bc: regression minibatch size")
    bc_learning_rate: float | None = _opt(None, "bc: Adam learning rate of the regression")
    bc_max_samples: int | None = _opt(None, "bc: size cap of the aggregated data set")
    bc_holdout: float | None = _opt(None, "bc: share of each iteration's samples held out")
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
    device: str = _opt(
        "cpu",
        "torch device (cpu, cuda, cuda:N, mps; auto: cuda when torch sees one, else cpu); must "
        "be available",
    )
    verbose: int = _opt(0, "SB3 verbosity", choices=(0, 1, 2))

    @property
    def run_name(self) -> str:
        """``<algo>_<scenario>_s<seed>`` (scenario paths reduced to their stem), prefixed
        ``rllib_`` for the RLlib engine."""
        prefix = f"{self.engine}_" if self.engine != "sb3" else ""
        return f"{prefix}{self.algo}_{Path(self.scenario).stem}_s{self.seed}"

    @property
    def out_dir(self) -> Path:
        """The output directory (``out`` or ``runs/<run_name>``)."""
        return Path(self.out) if self.out is not None else Path("runs") / self.run_name

    @property
    def action_range(self) -> ActionRange:
        """The physical range of the policy's normalised action."""
        return ActionRange(u_low=self.u_low, u_high=self.u_high, omega_high=self.omega_high)


def flag(name: str) -> str:
    """The command-line flag of option ``name`` (``n_envs`` -> ``--n-envs``)."""
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
#: Seeds are numpy/torch/python seeds, below 2**32 (the envs' are drawn from them:
#: :mod:`training.seeding`).
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
    # --- the fast engine (training.fast_ppo) ---
    "layout_repeats": Bound(1, 10**6),
    "log_std_init": Bound(-20, 2),
    "lagrangian_init": Bound(0),
    "lagrangian_max": Bound(0, low_open=True),
    "value_warmup": Bound(0, 10**6),
    "anchor_coef": Bound(0),
    # --- behaviour cloning (training.bc.BCConfig: the same names without bc_) ---
    "bc_iterations": Bound(1, 10_000),
    "bc_steps_per_iteration": Bound(1, 10**7),
    "bc_beta_decay": Bound(0, 1),
    "bc_epochs": Bound(1, 10_000),
    "bc_batch_size": Bound(1, 10**9),
    "bc_learning_rate": Bound(0, 1, low_open=True),
    "bc_max_samples": Bound(1, 10**10),
    "bc_holdout": Bound(0, 0.5),
}
#: The options of the fast engine only (``--engine fast``).
FAST_ONLY = (
    "layout_repeats",
    "log_std_init",
    "lagrangian_init",
    "lagrangian_max",
    "cost_advantage",
    "init_from",
    "value_warmup",
    "anchor_coef",
    "residual",
)
#: Largest layer of --net-arch.
MAX_LAYER = 65536


def device_error(name: str) -> str | None:
    """Why torch device ``name`` cannot be used here, or None (``auto``: :func:`auto_device`)."""
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


def auto_device() -> str:
    """``--device auto``: ``cuda`` when torch sees a CUDA device, else ``cpu`` (SB3's rule
    too)."""
    return "cuda" if torch.cuda.is_available() else "cpu"


def check_config(cfg: TrainConfig) -> list[str]:
    """Every problem with ``cfg`` that needs no scenario, each as an ``argparse`` message
    naming its option (``argument --gamma: must be in [0, 1], got 5.0``); empty when fine.

    Numbers must lie in :data:`BOUNDS` (floats finite), ``--u-low < --u-high``,
    ``--gradient-steps`` is ``-1`` or ``>= 1``, PPO needs ``--batch-size >= 2`` and SAC
    ``--batch-size <= --buffer-size``; ``--device`` must be available; ``--engine rllib``
    trains PPO or PPO-Lagrangian, not ``--batched``; ``--resume`` excludes ``--force``;
    ``--out`` must name a directory (not ``''``, not a file).
    """
    errors: list[str] = []

    def bad(name: str, message: str) -> None:
        errors.append(f"argument {flag(name)}: {message}")

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
    if cfg.scale_free_observations and not cfg.task_aware_observations:
        bad("scale_free_observations", "needs --task-aware-observations")
    if cfg.realism_preset is not None and cfg.realism_preset not in REALISM_PRESETS:
        bad(
            "realism_preset",
            f"must be one of {sorted(REALISM_PRESETS)}, got {cfg.realism_preset!r}",
        )
    threads = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    if cfg.env_threads > threads:
        bad("env_threads", f"must be at most numba's {threads} threads, got {cfg.env_threads}")
    if not errors:
        if not cfg.u_low < cfg.u_high:
            bad("u_high", f"must be > --u-low = {cfg.u_low:g}, got {cfg.u_high:g}")
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
    if cfg.engine == "rllib" and cfg.algo not in RLLIB_ALGOS:
        bad("algo", f"--engine rllib trains {' and '.join(RLLIB_ALGOS)}, got {cfg.algo!r}")
    if cfg.engine == "rllib" and cfg.batched:
        bad("batched", "--engine rllib samples with its own env runners, not --batched")
    if cfg.engine == "fast" and cfg.algo not in FAST_ALGOS:
        bad("algo", f"--engine fast trains {', '.join(FAST_ALGOS)}, got {cfg.algo!r}")
    if cfg.engine != "fast" and is_clone(cfg.algo):
        bad("algo", f"{cfg.algo} trains with --engine fast, got --engine {cfg.engine}")
    if cfg.engine == "fast" and cfg.batched:
        bad("batched", "--engine fast always steps the batched core; --batched is sb3's adapter")
    if cfg.engine != "fast":
        for name in FAST_ONLY:
            if getattr(cfg, name) is not None:
                bad(name, f"is an option of --engine fast, got --engine {cfg.engine}")
    if not is_clone(cfg.algo):
        for name in (f for f in BOUNDS if f.startswith("bc_")):
            if getattr(cfg, name) is not None:
                bad(name, f"is an option of --algo {' / '.join(clones())}, got {cfg.algo}")
    if cfg.previous_command and cfg.engine != "fast":
        bad("previous_command", f"is an option of --engine fast, got --engine {cfg.engine}")
    if cfg.previous_command and is_clone(cfg.algo):
        bad("previous_command", f"the clone reads the observation only (--algo {cfg.algo})")
    if cfg.residual is not None and is_clone(cfg.algo):
        bad("residual", f"starts from the law itself, not from a clone (--algo {cfg.algo})")
    if cfg.init_from is not None and not str(cfg.init_from).endswith(".zip"):
        bad("init_from", f"must be the path of a model .zip, got {cfg.init_from!r}")
    if cfg.resume and cfg.force:
        bad("force", "--resume continues the run in --out, --force discards it: pass one")
    if cfg.out is not None and not str(cfg.out).strip():
        # Path("") is the working directory: a run would spread its files over it.
        bad("out", f"must name a directory, got {cfg.out!r}")
    elif cfg.out_dir.exists() and not cfg.out_dir.is_dir():
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
    if cfg.engine in ("sb3", "fast") and cfg.algo in (*PPO_ALGOS, *FAST_ALGOS):
        rollout = cfg.n_steps * cfg.n_envs * followers
        if cfg.batch_size > rollout:
            errors.append(
                f"argument --batch-size: {cfg.batch_size} exceeds the PPO rollout n_steps * "
                f"n_envs * followers = {cfg.n_steps} * {cfg.n_envs} * {followers} = {rollout}"
            )
    return errors


def checked(cfg: TrainConfig) -> TrainConfig:
    """``cfg``, or ``ValueError`` with every problem :func:`check_config` finds (what the
    engines' library entry points do before anything else)."""
    errors = check_config(cfg)
    if errors:
        raise ValueError("; ".join(errors))
    return cfg


def scenario_option(error: ScenarioError) -> str:
    """The option a scenario error is about (the env options map to their flags)."""
    path = error.path or ""
    for name in ("control_period", "physics_substeps", "max_episode_steps"):
        if path.endswith("simulation." + name):
            return flag(name)
    text = str(error)
    if text.startswith("sensor profile") or "sensor_profile" in text:
        return "--sensor-profile"
    return "--scenario"


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
        if cfg.scale_free_observations:
            overrides["observation"]["scale_free"] = True
    if cfg.realism_preset is not None:
        overrides["realism"] = {"preset": cfg.realism_preset}
    return overrides


def make_env(cfg: TrainConfig) -> PlatoonParallelEnv:
    """One training env with :func:`env_overrides`.

    Its ``info`` holds only the violation entries (``diagnostics=False``): training reads
    nothing else, and the full dicts cost about a third of an env step.
    """
    return platoon_env.make(cfg.scenario, diagnostics=False, **env_overrides(cfg))


def env_metadata(cfg: TrainConfig, env: Any) -> dict[str, Any]:
    """What ``model.json`` records of the training env, for every engine: scenario (as given,
    and the resolved config with its fingerprint), seed, time step, step limit, episode-ending
    causes, the number of followers and the observation/action layout (the resolved
    scenario's: the 7-vector, or the 13 task-aware values). A mixture (``"a+b"``,
    :class:`~platoon_env.scenarios.source.MixtureSource`) also records each component's name
    and fingerprint (``scenario_components``); ``scenario_config`` is the first's."""
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
        **_mixture_metadata(env.source),
    }


def _mixture_metadata(source: Any) -> dict[str, Any]:
    """``{"scenario_components": [{"name", "fingerprint"}, ...]}`` of a mixture source (also
    one wrapped by the fast engine's layout repeater, ``.inner``), else ``{}``."""
    while not isinstance(source, MixtureSource) and hasattr(source, "inner"):
        source = source.inner
    if not isinstance(source, MixtureSource):
        return {}
    return {
        "scenario_components": [
            {"name": part.config.name, "fingerprint": config_fingerprint(part.config)}
            for part in source.components
        ]
    }


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
#: The options SB3's PPO and SAC take under their own names (:func:`sb3_options`).
_SB3_CLASS_OPTIONS: dict[str, tuple[str, ...]] = {
    "ppo": (
        "learning_rate",
        "n_steps",
        "batch_size",
        "n_epochs",
        "gamma",
        "gae_lambda",
        "clip_range",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
    ),
    "sac": (
        "learning_rate",
        "buffer_size",
        "learning_starts",
        "batch_size",
        "tau",
        "gamma",
        "train_freq",
        "gradient_steps",
    ),
}
#: The same, by algorithm: its SB3 class's (none for a clone, which the fast learner trains).
SB3_OPTIONS: dict[str, tuple[str, ...]] = {
    a.name: _SB3_CLASS_OPTIONS[a.sb3_class] for a in ALGORITHMS.values() if not a.clone
}
#: The options that define a run of one algorithm: what its learner is given (beyond the
#: common ones), and with a Lagrange multiplier its budget and step size.
RUN_FIELDS_ALGO: dict[str, tuple[str, ...]] = {
    algo: tuple(name for name in names if name not in RUN_FIELDS_COMMON)
    + (("cost_budget", "lagrangian_lr") if ALGORITHMS[algo].lagrangian else ())
    for algo, names in SB3_OPTIONS.items()
}
#: The options that define a run of one engine.
RUN_FIELDS_ENGINE: dict[str, tuple[str, ...]] = {
    "sb3": (),
    "rllib": ("num_env_runners", "num_learners", "critic"),
    "fast": (),  # its own resume rule: training.fast_ppo compares its whole config
}
#: The options that shape the training env: compared through the resolved scenario.
ENV_FIELDS = (
    "scenario",
    "control_period",
    "physics_substeps",
    "max_episode_steps",
    "sensor_profile",
    "task_aware_observations",
    "scale_free_observations",
    "realism_preset",
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


def net_arch(cfg: TrainConfig) -> list[int]:
    """The hidden layers of ``cfg``'s actor and critic: ``--net-arch``, else the default."""
    return list(cfg.net_arch) if cfg.net_arch else default_net_arch(cfg.algo, cfg.engine)


def sb3_options(cfg: TrainConfig) -> dict[str, Any]:
    """The keyword arguments of ``cfg.algo``'s SB3 learner that are options of the same name
    (:data:`SB3_OPTIONS`; none for an unknown algorithm)."""
    return {name: getattr(cfg, name) for name in SB3_OPTIONS.get(cfg.algo, ())}


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
            diffs.append(f"{flag(name)}: stored {before!r}, given {now!r}")
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
                diffs.append(f"{flag(name)}: stored {before!r}, given {now!r}")
    return diffs
