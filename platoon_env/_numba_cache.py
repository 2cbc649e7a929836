"""Where numba keeps the compiled kernels: one directory per version of the package's source.

numba's on-disk cache (``@njit(cache=True)``) checks only the file that holds the cached
function, not the files its callees live in. Editing ``reward.py`` therefore left the cached
``simulator.step_env`` (which inlines the reward) in use: tests passed against the old code.
This module keys the package's kernels on a hash of every source file of the package
(:func:`source_digest`), so any edit starts from a fresh cache, wherever the cache lives.

The directory (:data:`CACHE_DIR`) is the first writable one of (:func:`cache_candidates`):

1. ``$NUMBA_CACHE_DIR/platoon_env/<hash>`` when the user set ``NUMBA_CACHE_DIR`` (or
   ``numba.config.CACHE_DIR``);
2. ``$XDG_CACHE_HOME/platoon_env/numba/<hash>`` (``~/.cache`` by default);
3. ``<package>/__pycache__/numba/<hash>`` beside the sources.

When none is writable (read-only home and sources, no ``NUMBA_CACHE_DIR``), caching is off for
the package's kernels: one ``RuntimeWarning`` says so and the kernels are compiled in memory on
every run (numba itself would fail the import with "no locator available").

Only the package's own functions are affected: :func:`install` wraps numba's
``Dispatcher.enable_caching`` so that a function defined under this package gets a
:class:`PackageFunctionCache` (numba's ``FunctionCache`` with the locator above) and any other
function numba's own cache, exactly as before; ``numba.config.CACHE_DIR`` is left untouched.

A corrupt cache entry (a truncated or overwritten ``.nbi``/``.nbc`` file) does not crash: the
failure to load it is caught where numba loads it, at the kernel's first call, one
``RuntimeWarning`` names the file, the entry is deleted and the kernel is compiled and saved
afresh. (Checking the files at import would read every entry on every import; the load is
where numba finds out anyway.) A failure to save is a warning too: the kernel is then used from
memory.

Old hash directories are not removed (a running process may still use one):
``rm -rf ~/.cache/platoon_env/numba`` clears them all. This relies on numba's cache classes
(``numba.core.caching``); an expert setting of ``NUMBA_CACHE_LOCATOR_CLASSES`` is overridden for
the package's functions.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numba
from numba.core import caching, dispatcher

#: The package's directory, whose ``.py`` files the hash covers.
PACKAGE_DIR = Path(__file__).resolve().parent

# numba's locator for NUMBA_CACHE_DIR (``_UserProvidedCacheLocator`` in older versions).
try:
    _LocatorBase: Any = caching.UserProvidedCacheLocator
except AttributeError:  # pragma: no cover - older numba
    _LocatorBase = caching._UserProvidedCacheLocator  # type: ignore[attr-defined]


def source_digest(package_dir: Path) -> str:
    """A hash of the relative path and content of every ``.py`` file under ``package_dir``."""
    digest = hashlib.sha256()
    for path in sorted(package_dir.rglob("*.py")):
        digest.update(path.relative_to(package_dir).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def cache_candidates(digest: str) -> list[Path]:
    """The directories the kernels may be cached in, best first (see the module docstring)."""
    out: list[Path] = []
    user = os.environ.get("NUMBA_CACHE_DIR") or numba.config.CACHE_DIR  # type: ignore[attr-defined]
    if user:
        out.append(Path(user) / "platoon_env" / digest)
    xdg = os.environ.get("XDG_CACHE_HOME")
    try:
        root: Path | None = Path(xdg) if xdg else Path.home() / ".cache"
    except RuntimeError:  # no home directory
        root = None
    if root is not None:
        out.append(root / "platoon_env" / "numba" / digest)
    out.append(PACKAGE_DIR / "__pycache__" / "numba" / digest)
    return out


def _writable(directory: Path) -> bool:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=directory).close()
    except OSError:
        return False
    return True


def _is_package_function(py_func: Any) -> bool:
    code = getattr(py_func, "__code__", None)
    if code is None:
        return False
    try:
        return Path(code.co_filename).resolve().is_relative_to(PACKAGE_DIR)
    except (OSError, ValueError):
        return False


_warned: set[str] = set()


def _warn_once(kind: str, message: str) -> None:
    if kind not in _warned:
        _warned.add(kind)
        warnings.warn(message, RuntimeWarning, stacklevel=3)


class PackageLocator(_LocatorBase):  # type: ignore[misc]
    """numba's locator for a user-provided directory, pointed at :attr:`cache_root` (this
    source version's directory) instead of ``numba.config.CACHE_DIR``."""

    #: The cache directory of this source version; None: caching is off.
    cache_root: str | None = None

    def __init__(self, py_func: Any, py_file: str) -> None:
        assert self.cache_root is not None
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = os.path.join(self.cache_root, self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self) -> str:
        return self._cache_path

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> PackageLocator | None:
        if cls.cache_root is None or not os.path.exists(py_file):
            return None
        self = cls(py_func, py_file)
        try:
            self.ensure_cache_path()
        except OSError:
            return None
        return self


class _PackageCacheImpl(caching.CompileResultCacheImpl):  # type: ignore[misc]
    _locator_classes = [PackageLocator]

    def __init__(self, py_func: Any) -> None:
        super().__init__(py_func)
        if not isinstance(self._locator, PackageLocator):  # NUMBA_CACHE_LOCATOR_CLASSES set
            locator = PackageLocator.from_function(py_func, py_func.__code__.co_filename)
            if locator is None:
                raise RuntimeError(f"cannot cache {py_func.__qualname__} in {CACHE_DIR}")
            self._locator = locator


class PackageFunctionCache(caching.FunctionCache):  # type: ignore[misc]
    """numba's ``FunctionCache`` in this source version's directory, where an unreadable entry
    is a warning and a recompilation rather than an exception."""

    _impl_class = _PackageCacheImpl

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        try:
            return super().load_overload(sig, target_context)
        except Exception as exc:  # whatever a corrupt file raises
            index = Path(self._cache_file._index_path)
            _warn_once(
                "corrupt",
                f"platoon_env: ignoring an unreadable numba cache entry {index} "
                f"({type(exc).__name__}: {exc}); the kernel is compiled again and the entry "
                "rewritten (further unreadable entries are replaced without a warning)",
            )
            for path in (index, *index.parent.glob(f"{index.stem}.*.nbc")):
                try:
                    path.unlink()
                except OSError:
                    pass
            return None

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            super().save_overload(sig, data)
        except Exception as exc:  # a full disk, a vanished directory, ...
            _warn_once(
                "save",
                f"platoon_env: could not save a compiled kernel in {self.cache_path} "
                f"({type(exc).__name__}: {exc}); it is used from memory",
            )


_numba_enable_caching = dispatcher.Dispatcher.enable_caching


def _enable_caching(self: Any) -> None:
    """``Dispatcher.enable_caching``: the package's functions get a
    :class:`PackageFunctionCache` (or none, compiled in memory, when caching is off)."""
    if not _is_package_function(self.py_func):
        _numba_enable_caching(self)
        return
    if PackageLocator.cache_root is None:
        return  # numba's NullCache stays: compiled in memory
    try:
        self._cache = PackageFunctionCache(self.py_func)
    except Exception as exc:  # e.g. the directory vanished since the probe
        _warn_once(
            "locate",
            f"platoon_env: cannot cache {self.py_func.__qualname__} in {CACHE_DIR} "
            f"({type(exc).__name__}: {exc}); it is compiled in memory",
        )


_enable_caching.platoon_env = True  # type: ignore[attr-defined]


def install(cache_dir: Path | None) -> None:
    """Cache the package's kernels in ``cache_dir`` (None: compile them in memory).

    Must run before the first ``@njit(cache=True)`` function of the package is decorated.
    """
    PackageLocator.cache_root = None if cache_dir is None else str(cache_dir)
    if not getattr(dispatcher.Dispatcher.enable_caching, "platoon_env", False):
        dispatcher.Dispatcher.enable_caching = _enable_caching  # type: ignore[method-assign]


def configure_numba_cache() -> Path | None:
    """Choose this source version's cache directory and install it; returns it (None: no
    writable directory, caching off, with one warning)."""
    tried = cache_candidates(source_digest(PACKAGE_DIR))
    chosen = next((d for d in tried if _writable(d)), None)
    install(chosen)
    if chosen is None:
        warnings.warn(
            "platoon_env: no writable directory for numba's compiled-kernel cache (tried "
            f"{', '.join(str(d) for d in tried)}); the kernels are compiled in memory on every "
            "run, which makes the first step of a process slow. Set NUMBA_CACHE_DIR to a "
            "writable directory to cache them.",
            RuntimeWarning,
            stacklevel=2,
        )
    return chosen


# Importing this module configures the cache: platoon_env/__init__.py imports it before any
# module that compiles a kernel.
#: This source version's cache directory, or None when caching is off.
CACHE_DIR = configure_numba_cache()
