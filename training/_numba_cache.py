"""Keys the learning side's compiled kernels (:mod:`training.forward`) on their source.

As :mod:`baselines._numba_cache` does for the baselines: this registers the package with
:mod:`platoon_env._numba_cache`, so the cached kernels live in a directory named by a hash of
this package's sources (and of every uninstalled package it imports), and any edit starts from
a fresh cache. ``training/forward.py`` imports it before it defines a kernel.
"""

from __future__ import annotations

from pathlib import Path

from platoon_env._numba_cache import register_package

#: This source version's cache directory of the training kernels, or None when caching is off.
CACHE_DIR = register_package(Path(__file__).resolve().parent)
