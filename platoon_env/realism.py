"""Randomised realism: each episode draws its sensing and actuation realism from ranges.

A scenario's ``realism`` block (:class:`~platoon_env.config.RealismRanges`, ``docs/realism.md``)
names some of the realism fields of the schema, each with a range ``[lo, hi]``, or a shipped
preset of such ranges (:data:`REALISM_PRESETS`)::

    realism: {preset: ideal_to_beyond_aruco}
    realism: {camera.latency: [0.0, 0.1], robot.accel_max: [1.0, null]}

At every reset the env draws one value per named field from its own seeded RNG and writes it
into its :data:`~platoon_env.records.PARAMS_DTYPE` record, where the compiled perception
(:mod:`platoon_env.perception`) and actuators (:mod:`platoon_env.dynamics.actuators`) read it;
the fields not named keep the scenario's values. The draw rule, per field (:data:`FIELDS`):

* **linear** (the noise standard deviations, ``detection``, ``detection_edge``,
  ``proximity.noise``): uniform in ``[lo, hi]``;
* **reciprocal** (``camera.frame_rate``, ``robot.accel_max``, ``robot.alpha_max``, whose ideal
  is null): the reciprocal — the frame period [s], the seconds per m/s (or rad/s) of velocity
  change — uniform in ``[1 / hi, 1 / lo]``, with ``1 / null = 0``: a frame every control step,
  or no bound, the continuous end of the range;
* **latency** (``camera.latency``, a whole number of control periods): uniform among the whole
  numbers of control periods in ``[lo, hi]``.

All the fields of one episode come from one call ``rng.random(K)`` (``K`` the fields drawn, in
:data:`FIELDS` order), made after the initial configuration and the leader's speed factor and
before the perception stream is seeded; without a ``realism`` block nothing is drawn, so every
other episode draws exactly as before. What was drawn is reported, per field, in
``info[agent]["realism"]`` (:func:`reported_values`: a flat dict of floats) and by
:attr:`platoon_env.batched.BatchedPlatoon.realism`.

This module imports nothing of the package but :mod:`platoon_env.config`, so the scenario
checks (:mod:`platoon_env.scenarios.validate`) and the core (:mod:`platoon_env.core`) both call
it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np

from platoon_env.config import (
    LATENCY,
    LINEAR,
    REALISM_FIELDS,
    RECIPROCAL,
    RealismField,
    RealismRanges,
    ScenarioConfig,
    field_key,
    latency_steps,
    require,
    shown,
    stage_flags,
)

#: Tolerance of "a whole number of control periods" (as the schema's ``camera.latency`` rule).
_WHOLE = 1e-6

#: The fields ``realism`` may draw, in draw order: their one table is
#: :class:`~platoon_env.config.RealismRanges` (:data:`~platoon_env.config.REALISM_FIELDS`).
FIELDS: tuple[RealismField, ...] = REALISM_FIELDS
_BY_KEY: Mapping[str, RealismField] = MappingProxyType({f.key: f for f in FIELDS})

#: A range as the schema holds it: ``(lo, hi)``, ``hi`` None for "up to null".
Range = tuple[float, float | None]

#: Shipped presets: name -> ``{field key: (lo, hi)}``.
#:
#: ``ideal_to_beyond_aruco`` spans, per field, from the ideal value (no noise, every detection,
#: a frame every control step, no latency, no bound) to beyond the ``aruco`` sensor profile
#: (``platoon_env/scenarios/profiles/aruco.yaml``): at least 1.5 times its noise standard
#: deviations, its lost fraction of detections (``1 - detection``, and ``detection_edge``),
#: its frame period (30 Hz -> 20 Hz), its latency (0.05 s -> 0.08 s, the next whole number of
#: the default 0.01 s control period above 0.075 s) and the reciprocals of its acceleration
#: limits (2.5 -> 1.6 m/s^2, 3.2 -> 2.1 rad/s^2). ``robot.lag`` is not drawn (aruco has none).
REALISM_PRESETS: Mapping[str, Mapping[str, Range]] = MappingProxyType(
    {
        "ideal_to_beyond_aruco": MappingProxyType(
            {
                "camera.noise.position": (0.0, 0.0075),
                "camera.noise.position_per_m": (0.0, 0.015),
                "camera.noise.bearing": (0.0, 0.015),
                "camera.detection": (0.925, 1.0),
                "camera.detection_edge": (0.0, 0.75),
                "camera.frame_rate": (20.0, None),
                "camera.latency": (0.0, 0.08),
                "proximity.noise": (0.0, 0.015),
                "robot.accel_max": (1.6, None),
                "robot.alpha_max": (2.1, None),
            }
        ),
    }
)


def list_presets() -> list[str]:
    """Names of the shipped presets, sorted."""
    return sorted(REALISM_PRESETS)


class _Draw(NamedTuple):
    """One field's draw, resolved for a control period: ``x = a + b * u``, ``u`` uniform in
    ``[0, 1)``, written to params field ``param`` as ``x`` (``mode`` :data:`_AS_IS`: a linear
    field, or the frame period), ``1 / x`` (:data:`_INVERSE`: an acceleration limit) or
    ``floor(x)`` (:data:`_FLOOR`: the latency in whole control periods, at most ``a + b - 1``)."""

    key: str
    param: str
    mode: int
    a: float
    b: float


_AS_IS, _INVERSE, _FLOOR = range(3)


@dataclass(frozen=True)
class _Plan:
    """What a reset does for one ``realism`` block: its draws, the params fields of
    :data:`FIELDS` that it keeps (the scenario's values, which
    :func:`platoon_env.core.params_of` wrote) and the scenario's ``robot.lag`` [s]."""

    draws: tuple[_Draw, ...]
    kept: tuple[str, ...]
    lag: float


def ranges_of(cfg: ScenarioConfig) -> dict[str, Range]:
    """The ranges ``cfg`` draws from, ``{field key: (lo, hi)}`` in :data:`FIELDS` order: its
    preset's, each replaced by a range given beside it; empty without a ``realism`` block.
    (An unknown preset is left out here; :func:`check_realism_ranges` names it.)"""
    return {} if cfg.realism is None else _ranges(cfg.realism)


def _ranges(block: RealismRanges) -> dict[str, Range]:
    """:func:`ranges_of` of a ``realism`` block."""
    preset = REALISM_PRESETS.get(block.preset, {}) if block.preset is not None else {}
    out: dict[str, Range] = {}
    for f in fields(block):
        if f.name == "preset":
            continue
        given = getattr(block, f.name)
        rng = given if given is not None else preset.get(field_key(f))
        if rng is not None:
            out[field_key(f)] = (float(rng[0]), None if rng[1] is None else float(rng[1]))
    return out


def _latency_bounds(lo: float, hi: float, dt: float) -> tuple[int, int]:
    """The least and greatest whole number of control periods ``dt`` in ``[lo, hi]`` [s]."""
    return math.ceil(lo / dt - _WHOLE), math.floor(hi / dt + _WHOLE)


def check_realism_ranges(cfg: ScenarioConfig, path: str, max_latency_steps: int) -> None:
    """Check ``cfg``'s ``realism`` block: a known preset, at least one field drawn, every range
    ``lo <= hi`` within the field's own limits (the schema's, ``docs/realism.md``): ``frame_rate``
    in ``(0, 1 / control_period]`` (``hi`` may be null), the latency's upper end at most
    ``max_latency_steps`` control periods (the schema's ``MAX_LATENCY_STEPS``) and its range
    holding a whole number of them, the acceleration limits ``> 0`` (``hi`` may be null).
    Raises ``ScenarioError`` naming the field (``scenario.realism.camera.latency``)."""
    block = cfg.realism
    if block is None:
        return
    where = f"{path}.realism"
    require(
        block.preset is None or block.preset in REALISM_PRESETS,
        f"{where}.preset",
        f"expected one of {', '.join(list_presets())}, got {shown(block.preset)}",
    )
    ranges = ranges_of(cfg)
    require(
        bool(ranges),
        where,
        f"draws nothing: give a preset ({', '.join(list_presets())}) or a range of "
        f"{', '.join(f.key for f in FIELDS)}",
    )
    dt = cfg.simulation.control_period
    for key, (lo, hi) in ranges.items():
        f, at = _BY_KEY[key], f"{where}.{key}"
        if f.kind == RECIPROCAL:
            require(lo > 0, at, f"the lower end must be > 0, got {lo!r}")
            if f.key == "camera.frame_rate":
                top = 1.0 / dt
                require(
                    hi is None or hi <= top + 1e-9,
                    at,
                    f"the upper end must be at most 1 / control_period = {top:g} Hz, or null "
                    f"(a frame every control step), got {hi!r}",
                )
        else:
            assert hi is not None  # the schema types these [float, float]
            require(lo >= f.lo, at, f"the lower end must be >= {f.lo:g}, got {lo!r}")
            if f.hi is not None:
                require(hi <= f.hi, at, f"the upper end must be <= {f.hi:g}, got {hi!r}")
        require(hi is None or lo <= hi, at, f"empty range: lo = {lo!r} > hi = {hi!r}")
        if f.kind == LATENCY:
            assert hi is not None
            first, last = _latency_bounds(lo, hi, dt)
            require(
                first <= last,
                at,
                f"holds no whole number of control periods ({dt:g} s): [{lo!r}, {hi!r}]",
            )
            require(
                last <= max_latency_steps,
                at,
                f"the upper end must be at most {max_latency_steps} control periods, got {hi!r}",
            )


@functools.lru_cache(maxsize=64)
def _plan(block: RealismRanges, dt: float, lag: float) -> _Plan:
    """The resolved :class:`_Plan` of a ``realism`` block under control period ``dt`` with
    ``robot.lag`` ``lag`` (cached: the block is frozen, so a reset only looks it up)."""
    draws = []
    for key, (lo, hi) in _ranges(block).items():
        f = _BY_KEY[key]
        if f.kind == LINEAR:
            assert hi is not None
            draws.append(_Draw(key, f.param, _AS_IS, lo, hi - lo))
        elif f.kind == RECIPROCAL:
            small = 0.0 if hi is None else 1.0 / hi
            mode = _AS_IS if f.param == "frame_period" else _INVERSE
            draws.append(_Draw(key, f.param, mode, small, 1.0 / lo - small))
        else:
            assert hi is not None
            first, last = _latency_bounds(lo, hi, dt)
            draws.append(_Draw(key, f.param, _FLOOR, float(first), float(last - first + 1)))
    drawn = {d.param for d in draws}
    kept = tuple(f.param for f in FIELDS if f.param not in drawn)
    return _Plan(tuple(draws), kept, lag)


def max_latency_steps(cfg: ScenarioConfig) -> int:
    """The longest camera latency of ``cfg``'s episodes in control periods: the scenario's,
    or the upper end of its ``realism`` latency range (the core's frame ring holds this many)."""
    rng = ranges_of(cfg).get("camera.latency")
    if rng is None or rng[1] is None:
        return latency_steps(cfg)
    return _latency_bounds(rng[0], rng[1], cfg.simulation.control_period)[1]


def drawn_keys(cfg: ScenarioConfig) -> tuple[str, ...]:
    """The keys of the fields ``cfg`` draws, in draw order (empty without ``realism``)."""
    return tuple(ranges_of(cfg))


def draw_realism(p: np.void, cfg: ScenarioConfig, rng: np.random.Generator) -> dict[str, float]:
    """Draw an episode's realism into its params record ``p`` (a :data:`PARAMS_DTYPE` record,
    written in place) from ``rng``, and return what was drawn, ``{field key: value}`` in the
    schema's units (:func:`reported_value`).

    Without a ``realism`` block: nothing is drawn or written, and the result is empty. With
    one: one call ``rng.random(K)``; each drawn field is written to its params field, and the
    flags that switch the perception and actuator stages on (``random_perception``,
    ``perceive``, ``actuate``) are set by :func:`~platoon_env.config.stage_flags`, as
    :func:`platoon_env.core.params_of` sets them from a config holding the drawn values.
    """
    block = cfg.realism
    if block is None:
        return {}
    dt = cfg.simulation.control_period
    plan = _plan(block, dt, cfg.robot.lag)
    values = {name: float(p[name]) for name in plan.kept}
    drawn = DrawnRealism()
    for (key, param, mode, a, b), u in zip(
        plan.draws, rng.random(len(plan.draws)).tolist(), strict=True
    ):
        x = a + b * u
        if mode == _FLOOR:
            x = float(min(a + b - 1.0, math.floor(x)))
        elif mode == _INVERSE:
            x = math.inf if x <= 0.0 else 1.0 / x
        values[param] = x
        p[param] = x
        drawn[key] = reported_value(key, x, dt)
    schema = {f.key: _schema_value(f, values[f.param], dt) for f in FIELDS}
    p["random_perception"], p["perceive"], p["actuate"] = stage_flags(schema, plan.lag)
    return drawn


def _schema_value(f: RealismField, raw: float, dt: float) -> float | None:
    """The value of field ``f`` in the schema's units, as :func:`~platoon_env.config.stage_flags`
    reads it, from its params field ``raw``: the frame rate [Hz] of a frame period (None: a
    frame every control step, period 0), the latency [s] of whole control periods ``dt``, an
    acceleration limit (None: no bound, ``inf``), the other fields as written."""
    if f.kind == RECIPROCAL:
        if f.param == "frame_period":
            return 1.0 / raw if raw > 0 else None
        return raw if raw < math.inf else None
    if f.kind == LATENCY:
        return raw * dt
    return raw


def reported_value(key: str, raw: float, dt: float) -> float:
    """The value that field ``key``'s params field ``raw`` stands for, in the schema's units:
    the noise standard deviations, ``detection`` and ``detection_edge`` as written;
    ``camera.frame_rate`` the rate the camera runs at [Hz], ``1 / max(frame period, dt)`` (a
    drawn rate above ``1 / dt`` is a frame every control step, reported as ``1 / dt``);
    ``camera.latency`` [s], whole control periods ``dt``; the acceleration limits as bounds
    (``inf``: none, only for the draw ``u = 0`` of a range up to null)."""
    if key == "camera.frame_rate":
        return 1.0 / max(raw, dt)
    if key == "camera.latency":
        return raw * dt
    return raw


def reported_values(params: np.ndarray, keys: tuple[str, ...], dt: float) -> np.ndarray:
    """``(B, K)`` float64: :func:`reported_value` of each field of ``keys`` in each of the envs'
    params records ``params`` ``(B,)``."""
    out = np.empty((params.shape[0], len(keys)))
    for k, key in enumerate(keys):
        column = params[_BY_KEY[key].param].tolist()
        out[:, k] = [reported_value(key, float(raw), dt) for raw in column]
    return out


def realism_table(params: np.ndarray, cfg: ScenarioConfig) -> tuple[tuple[str, ...], np.ndarray]:
    """``(keys, values (B, K))``: the drawn fields of ``cfg`` and their values in each env's
    params record (:func:`reported_values`)."""
    keys = drawn_keys(cfg)
    return keys, reported_values(params, keys, cfg.simulation.control_period)


class DrawnRealism(dict[str, float]):
    """An episode's drawn realism, ``{field key: value}`` (:func:`draw_realism`), which also
    builds its numeric view once (:meth:`numeric`)."""

    _numeric: dict[str, np.float64] | None = None

    def numeric(self) -> dict[str, np.float64]:
        """The flat form of the numeric info view: ``{"realism." + key: numpy float64}`` (the
        view's values are numpy scalars and never nested, for TorchRL); built once."""
        if self._numeric is None:
            self._numeric = {f"realism.{k}": np.float64(v) for k, v in self.items()}
        return self._numeric


def add_realism_info(
    infos: dict[str, dict[str, Any]], drawn: dict[str, float], numeric: bool = False
) -> None:
    """Put ``drawn`` (an env's :attr:`~platoon_env.core.PlatoonCore.realism`) into every
    agent's info: as ``info[agent]["realism"]`` (one dict, shared: read it, do not change it),
    or with ``numeric`` (the numeric info view) flat, one ``"realism.<key>"`` float64 per
    field; nothing when it is empty (no ``realism`` block)."""
    if not drawn:
        return
    if numeric:
        flat = drawn.numeric() if isinstance(drawn, DrawnRealism) else DrawnRealism(drawn).numeric()
        for info in infos.values():
            info.update(flat)
    else:
        for info in infos.values():
            info["realism"] = drawn


__all__ = [
    "FIELDS",
    "REALISM_PRESETS",
    "DrawnRealism",
    "RealismField",
    "add_realism_info",
    "check_realism_ranges",
    "draw_realism",
    "drawn_keys",
    "list_presets",
    "max_latency_steps",
    "ranges_of",
    "realism_table",
    "reported_value",
    "reported_values",
]
