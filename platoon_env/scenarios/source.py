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
* :class:`MixtureSource` draws each episode from one of several sources, chosen uniformly (a
  name ``"a+b"``: families ``a`` and ``b``, e.g. two difficulty tiers for training).

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
from collections.abc import Mapping, Sequence
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
    "MIXTURE_SEPARATOR",
    "FixedSource",
    "MixtureSource",
    "ProceduralSource",
    "ScenarioSource",
    "SourceLike",
    "is_mixture",
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


#: The separator of a mixture's names: ``"procedural_sharp_train+procedural_paper_train"``.
MIXTURE_SEPARATOR = "+"
#: The config blocks every component of a :class:`MixtureSource` must share: the env sizes its
#: observation, buffers and camera-frame ring by the first component's, and times every
#: episode by its simulation block.
MIXTURE_SHARED = (
    "observation",
    "simulation",
    "realism",
    "camera",
    "proximity",
    "reward",
    "initial",
)


class MixtureSource:
    """Several sources, one chosen per episode: each episode first draws the component
    ``k = int(rng.integers(K))`` (uniform over the ``K`` components, one draw), then that
    component's scenario from the same stream (:meth:`ScenarioSource.sample`).

    For training on several families at once (e.g. the ``sharp`` and ``paper`` tiers, each with
    a formation drawn per layout); :func:`scenario_source` builds one from a name
    ``"a+b"`` (:data:`MIXTURE_SEPARATOR`). The components may differ in their generator (kind,
    split, tier, formation ranges), leader, robots, followers, safety and formation; the blocks
    of :data:`MIXTURE_SHARED`, which fix the env's observation layout, buffers and clock, must
    be equal (``ScenarioError`` naming the block otherwise). :attr:`config` is the first
    component's template; :attr:`followers_range` spans the components'.
    """

    def __init__(self, components: Sequence[ScenarioSource]) -> None:
        """Mix ``components`` (at least two sources; ``ValueError`` otherwise)."""
        parts = tuple(components)
        if len(parts) < 2:
            raise ValueError(f"MixtureSource needs at least two sources, got {len(parts)}")
        first = parts[0].config
        for part in parts[1:]:
            for block in MIXTURE_SHARED:
                if getattr(part.config, block) != getattr(first, block):
                    raise ScenarioError(
                        f"MixtureSource: {part.config.name!r} differs from {first.name!r} in its "
                        f"{block!r} block; the components of a mixture share "
                        f"{', '.join(MIXTURE_SHARED)}"
                    )
        self.components = parts

    @property
    def config(self) -> ScenarioConfig:
        """The first component's config (the template the env sizes itself by)."""
        return self.components[0].config

    @property
    def names(self) -> tuple[str, ...]:
        """The components' config names, in order."""
        return tuple(part.config.name for part in self.components)

    @property
    def bounds(self) -> Bounds:
        """The smallest box containing every component's bounds."""
        boxes = np.array([part.bounds for part in self.components], dtype=float)
        return (
            float(boxes[:, 0].min()),
            float(boxes[:, 1].min()),
            float(boxes[:, 2].max()),
            float(boxes[:, 3].max()),
        )

    @property
    def procedural(self) -> bool:
        """True: the workspace may change at every episode."""
        return True

    @property
    def followers_range(self) -> tuple[int, int]:
        """The least and the most followers an episode of any component may have."""
        ranges = [
            getattr(part, "followers_range", (part.config.followers, part.config.followers))
            for part in self.components
        ]
        return min(int(lo) for lo, _ in ranges), max(int(hi) for _, hi in ranges)

    def initial(self) -> Scenario:
        """The first component's representative scenario."""
        return self.components[0].initial()

    def sample(self, rng: np.random.Generator) -> Scenario:
        """Draw the component (one draw), then its scenario from ``rng``."""
        return self.components[int(rng.integers(len(self.components)))].sample(rng)

    def __repr__(self) -> str:
        return f"MixtureSource({', '.join(repr(part) for part in self.components)})"


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
            or a :class:`ScenarioSource`. A name ``"a+b"`` (shipped names or paths joined by
            :data:`MIXTURE_SEPARATOR`, not itself an existing file) gives a
            :class:`MixtureSource` of their sources, each with ``overrides``. A config or
            scenario with a ``generator`` block gives
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
    if isinstance(scenario, str) and is_mixture(scenario):
        return MixtureSource(
            [
                scenario_source(part, overrides, where=where)
                for part in scenario.split(MIXTURE_SEPARATOR)
            ]
        )
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


def is_mixture(name: str) -> bool:
    """Whether ``name`` names a mixture (``"a+b"``): it holds :data:`MIXTURE_SEPARATOR`
    between non-empty names and is not the path of an existing file."""
    parts = name.split(MIXTURE_SEPARATOR)
    return len(parts) > 1 and all(p.strip() for p in parts) and not Path(name).is_file()


def _rebuild(scenario: Scenario, cfg: ScenarioConfig) -> Scenario:
    """``scenario`` rebuilt with the config ``cfg`` (reusing its free space if the workspace is
    unchanged). A pinned procedural layout stays that layout: it is built as a fixed workspace
    and keeps its ``generator`` block and layout number."""
    free = scenario.free_space if cfg.workspace == scenario.config.workspace else None
    built = build_scenario(dataclasses.replace(cfg, generator=None), free_space=free)
    if cfg.generator is None:
        return built
    return dataclasses.replace(built, config=cfg, layout_index=scenario.layout_index)
