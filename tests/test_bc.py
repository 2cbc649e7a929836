"""Behaviour cloning with DAgger (training/bc.py): the clone's action error against the expert
falls on held-out states, DAgger labels the learner's own states with the expert's actions,
the fine-tuning starts from the clone's weights bit for bit, and bad options are refused by
name."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from tiny_runs import TINY

from baselines.ppc import PPCPolicy
from platoon_env.batched import BatchedPlatoon
from training.bc import (
    FINETUNE,
    BatchedExpert,
    BCConfig,
    Collector,
    ExpertEnv,
    action_error,
    to_normalised,
    train_bc,
    train_bc_ppo,
)
from training.config import TrainConfig
from training.fast_ppo import ActorCritic, FastPPOConfig, SlotSpec, make_core, train_fast
from training.policies import LearnedPolicy
from training.seeding import env_seeds
from training.train import bc_config, fast_config, main, parse_args

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: The tiny run at a period the PPC law holds (0.05 s is beyond it, DESIGN.md §4), in rollouts
#: of 16 steps (128 transitions), 256 timesteps in all.
PPO: dict[str, Any] = {
    **TINY,
    "control_period": 0.02,
    "n_steps": 16,
    "timesteps": 256,
    "log_every": 128,
}
BC: dict[str, Any] = {"iterations": 2, "steps_per_iteration": 40, "epochs": 30, "batch_size": 64}


def ppo_config(**changes: Any) -> FastPPOConfig:
    return FastPPOConfig(**{**PPO, **changes})


def collector(cfg: FastPPOConfig, seed: int = 0) -> Collector:
    core, obs = make_core(cfg if seed == cfg.seed else ppo_config(seed=seed))
    scale = SlotSpec.of(cfg, core).obs_scale
    assert scale is not None
    rng = np.random.default_rng(seed)
    device = torch.device("cpu")
    return Collector(core, obs, BatchedExpert(core), scale, cfg.action_range, rng, device)


def test_the_expert_of_a_copy_is_the_ppc_law_on_that_copy() -> None:
    cfg = ppo_config()
    core, obs = make_core(cfg)
    expert = BatchedExpert(core)
    law = PPCPolicy(ExpertEnv(tuple(core.possible_agents), core.control_period, core.scenarios[2]))
    commands = expert.act(obs)
    mine = law.act({a: obs[2, i, :7] for i, a in enumerate(core.possible_agents)})
    for i, agent in enumerate(core.possible_agents):
        np.testing.assert_array_equal(commands[2, i], mine[agent])


def test_the_expert_reads_scale_free_observations_in_metres() -> None:
    # One start, two observation layouts: the law's commands are the same (sensor_columns
    # undoes the scaling, up to float32 rounding).
    seeds = env_seeds(0, 4)
    layouts = ({"task_aware": True}, {"task_aware": True, "scale_free": True})
    commands = []
    for layout in layouts:
        core = BatchedPlatoon(
            "study_c", 4, auto_reset=True, control_period=0.02, observation=layout
        )
        commands.append(BatchedExpert(core).act(core.reset(seeds)))
    np.testing.assert_allclose(commands[0], commands[1], rtol=1e-4, atol=1e-4)
    assert np.abs(commands[0]).max() > 0.01


def test_labels_are_the_inverse_of_the_action_range_clipped() -> None:
    cfg = ppo_config()
    ar = cfg.action_range
    a = np.array([[-1.0, 0.5], [0.25, -1.0]], dtype=np.float32)
    back, clipped = to_normalised(ar.to_physical(a), ar)
    np.testing.assert_allclose(back, a, atol=1e-6)
    assert not clipped.any()
    far, clipped = to_normalised(np.array([[5.0, -9.0]]), ar)  # PPC transients exceed the range
    assert far.tolist() == [[1.0, -1.0]] and clipped.tolist() == [[True, True]]


def test_cloning_reduces_the_action_error_on_held_out_states(tmp_path: Path) -> None:
    cfg = ppo_config()
    run = train_bc(BCConfig(**BC), cfg, tmp_path / "bc")
    # Held-out states: the expert's rollouts on other env streams (seed 7), never trained on.
    held = collector(cfg, seed=7).rollout(None, 1.0, 60)
    untrained = ActorCritic(held.x.shape[1], cfg.net_arch, cfg.log_std_init, cost_head=False)
    before = action_error(untrained, [held.x], [held.y], torch.device("cpu"))
    after = action_error(run.network, [held.x], [held.y], torch.device("cpu"))
    assert before is not None and after is not None
    assert after < 0.5 * before
    meta = json.loads((tmp_path / "bc" / "model.json").read_text())
    assert meta["trainer"] == "training.bc" and meta["expert"] == "ppc"
    assert [h["aggregate"] for h in meta["bc_history"]] == [
        sum(h["samples"] - round(0.05 * h["samples"]) for h in meta["bc_history"][: i + 1])
        for i in range(2)
    ]
    LearnedPolicy.load(tmp_path / "bc" / "model.zip")  # an ordinary model


def test_dagger_labels_the_learners_own_states_with_the_experts_actions() -> None:
    cfg = ppo_config()
    # A learner that stands still (u = 0, omega = 0 in physical units): its states are not the
    # expert's (the predecessor drives away), and their labels are the expert's commands there.
    still = ActorCritic(7, cfg.net_arch, 0.0, cost_head=False)
    standstill, _ = to_normalised(np.zeros((1, 2)), cfg.action_range)
    with torch.no_grad():
        still.action_net.weight.zero_()
        still.action_net.bias.copy_(torch.as_tensor(standstill[0]))
    learner = collector(cfg).rollout(still, 0.0, 40)
    expert = collector(cfg).rollout(None, 1.0, 40)
    assert learner.x.shape == expert.x.shape
    assert not np.allclose(learner.x, expert.x)
    # Along the learner's trajectory the leader drives away from the first follower, which
    # stands still: its x~ grows ...
    x_rel = learner.x[:, 1].reshape(40, 4, 2)[:, :, 0]
    assert (x_rel[-1] > x_rel[0] + 0.1).all()
    # ... and the expert, fed those states, asks it for the speed the learner does not give.
    u_label = cfg.action_range.to_physical(learner.y)[:, 0].reshape(40, 4, 2)[:, :, 0]
    assert (u_label[-1] > 0.05).all()


def test_the_fine_tuning_starts_from_the_clone_bit_for_bit(tmp_path: Path) -> None:
    cfg = ppo_config()
    train_bc(BCConfig(**BC), cfg, tmp_path / "bc")
    clone = torch.load(tmp_path / "bc" / "model.state.pt", weights_only=True)["network"]
    # A value warm-up longer than the run: the actor never moves, only the critic learns.
    tuned = ppo_config(
        init_from=str(tmp_path / "bc" / "model.zip"), log_std_init=-1.5, value_warmup=100
    )
    train_fast(tuned, tmp_path / "ft")
    after = torch.load(tmp_path / "ft" / "model.state.pt", weights_only=True)["network"]
    actor = [k for k in clone if k.startswith(("mlp_extractor.policy_net", "action_net"))]
    assert actor and all(torch.equal(after[k], clone[k]) for k in actor)
    assert torch.equal(after["log_std"], torch.full((2,), -1.5))
    assert not torch.equal(after["value_net.weight"], clone["value_net.weight"])
    meta = json.loads((tmp_path / "ft" / "model.json").read_text())
    assert meta["initialised_from"]["path"] == str(tmp_path / "bc" / "model.zip")


def test_bc_ppo_clones_then_fine_tunes_and_refuses_a_used_folder(tmp_path: Path) -> None:
    cfg = ppo_config()
    run = train_bc_ppo(BCConfig(**{**BC, "iterations": 1}), cfg, tmp_path)
    assert run.timesteps >= 256 and (tmp_path / "bc" / "model.zip").is_file()
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["trainer"] == "training.bc"
    with pytest.raises(ValueError, match="already holds a cloned model"):
        train_bc_ppo(BCConfig(**{**BC, "iterations": 1}), cfg, tmp_path)
    with pytest.raises(ValueError, match=r"epochs: stored 30, given 5"):
        train_bc_ppo(BCConfig(**{**BC, "iterations": 1, "epochs": 5}), cfg, tmp_path, resume=True)


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("expert", "oracle"),
        ("iterations", 0),
        ("steps_per_iteration", 1.5),
        ("beta_decay", 1.5),
        ("holdout", -0.1),
        ("learning_rate", 0.0),
    ],
)
def test_bad_bc_options_are_refused_by_name(option: str, value: Any) -> None:
    with pytest.raises(ValueError, match=option):
        BCConfig(**{option: value})


def test_init_from_a_missing_or_misfit_model_is_refused_by_name(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="init_from"):
        FastPPOConfig(init_from="weights.pt")
    with pytest.raises(ValueError, match="init_from: no model"):
        train_fast(ppo_config(init_from=str(tmp_path / "none.zip")), tmp_path / "a")
    train_bc(BCConfig(**{**BC, "iterations": 1, "epochs": 1}), ppo_config(), tmp_path / "bc")
    wide = ppo_config(init_from=str(tmp_path / "bc" / "model.zip"), net_arch=(32, 32))
    with pytest.raises(ValueError, match=r"init_from: .* does not fit"):
        train_fast(wide, tmp_path / "b")


# ------------------------------------------------------------------------------------------------
# platoon-train --engine fast
# ------------------------------------------------------------------------------------------------
TINY_CLI = [
    "--engine", "fast", "--algo", "bc_ppo", "--scenario", "study_c", "--n-envs", "4",
    "--control-period", "0.02", "--n-steps", "16", "--batch-size", "64", "--n-epochs", "2",
    "--timesteps", "256", "--log-every", "128", "--checkpoint-every", "0", "--no-progress-bar",
    "--bc-iterations", "1", "--bc-steps-per-iteration", "20", "--bc-epochs", "2",
    "--bc-batch-size", "64",
]  # fmt: skip


def test_the_fast_engine_takes_its_own_defaults_for_options_not_given() -> None:
    fast = parse_args(["--engine", "fast"])
    assert (fast.n_envs, fast.batch_size, fast.n_steps) == (512, 8192, 64)
    assert fast_config(fast) == FastPPOConfig(device="cpu")
    assert parse_args(["--engine", "fast", "--n-envs", "8"]).n_envs == 8
    assert parse_args([]).n_envs == TrainConfig().n_envs  # sb3 keeps its own
    bc = parse_args(["--engine", "fast", "--algo", "bc_ppo"])
    assert bc.control_period == FINETUNE["control_period"]
    assert bc.value_warmup == FINETUNE["value_warmup"]
    assert bc_config(bc) == BCConfig() and bc.bc_iterations == BCConfig().iterations
    assert fast_config(bc).algo == "ppo"
    assert fast_config(parse_args(["--engine", "fast", "--device", "auto"])).device in (
        "cpu",
        "cuda",
    )


def test_platoon_train_engine_fast_bc_ppo_runs_in_its_folder(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert main([*TINY_CLI, "--out", str(out)]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["trainer"] == "training.bc" and meta["config"]["n_envs"] == 4
    assert meta["initialised_from"]["path"] == str(out / "bc" / "model.zip")
    assert json.loads((out / "bc" / "model.json").read_text())["stage"] == "clone"
    assert not (out / "run.lock").exists()
    with pytest.raises(SystemExit) as refused:
        main([*TINY_CLI, "--out", str(out)])  # a used folder (run.py's rule)
    assert refused.value.code == 2
    assert main([*TINY_CLI, "--out", str(out), "--resume"]) == 0  # finished: left as it is
    assert json.loads((out / "model.json").read_text()) == meta
    assert main([*TINY_CLI, "--out", str(out), "--force"]) == 0  # starts over, clone included


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["--engine", "fast", "--algo", "sac"], "--algo"),
        (["--algo", "bc_ppo"], "--algo"),
        (["--layout-repeats", "4"], "--layout-repeats"),
        (["--engine", "fast", "--bc-iterations", "3"], "--bc-iterations"),
        (["--engine", "fast", "--algo", "bc_ppo", "--bc-iterations", "0"], "--bc-iterations"),
        (["--engine", "fast", "--algo", "bc_ppo", "--bc-beta-decay", "2"], "--bc-beta-decay"),
        (["--engine", "fast", "--init-from", "weights.pt"], "--init-from"),
        (["--engine", "fast", "--value-warmup", "-1"], "--value-warmup"),
        (["--engine", "fast", "--batched"], "--batched"),
    ],
)
def test_bad_fast_options_are_argparse_errors_naming_the_option(
    argv: list[str], option: str, usage_error: Callable[..., str]
) -> None:
    assert f"argument {option}" in usage_error(parse_args, argv)


def test_resuming_an_empty_folder_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as refused:
        main([*TINY_CLI, "--out", str(tmp_path / "empty"), "--resume"])
    assert refused.value.code == 2
