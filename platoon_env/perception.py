"""What a follower is told: the camera's frames and the proximity sensor's noisy clearances.

The sensing kernel (:mod:`platoon_env.geometry.sensing`) computes the ground truth: ``d_i``,
``beta_i`` (eqs. 2-3), visibility and the four clearances. The observation starts as that truth
(:func:`platoon_env.simulator.observe_into`); this module then turns it into what a real sensor
reports (``docs/realism.md``), per follower and control step ``k``:

1. **frames**: a camera frame is taken at step ``k`` when a new frame period ``1 / frame_rate``
   has begun (every step without a frame rate; step 0, the reset, always);
2. **detection**: a frame reports the predecessor only if it is truly visible, and then with
   probability ``detection * (1 - detection_edge * (beta / beta_con)^2)``; otherwise it reports
   nothing (flag 0, zeros);
3. **noise**: a reported position ``(x~, y~)`` gets independent Gaussian noise of std
   ``position + position_per_m * d`` per axis and is then rotated by an angle of std
   ``bearing``; the result is clipped to ``x~ in [0, d_con]``, ``y~ in [-d_con, d_con]`` (the
   observation space's bounds: a noisy reading never leaves it);
4. **latency**: the frame taken at step ``k`` is delivered at step ``k + latency_steps``;
   between deliveries the observation holds the last delivered frame. At the reset the history
   is filled with the first frame (the platoon stood still before it started);
5. **proximity noise**: each of the four clearances gets Gaussian noise of std
   ``proximity.noise``, clipped to ``[0, proximity range]``.

Safety, rewards and ``info`` keep using the ground truth. Every random number comes from the
env's own stream (a splitmix64 state in ``episode.noise_state``), seeded from the env's RNG on
reset, so the same seed gives the same noise in the single env and in the batched core.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D
from platoon_env.observation import OBS_CLEARANCES, OBS_VISIBLE, OBS_X_REL, OBS_Y_REL
from platoon_env.records import FRAME_CAPTURED, FRAME_VISIBLE, FRAME_X, FRAME_Y

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True)
def uniform(ep: np.record) -> float:
    """The next number in ``[0, 1)`` of the env's stream (splitmix64, 53 bits)."""
    state = ep.noise_state + _GOLDEN
    ep.noise_state = state
    z = state
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def normal(ep: np.record) -> float:
    """A standard normal number from the env's stream (Box-Muller)."""
    u1 = 1.0 - uniform(ep)  # in (0, 1]
    u2 = uniform(ep)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True)
def frame_due_at(step: int, control_period: float, frame_period: float) -> bool:
    """Whether control step ``step`` takes a camera frame, with control steps every
    ``control_period`` and frames every ``frame_period`` seconds (0: a frame every step).

    A frame is due when a new frame period has begun, ``floor(k dt / T) > floor((k-1) dt / T)``,
    with a ``1e-9`` tolerance so that a frame period that is a whole number of control periods
    is not lost to rounding; step 0 (the reset) always takes one. The env's camera follows it
    (:func:`frame_due`), and so does a policy that models the camera's timing.
    """
    if frame_period <= 0.0 or step == 0:
        return True
    now = step * control_period / frame_period
    before = (step - 1) * control_period / frame_period
    return math.floor(now + 1e-9) > math.floor(before + 1e-9)


@njit(cache=True)
def frame_due(step: int, p: np.record) -> bool:
    """Whether step ``step`` of an episode takes a camera frame (:func:`frame_due_at` with the
    params record ``p``'s control and frame periods)."""
    return frame_due_at(step, p.control_period, p.frame_period)


@njit(cache=True)
def capture(
    sensed_row: np.ndarray, obs_row: np.ndarray, ep: np.record, p: np.record
) -> tuple[float, float, float]:
    """One frame of a follower from its ground truth: ``(visible, x~, y~)``."""
    if obs_row[OBS_VISIBLE] <= 0.0:
        return 0.0, 0.0, 0.0
    prob = p.detection
    if p.detection_edge > 0.0:
        ratio = sensed_row[SENSE_BETA] / p.beta_con
        prob *= 1.0 - p.detection_edge * ratio * ratio
    if prob < 1.0 and uniform(ep) >= prob:
        return 0.0, 0.0, 0.0
    d, beta = sensed_row[SENSE_D], sensed_row[SENSE_BETA]
    x, y = d * math.cos(beta), d * math.sin(beta)
    sigma = p.noise_position + p.noise_position_per_m * d
    if sigma > 0.0:
        x += sigma * normal(ep)
        y += sigma * normal(ep)
    if p.noise_bearing > 0.0:
        a = p.noise_bearing * normal(ep)
        c, s = math.cos(a), math.sin(a)
        x, y = c * x - s * y, s * x + c * y
    # A reading stays inside the camera's reach and the observation space: x~ in [0, d_con],
    # y~ in [-d_con, d_con] (noise may carry it past the range, or behind the camera).
    x = min(max(x, 0.0), p.d_con)
    y = min(max(y, -p.d_con), p.d_con)
    return 1.0, x, y


@njit(cache=True)
def perceive(
    sensed: np.ndarray, obs: np.ndarray, frames: np.ndarray, ep: np.record, p: np.record, step: int
) -> None:
    """Turn the true observations ``obs`` (N, OBS_SIZE) of step ``step`` into perceived ones.

    ``sensed`` is the ground truth (for ``d`` and ``beta``), ``frames`` the env's frame ring
    ``(N, K + 1, FRAME_SIZE)``, ``K > p.latency_steps`` (a randomised latency, ``realism``,
    sizes it for its range's longest; a frame is read ``latency_steps`` steps after it was
    written, before its slot comes round again); step 0 (a reset) fills the ring with its frame.
    """
    k_ring = frames.shape[1] - 1
    due = frame_due(step, p)
    slot = step % k_ring
    arrive = (step - p.latency_steps) % k_ring
    for i in range(obs.shape[0]):
        ring = frames[i]
        if due:
            vis, x, y = capture(sensed[i], obs[i], ep, p)
            first = 0 if step == 0 else slot
            last = k_ring if step == 0 else slot + 1
            for r in range(first, last):
                ring[r, FRAME_CAPTURED] = 1.0
                ring[r, FRAME_VISIBLE] = vis
                ring[r, FRAME_X] = x
                ring[r, FRAME_Y] = y
        else:
            ring[slot, FRAME_CAPTURED] = 0.0
        if ring[arrive, FRAME_CAPTURED] > 0.0:
            for c in range(ring.shape[1]):
                ring[k_ring, c] = ring[arrive, c]
        obs[i, OBS_VISIBLE] = ring[k_ring, FRAME_VISIBLE]
        obs[i, OBS_X_REL] = ring[k_ring, FRAME_X]
        obs[i, OBS_Y_REL] = ring[k_ring, FRAME_Y]
        if p.proximity_noise > 0.0:
            for c in OBS_CLEARANCES:
                value = obs[i, c] + p.proximity_noise * normal(ep)
                obs[i, c] = min(p.proximity_range, max(0.0, value))
