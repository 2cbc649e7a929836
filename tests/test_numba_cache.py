"""numba's kernel cache is keyed on the package's source (and, for the baselines, on the
packages they import from), so no edit runs stale kernels; a cache that cannot be written or
read is a warning, never a failed import.

The subprocess tests run a fresh interpreter with ``HOME``, ``XDG_CACHE_HOME`` and
``NUMBA_CACHE_DIR`` pointed at temporary paths (and, where the package's own directory matters,
on a copy of the package), so they never touch the user's cache.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import baselines
import platoon_env
from baselines import _numba_cache as baselines_cache
from baselines import ppc
from platoon_env import _numba_cache

PACKAGE = Path(platoon_env.__file__).resolve().parent
BASELINES = Path(baselines.__file__).resolve().parent

# Calls one small kernel (compiled in about a second) and reports where its cache lives.
KERNEL_CODE = """
import platoon_env, platoon_env._numba_cache as c
from platoon_env.dynamics import unicycle
k = unicycle.unicycle_arc
print(platoon_env.__file__)
print(c.CACHE_DIR)
print(type(k._cache).__name__, getattr(k._cache, "cache_path", None))
print(k(0.0, 0.0, 0.0, 1.0, 1.0, 0.1))
print(sum(k._cache_hits.values()), sum(k._cache_misses.values()))
"""


def _run(code: str, cwd: Path, **env: str) -> subprocess.CompletedProcess[str]:
    """Run ``code`` in a fresh interpreter with only ``env`` (plus PATH) in its environment.

    ``PYTHONPATH`` defaults to the directory holding the package under test, so the child
    imports the same ``platoon_env`` as this process.
    """
    full = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "PYTHONPATH": str(PACKAGE.parent),
        **env,
    }
    return subprocess.run(
        [sys.executable, "-W", "always::RuntimeWarning", "-c", code],
        env=full,
        cwd=cwd,  # not the checkout: '' on sys.path must not shadow PYTHONPATH
        capture_output=True,
        text=True,
        timeout=600,
    )


def _kernel(cwd: Path, **env: str) -> tuple[list[str], str]:
    """Run :data:`KERNEL_CODE`; its output lines and its stderr (the run must succeed)."""
    out = _run(KERNEL_CODE, cwd, **env)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines(), out.stderr


def _copy_package(root: Path, package: Path = PACKAGE) -> Path:
    """A copy of ``package`` (sources and data, no caches) under ``root``; returns its dir."""
    target = root / package.name
    shutil.copytree(package, target, ignore=shutil.ignore_patterns("__pycache__"))
    return target


def _block_in_tree_caches(package: Path) -> None:
    """Make ``__pycache__`` a regular file in every package directory: nothing (not even root)
    can create a cache directory there."""
    for directory in [package, *(p for p in package.rglob("*") if p.is_dir())]:
        (directory / "__pycache__").write_text("")


def test_digest_follows_every_source_file(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "sub" / "b.py").write_text("y = 2\n")
    (tmp_path / "notes.txt").write_text("not source\n")
    first = _numba_cache.source_digest(tmp_path)
    assert _numba_cache.source_digest(tmp_path) == first
    (tmp_path / "notes.txt").write_text("changed\n")
    assert _numba_cache.source_digest(tmp_path) == first
    (tmp_path / "sub" / "b.py").write_text("y = 3\n")
    second = _numba_cache.source_digest(tmp_path)
    assert second != first
    (tmp_path / "sub" / "b.py").rename(tmp_path / "sub" / "c.py")
    assert _numba_cache.source_digest(tmp_path) != second


def test_kernels_cache_in_the_source_versions_directory() -> None:
    from platoon_env import simulator

    if _numba_cache.CACHE_DIR is None:
        pytest.skip("no writable cache directory in this environment (caching is off)")
    env = platoon_env.make("study_c")  # compiles (or loads) the step kernel
    env.reset(seed=0)
    env.step({a: np.zeros(2) for a in env.agents})
    assert _numba_cache.CACHE_DIR.name == _numba_cache.source_digest(PACKAGE)
    assert Path(simulator.step_env._cache.cache_path).is_relative_to(_numba_cache.CACHE_DIR)
    assert list(_numba_cache.CACHE_DIR.rglob("simulator.step_env-*.nbi"))


def test_users_numba_cache_dir_is_keyed_on_the_source(tmp_path: Path) -> None:
    """A user's NUMBA_CACHE_DIR holds the kernels in a subfolder named by the source hash."""
    cache = tmp_path / "numba-cache"
    lines, _ = _kernel(tmp_path, NUMBA_CACHE_DIR=str(cache), HOME=str(tmp_path))
    assert Path(lines[0]).resolve().parent == PACKAGE
    expected = cache / "platoon_env" / _numba_cache.source_digest(PACKAGE)
    assert lines[1] == str(expected)
    kind, cache_path = lines[2].split()
    assert kind == "PackageFunctionCache"
    assert Path(cache_path).is_relative_to(expected)
    assert list(expected.rglob("unicycle.unicycle_arc-*.nbi"))


def test_other_numba_functions_keep_numbas_own_cache(tmp_path: Path) -> None:
    """Only the package's functions are redirected: a user's ``cache=True`` function (in a file
    of their own) still caches where numba puts it, and numba.config.CACHE_DIR is untouched."""
    (tmp_path / "user_mod.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x + 1\n"
    )
    code = (
        "import numba, platoon_env, user_mod\n"
        "print(numba.config.CACHE_DIR)\n"
        "print(type(user_mod.f._cache).__name__, user_mod.f._cache.cache_path)\n"
    )
    cache = tmp_path / "numba-cache"
    out = _run(code, tmp_path, NUMBA_CACHE_DIR=str(cache), HOME=str(tmp_path))
    assert out.returncode == 0, out.stderr
    config_dir, line = out.stdout.splitlines()
    assert config_dir == str(cache)
    kind, path = line.split()
    assert kind == "FunctionCache"
    assert Path(path).parent == cache  # numba's own layout: <CACHE_DIR>/<dir>_<hash>


# An edit to a callee's file must reach the caller's cached kernel. numba alone checks only the
# caller's file; two probe modules in a copy of the package show it: _probe_a.probe() returns
# _probe_b.value().
PROBE_A = (
    "from numba import njit\n\nfrom platoon_env._probe_b import value\n\n\n"
    "@njit(cache=True)\ndef probe():\n    return value()\n"
)
PROBE_B = "from numba import njit\n\n\n@njit(cache=True)\ndef value():\n    return {}\n"
PROBE_CODE = "from platoon_env._probe_a import probe\nprint(probe())\n"


@pytest.mark.parametrize("where", ["NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "unusable HOME"])
def test_an_edit_to_a_callee_is_never_run_stale(tmp_path: Path, where: str) -> None:
    package = _copy_package(tmp_path / "src")
    (package / "_probe_a.py").write_text(PROBE_A)
    (package / "_probe_b.py").write_text(PROBE_B.format("1.0"))
    env = {"PYTHONPATH": str(tmp_path / "src"), "HOME": str(tmp_path / "home")}
    (tmp_path / "home").mkdir()
    if where == "NUMBA_CACHE_DIR":
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba-cache")
    elif where == "XDG_CACHE_HOME":
        env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    else:  # HOME is a file: no ~/.cache, so the cache falls back to the package's __pycache__
        (tmp_path / "home").rmdir()
        (tmp_path / "home").write_text("")
    first = _run(PROBE_CODE, tmp_path, **env)
    assert first.returncode == 0, first.stderr
    assert first.stdout.split() == ["1.0"]
    again = _run(PROBE_CODE, tmp_path, **env)
    assert again.stdout.split() == ["1.0"]
    (package / "_probe_b.py").write_text(PROBE_B.format("2.0"))
    edited = _run(PROBE_CODE, tmp_path, **env)
    assert edited.returncode == 0, edited.stderr
    assert edited.stdout.split() == ["2.0"], "the cached kernel ran the callee's old code"


def test_no_writable_cache_warns_once_and_compiles_in_memory(tmp_path: Path) -> None:
    """HOME, XDG_CACHE_HOME and every __pycache__ unusable, no NUMBA_CACHE_DIR: numba alone
    fails the import ('no locator available'); here the kernels compile in memory, with one
    warning. (Regular files stand in for read-only directories, which root could still write.)"""
    package = _copy_package(tmp_path / "src")
    _block_in_tree_caches(package)
    blocked = tmp_path / "not-a-directory"
    blocked.write_text("")
    lines, stderr = _kernel(
        tmp_path,
        PYTHONPATH=str(tmp_path / "src"),
        HOME=str(blocked),
        XDG_CACHE_HOME=str(blocked),
    )
    assert Path(lines[0]).parent == package
    assert lines[1] == "None"
    assert lines[2].split()[0] == "NullCache"
    assert stderr.count("no writable directory for numba's compiled-kernel cache") == 1
    assert "NUMBA_CACHE_DIR" in stderr


def _read_only(path: Path) -> None:
    for p in [path, *path.rglob("*")]:
        if p.is_dir():
            p.chmod(stat.S_IRUSR | stat.S_IXUSR)


def test_read_only_home_and_sources(tmp_path: Path) -> None:
    """The same with real read-only directories (chmod), for a user who is not root."""
    package = _copy_package(tmp_path / "src")
    home = tmp_path / "home"
    home.mkdir()
    _read_only(tmp_path / "src")
    _read_only(home)
    try:
        try:
            (home / "probe").write_text("")
        except OSError:
            pass
        else:
            pytest.skip("chmod does not prevent writes here (running as root)")
        lines, stderr = _kernel(tmp_path, PYTHONPATH=str(tmp_path / "src"), HOME=str(home))
        assert Path(lines[0]).parent == package
        assert lines[1] == "None" and lines[2].split()[0] == "NullCache"
        assert stderr.count("no writable directory for numba's compiled-kernel cache") == 1
    finally:
        for p in [tmp_path, *tmp_path.rglob("*")]:
            if p.is_dir():
                p.chmod(stat.S_IRWXU)


@pytest.mark.parametrize("corrupt", ["index", "data", "both"])
def test_corrupt_cache_entry_is_recompiled(tmp_path: Path, corrupt: str) -> None:
    """Garbage in a cache file is a warning, a recompilation and a rewritten entry."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "numba-cache"), "HOME": str(tmp_path)}
    lines, _ = _kernel(tmp_path, **env)
    assert Path(lines[0]).resolve().parent == PACKAGE
    result = lines[3]
    assert lines[4] == "0 1"  # compiled and saved
    suffixes = {"index": (".nbi",), "data": (".nbc",), "both": (".nbi", ".nbc")}[corrupt]
    files = [p for p in (tmp_path / "numba-cache").rglob("*") if p.suffix in suffixes]
    assert files
    for path in files:
        path.write_bytes(b"\x80\x05 this is not a pickle")
    lines, stderr = _kernel(tmp_path, **env)
    assert lines[3] == result
    assert lines[4] == "0 1"  # recompiled
    assert "ignoring an unreadable numba cache entry" in stderr
    lines, stderr = _kernel(tmp_path, **env)
    assert lines[3] == result
    assert lines[4] == "1 0"  # the rewritten entry loads
    assert "unreadable" not in stderr


def test_kernel_sources_follow_the_imports_of_local_packages(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A package's hash covers the packages it imports that are not installed, transitively,
    so that an edit there (a constant its kernels inline) changes it."""
    for name, body in {
        "pkg_a": "import math\nfrom pkg_b.consts import C\n",
        "pkg_b": "import numpy\n",
        "pkg_c": "X = 1\n",
    }.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text(body)
    (tmp_path / "pkg_b" / "consts.py").write_text("import pkg_c\nC = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    a, b, c = (tmp_path / n for n in ("pkg_a", "pkg_b", "pkg_c"))
    assert _numba_cache.kernel_sources(a) == [b, c]  # numpy, math: installed
    assert _numba_cache.kernel_sources(c) == []
    before = _numba_cache.source_digest(a, *_numba_cache.kernel_sources(a))
    (tmp_path / "pkg_b" / "consts.py").write_text("import pkg_c\nC = 2\n")
    assert _numba_cache.source_digest(a, *_numba_cache.kernel_sources(a)) != before
    # the repository: the baselines import platoon_env, which imports no local package
    assert _numba_cache.kernel_sources(BASELINES) == [PACKAGE]
    assert _numba_cache.kernel_sources(PACKAGE) == []


def test_baselines_kernels_cache_in_their_source_versions_directory() -> None:
    if baselines_cache.CACHE_DIR is None:
        pytest.skip("no writable cache directory in this environment (caching is off)")
    assert baselines_cache.CACHE_DIR.name == _numba_cache.source_digest(BASELINES, PACKAGE)
    assert type(ppc._ppc_step._cache).__name__ == "PackageFunctionCache"
    assert Path(ppc._ppc_step._cache.cache_path).is_relative_to(baselines_cache.CACHE_DIR)


# One step of the PPC law's kernel, which reads the observation columns of
# platoon_env/observation.py, on a row [visible, x~, y~, clearances]; it reports where its cache
# lives, the command and whether it was loaded from the cache (hits) or compiled (misses).
PPC_CODE = """
import numpy as np
from baselines import _numba_cache as c, ppc
p = ppc.PPCParams(r=0.15, d_des=1.0, d_col=0.3, d_con=1.5, beta_con=0.4, lambda_=0.5,
                  rho_d_inf=0.05, rho_beta_inf=0.1, k_d=1.0, k_beta=2.0, delta=0.5,
                  epsilon=0.75, dt=0.01)
obs = np.array([[1.0, 1.1, 0.05, 0.6, 0.6, 0.6, 0.6]])
rho = p.initial_rho()[:, None].copy()
sig = np.zeros((len(ppc.SIGNAL_NAMES), 1))
counts = np.zeros((3, 1), dtype=np.int64)
k = ppc._ppc_step
cmd = k(obs, np.zeros(1, dtype=np.intp), ppc._kernel_params(p), ppc._kernel_sets(p), rho, sig,
        counts)
print(c.CACHE_DIR)
print(type(k._cache).__name__)
print(repr(float(cmd[0, 0])), repr(float(cmd[0, 1])))
print(sum(k._cache_hits.values()), sum(k._cache_misses.values()))
"""


def _ppc_kernel(cwd: Path, **env: str) -> tuple[list[str], str]:
    """Run :data:`PPC_CODE`; its output lines and its stderr (the run must succeed)."""
    out = _run(PPC_CODE, cwd, **env)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines(), out.stderr


def test_an_edit_of_an_imported_constant_reaches_the_baselines_kernel(tmp_path: Path) -> None:
    """The bug this fixes: numba keyed the baselines' cached kernels on their own file only, so
    after an edit of observation.py's columns the PPC kernel kept reading the old ones."""
    src = tmp_path / "src"
    _copy_package(src, PACKAGE)
    _copy_package(src, BASELINES)
    env = {"PYTHONPATH": str(src), "HOME": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "nc")}
    first, _ = _ppc_kernel(tmp_path, **env)
    assert first[1] == "PackageFunctionCache"
    assert first[3] == "0 1"  # compiled and saved
    again, _ = _ppc_kernel(tmp_path, **env)
    assert again[2] == first[2] and again[3] == "1 0"  # loaded
    layout = src / "platoon_env" / "observation.py"
    columns, swapped = "OBS_X_REL = 1\nOBS_Y_REL = 2\n", "OBS_X_REL = 2\nOBS_Y_REL = 1\n"
    text = layout.read_text()
    assert columns in text
    layout.write_text(text.replace(columns, swapped))
    edited, _ = _ppc_kernel(tmp_path, **env)
    assert edited[0] != first[0]  # another source version, another directory
    assert edited[3] == "0 1", "the cached kernel was loaded after its constants changed"
    assert edited[2] != first[2]  # it reads x~ = 0.05, y~ = 1.1 now
    # the edited columns, computed without any cache, give the same command
    fresh, _ = _ppc_kernel(tmp_path, **{**env, "NUMBA_CACHE_DIR": str(tmp_path / "fresh")})
    assert fresh[2] == edited[2]


def test_corrupt_baselines_cache_entry_is_recompiled(tmp_path: Path) -> None:
    """A baselines kernel's unreadable cache file is a warning naming it and a recompilation,
    not a traceback."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "nc"), "HOME": str(tmp_path)}
    lines, _ = _ppc_kernel(tmp_path, **env)
    assert lines[3] == "0 1"
    files = list(Path(lines[0]).rglob("ppc._ppc_step-*.nb[ic]"))
    assert {p.suffix for p in files} == {".nbi", ".nbc"}
    for path in files:
        path.write_bytes(b"\x80\x05 this is not a pickle")
    again, stderr = _ppc_kernel(tmp_path, **env)
    assert again[2] == lines[2] and again[3] == "0 1"  # recompiled, same command
    assert "ignoring an unreadable numba cache entry" in stderr
    assert "ppc._ppc_step-" in stderr  # names the file
    third, stderr = _ppc_kernel(tmp_path, **env)
    assert third[3] == "1 0" and "unreadable" not in stderr
