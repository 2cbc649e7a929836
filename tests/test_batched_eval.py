"""The batched evaluator (:mod:`experiments.batched_eval`) gives ``run_cell``'s results to the bit.

Every policy kind of the registry that the leaderboard runs, a plain and a residual shipped
model, on a paper study and a held-out procedural tier, ideal and aruco, several seeds whose
episodes end at different steps (violations, successes, step limits); refusals and failures
inside a chunk; the ``act_group`` hook; ``run_grid(batch=...)``; the core's partial step.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

import platoon_env
from baselines.ppc import PPCPolicy
from experiments.batched_eval import batch_key, chunk_cells, run_cells
from experiments.grid import Cell, CellResult, ResolvedCell, resolve_cells, run_cell, run_grid
from experiments.policies import REGISTRY, PolicyKind, PolicySpec, default_models_dir
from experiments.policies import shipped_models as _shipped
from experiments.store import Store
from platoon_env.batched import BatchedPlatoon

ARUCO = {"sensor_profile": "aruco"}
HELDOUT = "procedural_medium_test"


def _same(a: Any, b: Any) -> bool:
    """Exact equality of metric values (types too; NaN equals NaN, inf equals inf)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)
    return bool(a == b)


def _cells(spec: PolicySpec, scenario: str, seeds: list[int], **overrides: Any) -> list[Any]:
    return resolve_cells([Cell.of(spec, scenario, s, overrides) for s in seeds])


def _check(cells: list[ResolvedCell]) -> tuple[list[CellResult], list[CellResult]]:
    """Run ``cells`` one by one and as one chunk; assert the same statuses and metrics."""
    single = [run_cell(rc) for rc in cells]
    batched = run_cells(cells)
    assert len(batched) == len(cells)
    for rc, one, many in zip(cells, single, batched, strict=True):
        where = f"{rc.cell.policy.name} {rc.cell.scenario} seed {rc.cell.seed}"
        assert many.status == one.status, (where, one.error[-400:], many.error[-400:])
        assert _same(many.metrics, one.metrics), (where, one.metrics, many.metrics)
    return single, batched


def _model(name: str) -> PolicySpec:
    folder = default_models_dir()
    if folder is None:
        pytest.skip("no shipped models")
    specs = {s.name: s for s in _shipped(folder)}
    if name not in specs:
        pytest.skip(f"model {name} not shipped")
    return specs[name]


# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", ["ppc", "filtered_ppc", "last_seen", "ppc_tuned"])
@pytest.mark.parametrize(
    ("scenario", "overrides"),
    [("study_c", {"max_episode_steps": 250}), (HELDOUT, {**ARUCO, "max_episode_steps": 250})],
)
def test_analytic_laws_bit_identical(law: str, scenario: str, overrides: dict[str, Any]) -> None:
    _check(_cells(PolicySpec.of(law), scenario, [0, 1, 2], **overrides))


@pytest.mark.parametrize("model", ["residual_ppc_s0", "ppo_ta_aruco_s0"])
@pytest.mark.parametrize(
    ("scenario", "overrides"),
    [("study_c", {"max_episode_steps": 200}), (HELDOUT, {**ARUCO, "max_episode_steps": 450})],
)
def test_shipped_models_bit_identical(model: str, scenario: str, overrides: dict[str, Any]) -> None:
    single, _ = _check(_cells(_model(model), scenario, [0, 1, 2, 3], **overrides))
    assert all(r.status == "done" for r in single)


def test_episodes_ending_at_different_steps() -> None:
    """A violation early and step limits in one chunk (ppc under aruco on held-out layouts)."""
    single, _ = _check(_cells(PolicySpec.of("ppc"), HELDOUT, [0, 2, 3], **ARUCO,
                              max_episode_steps=800))  # fmt: skip
    steps = [r.metrics["steps"] for r in single]
    assert len(set(steps)) > 1 and min(steps) < 800
    assert any(r.metrics["violation"] for r in single)


def test_full_episodes_to_success() -> None:
    """Whole held-out episodes (each layout's own step limit) that end in success at different
    steps, with the residual model's early violations under aruco beside them."""
    single, _ = _check(_cells(PolicySpec.of("filtered_ppc"), HELDOUT, [3, 0]))
    assert all(r.metrics["success"] for r in single)
    assert single[0].metrics["steps"] != single[1].metrics["steps"]
    single, _ = _check(_cells(_model("residual_ppc_s0"), HELDOUT, [1, 2], **ARUCO))
    assert [r.metrics["success"] for r in single] == [False, False]


def test_step_limits_are_each_layouts() -> None:
    """Each copy's step limit is its layout's, as the env's truncation."""
    seeds = [0, 1, 2, 3]
    core = BatchedPlatoon(HELDOUT, batch_size=len(seeds))
    core.reset(seeds)
    limits = []
    for seed in seeds:
        env = platoon_env.make(HELDOUT)
        env.reset(seed=seed)
        limits.append(env.max_episode_steps)
    assert core.step_limits.tolist() == limits
    assert len(set(limits)) > 1


# ------------------------------------------------------------------------------------------------
class _FailsOnSeed1:
    """PPC, except that its act raises on seed 1 and gives NaN on seed 2."""

    def __init__(self, env: Any) -> None:
        self._ppc = PPCPolicy(env)
        self._seed: int | None = None

    def reset(self, seed: int | None = None) -> None:
        self._seed = seed
        self._ppc.reset(seed=seed)

    def act(self, obs: dict[str, Any]) -> dict[str, Any]:
        if self._seed == 1:
            raise RuntimeError("policy bug on seed 1")
        out = self._ppc.act(obs)
        if self._seed == 2:
            out[next(iter(out))] = np.array([math.nan, 0.0], dtype=np.float32)
        return out


class _Refusing:
    def __init__(self, env: Any) -> None:
        raise ValueError("no feasible funnel")


@pytest.fixture
def test_kinds() -> Any:
    kinds = {
        "_t_fails": PolicyKind(f"{__name__}:_FailsOnSeed1", "test"),
        "_t_refuses": PolicyKind(f"{__name__}:_Refusing", "test"),
        "_t_group": PolicyKind(f"{__name__}:_GroupPPC", "test"),
    }
    REGISTRY.update(kinds)
    yield
    for name in kinds:
        del REGISTRY[name]


def test_failures_and_refusals_in_a_chunk(test_kinds: Any) -> None:
    cells = _cells(PolicySpec.of("_t_fails"), "study_c", [0, 1, 2, 3], max_episode_steps=120)
    single, batched = _check(cells)
    assert [r.status for r in batched] == ["done", "failed", "failed", "done"]
    assert "RuntimeError: policy bug on seed 1" in batched[1].error
    assert "NaN or inf" in batched[2].error and "NaN or inf" in single[2].error
    refused = run_cells(_cells(PolicySpec.of("_t_refuses"), "study_c", [0, 1]))
    assert [r.status for r in refused] == ["refused", "refused"]
    assert (
        refused[0].error == run_cell(_cells(PolicySpec.of("_t_refuses"), "study_c", [0])[0]).error
    )


class _GroupPPC(PPCPolicy):
    """PPC with the vectorised hook: ``act_group`` acts for every live copy at once (here by
    each one's ``act``) and logs the group sizes."""

    calls: ClassVar[list[int]] = []

    @classmethod
    def act_group(
        cls, policies: list[_GroupPPC], observations: list[dict[str, Any]]
    ) -> list[dict[str, Any]]:
        cls.calls.append(len(policies))
        return [PPCPolicy.act(p, o) for p, o in zip(policies, observations, strict=True)]

    def act(self, observations: Any) -> Any:
        if _GroupPPC.calls:  # only the hook acts in a batched chunk
            raise AssertionError("act called beside act_group")
        return super().act(observations)


def test_act_group_hook(test_kinds: Any) -> None:
    spec = PolicySpec.of("_t_group")
    cells = _cells(spec, HELDOUT, [0, 2, 3], **ARUCO, max_episode_steps=300)
    _GroupPPC.calls.clear()
    single = [run_cell(rc) for rc in cells]
    _GroupPPC.calls.clear()
    batched = run_cells(cells)
    calls = list(_GroupPPC.calls)
    _GroupPPC.calls.clear()
    for one, many in zip(single, batched, strict=True):
        assert many.status == one.status == "done"
        assert _same(many.metrics, one.metrics)
    steps = sorted(r.metrics["steps"] for r in single)
    # one call per step, for the copies still running
    assert len(calls) == steps[-1]
    assert calls == sorted(calls, reverse=True) and calls[0] == 3
    assert calls.count(3) == steps[0]


# ------------------------------------------------------------------------------------------------
def test_chunks_and_fallbacks() -> None:
    ppc = PolicySpec.of("ppc")
    cells = resolve_cells(
        [Cell.of(ppc, "study_c", s) for s in range(5)]
        + [Cell.of(PolicySpec.of("last_seen"), "study_c", 0)]
        + [Cell.of(ppc, "study_c", 9, {"render_mode": "rgb_array"})]
        + [Cell.of(ppc, "study_c", 7, record_signals=True)]
    )
    assert batch_key(cells[-1]) is None and batch_key(cells[-2]) is None
    chunks = chunk_cells(cells, 2, keep=lambda cell: cell.seed == 4)
    sizes = [[rc.cell.seed for rc in c] for c in chunks]
    assert sizes == [[0, 1], [2, 3], [4], [0], [9], [7]]
    with pytest.raises(ValueError, match="batched core can run"):
        run_cells([cells[0], cells[5]])


def test_run_grid_batch_stores_the_same_records(tmp_path: Path, test_kinds: Any) -> None:
    cells = [
        Cell.of(PolicySpec.of(kind), "study_c", s, {"max_episode_steps": 80})
        for kind in ("ppc", "filtered_ppc", "_t_fails", "_t_refuses")
        for s in range(3)
    ]
    plain = run_grid(tmp_path / "a.sqlite", cells, tool="t", stamp={"t": 1}, progress=False)
    batched = run_grid(
        tmp_path / "b.sqlite", cells, tool="t", stamp={"t": 1}, progress=False, batch=2
    )
    assert plain.ran == batched.ran == len(cells)
    assert plain.records.keys() == batched.records.keys()
    for key, rec in plain.records.items():
        other = batched.records[key]
        assert (other.status, other.policy_name) == (rec.status, rec.policy_name)
        assert _same(other.metrics, rec.metrics), key
    again = run_grid(tmp_path / "b.sqlite", cells, tool="t", stamp={"t": 1}, progress=False,
                     batch=2)  # fmt: skip
    assert again.ran == 2 and again.reused == len(cells) - 2  # the failed cells run again
    with Store(tmp_path / "b.sqlite") as store:
        assert len(store.episodes([rc.key for rc in batched.cells])) == len(cells)


def test_core_steps_only_the_envs_given() -> None:
    """``step(envs=...)``: an ended env stays as it is without a reset; the others go on as
    single envs."""
    seeds = [0, 1, 2]
    core = BatchedPlatoon("study_c", batch_size=3, max_episode_steps=5)
    envs = [platoon_env.make("study_c", max_episode_steps=5) for _ in seeds]
    core.reset(seeds)
    for env, seed in zip(envs, seeds, strict=True):
        env.reset(seed=seed)
    agents = envs[0].possible_agents
    act = np.tile(np.array([0.2, 0.1]), (3, len(agents), 1))
    for _ in range(5):
        core.step(act, envs=[0, 1])
        for env in envs[:2]:
            env.step({a: act[0, i] for i, a in enumerate(agents)})
    frozen = core.poses[2].copy()
    assert core.steps.tolist() == [5, 5, 0]
    with pytest.raises(RuntimeError, match="finished"):
        core.step(act, envs=np.array([True, False, True]))
    _, _, term, trunc, _ = core.step(act, envs=np.array([False, False, True]))
    envs[2].step({a: act[2, i] for i, a in enumerate(agents)})
    np.testing.assert_array_equal(core.poses[2], envs[2].poses)
    assert not (term[2] or trunc[2]) and trunc[0] and trunc[1]
    assert not np.array_equal(core.poses[2], frozen)
    for b in (0, 1):
        np.testing.assert_array_equal(core.poses[b], envs[b].poses)
    with pytest.raises(ValueError, match="indices"):
        core.step(act, envs=[3])


def test_drivers_take_batch(capsys: pytest.CaptureFixture[str]) -> None:
    """``--batch N`` of the leaderboard and evaluate drivers (default 0), in their --help."""
    from experiments.studies import evaluate, leaderboard

    for parse in (leaderboard.parse_args, evaluate.parse_args):
        assert parse([]).batch == 0
        assert parse(["--batch", "20"]).batch == 20
        with pytest.raises(SystemExit):
            parse(["--help"])
        assert "--batch N" in capsys.readouterr().out
        with pytest.raises(SystemExit):
            parse(["--batch", "-1"])
