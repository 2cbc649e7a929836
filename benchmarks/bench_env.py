"""Env-steps per second of one ParallelEnv (PettingZoo dict API), per shipped scenario.

Usage: ``python benchmarks/bench_env.py [--scenario study_a] [--steps 20000]``.
Actions are a fixed forward command; no violation ends the episode (``terminate_on=()``) so
every step does the full work, and the episode is reset when the leader's run is over.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

import platoon_env


def measure(scenario: str, steps: int, followers: int | None) -> tuple[float, int, int]:
    """Return (env-steps/s, followers, boundary edges) for ``steps`` steps of ``scenario``."""
    kwargs = {} if followers is None else {"followers": followers}
    env = platoon_env.make(scenario, terminate_on=(), **kwargs)
    env.reset(seed=0)
    actions = {a: np.array([0.2, 0.0], dtype=np.float32) for a in env.possible_agents}
    env.step(actions)  # compile / warm up
    start = time.perf_counter()
    for _ in range(steps):
        env.step(actions)
        if not env.agents:
            env.reset()
    elapsed = time.perf_counter() - start
    return steps / elapsed, env.n_followers, int(env.scenario.workspace.edges.shape[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scenario", action="append", help="scenario(s); default: all shipped")
    parser.add_argument("--steps", type=int, default=20_000, help="timed steps per scenario")
    parser.add_argument("--followers", type=int, default=None, help="override N")
    args = parser.parse_args()
    print(
        f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}"
    )
    print(f"{'scenario':<12} {'N':>3} {'edges':>6} {'env-steps/s':>12} {'agent-steps/s':>14}")
    for scenario in args.scenario or platoon_env.list_scenarios():
        rate, n, edges = measure(scenario, args.steps, args.followers)
        print(f"{scenario:<12} {n:>3} {edges:>6} {rate:>12,.0f} {rate * n:>14,.0f}")


if __name__ == "__main__":
    main()
