"""The privileged oracle (:mod:`baselines.oracle`) and the fence around it.

* The privilege does not leak: every non-privileged policy of the registry runs on an env whose
  ground-truth attributes raise when read; only the oracle needs them (and refuses such an env).
* The oracle is deterministic for a seed, the same in the single env and as a copy of the
  batched evaluator, and registered as privileged.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import platoon_env
from baselines.filtered_ppc_drive import DriveAwareFilteredPPCPolicy
from baselines.oracle import BASE_LAWS, OracleParams, OraclePolicy
from experiments.batched_eval import run_cells
from experiments.grid import Cell, resolve_cells, run_cell
from experiments.policies import REGISTRY, PolicySpec, build_policy

#: What a policy acting on its sensors must never read: the env's ground truth.
GROUND_TRUTH = frozenset(
    {
        "poses",
        "sensed",
        "state",
        "snapshot",
        "restore",
        "applied_velocities",
        "violation_masks",
        "leader_velocity",
        "leader_speed_factor",
        "leader_arrived",
        "_core",
    }
)

#: A small oracle, so that the tests run in seconds.
SMALL = {"samples": 4, "horizon": 3, "knot": 5, "iterations": 1}


class GroundTruthRead(AttributeError):
    """A policy reached for the env's ground truth."""


class GroundTruthGuard:
    """``env`` as a policy may see it: everything but :data:`GROUND_TRUTH`, which raises (an
    ``AttributeError``, as an env without it would) and is recorded in :attr:`reads` (so that a
    policy that swallows the error, ``getattr(env, "poses", None)``, is caught too)."""

    def __init__(self, env: Any) -> None:
        object.__setattr__(self, "_env", env)
        object.__setattr__(self, "reads", [])

    def __getattr__(self, name: str) -> Any:
        if name in GROUND_TRUTH:
            object.__getattribute__(self, "reads").append(name)
            raise GroundTruthRead(f"a policy read the env's ground truth {name!r}")
        return getattr(object.__getattribute__(self, "_env"), name)


def _drive(env: Any, policy: Any, seed: int, steps: int) -> int:
    obs, _ = env.reset(seed=seed)
    policy.reset(seed=seed)
    for k in range(steps):
        obs, _, term, trunc, _ = env.step(policy.act(obs))
        if any(term.values()) or any(trunc.values()):
            return k + 1
    return steps


@pytest.mark.parametrize("name", sorted(k for k, v in REGISTRY.items() if not v.privileged))
@pytest.mark.parametrize("scenario", ["study_b", "study_c"])
def test_sensor_policies_never_read_ground_truth(name: str, scenario: str) -> None:
    env = platoon_env.make(scenario, sensor_profile="aruco")
    guard = GroundTruthGuard(env)
    policy = build_policy(PolicySpec.of(name), guard)
    assert _drive(env, policy, seed=1, steps=60) > 10
    assert guard.reads == []


def test_the_oracle_is_the_registry_s_only_privileged_policy_and_needs_the_truth() -> None:
    assert [k for k, v in REGISTRY.items() if v.privileged] == ["oracle"]
    assert "privileged" in REGISTRY["oracle"].label
    assert not REGISTRY["oracle"].studies  # no driver runs it among the comparisons
    env = platoon_env.make("study_c")
    guard = GroundTruthGuard(env)
    with pytest.raises(ValueError, match="true state"):
        OraclePolicy(guard)
    assert guard.reads == ["snapshot"]


def test_oracle_params_are_checked() -> None:
    with pytest.raises(ValueError, match="samples"):
        OracleParams(samples=0)
    with pytest.raises(ValueError, match="replan"):
        OracleParams(horizon=2, replan=3)
    with pytest.raises(TypeError, match="knot"):
        OracleParams(knot="5")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        OracleParams(unknown=1)  # type: ignore[call-arg]


def _commands(seed: int) -> list[np.ndarray]:
    env = platoon_env.make("study_c", sensor_profile="aruco")
    policy = OraclePolicy(env, **SMALL)
    obs, _ = env.reset(seed=seed)
    policy.reset(seed=seed)
    out = []
    for _ in range(25):
        cmd = policy.act(obs)
        out.append(np.stack([cmd[a] for a in env.agents]))
        obs, *_ = env.step(cmd)
    assert policy.plans == 5 and policy.model_steps > 0
    return out


def test_oracle_is_deterministic_for_a_seed() -> None:
    a, b = _commands(3), _commands(3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_oracle_keeps_the_platoon_safe_where_it_starts() -> None:
    """Over its first seconds on study C the oracle's true plan commits no violation."""
    env = platoon_env.make("study_c")
    policy = OraclePolicy(env, samples=8, horizon=10, knot=10, iterations=1)
    assert _drive(env, policy, seed=0, steps=300) == 300
    assert not env.violation_masks.any()


def test_oracle_as_a_batched_copy_matches_the_single_env() -> None:
    """As a copy of the batched evaluator (``CopyView.snapshot``) the oracle plans from its own
    copy's state: the same metrics, to the bit, as ``run_cell``."""
    spec = PolicySpec.of("oracle", **SMALL)
    cells = resolve_cells([Cell.of(spec, "study_c", s, {"max_episode_steps": 30}) for s in (0, 1)])
    single = [run_cell(rc) for rc in cells]
    batched = run_cells(cells)
    for one, many in zip(single, batched, strict=True):
        assert one.status == many.status == "done", (one.error, many.error)
        assert one.metrics == many.metrics
    assert single[0].metrics != single[1].metrics


def test_oracle_base_is_checked() -> None:
    with pytest.raises(ValueError, match="base"):
        OracleParams(base="no_such_law")
    assert OracleParams().base in BASE_LAWS
    assert set(BASE_LAWS) <= set(REGISTRY)  # the names a guided oracle takes are laws' names


def test_guided_oracle_is_its_law_wherever_the_law_is_safe() -> None:
    """Where the exact model shows the base law safe over the horizon, the guided oracle sends
    the law's own commands, to the bit, and never searches."""
    env = platoon_env.make("study_c", sensor_profile="aruco")
    twin = platoon_env.make("study_c", sensor_profile="aruco")
    oracle = OraclePolicy(env, samples=4, horizon=10, knot=5, iterations=1)
    law = DriveAwareFilteredPPCPolicy(twin)
    obs, _ = env.reset(seed=2)
    obs_twin, _ = twin.reset(seed=2)
    oracle.reset(seed=2)
    law.reset(seed=2)
    for _ in range(200):
        a, b = oracle.act(obs), law.act(obs_twin)
        assert a.keys() == b.keys()
        assert all(np.array_equal(a[k], b[k]) for k in a)
        obs, *_ = env.step(a)
        obs_twin, *_ = twin.step(b)
    assert oracle.plans == 40 and oracle.searches == 0


class _Halt:
    """A base law that stops every follower: the leader drives out of their range."""

    def __init__(self, env: Any) -> None:
        self.agents = list(env.possible_agents)

    def reset(self, seed: int | None = None) -> None:
        pass

    def act(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {a: np.zeros(2, dtype=np.float32) for a in observations}


def test_guided_oracle_corrects_a_law_it_sees_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A base law that would lose the leader (it stops) is corrected as soon as the model
    shows the failure within the horizon: the oracle searches, and keeps the platoon in range
    for longer than the law alone does."""
    monkeypatch.setitem(BASE_LAWS, "ppc", _Halt)
    params = {"base": "ppc", "samples": 16, "horizon": 10, "knot": 10, "iterations": 2}
    alone = platoon_env.make("study_c")
    steps_alone = _drive(alone, _Halt(alone), seed=0, steps=1500)
    assert steps_alone < 1500  # the law alone fails
    env = platoon_env.make("study_c")
    oracle = OraclePolicy(env, **params)
    steps = _drive(env, oracle, seed=0, steps=1500)
    assert oracle.searches > 0
    assert steps > steps_alone + 100
