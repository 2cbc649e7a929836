r"""The paper's decentralised Prescribed Performance Control law (section 3, eqs. 7 and 10-14).

Equation numbers refer to the paper "Coordination of Multiple Robotic Vehicles in
Obstacle-Cluttered Environments". For follower ``i`` (index ``i`` dropped below) the law is

* errors (eq. 7): ``e_d = d - d_des``, ``e_beta = beta``, with ``d = |p~|`` (eq. 2) and
  ``beta`` the angle of view (eq. 3), read from the camera's body-frame measurement
  ``(x~, y~) = (d cos beta, d sin beta)``;
* performance functions ``rho_d_lo < e_d < rho_d_hi``, ``rho_beta_lo < e_beta < rho_beta_hi``
  (eq. 10), adapted online by the update laws (eq. 12a-d) driven by the activation terms
  ``F_l, F_r``, each law passed through the projection operator ``Proj`` over its own set;
* transformed errors ``eps = ln((e - rho_lo) / (rho_hi - e))``;
* commands: ``u`` (eq. 13) and ``omega`` (eq. 14).

:class:`PPCPolicy` runs it for all followers at once, in one compiled (numba) loop over the
followers (:func:`_ppc_step`), in discrete time with the env's control period. The pure
functions below (:func:`S`, :func:`F`, :func:`projection`, :func:`rho_dot`,
:func:`transformed_error`, :func:`compensation`, :func:`linear_velocity`,
:func:`angular_velocity`) are the same equations on scalars or arrays, for unit tests and for
readers; :func:`_ppc_step` implements exactly them, with the same floors and clamps.

Where this implementation has to decide something the paper leaves open, or departs from the
printed equations, it says so here and next to the code:

1. **Compensation term of eqs. 13-14.** Differentiating ``eps = ln((e - lo)/(hi - e))`` gives
   ``eps_dot = J (e_dot - C)`` with ``J = (hi - lo) / ((e - lo)(hi - e)) > 0`` and
   ``C = (lo_dot (hi - e) + hi_dot (e - lo)) / (hi - lo)``. Eqs. 13 and 14 as printed swap
   the weights (``hi_dot (hi - e) + lo_dot (e - lo)``); the paper's own proof of Theorem 1
   (the expression for ``V_dot``) uses the derivation's ``C``, which is what cancels the
   performance functions' motion. :func:`compensation` implements the derivation's ``C``.
2. **Clearance floor.** ``F = S(m; delta) / m`` (after eq. 12) is unbounded as the margin
   ``m = min(d_sight - r, d_wall - r)`` closes and undefined for ``m <= 0`` (which happens in
   practice: the line of sight may pass within ``r`` of a corner without being occluded). The
   margin is floored at :data:`CLEARANCE_FLOOR` = 1 mm, so ``F <= 1/CLEARANCE_FLOOR - 1/delta``
   (about 998 for ``delta = 0.5``); every floored step is recorded.
3. **Discrete time.** The performance functions are advanced by explicit Euler with the control
   period ``dt``, and after each step each ``rho`` is clipped to its projection set. The
   continuous-time projection keeps ``rho`` in its set by itself; a finite step can overshoot,
   and the clip is the one discretisation safeguard.
4. **Funnel exits.** Held for a control period, the continuous law can push an error out of its
   funnel, where ``eps`` is undefined. The ratio ``(e - lo)/(hi - e)`` is then clamped so that
   ``|eps| <= EPS_MAX`` (= 10, i.e. the ratio lies in ``[e^-10, e^10]``), which is also the
   bound inside the funnel (reached only within ``4.5e-5`` of the funnel's width from a
   bound). Commands stay finite (they push the error back, with the saturated ``eps``); each
   such step is flagged and counted.
5. **Predecessor not visible.** The law needs ``d`` and ``beta``; when the camera reports
   nothing (``visible = 0``) the follower is commanded ``u = 0, omega = 0`` (it stops), its
   errors and transformed errors are reported as 0, and the step is counted. The performance
   functions keep following eq. 12, which uses only the proximity sensor.
6. **Degenerate observations** (never produced by the env while the predecessor is visible):
   ``d`` is floored at :data:`DISTANCE_FLOOR` and ``cos(beta)`` at :data:`COS_FLOOR` in the
   divisions of eqs. 13-14.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from baselines.policy import Followers, PolicyEnv, as_float, kernel_record
from platoon_env.observation import (
    OBS_D_SIGHT_LEFT,
    OBS_D_SIGHT_RIGHT,
    OBS_D_WALL_LEFT,
    OBS_D_WALL_RIGHT,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
)
from platoon_env.scenarios.schema import ScenarioConfig

__all__ = [
    "CLEARANCE_FLOOR",
    "COS_FLOOR",
    "DISTANCE_FLOOR",
    "EPS_MAX",
    "PPC_KERNEL_DTYPE",
    "PPC_SET_DTYPE",
    "RHO_NAMES",
    "SIGNAL_NAMES",
    "F",
    "PPCParams",
    "PPCPolicy",
    "S",
    "angular_velocity",
    "clearance_margin",
    "compensation",
    "initial_rho",
    "linear_velocity",
    "outside_funnel",
    "performance_sets",
    "projection",
    "rho_dot",
    "transformed_error",
]

FloatArray = NDArray[np.float64]

#: [m] floor on the clearance margin ``m`` in ``F = S(m; delta)/m`` (choice 2 above).
CLEARANCE_FLOOR: float = 1e-3
#: bound on ``|eps|``, the transformed errors (choice 4 above).
EPS_MAX: float = 10.0
#: [m] floor on ``d`` where eq. 14 divides by it (choice 6 above).
DISTANCE_FLOOR: float = 1e-6
#: floor on ``cos(beta)`` where eq. 13 divides by it (choice 6 above).
COS_FLOOR: float = 1e-3
#: floor on funnel widths ``hi - lo`` where :func:`compensation` divides by them.
_WIDTH_FLOOR: float = 1e-12
#: floor on ``e - lo`` and ``hi - e`` before their ratio is taken (then ``eps`` is clipped).
_TINY: float = 1e-200

#: The four performance functions, in the order used by :func:`initial_rho`,
#: :func:`performance_sets` and :func:`rho_dot`.
RHO_NAMES: tuple[str, str, str, str] = ("rho_d_lo", "rho_d_hi", "rho_beta_lo", "rho_beta_hi")

#: Keys of :attr:`PPCPolicy.signals`.
SIGNAL_NAMES: tuple[str, ...] = (
    *RHO_NAMES,
    *(f"{n}_dot" for n in RHO_NAMES),
    "d",
    "beta",
    "e_d",
    "e_beta",
    "eps_d",
    "eps_beta",
    "F_l",
    "F_r",
    "C_d",
    "C_beta",
    "u",
    "omega",
    "visible",
    "funnel_exit",
    "clearance_floored",
)


# ----------------------------------------------------------------------------------------------
# Pure functions: the paper's equations, elementwise on scalars or arrays.
# ----------------------------------------------------------------------------------------------


def S(x: ArrayLike, delta: float) -> FloatArray:
    r"""Activation function after eq. 12: ``S(x; delta) = 1 - x/delta`` on ``[0, delta)``, 0 on
    ``[delta, inf)``.

    For ``x < 0`` (outside the paper's domain) the linear branch is continued.
    """
    return np.maximum(1.0 - as_float(x) / delta, 0.0)


def clearance_margin(d_sight: ArrayLike, d_wall: ArrayLike, r: float) -> FloatArray:
    r"""The argument of ``S`` in ``F_l`` (``F_r``): ``m = min(d_l - r, d_W_l - r)`` (after eq. 12).

    ``d_sight`` is ``d_l`` (``d_r``), the clearance of the line of sight ``L_i``; ``d_wall`` is
    ``d_W_l`` (``d_W_r``), the clearance of the robot; ``r`` the robot radius.
    """
    return np.minimum(as_float(d_sight), as_float(d_wall)) - r


def F(m: ArrayLike, delta: float, floor: float = CLEARANCE_FLOOR) -> FloatArray:
    r"""Activation term after eq. 12: ``F = S(m; delta) / m`` with ``m`` from
    :func:`clearance_margin`.

    ``m`` is floored at ``floor`` (> 0) first, so ``F`` is finite: ``0 <= F <= 1/floor - 1/delta``
    (choice 2 in the module docstring). ``F = 0`` for ``m >= delta``.
    """
    mm = np.maximum(as_float(m), floor)
    return S(mm, delta) / mm


def initial_rho(d_des: float, d_col: float, d_con: float, beta_con: float) -> FloatArray:
    r"""Initial performance functions (eq. 12): ``rho_d_lo(0) = -(d_des - d_col)``,
    ``rho_d_hi(0) = d_con - d_des``, ``rho_beta_lo(0) = -beta_con``, ``rho_beta_hi(0) = beta_con``.

    Returned in the order of :data:`RHO_NAMES`.
    """
    return np.array([-(d_des - d_col), d_con - d_des, -beta_con, beta_con], dtype=np.float64)


def performance_sets(
    d_des: float,
    d_col: float,
    d_con: float,
    beta_con: float,
    rho_d_inf: float,
    rho_beta_inf: float,
) -> tuple[FloatArray, FloatArray]:
    r"""The projection sets of the four update laws (the four intervals listed after eq. 12).

    ``rho_d_lo in [-(d_des - d_col), d_con - d_des - 2 rho_d_inf]``,
    ``rho_d_hi in [-(d_des - d_col) + 2 rho_d_inf, d_con - d_des]``,
    ``rho_beta_lo in [-beta_con, beta_con - 2 rho_beta_inf]``,
    ``rho_beta_hi in [-beta_con + 2 rho_beta_inf, beta_con]``.
    Returns ``(rho_min, rho_max)``, each in the order of :data:`RHO_NAMES`.
    """
    rho_min = np.array(
        [
            -(d_des - d_col),
            -(d_des - d_col) + 2 * rho_d_inf,
            -beta_con,
            -beta_con + 2 * rho_beta_inf,
        ]
    )
    rho_max = np.array(
        [d_con - d_des - 2 * rho_d_inf, d_con - d_des, beta_con - 2 * rho_beta_inf, beta_con]
    )
    return rho_min, rho_max


def rho_dot(
    rho: ArrayLike,
    F_l: ArrayLike,
    F_r: ArrayLike,
    lambda_: float,
    rho_d_inf: float,
    rho_beta_inf: float,
) -> FloatArray:
    r"""Unprojected update laws (eq. 12a-d).

    ``rho`` has the four performance functions on its first axis (order of :data:`RHO_NAMES`)::

        rho_d_lo_dot    = -lambda (rho_d_lo    + rho_d_inf)    - F_r - F_l    (12a)
        rho_d_hi_dot    = -lambda (rho_d_hi    - rho_d_inf)    - F_r - F_l    (12b)
        rho_beta_lo_dot = -lambda (rho_beta_lo + rho_beta_inf) - F_r + F_l    (12c)
        rho_beta_hi_dot = -lambda (rho_beta_hi - rho_beta_inf) - F_r + F_l    (12d)
    """
    p, fl, fr = as_float(rho), as_float(F_l), as_float(F_r)
    return np.stack(
        [
            -lambda_ * (p[0] + rho_d_inf) - fr - fl,  # (12a)
            -lambda_ * (p[1] - rho_d_inf) - fr - fl,  # (12b)
            -lambda_ * (p[2] + rho_beta_inf) - fr + fl,  # (12c)
            -lambda_ * (p[3] - rho_beta_inf) - fr + fl,  # (12d)
        ]
    )


def projection(
    rho_dot: ArrayLike,
    rho: ArrayLike,
    rho_min: ArrayLike,
    rho_max: ArrayLike,
    epsilon: float,
) -> FloatArray:
    r"""Lipschitz projection operator over ``[rho_min, rho_max]`` (after eq. 12, ref. [43])::

        Proj(rho_dot; rho) = rho_dot (1 - f(rho))  if f(rho) > 0 and rho_dot f'(rho) > 0
                           = rho_dot               otherwise,
        f(rho) = (((2 rho - (rho_max + rho_min)) / (rho_max - rho_min))^2 - epsilon^2)
                 / (1 - epsilon^2),

    with ``0 < epsilon < 1``. ``f <= 0`` where the normalised position
    ``x = (2 rho - (rho_max + rho_min))/(rho_max - rho_min)`` has ``|x| <= epsilon`` (there the
    operator is the identity), ``f = 1`` on the bounds (an outward rate is cancelled), and
    ``f'(rho) = 4 x / ((1 - epsilon^2)(rho_max - rho_min))`` has the sign of ``x``.
    """
    rd, lo, hi = as_float(rho_dot), as_float(rho_min), as_float(rho_max)
    x = (2.0 * as_float(rho) - (hi + lo)) / (hi - lo)
    f = (x * x - epsilon * epsilon) / (1.0 - epsilon * epsilon)
    return np.where((f > 0.0) & (rd * x > 0.0), rd * (1.0 - f), rd)


def outside_funnel(e: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.bool_]:
    """True where the error has left its funnel: not ``lo < e < hi`` (eq. 10)."""
    ee = as_float(e)
    return ~((ee > as_float(lo)) & (ee < as_float(hi)))


def transformed_error(
    e: ArrayLike, lo: ArrayLike, hi: ArrayLike, eps_max: float = EPS_MAX
) -> FloatArray:
    r"""Transformed error (section 3, before eq. 13): ``eps = ln((e - lo) / (hi - e))``.

    Finite everywhere: the ratio is clamped to ``[exp(-eps_max), exp(eps_max)]`` so that
    ``|eps| <= eps_max``; outside the funnel (``e <= lo`` or ``e >= hi``) ``eps = -eps_max`` or
    ``+eps_max`` (choice 4 in the module docstring).
    """
    ee = as_float(e)
    num = np.maximum(ee - as_float(lo), _TINY)
    den = np.maximum(as_float(hi) - ee, _TINY)
    return np.clip(np.log(num / den), -eps_max, eps_max)


def compensation(
    e: ArrayLike, lo: ArrayLike, hi: ArrayLike, lo_dot: ArrayLike, hi_dot: ArrayLike
) -> FloatArray:
    r"""Compensation of the funnel's motion in eqs. 13-14:
    ``C = (lo_dot (hi - e) + hi_dot (e - lo)) / (hi - lo)``.

    This is the term for which ``eps_dot = J (e_dot - C)``, ``J = (hi - lo)/((e - lo)(hi - e))``,
    holds (differentiate ``eps = ln((e - lo)/(hi - e))``), and the one in the paper's ``V_dot``
    (proof of Theorem 1). Eqs. 13 and 14 as printed swap the weights,
    ``(hi_dot (hi - e) + lo_dot (e - lo)) / (hi - lo)``; with that term ``eps`` would not be
    compensated (choice 1 in the module docstring).
    """
    ee, lo_a, hi_a = as_float(e), as_float(lo), as_float(hi)
    width = np.maximum(hi_a - lo_a, _WIDTH_FLOOR)
    return (as_float(lo_dot) * (hi_a - ee) + as_float(hi_dot) * (ee - lo_a)) / width


def linear_velocity(eps_d: ArrayLike, beta: ArrayLike, C_d: ArrayLike, k_d: float) -> FloatArray:
    r"""Linear velocity command (eq. 13): ``u = (k_d eps_d - C_d) / cos(beta)``.

    ``C_d`` from :func:`compensation` with the distance funnel. ``cos(beta)`` is floored at
    :data:`COS_FLOOR` (only reachable with ``|beta| >= beta_con``, never while visible).
    """
    cos_b = np.maximum(np.cos(as_float(beta)), COS_FLOOR)
    return (k_d * as_float(eps_d) - as_float(C_d)) / cos_b


def angular_velocity(
    u: ArrayLike,
    d: ArrayLike,
    beta: ArrayLike,
    eps_beta: ArrayLike,
    C_beta: ArrayLike,
    k_beta: float,
) -> FloatArray:
    r"""Angular velocity command (eq. 14): ``omega = (u/d) sin(beta) + k_beta eps_beta - C_beta``.

    ``C_beta`` from :func:`compensation` with the angle-of-view funnel; ``d`` floored at
    :data:`DISTANCE_FLOOR`.
    """
    dd = np.maximum(as_float(d), DISTANCE_FLOOR)
    sin_b = np.sin(as_float(beta))
    return as_float(u) / dd * sin_b + k_beta * as_float(eps_beta) - as_float(C_beta)


# ----------------------------------------------------------------------------------------------
# Parameters
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PPCParams:
    """Everything the PPC law of one follower needs (paper symbols; SI units).

    Geometry and limits come from the scenario (``robot.radius``, ``formation.d_des``,
    ``safety.d_col``, ``camera.range``, ``camera.half_angle``), gains from its ``ppc`` block,
    ``dt`` from the env's control period.
    """

    r: float  # [m] robot radius
    d_des: float  # [m] desired distance
    d_col: float  # [m] collision distance
    d_con: float  # [m] camera range
    beta_con: float  # [rad] camera half angle
    lambda_: float  # [1/s] convergence rate of eq. 12
    rho_d_inf: float  # [m]
    rho_beta_inf: float  # [rad]
    k_d: float  # gain of eq. 13
    k_beta: float  # gain of eq. 14
    delta: float  # [m] activation distance of S
    epsilon: float  # projection parameter, in (0, 1)
    dt: float  # [s] control period (Euler step of eq. 12)
    clearance_floor: float = CLEARANCE_FLOOR  # [m] choice 2
    eps_max: float = EPS_MAX  # choice 4

    #: names that may be overridden in :meth:`from_config` / :class:`PPCPolicy`.
    PPC_KEYS: ClassVar[tuple[str, ...]] = (
        "lambda_",
        "rho_d_inf",
        "rho_beta_inf",
        "k_d",
        "k_beta",
        "delta",
        "epsilon",
        "clearance_floor",
        "eps_max",
        "dt",
    )

    def __post_init__(self) -> None:
        for name in (
            "r", "d_col", "d_con", "beta_con", "lambda_", "rho_d_inf", "rho_beta_inf",
            "k_d", "k_beta", "delta", "dt", "clearance_floor", "eps_max",
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"PPC parameter {name} must be finite and > 0, got {value!r}")
        if not 0.0 < self.epsilon < 1.0:
            raise ValueError(f"PPC parameter epsilon must lie in (0, 1), got {self.epsilon!r}")
        if not self.d_col < self.d_des < self.d_con:
            raise ValueError(
                f"need d_col < d_des < d_con, got {self.d_col}, {self.d_des}, {self.d_con}"
            )
        if not self.beta_con < math.pi / 2:
            raise ValueError(f"need beta_con < pi/2, got {self.beta_con}")
        if not 2 * self.rho_d_inf < min(self.d_des - self.d_col, self.d_con - self.d_des):
            raise ValueError("2 rho_d_inf must be smaller than d_des - d_col and d_con - d_des")
        if not 2 * self.rho_beta_inf < self.beta_con:
            raise ValueError("2 rho_beta_inf must be smaller than beta_con")

    @classmethod
    def from_config(cls, config: ScenarioConfig, dt: float, **overrides: float) -> PPCParams:
        """Build the parameters from a scenario's config and a control period.

        ``overrides`` may replace any of :attr:`PPC_KEYS` (``lambda`` is accepted for
        ``lambda_``). Raises :class:`ValueError` if the scenario has no ``ppc`` block and the
        gains are not all given as overrides.
        """
        ov = dict(overrides)
        if "lambda" in ov:
            ov["lambda_"] = ov.pop("lambda")
        unknown = sorted(set(ov) - set(cls.PPC_KEYS))
        if unknown:
            raise TypeError(f"unknown PPC override(s) {unknown}; expected some of {cls.PPC_KEYS}")
        gains: dict[str, float] = {}
        if config.ppc is not None:
            gains = {k: float(getattr(config.ppc, k)) for k in cls.PPC_KEYS[:7]}
        gains.update({k: float(v) for k, v in ov.items()})
        missing = [k for k in cls.PPC_KEYS[:7] if k not in gains]
        if missing:
            raise ValueError(
                f"scenario {config.name!r} has no ppc block (the PPC law's parameters: lambda, "
                "rho_d_inf, rho_beta_inf, k_d, k_beta, delta, epsilon); add one to the scenario "
                f"or pass them as overrides (missing: {', '.join(missing)})"
            )
        gains.setdefault("dt", float(dt))
        return cls(
            r=float(config.robot.radius),
            d_des=float(config.formation.d_des),
            d_col=float(config.safety.d_col),
            d_con=float(config.camera.range),
            beta_con=float(config.camera.half_angle),
            **gains,
        )

    def initial_rho(self) -> FloatArray:
        """Eq. 12 initial values, order of :data:`RHO_NAMES`."""
        return initial_rho(self.d_des, self.d_col, self.d_con, self.beta_con)

    def sets(self) -> tuple[FloatArray, FloatArray]:
        """Projection sets ``(rho_min, rho_max)``, order of :data:`RHO_NAMES`."""
        return performance_sets(
            self.d_des, self.d_col, self.d_con, self.beta_con, self.rho_d_inf, self.rho_beta_inf
        )


# ----------------------------------------------------------------------------------------------
# The policy
# ----------------------------------------------------------------------------------------------


# Rows of the signal buffer (``SIGNAL_NAMES`` order): 4 rho, 4 rho_dot, then the scalars.
_S_RHO = 0
_S_RHO_DOT = 4
_S_D = SIGNAL_NAMES.index("d")
_S_BETA = SIGNAL_NAMES.index("beta")
_S_E_D = SIGNAL_NAMES.index("e_d")
_S_E_BETA = SIGNAL_NAMES.index("e_beta")
_S_EPS_D = SIGNAL_NAMES.index("eps_d")
_S_EPS_BETA = SIGNAL_NAMES.index("eps_beta")
_S_F_L = SIGNAL_NAMES.index("F_l")
_S_F_R = SIGNAL_NAMES.index("F_r")
_S_C_D = SIGNAL_NAMES.index("C_d")
_S_C_BETA = SIGNAL_NAMES.index("C_beta")
_S_U = SIGNAL_NAMES.index("u")
_S_OMEGA = SIGNAL_NAMES.index("omega")
_S_VISIBLE = SIGNAL_NAMES.index("visible")
_S_FUNNEL_EXIT = SIGNAL_NAMES.index("funnel_exit")
_S_FLOORED = SIGNAL_NAMES.index("clearance_floored")
#: the boolean signals, stored as 0.0 / 1.0 in the buffer (they are the last three rows).
_FLAG_ROWS = (_S_VISIBLE, _S_FUNNEL_EXIT, _S_FLOORED)
assert _FLAG_ROWS == (len(SIGNAL_NAMES) - 3, len(SIGNAL_NAMES) - 2, len(SIGNAL_NAMES) - 1)

#: The scalar parameters of :func:`_ppc_step`, one record built from :class:`PPCParams`
#: (field names follow the paper's symbols; SI units).
PPC_KERNEL_DTYPE: np.dtype[np.void] = np.dtype(
    [
        # [m] robot radius r; after eq. 12: clearance margin m = min(d_l - r, d_W_l - r)
        ("r", np.float64),
        # [m] desired distance d_des; eq. 7: e_d = d - d_des
        ("d_des", np.float64),
        # [m] floor on the margin m in F = S(m; delta)/m, after eq. 12 (choice 2)
        ("clearance_floor", np.float64),
        # [m] activation distance delta of S(x; delta) = max(1 - x/delta, 0), after eq. 12
        ("delta", np.float64),
        # [1/s] convergence rate lambda of the update laws, eq. 12a-d
        ("lambda_", np.float64),
        # [-] bound on |eps_d|, |eps_beta|, the transformed errors before eq. 13 (choice 4)
        ("eps_max", np.float64),
        # [m/s] gain k_d of eq. 13: u = (k_d eps_d - C_d)/cos(beta)
        ("k_d", np.float64),
        # [rad/s] gain k_beta of eq. 14: omega = (u/d) sin(beta) + k_beta eps_beta - C_beta
        ("k_beta", np.float64),
        # [s] explicit Euler step of eq. 12, the env's control period (choice 3)
        ("dt", np.float64),
        # [-] 1/(1 - epsilon^2), epsilon of Proj (after eq. 12): f(rho) = f_scale x^2 - f_offset
        ("f_scale", np.float64),
        # [-] epsilon^2/(1 - epsilon^2), the offset of Proj's f(rho) (after eq. 12)
        ("f_offset", np.float64),
    ],
    align=True,
)

#: The constants of each performance function's update law and projection set, one record per
#: function in :data:`RHO_NAMES` order, built from :class:`PPCParams`; units of that ``rho``
#: ([m] for ``rho_d_*``, [rad] for ``rho_beta_*``; ``[.]/s`` for ``lam_target``).
PPC_SET_DTYPE: np.dtype[np.void] = np.dtype(
    [
        # [.]/s lambda (-+rho_inf): eq. 12a-d read rho_dot = lam_target - lambda rho + G, with
        # -rho_d_inf (12a), +rho_d_inf (12b), -rho_beta_inf (12c), +rho_beta_inf (12d)
        ("lam_target", np.float64),
        # [1/.] 2/(rho_max - rho_min): Proj's normalised position x = rho inv_half - mid_inv_half
        ("inv_half", np.float64),
        # [-] (rho_max + rho_min)/(rho_max - rho_min), the other term of x (after eq. 12)
        ("mid_inv_half", np.float64),
        # [.] the projection set [rho_min, rho_max] listed after eq. 12
        ("rho_min", np.float64),
        ("rho_max", np.float64),
    ],
    align=True,
)

# Rows of the per-follower counters.
_C_FUNNEL_EXITS = 0
_C_INVISIBLE = 1
_C_FLOORED = 2


def _kernel_params(p: PPCParams) -> NDArray[np.void]:
    """The scalar parameters of :func:`_ppc_step` from ``p``: a ``(1,)`` array of
    :data:`PPC_KERNEL_DTYPE` (the kernel reads its record ``[0]`` by field name)."""
    # f(rho) = (x^2 - epsilon^2)/(1 - epsilon^2) = f_scale x^2 - f_offset
    return kernel_record(
        PPC_KERNEL_DTYPE,
        p,
        f_scale=1.0 / (1.0 - p.epsilon**2),
        f_offset=p.epsilon**2 / (1.0 - p.epsilon**2),
    )


def _kernel_sets(p: PPCParams) -> NDArray[np.void]:
    """The per-function constants of :func:`_ppc_step` from ``p``: a ``(4,)`` array of
    :data:`PPC_SET_DTYPE`, one record per performance function (:data:`RHO_NAMES` order)."""
    rho_min, rho_max = p.sets()
    rho_inf = np.array([-p.rho_d_inf, p.rho_d_inf, -p.rho_beta_inf, p.rho_beta_inf])
    out = np.zeros(4, dtype=PPC_SET_DTYPE)
    out["lam_target"] = p.lambda_ * rho_inf
    out["inv_half"] = 2.0 / (rho_max - rho_min)
    out["mid_inv_half"] = (rho_max + rho_min) / (rho_max - rho_min)
    out["rho_min"] = rho_min
    out["rho_max"] = rho_max
    return out


@njit(cache=True)
def _ppc_step(
    obs: np.ndarray,
    idx: np.ndarray,
    params: np.ndarray,
    sets: np.ndarray,
    rho: np.ndarray,
    sig: np.ndarray,
    counts: np.ndarray,
) -> np.ndarray:
    r"""One control step of the PPC law (eqs. 7, 10-14) for the followers ``idx`` (compiled).

    ``obs`` (n, 7) float64 holds the observations of followers ``idx`` (n,), row by row.
    ``params`` (1,) :data:`PPC_KERNEL_DTYPE` and ``sets`` (4,) :data:`PPC_SET_DTYPE` are the
    constants, read by field name (``p = params[0]``, ``p.delta``, ``sets[j].rho_max``). The
    record is taken here, not passed: numba's dispatcher types and unboxes a ``numpy.void``
    record about 1 µs slower than a structured array (which costs ~0.15 µs more than a float
    array).
    ``rho`` (4, N) (order of :data:`RHO_NAMES`) is advanced in place for those followers; their
    columns of ``sig`` (len(SIGNAL_NAMES), N) receive the signals at time ``t`` (flags as
    0.0/1.0) and ``counts`` (3, N) their counters ([funnel exits, invisible steps, clearance
    floor hits]). Returns the (n, 2) float32 commands ``[u, omega]``.

    The same equations as the pure functions, with the same floors and clamps, per follower:

    * eqs. 2-3, 7: ``d = |p~|`` (floored at :data:`DISTANCE_FLOOR`, choice 6),
      ``beta = atan2(y~, x~)``; ``e_d = d - d_des``, ``e_beta = beta`` (0 when not visible,
      choice 5);
    * after eq. 12 (:func:`clearance_margin`, :func:`F`): ``m = min(d_l, d_W_l) - r`` (and right),
      floored at the clearance floor (choice 2), ``F = S(m; delta)/m = max(1/m - 1/delta, 0)``;
    * eq. 12a-d (:func:`rho_dot`): ``rho_dot = -lambda (rho -+ rho_inf) + G`` with
      ``G_d = -F_r - F_l`` (12a, 12b), ``G_beta = -F_r + F_l`` (12c, 12d), then
      :func:`projection`: ``x = (2 rho - (max + min))/(max - min)``,
      ``f = (x^2 - epsilon^2)/(1 - epsilon^2)``,
      ``Proj = rho_dot (1 - f)`` if ``f > 0`` and ``rho_dot x > 0``, else ``rho_dot``;
    * eq. 10 (:func:`outside_funnel`): exit unless ``lo < e < hi`` (flagged only if visible);
      :func:`transformed_error`: ``eps = ln((e - lo)/(hi - e))`` with ``e - lo``, ``hi - e``
      floored at ``_TINY`` and ``|eps| <= eps_max`` (choice 4);
      :func:`compensation`: ``C = (lo_dot (hi - e) + hi_dot (e - lo)) / (hi - lo)`` (the
      derivation's ``C``, choice 1; ``hi - lo`` floored at ``_WIDTH_FLOOR``);
    * eq. 13 (:func:`linear_velocity`): ``u = (k_d eps_d - C_d)/cos(beta)``,
      ``cos(beta) = x~/d`` floored at :data:`COS_FLOOR` (choice 6);
      eq. 14 (:func:`angular_velocity`): ``omega = (u/d) sin(beta) + k_beta eps_beta - C_beta``
      with ``sin(beta) = y~/d``; ``u = omega = 0`` without a visible predecessor (choice 5);
    * explicit Euler step ``rho += dt Proj(rho_dot)``, clipped to the set (choice 3).
    """
    n = obs.shape[0]
    cmd = np.empty((n, 2), dtype=np.float32)
    p = params[0]
    r = p.r  # after eq. 12
    d_des = p.d_des  # eq. 7
    floor = p.clearance_floor  # choice 2
    inv_delta = 1.0 / p.delta  # 1/delta of S, after eq. 12
    lam = p.lambda_  # eq. 12a-d
    eps_max = p.eps_max  # choice 4
    k_d = p.k_d  # eq. 13
    k_beta = p.k_beta  # eq. 14
    dt = p.dt  # choice 3
    f_scale = p.f_scale  # Proj's f(rho) = f_scale x^2 - f_offset, after eq. 12
    f_offset = p.f_offset
    pd = np.empty(4)
    for k in range(n):
        i = idx[k]
        visible = obs[k, OBS_VISIBLE] > 0.5
        v = 1.0 if visible else 0.0

        # eqs. 2-3 and 7: d = |p~| (floored, choice 6), beta = atan2(y~, x~); e = (d - d_des, beta),
        # reported as 0 without a visible predecessor (choice 5)
        x = obs[k, OBS_X_REL]
        y = obs[k, OBS_Y_REL]
        d = max(math.hypot(x, y), DISTANCE_FLOOR)
        e_d = (d - d_des) * v
        e_b = math.atan2(y, x) * v

        # after eq. 12: m = min(d_sight - r, d_wall - r) for left and right, floored (choice 2);
        # F = S(m; delta)/m = max(1/m - 1/delta, 0)
        m_l = min(obs[k, OBS_D_SIGHT_LEFT], obs[k, OBS_D_WALL_LEFT]) - r
        m_r = min(obs[k, OBS_D_SIGHT_RIGHT], obs[k, OBS_D_WALL_RIGHT]) - r
        floored = m_l < floor or m_r < floor
        F_l = max(1.0 / max(m_l, floor) - inv_delta, 0.0)
        F_r = max(1.0 / max(m_r, floor) - inv_delta, 0.0)

        # eq. 12a-d: rho_dot = -lambda (rho -+ rho_inf) + G, G_d = -F_r - F_l (12a, 12b),
        # G_beta = -F_r + F_l (12c, 12d); then the projection operator over each set:
        # x = (2 rho - (max + min))/(max - min), f = (x^2 - eps^2)/(1 - eps^2),
        # Proj = rd (1 - f) if f > 0 and rd f'(rho) > 0 (f' has the sign of x), else rd
        g_d = -F_l - F_r
        g_b = F_l - F_r
        for j in range(4):
            k_j = sets[j]
            rho_j = rho[j, i]
            rd = rho_j * -lam + k_j.lam_target + (g_d if j < 2 else g_b)
            xn = rho_j * k_j.inv_half - k_j.mid_inv_half
            f = max(xn * xn * f_scale - f_offset, 0.0)
            pd[j] = rd - f * rd if xn * rd > 0.0 else rd
            sig[_S_RHO + j, i] = rho_j
            sig[_S_RHO_DOT + j, i] = pd[j]

        # eq. 10: lo < e < hi; eps = ln((e - lo)/(hi - e)), |eps| <= eps_max (choice 4)
        lo_d = rho[0, i]
        hi_d = rho[1, i]
        lo_b = rho[2, i]
        hi_b = rho[3, i]
        num_d = e_d - lo_d
        den_d = hi_d - e_d
        num_b = e_b - lo_b
        den_b = hi_b - e_b
        funnel_exit = visible and min(min(num_d, den_d), min(num_b, den_b)) <= 0.0
        eps_d = math.log(max(num_d, _TINY) / max(den_d, _TINY))
        eps_d = min(max(eps_d, -eps_max), eps_max) * v
        eps_b = math.log(max(num_b, _TINY) / max(den_b, _TINY))
        eps_b = min(max(eps_b, -eps_max), eps_max) * v
        # C = (lo_dot (hi - e) + hi_dot (e - lo)) / (hi - lo)  (the derivation's C, choice 1)
        C_d = (pd[0] * den_d + num_d * pd[1]) / max(hi_d - lo_d, _WIDTH_FLOOR) * v
        C_b = (pd[2] * den_b + num_b * pd[3]) / max(hi_b - lo_b, _WIDTH_FLOOR) * v

        # eq. 13: u = (k_d eps_d - C_d) / cos(beta), cos(beta) = x~/d (floored, choice 6)
        # eq. 14: omega = (u/d) sin(beta) + k_beta eps_beta - C_beta, sin(beta) = y~/d
        cos_b = max(x / d, COS_FLOOR)
        u = (eps_d * k_d - C_d) / cos_b
        omega = u * y / (d * d) + eps_b * k_beta - C_b
        u *= v  # choice 5: stop
        omega *= v
        cmd[k, 0] = u
        cmd[k, 1] = omega

        # advance rho by one Euler step and clip it to its set (choice 3)
        for j in range(4):
            rho[j, i] = min(max(rho[j, i] + pd[j] * dt, sets[j].rho_min), sets[j].rho_max)

        sig[_S_D, i] = d * v
        sig[_S_BETA, i] = e_b
        sig[_S_E_D, i] = e_d
        sig[_S_E_BETA, i] = e_b
        sig[_S_EPS_D, i] = eps_d
        sig[_S_EPS_BETA, i] = eps_b
        sig[_S_F_L, i] = F_l
        sig[_S_F_R, i] = F_r
        sig[_S_C_D, i] = C_d
        sig[_S_C_BETA, i] = C_b
        sig[_S_U, i] = u
        sig[_S_OMEGA, i] = omega
        sig[_S_VISIBLE, i] = v
        sig[_S_FUNNEL_EXIT, i] = 1.0 if funnel_exit else 0.0
        sig[_S_FLOORED, i] = 1.0 if floored else 0.0
        if funnel_exit:
            counts[_C_FUNNEL_EXITS, i] += 1
        if not visible:
            counts[_C_INVISIBLE, i] += 1
        if floored:
            counts[_C_FLOORED, i] += 1
    return cmd


class PPCPolicy:
    r"""The paper's PPC law (eqs. 7, 12-14) for every follower, as a :class:`~baselines.Policy`.

    ``PPCPolicy(env)`` takes the parameters from ``env.scenario.config`` (its ``ppc`` block,
    ``formation.d_des``, ``safety.d_col``, ``camera.range`` = ``d_con``, ``camera.half_angle`` =
    ``beta_con``, ``robot.radius`` = ``r``) and the Euler step from ``env.control_period``; any
    of :attr:`PPCParams.PPC_KEYS` (e.g. ``k_d=2.0``, ``dt=0.005``, ``lambda_=1.0``) may be
    overridden by keyword. Followers are indexed by ``env.possible_agents``.

    Each :meth:`act` call, for all followers at once (one compiled call, :func:`_ppc_step`):

    1. read the observation at time ``t``: ``d``, ``beta`` (eqs. 2-3), errors (eq. 7) and the
       four clearances;
    2. ``F_l, F_r`` (after eq. 12) and the projected rates of eq. 12a-d at the current ``rho``;
    3. transformed errors ``eps_d``, ``eps_beta`` (clamped, choice 4) and compensation terms
       ``C`` (choice 1);
    4. commands ``u`` (eq. 13) and ``omega`` (eq. 14); ``0, 0`` without a visible predecessor;
    5. advance ``rho`` by one explicit Euler step ``dt`` and clip it to its set (choice 3).

    The module docstring lists the choices made where the paper is silent or inconsistent.

    After each call :attr:`signals` holds the internal signals at time ``t`` (``rho`` before the
    Euler step), and the per-follower counters since :meth:`reset` are updated:
    :attr:`funnel_exits` (steps with an error outside its funnel), :attr:`invisible_steps`
    (steps without a visible predecessor), :attr:`clearance_floor_hits` (steps where a clearance
    margin was floored).
    """

    def __init__(self, env: PolicyEnv, *, dt: float | None = None, **overrides: float) -> None:
        config = env.scenario.config
        period = float(env.control_period) if dt is None else float(dt)
        self.params: PPCParams = PPCParams.from_config(config, period, **overrides)
        self._followers = Followers(env.possible_agents, env.scenario.config)
        self.agents: tuple[str, ...] = self._followers.agents
        n = len(self.agents)
        p = self.params
        # the constants of _ppc_step, read there by field name: (1,) PPC_KERNEL_DTYPE and
        # (4,) PPC_SET_DTYPE (one record per performance function, RHO_NAMES order)
        self._kernel_params: NDArray[np.void] = _kernel_params(p)
        self._kernel_sets: NDArray[np.void] = _kernel_sets(p)
        self._rho0 = p.initial_rho()[:, None]  # eq. 12 initial values, (4, 1)
        self._rho = np.empty((4, n), dtype=np.float64)  # rows in RHO_NAMES order
        self._counts = np.zeros((3, n), dtype=np.int64)
        self.funnel_exits: NDArray[np.int64] = self._counts[_C_FUNNEL_EXITS]
        self.invisible_steps: NDArray[np.int64] = self._counts[_C_INVISIBLE]
        self.clearance_floor_hits: NDArray[np.int64] = self._counts[_C_FLOORED]
        self.steps: int = 0
        # the signals of the last call, rows in SIGNAL_NAMES order (flags as 0.0 / 1.0)
        self._sig = np.zeros((len(SIGNAL_NAMES), n), dtype=np.float64)
        self.reset()

    # -- Policy interface -----------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> None:
        """Restore the eq.-12 initial performance functions and clear counters and signals.

        The law is deterministic; ``seed`` is accepted for the :class:`Policy` interface.
        """
        del seed
        self._rho[...] = self._rho0
        self._counts[...] = 0
        self.steps = 0
        self._sig[...] = 0.0
        self._sig[_S_RHO : _S_RHO + 4] = self._rho

    def act(self, observations: Mapping[str, ArrayLike]) -> dict[str, NDArray[np.float32]]:
        """Commands ``{agent: float32 [u, omega]}`` for every agent in ``observations``.

        Agents of ``env.possible_agents`` absent from ``observations`` (e.g. terminated ones)
        keep their state and signals.
        """
        keys, obs, found = self._followers.read(observations)
        self.steps += 1
        idx = self._followers.all if found is None else found
        cmd = _ppc_step(
            obs, idx, self._kernel_params, self._kernel_sets, self._rho, self._sig, self._counts
        )
        # len(cmd) == len(keys) by the shape check above. strict=True would cost about 0.8 µs a
        # call: its end check indexes cmd one row past its end (ndarray iterates by __getitem__),
        # and numpy raises and formats an IndexError.
        return dict(zip(keys, cmd, strict=False))

    # -- diagnostics ----------------------------------------------------------------------------

    @property
    def rho(self) -> FloatArray:
        """Current performance functions (after the last Euler step), shape (4, N), rows in
        :data:`RHO_NAMES` order (a copy)."""
        return self._rho.copy()

    @property
    def signals(self) -> dict[str, NDArray[Any]]:
        """Internal signals of the last :meth:`act`, at time ``t``: arrays of shape (N,) (copies).

        Keys :data:`SIGNAL_NAMES`: the four ``rho`` (before the Euler step) and their projected
        rates ``*_dot``, ``d``, ``beta``, errors ``e_d``, ``e_beta`` (eq. 7), ``eps_d``,
        ``eps_beta``, ``F_l``, ``F_r``, compensation terms ``C_d``, ``C_beta``, commands ``u``,
        ``omega`` and the boolean flags ``visible``, ``funnel_exit``, ``clearance_floored``. For
        a follower without a visible predecessor ``d``, ``beta``, errors, ``eps``, ``C``, ``u``
        and ``omega`` are 0. Before the first :meth:`act` the ``rho`` are the initial values and
        everything else is 0.
        """
        sig = self._sig
        out: dict[str, NDArray[Any]] = {}
        for k, name in enumerate(SIGNAL_NAMES):
            out[name] = sig[k] != 0.0 if k in _FLAG_ROWS else sig[k].copy()
        return out
