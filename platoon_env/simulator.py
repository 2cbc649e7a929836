"""One env step as one compiled call: sub-steps of kinematics, the leader, safety, then sensing.

Pipeline per control period (HighwayEnv-style, fixed order):

1. for each of ``physics_substeps`` sub-steps of ``h = control_period / physics_substeps``:
   the leader's pure-pursuit command, exact unicycle arcs for every robot (eq. 1), the safety
   checks of :mod:`platoon_env.safety`; stop early when a violation in ``terminate_mask`` occurs;
2. sensing of every follower (:mod:`platoon_env.geometry.sensing`) and the observation vectors
   (:mod:`platoon_env.observation`); in the last sub-step the safety masks come from that same
   sensing (clearance, occlusion, ``d``, ``beta``), so no edge is tested twice;
3. the reward terms of :mod:`platoon_env.reward` and each follower's summed reward.

Both the safety checks and sensing visit only the boundary edges that a static grid
(:mod:`platoon_env.geometry.grid`) lists near each follower, so the cost does not grow with the
size of the map. Everything is a function of arrays owned by the caller (the env, or the batched
core of :mod:`platoon_env.batched`), so the env class only coordinates.
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
    SENSE_OCCLUDED,
    SENSE_VISIBLE,
    sense_follower_grid,
)
from platoon_env.observation import (
    ACT_OMEGA,
    ACT_U,
    OBS_D_SIGHT_LEFT,
    OBS_D_SIGHT_RIGHT,
    OBS_D_WALL_LEFT,
    OBS_D_WALL_RIGHT,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
    action_space,
)
from platoon_env.reward import REWARD_TERMS, reward_terms_into, reward_weights
from platoon_env.safety import robot_contacts, sensed_violation, violation_masks_grid
from platoon_env.scenarios.schema import ScenarioConfig

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
P_D_DES = 9
P_REWARD_D_SCALE = 10
P_U_LOW = 11
P_OMEGA_LOW = 12
P_U_HIGH = 13
P_OMEGA_HIGH = 14
P_WALL_MARGIN = 15
P_PROXIMITY_HALF_ANGLE = 16
#: The weights of ``REWARD_TERMS`` occupy ``P_REWARD_WEIGHTS ... P_REWARD_WEIGHTS + 5``.
P_REWARD_WEIGHTS = 17
P_SIZE = P_REWARD_WEIGHTS + len(REWARD_TERMS)


def kernel_params(cfg: ScenarioConfig) -> np.ndarray:
    """The float64 parameter vector (``P_*`` layout) of a scenario's config."""
    params = np.zeros(P_SIZE)
    params[P_RADIUS] = cfg.robot.radius
    params[P_D_COL] = cfg.safety.d_col
    params[P_D_CON] = cfg.camera.range
    params[P_BETA_CON] = cfg.camera.half_angle
    params[P_PROXIMITY] = cfg.proximity_range
    params[P_PROXIMITY_HALF_ANGLE] = cfg.proximity_half_angle
    params[P_LEADER_SPEED] = cfg.leader.speed
    params[P_LOOKAHEAD] = cfg.leader.lookahead
    params[P_LEADER_TURN] = cfg.leader.max_turn_rate
    params[P_SUBSTEP] = cfg.simulation.control_period / cfg.simulation.physics_substeps
    params[P_D_DES] = cfg.formation.d_des
    # The distance error is normalised by d_con - d_des, the bearing error by beta_con.
    params[P_REWARD_D_SCALE] = cfg.camera.range - cfg.formation.d_des
    params[P_WALL_MARGIN] = cfg.reward.wall_margin
    # Actuator limits exactly as the float32 action Box holds them.
    space = action_space(cfg)
    params[P_U_LOW], params[P_OMEGA_LOW] = space.low.astype(np.float64)
    params[P_U_HIGH], params[P_OMEGA_HIGH] = space.high.astype(np.float64)
    params[P_REWARD_WEIGHTS : P_REWARD_WEIGHTS + len(REWARD_TERMS)] = reward_weights(cfg)
    return params


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
def advance_substep(
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    params: np.ndarray,
    prev: np.ndarray,
) -> None:
    """One physics sub-step: the leader's pure-pursuit command and exact arcs for every robot.

    ``prev`` receives the poses before the sub-step.
    """
    h = params[P_SUBSTEP]
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
    for i in range(actions.shape[0]):
        x, y, th = unicycle_arc(
            poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2], actions[i, 0], actions[i, 1], h
        )
        poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2] = x, y, th


@njit(cache=True)
def simulate(
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    params: np.ndarray,
    n_substeps: int,
    terminate_mask: int,
    violations: np.ndarray,
    sensed: np.ndarray,
    obs: np.ndarray,
) -> int:
    """Sub-steps, safety, sensing and observations of one control period (no reward).

    See :func:`platoon_step`; returns the number of sub-steps simulated. On entry ``sensed``
    must hold the sensing of ``poses`` (as the previous call, or a reset with
    ``n_substeps = 0``, left it) or zeros: the sub-step safety checks use it to skip the edge
    tests of followers that cannot have reached a wall.
    """
    n = actions.shape[0]
    radius = params[P_RADIUS]
    d_col = params[P_D_COL]
    d_con = params[P_D_CON]
    beta_con = params[P_BETA_CON]
    prox = params[P_PROXIMITY]
    prox_half_angle = params[P_PROXIMITY_HALF_ANGLE]
    prev = np.empty_like(poses)
    sub_mask = np.empty(n, dtype=np.int64)
    cand = np.empty(edges.shape[0], dtype=np.int64)
    # How far each robot can have moved since the sensing in `sensed` (the start of this
    # period): lets the sub-step safety checks skip followers far from every wall.
    travel = np.zeros(n + 1)
    h = params[P_SUBSTEP]
    for i in range(n):
        violations[i] = 0
    done = 0
    sensed_now = False
    for k in range(n_substeps):
        advance_substep(poses, actions, leader, path, cum, params, prev)
        done += 1
        # The chord of an arc is at most its length |u| h; the leader never exceeds its speed.
        travel[0] += abs(params[P_LEADER_SPEED]) * h
        for i in range(n):
            travel[i + 1] += abs(actions[i, ACT_U]) * h
        if k == n_substeps - 1:
            # Last sub-step: sense now and read the safety masks off the sensing.
            for i in range(n):
                clear2, motion_hit = sense_follower_grid(
                    poses[i + 1, 0],
                    poses[i + 1, 1],
                    poses[i + 1, 2],
                    poses[i, 0],
                    poses[i, 1],
                    prev[i + 1, 0],
                    prev[i + 1, 1],
                    True,
                    edges,
                    boxes,
                    grid_params,
                    cell_start,
                    cell_edges,
                    edge_cell,
                    cand,
                    d_con,
                    beta_con,
                    prox,
                    prox_half_angle,
                    sensed[i],
                )
                sub_mask[i] = sensed_violation(
                    sensed[i, SENSE_D],
                    sensed[i, SENSE_BETA],
                    clear2,
                    sensed[i, SENSE_OCCLUDED] > 0.0,
                    motion_hit,
                    radius,
                    d_col,
                    d_con,
                    beta_con,
                )
            robot_contacts(poses, radius, sub_mask)
            sensed_now = True
        else:
            violation_masks_grid(
                poses,
                prev,
                edges,
                boxes,
                grid_params,
                cell_start,
                cell_edges,
                edge_cell,
                cand,
                radius,
                d_col,
                d_con,
                beta_con,
                sub_mask,
                sensed,
                travel,
            )
        stop = False
        for i in range(n):
            violations[i] |= sub_mask[i]
            if sub_mask[i] & terminate_mask:
                stop = True
        if stop:
            break
    if not sensed_now:
        for i in range(n):
            sense_follower_grid(
                poses[i + 1, 0],
                poses[i + 1, 1],
                poses[i + 1, 2],
                poses[i, 0],
                poses[i, 1],
                poses[i + 1, 0],
                poses[i + 1, 1],
                False,
                edges,
                boxes,
                grid_params,
                cell_start,
                cell_edges,
                edge_cell,
                cand,
                d_con,
                beta_con,
                prox,
                prox_half_angle,
                sensed[i],
            )
    observe_into(sensed, obs)
    return done


@njit(cache=True)
def platoon_step(
    poses: np.ndarray,
    actions: np.ndarray,
    leader: np.ndarray,
    path: np.ndarray,
    cum: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    params: np.ndarray,
    n_substeps: int,
    terminate_mask: int,
    violations: np.ndarray,
    sensed: np.ndarray,
    obs: np.ndarray,
    terms: np.ndarray,
    rewards: np.ndarray,
) -> int:
    """Advance the platoon by one control period in place; returns the sub-steps simulated.

    ``actions`` (N, 2) holds each follower's ``[u, omega]``: with ``n_substeps > 0`` they are
    first checked (a row holding NaN or inf: nothing changes and ``-1 - row`` is returned) and
    clipped in place to the actuator limits in ``params``. ``poses`` (N+1, 3) and ``leader``
    (L_SIZE,) are updated; ``edges`` to ``edge_cell`` are
    :attr:`platoon_env.geometry.grid.EdgeGrid.arrays`; ``params`` is :func:`kernel_params`.
    Outputs: ``violations`` (N,) the union of the violation masks seen over the sub-steps,
    ``sensed`` (N, SENSE_SIZE) and ``obs`` (N, OBS_SIZE) the final sensing and observations,
    ``terms`` (N, len(REWARD_TERMS)) the reward terms and ``rewards`` (N,) their sums. Stops
    after the first sub-step with a violation whose cause is in ``terminate_mask``. With
    ``n_substeps = 0`` it only senses (as on reset) and leaves ``terms`` and ``rewards`` alone.
    On entry ``sensed`` must hold the sensing of ``poses``, as the previous call left it (or
    zeros; see :func:`simulate`).
    """
    if n_substeps > 0:
        bad = clip_actions_to(actions, params)
        if bad >= 0:
            return -1 - bad
    done = simulate(
        poses,
        actions,
        leader,
        path,
        cum,
        edges,
        boxes,
        grid_params,
        cell_start,
        cell_edges,
        edge_cell,
        params,
        n_substeps,
        terminate_mask,
        violations,
        sensed,
        obs,
    )
    if n_substeps > 0:
        reward_terms_into(
            sensed,
            params[P_D_DES],
            actions,
            violations,
            params[P_REWARD_WEIGHTS : P_REWARD_WEIGHTS + terms.shape[1]],
            params[P_REWARD_D_SCALE],
            params[P_BETA_CON],
            params[P_RADIUS],
            params[P_WALL_MARGIN],
            terms,
        )
        for i in range(terms.shape[0]):
            total = 0.0
            for t in range(terms.shape[1]):
                total += terms[i, t]
            rewards[i] = total
    return done


@njit(cache=True)
def clip_actions_to(actions: np.ndarray, params: np.ndarray) -> int:
    """Clip ``actions`` (N, 2) in place to the actuator limits in ``params`` (``P_U_LOW`` ...).

    Returns the index of the first row holding NaN or inf (nothing is clipped then), or -1.
    """
    for i in range(actions.shape[0]):
        for j in range(actions.shape[1]):
            if not math.isfinite(actions[i, j]):
                return i
    for i in range(actions.shape[0]):
        actions[i, ACT_U] = min(params[P_U_HIGH], max(params[P_U_LOW], actions[i, ACT_U]))
        actions[i, ACT_OMEGA] = min(
            params[P_OMEGA_HIGH], max(params[P_OMEGA_LOW], actions[i, ACT_OMEGA])
        )
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

    The grid-less form of :func:`platoon_step` (every edge is visited; no reward): ``poses``
    (N+1, 3) and ``leader`` (L_SIZE,) are updated; ``actions`` (N, 2) holds each follower's
    ``[u, omega]``; ``violations`` (N,) receives the union of the violation masks seen over the
    sub-steps; ``sensed`` and ``obs`` the final sensing and observations (on entry, ``sensed``
    holds the sensing of ``poses`` or zeros, see :func:`simulate`). ``prev`` and ``sub_mask``
    are unused (kept for compatibility). Stops after the first sub-step with a
    violation whose cause is in ``terminate_mask``.
    """
    n_edges = edges.shape[0]
    grid_params = np.array([0.0, 0.0, 0.0, 1.0, 1.0])  # one cell holding every edge
    cell_start = np.array([0, n_edges], dtype=np.int64)
    cell_edges = np.arange(n_edges)
    edge_cell = np.zeros((n_edges, 2), dtype=np.int64)
    return simulate(
        poses,
        actions,
        leader,
        path,
        cum,
        edges,
        boxes,
        grid_params,
        cell_start,
        cell_edges,
        edge_cell,
        params,
        n_substeps,
        terminate_mask,
        violations,
        sensed,
        obs,
    )
