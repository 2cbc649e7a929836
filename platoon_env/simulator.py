"""One env step as one compiled call: sub-steps of kinematics, the leader, safety, then sensing.

Pipeline per control period (HighwayEnv-style, fixed order):

1. for each of ``physics_substeps`` sub-steps of ``h = control_period / physics_substeps``:
   the leader's pure-pursuit command, exact unicycle arcs for every robot (eq. 1), the safety
   checks of :mod:`platoon_env.safety`; stop early when a violation in ``terminate_mask`` occurs;
2. sensing of every follower (:mod:`platoon_env.geometry.sensing`) and the observation vectors
   (:mod:`platoon_env.observation`).

Everything is a function of arrays owned by the env, so the env class only coordinates.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.dynamics.leader import leader_command
from platoon_env.dynamics.unicycle import unicycle_arc
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_D,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
    SENSE_D_WALL_LEFT,
    SENSE_D_WALL_RIGHT,
    SENSE_VISIBLE,
    sense_into,
)
from platoon_env.observation import (
    OBS_D_SIGHT_LEFT,
    OBS_D_SIGHT_RIGHT,
    OBS_D_WALL_LEFT,
    OBS_D_WALL_RIGHT,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
)
from platoon_env.safety import violation_masks

# Layout of the float64 parameter vector passed to the kernel.
P_RADIUS = 0
P_D_COL = 1
P_D_CON = 2
P_BETA_CON = 3
P_PROXIMITY = 4
P_LEADER_SPEED = 5
P_LOOKAHEAD = 6
P_LEADER_TURN = 7
P_SUBSTEP = 8
P_SIZE = 9

# Layout of the leader state vector: progress s along the path and an arrived flag.
L_PROGRESS = 0
L_ARRIVED = 1
L_SIZE = 2


@njit(cache=True)
def observe_into(sensed: np.ndarray, obs: np.ndarray) -> None:
    """Observation vectors (float32) from the sensing columns; camera zeros when not visible."""
    for i in range(sensed.shape[0]):
        vis = sensed[i, SENSE_VISIBLE]
        obs[i, OBS_VISIBLE] = vis
        if vis > 0.0:
            obs[i, OBS_X_REL] = sensed[i, SENSE_D] * math.cos(sensed[i, SENSE_BETA])
            obs[i, OBS_Y_REL] = sensed[i, SENSE_D] * math.sin(sensed[i, SENSE_BETA])
        else:
            obs[i, OBS_X_REL] = 0.0
            obs[i, OBS_Y_REL] = 0.0
        obs[i, OBS_D_WALL_LEFT] = sensed[i, SENSE_D_WALL_LEFT]
        obs[i, OBS_D_WALL_RIGHT] = sensed[i, SENSE_D_WALL_RIGHT]
        obs[i, OBS_D_SIGHT_LEFT] = sensed[i, SENSE_D_SIGHT_LEFT]
        obs[i, OBS_D_SIGHT_RIGHT] = sensed[i, SENSE_D_SIGHT_RIGHT]


@njit(cache=True)
def clip_actions(actions: np.ndarray, low: np.ndarray, high: np.ndarray) -> int:
    """Clip ``actions`` (N, 2) into ``[low, high]`` in place.

    Returns the index of the first row holding NaN or inf (left unclipped), or -1.
    """
    for i in range(actions.shape[0]):
        for j in range(actions.shape[1]):
            if not math.isfinite(actions[i, j]):
                return i
    for i in range(actions.shape[0]):
        for j in range(actions.shape[1]):
            actions[i, j] = min(high[j], max(low[j], actions[i, j]))
    return -1


@njit(cache=True)
def step_kernel(
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    params: np.ndarray,
    n_substeps: int,
    terminate_mask: int,
    prev: np.ndarray,
    sub_mask: np.ndarray,
    violations: np.ndarray,
    sensed: np.ndarray,
    obs: np.ndarray,
) -> int:
    """Advance the platoon by one control period in place; returns the sub-steps simulated.

    ``poses`` (N+1, 3) and ``leader`` (L_SIZE,) are updated; ``actions`` (N, 2) holds each
    follower's ``[u, omega]``; ``violations`` (N,) receives the union of the violation masks seen
    over the sub-steps; ``sensed`` and ``obs`` the final sensing and observations. ``prev`` and
    ``sub_mask`` are scratch buffers. Stops after the first sub-step with a violation whose cause
    is in ``terminate_mask``.
    """
    h = params[P_SUBSTEP]
    n = actions.shape[0]
    for i in range(n):
        violations[i] = 0
    done = 0
    for _ in range(n_substeps):
        for r in range(poses.shape[0]):
            prev[r, 0] = poses[r, 0]
            prev[r, 1] = poses[r, 1]
            prev[r, 2] = poses[r, 2]
        u0, w0 = 0.0, 0.0
        if leader[L_ARRIVED] == 0.0:
            u0, w0, s_new, arrived = leader_command(
                path,
                cum,
                poses[0, 0],
                poses[0, 1],
                poses[0, 2],
                leader[L_PROGRESS],
                params[P_LEADER_SPEED],
                params[P_LOOKAHEAD],
                params[P_LEADER_TURN],
                h,
            )
            leader[L_PROGRESS] = s_new
            if arrived:
                leader[L_ARRIVED] = 1.0
        x, y, th = unicycle_arc(poses[0, 0], poses[0, 1], poses[0, 2], u0, w0, h)
        poses[0, 0], poses[0, 1], poses[0, 2] = x, y, th
        for i in range(n):
            x, y, th = unicycle_arc(
                poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2], actions[i, 0], actions[i, 1], h
            )
            poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2] = x, y, th
        done += 1
        violation_masks(
            poses,
            prev,
            edges,
            boxes,
            params[P_RADIUS],
            params[P_D_COL],
            params[P_D_CON],
            params[P_BETA_CON],
            sub_mask,
        )
        stop = False
        for i in range(n):
            violations[i] |= sub_mask[i]
            if sub_mask[i] & terminate_mask:
                stop = True
        if stop:
            break
    sense_into(
        poses, edges, boxes, params[P_D_CON], params[P_BETA_CON], params[P_PROXIMITY], sensed
    )
    observe_into(sensed, obs)
    return done
