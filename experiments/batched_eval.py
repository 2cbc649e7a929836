"""The batched evaluator: one policy's episodes on one task, run as copies of the batched core.

:func:`experiments.grid.run_cell` runs one episode: a ``platoon_env.make`` env, the cell's
policy, :func:`platoon_env.rollout.run_episode`, the cell's measure. :func:`run_cells` runs a
**chunk** of cells that differ only in their seed (the same policy, scenario, ``make()``
keywords and measure; :func:`batch_key`) as the ``B`` copies of one
:class:`~platoon_env.batched.BatchedPlatoon`: one compiled call steps every copy whose episode
goes on (``BatchedPlatoon.step(..., envs=...)``; a copy whose episode ended is no longer
stepped), and each copy's episode is recorded by :class:`~platoon_env.rollout.EpisodeRecorder`
exactly as ``run_episode`` records it. The returned :class:`~experiments.grid.CellResult` of
each cell has the metrics ``run_cell`` gives for it, to the bit (``tests/test_batched_eval.py``),
and the same statuses: a policy constructor raising ``ValueError`` is ``refused``, any other
error ``failed`` with its traceback. Errors are the copy's own where they can be told apart (its
env or policy construction, its reset, its ``act``, its actions, its measure); an error of the
shared step fails every cell still running in the chunk. The wall time of the chunk is shared
evenly among its cells.

**One policy per copy.** Policies are stateful (PPC's funnels, the filters, a residual
policy's law), so every copy has its own, built by :func:`~experiments.policies.build_policy`
on a copy view (:meth:`~platoon_env.batched.BatchedPlatoon.copy_view`): copy ``b`` of the
core seen as the env ``run_cell`` gives the policy. It
answers what changes with an episode (the scenario: a procedural layout drawn by the copy's
seed; the agents, the step limit, the state, the RNG) from the core's copy ``b`` and everything
else (the spaces, the source, the control period, ...) from one ``platoon_env.make`` env of the
cell's, made once per chunk and never reset, so a policy reads at construction and at its reset
what it reads in ``run_cell`` (a residual policy builds its law on the episode's layout at
reset). A model's files are read and loaded once per chunk (:func:`~experiments.policies.
load_model`, checked against the planned fingerprint) and every copy gets a deep copy of the
fresh policy.

**Falling back.** :func:`chunk_cells` leaves in chunks of one (run by ``run_cell``) the cells
the batched core cannot take: ``make()`` keywords that are no scenario override
(``render_mode``, ``diagnostics``, ``info_view``), cells recording their policy's signals
(``record_signals``) or whose episode is kept (``keep``); :func:`run_cells` falls back to
``run_cell`` for a scenario that draws its formation size (``generator.formation.followers`` a
range).

**The vectorised hook** (optional, for learned models). A policy class may define a classmethod
``act_group(policies, observations)``: ``policies`` a sequence of instances of that class (one
per live copy, in copy order) and ``observations`` the matching sequence of ``{agent: obs}``
dicts (what each instance's ``act`` would be given); it returns a list of ``{agent: action}``
dicts, one per instance, equal to what each ``act`` would return, and must update each
instance's state as its ``act`` would (e.g. one batched network call for all copies instead of
one per copy). When the class of the chunk's policies defines it, it is called once per step
for all live copies instead of each policy's ``act``; an error in it fails every cell it acted
for.
"""

from __future__ import annotations

import copy
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from experiments.cells import (
    CellResult,
    ResolvedCell,
    check_planned_scenario,
    measure_of,
    plain_metrics,
    run_cell,
)
from experiments.policies import MODEL, build_policy, load_model
from platoon_env.env import read_actions
from platoon_env.rollout import EpisodeRecorder
from platoon_env.scenarios.fingerprint import canonical_json
from platoon_env.scenarios.options import OVERRIDE_OPTIONS

__all__ = ["batch_key", "chunk_cells", "run_cells"]


def batch_key(rc: ResolvedCell) -> tuple[Any, ...] | None:
    """What cells must share to run as copies of one batched core (policy, scenario, ``make()``
    keywords, measure; not the seed), or None for a cell that only :func:`run_cell` runs:
    keywords the batched core does not take (anything but the scenario overrides,
    :data:`~platoon_env.scenarios.options.OVERRIDE_OPTIONS`), ``record_signals``, or keywords
    contradicting the policy's (``run_cell`` reports that)."""
    cell = rc.cell
    if cell.record_signals:
        return None
    try:
        kwargs = cell.make_kwargs()
    except ValueError:
        return None
    if any(v is not None and k not in OVERRIDE_OPTIONS for k, v in kwargs.items()):
        return None
    return (
        cell.policy,
        rc.key.policy,
        cell.scenario,
        rc.key.scenario,
        canonical_json(kwargs),
        cell.measure,
    )


def chunk_cells(
    cells: Sequence[ResolvedCell], size: int, keep: Callable[[Any], bool] | None = None
) -> list[list[ResolvedCell]]:
    """``cells`` in chunks for :func:`run_cells`: the cells of one :func:`batch_key` in chunks of
    at most ``size`` (in their order; a key's chunks where its first cell is), every other cell
    (no key, or ``keep(cell)`` true: its episode is returned, which ``run_cell`` does) alone."""
    keep = keep or (lambda cell: False)
    groups: dict[Any, list[list[ResolvedCell]]] = {}
    out: list[list[ResolvedCell]] = []
    for rc in cells:
        key = None if keep(rc.cell) else batch_key(rc)
        if key is None or size <= 1:
            out.append([rc])
            continue
        chunks = groups.get(key)
        if chunks is None or len(chunks[-1]) >= size:
            chunk: list[ResolvedCell] = []
            out.append(chunk)
            groups.setdefault(key, []).append(chunk)
            chunk.append(rc)
        else:
            chunks[-1].append(rc)
    return out


def _refused(exc: ValueError) -> str:
    return f"{type(exc).__name__}: {exc}"


class _Copy:
    """One cell of a chunk: its env (for building and resetting its policy), its policy, its
    recorder, its result once known."""

    def __init__(self, index: int, rc: ResolvedCell) -> None:
        self.index = index
        self.rc = rc
        self.env: Any = None
        self.policy: Any = None
        self.recorder: EpisodeRecorder | None = None
        self.obs: dict[str, np.ndarray] = {}
        self.status = ""
        self.metrics: dict[str, Any] = {}
        self.error = ""

    def fail(self, error: str | None = None) -> None:
        self.status = "failed"
        self.error = traceback.format_exc(limit=20) if error is None else error
        self.recorder = None


def run_cells(cells: Sequence[ResolvedCell]) -> list[CellResult]:
    """Run ``cells`` (one :func:`batch_key`, differing in seed) as copies of one batched core;
    one :class:`~experiments.grid.CellResult` per cell, in order, with ``run_cell``'s metrics
    and statuses (see the module doc). One cell, or a formation of drawn size, runs through
    ``run_cell``; cells of different keys are a ``ValueError``."""
    chunk = list(cells)
    if not chunk:
        return []
    keys = {batch_key(rc) for rc in chunk}
    if None in keys or len(keys) > 1:
        raise ValueError(
            "run_cells() needs cells of one policy, scenario, make() keywords and measure that "
            "the batched core can run (see chunk_cells)"
        )
    if len(chunk) == 1:
        return [run_cell(chunk[0])]
    start = time.perf_counter()
    copies = [_Copy(b, rc) for b, rc in enumerate(chunk)]
    try:
        done = _run_chunk(copies)
    except Exception:  # the chunk's own set-up failed: every cell fails with it
        error = traceback.format_exc(limit=20)
        for c in copies:
            if not c.status:
                c.fail(error)
        done = True
    if not done:
        return [run_cell(rc) for rc in chunk]
    share = (time.perf_counter() - start) / len(chunk)
    return [CellResult(c.status, c.metrics, c.error, share) for c in copies]


def _run_chunk(copies: list[_Copy]) -> bool:
    """Build, run and measure the chunk's copies (their status, metrics and error are set);
    False when the chunk must run through ``run_cell`` instead (a drawn formation size)."""
    import platoon_env
    from platoon_env.batched import BatchedPlatoon

    first = copies[0].rc
    spec = first.cell.policy
    if spec.kind == MODEL:
        import torch

        torch.set_num_threads(1)
    kwargs = first.cell.make_kwargs()
    core = BatchedPlatoon(first.cell.scenario, batch_size=len(copies), **kwargs)
    check_planned_scenario(first, core.source.config)
    if core.variable_followers:
        return False
    measure = measure_of(first.cell.measure)

    # A model's files, read and loaded once (every copy gets a deep copy of the fresh policy).
    template: Any = None
    if spec.kind == MODEL:
        try:
            template = load_model(spec, first.key.policy)
        except ValueError as exc:
            for c in copies:
                c.status, c.error = "refused", _refused(exc)
            return True
        except Exception:
            error = traceback.format_exc(limit=20)
            for c in copies:
                c.fail(error)
            return True

    # The episodes start (as run_cell: the env's reset, the policy built on the episode's own
    # scenario, then the policy's reset), every copy the model did not refuse.
    live = [c for c in copies if not c.status]
    if not live:
        return True
    obs = core.reset([c.rc.cell.seed for c in live], envs=[c.index for c in live])
    env = platoon_env.make(first.cell.scenario, **kwargs)
    for c in live:
        try:
            c.env = core.copy_view(c.index, env)
            loaded = None if template is None else copy.deepcopy(template)
            try:
                c.policy = build_policy(spec, c.env, planned=c.rc.key.policy, loaded=loaded)
            except ValueError as exc:
                c.status, c.error = "refused", _refused(exc)
        except Exception:
            c.fail()
    live = [c for c in live if not c.status]
    if not live:
        return True
    agents = tuple(core.possible_agents)
    sim_time, poses, sensed = core.sim_time, core.poses, core.sensed
    for c in live:
        b = c.index
        c.env.start()
        try:
            c.policy.reset(seed=c.rc.cell.seed)
        except Exception:
            c.fail()
            continue
        space = c.env.action_space(c.env.possible_agents[0])
        c.recorder = EpisodeRecorder(
            agents, space.low, space.high, float(sim_time[b]), poses[b], sensed[b]
        )
        c.obs = dict(zip(agents, obs[b], strict=True))
    live = [c for c in live if not c.status]
    limits = core.step_limits
    _loop(core, live, agents, limits, measure)
    return True


def _act(live: list[_Copy]) -> list[dict[str, Any] | None]:
    """Each live copy's commands (None: its policy raised; the copy is failed): one
    ``act_group`` call per policy class that defines it, else each policy's ``act``."""
    out: list[dict[str, Any] | None] = [None] * len(live)
    by_class: dict[type, list[int]] = {}
    for k, c in enumerate(live):
        by_class.setdefault(type(c.policy), []).append(k)
    for cls, members in by_class.items():
        group = getattr(cls, "act_group", None)
        if group is None:
            for k in members:
                c = live[k]
                try:
                    out[k] = c.policy.act(c.obs)
                except Exception:
                    c.fail()
            continue
        try:
            cmds = list(group([live[k].policy for k in members], [live[k].obs for k in members]))
            if len(cmds) != len(members):
                raise ValueError(
                    f"{cls.__name__}.act_group returned {len(cmds)} action dicts for "
                    f"{len(members)} policies"
                )
        except Exception:
            error = traceback.format_exc(limit=20)
            for k in members:
                live[k].fail(error)
            continue
        for k, cmd in zip(members, cmds, strict=True):
            out[k] = cmd
    return out


def _check_finite(rows: np.ndarray, agents: tuple[str, ...]) -> None:
    """A ``ValueError`` (the env's) for NaN or inf in one copy's actions ``(N, 2)``."""
    finite = np.isfinite(rows).all(axis=1)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise ValueError(f"action of {agents[i]!r} contains NaN or inf: {rows[i].tolist()}")


def _loop(
    core: Any,
    live: list[_Copy],
    agents: tuple[str, ...],
    limits: np.ndarray,
    measure: Callable[[Any], Any],
) -> None:
    """Step the live copies until every episode ended (as ``run_episode``'s loop: the env's end,
    or its step limit), measuring each copy when its episode ends."""
    actions = np.zeros((core.batch_size, len(agents), 2))
    active = np.zeros(core.batch_size, dtype=bool)
    for c in live:
        active[c.index] = True
    step = 0
    while live:
        cmds = _act(live)
        stepped: list[tuple[_Copy, dict[str, Any]]] = []
        for c, cmd in zip(live, cmds, strict=True):
            if cmd is None:
                active[c.index] = False
                continue
            try:
                actions[c.index] = read_actions(cmd, agents)
            except Exception:
                c.fail()
                active[c.index] = False
                continue
            stepped.append((c, cmd))
        if not np.isfinite(actions).all():  # the env refuses these (only live rows are set)
            kept = []
            for c, cmd in stepped:
                try:
                    _check_finite(actions[c.index], agents)
                    kept.append((c, cmd))
                except ValueError:
                    c.fail()
                    active[c.index] = False
                    actions[c.index] = 0.0
            stepped = kept
        if not stepped:
            return
        try:
            obs, _, terminated, truncated, info = core.step(actions, envs=active)
        except Exception:
            error = traceback.format_exc(limit=20)
            for c, _cmd in stepped:
                c.fail(error)
            return
        sim_time, poses, sensed = core.sim_time, core.poses, core.sensed
        masks = info["violations"]
        arrived: np.ndarray | None = None
        live = []
        for c, cmd in stepped:
            b = c.index
            rec = c.recorder
            assert rec is not None
            rec.record_step(step, cmd, masks[b], float(sim_time[b]), poses[b], sensed[b])
            if terminated[b] or truncated[b] or step + 1 >= limits[b]:
                arrived = core.leader_arrived if arrived is None else arrived
                active[b] = False
                _finish(c, core, bool(terminated[b]), bool(truncated[b]), bool(arrived[b]), measure)
            else:
                c.obs = dict(zip(agents, obs[b]))  # noqa: B905 - N rows, N agents
                live.append(c)
        step += 1


def _finish(
    c: _Copy,
    core: Any,
    terminated: bool,
    truncated: bool,
    leader_arrived: bool,
    measure: Callable[[Any], Any],
) -> None:
    """The copy's :class:`~platoon_env.rollout.Episode` and its measure (as ``run_cell``)."""
    rec = c.recorder
    assert rec is not None
    try:
        ep = rec.episode(
            c.policy,
            scenario=core.scenarios[c.index],
            seed=c.rc.cell.seed,
            control_period=c.env.control_period,
            terminated=terminated,
            truncated=truncated,
            leader_arrived=leader_arrived,
        )
        metrics = plain_metrics(measure(ep))
    except Exception:
        c.fail()
        return
    c.status, c.metrics, c.recorder = "done", metrics, None
