"""Provenance: which code and which package versions produced a result.

One source for every tool that records where a result came from: the evaluation drivers'
metadata stamp (``experiments.stamp``) and the ``model.json`` of a trained model both call
:func:`code_version` and :func:`package_versions`.

:func:`code_version` names the commit and every uncommitted change under the source folders
*with the SHA-256 of its content*, so two different edits of one commit are told apart (a list
of file names alone would make them look identical).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import platform
import subprocess
from pathlib import Path
from typing import Any

from platoon_env import __version__

__all__ = ["REPO_ROOT", "SOURCE_DIRS", "code_version", "package_versions"]

#: The source checkout holding this package (a clone has ``.git``; an installed wheel has not).
REPO_ROOT = Path(__file__).resolve().parents[1]
#: The source folders whose uncommitted edits change results.
SOURCE_DIRS: tuple[str, ...] = ("platoon_env", "baselines", "training", "experiments", "models")
#: The distributions whose versions change results (always recorded, "not installed" if absent).
_PACKAGES = ("numpy", "numba", "scipy", "shapely", "gymnasium", "pettingzoo", "torch")
#: Recorded only when installed.
_PACKAGES_OPTIONAL = ("stable-baselines3", "ray")


def _git(root: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(root), *args], capture_output=True, text=True, check=True, timeout=30
    ).stdout


def _content_hash(path: Path) -> str:
    """SHA-256 of a file's bytes; ``"deleted"`` for a path that no longer exists; for a folder
    (an untracked directory), the hash of its files' relative paths and contents."""
    if path.is_file():
        return hashlib.sha256(path.read_bytes()).hexdigest()
    if path.is_dir():
        digest = hashlib.sha256()
        for f in sorted(p for p in path.rglob("*") if p.is_file()):
            digest.update(str(f.relative_to(path)).encode() + b"\0" + f.read_bytes())
        return digest.hexdigest()
    return "deleted"


def code_version(root: Path = REPO_ROOT) -> dict[str, Any]:
    """``{"commit": sha, "modified": [paths], "modified_sha256": {path: sha256}}`` of the
    checkout at ``root``; ``{}`` outside a git checkout (an installed wheel).

    ``modified`` lists the uncommitted files (tracked or not) under :data:`SOURCE_DIRS`: rows
    made with them are not reproducible from the commit alone; ``modified_sha256`` holds the
    content hash of each, so that two runs from different edits of one commit differ.
    """
    try:
        commit = _git(root, "rev-parse", "HEAD").strip()
        status = _git(root, "status", "--porcelain", "--", *SOURCE_DIRS)
    except (OSError, subprocess.SubprocessError):
        return {}
    modified = sorted(line[3:].split(" -> ")[-1].strip('"') for line in status.splitlines())
    return {
        "commit": commit,
        "modified": modified,
        "modified_sha256": {p: _content_hash(root / p) for p in modified},
    }


def package_versions() -> dict[str, str]:
    """Python's and every result-changing distribution's version (``platoon_env`` included)."""
    out = {"python": platform.python_version(), "platoon_env": __version__}
    for name in (*_PACKAGES, *_PACKAGES_OPTIONAL):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            if name in _PACKAGES:
                out[name] = "not installed"
    return out
