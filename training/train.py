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

Seeds: ``--seed`` seeds python, numpy, torch and the policy; every env of the run draws its own
stream of ``numpy.random.SeedSequence(seed)``, spawned per env and per segment (a ``--resume``
is a new segment: it continues with fresh streams instead of replaying the first episodes),
for both engines: :mod:`training.seeding`. Until this rule env ``j`` was seeded ``seed + j``,
so training seeds 0 and 1 shared 3 of their 4 envs: a new training run sees other layouts and
starts than one of the same seed did before (evaluation results do not change).

Every option is range-checked before anything is written (:func:`check_config`, then
:func:`check_scenario` against the resolved scenario): a bad value is an ``argparse`` error
naming the option (exit status 2), e.g. ``--timesteps`` below 1, ``--gamma`` outside [0, 1], a
``--device`` that is not available, an action range beyond the scenario's actuator limits, a
PPO ``--batch-size`` larger than its rollout or an empty ``--out``. Integer options take an
integral number in exponent form too (``--timesteps 2e6``), as floats take ``5e-2``, read
exactly (never through a float) and at most ``2**63 - 1`` in magnitude (:func:`integer`).

The code: the options, their checks and the training env are :mod:`training.config`; what a
run does in its folder (planning, the lock, segments) is :mod:`training.run`, shared with the
RLlib engine (:mod:`training.rllib`, imported only for ``--engine rllib``: Ray is optional);
this module is the command line and the SB3 driver.

Outputs in ``--out DIR``:

* ``model.zip`` + ``model.json`` — the final model and its description; see
  :mod:`training.policies`. Load with ``LearnedPolicy.load("DIR/model.zip")``.
* ``checkpoint.zip`` + ``checkpoint.json`` — the latest periodic checkpoint, replaced whole (both
  files written beside them first, then renamed into place, the JSON last, with SIGINT and
  SIGTERM held meanwhile: :func:`training.run.save_point`), so an interrupted run keeps its
  last one. On Ctrl-C the model so far is saved as
  ``model.zip`` (``"interrupted": true`` in ``model.json``) before exiting with status 130.
* ``progress.csv`` — the learning curve, a row every ``--log-every`` timesteps: mean return,
  success rate and cost of the follower episodes that ended in the window
  (:mod:`training.curves`).
* ``tb/`` — TensorBoard logs (``tensorboard --logdir DIR/tb``): SB3's losses, per-follower
  episode return/length (``rollout/``) and how follower episodes end (``platoon/``).

One run per directory: ``--out``, ``--resume``, ``--force``
-----------------------------------------------------------

A directory *holds a run* when it has any of :data:`RUN_FILES` (``model.zip``/``.json``,
``checkpoint.zip``/``.json``, ``rllib_checkpoint/``, ``tb/``, ``progress.csv``); an empty or
missing one does not. Every refusal below is an ``argparse``-style error (exit status 2) with
nothing written.

* One process at a time: a run holds ``DIR/run.lock`` (an ``fcntl.flock``; the file names its
  host, pid and start time) from planning to its last write, and a second run into the same
  ``--out`` is refused, naming that holder and how to release it. The lock dies with its
  process, ``kill -9`` included; a clean exit removes the file, so one left behind marks a
  killed run (:func:`training.run.run_status`), which the next run in the folder notes. An
  ``--out`` that cannot be created or written is refused the same way.

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
  ``model.zip`` (the final or Ctrl-C model), each only if its JSON's ``zip_sha256`` matches (a
  zip without its JSON, or with a JSON of another save, is a save cut off by ``kill -9``: it is
  left out, and named). If that already has ``--timesteps`` (a finished run), nothing is
  trained and nothing written: it says so and exits 0. With neither a checkpoint nor a model to
  continue from, it is an error (``platoon-sweep`` then starts the run over with ``--force``).
  ``--resume --force`` together is an error.

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
import json
import sys
import types
import typing
from collections.abc import Callable, Sequence
from contextlib import closing
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

import stable_baselines3
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecMonitor

from platoon_env.env import PlatoonParallelEnv
from platoon_env.scenarios.schema import VIOLATION_CAUSES, ScenarioError
from training.algorithms import finetune_algo, has_multiplier, is_clone, trained_by
from training.batched_vec_env import BatchedPlatoonVecEnv
from training.bc import BC_DIR, FINETUNE, BCConfig, train_bc_ppo
from training.config import (
    BOUNDS,
    ENV_FIELDS,
    MAX_LAYER,
    MAX_N_ENVS,
    MAX_SEED,
    MAX_TIMESTEPS,
    PPO_ALGOS,
    RUN_FIELDS_ALGO,
    RUN_FIELDS_COMMON,
    RUN_FIELDS_ENGINE,
    Bound,
    TrainConfig,
    auto_device,
    check_config,
    check_scenario,
    checked,
    config_differences,
    default_net_arch,
    device_error,
    env_metadata,
    env_overrides,
    flag,
    make_env,
    net_arch,
    run_fields,
    sb3_options,
    scenario_option,
)
from training.curves import PROGRESS_FILE, LearningCurveCallback
from training.fast_ppo import FastPPOConfig, train_fast
from training.lagrangian import LagrangeMultiplier, LagrangianCallback, LagrangianVecEnv
from training.policies import ALGORITHMS, adapter_metadata, save_model
from training.run import (
    RUN_FILES,
    RunError,
    RunPlan,
    Segment,
    finished_run,
    git_commit,
    hold_run,
    library_versions,
    open_run,
    plan_run,
    previous_segments,
    report_interrupt,
    save_point,
    segment_metadata,
    start_run,
    timing_metadata,
)
from training.seeding import process_seed
from training.vec_env import PlatoonVecEnv

#: The command line and the SB3 driver, and the names that moved to training.config and
#: training.run (importable from here as before).
__all__ = [
    "BOUNDS",
    "ENV_FIELDS",
    "MAX_LAYER",
    "MAX_N_ENVS",
    "MAX_SEED",
    "MAX_TIMESTEPS",
    "PPO_ALGOS",
    "RUN_FIELDS_ALGO",
    "RUN_FIELDS_COMMON",
    "RUN_FIELDS_ENGINE",
    "RUN_FILES",
    "Bound",
    "RunError",
    "RunPlan",
    "TrainConfig",
    "bc_config",
    "build_model",
    "build_parser",
    "build_vec_env",
    "check_config",
    "check_scenario",
    "cli_args",
    "config_differences",
    "default_net_arch",
    "device_error",
    "env_metadata",
    "env_overrides",
    "fast_config",
    "fast_defaults",
    "finished_run",
    "git_commit",
    "given_options",
    "integer",
    "main",
    "make_env",
    "parse_args",
    "plan_run",
    "previous_segments",
    "run_fields",
    "run_metadata",
    "segment_metadata",
    "start_run",
    "timing_metadata",
    "train",
    "train_fast_engine",
]


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


#: The largest magnitude of an integer option: int64's (numpy's, torch's and SQLite's).
INT64_MAX = 2**63 - 1


def integer(text: str) -> int:
    """The value of an integer option: an integer (``2000000``, ``2_000_000``) or an integral
    number in exponent form, as YAML writes it (``2e6``, ``1.5e3``), read exactly (never
    through a float) and at most :data:`INT64_MAX` in magnitude (so ``1e400`` or a
    5,000-digit number is refused at once, not computed); anything else is an ``argparse``
    error naming the option."""
    try:
        value = int(text)
    except ValueError:  # not an integer literal, or one of more digits than Python reads
        try:
            exact = Decimal(text.strip())  # exact: 1e23 is 10**23, not the nearest float's
        except InvalidOperation:
            exact = Decimal("NaN")
        # adjusted(): the exponent of the leading digit, read without arithmetic (1e10000000
        # is neither computed nor an overflow)
        if exact.is_finite() and exact != 0 and exact.adjusted() > len(str(INT64_MAX)):
            raise argparse.ArgumentTypeError(
                f"expected an integer of magnitude at most 2**63 - 1, got {text!r}"
            ) from None
        if not exact.is_finite() or exact != exact.to_integral_value():
            raise argparse.ArgumentTypeError(
                f"expected an integer (e.g. 100000 or 1e5), got {text!r}"
            ) from None
        value = int(exact)
    if abs(value) > INT64_MAX:
        raise argparse.ArgumentTypeError(
            f"expected an integer of magnitude at most 2**63 - 1, got {text!r}"
        )
    return value


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
            kwargs["type"] = _option_type(typing.get_args(tp)[0])
            kwargs["nargs"] = "+"
        else:
            kwargs["type"] = _option_type(tp)
        parser.add_argument(flag(f.name), dest=f.name, **kwargs)
    return parser


def _option_type(tp: Any) -> Any:
    """How the command line reads a value of type ``tp`` (ints: :func:`integer`)."""
    return integer if tp is int else tp


def parse_args(argv: Sequence[str] | None = None) -> TrainConfig:
    """Parse the command line into a :class:`TrainConfig`; a value out of range (see
    :func:`check_config`) is an ``argparse`` error (``SystemExit(2)``, the message on stderr).

    With ``--engine fast`` the options not given take the fast learner's defaults
    (:func:`fast_defaults`)."""
    parser = build_parser()
    cfg = TrainConfig(**vars(parser.parse_args(argv)))
    errors = check_config(cfg)
    if errors:
        parser.error("; ".join(errors))
    if cfg.engine == "fast":
        cfg = fast_defaults(cfg, given_options(argv))
    return cfg


#: A value no option can have: what :func:`given_options` parses the defaults as.
_UNSET = object()


def given_options(argv: Sequence[str] | None = None) -> set[str]:
    """The :class:`TrainConfig` fields the command line ``argv`` sets explicitly."""
    parser = build_parser()
    parser.set_defaults(**{f.name: _UNSET for f in dataclasses.fields(TrainConfig)})
    return {name for name, value in vars(parser.parse_args(argv)).items() if value is not _UNSET}


def fast_defaults(cfg: TrainConfig, given: set[str]) -> TrainConfig:
    """``cfg`` (``--engine fast``) with every option not in ``given`` that the fast learner has
    at its default there: :class:`~training.fast_ppo.FastPPOConfig`'s (e.g. ``--n-envs 512``,
    ``--n-steps 64``, ``--batch-size 8192``), for ``--algo bc_*`` :data:`training.bc.FINETUNE`'s
    and :class:`~training.bc.BCConfig`'s (``--bc-*``). So ``model.json``'s ``config`` records
    what was trained."""
    fast = FastPPOConfig()
    bc = BCConfig()
    bc_algo = is_clone(cfg.algo)
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(TrainConfig):
        if f.name in given:
            continue
        if bc_algo and f.name in FINETUNE:
            changes[f.name] = FINETUNE[f.name]
        elif f.name in FAST_FIELDS and f.name not in ("scenario", "algo", "seed", "device"):
            value = getattr(fast, f.name)
            changes[f.name] = list(value) if isinstance(value, tuple) else value
        elif bc_algo and f.name.startswith("bc_"):
            changes[f.name] = getattr(bc, f.name[3:])
    return dataclasses.replace(cfg, **changes)


#: What ``--engine fast --resume`` continues from (one of them must be in ``--out``).
FAST_RESUMABLE = ("model.json", "checkpoint.json", f"{BC_DIR}/model.json")
#: The fields of :class:`~training.fast_ppo.FastPPOConfig`.
FAST_FIELDS = frozenset(f.name for f in dataclasses.fields(FastPPOConfig))


def fast_config(cfg: TrainConfig) -> FastPPOConfig:
    """The :class:`~training.fast_ppo.FastPPOConfig` of ``cfg`` (``--engine fast``): every
    option of the same name (None: the fast learner's default), ``--algo bc_ppo`` fine-tunes
    with ``ppo`` (``bc_ppo_lagrangian``: ``ppo_lagrangian``), ``--device auto`` is
    :func:`~training.config.auto_device`."""
    values: dict[str, Any] = {}
    for name in FAST_FIELDS:
        if not hasattr(cfg, name) or getattr(cfg, name) is None:
            continue
        values[name] = getattr(cfg, name)
    values["algo"] = finetune_algo(cfg.algo)
    if cfg.device == "auto":
        values["device"] = auto_device()
    if "net_arch" in values:
        values["net_arch"] = tuple(values["net_arch"])
    return FastPPOConfig(**values)


def bc_config(cfg: TrainConfig) -> BCConfig:
    """The :class:`~training.bc.BCConfig` of ``cfg``'s ``--bc-*`` options (None: its default)."""
    values = {
        f.name: getattr(cfg, "bc_" + f.name)
        for f in dataclasses.fields(BCConfig)
        if getattr(cfg, "bc_" + f.name) is not None
    }
    return BCConfig(**values)


def train_fast_engine(cfg: TrainConfig, plan: RunPlan) -> tuple[Path, bool]:
    r"""``--engine fast``: :func:`training.fast_ppo.train_fast`, or for ``--algo bc_*``
    :func:`training.bc.train_bc_ppo`, into ``--out`` as ``plan`` says (held by the caller:
    :func:`training.run.hold_run`). ``--resume`` is the fast learner's own (it compares its
    whole config with the stored one and leaves a finished run as it is); its refusals are
    :class:`~training.run.RunError`\ s."""
    out = cfg.out_dir
    if plan.mode == "new":
        start_run(cfg, plan)
    elif not any((out / name).is_file() for name in FAST_RESUMABLE):
        raise RunError(
            f"argument --resume: nothing to resume in {out}: no model, checkpoint or clone "
            f"({', '.join(FAST_RESUMABLE)})"
        )
    try:
        fast = fast_config(cfg)
        if is_clone(cfg.algo):
            run = train_bc_ppo(bc_config(cfg), fast, out, resume=cfg.resume)
        else:
            run = train_fast(fast, out, resume=cfg.resume)
    except ValueError as e:
        raise RunError(str(e)) from None
    return run.path, run.interrupted


def cli_args(**options: Any) -> list[str]:
    """The ``platoon-train`` arguments setting ``options`` (:class:`TrainConfig` field names),
    the inverse of :func:`parse_args`: ``cli_args(seed=0, net_arch=[16, 16],
    progress_bar=False)`` is ``["--seed", "0", "--net-arch", "16", "16",
    "--no-progress-bar"]``. A None value is left out (every optional option defaults to None).
    """
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(options) - names)
    if unknown:
        raise TypeError(f"not options of platoon-train: {', '.join(unknown)}")
    args: list[str] = []
    for name, value in options.items():
        if value is None:
            continue
        if isinstance(value, bool):
            args.append(flag(name) if value else "--no-" + flag(name)[2:])
        elif isinstance(value, list | tuple):
            args += [flag(name), *(str(v) for v in value)]
        else:
            args += [flag(name), str(value)]
    return args


# ------------------------------------------------------------------------------------------------
# Building blocks (also used by the tests)
# ------------------------------------------------------------------------------------------------
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
    if not has_multiplier(cfg.algo):
        return venv
    lam = LagrangeMultiplier(budget=cfg.cost_budget, lr=cfg.lagrangian_lr)
    if multiplier is not None:
        lam.value = float(multiplier)
    return LagrangianVecEnv(venv, lam)


def build_model(cfg: TrainConfig, venv: Any, tensorboard_log: str | None = None) -> BaseAlgorithm:
    """The SB3 model for ``cfg.algo`` on ``venv``, seeded with ``cfg.seed`` (``ppo_lagrangian``
    is SB3's PPO on :func:`lagrangian_env`'s penalised rewards)."""
    arch = net_arch(cfg)
    kwargs: dict[str, Any] = {
        **sb3_options(cfg),
        "tensorboard_log": tensorboard_log,
        "seed": cfg.seed,
        "device": cfg.device,
        "verbose": cfg.verbose,
    }
    if cfg.algo in PPO_ALGOS:
        layers = {"net_arch": {"pi": arch, "vf": arch}}
        return PPO("MlpPolicy", lagrangian_env(cfg, venv), policy_kwargs=layers, **kwargs)
    if cfg.algo == "sac":
        return SAC("MlpPolicy", venv, policy_kwargs={"net_arch": arch}, **kwargs)
    known = trained_by("sb3")
    raise ValueError(
        f"unknown algo {cfg.algo!r}; expected {', '.join(map(repr, known[:-1]))} or {known[-1]!r}"
    )


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
        "versions": library_versions(stable_baselines3, torch),
        "command": sys.argv,
    }


# ------------------------------------------------------------------------------------------------
# Callbacks
# ------------------------------------------------------------------------------------------------
class CheckpointCallback(BaseCallback):
    """Every ``every`` timesteps, replace ``DIR/checkpoint.zip`` (+ ``.json``) whole
    (:func:`training.run.save_point`)."""

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
            meta = self.metadata()
            save_point(self.path, lambda tmp: save_model(self.model, tmp, meta))
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
def train(cfg: TrainConfig, plan: RunPlan | None = None) -> tuple[Path, bool]:
    """Train as ``cfg`` says; returns ``(path of model.zip, interrupted)``.

    ``plan``: :func:`plan_run`'s decision for ``--out`` (computed here if None). Raises
    ``ValueError`` for an option out of range and :class:`RunError` for a refused ``--out``
    (one another process holds, among others), both before anything is written. A finished
    run (``--resume``) is left as it is. Holds ``--out`` (:func:`training.run.hold_run`)
    throughout, as :func:`main` does around it.
    """
    checked(cfg)
    out = cfg.out_dir
    torch.set_num_threads(cfg.torch_threads)
    set_random_seed(cfg.seed)
    with closing(build_vec_env(cfg)) as venv, hold_run(out):
        plan = open_run(cfg, venv.envs[0], plan)
        if plan.mode == "finished":
            return finished_run(plan)
        # Before the model seeds the envs: a resumed segment draws new env streams.
        venv.seed_segment = plan.segment_index
        if plan.mode == "resume":
            model = _resumed_model(cfg, plan, venv)
        else:
            model = build_model(cfg, VecMonitor(venv), tensorboard_log=str(out / "tb"))
        segment = Segment(plan, int(model.num_timesteps))

        def metadata(**extra: Any) -> dict[str, Any]:
            done = int(model.num_timesteps)
            return run_metadata(cfg, venv, model, **segment.metadata(done), **extra)

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
                resume_from=segment.timesteps_start if plan.mode == "resume" else None,
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
                reset_num_timesteps=plan.mode != "resume",
                callback=CallbackList(callback_list),
                tb_log_name=cfg.run_name,
                progress_bar=sb3_bar,
            )
        except KeyboardInterrupt:
            interrupted = True
            report_interrupt(model.num_timesteps)
        meta = metadata(interrupted=interrupted)
        path = save_point(out / "model.zip", lambda tmp: save_model(model, tmp, meta))
    return path, interrupted


def _resumed_model(
    cfg: TrainConfig, plan: RunPlan, venv: PlatoonVecEnv | BatchedPlatoonVecEnv
) -> BaseAlgorithm:
    """The model ``plan`` resumes from, on ``venv``, seeded for its segment."""
    assert plan.source is not None
    model = ALGORITHMS[cfg.algo].load(
        plan.source,
        env=lagrangian_env(cfg, VecMonitor(venv), _stored_multiplier(plan.source)),
        device=cfg.device,
        tensorboard_log=str(cfg.out_dir / "tb"),
    )
    # Loading re-seeds python/numpy/torch with the run's seed, which would replay the first
    # segment's action noise: this segment has its own (training.seeding.process_seed).
    seed = process_seed(cfg.seed, plan.segment_index)
    set_random_seed(seed)
    model.action_space.seed(seed)
    print(plan.message, file=sys.stderr)
    return model


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


def _engine(
    parser: argparse.ArgumentParser, cfg: TrainConfig
) -> Callable[[TrainConfig, RunPlan], tuple[Path, bool]]:
    """The training function of ``--engine``: :func:`train`, :func:`train_fast_engine`, or
    RLlib's (a refusal if Ray RLlib is not installed)."""
    if cfg.engine == "fast":
        return train_fast_engine
    if cfg.engine != "rllib":
        return train
    try:
        # Here, not at the top: Ray is an optional, heavy dependency (training.rllib's classes
        # subclass RLlib's, so it imports Ray at its top); training.rllib does not import this
        # module, so there is no cycle.
        from training.rllib import train_rllib
    except ImportError as e:
        _fail(
            parser,
            f"argument --engine: rllib needs Ray RLlib ({e}); install the extra: "
            'pip install torch==2.13.0 -e ".[train,rllib]"',
        )
    return train_rllib


def _probe_env(parser: argparse.ArgumentParser, cfg: TrainConfig) -> PlatoonParallelEnv:
    """One training env, to check ``cfg`` against and plan with; a scenario that does not
    resolve is an ``argparse`` error naming its option."""
    try:
        return make_env(cfg)
    except ScenarioError as e:
        _fail(parser, f"argument {scenario_option(e)}: {e}")
    except (OSError, TypeError, ValueError) as e:
        _fail(parser, f"argument --scenario: {e}")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``platoon-train``; returns the exit status (130 after Ctrl-C).

    Every refusal (an option out of range, a scenario that does not resolve, a used
    ``--out``, an ``--out`` another run holds or that cannot be written, a ``--resume`` that
    does not match) exits with status 2 and an ``argparse`` message before anything is
    written; a ``--resume`` of a finished run exits 0 untouched.
    """
    parser = build_parser()
    cfg = parse_args(argv)
    engine = _engine(parser, cfg)
    try:
        # Held from before the plan to the last write: no other run plans on this folder until
        # this one is done with it (and a second run is refused before it spends time on its
        # env).
        with hold_run(cfg.out_dir):
            with closing(_probe_env(parser, cfg)) as probe:
                errors = check_scenario(cfg, probe)
                if errors:
                    _fail(parser, "; ".join(errors))
                # The fast learner resumes by its own rule (train_fast_engine); the folder's
                # new-run rules (a used --out, --force) are plan_run's for every engine.
                if cfg.engine == "fast" and cfg.resume:
                    plan = RunPlan("resume", cfg.out_dir)
                else:
                    plan = plan_run(cfg, probe)
            if plan.mode == "finished":
                print(plan.message)
                return 0
            path, interrupted = engine(cfg, plan)
    except RunError as e:
        _fail(parser, str(e))
    print(f"saved {path} and {path.with_suffix('.json')}")
    return 130 if interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
