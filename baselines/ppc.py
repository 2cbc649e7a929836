r"""The paper's decentralised Prescribed Performance Control law (section 3, eqs. 7 and 10-14).

Equation numbers refer to ``paper/coordination-of-multiple-robotic-vehicles.md``. For follower
``i`` (index ``i`` dropped below) the law is

* errors (eq. 7): ``e_d = d - d_des``, ``e_beta = beta``, with ``d = |p~|`` (eq. 2) and
  ``beta`` the angle of view (eq. 3), read from the camera's body-frame measurement
  ``(x~, y~) = (d cos beta, d sin beta)``;
* performance functions ``rho_d_lo < e_d < rho_d_hi``, ``rho_beta_lo < e_beta < rho_beta_hi``
  (eq. 10), adapted online by the update laws (eq. 12a-d) driven by the activation terms
  ``F_l, F_r``, each law passed through the projection operator ``Proj`` over its own set;
* transformed errors ``eps = ln((e - rho_lo) / (rho_hi - e))``;
* commands: ``u`` (eq. 13) and ``omega`` (eq. 14).

:class:`PPCPolicy` runs it for all followers at once, vectorised over followers, in discrete
time with the env's control period. The pure functions below (:func:`S`, :func:`F`,
:func:`projection`, :func:`rho_dot`, :func:`transformed_error`, :func:`compensation`,
:func:`linear_velocity`, :func:`angular_velocity`) are the same equations on scalars or arrays,
for unit tests and for readers.

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

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from platoon_env.observation import (
    OBS_D_SIGHT_LEFT,
    OBS_D_SIGHT_RIGHT,
    OBS_D_WALL_LEFT,
    OBS_D_WALL_RIGHT,
    OBS_SIZE,
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


def _f(x: ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


def S(x: ArrayLike, delta: float) -> FloatArray:
    r"""Activation function after eq. 12: ``S(x; delta) = 1 - x/delta`` on ``[0, delta)``, 0 on
    ``[delta, inf)``.

    For ``x < 0`` (outside the paper's domain) the linear branch is continued.
    """
    return np.maximum(1.0 - _f(x) / delta, 0.0)


def clearance_margin(d_sight: ArrayLike, d_wall: ArrayLike, r: float) -> FloatArray:
    r"""The argument of ``S`` in ``F_l`` (``F_r``): ``m = min(d_l - r, d_W_l - r)`` (after eq. 12).

    ``d_sight`` is ``d_l`` (``d_r``), the clearance of the line of sight ``L_i``; ``d_wall`` is
    ``d_W_l`` (``d_W_r``), the clearance of the robot; ``r`` the robot radius.
    """
    return np.minimum(_f(d_sight), _f(d_wall)) - r


def F(m: ArrayLike, delta: float, floor: float = CLEARANCE_FLOOR) -> FloatArray:
    r"""Activation term after eq. 12: ``F = S(m; delta) / m`` with ``m`` from
    :func:`clearance_margin`.

    ``m`` is floored at ``floor`` (> 0) first, so ``F`` is finite: ``0 <= F <= 1/floor - 1/delta``
    (choice 2 in the module docstring). ``F = 0`` for ``m >= delta``.
    """
    mm = np.maximum(_f(m), floor)
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
    p, fl, fr = _f(rho), _f(F_l), _f(F_r)
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
    rd, lo, hi = _f(rho_dot), _f(rho_min), _f(rho_max)
    x = (2.0 * _f(rho) - (hi + lo)) / (hi - lo)
    f = (x * x - epsilon * epsilon) / (1.0 - epsilon * epsilon)
    return np.where((f > 0.0) & (rd * x > 0.0), rd * (1.0 - f), rd)


def outside_funnel(e: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.bool_]:
    """True where the error has left its funnel: not ``lo < e < hi`` (eq. 10)."""
    ee = _f(e)
    return ~((ee > _f(lo)) & (ee < _f(hi)))


def transformed_error(
    e: ArrayLike, lo: ArrayLike, hi: ArrayLike, eps_max: float = EPS_MAX
) -> FloatArray:
    r"""Transformed error (section 3, before eq. 13): ``eps = ln((e - lo) / (hi - e))``.

    Finite everywhere: the ratio is clamped to ``[exp(-eps_max), exp(eps_max)]`` so that
    ``|eps| <= eps_max``; outside the funnel (``e <= lo`` or ``e >= hi``) ``eps = -eps_max`` or
    ``+eps_max`` (choice 4 in the module docstring).
    """
    ee = _f(e)
    num = np.maximum(ee - _f(lo), _TINY)
    den = np.maximum(_f(hi) - ee, _TINY)
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
    ee, lo_a, hi_a = _f(e), _f(lo), _f(hi)
    width = np.maximum(hi_a - lo_a, _WIDTH_FLOOR)
    return (_f(lo_dot) * (hi_a - ee) + _f(hi_dot) * (ee - lo_a)) / width


def linear_velocity(eps_d: ArrayLike, beta: ArrayLike, C_d: ArrayLike, k_d: float) -> FloatArray:
    r"""Linear velocity command (eq. 13): ``u = (k_d eps_d - C_d) / cos(beta)``.

    ``C_d`` from :func:`compensation` with the distance funnel. ``cos(beta)`` is floored at
    :data:`COS_FLOOR` (only reachable with ``|beta| >= beta_con``, never while visible).
    """
    cos_b = np.maximum(np.cos(_f(beta)), COS_FLOOR)
    return (k_d * _f(eps_d) - _f(C_d)) / cos_b


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
    dd = np.maximum(_f(d), DISTANCE_FLOOR)
    return _f(u) / dd * np.sin(_f(beta)) + k_beta * _f(eps_beta) - _f(C_beta)


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


class _Scenario(Protocol):
    @property
    def config(self) -> ScenarioConfig: ...


class PPCEnv(Protocol):
    """What :class:`PPCPolicy` reads from the env."""

    @property
    def possible_agents(self) -> Sequence[str]: ...

    @property
    def control_period(self) -> float: ...

    @property
    def scenario(self) -> _Scenario: ...


def _to_jk(v4: FloatArray) -> FloatArray:
    """(4, ...) in :data:`RHO_NAMES` order -> (2, 2, ...) indexed [lo/hi, d/beta, ...]."""
    return np.ascontiguousarray(np.swapaxes(v4.reshape((2, 2, *v4.shape[1:])), 0, 1))


def _to_4(a: FloatArray) -> FloatArray:
    """(2, 2, n) indexed [lo/hi, d/beta, :] -> a new (4, n) array in :data:`RHO_NAMES` order."""
    out = np.empty((4, a.shape[-1]), dtype=np.float64)
    out.reshape(2, 2, -1)[...] = np.swapaxes(a, 0, 1)
    return out


# The two clearances of each side are adjacent in the observation, so that the law reads them
# with slices ([left, right] columns) instead of fancy indexing.
assert OBS_D_WALL_RIGHT == OBS_D_WALL_LEFT + 1 and OBS_D_SIGHT_RIGHT == OBS_D_SIGHT_LEFT + 1
_WALL = slice(OBS_D_WALL_LEFT, OBS_D_WALL_RIGHT + 1)
_SIGHT = slice(OBS_D_SIGHT_LEFT, OBS_D_SIGHT_RIGHT + 1)
#: [G_d, G_beta] = [F_l, F_r] @ _G_OF_F: G_d = -F_l - F_r (12a, 12b), G_beta = F_l - F_r (12c, 12d)
_G_OF_F = np.array([[-1.0, 1.0], [-1.0, -1.0]])


@dataclass(frozen=True)
class _Consts:
    """Per-call constants in the layout [lo/hi, d/beta, follower], shape (2, 2, n) or (2, 2, 1)."""

    lam_target: FloatArray  # lambda * (-+rho_inf): eq. 12 is rho_dot = lam_target - lambda rho + G
    inv_half: FloatArray  # 2 / (rho_max - rho_min)
    mid_inv_half: FloatArray  # (rho_max + rho_min) / (rho_max - rho_min)
    rho_min: FloatArray
    rho_max: FloatArray

    def tiled(self, n: int) -> _Consts:
        """The same constants repeated for ``n`` followers (avoids broadcasting in the loop)."""
        return _Consts(
            *(
                np.ascontiguousarray(np.broadcast_to(a, (2, 2, n)))
                for a in dataclasses.astuple(self)
            )
        )


class PPCPolicy:
    r"""The paper's PPC law (eqs. 7, 12-14) for every follower, as a :class:`~baselines.Policy`.

    ``PPCPolicy(env)`` takes the parameters from ``env.scenario.config`` (its ``ppc`` block,
    ``formation.d_des``, ``safety.d_col``, ``camera.range`` = ``d_con``, ``camera.half_angle`` =
    ``beta_con``, ``robot.radius`` = ``r``) and the Euler step from ``env.control_period``; any
    of :attr:`PPCParams.PPC_KEYS` (e.g. ``k_d=2.0``, ``dt=0.005``, ``lambda_=1.0``) may be
    overridden by keyword. Followers are indexed by ``env.possible_agents``.

    Each :meth:`act` call, for all followers at once (numpy, no loop over followers):

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

    def __init__(self, env: PPCEnv, *, dt: float | None = None, **overrides: float) -> None:
        config = env.scenario.config
        period = float(env.control_period) if dt is None else float(dt)
        self.params: PPCParams = PPCParams.from_config(config, period, **overrides)
        self.agents: tuple[str, ...] = tuple(env.possible_agents)
        self._index: dict[str, int] = {a: i for i, a in enumerate(self.agents)}
        n = len(self.agents)
        p = self.params
        rho_min4, rho_max4 = p.sets()
        rho_min = _to_jk(rho_min4)[..., None]  # (2, 2, 1), layout [lo/hi, d/beta, follower]
        rho_max = _to_jk(rho_max4)[..., None]
        target = _to_jk(np.array([-p.rho_d_inf, p.rho_d_inf, -p.rho_beta_inf, p.rho_beta_inf]))
        self._consts1 = _Consts(
            lam_target=p.lambda_ * target[..., None],
            inv_half=2.0 / (rho_max - rho_min),
            mid_inv_half=(rho_max + rho_min) / (rho_max - rho_min),
            rho_min=rho_min,
            rho_max=rho_max,
        )
        self._consts = self._consts1.tiled(n)
        self._rho0 = _to_jk(p.initial_rho())[..., None]  # eq. 12 initial values
        # f(rho) = a x^2 - b with a = 1/(1 - epsilon^2), b = epsilon^2/(1 - epsilon^2)
        self._f_a = 1.0 / (1.0 - p.epsilon**2)
        self._f_b = p.epsilon**2 / (1.0 - p.epsilon**2)
        self._rho = np.empty((2, 2, n), dtype=np.float64)
        self.funnel_exits: NDArray[np.int64] = np.zeros(n, dtype=np.int64)
        self.invisible_steps: NDArray[np.int64] = np.zeros(n, dtype=np.int64)
        self.clearance_floor_hits: NDArray[np.int64] = np.zeros(n, dtype=np.int64)
        self.steps: int = 0
        self._raw: _Raw | None = None  # the last full call's signals, turned into a dict lazily
        self._sig: dict[str, NDArray[Any]] = {}
        self.reset()

    # -- Policy interface -----------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> None:
        """Restore the eq.-12 initial performance functions and clear counters and signals.

        The law is deterministic; ``seed`` is accepted for the :class:`Policy` interface.
        """
        del seed
        self._rho[...] = self._rho0
        self.funnel_exits[:] = 0
        self.invisible_steps[:] = 0
        self.clearance_floor_hits[:] = 0
        self.steps = 0
        n = len(self.agents)
        self._raw = None
        self._sig = {name: np.zeros(n) for name in SIGNAL_NAMES}
        for name in ("visible", "funnel_exit", "clearance_floored"):
            self._sig[name] = np.zeros(n, dtype=bool)
        for name, row in zip(RHO_NAMES, _to_4(self._rho), strict=True):
            self._sig[name] = row

    def act(self, observations: Mapping[str, ArrayLike]) -> dict[str, NDArray[np.float32]]:
        """Commands ``{agent: float32 [u, omega]}`` for every agent in ``observations``.

        Agents of ``env.possible_agents`` absent from ``observations`` (e.g. terminated ones)
        keep their state and signals.
        """
        keys = tuple(observations)
        obs = np.array(list(observations.values()), dtype=np.float64)
        if obs.shape != (len(keys), OBS_SIZE):
            raise ValueError(f"expected observations of shape ({OBS_SIZE},), got {obs.shape[1:]}")
        self.steps += 1
        if keys == self.agents:
            cmd, raw = self._step(obs, self._rho, self._consts)
            self.funnel_exits += raw.funnel_exit
            self.invisible_steps += ~raw.visible
            self.clearance_floor_hits += raw.floored
            self._raw = raw
        else:  # a subset (or another order) of the followers
            try:
                idx = np.array([self._index[a] for a in keys], dtype=np.intp)
            except KeyError as err:
                raise KeyError(
                    f"unknown agent {err.args[0]!r}; expected some of {self.agents}"
                ) from None
            rho = self._rho[:, :, idx]
            cmd, raw = self._step(obs, rho, self._consts1)
            self._rho[:, :, idx] = rho
            self.funnel_exits[idx] += raw.funnel_exit
            self.invisible_steps[idx] += ~raw.visible
            self.clearance_floor_hits[idx] += raw.floored
            self._materialise()
            for name, value in raw.to_dict().items():
                merged = self._sig[name].copy()
                merged[idx] = value
                self._sig[name] = merged
        return dict(zip(keys, cmd, strict=True))

    # -- diagnostics ----------------------------------------------------------------------------

    @property
    def rho(self) -> FloatArray:
        """Current performance functions (after the last Euler step), shape (4, N), rows in
        :data:`RHO_NAMES` order (a copy)."""
        return _to_4(self._rho)

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
        self._materialise()
        return {k: v.copy() for k, v in self._sig.items()}

    def _materialise(self) -> None:
        if self._raw is not None:
            self._sig = self._raw.to_dict()
            self._raw = None

    # -- the law --------------------------------------------------------------------------------

    def _step(
        self, obs: FloatArray, rho: FloatArray, c: _Consts
    ) -> tuple[NDArray[np.float32], _Raw]:
        """One control step for the ``n`` followers of ``obs`` (n, 7); ``rho`` (2, 2, n) is
        advanced in place. Returns the (n, 2) float32 commands and the signals at time ``t``."""
        p = self.params
        n = obs.shape[0]
        visible = obs[:, OBS_VISIBLE] > 0.5
        all_visible = bool(visible.all())

        # eqs. 2-3 and 7: d = |p~|, beta = atan2(y~, x~); e = (d - d_des, beta)
        x = obs[:, OBS_X_REL]
        y = obs[:, OBS_Y_REL]
        d = np.hypot(x, y)
        np.maximum(d, DISTANCE_FLOOR, out=d)  # choice 6
        e = np.empty((2, n))
        np.subtract(d, p.d_des, out=e[0])
        np.arctan2(y, x, out=e[1])
        if not all_visible:
            e *= visible  # choice 5: errors reported as 0

        # after eq. 12: m = min(d_sight - r, d_wall - r) for [left, right], floored (choice 2);
        # F = S(m; delta)/m = max(1/m - 1/delta, 0)
        m = np.minimum(obs[:, _SIGHT], obs[:, _WALL])
        m -= p.r
        floored_lr = m < p.clearance_floor
        floored = floored_lr[:, 0] | floored_lr[:, 1]
        np.maximum(m, p.clearance_floor, out=m)
        Fm = np.reciprocal(m)
        Fm -= 1.0 / p.delta
        np.maximum(Fm, 0.0, out=Fm)  # columns F_l, F_r

        # eq. 12a-d: rho_dot = -lambda (rho -+ rho_inf) + G, G_d = -F_r - F_l, G_beta = -F_r + F_l
        G = Fm @ _G_OF_F  # (n, 2): [G_d, G_beta]
        rd = rho * -p.lambda_
        rd += c.lam_target
        rd += G.T
        # projection operator over each set: x = (2 rho - (max + min))/(max - min),
        # f = (x^2 - eps^2)/(1 - eps^2); Proj = rd (1 - f) if f > 0 and rd f'(rho) > 0 (f' ~ x)
        xn = rho * c.inv_half
        xn -= c.mid_inv_half
        f = xn * xn
        f *= self._f_a
        f -= self._f_b
        np.maximum(f, 0.0, out=f)  # f > 0 ...
        xn *= rd
        f *= xn > 0.0  # ... and rd f'(rho) > 0; else the factor is 0
        f *= rd
        pd = np.subtract(rd, f, out=f)  # Proj(rho_dot; rho) = rd - rd f [f > 0, rd x > 0]

        # eq. 10: lo < e < hi; eps = ln((e - lo)/(hi - e)), |eps| <= eps_max (choice 4)
        lo = rho[0]
        hi = rho[1]
        num = e - lo
        den = hi - e
        gap = np.minimum(num, den)
        funnel_exit = np.minimum(gap[0], gap[1]) <= 0.0
        eps = np.maximum(num, _TINY)
        eps /= np.maximum(den, _TINY)
        np.log(eps, out=eps)
        np.maximum(eps, -p.eps_max, out=eps)
        np.minimum(eps, p.eps_max, out=eps)
        # C = (lo_dot (hi - e) + hi_dot (e - lo)) / (hi - lo)  (the derivation's C, choice 1)
        C = pd[0] * den
        num *= pd[1]
        C += num
        width = hi - lo
        np.maximum(width, _WIDTH_FLOOR, out=width)
        C /= width
        if not all_visible:
            funnel_exit &= visible
            eps *= visible
            C *= visible

        # eq. 13: u = (k_d eps_d - C_d) / cos(beta), cos(beta) = x~/d (floored, choice 6)
        # eq. 14: omega = (u/d) sin(beta) + k_beta eps_beta - C_beta, sin(beta) = y~/d
        cmd = np.empty((n, 2))
        u = cmd[:, 0]
        omega = cmd[:, 1]
        cos_b = x / d
        np.maximum(cos_b, COS_FLOOR, out=cos_b)
        np.multiply(eps[0], p.k_d, out=u)
        u -= C[0]
        u /= cos_b
        np.multiply(u, y, out=omega)
        omega /= d * d
        omega += eps[1] * p.k_beta
        omega -= C[1]
        if not all_visible:
            cmd *= visible[:, None]  # choice 5: stop

        # advance rho by one Euler step and clip it to its set (choice 3)
        rho_t = rho.copy()
        rho += pd * p.dt
        np.maximum(rho, c.rho_min, out=rho)
        np.minimum(rho, c.rho_max, out=rho)
        raw = _Raw(rho_t, pd, d, e, eps, Fm, C, cmd, visible, funnel_exit, floored)
        return cmd.astype(np.float32), raw


@dataclass(frozen=True)
class _Raw:
    """One call's internal signals as computed (turned into :attr:`PPCPolicy.signals` lazily)."""

    rho: FloatArray  # (2, 2, n), at time t
    rho_dot: FloatArray  # (2, 2, n), projected
    d: FloatArray
    e: FloatArray  # (2, n)
    eps: FloatArray  # (2, n)
    F: FloatArray  # (n, 2): F_l, F_r
    C: FloatArray  # (2, n)
    cmd: FloatArray  # (n, 2)
    visible: NDArray[np.bool_]
    funnel_exit: NDArray[np.bool_]
    floored: NDArray[np.bool_]

    def to_dict(self) -> dict[str, NDArray[Any]]:
        out: dict[str, NDArray[Any]] = {}
        for name, row in zip(RHO_NAMES, _to_4(self.rho), strict=True):
            out[name] = row
        for name, row in zip(RHO_NAMES, _to_4(self.rho_dot), strict=True):
            out[name + "_dot"] = row
        out["d"] = self.d * self.visible
        out["beta"] = self.e[1].copy()
        out["e_d"] = self.e[0].copy()
        out["e_beta"] = self.e[1].copy()
        out["eps_d"] = self.eps[0].copy()
        out["eps_beta"] = self.eps[1].copy()
        out["F_l"] = self.F[:, 0].copy()
        out["F_r"] = self.F[:, 1].copy()
        out["C_d"] = self.C[0].copy()
        out["C_beta"] = self.C[1].copy()
        out["u"] = self.cmd[:, 0].copy()
        out["omega"] = self.cmd[:, 1].copy()
        out["visible"] = self.visible.copy()
        out["funnel_exit"] = self.funnel_exit.copy()
        out["clearance_floored"] = self.floored.copy()
        return out
