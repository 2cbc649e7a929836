"""Comparing generated layouts (platoon_env.scenarios.procedural), for the tier tests."""

from __future__ import annotations

import numpy as np

from platoon_env.scenarios.scenario import Scenario


def same_layout(a: Scenario, b: Scenario) -> bool:
    """Whether two scenarios have the same walls and the same leader path."""
    return np.array_equal(a.workspace.edges, b.workspace.edges) and np.array_equal(
        a.leader_path, b.leader_path
    )
