"""Scenarios: the YAML schema, its typed config objects, the built :class:`Scenario`, and the
:class:`ScenarioSource` an env draws each episode's scenario from (one fixed workspace, or a
procedural family)."""

from platoon_env.config import ScenarioConfig, ScenarioError
from platoon_env.scenarios.loader import list_scenarios, load_config, load_scenario
from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.source import (
    FixedSource,
    ProceduralSource,
    ScenarioSource,
    scenario_source,
)
from platoon_env.violations import VIOLATION_CAUSES

__all__ = [
    "VIOLATION_CAUSES",
    "FixedSource",
    "ProceduralSource",
    "Scenario",
    "ScenarioConfig",
    "ScenarioError",
    "ScenarioSource",
    "build_scenario",
    "list_scenarios",
    "load_config",
    "load_scenario",
    "scenario_source",
]
