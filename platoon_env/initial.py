"""The initial configuration of an episode: the scenario's default one, optionally perturbed.

On ``reset(seed)`` the followers' positions and headings are perturbed uniformly (the scenario's
``initial`` block: ``position_noise`` [m] per coordinate, ``heading_noise`` [rad]) with the env's
own RNG, until a draw satisfies every constraint of the initial configuration (DESIGN §3); after
:data:`PERTURB_ATTEMPTS` infeasible draws the default configuration is used. The leader is not
perturbed.

:class:`InitialSampler` does this for one scenario. Its feasibility test is compiled but takes
exactly the decisions of :func:`platoon_env.scenarios.scenario.initial_violations` (the same
sensing kernel, the same comparisons; the leader's clearance, which no draw changes, is computed
once with shapely), so the same RNG gives the same poses whichever is used. The single env and
the batched core (:mod:`platoon_env.batched`) both draw through it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_OCCLUDED,
    SENSE_SIZE,
    sense_into,
)
from platoon_env.scenarios.scenario import Scenario

#: Attempts at drawing a feasible perturbed initial configuration before using the default one.
PERTURB_ATTEMPTS = 50


@njit(cache=True)
def _feasible(
    poses: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    radius: float,
    d_col: float,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    sensed: np.ndarray,
) -> bool:
    """The followers' and pairs' part of ``initial_violations(...) == []``."""
    sense_into(poses, edges, boxes, d_con, beta_con, proximity_range, sensed)
    for i in range(sensed.shape[0]):
        if not sensed[i, SENSE_D] > d_col:
            return False
        if not sensed[i, SENSE_D] < d_con:
            return False
        if not abs(sensed[i, SENSE_BETA]) < beta_con:
            return False
        if not sensed[i, SENSE_CLEARANCE] > radius:
            return False
        if sensed[i, SENSE_OCCLUDED] > 0:
            return False
    touch = 2 * radius
    for j in range(poses.shape[0]):
        for k in range(j + 1, poses.shape[0]):
            if math.hypot(poses[j, 0] - poses[k, 0], poses[j, 1] - poses[k, 1]) <= touch:
                return False
    return True


class InitialSampler:
    """Draws initial configurations of one (fixed-workspace) scenario; see the module docstring.

    Args:
        scenario: the built scenario (``env.scenario``).
    """

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        cfg = scenario.config
        self.base = np.array(scenario.initial_poses, dtype=np.float64)
        self._n = cfg.followers
        self._position_noise = cfg.initial.position_noise
        self._heading_noise = cfg.initial.heading_noise
        self._radius = cfg.robot.radius
        self._d_col = cfg.safety.d_col
        self._d_con = cfg.camera.range
        self._beta_con = cfg.camera.half_angle
        self._proximity = cfg.proximity_range
        self._edges = np.ascontiguousarray(scenario.workspace.edges, dtype=np.float64)
        self._boxes = np.ascontiguousarray(scenario.workspace.boxes, dtype=np.float64)
        leader = self.base[0]
        self._leader_ok = (
            scenario.workspace.clearance(float(leader[0]), float(leader[1])) > self._radius
        )
        self._sensed = np.empty((self._n, SENSE_SIZE))

    def feasible(self, poses: np.ndarray) -> bool:
        """Whether ``poses`` (with the default leader pose) is a feasible initial configuration.

        Same answer as ``not initial_violations(cfg, workspace, poses)`` for any ``poses`` whose
        leader row is the default one.
        """
        if not self._leader_ok:
            return False
        return bool(
            _feasible(
                np.ascontiguousarray(poses, dtype=np.float64),
                self._edges,
                self._boxes,
                self._radius,
                self._d_col,
                self._d_con,
                self._beta_con,
                self._proximity,
                self._sensed,
            )
        )

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
