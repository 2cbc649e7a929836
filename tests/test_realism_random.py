"""Randomised realism (``realism`` block, :mod:`platoon_env.realism`, ``docs/realism.md``):
each episode draws its sensing and actuation realism from ranges, from the env's own RNG."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
import yaml

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.core import params_of
from platoon_env.realism import (
    FIELDS,
    REALISM_PRESETS,
    draw_realism,
    max_latency_steps,
    ranges_of,
)
from platoon_env.scenarios.options import apply_overrides
from platoon_env.scenarios.profiles import load_profile
from platoon_env.scenarios.schema import (
    ScenarioError,
    config_to_mapping,
    has_realism,
    parse_scenario,
)

PRESET = "ideal_to_beyond_aruco"
SCENARIO = "study_c"
DT = 0.01  # study C's control period


def _env(**overrides: Any) -> Any:
    return platoon_env.make(SCENARIO, realism={"preset": PRESET}, **overrides)


def _rollout(env: Any, seed: int, steps: int = 60) -> tuple[dict[str, float], np.ndarray]:
    """The drawn realism and the observations of a seeded episode under a fixed command."""
    obs, info = env.reset(seed=seed)
    drawn = info["follower_1"].get("realism", {})
    rows = [np.concatenate([obs[a] for a in env.agents])]
    for _ in range(steps):
        obs, _, term, trunc, _ = env.step({a: np.array([0.25, 0.0]) for a in env.agents})
        rows.append(np.concatenate([obs[a] for a in obs]))
        if any(term.values()) or any(trunc.values()):
            break
    return drawn, np.array(rows)


def _within(key: str, value: float, lo: float, hi: float | None) -> bool:
    if key == "camera.frame_rate":  # a rate above 1 / dt is a frame every step, 1 / dt
        return lo - 1e-9 <= value <= (1.0 / DT if hi is None else hi) + 1e-9
    return lo - 1e-12 <= value <= (math.inf if hi is None else hi) + 1e-12


def test_draws_lie_in_the_preset_ranges() -> None:
    env = _env()
    ranges = REALISM_PRESETS[PRESET]
    for seed in range(40):
        _, info = env.reset(seed=seed)
        drawn = info["follower_1"]["realism"]
        assert set(drawn) == set(ranges)
        for key, (lo, hi) in ranges.items():
            assert _within(key, drawn[key], lo, hi), (seed, key, drawn[key])
        steps = drawn["camera.latency"] / DT
        assert abs(steps - round(steps)) < 1e-9  # whole control periods


def test_same_seed_same_draw_and_episode() -> None:
    env = _env()
    first = _rollout(env, 7)
    _rollout(env, 8)  # another episode in between
    again = _rollout(env, 7)
    assert first[0] == again[0]
    np.testing.assert_array_equal(first[1], again[1])
    other = platoon_env.make(SCENARIO, realism={"preset": PRESET})
    assert _rollout(other, 7)[0] == first[0]  # a second env draws the same


def test_episodes_draw_different_values() -> None:
    env = _env()
    env.reset(seed=3)
    draws = [env.reset()[1]["follower_1"]["realism"] for _ in range(6)]
    for key in REALISM_PRESETS[PRESET]:
        values = {d[key] for d in draws}
        # Latency takes 9 values (0 .. 8 control periods): 6 draws may repeat some.
        assert len(values) >= (2 if key == "camera.latency" else 6), key


def test_info_holds_the_values_at_reset_and_every_step() -> None:
    env = _env(diagnostics=False)
    _, info = env.reset(seed=1)
    drawn = info["follower_1"]["realism"]
    assert all(isinstance(v, float) for v in drawn.values())
    assert all(i["realism"] == drawn for i in info.values())
    for _ in range(3):
        _, _, _, _, info = env.step({a: np.zeros(2) for a in env.agents})
        assert all(i["realism"] == drawn for i in info.values())
    # What info reports is what the compiled step reads.
    p = env._core.params[0]
    assert p["noise_bearing"] == drawn["camera.noise.bearing"]
    assert p["latency_steps"] == round(drawn["camera.latency"] / DT)
    assert 1.0 / max(p["frame_period"], DT) == drawn["camera.frame_rate"]
    assert p["accel_max"] == drawn["robot.accel_max"]


def test_without_the_block_nothing_changes() -> None:
    env = platoon_env.make(SCENARIO)
    _, info = env.reset(seed=0)
    assert "realism" not in info["follower_1"]
    _, _, _, _, info = env.step({a: np.zeros(2) for a in env.agents})
    assert "realism" not in info["follower_1"]
    cfg = env.scenario.config
    assert cfg.realism is None and "realism" not in config_to_mapping(cfg)
    assert env._core.params[0].tobytes() == params_of(cfg, env.max_episode_steps).tobytes()


def test_ranges_pinned_at_ideal_run_the_ideal_episode_bit_for_bit() -> None:
    """The draw comes after every other draw of a reset, so a block that draws the ideal
    values (a frame every step, no latency, no noise, every detection) runs the ideal episode
    exactly; an acceleration bound of 10^9 m/s^2 never binds."""
    ideal = {
        "camera.noise.position": [0.0, 0.0],
        "camera.noise.position_per_m": [0.0, 0.0],
        "camera.noise.bearing": [0.0, 0.0],
        "camera.detection": [1.0, 1.0],
        "camera.detection_edge": [0.0, 0.0],
        "camera.frame_rate": [1.0 / DT, None],
        "camera.latency": [0.0, 0.0],
        "proximity.noise": [0.0, 0.0],
        "robot.accel_max": [1e9, None],
    }
    pinned = platoon_env.make(SCENARIO, realism=ideal)
    plain = platoon_env.make(SCENARIO)
    for seed in (0, 1):
        a, b = _rollout(pinned, seed, steps=120), _rollout(plain, seed, steps=120)
        assert a[0]["camera.latency"] == 0.0 and b[0] == {}
        np.testing.assert_array_equal(a[1], b[1])
        np.testing.assert_array_equal(pinned.poses, plain.poses)


def test_drawn_params_equal_params_of_the_fixed_config() -> None:
    """The draw writes the params record exactly as :func:`params_of` writes a config that
    holds the drawn values (flags included)."""
    ranges = {
        "camera.noise.position": [0.0, 0.01],
        "camera.detection": [0.9, 1.0],
        "camera.detection_edge": [0.0, 0.5],
        "camera.frame_rate": [20.0, 100.0],
        "camera.latency": [0.0, 0.05],
        "robot.alpha_max": [2.0, 50.0],
    }
    env = platoon_env.make(SCENARIO, realism=ranges, sensor_profile="aruco")
    base = env.scenario.config
    for seed in range(5):
        _, info = env.reset(seed=seed)
        d = info["follower_1"]["realism"]
        fixed = apply_overrides(
            base,
            {
                "camera": {
                    "noise": {"position": d["camera.noise.position"]},
                    "detection": d["camera.detection"],
                    "detection_edge": d["camera.detection_edge"],
                    "frame_rate": d["camera.frame_rate"],
                    "latency": d["camera.latency"],
                },
                "robot": {"alpha_max": d["robot.alpha_max"]},
            },
        )
        fixed = dataclasses.replace(fixed, realism=None)
        want = params_of(fixed, env.max_episode_steps)
        got = env._core.params[0]
        for name in got.dtype.names:
            if np.issubdtype(got.dtype[name], np.floating):
                assert math.isclose(got[name], want[name], rel_tol=1e-12), name
            else:
                assert got[name] == want[name], name


def test_batched_core_draws_as_the_single_env() -> None:
    batched = BatchedPlatoon(SCENARIO, 3, realism={"preset": PRESET})
    batched.reset(seeds=[4, 5, 6])
    assert batched.realism_keys == tuple(REALISM_PRESETS[PRESET])
    single = _env()
    for b, seed in enumerate((4, 5, 6)):
        drawn = single.reset(seed=seed)[1]["follower_1"]["realism"]
        assert batched.realism[b].tolist() == [drawn[k] for k in batched.realism_keys]
        assert batched._core.realism[b] == drawn


def test_frame_ring_holds_the_longest_latency() -> None:
    env = platoon_env.make(SCENARIO, realism={"camera.latency": [0.0, 0.08]})
    assert max_latency_steps(env.scenario.config) == 8
    assert env._core.frames.shape[2] == 8 + 2
    seen = set()
    for seed in range(30):
        _, info = env.reset(seed=seed)
        seen.add(round(info["follower_1"]["realism"]["camera.latency"] / DT))
    assert seen <= set(range(9)) and {0, 8} <= seen  # both ends are drawn


def test_reciprocal_fields_reach_the_ideal_end() -> None:
    """``[lo, null]`` draws the reciprocal uniformly down to 0: high frame rates (a frame every
    step) and loose acceleration bounds are drawn as well as the strict end."""
    env = platoon_env.make(
        SCENARIO, realism={"camera.frame_rate": [20.0, None], "robot.accel_max": [1.6, None]}
    )
    rates, accels = [], []
    for seed in range(60):
        drawn = env.reset(seed=seed)[1]["follower_1"]["realism"]
        rates.append(drawn["camera.frame_rate"])
        accels.append(drawn["robot.accel_max"])
    assert min(rates) < 25.0 and max(rates) == 1.0 / DT
    assert min(accels) < 2.0 and max(accels) > 20.0


def test_a_range_given_beside_the_preset_replaces_its_own() -> None:
    env = platoon_env.make(SCENARIO, realism={"preset": PRESET, "camera.latency": [0.1, 0.1]})
    ranges = ranges_of(env.scenario.config)
    assert ranges["camera.latency"] == (0.1, 0.1)
    assert ranges["proximity.noise"] == REALISM_PRESETS[PRESET]["proximity.noise"]
    assert env.reset(seed=0)[1]["follower_1"]["realism"]["camera.latency"] == pytest.approx(0.1)


def test_the_preset_spans_ideal_to_beyond_aruco() -> None:
    """Every range of the preset includes the ideal value and reaches at least 1.5 times the
    aruco profile's severity (noise, lost detections, frame period, latency, 1 / limits)."""
    aruco = load_profile("aruco")
    cam, noise = aruco["camera"], aruco["camera"]["noise"]
    r = REALISM_PRESETS[PRESET]
    assert set(r) == {f.key for f in FIELDS}
    for key in ("position", "position_per_m", "bearing"):
        lo, hi = r[f"camera.noise.{key}"]
        assert lo == 0.0 and hi is not None and hi >= 1.5 * noise[key]
    lo, hi = r["camera.detection"]
    assert hi == 1.0 and 1.0 - lo >= 1.5 * (1.0 - cam["detection"]) - 1e-12
    lo, hi = r["camera.detection_edge"]
    assert lo == 0.0 and hi is not None and hi >= 1.5 * cam["detection_edge"]
    lo, hi = r["camera.frame_rate"]
    assert hi is None and 1.0 / lo >= 1.5 / cam["frame_rate"] - 1e-12
    lo, hi = r["camera.latency"]
    assert lo == 0.0 and hi is not None and hi >= 1.5 * cam["latency"]
    lo, hi = r["proximity.noise"]
    assert lo == 0.0 and hi is not None and hi >= 1.5 * aruco["proximity"]["noise"]
    for key in ("accel_max", "alpha_max"):
        lo, hi = r[f"robot.{key}"]
        assert hi is None and 1.0 / lo >= 1.5 / aruco["robot"][key]


def test_the_block_round_trips_and_counts_as_realism() -> None:
    cfg = _env().scenario.config
    assert has_realism(cfg)
    data = config_to_mapping(cfg)
    assert data["realism"] == {"preset": PRESET}
    assert parse_scenario(data) == cfg
    custom = platoon_env.make(SCENARIO, realism={"robot.accel_max": [1.0, None]}).scenario.config
    assert config_to_mapping(custom)["realism"] == {"robot.accel_max": [1.0, None]}
    assert parse_scenario(config_to_mapping(custom)) == custom


def test_detection_edge_alone_turns_perception_on() -> None:
    """``camera.detection_edge`` with ``detection = 1`` still drops detections (it draws
    random numbers), so the perception stage and its seeded stream are on."""
    env = platoon_env.make(SCENARIO, camera={"detection_edge": 0.9})
    p = env._core.params[0]
    assert p["random_perception"] and p["perceive"]
    env.reset(seed=0)
    assert env._core.episode[0]["noise_state"] != 0


@pytest.mark.parametrize(
    ("block", "path", "words"),
    [
        ({"camera.latency": [0.05, 0.01]}, "camera.latency", "empty range"),
        ({"camera.latency": [0.011, 0.019]}, "camera.latency", "no whole number"),
        ({"camera.latency": [0.0, 20.0]}, "camera.latency", "at most 1000"),
        ({"camera.latency": [0.1]}, "camera.latency", "expected 2 values"),
        ({"camera.detection": [0.5, 1.5]}, "camera.detection", "<= 1"),
        ({"camera.detection": [0.9, None]}, "camera.detection[1]", "expected a number"),
        ({"camera.noise.position": [-0.1, 0.1]}, "camera.noise.position", ">= 0"),
        ({"proximity.noise": [0.02, 0.01]}, "proximity.noise", "empty range"),
        ({"camera.frame_rate": [0.0, 30.0]}, "camera.frame_rate", "> 0"),
        ({"camera.frame_rate": [10.0, 500.0]}, "camera.frame_rate", "1 / control_period"),
        ({"robot.accel_max": [3.0, 1.0]}, "robot.accel_max", "empty range"),
        ({"robot.alpha_max": [None, 1.0]}, "robot.alpha_max[0]", "expected a number"),
        ({"robot.lag": [0.0, 0.1]}, "robot.lag", "unknown key"),
        ({"preset": "nope"}, "preset", PRESET),
        ({}, None, "draws nothing"),
    ],
)
def test_bad_ranges_name_the_field(block: dict[str, Any], path: str | None, words: str) -> None:
    with pytest.raises(ScenarioError, match="realism") as err:
        platoon_env.make(SCENARIO, realism=block)
    where = "scenario.realism" if path is None else f"scenario.realism.{path}"
    assert err.value.path == where
    assert words in str(err.value)


def test_a_scenario_file_takes_the_block(tmp_path: Any) -> None:
    data = config_to_mapping(platoon_env.make(SCENARIO).scenario.config)
    data["realism"] = {"preset": PRESET, "camera.latency": [0.02, 0.04]}
    path = tmp_path / "randomised.yaml"
    path.write_text(yaml.safe_dump(data))
    env = platoon_env.make(str(path))
    drawn = env.reset(seed=2)[1]["follower_1"]["realism"]
    assert 0.02 - 1e-12 <= drawn["camera.latency"] <= 0.04 + 1e-12
    bad = {**data, "realism": {"camera.latency": [0.04, 0.02]}}
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(ScenarioError, match=r"realism\.camera\.latency"):
        platoon_env.make(str(path))


def test_draw_realism_without_a_block_draws_nothing() -> None:
    env = platoon_env.make(SCENARIO)
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    p = env._core.params[0].copy()
    assert draw_realism(p, env.scenario.config, rng) == {}
    assert rng.bit_generator.state == state
    assert p.tobytes() == env._core.params[0].tobytes()


def test_numeric_info_view_holds_the_values_flat() -> None:
    """The numeric view (TorchRL) never nests: one ``realism.<key>`` float64 per field, the same
    keys at reset and at every step."""
    env = _env(info_view="numeric")
    _, info = env.reset(seed=1)
    rich = _env().reset(seed=1)[1]["follower_1"]["realism"]
    flat = {k: v for k, v in info["follower_1"].items() if k.startswith("realism.")}
    assert "realism" not in info["follower_1"]
    assert flat == {f"realism.{k}": v for k, v in rich.items()}
    assert all(type(v) is np.float64 for v in flat.values())
    _, _, _, _, info = env.step({a: np.zeros(2) for a in env.agents})
    assert {k: v for k, v in info["follower_2"].items() if k.startswith("realism.")} == flat
