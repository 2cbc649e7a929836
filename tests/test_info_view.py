"""The numeric info view (``make(..., info_view="numeric")``) and ``make()``'s TypeError for an
unknown keyword, worded as Python words it (issue 25: TorchRL's PettingZooWrapper and GymEnv)."""

from __future__ import annotations

import pickle
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import platoon_env
from platoon_env.env import ENV_OPTIONS, INFO_VIEWS
from platoon_env.reward import REWARD_TERMS
from platoon_env.scenarios.options import OVERRIDE_OPTIONS, apply_overrides, unexpected_keyword
from platoon_env.scenarios.schema import ScenarioError
from platoon_env.violations import (
    VIOLATION_CAUSES,
    VIOLATION_CODE_NAMES,
    VIOLATION_NUMERIC_INFO,
    mask_to_causes,
    violation_cause,
    violation_code,
)

#: Actions that end the corridor's episode by different causes (see tests/test_env.py), and a
#: seeded random policy.
_DRIVES: dict[str, Any] = {
    "ram": np.array([5.0, 0.0]),  # collision_robot
    "still": np.array([0.0, 0.0]),  # out_of_range
    "spin": np.array([0.0, 2.0]),  # out_of_fov
    "random": None,
}


def _numeric(value: Any) -> bool:
    """A numpy integer or float scalar (array-minded readers look at its ``dtype``; a bool is
    not a number here)."""
    return isinstance(value, np.integer | np.floating) and value.shape == ()


def _paired_rollout(
    scenario: Any, drive: str, diagnostics: bool, steps: int = 400
) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """(rich info, numeric info) of the same agents, reset first, from two envs driven alike."""
    rich = platoon_env.make(scenario, diagnostics=diagnostics)
    num = platoon_env.make(scenario, diagnostics=diagnostics, info_view="numeric")
    _, info_r = rich.reset(seed=3)
    _, info_n = num.reset(seed=3)
    pairs = [(info_r, info_n)]
    rng = np.random.default_rng(7)
    for _ in range(steps):
        if not rich.agents:
            break
        space = rich.action_space(rich.agents[0])
        fixed = _DRIVES[drive]
        actions = {
            a: fixed if fixed is not None else rng.uniform(space.low, space.high)
            for a in rich.agents
        }
        *_, info_r = rich.step(actions)
        *_, info_n = num.step(actions)
        pairs.append((info_r, info_n))
    assert not num.agents and not rich.agents, "the episode should have ended"
    return pairs


@pytest.mark.parametrize("diagnostics", [True, False])
@pytest.mark.parametrize("drive", list(_DRIVES))
def test_numeric_view_matches_the_rich_view(
    corridor: dict[str, Any], drive: str, diagnostics: bool
) -> None:
    pairs = _paired_rollout(corridor, drive, diagnostics)
    seen = set()
    for step, (rich, num) in enumerate(pairs):
        assert rich.keys() == num.keys()
        for agent in rich:
            r, n = rich[agent], num[agent]
            assert VIOLATION_CODE_NAMES[n["violation"]] == (r["violation"] or "none")
            assert violation_cause(n["violation"]) == r["violation"]
            assert mask_to_causes(n["violation_mask"]) == r["violations"]
            assert n["cost"] == r["cost"]
            seen.add(r["violation"])
            if not diagnostics:
                assert set(n) == {"violation", "violation_mask", "cost"}
                continue
            for key in ("d", "beta", "e_d", "e_beta", "d_W_l", "d_W_r", "d_l", "d_r"):
                assert n[key] == r[key], key
            assert n["clearance"] == r["clearance"]
            assert n["visible"] == int(r["visible"])
            for term in REWARD_TERMS:
                expected = 0.0 if step == 0 else r["reward_terms"][term]
                assert n[f"reward_{term}"] == expected, term
    # The episode ended by a violation (or, for the random drive, at least ran), so a nonzero
    # code was compared, not only zeros.
    assert seen - {None}


@pytest.mark.parametrize("diagnostics", [True, False])
@pytest.mark.parametrize("scenario", ["study_a", "study_c"])
def test_numeric_view_has_fixed_keys_and_only_numbers(scenario: str, diagnostics: bool) -> None:
    env = platoon_env.make(scenario, diagnostics=diagnostics, info_view="numeric")
    _, infos = env.reset(seed=0)
    keys = {agent: list(info) for agent, info in infos.items()}
    assert set(keys) == set(env.possible_agents)
    rng = np.random.default_rng(0)
    history = [infos]
    while env.agents:
        space = env.action_space(env.agents[0])
        *_, infos = env.step({a: rng.uniform(space.low, space.high) for a in env.agents})
        history.append(infos)
    for infos in history:
        for agent, info in infos.items():
            assert list(info) == keys[agent]  # same keys, same order, at reset and every step
            bad = {k: v for k, v in info.items() if not _numeric(v)}
            assert not bad, f"non-numeric info values: {bad}"
    assert all(info["violation"].dtype == np.int64 for info in history[-1].values())


def test_rich_view_is_the_default(corridor: dict[str, Any]) -> None:
    env = platoon_env.make(corridor)
    assert env.info_view == "rich" == INFO_VIEWS[0]
    _, infos = env.reset(seed=0)
    assert infos["follower_1"]["violation"] is None
    assert infos["follower_1"]["violations"] == ()
    assert infos["follower_1"]["reward_terms"] == {}


def test_numeric_view_through_the_gymnasium_ids() -> None:
    env = gym.make("platoon_env/SingleFollower-StudyC-v1", info_view="numeric")
    _, info = env.reset(seed=0)
    keys = list(info)
    assert info["violation"] == 0 and all(_numeric(v) for v in info.values())
    terminated = truncated = False
    while not (terminated or truncated):
        *_, terminated, truncated, info = env.step(np.array([0.0, 2.0]))  # spin: out_of_fov
        assert list(info) == keys and all(_numeric(v) for v in info.values())
    assert terminated and info["violation"] == violation_code("out_of_fov")
    env.close()


def test_numeric_view_survives_pickling(corridor: dict[str, Any]) -> None:
    env = pickle.loads(pickle.dumps(platoon_env.make(corridor, info_view="numeric")))
    _, infos = env.reset(seed=0)
    assert env.info_view == "numeric" and infos["follower_1"]["violation"] == 0


@pytest.mark.parametrize("bad", ["torchrl", "", None, 1, "Numeric"])
def test_bad_info_view_is_a_scenario_error_naming_it(bad: Any) -> None:
    with pytest.raises(ScenarioError, match=r"^make\(\): info_view: expected one of 'rich', "):
        platoon_env.make("study_c", info_view=bad)


def test_violation_code_table() -> None:
    assert VIOLATION_CODE_NAMES == ("none", *VIOLATION_CAUSES)
    assert violation_code(None) == 0 and violation_cause(0) is None
    for k, cause in enumerate(VIOLATION_CAUSES):
        assert violation_code(cause) == k + 1
        assert violation_cause(k + 1) == cause
    # The first cause's code is that of the lowest set bit (the reporting order).
    for mask, (code, same_mask, cost) in enumerate(VIOLATION_NUMERIC_INFO):
        assert same_mask == mask and cost == (1 if mask else 0)
        causes = mask_to_causes(mask)
        assert code == (violation_code(causes[0]) if causes else 0)
    with pytest.raises(ValueError, match="unknown violation cause 'crash'"):
        violation_code("crash")
    with pytest.raises(ValueError, match=r"violation code must be in 0\.\.5, got 6"):
        violation_cause(6)


# ------------------------------------------------------------------------------------------
# Unknown keywords: Python's TypeError wording
# ------------------------------------------------------------------------------------------


def test_unknown_keyword_is_pythons_type_error_listing_valid_ones() -> None:
    with pytest.raises(TypeError) as exc:
        platoon_env.make("study_c", frameskip=1)
    message = str(exc.value)
    # The phrase TorchRL's GymEnv matches to drop its frameskip keyword.
    assert message.startswith("make() got an unexpected keyword argument 'frameskip' ")
    assert "unexpected keyword argument 'frameskip'" in message
    listed = message.split("(valid keywords: ", 1)[1].rstrip(")").split(", ")
    assert listed == [*OVERRIDE_OPTIONS, *ENV_OPTIONS]


def test_several_unknown_keywords_are_all_named() -> None:
    with pytest.raises(TypeError, match=r"argument 'u_maxx' \(and 'speed', 'fps'\) \(valid"):
        platoon_env.make("study_c", u_maxx=1.0, speed=2, fps=3)


def test_unknown_keyword_through_gymnasium_and_the_aec_env() -> None:
    with pytest.raises(TypeError, match=r"make\(\) got an unexpected keyword argument 'frameskip'"):
        gym.make("platoon_env/SingleFollower-StudyC-v1", frameskip=4)
    with pytest.raises(TypeError, match=r"make\(\) got an unexpected keyword argument 'fps'"):
        platoon_env.env("study_c", fps=3)


def test_env_keywords_and_scenario_options_are_still_accepted() -> None:
    env = platoon_env.make(
        "study_c", render_mode=None, diagnostics=False, info_view="numeric", u_max=2.0
    )
    assert env.action_space("follower_1").high[0] == np.float32(2.0)


def test_apply_overrides_words_unknown_options_alike() -> None:
    from platoon_env.scenarios.loader import load_config

    with pytest.raises(TypeError) as exc:
        apply_overrides(load_config("study_c"), {"nope": 1}, where="BatchedPlatoon()")
    assert str(exc.value).startswith("BatchedPlatoon() got an unexpected keyword argument 'nope'")
    with pytest.raises(ValueError, match="at least one unknown keyword"):
        unexpected_keyword("make()", [], OVERRIDE_OPTIONS)


def test_the_published_code_table_matches_the_code() -> None:
    """docs/api.md's table of violation codes is VIOLATION_CODE_NAMES, row for row."""
    import re
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "api.md").read_text(encoding="utf-8")
    table = text.split("| code | cause |", 1)[1].split("\n\n", 1)[0]
    rows = re.findall(r"^\| (\d+) \| `?([a-z_]+)`? \|$", table, flags=re.MULTILINE)
    assert [(int(code), name) for code, name in rows] == list(enumerate(VIOLATION_CODE_NAMES))
