"""The metadata stamp every experiment output carries: code, versions, machine, command.

A table or a figure without the code and settings that made it cannot be checked. Every
driver in :mod:`experiments` records :func:`metadata_stamp` with its run in the store and
writes it into the headers of its markdown exports (:func:`stamp_markdown`) and into the
``Description`` field of its PNGs (:func:`png_metadata`). Those two write the command line
through :func:`portable_argv`, so that no absolute path of the machine that ran it is
published (the stamp in the store keeps the arguments exactly as given).
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import re
import socket
import sys
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from platoon_env.provenance import REPO_ROOT, code_version, package_versions

__all__ = [
    "REPO_ROOT",
    "code_version",
    "metadata_stamp",
    "png_metadata",
    "portable_argv",
    "portable_path",
    "stamp_markdown",
]

#: An absolute path: POSIX (``/...``), a Windows drive (``C:\\...``, ``C:/...``) or a UNC share.
_ABSOLUTE = re.compile(r"^(/|[A-Za-z]:[\\/]|\\\\)")


def _under(path: str, folder: str) -> str | None:
    """``path`` relative to ``folder`` (``/`` separators; ``""`` for the folder itself), or None
    when it is not inside. String logic only: the path need not exist on this machine."""
    norm = path.replace("\\", "/")
    base = folder.replace("\\", "/").rstrip("/")
    if not base:
        return None
    if norm == base:
        return ""
    return norm[len(base) + 1 :] if norm.startswith(base + "/") else None


def portable_path(
    arg: str,
    root: Path | str = REPO_ROOT,
    home: Path | str | None = None,
    tmp: Path | str | None = None,
) -> str:
    """``arg`` with no absolute path of this machine in it, for a published command line.

    An absolute path becomes, in this order: under the checkout ``root`` (as given or
    resolved), relative to it (``/home/u/platoon/models`` -> ``models``; the root itself
    ``.``); under the temporary folder (``tmp``, default :func:`tempfile.gettempdir` and
    ``/tmp``), ``<tmp>/REST``; under the home folder (``home``, default :meth:`Path.home`),
    ``~/REST``; anywhere else ``<outside>/NAME``, its last component only. ``--option=PATH``
    and ``NAME=PATH`` keep their prefix. Other arguments (options, numbers, relative paths)
    are returned as they are.
    """
    if not _ABSOLUTE.match(arg):
        key, sep, value = arg.partition("=")
        if sep and _ABSOLUTE.match(value):
            return f"{key}={portable_path(value, root, home, tmp)}"
        return arg
    for checkout in dict.fromkeys((str(root), str(Path(root).resolve()))):
        rel = _under(arg, checkout)
        if rel is not None:
            return rel or "."
    for folder in [str(tmp)] if tmp is not None else [tempfile.gettempdir(), "/tmp"]:
        rest = _under(arg, folder)
        if rest is not None:
            return f"<tmp>/{rest}" if rest else "<tmp>"
    rest = _under(arg, str(Path.home() if home is None else home))
    if rest is not None:
        return f"~/{rest}" if rest else "~"
    name = re.split(r"[\\/]", arg.rstrip("/\\"))[-1]
    return f"<outside>/{name}" if name else "<outside>"


def portable_argv(argv: Sequence[str], root: Path | str = REPO_ROOT) -> list[str]:
    """Every argument of ``argv`` through :func:`portable_path`, against the checkout ``root``."""
    return [portable_path(str(a), root) for a in argv]


def metadata_stamp(
    tool: str, config: Mapping[str, Any] | None = None, argv: Sequence[str] | None = None
) -> dict[str, Any]:
    """The stamp of one run of ``tool``: UTC time, command line, code version, package
    versions, host and CPU count, and the run's ``config`` (JSON-able settings)."""
    return {
        "tool": tool,
        "time": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "argv": list(sys.argv[1:] if argv is None else argv),
        **code_version(),
        "versions": package_versions(),
        "host": socket.gethostname(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "config": dict(config or {}),
    }


def _commit_text(stamp: Mapping[str, Any]) -> str:
    commit = str(stamp.get("commit", ""))[:12] or "unknown (not a git checkout)"
    modified = stamp.get("modified") or []
    if modified:
        shown = ", ".join(modified[:5]) + (", ..." if len(modified) > 5 else "")
        return f"{commit} + uncommitted changes to {shown}"
    return commit


def stamp_markdown(stamp: Mapping[str, Any]) -> str:
    """A few markdown lines stating the stamp (for the header of a table)."""
    versions = ", ".join(f"{k} {v}" for k, v in stamp.get("versions", {}).items())
    argv = " ".join(portable_argv(stamp.get("argv", []))) or "(none)"
    return (
        f"- made by `{stamp.get('tool', '?')}` at {stamp.get('time', '?')} on "
        f"{stamp.get('host', '?')} ({stamp.get('cpus', '?')} CPUs, {stamp.get('platform', '?')})\n"
        f"- arguments: `{argv}`\n"
        f"- code: {_commit_text(stamp)}\n"
        f"- versions: {versions}\n"
    )


def png_metadata(stamp: Mapping[str, Any]) -> dict[str, str]:
    """PNG text fields (``savefig(metadata=...)``) of the stamp."""
    return {
        "Software": f"platoon_env {stamp.get('versions', {}).get('platoon_env', '?')}",
        "Description": (
            f"{stamp.get('tool', '?')} {' '.join(portable_argv(stamp.get('argv', [])))}; "
            f"code {_commit_text(stamp)}; {stamp.get('time', '?')}"
        ),
    }
