r"""PPC behind a measurement filter: the paper's law, made robust to a realistic camera and drive.

:class:`FilteredPPCPolicy` runs the unchanged Prescribed Performance Control law of
:mod:`baselines.ppc` (eqs. 7, 12-14 of "Coordination of Multiple Robotic Vehicles in
Obstacle-Cluttered Environments") on *estimates* instead of raw camera frames. The paper assumes
ideal sensing. Under the env's realism settings (``camera.noise``, ``detection``,
``frame_rate``, ``latency``, ``proximity.noise``, ``robot.accel_max`` / ``alpha_max`` /
``lag``; ``docs/sensing.md``, the ``aruco`` sensor profile) the raw law fails fast: a 50 ms
latency makes its high-gain bearing loop oscillate out of the field of view within seconds,
and camera noise alone lets the followers close up past ``d_col`` in study C's narrow
corridor, where the law deliberately holds the distance funnel against ``d_col`` and the
bearing funnel against ``beta_con``.

Per follower ``i`` (index dropped) and control step ``k`` (time ``t_k = k dt``) the policy

1. **dead-reckons its own pose** ``o_k = (X_k, Y_k, Theta_k)`` in its own odometry frame
   (``o_0 = 0``) from its own commands. Each command is clipped to the action box and passed
   through the actuator model the scenario declares: the first-order lag
   ``v += (c - v)(1 - exp(-dt / lag))``, then the rate limits ``accel_max dt`` and
   ``alpha_max dt`` (:func:`actuator_step`: the env's rule,
   :func:`platoon_env.dynamics.actuators.follow`). The applied ``(u, omega)`` is held for
   ``dt`` on the exact unicycle arc of eq. 1 (:func:`odometry_step`: the env's
   :func:`~platoon_env.dynamics.unicycle.unicycle_arc`). A robot knows its own drive; no
   ground truth is read;
2. **filters the camera** with a constant-velocity Kalman filter on the predecessor's position
   in its own body frame, run at the time the latest frame shows (latency compensation, below);
3. **moves the estimate to the present**, through its own motion since then, and on by the
   **lookahead** ``tau`` (below);
4. **low-passes the four clearances** ``d_W_l, d_W_r, d_l, d_r``;
5. runs an inner :class:`baselines.ppc.PPCPolicy`, the paper's law, on
   ``[tracked, x^, y^, c^_W_l, c^_W_r, c^_l, c^_r]``: ``d = |p^|``, ``beta = atan2(y^, x^)``
   (eqs. 2-3), errors (eq. 7), performance functions (eq. 12), ``u`` (eq. 13), ``omega``
   (eq. 14). Its constraints ``d_col``, ``beta_con``, ``d_con`` are **tightened** by margins
   sized to the camera's noise (below). Its commands are returned unchanged.

The filter (:func:`kf_predict`, :func:`kf_update`)
--------------------------------------------------
State, in the follower's body frame at the filter's time ``t_j``::

    s = [p_x, p_y, w_x, w_y]^T

``p = (p_x, p_y)``: the predecessor's position (the camera's ``(x~, y~)``); ``w``: the
predecessor's *world* velocity expressed in the body frame, which stays constant while the
predecessor drives straight at constant speed, whatever the follower does.

Prediction over one control period, in which the follower moves by ``(dx, dy)`` (in its old
body frame) and turns by ``a`` (the relative pose of ``o_{j+1}`` in ``o_j``, from the
odometry), with ``R(a) = [[cos a, -sin a], [sin a, cos a]]``::

    s' = F s + b,    F = [[R(-a), dt R(-a)],        b = [-R(-a) (dx, dy)^T]
                          [0,     R(-a)   ]],            [ 0              ]
    P' = F P F^T + Q,  Q = q [[dt^3/3 I_2, dt^2/2 I_2],
                              [dt^2/2 I_2, dt     I_2]].

The predecessor moves by ``w dt`` while the frame moves along the follower's arc. ``Q`` is the
white-noise-acceleration model of the predecessor (spectral density ``q`` [m^2/s^3],
``q_accel``; isotropic, so the rotation leaves it unchanged). The follower's own motion is taken
as exact (in simulation it is: the actuator model is deterministic); ``q`` also absorbs the
manoeuvres of a predecessor that is itself a follower.

Measurement, when a frame with a detection arrives::

    z = (x~, y~)^T = H s + v,   H = [I_2  0],
    R = sigma^2 I_2 + sigma_b^2 [[ y~^2,  -x~ y~],
                                 [-x~ y~,  x~^2 ]],   sigma = max(sigma_0 + sigma_1 |z|, sigma_f)

This is the covariance of the env's camera model (``camera.noise``): per-axis noise of std
``sigma_0 + sigma_1 d`` (``position``, ``position_per_m``), then a rotation by an angle of std
``sigma_b`` (``bearing``), which moves the point by about ``d sigma_b`` along the tangent
``(-y~, x~)/d``. The floor ``sigma_f`` (``sigma_floor``) keeps ``R > 0`` with an ideal camera.
The update is the standard one::

    S = H P H^T + R,   K = P H^T S^-1,   s += K (z - H s),   P -= K S K^T.

Start: at the first frame with a detection ``s = [z, 0, 0]`` (the platoon stands still at a
reset), ``P = blockdiag(R, v0_std^2 I_2)``.

Frames, dropouts and latency
----------------------------
The policy knows its camera's timing (``camera.frame_rate`` and ``camera.latency`` from
``env.scenario.config``: a robot knows its sensor's datasheet and timestamps its frames) and
mirrors it: a frame is taken at step ``j`` when a new frame period ``1/frame_rate`` begins
(every step without a frame rate; step 0 always: :func:`frame_due`, the env camera's rule
:func:`platoon_env.perception.frame_due_at`) and is delivered
``L = latency / dt`` steps later. The filter is therefore kept at ``t_j``, ``j = max(k - L, 0)``:

* each step it is predicted from ``t_{j-1}`` to ``t_j`` with the odometry between them;
* if a frame taken at ``t_j`` is delivered now and reports the predecessor (``visible = 1``),
  the filter is updated with it. A frame without a detection (a dropout), or a step without a
  new frame (the env holds the last one), is only predicted through: a held frame is never
  used twice;
* the estimate handed to the law is the filter's mean moved to ``t_k``: the predecessor by
  ``w (k - j) dt``, the frame by the follower's relative pose ``o_j^{-1} o_k``, the exact
  composition of the ``k - j`` arcs, read from a ring of the last ``L + 2`` odometry poses
  (:func:`propagate_mean`)::

      p^_k = R(-A) (p_j + w_j (k - j) dt - D),   (D, A) = the pose of o_k in the frame of o_j.

If the filter has had no update for more than ``max_coast`` seconds (or none yet), the law is
told the predecessor is not visible, and it stops the follower (ppc.py, choice 5). The filter
keeps predicting, and the next detection updates it.

Lookahead: the drive's response time
------------------------------------
With rate limits (or a lag) a command takes effect only gradually, and the law's high gains
(``k_d J``, with ``J = (hi - lo)/((e - lo)(hi - e))``, about ``40 /s`` on study C's narrow
funnels) then overshoot: the follower keeps accelerating until the error has crossed the
funnel. The policy therefore shows the law the predecessor where it will be ``tau`` seconds on
(``lookahead``) if the follower keeps its applied velocity ``(u_a, omega_a)`` (from the
actuator model) and the predecessor its estimated one: with ``(D, A)`` the arc of
``(u_a, omega_a)`` over ``tau``, ``p^ <- R(-A) (p^ + w^ tau - D)``. This is a predictor for
the drive's delay; near the set point it adds the damping term ``tau e_dot`` to the errors the
law sees. The default is ``tau = lag + 0.1 s`` when the scenario declares rate limits or a
lag, and ``tau = 0`` without them, when the estimate is the present one (and with an ideal
camera the commands are the plain law's). The 0.1 s is measured: on study C with the aruco
profile and ``accel_max = 1`` (5 seeds), ``tau = 0`` collided in 5 of 5 episodes,
``tau = 0.05`` passed with 67 funnel exits in all, ``0.1`` and ``0.2`` passed (0.2 with more
command chatter under the profile's own 2.5 m/s^2).

``lookahead_predecessor`` (``phi``, default 1) is the fraction of ``tau`` over which the
predecessor is moved on: ``p^ <- R(-A) (p^ + phi w^ tau - D)``. At ``phi = 1`` (the default
above) the law sees where both robots will be; at ``phi = 0`` it sees where the *follower*
will be, relative to where the predecessor is now: a predictor of the follower's own drive
alone. A long ``tau`` with ``phi = 1`` extrapolates the predecessor in a straight line past
the corners it is turning, and the follower cuts them; with ``phi = 0`` a long ``tau`` only
damps the follower's own turn (``beta`` moves by about ``-omega_a tau``), which is what a
rate-limited ``omega`` needs (:mod:`baselines.filtered_ppc_drive` chooses both values on
training layouts).

Constraint tightening
---------------------
The law is designed to work *at* its constraints: in a narrow passage its activation terms
``F_l, F_r`` (after eq. 12) push the distance funnel down to ``rho_d_lo = -(d_des - d_col)``
and the bearing funnel against ``+-beta_con``. Fed an estimate with error ``delta``, it then
holds the *true* state up to ``delta`` beyond the constraint. The inner law is therefore given
tightened constraints, each by ``margin_sigmas`` (``kappa``, default 4) times the camera's
per-frame noise std where the constraint binds:

* ``d_col' = d_col + kappa (sigma_0 + sigma_1 d_col)``;
* ``beta_con' = beta_con - kappa (sigma_b + (sigma_0 + sigma_1 d_des) / d_des)``;
* ``d_con' = d_con - kappa (sigma_0 + sigma_1 d_con)``.

The margins are zero with an ideal camera; ``d_col_margin``, ``beta_margin`` and
``range_margin`` set them explicitly. The law's funnels, gains and equations are unchanged;
only its limits move inward.

Clearances
----------
Each clearance ``c`` (noise ``proximity.noise``) is low-passed,
``c^ += (c - c^)(1 - exp(-dt / clearance_tau))``, and the law's ``F = S(m; delta)/m`` (after
eq. 12) reads ``c^``. ``clearance_tau = 0`` hands the raw values through; it is the default
with a noise-free proximity sensor, and 0.05 s with a noisy one. The clearances change with the
robot's own motion past static walls, so a long ``tau`` delays them (0.05 s at 0.5 m/s: 2.5
cm). Measured on study C with the aruco profile: 0.05 s cuts the step-to-step jitter of
``F_l + F_r`` sevenfold (std 0.064 -> 0.009) and changes neither success nor the smallest
clearance; it is a light touch, not a safety device.

Tuning and results
------------------
``q_accel = 0.002`` m^2/s^3 comes from a sweep on studies B and C under the aruco profile (5
seeds each, also with ``accel_max = 1`` and with ``lag = 0.05``): lower ``q`` averages more
frames and the law's commands chatter less (std of the step-to-step change of ``u`` on study
C: 0.13 m/s at 0.002, 0.19 at 0.01, 0.79 at 0.1); ``q >= 0.03`` gave funnel exits and, at 0.1,
a collision. ``margin_sigmas = 4`` keeps the smallest inter-robot distance on study C at 0.34-
0.35 m against ``d_col = 0.3`` (0.31 without margins).

Under the aruco profile (seeds 0-11 per study) the policy runs studies B and C without a
violation, where the plain law fails study C in every episode (out of the field of view, once
out of range, after 3.9-6.7 s) and study B once (a collision at 62 s). It does so as well with
the profile's stricter variant ``accel_max = 1`` (plain law: 0/12 on C, 10/12 on B) and with a
drive lag of 0.05 s (plain law: 0/12, 11/12). With ideal sensing and drive it matches the plain
law (commands within 2e-4 over whole episodes). Study A (seven followers) is not solved: the
filter handles the profile's sensing (12 of 12 with the profile's camera and LiDAR but an
ideal drive, where the plain law fails all 12 within 2.5 s), but the drive limits (2.5 m/s^2,
3.2 rad/s^2) are beyond the law's demands there. With ideal sensing and those limits the plain
law already collides in the start transient (3-3.7 s: the asymmetric initial distance funnel
commands a reverse of about 1.1 m/s at ``t = 0``, and the rate-limited drive turns it into a
stop-and-go wave along the string); the lookahead carries the filtered law through the start,
but in gap G2 the activation terms move the funnels at 1-3 m/s or rad/s and the followers
collide (39.5 s). With the full profile it collides at 3.4-4.3 s.

Implementation
--------------
The pure functions (:func:`kf_predict`, :func:`kf_update`, :func:`measurement_covariance`,
:func:`propagate_mean`, :func:`relative_pose`) are the filter's equations, vectorised over
followers with numpy, for tests and readers; :func:`odometry_step`, :func:`actuator_step` and
:func:`frame_due` apply the env's own rules (the unicycle arc, the actuators, the camera's
frame timing) elementwise. :class:`FilteredPPCPolicy` runs the same equations in one compiled
(numba) loop over the followers (:func:`_filter_step`, :func:`_dead_reckon_step`, which call
those rules and :mod:`baselines.odometry`), then the inner law's own compiled kernel. The
filter's state is one record of named arrays (:class:`FilterState`) and its constants one
structured record (:data:`FILTER_KERNEL_DTYPE`), both read by field name.
"""

from __future__ import annotations

import math
from collections import namedtuple
from collections.abc import Mapping
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from typing import Any, ClassVar

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from baselines.odometry import body_arc, in_frame
from baselines.policy import Followers, PolicyEnv, as_float, kernel_record
from baselines.ppc import PPCPolicy
from platoon_env.dynamics.actuators import follow, lag_gain
from platoon_env.dynamics.unicycle import unicycle_arc
from platoon_env.observation import (
    ACT_OMEGA,
    ACT_U,
    OBS_CLEARANCES,
    OBS_SIZE,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
)
from platoon_env.perception import frame_due_at
from platoon_env.scenarios.schema import ObservationConfig, RobotConfig, ScenarioConfig

__all__ = [
    "FILTER_KERNEL_DTYPE",
    "FILTER_SIGNAL_NAMES",
    "FilterParams",
    "FilterState",
    "FilteredPPCPolicy",
    "actuator_step",
    "drive_limited",
    "frame_due",
    "kf_predict",
    "kf_update",
    "measurement_covariance",
    "odometry_step",
    "process_noise",
    "propagate_mean",
    "relative_pose",
]

FloatArray = NDArray[np.float64]

#: Keys :attr:`FilteredPPCPolicy.signals` adds to the inner law's
#: (:data:`baselines.ppc.SIGNAL_NAMES`).
FILTER_SIGNAL_NAMES: tuple[str, ...] = (
    "x_hat",  # [m] the predecessor's position handed to the law (body frame, t_k + tau)
    "y_hat",
    "w_x",  # [m/s] its estimated world velocity, in the body frame at t_k
    "w_y",
    "pos_std",  # [m] sqrt of the trace of the filter's position covariance, at t_j
    "coast",  # [s] since the last measurement update (inf before the first)
    "updated",  # a measurement update happened this step
    "tracked",  # the law was told the predecessor is visible
)
_FLAG_SIGNALS = ("updated", "tracked")


# ----------------------------------------------------------------------------------------------
# Pure functions: the equations of the module docstring, vectorised over followers
# ----------------------------------------------------------------------------------------------


#: Whether the camera takes a frame at control step ``step`` (step 0 always does):
#: ``frame_due(step, control_period, frame_period)``, the env camera's own rule
#: (:func:`platoon_env.perception.frame_due_at`), under the name this module has exported.
frame_due = frame_due_at


def actuator_step(
    applied: ArrayLike, command: ArrayLike, lag_gain: float, max_change: ArrayLike
) -> FloatArray:
    r"""The velocity the wheels apply after one period: the lag, then the rate limit.

    ``v' = clip(v + (c - v) g, v - max_change, v + max_change)``, with ``g = 1 - exp(-dt/lag)``
    (``g = 1``: no lag) and ``max_change = (accel_max dt, alpha_max dt)`` (``inf``: no limit).
    ``applied`` and ``command`` are ``(..., 2)`` ``[u, omega]``. The env's rule
    (:func:`platoon_env.dynamics.actuators.follow`), elementwise.
    """
    return np.vectorize(follow, otypes=[np.float64])(applied, command, lag_gain, max_change)


def odometry_step(pose: ArrayLike, u: ArrayLike, omega: ArrayLike, dt: float) -> FloatArray:
    r"""Dead reckoning: the pose ``(X, Y, Theta)`` (``(..., 3)``) after holding ``(u, omega)``
    for ``dt`` on the exact unicycle arc of eq. 1 (the env's
    :func:`~platoon_env.dynamics.unicycle.unicycle_arc`, pose by pose).

    In its old body frame the robot moves by ``(dx, dy) = (u dt sinc(a), u dt (1 - cos a)/a)``
    and turns by ``a = omega dt``.
    """
    o = as_float(pose)
    arc = np.vectorize(unicycle_arc, otypes=[np.float64] * 3)
    return np.stack(arc(o[..., 0], o[..., 1], o[..., 2], u, omega, dt), -1)


def relative_pose(
    pose_from: ArrayLike, pose_to: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    r"""``(D_x, D_y, A)``: the pose ``pose_to`` in the body frame of ``pose_from``
    (``o_from^{-1} o_to``): ``D = R(-Theta_from) (P_to - P_from)``, ``A = Theta_to -
    Theta_from``. A point at ``p`` in the old frame is at ``R(-A) (p - D)`` in the new one."""
    a, b = as_float(pose_from), as_float(pose_to)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    ex, ey = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return c * ex + s * ey, -s * ex + c * ey, b[..., 2] - a[..., 2]


def process_noise(q: float, dt: float) -> FloatArray:
    """``Q`` (4, 4) of :func:`kf_predict`: white-noise acceleration of spectral density ``q``."""
    eye = np.eye(2)
    return q * np.block([[dt**3 / 3 * eye, dt**2 / 2 * eye], [dt**2 / 2 * eye, dt * eye]])


def kf_predict(
    s: ArrayLike,
    P: ArrayLike,
    dx: ArrayLike,
    dy: ArrayLike,
    a: ArrayLike,
    dt: float,
    q: float,
) -> tuple[FloatArray, FloatArray]:
    r"""One prediction step: ``s' = F s + b``, ``P' = F P F^T + Q`` (module docstring).

    ``s`` (n, 4) ``[p_x, p_y, w_x, w_y]``, ``P`` (n, 4, 4); ``(dx, dy, a)`` (n,) the follower's
    own motion over ``dt`` (:func:`relative_pose` of consecutive odometry poses).
    """
    ss, PP = as_float(s).reshape(-1, 4), as_float(P).reshape(-1, 4, 4)
    aa = as_float(a).reshape(-1)
    c, sn = np.cos(aa), np.sin(aa)
    rot = np.zeros((aa.shape[0], 2, 2))  # R(-a)
    rot[:, 0, 0] = rot[:, 1, 1] = c
    rot[:, 0, 1] = sn
    rot[:, 1, 0] = -sn
    F = np.zeros((aa.shape[0], 4, 4))
    F[:, 0:2, 0:2] = F[:, 2:4, 2:4] = rot
    F[:, 0:2, 2:4] = rot * dt
    disp = np.stack([as_float(dx).reshape(-1), as_float(dy).reshape(-1)], -1)
    s_new = np.einsum("nij,nj->ni", F, ss)
    s_new[:, 0:2] -= np.einsum("nij,nj->ni", rot, disp)
    P_new = F @ PP @ np.swapaxes(F, 1, 2) + process_noise(q, dt)
    return s_new, P_new


def measurement_covariance(
    z: ArrayLike, sigma_0: float, sigma_1: float, sigma_b: float, sigma_floor: float = 0.0
) -> FloatArray:
    r"""``R`` (n, 2, 2) of camera points ``z = (x~, y~)`` (n, 2) (module docstring):
    ``R = sigma^2 I + sigma_b^2 [[y~^2, -x~ y~], [-x~ y~, x~^2]]``,
    ``sigma = max(sigma_0 + sigma_1 |z|, sigma_floor)``."""
    zz = as_float(z).reshape(-1, 2)
    x, y = zz[:, 0], zz[:, 1]
    sig2 = np.maximum(sigma_0 + sigma_1 * np.hypot(x, y), sigma_floor) ** 2
    b2 = sigma_b**2
    R = np.empty((zz.shape[0], 2, 2))
    R[:, 0, 0] = sig2 + b2 * y * y
    R[:, 1, 1] = sig2 + b2 * x * x
    R[:, 0, 1] = R[:, 1, 0] = -b2 * x * y
    return R


def kf_update(
    s: ArrayLike, P: ArrayLike, z: ArrayLike, R: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    r"""One measurement update with ``H = [I_2 0]`` (module docstring):
    ``S = P_pp + R``, ``K = P H^T S^-1``, ``s += K (z - p)``, ``P -= K S K^T``.

    ``s`` (n, 4), ``P`` (n, 4, 4), ``z`` (n, 2), ``R`` (n, 2, 2).
    """
    ss, PP = as_float(s).reshape(-1, 4), as_float(P).reshape(-1, 4, 4)
    zz, RR = as_float(z).reshape(-1, 2), as_float(R).reshape(-1, 2, 2)
    S = PP[:, 0:2, 0:2] + RR
    K = PP[:, :, 0:2] @ np.linalg.inv(S)  # (n, 4, 2)
    s_new = ss + np.einsum("nij,nj->ni", K, zz - ss[:, 0:2])
    P_new = PP - K @ S @ np.swapaxes(K, 1, 2)
    return s_new, 0.5 * (P_new + np.swapaxes(P_new, 1, 2))


def propagate_mean(
    s: ArrayLike, dx: ArrayLike, dy: ArrayLike, a: ArrayLike, elapsed: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    r"""The filter's mean ``s`` (n, 4) moved on by ``T`` = ``elapsed`` seconds, in which the
    follower's pose changed by ``(D_x, D_y, A)`` = ``(dx, dy, a)``: ``p^ = R(-A)(p + w T - D)``,
    ``w^ = R(-A) w``. Returns ``(p^, w^)``, (n, 2) each."""
    ss = as_float(s).reshape(-1, 4)
    c, sn = np.cos(as_float(a)), np.sin(as_float(a))
    T = as_float(elapsed)
    px = ss[:, 0] + ss[:, 2] * T - as_float(dx)
    py = ss[:, 1] + ss[:, 3] * T - as_float(dy)
    p = np.stack([c * px + sn * py, -sn * px + c * py], -1)
    w = np.stack([c * ss[:, 2] + sn * ss[:, 3], -sn * ss[:, 2] + c * ss[:, 3]], -1)
    return p, w


# ----------------------------------------------------------------------------------------------
# Parameters
# ----------------------------------------------------------------------------------------------


def drive_limited(robot: RobotConfig) -> bool:
    """Whether the drive delays a command: a first-order lag or a rate limit on ``u`` or
    ``omega`` (the scenario's ``robot.lag``, ``accel_max``, ``alpha_max``). Only such a drive
    gets a lookahead by default."""
    return robot.lag > 0 or robot.accel_max is not None or robot.alpha_max is not None


@dataclass(frozen=True)
class FilterParams:
    """The policy's model of its camera, proximity sensor and drive, and the filter's tuning.

    The sensor and drive values come from the scenario (``camera``, ``robot`` blocks: what the
    datasheets say); the tuning (:attr:`TUNABLE`) has defaults and may be overridden by keyword.
    :meth:`from_config` derives ``clearance_tau``, ``lookahead`` and the three margins from the
    scenario unless they are given (module docstring); the field defaults here are the values
    of an ideal camera and drive.
    """

    dt: float  # [s] control period
    latency_steps: int  # L = camera.latency / dt
    frame_period: float  # [s] 1 / camera.frame_rate; 0: a frame every control step
    sigma_0: float  # [m] camera.noise.position
    sigma_1: float  # [m/m] camera.noise.position_per_m
    sigma_b: float  # [rad] camera.noise.bearing
    u_max: float  # [m/s] action box, robot.u_max
    omega_max: float  # [rad/s] robot.omega_max
    lag_gain: float  # 1 - exp(-dt / robot.lag); 1: no lag
    du_max: float  # [m/s] robot.accel_max dt: largest change of the applied u in one period
    dw_max: float  # [rad/s] robot.alpha_max dt
    # -- tuning --
    q_accel: float = 0.002  # [m^2/s^3] spectral density of the predecessor's acceleration
    v0_std: float = 0.5  # [m/s] prior std of the predecessor's velocity at the first frame
    sigma_floor: float = 1e-6  # [m] floor on the measurement std (R > 0, ideal camera)
    max_coast: float = 1.0  # [s] tell the law "not visible" after this long without an update
    clearance_tau: float = 0.0  # [s] time constant of the clearance low-pass; 0: none
    lookahead: float = 0.0  # [s] tau: the estimate is shown tau ahead (drive's response)
    lookahead_predecessor: float = 1.0  # the predecessor is moved on for this fraction of tau
    margin_sigmas: float = 4.0  # kappa: margins = kappa x the camera's per-frame noise std
    d_col_margin: float = 0.0  # [m] inner law's d_col = d_col + this
    beta_margin: float = 0.0  # [rad] inner law's beta_con = beta_con - this
    range_margin: float = 0.0  # [m] inner law's d_con = d_con - this

    TUNABLE: ClassVar[tuple[str, ...]] = (
        "q_accel",
        "v0_std",
        "sigma_floor",
        "max_coast",
        "clearance_tau",
        "lookahead",
        "lookahead_predecessor",
        "margin_sigmas",
        "d_col_margin",
        "beta_margin",
        "range_margin",
    )
    #: [s] added to ``robot.lag`` for the default lookahead when the drive is rate-limited
    LOOKAHEAD_RATE_LIMITED: ClassVar[float] = 0.1
    #: [s] default clearance time constant when the proximity sensor is noisy
    CLEARANCE_TAU: ClassVar[float] = 0.05

    def __post_init__(self) -> None:
        for name in ("dt", "q_accel", "v0_std", "sigma_floor", "max_coast"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"filter parameter {name} must be finite and > 0, got {value!r}")
        for name in (
            "clearance_tau", "lookahead", "margin_sigmas", "d_col_margin", "beta_margin",
            "range_margin",
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"filter parameter {name} must be finite and >= 0, got {value!r}")
        if not 0.0 <= self.lookahead_predecessor <= 1.0:
            raise ValueError(
                "filter parameter lookahead_predecessor must be in [0, 1], got "
                f"{self.lookahead_predecessor!r}"
            )
        if self.latency_steps < 0:
            raise ValueError(f"latency_steps must be >= 0, got {self.latency_steps!r}")

    @property
    def clearance_gain(self) -> float:
        """``1 - exp(-dt / clearance_tau)`` (1: no filtering)."""
        return 1.0 if self.clearance_tau == 0 else -math.expm1(-self.dt / self.clearance_tau)

    @classmethod
    def from_config(
        cls, config: ScenarioConfig, dt: float, **overrides: float | None
    ) -> FilterParams:
        """The sensor and drive model of ``config`` at control period ``dt``, plus tuning
        ``overrides`` (names in :attr:`TUNABLE`). ``clearance_tau``, ``lookahead`` and the three
        margins default to the values derived in the module docstring (pass a number to fix
        one; ``None`` is the same as not passing it)."""
        unknown = sorted(set(overrides) - set(cls.TUNABLE))
        if unknown:
            raise TypeError(f"unknown filter option(s) {unknown}; expected some of {cls.TUNABLE}")
        ov = {k: v for k, v in overrides.items() if v is not None}
        cam, rob = config.camera, config.robot
        s0, s1, sb = (float(cam.noise.position), float(cam.noise.position_per_m),
                      float(cam.noise.bearing))  # fmt: skip
        kappa = float(ov.get("margin_sigmas", cls.margin_sigmas))
        d_col, d_des, d_con = config.safety.d_col, config.formation.d_des, cam.range
        # The derived margins keep the law feasible however noisy the camera: each takes at
        # most half the slack the PPC law leaves its constraint (2 rho_inf < the gap, see
        # PPCParams), so at large noise the policy runs with the margin it can afford.
        rho_d = config.ppc.rho_d_inf if config.ppc is not None else 0.0
        rho_b = config.ppc.rho_beta_inf if config.ppc is not None else 0.0
        ov.setdefault(
            "d_col_margin", min(kappa * (s0 + s1 * d_col), 0.5 * (d_des - d_col - 2 * rho_d))
        )
        ov.setdefault(
            "beta_margin",
            min(kappa * (sb + (s0 + s1 * d_des) / d_des), 0.5 * (cam.half_angle - 2 * rho_b)),
        )
        ov.setdefault(
            "range_margin", min(kappa * (s0 + s1 * d_con), 0.5 * (d_con - d_des - 2 * rho_d))
        )
        ov.setdefault("clearance_tau", cls.CLEARANCE_TAU if config.proximity.noise > 0 else 0.0)
        ov.setdefault(
            "lookahead", rob.lag + cls.LOOKAHEAD_RATE_LIMITED if drive_limited(rob) else 0.0
        )
        return cls(
            dt=dt,
            latency_steps=round(cam.latency / dt),
            frame_period=0.0 if cam.frame_rate is None else 1.0 / cam.frame_rate,
            sigma_0=s0,
            sigma_1=s1,
            sigma_b=sb,
            u_max=float(rob.u_max),
            omega_max=float(rob.omega_max),
            lag_gain=lag_gain(rob.lag, dt),
            du_max=math.inf if rob.accel_max is None else float(rob.accel_max) * dt,
            dw_max=math.inf if rob.alpha_max is None else float(rob.alpha_max) * dt,
            **{k: float(v) for k, v in ov.items()},
        )

    def tightened(self, config: ScenarioConfig) -> ScenarioConfig:
        """``config`` with the inner law's constraints: ``d_col + d_col_margin``,
        ``beta_con - beta_margin``, ``d_con - range_margin``."""
        cam = config.camera
        return dc_replace(
            config,
            safety=dc_replace(config.safety, d_col=config.safety.d_col + self.d_col_margin),
            camera=dc_replace(
                cam,
                half_angle=cam.half_angle - self.beta_margin,
                range=cam.range - self.range_margin,
            ),
        )


#: The constants of :func:`_filter_step` and :func:`_dead_reckon_step`, one record built from
#: :class:`FilterParams` (SI units; names as in the module docstring).
FILTER_KERNEL_DTYPE: np.dtype[np.void] = np.dtype(
    [
        ("dt", np.float64),  # [s] control period
        ("latency_steps", np.int64),  # L
        ("frame_period", np.float64),  # [s] 1 / camera.frame_rate; 0: a frame every step
        ("q_accel", np.float64),  # [m^2/s^3] q of Q
        ("v0_var", np.float64),  # [m^2/s^2] v0_std^2, the prior velocity variance
        ("sigma_0", np.float64),  # [m] R: sigma = max(sigma_0 + sigma_1 |z|, sigma_floor)
        ("sigma_1", np.float64),  # [m/m]
        ("sigma_b2", np.float64),  # [rad^2] sigma_b^2 of R's tangential term
        ("sigma_floor", np.float64),  # [m]
        ("max_coast", np.float64),  # [s]
        ("clearance_gain", np.float64),  # 1 - exp(-dt / clearance_tau)
        ("lookahead", np.float64),  # [s] tau
        ("lookahead_predecessor", np.float64),  # the predecessor moves on for this x tau
        ("u_max", np.float64),  # [m/s] action box
        ("omega_max", np.float64),  # [rad/s]
        ("lag_gain", np.float64),  # 1 - exp(-dt / lag)
        ("du_max", np.float64),  # [m/s] accel_max dt (inf: none)
        ("dw_max", np.float64),  # [rad/s] alpha_max dt
    ],
    align=True,
)


def _kernel_params(p: FilterParams) -> NDArray[np.void]:
    """The constants of the kernels from ``p``: a ``(1,)`` :data:`FILTER_KERNEL_DTYPE` array."""
    return kernel_record(FILTER_KERNEL_DTYPE, p, v0_var=p.v0_std**2, sigma_b2=p.sigma_b**2)


#: The filter's state of N followers (L = latency steps), advanced in place by the kernels:
#:
#: * ``mean`` (N, 4) and ``cov`` (N, 4, 4): the filter's ``s`` and ``P`` at ``t_j``;
#: * ``started`` (N,) bool: had a detection (the filter is running);
#: * ``last_update`` (N,) int64: the step ``j`` of the last measurement update;
#: * ``odometry`` (L + 2, N, 3): the odometry poses, ``o_m`` in row ``m % (L + 2)``;
#: * ``applied`` (N, 2): the actuator model's applied ``[u, omega]``;
#: * ``clearances`` (N, 4): the low-passed clearances (``OBS_CLEARANCES`` order);
#: * ``updates``, ``untracked`` (N,) int64: measurement updates, and steps the law was told
#:   "not visible", since the reset.
#:
#: Like the env core's records (:mod:`platoon_env.records`), it enters compiled code as a plain
#: tuple of its arrays (which numba types faster than a named tuple) and is named there again
#: (``FilterState(*state)``).
FilterState = namedtuple(
    "FilterState",
    "mean cov started last_update odometry applied clearances updates untracked",
)


# ----------------------------------------------------------------------------------------------
# Compiled kernels: the same equations, per follower
# ----------------------------------------------------------------------------------------------

# Rows of the filter's signal buffer (FILTER_SIGNAL_NAMES order).
_F_X, _F_Y, _F_WX, _F_WY, _F_STD, _F_COAST, _F_UPDATED, _F_TRACKED = range(8)


@njit(cache=True)
def _relative(o_from: np.ndarray, o_to: np.ndarray) -> tuple[float, float, float]:
    """:func:`relative_pose` of two ``(3,)`` poses."""
    dx, dy = in_frame(o_to[0], o_to[1], o_from[0], o_from[1], o_from[2])
    return dx, dy, o_to[2] - o_from[2]


@njit(cache=True)
def _propagate(
    est: tuple[float, float, float, float], motion: tuple[float, float, float], T: float
) -> tuple[float, float, float, float]:
    """:func:`propagate_mean` of one estimate ``est = (p_x, p_y, w_x, w_y)`` over ``T`` seconds
    in which the follower moved by ``motion = (D_x, D_y, A)``: ``p^ = R(-A)(p + w T - D)``,
    ``w^ = R(-A) w``."""
    px, py, wx, wy = est
    dx, dy, a = motion
    qx, qy = in_frame(px + wx * T, py + wy * T, dx, dy, a)
    vx, vy = in_frame(wx, wy, 0.0, 0.0, a)
    return qx, qy, vx, vy


@njit(cache=True)
def _predict(s: np.ndarray, P: np.ndarray, dx: float, dy: float, a: float, dt: float, q: float):
    """:func:`kf_predict` of one state ``s`` (4,), ``P`` (4, 4), in place."""
    c, sn = math.cos(a), math.sin(a)
    F = np.zeros((4, 4))
    for r0 in (0, 2):  # R(-a) = [[c, s], [-s, c]] on the diagonal blocks
        F[r0, r0] = c
        F[r0, r0 + 1] = sn
        F[r0 + 1, r0] = -sn
        F[r0 + 1, r0 + 1] = c
    for r in range(2):
        for col in range(2):
            F[r, 2 + col] = F[r, col] * dt
    x0 = F[0, 0] * s[0] + F[0, 1] * s[1] + F[0, 2] * s[2] + F[0, 3] * s[3] - (c * dx + sn * dy)
    x1 = F[1, 0] * s[0] + F[1, 1] * s[1] + F[1, 2] * s[2] + F[1, 3] * s[3] - (-sn * dx + c * dy)
    x2 = c * s[2] + sn * s[3]
    x3 = -sn * s[2] + c * s[3]
    s[0], s[1], s[2], s[3] = x0, x1, x2, x3
    FP = F @ P
    P[:, :] = FP @ F.T
    q3, q2, q1 = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    for r in range(2):
        P[r, r] += q3
        P[r, r + 2] += q2
        P[r + 2, r] += q2
        P[r + 2, r + 2] += q1


@njit(cache=True)
def _update(s: np.ndarray, P: np.ndarray, zx: float, zy: float, R: np.ndarray):
    """:func:`kf_update` of one state, in place (``S`` inverted in closed form)."""
    s00 = P[0, 0] + R[0, 0]
    s01 = P[0, 1] + R[0, 1]
    s10 = P[1, 0] + R[1, 0]
    s11 = P[1, 1] + R[1, 1]
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    K = np.empty((4, 2))
    for r in range(4):
        K[r, 0] = P[r, 0] * i00 + P[r, 1] * i10
        K[r, 1] = P[r, 0] * i01 + P[r, 1] * i11
    nx, ny = zx - s[0], zy - s[1]
    for r in range(4):
        s[r] += K[r, 0] * nx + K[r, 1] * ny
    # P -= K S K^T, with S = [[s00, s01], [s10, s11]]; then symmetrised
    for r in range(4):
        a0 = K[r, 0] * s00 + K[r, 1] * s10
        a1 = K[r, 0] * s01 + K[r, 1] * s11
        for col in range(4):
            P[r, col] -= a0 * K[col, 0] + a1 * K[col, 1]
    for r in range(4):
        for col in range(r + 1, 4):
            m = 0.5 * (P[r, col] + P[col, r])
            P[r, col] = m
            P[col, r] = m


@njit(cache=True)
def _covariance(zx: float, zy: float, p: Any) -> np.ndarray:
    """:func:`measurement_covariance` of one point."""
    sig = max(p.sigma_0 + p.sigma_1 * math.hypot(zx, zy), p.sigma_floor)
    R = np.empty((2, 2))
    R[0, 0] = sig * sig + p.sigma_b2 * zy * zy
    R[1, 1] = sig * sig + p.sigma_b2 * zx * zx
    R[0, 1] = -p.sigma_b2 * zx * zy
    R[1, 0] = R[0, 1]
    return R


@njit(cache=True)
def _filter_step(
    obs: np.ndarray,
    idx: np.ndarray,
    k: int,
    params: np.ndarray,
    state: tuple,  # type: ignore[type-arg]
    out: np.ndarray,
    signals: np.ndarray,
) -> None:
    r"""Steps 1-4 of the module docstring for followers ``idx`` at control step ``k``.

    ``obs`` (n, 7) their observations; ``params`` (1,) :data:`FILTER_KERNEL_DTYPE` the
    constants; ``state`` the :class:`FilterState` of all N followers (as a plain tuple),
    advanced in place for ``idx``. A frame taken at ``t_j``, ``j = max(k - L, 0)``, arrives now
    when the camera took one at step ``j`` (:func:`frame_due`; step 0's frame at once). Writes
    the law's observation rows to ``out`` (n, 7) and the signals to ``signals`` (8, N).
    """
    p = params[0]
    st = FilterState(*state)
    dt = p.dt
    L = p.latency_steps
    ring = st.odometry.shape[0]
    j = max(k - L, 0)
    delivered = k == 0 or (j >= 1 and frame_due_at(j, dt, p.frame_period))
    for r in range(obs.shape[0]):
        i = idx[r]
        si = st.mean[i]
        Pi = st.cov[i]
        oj = st.odometry[j % ring, i]
        # 1a. predict t_{j-1} -> t_j with the odometry (once the delayed time is past step 0)
        if k - L >= 1:
            dx, dy, a = _relative(st.odometry[(j - 1) % ring, i], oj)
            _predict(si, Pi, dx, dy, a, dt, p.q_accel)
        # 1b. update with a delivered frame that reports the predecessor
        upd = delivered and obs[r, OBS_VISIBLE] > 0.5
        if upd:
            zx, zy = obs[r, OBS_X_REL], obs[r, OBS_Y_REL]
            R = _covariance(zx, zy, p)
            if st.started[i]:
                _update(si, Pi, zx, zy, R)
            else:  # first detection: s = [z, 0, 0], P = blockdiag(R, v0^2 I)
                si[0], si[1], si[2], si[3] = zx, zy, 0.0, 0.0
                Pi[:, :] = 0.0
                Pi[0:2, 0:2] = R
                Pi[2, 2] = p.v0_var
                Pi[3, 3] = p.v0_var
                st.started[i] = True
            st.last_update[i] = j
            st.updates[i] += 1
        # 2. the estimate at t_k (through the odometry), then tau ahead (applied velocity held)
        est = _propagate(
            (si[0], si[1], si[2], si[3]), _relative(oj, st.odometry[k % ring, i]), (k - j) * dt
        )
        if p.lookahead > 0.0:
            # Only a channel the drive delays is held ahead: an instant omega (no alpha_max,
            # no lag) would be the law's own chattering command, extrapolated.
            lagged = p.lag_gain < 1.0
            u_ahead = st.applied[i, ACT_U] if lagged or p.du_max < math.inf else 0.0
            w_ahead = st.applied[i, ACT_OMEGA] if lagged or p.dw_max < math.inf else 0.0
            est = _propagate(
                est,
                body_arc(u_ahead, w_ahead, p.lookahead),
                p.lookahead * p.lookahead_predecessor,
            )
        px, py, wx, wy = est
        coast = (k - st.last_update[i]) * dt if st.started[i] else math.inf
        tracked = st.started[i] and coast <= p.max_coast
        # 4. the clearances, low-passed (the first step starts the filter)
        clear = st.clearances[i]
        for c in range(4):
            raw = obs[r, OBS_CLEARANCES[c]]
            clear[c] = raw if k == 0 else clear[c] + (raw - clear[c]) * p.clearance_gain
        for c in range(OBS_SIZE):
            out[r, c] = obs[r, c]
        out[r, OBS_VISIBLE] = 1.0 if tracked else 0.0
        out[r, OBS_X_REL] = px if tracked else 0.0
        out[r, OBS_Y_REL] = py if tracked else 0.0
        for c in range(4):
            out[r, OBS_CLEARANCES[c]] = clear[c]
        if not tracked:
            st.untracked[i] += 1
        signals[_F_X, i] = px
        signals[_F_Y, i] = py
        signals[_F_WX, i] = wx
        signals[_F_WY, i] = wy
        signals[_F_STD, i] = math.sqrt(max(Pi[0, 0] + Pi[1, 1], 0.0))
        signals[_F_COAST, i] = coast
        signals[_F_UPDATED, i] = 1.0 if upd else 0.0
        signals[_F_TRACKED, i] = 1.0 if tracked else 0.0


@njit(cache=True)
def _dead_reckon_step(
    cmd: np.ndarray,
    idx: np.ndarray,
    k: int,
    params: np.ndarray,
    state: tuple,  # type: ignore[type-arg]
) -> None:
    """Step 1 of the module docstring after the law: the applied velocity of the commands
    ``cmd`` (n, 2) (float32, as the env receives them; clipped to the box; the env's actuator
    rule) and the odometry pose ``o_{k+1}`` of followers ``idx`` (the env's unicycle arc), in
    their :class:`FilterState` ``state``."""
    p = params[0]
    st = FilterState(*state)
    ring = st.odometry.shape[0]
    for r in range(cmd.shape[0]):
        i = idx[r]
        c_u = min(max(float(cmd[r, ACT_U]), -p.u_max), p.u_max)
        c_w = min(max(float(cmd[r, ACT_OMEGA]), -p.omega_max), p.omega_max)
        v = st.applied[i]
        v[ACT_U] = follow(v[ACT_U], c_u, p.lag_gain, p.du_max)
        v[ACT_OMEGA] = follow(v[ACT_OMEGA], c_w, p.lag_gain, p.dw_max)
        o = st.odometry[k % ring, i]
        x, y, theta = unicycle_arc(o[0], o[1], o[2], v[ACT_U], v[ACT_OMEGA], p.dt)
        nxt = st.odometry[(k + 1) % ring, i]
        nxt[0] = x
        nxt[1] = y
        nxt[2] = theta


# ----------------------------------------------------------------------------------------------
# The policy
# ----------------------------------------------------------------------------------------------


class _Scenario:
    def __init__(self, config: ScenarioConfig) -> None:
        self.config = config


class _InnerEnv:
    """The env as the inner law sees it: the same agents and control period, the scenario's
    constraints tightened (:meth:`FilterParams.tightened`), and observations in metres (the
    filter's estimates; a scale-free env's are un-scaled on the way in)."""

    def __init__(self, env: PolicyEnv, config: ScenarioConfig) -> None:
        self.possible_agents = tuple(env.possible_agents)
        self.control_period = float(env.control_period)
        self.scenario = _Scenario(dc_replace(config, observation=ObservationConfig()))


class FilteredPPCPolicy:
    r"""The paper's PPC law on filtered, latency-compensated estimates (module docstring).

    ``FilteredPPCPolicy(env, **options)``: ``options`` may hold the filter's tuning
    (:attr:`FilterParams.TUNABLE`: ``q_accel``, ``v0_std``, ``sigma_floor``, ``max_coast``,
    ``clearance_tau``, ``lookahead``, ``lookahead_predecessor``, ``margin_sigmas``,
    ``d_col_margin``, ``beta_margin``, ``range_margin``) and any override of the inner law
    (:attr:`baselines.ppc.PPCParams.PPC_KEYS`, passed to :class:`~baselines.ppc.PPCPolicy`).
    The sensor and drive model is read from ``env.scenario.config`` (camera noise, frame rate
    and latency; action box, lag and rate limits), never the ground truth. Followers are
    indexed by ``env.possible_agents``.

    Each :meth:`act` call, for the given followers at once (two compiled loops and the law's):

    1. :func:`_filter_step`: predict the filter from ``t_{j-1}`` to ``t_j`` (``j = max(k - L,
       0)``), update it if a frame taken at ``t_j`` with a detection arrives now, move its mean
       to ``t_k + tau``, low-pass the clearances;
    2. the inner law (:class:`PPCPolicy`, tightened constraints) on
       ``[tracked, x^, y^, c^_W_l, c^_W_r, c^_l, c^_r]``;
    3. :func:`_dead_reckon_step`: the applied velocity and odometry pose after its commands
       (the env's actuator rule and unicycle arc).

    :attr:`ppc` is the inner law (its :attr:`~PPCPolicy.signals` and counters are computed on
    the estimate); :attr:`signals` holds its signals and :data:`FILTER_SIGNAL_NAMES`;
    :attr:`funnel_exits` is the inner law's; :attr:`updates` counts measurement updates and
    :attr:`untracked_steps` the steps the law was told "not visible", per follower.
    """

    def __init__(self, env: PolicyEnv, *, dt: float | None = None, **options: float) -> None:
        period = float(env.control_period) if dt is None else float(dt)
        filter_opts = {k: v for k, v in options.items() if k in FilterParams.TUNABLE}
        ppc_opts = {k: v for k, v in options.items() if k not in FilterParams.TUNABLE}
        config = env.scenario.config
        self.params: FilterParams = FilterParams.from_config(config, period, **filter_opts)
        try:
            self.ppc: PPCPolicy = PPCPolicy(
                _InnerEnv(env, self.params.tightened(config)), dt=period, **ppc_opts
            )
        except ValueError as err:
            raise ValueError(
                f"the tightened constraints are infeasible for the PPC law ({err}); lower "
                "margin_sigmas or set d_col_margin, beta_margin, range_margin"
            ) from None
        self._followers = Followers(env.possible_agents, env.scenario.config)
        self.agents: tuple[str, ...] = self._followers.agents
        self._kernel: NDArray[np.void] = _kernel_params(self.params)
        n = len(self.agents)
        counter = np.zeros(n, dtype=np.int64)
        self._state = FilterState(
            mean=np.zeros((n, 4)),
            cov=np.zeros((n, 4, 4)),
            started=np.zeros(n, dtype=np.bool_),
            last_update=np.zeros(n, dtype=np.int64),
            odometry=np.zeros((self.params.latency_steps + 2, n, 3)),  # o_{k-L-1} .. o_k
            applied=np.zeros((n, 2)),
            clearances=np.zeros((n, 4)),
            updates=counter,
            untracked=counter.copy(),
        )
        # what the kernels take: the same arrays as a plain tuple (numba types it faster)
        self._state_arrays: tuple[NDArray[Any], ...] = tuple(self._state)
        self._fsig = np.zeros((len(FILTER_SIGNAL_NAMES), n))
        self.updates: NDArray[np.int64] = self._state.updates
        self.untracked_steps: NDArray[np.int64] = self._state.untracked
        self.steps: int = 0
        self.reset()

    # -- Policy interface -----------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> None:
        """Forget the filter, odometry and clearance states, reset the inner law (the eq. 12
        initial funnels) and the counters. Deterministic; ``seed`` is accepted for the
        interface."""
        self.ppc.reset(seed)
        for a in (*self._state, self._fsig):
            a[...] = 0
        self._fsig[_F_COAST] = math.inf
        self.steps = 0

    def act(self, observations: Mapping[str, ArrayLike]) -> dict[str, NDArray[np.float32]]:
        """Commands ``{agent: float32 [u, omega]}`` for every agent in ``observations``.

        Agents of ``env.possible_agents`` absent from ``observations`` keep their state. The
        policy counts its calls since :meth:`reset` as the control step ``k``: call it once per
        env step. Non-finite observation entries are read as 0.
        """
        keys, obs, found = self._followers.read(observations)
        idx = self._followers.all if found is None else found
        if not np.all(np.isfinite(obs)):
            obs = np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
        k = self.steps
        filtered = np.empty_like(obs)
        _filter_step(obs, idx, k, self._kernel, self._state_arrays, filtered, self._fsig)
        actions = self.ppc.act(dict(zip(keys, filtered, strict=False)))
        cmd = np.array(list(actions.values()), dtype=np.float32).reshape(len(keys), 2)
        _dead_reckon_step(cmd, idx, k, self._kernel, self._state_arrays)
        self.steps += 1
        return actions

    # -- diagnostics ----------------------------------------------------------------------------

    @property
    def funnel_exits(self) -> NDArray[np.int64]:
        """Steps with an error of the estimate outside its funnel, per follower (inner law)."""
        return self.ppc.funnel_exits

    @property
    def applied(self) -> FloatArray:
        """The actuator model's applied ``[u, omega]`` after the last command, (N, 2) (a copy)."""
        return self._state.applied.copy()

    @property
    def signals(self) -> dict[str, NDArray[Any]]:
        """The inner law's signals (:attr:`PPCPolicy.signals`, on the estimate) and the
        filter's (:data:`FILTER_SIGNAL_NAMES`, flags as booleans), arrays of shape (N,)."""
        out = self.ppc.signals
        for row, name in enumerate(FILTER_SIGNAL_NAMES):
            value = self._fsig[row]
            out[name] = value != 0.0 if name in _FLAG_SIGNALS else value.copy()
        return out
