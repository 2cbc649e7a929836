"""Finding, reading and building scenarios: shipped names, YAML paths, or dicts.

See ``docs/scenarios.md`` (the schema) and ``docs/api.md`` (the public names).
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.schema import ScenarioConfig, ScenarioError, parse_scenario

_DATA = "platoon_env.scenarios.data"

ScenarioLike = str | Path | Mapping[str, Any] | ScenarioConfig | Scenario


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios (usable wherever a scenario is expected)."""
    names = [
        p.name[: -len(".yaml")]
        for p in resources.files(_DATA).iterdir()
        if p.name.endswith(".yaml")
    ]
    return sorted(names)


def read_yaml(text: str, source: str) -> Any:
    """Safe-load YAML; errors name the file and line. Tags that would build Python objects are
    rejected (never executed)."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{source}:{mark.line + 1}" if mark is not None else source
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(f"{where}: malformed YAML: {problem}") from exc


def _config_from_file(path: Path) -> ScenarioConfig:
    if not path.is_file():
        raise ScenarioError(f"{path}: no such scenario file")
    data = read_yaml(path.read_text(encoding="utf-8"), str(path))
    try:
        return parse_scenario(data)
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: {exc}") from exc


def load_config(scenario: ScenarioLike) -> ScenarioConfig:
    """Parse a scenario given as a shipped name, a YAML path or a mapping (not yet built)."""
    if isinstance(scenario, Scenario):
        return scenario.config
    if isinstance(scenario, ScenarioConfig):
        return scenario
    if isinstance(scenario, Mapping):
        return parse_scenario(scenario)
    if isinstance(scenario, (str, Path)):
        text = str(scenario)
        if text in list_scenarios():
            ref = resources.files(_DATA).joinpath(f"{text}.yaml")
            return parse_scenario(read_yaml(ref.read_text(encoding="utf-8"), f"{text}.yaml"))
        path = Path(text)
        if path.suffix in (".yaml", ".yml") or path.exists():
            return _config_from_file(path)
        raise ScenarioError(
            f"unknown scenario {text!r}: not a shipped name ({', '.join(list_scenarios())}) "
            "nor a YAML file"
        )
    raise TypeError(f"scenario must be a name, a path or a mapping, got {type(scenario).__name__}")


def load_scenario(scenario: ScenarioLike) -> Scenario:
    """Load, validate and build a fixed scenario from a shipped name, a YAML path or a dict.

    A :class:`Scenario` is returned as is. Raises :class:`ScenarioError` for a procedural
    scenario (a ``generator`` block, e.g. ``procedural_train``): it has no single workspace;
    :func:`platoon_env.scenarios.source.scenario_source` gives its
    :class:`~platoon_env.scenarios.source.ProceduralSource` (``.initial()`` is layout 0,
    ``.sample(rng)`` an episode's layout).
    """
    if isinstance(scenario, Scenario):
        return scenario
    return build_scenario(load_config(scenario))
