"""Task-aware observations (``observation: {task_aware: true}``, :mod:`platoon_env.observation`):
the 13-value layout and its exact bounds, the five task features, the ``t_unseen`` rule, the
batched core equal to the single env with the option on, the default (off) bit-identical to an
env without the block, and a tiny PPO run with ``--task-aware-observations`` whose model acts
in a task-aware env and is refused by a 7-vector env (and a 7-vector model by a task-aware env).
"""

from __future__ import annotations

import json
import math
import pickle
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.observation import (
    OBS_BETA_CON,
    OBS_D_COL,
    OBS_D_CON,
    OBS_D_DES,
    OBS_NAMES,
    OBS_NAMES_TASK,
    OBS_RADIUS,
    OBS_SIZE,
    OBS_SIZE_TASK,
    OBS_T_UNSEEN,
    OBS_TASK_NAMES,
    OBS_VISIBLE,
    TASK_DISTANCE_SCALE,
    TASK_SCALES,
    UNSEEN_HORIZON,
    observation_space,
    task_features,
)
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping
from platoon_env.scenarios.schema import ScenarioError

REPO = Path(__file__).resolve().parents[1]
TASK = {"observation": {"task_aware": True}}
STUDIES = ("study_a", "study_b", "study_c")


def _actions(rng: np.random.Generator, agents: list[str]) -> dict[str, np.ndarray]:
    return {a: rng.uniform([-0.3, -1.0], [1.0, 1.0]) for a in agents}


def _rollout(env: Any, seed: int, steps: int) -> Iterator[dict[str, np.ndarray]]:
    """The observations of a seeded random-action rollout, through resets."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    yield obs
    for _ in range(steps):
        obs, *_ = env.step(_actions(rng, env.agents))
        yield obs
        if not env.agents:
            obs, _ = env.reset()
            yield obs


# ------------------------------------------------------------------------------------------------
# The option, its layout and bounds
# ------------------------------------------------------------------------------------------------
def test_layout_constants() -> None:
    assert OBS_SIZE_TASK == len(OBS_NAMES_TASK) == 13
    assert OBS_NAMES_TASK[:OBS_SIZE] == OBS_NAMES
    columns = (OBS_D_DES, OBS_D_COL, OBS_D_CON, OBS_BETA_CON, OBS_RADIUS)
    assert [OBS_NAMES_TASK[c] for c in columns] == list(OBS_TASK_NAMES)
    assert OBS_NAMES_TASK[OBS_T_UNSEEN] == "t_unseen" and OBS_T_UNSEEN == OBS_SIZE_TASK - 1
    assert TASK_SCALES == (5.0, 5.0, 5.0, math.pi / 2, 2.5) and TASK_DISTANCE_SCALE == 5.0


def test_option_is_validated_recorded_and_default_off() -> None:
    off = platoon_env.make("study_c")
    explicit = platoon_env.make("study_c", observation={"task_aware": False})
    on = platoon_env.make("study_c", **TASK)
    assert off.source.config.observation.task_aware is False
    assert explicit.source.config == off.source.config
    assert "observation" not in config_mapping(off.source.config)
    assert config_fingerprint(explicit.source.config) == config_fingerprint(off.source.config)
    assert config_mapping(on.source.config)["observation"] == {"task_aware": True}
    assert config_fingerprint(on.source.config) != config_fingerprint(off.source.config)
    for bad in (1, "yes", 0.0):
        with pytest.raises(ScenarioError, match=r"observation\.task_aware: expected a boolean"):
            platoon_env.make("study_c", observation={"task_aware": bad})
    with pytest.raises(ScenarioError, match=r"observation\.task_awre: unknown key"):
        platoon_env.make("study_c", observation={"task_awre": True})
    # the block in a scenario file (a dict here) is read like any other
    data = {**config_mapping(off.source.config), **TASK}
    assert platoon_env.make(data).observation_space("follower_1").shape == (OBS_SIZE_TASK,)


def test_spaces_are_exact() -> None:
    for name in (*STUDIES, "procedural_train"):
        off = platoon_env.make(name)
        on = platoon_env.make(name, **TASK)
        base = off.observation_space("follower_1")
        space = on.observation_space("follower_1")
        assert base.shape == (OBS_SIZE,) and space.shape == (OBS_SIZE_TASK,)
        assert space.dtype == np.float32
        np.testing.assert_array_equal(space.low[:OBS_SIZE], base.low)
        np.testing.assert_array_equal(space.high[:OBS_SIZE], base.high)
        np.testing.assert_array_equal(space.low[OBS_SIZE:], np.zeros(6, dtype=np.float32))
        np.testing.assert_array_equal(space.high[OBS_SIZE:], np.ones(6, dtype=np.float32))
        assert observation_space(on.source.config) == space
        batched = BatchedPlatoon(name, 2, **TASK)
        assert batched.single_observation_space == space
        assert batched.reset(seeds=0).shape == (2, on.n_followers, OBS_SIZE_TASK)


@pytest.mark.parametrize("name", [*STUDIES, "procedural_train"])
def test_space_contains_every_observation(name: str) -> None:
    """A random rollout (with the dropouts, latency and frames of the aruco profile, and no
    cause ending it) never leaves the Box (the cap: the forced loss below)."""
    env = platoon_env.make(
        name, sensor_profile="aruco", control_period=0.025, terminate_on=(), **TASK
    )
    space = env.observation_space("follower_1")
    t_max = 0.0
    for obs in _rollout(env, seed=3, steps=200):
        for a, o in obs.items():
            assert o.dtype == np.float32 and space.contains(o), (a, o)
            t_max = max(t_max, float(o[OBS_T_UNSEEN]))
    assert t_max > 0.0  # some follower lost its predecessor


# ------------------------------------------------------------------------------------------------
# The values
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", [*STUDIES, "procedural_test"])
def test_task_features_are_the_config_over_its_scales(name: str) -> None:
    env = platoon_env.make(name, **TASK)
    cfg = env.source.config
    # The config's value of each feature by its name, so the columns' order is checked too.
    value = {
        "d_des": cfg.formation.d_des,
        "d_col": cfg.safety.d_col,
        "d_con": cfg.camera.range,
        "beta_con": cfg.camera.half_angle,
        "r": cfg.robot.radius,
    }
    scaled = [value[name] / s for name, s in zip(OBS_TASK_NAMES, TASK_SCALES, strict=True)]
    expected = np.array(scaled, np.float32)
    assert np.all((expected > 0) & (expected < 1))  # no shipped scenario clips
    np.testing.assert_array_equal(task_features(cfg), expected)
    for obs in _rollout(env, seed=1, steps=30):
        for o in obs.values():
            np.testing.assert_array_equal(o[OBS_D_DES : OBS_RADIUS + 1], expected)


def test_study_a_values_and_the_clip() -> None:
    obs, _ = platoon_env.make("study_a", **TASK).reset(seed=0)
    np.testing.assert_array_equal(
        obs["follower_3"][OBS_SIZE:],
        np.array(
            [2 / 5, 0.5 / 5, 4 / 5, (math.pi / 4) / (math.pi / 2), 0.2 / 2.5, 0.0], np.float32
        ),
    )
    # a camera beyond the reference distance saturates: d_con clips to 1, the others do not
    wide = platoon_env.make("study_a", camera={"range": 8.0}, **TASK)
    obs, _ = wide.reset(seed=0)
    assert obs["follower_1"][OBS_D_CON] == 1.0
    assert obs["follower_1"][OBS_D_DES] == np.float32(0.4)
    assert wide.observation_space("follower_1").contains(obs["follower_1"])


def _check_t_unseen(env: Any, seed: int, steps: int) -> tuple[int, int]:
    """Follow the rule alongside the env; returns (steps perceived lost while truly visible,
    steps at the cap)."""
    dt = env.control_period
    obs, infos = env.reset(seed=seed)
    count = dict.fromkeys(env.agents, 0)
    for a in env.agents:
        assert obs[a][OBS_T_UNSEEN] == 0.0  # the start counts as visible
    rng = np.random.default_rng(seed)
    hidden = capped = 0
    for _ in range(steps):
        obs, _, _, _, infos = env.step(_actions(rng, env.agents))
        for a, o in obs.items():
            count[a] = 0 if o[OBS_VISIBLE] > 0 else count[a] + 1
            assert o[OBS_T_UNSEEN] == np.float32(min(1.0, count[a] * (dt / UNSEEN_HORIZON))), a
            hidden += int(o[OBS_VISIBLE] == 0 and infos[a]["visible"])
            capped += int(o[OBS_T_UNSEEN] == 1.0)
        if not env.agents:
            break
    return hidden, capped


def test_t_unseen_counts_perceived_dropouts() -> None:
    """Detection dropouts: the truth sees the predecessor, the follower does not, and the
    time since grows by the control period per step until the next detection."""
    env = platoon_env.make("study_c", camera={"detection": 0.6}, **TASK)
    hidden, _ = _check_t_unseen(env, seed=0, steps=300)
    assert hidden > 50


def test_t_unseen_counts_frames_and_latency_as_perceived() -> None:
    """With a frame rate and latency the rule reads the perceived (held, delayed) flag."""
    env = platoon_env.make("study_c", sensor_profile="aruco", **TASK)
    hidden, _ = _check_t_unseen(env, seed=2, steps=400)
    assert hidden > 0


def test_t_unseen_grows_to_the_cap_after_a_forced_loss_and_resets() -> None:
    """The follower backs away (until the wall behind it; no cause terminates): once its
    leader is out of range for good, ``t_unseen`` is ``k dt / T`` after ``k`` lost steps,
    then 1."""
    env = platoon_env.make("study_c", followers=1, terminate_on=(), control_period=0.05, **TASK)
    dt = env.control_period
    obs, _ = env.reset(seed=0)
    back = {a: np.array([-1.0, 0.0]) for a in env.agents}
    rows = []
    for _ in range(int(UNSEEN_HORIZON / dt) + 30):
        obs, *_ = env.step(back)
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        rows.append([obs[a][[OBS_VISIBLE, OBS_T_UNSEEN]] for a in env.possible_agents])
    seen = np.array(rows)  # (steps, N, [visible, t_unseen])
    for i in range(env.n_followers):
        lost = np.flatnonzero(seen[:, i, 0] == 0)
        first = int(lost[0])
        assert first < 20 and np.all(seen[first:, i, 0] == 0)  # lost for good
        expected = [
            np.float32(min(1.0, k * (dt / UNSEEN_HORIZON))) for k in range(1, len(seen) - first + 1)
        ]
        np.testing.assert_array_equal(seen[first:, i, 1], np.array(expected, np.float32))
        assert seen[-1, i, 1] == 1.0 and np.all(seen[:first, i, 1] == 0.0)
    obs, _ = env.reset(seed=1)
    assert all(o[OBS_T_UNSEEN] == 0.0 for o in obs.values())


# ------------------------------------------------------------------------------------------------
# Default off, batched == single, the other API forms
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("name", "extra"), [("study_c", {}), ("study_b", {"sensor_profile": "aruco"})]
)
def test_default_off_is_bit_identical_and_on_only_appends(name: str, extra: dict[str, Any]) -> None:
    """Without the block, with it off and with it on, the episodes are the same bit for bit:
    the option only appends columns (the first 7 are the default observation)."""
    runs = [
        list(_rollout(platoon_env.make(name, **extra, **kw), seed=4, steps=250))
        for kw in ({}, {"observation": {"task_aware": False}}, TASK)
    ]
    assert len(runs[0]) == len(runs[1]) == len(runs[2])
    for none, off, on in zip(*runs, strict=True):
        assert none.keys() == off.keys() == on.keys()
        for a in none:
            assert none[a].shape == (OBS_SIZE,)
            assert none[a].tobytes() == off[a].tobytes()
            assert none[a].tobytes() == on[a][:OBS_SIZE].tobytes()


@pytest.mark.parametrize("n_threads", [1, 2])
def test_batched_equals_single_env_with_the_option(n_threads: int) -> None:
    kw: dict[str, Any] = {"camera": {"detection": 0.7}, "max_episode_steps": 60, **TASK}
    b_envs = 3
    batched = BatchedPlatoon("study_c", b_envs, n_threads=n_threads, auto_reset=True, **kw)
    singles = [platoon_env.make("study_c", **kw) for _ in range(b_envs)]
    obs = batched.reset(seeds=10)
    for k, env in enumerate(singles):
        o, _ = env.reset(seed=10 + k)
        np.testing.assert_array_equal(obs[k], np.stack([o[a] for a in env.possible_agents]))
    rng = np.random.default_rng(0)
    n = batched.n_followers
    ended = 0
    t_seen = 0.0
    for _ in range(150):
        act = rng.uniform([-0.3, -1.0], [1.0, 1.0], size=(b_envs, n, 2))
        obs, _, term, trunc, info = batched.step(act)
        for k, env in enumerate(singles):
            o, _, te, tr, _ = env.step({a: act[k, i] for i, a in enumerate(env.possible_agents)})
            last = np.stack([o[a] for a in env.possible_agents])
            assert (all(te.values()), all(tr.values())) == (term[k], trunc[k])
            if term[k] or trunc[k]:
                ended += 1
                np.testing.assert_array_equal(info["final_observation"][k], last)
                o, _ = env.reset()
                last = np.stack([o[a] for a in env.possible_agents])
                assert np.all(last[:, OBS_T_UNSEEN] == 0.0)
            np.testing.assert_array_equal(obs[k], last)
        t_seen = max(t_seen, float(obs[:, :, OBS_T_UNSEEN].max()))
    assert ended >= b_envs  # resets were exercised
    assert t_seen > 0  # and dropouts


def test_a_pickled_env_keeps_counting() -> None:
    """The count and the column views survive pickling (the copy steps like the original)."""
    env = platoon_env.make("study_c", camera={"detection": 0.5}, **TASK)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.step(_actions(rng, env.agents))
    copy = pickle.loads(pickle.dumps(env))
    t_max = 0.0
    for _ in range(30):
        act = _actions(rng, env.agents)
        a, b = env.step(act)[0], copy.step(act)[0]
        for agent in a:
            assert a[agent].tobytes() == b[agent].tobytes()
            t_max = max(t_max, float(b[agent][OBS_T_UNSEEN]))
    assert t_max > 0.0


def test_aec_and_gymnasium_forms() -> None:
    aec = platoon_env.env("study_c", **TASK)
    aec.reset(seed=0)
    space = aec.observation_space("follower_1")
    assert space.shape == (OBS_SIZE_TASK,) and space.contains(aec.observe("follower_1"))
    for agent in aec.agent_iter(max_iter=40):
        obs, *_ = aec.last()
        assert space.contains(obs) and obs.tobytes() == aec.observe(agent).tobytes()
        aec.step(np.array([0.2, 0.0], dtype=np.float32))
    from gymnasium.utils.env_checker import check_env

    env = gym.make("platoon_env/SingleFollower-StudyC-v1", **TASK)
    assert env.observation_space.shape == (OBS_SIZE_TASK,)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs[OBS_T_UNSEEN] == 0.0 and obs[OBS_D_DES] == np.float32(0.2)


# ------------------------------------------------------------------------------------------------
# Training and loading
# ------------------------------------------------------------------------------------------------
def test_training_adapters_normalise_the_13_values() -> None:
    pytest.importorskip("stable_baselines3")
    from training.batched_vec_env import BatchedPlatoonVecEnv
    from training.vec_env import PlatoonVecEnv, observation_scale

    venv = PlatoonVecEnv([lambda: platoon_env.make("study_c", **TASK)] * 2)
    base = observation_scale(platoon_env.make("study_c").observation_space("follower_1"))
    assert venv.obs_scale is not None
    np.testing.assert_array_equal(venv.obs_scale[:OBS_SIZE], base)
    np.testing.assert_array_equal(venv.obs_scale[OBS_SIZE:], np.ones(6, dtype=np.float32))
    bvenv = BatchedPlatoonVecEnv("study_c", 2, **TASK)
    assert bvenv.observation_space == venv.observation_space
    venv.seed(5)
    bvenv.seed(5)
    a, b = venv.reset(), bvenv.reset()
    assert a.shape == (4, OBS_SIZE_TASK)
    np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(0)
    for _ in range(20):
        act = rng.uniform(-1, 1, size=(4, 2)).astype(np.float32)
        np.testing.assert_array_equal(venv.step(act)[0], bvenv.step(act)[0])


def test_rllib_engine_takes_the_flag() -> None:
    """The RLlib engine builds its actor on the scenario's observation length
    (tests/test_rllib.py trains one)."""
    from training.train import TrainConfig, check_config

    assert check_config(TrainConfig(engine="rllib", task_aware_observations=True)) == []


def test_tiny_ppo_run_with_the_flag(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    import torch

    from training import LearnedPolicy
    from training.train import main

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        code = main(
            [
                "--algo", "ppo", "--scenario", "study_c", "--seed", "0", "--n-envs", "1",
                "--n-steps", "128", "--batch-size", "64", "--n-epochs", "1",
                "--net-arch", "16", "16", "--checkpoint-every", "0", "--no-progress-bar",
                "--timesteps", "256", "--out", str(tmp_path), "--task-aware-observations",
            ]
        )  # fmt: skip
    finally:
        torch.set_num_threads(before)
    assert code == 0
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["observation_layout"] == list(OBS_NAMES_TASK)
    assert meta["scenario_config"]["observation"] == {"task_aware": True}
    assert meta["config"]["task_aware_observations"] is True
    scale = meta["observation_normalization"]["scale"]
    assert len(scale) == OBS_SIZE_TASK and scale[OBS_SIZE:] == [1.0] * 6

    policy = LearnedPolicy.load(tmp_path / "model.zip")
    assert policy.task_aware and policy.observation_layout == OBS_NAMES_TASK
    period = policy.control_period
    env = platoon_env.make("study_c", control_period=period, **TASK)
    assert policy.check_env(env) == []
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        act = policy.act(obs)
        assert all(env.action_space(a).contains(u) for a, u in act.items())
        obs, *_ = env.step(act)
    # another formation, same policy: allowed (a note), as any other scenario
    notes = policy.check_env(
        platoon_env.make("study_a", control_period=period, followers=2, **TASK)
    )
    assert any("scenario:" in n for n in notes)

    plain = platoon_env.make("study_c", control_period=period)
    with pytest.raises(ValueError, match=r"task-aware observations \(13 values\).*7-vector"):
        policy.check_env(plain)
    with pytest.raises(ValueError, match=r"observation=\{'task_aware': True\}"):
        policy.check_env(plain)
    obs7, _ = plain.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(13,\)"):
        policy.act(obs7)


def test_a_7_vector_model_is_refused_by_a_task_aware_env() -> None:
    pytest.importorskip("stable_baselines3")
    from training import LearnedPolicy

    shipped = LearnedPolicy.load(REPO / "models" / "legacy" / "ppo_corridors_s0")
    assert not shipped.task_aware and shipped.observation_layout == OBS_NAMES
    period = shipped.control_period
    with pytest.raises(ValueError, match=r"reads the 7-vector.*task-aware observations"):
        shipped.check_env(platoon_env.make("study_c", control_period=period, **TASK))
    # it acts on the 7-vector as before, and refuses task-aware observations when asked to
    obs, _ = platoon_env.make("study_c", control_period=period).reset(seed=0)
    assert all(a.shape == (2,) for a in shipped.act(obs).values())
    obs, _ = platoon_env.make("study_c", control_period=period, **TASK).reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(7,\) \(the 7-vector\)"):
        shipped.act(obs)


def test_analytic_laws_act_in_a_task_aware_env() -> None:
    """PPC, last-seen and filtered PPC read the sensor part of a 13-vector (their task comes
    from the scenario) and act exactly as on the 7-vector; any other width is refused."""
    import numpy as np
    import pytest

    import platoon_env
    from baselines import FilteredPPCPolicy, LastSeenPolicy, PPCPolicy

    for cls in (PPCPolicy, LastSeenPolicy, FilteredPPCPolicy):
        plain = platoon_env.make("study_c")
        task = platoon_env.make("study_c", observation={"task_aware": True})
        obs7, _ = plain.reset(seed=0)
        obs13, _ = task.reset(seed=0)
        a, b = cls(plain), cls(task)
        for _ in range(20):
            act7, act13 = a.act(obs7), b.act(obs13)
            for agent in act7:
                np.testing.assert_array_equal(act7[agent], act13[agent])
            obs7, *_ = plain.step(act7)
            obs13, *_ = task.step(act13)
        with pytest.raises(ValueError, match="expected observations of shape"):
            cls(plain).act({agent: o[:5] for agent, o in obs7.items()})
