"""Soak benchmark: a million env steps with resets, printing the process's memory as it goes.

Usage: ``python benchmarks/soak.py [--steps 1000000] [--scenario procedural_train]``.
Memory (resident set size) should stay flat: the env allocates its buffers once, and a reset
only replaces the workspace arrays (procedural scenarios) or reuses them.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

import platoon_env


def rss_mib() -> float:
    """Current resident set size in MiB (Linux /proc; falls back to the peak)."""
    status = Path("/proc/self/status")
    if status.is_file():
        for line in status.read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--scenario", default="procedural_train")
    parser.add_argument("--report-every", type=int, default=100_000)
    args = parser.parse_args()
    env = platoon_env.make(args.scenario, max_episode_steps=500)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    resets = 0
    start = time.perf_counter()
    print(f"{'steps':>10} {'resets':>8} {'RSS [MiB]':>10} {'steps/s':>10}")
    for k in range(1, args.steps + 1):
        actions = {a: rng.uniform([0.0, -0.5], [0.5, 0.5]) for a in env.agents}
        env.step(actions)
        if not env.agents:
            env.reset()
            resets += 1
        if k % args.report_every == 0:
            rate = k / (time.perf_counter() - start)
            print(f"{k:>10} {resets:>8} {rss_mib():>10.1f} {rate:>10,.0f}", flush=True)


if __name__ == "__main__":
    main()
