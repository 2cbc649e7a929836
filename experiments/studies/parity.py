"""The fast learner against Stable-Baselines3 at equal transitions (``python -m
experiments.studies.parity``).

Three learners (:data:`VARIANTS`) train PPO on one training scenario, with the same
observation, reward, control period and number of follower transitions, for the same training
seeds:

* ``sb3``: ``platoon-train --engine sb3`` at its defaults (4 env copies, rollouts of 512 steps,
  256-sample minibatches, 10 epochs, learning rate 3e-4);
* ``fast``: ``--engine fast`` at :class:`training.fast_ppo.FastPPOConfig`'s defaults (512
  copies, 64 steps, 8,192-sample minibatches, 5 epochs, 1e-3): built for throughput, about
  sixty times fewer gradient steps per transition than SB3;
* ``fast_sb3_schedule``: the fast engine on SB3's update schedule: a rollout of the same size
  (64 copies x 32 steps instead of 4 x 512), 256-sample minibatches, 10 epochs, 3e-4, so as
  many gradient steps per transition as SB3 takes. This is the parity check of the
  implementation: the same algorithm, the same schedule, another engine.

Each run is one ``platoon-train`` process into ``OUT/<variant>/s<seed>`` (resumed when it holds
a model, as ``platoon-sweep`` does). The comparison is the team success rate of the training
episodes in ``progress.csv`` (``training.curves``), averaged over each run's last ``--tail``
logged windows: per variant the mean over seeds, and each fast variant's difference from SB3
with Welch's t-test and its 95 % interval. "Within noise" means that interval contains 0.

Outputs: ``OUT/parity.md`` (the table, the test and the command) and ``OUT/parity.png`` (the
learning curves of both engines, mean over seeds with the band from the lowest to the highest
seed), both stamped with the code version.

Usage::

    python -m experiments.studies.parity --out results/parity            # 5 seeds, 1 M each
    python -m experiments.studies.parity --seeds 0 1 --timesteps 200000  # a smaller check
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.cli import count
from experiments.report import write_text_atomic
from experiments.stamp import metadata_stamp, png_metadata, stamp_markdown
from training.curves import plot_learning_curves, read_progress

__all__ = ["ENGINES", "VARIANTS", "main", "tail_success", "train_args", "wall_time"]

#: The learners compared: name -> (``platoon-train --engine``, its extra options).
VARIANTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "sb3": ("sb3", ()),
    "fast": ("fast", ()),
    "fast_sb3_schedule": (
        "fast",
        (
            "--n-envs",
            "64",
            "--n-steps",
            "32",
            "--batch-size",
            "256",
            "--n-epochs",
            "10",
            "--learning-rate",
            "3e-4",
        ),
    ),
}
#: The variants' names, the reference first.
ENGINES = tuple(VARIANTS)


def train_args(variant: str, scenario: str, timesteps: int, seed: int, out: Path) -> list[str]:
    """The ``platoon-train`` arguments of one run of ``variant`` (:data:`VARIANTS`;
    ``--resume`` when ``out`` holds a model)."""
    engine, extra = VARIANTS[variant]
    args = [
        "--engine",
        engine,
        *extra,
        "--algo",
        "ppo",
        "--scenario",
        scenario,
        "--task-aware-observations",
        "--timesteps",
        str(timesteps),
        "--seed",
        str(seed),
        "--out",
        str(out),
        "--log-every",
        str(max(timesteps // 50, 1000)),
        "--no-progress-bar",
        "--torch-threads",
        "1",
    ]
    if (out / "model.zip").exists() or (out / "checkpoint.zip").exists():
        args.append("--resume")
    return args


def tail_success(progress: Path, tail: int) -> float:
    """The mean team success rate over the last ``tail`` logged windows that had an episode."""
    rate = read_progress(progress)["success_rate"]
    rate = rate[~np.isnan(rate)]
    if rate.size == 0:
        raise ValueError(f"{progress}: no logged window with a finished episode")
    return float(np.mean(rate[-tail:]))


def _train(engine: str, args: argparse.Namespace, seed: int) -> Path:
    out = Path(args.out) / engine / f"s{seed}"
    out.mkdir(parents=True, exist_ok=True)
    cmd = [
        sys.executable,
        "-m",
        "training.train",
        *train_args(engine, args.scenario, args.timesteps, seed, out),
    ]
    with (out / "train.log").open("a") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        log.flush()
        # the caller's working directory: a relative --out (or scenario path) names the
        # same place for the child as for the log written here
        rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    if rc != 0:
        raise RuntimeError(f"{engine} seed {seed} failed (exit {rc}); see {out / 'train.log'}")
    print(f"{engine} s{seed}: done", flush=True)
    return out / "progress.csv"


def wall_time(progress: Path) -> float:
    """The run's training wall time in seconds, from the ``wall_time_s`` column of
    ``progress``: each segment of a resumed run counts from 0 again, so the time is the sum of
    each segment's last value (a segment ends where the column drops)."""
    wall = read_progress(progress)["wall_time_s"]
    if wall.size == 0:
        raise ValueError(f"{progress}: no logged window")
    ends = np.flatnonzero(np.diff(wall) < 0)  # the last row of every segment but the last
    return float(wall[ends].sum() + wall[-1])


def report(
    rates: dict[str, list[float]],
    seeds: Sequence[int],
    args: argparse.Namespace,
    stamp: Any,
    walls: dict[str, list[float]] | None = None,
) -> str:
    """The markdown of ``parity.md`` (``walls``: each run's wall time, a column when given)."""
    from scipy import stats

    sb3 = np.array(rates["sb3"])
    verdicts = []
    for variant in [v for v in rates if v != "sb3"]:
        fast = np.array(rates[variant])
        test = stats.ttest_ind(fast, sb3, equal_var=False)
        interval = test.confidence_interval(0.95)
        if np.isnan(test.pvalue):  # both rates constant: no variance to test
            verdict = "no variance to test (every run of each engine has the same rate)"
        elif interval.low <= 0.0 <= interval.high:
            verdict = "**within noise** (the interval contains 0)"
        else:
            verdict = "**not within noise**"
        verdicts.append(
            f"- {variant} - sb3: {float(fast.mean() - sb3.mean()):+.3f}, Welch's t-test p = "
            f"{float(test.pvalue):.3f}, 95 % interval [{interval.low:+.3f}, "
            f"{interval.high:+.3f}]: {verdict}."
        )
    lines = [
        "# The fast learner against SB3 at equal transitions",
        "",
        f"PPO on `{args.scenario}` (task-aware observations, ideal sensing), "
        f"{args.timesteps:,} follower transitions per run, training seeds "
        f"{', '.join(map(str, seeds))}; the variants as the driver's docstring defines them "
        "(`fast_sb3_schedule`: the fast engine on SB3's rollout size, minibatches, epochs and "
        f"learning rate). Team success rate of the training episodes over each run's last "
        f"{args.tail} logged windows.",
        "",
        "| learner | "
        + " | ".join(f"seed {s}" for s in seeds)
        + " | mean |"
        + (" median wall time [s] | transitions/s |" if walls else ""),
        "|---|" + "---|" * (len(seeds) + 1 + (2 if walls else 0)),
    ]
    for engine in rates:
        values = rates[engine]
        row = (
            f"| {engine} | "
            + " | ".join(f"{v:.3f}" for v in values)
            + f" | {float(np.mean(values)):.3f} |"
        )
        if walls:
            wall = float(np.median(walls[engine]))
            row += f" {wall:.0f} | {args.timesteps / wall:,.0f} |"
        lines.append(row)
    lines += [
        "",
        *verdicts,
        "",
        *(
            [
                "Wall time: each run's training time from its `progress.csv` (collection and "
                "updates, one torch thread); the driver trains two runs at a time, and what "
                "else the machine ran is not recorded, so compare the learners with each "
                "other (`benchmarks/train_speed.py` measures speed on a quiet machine).",
                "",
            ]
            if walls
            else []
        ),
        "![learning curves](parity.png)",
        "",
        stamp_markdown(stamp),
        "",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.studies.parity",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    parser.add_argument("--out", default="results/parity", help="output folder")
    parser.add_argument("--scenario", default="procedural_medium_train", help="training scenario")
    parser.add_argument(
        "--timesteps", type=count(1, "timesteps"), default=1_000_000, help="per run"
    )
    parser.add_argument(
        "--seeds", nargs="+", type=count(0, "seed"), default=[0, 1, 2, 3, 4], help="seeds"
    )
    parser.add_argument(
        "--tail", type=count(1, "tail"), default=5, help="logged windows averaged at the end"
    )
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=ENGINES,
        default=list(ENGINES),
        help="the learners compared (sb3 always included: the reference)",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if len(set(args.seeds)) != len(args.seeds) or len(args.seeds) < 2:
        parser.error(f"--seeds must be at least two distinct seeds, got {args.seeds}")
    from concurrent.futures import ThreadPoolExecutor

    # the two engines side by side, one core each
    with ThreadPoolExecutor(2) as pool:
        variants = ["sb3", *(v for v in ENGINES if v in args.variants and v != "sb3")]
        futures = {e: [pool.submit(_train, e, args, s) for s in args.seeds] for e in variants}
        progress = {e: [f.result() for f in fs] for e, fs in futures.items()}
    rates = {e: [tail_success(p, args.tail) for p in files] for e, files in progress.items()}
    walls = {e: [wall_time(p) for p in files] for e, files in progress.items()}
    stamp = metadata_stamp(
        "python -m experiments.studies.parity", {k: str(v) for k, v in vars(args).items()}, argv
    )
    out = Path(args.out)
    plot_learning_curves(progress, out / "parity.png", metadata=png_metadata(stamp))
    write_text_atomic(out / "parity.md", report(rates, args.seeds, args, stamp, walls))
    print(f"wrote {out / 'parity.md'}, {out / 'parity.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
