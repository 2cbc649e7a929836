"""Train one shared policy for all followers with Stable-Baselines3 (``platoon-train``).

Usage::

    platoon-train --algo ppo --scenario study_c --timesteps 1000000 --seed 0 --out runs/ppo_c
    platoon-train --engine rllib --num-env-runners 2 --scenario study_c --out runs/rllib_c
    python -m training.train --help        # every option, with its default

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

Outputs in ``--out DIR``:

* ``model.zip`` + ``model.json`` — the final model and its description (full config, git commit,
  algo, scenario, seed, timesteps, wall time, action range, observation normalisation); see
  :mod:`training.policies`. Load with ``LearnedPolicy.load("DIR/model.zip")``.
* ``checkpoint.zip`` + ``checkpoint.json`` — the latest periodic checkpoint, replaced atomically,
  so an interrupted run keeps its last one. On Ctrl-C the model so far is saved as
  ``model.zip`` (``"interrupted": true`` in ``model.json``) before exiting with status 130.
* ``tb/`` — TensorBoard logs (``tensorboard --logdir DIR/tb``): SB3's losses, per-follower
  episode return/length (``rollout/``) and how follower episodes end (``platoon/``).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import platform
import subprocess
import sys
import time
import types
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
from platoon_env.scenarios.schema import VIOLATION_CAUSES
from training.batched_vec_env import BatchedPlatoonVecEnv
from training.policies import ALGORITHMS, adapter_metadata, save_model
from training.vec_env import ActionRange, PlatoonVecEnv

__all__ = ["TrainConfig", "build_model", "build_vec_env", "main", "parse_args", "train"]


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
    algo: str = _opt("ppo", "learning algorithm", choices=("ppo", "sac"))
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
    resume: bool = _opt(
        False,
        "continue an interrupted run in --out: from model.zip if it was saved on Ctrl-C, else "
        "from checkpoint.zip, up to --timesteps in total (SAC restarts with an empty replay "
        "buffer; a resumed run is not bit-identical to an uninterrupted one)",
    )
    progress_bar: bool = _opt(True, "show a progress bar (tqdm + rich)")
    torch_threads: int = _opt(1, "torch intra-op threads (1 is fastest for these small MLPs)")
    device: str = _opt("cpu", "torch device")
    verbose: int = _opt(0, "SB3 verbosity (0, 1, 2)")

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


def parse_args(argv: Sequence[str] | None = None) -> TrainConfig:
    """Parse the command line into a :class:`TrainConfig`."""
    return TrainConfig(**vars(build_parser().parse_args(argv)))


# ------------------------------------------------------------------------------------------------
# Building blocks (also used by the tests)
# ------------------------------------------------------------------------------------------------
def env_overrides(cfg: TrainConfig) -> dict[str, Any]:
    """The ``platoon_env.make`` overrides of the training envs: the training control period and
    whatever sub-steps and step limit ``cfg`` sets (default termination)."""
    overrides: dict[str, Any] = {"control_period": cfg.control_period}
    if cfg.physics_substeps is not None:
        overrides["physics_substeps"] = cfg.physics_substeps
    if cfg.max_episode_steps is not None:
        overrides["max_episode_steps"] = cfg.max_episode_steps
    if cfg.sensor_profile is not None:
        overrides["sensor_profile"] = cfg.sensor_profile
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


def build_model(cfg: TrainConfig, venv: Any, tensorboard_log: str | None = None) -> BaseAlgorithm:
    """The SB3 model for ``cfg.algo`` on ``venv``, seeded with ``cfg.seed``."""
    if cfg.algo == "ppo":
        arch = cfg.net_arch or [64, 64]
        return PPO(
            "MlpPolicy",
            venv,
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
    raise ValueError(f"unknown algo {cfg.algo!r}; expected 'ppo' or 'sac'")


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
    """What ``model.json`` records of the training env, for every engine: scenario, seed, time
    step, step limit, episode-ending causes and the number of followers."""
    # A procedural source's layouts each derive the limit from their own path: record only a
    # set one.
    procedural = env.source.procedural
    return {
        "scenario": cfg.scenario,
        "seed": cfg.seed,
        "control_period": env.control_period,
        "physics_substeps": env.physics_substeps,
        "max_episode_steps": cfg.max_episode_steps if procedural else env.max_episode_steps,
        "terminate_on": sorted(env.terminate_on),
        "n_followers": env.n_followers,
    }


def run_metadata(
    cfg: TrainConfig,
    venv: PlatoonVecEnv | BatchedPlatoonVecEnv,
    model: BaseAlgorithm,
    **extra: Any,
) -> dict[str, Any]:
    """The ``model.json`` content for ``model`` trained by ``cfg`` on ``venv``."""
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
def resume_point(out: Path) -> Path | None:
    """Where to resume a run in ``out``: an interrupted ``model.zip``, else ``checkpoint.zip``."""
    model_json = out / "model.json"
    if model_json.is_file() and json.loads(model_json.read_text()).get("interrupted"):
        return out / "model.zip"
    checkpoint = out / "checkpoint.zip"
    return checkpoint if checkpoint.is_file() else None


def train(cfg: TrainConfig) -> tuple[Path, bool]:
    """Train as ``cfg`` says; returns ``(path of model.zip, interrupted)``."""
    out = cfg.out_dir
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(cfg.torch_threads)
    set_random_seed(cfg.seed)
    venv = build_vec_env(cfg)
    start_from = resume_point(out) if cfg.resume else None
    if start_from is not None:
        model = ALGORITHMS[cfg.algo].load(
            start_from, env=VecMonitor(venv), device=cfg.device, tensorboard_log=str(out / "tb")
        )
        print(f"resuming from {start_from} at {model.num_timesteps} timesteps", file=sys.stderr)
    else:
        model = build_model(cfg, VecMonitor(venv), tensorboard_log=str(out / "tb"))
    commit = git_commit()
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    t0 = time.perf_counter()

    def metadata(**extra: Any) -> dict[str, Any]:
        wall = time.perf_counter() - t0
        return run_metadata(
            cfg,
            venv,
            model,
            **commit,
            started_at=started,
            wall_time_s=round(wall, 3),
            timesteps_per_s=round(model.num_timesteps / wall, 1) if wall > 0 else None,
            **extra,
        )

    callback_list: list[BaseCallback] = [
        CheckpointCallback(out / "checkpoint.zip", cfg.checkpoint_every, metadata),
        EpisodeEndCallback(),
    ]
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``platoon-train``; returns the exit status (130 after Ctrl-C)."""
    cfg = parse_args(argv)
    if cfg.engine == "rllib":
        if cfg.algo != "ppo" or cfg.batched:
            print("platoon-train: --engine rllib trains PPO without --batched", file=sys.stderr)
            return 2
        try:
            from training.rllib import train_rllib
        except ImportError as e:
            print(
                f"platoon-train: --engine rllib needs Ray RLlib ({e}); install the extra: "
                'pip install torch==2.13.0 -e ".[train,rllib]"',
                file=sys.stderr,
            )
            return 2
        path, interrupted = train_rllib(cfg)
    else:
        path, interrupted = train(cfg)
    print(f"saved {path} and {path.with_suffix('.json')}")
    return 130 if interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
