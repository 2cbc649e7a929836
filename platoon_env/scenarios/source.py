"""Where each episode's scenario comes from: one fixed workspace, or a procedural family.

An env holds one :class:`ScenarioSource` and asks it for the scenario of every episode, so it
needs no special case for procedural scenarios:

* :class:`FixedSource` wraps one built :class:`~platoon_env.scenarios.scenario.Scenario` (the
  paper's studies, any YAML file or dict without a ``generator`` block). :meth:`~FixedSource.sample`
  returns that scenario and never draws from the random stream, so episodes on a fixed workspace
  are unchanged by it.
* :class:`ProceduralSource` wraps a template (a config with a ``generator`` block, e.g.
  ``procedural_train``). :meth:`~ProceduralSource.sample` draws the layout number
  ``int(rng.integers(LAYOUTS_PER_SPLIT))`` from the env's stream and builds it with
  :func:`~platoon_env.scenarios.procedural.generate_scenario`.

:func:`scenario_source` turns whatever a user passes to ``make()`` (a shipped name, a YAML path,
a dict, a :class:`~platoon_env.scenarios.schema.ScenarioConfig`, a built scenario or a source)
into a source, applying ``make()``'s keyword overrides.

Typical use in an env::

    source = scenario_source(scenario, overrides)
    first = source.initial()           # shapes for spaces and buffers (not an episode draw)
    box = source.bounds                # contains every workspace the source can yield
    ...
    sc = source.sample(self.np_random)  # at each reset: this episode's scenario

Imports run one way: this module imports :mod:`~platoon_env.scenarios.procedural`,
:mod:`~platoon_env.scenarios.loader`, :mod:`~platoon_env.scenarios.options` and
:mod:`~platoon_env.scenarios.scenario`; none of them imports it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol, TypeAlias, runtime_checkable

import numpy as np

from platoon_env.config import ScenarioConfig, ScenarioError
from platoon_env.scenarios.loader import ScenarioLike, load_config
from platoon_env.scenarios.options import apply_overrides
from platoon_env.scenarios.procedural import LAYOUT_BOUNDS, LAYOUTS_PER_SPLIT, generate_scenario
from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.validate import check_ranges

__all__ = [
    "FixedSource",
    "ProceduralSource",
    "ScenarioSource",
    "SourceLike",
    "scenario_source",
]

#: ``(xmin, ymin, xmax, ymax)`` [m].
Bounds: TypeAlias = tuple[float, float, float, float]


@runtime_checkable
class ScenarioSource(Protocol):
    """What an env needs to know about the scenarios of its episodes.

    Implemented by :class:`FixedSource` and :class:`ProceduralSource`; any object with these
    members can be passed where a scenario is expected.
    """

    @property
    def config(self) -> ScenarioConfig:
        """The template config: robots, sensors, safety, formation, PPC, simulation, reward.

        Every scenario the source yields has these parameters; only the workspace and the
        leader's path may differ, and with ``generator.formation`` the drawn formation
        (followers, radius, distances, camera, leader speed) (a fixed source: the config of
        its one scenario).
        """
        ...

    @property
    def bounds(self) -> Bounds:
        """``(xmin, ymin, xmax, ymax)`` [m]: a box containing every workspace it can yield."""
        ...

    @property
    def procedural(self) -> bool:
        """Whether episodes may run on different workspaces (a new layout per episode)."""
        ...

    # Optional: ``followers_range`` ``(least, most)``, the followers an episode may have (a
    # source without it: the config's ``followers`` in every episode).

    def initial(self) -> Scenario:
        """A representative scenario, without a random stream (not an episode draw).

        For what must be known before the first reset: spaces, buffers, the number of
        followers. The first episode's scenario comes from :meth:`sample`.
        """
        ...

    def sample(self, rng: np.random.Generator) -> Scenario:
        """The scenario of the next episode, drawing (if at all) from ``rng``."""
        ...


class FixedSource:
    """One fixed workspace: every episode runs on the same :class:`Scenario`.

    :meth:`sample` never draws from the random stream. Any built scenario may be wrapped,
    including one layout of a procedural family (to pin that layout).
    """

    def __init__(self, scenario: Scenario) -> None:
        """Wrap the built ``scenario`` (``TypeError`` for anything else)."""
        if not isinstance(scenario, Scenario):
            raise TypeError(f"FixedSource needs a built Scenario, got {type(scenario).__name__}")
        self._scenario = scenario

    @property
    def scenario(self) -> Scenario:
        """The one scenario of every episode."""
        return self._scenario

    @property
    def config(self) -> ScenarioConfig:
        """The scenario's config."""
        return self._scenario.config

    @property
    def bounds(self) -> Bounds:
        """The bounding box of the scenario's free space."""
        return self._scenario.workspace.bounds

    @property
    def procedural(self) -> bool:
        """False: one workspace."""
        return False

    @property
    def followers_range(self) -> tuple[int, int]:
        """``(N, N)``: every episode has the scenario's followers."""
        n = self._scenario.config.followers
        return n, n

    def initial(self) -> Scenario:
        """The scenario (not an episode draw; :meth:`sample` returns the same)."""
        return self._scenario

    def sample(self, rng: np.random.Generator) -> Scenario:
        """The scenario; ``rng`` is not drawn from (its state is left untouched)."""
        del rng
        return self._scenario

    def __repr__(self) -> str:
        return f"FixedSource({self._scenario.name!r})"


class ProceduralSource:
    """A procedural family: a new layout of ``template.generator.split`` on every episode.

    The layouts are those of :func:`~platoon_env.scenarios.procedural.generate_scenario`; each
    lies in :data:`~platoon_env.scenarios.procedural.LAYOUT_BOUNDS` and carries its number in
    :attr:`Scenario.layout_index <platoon_env.scenarios.scenario.Scenario.layout_index>`.
    """

    def __init__(self, template: ScenarioConfig) -> None:
        """Wrap ``template``, a config with a ``generator`` block (its workspace and leader path,
        if any, are ignored).

        Raises :class:`ScenarioError` for a config without a ``generator`` block or with
        out-of-range parameters (naming the field).
        """
        if template.generator is None:
            raise ScenarioError(
                f"scenario {template.name!r} has no 'generator' block: it is a fixed workspace "
                "(use scenario_source(...) or FixedSource(build_scenario(cfg)))"
            )
        check_ranges(template)
        self._template = template
        self._initial: Scenario | None = None

    @property
    def config(self) -> ScenarioConfig:
        """The template (with its ``generator`` block)."""
        return self._template

    @property
    def bounds(self) -> Bounds:
        """:data:`~platoon_env.scenarios.procedural.LAYOUT_BOUNDS`, which holds every layout."""
        return LAYOUT_BOUNDS

    @property
    def procedural(self) -> bool:
        """True: a new workspace per episode."""
        return True

    @property
    def followers_range(self) -> tuple[int, int]:
        """``(least, most)`` followers of an episode: ``generator.formation.followers``, else
        the template's ``followers`` twice. The batched core sizes its buffers for the most
        (a maximum N with masks, ``docs/api.md``)."""
        gen = self._template.generator
        assert gen is not None
        if gen.formation is not None and gen.formation.followers is not None:
            lo, hi = gen.formation.followers
            return int(lo), int(hi)
        n = self._template.followers
        return n, n

    def layout(self, index: int) -> Scenario:
        """Layout number ``index`` (``0 <= index < LAYOUTS_PER_SPLIT``) of the template's split."""
        return generate_scenario(self._template, index)

    def initial(self) -> Scenario:
        """Layout number 0, built once and cached: for shapes, not an episode draw."""
        if self._initial is None:
            self._initial = self.layout(0)
        return self._initial

    def sample(self, rng: np.random.Generator) -> Scenario:
        """Draw ``index = int(rng.integers(LAYOUTS_PER_SPLIT))`` (one draw) and build it."""
        return self.layout(int(rng.integers(LAYOUTS_PER_SPLIT)))

    def __repr__(self) -> str:
        gen = self._template.generator
        assert gen is not None
        tier = "" if gen.tier is None else f", tier={gen.tier!r}"
        return (
            f"ProceduralSource({self._template.name!r}, kind={gen.kind!r}, split={gen.split!r}"
            f"{tier})"
        )


#: Anything :func:`scenario_source` accepts.
SourceLike: TypeAlias = ScenarioLike | ScenarioSource


def scenario_source(
    scenario: SourceLike,
    overrides: Mapping[str, Any] | None = None,
    *,
    where: str = "make()",
) -> ScenarioSource:
    """The source of the episodes' scenarios for ``scenario``, with ``overrides`` applied.

    Args:
        scenario: a shipped name (see :func:`~platoon_env.scenarios.loader.list_scenarios`), a
            YAML path, a mapping in the scenario schema, a
            :class:`~platoon_env.scenarios.schema.ScenarioConfig`, a built :class:`Scenario`,
            or a :class:`ScenarioSource`. A config or scenario with a ``generator`` block gives
            a :class:`ProceduralSource` (a built layout of one serves as its template, as
            ``make()`` has always treated it; wrap it in :class:`FixedSource` to pin that
            layout); anything else a :class:`FixedSource`.
        overrides: ``make()``'s keyword overrides (``followers``, ``control_period``, ...),
            applied by :func:`platoon_env.scenarios.options.apply_overrides`. None or empty:
            none, and a source passed in is returned as is.
        where: names the caller in the error messages of bad overrides.

    A built scenario (or a :class:`FixedSource`) whose workspace the overrides leave unchanged
    is rebuilt from its existing free space, not from its config. Raises
    :class:`ScenarioError` for an invalid or infeasible scenario and ``TypeError`` for an
    unsupported argument (or overrides on a source of another type).
    """
    fixed: Scenario | None = None  # a built scenario to rebuild (rather than from its config)
    if isinstance(scenario, Scenario):
        if not overrides and scenario.config.generator is None:
            return FixedSource(scenario)
        fixed = scenario if scenario.config.generator is None else None
        base = scenario.config
    elif isinstance(scenario, (str, Path, Mapping, ScenarioConfig)):
        base = load_config(scenario)
    elif isinstance(scenario, (FixedSource, ProceduralSource)):
        if not overrides:
            return scenario
        if isinstance(scenario, FixedSource):
            cfg = apply_overrides(scenario.config, overrides, where=where)
            return FixedSource(_rebuild(scenario.scenario, cfg))
        base = scenario.config
    elif isinstance(scenario, ScenarioSource):
        if overrides:
            raise TypeError(
                f"{where}: cannot apply overrides to a {type(scenario).__name__}; apply them "
                "when building that source"
            )
        return scenario
    else:
        raise TypeError(
            "scenario must be a name, a path, a mapping, a ScenarioConfig, a Scenario or a "
            f"ScenarioSource, got {type(scenario).__name__}"
        )
    cfg = apply_overrides(base, overrides, where=where) if overrides else base
    if cfg.generator is not None:
        return ProceduralSource(cfg)
    if fixed is not None:
        return FixedSource(_rebuild(fixed, cfg))
    return FixedSource(build_scenario(cfg))


def _rebuild(scenario: Scenario, cfg: ScenarioConfig) -> Scenario:
    """``scenario`` rebuilt with the config ``cfg`` (reusing its free space if the workspace is
    unchanged). A pinned procedural layout stays that layout: it is built as a fixed workspace
    and keeps its ``generator`` block and layout number."""
    free = scenario.free_space if cfg.workspace == scenario.config.workspace else None
    built = build_scenario(dataclasses.replace(cfg, generator=None), free_space=free)
    if cfg.generator is None:
        return built
    return dataclasses.replace(built, config=cfg, layout_index=scenario.layout_index)
