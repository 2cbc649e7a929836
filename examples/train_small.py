"""Train a small shared follower policy with PPO, then load it and run one episode.

Uses the documented Python route of ``platoon-train --engine fast`` (docs/training.md):
``training.fast_ppo.train_fast(FastPPOConfig(...), out)``, PPO on the batched core. The run
folder gets ``model.zip`` + ``model.json`` (an ordinary SB3 model) and ``progress.csv``;
``training.LearnedPolicy.load`` reads it back, and the episode runs at the control period the
model was trained at. A few thousand transitions teach a policy little: this shows the
plumbing, not a good follower (docs/training.md has the schedules that learn).

Run (some seconds; the command-line equivalent is ``platoon-train --engine fast ...``)::

    python examples/train_small.py                    # 4096 transitions into a temp folder
    python examples/train_small.py --timesteps 20000 --out runs/small
    platoon-evaluate --policy small=runs/small --scenario study_c --episodes 3
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import platoon_env
from platoon_env.rollout import episode_metrics, run_episode
from training import LearnedPolicy
from training.fast_ppo import FastPPOConfig, train_fast


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="study_c", help="shipped name or YAML path")
    parser.add_argument("--timesteps", type=int, default=4096, help="follower transitions")
    parser.add_argument("--out", type=Path, default=None, help="new run folder (default: temp)")
    parser.add_argument("--max-steps", type=int, default=None, help="cap the evaluation episode")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="platoon_train_small_"))

    # 8 copies x 32 steps x 2 followers = 512 transitions per PPO update (SB3-like schedule).
    config = FastPPOConfig(
        scenario=args.scenario, timesteps=args.timesteps, seed=0, n_envs=8, n_steps=32,
        batch_size=256, n_epochs=5, learning_rate=3e-4, log_every=512, checkpoint_every=0,
        progress_bar=False,
    )  # fmt: skip
    run = train_fast(config, out)
    print(f"trained {run.timesteps} transitions: {run.path}")

    policy = LearnedPolicy.load(run.path)
    env = platoon_env.make(args.scenario, control_period=policy.control_period)
    policy.check_env(env)  # raises if the model cannot act in this env
    episode = run_episode(env, policy, seed=0, max_steps=args.max_steps)
    metrics = episode_metrics(episode)
    cause = episode.first_violation[1] if episode.first_violation else "none"
    print(f"evaluation on {args.scenario} at {policy.control_period:g} s: {episode.steps} steps, "
          f"success {metrics['success']}, first violation: {cause}")  # fmt: skip


if __name__ == "__main__":
    main()
