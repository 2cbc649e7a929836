"""Where numba keeps the compiled kernels: one directory per version of the source they depend on.

numba's on-disk cache (``@njit(cache=True)``) checks only the file that holds the cached
function, not the files its callees and constants live in. Editing ``reward.py`` therefore left
the cached ``simulator.step_env`` (which inlines the reward) in use, and editing
``observation.py``'s column constants left the baselines' cached PPC kernel reading the old
columns: tests passed, or failed, against old code. This module keys
the kernels of a *registered package* on a hash of every source file of the package and of every
package it imports that is not installed (:func:`kernel_sources`, :func:`source_digest`), so any
edit of a source a kernel can read starts from a fresh cache, wherever the cache lives.
``platoon_env`` registers itself here on import; ``baselines`` registers itself
(:func:`register_package`) before its first kernel, and its hash covers ``platoon_env`` too.
Installed packages (the standard library, ``site-packages``: numpy, numba) are not hashed: they
change by a reinstall, and numba's cache index already records numba's version.

A package's directory (:data:`CACHE_DIR` for ``platoon_env``) is the first writable one of
(:func:`cache_candidates`):

1. ``$NUMBA_CACHE_DIR/platoon_env/<hash>`` when the user set ``NUMBA_CACHE_DIR`` (or
   ``numba.config.CACHE_DIR``);
2. ``$XDG_CACHE_HOME/platoon_env/numba/<hash>`` (``~/.cache`` by default);
3. ``<package>/__pycache__/numba/<hash>`` beside the sources.

(The packages' hashes differ, so their directories sit side by side.) When none is writable
(read-only home and sources, no ``NUMBA_CACHE_DIR``), caching is off for the package's kernels:
one ``RuntimeWarning`` says so and the kernels are compiled in memory on every run (numba itself
would fail the import with "no locator available").

Only the registered packages' own functions are affected: :func:`install` wraps numba's
``Dispatcher.enable_caching`` so that a function defined under a registered package gets a
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
the registered packages' functions.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import re
import site
import sys
import sysconfig
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numba
from numba.core import caching, dispatcher

#: The directory of ``platoon_env``, the first registered package.
PACKAGE_DIR = Path(__file__).resolve().parent

# numba's locator for NUMBA_CACHE_DIR (``_UserProvidedCacheLocator`` in older versions).
try:
    _LocatorBase: Any = caching.UserProvidedCacheLocator
except AttributeError:  # pragma: no cover - older numba
    _LocatorBase = caching._UserProvidedCacheLocator  # type: ignore[attr-defined]


def _source_files(root: Path) -> list[Path]:
    """The ``.py`` files of a package directory (sorted), or ``[root]`` for a module file."""
    return [root] if root.is_file() else sorted(root.rglob("*.py"))


def source_digest(package_dir: Path, *dependencies: Path) -> str:
    """A hash of the relative path and content of every ``.py`` file under ``package_dir``, then
    of each of ``dependencies`` (package directories or module files, named by their name)."""
    digest = hashlib.sha256()
    roots = [("", package_dir)] + [(f"{d.name}:", d) for d in sorted(dependencies)]
    for prefix, root in roots:
        base = root.parent if root.is_file() else root
        for path in _source_files(root):
            digest.update((prefix + path.relative_to(base).as_posix()).encode())
            digest.update(b"\0")
            digest.update(path.read_bytes())
            digest.update(b"\0")
    return digest.hexdigest()[:16]


# The top-level module of each absolute import statement (``import a.b``, ``from a.b import c``).
# A line of prose that begins with "from" or "import" adds a name that is then not found, or
# found installed: harmless.
_IMPORT = re.compile(rb"^[ \t]*(?:from|import)[ \t]+([A-Za-z_][A-Za-z0-9_]*)", re.MULTILINE)


def _imported_names(root: Path) -> set[str]:
    """The top-level modules the ``.py`` files of ``root`` import (:data:`_IMPORT`)."""
    names: set[str] = set()
    for path in _source_files(root):
        names.update(m.group(1).decode() for m in _IMPORT.finditer(path.read_bytes()))
    return names


def _installed_roots() -> list[Path]:
    """The interpreter's installation directories: the standard library and site-packages."""
    paths = sysconfig.get_paths()
    roots = [paths[k] for k in ("stdlib", "platstdlib", "purelib", "platlib") if k in paths]
    roots += site.getsitepackages() if hasattr(site, "getsitepackages") else []
    roots.append(site.getusersitepackages())
    return [Path(r).resolve() for r in roots]


def local_source(name: str, installed: Iterable[Path]) -> Path | None:
    """The source of the top-level module ``name`` when it is not installed: its package
    directory or module file. None for a module under one of ``installed``, a built-in, a
    namespace package or a module that is not found."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):  # ValueError: in sys.modules without a __spec__
        return None
    if spec is None or spec.origin is None or not spec.has_location:
        return None
    path = Path(spec.origin).resolve()
    if spec.submodule_search_locations is not None:
        path = path.parent
    if any(path.is_relative_to(root) for root in installed):
        return None
    return path


def kernel_sources(package_dir: Path) -> list[Path]:
    """Every source a kernel of the package in ``package_dir`` may read besides its own: the
    packages (or modules) its modules import that are not installed (:func:`local_source`), and
    theirs, transitively; sorted. For ``baselines``: ``platoon_env``."""
    installed = _installed_roots()
    found: set[Path] = set()
    todo = [package_dir.resolve()]
    done = set(todo)
    while todo:
        root = todo.pop()
        for name in sorted(_imported_names(root)):
            source = local_source(name, installed)
            if source is not None and source not in done:
                done.add(source)
                found.add(source)
                todo.append(source)
    return sorted(found)


def cache_candidates(digest: str, package_dir: Path = PACKAGE_DIR) -> list[Path]:
    """The directories the kernels of the package in ``package_dir`` with source hash ``digest``
    may be cached in, best first (see the module docstring)."""
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
    out.append(package_dir / "__pycache__" / "numba" / digest)
    return out


def _writable(directory: Path) -> bool:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=directory).close()
    except OSError:
        return False
    return True


#: The registered packages' directories and their cache directories (None: caching is off).
_CACHE_ROOTS: dict[Path, str | None] = {}


def _package_of(py_func: Any) -> Path | None:
    """The registered package directory that holds ``py_func``'s file, or None."""
    code = getattr(py_func, "__code__", None)
    if code is None:
        return None
    try:
        path = Path(code.co_filename).resolve()
    except (OSError, ValueError):
        return None
    return next((d for d in _CACHE_ROOTS if path.is_relative_to(d)), None)


def _cache_root_of(py_func: Any) -> str | None:
    """The cache directory of ``py_func``'s registered package (None: not a registered
    package's function, or caching is off for it)."""
    package = _package_of(py_func)
    return None if package is None else _CACHE_ROOTS[package]


_warned: set[str] = set()


def _warn_once(kind: str, message: str) -> None:
    if kind not in _warned:
        _warned.add(kind)
        warnings.warn(message, RuntimeWarning, stacklevel=3)


class PackageLocator(_LocatorBase):  # type: ignore[misc]
    """numba's locator for a user-provided directory, pointed at the cache directory of the
    function's package and source version instead of ``numba.config.CACHE_DIR``."""

    def __init__(self, py_func: Any, py_file: str) -> None:
        root = _cache_root_of(py_func)
        assert root is not None
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = os.path.join(root, self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self) -> str:
        return self._cache_path

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> PackageLocator | None:
        if _cache_root_of(py_func) is None or not os.path.exists(py_file):
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
                where = _cache_root_of(py_func)
                raise RuntimeError(f"cannot cache {py_func.__qualname__} in {where}")
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
    """``Dispatcher.enable_caching``: a registered package's functions get a
    :class:`PackageFunctionCache` (or none, compiled in memory, when caching is off)."""
    if _package_of(self.py_func) is None:
        _numba_enable_caching(self)
        return
    root = _cache_root_of(self.py_func)
    if root is None:
        return  # numba's NullCache stays: compiled in memory
    try:
        self._cache = PackageFunctionCache(self.py_func)
    except Exception as exc:  # e.g. the directory vanished since the probe
        _warn_once(
            "locate",
            f"platoon_env: cannot cache {self.py_func.__qualname__} in {root} "
            f"({type(exc).__name__}: {exc}); it is compiled in memory",
        )


_enable_caching.platoon_env = True  # type: ignore[attr-defined]


def install(cache_dir: Path | None, package_dir: Path = PACKAGE_DIR) -> None:
    """Cache the kernels of the package in ``package_dir`` in ``cache_dir`` (None: compile them
    in memory).

    Must run before the package's first ``@njit(cache=True)`` function is decorated.
    """
    _CACHE_ROOTS[package_dir.resolve()] = None if cache_dir is None else str(cache_dir)
    if not getattr(dispatcher.Dispatcher.enable_caching, "platoon_env", False):
        dispatcher.Dispatcher.enable_caching = _enable_caching  # type: ignore[method-assign]


def register_package(package_dir: Path) -> Path | None:
    """Cache the kernels of the package in ``package_dir`` in the directory of this version of
    its source and of :func:`kernel_sources`; returns it (None: no writable directory, caching
    off for the package, with one warning).

    Call it before the package's first ``@njit(cache=True)`` function is decorated (first thing
    in its ``__init__``).
    """
    package_dir = package_dir.resolve()
    tried = cache_candidates(source_digest(package_dir, *kernel_sources(package_dir)), package_dir)
    chosen = next((d for d in tried if _writable(d)), None)
    install(chosen, package_dir)
    if chosen is None:
        warnings.warn(
            f"platoon_env: no writable directory for numba's compiled-kernel cache of "
            f"{package_dir.name} (tried {', '.join(str(d) for d in tried)}); its kernels are "
            "compiled in memory on every run, which makes the first step of a process slow. "
            "Set NUMBA_CACHE_DIR to a writable directory to cache them.",
            RuntimeWarning,
            stacklevel=2,
        )
    return chosen


def configure_numba_cache() -> Path | None:
    """Register ``platoon_env`` (:func:`register_package`); returns its cache directory."""
    return register_package(PACKAGE_DIR)


def is_cold(cache_dir: Path | None) -> bool:
    """Whether ``cache_dir`` holds no compiled kernel yet (no numba index file): the first use
    of this source version on this machine (or caching off) compiles every kernel it calls."""
    if cache_dir is None:
        return True
    try:
        return not any(cache_dir.rglob("*.nbi"))
    except OSError:
        return True


def cold_start_notice(cache_dir: Path | None) -> str | None:
    """The one line printed at import when :func:`is_cold`: the first step compiles the
    kernels (a minute or two), once per source version and machine, and where they are kept;
    None when the cache already holds kernels or ``PLATOON_ENV_QUIET`` is set."""
    if os.environ.get("PLATOON_ENV_QUIET") or not is_cold(cache_dir):
        return None
    where = f"cached in {cache_dir}" if cache_dir is not None else "not cached: no writable dir"
    return (
        "platoon_env: first use of this version here: the first steps compile the simulation "
        f"kernels (about a minute, once; {where})"
    )


# Importing this module configures the cache: platoon_env/__init__.py imports it before any
# module that compiles a kernel.
#: This source version's cache directory of platoon_env's kernels, or None when caching is off.
CACHE_DIR = configure_numba_cache()
_NOTICE = cold_start_notice(CACHE_DIR)
if _NOTICE is not None:
    print(_NOTICE, file=sys.stderr, flush=True)
