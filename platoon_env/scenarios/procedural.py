"""Procedural workspaces: a fresh, seeded workspace and leader path on every reset.

A procedural scenario (one with a ``generator`` block, see
:class:`~platoon_env.scenarios.schema.GeneratorConfig`) keeps the robots, sensors, safety limits,
formation and PPC parameters of its file, and draws the workspace and the leader's path from a
numbered family of layouts; with ``generator.formation`` each layout first draws its formation
(N, r, d_col, d_des, d_con, beta_con, leader speed) from ranges (:func:`draw_formation`) and is
sized for it. :func:`generate_scenario` builds layout number ``index`` of the
template's ``split`` (and ``tier``):

* the layout's random stream is ``np.random.default_rng(layout_seed(split, index, tier))``
  and nothing else (no global state), so the same template and index always give the same
  :class:`~platoon_env.scenarios.scenario.Scenario`, bit for bit;
* the seed is ``TIER_OFFSETS[tier] + SPLIT_OFFSETS[split] + index``: untiered ``train`` uses
  the seeds ``0 .. LAYOUTS_PER_SPLIT - 1`` and untiered ``test`` the next ``LAYOUTS_PER_SPLIT``;
  each tier (``easy``, ``medium``, ``hard``) shifts both by a multiple of
  ``2 * LAYOUTS_PER_SPLIT``, so every (tier, split) pair has a block of seeds of its own
  (:func:`seed_range`): no two splits, and no two tiers, ever share a layout seed, so
  evaluation on a ``test`` split uses workspaces that were never seen in training on any
  ``train`` split.

Difficulty tiers (``generator.tier``): :data:`TIERS` maps each tier to its
:class:`~platoon_env.scenarios._layout.Difficulty`, the ranges the kinds draw from (corridor
clearances, turn magnitudes and corner radii, pillars, number of rooms, doorway widths,
obstacle counts, sizes and distances to the path). From ``easy`` to ``hard`` every one of them
moves towards the harder end; a template without a tier uses :data:`DEFAULT_DIFFICULTY`, the
ranges described below, and gives the same layouts as before tiers existed. The tiers keep
the guarantees below (clearance of the path, feasible start, the fallback), so every layout of
every tier stays solvable in principle: the leader's path keeps ``r + PATH_CLEARANCE`` from
every wall, and a follower on it sees its predecessor within ``bearing_fraction * beta_con``
(at most ``0.9 beta_con``, in ``hard``).

:class:`~platoon_env.scenarios.source.ProceduralSource` (what
:func:`~platoon_env.scenarios.source.scenario_source` returns for such a template) draws one
index per episode from the env's random stream and calls :func:`generate_scenario`;
:func:`~platoon_env.scenarios.scenario.build_scenario` and
:func:`~platoon_env.scenarios.loader.load_scenario` refuse a procedural template (it has no
single workspace). This module imports :mod:`~platoon_env.scenarios.scenario`, never the reverse.

Kinds of layout (``generator.kind``), each sampled by its own module:

``corridor`` (:mod:`~platoon_env.scenarios.corridor_layouts`)
    A corridor (the free space's outer polygon, sometimes with a small pillar as a hole) along a
    random polyline of 4-8 segments: a straight start stretch with room for the platoon
    (``followers * d_des + 1`` m), then turns of which at least one is sharp (30°-100°), and
    pieces of varying width, at least one narrow enough (clearance beyond ``r`` below the PPC's
    ``delta``) that the followers' clearance terms engage on both sides. Outer corners are
    sharp; the leader's path follows the centreline with circular arcs whose radius is at least
    ``d_des / (2 sin(0.8 beta_con))``, so that a follower on the path at chord ``d_des`` keeps
    its predecessor within ``0.8 beta_con`` of its heading. (The numbers are those of the
    untiered family; a tier has its own, :data:`TIERS`.)
``rooms`` (:mod:`~platoon_env.scenarios.room_layouts`)
    A rectangle divided into 2-4 rooms by interior walls with doorways, with 2-5 free-standing
    non-convex obstacles (L-, U-, T-shapes, irregular stars) placed off the path; the leader's
    path runs straight through each doorway and joins random waypoints with rounded corners.
``mixed``
    Each layout draws ``corridor`` or ``rooms`` (even odds) from its own random stream.

Every layout lies inside :data:`LAYOUT_BOUNDS`, its leader path is 15-40 m long (longer only when
the platoon itself needs it) and keeps a clearance of at least ``r + 0.25`` m from every wall,
and its default initial configuration is feasible: :func:`generate_scenario` resamples (from the
same stream) until :func:`~platoon_env.scenarios.scenario.build_scenario` accepts a layout, and
after a bounded number of attempts returns a straight, wide corridor that is always feasible.

This module holds the public API and the orchestration: seeds and kinds, the attempt loop, the
fallback corridor and the conversion of a sampled layout into a config. What both kinds share
(the generator's parameters, :data:`LAYOUT_BOUNDS` and :data:`PATH_CLEARANCE`, corner rounding,
fitting a layout into the bounds) is in :mod:`platoon_env.scenarios._layout`.
"""

from __future__ import annotations

import dataclasses
import numbers

import numpy as np
from shapely.geometry import box

from platoon_env.scenarios import corridor_layouts, room_layouts, sharp_layouts
from platoon_env.scenarios._layout import (
    BOUNDS_MARGIN,
    DEFAULT_DIFFICULTY,
    LAYOUT_BOUNDS,
    PATH_CLEARANCE,
    SHARP_TIERS,
    TIERS,
    Difficulty,
    Layout,
    Params,
    SharpDifficulty,
    difficulty,
)
from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.schema import (
    GENERATOR_KINDS,
    GENERATOR_TIERS,
    FreeSpaceConfig,
    GeneratorConfig,
    ScenarioConfig,
    ScenarioError,
    WorkspaceConfig,
    trajectory_mean_speed,
)
from platoon_env.scenarios.sharp_layouts import SharpParams
from platoon_env.scenarios.validate import formation_gap, formation_limits

# LAYOUT_BOUNDS, PATH_CLEARANCE, Difficulty, DEFAULT_DIFFICULTY and TIERS are defined (and
# documented) in _layout, where the kinds can reach them without importing this module; this is
# their public home.
__all__ = [
    "DEFAULT_DIFFICULTY",
    "LAYOUTS_PER_SPLIT",
    "LAYOUT_BOUNDS",
    "MAX_ATTEMPTS",
    "PATH_CLEARANCE",
    "SHARP_TIERS",
    "SPLIT_OFFSETS",
    "TIERS",
    "TIER_OFFSETS",
    "Difficulty",
    "SharpDifficulty",
    "draw_formation",
    "generate_scenario",
    "layout_kind",
    "layout_seed",
    "seed_range",
]

#: Number of distinct layouts in each split (valid indices are ``0 .. LAYOUTS_PER_SPLIT - 1``).
LAYOUTS_PER_SPLIT: int = 1_000_000
#: Layout seed = ``TIER_OFFSETS[tier] + SPLIT_OFFSETS[split] + index``: the splits of one tier
#: use disjoint seed ranges.
SPLIT_OFFSETS: dict[str, int] = {"train": 0, "test": LAYOUTS_PER_SPLIT}
#: Offset of each tier's seeds (None: untiered). Each tier's two splits fill the block of
#: ``2 * LAYOUTS_PER_SPLIT`` seeds after the previous tier's, so no seed is in two
#: (tier, split) pairs; the untiered block is the first, as it was before tiers.
TIER_OFFSETS: dict[str | None, int] = {
    None: 0,
    **{tier: 2 * LAYOUTS_PER_SPLIT * (k + 1) for k, tier in enumerate(GENERATOR_TIERS)},
}
#: Attempts at sampling a feasible layout before the straight-corridor fallback.
MAX_ATTEMPTS = 40

_COORD_DECIMALS = 4  # coordinates are rounded to 0.1 mm in the generated config


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def layout_seed(split: str, index: int, tier: str | None = None) -> int:
    """The seed of layout ``index`` of ``split`` of ``tier`` (None: untiered), that is
    ``TIER_OFFSETS[tier] + SPLIT_OFFSETS[split] + index``.

    Raises ``ValueError`` for an unknown split or tier or an index outside
    ``[0, LAYOUTS_PER_SPLIT)``.
    """
    offset = seed_range(split, tier).start
    if isinstance(index, bool) or not isinstance(index, numbers.Integral):
        raise ValueError(f"layout index must be an integer, got {index!r}")
    if not 0 <= int(index) < LAYOUTS_PER_SPLIT:
        raise ValueError(f"layout index must satisfy 0 <= index < {LAYOUTS_PER_SPLIT}, got {index}")
    return offset + int(index)


def seed_range(split: str, tier: str | None = None) -> range:
    """Every layout seed of ``split`` of ``tier`` (None: untiered): ``LAYOUTS_PER_SPLIT``
    consecutive seeds, disjoint from those of every other (tier, split) pair.

    Raises ``ValueError`` for an unknown split or tier.
    """
    if split not in SPLIT_OFFSETS:
        raise ValueError(
            f"generator.split must be one of {', '.join(SPLIT_OFFSETS)}, got {split!r}"
        )
    if tier not in TIER_OFFSETS:
        raise ValueError(
            f"generator.tier must be one of {', '.join(TIERS)} (or absent), got {tier!r}"
        )
    start = TIER_OFFSETS[tier] + SPLIT_OFFSETS[split]
    return range(start, start + LAYOUTS_PER_SPLIT)


def layout_kind(template: ScenarioConfig, index: int) -> str:
    """The kind (``"corridor"`` or ``"rooms"``) drawn for layout ``index`` of ``template``.

    For ``kind: mixed`` this is the layout's first random draw; for the other kinds it is the
    kind itself. (In the rare case that no sampled layout is feasible, the layout is the
    straight-corridor fallback whatever its kind.)
    """
    gen = _generator(template)
    rng = np.random.default_rng(layout_seed(gen.split, index, gen.tier))
    return _draw_kind(rng, gen.kind)


def generate_scenario(template: ScenarioConfig, index: int) -> Scenario:
    """Build procedural layout number ``index`` of ``template.generator.split``.

    Deterministic: the layout depends only on the split, the tier, the kind and ``index`` (and
    on the template's robot, formation, camera, PPC and leader parameters, which size it; with
    ``generator.formation`` on the formation drawn first from the layout's stream); any
    workspace or leader path already in ``template`` is ignored. The returned scenario keeps
    every other field of ``template`` (name, robots, sensors, safety, PPC, simulation,
    generator block), and its
    :attr:`~platoon_env.scenarios.scenario.Scenario.layout_index` is ``index``.
    :class:`~platoon_env.scenarios.source.ProceduralSource` draws ``index`` per episode.

    Raises ``ValueError`` for an index outside ``[0, LAYOUTS_PER_SPLIT)`` or an unknown split,
    tier or kind, and :class:`ScenarioError` only if even the straight-corridor fallback is
    infeasible for the template (e.g. a platoon too long to fit in :data:`LAYOUT_BOUNDS`).
    """
    gen = _generator(template)
    seed = layout_seed(gen.split, index, gen.tier)
    if gen.kind not in GENERATOR_KINDS:
        raise ValueError(
            f"generator.kind must be one of {', '.join(GENERATOR_KINDS)}, got {gen.kind!r}"
        )
    level = difficulty(gen.tier)
    rng = np.random.default_rng(seed)
    template, params = _formation_and_params(rng, template, level)
    kind = _draw_kind(rng, gen.kind)
    for _ in range(MAX_ATTEMPTS):
        layout = _sample(rng, kind, params)
        if layout is None:
            continue
        try:
            return _build_layout(template, layout, int(index))
        except ScenarioError:
            continue
    return _build_layout(template, _straight_corridor(params), int(index))


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _generator(template: ScenarioConfig) -> GeneratorConfig:
    return template.generator if template.generator is not None else GeneratorConfig()


def draw_formation(rng: np.random.Generator, template: ScenarioConfig) -> ScenarioConfig:
    """``template`` with a formation drawn from its ``generator.formation`` ranges
    (:class:`~platoon_env.config.FormationRanges`; ``template`` itself without them, nothing
    drawn).

    Seven draws from ``rng``, always in this order, each uniform: the number of followers
    ``N`` (an integer), ``r``, ``d_col``, ``d_des``, ``d_con``, ``beta_con`` and the leader's
    speed. The distances come from the ranges of
    :func:`~platoon_env.scenarios.validate.formation_limits`, each lower end raised to what the
    previous distance imposes (``d_col >= 2 r``, ``d_des >= d_col + g``, ``d_con >= d_des +
    g``, ``g`` = :func:`~platoon_env.scenarios.validate.formation_gap`), so the draw is
    consistent by construction: ``2 r <= d_col < d_des < d_con`` with gaps of at least ``g``.
    The proximity range follows ``d_con`` unless ``proximity.range`` is set. The ``generator``
    block is kept (the layout still names its family).
    """
    gen = _generator(template)
    if gen.formation is None:
        return template
    lim = formation_limits(template)
    gap = formation_gap(template)
    n_lo, n_hi = lim["followers"]
    n = int(rng.integers(int(n_lo), int(n_hi) + 1))
    r = float(rng.uniform(*lim["radius"]))
    d_col = float(rng.uniform(max(lim["d_col"][0], 2.0 * r), lim["d_col"][1]))
    d_des = float(rng.uniform(max(lim["d_des"][0], d_col + gap), lim["d_des"][1]))
    d_con = float(rng.uniform(max(lim["d_con"][0], d_des + gap), lim["d_con"][1]))
    beta_con = float(rng.uniform(*lim["beta_con"]))
    speed = float(rng.uniform(*lim["leader_speed"]))
    return dataclasses.replace(
        template,
        followers=n,
        robot=dataclasses.replace(template.robot, radius=r),
        safety=dataclasses.replace(template.safety, d_col=d_col),
        formation=dataclasses.replace(template.formation, d_des=d_des),
        camera=dataclasses.replace(template.camera, range=d_con, half_angle=beta_con),
        leader=dataclasses.replace(template.leader, speed=speed),
    )


def _formation_and_params(
    rng: np.random.Generator, template: ScenarioConfig, level: Difficulty | SharpDifficulty
) -> tuple[ScenarioConfig, Params | SharpParams]:
    """The layout's template (its formation drawn by :func:`draw_formation`, when the
    template has ``generator.formation``) and the layout sampler's parameters for it.

    A sharp tier refuses some robots and leaders (doors too narrow for the radius, corners too
    tight for the leader's speed: :meth:`SharpParams.from_template`); a drawn formation it
    refuses is drawn again from the same stream, up to :data:`MAX_ATTEMPTS` times (then that
    ``ScenarioError``). Without ``generator.formation`` nothing is drawn, so every existing
    family's layouts stay as they were."""
    drawn = _generator(template).formation is not None
    error: ScenarioError | None = None
    for _ in range(MAX_ATTEMPTS if drawn else 1):
        cfg = draw_formation(rng, template)
        try:
            if isinstance(level, SharpDifficulty):
                return cfg, SharpParams.from_template(cfg, level)
            return cfg, Params.from_template(cfg)
        except ScenarioError as err:
            if not drawn:
                raise
            error = err
    assert error is not None
    raise ScenarioError(
        f"generator.formation: {MAX_ATTEMPTS} drawn formations were all refused by "
        f"generator.tier {_generator(template).tier!r}; the last: {error}"
    )


def _sample(rng: np.random.Generator, kind: str, params: Params | SharpParams) -> Layout | None:
    """One layout of ``kind`` from the sampler of the family ``params`` belongs to."""
    if isinstance(params, SharpParams):
        if kind == "corridor":
            return sharp_layouts.sample_sharp_corridor(rng, params)
        return sharp_layouts.sample_sharp_rooms(rng, params)
    if kind == "corridor":
        return corridor_layouts.sample_corridor(rng, params)
    return room_layouts.sample_rooms(rng, params)


def _draw_kind(rng: np.random.Generator, kind: str) -> str:
    if kind == "mixed":
        return "corridor" if rng.random() < 0.5 else "rooms"
    return kind


def _build_layout(template: ScenarioConfig, layout: Layout, index: int) -> Scenario:
    """Build ``layout`` as a fixed scenario, then tag it as layout ``index`` of ``template``.

    :func:`~platoon_env.scenarios.scenario.build_scenario` only builds fixed configs, so the
    layout is built without the generator block; the block is put back on the returned
    scenario's config (the geometry does not depend on it), so that the layout still names its
    family and can serve as a template itself.
    """
    cfg = _layout_config(template, layout)
    built = build_scenario(dataclasses.replace(cfg, generator=None))
    return dataclasses.replace(built, config=cfg, layout_index=index)


def _layout_config(template: ScenarioConfig, layout: Layout) -> ScenarioConfig:
    """``template`` with the layout's free space and leader path (coordinates rounded)."""

    def ring(coords: object) -> tuple[tuple[float, float], ...]:
        xy = np.round(np.asarray(coords, dtype=np.float64)[:-1], _COORD_DECIMALS)
        return tuple((float(x), float(y)) for x, y in xy.tolist())

    free = layout.free_space
    workspace = WorkspaceConfig(
        free_space=FreeSpaceConfig(
            exterior=ring(free.exterior.coords),
            holes=tuple(ring(h.coords) for h in free.interiors),
        )
    )
    if layout.trajectory is not None:
        # a timed trajectory (study B's planner): times to the microsecond, poses as the path
        timed = np.column_stack(
            [
                np.round(layout.trajectory[:, 0], 6),
                np.round(layout.trajectory[:, 1:], _COORD_DECIMALS),
            ]
        )
        samples = tuple((float(t), float(x), float(y), float(th)) for t, x, y, th in timed)
        leader = dataclasses.replace(
            template.leader, path=(), trajectory=samples, speed=trajectory_mean_speed(samples)
        )
        return dataclasses.replace(template, workspace=workspace, leader=leader)
    path = np.round(layout.path, _COORD_DECIMALS)
    keep = np.ones(path.shape[0], dtype=bool)
    keep[1:] = np.any(np.diff(path, axis=0) != 0.0, axis=1)
    leader = dataclasses.replace(
        template.leader, path=tuple((float(x), float(y)) for x, y in path[keep].tolist())
    )
    return dataclasses.replace(template, workspace=workspace, leader=leader)


def _straight_corridor(p: Params | SharpParams) -> Layout:
    """The fallback: a straight corridor, ``r + 1`` m of clearance on each side, in the middle
    of :data:`LAYOUT_BOUNDS`. Feasible for any template whose platoon fits in the box."""
    bx0, by0, bx1, by1 = LAYOUT_BOUNDS
    span = bx1 - bx0 - 2.0 * BOUNDS_MARGIN
    ext = p.r + 0.5
    length = min(max(p.len_min, p.start_len + 2.0), span - 2.0 * ext)
    if length < p.start_len:
        raise ScenarioError(
            f"scenario.followers: a platoon needing a {p.start_len:g} m start stretch does not "
            f"fit in the procedural layout bounds {LAYOUT_BOUNDS}"
        )
    y = 0.5 * (by0 + by1)
    x0 = 0.5 * (bx0 + bx1) - 0.5 * length
    half = p.r + 1.0
    free = box(x0 - ext, y - half, x0 + length + ext, y + half)
    path = np.array([[x0, y], [x0 + length, y]])
    return Layout("corridor", free, path)
