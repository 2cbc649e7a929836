"""numba's kernel cache is keyed on the package's source, so no edit runs stale kernels."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from platoon_env import _numba_cache


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
    import platoon_env

    if _numba_cache.CACHE_DIR is None:
        pytest.skip("NUMBA_CACHE_DIR is set, or no writable cache directory")
    env = platoon_env.make("study_c")  # compiles (or loads) the step kernel
    env.reset(seed=0)
    env.step({a: np.zeros(2) for a in env.agents})
    package = Path(platoon_env.__file__).resolve().parent
    assert Path(numba.config.CACHE_DIR) == _numba_cache.CACHE_DIR
    assert _numba_cache.CACHE_DIR.name == _numba_cache.source_digest(package)
    assert list(_numba_cache.CACHE_DIR.rglob("simulator.step_env-*.nbi"))


def test_users_numba_cache_dir_wins(tmp_path: Path) -> None:
    code = "import numba, platoon_env._numba_cache as c; print(c.CACHE_DIR, numba.config.CACHE_DIR)"
    env = {"NUMBA_CACHE_DIR": str(tmp_path), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["None", str(tmp_path)]
