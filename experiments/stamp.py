"""The metadata stamp every experiment output carries: code, versions, machine, command.

A table or a figure without the code and settings that made it cannot be checked. Every
driver in :mod:`experiments` records :func:`metadata_stamp` with its run in the store and
writes it into the headers of its markdown exports (:func:`stamp_markdown`) and into the
``Description`` field of its PNGs (:func:`png_metadata`).
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import socket
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from platoon_env.provenance import REPO_ROOT, code_version, package_versions

__all__ = ["REPO_ROOT", "code_version", "metadata_stamp", "png_metadata", "stamp_markdown"]


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
    argv = " ".join(stamp.get("argv", [])) or "(none)"
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
            f"{stamp.get('tool', '?')} {' '.join(stamp.get('argv', []))}; "
            f"code {_commit_text(stamp)}; {stamp.get('time', '?')}"
        ),
    }
