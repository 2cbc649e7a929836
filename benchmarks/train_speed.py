"""End-to-end training speed: follower transitions per second, collection and updates included.

Times, in one run and each in a fresh process (so that numba's and torch's thread pools do not
interfere), on ``procedural_medium_train`` with task-aware observations:

a. ``platoon-train`` as it runs by default (:class:`training.config.TrainConfig`'s defaults):
   SB3 PPO on 4 PettingZoo envs (:class:`training.vec_env.PlatoonVecEnv`), rollouts of 512
   steps, 10 epochs of minibatches of 256;
b. SB3 PPO on the batched core (:class:`training.batched_vec_env.BatchedPlatoonVecEnv`,
   ``--batched``) with many envs and the large rollouts and minibatches of (c);
c. the fast learner (:func:`training.fast_ppo.train_fast`) with the rollouts and minibatches of
   (b) (its other options the defaults);
c'. the fast learner with its defaults and ``layout_repeats=16`` (each env copy keeps a layout
   for 16 episodes): the layout generation (10-15 ms a layout on an idle core), not the
   learner, bounds (a)-(c) while the policy is untrained.

Each run logs a row of ``progress.csv`` at the end of every rollout's collection (before its
update); the speed is the transitions between its first and its last row over the wall time
between them, so it leaves out the start-up (imports, env construction, the first layouts and
rollout) and covers whole collect + update cycles. Every run starts from an untrained policy,
whose episodes are short (about 17 steps), so these are the speeds of the first minutes of a
run; episodes lengthen as a policy learns, and the layout cost per transition falls.

Other processes share the machine: the table gives the load average before and after.

    python benchmarks/train_speed.py             # 2-5 minutes (by the machine's load)
    python benchmarks/train_speed.py --scale 0.5 # fewer rollouts per path
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

SCENARIO = "procedural_medium_train"
#: Rollout sizes in follower transitions (procedural_medium_train has 2 followers).
FOLLOWERS = 2


def _paths(scale: float) -> dict[str, dict[str, Any]]:
    """The timed configurations: what each runs and for how many rollouts."""

    def rollouts(n: int) -> int:
        return max(3, round(n * scale))  # two full cycles between the first and last rows

    # (b) and (c) share one rollout shape: 512 copies x 16 steps x 2 followers = 16,384
    # transitions (the fast learner's default is 64 steps; shorter here to fit the budget, as
    # an untrained policy's rollouts are dominated by layout generation), minibatches of 8192.
    large = {"n_envs": 512, "n_steps": 16, "batch_size": 8192, "n_epochs": 5}
    return {
        "a": {
            "label": "SB3, 4 ParallelEnvs (platoon-train default)",
            "kind": "sb3",
            "options": {},
            "rollouts": rollouts(4),
        },
        "b": {
            "label": "SB3, BatchedPlatoonVecEnv, 512 envs, minibatch 8192",
            "kind": "sb3",
            "options": {"batched": True, **large, "learning_rate": 1e-3},
            "rollouts": rollouts(3),
        },
        "c": {
            "label": "fast_ppo, 512 envs, minibatch 8192",
            "kind": "fast",
            "options": large,
            "rollouts": rollouts(3),
        },
        "c'": {
            "label": "fast_ppo, defaults (512 envs x 64 steps), layout_repeats=16",
            "kind": "fast",
            "options": {"layout_repeats": 16},
            "rollouts": rollouts(4),
        },
    }


def _run_one(kind: str, options: dict[str, Any], rollouts: int, out: Path) -> dict[str, Any]:
    """Train one configuration for ``rollouts`` rollouts into ``out``; its speed.

    Imported here, in the child process: the parent imports neither torch nor numba."""
    from training.config import TrainConfig
    from training.curves import read_progress
    from training.fast_ppo import FastPPOConfig, train_fast

    env = {"scenario": SCENARIO, "task_aware_observations": True, "checkpoint_every": 0}
    t0 = time.perf_counter()
    if kind == "sb3":
        from training.train import train

        cfg = TrainConfig(**{**env, **options, "progress_bar": False, "out": str(out)})
        rollout = cfg.n_steps * cfg.n_envs * FOLLOWERS
        cfg = TrainConfig(
            **{**env, **options, "progress_bar": False, "out": str(out)},
            timesteps=rollout * rollouts,
            log_every=rollout,
        )
        train(cfg)
        threads = cfg.torch_threads
    else:
        base = FastPPOConfig(**{**env, **options, "progress_bar": False})
        rollout = base.n_steps * base.n_envs * FOLLOWERS
        fast = FastPPOConfig(
            **{**env, **options, "progress_bar": False},
            timesteps=rollout * rollouts,
            log_every=rollout,
        )
        train_fast(fast, out)
        threads = fast.torch_threads
    total = time.perf_counter() - t0
    rows = read_progress(out / "progress.csv")
    steps, wall = rows["timesteps"], rows["wall_time_s"]
    timed = float(steps[-1] - steps[0])
    seconds = float(wall[-1] - wall[0])
    return {
        "rollout": rollout,
        "transitions": int(steps[-1]),
        "timed_transitions": int(timed),
        "timed_s": seconds,
        "per_s": timed / seconds if seconds > 0 else float("nan"),
        "total_s": total,
        "episodes": int(rows["episodes"][1:].sum()),
        "torch_threads": threads,
    }


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main(argv: list[str] | None = None) -> int:
    """Time every path (each in a fresh process) and print the table and the ratios."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="rollouts per path, scaled")
    parser.add_argument("--only", nargs="+", help="time only these paths (a b c c')")
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # a child process: one path
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    paths = _paths(args.scale)
    if args.one is not None:
        spec = paths[args.one]
        result = _run_one(spec["kind"], spec["options"], spec["rollouts"], args.out)
        print(json.dumps(result))
        return 0

    names = args.only or list(paths)
    print(
        f"training speed on {SCENARIO} (task-aware observations), {os.cpu_count()} cores, {_cpu()}"
    )
    before = _load()
    print(f"load average before: {before}", flush=True)
    results: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="train_speed_") as tmp:
        for name in names:
            out = Path(tmp) / name.replace("'", "_prime")
            load = _load()
            proc = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    "--one",
                    name,
                    "--out",
                    str(out),
                    "--scale",
                    str(args.scale),
                ],
                capture_output=True,
                text=True,
                check=False,
            )
            if proc.returncode != 0:
                print(proc.stderr[-3000:], file=sys.stderr)
                raise SystemExit(f"path {name} failed (exit {proc.returncode})")
            results[name] = {**json.loads(proc.stdout.strip().splitlines()[-1]), "load": load}
            r = results[name]
            print(
                f"  {name}: {r['per_s']:,.0f} transitions/s ({r['timed_transitions']:,} in "
                f"{r['timed_s']:.1f} s; {r['total_s']:.0f} s with start-up; load {load})",
                flush=True,
            )
    after = _load()
    print(f"load average after: {after}\n")
    base = results.get("a", {}).get("per_s")
    print("| path | configuration | rollout | timed transitions | s | transitions/s | vs (a) |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name in names:
        r = results[name]
        ratio = f"{r['per_s'] / base:.1f}x" if base else "-"
        print(
            f"| ({name}) | {paths[name]['label']} | {r['rollout']:,} | "
            f"{r['timed_transitions']:,} | {r['timed_s']:.1f} | {r['per_s']:,.0f} | {ratio} |"
        )
    if args.json is not None:
        args.json.write_text(
            json.dumps({"load_before": before, "load_after": after, "results": results}, indent=2)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
