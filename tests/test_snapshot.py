"""Snapshot and restore of the core's state: a restored copy continues exactly as the original.

The privileged oracle (:mod:`baselines.oracle`) plans by restoring one moment of an episode into
many copies; a copy that drifts by one bit from the original would plan against another world.
So every test compares whole trajectories for exact equality, under the realism that keeps state
between steps (camera latency, frame rate, detection and noise draws, actuator lag and rate
limits) and with a procedural source (a restored env installs the snapshot's layout).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import platoon_env
from platoon_env import CoreSnapshot
from platoon_env.batched import BatchedPlatoon

#: Realism whose state carries across steps: frames in flight, held frames, random draws, drive.
REALISM: dict[str, Any] = {"sensor_profile": "aruco"}


def _actions(rng: np.random.Generator, n_steps: int, n: int) -> np.ndarray:
    """Commands near PPC's scale: forward speed and turn rates that keep the platoon moving."""
    out = np.empty((n_steps, n, 2))
    out[..., 0] = rng.uniform(0.0, 1.0, (n_steps, n))
    out[..., 1] = rng.uniform(-1.0, 1.0, (n_steps, n))
    return out


def _run(env: platoon_env.PlatoonParallelEnv, actions: np.ndarray) -> list[Any]:
    """Step ``env`` with ``actions`` until they run out or the episode ends; every output."""
    out: list[Any] = []
    for a in actions:
        if not env.agents:
            break
        obs, rew, term, trunc, info = env.step({agent: a[i] for i, agent in enumerate(env.agents)})
        out.append(
            (
                {k: v.tobytes() for k, v in obs.items()},
                rew,
                term,
                trunc,
                {k: (v["violations"], v["d"], v["beta"]) for k, v in info.items()},
                env.poses.tobytes(),
                env.applied_velocities.tobytes(),
                env.sim_time,
            )
        )
    return out


@pytest.mark.parametrize("overrides", [{}, REALISM], ids=["ideal", "aruco"])
def test_restored_env_continues_bit_identically(overrides: dict[str, Any]) -> None:
    env = platoon_env.make("study_c", **overrides)
    env.reset(seed=3)
    actions = _actions(np.random.default_rng(0), 80, env.n_followers)
    _run(env, actions[:30])
    snap = env.snapshot()
    assert isinstance(snap, CoreSnapshot) and not snap.ended
    expected = _run(env, actions[30:])
    assert len(expected) > 10

    # the same env, after it has moved on
    env.restore(snap)
    assert _run(env, actions[30:]) == expected
    # another env of the same scenario, at a different moment of another episode
    other = platoon_env.make("study_c", **overrides)
    other.reset(seed=99)
    _run(other, actions[:5])
    other.restore(snap)
    assert _run(other, actions[30:]) == expected
    # the snapshot itself is unchanged by the runs that followed it (a deep copy)
    again = platoon_env.make("study_c", **overrides)
    again.reset(seed=7)
    again.restore(snap)
    assert _run(again, actions[30:]) == expected


def test_restored_copies_do_not_share_an_rng() -> None:
    """Two copies of one moment draw the same noise, each from its own generator."""
    env = platoon_env.make("study_c", **REALISM)
    env.reset(seed=1)
    snap = env.snapshot()
    a, b = platoon_env.make("study_c", **REALISM), platoon_env.make("study_c", **REALISM)
    for e in (a, b):
        e.reset(seed=5)
        e.restore(snap)
    assert a.np_random is not b.np_random
    assert a.np_random.random() == b.np_random.random()


def test_batched_rows_restored_from_one_env_follow_it() -> None:
    """``B`` rows restored from a single env's snapshot, fed the same actions, all follow it
    bit for bit; rows fed other actions diverge (so the copies are real copies)."""
    env = platoon_env.make("study_c", **REALISM)
    env.reset(seed=11)
    actions = _actions(np.random.default_rng(1), 60, env.n_followers)
    _run(env, actions[:20])
    snap = env.snapshot()
    batch = BatchedPlatoon("study_c", 3, **REALISM)
    batch.reset(seeds=0)
    obs = batch.restore(snap, envs=[0, 2])
    np.testing.assert_array_equal(obs[0], np.stack(list(env.restore(snap).values())))
    poses = []
    for k in range(20, 60):
        act = np.stack([actions[k], actions[k], -actions[k]])
        _, _, term, trunc, _ = batch.step(act)
        env.step({a: actions[k][i] for i, a in enumerate(env.agents)})
        poses.append((batch._core.poses[0].copy(), env.poses.copy(), batch._core.poses[2].copy()))
        if term.any() or trunc.any() or not env.agents:
            break
    assert len(poses) > 5
    for row0, single, _ in poses:
        np.testing.assert_array_equal(row0, single)
    assert not np.array_equal(poses[-1][2], poses[-1][1])
    # row 1 was left alone by the restore: its own episode (seed 1), stepped as often
    assert batch.steps[1] == len(poses) and batch.steps[0] == 20 + len(poses)


def test_procedural_snapshot_installs_its_layout() -> None:
    """A procedural env's snapshot carries its layout: restored into an env that drew another
    layout, the env continues on the snapshot's map."""
    source = BatchedPlatoon("procedural_train", 2, max_episode_steps=200)
    source.reset(seeds=[4, 5])
    assert source.scenarios[0] is not source.scenarios[1]
    snap = source.snapshot(0)
    target = BatchedPlatoon("procedural_train", 1, max_episode_steps=200)
    target.reset(seeds=[77])
    target.restore(snap)
    assert target.scenarios[0] is snap.scenario
    act = np.zeros((2, source.n_followers, 2))
    act[..., 0] = 0.3
    for _ in range(30):
        out_s = source.step(act)
        out_t = target.step(act[:1])
        np.testing.assert_array_equal(out_s[0][0], out_t[0][0])
        np.testing.assert_array_equal(out_s[1][0], out_t[1][0])
        assert (out_s[2][0], out_s[3][0]) == (out_t[2][0], out_t[3][0])
        if out_s[2][0] or out_s[3][0]:
            break


def test_snapshot_of_an_ended_episode_needs_a_reset() -> None:
    env = platoon_env.make("study_c", max_episode_steps=3)
    env.reset(seed=0)
    for _ in range(3):
        env.step({a: np.array([0.2, 0.0], dtype=np.float32) for a in env.agents})
    assert not env.agents
    snap = env.snapshot()
    assert snap.ended
    batch = BatchedPlatoon("study_c", 2, max_episode_steps=3)
    batch.reset(seeds=0)
    batch.restore(snap, envs=[1])
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(np.zeros((2, batch.n_followers, 2)))
    batch.step(np.zeros((2, batch.n_followers, 2)), envs=[0])  # the other env steps on
    fresh = platoon_env.make("study_c", max_episode_steps=3)
    fresh.reset(seed=0)
    fresh.restore(snap)
    assert fresh.agents == []


def test_restore_refuses_another_scenario_and_leaves_the_env_as_it_was() -> None:
    b_env = platoon_env.make("study_b")
    b_env.reset(seed=0)
    c_env = platoon_env.make("study_c")
    c_env.reset(seed=0)
    before = c_env.snapshot()
    with pytest.raises(ValueError, match=r"does not fit|cannot be restored"):
        c_env.restore(b_env.snapshot())
    assert c_env.poses.tobytes() == before.rows["poses"].tobytes()
    # same buffer shapes, another scenario: refused by fingerprint
    slower = platoon_env.make("study_c", control_period=0.02)
    slower.reset(seed=0)
    with pytest.raises(ValueError, match="fingerprints differ"):
        c_env.restore(slower.snapshot())
    with pytest.raises(TypeError, match="CoreSnapshot"):
        c_env.restore("not a snapshot")  # type: ignore[arg-type]
    batch = BatchedPlatoon("study_c", 2)
    with pytest.raises(ValueError, match="env index"):
        batch.snapshot(2)
