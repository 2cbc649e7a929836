"""Seed diversity: ``leader.speed_variation`` draws the leader's speed per episode (issue 13).

Without it, seeds 0, 1, 2 of a study give the same leader and, once the 5 cm / 0.05 rad start
perturbation has settled under PPC, nearly the same episode. With ``speed_variation = v`` every
reset draws a factor ``f`` uniformly in ``[1 - v, 1 + v]`` from the env's own seeded RNG (after
the initial configuration); the leader drives at ``f * leader.speed`` (a trajectory: replayed
``f`` times as fast). ``v = 0`` (default) draws nothing: every episode is bit for bit as before.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from test_golden import rollout_digest

import platoon_env
from baselines import PPCPolicy
from platoon_env.batched import BatchedPlatoon
from platoon_env.rollout import run_episode
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping

STUDIES = ["study_a", "study_b", "study_c"]
#: 15 s of PPC: long enough for the start perturbation to settle (measured on the studies of
#: commit 6dc2508 at 15 s: seeds 0, 1, 2 within 0.013 m of each other without variation, 0.3 to
#: 3.3 m apart with it).
STEPS = 1500
#: Study B's leader replays a planner's trajectory that starts by turning in place at rest:
#: after 15 s the leaders of two speed factors are only a few cm apart; 30 s of it.
STEPS_OF = {"study_b": 3000}
VARIED = {"speed_variation": 0.2}
#: The shipped studies draw a leader speed factor (``speed_variation: 0.2``); without it:
FIXED = {"speed_variation": 0.0}


def _poses(env: Any, seed: int) -> np.ndarray:
    """The poses (T+1, N+1, 3) of a PPC episode from ``reset(seed)``, at most STEPS steps."""
    steps = STEPS_OF.get(env.scenario.config.name, STEPS)
    return run_episode(env, PPCPolicy(env), seed=seed, max_steps=steps, record_signals=False).poses


def _final_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between the same robot of two episodes at their last common step
    (robots along the last axis but one)."""
    n = min(len(a), len(b))
    return float(np.max(np.hypot(*(a[n - 1, :, :2] - b[n - 1, :, :2]).T)))


@pytest.mark.parametrize("study", STUDIES)
def test_without_variation_every_seed_has_the_same_leader(study: str) -> None:
    """The issue: without a speed factor, the seed moves only the followers' start; the leader
    is the same."""
    env = platoon_env.make(study, leader=FIXED)
    runs = [_poses(env, seed) for seed in (0, 1, 2)]
    n = min(len(r) for r in runs)
    for other in runs[1:]:
        np.testing.assert_array_equal(other[:n, 0], runs[0][:n, 0])


@pytest.mark.parametrize("study", STUDIES)
def test_speed_variation_gives_each_seed_its_own_episode(study: str) -> None:
    """With ``speed_variation = 0.2`` seeds 0, 1, 2 draw different factors, and their leaders
    and followers take different trajectories (more than 0.1 m apart at the end); the same seed
    gives the same episode bit for bit."""
    env = platoon_env.make(study, leader=VARIED)
    runs, factors = [], []
    for seed in (0, 1, 2):
        runs.append(_poses(env, seed))
        factors.append(env.leader_speed_factor)
    assert len(set(factors)) == 3 and all(0.8 <= f <= 1.2 for f in factors), factors
    for i in range(3):
        for j in range(i + 1, 3):
            assert _final_gap(runs[i][:, :1], runs[j][:, :1]) > 0.1, (i, j)  # the leaders
            assert _final_gap(runs[i][:, 1:], runs[j][:, 1:]) > 0.1, (i, j)  # the followers
    again = platoon_env.make(study, leader=VARIED)
    np.testing.assert_array_equal(_poses(again, 1), runs[1])
    assert again.leader_speed_factor == factors[1]


def test_pure_pursuit_drives_at_the_drawn_speed(corridor: dict[str, Any]) -> None:
    """The leader's command on a straight is exactly ``f * leader.speed``; successive resets
    without a seed continue the RNG (new factors); ``v = 0`` gives ``f = 1``."""
    corridor["leader"]["speed_variation"] = 0.5
    env = platoon_env.make(corridor)
    seen = set()
    for _ in range(4):
        env.reset()
        f = env.leader_speed_factor
        env.step({a: [0.0, 0.0] for a in env.agents})
        assert env.leader_velocity[0] == 0.3 * f
        assert 0.5 <= f <= 1.5
        seen.add(f)
    assert len(seen) == 4
    corridor["leader"]["speed_variation"] = 0.0
    plain = platoon_env.make(corridor)
    plain.reset(seed=0)
    plain.step({a: [0.0, 0.0] for a in plain.agents})
    assert plain.leader_speed_factor == 1.0 and plain.leader_velocity[0] == 0.3


def test_a_failed_reset_restores_the_rng(corridor: dict[str, Any]) -> None:
    """A reset that fails (infeasible given poses) leaves the RNG as it was: the next reset
    draws the factor (and perturbation) a fresh env draws."""
    corridor["leader"]["speed_variation"] = 0.3
    env, fresh = platoon_env.make(corridor), platoon_env.make(corridor)
    env.reset(seed=3)
    fresh.reset(seed=3)
    bad = env.poses
    bad[1, :2] = bad[0, :2]  # follower 1 on the leader
    with pytest.raises(ScenarioError):
        env.reset(options={"poses": bad})
    env.reset()
    fresh.reset()
    assert env.leader_speed_factor == fresh.leader_speed_factor
    np.testing.assert_array_equal(env.poses, fresh.poses)


def test_batched_draws_as_the_single_env(corridor: dict[str, Any]) -> None:
    """Env ``b`` of a batch reset with seed ``s`` draws the factor the single env draws, and
    follows it bit for bit; ``auto_reset`` continues each env's own RNG."""
    corridor["leader"]["speed_variation"] = 0.25
    seeds = [4, 5, 6]
    batch = BatchedPlatoon(corridor, 3, auto_reset=True, max_episode_steps=60)
    batch.reset(seeds)
    singles = [platoon_env.make(corridor, max_episode_steps=60) for _ in seeds]
    for env, seed in zip(singles, seeds, strict=True):
        env.reset(seed=seed)
    rng = np.random.default_rng(0)
    for step in range(150):
        act = rng.uniform([0.0, -0.3], [0.4, 0.3], size=(3, 2, 2))
        batch.step(act)
        for b, env in enumerate(singles):
            _, _, term, trunc, _ = env.step({a: act[b, i] for i, a in enumerate(env.agents)})
            if any(term.values()) or any(trunc.values()):
                env.reset()
            np.testing.assert_array_equal(batch.poses[b], env.poses, err_msg=f"{step} {b}")
            assert batch.leader_speed_factor[b] == env.leader_speed_factor


def test_default_step_limit_covers_the_slowest_leader(corridor: dict[str, Any]) -> None:
    """The default step limit allows twice the slowest leader's driving time."""
    corridor["leader"]["speed_variation"] = 0.5
    env = platoon_env.make(corridor)
    length = 19.5
    assert env.max_episode_steps == math.ceil((2 * length / (0.3 * 0.5) + 2.0 + 10.0) / 0.01)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (-0.1, r"must lie in \[0, 0\.9\]"),
        (0.95, r"must lie in \[0, 0\.9\]"),
        (math.nan, "must be finite"),
        (True, "expected a number"),
    ],
)
def test_bad_speed_variation(corridor: dict[str, Any], value: Any, message: str) -> None:
    corridor["leader"]["speed_variation"] = value
    with pytest.raises(ScenarioError, match=r"scenario\.leader\.speed_variation: " + message):
        platoon_env.make(corridor)


def test_zero_variation_changes_nothing() -> None:
    """Spelled out, ``speed_variation: 0`` is the default: same config, mapping, episodes (on
    a procedural scenario, which does not set it; the studies ship with 0.2)."""
    default = platoon_env.make("procedural_test")
    explicit = platoon_env.make("procedural_test", leader={"speed_variation": 0.0})
    assert explicit.source.config == default.source.config
    assert "speed_variation" not in config_to_mapping(default.source.config)["leader"]
    assert rollout_digest("procedural_test", 1, steps=150) == rollout_digest(
        "procedural_test", 1, steps=150, leader={"speed_variation": 0.0}
    )
    assert platoon_env.make("study_b").source.config.leader.speed_variation == 0.2


# ------------------------------------------------------------------------------------------------
# Training runs: every env of every run on its own stream (training/seeding.py)
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def procedural_venv() -> Any:
    """The training adapter of ``platoon-train --scenario procedural_train --n-envs 8``."""
    pytest.importorskip("stable_baselines3")
    from training.config import TrainConfig
    from training.train import build_vec_env

    return build_vec_env(TrainConfig(scenario="procedural_train", n_envs=8))


def _first_layouts(venv: Any, seed: int, segment: int = 0) -> list[int]:
    """The layout each env of ``venv`` draws first when a run seeded ``seed`` starts segment
    ``segment``."""
    venv.seed_segment = segment
    venv.seed(seed)
    venv.reset()
    return [int(env.layout_index) for env in venv.envs]


def test_training_seeds_share_no_env_stream(procedural_venv: Any) -> None:
    """Seeds 0-4 x 8 envs: 40 distinct first layouts (with env j seeded seed + j, seeds 0 and
    1 shared 7 of their 8 envs' layouts, and the 40 envs drew only 12)."""
    layouts = [layout for seed in range(5) for layout in _first_layouts(procedural_venv, seed)]
    assert len(set(layouts)) == 40
    # the streams are the run seed's, not the adapter's: the same seed draws them again
    assert _first_layouts(procedural_venv, 3) == layouts[24:32]


def test_a_resumed_segment_draws_new_episodes(procedural_venv: Any) -> None:
    """Segment 1 of a run (its first --resume) starts other layouts than segment 0, and the
    envs of a fixed workspace start other perturbed configurations."""
    first, resumed = _first_layouts(procedural_venv, 0), _first_layouts(procedural_venv, 0, 1)
    assert not set(first) & set(resumed) and len(set(resumed)) == 8
    from training.config import TrainConfig
    from training.train import build_vec_env

    starts = []
    for segment in (0, 1):
        venv = build_vec_env(TrainConfig(scenario="study_c", n_envs=2))
        venv.seed_segment = segment
        venv.seed(0)
        starts.append(venv.reset())
    assert not np.any(np.all(starts[0] == starts[1], axis=1))  # no follower starts alike


@pytest.mark.usefixtures("one_torch_thread")
def test_platoon_train_resume_seeds_its_segment(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``platoon-train`` then ``--resume``: the first segment's envs get the seeds of segment 0,
    the resumed one's those of segment 1 (what SB3 asks the adapter for on load)."""
    pytest.importorskip("stable_baselines3")
    from training.seeding import env_seeds
    from training.train import cli_args, main
    from training.vec_env import SlotVecEnv

    given: list[list[int | None]] = []
    seed = SlotVecEnv.seed

    def spy(self: SlotVecEnv, value: int | None = None) -> Any:
        given.append(list(seed(self, value)))
        return given[-1]

    monkeypatch.setattr(SlotVecEnv, "seed", spy)
    argv = cli_args(
        n_envs=2,
        n_steps=64,
        batch_size=64,
        n_epochs=1,
        net_arch=[8],
        seed=5,
        out=tmp_path / "r",
        progress_bar=False,
    )
    assert main([*argv, "--timesteps", "256"]) == 0
    assert given and all(g == env_seeds(5, 2, segment=0) for g in given)
    given.clear()
    assert main([*argv, "--timesteps", "512", "--resume"]) == 0
    assert given and all(g == env_seeds(5, 2, segment=1) for g in given)
