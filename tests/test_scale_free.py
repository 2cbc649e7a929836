"""Scale-free observations (``observation: {task_aware: true, scale_free: true}``,
:mod:`platoon_env.observation`): the 15-value layout and its bounds, the same dynamics as the
task-aware env with every length over ``d_con`` (un-scaled exactly by
:func:`~platoon_env.observation.sensor_columns`), the analytic laws acting as in the physical
layout, the batched core equal to the single env, the option refused without ``task_aware``,
the default leaving every fingerprint alone, and ``LearnedPolicy`` refusing a layout mismatch.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.observation import (
    OBS_BETA_REL,
    OBS_D_REL,
    OBS_NAMES_SCALE_FREE,
    OBS_NAMES_TASK,
    OBS_SIZE,
    OBS_SIZE_SCALE_FREE,
    OBS_VISIBLE,
    OBS_X_REL,
    OBS_Y_REL,
    observation_names,
    sensor_columns,
    task_features,
)
from platoon_env.scenarios.fingerprint import config_fingerprint
from platoon_env.scenarios.schema import ScenarioError

TASK = {"task_aware": True}
FREE = {"task_aware": True, "scale_free": True}
STUDIES = ("study_a", "study_b", "study_c")


def _pair_rollout(scenario: str, seed: int, steps: int, **kw: Any) -> list[tuple[Any, Any]]:
    """The observations of a task-aware and a scale-free env driven by the same actions."""
    plain = platoon_env.make(scenario, observation=TASK, **kw)
    free = platoon_env.make(scenario, observation=FREE, **kw)
    o1, _ = plain.reset(seed=seed)
    o2, _ = free.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [(o1, o2)]
    for _ in range(steps):
        act = {a: rng.uniform([-0.2, -1.0], [1.0, 1.0]).astype(np.float32) for a in plain.agents}
        o1, _, t1, _, _ = plain.step(act)
        o2, _, t2, _, _ = free.step(act)
        assert t1 == t2
        out.append((o1, o2))
        if not plain.agents:
            break
    return out


@pytest.mark.parametrize("scenario", STUDIES)
def test_layout_bounds_and_unscaling(scenario: str) -> None:
    env = platoon_env.make(scenario, observation=FREE)
    cfg = env.scenario.config
    assert observation_names(cfg) == OBS_NAMES_SCALE_FREE
    space = env.observation_space(env.possible_agents[0])
    assert space.shape == (OBS_SIZE_SCALE_FREE,)
    assert space.high[OBS_X_REL] == 1.0 and space.low[OBS_Y_REL] == -1.0
    assert space.low[OBS_BETA_REL] == -1.0 and space.high[OBS_D_REL] == 1.0
    d_con, beta_con = cfg.camera.range, cfg.camera.half_angle
    seen = 0
    for physical, scaled in _pair_rollout(scenario, seed=3, steps=60):
        for agent, row in scaled.items():
            assert space.contains(row), (agent, row)
            ref = physical[agent]
            back = sensor_columns(row[None], cfg)[0]
            np.testing.assert_allclose(back, ref[:OBS_SIZE], rtol=1e-6, atol=1e-6)
            # the task columns: the scale-free task features, then t_unseen as before
            np.testing.assert_array_equal(row[7:12], task_features(cfg))
            assert row[12] == ref[12]
            if row[OBS_VISIBLE] > 0:
                seen += 1
                x, y = float(ref[OBS_X_REL]), float(ref[OBS_Y_REL])
                assert row[OBS_D_REL] == pytest.approx(math.hypot(x, y) / d_con, abs=1e-6)
                assert row[OBS_BETA_REL] == pytest.approx(math.atan2(y, x) / beta_con, abs=1e-6)
            else:
                assert row[OBS_D_REL] == 0.0 and row[OBS_BETA_REL] == 0.0
    assert seen > 0


def test_scale_free_task_features_are_in_task_units() -> None:
    cfg = platoon_env.make("study_a", observation=FREE).scenario.config
    d_des, d_col, d_con, beta_con, r = task_features(cfg)
    assert d_des == pytest.approx(2.0 / 4.0) and d_col == pytest.approx(0.5 / 4.0)
    assert r == pytest.approx(0.2 / 4.0) and d_con == pytest.approx(4.0 / 5.0)
    assert beta_con == pytest.approx(0.5)


def test_realism_is_the_physical_camera_scaled() -> None:
    """Noise, dropouts and latency are drawn in metres, then scaled: the same seeded draws."""
    kw = {"sensor_profile": "aruco"}
    for physical, scaled in _pair_rollout("study_c", seed=5, steps=40, **kw):
        cfg = platoon_env.make("study_c", observation=FREE, **kw).scenario.config
        for agent, row in scaled.items():
            np.testing.assert_allclose(
                sensor_columns(row[None], cfg)[0], physical[agent][:OBS_SIZE], atol=1e-6
            )
        break


def test_needs_task_aware_and_default_keeps_fingerprints() -> None:
    with pytest.raises(ScenarioError, match=r"observation\.scale_free: needs observation"):
        platoon_env.make("study_c", observation={"scale_free": True})
    with pytest.raises(ScenarioError, match=r"observation\.scale_free: expected a boolean"):
        platoon_env.make("study_c", observation={"task_aware": True, "scale_free": 1})
    base = platoon_env.make("study_c").scenario.config
    off = platoon_env.make("study_c", observation={"scale_free": False}).scenario.config
    assert config_fingerprint(off) == config_fingerprint(base)
    on = platoon_env.make("study_c", observation=FREE).scenario.config
    assert config_fingerprint(on) != config_fingerprint(
        platoon_env.make("study_c", observation=TASK).scenario.config
    )


def test_batched_equals_single_env() -> None:
    batch = BatchedPlatoon("study_b", 3, observation=FREE)
    obs = batch.reset(seeds=[0, 1, 2])
    singles = [platoon_env.make("study_b", observation=FREE) for _ in range(3)]
    for k, env in enumerate(singles):
        o, _ = env.reset(seed=k)
        np.testing.assert_array_equal(obs[k], np.stack([o[a] for a in env.possible_agents]))
    rng = np.random.default_rng(0)
    for _ in range(20):
        act = rng.uniform([-0.2, -1.0], [1.0, 1.0], size=(3, 2, 2))
        out, _, term, trunc, _ = batch.step(act)
        for k, env in enumerate(singles):
            o, *_ = env.step({a: act[k, i] for i, a in enumerate(env.possible_agents)})
            np.testing.assert_array_equal(out[k], np.stack([o[a] for a in env.possible_agents]))
        if np.any(term | trunc):
            break


@pytest.mark.parametrize("name", ["ppc", "last_seen", "filtered_ppc"])
def test_analytic_laws_act_as_in_metres(name: str) -> None:
    from baselines import FilteredPPCPolicy, LastSeenPolicy, PPCPolicy

    laws: dict[str, Any] = {
        "ppc": PPCPolicy,
        "last_seen": LastSeenPolicy,
        "filtered_ppc": FilteredPPCPolicy,
    }
    cls = laws[name]
    plain = platoon_env.make("study_c", observation=TASK)
    free = platoon_env.make("study_c", observation=FREE)
    p1, p2 = cls(plain), cls(free)
    o1, _ = plain.reset(seed=0)
    o2, _ = free.reset(seed=0)
    p1.reset()
    p2.reset()
    for _ in range(200):
        a1, a2 = p1.act(o1), p2.act(o2)
        for agent in a1:
            np.testing.assert_allclose(a1[agent], a2[agent], rtol=1e-3, atol=1e-3)
        o1, _, term, _, _ = plain.step(a1)
        o2, *_ = free.step(a1)  # the same commands: the laws' inputs stay equal
        if not plain.agents:
            break
    assert not any(term.values())


def test_sensor_part_needs_the_config_for_scale_free_rows() -> None:
    from baselines.policy import sensor_part

    with pytest.raises(ValueError, match="scale-free"):
        sensor_part(np.zeros((2, OBS_SIZE_SCALE_FREE)), 2)


def test_learned_policy_refuses_another_layout() -> None:
    pytest.importorskip("stable_baselines3")
    from training.policies import LearnedPolicy, MLPActor

    def policy(layout: tuple[str, ...]) -> LearnedPolicy:
        n = len(layout)
        layers = [(np.zeros((2, n), np.float32), np.zeros(2, np.float32))]
        meta = {"observation_layout": list(layout), "action_layout": ["u", "omega"]}
        return LearnedPolicy(
            MLPActor(layers),
            action_range=None,
            obs_scale=None,
            control_period=0.01,
            metadata=meta,
        )

    free_env = platoon_env.make("study_c", observation=FREE)
    task_env = platoon_env.make("study_c", observation=TASK)
    free_model, task_model = policy(OBS_NAMES_SCALE_FREE), policy(OBS_NAMES_TASK)
    assert free_model.scale_free and free_model.task_aware and not task_model.scale_free
    free_model.check_env(free_env)
    with pytest.raises(ValueError, match=r"scale-free.*'scale_free': True"):
        free_model.check_env(task_env)
    with pytest.raises(ValueError, match=r"task-aware observations \(13 values\).*scale-free"):
        task_model.check_env(free_env)
