"""Command-line pieces every driver shares: the parser, counts, numbers, the grid's options
and the rule for a store that fails.

Every error in an option is an ``argparse.ArgumentTypeError``, so argparse reports it as a usage
error (exit 2) naming the option, before anything is written. Numbers are read as YAML reads
them (``5e-2``, ``1e3``), so a value that works in a scenario file works on the command line.
A store that cannot be opened, or fails during the run, is one line ``TOOL: error: ...`` and
an exit code (:func:`open_store`), never a traceback.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from experiments.store import Store, StoreError

if TYPE_CHECKING:
    from experiments.grid import GridResult

__all__ = [
    "add_batch_option",
    "add_grid_options",
    "add_models_option",
    "add_workers_option",
    "count",
    "failed_episodes",
    "new_parser",
    "number",
    "open_store",
]


def new_parser(prog: str, doc: str | None, *, out: Path | None = None) -> argparse.ArgumentParser:
    """A driver's parser: named ``prog``, its description the driver's module docstring ``doc``
    (its layout kept), and, when ``out`` is given, ``--out`` (the output folder, default
    ``out``) as its first option."""
    p = argparse.ArgumentParser(
        prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    if out is not None:
        p.add_argument("--out", type=Path, default=out, help="output folder")
    return p


def number(text: str) -> float:
    """A finite number as YAML writes it (``0.05``, ``5e-2``, ``1_000``)."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


#: The largest integer a count may be: SQLite's (and the store's) signed 64-bit integers.
INT64_MAX = 2**63 - 1


def count(minimum: int = 1, name: str = "count", maximum: int = INT64_MAX) -> Callable[[str], int]:
    """An argparse ``type``: a whole number in ``[minimum, maximum]`` (``20``, ``2e1`` and
    ``20.0`` read 20; ``2.5`` is refused). An integer literal is read as an integer, never
    through a float (``9007199254740993`` stays itself); a float form is taken only where
    floats are exact (below 2**53)."""

    def parse(text: str) -> int:
        stripped = text.strip().replace("_", "")
        literal = re.fullmatch(r"[+-]?[0-9]+", stripped) is not None
        if literal:
            try:
                value = int(stripped)
            except ValueError:  # more digits than Python reads (4,300): beyond any bound
                bound = f">= {minimum}" if stripped.startswith("-") else f"<= {maximum}"
                raise argparse.ArgumentTypeError(
                    f"must be {bound}, got a number of {len(stripped)} digits"
                ) from None
        else:
            try:
                as_float = number(text)
            except argparse.ArgumentTypeError:
                raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
            if as_float != int(as_float):
                raise argparse.ArgumentTypeError(f"{text!r} is not a whole number")
            if abs(as_float) >= 2**53:
                raise argparse.ArgumentTypeError(
                    f"{text!r}: write integers this large in digits (a float is not exact)"
                )
            value = int(as_float)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {text}")
        if value > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum}, got {text}")
        return value

    parse.__name__ = name  # argparse names the type in its messages
    return parse


def add_workers_option(
    parser: argparse.ArgumentParser,
    text: str = "parallel worker processes (1: run in this process)",
) -> None:
    """Add ``--workers`` (default 2): how many processes run the episodes at once; ``text`` is
    its help."""
    parser.add_argument("--workers", type=count(1, "workers"), default=2, help=text)


def add_batch_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--batch N`` (default 0): run each policy's episodes on one task as chunks of up to
    ``N`` copies of one batched core (``run_grid(batch=N)``, :mod:`experiments.batched_eval`;
    the same metrics, to the bit); 0 or 1: one episode at a time."""
    parser.add_argument(
        "--batch",
        type=count(0, "batch"),
        metavar="N",
        default=0,
        help="run each policy's episodes on one task as chunks of up to N copies of one "
        "batched core, a chunk per worker job (the same results, to the bit; faster); "
        "0 or 1: one episode per job (default: 0)",
    )


def add_models_option(parser: argparse.ArgumentParser, use: str) -> None:
    """Add ``--models`` (default None: :func:`experiments.policies.default_models_dir`), the
    folder of trained models, ``use`` saying what the driver does with them."""
    parser.add_argument(
        "--models",
        type=Path,
        default=None,
        help=f"folder of models (DIR/*/model.zip) {use}; default: the source checkout's "
        "models/ (never ./models unless named: loading a model unpickles code)",
    )


def add_grid_options(
    parser: argparse.ArgumentParser, *, seeds: int | None, seeds_help: str, store: Path | None
) -> None:
    """Add ``--seeds`` (default ``seeds``), ``--workers`` (default 2) and, when ``store`` is
    given, ``--store`` (the evaluation store the episodes go to and resume from)."""
    parser.add_argument("--seeds", type=count(1, "seeds"), default=seeds, help=seeds_help)
    add_workers_option(parser, "parallel worker processes")
    if store is not None:
        parser.add_argument(
            "--store",
            type=Path,
            default=store,
            help=f"the evaluation store the episodes go to and resume from (default: {store})",
        )


def failed_episodes(result: GridResult) -> int:
    """A driver's exit code after its grid: 0, or 1 when episodes failed (one line on stderr
    says how many; the next run of the same command retries them)."""
    if not result.failed:
        return 0
    print(f"{len(result.failed)} episode(s) failed; re-run to retry them", file=sys.stderr)
    return 1


def _fail(tool: str, exc: StoreError, code: int) -> NoReturn:
    print(f"{tool}: error: {exc}", file=sys.stderr)
    raise SystemExit(code)


@contextmanager
def open_store(tool: str, path: Path) -> Iterator[Store]:
    """The evaluation store at ``path`` for a driver's run, closed at the end. A store that
    cannot be opened (not a store, not ours, damaged) ends the process with exit code 2 before
    any work, a store error during the run (a :class:`~experiments.store.ClaimTimeout`, a
    store damaged mid-run) with exit code 1; each after the one line ``TOOL: error: ...`` on
    stderr, the message naming the file."""
    try:
        store = Store(path)
    except StoreError as exc:
        _fail(tool, exc, 2)
    try:
        with store:
            yield store
    except StoreError as exc:
        _fail(tool, exc, 1)
