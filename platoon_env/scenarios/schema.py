"""A scenario's mapping form (``docs/scenarios.md``) and its typed config: parsing and unparsing.

A scenario file is YAML; :func:`platoon_env.scenarios.loader.load_scenario` safe-loads it and
passes the resulting mapping to :func:`parse_scenario`, which builds the frozen dataclasses of
:mod:`platoon_env.config`, rejects unknown keys (naming their path, e.g.
``scenario.leader.sped``) and checks every field
(:func:`~platoon_env.scenarios.validate.check_ranges`).
:func:`config_to_mapping` is its exact inverse, so keyword overrides
(:mod:`platoon_env.scenarios.options`) are checked by the same rules as a file; its output is
also the canonical form that :mod:`~platoon_env.scenarios.fingerprint` hashes.

This module is the public home of the whole schema: it re-exports the config types and the
error (:mod:`platoon_env.config`), the range checks and their bounds
(:mod:`platoon_env.scenarios.validate`) and the trajectory rules
(:mod:`platoon_env.scenarios.trajectory`).

Units are SI throughout: metres, seconds, radians.
"""

from __future__ import annotations

import math
import numbers
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING, fields, is_dataclass
from typing import Any, TypeVar

import numpy as np

from platoon_env.config import (
    GENERATOR_KINDS,
    GENERATOR_SPLITS,
    GENERATOR_TIERS,
    CameraConfig,
    CameraNoiseConfig,
    FormationConfig,
    FreeSpaceConfig,
    GeneratorConfig,
    InitialConfig,
    LeaderConfig,
    ObservationConfig,
    Point,
    Polygon,
    PPCConfig,
    ProximityConfig,
    RewardConfig,
    RobotConfig,
    SafetyConfig,
    ScenarioConfig,
    ScenarioError,
    SimulationConfig,
    TrajectorySample,
    WorkspaceConfig,
    field_error,
    field_key,
    has_realism,
    is_identity,
    latency_steps,
    shown,
)
from platoon_env.scenarios.trajectory import (
    MAX_TRAJECTORY_DURATION,
    MAX_TRAJECTORY_SAMPLES,
    MIN_TRAJECTORY_INTERVAL,
    TRAJECTORY_HEADING_TOLERANCE,
    TRAJECTORY_LIMIT_TOLERANCE,
    TRAJECTORY_POSITION_TOLERANCE,
    check_trajectory_times,
    fit_leader_to_drive,
    trajectory_mean_speed,
    trajectory_route,
)
from platoon_env.scenarios.validate import (
    ACTION_BOUND_RANGE,
    MAX_CONTROL_PERIOD,
    MAX_COORDINATE,
    MAX_EPISODE_STEPS,
    MAX_FOLLOWERS,
    MAX_LATENCY_STEPS,
    MAX_PHYSICS_SUBSTEPS,
    MAX_SETTLE_TIME,
    MAX_SPEED_VARIATION,
    MIN_CONTROL_PERIOD,
    check_ranges,
)
from platoon_env.violations import VIOLATION_CAUSES

__all__ = [
    "ACTION_BOUND_RANGE",
    "GENERATOR_KINDS",
    "GENERATOR_SPLITS",
    "GENERATOR_TIERS",
    "MAX_CONTROL_PERIOD",
    "MAX_COORDINATE",
    "MAX_EPISODE_STEPS",
    "MAX_FOLLOWERS",
    "MAX_LATENCY_STEPS",
    "MAX_PHYSICS_SUBSTEPS",
    "MAX_SETTLE_TIME",
    "MAX_SPEED_VARIATION",
    "MAX_TRAJECTORY_DURATION",
    "MAX_TRAJECTORY_SAMPLES",
    "MIN_CONTROL_PERIOD",
    "MIN_TRAJECTORY_INTERVAL",
    "TRAJECTORY_HEADING_TOLERANCE",
    "TRAJECTORY_LIMIT_TOLERANCE",
    "TRAJECTORY_POSITION_TOLERANCE",
    "VIOLATION_CAUSES",
    "CameraConfig",
    "CameraNoiseConfig",
    "FormationConfig",
    "FreeSpaceConfig",
    "GeneratorConfig",
    "InitialConfig",
    "LeaderConfig",
    "ObservationConfig",
    "PPCConfig",
    "Point",
    "Polygon",
    "ProximityConfig",
    "RewardConfig",
    "RobotConfig",
    "SafetyConfig",
    "ScenarioConfig",
    "ScenarioError",
    "SimulationConfig",
    "TrajectorySample",
    "WorkspaceConfig",
    "check_ranges",
    "check_trajectory_times",
    "config_to_mapping",
    "field_error",
    "has_realism",
    "latency_steps",
    "parse_scenario",
    "parse_section",
    "trajectory_mean_speed",
    "trajectory_route",
]

T = TypeVar("T")

# --------------------------------------------------------------------------------------------
# Parsing: mapping -> dataclasses, with the path of every offending key in the message.
# --------------------------------------------------------------------------------------------


def _optional_of(tp: Any) -> tuple[Any, bool] | None:
    """``(the non-None type, whether None is allowed)`` of a union ``tp``; None for a type
    that is not a union."""
    if typing.get_origin(tp) not in (typing.Union, types.UnionType):
        return None
    args = typing.get_args(tp)
    non_none = [a for a in args if a is not type(None)]
    return non_none[0], len(non_none) < len(args)


# Python callers (keyword overrides) may pass numpy scalars, so the numeric checks go by the
# numbers ABCs; bools are numbers to Python but never to a scenario.
def _parse_number(value: Any, path: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise field_error(path, f"expected a number, got {shown(value)}")
    try:
        out = float(value)
    except OverflowError:  # an int (or Fraction) beyond float's range, e.g. YAML 10**400
        out = math.inf
    if not math.isfinite(out):
        raise field_error(path, f"must be finite, got {shown(value)}")
    return out


def _parse_int(value: Any, path: str) -> int:
    # A float, even 2.0, is rejected: YAML ``followers: 2.0`` always was, and a silent
    # int(2.7) == 2 is the bug this guards against.
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise field_error(path, f"expected an integer, got {shown(value)}")
    return int(value)


def _parse_value(tp: Any, value: Any, path: str) -> Any:
    optional = _optional_of(tp)
    if optional is not None:
        inner, allows_none = optional
        if value is None:
            if allows_none:
                return None
            raise field_error(path, "must not be empty")
        return _parse_value(inner, value, path)
    if tp is float:
        return _parse_number(value, path)
    if tp is int:
        return _parse_int(value, path)
    if tp is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise field_error(path, f"expected a boolean (true or false), got {value!r}")
        return bool(value)
    if tp is str:
        if not isinstance(value, str):
            raise field_error(path, f"expected a string, got {value!r}")
        return str(value)
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        is_array = isinstance(value, np.ndarray) and value.ndim > 0
        if not (is_array or isinstance(value, (list, tuple))):
            raise field_error(path, f"expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_parse_value(args[0], v, f"{path}[{k}]") for k, v in enumerate(value))
        if len(value) != len(args):
            raise field_error(path, f"expected {len(args)} values, got {len(value)}")
        pairs = enumerate(zip(args, value, strict=True))
        return tuple(_parse_value(a, v, f"{path}[{k}]") for k, (a, v) in pairs)
    if isinstance(tp, type) and hasattr(tp, "__dataclass_fields__"):
        return parse_section(tp, value, path)
    raise TypeError(f"unsupported field type {tp!r} at {path}")  # pragma: no cover


def parse_section(cls: type[T], data: Any, path: str) -> T:
    """Build dataclass ``cls`` from a mapping, rejecting unknown keys and wrong types.

    ``path`` is the dotted location of ``data`` in the file, used in every error message.
    """
    if not isinstance(data, Mapping):
        raise field_error(path, f"expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    known = {field_key(f): f for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in data if k not in known)
    if unknown:
        raise field_error(
            f"{path}.{unknown[0]}", f"unknown key (expected one of {', '.join(sorted(known))})"
        )
    kwargs: dict[str, Any] = {}
    for key, f in known.items():
        if key in data:
            kwargs[f.name] = _parse_value(hints[f.name], data[key], f"{path}.{key}")
        elif f.default is MISSING and f.default_factory is MISSING:
            raise field_error(f"{path}.{key}", "required key is missing")
    return cls(**kwargs)


def parse_scenario(data: Any, path: str = "scenario") -> ScenarioConfig:
    """Parse and range-check a scenario mapping (the schema of ``docs/scenarios.md``).

    Raises :class:`ScenarioError` naming the field for unknown keys, wrong types and
    out-of-range parameters (:func:`~platoon_env.scenarios.validate.check_ranges`). A
    ``leader.trajectory`` without ``leader.speed`` gets its mean speed
    (:func:`trajectory_mean_speed`). With ``leader.drive: retime`` the leader is slowed to the
    robots' drive (:func:`~platoon_env.scenarios.trajectory.fit_leader_to_drive`).
    """
    cfg = parse_section(ScenarioConfig, _with_trajectory_speed(data, path), path)
    if cfg.leader.drive == "retime":
        if cfg.leader.trajectory:  # retiming reads the sample times: they must be valid
            check_trajectory_times(cfg.leader.trajectory, f"{path}.leader.trajectory")
        cfg = fit_leader_to_drive(cfg)
    check_ranges(cfg, path)
    return cfg


#: The parsed type of ``leader.trajectory``.
_TRAJECTORY_TYPE = tuple[TrajectorySample, ...]


def _with_trajectory_speed(data: Any, path: str) -> Any:
    """``data`` with ``leader.speed`` set to the trajectory's mean speed, when the leader block
    gives a ``trajectory`` and no ``speed`` (anything else is returned as is)."""
    if not isinstance(data, Mapping):
        return data
    leader = data.get("leader")
    if not isinstance(leader, Mapping) or "trajectory" not in leader or "speed" in leader:
        return data
    where = f"{path}.leader.trajectory"
    samples = _parse_value(_TRAJECTORY_TYPE, leader["trajectory"], where)
    check_trajectory_times(samples, where)
    return {**data, "leader": {**leader, "speed": trajectory_mean_speed(samples)}}


# --------------------------------------------------------------------------------------------
# Unparsing: dataclasses -> the mapping parse_scenario reads (the canonical form).
# --------------------------------------------------------------------------------------------


def _at_default(f: Any, value: Any) -> bool:
    """Whether ``value`` of the dataclass field ``f`` is its default (a required field has
    none)."""
    if f.default is not MISSING:
        return bool(value == f.default)
    if f.default_factory is not MISSING:
        return bool(value == f.default_factory())
    return False


def _to_plain(tp: Any, value: Any) -> Any:
    """``value`` of the schema type ``tp`` as plain data: a section as a mapping, a tuple as a
    list, a numpy scalar as a Python one, and a number where the schema's type is float as a
    float (``accel_max=1`` and ``accel_max=1.0`` are one config, so one canonical form)."""
    if is_dataclass(value) and not isinstance(value, type):
        return _section_to_mapping(value)
    if isinstance(value, np.generic):  # a config built in code may hold numpy scalars
        value = value.item()
    optional = _optional_of(tp)
    if optional is not None:
        return None if value is None else _to_plain(optional[0], value)
    if isinstance(value, (tuple, list, np.ndarray)):
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return [_to_plain(args[0], v) for v in value]
        if len(args) == len(value):
            return [_to_plain(a, v) for a, v in zip(args, value, strict=True)]
        return [_to_plain(Any, v) for v in value]
    if tp is float and isinstance(value, numbers.Real) and not isinstance(value, bool):
        return float(value)
    return value


def _section_to_mapping(section: Any) -> dict[str, Any]:
    hints = typing.get_type_hints(type(section))
    out: dict[str, Any] = {}
    for f in fields(section):
        value = getattr(section, f.name)
        # A field at its default is left out, as a file would leave it out, so that a field
        # added later keeps every stored fingerprint; an identity-bearing field (written out
        # at its default when fingerprints were first recorded) is kept, so theirs stay.
        if _at_default(f, value) and not is_identity(f):
            continue
        out[field_key(f)] = _to_plain(hints[f.name], value)
    return out


def config_to_mapping(cfg: ScenarioConfig) -> dict[str, Any]:
    """The mapping form of ``cfg``: the exact inverse of :func:`parse_scenario`, and the
    canonical form that a fingerprint hashes.

    Keys are the file's (``ppc.lambda``, not ``lambda_``), tuples become lists, numpy scalars
    become Python ones, and a number where the schema's type is float becomes a float. A field
    at its default is omitted (so are None-valued optional blocks, e.g. ``ppc``,
    ``generator``), unless it is identity-bearing (:func:`platoon_env.config.identity`): so
    ``parse_scenario(config_to_mapping(cfg)) == cfg`` and the result is plain YAML
    (``yaml.safe_dump`` writes it). Units are those of the schema: metres, seconds, radians.
    """
    return _section_to_mapping(cfg)
