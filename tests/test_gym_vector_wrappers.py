"""The Gymnasium ids as a first-class Gymnasium 1.x citizen (issue 45): the vector env's
``autoreset_mode`` (an attribute; ``NEXT_STEP`` by default, ``SAME_STEP`` and ``DISABLED`` on
request), Gymnasium's own vector wrappers over ``gymnasium.make_vec(id, n)``, infos that array
libraries can read, ``metadata["render_fps"]`` as the simulation's steps per second, and every
spec's ``max_episode_steps``.

NEXT_STEP is checked the strongest way: step for step equality, infos included, with
Gymnasium's ``SyncVectorEnv`` of ``gymnasium.make(id)`` envs in that mode, through staggered
episode ends and a partial reset. SAME_STEP's equality is ``tests/test_gym_vector.py``'s.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.wrappers import vector as vector_wrappers

import platoon_env
from platoon_env.gym_env import GYM_STEP_LIMITS, SingleFollowerEnv, single_follower
from platoon_env.gym_vector import SingleFollowerVectorEnv
from platoon_env.scenarios.source import scenario_source
from platoon_env.scenarios.validate import default_max_steps, formation_limits

STUDY_C = "platoon_env/SingleFollower-StudyC-v1"
STUDY_B = "platoon_env/SingleFollower-StudyB-v1"
#: A procedural tier with the aruco profile: layouts and sensor noise drawn from each env's RNG.
PROCEDURAL_ARUCO = "platoon_env/SingleFollower-ProceduralEasyTrain-Aruco-v1"
#: Sub-env 0 spins in place (out_of_fov ends its episodes after about 20 steps on study_c).
_SPIN = np.array([0.0, 2.0], dtype=np.float32)


def _vec(env_id: str, num_envs: int, **kwargs: Any) -> Any:
    """``gymnasium.make_vec`` (typed Any: Gymnasium's stubs know neither this env's attributes
    nor list seeds)."""
    return gym.make_vec(env_id, num_envs=num_envs, **kwargs)


def _make(env_id: str, **kwargs: Any) -> Any:
    """``gymnasium.make``, typed Any (see :func:`_vec`)."""
    return gym.make(env_id, **kwargs)


def _sync(env_id: str, num_envs: int, mode: AutoresetMode, **kwargs: Any) -> Any:
    """Gymnasium's ``SyncVectorEnv`` of ``gymnasium.make(env_id)`` envs in ``mode``."""
    return SyncVectorEnv(
        [lambda: gym.make(env_id, **kwargs) for _ in range(num_envs)], autoreset_mode=mode
    )


def _actions(space: Any, steps: int, seed: int = 11) -> list[np.ndarray]:
    """Random actions, sub-env 0 spinning: its episodes end by a violation, the others' by the
    step limit, so the ends are staggered."""
    space.seed(seed)
    actions = [space.sample() for _ in range(steps)]
    for action in actions:
        action[0] = _SPIN
    return actions


def _assert_same(ours: tuple[Any, ...], theirs: tuple[Any, ...], where: str) -> None:
    names = ("observations", "rewards", "terminated", "truncated", "infos")
    for name, a, b in zip(names if len(ours) == 5 else names[::4], ours, theirs, strict=True):
        assert data_equivalence(a, b, exact=True), f"{where}: {name} differ:\n{a}\n{b}"


# ------------------------------------------------------------------------------------------
# autoreset_mode
# ------------------------------------------------------------------------------------------


def test_autoreset_mode_is_an_attribute_next_step_by_default() -> None:
    """``autoreset_mode`` is an attribute and a metadata entry (as Gymnasium's vector envs set
    both), NEXT_STEP unless the keyword says otherwise (an enum or its value); the class's
    metadata is not changed by an instance."""
    envs = _vec(STUDY_C, 2)
    assert isinstance(envs.unwrapped, SingleFollowerVectorEnv)
    assert envs.autoreset_mode is AutoresetMode.NEXT_STEP
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    for given, mode in (
        (AutoresetMode.SAME_STEP, AutoresetMode.SAME_STEP),
        ("SameStep", AutoresetMode.SAME_STEP),
        (AutoresetMode.DISABLED, AutoresetMode.DISABLED),
        ("NextStep", AutoresetMode.NEXT_STEP),
    ):
        other = _vec(STUDY_C, 2, autoreset_mode=given)
        assert other.autoreset_mode is mode and other.metadata["autoreset_mode"] is mode
    assert SingleFollowerVectorEnv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    with pytest.raises(ValueError, match=r"autoreset_mode: expected one of .*'same_step'"):
        _vec(STUDY_C, 2, autoreset_mode="same_step")


def test_vector_kwargs_reach_only_gymnasiums_own_vectorisation() -> None:
    """Gymnasium 1.x's ``make_vec`` refuses ``vector_kwargs`` for a vector entry point (its
    arguments come as keywords, ``autoreset_mode=...``); with ``vectorization_mode="sync"`` they
    reach ``SyncVectorEnv``. The two routes agree in the mode chosen."""
    with pytest.raises(gym.error.Error, match="vector_kwargs"):
        _vec(STUDY_C, 2, vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    sync = _vec(
        STUDY_C,
        2,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
    )
    assert isinstance(sync, SyncVectorEnv) and sync.autoreset_mode is AutoresetMode.SAME_STEP
    # The default of both routes is NEXT_STEP.
    assert _vec(STUDY_C, 2, vectorization_mode="sync").autoreset_mode is (
        _vec(STUDY_C, 2).autoreset_mode
    )


@pytest.mark.parametrize(
    ("env_id", "info_view", "normalize_actions"),
    [(STUDY_C, "rich", False), (STUDY_C, "numeric", True), (PROCEDURAL_ARUCO, "rich", True)],
)
def test_next_step_equals_sync_vector_env(
    env_id: str, info_view: str, normalize_actions: bool
) -> None:
    """NEXT_STEP step for step, infos included, against Gymnasium's ``SyncVectorEnv`` in that
    mode: the step after an end returns the reset's observation and info, reward 0.0, flags
    False, and ignores that sub-env's action (a NaN there raises nothing); a partial reset
    clears a pending autoreset of the sub-envs it resets only."""
    kwargs = {
        "max_episode_steps": 9,
        "info_view": info_view,
        "normalize_actions": normalize_actions,
    }
    ours = _vec(env_id, 3, **kwargs)
    theirs = _sync(env_id, 3, AutoresetMode.NEXT_STEP, **kwargs)
    seeds = [5, 6, 7]
    _assert_same(ours.reset(seed=seeds), theirs.reset(seed=seeds), "reset")
    pending = np.zeros(3, dtype=bool)
    resets = nan_rows = 0
    for t, action in enumerate(_actions(ours.action_space, 60)):
        if t == 30:  # a partial reset, whatever is pending
            mask = np.array([False, True, False])
            options = {"reset_mask": mask}
            _assert_same(
                ours.reset(seed=[None, 42, None], options=dict(options)),
                theirs.reset(seed=[None, 42, None], options=dict(options)),
                "partial reset",
            )
            pending &= ~mask
        if pending.any():
            action = action.copy()
            action[pending] = np.nan  # ignored by both
            nan_rows += 1
        step = ours.step(action)
        _assert_same(step, theirs.step(action), f"step {t}")
        _, rewards, terminated, truncated, _ = step
        assert not (rewards[pending].any() or terminated[pending].any() or truncated[pending].any())
        resets += int(pending.sum())
        assert "final_obs" not in step[4] and "final_info" not in step[4]
        pending = terminated | truncated
    assert resets >= 4 and nan_rows >= 4  # autoresets were compared
    ours.close()
    theirs.close()


def test_same_step_still_available_and_unchanged() -> None:
    """SAME_STEP by keyword: the results of the former default (``final_obs``/``final_info``,
    the reset within the ending step), equal to ``SyncVectorEnv`` in that mode."""
    kwargs = {"max_episode_steps": 9}
    ours = _vec(STUDY_C, 2, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    theirs = _sync(STUDY_C, 2, AutoresetMode.SAME_STEP, **kwargs)
    _assert_same(ours.reset(seed=[1, 2]), theirs.reset(seed=[1, 2]), "reset")
    finals = 0
    for t, action in enumerate(_actions(ours.action_space, 25)):
        step = ours.step(action)
        _assert_same(step, theirs.step(action), f"step {t}")
        finals += "final_obs" in step[4]
    assert finals >= 2


def test_disabled_refuses_to_step_an_ended_sub_env() -> None:
    """DISABLED: no autoreset; a step while a sub-env's episode has ended is a RuntimeError
    naming it (nothing changes), until a (partial) reset restarts it."""
    envs = _vec(STUDY_C, 2, max_episode_steps=3, autoreset_mode=AutoresetMode.DISABLED)
    twin = _vec(STUDY_C, 2, max_episode_steps=3)
    envs.reset(seed=[1, 2])
    twin.reset(seed=[1, 2])
    action = np.array([[0.3, 0.0], [0.2, 0.1]], dtype=np.float32)
    for _ in range(3):
        step = envs.step(action)
        _assert_same(step, twin.step(action), "DISABLED steps as NEXT_STEP until an end")
    assert step[3].all()
    with pytest.raises(RuntimeError, match=r"sub-env\(s\) \[0, 1\] ended .* DISABLED"):
        envs.step(action)
    envs.reset(seed=[None, 9], options={"reset_mask": np.array([False, True])})
    with pytest.raises(RuntimeError, match=r"sub-env\(s\) \[0\] ended"):
        envs.step(action)
    envs.reset(options={"reset_mask": np.array([True, False])})
    assert not envs.step(action)[3].any()


def test_disabled_equals_sync_vector_env_reset_by_mask() -> None:
    """DISABLED driven as TorchRL drives it (each ended sub-env reset by ``reset_mask``), step
    for step against ``SyncVectorEnv`` in that mode, numeric infos included."""
    kwargs = {"max_episode_steps": 9, "info_view": "numeric"}
    ours = _vec(STUDY_C, 3, autoreset_mode=AutoresetMode.DISABLED, **kwargs)
    theirs = _sync(STUDY_C, 3, AutoresetMode.DISABLED, **kwargs)
    _assert_same(ours.reset(seed=[3, 4, 5]), theirs.reset(seed=[3, 4, 5]), "reset")
    resets = 0
    for t, action in enumerate(_actions(ours.action_space, 40)):
        step = ours.step(action)
        _assert_same(step, theirs.step(action), f"step {t}")
        ended = step[2] | step[3]
        if ended.any():
            options = {"reset_mask": ended}
            _assert_same(
                ours.reset(options=dict(options)), theirs.reset(options=dict(options)), "mask"
            )
            resets += int(ended.sum())
    assert resets >= 4


def test_torchrl_gym_wrapper_route() -> None:
    """TorchRL's ``GymWrapper`` over ``make_vec`` (``docs/ecosystem.md``): it reads the
    ``autoreset_mode`` attribute, refuses NEXT_STEP and takes DISABLED (resetting ended
    sub-envs itself); with the numeric view it passes ``check_env_specs`` and rolls out
    through episode ends with int64 codes. Skipped unless TorchRL is installed."""
    pytest.importorskip("torchrl")
    from torchrl.envs import GymWrapper
    from torchrl.envs.libs.gym import default_info_dict_reader
    from torchrl.envs.utils import check_env_specs

    with pytest.raises(RuntimeError, match="SAME_STEP or DISABLED"):
        GymWrapper(_vec(STUDY_C, 2, info_view="numeric"))
    env = GymWrapper(
        _vec(
            STUDY_C,
            4,
            max_episode_steps=6,
            info_view="numeric",
            autoreset_mode=AutoresetMode.DISABLED,
        )
    )
    env.set_info_dict_reader(default_info_dict_reader())
    check_env_specs(env, seed=0)
    td = env.rollout(20, break_when_any_done=False)
    assert td.batch_size == (4, 20)
    assert int(td["next", "done"].sum()) >= 8  # every sub-env's episodes end by step 6
    assert str(td["next", "violation"].dtype) == "torch.int64"


# ------------------------------------------------------------------------------------------
# Gymnasium's vector wrappers over the default make_vec
# ------------------------------------------------------------------------------------------


def _wrapped(envs: Any) -> Any:
    """Gymnasium's vector wrappers, stacked as a training script would."""
    space = envs.single_observation_space
    wrapped: Any = vector_wrappers.TransformObservation(
        envs, lambda obs: np.clip(obs, space.low, space.high), envs.observation_space
    )
    wrapped = vector_wrappers.NormalizeObservation(wrapped)
    wrapped = vector_wrappers.NormalizeReward(wrapped, gamma=0.99)
    wrapped = vector_wrappers.RecordEpisodeStatistics(wrapped)
    return vector_wrappers.ClipAction(wrapped)


@pytest.mark.parametrize("env_id", [STUDY_C, PROCEDURAL_ARUCO])
def test_gymnasium_vector_wrappers_over_the_default(env_id: str) -> None:
    """TransformObservation, NormalizeObservation, NormalizeReward, RecordEpisodeStatistics and
    ClipAction wrap ``gymnasium.make_vec(id, 4)`` as it comes, through episode ends (by the
    step limit and by a violation): episode statistics at each end, with the lengths that the
    unwrapped env's own flags give."""
    envs = _wrapped(_vec(env_id, 4, max_episode_steps=8))
    plain = _vec(env_id, 4, max_episode_steps=8)
    obs, _ = envs.reset(seed=3)
    plain.reset(seed=3)
    assert obs.shape == (4, *plain.single_observation_space.shape)
    lengths = np.zeros(4, dtype=np.int64)
    pending = np.zeros(4, dtype=bool)
    ended = 0
    for action in _actions(plain.action_space, 30):
        action = action * 3.0  # out of the Box: ClipAction clips, as the env would
        obs, rewards, terminated, truncated, info = envs.step(action)
        expected = plain.step(np.clip(action, plain.action_space.low, plain.action_space.high))
        assert np.array_equal(terminated, expected[2]) and np.array_equal(truncated, expected[3])
        assert np.isfinite(obs).all() and np.isfinite(rewards).all()
        assert not rewards[pending].any()  # NEXT_STEP: the reset step, reward 0 (normalised)
        lengths = np.where(pending, 0, lengths + 1)
        done = terminated | truncated
        if done.any():
            assert info["_episode"].tolist() == done.tolist()
            assert info["episode"]["l"][done].tolist() == lengths[done].tolist()
            ended += int(done.sum())
        else:
            assert "episode" not in info
        pending = done
    assert ended >= 4 and (lengths <= 8).all()


def test_observation_wrappers_refuse_same_step() -> None:
    """Why NEXT_STEP is the default: Gymnasium's vector observation wrappers refuse SAME_STEP."""
    envs = _vec(STUDY_C, 2, autoreset_mode=AutoresetMode.SAME_STEP)
    with pytest.raises(ValueError, match="Expected autoreset_mode to be NEXT_STEP or DISABLED"):
        vector_wrappers.TransformObservation(envs, lambda obs: obs)
    with pytest.raises(ValueError, match="NEXT_STEP"):
        vector_wrappers.NormalizeObservation(envs)
    # The others take it.
    vector_wrappers.ClipAction(vector_wrappers.RecordEpisodeStatistics(envs))


def _numeric_leaves(info: dict[str, Any], where: str) -> int:
    """Every leaf of a batched info is an int64/float64 array (its ``_key`` mask bool)."""
    count = 0
    for key, value in info.items():
        if isinstance(value, dict):
            count += _numeric_leaves(value, f"{where}.{key}")
            continue
        assert isinstance(value, np.ndarray), f"{where}.{key} is {type(value)}"
        kinds = "b" if key.startswith("_") else "iuf"
        assert value.dtype.kind in kinds, f"{where}.{key} has dtype {value.dtype}"
        count += 1
    return count


def test_numeric_next_step_infos_are_arrays_only() -> None:
    """The route for TorchRL and BenchMARL (``docs/ecosystem.md``): ``info_view="numeric"``
    with the default NEXT_STEP gives infos of numeric arrays only, through episode ends and
    with Gymnasium's episode statistics on top, so each converts with ``torch.as_tensor``;
    the rich default (object arrays with None) does not."""
    torch = pytest.importorskip("torch")
    envs: Any = vector_wrappers.RecordEpisodeStatistics(
        _vec(STUDY_C, 2, max_episode_steps=6, info_view="numeric")
    )
    infos = [envs.reset(seed=[1, 2])[1]]
    for action in _actions(envs.action_space, 14):
        infos.append(envs.step(action)[4])
    for t, info in enumerate(infos):
        _numeric_leaves(info, f"step {t}")
        for value in info.values():
            if not isinstance(value, dict):
                torch.as_tensor(value)
    assert any("episode" in info for info in infos)
    rich = _vec(STUDY_C, 2)
    _, info = rich.reset(seed=[1, 2])
    with pytest.raises(TypeError, match=r"numpy\.object_"):
        torch.as_tensor(info["violation"])


# ------------------------------------------------------------------------------------------
# render_fps
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("control_period", [None, 0.02, 0.03])
def test_render_fps_is_the_steps_per_second(control_period: float | None) -> None:
    """``metadata["render_fps"]`` times the control period is 1 (one frame per step plays in
    real time) for the PettingZoo env (both forms), the Gymnasium env and the vector env, per
    instance: an env of another control period leaves the class's metadata alone."""
    kwargs = {} if control_period is None else {"control_period": control_period}
    envs: list[tuple[Any, float]] = []
    parallel = platoon_env.make("study_c", **kwargs)
    envs.append((parallel, parallel.control_period))
    envs.append((platoon_env.env("study_c", **kwargs), parallel.control_period))
    single = _make(STUDY_C, **kwargs)
    envs.append((single, single.unwrapped.parallel.control_period))
    vector = _vec(STUDY_C, 2, **kwargs)
    envs.append((vector, vector.unwrapped.batch.control_period))
    for env, period in envs:
        assert period == (0.01 if control_period is None else control_period)
        assert math.isclose(env.metadata["render_fps"] * period, 1.0), env
    if control_period in (None, 0.02):
        assert single.metadata["render_fps"] == round(1 / single.unwrapped.parallel.control_period)
        assert isinstance(single.metadata["render_fps"], int)
    assert platoon_env.PlatoonParallelEnv.metadata["render_fps"] == 100
    assert SingleFollowerEnv.metadata["render_fps"] == 100
    assert SingleFollowerVectorEnv.metadata["render_fps"] == 100


def test_record_video_plays_in_real_time(tmp_path: Path) -> None:
    """``RecordVideo`` writes the frames at the env's steps per second (needs moviepy)."""
    pytest.importorskip("moviepy")
    env = gym.wrappers.RecordVideo(
        gym.make(STUDY_C, render_mode="rgb_array", max_episode_steps=5),
        str(tmp_path),
        episode_trigger=lambda episode: episode == 0,
        disable_logger=True,
    )
    assert env.frames_per_sec == 100
    env.reset(seed=0)
    done = False
    while not done:
        *_, terminated, truncated, _ = env.step(np.array([0.3, 0.0], dtype=np.float32))
        done = terminated or truncated
    env.close()
    assert list(tmp_path.glob("*.mp4"))


# ------------------------------------------------------------------------------------------
# max_episode_steps of the specs
# ------------------------------------------------------------------------------------------


def _step_limit_bound(env_id: str) -> int:
    """:data:`GYM_STEP_LIMITS`' rule, recomputed: a study's own step limit; a procedural
    family's at its longest path (40 m) and slowest leader."""
    kwargs = dict(platoon_env.GYM_IDS[env_id])
    scenario = kwargs.pop("scenario")
    source = scenario_source(scenario, single_follower(kwargs, scenario))
    cfg = source.config
    if cfg.generator is None:
        return int(source.initial().max_episode_steps)
    speed = cfg.leader.speed
    if cfg.generator.formation is not None:
        speed = formation_limits(cfg)["leader_speed"][0]
    slowest = dataclasses.replace(cfg, leader=dataclasses.replace(cfg.leader, speed=speed))
    return default_max_steps(slowest, 40.0)


@pytest.mark.parametrize("env_id", sorted(platoon_env.GYM_IDS))
def test_every_spec_has_a_step_limit(env_id: str) -> None:
    """``gymnasium.spec(id).max_episode_steps`` is a positive int, the rule recomputed; a study's
    ``TimeLimit`` (what ``gymnasium.make`` adds) stops at the env's own limit, a procedural
    family's at or beyond every sampled layout's own limit."""
    spec = gym.spec(env_id)
    limit = spec.max_episode_steps
    assert isinstance(limit, int) and limit > 0
    assert limit == GYM_STEP_LIMITS[platoon_env.GYM_IDS[env_id]["scenario"]]
    assert limit == _step_limit_bound(env_id)
    env = _make(env_id)
    assert isinstance(env, gym.wrappers.TimeLimit) and env._max_episode_steps == limit
    inner: Any = env.unwrapped
    own = []
    for seed in range(6 if "Procedural" in env_id else 1):
        env.reset(seed=seed)
        own.append(inner.parallel.max_episode_steps)
    if "Procedural" in env_id:
        assert max(own) <= limit
    else:
        assert own == [limit]


def test_make_vec_keeps_each_layouts_own_limit() -> None:
    """``make_vec`` does not pass the spec's limit on as a scenario option (the ids' kwargs
    hold ``max_episode_steps=None``): each procedural layout keeps its own, as the single env's;
    an explicit ``max_episode_steps`` still sets every sub-env's."""
    assert gym.spec(PROCEDURAL_ARUCO).kwargs["max_episode_steps"] is None
    envs = _vec(PROCEDURAL_ARUCO, 3)
    envs.reset(seed=[1, 2, 3])
    single = _make(PROCEDURAL_ARUCO)
    own = []
    for seed in (1, 2, 3):
        single.reset(seed=seed)
        own.append(single.unwrapped.parallel.max_episode_steps)
    assert envs.unwrapped.batch.step_limits.tolist() == own
    assert len(set(own)) > 1 and max(own) < gym.spec(PROCEDURAL_ARUCO).max_episode_steps
    fixed = _vec(PROCEDURAL_ARUCO, 2, max_episode_steps=7)
    fixed.reset(seed=[1, 2])
    assert fixed.unwrapped.batch.step_limits.tolist() == [7, 7]


def _episode_end(make: Callable[[], gym.Env[Any, Any]]) -> tuple[int, bool, bool]:
    env = make()
    env.reset(seed=0)
    steps, terminated, truncated = 0, False, False
    action = np.zeros(2, dtype=np.float32)
    while not (terminated or truncated):
        *_, terminated, truncated, _ = env.step(action)
        steps += 1
    return steps, terminated, truncated


def test_time_limit_ends_no_episode_earlier() -> None:
    """A whole study B episode (no violation ends it: ``terminate_on=()``; it ends when the
    leader has arrived and settled) ends at the same step, truncated, with the spec's
    ``TimeLimit`` and without it (``max_episode_steps=-1``: the env as registered before)."""
    with_limit = _episode_end(lambda: gym.make(STUDY_B, terminate_on=()))
    without = _episode_end(lambda: gym.make(STUDY_B, terminate_on=(), max_episode_steps=-1))
    assert with_limit == without
    steps, terminated, truncated = with_limit
    assert truncated and not terminated and steps < GYM_STEP_LIMITS["study_b"]
