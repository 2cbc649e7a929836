"""Where numba keeps the compiled kernels: one directory per version of the package's source.

numba's on-disk cache (``@njit(cache=True)``) checks only the modification time of the file
that holds the cached function, not of the files its callees live in. Editing
``reward.py`` therefore left the cached ``simulator.platoon_step`` (which inlines the reward)
in use: tests passed against the old code. Keying the cache directory on a hash of every
source file of the package makes any edit start from a fresh cache.

The directory is ``$XDG_CACHE_HOME/platoon_env/numba/<hash>`` (``~/.cache`` by default).
A user's own ``NUMBA_CACHE_DIR`` wins; if the directory cannot be created, numba's default
(``__pycache__`` beside the sources) is left in place. Old directories are not removed (a
running process may still use one): ``rm -rf ~/.cache/platoon_env/numba`` clears them all.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba


def source_digest(package_dir: Path) -> str:
    """A hash of the relative path and content of every ``.py`` file under ``package_dir``."""
    digest = hashlib.sha256()
    for path in sorted(package_dir.rglob("*.py")):
        digest.update(path.relative_to(package_dir).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def configure_numba_cache() -> Path | None:
    """Point numba's cache at this source version's directory; returns it (None: unchanged).

    Must run before the first ``@njit(cache=True)`` function of the package is decorated.
    """
    if os.environ.get("NUMBA_CACHE_DIR") or numba.config.CACHE_DIR:  # type: ignore[attr-defined]
        return None
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    cache_dir = root / "platoon_env" / "numba" / source_digest(Path(__file__).resolve().parent)
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        probe = cache_dir / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError:
        return None
    numba.config.CACHE_DIR = str(cache_dir)  # type: ignore[attr-defined]
    return cache_dir


# Importing this module configures the cache: platoon_env/__init__.py imports it before any
# module that compiles a kernel.
CACHE_DIR = configure_numba_cache()
