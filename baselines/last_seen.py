r"""The comparison baseline: a saturated tracking law with a leader-loss mode, after ref. [32].

Equation and section numbers refer to the paper *Coordination of Multiple Robotic Vehicles in
Obstacle-Cluttered Environments*.
The paper describes its reference [32] in three places, and this module implements that
description (not [32]'s own equations, which the paper does not reproduce):

* §1.1: "a tracking control scheme ... that takes sensor limitations explicitly into account
  along with the safety in unknown obstacle environments. Moreover, the leader-loss situation
  was tackled by an extra control mode that drives the follower towards the position where its
  leader was visually tracked for the last time";
* §4.2 (study B, Figs. 8-11): it "violates periodically the angle-of-view constraints", then
  "performs a maneuver towards the position where the preceding robot was last detected
  assuming it will then regain visibility with it"; its velocity commands are bounded and of
  the same range as PPC's (Figs. 10, 11);
* §4.3 (study C, Fig. 15): in the snaky passage the leader is lost at the first sharp corner and
  "by the time the follower arrived at the position where the leader was detected for the last
  time the leader was no longer visible".

For follower ``i`` (index dropped) the law works on a *target* ``(x_T, y_T)`` in the follower's
body frame, at distance ``rho_T = |(x_T, y_T)|`` and bearing ``phi_T = atan2(y_T, x_T)``:

1. **Tracking mode** (``mode = 0``, predecessor visible): the target is the camera's measurement
   ``(x~, y~) = (d cos beta, d sin beta)`` (eqs. 2-3), so ``rho_T = d``, ``phi_T = beta``, and
   the set-point is ``d_ref = d_des``.
2. **Leader-loss mode** (``mode = 1``, predecessor not visible): the target is the last-seen
   point, the predecessor's position at the last step it was visible, and ``d_ref = 0`` (drive
   to the point itself). The point is kept in the follower's *own odometry frame*: every control
   period the follower moves its stored body-frame coordinates by its own commanded motion,
   ``(u, omega)`` held for ``dt`` — the exact unicycle arc of eq. 1, by the env's own rule
   (:func:`ego_motion`, :mod:`baselines.odometry`). No global position is used. When the
   predecessor is seen again the follower returns to tracking with the new measurement.
3. **Arrival.** When in leader-loss mode the follower comes within ``arrive_radius`` (default
   ``d_col``: any closer would be a collision, had the predecessor still been there) of the
   last-seen point without having re-acquired its predecessor, it **stops** (``u = omega = 0``)
   and waits; it resumes tracking if the predecessor comes back into view. Stopping rather than
   searching is the behaviour §4.3 reports for [32] ("by the time the follower arrived ... the
   leader was no longer visible"), and keeps the baseline free of a search strategy [32] is not
   described to have. A follower that is blind from its very first step has no last-seen point
   and stops at once.

Commands, for both modes (vectorised over followers)::

    u     = sat(k_d (rho_T - d_ref) cos(phi_T), u_max) (1 - s_W min(P, 1))
    omega = sat(k_beta phi_T + k_wall (|u| / u_max) (P_r - P_l), omega_max)
    P_l = max(m_W / (d_W_l - r) - 1, 0),  P_r likewise,  P = max(P_l, P_r)

and ``u = omega = 0`` once arrived (3.). The choices:

* the distance law is proportional with a **saturated** speed (actuator limit ``u_max``,
  default twice the leader's speed from the scenario: a follower must be able to catch up),
  unlike PPC's unbounded transients (§4.2: "our method does not impose any explicit bounds");
  ``cos(phi_T)`` makes it drive only as far as it faces the target;
* the sensor limits are "taken into account" (§1.1) through the gains and the leader-loss mode
  only: the bearing gain saturates the turn rate at the edge of the view, and a lost
  predecessor switches the mode. The paper describes no mode that slows the follower to keep
  its predecessor in view, so :class:`LastSeenPolicy` has none. The variant
  :class:`LastSeenFOVPolicy` (``last_seen_fov``) adds a **field-of-view slow-down**
  ``g(phi_T) = clip((beta_con - |phi_T|) / (beta_con - beta_slow), 0, 1)`` on ``u``: full speed
  while ``|phi_T| <= beta_slow`` (default ``beta_con / 2``), none at ``|phi_T| >= beta_con``,
  so the follower turns in place towards a predecessor at the edge of its view. That is a
  choice of this project, which makes field-of-view loss structurally hard; the comparison
  (``python -m experiments.studies.comparison``) runs both;
* the bearing law is **proportional** (``omega = k_beta phi_T``, default
  ``k_beta = omega_max / beta_con``: saturation exactly at the field-of-view edge), without
  PPC's feed-forward ``(u/d) sin(beta)`` (eq. 14) or its funnels: when the predecessor turns a
  sharp corner the bearing lags, and with ``beta_con = 0.4`` it can leave the narrow view;
* **obstacles** are avoided reactively, from the proximity sensor only (``d_W_l``, ``d_W_r``,
  §2, the sides of the line of sight ``L_i``): a potential-field push ``P`` (:func:`wall_push`)
  engages when the margin ``d_W - r`` drops below ``m_W`` (``wall_margin``, default ``r + 0.1``
  m: the robot's radius plus the 0.1 m by which §4.2 augments the obstacles), is 1 at half of
  it and grows without bound at contact. It slows the follower (by up to the fraction
  ``s_W`` = ``wall_slowdown``, default 0.5) and bends its path away from the nearer side. The
  bend is a curvature (scaled by ``|u| / u_max``, ``k_wall`` default ``omega_max``): turning in
  place does not move a disk robot away from a wall, and a turn-rate term that also acts at
  standstill deadlocks the follower against the wall when the target is beside it (found in
  development: the follower sat at a corner with the two terms cancelling). Nothing keeps the
  line of sight clear of obstacles (PPC's ``d_l``, ``d_r`` terms of eq. 12): that is the gap
  §1.1 and §4.3 point at.

Defaults scale with the scenario: ``u_max = 2 v_0`` (``v_0`` = ``leader.speed``, a property of
the team rather than an observation; capped by the action space's ``robot.u_max``),
``omega_max = 2 u_max / d_des`` (twice the bearing rate of a predecessor crossing at ``u_max``
at ``d_des``; capped by ``robot.omega_max``), ``k_d = 4 u_max / d_des`` (the speed saturates at
``|e_d| = d_des / 4``; steady lag ``v_0 / k_d = d_des / 8`` behind a leader at ``v_0``),
``k_beta = omega_max / beta_con``. Every one can be overridden by keyword (:attr:`TUNABLE
<LastSeenParams.TUNABLE>`).

Where the behaviour depends on the tuning and the variant, the comparison study
(``python -m experiments.studies.comparison``) measures it on studies B and C over 20 seeds
(``docs/figures/comparison.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from baselines.odometry import body_arc, in_frame
from baselines.policy import Followers, PolicyEnv, as_float
from platoon_env.observation import (
    OBS_D_WALL_LEFT,
    OBS_D_WALL_RIGHT,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
)
from platoon_env.scenarios.schema import ScenarioConfig

__all__ = [
    "MODE_LOST",
    "MODE_TRACKING",
    "SIGNAL_NAMES",
    "LastSeenFOVPolicy",
    "LastSeenParams",
    "LastSeenPolicy",
    "commands",
    "ego_motion",
]

FloatArray = NDArray[np.float64]

#: ``mode`` signal: tracking the visible predecessor.
MODE_TRACKING: int = 0
#: ``mode`` signal: predecessor not visible, driving to (or stopped at) its last-seen point.
MODE_LOST: int = 1

#: Keys of :attr:`LastSeenPolicy.signals`.
SIGNAL_NAMES: tuple[str, ...] = (
    "mode",
    "target_x",
    "target_y",
    "u",
    "omega",
    "visible",
    "arrived",
)


# ----------------------------------------------------------------------------------------------
# Pure functions
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def _ego_motion(
    x: np.ndarray, y: np.ndarray, u: np.ndarray, omega: np.ndarray, h: float, out: np.ndarray
) -> None:
    """:func:`ego_motion` of 1-D arrays, into ``out`` (2, n)."""
    for r in range(x.shape[0]):
        dx, dy, a = body_arc(u[r], omega[r], h)
        out[0, r], out[1, r] = in_frame(x[r], y[r], dx, dy, a)


def ego_motion(
    x: ArrayLike, y: ArrayLike, u: ArrayLike, omega: ArrayLike, dt: float
) -> tuple[FloatArray, FloatArray]:
    r"""Body-frame coordinates of a fixed point after the follower's own motion (eq. 1).

    The follower holds ``(u, omega)`` for ``dt``: it moves on an exact unicycle arc by
    ``(dx, dy) = (u dt sin(a)/a, u dt (1 - cos a)/a)`` in its old body frame and turns by
    ``a = omega dt`` (the env's arc, :func:`baselines.odometry.body_arc`: a straight line as
    ``a -> 0``). A point at ``(x, y)`` in the old frame is at ``R(-a) ((x, y) - (dx, dy))`` in
    the new one. Elementwise on broadcast arrays.
    """
    xs, ys, us, ws = np.broadcast_arrays(as_float(x), as_float(y), as_float(u), as_float(omega))
    out = np.empty((2, xs.size))
    _ego_motion(xs.ravel(), ys.ravel(), us.ravel(), ws.ravel(), dt, out)
    return out[0].reshape(xs.shape), out[1].reshape(xs.shape)


#: [m] floor on the margin ``d_W - r`` in :func:`wall_push` (bounds the push at contact).
WALL_FLOOR: float = 1e-3


def wall_push(d_wall: ArrayLike, r: float, margin: float) -> FloatArray:
    r"""Reactive repulsion from one side's wall: ``P = margin / m - 1`` for ``m = d_W - r``
    below ``margin``, 0 above (``P = 1`` at ``m = margin / 2``, unbounded at contact).

    A potential-field term like PPC's ``F = S(m; delta)/m`` (after eq. 12), but acting
    directly on the robot's turn rate and speed; ``m`` is floored at :data:`WALL_FLOOR`.
    """
    m = np.maximum(as_float(d_wall) - r, WALL_FLOOR)
    return np.maximum(margin / m - 1.0, 0.0)


def commands(
    x_t: ArrayLike,
    y_t: ArrayLike,
    d_ref: ArrayLike,
    d_wall_left: ArrayLike,
    d_wall_right: ArrayLike,
    p: LastSeenParams,
) -> tuple[FloatArray, FloatArray]:
    r"""The tracking law towards a body-frame target ``(x_T, y_T)`` at set-point ``d_ref``.

    ``u = sat(k_d (rho_T - d_ref) cos(phi_T), u_max) g(phi_T) (1 - max(p_l, p_r))`` and
    ``omega = sat(k_beta phi_T + k_wall (p_r - p_l), omega_max)``, with the field-of-view
    slow-down ``g`` (1 unless ``p.fov_slowdown``) and the wall terms ``p_l``, ``p_r`` of the
    module docstring. Elementwise on
    arrays; finite for finite inputs (``phi_T = 0`` for a target at the origin).
    """
    xt, yt = as_float(x_t), as_float(y_t)
    rho = np.hypot(xt, yt)
    phi = np.arctan2(yt, xt)  # 0 at the origin
    u = np.clip(p.k_d * (rho - as_float(d_ref)) * np.cos(phi), -p.u_max, p.u_max)
    if p.fov_slowdown:  # the variant LastSeenFOVPolicy only: not in the paper's description
        u *= np.clip((p.beta_con - np.abs(phi)) / (p.beta_con - p.beta_slow), 0.0, 1.0)
    push_l = wall_push(d_wall_left, p.r, p.wall_margin)
    push_r = wall_push(d_wall_right, p.r, p.wall_margin)
    u *= 1.0 - p.wall_slowdown * np.minimum(np.maximum(push_l, push_r), 1.0)
    # the wall term bends the path (a curvature, scaled by |u|/u_max): turning in place does
    # not move a disk robot away from a wall, and must stay free to face the target
    bend = p.k_wall * (np.abs(u) / p.u_max) * (push_r - push_l)
    omega = np.clip(p.k_beta * phi + bend, -p.omega_max, p.omega_max)
    return u, omega


# ----------------------------------------------------------------------------------------------
# Parameters
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LastSeenParams:
    """Everything the last-seen law needs (paper symbols; SI units).

    Geometry from the scenario (``robot.radius`` = ``r``, ``formation.d_des``,
    ``safety.d_col``, ``camera.range`` = ``d_con``, ``camera.half_angle`` = ``beta_con``),
    ``dt`` from the env's control period, gains and limits from :meth:`from_config`'s defaults
    (module docstring) or keyword overrides.
    """

    r: float  # [m] robot radius
    d_des: float  # [m] desired distance
    d_col: float  # [m] collision distance
    d_con: float  # [m] camera range
    beta_con: float  # [rad] camera half angle
    dt: float  # [s] control period (odometry step)
    u_max: float  # [m/s] actuator limit on |u|
    omega_max: float  # [rad/s] actuator limit on |omega|
    k_d: float  # [1/s] distance gain
    k_beta: float  # [1/s] bearing gain
    beta_slow: float  # [rad] |phi_T| above which u is reduced (zero at beta_con)
    wall_margin: float  # [m] d_W - r below which the follower slows and steers away
    wall_slowdown: float  # fraction of u removed at contact with a wall, in (0, 1]
    k_wall: float  # [rad/s] turn rate away from a wall at contact
    arrive_radius: float  # [m] distance to the last-seen point counted as arrival
    fov_slowdown: bool = False  # slow down towards the edge of the view (the variant only)

    #: names that may be overridden in :meth:`from_config` / :class:`LastSeenPolicy`.
    TUNABLE: ClassVar[tuple[str, ...]] = (
        "dt",
        "u_max",
        "omega_max",
        "k_d",
        "k_beta",
        "beta_slow",
        "wall_margin",
        "wall_slowdown",
        "k_wall",
        "arrive_radius",
        "fov_slowdown",
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "fov_slowdown":
                if not isinstance(value, bool):
                    raise ValueError(f"fov_slowdown must be a bool, got {value!r}")
                continue
            if not (math.isfinite(value) and value > 0):
                raise ValueError(
                    f"last-seen parameter {f.name} must be finite and > 0, got {value!r}"
                )
        if not self.wall_slowdown <= 1.0:
            raise ValueError(f"need wall_slowdown <= 1, got {self.wall_slowdown}")
        if not self.beta_slow < self.beta_con:
            raise ValueError(f"need beta_slow < beta_con, got {self.beta_slow}, {self.beta_con}")

    @classmethod
    def from_config(
        cls, config: ScenarioConfig, dt: float, **overrides: float | bool
    ) -> LastSeenParams:
        """Parameters for ``config`` with the scenario-scaled defaults of the module docstring.

        ``overrides`` may replace any of :attr:`TUNABLE`; a default that depends on an
        overridden value (e.g. ``k_beta`` on ``omega_max``) follows the override.
        """
        unknown = sorted(set(overrides) - set(cls.TUNABLE))
        if unknown:
            raise TypeError(
                f"unknown last-seen override(s) {unknown}; expected some of {cls.TUNABLE}"
            )
        fov_slowdown = overrides.pop("fov_slowdown", False)
        ov = {k: float(v) for k, v in overrides.items()}
        d_des = float(config.formation.d_des)
        beta_con = float(config.camera.half_angle)
        u_max = ov.get("u_max", min(2.0 * float(config.leader.speed), float(config.robot.u_max)))
        omega_max = ov.get("omega_max", min(2.0 * u_max / d_des, float(config.robot.omega_max)))
        return cls(
            r=float(config.robot.radius),
            d_des=d_des,
            d_col=float(config.safety.d_col),
            d_con=float(config.camera.range),
            beta_con=beta_con,
            dt=ov.get("dt", float(dt)),
            u_max=u_max,
            omega_max=omega_max,
            k_d=ov.get("k_d", 4.0 * u_max / d_des),
            k_beta=ov.get("k_beta", omega_max / beta_con),
            beta_slow=ov.get("beta_slow", 0.5 * beta_con),
            wall_margin=ov.get("wall_margin", float(config.robot.radius) + 0.1),
            wall_slowdown=ov.get("wall_slowdown", 0.5),
            k_wall=ov.get("k_wall", omega_max),
            arrive_radius=ov.get("arrive_radius", float(config.safety.d_col)),
            fov_slowdown=fov_slowdown,  # type: ignore[arg-type]
        )


# ----------------------------------------------------------------------------------------------
# The policy
# ----------------------------------------------------------------------------------------------


class LastSeenPolicy:
    r"""Ref. [32] as the paper describes it: saturated tracking, drive to the last-seen point.

    ``LastSeenPolicy(env)`` reads ``env.possible_agents``, ``env.control_period`` (the odometry
    step ``dt``) and ``env.scenario.config``; any of :attr:`LastSeenParams.TUNABLE` may be
    overridden by keyword (e.g. ``u_max=0.6``, ``k_beta=3.0``). See the module docstring for
    the law and the design choices.

    Each :meth:`act` call, for the given followers at once (numpy, no loop over followers):

    1. move every stored target by the follower's previous command (:func:`ego_motion`);
    2. where the predecessor is visible: target := measurement ``(x~, y~)``, tracking mode;
       where it is not: leader-loss mode towards the (moved) last-seen point, and a follower
       within ``arrive_radius`` of it is marked arrived and stops;
    3. commands by :func:`commands` (zero for arrived followers), remembered for step 1.

    State and counters since :meth:`reset`, per follower (index of ``env.possible_agents``):
    :attr:`lost_steps` (calls without a visible predecessor), :attr:`losses` (visible ->
    not-visible transitions; the predecessor counts as visible before the first call, as the
    initial configuration requires). :attr:`signals` holds the last call's signals.
    """

    def __init__(
        self, env: PolicyEnv, *, dt: float | None = None, **overrides: float | bool
    ) -> None:
        if dt is not None:
            overrides["dt"] = dt
        self.params: LastSeenParams = LastSeenParams.from_config(
            env.scenario.config, float(env.control_period), **overrides
        )
        self._followers = Followers(env.possible_agents, env.scenario.config)
        self.agents: tuple[str, ...] = self._followers.agents
        n = len(self.agents)
        self._target = np.zeros((2, n))  # last-seen / measured point, body frame
        self._cmd = np.zeros((2, n))  # previous command [u, omega]
        self._visible = np.ones(n, dtype=bool)  # predecessor visible at the previous call
        self._arrived = np.zeros(n, dtype=bool)
        self._has_target = np.zeros(n, dtype=bool)  # a last-seen point exists
        self.lost_steps: NDArray[np.int64] = np.zeros(n, dtype=np.int64)
        self.losses: NDArray[np.int64] = np.zeros(n, dtype=np.int64)
        self.steps: int = 0
        self._sig: dict[str, NDArray[Any]] = {}
        self.reset()

    # -- Policy interface -----------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> None:
        """Forget targets and previous commands, clear counters and signals.

        The law is deterministic; ``seed`` is accepted for the :class:`~baselines.Policy`
        interface.
        """
        del seed
        n = len(self.agents)
        self._target[...] = 0.0
        self._cmd[...] = 0.0
        self._visible[:] = True
        self._arrived[:] = False
        self._has_target[:] = False
        self.lost_steps[:] = 0
        self.losses[:] = 0
        self.steps = 0
        self._sig = {name: np.zeros(n) for name in SIGNAL_NAMES}
        self._sig["mode"] = np.zeros(n, dtype=np.int64)
        self._sig["visible"] = np.ones(n, dtype=bool)
        self._sig["arrived"] = np.zeros(n, dtype=bool)

    def act(self, observations: Mapping[str, ArrayLike]) -> dict[str, NDArray[np.float32]]:
        """Commands ``{agent: float32 [u, omega]}`` for every agent in ``observations``.

        Agents of ``env.possible_agents`` absent from ``observations`` (e.g. terminated ones)
        keep their state. Non-finite observation entries are treated as 0 (a NaN ``visible``
        flag as not visible, a NaN clearance as contact), so commands are always finite.
        """
        keys, obs, found = self._followers.read(observations)
        idx: slice | NDArray[np.intp] = slice(None) if found is None else found
        self.steps += 1
        cmd = self._step(np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0), idx)
        return dict(zip(keys, cmd.astype(np.float32), strict=True))

    # -- diagnostics ----------------------------------------------------------------------------

    @property
    def signals(self) -> dict[str, NDArray[Any]]:
        """Signals of the last :meth:`act`, arrays of shape (N,) (copies), keys
        :data:`SIGNAL_NAMES`: ``mode`` (:data:`MODE_TRACKING` / :data:`MODE_LOST`),
        ``target_x``, ``target_y`` (the target in the body frame at the time of the call: the
        measurement while tracking, the last-seen point in leader-loss mode), the commands
        ``u``, ``omega``, and the flags ``visible`` and ``arrived`` (stopped at the last-seen
        point)."""
        return {k: v.copy() for k, v in self._sig.items()}

    # -- the law --------------------------------------------------------------------------------

    def _step(self, obs: FloatArray, idx: slice | NDArray[np.intp]) -> FloatArray:
        """One control step for the followers ``idx`` with observations ``obs`` (n, 7);
        updates their state, counters and signals; returns the (n, 2) commands."""
        p = self.params
        # 1. odometry: the stored point, seen from where the previous command took the follower
        tx, ty = ego_motion(
            self._target[0, idx], self._target[1, idx], self._cmd[0, idx], self._cmd[1, idx], p.dt
        )
        # 2. mode switching
        visible = obs[:, OBS_VISIBLE] > 0.5
        was_visible = self._visible[idx]
        tx = np.where(visible, obs[:, OBS_X_REL], tx)
        ty = np.where(visible, obs[:, OBS_Y_REL], ty)
        lost = ~visible
        # arrived (stopped): once within arrive_radius of the last-seen point, until the
        # predecessor is seen again; at once if it was never seen (no last-seen point)
        has_target = self._has_target[idx] | visible
        reached = np.hypot(tx, ty) <= p.arrive_radius
        arrived = lost & (self._arrived[idx] | reached | ~has_target)
        d_ref = np.where(visible, p.d_des, 0.0)
        # 3. commands
        u, omega = commands(tx, ty, d_ref, obs[:, OBS_D_WALL_LEFT], obs[:, OBS_D_WALL_RIGHT], p)
        u[arrived] = 0.0
        omega[arrived] = 0.0
        # what the env receives (float32): the odometry of step 1 integrates exactly this
        u = u.astype(np.float32).astype(np.float64)
        omega = omega.astype(np.float32).astype(np.float64)
        # bookkeeping
        self._target[0, idx] = tx
        self._target[1, idx] = ty
        self._cmd[0, idx] = u
        self._cmd[1, idx] = omega
        self.losses[idx] += was_visible & lost
        self.lost_steps[idx] += lost
        self._visible[idx] = visible
        self._arrived[idx] = arrived
        self._has_target[idx] = has_target
        new = {
            "mode": np.where(visible, MODE_TRACKING, MODE_LOST).astype(np.int64),
            "target_x": tx,
            "target_y": ty,
            "u": u,
            "omega": omega,
            "visible": visible,
            "arrived": arrived,
        }
        for name, value in new.items():
            if isinstance(idx, slice):
                self._sig[name] = value.copy()
            else:
                merged = self._sig[name].copy()
                merged[idx] = value
                self._sig[name] = merged
        return np.stack([u, omega], axis=-1)


class LastSeenFOVPolicy(LastSeenPolicy):
    """The variant of :class:`LastSeenPolicy` with the **field-of-view slow-down**: the speed
    is scaled by ``g(phi_T) = clip((beta_con - |phi_T|) / (beta_con - beta_slow), 0, 1)``, full
    while ``|phi_T| <= beta_slow`` (default ``beta_con / 2``), zero at ``|phi_T| >= beta_con``,
    so the follower turns in place towards a predecessor at the edge of its view.

    The paper does not describe such a mode for ref. [32]; it is a design choice of this
    project that makes field-of-view loss structurally hard, kept under its own name
    (``last_seen_fov`` in :data:`experiments.policies.REGISTRY`) so the comparison can show
    both. Same keyword overrides as :class:`LastSeenPolicy`.
    """

    def __init__(
        self, env: PolicyEnv, *, dt: float | None = None, **overrides: float | bool
    ) -> None:
        overrides.setdefault("fov_slowdown", True)
        super().__init__(env, dt=dt, **overrides)
