r"""Behaviour cloning of the analytic laws with DAgger, then PPO fine-tuning, on the fast path.

PPO from scratch on the ``sharp`` tier (sharp corners in narrow passages, study C's formation)
finds no successful team episode in ten million transitions, while the paper's PPC law
(:class:`baselines.PPCPolicy`) drives those layouts. This module starts the learner from the
law instead:

1. **Expert.** The law acts for every env copy of a :class:`platoon_env.batched.BatchedPlatoon`:
   one policy per copy (``ppc``: :class:`baselines.PPCPolicy`; ``filtered_ppc``:
   :class:`baselines.filtered_ppc.FilteredPPCPolicy`), built through a small
   :class:`~baselines.policy.PolicyEnv` shim (:class:`ExpertEnv`: the copy's followers, the
   control period and *the copy's current scenario*) and rebuilt and reset at each episode
   start of that copy. It is fed its copy's observations as the core gives them, in whatever
   layout :class:`~training.fast_ppo.FastPPOConfig`'s observation options make, and reads its
   physical sensor 7-vector from them by the laws' own rule
   (:func:`baselines.policy.sensor_part`, which un-scales a scale-free layout); the learner
   reads the same arrays, divided by the fixed observation scale.
2. **Labels in the learner's action space.** The law's command ``[u, omega]`` is mapped to the
   normalised action by the inverse of :class:`~training.vec_env.ActionRange`
   (:func:`to_normalised`) and **clipped to** ``[-1, 1]^2``: the law's commands are unbounded
   by design (transients of several m/s), the learner's range is not. The executed expert
   action is the clipped one (what the learner can at best reproduce), and the share of
   clipped labels is recorded (``label_clipped`` in ``bc_history``).
3. **DAgger** (Ross, Gordon and Bagnell, 2011). Iteration ``i`` rolls out the mixture
   ``beta_i`` expert / ``1 - beta_i`` learner (``beta_i = beta_decay ** i``: iteration 0 is
   the expert's own rollouts, i.e. plain behaviour cloning data), chosen per env copy and per
   step; the expert runs in shadow on every step, so every visited state, the learner's
   included, is labelled with the expert's action there; the samples are aggregated; the
   actor (the mean of :class:`~training.fast_ppo.ActorCritic`, SB3's ``MlpPolicy`` layout) is
   regressed on the whole aggregate (mean squared error in the normalised action space,
   Adam). The learner acts by its deterministic mode (the mean, clipped).
4. **PPO fine-tuning**: :func:`training.fast_ppo.train_fast` with ``init_from`` the cloned
   model (every policy parameter but ``log_std``, which starts at ``log_std_init``; a small
   one keeps the cloned behaviour from being drowned in exploration noise) and
   ``value_warmup`` rollouts in which only the critic learns (the cloned model's critic is
   untrained, and its first advantages would be noise).

**The clock.** PPC's performance functions (eq. 12) start wide (``rho_d(0) = d_con -
d_des`` ...) and shrink at rate ``lambda`` towards ``rho_inf``: the law's command for an
observation depends on the time since the episode start, which a stateless MLP does not see
(``t_unseen`` is the time since the predecessor was last perceived, not a clock). Nothing is
added to the observation for it: the expert keeps its own clock along every rollout (its state
is a function of the observations it was fed and the elapsed time, so the labels of learner
states are well defined), and the regression fits the conditional mean over the times at
which each observation occurs. After the transient (``~ 3 / lambda`` s) the funnels sit at
their limits unless the clearance terms widen them (those depend on the observation), so the
aliasing is confined to the first seconds of an episode, where errors are far from the
funnel's bounds anyway.

Files in ``out`` (:func:`train_bc_ppo`): ``bc/model.zip`` + ``bc/model.json`` (the cloned
model, an ordinary SB3 ``PPO`` zip that :meth:`training.policies.LearnedPolicy.load` reads;
``"trainer": "training.bc"``, ``"stage": "clone"``, ``bc_history`` per iteration: samples,
beta, team success of the rollout, training and held-out action errors, label clip rates) and
``bc/model.state.pt`` (the network); then the fine-tuned run of
:func:`~training.fast_ppo.train_fast` in ``out`` itself (``"trainer": "training.bc"`` too,
``initialised_from`` naming ``bc/model.zip`` and its SHA-256).

Use::

    from training.bc import BCConfig, train_bc_ppo
    from training.fast_ppo import FastPPOConfig
    ppo = FastPPOConfig(scenario="procedural_sharp_train", task_aware_observations=True,
                        layout_repeats=16, timesteps=5_000_000, log_std_init=-1.5)
    train_bc_ppo(BCConfig(iterations=6), ppo, "runs/bc_sharp")
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import math
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import stable_baselines3
import torch
from numpy.typing import NDArray

from platoon_env.batched import BatchedPlatoon
from platoon_env.scenarios.fingerprint import file_sha256
from training.config import BOUNDS, ENV_FIELDS, env_metadata
from training.experts import EXPERTS, BatchedExpert, ExpertEnv, to_normalised
from training.fast_ppo import (
    ActorCritic,
    FastPPOConfig,
    FastRun,
    SlotSpec,
    _read_point,
    _torch_threads,
    _train_view,
    json_config,
    make_core,
    sb3_model,
    train_fast,
)
from training.policies import adapter_metadata, save_model
from training.run import (
    git_commit,
    library_versions,
    save_point,
    segment_metadata,
    timing_metadata,
)
from training.seeding import process_seed, stream_seed
from training.vec_env import ActionRange

__all__ = [
    "BC_DIR",
    "EXPERTS",
    "BCConfig",
    "BCRun",
    "BatchedExpert",
    "Collector",
    "ExpertEnv",
    "Rollout",
    "action_error",
    "to_normalised",
    "train_bc",
    "train_bc_ppo",
]

#: Where :func:`train_bc_ppo` keeps the cloned model inside its run folder.
BC_DIR = "bc"
#: What the model.json of a cloned or fine-tuned model names as its trainer.
TRAINER = "training.bc"


# ------------------------------------------------------------------------------------------------
# Options
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BCConfig:
    """The options of the cloning stage; invalid values raise ``ValueError`` naming the option.

    ``expert`` (:data:`EXPERTS`), ``iterations`` (DAgger iterations, at least 1; iteration 0
    rolls out the expert alone), ``steps_per_iteration`` (control steps of every env copy per
    iteration: ``steps * n_envs * N`` labelled samples; the copies' episodes go on across
    iterations, and an episode of a procedural layout lasts thousands of steps at a period the
    law holds, so an iteration should cover a good part of one), ``beta_decay`` (``beta_i =
    beta_decay ** i``, the probability that the expert acts for a copy at a step of iteration
    ``i``; 0: the learner alone after iteration 0), ``epochs`` (passes over the aggregate per
    iteration), ``batch_size``, ``learning_rate`` (Adam), ``max_samples`` (the aggregate's
    size cap; the oldest samples are dropped beyond it), ``holdout`` (share of each
    iteration's samples kept out of training to measure the held-out action error).

    The env, network, action range and seed are the fine-tuning
    :class:`~training.fast_ppo.FastPPOConfig`'s (one network layout for both stages).
    """

    expert: str = "ppc"
    iterations: int = 6
    steps_per_iteration: int = 1000
    beta_decay: float = 0.5
    epochs: int = 10
    batch_size: int = 4096
    learning_rate: float = 1e-3
    max_samples: int = 5_000_000
    holdout: float = 0.05

    def __post_init__(self) -> None:
        problems = bc_config_problems(self)
        if problems:
            raise ValueError("BCConfig: " + "; ".join(problems))

    def beta(self, iteration: int) -> float:
        """``beta_i``: 1 at iteration 0, then ``beta_decay ** i``."""
        return 1.0 if iteration == 0 else float(self.beta_decay**iteration)


_BC_INTEGERS = ("iterations", "steps_per_iteration", "epochs", "batch_size", "max_samples")
#: The fine-tuning defaults of ``platoon-train --algo bc_*`` where they differ from
#: :class:`~training.fast_ppo.FastPPOConfig`'s: a small exploration noise around the clone, a
#: critic warmed up before the actor moves, and a control period the PPC law holds on the
#: sharp tier (at the training default of 0.05 s its errors leave their funnels there: the
#: law, not the clipping, fails; measure with ``python -m training.bc --probe``).
FINETUNE: dict[str, Any] = {"log_std_init": -1.5, "value_warmup": 3, "control_period": 0.03}


def bc_config_problems(cfg: BCConfig) -> list[str]:
    """Every problem of ``cfg``, each naming its option."""
    problems: list[str] = []
    if cfg.expert not in EXPERTS:
        problems.append(f"expert must be one of {tuple(EXPERTS)}, got {cfg.expert!r}")
    for f in dataclasses.fields(cfg):
        if f.name == "expert":
            continue
        value, bound = getattr(cfg, f.name), BOUNDS["bc_" + f.name]
        integral = f.name in _BC_INTEGERS
        if isinstance(value, bool) or not isinstance(value, int if integral else int | float):
            kind = "an integer" if integral else "a number"
            problems.append(f"{f.name} must be {kind}, got {value!r}")
        elif not math.isfinite(value) or value not in bound:
            problems.append(f"{f.name} must be {bound}, got {value!r}")
    return problems


# ------------------------------------------------------------------------------------------------
# Cloning with DAgger
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BCRun:
    """What :func:`train_bc` returns: the cloned model's path, its per-iteration history and the
    network (the actor's weights, on the CPU)."""

    path: Path
    history: list[dict[str, Any]]
    network: ActorCritic


def _spawn_rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(stream_seed(seed, *key))


@dataclass
class Rollout:
    """One DAgger iteration's samples: the learner's inputs ``x`` (normalised observations of
    the live follower slots), the expert's labels ``y`` (normalised, clipped) and what the
    rollout did: the success of each team episode that ended in it (the leader reached its
    path's end, no follower violated) and the share of clipped labels per component."""

    x: NDArray[np.float32]
    y: NDArray[np.float32]
    team_success: NDArray[np.bool_]
    label_clipped: NDArray[np.float64]


class Collector:
    """The DAgger rollouts of one run: ``core`` (auto-resetting copies) with the expert acting
    in shadow for every copy (:class:`BatchedExpert`), the mixture drawn from ``rng``."""

    def __init__(
        self,
        core: BatchedPlatoon,
        obs: NDArray[np.float32],
        expert: BatchedExpert,
        scale: NDArray[np.float32],
        action_range: ActionRange,
        rng: np.random.Generator,
        device: torch.device,
    ) -> None:
        self.core, self.obs, self.expert = core, obs, expert
        self.scale, self.action_range, self.rng, self.device = scale, action_range, rng, device
        B, N = core.batch_size, core.n_followers
        self._cost = np.zeros((B, N))

    def live(self) -> NDArray[np.bool_]:
        """The follower slots ``(B, N)`` each copy's current episode has."""
        counts = np.array([int(sc.config.followers) for sc in self.core.scenarios])
        mask: NDArray[np.bool_] = np.arange(self.core.n_followers)[None, :] < counts[:, None]
        return mask

    def rollout(self, net: ActorCritic | None, beta: float, steps: int) -> Rollout:
        """``steps`` control steps of every copy; at each, the expert acts for a copy with
        probability ``beta`` (always when ``net`` is None), else the learner's deterministic
        mode; every visited state of a live slot is labelled with the expert's command."""
        core, B, N = self.core, self.core.batch_size, self.core.n_followers
        K = self.obs.shape[-1]
        xs: list[NDArray[np.float32]] = []
        ys: list[NDArray[np.float32]] = []
        teams: list[NDArray[np.bool_]] = []
        clipped = np.zeros(2)
        labelled = 0
        for _t in range(steps):
            live = self.live()
            label, clip_mask = to_normalised(self.expert.act(self.obs), self.action_range)
            x = (self.obs / self.scale).astype(np.float32)
            xs.append(x[live])
            ys.append(label[live])
            clipped += clip_mask[live].sum(axis=0)
            labelled += int(live.sum())
            act = label
            if net is not None and beta < 1.0:
                with torch.no_grad():
                    mean = net.actor(torch.as_tensor(x.reshape(B * N, K), device=self.device))
                mine = mean.clamp(-1.0, 1.0).cpu().numpy().reshape(B, N, 2)
                expert_acts = self.rng.random(B) < beta
                act = np.where(expert_acts[:, None, None], label, mine)
            arrived = core.leader_arrived  # before the step: its episode may end in it
            self.obs, _, terminated, truncated, info = core.step(self.action_range.to_physical(act))
            self._cost += info["violations"] != 0
            ended = terminated | truncated
            if ended.any():
                # success: the leader reached its path's end and no follower violated
                clean = ((self._cost == 0) | ~live).all(axis=1) & arrived & ~terminated
                teams.append(clean[ended])
                self._cost[ended] = 0.0
                self.expert.restart(ended)
        return Rollout(
            np.concatenate(xs),
            np.concatenate(ys),
            np.concatenate(teams) if teams else np.zeros(0, dtype=bool),
            clipped / max(labelled, 1),
        )


def train_bc(
    bc: BCConfig,
    ppo: FastPPOConfig,
    out: str | Path,
    *,
    on_iteration: Callable[[dict[str, Any]], None] | None = None,
) -> BCRun:
    """Clone ``bc.expert`` into the actor of ``ppo``'s network layout by DAgger (module doc)
    and save it as ``out/model.zip`` (+ ``.json``, ``.state.pt``). ``on_iteration`` is called
    with each iteration's history entry (for progress reports)."""
    out = Path(out)
    with _torch_threads(ppo.torch_threads):
        return _clone(bc, ppo, out, on_iteration)


def _clone(
    bc: BCConfig,
    ppo: FastPPOConfig,
    out: Path,
    on_iteration: Callable[[dict[str, Any]], None] | None,
) -> BCRun:
    """DAgger: ``bc.iterations`` rollouts of the mixture ``beta_i`` expert / ``1 - beta_i``
    learner, each aggregated and the actor regressed on the aggregate; then the save."""
    device = torch.device(ppo.device)
    seed = process_seed(ppo.seed, 0)
    torch.manual_seed(seed)
    gen = torch.Generator(device="cpu")
    gen.manual_seed(seed)
    rng = _spawn_rng(ppo.seed, 1 << 20, 0)  # the mixture and the hold-out: not the envs' streams

    core, obs = make_core(ppo, segment=0)
    spec = SlotSpec.of(ppo, core)
    K = int(core.single_observation_space.shape[0])
    scale = (
        spec.obs_scale
        if spec.obs_scale is not None
        else np.ones(core.single_observation_space.shape, np.float32)
    )
    collector = Collector(
        core, obs, BatchedExpert(core, bc.expert), scale, ppo.action_range, rng, device
    )
    net = ActorCritic(K, ppo.net_arch, ppo.log_std_init, cost_head=False).to(device)
    optimizer = torch.optim.Adam(net.actor_parameters(), lr=bc.learning_rate)

    aggregate = _Aggregate()
    history: list[dict[str, Any]] = []
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    clock = time.perf_counter()
    commit = git_commit()

    for iteration in range(bc.iterations):
        beta = bc.beta(iteration)
        net.eval()
        data = collector.rollout(net, beta, bc.steps_per_iteration)
        aggregate.add(data, bc, rng)
        X, Y = aggregate.training_set(bc, device)
        train_error = _regress(net, optimizer, X, Y, bc, gen, device)
        teams = data.team_success
        entry = {
            "iteration": iteration,
            "beta": beta,
            "samples": len(data.x),
            "aggregate": len(X),
            "team_episodes": len(teams),
            "team_success": float(teams.mean()) if len(teams) else None,
            "train_error": train_error,
            "holdout_error": action_error(net, aggregate.hold_x, aggregate.hold_y, device),
            "holdout_error_this_iteration": action_error(
                net, aggregate.hold_x[-1:], aggregate.hold_y[-1:], device
            ),
            "label_clipped": [float(c) for c in data.label_clipped],
            "wall_time_s": round(time.perf_counter() - clock, 3),
        }
        history.append(entry)
        if on_iteration is not None:
            on_iteration(entry)

    net = net.cpu()
    path = save_point(
        out / "model.zip",
        lambda tmp: _write_clone(
            bc,
            ppo,
            tmp,
            core,
            spec,
            net,
            aggregate.samples_seen,
            history,
            started=started,
            clock=clock,
            commit=commit,
        ),
    )
    return BCRun(path, history, net)


@dataclass
class _Aggregate:
    """DAgger's aggregate: each iteration's samples, a held-out share of each kept for the
    held-out error, the oldest training samples dropped beyond ``max_samples``."""

    train_x: list[NDArray[np.float32]] = dataclasses.field(default_factory=list)
    train_y: list[NDArray[np.float32]] = dataclasses.field(default_factory=list)
    hold_x: list[NDArray[np.float32]] = dataclasses.field(default_factory=list)
    hold_y: list[NDArray[np.float32]] = dataclasses.field(default_factory=list)
    samples_seen: int = 0

    def add(self, data: Rollout, bc: BCConfig, rng: np.random.Generator) -> None:
        """Aggregate an iteration's samples, a random ``holdout`` share of them held out."""
        order = rng.permutation(len(data.x))
        n_hold = round(bc.holdout * len(data.x))
        self.hold_x.append(data.x[order[:n_hold]])
        self.hold_y.append(data.y[order[:n_hold]])
        self.train_x.append(data.x[order[n_hold:]])
        self.train_y.append(data.y[order[n_hold:]])
        self.samples_seen += len(data.x)
        while sum(len(a) for a in self.train_x) > bc.max_samples and len(self.train_x) > 1:
            self.train_x.pop(0)
            self.train_y.pop(0)

    def training_set(self, bc: BCConfig, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """The inputs and labels to regress on: the newest ``max_samples`` training samples."""
        X = torch.as_tensor(np.concatenate(self.train_x), device=device)[-bc.max_samples :]
        Y = torch.as_tensor(np.concatenate(self.train_y), device=device)[-bc.max_samples :]
        return X, Y


def _regress(
    net: ActorCritic,
    optimizer: torch.optim.Optimizer,
    X: torch.Tensor,
    Y: torch.Tensor,
    bc: BCConfig,
    gen: torch.Generator,
    device: torch.device,
) -> float:
    """Regress the actor's mean on the labels: ``bc.epochs`` passes of Adam over minibatches,
    the squared error summed over the two action components; returns the mean training loss."""
    net.train()
    loss_sum, loss_n = 0.0, 0
    for _epoch in range(bc.epochs):
        perm = torch.randperm(len(X), generator=gen).to(device)
        for start in range(0, len(X), bc.batch_size):
            idx = perm[start : start + bc.batch_size]
            loss = ((net.actor(X[idx]) - Y[idx]) ** 2).sum(-1).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            loss_sum += float(loss.detach()) * len(idx)
            loss_n += len(idx)
    return loss_sum / max(loss_n, 1)


def _write_clone(
    bc: BCConfig,
    ppo: FastPPOConfig,
    path: Path,
    core: BatchedPlatoon,
    spec: SlotSpec,
    net: ActorCritic,
    samples_seen: int,
    history: list[dict[str, Any]],
    *,
    started: str,
    clock: float,
    commit: dict[str, Any],
) -> Path:
    """Write the clone (``net`` on the CPU) as an ordinary SB3 ``PPO`` zip of the actor (the
    critic is untrained) at ``path`` (``model.zip``), with its ``model.json`` and
    ``model.state.pt`` beside it; ``started``, ``clock`` (``perf_counter`` at the start) and
    ``commit`` are the run's. The caller writes it through :func:`training.run.save_point`, so
    that the three files appear whole."""
    B, N = core.batch_size, core.n_followers
    state_file = path.with_suffix(".state.pt")
    torch.save({"network": net.state_dict()}, state_file)
    saver = sb3_model(ppo, spec, max(2, ppo.n_steps * B * N))
    saver.policy.load_state_dict(net.sb3_state_dict())
    saver.num_timesteps = samples_seen
    wall = time.perf_counter() - clock
    this = segment_metadata(
        started_at=started,
        wall_time_s=wall,
        timesteps_start=0,
        timesteps_end=samples_seen,
        resumed_from=None,
        commit=commit,
    )
    meta: dict[str, Any] = {
        "algo": "ppo",  # the zip's class (LearnedPolicy.load reads it as SB3's PPO)
        "trainer": TRAINER,
        "stage": "clone",
        **env_metadata(_train_view(ppo), core),
        **adapter_metadata(spec),
        "timesteps": samples_seen,
        "timesteps_requested": bc.iterations * bc.steps_per_iteration * B * N,
        **commit,
        **timing_metadata([this], samples_seen),
        "learner_state": state_file.name,
        "learner_state_sha256": file_sha256(state_file),
        "expert": bc.expert,
        "bc_config": dataclasses.asdict(bc),
        "bc_history": history,
        "clock": (
            "none: a stateless MLP; the expert keeps its own clock and the labels are its "
            "commands at the elapsed time (training/bc.py, the clock)"
        ),
        "config": json_config(ppo),
        "versions": library_versions(stable_baselines3, torch),
        "command": list(sys.argv),
    }
    return save_model(saver, path, meta)


def action_error(
    net: ActorCritic,
    xs: list[NDArray[np.float32]],
    ys: list[NDArray[np.float32]],
    device: torch.device,
) -> float | None:
    """Mean squared error (summed over the two action components) of the actor's clipped mean
    against the labels, over the held-out samples ``xs`` (None: none held out)."""
    if not xs or sum(len(x) for x in xs) == 0:
        return None
    X = torch.as_tensor(np.concatenate(xs), device=device)
    Y = torch.as_tensor(np.concatenate(ys), device=device)
    with torch.no_grad():
        err = ((net.actor(X).clamp(-1.0, 1.0) - Y) ** 2).sum(-1).mean()
    return float(err)


# ------------------------------------------------------------------------------------------------
# Cloning, then fine-tuning
# ------------------------------------------------------------------------------------------------
def train_bc_ppo(
    bc: BCConfig,
    ppo: FastPPOConfig,
    out: str | Path,
    *,
    resume: bool = False,
    on_iteration: Callable[[dict[str, Any]], None] | None = None,
) -> FastRun:
    """Clone ``bc.expert`` into ``out/bc`` (:func:`train_bc`), then fine-tune it with
    :func:`~training.fast_ppo.train_fast` into ``out`` (``ppo`` with ``init_from`` the cloned
    model; ``ppo.init_from`` must be None, ``ppo.timesteps`` counts the fine-tuning's
    transitions). ``resume=True`` keeps a complete ``out/bc`` cloned with the same options
    (``ValueError`` if they differ) and resumes (or starts) the fine-tuning; without it, an
    ``out`` holding a cloned model is refused."""
    out = Path(out)
    if ppo.init_from is not None:
        raise ValueError("init_from: train_bc_ppo starts the fine-tuning from its own clone")
    bc_dir = out / BC_DIR
    cloned = bc_dir / "model.zip"
    stored = _stored_clone(bc_dir)
    if stored is not None and not resume:
        raise ValueError(
            f"out: {out} already holds a cloned model ({cloned}); pass resume=True to continue "
            "the run, or choose another directory"
        )
    if stored is not None:
        diffs = _clone_differences(stored, bc, ppo)
        if diffs:
            raise ValueError(
                f"resume: the options differ from the clone in {bc_dir}: " + "; ".join(diffs)
            )
    else:
        train_bc(bc, ppo, bc_dir, on_iteration=on_iteration)
    finetune = dataclasses.replace(ppo, init_from=str(cloned))
    resume_finetune = resume and any((out / n).exists() for n in ("model.json", "checkpoint.json"))
    return train_fast(finetune, out, resume=resume_finetune, trainer=TRAINER)


def _stored_clone(bc_dir: Path) -> Mapping[str, Any] | None:
    """The model.json of a complete clone in ``bc_dir`` (None: none, or a save cut off; the
    fast learner's rule for a saved point)."""
    point = _read_point(bc_dir, "model")
    return None if point is None else point.meta


#: The options a stored clone must share with the run that fine-tunes it: the env's
#: (:data:`training.config.ENV_FIELDS`), and what shapes the samples and the network.
_CLONE_KEYS = (
    *ENV_FIELDS,
    "seed",
    "n_envs",
    "layout_repeats",
    "u_low",
    "u_high",
    "omega_high",
    "normalize_observations",
    "net_arch",
)


def _clone_differences(stored: Mapping[str, Any], bc: BCConfig, ppo: FastPPOConfig) -> list[str]:
    """How ``bc`` and the cloning-relevant options of ``ppo`` differ from a stored clone's."""
    diffs: list[str] = []
    stored_bc = stored.get("bc_config", {})
    for key, value in dataclasses.asdict(bc).items():
        if stored_bc.get(key) != value:
            diffs.append(f"{key}: stored {stored_bc.get(key)!r}, given {value!r}")
    stored_ppo = stored.get("config", {})
    given = json_config(ppo)
    for key in _CLONE_KEYS:
        if stored_ppo.get(key) != given[key]:
            diffs.append(f"{key}: stored {stored_ppo.get(key)!r}, given {given[key]!r}")
    return diffs


# ------------------------------------------------------------------------------------------------
# The expert at a control period: python -m training.bc --probe
# ------------------------------------------------------------------------------------------------
def probe_expert(ppo: FastPPOConfig, expert: str = "ppc", episodes: int = 64) -> tuple[int, int]:
    """``(successes, episodes)``: the team episodes of ``expert`` alone (its commands clipped
    to ``ppo``'s action range, as it acts during cloning) on ``ppo``'s copies, the first
    ``episodes`` (at least) that end."""
    core, obs = make_core(ppo)
    spec = SlotSpec.of(ppo, core)
    scale = spec.obs_scale if spec.obs_scale is not None else np.ones(obs.shape[-1], np.float32)
    rng = _spawn_rng(ppo.seed, 1 << 20, 1)
    collector = Collector(
        core, obs, BatchedExpert(core, expert), scale, ppo.action_range, rng, torch.device("cpu")
    )
    ended: list[NDArray[np.bool_]] = []
    while sum(len(e) for e in ended) < episodes:
        ended.append(collector.rollout(None, 1.0, 50).team_success)
    teams = np.concatenate(ended)
    return int(teams.sum()), len(teams)


def main(argv: list[str] | None = None) -> int:
    """``python -m training.bc --probe``: how the expert does at a control period."""
    parser = argparse.ArgumentParser(
        prog="python -m training.bc",
        description="Team success of the analytic law alone, its commands clipped to the "
        "learner's action range, as it acts while it is cloned (training/bc.py).",
    )
    parser.add_argument("--probe", action="store_true", required=True, help="run the probe")
    parser.add_argument("--scenario", default="procedural_sharp_train")
    parser.add_argument("--control-period", type=float, default=FINETUNE["control_period"])
    parser.add_argument("--expert", choices=tuple(EXPERTS), default="ppc")
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--n-envs", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        ppo = FastPPOConfig(
            scenario=args.scenario,
            control_period=args.control_period,
            n_envs=args.n_envs,
            seed=args.seed,
            progress_bar=False,
        )
    except ValueError as e:
        parser.error(str(e))
    if args.episodes < 1:
        parser.error(f"argument --episodes: must be >= 1, got {args.episodes}")
    wins, total = probe_expert(ppo, args.expert, args.episodes)
    print(
        f"{args.expert} (commands clipped to the action range) on {args.scenario} at "
        f"control period {args.control_period:g} s: {wins}/{total} team episodes succeed"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
