"""Command-line pieces every driver shares: counts, numbers and the grid's options.

Every error is an ``argparse.ArgumentTypeError``, so argparse reports it as a usage error
(exit 2) naming the option, before anything is written. Numbers are read as YAML reads them
(``5e-2``, ``1e3``), so a value that works in a scenario file works on the command line.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

__all__ = ["add_grid_options", "count", "number"]


def number(text: str) -> float:
    """A finite number as YAML writes it (``0.05``, ``5e-2``, ``1_000``)."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def count(minimum: int = 1, name: str = "count") -> Callable[[str], int]:
    """An argparse ``type``: a whole number ``>= minimum`` (``20``, ``2e1`` and ``20.0`` read 20;
    ``2.5`` is refused)."""

    def parse(text: str) -> int:
        try:
            value = number(text)
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value != int(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number")
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {text}")
        return int(value)

    parse.__name__ = name  # argparse names the type in its messages
    return parse


def add_grid_options(
    parser: argparse.ArgumentParser, *, seeds: int | None, seeds_help: str, store: Path | None
) -> None:
    """Add ``--seeds`` (default ``seeds``), ``--workers`` (default 2) and, when ``store`` is
    given, ``--store`` (the evaluation store the episodes go to and resume from)."""
    parser.add_argument("--seeds", type=count(1, "seeds"), default=seeds, help=seeds_help)
    parser.add_argument(
        "--workers", type=count(1, "workers"), default=2, help="parallel worker processes"
    )
    if store is not None:
        parser.add_argument(
            "--store",
            type=Path,
            default=store,
            help=f"the evaluation store the episodes go to and resume from (default: {store})",
        )
