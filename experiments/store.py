"""The evaluation store: one SQLite database of episodes, safe under crashes and concurrency.

Every episode an experiment runs is one row of the ``episodes`` table, keyed by

* the **policy** fingerprint (:meth:`experiments.policies.PolicySpec.fingerprint`),
* the **scenario** fingerprint: the resolved config, after the YAML, the sensor profile and
  every override (:func:`platoon_env.scenarios.fingerprint.config_fingerprint`),
* the **overrides** fingerprint: the ``make()`` keyword arguments as given,
* the **seed** of ``reset``,
* the **measure**: the function that turned the episode into its metrics.

The content behind each fingerprint is kept in the ``policies``, ``scenarios`` and
``overrides`` tables, so a row can always be traced back to what it ran.

Safety rules:

* WAL journal, ``synchronous=FULL`` and one transaction per episode: a killed evaluator loses
  at most the episodes in flight, and a reader never sees half a row.
* Before running a cell, a run **claims** it (status ``running``, with its ``run_id``). Another
  run skips cells claimed by a live run and waits for them, for a bounded time
  (:func:`experiments.grid.run_grid`'s ``claim_timeout``); the claims of a run whose process
  is gone from this host (killed, crashed) are taken over at once. A claim of a run on another
  host, or of a stopped process, ends the wait with a :class:`ClaimTimeout` naming the holder
  and how to release it (:meth:`Store.release_run`, ``python -m experiments.store STORE
  --release RUN``). A finished row is never overwritten: two evaluators into one store give one
  row per episode.
* A claim of a run on another host (a copied store, or a container sharing the file) cannot be
  checked against a process: it is taken over once that run has written nothing to the store
  for :data:`FOREIGN_CLAIM_STALE` seconds (taking over a live run's cell only repeats work: the
  first finished row is kept, and an episode is a pure function of its key).
* Waiting for the write lock is bounded too (``timeout``, SQLite's busy timeout): then a
  :class:`StoreError` names the runs this store marks as running (the likely holders) and
  what to do, never a bare "database is locked".
* A file that is not an evaluation store (another SQLite database, a damaged one) is refused
  before anything is written into it; a damaged page or an unreadable row met later is a
  :class:`StoreError` naming the file (and the row), never a raw ``sqlite3`` error.
* Every row read back is validated before it is trusted (:meth:`Store.episodes`,
  :meth:`Store.runs`, :meth:`Store.scenario_config`, and the runs :meth:`Store.claim` looks
  at): each column's type, a JSON column an object, a run's status one of
  :data:`RUN_STATUSES` and its pid a process id, a finished episode of a measure in
  :data:`EPISODE_METRICS_MEASURES` holding every field of :data:`EPISODE_METRICS` with its
  type (those of :data:`EPISODE_METRICS_LATER` may be missing from older rows). A row that
  fails is one :class:`StoreError` naming the file, the row (its key) and the field, never a
  traceback from deep inside a report.
* ``failed`` rows (the episode raised) are retried by the next run; ``refused`` rows (the
  policy declined the configuration, e.g. the filtered PPC without a feasible funnel) are a
  result, like ``done``.

Schema version :data:`SCHEMA_VERSION` is in the ``meta`` table; a store of another version
is refused with the reason. ``docs/results.md`` describes the tables.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import socket
import sqlite3
import sys
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

__all__ = [
    "EPISODE_METRICS",
    "EPISODE_METRICS_LATER",
    "EPISODE_METRICS_MEASURES",
    "FINISHED",
    "FOREIGN_CLAIM_STALE",
    "MAX_PID",
    "RUN_STATUSES",
    "SCHEMA_VERSION",
    "STATUSES",
    "TABLES",
    "Claim",
    "ClaimTimeout",
    "EpisodeKey",
    "EpisodeRecord",
    "Store",
    "StoreError",
]

#: Version of the tables below; bump it (and migrate) when they change.
SCHEMA_VERSION = 1
#: Episode statuses. ``done`` and ``refused`` are results; ``failed`` is retried.
STATUSES: tuple[str, ...] = ("running", "done", "failed", "refused")
#: The statuses a run does not run again.
FINISHED: frozenset[str] = frozenset({"done", "refused"})
#: Run statuses: ``running`` until :meth:`Store.finish_run` records how it ended
#: (``finished``, ``interrupted``, ``failed``), or :meth:`Store.release_run` ``released`` it.
RUN_STATUSES: tuple[str, ...] = ("running", "finished", "interrupted", "failed", "released")
#: Largest process id a ``runs`` row may hold (``pid_t`` is a signed 32-bit integer).
MAX_PID = 2**31 - 1
#: [s] How long a run on another host may write nothing to the store (no claim, no result)
#: before its claims are taken over. This host cannot look at that run's process; a live
#: evaluator writes a row with every finished cell (episodes of this benchmark take seconds),
#: so five minutes of silence means it is gone (a copied store: its claims are as old as the
#: copy, and are taken over at once). Its times are that host's clock: a clock far behind
#: only makes a live run's cells run twice (the first finished row is kept).
FOREIGN_CLAIM_STALE = 300.0

#: The metrics of :func:`platoon_env.rollout.episode_metrics` (``docs/metrics.md``) and their
#: types: ``bool``, ``str``, ``count`` (an integer >= 0), ``number`` (an integer or a float;
#: ``inf``/``-inf``/``nan`` as :data:`NONFINITE` writes them). A finished (``done``) row of a
#: measure in :data:`EPISODE_METRICS_MEASURES` must hold each, of its type.
EPISODE_METRICS: dict[str, str] = {
    "success": "bool",
    "violation": "str",
    "time_to_violation": "number",
    "rms_e_d": "number",
    "rms_e_beta": "number",
    "max_abs_e_d": "number",
    "max_abs_e_beta": "number",
    "min_inter_robot_distance": "number",
    "min_obstacle_clearance": "number",
    "control_effort": "number",
    "peak_u": "number",
    "peak_omega": "number",
    "command_rate_u": "number",
    "command_rate_omega": "number",
    "steps": "count",
    "sim_time": "number",
    "leader_arrived": "bool",
    "lost_sight_steps": "count",
    "funnel_exits": "count",
    "path_fraction": "number",
    "min_margin_distance": "number",
    "min_margin_bearing": "number",
    "min_margin_clearance": "number",
    "min_margin_sight": "number",
}
#: The fields of :data:`EPISODE_METRICS` added after stores already held rows (the graded
#: metrics, platoon_env 0.2): a row written before them is valid without them (its reports
#: show "–"), and a row that holds them holds them of their type.
EPISODE_METRICS_LATER: frozenset[str] = frozenset(
    {
        "path_fraction",
        "min_margin_distance",
        "min_margin_bearing",
        "min_margin_clearance",
        "min_margin_sight",
    }
)
#: The measures whose metrics include :data:`EPISODE_METRICS` (the default measure and the
#: comparison's, which extend it); a row of another measure is checked for its shape only (a
#: JSON object), since only its measure knows its fields.
EPISODE_METRICS_MEASURES: frozenset[str] = frozenset(
    {
        "platoon_env.rollout:episode_metrics",
        "experiments.studies.comparison:comparison_metrics",
        "experiments.studies.comparison:fig15_metrics",
    }
)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS runs (
    run_id INTEGER PRIMARY KEY AUTOINCREMENT,
    tool TEXT NOT NULL,
    started REAL NOT NULL,
    finished REAL,
    status TEXT NOT NULL,
    pid INTEGER NOT NULL,
    host TEXT NOT NULL,
    proc_start TEXT NOT NULL,
    stamp TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS policies (
    fingerprint TEXT PRIMARY KEY,
    kind TEXT NOT NULL,
    description TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS scenarios (
    fingerprint TEXT PRIMARY KEY,
    config TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS overrides (
    fingerprint TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS episodes (
    policy TEXT NOT NULL REFERENCES policies (fingerprint),
    scenario TEXT NOT NULL REFERENCES scenarios (fingerprint),
    overrides TEXT NOT NULL REFERENCES overrides (fingerprint),
    seed INTEGER NOT NULL,
    measure TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('running', 'done', 'failed', 'refused')),
    run_id INTEGER NOT NULL REFERENCES runs (run_id),
    policy_name TEXT NOT NULL,
    scenario_name TEXT NOT NULL,
    updated REAL NOT NULL,
    wall_time REAL,
    metrics TEXT,
    error TEXT,
    PRIMARY KEY (policy, scenario, overrides, seed, measure)
);
"""


#: The tables of a store (``sqlite_sequence`` is SQLite's own, for ``AUTOINCREMENT``): a
#: database holding any other table is not an evaluation store, and is refused untouched.
TABLES: frozenset[str] = frozenset(
    {"meta", "runs", "policies", "scenarios", "overrides", "episodes", "sqlite_sequence"}
)


#: How a metric that is not a finite number is stored: JSON has no inf or NaN (SQLite's
#: ``json_extract`` refuses Python's ``Infinity``), so such a float is the string given here and
#: read back as the float. Rows written before hold ``Infinity``, which still reads.
NONFINITE: dict[str, float] = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


def _encode_nonfinite(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """``metrics`` with every non-finite float as its :data:`NONFINITE` string."""
    out: dict[str, Any] = {}
    for k, v in metrics.items():
        if isinstance(v, float) and not math.isfinite(v):
            v = "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        out[k] = v
    return out


def _decode_nonfinite(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The inverse of :func:`_encode_nonfinite`."""
    return {
        k: NONFINITE[v] if isinstance(v, str) and v in NONFINITE else v for k, v in metrics.items()
    }


def _shown(value: Any) -> str:
    """``value`` for an error message: its ``repr`` (control characters escaped), cut short."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _name(value: Any) -> str:
    """A name or fingerprint read from a row, for a message: as it is if it is plain printable
    text, else :func:`_shown` (a terminal escape sequence is never printed raw)."""
    if isinstance(value, str) and value.isprintable() and 0 < len(value) <= 80:
        return value
    return _shown(value)


def _short(value: Any) -> str:
    """A key field for a message: a fingerprint's first 12 characters, or :func:`_shown`."""
    return _name(value)[:12] if isinstance(value, str) and value.isprintable() else _shown(value)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_time(value: Any) -> bool:
    """A finite number >= 0 (a time stamp, a duration)."""
    return _is_number(value) and math.isfinite(value) and value >= 0


#: The test and the wording of each :data:`EPISODE_METRICS` type.
_KINDS: dict[str, tuple[Any, str]] = {
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "count": (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    "number": (_is_number, 'a number (or "inf", "-inf", "nan")'),
}


class _RowError(Exception):
    """A field of a row that fails validation (turned into a :class:`StoreError` naming the file
    and the row by :meth:`Store._invalid`)."""

    def __init__(self, field: str, expected: str, value: Any) -> None:
        super().__init__(f"its {field} must be {expected}, got {_shown(value)}")


def _require(ok: bool, field: str, expected: str, value: Any) -> None:
    if not ok:
        raise _RowError(field, expected, value)


def _check_episode_row(row: Mapping[str, Any]) -> None:
    """Validate the columns of an ``episodes`` row except its metrics (:func:`_check_metrics`);
    a failure is a :class:`_RowError` naming the field."""
    for field in ("policy", "scenario", "overrides", "measure"):
        _require(
            isinstance(row[field], str) and row[field] != "",
            field,
            "a non-empty string",
            row[field],
        )
    _require(_is_int(row["seed"]), "seed", "an integer", row["seed"])
    _require(row["status"] in STATUSES, "status", f"one of {', '.join(STATUSES)}", row["status"])
    _require(_is_int(row["run_id"]) and row["run_id"] > 0, "run_id", "a run number", row["run_id"])
    for field in ("policy_name", "scenario_name"):
        value = row[field]
        _require(
            isinstance(value, str) and value.isprintable(),
            field,
            "printable text (no control characters)",
            value,
        )
    _require(_is_time(row["updated"]), "updated", "a time (a finite number >= 0)", row["updated"])
    _require(
        row["wall_time"] is None or _is_time(row["wall_time"]),
        "wall_time",
        "empty or a duration (a finite number >= 0) [s]",
        row["wall_time"],
    )
    _require(
        row["error"] is None or isinstance(row["error"], str),
        "error",
        "empty or text",
        row["error"],
    )
    _require(
        row["metrics"] is None or isinstance(row["metrics"], str),
        "metrics",
        "empty or JSON text",
        row["metrics"],
    )


def _check_metrics(metrics: Any, status: str, measure: str) -> None:
    """Validate an episode's decoded metrics: a JSON object; a ``done`` row of a measure in
    :data:`EPISODE_METRICS_MEASURES` holds every :data:`EPISODE_METRICS` field, of its type."""
    _require(isinstance(metrics, dict), "metrics", "a JSON object", metrics)
    if status != "done" or measure not in EPISODE_METRICS_MEASURES:
        return
    for field, kind in EPISODE_METRICS.items():
        test, expected = _KINDS[kind]
        if field not in metrics and field in EPISODE_METRICS_LATER:
            continue
        if field not in metrics:
            raise _RowError(f"metrics.{field}", f"{expected} (the field is missing)", metrics)
        _require(test(metrics[field]), f"metrics.{field}", expected, metrics[field])


def _check_run_row(row: Mapping[str, Any]) -> None:
    """Validate the columns of a ``runs`` row except its stamp (a JSON object, checked where it
    is parsed); a failure is a :class:`_RowError` naming the field."""
    _require(_is_int(row["run_id"]) and row["run_id"] > 0, "run_id", "a run number", row["run_id"])
    _require(isinstance(row["tool"], str), "tool", "text", row["tool"])
    _require(_is_time(row["started"]), "started", "a time (a finite number >= 0)", row["started"])
    _require(
        row["finished"] is None or _is_time(row["finished"]),
        "finished",
        "empty or a time (a finite number >= 0)",
        row["finished"],
    )
    _require(
        row["status"] in RUN_STATUSES, "status", f"one of {', '.join(RUN_STATUSES)}", row["status"]
    )
    _require(
        _is_int(row["pid"]) and 0 < row["pid"] <= MAX_PID,
        "pid",
        f"a process id (an integer in [1, {MAX_PID}])",
        row["pid"],
    )
    _require(isinstance(row["host"], str) and row["host"] != "", "host", "a host name", row["host"])
    start = row["proc_start"]
    _require(
        isinstance(start, str) and (start == "" or start.isdigit()),
        "proc_start",
        "empty or a process start time (digits)",
        start,
    )
    _require(isinstance(row["stamp"], str), "stamp", "JSON text", row["stamp"])


class StoreError(RuntimeError):
    """A store that cannot be used: not a database, not ours, another schema version, damaged,
    locked too long, or a row that cannot be read."""


class ClaimTimeout(StoreError):
    """Cells held by another run that made no progress for the whole allowed wait; the
    message names each holder (run, tool, host, pid) and how to release its claims."""


class EpisodeKey(NamedTuple):
    """What identifies one episode of the store (fingerprints are hex SHA-256)."""

    policy: str
    scenario: str
    overrides: str
    seed: int
    measure: str


@dataclass(frozen=True)
class EpisodeRecord:
    """One row of ``episodes``: its key, status, the run that wrote it, the names the policy
    and scenario were given by that run, its metrics (a dict) or its error text."""

    key: EpisodeKey
    status: str
    run_id: int
    policy_name: str
    scenario_name: str
    updated: float
    wall_time: float | None
    metrics: dict[str, Any]
    error: str


@dataclass(frozen=True)
class Claim:
    """The outcome of :meth:`Store.claim`: keys now ours to run, keys already finished, and
    keys a live run is working on."""

    mine: tuple[EpisodeKey, ...]
    finished: tuple[EpisodeKey, ...]
    busy: tuple[EpisodeKey, ...]


def _proc_start(pid: int) -> str:
    """The start time of process ``pid`` (Linux: ``/proc/PID/stat`` field 22), "" where it
    cannot be read; with the pid it tells a live owner from a reused pid."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    return text.rsplit(")", 1)[1].split()[19]


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _proc_state(pid: int) -> str:
    """The state letter of process ``pid`` (``/proc/PID/stat`` field 3: ``T`` stopped, ``Z``
    zombie, ...), "" where it cannot be read."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    return text.rsplit(")", 1)[1].split()[0]


def _is_lock_error(exc: sqlite3.OperationalError) -> bool:
    """Whether SQLite gave up waiting for a lock (its busy timeout passed)."""
    text = str(exc).lower()
    return "locked" in text or "busy" in text


def _expected_columns() -> dict[str, list[tuple[Any, ...]]]:
    """Each table's ``PRAGMA table_info`` rows as :data:`_SCHEMA` creates them."""
    db = sqlite3.connect(":memory:")
    try:
        db.executescript(_SCHEMA)
        names = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
        return {n: [tuple(r) for r in db.execute(f"PRAGMA table_info({n})")] for n in names}
    finally:
        db.close()


def _foreign_objects(db: sqlite3.Connection) -> list[str]:
    """The schema objects of ``db`` that this module does not create: triggers, views and
    indexes (SQLite's own ``sqlite_autoindex_*`` excepted), and store tables whose columns
    differ from :data:`_SCHEMA`'s (a trigger or a column default runs SQL the store did not
    write: such a file is refused, never used)."""
    out: list[str] = []
    expected = _expected_columns()
    for kind, name in db.execute("SELECT type, name FROM sqlite_master"):
        if kind == "table" and name in TABLES:
            if name in expected:
                found = [tuple(r) for r in db.execute(f"PRAGMA table_info({name})")]
                if found != expected[name]:
                    out.append(f"table {name} (other columns)")
        elif kind == "index" and str(name).startswith("sqlite_autoindex_"):
            continue
        elif kind != "table":
            out.append(f"{kind} {name}")
    return out


def _check_own(db: sqlite3.Connection, path: Path) -> None:
    """Refuse, before anything is written, a database that is not an evaluation store (another
    program's tables, or any schema object the store does not create: :func:`_foreign_objects`)
    or is damaged (``PRAGMA quick_check``). Only reads."""
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    foreign = sorted(tables - TABLES)
    if not foreign:
        alien = _foreign_objects(db)
        if alien:
            raise StoreError(
                f"{path}: not an evaluation store as this code writes it: it holds "
                f"{', '.join(alien[:5])}; it was left untouched: give another path"
            )
    if tables and not foreign:
        try:
            versioned = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        except sqlite3.OperationalError:  # a "meta" table of another layout
            versioned = None
        foreign = [] if versioned is not None else sorted(tables)
    if foreign:
        shown = ", ".join(foreign[:8]) + (", ..." if len(foreign) > 8 else "")
        raise StoreError(
            f"{path}: not an evaluation store (an SQLite database with the tables {shown}); "
            "it was left untouched: give another path"
        )
    try:
        problems = [str(r[0]) for r in db.execute("PRAGMA quick_check").fetchall()]
    except sqlite3.DatabaseError as exc:  # too damaged to be checked
        problems = [str(exc)]
    if problems != ["ok"]:
        raise StoreError(
            f"{path}: the database is damaged ({'; '.join(problems[:3])}); it was left "
            "untouched: restore it from a copy, or give another path"
        )


class Store:
    """An evaluation store at ``path`` (created if absent); see the module docstring.

    One ``Store`` per process (the connection is not shared with workers: they return their
    results to the process that owns the store).
    """

    def __init__(self, path: str | Path, *, timeout: float = 120.0) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_file():
            raise StoreError(f"{self.path}: not a file")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(
                f"{self.path}: cannot create its folder {self.path.parent} ({exc.strerror or exc})"
            ) from None
        if not self.path.exists() and not os.access(self.path.parent, os.W_OK | os.X_OK):
            raise StoreError(
                f"{self.path}: cannot create the store ({self.path.parent} is not writable)"
            )
        self._timeout = timeout
        self._host = socket.gethostname()
        try:
            self._db = sqlite3.connect(self.path, timeout=timeout, isolation_level=None)
            self._db.row_factory = sqlite3.Row
            # Look before writing: the WAL pragma and the tables below change the file.
            _check_own(self._db, self.path)
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        except sqlite3.OperationalError as exc:  # the file could not be read or written
            message = self._lock_message(exc) if _is_lock_error(exc) else None
            self._close_quietly()
            raise StoreError(
                message
                or f"{self.path}: cannot open the store ({exc}): is its disk full, or the file "
                "or its folder read-only?"
            ) from None
        except sqlite3.DatabaseError as exc:
            self._close_quietly()
            raise StoreError(f"{self.path}: not an evaluation store ({exc})") from None
        except StoreError:
            self._close_quietly()
            raise
        if str(mode).lower() != "wal":
            raise StoreError(f"{self.path}: SQLite refused the WAL journal (got {mode!r})")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA foreign_keys=ON")  # a no-op inside a transaction
        with self.transaction():
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    self._db.execute(statement)
            row = self._db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
            if row is None:
                self._db.execute(
                    "INSERT INTO meta (key, value) VALUES ('schema_version', ?), ('created', ?)",
                    (str(SCHEMA_VERSION), time.strftime("%Y-%m-%dT%H:%M:%S%z")),
                )
            elif row["value"] != str(SCHEMA_VERSION):
                raise StoreError(
                    f"{self.path}: schema version {row['value']}, this code reads version "
                    f"{SCHEMA_VERSION}; use another output folder or the matching platoon_env"
                )

    def close(self) -> None:
        """Close the connection."""
        self._db.close()

    def _close_quietly(self) -> None:
        db = getattr(self, "_db", None)
        if db is not None:
            db.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _errors(self) -> Iterator[None]:
        """SQLite's errors as a :class:`StoreError` naming the file (a damaged page, a full disk,
        a lock held too long)."""
        try:
            yield
        except sqlite3.OperationalError as exc:
            if _is_lock_error(exc):
                raise StoreError(self._lock_message(exc)) from None
            raise StoreError(f"{self.path}: {exc}") from None
        except sqlite3.DatabaseError as exc:
            raise StoreError(
                f"{self.path}: the database is damaged ({exc}); restore it from a copy, or use "
                "another path"
            ) from None

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` (``ROLLBACK`` on an exception): the write lock is
        taken at the start, so two writers queue instead of failing half-way."""
        try:
            self._db.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            if _is_lock_error(exc):
                raise StoreError(self._lock_message(exc)) from None
            raise StoreError(f"{self.path}: could not lock the store ({exc})") from None
        with self._errors():
            try:
                yield self._db
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise
            else:
                self._db.execute("COMMIT")

    def _rows(self, sql: str, params: Sequence[Any] = ()) -> list[sqlite3.Row]:
        """The rows of a read (errors as :class:`StoreError`)."""
        with self._errors():
            return self._db.execute(sql, params).fetchall()

    def _json(self, text: str | None, what: str) -> Any:
        """A JSON column's value; a value that does not parse is a :class:`StoreError` naming
        the row (``what``) and the file."""
        if not text:
            return None
        try:
            return json.loads(text)
        except (ValueError, RecursionError) as exc:
            why = "nested too deep" if isinstance(exc, RecursionError) else str(exc)
            raise StoreError(
                f"{self.path}: {what} is not readable JSON ({why}); it was not written by this "
                "code: delete the row (sqlite3) to run it again"
            ) from None

    def _invalid(self, what: str, exc: _RowError) -> StoreError:
        """The :class:`StoreError` of a row that failed validation: the file, the row
        (``what``: its table and key) and the field."""
        return StoreError(
            f"{self.path}: {what}: {exc}; this code did not write it: delete the row (sqlite3), "
            "or use another store"
        )

    def _lock_message(self, exc: sqlite3.OperationalError) -> str:
        """Why the write lock was not had within the busy timeout, naming the runs this store
        marks as running (SQLite does not record who holds its lock: one of them, or another
        program with the file open) and what to do."""
        lines = []
        try:
            rows = self._db.execute(
                "SELECT run_id, tool, host, pid FROM runs WHERE status = 'running' ORDER BY run_id"
            ).fetchall()
        except sqlite3.DatabaseError:  # the file cannot even be read now
            rows = []
        for r in rows[:8]:
            where = "this host" if r["host"] == self._host else f"host {_name(r['host'])}"
            lines.append(f"  run {r['run_id']} ({_name(r['tool'])}, {where}, pid {r['pid']})")
        held = (
            "the runs it marks as running:\n" + "\n".join(lines)
            if lines
            else "no run of it is marked as running"
        )
        return (
            f"{self.path}: could not lock the store within {self._timeout:g} s ({exc}): another "
            f"connection holds it; {held}\nWait for that run to finish and try again, or end it; "
            "if none is running, another program (an sqlite3 shell?) has the file open: close it"
        )

    # --- runs ---------------------------------------------------------------------------------

    def begin_run(self, tool: str, stamp: Mapping[str, Any]) -> int:
        """Record a run of this process; returns its ``run_id``."""
        pid = os.getpid()
        with self.transaction() as db:
            cur = db.execute(
                "INSERT INTO runs (tool, started, status, pid, host, proc_start, stamp) "
                "VALUES (?, ?, 'running', ?, ?, ?, ?)",
                (tool, time.time(), pid, self._host, _proc_start(pid), json.dumps(stamp)),
            )
        assert cur.lastrowid is not None
        return int(cur.lastrowid)

    def finish_run(self, run_id: int, status: str) -> None:
        """End a run (``finished``, ``interrupted``, ``failed``): its unfinished claims are
        released, so that the next run takes them at once."""
        if status not in RUN_STATUSES[1:]:
            raise ValueError(f"status must be one of {', '.join(RUN_STATUSES[1:])}, got {status!r}")
        with self.transaction() as db:
            db.execute("DELETE FROM episodes WHERE run_id = ? AND status = 'running'", (run_id,))
            db.execute(
                "UPDATE runs SET finished = ?, status = ? WHERE run_id = ?",
                (time.time(), status, run_id),
            )

    def runs(self, run_ids: Iterable[int] | None = None) -> list[dict[str, Any]]:
        """The ``runs`` rows (all, or those of ``run_ids``), their stamps parsed, each with its
        ``state``: the stored ``status``, except ``killed`` for a ``running`` run whose process
        is gone from this host (``kill -9``, a crash: it never recorded its end)."""
        rows = self._rows("SELECT * FROM runs ORDER BY run_id")
        wanted = None if run_ids is None else set(run_ids)
        out = []
        for row in rows:
            r = dict(row)
            if wanted is not None and r["run_id"] not in wanted:
                continue
            self._check_run(r)
            out.append({**r, "stamp": self._stamp(r), "state": self._run_state(r)})
        return out

    def _check_run(self, run: Mapping[str, Any]) -> None:
        """Validate a ``runs`` row (:func:`_check_run_row`) before it is used."""
        try:
            _check_run_row(run)
        except _RowError as exc:
            raise self._invalid(f"the runs row of run {_shown(run['run_id'])}", exc) from None

    def _stamp(self, run: Mapping[str, Any]) -> dict[str, Any]:
        """The parsed stamp of a (checked) ``runs`` row: a JSON object."""
        stamp = self._json(run["stamp"], f"the stamp of run {run['run_id']}")
        try:
            _require(isinstance(stamp, dict), "stamp", "a JSON object", stamp)
        except _RowError as exc:
            raise self._invalid(f"the runs row of run {run['run_id']}", exc) from None
        out: dict[str, Any] = stamp
        return out

    def _run_state(self, run: Mapping[str, Any]) -> str:
        """``running``, ``killed`` (a running run gone from this host), ``stale`` (a running run
        of another host silent for :data:`FOREIGN_CLAIM_STALE`), ``stopped`` (its process is
        stopped, e.g. by Ctrl-Z or ``kill -STOP``), or the status it recorded."""
        if run["status"] != "running":
            return str(run["status"])
        if not self._run_alive(run):
            return "killed" if run["host"] == self._host else "stale"
        if run["host"] == self._host and _proc_state(int(run["pid"])) == "T":
            return "stopped"
        return "running"

    def _run_alive(self, run: Mapping[str, Any]) -> bool:
        """Whether the run that holds a claim may still finish it (a checked ``runs`` row)."""
        if run["status"] != "running":
            return False
        if run["host"] != self._host:
            # Another machine's processes cannot be looked at: trust the run while it writes.
            return time.time() - self._last_write(run) < FOREIGN_CLAIM_STALE
        pid = int(run["pid"])
        if not _pid_alive(pid) or _proc_state(pid) == "Z":
            return False
        start = _proc_start(pid)
        return not (start and run["proc_start"] and start != run["proc_start"])

    def _last_write(self, run: Mapping[str, Any]) -> float:
        """When run ``run`` last wrote to the store (its start, a claim, a result), by its
        host's clock."""
        with self._errors():
            row = self._db.execute(
                "SELECT MAX(updated) AS t FROM episodes WHERE run_id = ?", (run["run_id"],)
            ).fetchone()
        last = row["t"] if row is not None and _is_time(row["t"]) else 0.0
        return max(float(run["started"]), float(last))

    def holders(self, keys: Iterable[EpisodeKey]) -> list[dict[str, Any]]:
        """The runs holding claims (``running`` rows) on ``keys``: each run's row (with its
        ``state``, as :meth:`runs`) and ``held``, how many of ``keys`` it holds."""
        held: dict[int, int] = {}
        for key in keys:
            for r in self._rows(
                "SELECT run_id FROM episodes WHERE policy = ? AND scenario = ? AND overrides = ? "
                "AND seed = ? AND measure = ? AND status = 'running'",
                key,
            ):
                held[r["run_id"]] = held.get(r["run_id"], 0) + 1
        return [{**run, "held": held[run["run_id"]]} for run in self.runs(held)]

    def holders_message(self, keys: Iterable[EpisodeKey], waited: float) -> str:
        """Why the cells of ``keys`` cannot be run yet, and how to release them: a line per
        holding run (run, tool, host, pid, state)."""
        lines = []
        for run in self.holders(keys):
            where = "this host" if run["host"] == self._host else f"host {_name(run['host'])}"
            why = {
                "stopped": f"its process is stopped: `kill -CONT {run['pid']}` lets it go on",
                "running": (
                    "it is running on this host: wait for it, or end it"
                    if run["host"] == self._host
                    else "this host cannot see whether it is still alive (a copied store?); "
                    f"it last wrote {time.time() - self._last_write(run):.0f} s ago, and its "
                    f"claims are taken over after {FOREIGN_CLAIM_STALE:.0f} s of silence"
                ),
            }.get(run["state"], run["state"])
            lines.append(
                f"  run {run['run_id']} ({_name(run['tool'])}, {where}, pid {run['pid']}, started "
                f"{time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(run['started']))}) holds "
                f"{run['held']} cell(s): {why}"
            )
        release = f"python -m experiments.store {shlex.quote(str(self.path))}"
        return (
            f"{self.path}: cells held by another run made no progress for {waited:.0f} s:\n"
            + "\n".join(lines)
            + f"\nIf that run is gone, release its claims: {release} --release RUN_ID "
            "(its unfinished cells are then run by the next evaluator)"
        )

    def release_run(self, run_id: int) -> int:
        """Release the claims of run ``run_id`` (gone, on another host, or stopped for good):
        its ``running`` rows are dropped, and a run still marked ``running`` becomes
        ``released``. Returns the number of claims dropped; finished rows are kept."""
        with self.transaction() as db:
            if db.execute("SELECT 1 FROM runs WHERE run_id = ?", (run_id,)).fetchone() is None:
                raise StoreError(f"{self.path}: no run {run_id}")
            cur = db.execute(
                "DELETE FROM episodes WHERE run_id = ? AND status = 'running'", (run_id,)
            )
            db.execute(
                "UPDATE runs SET status = 'released', finished = ? "
                "WHERE run_id = ? AND status = 'running'",
                (time.time(), run_id),
            )
        return cur.rowcount

    # --- what the fingerprints stand for ------------------------------------------------------

    def register(
        self,
        policies: Mapping[str, tuple[str, Mapping[str, Any]]],
        scenarios: Mapping[str, Mapping[str, Any]],
        overrides: Mapping[str, Mapping[str, Any]],
    ) -> None:
        """Store what each fingerprint stands for: ``{fp: (kind, description)}`` of the
        policies, ``{fp: config mapping}`` of the scenarios, ``{fp: overrides}``."""
        with self.transaction() as db:
            db.executemany(
                "INSERT OR IGNORE INTO policies (fingerprint, kind, description) VALUES (?, ?, ?)",
                [
                    (fp, kind, json.dumps(desc, sort_keys=True))
                    for fp, (kind, desc) in policies.items()
                ],
            )
            db.executemany(
                "INSERT OR IGNORE INTO scenarios (fingerprint, config) VALUES (?, ?)",
                [(fp, json.dumps(cfg, sort_keys=True)) for fp, cfg in scenarios.items()],
            )
            db.executemany(
                "INSERT OR IGNORE INTO overrides (fingerprint, value) VALUES (?, ?)",
                [(fp, json.dumps(ov, sort_keys=True)) for fp, ov in overrides.items()],
            )

    def scenario_config(self, fingerprint: str) -> dict[str, Any]:
        """The resolved config a scenario fingerprint stands for."""
        rows = self._rows("SELECT config FROM scenarios WHERE fingerprint = ?", (fingerprint,))
        if not rows:
            raise KeyError(fingerprint)
        what = f"the scenarios row of {_name(fingerprint)}"
        config = self._json(rows[0]["config"], what)
        try:
            _require(isinstance(config, dict), "config", "a JSON object", config)
        except _RowError as exc:
            raise self._invalid(what, exc) from None
        out: dict[str, Any] = config
        return out

    # --- episodes -----------------------------------------------------------------------------

    def claim(
        self, keys: Sequence[EpisodeKey], run_id: int, names: Mapping[EpisodeKey, tuple[str, str]]
    ) -> Claim:
        """Claim the unfinished ``keys`` for ``run_id`` in one transaction.

        A key without a row, with a ``failed`` row, or claimed by a run that is gone becomes
        ours; a finished key is reported as such; a key claimed by a live run is ``busy``.
        ``names`` gives each key's (policy name, scenario name) for the row.
        """
        mine: list[EpisodeKey] = []
        finished: list[EpisodeKey] = []
        busy: list[EpisodeKey] = []
        now = time.time()
        with self.transaction() as db:
            runs = {r["run_id"]: dict(r) for r in db.execute("SELECT * FROM runs").fetchall()}
            alive: dict[int, bool] = {}
            for key in keys:
                row = db.execute(
                    "SELECT status, run_id FROM episodes WHERE policy = ? AND scenario = ? "
                    "AND overrides = ? AND seed = ? AND measure = ?",
                    key,
                ).fetchone()
                if row is not None and row["status"] in FINISHED:
                    finished.append(key)
                    continue
                if row is not None and row["status"] == "running" and row["run_id"] != run_id:
                    owner = row["run_id"]
                    if owner not in alive:
                        if owner in runs:
                            self._check_run(runs[owner])
                        alive[owner] = owner in runs and self._run_alive(runs[owner])
                    if alive[owner]:
                        busy.append(key)
                        continue
                policy_name, scenario_name = names[key]
                db.execute(
                    "INSERT INTO episodes (policy, scenario, overrides, seed, measure, status, "
                    "run_id, policy_name, scenario_name, updated) "
                    "VALUES (?, ?, ?, ?, ?, 'running', ?, ?, ?, ?) "
                    "ON CONFLICT DO UPDATE SET status = 'running', run_id = excluded.run_id, "
                    "policy_name = excluded.policy_name, scenario_name = excluded.scenario_name, "
                    "updated = excluded.updated, metrics = NULL, error = NULL, wall_time = NULL",
                    (*key, run_id, policy_name, scenario_name, now),
                )
                mine.append(key)
        return Claim(tuple(mine), tuple(finished), tuple(busy))

    def record(
        self,
        key: EpisodeKey,
        run_id: int,
        status: str,
        *,
        metrics: Mapping[str, Any] | None = None,
        error: str = "",
        wall_time: float | None = None,
        names: tuple[str, str] = ("", ""),
    ) -> bool:
        """Write the outcome of one episode (its own transaction). A row another run has
        already finished is kept (returns False); else the row is written (True)."""
        if status not in STATUSES or status == "running":
            raise ValueError(f"status must be one of done, failed, refused, got {status!r}")
        text = json.dumps(_encode_nonfinite(dict(metrics or {})), sort_keys=True, allow_nan=False)
        with self.transaction() as db:
            cur = db.execute(
                "INSERT INTO episodes (policy, scenario, overrides, seed, measure, status, run_id, "
                "policy_name, scenario_name, updated, wall_time, metrics, error) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT DO UPDATE SET status = excluded.status, run_id = excluded.run_id, "
                "updated = excluded.updated, wall_time = excluded.wall_time, "
                "metrics = excluded.metrics, error = excluded.error "
                "WHERE episodes.status NOT IN ('done', 'refused')",
                (*key, status, run_id, *names, time.time(), wall_time, text, error),
            )
        return cur.rowcount > 0

    def release(self, keys: Iterable[EpisodeKey], run_id: int) -> None:
        """Drop this run's claims on ``keys`` (episodes it will not run after all)."""
        with self.transaction() as db:
            db.executemany(
                "DELETE FROM episodes WHERE policy = ? AND scenario = ? AND overrides = ? "
                "AND seed = ? AND measure = ? AND run_id = ? AND status = 'running'",
                [(*k, run_id) for k in keys],
            )

    def episodes(self, keys: Iterable[EpisodeKey] | None = None) -> dict[EpisodeKey, EpisodeRecord]:
        """The rows of ``keys`` that exist (all rows if None), by key."""
        if keys is None:
            rows = self._rows("SELECT * FROM episodes")
        else:
            rows = []
            for key in keys:
                rows += self._rows(
                    "SELECT * FROM episodes WHERE policy = ? AND scenario = ? AND overrides = ? "
                    "AND seed = ? AND measure = ?",
                    key,
                )
        out = {}
        for r in rows:
            metrics = self._episode_metrics(dict(r))
            key = EpisodeKey(r["policy"], r["scenario"], r["overrides"], r["seed"], r["measure"])
            out[key] = EpisodeRecord(
                key=key,
                status=r["status"],
                run_id=r["run_id"],
                policy_name=r["policy_name"],
                scenario_name=r["scenario_name"],
                updated=r["updated"],
                wall_time=r["wall_time"],
                metrics=metrics,
                error=r["error"] or "",
            )
        return out

    def _episode_metrics(self, row: Mapping[str, Any]) -> dict[str, Any]:
        """Validate an ``episodes`` row (:func:`_check_episode_row`, :func:`_check_metrics`)
        and return its metrics, decoded (:func:`_decode_nonfinite`)."""
        key = ", ".join(
            f"{field} {_short(row[field])}" for field in ("policy", "scenario", "overrides", "seed")
        )
        key += f", measure {_name(row['measure'])}"
        episode = (
            f"the episode of {_name(row['policy_name'])} on {_name(row['scenario_name'])}, seed "
            f"{_shown(row['seed'])} ({key})"
        )
        what = f"the episodes row of {episode}"
        try:
            _check_episode_row(row)
            metrics = self._json(row["metrics"], f"the metrics of {episode}")
            if metrics is None:
                metrics = {}
            _require(isinstance(metrics, dict), "metrics", "a JSON object", metrics)
            metrics = _decode_nonfinite(metrics)
            _check_metrics(metrics, row["status"], row["measure"])
        except _RowError as exc:
            raise self._invalid(what, exc) from None
        return metrics

    def counts(self) -> dict[str, int]:
        """Episodes per status over the whole store."""
        rows = self._rows("SELECT status, COUNT(*) AS n FROM episodes GROUP BY status")
        return {r["status"]: r["n"] for r in rows}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m experiments.store STORE [--release RUN_ID]``: list the runs of a store (state,
    host, pid, claims held) or release the claims of one (a run gone for good: killed on
    another host, a copied store, a stopped process)."""
    parser = argparse.ArgumentParser(prog="python -m experiments.store", description=main.__doc__)
    parser.add_argument("store", type=Path, help="the store (an .sqlite file)")
    parser.add_argument("--release", type=int, metavar="RUN_ID", help="drop the claims of this run")
    args = parser.parse_args(argv)
    if not args.store.is_file():
        parser.error(f"{args.store}: no such store file")
    try:
        with Store(args.store) as store:
            if args.release is not None:
                n = store.release_run(args.release)
                print(f"{store.path}: released {n} claim(s) of run {args.release}")
                return 0
            held = {
                r["run_id"]: r["n"]
                for r in store._rows(
                    "SELECT run_id, COUNT(*) AS n FROM episodes WHERE status = 'running' "
                    "GROUP BY run_id"
                )
            }
            for run in store.runs():
                print(
                    f"run {run['run_id']}: {run['tool']} {run['state']}, host {run['host']}, "
                    f"pid {run['pid']}, {held.get(run['run_id'], 0)} claim(s) held"
                )
    except StoreError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
