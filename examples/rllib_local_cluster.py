"""PPO with Ray RLlib on a local Ray instance (or a running cluster), then one episode of it.

Runs ``platoon-train --engine rllib`` (docs/rllib.md) through ``training.train.main``: env
runners (Ray actors) sample, the learner in this process updates the policy every follower
shares, and the run folder gets ``model.zip`` + ``model.json``, which ``training.LearnedPolicy``
loads without Ray. Ray lives in its own venv, ``.venv-rllib`` (``bash scripts/test_rllib.sh``);
without Ray this script says so and exits 0. Run (a minute or two, mostly Ray starting up)::

    .venv-rllib/bin/python examples/rllib_local_cluster.py --env-runners 2 --timesteps 1024
    ray start --head --num-cpus=4       # or a cluster on this machine, joined with:
    .venv-rllib/bin/python examples/rllib_local_cluster.py --address auto
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="study_c", help="shipped name or YAML path")
    parser.add_argument("--env-runners", type=int, default=2, help="Ray env-runner actors")
    parser.add_argument("--timesteps", type=int, default=1024, help="follower transitions")
    parser.add_argument("--address", default=None, help="a running cluster (default: local)")
    parser.add_argument("--out", type=Path, default=None, help="new run folder (default: temp)")
    parser.add_argument("--max-steps", type=int, default=None, help="cap the evaluation episode")
    args = parser.parse_args()
    try:
        import ray
    except ImportError:
        print("skipped: ray is not installed (pip install -e '.[rllib]' in its own venv, "
              "see docs/rllib.md)")  # fmt: skip
        return 0
    import platoon_env
    from platoon_env.rollout import run_episode
    from training import LearnedPolicy
    from training.train import main as platoon_train

    out = args.out or Path(tempfile.mkdtemp(prefix="platoon_rllib_")) / "run"
    # one PPO iteration: 64 steps x 1 env x K runners x 2 followers transitions
    argv = ["--engine", "rllib", "--scenario", args.scenario, "--timesteps", str(args.timesteps)]
    argv += ["--num-env-runners", str(args.env_runners), "--n-envs", "1", "--n-steps", "64"]
    # one minibatch per iteration: RLlib needs minibatch <= the iteration's batch (64 x K)
    argv += ["--batch-size", str(64 * args.env_runners), "--n-epochs", "2", "--log-every", "128"]
    argv += ["--checkpoint-every", "0", "--no-progress-bar", "--seed", "0", "--out", str(out)]
    argv += ["--address", args.address] if args.address else []
    status = platoon_train(argv)
    ray.shutdown()  # the local instance (or our connection to the cluster)
    if status != 0:
        return status
    meta = json.loads((out / "model.json").read_text())
    runners = meta["ray"].get("env_runners", [])
    nodes = len(meta["ray"].get("nodes_alive", []))
    steps = ", ".join(f"runner {r['worker_index']}: {r['env_steps']}" for r in runners)
    print(f"trained {meta['timesteps']} transitions with {len(runners)} env runner(s) on "
          f"{nodes} Ray node(s) (env steps: {steps})")  # fmt: skip

    policy = LearnedPolicy.load(out)  # NumPy only: no Ray needed from here on
    env = platoon_env.make(args.scenario, control_period=policy.control_period)
    episode = run_episode(env, policy, seed=0, max_steps=args.max_steps)
    cause = episode.first_violation[1] if episode.first_violation else "none"
    print(f"model {out / 'model.zip'}: {episode.steps} steps on {args.scenario}, "
          f"first violation: {cause}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
