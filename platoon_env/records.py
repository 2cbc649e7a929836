"""The named records that the compiled core passes around, so a parameter is read by its name.

The core (:mod:`platoon_env.simulator`) steps ``B`` envs at once. What its kernels need comes in
four records; each is either a numpy structured array (read by field name in compiled code,
``p.d_con``) or a named tuple of arrays (``walls.edges``):

==================  =====================================  =========================================
record              type                                   holds
==================  =====================================  =========================================
``params``          ``(B,)`` array of :data:`PARAMS_DTYPE`  every physical, sensing, reward and
                                                           episode-rule parameter of env ``b``
``episode``         ``(B,)`` array of :data:`EPISODE_DTYPE` env ``b``'s scalar state: the leader's
                                                           progress, time, steps, arrival, the
                                                           step's outcome and its map slot
``maps``            :class:`MapBank` (named tuple)         the boundary-edge arrays, edge grids and
                                                           leader routes (paths, or timed
                                                           trajectories) of ``M`` map slots,
                                                           padded; :func:`walls_of` and
                                                           :func:`path_of` give the views of one
                                                           slot
``buffers``         :class:`Buffers` (named tuple)         per-follower state and outputs: poses,
                                                           actions, violations, sensing,
                                                           observations, reward terms, rewards
==================  =====================================  =========================================

At the Python boundary the two named tuples travel as plain tuples of arrays (numba types a plain
tuple of arrays about as fast as separate arguments, a named tuple several times slower; measured
in ``benchmarks/README.md``) and are named again on entry (``MapBank(*maps)``).

Inside compiled code a follower's geometry is read through :class:`Walls` (the edges, their
bounding boxes and the static edge grid of :mod:`platoon_env.geometry.grid`, of one map).
"""

from __future__ import annotations

import math
from collections import namedtuple
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

if TYPE_CHECKING:
    from platoon_env.config import ScenarioConfig

_F8 = np.float64
_I8 = np.int64

#: Parameters of one env, each read by its name in compiled code (``params[b].d_con``). Symbols
#: are the paper's: ``r`` (robot radius), ``d_col`` (eq. 4), ``d_con``, ``beta_con`` (eq. 5),
#: ``d_des`` (Problem 1).
PARAMS_DTYPE = np.dtype(
    [
        # robot and actuators (eq. 1); the limits exactly as the float32 action Box holds them
        ("radius", _F8),  # [m] r
        ("u_low", _F8),  # [m/s]
        ("u_high", _F8),  # [m/s]
        ("omega_low", _F8),  # [rad/s]
        ("omega_high", _F8),  # [rad/s]
        # safety (eqs. 4-5) and the causes that end an episode (bit k: VIOLATION_CAUSES[k])
        ("d_col", _F8),  # [m]
        ("terminate_mask", _I8),
        # [m] safety.inflation m: the obstacles as every rule sees them are inflated by m
        # (collision at true clearance <= r + m; sensing and clearances to the inflated outline)
        ("inflation", _F8),
        # camera: the field of view F_i (eq. 5)
        ("d_con", _F8),  # [m]
        ("beta_con", _F8),  # [rad]
        # proximity sensor: range and sector half-angle (pi: all around)
        ("proximity_range", _F8),  # [m]
        ("proximity_half_angle", _F8),  # [rad]
        # the scripted leader: pure pursuit along its path, or the replay of a timed trajectory
        ("leader_replay", np.bool_),  # True: replay leader.trajectory (platoon_env.dynamics.leader)
        ("leader_speed", _F8),  # [m/s] pure pursuit's speed (trajectory: its mean speed)
        ("leader_speed_bound", _F8),  # [m/s] bound on the leader's |u| at speed factor 1
        ("lookahead", _F8),  # [m]
        ("leader_turn_rate", _F8),  # [rad/s] bound on the leader's |omega|
        # pure pursuit within the robots' rate limits (leader.drive check/retime): the changes
        # of the leader's u and omega per sub-step bounded, and braking towards the path's end
        ("leader_rate_limited", np.bool_),
        ("leader_accel", _F8),  # [m/s^2] bound on the change of the leader's u
        ("leader_alpha", _F8),  # [rad/s^2] bound on the change of the leader's omega
        # formation and reward (platoon_env.reward)
        ("d_des", _F8),  # [m]
        ("reward_d_scale", _F8),  # [m] d_con - d_des, normalises e_d
        ("wall_margin", _F8),  # [m]
        # the weight of each reward term, "w_" + its name in platoon_env.reward.REWARD_TERMS
        # (this module imports nothing of the package: reward.py checks the names)
        ("w_distance", _F8),
        ("w_bearing", _F8),
        ("w_effort", _F8),
        ("w_alive", _F8),
        ("w_violation", _F8),
        ("w_wall", _F8),
        # time and episode rules
        ("control_period", _F8),  # [s]
        ("substep", _F8),  # [s] control_period / physics_substeps
        ("physics_substeps", _I8),
        ("max_episode_steps", _I8),
        ("settle_time", _F8),  # [s]
        # perception (platoon_env.perception, docs/realism.md): what the follower is told; the
        # stage flags here and in the actuators are platoon_env.config.stage_flags
        ("perceive", np.bool_),  # any camera or proximity realism below is on
        ("random_perception", np.bool_),  # some of it draws random numbers
        ("noise_position", _F8),  # [m] std of each body-frame coordinate ...
        ("noise_position_per_m", _F8),  # [m/m] ... plus this much per metre of d
        ("noise_bearing", _F8),  # [rad] std of the rotation of a reported position
        ("detection", _F8),  # probability that a visible predecessor is reported in a frame
        ("detection_edge", _F8),  # fraction of it lost at |beta| = beta_con (quadratic)
        ("frame_period", _F8),  # [s] between camera frames; 0: a frame every control step
        ("latency_steps", _I8),  # control periods between a frame and its report
        ("proximity_noise", _F8),  # [m] std of each reported clearance
        # actuators (platoon_env.dynamics.actuators): command -> applied velocity
        ("actuate", np.bool_),  # any of the three below is on
        ("lag_gain", _F8),  # 1 - exp(-control_period / lag); 1: no lag
        ("accel_max", _F8),  # [m/s^2] bound on the change of the applied u; inf: none
        ("alpha_max", _F8),  # [rad/s^2] bound on the change of the applied omega; inf: none
        # the observation's layout (platoon_env.observation): lengths over d_con, bearing over
        # beta_con (observation.scale_free)
        ("scale_free", np.bool_),
        # the followers of env b's current episode: rows 0 .. n_followers - 1 of its
        # per-follower buffers are live, the rest (up to the buffers' N) inert
        ("n_followers", _I8),
    ],
    align=True,
)

#: Scalar state of one env's episode (``episode[b]``; written by the core).
EPISODE_DTYPE = np.dtype(
    [
        ("leader_progress", _F8),  # [m] the leader's arc length s along its path
        ("leader_arrived", np.bool_),  # the leader has reached its path's end
        # the leader's speed factor of this episode (1 + leader.speed_variation * U(-1, 1),
        # drawn at reset; 1 without variation): pure pursuit at factor * leader_speed, a
        # trajectory replayed factor times as fast
        ("leader_speed_factor", _F8),
        ("leader_substeps", _I8),  # physics sub-steps the leader has moved in this episode
        ("leader_u", _F8),  # [m/s] the leader's u in the last sub-step
        ("leader_omega", _F8),  # [rad/s] the leader's omega in the last sub-step
        ("sim_time", _F8),  # [s]
        ("steps", _I8),  # steps taken in this episode
        ("arrival_time", _F8),  # [s] sim_time when the leader arrived; NaN before
        ("substeps", _I8),  # physics sub-steps simulated by the last call
        ("terminated", np.bool_),  # the last step ended the episode by a violation
        ("truncated", np.bool_),  # ... by the time limit or the leader's settle time
        ("map_slot", _I8),  # which slot of the MapBank this env's workspace is in
        ("noise_state", np.uint64),  # the env's perception noise stream (splitmix64 state)
    ],
    align=True,
)

#: One map slot's sizes and edge-grid geometry (:mod:`platoon_env.geometry.grid`): origin
#: ``(x0, y0)`` [m], inverse cell side [1/m] and cells per axis.
MAP_INFO_DTYPE = np.dtype(
    [
        ("n_edges", _I8),
        ("n_cells", _I8),
        ("n_cell_edges", _I8),
        ("n_path", _I8),
        ("x0", _F8),
        ("y0", _F8),
        ("inv_cell", _F8),
        ("nx", _I8),
        ("ny", _I8),
    ],
    align=True,
)

#: The boundary of one workspace as the geometry kernels read it: ``edges`` ``(E, 4)``
#: ``[ax, ay, bx, by]``, their bounding ``boxes`` ``(E, 4)`` ``[x0, y0, x1, y1]``, and the edge
#: grid: ``grid`` (a :data:`MAP_INFO_DTYPE` record), ``cell_start`` ``(cells + 1,)``,
#: ``cell_edges`` and ``edge_cell`` ``(E, 2)`` (see :mod:`platoon_env.geometry.grid`).
Walls = namedtuple("Walls", "edges boxes grid cell_start cell_edges edge_cell")

#: ``M`` map slots, padded to the largest: ``info`` ``(M,)`` :data:`MAP_INFO_DTYPE`, ``edges``,
#: ``boxes`` ``(M, E, 4)``, ``cell_start`` ``(M, C + 1)``, ``cell_edges`` ``(M, K)``,
#: ``edge_cell`` ``(M, E, 2)``, the leader's ``path`` ``(M, P, 4)`` (columns :data:`PATH_X`,
#: :data:`PATH_Y`; for a timed trajectory, ``leader.trajectory``, whose sample positions are
#: the path, also each sample's time :data:`PATH_T` and heading :data:`PATH_THETA`, zeros for
#: a pure-pursuit path) and its cumulative arc length ``path_s`` ``(M, P)``. (The trajectory's
#: columns ride in ``path``: each array of the bank costs the compiled step's call about
#: 0.15 us to unbox, measured.)
MapBank = namedtuple("MapBank", "info edges boxes cell_start cell_edges edge_cell path path_s")

#: Columns of a route's ``path``: position [m], and a timed trajectory's sample time [s] and
#: heading [rad].
PATH_X, PATH_Y, PATH_T, PATH_THETA = range(4)
PATH_SIZE = 4

#: The leader's route of one map slot as the leader kernels read it (:func:`path_of`):
#: ``(path (P, 4), path_s (P,))``; the pure-pursuit kernels read the first two columns only
#: (a ``(P, 2)`` path serves them as well).
Route = tuple[np.ndarray, np.ndarray]

#: Per-follower arrays of ``B`` envs with up to ``N`` followers (env ``b`` has
#: ``params[b].n_followers`` of them, in rows ``0 .. n_followers - 1``; the compiled step
#: reads and writes only those): ``poses`` ``(B, N+1, 3)`` (leader
#: first), ``actions`` ``(B, N, 2)`` the commands (clipped), ``applied`` ``(B, N, 2)`` the
#: velocities the actuators applied, ``violations`` ``(B, N)`` int64 bit masks, ``sensed``
#: ``(B, N, SENSE_SIZE)`` ground-truth sensing, ``obs`` ``(B, N, OBS_SIZE)`` float32, ``terms``
#: ``(B, N, len(REWARD_TERMS))``, ``rewards`` ``(B, N)``, and ``frames`` ``(B, N, K + 1,
#: FRAME_SIZE)`` the camera frames in flight (a ring of ``K = latency_steps + 1``; row ``K``
#: holds the frame last delivered), see :mod:`platoon_env.perception`.
Buffers = namedtuple("Buffers", "poses actions applied violations sensed obs terms rewards frames")

#: Columns of a camera frame: captured at that step (1/0), predecessor reported (1/0), x~, y~.
FRAME_CAPTURED, FRAME_VISIBLE, FRAME_X, FRAME_Y = range(4)
FRAME_SIZE = 4


@njit(cache=True, inline="always")
def walls_of(maps: MapBank, slot: int) -> Walls:
    """The :class:`Walls` views of map ``slot`` (no copy)."""
    info = maps.info[slot]
    n_e = info.n_edges
    return Walls(
        maps.edges[slot, :n_e],
        maps.boxes[slot, :n_e],
        info,
        maps.cell_start[slot, : info.n_cells + 1],
        maps.cell_edges[slot, : info.n_cell_edges],
        maps.edge_cell[slot, :n_e],
    )


@njit(cache=True, inline="always")
def path_of(maps: MapBank, slot: int) -> Route:
    """The leader's :data:`Route` of map ``slot``: its path ``(P, 4)`` (positions, and a timed
    trajectory's sample times and headings) and cumulative arc length ``(P,)`` (no copy)."""
    n_p = maps.info[slot].n_path
    return maps.path[slot, :n_p], maps.path_s[slot, :n_p]


def new_episode(batch_size: int) -> np.ndarray:
    """A zeroed ``(B,)`` :data:`EPISODE_DTYPE` array (arrival times NaN, speed factors 1)."""
    out = np.zeros(batch_size, dtype=EPISODE_DTYPE)
    out["arrival_time"] = math.nan
    out["leader_speed_factor"] = 1.0
    return out


def constraint_params(cfg: ScenarioConfig) -> np.ndarray:
    """A ``(1,)`` :data:`PARAMS_DTYPE` array holding only what the constraint rules read
    (``radius``, ``d_col``, ``inflation``, ``d_con``, ``beta_con``, the proximity range and
    sector) — for
    checking a configuration (:func:`platoon_env.safety.configuration_masks`) before an env
    exists. :func:`platoon_env.core.params_of` fills every field."""
    out = np.zeros(1, dtype=PARAMS_DTYPE)
    out["radius"] = cfg.robot.radius
    out["d_col"] = cfg.safety.d_col
    out["inflation"] = cfg.safety.inflation
    out["d_con"] = cfg.camera.range
    out["beta_con"] = cfg.camera.half_angle
    out["proximity_range"] = cfg.proximity_range
    out["proximity_half_angle"] = cfg.proximity_half_angle
    return out
