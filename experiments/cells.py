"""One cell of the grid: what it is (:class:`Cell`), its key in the store once resolved
(:class:`ResolvedCell`, :func:`resolve_cells`), and one episode of it run in any process
(:func:`run_cell` → :class:`CellResult`).

The grid runner (:mod:`experiments.grid`) and the batched evaluator
(:mod:`experiments.batched_eval`) both run cells; both import them from here, and
:mod:`experiments.grid` re-exports the public names.
"""

from __future__ import annotations

import importlib
import json
import time
import traceback
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from experiments.policies import PolicySpec, build_policy
from experiments.store import EpisodeKey
from platoon_env.scenarios.fingerprint import (
    canonical_json,
    config_fingerprint,
    config_mapping,
    text_sha256,
)

__all__ = [
    "DEFAULT_MEASURE",
    "Cell",
    "CellResult",
    "ResolvedCell",
    "check_planned_scenario",
    "effective_overrides",
    "measure_of",
    "merge_overrides",
    "plain_metrics",
    "resolve_cells",
    "run_cell",
]

#: The measure of a cell unless it names another: ``platoon_env.rollout.episode_metrics``.
DEFAULT_MEASURE = "platoon_env.rollout:episode_metrics"
#: Options of ``make()`` that do not change an episode (left out of the fingerprints).
_PRESENTATION_OPTIONS = frozenset({"render_mode", "diagnostics"})


@dataclass(frozen=True)
class Cell:
    """One episode to run: ``policy`` on ``scenario`` (a shipped name or a YAML path) with
    ``overrides`` (JSON of ``platoon_env.make`` keyword arguments), from ``reset(seed)``,
    turned into metrics by ``measure`` (``"module:function"``, called with the
    :class:`~platoon_env.rollout.Episode`); ``record_signals`` keeps the policy's internal
    signals for the measure."""

    policy: PolicySpec
    scenario: str
    seed: int
    overrides: str = "{}"
    measure: str = DEFAULT_MEASURE
    record_signals: bool = False

    @classmethod
    def of(
        cls,
        policy: PolicySpec,
        scenario: str,
        seed: int,
        overrides: Mapping[str, Any] | None = None,
        **options: Any,
    ) -> Cell:
        """A cell with ``overrides`` given as a mapping (numbers canonical: a float with a whole
        value is that integer, so ``accel_max=1`` and ``accel_max=1.0`` are one cell and one
        episode in the store)."""
        canonical = canonical_json(_whole_numbers(dict(overrides or {})))
        return cls(policy, scenario, int(seed), canonical, **options)

    def make_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of ``platoon_env.make`` for this cell: the policy's own
        (:meth:`PolicySpec.env_overrides`: a model's control period and observation) and the
        cell's overrides. An override that contradicts the policy's is a ``ValueError`` naming
        both (a model evaluated at another control period than it was trained at would be
        another policy, stored under its fingerprint)."""
        return merge_overrides(self.policy, json.loads(self.overrides))


def _whole_numbers(value: Any) -> Any:
    """``value`` with every finite float of a whole value (``1.0``) as an int (``1``), inside
    mappings and lists; booleans and other values unchanged."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        return int(value)
    if isinstance(value, Mapping):
        return {k: _whole_numbers(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_whole_numbers(v) for v in value]
    return value


def merge_overrides(policy: PolicySpec, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``policy.env_overrides()`` with ``overrides`` added; a key both set to different values
    is a ``ValueError`` naming the policy, the key and both values."""
    own = policy.env_overrides()
    for key in sorted(set(own) & set(overrides)):
        if canonical_json(own[key]) != canonical_json(overrides[key]):
            raise ValueError(
                f"{key}={json.dumps(overrides[key])} contradicts policy {policy.name!r}, which "
                f"runs at {key}={json.dumps(own[key])} (what it was trained with, its "
                "model.json): leave the option out, or evaluate such models separately"
            )
    return {**own, **overrides}


@dataclass(frozen=True)
class ResolvedCell:
    """A cell with its key in the store and the resolved config behind the key."""

    cell: Cell
    key: EpisodeKey
    config: dict[str, Any] = field(repr=False)

    @property
    def names(self) -> tuple[str, str]:
        return (self.cell.policy.name, self.cell.scenario)


def effective_overrides(cell: Cell) -> dict[str, Any]:
    """The cell's overrides that change an episode (its presentation options left out): what
    its key's overrides fingerprint is made of."""
    return {k: v for k, v in json.loads(cell.overrides).items() if k not in _PRESENTATION_OPTIONS}


def resolve_cells(cells: Iterable[Cell], *, unique: bool = True) -> list[ResolvedCell]:
    """Resolve the cells (configs and fingerprints). With ``unique``, a cell whose key an
    earlier cell has is dropped (it would run the same episode); else there is one resolved
    cell per cell, in order. Bad scenarios and overrides raise the schema's errors
    (``ScenarioError``, ``TypeError``, ``OSError``) here, before anything runs."""
    from platoon_env.scenarios.loader import load_config
    from platoon_env.scenarios.options import apply_overrides

    configs: dict[tuple[str, str], tuple[str, dict[str, Any]]] = {}
    out: list[ResolvedCell] = []
    seen: set[EpisodeKey] = set()
    for cell in cells:
        kwargs = {k: v for k, v in cell.make_kwargs().items() if k not in _PRESENTATION_OPTIONS}
        cache_key = (cell.scenario, canonical_json(kwargs))
        if cache_key not in configs:
            cfg = apply_overrides(load_config(cell.scenario), kwargs, where="make()")
            configs[cache_key] = (config_fingerprint(cfg), config_mapping(cfg))
        scenario_fp, mapping = configs[cache_key]
        key = EpisodeKey(
            cell.policy.fingerprint(),
            scenario_fp,
            text_sha256(canonical_json(effective_overrides(cell))),
            cell.seed,
            cell.measure,
        )
        if unique and key in seen:
            continue
        seen.add(key)
        out.append(ResolvedCell(cell, key, mapping))
    return out


# ----------------------------------------------------------------------------------------------
# One cell, in a worker
# ----------------------------------------------------------------------------------------------


@dataclass
class CellResult:
    """What a worker returns: the status (``done``, ``failed``, ``refused``), the metrics, the
    error text, the wall time [s] and, if asked, the recorded episode."""

    status: str
    metrics: dict[str, Any]
    error: str
    wall_time: float
    episode: Any = None


def measure_of(dotted: str) -> Callable[..., Any]:
    """The function a cell's ``measure`` names (``"module:function"``)."""
    module, _, attr = dotted.partition(":")
    fn: Callable[..., Any] = getattr(importlib.import_module(module), attr)
    return fn


def _plain(value: Any) -> Any:
    """JSON-able Python values of a metrics dict (numpy scalars and arrays converted)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    item = getattr(value, "tolist", None)
    return item() if callable(item) else value


def plain_metrics(measured: Any) -> dict[str, Any]:
    """A measure's result as the store keeps it: a dict of JSON-able Python values (numpy
    scalars and arrays converted); a value JSON cannot hold raises here, not in the store."""
    metrics: dict[str, Any] = _plain(dict(measured))
    canonical_json(metrics)
    return metrics


def check_planned_scenario(resolved: ResolvedCell, config: Any) -> None:
    """A ``RuntimeError`` unless ``config`` (the env's resolved scenario config) has the
    fingerprint the cell was planned (and is keyed) with."""
    actual = config_fingerprint(config)
    if actual != resolved.key.scenario:
        raise RuntimeError(
            f"the env's resolved scenario ({actual[:12]}) is not the planned one "
            f"({resolved.key.scenario[:12]}): did {resolved.cell.scenario!r} change on disk?"
        )


def run_cell(resolved: ResolvedCell, keep: bool = False) -> CellResult:
    """Run one cell (in any process); never raises for the cell's own errors.

    A policy whose constructor raises ``ValueError`` has *refused* the configuration (a
    result); any other exception is a *failure* (retried by the next run).
    """
    import platoon_env
    from platoon_env.rollout import run_episode

    cell = resolved.cell
    start = time.perf_counter()
    try:
        if cell.policy.kind == "model":
            import torch

            torch.set_num_threads(1)
        env = platoon_env.make(cell.scenario, **cell.make_kwargs())
        check_planned_scenario(resolved, env.source.config)
        # The policy is built on the episode's own scenario: a procedural source draws its
        # layout (and may draw its formation: followers, d_des, ...) at reset. run_episode
        # resets again with the same seed, to the same episode.
        env.reset(seed=cell.seed)
        try:
            # the model's files are checked against the fingerprint the row is keyed by
            policy = build_policy(cell.policy, env, planned=resolved.key.policy)
        except ValueError as exc:
            return CellResult(
                "refused", {}, f"{type(exc).__name__}: {exc}", time.perf_counter() - start
            )
        ep = run_episode(env, policy, seed=cell.seed, record_signals=cell.record_signals or keep)
        metrics = plain_metrics(measure_of(cell.measure)(ep))
    except Exception:
        return CellResult("failed", {}, traceback.format_exc(limit=20), time.perf_counter() - start)
    return CellResult("done", metrics, "", time.perf_counter() - start, ep if keep else None)
