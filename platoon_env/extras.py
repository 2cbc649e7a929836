"""Optional extras: a missing one is a one-line message naming the extra, not a traceback.

The package installs with the env's dependencies only; training, plotting and the aggregate
statistics are extras (``pip install 'platoon-env[train]'`` and so on). A tool that needs one
calls :func:`require_extra` before it starts, so that a user sees which extra to install
instead of a ``ModuleNotFoundError`` from deep inside a worker process.
"""

from __future__ import annotations

import importlib.util

__all__ = ["MissingExtraError", "require_extra"]

#: What each extra adds to the install command (torch is pinned in the same command: any other
#: torch request pulls a multi-GB CUDA build).
_INSTALL = {
    "train": "pip install 'platoon-env[train]' torch==2.13.0",
    "plot": "pip install 'platoon-env[plot]'",
    "stats": "pip install 'platoon-env[stats]'",
    "rllib": "pip install 'platoon-env[train,rllib]' torch==2.13.0",
}


#: The modules that stand for each extra in a check (:func:`require_extra` without modules).
_MODULES = {
    "train": ("torch", "stable_baselines3"),
    "plot": ("matplotlib", "imageio"),
    "stats": ("rliable", "pandas"),
    "rllib": ("ray",),
}


class MissingExtraError(ImportError):
    """An optional extra a tool needs is not installed (the message says which, and how)."""


def require_extra(extra: str, *modules: str, purpose: str) -> None:
    """Raise :class:`MissingExtraError` unless every module in ``modules`` can be imported
    (none given: the modules that stand for ``extra``, :data:`_MODULES`).

    ``purpose`` says what needs them (``"evaluating trained models"``); the message names the
    extra and its install command.
    """
    if extra not in _INSTALL:
        raise ValueError(f"unknown extra {extra!r}; known: {', '.join(_INSTALL)}")
    missing = [m for m in modules or _MODULES[extra] if importlib.util.find_spec(m) is None]
    if missing:
        raise MissingExtraError(
            f"{purpose} needs the optional [{extra}] extra (missing: {', '.join(missing)}); "
            f"install it with: {_INSTALL[extra]}"
        )
