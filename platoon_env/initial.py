"""The initial configuration of an episode: the scenario's default one, optionally perturbed.

On ``reset(seed)`` the followers' positions and headings are perturbed uniformly (the scenario's
``initial`` block: ``position_noise`` [m] per coordinate, ``heading_noise`` [rad]) with the env's
own RNG, until a draw satisfies every constraint of the initial configuration
(``docs/safety.md``); after :data:`PERTURB_ATTEMPTS` infeasible draws the default configuration
is used. The leader is not perturbed.

A configuration is feasible when no follower violates any constraint there: the rule is
:func:`platoon_env.safety.configuration_masks`, the one the step applies after every sub-step,
so a start is never one that the first step would end (with the obstacles inflated by
``safety.inflation``). The leader (which no draw moves) must also keep a clearance above
``r + m`` (:func:`~platoon_env.scenarios.scenario.leader_clear`).
:func:`platoon_env.scenarios.scenario.initial_violations` words the same decisions as messages.
"""

from __future__ import annotations

import numpy as np

from platoon_env.geometry.grid import EdgeGrid
from platoon_env.geometry.sensing import SENSE_SIZE
from platoon_env.records import Walls, constraint_params
from platoon_env.safety import configuration_masks
from platoon_env.scenarios.scenario import Scenario, initial_violations, leader_clear

#: Attempts at drawing a feasible perturbed initial configuration before using the default one.
PERTURB_ATTEMPTS = 50


class InitialSampler:
    """Draws initial configurations of one scenario; see the module docstring.

    Args:
        scenario: the built scenario.
        walls: its boundary as :class:`~platoon_env.records.Walls` (default: built here).
        params: a ``(1,)`` :data:`~platoon_env.records.PARAMS_DTYPE` array with at least the
            constraint fields (default: :func:`~platoon_env.records.constraint_params`).
    """

    def __init__(
        self, scenario: Scenario, walls: Walls | None = None, params: np.ndarray | None = None
    ) -> None:
        self.scenario = scenario
        cfg = scenario.config
        self.base = np.array(scenario.initial_poses, dtype=np.float64)
        self._n = cfg.followers
        self._position_noise = cfg.initial.position_noise
        self._heading_noise = cfg.initial.heading_noise
        if walls is None:
            walls = EdgeGrid.build(scenario.workspace.edges, reach=cfg.proximity_range).walls
        self._walls = walls
        self._params = constraint_params(cfg) if params is None else params
        leader = self.base[0]
        self._leader_ok = leader_clear(cfg, scenario.workspace, (leader[0], leader[1]))
        self._sensed = np.empty((self._n, SENSE_SIZE))
        self._masks = np.empty(self._n, dtype=np.int64)

    def feasible(self, poses: np.ndarray) -> bool:
        """Whether ``poses`` (with the default leader pose) is a feasible initial configuration.

        Same answer as ``not initial_violations(cfg, workspace, poses)`` for any ``poses`` whose
        leader row is the default one.
        """
        if not self._leader_ok:
            return False
        configuration_masks(
            np.ascontiguousarray(poses, dtype=np.float64),
            self._walls,
            self._params[0],
            self._sensed,
            self._masks,
        )
        return not self._masks.any()

    def violations(self, poses: np.ndarray) -> list[str]:
        """Every constraint that ``poses`` violates, as messages naming follower and rule."""
        sc = self.scenario
        return initial_violations(sc.config, sc.workspace, np.asarray(poses, dtype=np.float64))

    def sample(self, rng: np.random.Generator, perturb: bool) -> np.ndarray:
        """The initial poses ``(N+1, 3)`` of an episode, drawing from ``rng`` when perturbing."""
        base = self.base.copy()
        if not perturb or (self._position_noise == 0 and self._heading_noise == 0):
            return base
        n = self._n
        for _ in range(PERTURB_ATTEMPTS):
            cand = base.copy()
            cand[1:, :2] += rng.uniform(-1, 1, size=(n, 2)) * self._position_noise
            cand[1:, 2] += rng.uniform(-1, 1, size=n) * self._heading_noise
            if self.feasible(cand):
                return cand
        return base


def initial_poses(scenario: Scenario, rng: np.random.Generator, perturb: bool) -> np.ndarray:
    """One-off :meth:`InitialSampler.sample` (build the sampler once to draw repeatedly)."""
    return InitialSampler(scenario).sample(rng, perturb)
