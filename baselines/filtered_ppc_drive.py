r"""The filtered PPC with a lookahead sized for a rate-limited drive (paper, Remark 3).

Remark 3 of "Coordination of Multiple Robotic Vehicles in Obstacle-Cluttered Environments":
the performance functions (eq. 12) meet the specifications by themselves, but "additional fine
tuning might be needed in real robot implementation to meet the actuation constraints". Under
the ``aruco`` profile's acceleration limits (2.5 m/s^2, 3.2 rad/s^2) the filtered PPC
(:mod:`baselines.filtered_ppc`) fails studies A and B: its bearing loop asks for up to 7 rad/s,
the applied ``omega`` ramps at ``alpha_max`` and keeps turning after ``beta`` has crossed zero,
and ``beta`` overshoots past ``beta_con`` (docs/frontiers.md, "What breaks whom": the limits
alone break it on both studies; without them the rest of the profile does not break study B).

:class:`DriveAwareFilteredPPCPolicy` is :class:`~baselines.filtered_ppc.FilteredPPCPolicy`
(the same filter, margins and inner law, eqs. 7 and 12-14 unchanged) with two filter options
taken from the shipped table :data:`DEFAULT_TABLE` (``baselines/data/filtered_ppc_drive.yaml``)
instead of the defaults:

* ``lookahead_rate_limited`` ``tau_r`` [s]: the lookahead ``tau = robot.lag + tau_r`` on a
  drive that delays its commands (:func:`~baselines.filtered_ppc.drive_limited`); the filtered
  PPC's own is ``robot.lag + 0.1 s``. A drive without lag or rate limits gets ``tau = 0``, as
  in the filtered PPC, so with an ideal drive the two policies' commands are the same;
* ``lookahead_predecessor`` ``phi``: the fraction of ``tau`` over which the predecessor's
  estimated velocity is extrapolated (the filtered PPC's 1). At ``phi = 0`` the law sees the
  predecessor where it is, from where the follower's own applied velocity will take it in
  ``tau``: a predictor of the follower's drive, which damps its turn (``beta`` moves by about
  ``-omega_a tau``) without cutting the predecessor's corners.

The table is written by ``python -m experiments.studies.tune_filtered``: a grid over ``tau_r``
and ``phi`` on **training layouts only** under the ``aruco`` profile, with its provenance
(command, commit, objective, every grid point's value). Options given by keyword win over the
table's (the search itself passes them).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from baselines.filtered_ppc import FilteredPPCPolicy, drive_limited
from baselines.policy import PolicyEnv

__all__ = [
    "DEFAULT_TABLE",
    "TABLE_KEYS",
    "DriveAwareFilteredPPCPolicy",
    "DriveTable",
    "DriveTableError",
    "load_drive_table",
]

#: The shipped table (package data of ``baselines.data``).
DEFAULT_TABLE: Path = Path(__file__).resolve().parent / "data" / "filtered_ppc_drive.yaml"
#: The options a table sets.
TABLE_KEYS: tuple[str, ...] = ("lookahead_rate_limited", "lookahead_predecessor")


class DriveTableError(ValueError):
    """A table that does not validate; the message names the file and the field."""


@dataclass(frozen=True)
class DriveTable:
    """A validated table: the search's ``provenance`` and the chosen ``params``
    (:data:`TABLE_KEYS`)."""

    provenance: Mapping[str, Any]
    lookahead_rate_limited: float
    lookahead_predecessor: float
    path: Path | None = None


def _check(params: Mapping[str, Any], where: str) -> dict[str, float]:
    unknown = sorted(set(params) - set(TABLE_KEYS))
    missing = sorted(set(TABLE_KEYS) - set(params))
    if unknown or missing:
        raise DriveTableError(f"{where}: expected keys {list(TABLE_KEYS)}; missing {missing}, "
                              f"unknown {unknown}")  # fmt: skip
    out = {}
    for key in TABLE_KEYS:
        value = params[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DriveTableError(f"{where}: {key} must be a number, got {value!r}")
        out[key] = float(value)
    if not (math.isfinite(out["lookahead_rate_limited"]) and out["lookahead_rate_limited"] >= 0):
        raise DriveTableError(f"{where}: lookahead_rate_limited must be finite and >= 0")
    if not 0.0 <= out["lookahead_predecessor"] <= 1.0:
        raise DriveTableError(f"{where}: lookahead_predecessor must be in [0, 1]")
    return out


@functools.lru_cache(maxsize=8)
def _load(path: Path, mtime_ns: int) -> DriveTable:
    where = str(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise DriveTableError(f"{where}: cannot read the table ({exc})") from None
    if not isinstance(data, dict) or set(data) != {"provenance", "params", "grid"}:
        raise DriveTableError(f"{where}: expected the keys provenance, params, grid")
    if not isinstance(data["params"], dict):
        raise DriveTableError(f"{where}: params must be a mapping")
    params = _check(data["params"], f"{where}: params")
    return DriveTable(dict(data["provenance"] or {}), **params, path=path)


def load_drive_table(path: str | Path | None = None) -> DriveTable:
    """The table at ``path`` (default :data:`DEFAULT_TABLE`), validated; read once per file
    version (the env copies of a training run build a law per episode)."""
    p = Path(DEFAULT_TABLE if path is None else path).resolve()
    try:
        mtime = p.stat().st_mtime_ns
    except OSError as exc:
        raise DriveTableError(f"{p}: cannot read the table ({exc})") from None
    return _load(p, mtime)


class DriveAwareFilteredPPCPolicy(FilteredPPCPolicy):
    """The filtered PPC with the table's drive lookahead (module docstring).

    ``DriveAwareFilteredPPCPolicy(env, table=None, **options)``: ``table`` a table path
    (default :data:`DEFAULT_TABLE`); ``lookahead_rate_limited`` and ``lookahead_predecessor``
    in ``options`` replace the table's; ``lookahead`` in ``options`` fixes ``tau`` outright.
    Every other option is the filtered PPC's.
    """

    def __init__(
        self,
        env: PolicyEnv,
        *,
        table: str | Path | None = None,
        dt: float | None = None,
        **options: float,
    ) -> None:
        tab = load_drive_table(table)
        tau_r = float(options.pop("lookahead_rate_limited", tab.lookahead_rate_limited))
        if not (math.isfinite(tau_r) and tau_r >= 0):
            raise ValueError(f"lookahead_rate_limited must be finite and >= 0, got {tau_r!r}")
        robot = env.scenario.config.robot
        if drive_limited(robot):  # else: no lookahead, the filtered PPC's parameters exactly
            options.setdefault("lookahead", robot.lag + tau_r)
            options.setdefault("lookahead_predecessor", tab.lookahead_predecessor)
        self.table: DriveTable = tab
        super().__init__(env, dt=dt, **options)
