"""Keyword overrides of a scenario (``platoon_env.make(..., u_max=2)``), checked like a file.

:func:`apply_overrides` turns the scenario back into its mapping form
(:func:`~platoon_env.scenarios.schema.config_to_mapping`), merges the overrides into it and
parses the result with :func:`~platoon_env.scenarios.schema.parse_scenario`, so an override is
held to exactly the rules of a YAML file: types, finiteness, ranges and cross-field rules.

Two kinds of option:

* **Shortcuts** (:data:`SCENARIO_OPTIONS`) set one field: ``control_period`` [s],
  ``physics_substeps``, ``max_episode_steps`` (``simulation.*``); ``terminate_on``
  (``safety.terminate_on``: one cause name, or an iterable of them); ``followers``;
  ``perturb`` (``initial.perturb``); ``u_max`` [m/s] and ``omega_max`` [rad/s] (``robot.*``).
* **Blocks** (:data:`BLOCK_OPTIONS`): a mapping for a top-level block of the schema, merged key
  by key into the scenario's block, nested mappings too (``camera={"noise": {"position":
  0.01}}`` keeps the other noise fields), e.g. ``camera={"half_angle": 0.5}``. In
  ``workspace`` a given key replaces the scenario's (a new outline or obstacle list). In
  ``leader`` the two modes replace each other: a given ``trajectory`` drops the scenario's
  ``path`` (and its ``speed``, which a trajectory derives), a given ``path`` drops its
  ``trajectory``. Keys are the file's keys (``ppc={"lambda": 0.5}``). The ``observation``
  block selects the observation (``observation={"task_aware": True}``: the task-aware 13
  values of :mod:`platoon_env.observation`).
* **A sensor profile** (:data:`PROFILE_OPTION`, ``sensor_profile="aruco"``): a shipped name or
  a YAML file of :mod:`platoon_env.scenarios.profiles`, whose camera, proximity and robot
  blocks are merged before the block options (so those override single fields of it).

A value of None, for either kind, means "not overridden".

Errors: a bad value is a :class:`~platoon_env.config.ScenarioError` (a
``ValueError``) whose message starts with ``where`` and names the option as passed, then the
file path in parentheses, e.g. ``make(): physics_substeps: expected an integer, got 1.5
(scenario.simulation.physics_substeps)``. An unknown option name is a ``TypeError`` in
Python's own wording, ``make() got an unexpected keyword argument 'frameskip'`` (libraries
such as TorchRL's ``GymEnv`` match that phrase to drop a keyword the env does not take), then
the valid names (:func:`unexpected_keyword`).

Env-level flags that are not part of the scenario (``diagnostics``) are checked with
:func:`check_bool`.
"""

from __future__ import annotations

import typing
from collections.abc import Iterable, Mapping
from dataclasses import is_dataclass
from typing import Any

import numpy as np

from platoon_env.config import ScenarioConfig, ScenarioError
from platoon_env.scenarios.profiles import load_profile
from platoon_env.scenarios.schema import config_to_mapping, parse_scenario
from platoon_env.violations import VIOLATION_CAUSES

#: Shortcut option -> (block, key) of the field it sets; block None is a top-level field.
_SHORTCUT_FIELDS: dict[str, tuple[str | None, str]] = {
    "control_period": ("simulation", "control_period"),
    "physics_substeps": ("simulation", "physics_substeps"),
    "max_episode_steps": ("simulation", "max_episode_steps"),
    "terminate_on": ("safety", "terminate_on"),
    "followers": (None, "followers"),
    "perturb": ("initial", "perturb"),
    "u_max": ("robot", "u_max"),
    "omega_max": ("robot", "omega_max"),
}

#: Names of the shortcut options, each setting one scenario field (see the module docstring).
SCENARIO_OPTIONS: tuple[str, ...] = tuple(_SHORTCUT_FIELDS)


def _is_block(tp: Any) -> bool:
    return any(is_dataclass(a) for a in (tp, *typing.get_args(tp)))


#: Names of the block options: every top-level block of the schema, in its field order
#: (derived from :class:`ScenarioConfig`, so a new block is overridable without a change here).
BLOCK_OPTIONS: tuple[str, ...] = tuple(
    name for name, tp in typing.get_type_hints(ScenarioConfig).items() if _is_block(tp)
)

#: The option naming a sensor profile (:mod:`platoon_env.scenarios.profiles`): its blocks are
#: merged first, so the block options given beside it override single fields of it.
PROFILE_OPTION = "sensor_profile"

#: Every option :func:`apply_overrides` accepts: the shortcuts, the blocks and the profile.
OVERRIDE_OPTIONS: tuple[str, ...] = (*SCENARIO_OPTIONS, *BLOCK_OPTIONS, PROFILE_OPTION)

_ROOT = "scenario"


def unexpected_keyword(where: str, unknown: Iterable[Any], valid: Iterable[str]) -> TypeError:
    """The ``TypeError`` for keywords ``where`` does not take, worded as Python words it.

    ``where`` is the callable with its parentheses (``"make()"``). The message names the first
    unknown keyword as Python does (``make() got an unexpected keyword argument 'frameskip'``:
    the phrase TorchRL's ``GymEnv`` and others match), then any further ones, then the valid
    names, e.g. ``make() got an unexpected keyword argument 'u_maxx' (valid keywords:
    control_period, ...)``.
    """
    names = [repr(k) for k in unknown]
    if not names:
        raise ValueError("unexpected_keyword() needs at least one unknown keyword")
    also = f" (and {', '.join(names[1:])})" if len(names) > 1 else ""
    return TypeError(
        f"{where} got an unexpected keyword argument {names[0]}{also} "
        f"(valid keywords: {', '.join(valid)})"
    )


def check_bool(name: str, value: Any, where: str) -> bool:
    """``value`` as a bool if it is one (``bool`` or ``numpy.bool_``).

    Anything else, including ``0``, ``1`` and ``"no"``, is a :class:`ScenarioError` naming
    ``name`` and the value (``where`` prefixes the message, e.g. ``"make()"``): a truthiness
    test would read ``diagnostics="no"`` as True.
    """
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise ScenarioError(f"{where}: {name}: expected True or False, got {value!r}")


def _causes(value: Any, where: str) -> list[Any]:
    # A string is iterable too: without this, "collision_robot" would be 15 one-letter causes.
    if isinstance(value, str):
        return [value]
    if isinstance(value, (bytes, bytearray, Mapping)) or not isinstance(value, Iterable):
        raise ScenarioError(
            f"{where}: terminate_on: expected a cause name or an iterable of them (some of "
            f"{', '.join(VIOLATION_CAUSES)}), got {value!r}"
        )
    if isinstance(value, (set, frozenset)):
        # Sets have no order; the config should not depend on string hashing.
        rank = {c: k for k, c in enumerate(VIOLATION_CAUSES)}
        return sorted(value, key=lambda c: (rank.get(c, len(rank)), repr(c)))
    return list(value)


def _relabel(
    exc: ScenarioError, labels: Mapping[str, str], given: Iterable[str], where: str
) -> ScenarioError:
    """``exc`` reworded to name the option that holds its field, if one does."""
    path = exc.path
    if path is None or exc.reason is None:
        return ScenarioError(f"{where}: {exc}", path=path, reason=exc.reason)
    # The longest matching prefix names the most specific option: a shortcut or a block key
    # before the whole block.
    for prefix in sorted(labels, key=len, reverse=True):
        if path == prefix or path.startswith((prefix + ".", prefix + "[")):
            label = labels[prefix] + path[len(prefix) :]
            return ScenarioError(
                f"{where}: {label}: {exc.reason} ({path})", path=path, reason=exc.reason
            )
    # A field no override touched, broken by one that did (a cross-field rule).
    return ScenarioError(
        f"{where}: {path}: {exc.reason} (with the overrides {', '.join(given)})",
        path=path,
        reason=exc.reason,
    )


def _leader_base(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """The scenario's leader block without what ``update`` replaces: ``path`` and
    ``trajectory`` are alternatives (giving one drops the other, and a trajectory derives its
    own ``speed``)."""
    out = dict(base)
    if "trajectory" in update and "path" not in update:
        out.pop("path", None)
        if "speed" not in update:
            out.pop("speed", None)
    if "path" in update and "trajectory" not in update:
        out.pop("trajectory", None)
    return out


def _merged(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``update`` merged in, nested mappings key by key (``camera={"noise":
    {"position": 0.01}}`` keeps the other noise fields)."""
    out = dict(base)
    for key, value in update.items():
        old = out.get(key)
        if isinstance(value, Mapping) and isinstance(old, Mapping):
            out[key] = _merged(old, value)
        else:
            out[key] = value
    return out


def apply_overrides(
    cfg: ScenarioConfig, overrides: Mapping[str, Any], *, where: str = "make()"
) -> ScenarioConfig:
    """A new config: ``cfg`` with ``overrides`` applied and validated as a scenario file is.

    Args:
        cfg: the scenario to start from.
        overrides: option name -> value, for names in :data:`OVERRIDE_OPTIONS` (shortcuts and
            blocks, see the module docstring); None values are ignored.
        where: the caller, e.g. ``"make()"`` or ``"BatchedPlatoon()"``, to start messages.

    Returns:
        ``cfg`` itself if nothing is overridden, else a newly parsed :class:`ScenarioConfig`.

    Raises:
        TypeError: an option name is not in :data:`OVERRIDE_OPTIONS` (worded by
            :func:`unexpected_keyword`).
        ScenarioError: a value is invalid, a block value is not a mapping, or a field is given
            both as a shortcut and in its block; the message names the option and the value.
    """
    given = {k: v for k, v in overrides.items() if v is not None}
    unknown = [k for k in given if k not in OVERRIDE_OPTIONS]
    if unknown:
        raise unexpected_keyword(where, unknown, OVERRIDE_OPTIONS)
    if not given:
        return cfg
    data = config_to_mapping(cfg)
    labels: dict[str, str] = {}  # file path -> option label, to reword parse errors
    if PROFILE_OPTION in given:
        profile = load_profile(given[PROFILE_OPTION])
        for name, fields in profile.items():
            data[name] = _merged(data.get(name, {}), fields)
            for key in fields:
                labels[f"{_ROOT}.{name}.{key}"] = (
                    f"{PROFILE_OPTION} {given[PROFILE_OPTION]!r}: {name}.{key}"
                )
    for name in BLOCK_OPTIONS:
        if name not in given:
            continue
        block = given[name]
        if not isinstance(block, Mapping):
            raise ScenarioError(
                f"{where}: {name}: expected a mapping of {name} keys, got {block!r}",
                path=f"{_ROOT}.{name}",
            )
        labels[f"{_ROOT}.{name}"] = name
        for key in block:
            labels[f"{_ROOT}.{name}.{key}"] = f"{name}.{key}"
        base = data.get(name, {})
        if name == "leader":
            base = _leader_base(base, block)
        data[name] = (
            {**base, **block}
            if name == "workspace"  # a new outline or obstacle list replaces the old one
            else _merged(base, block)
        )
    for name in SCENARIO_OPTIONS:
        if name not in given:
            continue
        value = _causes(given[name], where) if name == "terminate_on" else given[name]
        section, key = _SHORTCUT_FIELDS[name]
        if section is None:
            data[key] = value
            labels[f"{_ROOT}.{key}"] = name
            continue
        block = given.get(section)
        if block is not None and key in block:
            raise ScenarioError(
                f"{where}: {name} is given twice, as {name}={given[name]!r} and as "
                f"{section}.{key}={block[key]!r}; give one",
                path=f"{_ROOT}.{section}.{key}",
            )
        data[section] = {**data.get(section, {}), key: value}
        labels[f"{_ROOT}.{section}.{key}"] = name
    try:
        return parse_scenario(data, _ROOT)
    except ScenarioError as exc:
        # The file-form message alone would name a path the caller never wrote.
        raise _relabel(exc, labels, given, where) from None


__all__ = [
    "BLOCK_OPTIONS",
    "OVERRIDE_OPTIONS",
    "PROFILE_OPTION",
    "SCENARIO_OPTIONS",
    "apply_overrides",
    "check_bool",
    "unexpected_keyword",
]
