"""The realism axes of the robustness studies: one setting of the camera, the proximity sensor
or the actuators at a time, each a list of levels from ideal to harsh.

Each :class:`Axis` turns a level into ``platoon_env.make`` overrides (the ideal level into none),
so that the frontiers (:mod:`experiments.studies.frontiers`) and the ``robustness`` suite
(:mod:`experiments.suites`) run the same conditions from one definition:

* ``camera_noise``: camera position noise sigma in {0, 0.5, 1, 2, 5, 10} cm;
* ``detection``: detection probability in {1, 0.95, 0.8, 0.5};
* ``latency``: camera latency in {0, 10, 30, 50, 100} ms;
* ``frame_rate``: camera frame rate in {every control step, 30, 15} Hz;
* ``accel_max``: bound on the follower's linear acceleration in {none, 2, 1, 0.5} m/s^2;
* ``profile``: the shipped ``aruco`` sensor profile (``docs/realism.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from experiments.names import by_name
from platoon_env.scenarios.options import PROFILE_OPTION
from platoon_env.scenarios.profiles import load_profile

__all__ = ["AXES", "Axis", "Level", "level_key", "profile_overrides"]

#: A level of an axis: a number in the axis' unit, a name (a profile), or None (off).
Level = float | str | None


def level_key(level: Level) -> str:
    """The CSV form of a level: ``"none"`` for None, ``f"{x:g}"`` for a number, else the text."""
    if level is None:
        return "none"
    if isinstance(level, str):
        return level
    return f"{float(level):g}"


@dataclass(frozen=True)
class Axis:
    """One realism axis: its levels (in the unit shown, from ideal to harsh) and how a level
    becomes ``platoon_env.make`` overrides."""

    name: str
    label: str  # axis title with its unit
    levels: tuple[Level, ...]
    quick: tuple[Level, ...]  # the levels of a --quick run
    to_overrides: Callable[[Any], dict[str, Any]]
    none_label: str = "none"  # how the level None is shown

    def show(self, level: Level) -> str:
        """A level as shown in tables and on plots."""
        return self.none_label if level is None else level_key(level)

    def overrides(self, level: Level) -> dict[str, Any]:
        """The ``make`` keyword overrides of ``level`` ({} for the ideal level)."""
        return self.to_overrides(level)


def _noise(cm: float) -> dict[str, Any]:
    return {"camera": {"noise": {"position": cm / 100.0}}} if cm else {}


def _detection(p: float) -> dict[str, Any]:
    return {"camera": {"detection": p}} if p != 1 else {}


def _latency(ms: float) -> dict[str, Any]:
    return {"camera": {"latency": ms / 1000.0}} if ms else {}


def _frame_rate(hz: float | None) -> dict[str, Any]:
    return {} if hz is None else {"camera": {"frame_rate": hz}}


def _accel(a: float | None) -> dict[str, Any]:
    return {} if a is None else {"robot": {"accel_max": a}}


def profile_overrides(name: str) -> dict[str, Any]:
    """The ``make`` overrides of a shipped sensor profile: ``sensor_profile=name``, after
    :func:`platoon_env.scenarios.profiles.load_profile` has checked that the profile exists and
    is valid (it raises ``ScenarioError`` otherwise)."""
    load_profile(name)
    return {PROFILE_OPTION: name}


#: The realism axes of the frontier, each run alone (:func:`build_grid`).
AXES: dict[str, Axis] = by_name(
    Axis(
        "camera_noise",
        "camera position noise sigma [cm]",
        (0.0, 0.5, 1.0, 2.0, 5.0, 10.0),
        (0.0, 5.0),
        _noise,
    ),
    Axis("detection", "detection probability", (1.0, 0.95, 0.8, 0.5), (1.0, 0.5), _detection),
    Axis("latency", "camera latency [ms]", (0.0, 10.0, 30.0, 50.0, 100.0), (0.0, 50.0), _latency),
    Axis(
        "frame_rate",
        "camera frame rate [Hz]",
        (None, 30.0, 15.0),
        (None, 15.0),
        _frame_rate,
        none_label="every step",
    ),
    Axis("accel_max", "accel_max [m/s²]", (None, 2.0, 1.0, 0.5), (None, 0.5), _accel),
    Axis("profile", "sensor profile", ("aruco",), ("aruco",), profile_overrides),
)
