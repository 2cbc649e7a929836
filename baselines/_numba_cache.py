"""Keys the baselines' compiled kernels on their source and on every package they import from.

The baselines' kernels read ``platoon_env``'s constants (the observation columns) and call its
rules (the unicycle arc, the actuators, the camera's frame timing), which numba inlines into the
cached kernel. numba's own cache checks only the kernel's file, so an edit of
``platoon_env/observation.py`` used to leave the cached PPC kernel reading the old columns. This
module registers the package with :mod:`platoon_env._numba_cache`, whose hash for ``baselines``
covers ``baselines`` and ``platoon_env``; ``baselines/__init__.py`` imports it before any module
that defines a kernel.
"""

from __future__ import annotations

from pathlib import Path

from platoon_env._numba_cache import register_package

#: This source version's cache directory of the baselines' kernels, or None when caching is off.
CACHE_DIR = register_package(Path(__file__).resolve().parent)
