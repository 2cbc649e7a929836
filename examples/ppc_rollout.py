"""One episode of the paper's PPC law on a shipped scenario, and how it ended.

Builds the PettingZoo env with ``platoon_env.make``, drives every follower with
``baselines.PPCPolicy`` (eqs. 12-14 of the paper) through ``platoon_env.rollout.run_episode``,
and prints whether the platoon succeeded (the leader arrived, no follower violated a
constraint), how many steps it took and the first violation, if any.

Run (about two seconds for study C's 150 s episode)::

    python examples/ppc_rollout.py
    python examples/ppc_rollout.py --scenario study_a --seed 3
    python examples/ppc_rollout.py --max-steps 200     # stop early: no success, no violation
"""

from __future__ import annotations

import argparse

import platoon_env
from baselines import PPCPolicy
from platoon_env.rollout import episode_metrics, run_episode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="study_c", help="shipped name or YAML path")
    parser.add_argument("--seed", type=int, default=0, help="episode seed")
    parser.add_argument("--max-steps", type=int, default=None, help="stop after this many steps")
    args = parser.parse_args()

    env = platoon_env.make(args.scenario)
    policy = PPCPolicy(env)
    episode = run_episode(env, policy, seed=args.seed, max_steps=args.max_steps)
    metrics = episode_metrics(episode)

    print(f"scenario {args.scenario}, seed {args.seed}: {len(env.possible_agents)} followers")
    print(f"steps: {episode.steps} ({metrics['sim_time']:.2f} s simulated)")
    print(f"success: {metrics['success']}")
    if episode.first_violation is None:
        print("first violation: none")
    else:
        step, cause, follower = episode.first_violation
        time = (step + 1) * episode.control_period
        print(f"first violation: {cause} by follower_{follower} at step {step} ({time:.2f} s)")
    if not episode.leader_arrived and episode.first_violation is None:
        print("note: stopped before the leader reached the end of its path")
    print(
        f"rms distance error: {metrics['rms_e_d']:.3f} m, "
        f"min obstacle clearance: {metrics['min_obstacle_clearance']:.3f} m"
    )


if __name__ == "__main__":
    main()
