"""The per-follower observation vector and the per-follower action (``docs/sensing.md``).

Everything a policy may use is here, derived from the follower's own sensors only: the
camera's body-frame measurement of its predecessor and the proximity sensor's four clearances.
No global positions, no leader speed.

======  ===========  =============================================  ==================
index   name         meaning                                        range
======  ===========  =============================================  ==================
0       visible      1 if the predecessor is visible, else 0        {0, 1}
1       x_rel        ``x~ = d cos(beta)`` (0 when not visible)      [0, d_con]
2       y_rel        ``y~ = d sin(beta)`` (0 when not visible)      [-d_con, d_con]
3       d_W_l        clearance of the robot, left of ``L_i``        [0, proximity range]
4       d_W_r        clearance of the robot, right of ``L_i``       [0, proximity range]
5       d_l          clearance of the line of sight ``L_i``, left   [0, proximity range]
6       d_r          clearance of the line of sight ``L_i``, right  [0, proximity range]
======  ===========  =============================================  ==================

Distances in metres. ``beta`` is the angle of view (eq. 3), ``d`` the distance (eq. 2).

**Task-aware observations** (scenario option ``observation: {task_aware: true}``, e.g.
``make("study_a", observation={"task_aware": True})``; off by default, so the 7-vector above
stays the contract): the same 7, then what a real follower knows of its task and its sensors,
so that one policy can serve every formation (13 values, :data:`OBS_NAMES_TASK`):

======  ========  =============================================================  ========
index   name      meaning                                                        range
======  ========  =============================================================  ========
7       d_des     ``min(1, d_des / D)``, the desired distance (Problem 1)        [0, 1]
8       d_col     ``min(1, d_col / D)``, the collision distance (eq. 4)          [0, 1]
9       d_con     ``min(1, d_con / D)``, the camera range (eq. 5)                [0, 1]
10      beta_con  ``beta_con / (pi / 2)``, the camera half-angle (eq. 5)         [0, 1]
11      r         ``min(1, r / (D / 2))``, the robot radius                      [0, 1]
12      t_unseen  ``min(1, t_u / T)``, time since the predecessor was perceived  [0, 1]
======  ========  =============================================================  ========

The reference scales are fixed (:data:`TASK_SCALES`), not the scenario's, so that the same
number means the same task in every scenario: ``D`` = :data:`TASK_DISTANCE_SCALE` = 5 m,
``pi / 2`` (the schema's bound ``0 < beta_con < pi / 2``), ``D / 2`` for the radius. Since the
schema requires ``2 r <= d_col < d_des < d_con``, every scenario with ``d_con <= D`` (all shipped
ones: at most 4 m) has all five in ``[0, 1)`` unclipped; a larger ``d_con`` saturates at 1 (the
schema bounds no distance, so a fixed scale must clip somewhere).

**Scale-free observations** (``observation: {task_aware: true, scale_free: true}``, e.g.
``make("procedural_formations_train", observation={"task_aware": True, "scale_free": True})``;
``scale_free`` needs ``task_aware``): every length in the task's own unit, the camera range
``d_con``, and the bearing over the camera half-angle ``beta_con``, so that one policy's
inputs keep the same bounds in every formation (15 values, :data:`OBS_NAMES_SCALE_FREE`):

======  =============  ======================================================  ============
index   name           meaning                                                 range
======  =============  ======================================================  ============
0       visible        as above                                                {0, 1}
1       x_rel/d_con    ``x~ / d_con``                                          [0, 1]
2       y_rel/d_con    ``y~ / d_con``                                          [-1, 1]
3-6     d_W_l/d_con..  the four clearances over ``d_con``                      [0, c]
7       d_des/d_con    ``d_des / d_con``                                       [0, 1]
8       d_col/d_con    ``d_col / d_con``                                       [0, 1]
9       d_con          ``min(1, d_con / D)``: the one absolute scale kept      [0, 1]
10      beta_con       ``beta_con / (pi / 2)``                                 [0, 1]
11      r/d_con        ``r / d_con``                                           [0, 1]
12      t_unseen       as above                                                [0, 1]
13      d/d_con        ``d / d_con`` of the reported position (eq. 2)          [0, 1]
14      beta/beta_con  ``beta / beta_con`` of the reported position (eq. 3)    [-1, 1]
======  =============  ======================================================  ============

``c`` is the proximity range over ``d_con``: 1 unless ``proximity.range`` is set. The schema's
``2 r <= d_col < d_des < d_con`` puts columns 7, 8 and 11 in ``[0, 1)``. Columns 13 and 14 are
0 when the predecessor is not reported, and clipped to their ranges (a noisy report may lie
just beyond the field of view). The compiled step writes the scaled columns
(:func:`scale_free_into`, after perception, so noise, dropouts and latency are those of the
physical camera); the analytic laws read the physical 7-vector back with
:func:`sensor_columns` (the one rule that undoes the scaling).

``t_u`` [s] is the time since the follower last *perceived* its predecessor: 0 in a step whose
observation has ``visible = 1`` (the perceived flag, after detection dropouts, the frame rate's
held frames and the latency of :mod:`platoon_env.perception`), else the previous value plus the
control period; the reset counts as visible (``t_u = 0``). It is divided by the horizon ``T`` =
:data:`UNSEEN_HORIZON` = 2 s and capped at 1. The core keeps it
(:meth:`platoon_env.core.PlatoonCore.observe_task`).
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from numba import njit

from platoon_env.scenarios.schema import ScenarioConfig

OBS_VISIBLE = 0
OBS_X_REL = 1
OBS_Y_REL = 2
OBS_D_WALL_LEFT = 3
OBS_D_WALL_RIGHT = 4
OBS_D_SIGHT_LEFT = 5
OBS_D_SIGHT_RIGHT = 6
#: Length of the default observation (the 7-vector; the compiled kernels write these columns).
OBS_SIZE = 7
#: The proximity sensor's four clearance columns ``d_W_l, d_W_r, d_l, d_r``, in table order: for
#: the code that treats the four alike (copies, noise, filters them).
OBS_CLEARANCES: tuple[int, int, int, int] = (
    OBS_D_WALL_LEFT,
    OBS_D_WALL_RIGHT,
    OBS_D_SIGHT_LEFT,
    OBS_D_SIGHT_RIGHT,
)
OBS_NAMES: tuple[str, ...] = ("visible", "x_rel", "y_rel", "d_W_l", "d_W_r", "d_l", "d_r")

# Task-aware observations (``observation.task_aware``): the 7 above, then these.
OBS_D_DES = 7
OBS_D_COL = 8
OBS_D_CON = 9
OBS_BETA_CON = 10
OBS_RADIUS = 11
OBS_T_UNSEEN = 12
OBS_SIZE_TASK = 13
#: Names of the five task features (columns ``OBS_D_DES .. OBS_RADIUS``).
OBS_TASK_NAMES: tuple[str, ...] = ("d_des", "d_col", "d_con", "beta_con", "r")
OBS_NAMES_TASK: tuple[str, ...] = (*OBS_NAMES, *OBS_TASK_NAMES, "t_unseen")

# Scale-free observations (``observation.scale_free``): the 13 task-aware columns in the task's
# units, then these two.
OBS_D_REL = 13
OBS_BETA_REL = 14
OBS_SIZE_SCALE_FREE = 15
#: Names of the scale-free layout's columns (``observation.scale_free``; the module docstring).
OBS_NAMES_SCALE_FREE: tuple[str, ...] = (
    "visible",
    *(f"{name}/d_con" for name in OBS_NAMES[1:]),
    "d_des/d_con",
    "d_col/d_con",
    "d_con",
    "beta_con",
    "r/d_con",
    "t_unseen",
    "d/d_con",
    "beta/beta_con",
)

#: [m] ``D``, the reference distance of ``d_des``, ``d_col`` and ``d_con`` (``r``: ``D / 2``).
TASK_DISTANCE_SCALE = 5.0
#: The divisors of the five task features, in :data:`OBS_TASK_NAMES` order ([m, m, m, rad, m]).
TASK_SCALES: tuple[float, ...] = (
    TASK_DISTANCE_SCALE,
    TASK_DISTANCE_SCALE,
    TASK_DISTANCE_SCALE,
    math.pi / 2,
    TASK_DISTANCE_SCALE / 2,
)
#: [s] ``T``, the horizon of ``t_unseen``: the time since the predecessor was perceived over
#: it, capped at 1. Far beyond the gaps of a realistic camera's dropouts and latency (the
#: ``aruco`` profile: 33 ms frames, 50 ms latency, 5 % dropouts), which it resolves; by then,
#: at the shipped leader speeds (0.25-0.5 m/s), the predecessor has gone half a metre or more.
UNSEEN_HORIZON = 2.0

ACT_U = 0
ACT_OMEGA = 1
ACT_SIZE = 2


def observation_names(cfg: ScenarioConfig) -> tuple[str, ...]:
    """The names of one follower's observation columns: :data:`OBS_NAMES`, or
    :data:`OBS_NAMES_TASK` with ``observation.task_aware``, or :data:`OBS_NAMES_SCALE_FREE`
    with ``observation.scale_free`` too."""
    if cfg.observation.scale_free:
        return OBS_NAMES_SCALE_FREE
    return OBS_NAMES_TASK if cfg.observation.task_aware else OBS_NAMES


def observation_size(cfg: ScenarioConfig) -> int:
    """The length of one follower's observation: :data:`OBS_SIZE`, :data:`OBS_SIZE_TASK` or
    :data:`OBS_SIZE_SCALE_FREE`."""
    return len(observation_names(cfg))


def task_features(cfg: ScenarioConfig) -> np.ndarray:
    """The five task features ``[d_des, d_col, d_con, beta_con, r]`` of ``cfg`` (float32, the
    observation's dtype), each over its :data:`TASK_SCALES` entry and clipped to ``[0, 1]``;
    with ``observation.scale_free`` ``d_des``, ``d_col`` and ``r`` over ``d_con`` instead."""
    d_con = cfg.camera.range
    values = (
        cfg.formation.d_des,
        cfg.safety.d_col,
        d_con,
        cfg.camera.half_angle,
        cfg.robot.radius,
    )
    scales = list(TASK_SCALES)
    if cfg.observation.scale_free:
        scales[0] = scales[1] = scales[4] = d_con
    scaled = [min(1.0, max(0.0, v / s)) for v, s in zip(values, scales, strict=True)]
    return np.array(scaled, dtype=np.float32)


def distance_bounds(cfg: ScenarioConfig) -> tuple[float, float, float]:
    """``(d_con_lo, d_con_hi, prox_hi)`` [m]: the least and greatest camera range ``d_con`` and
    the greatest proximity range of the episodes of ``cfg``. One value each for a fixed
    formation; with ``generator.formation`` drawing ``d_con`` its range (the proximity range
    is ``d_con`` unless ``proximity.range`` is set)."""
    d_con = cfg.camera.range
    lo = hi = d_con
    gen = cfg.generator
    drawn = None if gen is None or gen.formation is None else gen.formation.d_con
    if drawn is not None:
        lo, hi = drawn
    prox = hi if cfg.proximity.range is None else cfg.proximity.range
    return lo, hi, prox


def observation_space(cfg: ScenarioConfig) -> spaces.Box:
    """The bounded float32 Box of one follower's observation (7 values, or 13 with
    ``observation.task_aware``: the task features and ``t_unseen`` lie in ``[0, 1]``; 15 with
    ``observation.scale_free``, the module docstring's ranges). Bounds hold every episode of
    the scenario: with a drawn formation (``generator.formation``), its largest ``d_con``."""
    d_lo, d_con, prox = distance_bounds(cfg)
    if cfg.observation.scale_free:
        # the clearances over d_con: at most the proximity range over the least d_con
        c = 1.0 if cfg.proximity.range is None else prox / d_lo
        low = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0]
        high = [1.0, 1.0, 1.0, c, c, c, c]
    else:
        low = [0.0, 0.0, -d_con, 0.0, 0.0, 0.0, 0.0]
        high = [1.0, d_con, d_con, prox, prox, prox, prox]
    if cfg.observation.task_aware:
        extra = OBS_SIZE_TASK - OBS_SIZE
        low += [0.0] * extra
        high += [1.0] * extra
    if cfg.observation.scale_free:
        low += [0.0, -1.0]
        high += [1.0, 1.0]
    return spaces.Box(
        low=np.array(low, dtype=np.float32), high=np.array(high, dtype=np.float32), dtype=np.float32
    )


@njit(cache=True)
def scale_free_into(obs: np.ndarray, d_con: float, beta_con: float) -> None:
    """Rewrite one env's observation rows ``obs`` (N, :data:`OBS_SIZE_SCALE_FREE`), whose
    first :data:`OBS_SIZE` columns hold the physical (perceived) 7-vector, in the scale-free
    layout: ``x~, y~`` and the four clearances over ``d_con``, then ``d / d_con`` and
    ``beta / beta_con`` (eqs. 2-3, of the reported position; 0 when not reported), clipped to
    ``[0, 1]`` and ``[-1, 1]``. The compiled step calls it last; the task columns are the
    core's."""
    inv = 1.0 / d_con
    for i in range(obs.shape[0]):
        x = float(obs[i, OBS_X_REL])
        y = float(obs[i, OBS_Y_REL])
        for c in range(OBS_X_REL, OBS_SIZE):
            obs[i, c] = obs[i, c] * inv
        if obs[i, OBS_VISIBLE] > 0.0:
            obs[i, OBS_D_REL] = min(1.0, math.hypot(x, y) * inv)
            obs[i, OBS_BETA_REL] = min(1.0, max(-1.0, math.atan2(y, x) / beta_con))
        else:
            obs[i, OBS_D_REL] = 0.0
            obs[i, OBS_BETA_REL] = 0.0


def sensor_columns(obs: np.ndarray, cfg: ScenarioConfig) -> np.ndarray:
    """The physical 7-vector part ``(n, OBS_SIZE)`` (float64) of ``n`` stacked observations of
    an env made with ``cfg``: the first :data:`OBS_SIZE` columns, times ``d_con`` for every
    length with ``observation.scale_free`` (the inverse of :func:`scale_free_into`, up to
    float32 rounding). The one rule by which an analytic law reads a scale-free observation."""
    if not cfg.observation.scale_free:
        return np.asarray(obs[:, :OBS_SIZE], dtype=np.float64)
    out = np.array(obs[:, :OBS_SIZE], dtype=np.float64)  # a copy: the caller's stays scaled
    out[:, OBS_X_REL:] *= cfg.camera.range
    return out


def action_space(cfg: ScenarioConfig) -> spaces.Box:
    """The float32 Box of one follower's action ``[u, omega]`` in m/s and rad/s.

    Its bounds are the actuator limits ``robot.u_max`` and ``robot.omega_max``; actions outside
    are clipped by the env.
    """
    high = np.array([cfg.robot.u_max, cfg.robot.omega_max], dtype=np.float32)
    return spaces.Box(low=-high, high=high, dtype=np.float32)
