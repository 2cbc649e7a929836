"""The analytic laws acting on the fast path: one law per env copy of a batched core.

The paper's PPC law (:class:`baselines.PPCPolicy`) and the filtered PPC
(:class:`baselines.filtered_ppc.FilteredPPCPolicy`) act per follower of one env; the fast
learner steps hundreds of env copies at once. :class:`BatchedExpert` runs one instance of a
law per copy of a :class:`~platoon_env.batched.BatchedPlatoon` (rebuilt at each of that copy's
episode starts, on its current scenario) and maps their commands into the learner's
normalised action space with :func:`to_normalised`. Two learners use it: behaviour cloning
(:mod:`training.bc`: the law is the expert whose actions label every visited state) and the
residual policies of :mod:`training.fast_ppo` (``residual``: the policy's mean is the law's
clipped, normalised command plus the network's output).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines.filtered_ppc import FilteredPPCPolicy
from baselines.filtered_ppc_drive import DriveAwareFilteredPPCPolicy
from baselines.policy import Policy
from baselines.ppc import PPCPolicy
from platoon_env.action_range import ActionRange
from platoon_env.batched import BatchedPlatoon
from platoon_env.scenarios.scenario import Scenario

__all__ = ["EXPERTS", "BatchedExpert", "ExpertEnv", "to_normalised"]

#: The analytic laws a learner can clone or build on, by registry name.
EXPERTS: dict[str, Callable[..., Policy]] = {
    "ppc": PPCPolicy,
    "filtered_ppc": FilteredPPCPolicy,
    "filtered_ppc_drive": DriveAwareFilteredPPCPolicy,
}


# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ExpertEnv:
    """What an expert law is built on for one episode of one env copy of a batched core: the
    :class:`~baselines.policy.PolicyEnv` fields the analytic laws read at construction (the
    copy's followers in that episode, the control period, its scenario), fixed for the episode.

    Not a view of the copy (that is :class:`platoon_env.batched.CopyView`, which follows the
    copy's state and answers everything else from a made env): the fast learner's cores draw a
    formation per layout, so no one made env fits every copy, and the law only needs these
    three fields; :class:`BatchedExpert` builds a new one at each of the copy's episodes.
    """

    possible_agents: tuple[str, ...]
    control_period: float
    scenario: Scenario


def to_normalised(
    physical: NDArray[Any], action_range: ActionRange
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """The inverse of :meth:`ActionRange.to_physical`: ``[u, omega]`` ``(..., 2)`` as
    normalised actions clipped to ``[-1, 1]``, and where a component had to be clipped."""
    p = np.asarray(physical, dtype=np.float64)
    a = np.empty(p.shape, dtype=np.float64)
    a[..., 0] = 2.0 * (p[..., 0] - action_range.u_low) / (action_range.u_high - action_range.u_low)
    a[..., 0] -= 1.0
    a[..., 1] = p[..., 1] / action_range.omega_high
    clipped = np.abs(a) > 1.0
    return np.clip(a, -1.0, 1.0).astype(np.float32), clipped


class BatchedExpert:
    """An analytic law acting for every env copy of ``core``: one policy per copy
    (:data:`EXPERTS`), built on :class:`ExpertEnv` and reset at each episode start of its copy.

    :meth:`restart` (after a reset of some copies) rebuilds theirs from their new scenarios;
    :meth:`act` feeds each copy's policy that copy's observations and returns the commands
    ``(B, N, 2)`` [m/s, rad/s] (zeros for slots beyond a copy's followers).
    """

    def __init__(self, core: BatchedPlatoon, name: str = "ppc", **options: float) -> None:
        if name not in EXPERTS:
            raise ValueError(f"expert must be one of {tuple(EXPERTS)}, got {name!r}")
        self.core = core
        self.name = name
        self.options = dict(options)
        self.policies: list[Policy] = []
        self._agents: list[tuple[str, ...]] = []
        for b in range(core.batch_size):
            self.policies.append(self._build(b))

    def _build(self, b: int) -> Policy:
        scenario = self.core.scenarios[b]
        n = int(scenario.config.followers)
        agents = tuple(self.core.possible_agents[:n])
        env = ExpertEnv(agents, float(self.core.control_period), scenario)
        policy = EXPERTS[self.name](env, **self.options)
        policy.reset()
        if b < len(self._agents):
            self._agents[b] = agents
        else:
            self._agents.append(agents)
        return policy

    def restart(self, envs: NDArray[np.bool_] | NDArray[np.intp]) -> None:
        """A new episode began in ``envs`` (a mask or indices): their policies start over on
        their copies' current scenarios."""
        idx = np.flatnonzero(envs) if np.asarray(envs).dtype == bool else np.asarray(envs)
        for b in idx.tolist():
            self.policies[b] = self._build(b)

    def act(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        """The commands ``(B, N, 2)`` for observations ``(B, N, K)``."""
        out = np.zeros((*obs.shape[:2], 2), dtype=np.float32)
        for b, policy in enumerate(self.policies):
            agents = self._agents[b]
            # As the env gives them: the law reads its physical sensor 7-vector from any layout
            # (baselines.policy.sensor_part, which un-scales a scale-free one).
            actions = policy.act(dict(zip(agents, obs[b, : len(agents)], strict=True)))
            for i, agent in enumerate(agents):
                out[b, i] = actions[agent]
        return out
