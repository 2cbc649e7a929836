"""The run folder both engines train into: what it holds, who owns it, what a run does there.

``platoon-train`` (either engine) follows the rules of :mod:`training.train`'s module doc for
``--out``, ``--resume`` and ``--force``; this module implements them:

* :func:`hold_run` — **one owner per folder.** A run takes an exclusive ``fcntl.flock`` on
  ``--out``/:data:`LOCK_FILE` for its whole life; the file records the holder (host, pid,
  start time, command). A second run into the same folder is refused (a :class:`RunError`,
  exit status 2) with the holder's name and how to release it. The lock goes with the
  process, also after ``kill -9``; a clean exit (Ctrl-C included) removes the file, so a lock
  file nobody holds marks a run that was killed (:func:`run_status` reports it so, and the
  next run says so when it takes the folder over).
* :func:`plan_run` — what training does in ``--out`` (``new``, ``resume`` or ``finished``:
  :class:`RunPlan`), refusing what would mix two runs; :func:`open_run` checks, plans and
  prepares the folder under the lock.
* :class:`Segment` — one invocation's share of a run: its commit, start time and wall time,
  and the timing over every segment before it (``segments`` in ``model.json``). Its
  :attr:`RunPlan.segment_index` keys the env seeds (:mod:`training.seeding`).
* :func:`save_point` — **a saved point appears whole.** A model or checkpoint is several files
  (``NAME.zip``, ``NAME.json`` and, for the fast engine, ``NAME.state.pt``); they are written
  into a temporary folder beside them, then renamed into place, the JSON last, with SIGINT and
  SIGTERM held until the last rename. A failed write (a full disk) leaves the previous point
  as it was; only a ``kill -9`` between two renames can leave a zip beside a JSON that does
  not record it, which :func:`incomplete_point` names: a resume leaves such a point out (the
  newer complete one is continued) and ``platoon-sweep`` starts a run that has no complete
  point over rather than failing it.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import fcntl
import json
import os
import platform
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
import types
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import platoon_env
from platoon_env.provenance import code_version
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping, file_sha256
from training.config import TrainConfig, check_scenario, config_differences
from training.policies import zip_mismatch

__all__ = [
    "LOCK_FILE",
    "RLLIB_CHECKPOINT",
    "RUN_FILES",
    "RUN_STATES",
    "Holder",
    "RunError",
    "RunPlan",
    "RunStatus",
    "Segment",
    "finished_run",
    "git_commit",
    "hold_run",
    "holds_run",
    "incomplete_point",
    "library_versions",
    "open_run",
    "plan_run",
    "previous_segments",
    "report_interrupt",
    "run_status",
    "save_point",
    "segment_metadata",
    "start_run",
    "timing_metadata",
]

#: Where ``platoon-train --engine rllib`` keeps the full RLlib algorithm checkpoint in ``--out``.
RLLIB_CHECKPOINT = "rllib_checkpoint"
#: What marks ``--out`` as holding a run (and what ``--force`` removes).
RUN_FILES = (
    "model.zip",
    "model.json",
    "checkpoint.zip",
    "checkpoint.json",
    RLLIB_CHECKPOINT,
    "tb",
    "progress.csv",
    # the fast engine's learner states and behaviour cloning's clone (training.fast_ppo/bc)
    "model.state.pt",
    "checkpoint.state.pt",
    "bc",
)
#: The lock file of a run folder (:func:`hold_run`); not a run file: ``--force`` keeps it.
LOCK_FILE = "run.lock"


class RunError(ValueError):
    """A refused ``--out``/``--resume``/``--force`` (``platoon-train`` exits 2 with it)."""


def _now() -> str:
    """Now, in UTC, to the second (ISO 8601)."""
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


# ------------------------------------------------------------------------------------------------
# One owner per folder
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Holder:
    """Who holds (or last held) a run folder's lock: what :data:`LOCK_FILE` records."""

    host: str
    pid: int
    started_at: str
    command: tuple[str, ...] = ()

    @classmethod
    def this_process(cls) -> Holder:
        """This process, now."""
        return cls(socket.gethostname(), os.getpid(), _now(), tuple(sys.argv))

    @property
    def local(self) -> bool:
        """Whether it runs (ran) on this host."""
        return self.host == socket.gethostname()

    def alive(self) -> bool | None:
        """Whether its pid still runs here (None: another host, not checkable from here). A
        zombie (a killed process its parent has not reaped yet, e.g. a training whose sweep was
        killed) runs no more: it holds nothing."""
        if not self.local:
            return None
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # another user's process
            return True
        try:  # Linux: the state field after the command's closing parenthesis
            stat = Path(f"/proc/{self.pid}/stat").read_text()
        except OSError:
            return True
        return stat[stat.rfind(")") + 2 : stat.rfind(")") + 3] != "Z"

    def __str__(self) -> str:
        return f"pid {self.pid} on {self.host}, started {self.started_at}"


def read_holder(lock: Path) -> Holder | None:
    """The holder a lock file records (None: no file, or not written yet)."""
    try:
        data = json.loads(lock.read_text())
        return Holder(
            host=str(data["host"]),
            pid=int(data["pid"]),
            started_at=str(data.get("started_at", "?")),
            command=tuple(str(c) for c in data.get("command", ())),
        )
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None


@dataclass
class _Lock:
    fd: int
    path: Path
    created: tuple[Path, ...]  # the folders taking the lock created, deepest first
    previous: Holder | None  # who held the file last without removing it (killed)


#: The folders this process holds, by resolved path (:func:`hold_run` is re-entrant).
_HELD: dict[Path, _Lock] = {}
#: Tries at a lock that is busy only for a moment (:func:`run_status`'s probe, a holder that
#: has not written its name yet), and the pause between them [s].
_ATTEMPTS, _PAUSE = 10, 0.05


def holds_run(out: Path) -> bool:
    """Whether this process holds ``out``'s lock."""
    return Path(out).resolve() in _HELD


@contextmanager
def hold_run(out: Path) -> Iterator[Holder | None]:
    """Own the run folder ``out`` while the block runs (see the module doc); yields the holder
    before this one that never released it (a killed run), else None.

    Creates ``out`` if needed; raises :class:`RunError` when another process holds it or it
    cannot be written. On leaving, the lock file is removed, and so are the folders this call
    created if they are still empty (a refused run leaves nothing behind). Re-entrant: a
    process holding ``out`` enters again freely (``main`` holds it across planning and
    training; :func:`training.train.train` takes it when called alone).
    """
    key = Path(out).resolve()
    if key in _HELD:
        yield _HELD[key].previous
        return
    lock = _acquire(Path(out))
    _HELD[key] = lock
    try:
        if lock.previous is not None:
            print(
                f"note: {out}: the run that held it ({lock.previous}) ended without releasing "
                "it: it was killed; its files are kept as it left them",
                file=sys.stderr,
            )
        yield lock.previous
    finally:
        del _HELD[key]
        _release(lock)


def _acquire(out: Path) -> _Lock:
    created = _missing_dirs(out)
    path = out / LOCK_FILE
    holder: Holder | None = None
    for _ in range(_ATTEMPTS):
        try:
            out.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            _remove_empty(created)
            where = f" ({e.filename})" if e.filename and str(e.filename) != str(out) else ""
            raise RunError(
                f"argument --out: cannot write to {out}: {e.strerror or e}{where}"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            holder = read_holder(path)
            if holder is None or holder.alive() is False:
                time.sleep(_PAUSE)  # a holder about to write its name, or a status probe
                continue
            break
        except OSError as e:  # e.g. a network file system without locks
            os.close(fd)
            _remove_empty(created)
            raise RunError(f"argument --out: cannot lock {path}: {e.strerror or e}") from None
        if not _same_file(fd, path):  # released and removed between our open and our flock
            os.close(fd)
            continue
        previous = read_holder(path)
        me = json.dumps(dataclasses.asdict(Holder.this_process()), indent=1).encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, me, 0)
        return _Lock(fd, path, created, previous)
    _remove_empty(created)
    raise RunError(_busy_message(out, path, holder))


def _busy_message(out: Path, lock: Path, holder: Holder | None) -> str:
    who = str(holder) if holder is not None else "a process that has not recorded itself yet"
    if holder is None or holder.local:
        pid = holder.pid if holder is not None else "PID"
        release = (
            f"Wait for it to end, stop it (kill -INT {pid}: it saves its model so far) or train "
            "into another --out; the lock is released when that process ends, even by kill -9"
        )
    else:
        release = (
            f"Wait for it to end or train into another --out; if it no longer runs on "
            f"{holder.host} (a crashed host), delete {lock} to release it"
        )
    return (
        f"argument --out: {out} is in use by another platoon-train run ({who}; lock {lock}). "
        + release
    )


def _release(lock: _Lock) -> None:
    try:
        if _same_file(lock.fd, lock.path):  # still ours (not deleted by hand and retaken)
            lock.path.unlink()
    finally:
        os.close(lock.fd)  # releases the flock
    _remove_empty(lock.created)


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except OSError:
        return False


def _missing_dirs(out: Path) -> tuple[Path, ...]:
    """``out`` and its parents that do not exist yet, deepest first."""
    missing: list[Path] = []
    path = out
    while not path.exists() and path != path.parent:
        missing.append(path)
        path = path.parent
    return tuple(missing)


def _remove_empty(dirs: tuple[Path, ...]) -> None:
    for path in dirs:
        try:
            path.rmdir()
        except OSError:  # not empty (a run wrote into it), or gone
            return


#: The states :func:`run_status` reports.
RUN_STATES = ("empty", "running", "killed", "unknown", "interrupted", "finished", "unfinished")


@dataclass(frozen=True)
class RunStatus:
    """What a run folder holds and whether a process trains into it (:func:`run_status`).

    ``state``: ``running`` (its lock is held: ``holder``), ``killed`` (a lock file nobody
    holds: its ``holder`` on this host ended without its clean-up, e.g. ``kill -9``),
    ``unknown`` (the same for a holder on another host, which this host cannot check),
    ``interrupted`` (a ``model.json`` saved on Ctrl-C), ``finished`` (a final ``model.json``),
    ``unfinished`` (run files but no model: a run that ended before it saved one) or
    ``empty``. ``timesteps``: the most recorded by ``model.json``/``checkpoint.json``.
    """

    state: str
    holder: Holder | None = None
    timesteps: int | None = None

    def __str__(self) -> str:
        text = self.state
        if self.holder is not None:
            text += f" ({self.holder})"
        if self.timesteps is not None:
            text += f" at {self.timesteps} timesteps"
        return text


def run_status(out: Path) -> RunStatus:
    """The :class:`RunStatus` of the run folder ``out`` (reads it; changes nothing)."""
    out = Path(out)
    metas = {name: _peek_json(out / f"{name}.json") for name in ("model", "checkpoint")}
    steps = [int(m.get("timesteps") or 0) for m in metas.values() if m is not None]
    timesteps = max(steps) if steps else None
    lock = out / LOCK_FILE
    if lock.exists():
        holder = read_holder(lock)
        held = _lock_held(lock)
        if held is None:  # unreadable here: fall back on the recorded pid
            held = holder is None or holder.alive() is not False
        if held:
            return RunStatus("running", holder, timesteps)
        local = holder is None or holder.local
        return RunStatus("killed" if local else "unknown", holder, timesteps)
    model = metas["model"]
    if model is not None:
        return RunStatus("interrupted" if model.get("interrupted") else "finished", None, timesteps)
    if any((out / name).exists() for name in RUN_FILES):
        return RunStatus("unfinished", None, timesteps)
    return RunStatus("empty")


def _lock_held(lock: Path) -> bool | None:
    """Whether a process holds ``lock`` (None: it cannot be opened here)."""
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # also drops the shared lock taken just now
    return False


def _peek_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


# ------------------------------------------------------------------------------------------------
# What a run does in its folder
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunPlan:
    """What :func:`plan_run` decided for ``--out``.

    ``mode``: ``"new"`` (train from scratch; ``discard``: what ``--force`` removes first),
    ``"resume"`` (continue from ``source``, whose JSON is ``stored``) or ``"finished"``
    (nothing to train: ``source`` is the model that already has ``--timesteps``; ``message``
    says so).
    """

    mode: str
    out: Path
    source: Path | None = None
    stored: Mapping[str, Any] = field(default_factory=dict)
    discard: tuple[Path, ...] = ()
    message: str = ""

    @property
    def timesteps(self) -> int:
        """Timesteps already trained (0 for a new run)."""
        return int(self.stored.get("timesteps", 0) or 0)

    @property
    def segments(self) -> list[dict[str, Any]]:
        """The training segments that led to ``source`` (empty for a new run)."""
        return previous_segments(self.stored)

    @property
    def segment_index(self) -> int:
        """This invocation's segment: how many came before it (0 for a new run); it keys the
        env seeds (:mod:`training.seeding`)."""
        return len(self.segments)

    @property
    def resumed_from(self) -> str | None:
        """The name of what a resume continues from (None for a new run)."""
        return self.source.name if self.mode == "resume" and self.source is not None else None


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise RunError(f"{path} is unreadable ({e}); pass --force to start over") from None
    if not isinstance(data, dict):
        raise RunError(f"{path} is not a model description; pass --force to start over")
    return data


@dataclass(frozen=True)
class _Saved:
    name: str  # "model" or "checkpoint"
    meta: dict[str, Any]
    resume_from: Path | None  # what the engine restores (None: not resumable)

    @property
    def timesteps(self) -> int:
        return int(self.meta.get("timesteps", 0) or 0)


def _saved_points(cfg: TrainConfig, out: Path) -> tuple[list[_Saved], list[str]]:
    """The model and checkpoint in ``out`` whose zip matches its JSON, and why others were
    left out."""
    points: list[_Saved] = []
    skipped: list[str] = []
    for name in ("model", "checkpoint"):
        zip_path, meta = out / f"{name}.zip", _read_json(out / f"{name}.json")
        if meta is None and zip_path.is_file():
            skipped.append(f"{name}.zip (no {name}.json beside it: a save cut off)")
            continue
        if meta is None or not zip_path.is_file():
            continue
        reason = zip_mismatch(zip_path, meta)
        if reason is not None:
            skipped.append(f"{name}.zip ({reason})")
            continue
        if cfg.engine == "rllib":  # restored from the full RLlib checkpoint beside it
            ckpt = out / RLLIB_CHECKPOINT
            resume_from = ckpt if name == "checkpoint" and ckpt.is_dir() else None
        else:
            resume_from = zip_path
        points.append(_Saved(name, meta, resume_from))
    return points, skipped


def plan_run(cfg: TrainConfig, env: Any) -> RunPlan:
    """Decide what training ``cfg`` does in ``--out`` (the rules of :mod:`training.train`'s
    module doc), given its resolved training env ``env``; raises :class:`RunError` for a
    refusal. Writes nothing (call it holding the folder: :func:`hold_run`)."""
    out = cfg.out_dir
    if out.exists() and not out.is_dir():
        raise RunError(f"argument --out: {out} exists and is not a directory")
    present = tuple(out / name for name in RUN_FILES if (out / name).exists())
    if cfg.resume and cfg.force:
        raise RunError("argument --force: --resume continues the run in --out, --force discards it")
    if not cfg.resume:
        if present and not cfg.force:
            raise RunError(
                f"argument --out: {out} already holds a run "
                f"({', '.join(p.name for p in present)}); "
                "pass --resume to continue it (same options, --timesteps may be raised) or "
                "--force to discard it and start over"
            )
        return RunPlan("new", out, discard=present if cfg.force else ())
    points, skipped = _saved_points(cfg, out)
    note = f" (left out: {'; '.join(skipped)})" if skipped else ""
    if not points:
        found = ", ".join(p.name for p in present) or "nothing"
        raise RunError(
            f"argument --resume: nothing to resume in {out}: no checkpoint and no model "
            f"(found: {found}){note}; pass --force to start over"
        )
    fingerprint = config_fingerprint(env.source.config)
    scenario = config_mapping(env.source.config)
    for point in points:
        diffs = config_differences(cfg, point.meta, fingerprint, scenario)
        if diffs:
            raise RunError(
                f"argument --resume: the options differ from the run in {out} "
                f"({point.name}.json) on what defines it: "
                + "; ".join(diffs)
                + ". Give the stored options, or --force to start over"
            )
    model = next((p for p in points if p.name == "model"), None)
    if model is not None and model.timesteps >= cfg.timesteps:
        how = "saved on Ctrl-C" if model.meta.get("interrupted") else "finished"
        return RunPlan(
            "finished",
            out,
            source=out / "model.zip",
            stored=model.meta,
            message=(
                f"{out}: nothing to do: model.zip ({how}) already has {model.timesteps} "
                f"timesteps >= --timesteps {cfg.timesteps}; left unchanged (raise --timesteps "
                "to train on)"
            ),
        )
    resumable = [p for p in points if p.resume_from is not None]
    if not resumable:
        raise RunError(
            f"argument --resume: nothing to resume in {out}: "
            + ("no rllib_checkpoint/ beside checkpoint.json" if cfg.engine == "rllib" else "")
            + note
        )
    best = max(resumable, key=lambda p: (p.timesteps, p.name == "model"))
    return RunPlan(
        "resume",
        out,
        source=best.resume_from,
        stored=best.meta,
        message=f"resuming from {best.resume_from} at {best.timesteps} timesteps{note}",
    )


def open_run(cfg: TrainConfig, env: Any, plan: RunPlan | None = None) -> RunPlan:
    """``plan``, or what :func:`plan_run` decides for ``--out``, once ``cfg`` is checked
    against its resolved training env ``env`` (:func:`~training.config.check_scenario`); the
    folder is prepared (:func:`start_run`) unless the run is finished. Raises ``ValueError`` or
    :class:`RunError` before anything is written. Shared by both engines; the caller holds
    the folder (:func:`hold_run`)."""
    if not holds_run(cfg.out_dir):
        raise RuntimeError(f"open_run: hold_run({cfg.out_dir}) first")
    errors = check_scenario(cfg, env)
    if errors:
        raise ValueError("; ".join(errors))
    plan = plan if plan is not None else plan_run(cfg, env)
    if plan.mode != "finished":
        start_run(cfg, plan)
    return plan


def start_run(cfg: TrainConfig, plan: RunPlan) -> None:
    """Prepare ``--out`` for ``plan`` (not ``"finished"``): with ``--force``, say so and remove
    the earlier run's files; create the directory."""
    if cfg.force:
        if plan.discard:
            names = ", ".join(p.name for p in plan.discard)
            print(
                f"--force: discarding the earlier run in {plan.out} ({names}); starting over",
                file=sys.stderr,
            )
        else:
            print(f"--force: {plan.out} holds no earlier run; starting a new one", file=sys.stderr)
        try:
            for path in plan.discard:
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink()
        except OSError as e:
            raise RunError(f"argument --force: cannot remove {e.filename}: {e.strerror}") from None
    plan.out.mkdir(parents=True, exist_ok=True)


def previous_segments(stored: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The training segments recorded in a ``model.json``/``checkpoint.json`` (one per
    invocation of ``platoon-train``); a file written before segments were recorded gives one
    segment from its ``wall_time_s``, which then covers only its last segment."""
    if not stored:
        return []
    segments = stored.get("segments")
    if isinstance(segments, list):
        return [dict(s) for s in segments]
    return [
        {
            "started_at": stored.get("started_at"),
            "wall_time_s": stored.get("wall_time_s"),
            "timesteps_start": None,
            "timesteps_end": stored.get("timesteps"),
            "resumed_from": None,
            "git_commit": stored.get("git_commit"),
            "git_dirty": stored.get("git_dirty"),
            "note": "recorded before segments were: the wall time of its last segment only",
        }
    ]


def segment_metadata(
    *,
    started_at: str,
    wall_time_s: float,
    timesteps_start: int,
    timesteps_end: int,
    resumed_from: str | None,
    commit: Mapping[str, Any],
) -> dict[str, Any]:
    """One entry of ``segments``: one invocation's share of the training."""
    done = timesteps_end - timesteps_start
    return {
        "started_at": started_at,
        "wall_time_s": round(wall_time_s, 3),
        "timesteps_start": timesteps_start,
        "timesteps_end": timesteps_end,
        "timesteps_per_s": round(done / wall_time_s, 1) if wall_time_s > 0 else None,
        "resumed_from": resumed_from,
        **commit,
        "command": list(sys.argv),
    }


def timing_metadata(segments: list[dict[str, Any]], timesteps: int) -> dict[str, Any]:
    """``started_at`` (the first segment's), ``wall_time_s`` (the sum over ``segments``),
    ``timesteps_per_s`` (``timesteps`` over that) and ``segments``."""
    total = sum(float(s.get("wall_time_s") or 0.0) for s in segments)
    return {
        "started_at": segments[0].get("started_at") if segments else None,
        "wall_time_s": round(total, 3),
        "timesteps_per_s": round(timesteps / total, 1) if total > 0 else None,
        "segments": segments,
    }


def finished_run(plan: RunPlan) -> tuple[Path, bool]:
    """What a ``--resume`` of a finished run returns (it says so, and changes nothing)."""
    print(plan.message, file=sys.stderr)
    assert plan.source is not None
    return plan.source, False


@dataclass
class Segment:
    """This invocation's share of the run ``plan`` continues (or starts), from
    ``timesteps_start``: its commit and start, timed from when it is made."""

    plan: RunPlan
    timesteps_start: int
    commit: dict[str, Any] = field(default_factory=lambda: git_commit())  # defined below
    started_at: str = field(default_factory=_now)
    _clock: float = field(default_factory=time.perf_counter)

    @property
    def index(self) -> int:
        """:attr:`RunPlan.segment_index`."""
        return self.plan.segment_index

    def metadata(self, timesteps: int) -> dict[str, Any]:
        """What ``model.json`` records of the segments, this one run up to ``timesteps``:
        ``git_commit``/``git_dirty`` (this segment's) and :func:`timing_metadata`."""
        segment = segment_metadata(
            started_at=self.started_at,
            wall_time_s=time.perf_counter() - self._clock,
            timesteps_start=self.timesteps_start,
            timesteps_end=timesteps,
            resumed_from=self.plan.resumed_from,
            commit=self.commit,
        )
        return {**self.commit, **timing_metadata([*self.plan.segments, segment], timesteps)}


# ------------------------------------------------------------------------------------------------
# Saved points: written whole, checked whole
# ------------------------------------------------------------------------------------------------
#: The signals :func:`save_point` holds while it moves a point's files into place.
HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def held_signals() -> Iterator[None]:
    """Hold SIGINT and SIGTERM for the duration: one that arrives is delivered (to the handler
    it had, e.g. ``KeyboardInterrupt``, or the default: termination) when the block ends. Only
    the main thread can set handlers; elsewhere, and for a signal whose handler Python did not
    set, nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        received.append(signum)

    previous: dict[signal.Signals, Any] = {}
    try:
        for signum in HELD_SIGNALS:
            handler = signal.getsignal(signum)
            if handler is None:
                continue
            previous[signum] = handler
            signal.signal(signum, hold)
        yield
    finally:
        for held, handler in previous.items():
            signal.signal(held, handler)
        for pending in dict.fromkeys(received):
            signal.raise_signal(pending)


def save_point(path: Path, save: Callable[[Path], Any]) -> Path:
    """Write the saved point ``path`` (``DIR/NAME.zip``) whole: ``save(tmp)`` writes the zip
    at ``tmp`` (same name, in a new temporary folder in ``DIR``) and whatever goes beside it
    (``NAME.json``, ``NAME.state.pt``); the files are then renamed into ``DIR``, the JSON last.
    SIGINT and SIGTERM are held from the first write to the last rename (:func:`held_signals`).
    A failure leaves ``DIR`` as it was, its previous point included, and removes the
    temporary folder. Returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with held_signals():
        tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".save"))
        try:
            save(tmp / path.name)
            for f in sorted(tmp.iterdir(), key=lambda f: (f.suffix == ".json", f.name)):
                os.replace(f, path.parent / f.name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return path


def incomplete_point(out: Path, name: str) -> str | None:
    """Why the saved point ``name`` (``"model"`` or ``"checkpoint"``) of ``out`` is not one
    save, or None (its files belong together, or it has no zip): a zip without its JSON, a zip
    or a learner state (``NAME.state.pt``, the fast engine's) other than the one the JSON
    records: what a save cut off between its files (or an edit) leaves. A JSON that cannot be
    read is not judged here: ``platoon-train --resume`` refuses it, naming it."""
    zip_path, meta_file = out / f"{name}.zip", out / f"{name}.json"
    if not zip_path.is_file():
        return None
    if not meta_file.is_file():
        return f"{zip_path.name} without {meta_file.name}: a save cut off"
    meta = _peek_json(meta_file)
    if meta is None:
        return None
    reason = zip_mismatch(zip_path, meta)
    if reason is not None:
        return reason
    recorded = meta.get("learner_state_sha256")
    if recorded is not None:
        state = out / f"{name}.state.pt"
        if not state.is_file() or file_sha256(state) != recorded:
            return f"{state.name} is not the learner state {meta_file.name} records: a save cut off"
    return None


def report_interrupt(timesteps: int) -> None:
    """Say on stderr that Ctrl-C stopped training at ``timesteps`` (the model is saved next)."""
    print(f"\ninterrupted after {timesteps} timesteps; saving the model so far", file=sys.stderr)


def library_versions(*modules: types.ModuleType) -> dict[str, str]:
    """``versions`` of ``model.json``: platoon_env's, each of ``modules``' (by its name), and
    numpy's and python's."""
    return {
        "platoon_env": platoon_env.__version__,
        **{m.__name__: str(getattr(m, "__version__", "?")) for m in modules},
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def git_commit() -> dict[str, Any]:
    """The checkout's commit, whether its source folders hold uncommitted changes, and the
    content hash of each changed file (:func:`platoon_env.provenance.code_version`, the one
    provenance rule; None / {} outside a git checkout)."""
    version = code_version()
    if not version:
        return {"git_commit": None, "git_dirty": None, "git_modified_sha256": {}}
    return {
        "git_commit": version["commit"],
        "git_dirty": bool(version["modified"]),
        "git_modified_sha256": version["modified_sha256"],
    }
