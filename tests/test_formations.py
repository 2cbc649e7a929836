"""Every formation (``generator.formation``): each layout draws N, r, d_col, d_des, d_con,
beta_con and the leader's speed from ranges; the draw is consistent by construction and
deterministic, families without the block are untouched, bad ranges are a ``ScenarioError``
naming the field, and the cores hold a maximum N with masks: inert slots stay zero, the
PettingZoo env's ``agents`` are the episode's, the batched core equals the single env, the SB3
adapters refuse a variable N and the Gymnasium ids draw one follower.
"""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.config import FORMATION_GAP, FormationRanges
from platoon_env.scenarios import load_config, scenario_source
from platoon_env.scenarios.procedural import draw_formation, generate_scenario
from platoon_env.scenarios.schema import ScenarioError
from platoon_env.scenarios.source import ProceduralSource
from platoon_env.scenarios.validate import formation_gap

TRAIN = "procedural_formations_train"
RANGES = {
    "followers": (1, 7),
    "radius": (0.15, 0.3),
    "d_col": (0.3, 0.6),
    "d_des": (1.0, 2.0),
    "d_con": (1.5, 4.0),
    "beta_con": (0.4, 0.785398),
    "leader_speed": (0.25, 0.5),
}


def _drawn(cfg: Any) -> dict[str, float]:
    return {
        "followers": cfg.followers,
        "radius": cfg.robot.radius,
        "d_col": cfg.safety.d_col,
        "d_des": cfg.formation.d_des,
        "d_con": cfg.camera.range,
        "beta_con": cfg.camera.half_angle,
        "leader_speed": cfg.leader.speed,
    }


def test_shipped_ranges_cover_the_three_studies() -> None:
    template = load_config(TRAIN)
    gen = template.generator
    assert gen is not None and gen.formation is not None
    assert {k: tuple(getattr(gen.formation, k)) for k in RANGES} == RANGES
    for study in ("study_a", "study_b", "study_c"):
        values = _drawn(load_config(study))
        for name, (lo, hi) in RANGES.items():
            if name == "leader_speed" and study == "study_b":
                continue  # a timed trajectory: its speed is derived
            assert lo <= values[name] <= hi + 1e-6, (study, name)


@pytest.mark.parametrize("name", [TRAIN, "procedural_formations_test"])
def test_every_drawn_layout_is_consistent_and_feasible(name: str) -> None:
    source = scenario_source(name)
    assert isinstance(source, ProceduralSource)
    gap = formation_gap(source.config)
    seen = set()
    for index in range(25):
        layout = source.layout(index)  # built: its start is feasible for the drawn robots
        cfg = layout.config
        values = _drawn(cfg)
        for key, (lo, hi) in RANGES.items():
            assert lo <= values[key] <= hi, (index, key)
        assert 2 * cfg.robot.radius <= cfg.safety.d_col + 1e-12
        assert cfg.safety.d_col + gap <= cfg.formation.d_des + 1e-12
        assert cfg.formation.d_des + gap <= cfg.camera.range + 1e-12
        assert layout.initial_poses.shape == (cfg.followers + 1, 3)
        seen.add(cfg.followers)
        # deterministic: the same index, the same layout and formation
        assert generate_scenario(source.config, index).config == cfg
    assert len(seen) >= 4  # N varies across layouts


def test_gap_includes_the_ppc_band() -> None:
    template = load_config(TRAIN)
    assert template.ppc is not None
    assert formation_gap(template) == pytest.approx(FORMATION_GAP + 2 * template.ppc.rho_d_inf)


def test_no_formation_block_draws_nothing() -> None:
    template = load_config("procedural_train")
    rng = np.random.default_rng(7)
    state = rng.bit_generator.state
    assert draw_formation(rng, template) is template
    assert rng.bit_generator.state == state


def _with(**ranges: Any) -> dict[str, Any]:
    return {"generator": {"formation": ranges}}


@pytest.mark.parametrize(
    ("ranges", "field"),
    [
        ({"followers": [3, 2]}, "generator.formation.followers"),  # empty
        ({"followers": [0, 3]}, "generator.formation.followers"),  # N out of range
        ({"followers": [1, 11]}, "generator.formation.followers"),
        ({"radius": [0.3, 0.2]}, "generator.formation.radius"),
        ({"radius": [-0.1, 0.2]}, "generator.formation.radius"),
        ({"d_des": [2.0, 1.0]}, "generator.formation.d_des"),
        ({"beta_con": [0.4, 1.6]}, "generator.formation.beta_con"),
        ({"beta_con": [0.1, 0.5]}, "generator.formation.beta_con"),  # under 2 rho_beta_inf
        ({"leader_speed": [0.0, 0.5]}, "generator.formation.leader_speed"),
        # inconsistent (the error names the range that bounds the emptied one from above):
        # every d_col above every d_des
        ({"d_col": [1.5, 2.0], "d_des": [1.0, 1.4]}, "generator.formation.d_des"),
        # no d_con beyond d_des + gap
        ({"d_des": [1.8, 2.0], "d_con": [1.5, 1.9]}, "generator.formation.d_con"),
        ({"d_con": [0.5, 0.9]}, "generator.formation.d_con"),
        # robots too large for any d_col
        ({"radius": [0.4, 0.5], "d_col": [0.3, 0.6]}, "generator.formation.d_col"),
        ({"followers": [1.5, 2]}, "generator.formation.followers[0]"),  # not an integer
        ({"d_con": [1.5]}, "generator.formation.d_con"),  # not a range
        ({"width": [1, 2]}, "generator.formation.width"),  # unknown key
    ],
)
def test_bad_ranges_are_scenario_errors_naming_the_field(
    ranges: dict[str, Any], field: str
) -> None:
    with pytest.raises(ScenarioError) as err:
        scenario_source(TRAIN, _with(**ranges))
    assert field in str(err.value)
    assert err.value.path is not None and err.value.path.endswith(field)


def test_pinned_ranges_give_a_fixed_formation() -> None:
    src = scenario_source(TRAIN, _with(followers=[3, 3], radius=[0.2, 0.2]))
    assert src.followers_range == (3, 3)  # type: ignore[attr-defined]
    for index in range(3):
        cfg = src.layout(index).config  # type: ignore[attr-defined]
        assert cfg.followers == 3 and cfg.robot.radius == 0.2


def test_env_agents_follow_the_drawn_formation() -> None:
    env = platoon_env.make(TRAIN)
    assert env.variable_followers
    assert env.possible_agents == [f"follower_{i}" for i in range(1, 8)]
    counts = set()
    for seed in range(6):
        obs, infos = env.reset(seed=seed)
        n = env.scenario.config.followers
        counts.add(n)
        assert env.agents == env.possible_agents[:n]
        assert set(obs) == set(infos) == set(env.agents)
        assert env.poses.shape == (n + 1, 3) and env.sensed.shape[0] == n
        assert env.state_space.contains(env.state())
        space = env.observation_space(env.agents[0])
        for _ in range(20):
            obs, rewards, _, _, infos = env.step(
                {a: np.array([0.3, 0.0], np.float32) for a in env.agents}
            )
            assert all(space.contains(o) for o in obs.values())
            if not env.agents:
                break
        assert set(rewards) <= set(env.possible_agents[:n])
    assert len(counts) > 1


def test_fixed_formation_env_is_unchanged() -> None:
    env = platoon_env.make("procedural_train")
    assert not env.variable_followers
    env.reset(seed=0)
    assert env.agents == env.possible_agents


@pytest.mark.parametrize("observation", [None, {"task_aware": True, "scale_free": True}])
def test_batched_equals_single_and_inert_slots_stay_zero(observation: Any) -> None:
    kw = {} if observation is None else {"observation": observation}
    b_size = 4
    batch = BatchedPlatoon(TRAIN, b_size, **kw)
    assert batch.variable_followers and batch.n_followers == 7
    obs = batch.reset(seeds=list(range(b_size)))
    singles = [platoon_env.make(TRAIN, **kw) for _ in range(b_size)]
    for k, env in enumerate(singles):
        o, _ = env.reset(seed=k)
        n = len(env.agents)
        assert batch.n_active[k] == n and batch.live[k].sum() == n
        np.testing.assert_array_equal(obs[k, :n], np.stack([o[a] for a in env.agents]))
        assert not obs[k, n:].any()
    assert len(set(batch.n_active.tolist())) > 1
    space = batch.single_observation_space
    rng = np.random.default_rng(1)
    for _ in range(25):
        act = rng.uniform([0.0, -0.5], [0.6, 0.5], size=(b_size, 7, 2))
        act[~batch.live] = np.nan  # an inert slot's action is never read
        out, rew, term, trunc, info = batch.step(act)
        dead = ~batch.live
        assert not out[dead].any() and not rew[dead].any() and not info["violations"][dead].any()
        for k, env in enumerate(singles):
            if not env.agents:
                continue
            n = len(env.agents)
            o, r, *_ = env.step({a: act[k, i] for i, a in enumerate(env.agents)})
            np.testing.assert_array_equal(out[k, :n], np.stack([o[a] for a in o]))
            np.testing.assert_array_equal(rew[k, :n], [r[a] for a in o])
            assert all(space.contains(row) for row in out[k, :n])
        if np.any(term | trunc):
            break


def test_auto_reset_redraws_the_live_mask() -> None:
    batch = BatchedPlatoon(TRAIN, 3, auto_reset=True, max_episode_steps=5)
    batch.reset(seeds=0)
    counts = [batch.n_active.copy()]
    for _ in range(30):
        batch.step(np.zeros((3, 7, 2)))
        counts.append(batch.n_active.copy())
        live = batch.live
        np.testing.assert_array_equal(live.sum(1), batch.n_active)
        assert np.all(live[:, :1])  # always follower_1
    assert len({tuple(c) for c in counts}) > 1


def test_sb3_adapters_refuse_a_variable_formation() -> None:
    pytest.importorskip("stable_baselines3")
    from training.batched_vec_env import BatchedPlatoonVecEnv
    from training.vec_env import PlatoonVecEnv

    with pytest.raises(ValueError, match=r"draws its number of followers.*fast_ppo"):
        BatchedPlatoonVecEnv(TRAIN, 2)
    with pytest.raises(ValueError, match=r"draws its number of followers"):
        PlatoonVecEnv([lambda: platoon_env.make(TRAIN)])
    pinned = BatchedPlatoonVecEnv(TRAIN, 2, generator={"formation": {"followers": [2, 2]}})
    assert pinned.num_envs == 4


def test_gymnasium_ids_draw_one_follower() -> None:
    import gymnasium as gym

    env = gym.make("platoon_env/SingleFollower-ProceduralFormationsTrain-v1")
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        assert env.observation_space.contains(obs)
        cfg = cast(Any, env.unwrapped).parallel.scenario.config
        assert cfg.followers == 1
    radii = set()
    for seed in range(4):
        env.reset(seed=seed)
        radii.add(cast(Any, env.unwrapped).parallel.scenario.config.robot.radius)
    assert len(radii) > 1  # the rest of the formation is still drawn


def test_template_fields_are_kept() -> None:
    template = load_config(TRAIN)
    cfg = draw_formation(np.random.default_rng(0), template)
    same = dataclasses.replace(
        cfg,
        followers=template.followers,
        robot=template.robot,
        safety=template.safety,
        formation=template.formation,
        camera=template.camera,
        leader=template.leader,
    )
    assert same == template
    assert isinstance(template.generator.formation, FormationRanges)  # type: ignore[union-attr]


def test_fast_ppo_trains_on_the_live_slots_only(tmp_path: Any) -> None:
    torch = pytest.importorskip("torch")
    import json

    from training.fast_ppo import FastPPOConfig, train_fast

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        cfg = FastPPOConfig(
            scenario=TRAIN,
            n_envs=4,
            n_steps=32,
            batch_size=64,
            n_epochs=1,
            timesteps=64,
            log_every=64,
            checkpoint_every=0,
            progress_bar=False,
        )
        train_fast(cfg, tmp_path)
    finally:
        torch.set_num_threads(before)
    meta = json.loads((tmp_path / "model.json").read_text())
    # one rollout of 32 steps over 4 envs x 7 slots: only the live ones are counted
    assert 64 <= meta["timesteps"] < 32 * 4 * 7
