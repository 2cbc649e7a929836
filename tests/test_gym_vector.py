"""The Gymnasium vector entry point of every id (platoon_env.gym_vector) and normalised actions.

Gymnasium 1.4 has no public checker for vector envs (``gymnasium.utils.env_checker.check_env``
takes a single ``gymnasium.Env``; ``gymnasium.utils.env_match`` compares two single envs), so
the checks its own test suite applies to ``SyncVectorEnv``/``AsyncVectorEnv``
(``tests/vector/test_vector_env.py``: batched spaces, reset/step types, seeded determinism,
final observation and info, partial reset) are written here, plus the strongest one: step for
step equality with Gymnasium's ``SyncVectorEnv`` of ``gymnasium.make(id)`` envs in the same
autoreset mode, infos included. These tests pin ``AutoresetMode.SAME_STEP`` (the default until
issue 45); the default ``NEXT_STEP`` and Gymnasium's vector wrappers are
``tests/test_gym_vector_wrappers.py``'s.
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import batch_space

import platoon_env
from platoon_env.action_range import ActionRange
from platoon_env.gym_env import GYM_OPTIONS
from platoon_env.gym_vector import VECTOR_OPTIONS, SingleFollowerVectorEnv, sub_env_seeds
from platoon_env.reward import REWARD_TERMS
from platoon_env.scenarios import ScenarioError
from platoon_env.scenarios.options import OVERRIDE_OPTIONS
from platoon_env.violations import VIOLATION_CODE_NAMES, mask_to_causes

STUDY_C = "platoon_env/SingleFollower-StudyC-v1"
#: A procedural tier with the aruco profile: layouts and sensor noise drawn from each env's RNG.
PROCEDURAL_ARUCO = "platoon_env/SingleFollower-ProceduralEasyTrain-Aruco-v1"


def single_envs(env_id: str, num_envs: int, **kwargs: Any) -> SyncVectorEnv:
    """Gymnasium's own vectorisation of ``gymnasium.make(env_id)``, in our autoreset mode."""
    return SyncVectorEnv(
        [lambda: gym.make(env_id, **kwargs) for _ in range(num_envs)],
        autoreset_mode=AutoresetMode.SAME_STEP,
    )


def assert_same(ours: tuple[Any, ...], theirs: tuple[Any, ...], where: str) -> None:
    """Two ``reset`` or ``step`` returns are identical, to the bit and the dtype."""
    names = ("observations", "rewards", "terminated", "truncated", "infos")
    for name, a, b in zip(names if len(ours) == 5 else names[::4], ours, theirs, strict=True):
        assert data_equivalence(a, b, exact=True), f"{where}: {name} differ:\n{a}\n{b}"


def run_against_single(
    env_id: str, seeds: list[int], actions: list[np.ndarray], **kwargs: Any
) -> list[dict[str, Any]]:
    """Step ``make_vec(env_id)`` and Gymnasium's vectorised single envs side by side (SAME_STEP),
    asserting equality at every step; returns our infos."""
    ours = gym.make_vec(
        env_id, num_envs=len(seeds), autoreset_mode=AutoresetMode.SAME_STEP, **kwargs
    )
    theirs = single_envs(env_id, len(seeds), **kwargs)
    assert_same(ours.reset(seed=seeds), theirs.reset(seed=seeds), "reset")
    infos = []
    for t, action in enumerate(actions):
        step = ours.step(action)
        assert_same(step, theirs.step(action), f"step {t}")
        infos.append(step[4])
    ours.close()
    theirs.close()
    return infos


@pytest.mark.parametrize("env_id", sorted(platoon_env.GYM_IDS))
def test_make_vec_every_id(env_id: str) -> None:
    """Every id builds the batched vector env by default, with the single env's spaces batched,
    and its first steps equal the single envs' (Gymnasium's checks of reset/step types)."""
    envs = gym.make_vec(env_id, num_envs=2)
    assert isinstance(envs.unwrapped, SingleFollowerVectorEnv)
    assert isinstance(
        gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point").unwrapped,
        SingleFollowerVectorEnv,
    )
    single = gym.make(env_id)
    assert envs.num_envs == 2
    assert envs.single_observation_space == single.observation_space
    assert envs.single_action_space == single.action_space
    assert envs.observation_space == batch_space(single.observation_space, 2)
    assert envs.action_space == batch_space(single.action_space, 2)
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP  # Gymnasium's default

    obs, info = envs.reset(seed=[1, 2])
    assert obs in envs.observation_space and isinstance(info, dict)
    envs.action_space.seed(0)
    actions = [envs.action_space.sample() for _ in range(3)]
    for action in actions:
        obs, rewards, terminated, truncated, info = envs.step(action)
        assert obs in envs.observation_space
        assert rewards.shape == (2,) and rewards.dtype == np.float64
        assert terminated.shape == truncated.shape == (2,)
        assert terminated.dtype == truncated.dtype == np.bool_
        assert isinstance(info, dict)
    envs.close()
    assert envs.closed
    envs.close()  # idempotent
    run_against_single(env_id, [1, 2], actions)


@pytest.mark.parametrize("env_id", [STUDY_C, PROCEDURAL_ARUCO])
@pytest.mark.parametrize("normalize_actions", [False, True])
def test_equals_single_env_through_autoresets(env_id: str, normalize_actions: bool) -> None:
    """Random actions over several short episodes: every return equals the single envs',
    ``final_obs``/``final_info`` included (the sub-envs of a procedural source draw their own
    layouts, those of the aruco profile their own sensor noise)."""
    kwargs = {"max_episode_steps": 7, "normalize_actions": normalize_actions}
    space = gym.make_vec(env_id, num_envs=3, **kwargs).action_space
    space.seed(4)
    actions = [space.sample() for _ in range(20)]
    infos = run_against_single(env_id, [10, 11, 12], actions, **kwargs)
    ended = [info["_final_obs"] for info in infos if "_final_obs" in info]
    assert len(ended) >= 2


def test_same_step_autoreset() -> None:
    """SAME_STEP exactly: the step that ends an episode returns its last reward and flags, the
    next episode's first observation and reset info, the last observation and info under
    ``final_*``; the sub-env then continues with its own RNG (as ``env.reset()``), and the
    others are untouched."""
    envs = gym.make_vec(
        STUDY_C, num_envs=2, max_episode_steps=3, autoreset_mode=AutoresetMode.SAME_STEP
    )
    single = gym.make(STUDY_C, max_episode_steps=3)
    other = gym.make(STUDY_C, max_episode_steps=3)
    envs.reset(seed=[5, 6])
    single.reset(seed=5)
    other.reset(seed=6)
    action = np.array([[0.2, 0.1], [0.3, -0.1]], dtype=np.float32)
    envs.step(action)
    single.step(action[0])
    # Sub-env 1 restarts: its episode is now one step behind sub-env 0's.
    obs, info = envs.reset(seed=[None, 7], options={"reset_mask": np.array([False, True])})
    assert info["_violation"].tolist() == [False, True]
    assert np.array_equal(obs[1], other.reset(seed=7)[0])
    for _ in range(2):
        obs, rewards, terminated, truncated, info = envs.step(action)
        last = single.step(action[0])
        other.step(action[1])
    assert truncated.tolist() == [True, False] and not terminated.any()
    assert rewards[0] == last[1]
    assert info["_final_obs"].tolist() == [True, False] and info["final_obs"][1] is None
    assert np.array_equal(info["final_obs"][0], last[0])
    assert info["final_info"]["_d"].tolist() == [True, False]
    assert info["final_info"]["d"][0] == last[4]["d"]
    assert info["final_info"]["reward_terms"]["alive"][0] == last[4]["reward_terms"]["alive"]
    first, first_info = single.reset()  # no seed: the env's RNG continues
    assert np.array_equal(obs[0], first)
    assert info["d"][0] == first_info["d"] and info["cost"][0] == 0
    assert not info["reward_terms"]["_alive"][0] and info["reward_terms"]["_alive"][1]
    # The next step is an ordinary step of the new episode (no reset-only step).
    obs, rewards, terminated, truncated, info = envs.step(action)
    step = single.step(action[0])
    assert np.array_equal(obs[0], step[0]) and rewards[0] == step[1]
    assert truncated.tolist() == [False, True] and "final_obs" in info


def test_seeding_distinct_per_sub_env() -> None:
    """One int seeds the sub-envs with independent SeedSequence streams; a list seeds them one
    by one; the same seed gives the same episode, and the sub-envs' starts differ."""
    seeds = sub_env_seeds(3, 4)
    assert seeds == [
        int(c.generate_state(1, dtype=np.uint64)[0]) for c in np.random.SeedSequence(3).spawn(4)
    ]
    assert len(set(seeds)) == 4 and not set(seeds) & set(sub_env_seeds(4, 4))
    assert sub_env_seeds(3, 2) == seeds[:2]  # more envs extend the list, not reshuffle it

    envs = gym.make_vec(STUDY_C, num_envs=4)
    obs, info = envs.reset(seed=3)
    assert len({row.tobytes() for row in obs}) == 4  # perturbed starts, one per stream
    by_list, list_info = envs.reset(seed=seeds)
    assert data_equivalence((obs, info), (by_list, list_info), exact=True)
    single = gym.make(STUDY_C)
    for i, seed in enumerate(seeds):
        assert np.array_equal(obs[i], single.reset(seed=seed)[0])
    # Unseeded resets continue each sub-env's RNG: new starts, reproducible from the seed.
    again, _ = envs.reset()
    assert not np.array_equal(again, obs)
    envs.reset(seed=3)
    assert np.array_equal(envs.reset()[0], again)


def test_reset_rejects_bad_seeds_and_options() -> None:
    envs = gym.make_vec(STUDY_C, num_envs=2)
    obs, _ = envs.reset(seed=[1, 2])
    with pytest.raises(ValueError, match="one seed per sub-env"):
        envs.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match=">= 0"):
        envs.reset(seed=[1, -2])
    with pytest.raises(TypeError, match="seed"):
        envs.reset(seed=[1, 2.5])
    with pytest.raises(TypeError, match="seed"):
        envs.reset(seed="12")
    with pytest.raises(ValueError, match="poses"):
        envs.reset(options={"poses": np.zeros((2, 3))})
    with pytest.raises(ScenarioError, match="perturb"):
        envs.reset(options={"perturb": "no"})
    for mask, error in (
        ([True, False], TypeError),
        (np.array([True]), ValueError),
        (np.array([1, 0]), TypeError),
        (np.array([False, False]), ValueError),
    ):
        with pytest.raises(error, match="reset_mask"):
            envs.reset(options={"reset_mask": mask})
    with pytest.warns(UserWarning, match="ignoring unknown option"):
        envs.reset(seed=[1, 2], options={"colour": "red"})
    # perturb=False starts every sub-env from the scenario's default configuration.
    plain, _ = envs.reset(seed=[1, 2], options={"perturb": False})
    assert np.array_equal(plain[0], plain[1]) and not np.array_equal(plain, obs)


def test_partial_reset_keeps_the_other_sub_envs() -> None:
    """Gymnasium's partial reset (``options["reset_mask"]``): the masked sub-envs restart from
    their seeds; the others keep their state and observation row."""
    envs = gym.make_vec(STUDY_C, num_envs=3)
    initial, _ = envs.reset(seed=[0, 1, 2])
    action = np.tile(np.array([0.4, 0.2], dtype=np.float32), (3, 1))
    for _ in range(3):
        stepped, *_ = envs.step(action)
    obs, info = envs.reset(seed=[0, 1, 0], options={"reset_mask": np.array([True, True, False])})
    assert np.array_equal(obs[:2], initial[:2]) and np.array_equal(obs[2], stepped[2])
    assert info["_cost"].tolist() == [True, True, False]
    single = gym.make(STUDY_C)
    single.reset(seed=2)
    for _ in range(4):
        last = single.step(action[2])
    assert np.array_equal(envs.step(action)[0][2], last[0])


def test_returned_data_not_reused() -> None:
    """A later step or reset does not change arrays returned before (Gymnasium's
    ``check_returned_data_not_reused``, for a vector env)."""
    envs = gym.make_vec(
        STUDY_C, num_envs=2, max_episode_steps=2, autoreset_mode=AutoresetMode.SAME_STEP
    )
    obs0, info0 = envs.reset(seed=[1, 2])
    kept = (obs0.copy(), {k: np.copy(v) for k, v in info0.items() if k != "reward_terms"})
    action = np.full((2, 2), 0.3, dtype=np.float32)
    step1 = envs.step(action)
    copy1 = [np.copy(x) for x in step1[:4]]
    envs.step(action)  # ends both episodes: resets in place
    envs.reset(seed=[3, 4])
    assert np.array_equal(obs0, kept[0])
    assert all(np.array_equal(info0[k], v) for k, v in kept[1].items())
    assert all(np.array_equal(a, b) for a, b in zip(step1[:4], copy1, strict=True))


@pytest.mark.parametrize("normalize_actions", [False, True])
def test_bad_actions_raise_and_change_nothing(normalize_actions: bool) -> None:
    envs = gym.make_vec(STUDY_C, num_envs=2, normalize_actions=normalize_actions)
    twin = gym.make_vec(STUDY_C, num_envs=2, normalize_actions=normalize_actions)
    envs.reset(seed=[8, 9])
    twin.reset(seed=[8, 9])
    good = np.array([[0.5, 0.1], [0.2, -0.3]], dtype=np.float32)
    envs.step(good)
    twin.step(good)
    nan = good.copy()
    nan[1, 1] = np.nan
    for bad, error, match in (
        (good[0], ValueError, "shape"),
        (np.zeros((2, 3)), ValueError, "shape"),
        (np.zeros((3, 2)), ValueError, "shape"),
        (np.full((2, 2), "0.3"), TypeError, "real numbers"),
        (nan, ValueError, "NaN or inf"),
        (np.where(np.isnan(nan), np.inf, nan), ValueError, "NaN or inf"),
    ):
        with pytest.raises(error, match=match):
            envs.step(bad)
    assert_same(envs.step(good), twin.step(good), "after the bad actions")


def test_single_env_bad_normalised_actions_change_nothing() -> None:
    env = gym.make(STUDY_C, normalize_actions=True).unwrapped
    twin = gym.make(STUDY_C, normalize_actions=True).unwrapped
    env.reset(seed=3)
    twin.reset(seed=3)
    for bad, error in (
        (np.zeros(3), ValueError),
        (np.float32(0.5), ValueError),
        (np.array(["1", "0"]), TypeError),
        (np.array([np.nan, 0.0]), ValueError),
    ):
        with pytest.raises(error):
            env.step(bad)
    good = np.array([0.3, -0.2], dtype=np.float32)
    assert data_equivalence(env.step(good), twin.step(good), exact=True)


def test_normalised_action_mapping() -> None:
    """[-1, 1] maps affinely onto the default ActionRange (u in [-0.5, 1.5] m/s, omega in
    +-2 rad/s), clipped outside; a normalised env equals a physical one fed the mapped actions."""
    space = gym.make(STUDY_C, normalize_actions=True).action_space
    assert space == gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
    default = ActionRange()
    corners = np.array([[-1, -1], [1, 1], [0, 0], [5, -5], [-0.5, 0.25]], dtype=np.float32)
    expected = [[-0.5, -2.0], [1.5, 2.0], [0.5, 0.0], [1.5, -2.0], [0.0, 0.5]]
    assert np.allclose(default.to_physical(corners), expected)

    custom = {"u_low": 0.0, "u_high": 1.0, "omega_high": 1.0}
    normalised = gym.make_vec(STUDY_C, num_envs=2, normalize_actions=True, action_range=custom)
    physical = gym.make_vec(STUDY_C, num_envs=2)
    assert normalised.single_action_space == space
    assert normalised.unwrapped.action_range == ActionRange(**custom)
    normalised.reset(seed=[1, 2])
    physical.reset(seed=[1, 2])
    action = np.array([[0.6, -0.4], [-1.0, 2.0]], dtype=np.float32)
    mapped = np.array([[0.8, -0.4], [0.0, 1.0]], dtype=np.float32)
    assert_same(normalised.step(action), physical.step(mapped), "normalised vs mapped")


def test_normalised_action_options_are_checked() -> None:
    with pytest.raises(ValueError, match="actuator limits"):
        gym.make(STUDY_C, normalize_actions=True, u_max=1.0)
    with pytest.raises(ValueError, match="actuator limits"):
        gym.make_vec(STUDY_C, normalize_actions=True, action_range={"omega_high": 20.0})
    with pytest.raises(ValueError, match="needs normalize_actions"):
        gym.make(STUDY_C, action_range=ActionRange())
    with pytest.raises(ScenarioError, match="normalize_actions"):
        gym.make_vec(STUDY_C, normalize_actions=1)
    with pytest.raises(TypeError, match="action_range"):
        gym.make(STUDY_C, normalize_actions=True, action_range=(0.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="u_low < u_high"):
        gym.make(STUDY_C, normalize_actions=True, action_range={"u_low": 1.0, "u_high": 0.0})


def test_checkers_accept_normalised_actions() -> None:
    """Gymnasium's and SB3's env checkers pass the normalised env without the action-box
    warning that they give the physical one."""
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    def box_warnings(env: gym.Env[Any, Any]) -> list[str]:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sb3_check_env(env)
        return [str(w.message) for w in caught if "normalized Box action space" in str(w.message)]

    assert box_warnings(gym.make(STUDY_C).unwrapped)
    normalised = gym.make(STUDY_C, normalize_actions=True).unwrapped
    assert box_warnings(normalised) == []
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*normalized space.*")
        check_env(normalised, skip_render_check=True)


def test_render_matches_single_env() -> None:
    envs = gym.make_vec(STUDY_C, num_envs=2, render_mode="rgb_array")
    single = gym.make(STUDY_C, render_mode="rgb_array")
    envs.reset(seed=[4, 5])
    single.reset(seed=5)
    action = np.array([[0.3, 0.0], [0.4, 0.5]], dtype=np.float32)
    envs.step(action)
    single.step(action[1])
    frames = envs.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    assert frames[0].dtype == np.uint8 and frames[0].shape == frames[1].shape
    assert np.array_equal(frames[1], single.render())
    envs.close()
    with pytest.raises(ValueError, match="render_mode"):
        gym.make_vec(STUDY_C, render_mode="human")
    plain = gym.make_vec(STUDY_C, num_envs=1)
    plain.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert plain.render() is None


# ------------------------------------------------------------------------------------------
# info_view="numeric" and unknown keywords (issue 25)
# ------------------------------------------------------------------------------------------

#: Sub-env 0 spins in place (out_of_fov ends its episodes after about 20 steps on study_c, 50
#: on the procedural tier), sub-env 1 drives randomly.
_SPIN = np.array([0.0, 2.0], dtype=np.float32)


def _spin_and_random(space: gym.spaces.Box, steps: int) -> list[np.ndarray]:
    space.seed(11)
    actions = [space.sample() for _ in range(steps)]
    for action in actions:
        action[0] = _SPIN
    return actions


def _numeric_arrays(info: dict[str, Any], where: str) -> None:
    """Every entry of a batched numeric-view info is an int64 or float64 array over the
    sub-envs (its ``_key`` mask bool); ``final_info`` likewise. ``final_obs`` is Gymnasium's
    own object array of observations (None for sub-envs that did not end), not an info value."""
    for key, value in info.items():
        if key in ("final_obs", "_final_obs"):
            continue
        if key == "final_info":
            _numeric_arrays(value, f"{where} final_info")
            continue
        assert isinstance(value, np.ndarray), f"{where}: {key} is {type(value)}"
        expected = np.bool_ if key.startswith("_") else (np.int64, np.float64)
        assert value.dtype in np.atleast_1d(expected), f"{where}: {key} has dtype {value.dtype}"


@pytest.mark.parametrize("env_id", [STUDY_C, PROCEDURAL_ARUCO])
@pytest.mark.parametrize("diagnostics", [True, False])
def test_numeric_info_view_equals_single_envs(env_id: str, diagnostics: bool) -> None:
    """make_vec(..., info_view="numeric") through "vector_entry_point": every return, infos and
    final infos included, equals Gymnasium's SyncVectorEnv of the numeric single envs (bit and
    dtype), the infos hold only int64/float64 arrays, with the same keys at reset and every
    step."""
    kwargs = {"max_episode_steps": 60, "diagnostics": diagnostics, "info_view": "numeric"}
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    assert isinstance(envs.unwrapped, SingleFollowerVectorEnv)
    assert envs.unwrapped.info_view == "numeric"
    _, reset_info = envs.reset(seed=[3, 4])
    _numeric_arrays(reset_info, "reset")
    keys = [k for k in reset_info if not k.startswith("_")]
    if diagnostics:
        assert keys[:3] == ["violation", "violation_mask", "cost"]
        assert [f"reward_{t}" for t in REWARD_TERMS] == keys[-len(REWARD_TERMS) :]
        assert all(reset_info[f"reward_{t}"].tolist() == [0.0, 0.0] for t in REWARD_TERMS)
    else:
        assert keys == ["violation", "violation_mask", "cost"]
    actions = _spin_and_random(envs.action_space, 130)
    infos = run_against_single(env_id, [3, 4], actions, **kwargs)
    for t, info in enumerate(infos):
        _numeric_arrays(info, f"step {t}")
        assert [k for k in info if not k.startswith(("_", "final_"))] == keys
        if "final_info" in info:
            assert [k for k in info["final_info"] if not k.startswith("_")] == keys
    assert sum("final_info" in info for info in infos) >= 3  # autoresets were compared
    # and nonzero codes (the step that ends an episode holds its violation in final_info)
    assert any(info["final_info"]["violation"].any() for info in infos if "final_info" in info)


def _rows(info: dict[str, Any], i: int) -> dict[str, Any]:
    """Sub-env ``i``'s entries of a batched info (the keys its masks hold)."""
    out = {}
    for key, value in info.items():
        if key.startswith("_") or key in ("final_obs", "final_info"):
            continue
        if isinstance(value, dict):
            out[key] = _rows(value, i)
        elif info[f"_{key}"][i]:
            out[key] = value[i]
    return out


def _assert_same_content(rich: dict[str, Any], num: dict[str, Any], where: str) -> None:
    """One sub-env's rich and numeric info hold the same values where both have them."""
    assert VIOLATION_CODE_NAMES[num["violation"]] == (rich["violation"] or "none"), where
    assert mask_to_causes(int(num["violation_mask"])) == rich["violations"], where
    assert num["cost"] == rich["cost"], where
    if "d" not in rich:
        assert set(num) == {"violation", "violation_mask", "cost"}, where
        return
    for key in ("d", "beta", "e_d", "e_beta", "d_W_l", "d_W_r", "d_l", "d_r", "clearance"):
        assert num[key] == rich[key], f"{where}: {key}"
    assert num["visible"] == int(rich["visible"]), where
    for term in REWARD_TERMS:
        # A reset's rich info has no reward terms (masked out); the numeric view says 0.0.
        assert num[f"reward_{term}"] == rich["reward_terms"].get(term, 0.0), f"{where}: {term}"


@pytest.mark.parametrize("diagnostics", [True, False])
def test_numeric_info_view_holds_the_rich_views_values(diagnostics: bool) -> None:
    """The numeric vector env and the rich one, seeded and driven alike through autoresets:
    the same sub-envs report, and each value is the rich one's as a number (the violation as
    its VIOLATION_CODE_NAMES code, the causes as their bit mask, visible as 0/1, the reward
    terms flat), in the step infos and the final infos."""
    kwargs: dict[str, Any] = {
        "num_envs": 2,
        "max_episode_steps": 30,
        "diagnostics": diagnostics,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }
    rich = gym.make_vec(STUDY_C, **kwargs)
    num = gym.make_vec(STUDY_C, info_view="numeric", **kwargs)
    pairs = [(rich.reset(seed=[5, 6])[1], num.reset(seed=[5, 6])[1])]
    codes = set()
    for action in _spin_and_random(rich.action_space, 70):
        pairs.append((rich.step(action)[4], num.step(action)[4]))
    for t, (info_r, info_n) in enumerate(pairs):
        for block in ("", "final_info"):
            r, n = (info_r.get(block), info_n.get(block)) if block else (info_r, info_n)
            assert (r is None) == (n is None), f"step {t}: {block}"
            if r is None:
                continue
            assert r["_violation"].tolist() == n["_violation"].tolist()
            for i in np.flatnonzero(r["_violation"]):
                _assert_same_content(_rows(r, i), _rows(n, i), f"step {t} {block} env {i}")
                codes.add(int(n["violation"][i]))
    assert codes - {0}, "no violation was compared"


def test_unknown_keyword_is_pythons_type_error() -> None:
    """make_vec() and make() word an unknown keyword as Python does (the phrase TorchRL and
    others match), listing the scenario options and each env's own keywords."""
    for call, where, own in (
        (gym.make_vec, "make_vec()", VECTOR_OPTIONS),
        (gym.make, "make()", GYM_OPTIONS),
    ):
        with pytest.raises(TypeError) as exc:
            call(STUDY_C, frameskip=4)
        message = str(exc.value)  # gymnasium.make() appends where it was raised
        assert message.startswith(f"{where} got an unexpected keyword argument 'frameskip' ")
        listed = message.split("(valid keywords: ", 1)[1].split(")", 1)[0].split(", ")
        assert listed == [*OVERRIDE_OPTIONS, *own]
    assert VECTOR_OPTIONS == (*GYM_OPTIONS, "n_threads", "autoreset_mode")
    with pytest.raises(TypeError, match=r"'fps' \(and 'speed'\) \(valid keywords: "):
        SingleFollowerVectorEnv(2, "study_c", fps=25, speed=1)
    with pytest.raises(ScenarioError, match=r"^make_vec\(\): info_view: expected one of "):
        gym.make_vec(STUDY_C, info_view="torchrl")
    # Every listed keyword is taken (None: a scenario option left at its value).
    envs = gym.make_vec(
        STUDY_C, num_envs=1, info_view="rich", diagnostics=False, n_threads=1, u_max=None
    )
    keys = {"violation", "violations", "cost"}
    assert set(envs.reset(seed=0)[1]) == keys | {f"_{k}" for k in keys}
