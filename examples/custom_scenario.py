"""Your own workspace: a scenario YAML file, loaded by ``platoon_env.make(path)``, driven by PPC.

``examples/corridor.yaml`` (the default) is a 16 x 5 m hall with a wall from each side, a
leader path that weaves around them and two followers with study C's robots, camera and PPC
gains. Copy it, move the walls or the path, and run this script on your copy: the file is
validated as it loads (an unknown key, a path too close to a wall or an infeasible start is a
``ScenarioError`` naming the field; the schema is docs/scenarios.md).

Run (under a second)::

    python examples/custom_scenario.py
    python examples/custom_scenario.py --scenario my_hall.yaml --seed 1
    python examples/custom_scenario.py --max-steps 300
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import platoon_env
from baselines import PPCPolicy
from platoon_env.rollout import episode_metrics, run_episode

CORRIDOR = Path(__file__).resolve().with_name("corridor.yaml")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", type=Path, default=CORRIDOR, help="a scenario YAML file")
    parser.add_argument("--seed", type=int, default=0, help="episode seed")
    parser.add_argument("--max-steps", type=int, default=None, help="stop after this many steps")
    args = parser.parse_args()

    env = platoon_env.make(str(args.scenario))  # a path: read, validated, built
    scenario = env.scenario
    xmin, ymin, xmax, ymax = scenario.free_space.bounds  # a shapely polygon
    path = np.linalg.norm(np.diff(scenario.leader_path, axis=0), axis=1).sum()
    print(f"scenario {scenario.name!r} from {args.scenario}")
    print(
        f"workspace {xmax - xmin:.1f} x {ymax - ymin:.1f} m, "
        f"{len(scenario.config.workspace.obstacles)} obstacles, "
        f"{len(env.possible_agents)} followers, leader path {path:.1f} m"
    )

    episode = run_episode(env, PPCPolicy(env), seed=args.seed, max_steps=args.max_steps)
    metrics = episode_metrics(episode)
    violation = episode.first_violation
    print(f"steps: {episode.steps} ({metrics['sim_time']:.2f} s simulated)")
    print(f"success: {metrics['success']}")
    print(f"first violation: {'none' if violation is None else violation[1]}")
    print(f"min obstacle clearance: {metrics['min_obstacle_clearance']:.3f} m")


if __name__ == "__main__":
    main()
