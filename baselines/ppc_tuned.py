r"""The paper's PPC law with gains tuned per formation (Remark 3), read from a shipped table.

Remark 3 of the paper: the performance functions (eq. 12) meet the operational specifications
by themselves, "hence simplifying the selection of the control gains k_d and k_beta", but
"additional fine tuning might be needed in real robot implementation to meet the actuation
constraints". :class:`TunedPPCPolicy` is :class:`~baselines.ppc.PPCPolicy` (the same
eqs. 7 and 10-14, the same kernel) with the seven law parameters of eqs. 12-14
(``lambda_``, ``rho_d_inf``, ``rho_beta_inf`` of eq. 12, ``k_d`` of eq. 13, ``k_beta`` of
eq. 14, ``delta`` of ``S`` and ``epsilon`` of ``Proj``, after eq. 12) taken from the table
:data:`DEFAULT_TABLE` (``baselines/data/ppc_tuned.yaml``) instead of the scenario's ``ppc``
block. Nothing of the law changes.

**Per formation.** A table row holds one formation's geometry, the values :class:`PPCParams`
takes from the scenario (``r`` = ``robot.radius``, ``d_des`` = ``formation.d_des``,
``d_col`` = ``safety.d_col``, ``d_con`` = ``camera.range``, ``beta_con`` =
``camera.half_angle``), and the parameters found for it. An env is matched to the row with
the same geometry (to :data:`MATCH_TOL`). **An env whose geometry is in no row is refused**
(a ``ValueError``, which an evaluation records as ``refused``): gains tuned for another
formation, or the scenario's own gains under the label "tuned PPC", would both misreport what
was evaluated. Use :class:`~baselines.ppc.PPCPolicy` for such a scenario, or add its formation
to the search (``python -m experiments.studies.tune_ppc --formation NAME``).

The table is written by ``python -m experiments.studies.tune_ppc`` (an Optuna search under the
``aruco`` sensor profile on training layouts only; docs/realism.md, "Tuned PPC"), with its
provenance: command, commit, objective, trials and best value per formation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from baselines.policy import PolicyEnv
from baselines.ppc import PPCParams, PPCPolicy
from platoon_env.scenarios.schema import ScenarioConfig

__all__ = [
    "DEFAULT_TABLE",
    "GEOMETRY_KEYS",
    "MATCH_TOL",
    "TUNED_KEYS",
    "FormationGains",
    "TableError",
    "TunedPPCPolicy",
    "TunedTable",
    "formation_geometry",
    "load_table",
    "table_text",
]

#: The shipped table (package data of ``baselines.data``).
DEFAULT_TABLE: Path = Path(__file__).resolve().parent / "data" / "ppc_tuned.yaml"
#: The law parameters a row sets (the :class:`PPCParams` field names of eqs. 12-14).
TUNED_KEYS: tuple[str, ...] = PPCParams.PPC_KEYS[:7]
#: The geometry that identifies a formation: the :class:`PPCParams` fields read from the
#: scenario.
GEOMETRY_KEYS: tuple[str, ...] = ("r", "d_des", "d_col", "d_con", "beta_con")
#: [m, rad] an env's geometry matches a row's when every value is within this of it.
MATCH_TOL: float = 1e-9
#: The top-level keys of a table.
_TABLE_KEYS = ("provenance", "formations")
#: The keys of a row (``followers``: the platoon size the search ran; the law is per follower,
#: so a row applies to any platoon size with its geometry).
_ROW_KEYS = ("geometry", "params", "followers", "best_value", "baseline_value", "trials")


class TableError(ValueError):
    """A tuned-gains table that does not validate; the message names the file and the field."""


def formation_geometry(config: ScenarioConfig) -> dict[str, float]:
    """The formation's geometry of a scenario (:data:`GEOMETRY_KEYS`), as PPCParams reads it."""
    probe = PPCParams.from_config(config, 1.0, **_PROBE_GAINS)
    return {key: float(getattr(probe, key)) for key in GEOMETRY_KEYS}


# Any valid gains: formation_geometry reads only the geometry of the PPCParams they build.
_PROBE_GAINS = {
    "lambda_": 1.0,
    "rho_d_inf": 1e-6,
    "rho_beta_inf": 1e-6,
    "k_d": 1.0,
    "k_beta": 1.0,
    "delta": 1.0,
    "epsilon": 0.5,
}


@dataclass(frozen=True)
class FormationGains:
    """One row: the formation ``name`` (a study), its ``geometry`` (:data:`GEOMETRY_KEYS`), the
    law parameters ``params`` (:data:`TUNED_KEYS`), and the search's record: the platoon size
    it ran (``followers``), the best objective value, the value of the scenario's own gains on
    the same episodes (``baseline_value``) and the trials run."""

    name: str
    geometry: Mapping[str, float]
    params: Mapping[str, float]
    followers: int
    best_value: float
    baseline_value: float
    trials: int

    def matches(self, geometry: Mapping[str, float]) -> bool:
        """Whether ``geometry`` is this formation's (every value within :data:`MATCH_TOL`)."""
        return all(abs(geometry[k] - self.geometry[k]) <= MATCH_TOL for k in GEOMETRY_KEYS)

    def ppc_params(self, dt: float) -> PPCParams:
        """The :class:`PPCParams` of this row at control period ``dt``."""
        return PPCParams(**self.geometry, **self.params, dt=dt)


@dataclass(frozen=True)
class TunedTable:
    """A validated table: the search's ``provenance`` and a row per formation."""

    provenance: Mapping[str, Any]
    formations: tuple[FormationGains, ...]
    path: Path | None = None

    def lookup(self, config: ScenarioConfig) -> FormationGains:
        """The row of ``config``'s formation; a ``ValueError`` naming the scenario, its
        geometry and the table's formations if there is none (see the module docstring)."""
        geometry = formation_geometry(config)
        for row in self.formations:
            if row.matches(geometry):
                return row
        known = "; ".join(f"{row.name} {dict(row.geometry)}" for row in self.formations)
        raise ValueError(
            f"tuned PPC has no gains for the formation of scenario {config.name!r} "
            f"{geometry} (table {self.path}: {known}); run PPC with the scenario's own gains "
            "(policy ppc), or add the formation to the search (python -m "
            "experiments.studies.tune_ppc --formation ...)"
        )


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise TableError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _mapping(value: Any, where: str, keys: tuple[str, ...]) -> Mapping[str, Any]:
    """``value`` as a mapping with exactly ``keys``; else a :class:`TableError` at ``where``."""
    if not isinstance(value, Mapping):
        raise TableError(f"{where}: expected a mapping, got {value!r}")
    missing = [k for k in keys if k not in value]
    unknown = sorted(str(k) for k in value if k not in keys)
    if missing:
        raise TableError(f"{where}.{missing[0]}: missing (a row needs {', '.join(keys)})")
    if unknown:
        raise TableError(f"{where}.{unknown[0]}: unknown key (expected {', '.join(keys)})")
    return value


def _row(name: str, data: Any, where: str) -> FormationGains:
    row = _mapping(data, where, _ROW_KEYS)
    geometry = {
        k: _number(v, f"{where}.geometry.{k}")
        for k, v in _mapping(row["geometry"], f"{where}.geometry", GEOMETRY_KEYS).items()
    }
    params = {
        k: _number(v, f"{where}.params.{k}")
        for k, v in _mapping(row["params"], f"{where}.params", TUNED_KEYS).items()
    }
    followers = row["followers"]
    if isinstance(followers, bool) or not isinstance(followers, int) or followers < 1:
        raise TableError(f"{where}.followers: expected an integer >= 1, got {followers!r}")
    trials = row["trials"]
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise TableError(f"{where}.trials: expected an integer >= 1, got {trials!r}")
    out = FormationGains(
        name,
        geometry,
        params,
        followers,
        _number(row["best_value"], f"{where}.best_value"),
        _number(row["baseline_value"], f"{where}.baseline_value"),
        trials,
    )
    try:  # PPCParams' own rules: gains > 0, epsilon in (0, 1), 2 rho_inf inside the sets
        out.ppc_params(dt=0.01)
    except ValueError as exc:
        raise TableError(f"{where}.params: {exc}") from None
    return out


def load_table(path: str | Path | None = None) -> TunedTable:
    """Read and validate a table (default :data:`DEFAULT_TABLE`). Any defect is a
    :class:`TableError` whose message starts with the file and the field, e.g.
    ``ppc_tuned.yaml: formations.study_b.params.k_d: expected a finite number, got 'x'``."""
    file = DEFAULT_TABLE if path is None else Path(path)
    try:
        data = yaml.safe_load(file.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise TableError(f"{file}: cannot be read as YAML ({exc})") from None
    try:
        top = _mapping(data, "table", _TABLE_KEYS)
        if not isinstance(top["provenance"], Mapping):
            raise TableError(f"provenance: expected a mapping, got {top['provenance']!r}")
        rows = top["formations"]
        if not isinstance(rows, Mapping) or not rows:
            raise TableError(f"formations: expected a non-empty mapping, got {rows!r}")
        formations = tuple(_row(str(n), d, f"formations.{n}") for n, d in rows.items())
    except TableError as exc:
        raise TableError(f"{file}: {exc}") from None
    for k, row in enumerate(formations):
        for other in formations[:k]:
            if row.matches(other.geometry):
                raise TableError(
                    f"{file}: formations.{row.name}: the geometry of formations.{other.name}"
                )
    return TunedTable(dict(top["provenance"]), formations, file)


def table_text(provenance: Mapping[str, Any], formations: Mapping[str, Mapping[str, Any]]) -> str:
    """The YAML text of a table (what :func:`load_table` reads), with a header comment."""
    body = yaml.safe_dump(
        {"provenance": dict(provenance), "formations": {k: dict(v) for k, v in formations.items()}},
        sort_keys=False,
        default_flow_style=False,
        width=100,
    )
    return (
        "# Tuned PPC gains per formation (baselines/ppc_tuned.py). Written by\n"
        "# python -m experiments.studies.tune_ppc: do not edit by hand (the provenance would\n"
        "# no longer describe the numbers); re-run the search instead.\n" + body
    )


class TunedPPCPolicy(PPCPolicy):
    """:class:`~baselines.ppc.PPCPolicy` with the tuned parameters of ``env``'s formation.

    ``TunedPPCPolicy(env)`` reads :data:`DEFAULT_TABLE` (``table=PATH`` another one), finds the
    row of the env's formation (:meth:`TunedTable.lookup`; none: ``ValueError``) and builds the
    PPC law with that row's :data:`TUNED_KEYS` over the scenario's geometry, at the env's
    control period (``dt`` overrides it, as for PPCPolicy). :attr:`formation` names the row.
    """

    def __init__(
        self, env: PolicyEnv, *, table: str | Path | None = None, dt: float | None = None
    ) -> None:
        row = load_table(table).lookup(env.scenario.config)
        self.formation: str = row.name
        super().__init__(env, dt=dt, **row.params)
