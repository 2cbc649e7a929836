"""Train the shipped learned configurations over several seeds (``platoon-sweep``).

Usage::

    platoon-sweep                      # every configuration, seeds 0-4, 2 at a time
    platoon-sweep --config ppo_ta_aruco --seeds 0 1 --jobs 1
    platoon-sweep --list               # the configurations and their options
    platoon-sweep --ship               # copy finished runs to models/<config>_s<seed>
    platoon-sweep --config residual_ppc --curves docs/figures/x.png   # their learning curves

A **configuration** (:data:`CONFIGS`) is a named set of ``platoon-train`` options; a run is a
configuration and a seed, trained into ``RUNS/<config>/s<seed>`` (``--runs``, default
``runs/sweep``). Each run is one ``platoon-train`` process with ``--resume`` when its directory
holds a model or checkpoint whose files belong together (``--force`` when it holds only the
logs of a run killed before its first checkpoint, or only a save cut off between its zip and
its JSON: the sweep says so, and the run starts over), so an interrupted sweep continues where
it stopped and a finished run is left as it is (``platoon-train``'s own rules: a run whose
options changed is refused, naming the differences). ``--jobs`` runs train side by side (one
core each: ``--torch-threads 1``). Each run's output goes to ``RUNS/<config>/s<seed>/train.log``;
the sweep prints a line per run as it ends, and exits non-zero if one failed (the others are
still trained).

``--ship`` copies ``model.zip``, ``model.json`` and ``progress.csv`` of every finished run to
``models/<config>_s<seed>/`` (the cards are written by :mod:`experiments.studies.leaderboard`, which
evaluates them).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from experiments.cli import count
from experiments.configs import CONFIGS, DEFAULT_SEEDS, Config
from experiments.report import file_stem
from experiments.stamp import metadata_stamp, png_metadata
from platoon_env.extras import MissingExtraError, require_extra

__all__ = [
    "cut_saves",
    "main",
    "option_differences",
    "run_args",
    "ship",
    "unshippable",
]


def run_dir(runs: Path, config: str, seed: int) -> Path:
    """Where a sweep trains ``config`` with ``seed``."""
    return Path(runs) / config / f"s{seed}"


#: The files a run can continue from (``platoon-train --resume``).
RESUMABLE = ("model.zip", "checkpoint.zip", "rllib_checkpoint")


def run_args(config: Config, seed: int, out: Path) -> list[str]:
    """The ``platoon-train`` arguments of one run: ``--resume`` if ``out`` holds a model or a
    checkpoint to continue from; ``--force`` if it holds only the logs of a run killed before
    its first checkpoint, or only saved points cut off between their files (nothing to
    continue from: it starts over, :func:`cut_saves` says why); else neither."""
    from training.train import RUN_FILES

    args = [*config.args, "--seed", str(seed), "--out", str(out), "--no-progress-bar"]
    if _resumable(out):
        args.append("--resume")
    elif any((out / f).exists() for f in RUN_FILES):
        args.append("--force")
    return args


def cut_saves(out: Path) -> list[str]:
    """Why each saved point of ``out`` cannot be continued from: a zip without its JSON, or
    one other than its JSON records (:func:`training.run.incomplete_point`: a save cut off by
    ``kill -9`` between its files, or an edit)."""
    from training.run import incomplete_point

    found = ((n, incomplete_point(out, n)) for n in ("model", "checkpoint"))
    return [f"{name}: {reason}" for name, reason in found if reason]


def _resumable(out: Path) -> bool:
    """Whether ``out`` holds a saved point ``platoon-train --resume`` can continue from: one
    of :data:`RESUMABLE` whose files belong together (RLlib's ``rllib_checkpoint/`` goes with
    ``checkpoint.zip``)."""
    from training.run import incomplete_point

    for f in RESUMABLE:
        point = "checkpoint" if f == "rllib_checkpoint" else f.removesuffix(".zip")
        if (out / f).exists() and incomplete_point(out, point) is None:
            return True
    return False


#: The trainings running now (each ``_train`` registers its child), for :func:`stop_children`.
_CHILDREN: set[subprocess.Popen[bytes]] = set()
_CHILDREN_LOCK = threading.Lock()
#: Set by :func:`stop_children`: no training starts after it (a job whose thread was about to
#: start one returns 130 instead).
_STOPPING = threading.Event()
#: How long :func:`stop_children` waits for a training to end after SIGTERM before SIGKILL.
STOP_GRACE = 30.0


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """In a training child (Linux): SIGTERM when the sweep dies, even by SIGKILL."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _train(config: Config, seed: int, out: Path) -> tuple[str, int, float]:
    out.mkdir(parents=True, exist_ok=True)
    args = run_args(config, seed, out)
    name = f"{config.name} s{seed}"
    cut = cut_saves(out)
    if cut and "--force" in args:
        note = f"{name}: nothing complete to resume ({'; '.join(cut)}); starting it over"
        print(note, flush=True)
        with (out / "train.log").open("a") as log:
            log.write(note + "\n")
    cmd = [sys.executable, "-m", "training.train", *args, "--torch-threads", "1"]
    return name, *_run_child(cmd, out / "train.log")


def _run_child(cmd: Sequence[str], log_path: Path) -> tuple[int, float]:
    """Run ``cmd`` with its output appended to ``log_path``; its exit status and wall time.
    The child is registered for :func:`stop_children` and, on Linux, gets SIGTERM if this
    process dies (``PR_SET_PDEATHSIG``), so no training outlives the sweep."""
    t0 = time.perf_counter()
    with log_path.open("a") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        log.flush()
        # the caller's working directory: a relative --out (or scenario path) names the
        # same place for the child as for the log written here
        linux = sys.platform.startswith("linux")
        with _CHILDREN_LOCK:
            if _STOPPING.is_set():
                log.write("not started: the sweep is stopping\n")
                return 130, time.perf_counter() - t0
            proc = subprocess.Popen(
                list(cmd),
                stdout=log,
                stderr=subprocess.STDOUT,
                preexec_fn=_die_with_parent if linux else None,
            )
            _CHILDREN.add(proc)
        try:
            rc = proc.wait()
        finally:
            with _CHILDREN_LOCK:
                _CHILDREN.discard(proc)
    return rc, time.perf_counter() - t0


def stop_children(grace: float = STOP_GRACE) -> int:
    """SIGTERM every running training, SIGKILL those still running after ``grace`` seconds,
    and reap them all; returns how many there were. A training stopped so leaves its run
    folder as a crash would: the next sweep resumes it from its last checkpoint (or starts
    it over)."""
    with _CHILDREN_LOCK:
        _STOPPING.set()
        children = list(_CHILDREN)
    for proc in children:
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
    deadline = time.monotonic() + grace
    for proc in children:
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return len(children)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


#: What :func:`ship` copies of a finished run.
SHIPPED_FILES = ("model.zip", "model.json", "progress.csv")


def ship(runs: Path, models: Path, configs: Sequence[str], seeds: Sequence[int]) -> list[Path]:
    """Copy every finished run's model, description and learning curve to ``models``.

    A run is shipped when :func:`unshippable` finds nothing against it: its ``model.json`` is
    readable, not ``interrupted``, has trained the timesteps it was asked for, records the
    options of its configuration and seed, the run holds every one of :data:`SHIPPED_FILES`,
    and its ``model.zip`` is the one its ``model.json`` records (SHA-256). Any other run is
    skipped with a note on stderr naming the reason (nothing of it is copied), and the others
    are still shipped.

    A shipped folder appears whole or not at all (:func:`_replace_folder`): the files are
    copied into a temporary folder beside it, checked again, then renamed into place; a
    folder or a link already there is moved aside and removed, never written through.
    """
    shipped = []
    for name in configs:
        for seed in seeds:
            src = run_dir(runs, name, seed)
            reason = unshippable(CONFIGS[name], seed, src)
            if reason:
                print(f"skip {name} s{seed}: {reason}", file=sys.stderr)
                continue
            dst = Path(models) / file_stem(f"{name}_s{seed}")
            _replace_folder(dst, [src / f for f in SHIPPED_FILES])
            shipped.append(dst)
    return shipped


def _replace_folder(dst: Path, files: Sequence[Path]) -> None:
    """Make ``dst`` a folder holding copies of ``files``, all at once: they are copied into a
    temporary folder in ``dst``'s parent (the zip checked against its JSON once copied), which
    is renamed to ``dst`` after whatever was at ``dst`` (a folder, a file, a symbolic link:
    the link itself, not its target) has been renamed aside; the old one is then removed. A
    failure leaves ``dst`` as it was and removes the temporary folder."""
    import json

    from training.policies import zip_mismatch

    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=dst.parent, prefix=f".{dst.name}.", suffix=".tmp"))
    try:
        for f in files:
            shutil.copyfile(f, tmp / f.name)
        meta = tmp / "model.json"
        if meta.is_file():
            problem = zip_mismatch(tmp / "model.zip", json.loads(meta.read_text()))
            if problem:
                raise RuntimeError(f"{dst.name}: the copied {problem}")
        os.chmod(tmp, 0o755)
        old = None
        if dst.is_symlink() or dst.exists():
            old = dst.with_name(f".{dst.name}.{os.getpid()}.old")
            os.rename(dst, old)
        os.rename(tmp, dst)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if old is not None:
        if old.is_symlink() or old.is_file():
            old.unlink()
        else:
            shutil.rmtree(old, ignore_errors=True)


def unshippable(config: Config, seed: int, src: Path) -> str | None:
    """Why the run in ``src`` is not a finished run of ``config`` with ``seed`` (None if it
    is): a missing or unreadable ``model.json``, an unfinished run, a missing file, a
    ``model.zip`` other than the one ``model.json`` records (its SHA-256), or options other than
    the configuration's (each difference named, recorded vs configured)."""
    import json

    meta_path = src / "model.json"
    if not meta_path.exists():
        return f"no {meta_path}"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return f"{meta_path} is not readable JSON ({exc})"
    if not isinstance(meta, dict):
        return f"{meta_path} is not a JSON object"
    done, wanted = meta.get("timesteps"), meta.get("timesteps_requested")
    counts = [v for v in (done, wanted) if isinstance(v, int) and not isinstance(v, bool)]
    if meta.get("interrupted") or len(counts) < 2 or counts[0] < counts[1]:
        return f"unfinished ({done} of {wanted})"
    absent = [f for f in SHIPPED_FILES if not (src / f).is_file()]
    if absent:
        return f"no {', '.join(absent)} in {src}"
    from training.policies import zip_mismatch

    mismatch = zip_mismatch(src / "model.zip", meta)
    if mismatch:
        return mismatch
    differences = option_differences(config, seed, meta)
    if differences:
        return (
            f"{meta_path} records other options than the configuration {config.name} with seed "
            f"{seed}: {'; '.join(differences)}"
        )
    return None


def option_differences(config: Config, seed: int, meta: dict[str, Any]) -> list[str]:
    """How the options a run recorded (``model.json``'s ``config``) differ from ``config``'s with
    ``seed``: platoon-train's own comparison (:func:`training.config.config_differences`, on
    the options themselves, env options included) and the timesteps asked for."""
    from training.config import config_differences
    from training.train import parse_args

    recorded = meta.get("config")
    if not isinstance(recorded, dict):
        return ["no recorded options (model.json has no 'config')"]
    cfg = parse_args([*config.args, "--seed", str(seed), "--out", "unused"])
    if cfg.engine == "fast":
        return _fast_differences(cfg, meta, recorded)
    # without the scenario fingerprint, the env options are compared one by one (resolving the
    # scenario here would only repeat what platoon-train checked when it trained the run)
    options_only = {k: v for k, v in meta.items() if k != "scenario_fingerprint"}
    out = config_differences(cfg, options_only, "", {})
    if recorded.get("timesteps") != cfg.timesteps:
        out.append(f"--timesteps: stored {recorded.get('timesteps')!r}, given {cfg.timesteps!r}")
    return out


def _fast_differences(cfg: Any, meta: dict[str, Any], recorded: dict[str, Any]) -> list[str]:
    """:func:`option_differences` of a run of the fast engine, whose ``model.json`` records the
    learner's own options (:func:`training.fast_ppo.json_config`): each compared with what
    ``platoon-train`` makes of the configuration's, but those a resume may change and the
    fine-tuning's ``init_from`` (the run's own clone); an option recorded before it existed
    counts as its default. A ``bc_*`` configuration must have been trained by the cloner."""
    from training.algorithms import is_clone
    from training.fast_ppo import RESUMABLE_CHANGES, FastPPOConfig, json_config
    from training.train import fast_config

    expected = json_config(fast_config(cfg))
    defaults = json_config(FastPPOConfig())
    skip = {*RESUMABLE_CHANGES, "init_from"}
    out = []
    for key, value in expected.items():
        stored = recorded.get(key, defaults.get(key))
        if key not in skip and stored != value:
            out.append(f"{key}: stored {stored!r}, given {value!r}")
    trainer = "training.bc" if is_clone(cfg.algo) else "training.fast_ppo"
    if meta.get("trainer") != trainer:
        out.append(f"trainer: stored {meta.get('trainer')!r}, given {trainer!r}")
    return out


def curves(
    runs: Path, configs: Sequence[str], seeds: Sequence[int], png: Path, argv: Sequence[str] | None
) -> Path | None:
    """Draw the learning curves of ``configs`` from their runs' ``progress.csv`` in ``runs``
    (:func:`training.curves.plot_learning_curves`, stamped with the command and the code
    version); a configuration without a run is named on stderr; None if no run has a curve."""
    from training.curves import plot_learning_curves

    progress: dict[str, list[Path]] = {}
    for name in configs:
        files = [run_dir(runs, name, s) / "progress.csv" for s in seeds]
        found = [f for f in files if f.is_file()]
        if not found:
            print(f"no progress.csv of {name} in {runs}", file=sys.stderr)
            continue
        progress[name] = found
    if not progress:
        return None
    stamp = metadata_stamp("platoon-sweep", None, argv)
    out = plot_learning_curves(progress, png, metadata=png_metadata(stamp))
    print(f"wrote {out}")
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="platoon-sweep", description=__doc__.split("\n\n")[0] if __doc__ else None
    )
    parser.add_argument(
        "--config",
        nargs="+",
        choices=sorted(CONFIGS),
        default=list(CONFIGS),
        help="configurations to train (default: all)",
    )
    parser.add_argument(
        "--seeds",
        nargs="+",
        type=count(0, "seed"),
        default=list(DEFAULT_SEEDS),
        help="training seeds",
    )
    parser.add_argument(
        "--jobs", type=count(1, "jobs"), default=2, help="runs trained at once (>= 1)"
    )
    parser.add_argument("--runs", default="runs/sweep", help="folder of the run directories")
    parser.add_argument("--models", default="models", help="where --ship copies the models")
    parser.add_argument("--ship", action="store_true", help="copy finished runs, train nothing")
    parser.add_argument("--list", action="store_true", help="print the configurations and exit")
    parser.add_argument(
        "--curves",
        metavar="PNG",
        help="draw the learning curves of --config's runs in --runs (mean over the seeds that "
        "have a progress.csv, band from the lowest to the highest) to PNG; train nothing",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    if a.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {a.jobs}")
    if len(set(a.seeds)) != len(a.seeds) or min(a.seeds) < 0:
        parser.error(f"--seeds must be distinct and >= 0, got {a.seeds}")
    if a.list:
        for c in CONFIGS.values():
            print(f"{c.name}: {c.summary}\n    platoon-train {' '.join(c.args)}")
        return 0
    runs = Path(a.runs)
    try:  # training, shipping (its checks read the runs' options) and the curves import the
        # training package
        if a.curves:
            require_extra("plot", "matplotlib", purpose="--curves")  # PNGs only: no imageio
        require_extra("train", purpose="platoon-sweep")
    except MissingExtraError as exc:
        parser.error(str(exc))
    if a.curves:
        return 0 if curves(runs, a.config, a.seeds, Path(a.curves), argv) else 1
    if a.ship:
        shipped = ship(runs, Path(a.models), a.config, a.seeds)
        for p in shipped:
            print(f"shipped {p}")
        return 0 if shipped else 1
    jobs = [(CONFIGS[n], s, run_dir(runs, n, s)) for n in a.config for s in a.seeds]
    print(f"{len(jobs)} runs, {a.jobs} at a time, into {runs}/", flush=True)
    return _run_jobs(jobs, a.jobs)


def _run_jobs(jobs: Sequence[tuple[Config, int, Path]], parallel: int) -> int:
    """Train ``jobs`` ``parallel`` at a time; 0, 1 if one failed, 130 on SIGINT or SIGTERM
    (every running training is stopped and reaped first: :func:`stop_children`)."""
    failed = 0
    _STOPPING.clear()
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    pool = ThreadPoolExecutor(parallel)
    try:
        for future in as_completed([pool.submit(_train, *j) for j in jobs]):
            name, rc, wall = future.result()
            status = "done" if rc == 0 else f"FAILED (exit {rc}; see its train.log)"
            print(f"{name}: {status} in {wall / 60:.1f} min", flush=True)
            failed += rc != 0
    except KeyboardInterrupt:
        pool.shutdown(wait=False, cancel_futures=True)
        stopped = stop_children()
        pool.shutdown(wait=True)
        print(f"interrupted: {stopped} training(s) stopped; re-run to resume them", flush=True)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    pool.shutdown(wait=True)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
