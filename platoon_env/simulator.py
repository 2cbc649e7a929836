"""The compiled core: one step of ``B`` envs, with every episode rule, in one call.

Pipeline of env ``b``'s control period (HighwayEnv-style, fixed order), :func:`step_env`:

1. the actions are clipped to the actuator limits (a NaN or inf anywhere rejects the whole call
   before any state changes: :func:`first_bad_action`);
2. ``physics_substeps`` sub-steps of ``h = control_period / physics_substeps``: the leader's
   pure-pursuit command, or its pose replayed from a timed trajectory
   (:mod:`platoon_env.dynamics.leader`), exact unicycle arcs for every robot
   (eq. 1, :mod:`platoon_env.dynamics.unicycle`), the safety checks of
   :mod:`platoon_env.safety` (eqs. 4-5) after each; stop early when a violation of a cause in
   ``terminate_on`` occurs. In the last sub-step the safety masks come from the sensing computed
   anyway (clearance, occlusion, ``d``, ``beta``), so no edge is tested twice. When a collision
   with an obstacle does not end the episode, walls stay solid: a follower whose motion would
   cross one stays where it was (:func:`platoon_env.safety.stop_at_walls`), in contact;
   The followers move with the velocities their actuators apply
   (:mod:`platoon_env.dynamics.actuators`: lag and rate limits, or the command itself);
3. sensing of every follower (:mod:`platoon_env.geometry.sensing`) and the observation vectors
   (:mod:`platoon_env.observation`), turned into what the sensors report
   (:mod:`platoon_env.perception`: frames, dropouts, noise, latency) when realism is on;
4. the reward terms of :mod:`platoon_env.reward` and each follower's summed reward;
5. the episode rules (:func:`episode_rules`): *terminated* when a follower violated a cause in
   ``terminate_on``; *truncated* otherwise when ``max_episode_steps`` steps were taken or the
   leader arrived ``settle_time`` ago.

With ``n_substeps = 0`` a call only senses (the reset of an episode). Everything is a function
of the records of :mod:`platoon_env.records`, owned by :class:`platoon_env.core.PlatoonCore`;
the PettingZoo env is that core at ``B = 1`` and :class:`platoon_env.batched.BatchedPlatoon`
the same core at ``B > 1``. Safety and sensing visit only the boundary edges that a static grid
(:mod:`platoon_env.geometry.grid`) lists near each follower, so the cost does not grow with the
size of the map.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange

from platoon_env.dynamics.actuators import actuate
from platoon_env.dynamics.leader import leader_command, limit_leader_rates, replay_leader
from platoon_env.dynamics.unicycle import unicycle_arc
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_D,
    SENSE_PROXIMITY,
    SENSE_VISIBLE,
    sense_follower_grid,
)
from platoon_env.observation import (
    ACT_OMEGA,
    ACT_U,
    OBS_CLEARANCES,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
    scale_free_into,
)
from platoon_env.perception import perceive
from platoon_env.records import (
    EPISODE_DTYPE,
    MAP_INFO_DTYPE,
    PARAMS_DTYPE,
    Buffers,
    MapBank,
    Route,
    Walls,
    path_of,
    walls_of,
)
from platoon_env.reward import reward_terms_into
from platoon_env.safety import (
    COLLISION_OBSTACLE,
    robot_contacts,
    sensed_violation,
    stop_at_walls,
    violation_masks_grid,
)


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
        # The four clearances d_W_l, d_W_r, d_l, d_r, in both tables' order.
        for k in range(len(OBS_CLEARANCES)):
            obs[i, OBS_CLEARANCES[k]] = sensed[i, SENSE_PROXIMITY[k]]


@njit(cache=True)
def clip_actions(actions: np.ndarray, p: np.record) -> None:
    """Clip ``actions`` (N, 2) in place to the actuator limits of params record ``p``."""
    for i in range(actions.shape[0]):
        actions[i, ACT_U] = min(p.u_high, max(p.u_low, actions[i, ACT_U]))
        actions[i, ACT_OMEGA] = min(p.omega_high, max(p.omega_low, actions[i, ACT_OMEGA]))


@njit(cache=True)
def advance_substep(
    env: Buffers, ep: np.record, route: Route, p: np.record, prev: np.ndarray
) -> None:
    """One physics sub-step of ``h = p.substep``: the leader along ``route`` (pure pursuit, or
    with ``p.leader_replay`` its timed trajectory at clock ``tau = n h f``, ``n`` its sub-steps
    and ``f`` the episode's speed factor) and exact arcs (eq. 1) for every follower of ``env``
    (one env's :class:`~platoon_env.records.Buffers`; they move with their applied
    velocities). ``prev`` receives the poses before; ``ep.leader_u``, ``ep.leader_omega`` the
    leader's velocity."""
    poses, actions = env.poses, env.applied
    h = p.substep
    factor = ep.leader_speed_factor
    for r in range(poses.shape[0]):
        prev[r, 0] = poses[r, 0]
        prev[r, 1] = poses[r, 1]
        prev[r, 2] = poses[r, 2]
    u0, w0 = 0.0, 0.0
    ep.leader_substeps += 1
    if p.leader_replay:
        if not ep.leader_arrived:
            tau = ep.leader_substeps * h * factor
            x, y, th, s_new, u0, w0, arrived = replay_leader(route, tau)
            poses[0, 0], poses[0, 1], poses[0, 2] = x, y, th
            u0 *= factor
            w0 *= factor
            ep.leader_progress = s_new
            if arrived:
                ep.leader_arrived = True
    else:
        if not ep.leader_arrived:
            u0, w0, s_new, arrived = leader_command(
                route, (poses[0, 0], poses[0, 1], poses[0, 2]), ep.leader_progress, p, factor
            )
            ep.leader_progress = s_new
            if arrived:
                ep.leader_arrived = True
        if p.leader_rate_limited:
            u0, w0 = limit_leader_rates(u0, w0, ep.leader_u, ep.leader_omega, p)
        x, y, th = unicycle_arc(poses[0, 0], poses[0, 1], poses[0, 2], u0, w0, h)
        poses[0, 0], poses[0, 1], poses[0, 2] = x, y, th
    ep.leader_u = u0
    ep.leader_omega = w0
    for i in range(actions.shape[0]):
        x, y, th = unicycle_arc(
            poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2], actions[i, 0], actions[i, 1], h
        )
        poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2] = x, y, th


@njit(cache=True, inline="always")
def sense_platoon(
    poses: np.ndarray,
    prev: np.ndarray,
    check_motion: bool,
    walls: Walls,
    cand: np.ndarray,
    p: np.record,
    sensed: np.ndarray,
    masks: np.ndarray,
) -> None:
    """Sense every follower of ``poses`` into ``sensed`` and write each one's violation mask,
    read off that sensing (robot contacts included), into ``masks``; with ``check_motion`` the
    motion from ``prev`` is tested for crossing a wall."""
    for i in range(masks.shape[0]):
        clear2, motion_hit = sense_follower_grid(
            (poses[i + 1, 0], poses[i + 1, 1], poses[i + 1, 2]),
            (poses[i, 0], poses[i, 1]),
            (prev[i + 1, 0], prev[i + 1, 1]),
            check_motion,
            walls,
            cand,
            p,
            sensed[i],
        )
        masks[i] = sensed_violation(sensed[i], clear2, motion_hit, p)
    robot_contacts(poses, p.radius, masks)


@njit(cache=True)
def simulate(
    env: Buffers,
    ep: np.record,
    walls: Walls,
    route: Route,
    p: np.record,
    n_substeps: int,
) -> int:
    """Sub-steps, safety, sensing and observations of one control period (no reward).

    Returns the number of sub-steps simulated. On entry ``env.sensed`` must hold the sensing of
    ``env.poses`` (as the previous call, or a reset with ``n_substeps = 0``, left it) or zeros:
    the sub-step safety checks use it to skip the edge tests of followers that cannot have
    reached a wall.
    """
    poses, actions, violations, sensed = env.poses, env.applied, env.violations, env.sensed
    n = actions.shape[0]
    prev = np.empty_like(poses)
    sub_mask = np.empty(n, dtype=np.int64)
    cand = np.empty(walls.edges.shape[0], dtype=np.int64)
    # How far each robot can have moved since the sensing in `sensed` (the start of this
    # period): lets the sub-step safety checks skip followers far from every wall.
    travel = np.zeros(n + 1)
    h = p.substep
    # Walls are solid when collisions do not end the episode: a follower does not pass through.
    solid = not p.terminate_mask & COLLISION_OBSTACLE
    for i in range(n):
        violations[i] = 0
    done = 0
    sensed_now = False
    for k in range(n_substeps):
        advance_substep(env, ep, route, p, prev)
        done += 1
        # The chord of an arc is at most its length |u| h; the leader never exceeds its speed
        # bound (pure pursuit: its speed; a trajectory: its fastest segment), times f.
        travel[0] += p.leader_speed_bound * ep.leader_speed_factor * h
        for i in range(n):
            travel[i + 1] += abs(actions[i, ACT_U]) * h
        if k == n_substeps - 1:
            # Last sub-step: sense now and read the safety masks off the sensing.
            sense_platoon(poses, prev, True, walls, cand, p, sensed, sub_mask)
            sensed_now = True
            if solid and stop_at_walls(poses, prev, walls, cand, sub_mask):
                # Sense again where the stopped followers stand (their successors' lines of
                # sight changed too); they stay in collision.
                contact = sub_mask & COLLISION_OBSTACLE
                sense_platoon(poses, poses, False, walls, cand, p, sensed, sub_mask)
                sub_mask |= contact
        else:
            violation_masks_grid(poses, prev, walls, cand, p, sub_mask, sensed, travel)
            if solid:
                stop_at_walls(poses, prev, walls, cand, sub_mask)
        stop = False
        for i in range(n):
            violations[i] |= sub_mask[i]
            if sub_mask[i] & p.terminate_mask:
                stop = True
        if stop:
            break
    if not sensed_now:
        sense_platoon(poses, poses, False, walls, cand, p, sensed, sub_mask)
    observe_into(sensed, env.obs)
    return done


@njit(cache=True)
def episode_rules(ep: np.record, violations: np.ndarray, p: np.record, done: int) -> None:
    """Time, step count and the episode's end after a step of ``done`` sub-steps.

    *terminated*: some follower's violation mask has a cause of ``p.terminate_mask``;
    *truncated* (only when not terminated): ``p.max_episode_steps`` steps taken, or the leader
    arrived at least ``p.settle_time`` ago.
    """
    ep.sim_time += done * p.substep
    ep.steps += 1
    if ep.leader_arrived and math.isnan(ep.arrival_time):
        ep.arrival_time = ep.sim_time
    term = False
    for i in range(violations.shape[0]):
        if violations[i] & p.terminate_mask:
            term = True
    ep.terminated = term
    ep.truncated = not term and (
        ep.steps >= p.max_episode_steps
        or (
            not math.isnan(ep.arrival_time)
            and ep.sim_time - ep.arrival_time >= p.settle_time - 1e-9
        )
    )


@njit(cache=True)
def step_env(
    b: int, n_substeps: int, params: np.ndarray, episode: np.ndarray, maps: MapBank, bufs: Buffers
) -> None:
    """Env ``b``'s control period (see the module docstring); with ``n_substeps = 0`` only its
    sensing and observations (a reset)."""
    p = params[b]
    ep = episode[b]
    # Env b's own followers only (p.n_followers of the buffers' N rows): the rest stay inert.
    n = p.n_followers
    env = Buffers(
        bufs.poses[b, : n + 1],
        bufs.actions[b, :n],
        bufs.applied[b, :n],
        bufs.violations[b, :n],
        bufs.sensed[b, :n],
        bufs.obs[b, :n],
        bufs.terms[b, :n],
        bufs.rewards[b, :n],
        bufs.frames[b, :n],
    )
    if n_substeps > 0:
        clip_actions(env.actions, p)
        actuate(env.actions, env.applied, p)
    done = simulate(env, ep, walls_of(maps, ep.map_slot), path_of(maps, ep.map_slot), p, n_substeps)
    ep.substeps = done
    if p.perceive:
        perceive(env.sensed, env.obs, env.frames, ep, p, ep.steps + 1 if n_substeps > 0 else 0)
    if p.scale_free:
        scale_free_into(env.obs, p.d_con, p.beta_con)
    if n_substeps == 0:
        ep.terminated = False
        ep.truncated = False
        return
    reward_terms_into(env.sensed, env.actions, env.violations, p, env.terms)
    terms, rewards = env.terms, env.rewards
    for i in range(terms.shape[0]):
        total = 0.0
        for t in range(terms.shape[1]):
            total += terms[i, t]
        rewards[i] = total
    episode_rules(ep, env.violations, p, done)


@njit(cache=True)
def first_bad_action(active: np.ndarray, actions: np.ndarray, params: np.ndarray) -> int:
    """``b * N + i`` of the first active env's action row holding NaN or inf, else -1 (only the
    env's own followers, ``params[b].n_followers``, count: an inert row is never read)."""
    n = actions.shape[1]
    for b in range(actions.shape[0]):
        if active[b]:
            for i in range(params[b].n_followers):
                for j in range(actions.shape[2]):
                    if not math.isfinite(actions[b, i, j]):
                        return b * n + i
    return -1


@njit(cache=True)
def count_ended(active: np.ndarray, episode: np.ndarray) -> int:
    """Number of active envs whose episode ended in this call."""
    ended = 0
    for b in range(active.shape[0]):
        if active[b] and (episode[b].terminated or episode[b].truncated):
            ended += 1
    return ended


def _driver(name: str, parallel: bool, doc: str) -> Any:
    """A compiled driver of the step, ``name`` (docstring ``doc``): ``(active, n_substeps,
    params_bytes, episode_bytes, maps, bufs) -> int`` steps (or, with ``n_substeps = 0``,
    senses) the ``active`` envs, over numba's threads (``prange``) when ``parallel``, else one
    after the other.

    The records arrive as their bytes (``params.view(np.uint8)``, ...) and the named tuples as
    plain tuples (``maps``: a :class:`~platoon_env.records.MapBank` with its ``info`` as bytes;
    ``bufs``: a :class:`~platoon_env.records.Buffers`): numba types a structured array or a
    named tuple passed from Python on a slow path on every call (about 0.5 µs each, measured), a
    byte array or a plain tuple of arrays on its fast one. They are named again inside. The
    driver returns how many envs ended, or ``-1 - (b * N + i)`` when follower ``i`` of env
    ``b`` has a NaN or inf action (then nothing changed).

    One body, compiled twice: numba caches one compiled variant per function (its cache files
    are named by the function's qualified name, here ``name``), and ``prange`` parallelises
    only with ``parallel=True`` (without, it is ``range``).
    """

    def driver(
        active: np.ndarray,
        n_substeps: int,
        params_bytes: np.ndarray,
        episode_bytes: np.ndarray,
        maps: tuple,  # type: ignore[type-arg]
        bufs: tuple,  # type: ignore[type-arg]
    ) -> int:
        # The records and named tuples named again here, not through an inlined helper:
        # numba's parfor lowering cannot trace a named tuple that an inlined call returned into
        # the prange body.
        params = params_bytes.view(PARAMS_DTYPE)
        episode = episode_bytes.view(EPISODE_DTYPE)
        bank = MapBank(maps[0].view(MAP_INFO_DTYPE), *maps[1:])
        buf = Buffers(*bufs)
        bad = first_bad_action(active, buf.actions, params) if n_substeps > 0 else -1
        if bad >= 0:
            return -1 - bad
        for b in prange(active.shape[0]):
            if active[b]:
                step_env(b, n_substeps, params, episode, bank, buf)
        return count_ended(active, episode)

    driver.__name__ = driver.__qualname__ = name
    driver.__doc__ = doc
    return njit(cache=True, parallel=parallel)(driver)


step_serial = _driver("step_serial", False, "The :func:`_driver` of the envs one after the other.")
step_parallel = _driver("step_parallel", True, "The :func:`_driver` over numba's threads (prange).")
