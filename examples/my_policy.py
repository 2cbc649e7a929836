"""Your own policy on the board: a ten-line class, ranked against the published benchmark.

A policy is a class built as ``MyPolicy(env)`` with ``reset(seed=None)`` and ``act(observations)
-> {agent: np.array([u, omega], float32)}``; each follower sees ``[visible, x, y, d_W_l, d_W_r,
d_l, d_r]`` (docs/overview.md). This one cuts study C's corners: beating PPC is your job.
``platoon-evaluate`` imports ``module:Class`` from the working directory, and
``--compare-to published`` runs only your policy on the published scenarios and seeds and ranks
it against every entry of experiments/data/published_benchmark.json without re-running them::

    cd examples && platoon-evaluate --policy mine=my_policy:MyPolicy --compare-to published

This script runs that through ``experiments.studies.evaluate.main`` (``python
examples/my_policy.py [--published FILE] [--out DIR]``). Where the published file is missing or
was made by other code (then refused), it runs ``--policy ppc`` beside ``mine`` instead.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np


class MyPolicy:
    """Turn towards the predecessor, speed up as it gets further than d_des; stop unseen."""

    def __init__(self, env: Any) -> None:
        self.d_des = env.scenario.config.formation.d_des

    def reset(self, seed: int | None = None) -> None:
        pass

    def act(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        actions = {}
        for agent, (visible, x, y, *_) in observations.items():
            d, beta = math.hypot(x, y), math.atan2(y, x)
            u, omega = (0.8 * (d - self.d_des), 2.0 * beta) if visible else (0.0, 0.0)
            actions[agent] = np.array([u, omega], dtype=np.float32)
        return actions


def main() -> int:
    from experiments.published import PUBLISHED, PublishedError, check_compatible, load_published
    from experiments.studies import evaluate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--published", default="published", help="'published' or a rows file")
    parser.add_argument("--out", default="results/my_policy", help="evaluation folder")
    parser.add_argument("--scenario", default="study_c", help="without published rows")
    parser.add_argument("--episodes", type=int, default=3, help="without published rows")
    parser.add_argument("--max-steps", type=int, default=None, help="without published rows")
    args = parser.parse_args()
    # `python examples/my_policy.py` puts this folder first on sys.path: `my_policy` imports.
    common = ["--policy", "mine=my_policy:MyPolicy", "--no-plots", "--workers", "1", "--out"]
    common += [args.out]
    source = PUBLISHED if args.published == "published" else Path(args.published)
    try:
        check_compatible(load_published(source), {}, [])  # the code; evaluate checks the rest
        argv = [*common, "--compare-to", args.published]
    except PublishedError as exc:
        print(f"cannot compare to {args.published}: {exc}")
        print("running --policy ppc beside mine instead")
        argv = [*common, "--policy", "ppc", "--scenario", args.scenario, "--episodes"]
        argv += [str(args.episodes)]
        argv += [] if args.max_steps is None else ["--set", f"max_episode_steps={args.max_steps}"]
    print("platoon-evaluate " + " ".join(argv))
    return evaluate.main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
