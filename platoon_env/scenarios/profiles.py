"""Sensor profiles: named sets of sensing and actuation realism (``docs/realism.md``).

A profile is a YAML mapping of partial scenario blocks, ``{camera: {...}, proximity: {...},
robot: {...}, leader: {drive: ...}}``, holding the realism fields of the schema (camera noise,
detection, frame rate and latency; proximity noise; actuator lag, rate limits and velocity
box) and, for a profile that names its robot, ``leader.drive`` (the leader is one of those
robots: its motion is held to, or slowed to, their drive). ``extends: NAME`` builds on a
shipped profile (its blocks first, this profile's keys over them). It describes a kind of hardware,
not a scenario: the same profile merges into any scenario
(:func:`platoon_env.scenarios.options.apply_overrides`, ``make(..., sensor_profile="aruco")``),
whose field of view, ranges and geometry it leaves alone.

Shipped profiles live in ``platoon_env/scenarios/profiles/*.yaml``: ``ideal`` (the schema's
defaults, the paper's ideal sensors) and ``aruco`` (an ArUco marker camera, a 2D LiDAR and the
acceleration limits of a TurtleBot3-class robot, each number with its published source).

:func:`load_profile` checks the form of a profile: a mapping whose blocks are among
:data:`PROFILE_BLOCKS`, each a mapping of keys that block of the schema has. The values are
checked when the profile is merged into a scenario, by the scenario's own rules (ranges,
latency a whole number of control periods, ...).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import fields, is_dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from platoon_env.config import (
    CameraConfig,
    CameraNoiseConfig,
    LeaderConfig,
    ProximityConfig,
    RobotConfig,
    ScenarioError,
    field_key,
)
from platoon_env.scenarios.loader import read_yaml

#: The package whose ``profiles/`` folder holds the shipped profiles.
_PACKAGE = "platoon_env.scenarios"
_FOLDER = "profiles"
_SUFFIX = ".yaml"

#: The scenario blocks a profile may set, each with the schema section that reads it.
_BLOCK_SECTIONS: dict[str, type] = {
    "camera": CameraConfig,
    "proximity": ProximityConfig,
    "robot": RobotConfig,
    "leader": LeaderConfig,
}

#: Blocks of which a profile may set only some keys: of the leader, only whether it keeps the
#: robots' drive (``leader.drive``: a profile that names a robot makes the leader one of them).
_BLOCK_KEYS: dict[str, tuple[str, ...]] = {"leader": ("drive",)}

#: The key naming the shipped profile a profile builds on (its blocks merged first).
EXTENDS = "extends"

#: Names of the blocks a profile may hold (a sensor profile never touches the geometry).
PROFILE_BLOCKS: tuple[str, ...] = tuple(_BLOCK_SECTIONS)

#: Nested mappings inside a block: ``camera.noise`` is a section of its own.
_NESTED_SECTIONS: dict[tuple[str, str], type] = {("camera", "noise"): CameraNoiseConfig}

#: What :func:`load_profile` accepts: a shipped name or the path of a YAML file.
ProfileLike = str | os.PathLike[str]


def _folder() -> Any:
    return resources.files(_PACKAGE).joinpath(_FOLDER)


def list_profiles() -> list[str]:
    """Names of the shipped sensor profiles, sorted (e.g. ``["aruco", "ideal"]``)."""
    names = [
        p.name[: -len(_SUFFIX)]
        for p in _folder().iterdir()
        if p.name.endswith(_SUFFIX) and p.is_file()
    ]
    return sorted(names)


def _keys_of(section: type) -> list[str]:
    assert is_dataclass(section)
    return sorted(field_key(f) for f in fields(section))


def _block_keys(name: str) -> list[str]:
    return sorted(_BLOCK_KEYS.get(name, ())) or _keys_of(_BLOCK_SECTIONS[name])


def _shipped() -> str:
    return ", ".join(list_profiles())


def _error(source: str, message: str) -> ScenarioError:
    return ScenarioError(
        f"sensor profile {source}: {message} (shipped profiles: {_shipped()})", reason=message
    )


def _check_keys(source: str, where: str, block: Any, known: list[str]) -> None:
    if not isinstance(block, Mapping):
        raise _error(source, f"{where}: expected a mapping of {where} keys, got {block!r}")
    unknown = sorted(str(k) for k in block if k not in known)
    if unknown:
        raise _error(
            source, f"{where}.{unknown[0]}: unknown key (expected one of {', '.join(known)})"
        )


#: How many profiles deep ``extends`` may go.
_MAX_EXTENDS = 4


def _validated(data: Any, source: str, depth: int = 0) -> dict[str, dict[str, Any]]:
    """The profile's blocks as plain dicts, after checking their form; a profile that
    ``extends`` a shipped one gets that one's blocks first, its own keys over them
    (``camera.noise`` merged key by key)."""
    if not isinstance(data, Mapping):
        got = "an empty file" if data is None else repr(data)
        raise _error(
            source,
            f"expected a mapping of blocks (some of {', '.join(PROFILE_BLOCKS)}), got {got}",
        )
    unknown = sorted(str(k) for k in data if k not in _BLOCK_SECTIONS and k != EXTENDS)
    if unknown:
        raise _error(
            source,
            f"unknown block {', '.join(repr(k) for k in unknown)} "
            f"(a profile may set only {', '.join(PROFILE_BLOCKS)})",
        )
    out: dict[str, dict[str, Any]] = {}
    if EXTENDS in data:
        base = data[EXTENDS]
        if not isinstance(base, str) or base not in list_profiles():
            raise _error(source, f"{EXTENDS}: must name a shipped profile, got {base!r}")
        if depth >= _MAX_EXTENDS:
            raise _error(source, f"{EXTENDS}: more than {_MAX_EXTENDS} profiles deep (a cycle?)")
        out = _shipped_profile(base, depth + 1)
    for name, block in data.items():
        if name == EXTENDS:
            continue
        _check_keys(source, name, block, _block_keys(name))
        copied: dict[str, Any] = dict(out.get(name, {}))
        for key, value in block.items():
            nested = _NESTED_SECTIONS.get((name, key))
            if nested is not None:
                _check_keys(source, f"{name}.{key}", value, _keys_of(nested))
                value = {**copied.get(key, {}), **value}
            copied[key] = value
        out[name] = copied
    return out


def _parsed(text: str, filename: str, source: str, depth: int = 0) -> dict[str, dict[str, Any]]:
    try:
        data = read_yaml(text, filename)
    except ScenarioError as exc:  # malformed YAML: the message names the file and line
        raise _error(source, str(exc)) from exc
    return _validated(data, source, depth)


def _shipped_profile(name: str, depth: int = 0) -> dict[str, dict[str, Any]]:
    ref = _folder().joinpath(f"{name}{_SUFFIX}")
    return _parsed(ref.read_text(encoding="utf-8"), f"{_FOLDER}/{name}{_SUFFIX}", repr(name), depth)


def load_profile(profile: ProfileLike) -> dict[str, dict[str, Any]]:
    """The blocks of a sensor profile, ready to merge into a scenario.

    Args:
        profile: a shipped name (see :func:`list_profiles`) or the path of a YAML file of the
            same form (``.yaml``/``.yml``, or any existing file).

    Returns:
        A new ``{block: {key: value}}`` dict for some of :data:`PROFILE_BLOCKS` (the file's
        keys; ``camera.noise`` a nested dict). Mutating it does not change the profile.

    Raises:
        ScenarioError: the name is neither shipped nor a file, the YAML is malformed, the
            content is not a mapping, or it has a block or key the schema does not know; the
            message names the profile and lists the shipped ones.
        TypeError: ``profile`` is neither a string nor a path.
    """
    if not isinstance(profile, (str, os.PathLike)):
        raise TypeError(f"sensor profile must be a name or a path, got {type(profile).__name__}")
    text = os.fspath(profile)
    if isinstance(profile, str) and text in list_profiles():
        return _shipped_profile(text)
    path = Path(text)
    if path.suffix in (".yaml", ".yml") or path.exists():
        source = repr(str(path))
        if not path.is_file():
            raise _error(source, "no such file")
        return _parsed(path.read_text(encoding="utf-8"), str(path), source)
    raise _error(repr(text), "not a shipped profile name nor a YAML file")


__all__ = ["PROFILE_BLOCKS", "ProfileLike", "list_profiles", "load_profile"]
