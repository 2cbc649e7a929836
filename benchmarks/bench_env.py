"""Env-steps per second of one ParallelEnv (PettingZoo dict API), per shipped scenario.

Usage: ``python benchmarks/bench_env.py [--scenario study_a] [--seconds 3]``.

A quick check of the single env; ``benchmarks/run.py`` prints the full table (batched API,
maps of growing size, MPE and VMAS). The followers replay the PPC policy's actions recorded on
the same scenario and seed, with ``terminate_on=()`` so that every step does the full work;
the episode is reset when the recorded actions run out. Procedural scenarios (no PPC block of
their own layout) use a constant forward command.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from run import machine, record_ppc_actions, time_parallel_env

import platoon_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", action="append", help="scenario(s); default: all shipped")
    parser.add_argument("--seconds", type=float, default=3.0, help="timed seconds per scenario")
    parser.add_argument("--steps", type=int, default=2000, help="recorded PPC steps to replay")
    args = parser.parse_args()
    print("machine: " + ", ".join(f"{k}={v}" for k, v in machine().items()))
    print(f"{'scenario':<18} {'N':>3} {'edges':>6} {'env-steps/s':>12} {'agent-steps/s':>14}")
    for scenario in args.scenario or platoon_env.list_scenarios():
        env = platoon_env.make(scenario)
        n, edges = env.n_followers, int(env.scenario.workspace.edges.shape[0])
        if env.scenario.config.ppc is not None and env.scenario.config.generator is None:
            actions = record_ppc_actions(scenario, args.steps)
        else:
            actions = np.tile(np.array([0.2, 0.0], dtype=np.float32), (args.steps, n, 1))
        rate = time_parallel_env(scenario, actions, args.seconds)
        print(f"{scenario:<18} {n:>3} {edges:>6} {rate:>12,.0f} {rate * n:>14,.0f}")


if __name__ == "__main__":
    main()
