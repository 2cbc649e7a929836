"""Scenarios: the YAML schema, its typed config objects, and the built :class:`Scenario`."""

from platoon_env.scenarios.loader import list_scenarios, load_config, load_scenario
from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.schema import VIOLATION_CAUSES, ScenarioConfig, ScenarioError

__all__ = [
    "VIOLATION_CAUSES",
    "Scenario",
    "ScenarioConfig",
    "ScenarioError",
    "build_scenario",
    "list_scenarios",
    "load_config",
    "load_scenario",
]
