"""Exports of the store: statistics, CSV files, and the provenance lines of a table's header.

The CSV files and markdown summaries the drivers write are *exports*: made from the store's
rows at the end of a run (atomically: a reader never sees half a file), with headers counted
from those rows, never from what the command line asked for.
"""

from __future__ import annotations

import csv
import hashlib
import math
import os
import re
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from experiments.significance import wilson
from experiments.stamp import stamp_markdown
from experiments.store import EpisodeRecord, Store

__all__ = [
    "atomic_file",
    "file_stem",
    "format_value",
    "markdown_table",
    "mean_ci",
    "provenance_markdown",
    "seed_ranges",
    "wilson",
    "write_csv",
    "write_csv_stamp",
    "write_text_atomic",
]


#: Characters a file-name stem keeps; every other run of characters becomes ``_``.
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")
#: The longest stem :func:`file_stem` gives (file systems allow 255 bytes per name; room is
#: left for the suffixes the drivers add).
MAX_STEM = 80


def file_stem(name: str) -> str:
    """The file-name stem of a display name (a policy, a scenario, a condition): the one rule for
    every name that becomes part of a file name.

    Only ASCII letters, digits, ``_``, ``.`` and ``-``; never empty, never starting with ``.``
    (no ``..``, no hidden file), at most :data:`MAX_STEM` characters; so it never leaves the
    folder it is joined to. A name that had to change gets 8 hex digits of its SHA-256, so that
    two distinct names never share a file.
    """
    stem = _UNSAFE.sub("_", name).lstrip(".")[:MAX_STEM]
    if stem == name and stem:
        return stem
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    return f"{stem[: MAX_STEM - 9] or 'x'}-{digest}"


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    """A Markdown table: the ``header`` row, its rule, then one line per row (each cell
    ``str()``-ed); a row whose length differs from the header's is a ``ValueError``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        if len(row) != len(header):
            raise ValueError(f"a row of {len(row)} cells under a header of {len(header)}: {row}")
        lines.append("| " + " | ".join(str(c) for c in row) + " |")
    return "\n".join(lines)


def mean_ci(values: Sequence[float], z: float = 1.96) -> str:
    """``mean ± half-width`` of a normal-approximation 95 % interval of the finite values
    (``–`` if there are none; the value alone for one)."""
    vals = np.array([v for v in values if math.isfinite(v)], dtype=float)
    if vals.size == 0:
        return "–"
    if vals.size == 1:
        return f"{vals[0]:.3f}"
    half = z * float(np.std(vals, ddof=1)) / math.sqrt(vals.size)
    return f"{np.mean(vals):.3f} ± {half:.3f}"


def seed_ranges(seeds: Iterable[int]) -> str:
    """``0..4, 7, 9..10`` for the seeds ``{0, 1, 2, 3, 4, 7, 9, 10}`` ("none" if empty)."""
    values = sorted(set(seeds))
    if not values:
        return "none"
    parts = []
    lo = prev = values[0]
    for s in [*values[1:], None]:
        if s is not None and s == prev + 1:
            prev = s
            continue
        parts.append(str(lo) if lo == prev else f"{lo}..{prev}")
        if s is not None:
            lo = prev = s
    return ", ".join(parts)


def format_value(value: Any) -> str:
    """A CSV cell: floats in 6 significant digits (``inf``, ``-inf``, ``nan`` spelled out)."""
    if isinstance(value, bool) or value is None:
        return "" if value is None else str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.6g}"
    return str(value)


@contextmanager
def atomic_file(path: Path, newline: str | None = None) -> Iterator[TextIO]:
    """A text file (UTF-8) that appears at ``path`` whole or not at all: written to a temporary
    file in the same folder, flushed to disk, then renamed over ``path``. A symbolic link at
    ``path`` is replaced by the file, never followed; an error (a full disk, an exception in
    the ``with`` block) removes the temporary file and leaves ``path`` as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline=newline) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; outputs are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through :func:`atomic_file`; returns ``path``."""
    with atomic_file(path) as f:
        f.write(text)
    return Path(path)


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Mapping[str, Any]]) -> int:
    """Write ``rows`` to ``path`` atomically (:func:`atomic_file`); returns the number of
    rows. Missing values are empty cells."""
    n = 0
    with atomic_file(path, newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: format_value(row.get(k)) for k in columns})
            n += 1
    return n


def write_csv_stamp(
    csv_path: Path, store: Store, records: Iterable[EpisodeRecord], this_run: int
) -> Path:
    """``CSV.meta.json`` beside an exported CSV: the stamp of every run whose rows it holds
    (code, versions, command, host), by ``run_id`` (the CSV's ``run_id`` column), and the
    store it was exported from. A CSV cannot carry its provenance in a comment that every
    reader accepts; this file does."""
    import json

    used = sorted({rec.run_id for rec in records} | {this_run})
    runs = {r["run_id"]: r for r in store.runs(used)}
    meta = {
        "exported_by_run": this_run,
        "store": str(store.path),
        "runs": {str(k): runs[k] for k in used if k in runs},
    }
    path = csv_path.with_name(csv_path.name + ".meta.json")
    return write_text_atomic(path, json.dumps(meta, indent=2, sort_keys=True) + "\n")


def provenance_markdown(store: Store, records: Iterable[EpisodeRecord], this_run: int) -> str:
    """Markdown lines saying which runs (code, versions, command) made ``records``: the
    stamp of this run, then one line per earlier run whose rows are in the table."""
    runs = {r["run_id"]: r for r in store.runs()}
    used: dict[int, int] = {}
    for rec in records:
        used[rec.run_id] = used.get(rec.run_id, 0) + 1
    lines = []
    if this_run in runs:
        lines.append(stamp_markdown(runs[this_run]["stamp"]))
    earlier = sorted(k for k in used if k != this_run)
    # The code versions of the rows: this run's only where it wrote some (a table redrawn from
    # rows of one earlier version is not mixed).
    commits = {
        str(runs[k]["stamp"].get("commit", "?"))[:12]
        + ("+" if runs[k]["stamp"].get("modified") else "")
        for k in used
        if k in runs
    }
    lines.append(
        f"- rows: {used.get(this_run, 0)} from this run (run {this_run}), "
        f"{sum(used[k] for k in earlier)} from {len(earlier)} earlier run(s) of this store"
    )
    for k in earlier:
        if k in runs:
            st = runs[k]["stamp"]
            dirty = " + uncommitted changes" if st.get("modified") else ""
            state = runs[k].get("state", runs[k]["status"])
            if state == "killed":
                state = "killed: its process is gone and it never recorded its end"
            lines.append(
                f"  - run {k} ({state}, {st.get('time', '?')}, code "
                f"{str(st.get('commit', '?'))[:12]}{dirty}): {used[k]} rows"
            )
    if len(commits) > 1:
        lines.append(
            f"- **warning**: the rows come from {len(commits)} code versions "
            f"({', '.join(sorted(commits))}); results may not be comparable"
        )
    return "\n".join(line.rstrip("\n") for line in lines) + "\n"
