"""The timed leader trajectory: ``leader.trajectory: [[t, x, y, theta], ...]`` replayed exactly.

Semantics (``docs/scenarios.md``, :mod:`platoon_env.dynamics.leader`): at every sample time the
leader is at the sample's pose, bit for bit; in between, at the interpolation (linear in
``x, y``, the shorter way round in ``theta``); its velocity is the one the interpolation
implies; after the last sample it stays there (arrived), and the settle-time truncation
applies. The reference values here are computed independently in numpy.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import platoon_env
from platoon_env.batched import BatchedPlatoon
from platoon_env.dynamics.leader import trajectory_velocities
from platoon_env.scenarios import trajectory
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping, parse_scenario

R = 0.15


def unicycle_samples(duration: float = 12.0, dt: float = 0.1) -> list[list[float]]:
    """Samples of a unicycle (closed-form arcs) at 0.3 m/s: straight, a left arc of
    ``omega = 0.25`` from 3 s to 8 s, straight again. Times rounded as a log writes them."""
    out = [[0.0, 0.0, 0.0, 0.0]]
    x = y = th = 0.0
    n = round(duration / dt)
    for k in range(n):
        t0 = k * dt
        w = 0.25 if 3.0 <= t0 < 8.0 - 1e-9 else 0.0
        u = 0.3
        if w == 0.0:
            x, y = x + u * dt * math.cos(th), y + u * dt * math.sin(th)
        else:
            x += u / w * (math.sin(th + w * dt) - math.sin(th))
            y -= u / w * (math.cos(th + w * dt) - math.cos(th))
            th += w * dt
        out.append([round((k + 1) * dt, 10), x, y, th])
    return out


def scenario(samples: list[list[float]] | None = None, **leader: Any) -> dict[str, Any]:
    """An open room (the trajectory stays far from its walls), two followers behind the
    leader's first pose."""
    return {
        "name": "timed_leader",
        "workspace": {
            "bounds": [-5.0, -5.0, 10.0, 10.0],
            "obstacles": [[[8.0, 8.0], [9.0, 8.0], [9.0, 9.0], [8.0, 9.0]]],
        },
        "leader": {"trajectory": unicycle_samples() if samples is None else samples, **leader},
        "followers": 2,
        "robot": {"radius": R},
        "camera": {"half_angle": 0.7, "range": 2.5},
        "safety": {"d_col": 0.3},
        "formation": {"d_des": 1.0},
    }


def expected_pose(samples: np.ndarray, tau: float) -> np.ndarray:
    """The reference interpolation at trajectory time ``tau``."""
    t = samples[:, 0]
    if tau >= t[-1]:
        return samples[-1, 1:].copy()
    k = int(np.searchsorted(t, tau, side="right")) - 1
    s = (tau - t[k]) / (t[k + 1] - t[k])
    a, b = samples[k, 1:], samples[k + 1, 1:]
    turn = math.remainder(b[2] - a[2], 2.0 * math.pi)
    return np.array([a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * turn])


def expected_velocity(samples: np.ndarray, tau: float) -> tuple[float, float]:
    """The reference velocity of the motion just before ``tau`` (segment ``t_k < tau <=
    t_{k+1}``; the samples always move forwards)."""
    t = samples[:, 0]
    k = min(int(np.searchsorted(t, tau, side="left")) - 1, len(t) - 2)
    a, b = samples[k], samples[k + 1]
    dt = b[0] - a[0]
    return math.hypot(b[1] - a[1], b[2] - a[2]) / dt, math.remainder(b[3] - a[3], 2 * math.pi) / dt


def _still(env: Any) -> dict[str, list[float]]:
    return {a: [0.0, 0.0] for a in env.agents}


@pytest.mark.parametrize(
    ("period", "substeps"), [(0.05, 2), (0.1, 1), (0.03, 1), (0.07, 3)], ids=str
)
def test_replay_is_exact_at_sample_times_and_interpolates_between(
    period: float, substeps: int
) -> None:
    """Whenever the clock is at a sample time (every step for 0.1 s, every other for 0.05 s,
    every 10th for 0.03 s, every 10th for 0.07 s) the leader's pose is that sample's, bit for
    bit; otherwise the interpolation's, and its velocity the segment's."""
    samples = np.array(unicycle_samples())
    env = platoon_env.make(
        scenario(), control_period=period, physics_substeps=substeps, terminate_on=()
    )
    env.reset(seed=0)
    np.testing.assert_array_equal(env.poses[0], samples[0, 1:])
    exact = 0
    for step in range(1, round(12.0 / period)):
        env.step(_still(env))
        tau = step * period
        k = round(tau / 0.1)
        if abs(k * 0.1 - tau) < 1e-9:
            np.testing.assert_array_equal(env.poses[0], samples[k, 1:], err_msg=f"step {step}")
            exact += 1
        else:
            np.testing.assert_allclose(env.poses[0], expected_pose(samples, tau), atol=1e-12)
        np.testing.assert_allclose(env.leader_velocity, expected_velocity(samples, tau), atol=1e-9)
    assert exact >= 15  # every 0.7 s at worst


def test_arrival_stops_the_leader_and_settle_time_truncates() -> None:
    """After the last sample the leader stays there (velocity 0), has arrived at the step whose
    clock reached it, and the episode is truncated ``settle_time`` later; the default step limit
    is twice the trajectory's duration plus the settle time and 10 s."""
    samples = unicycle_samples(duration=3.0)
    env = platoon_env.make(scenario(samples, settle_time=1.0), terminate_on=(), perturb=False)
    env.reset()
    assert env.max_episode_steps == math.ceil((2 * 3.0 + 1.0 + 10.0) / 0.01 - 1e-6)
    last = np.array(samples[-1][1:])
    truncated_at = None
    for step in range(1, 500):
        _, _, _, trunc, _ = env.step(_still(env))
        t = env.sim_time
        assert env.leader_arrived == (t >= 3.0 - 1e-9), step
        if env.leader_arrived:
            np.testing.assert_array_equal(env.poses[0], last)
            if t > 3.0 + 1e-9:
                assert env.leader_velocity.tolist() == [0.0, 0.0]
        if trunc["follower_1"]:
            truncated_at = t
            break
    assert truncated_at == pytest.approx(4.0, abs=1e-9)


def test_default_start_and_the_leaders_first_pose() -> None:
    """The platoon starts lined up behind the first sample, ``d_des`` apart, facing along it;
    a given start must put the leader at the first sample."""
    env = platoon_env.make(scenario())
    env.reset(options={"perturb": False})
    np.testing.assert_allclose(env.poses, [[0, 0, 0], [-1, 0, 0], [-2, 0, 0]], atol=1e-15)
    env.reset(options={"poses": np.array([[0.0, 0.0, 0.0], [-1.1, 0.05, 0.0], [-2.0, 0, 0]])})
    with pytest.raises(ScenarioError, match=r"leader: with a timed trajectory the leader starts"):
        env.reset(options={"poses": np.array([[0.2, 0.0, 0.0], [-1.0, 0, 0], [-2.0, 0, 0]])})


@pytest.mark.parametrize("variation", [0.0, 0.3])
def test_batched_equals_single_env(variation: float) -> None:
    """``BatchedPlatoon`` env ``b`` reset with seed ``s`` and fed the same actions follows the
    single env bit for bit, with a trajectory leader (and a speed factor drawn per seed)."""
    sc = scenario(speed_variation=variation)
    seeds = [0, 1, 2]
    batch = BatchedPlatoon(sc, len(seeds), terminate_on=())
    batch.reset(seeds)
    rng = np.random.default_rng(5)
    actions = rng.uniform([-0.2, -0.5], [0.6, 0.5], size=(300, len(seeds), 2, 2))
    single = [platoon_env.make(sc, terminate_on=()) for _ in seeds]
    for env, seed in zip(single, seeds, strict=True):
        env.reset(seed=seed)
    factors = [env.leader_speed_factor for env in single]
    np.testing.assert_array_equal(batch.leader_speed_factor, factors)
    if variation > 0:
        assert len(set(factors)) == len(seeds)
    for step in range(actions.shape[0]):
        batch.step(actions[step])
        for b, env in enumerate(single):
            env.step({a: actions[step, b, i] for i, a in enumerate(env.agents)})
            np.testing.assert_array_equal(batch.poses[b], env.poses, err_msg=f"{step}, {b}")
            np.testing.assert_array_equal(batch.leader_velocity[b], env.leader_velocity)


def test_speed_factor_replays_the_trajectory_faster() -> None:
    """With ``speed_variation`` the episode's factor ``f`` scales the time axis: the leader is
    at the interpolation of ``f t``, with ``f`` times the velocity, and arrives at ``T / f``."""
    samples = np.array(unicycle_samples(duration=4.0))
    env = platoon_env.make(scenario(samples.tolist(), speed_variation=0.4), terminate_on=())
    env.reset(seed=11)
    f = env.leader_speed_factor
    assert f != 1.0 and 0.6 <= f <= 1.4
    arrived_at = None
    for _ in range(800):
        env.step(_still(env))
        tau = f * env.sim_time
        np.testing.assert_allclose(env.poses[0], expected_pose(samples, tau), atol=1e-9)
        if tau < 4.0 - 1e-9:
            u, w = expected_velocity(samples, tau)
            np.testing.assert_allclose(env.leader_velocity, [f * u, f * w], atol=1e-9)
        if env.leader_arrived and arrived_at is None:
            arrived_at = env.sim_time
            break
    assert arrived_at == pytest.approx(4.0 / f, abs=0.01 + 1e-9)


def test_mapping_round_trip_and_derived_speed(tmp_path: Path) -> None:
    """A trajectory's ``speed`` is derived (its mean speed); the config round-trips through its
    mapping and through YAML; ``make()`` overrides switch a path scenario to a trajectory."""
    samples = unicycle_samples()
    cfg = parse_scenario(scenario(samples))
    assert cfg.leader.path == ()
    xy = np.array(samples)[:, 1:3]
    chords = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
    assert cfg.leader.speed == pytest.approx(chords / 12.0, rel=1e-12)  # length / duration
    assert parse_scenario(config_to_mapping(cfg)) == cfg
    text = "\n".join(
        [
            "name: timed_yaml",
            "workspace: {bounds: [-5, -5, 10, 10]}",
            "leader:",
            "  trajectory:",
            *(f"    - [{t!r}, {x!r}, {y!r}, {th!r}]" for t, x, y, th in samples),
            "followers: 2",
            "robot: {radius: 0.15}",
            "camera: {half_angle: 0.7, range: 2.5}",
            "safety: {d_col: 0.3}",
            "formation: {d_des: 1.0}",
        ]
    )
    path = tmp_path / "timed.yaml"
    path.write_text(text)
    env = platoon_env.make(path)
    assert env.scenario.config.leader.trajectory == cfg.leader.trajectory
    with_path = copy.deepcopy(scenario(samples))
    with_path["leader"] = {"path": [[-3.0, 0.0], [5.0, 0.0]], "speed": 0.5}
    switched = platoon_env.make(with_path, leader={"trajectory": samples})
    assert switched.scenario.config.leader.path == ()
    assert switched.scenario.config.leader.speed == cfg.leader.speed
    back = platoon_env.make(with_path, leader={"trajectory": samples}).source.config
    assert back == switched.source.config


def _modified(**changes: Any) -> dict[str, Any]:
    sc = scenario()
    for key, value in changes.items():
        block, field = key.split("__")
        if value is None:
            sc[block].pop(field, None)
        else:
            sc[block][field] = value
    return sc


SAMPLES = unicycle_samples()
#: The heading of a straight drive from the origin into the obstacle at (8, 8).
HEADING_TO_WALL = math.atan2(7.9, 8.5)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"leader__trajectory": [[0.0, 0.0, 0.0, 0.0]]}, "leader.trajectory: needs at least two"),
        ({"leader__trajectory": [[0.5, 0, 0, 0], [1.0, 1, 0, 0]]}, r"trajectory\[0\]: the first"),
        (
            {"leader__trajectory": [[0, 0, 0, 0], [1.0, 0.1, 0, 0], [1.0, 0.2, 0, 0]]},
            r"trajectory\[2\]: sample times must increase",
        ),
        (
            {"leader__trajectory": [[0, 0, 0, 0], [1.0, 0.1, 0, 0], [0.5, 0.2, 0, 0]]},
            r"trajectory\[2\]: sample times must increase",
        ),
        ({"leader__trajectory": [[0, 0, 0, 0], [1.0, math.nan, 0, 0]]}, "must be finite"),
        ({"leader__trajectory": [[0, 0, 0, 0], [1.0, 0.1, 0, math.inf]]}, "must be finite"),
        ({"leader__trajectory": [[0, 0, 0, 0], [1.0, 0.1, 0]]}, "expected 4 values"),
        ({"leader__trajectory": [[0, 0, 0, 0], [1.0, 0, 0, 1.0]]}, "the leader never moves"),
        ({"leader__trajectory": [[0, 0, 0, 0], [2e6, 1.0, 0, 0]]}, "at most 1e\\+06 s"),
        ({"leader__trajectory": [[0, 0, 0, 0], [1e4, 2e6, 0, 0]]}, r"trajectory\[1\]: coordinates"),
        ({"leader__path": [[0.0, 0.0], [1.0, 0.0]]}, "give exactly one of 'path'"),
        ({"leader__trajectory": None}, "required key is missing"),
        ({"leader__speed": 0.5}, "leader.speed: with a trajectory the leader's speed is"),
        (
            {"robot__u_max": 0.25},
            r"trajectory\[\d+\]: infeasible: from sample \d+ to \d+ the leader's speed would be "
            r"0\.3 m/s, above robot\.u_max = 0\.25",
        ),
        (
            {"leader__max_turn_rate": 0.2},
            r"trajectory\[\d+\]: infeasible: .* turn rate would be 0\.25 rad/s, above "
            r"leader\.max_turn_rate = 0\.2",
        ),
        (
            {"leader__speed_variation": 0.9, "robot__u_max": 0.5},
            r"speed times 1 \+ leader\.speed_variation would be 0\.57",
        ),
        (
            {"leader__trajectory": [[0, 0, 0, HEADING_TO_WALL], [10, 8.5, 7.9, HEADING_TO_WALL]]},
            r"leader\.trajectory: the leader's path comes within",
        ),
    ],
)
def test_invalid_trajectories_name_the_field(changes: dict[str, Any], message: str) -> None:
    with pytest.raises(ScenarioError, match=message):
        platoon_env.make(_modified(**changes))


def test_size_bound_and_procedural_refusal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(trajectory, "MAX_TRAJECTORY_SAMPLES", 50)
    with pytest.raises(ScenarioError, match=r"at most 50 samples \(MAX_TRAJECTORY_SAMPLES\)"):
        parse_scenario(scenario())
    parse_scenario(scenario(SAMPLES[:50]))
    with pytest.raises(ScenarioError, match=r"a procedural scenario .* takes no trajectory"):
        platoon_env.make("procedural_train", leader={"trajectory": SAMPLES[:20]})


def test_the_fastest_segment_bounds_the_leaders_travel() -> None:
    """The compiled step skips the edge tests of followers that cannot have reached a wall,
    from a bound on each robot's travel; the replayed leader's bound is its fastest segment."""
    samples = unicycle_samples(duration=2.0)
    samples[5][1] += 0.02  # one faster segment (0.5 m/s) and a slower one after it
    env = platoon_env.make(scenario(samples))
    p = env._core.params[0]
    assert bool(p["leader_replay"])
    assert p["leader_speed_bound"] == pytest.approx(0.5, rel=1e-6)
    assert p["leader_speed"] == pytest.approx(env.scenario.config.leader.speed)


# ------------------------------------------------------------------------------------------
# The heading rule: a unicycle moves along its heading (no sliding sideways)
# ------------------------------------------------------------------------------------------


def straight_samples(heading: float, direction: float = 0.0, n: int = 40) -> list[list[float]]:
    """A leader driving 0.3 m/s along ``direction`` [rad] from the origin, sampled every 0.1 s,
    each sample with the heading ``heading``."""
    step = 0.03
    return [
        [
            round(0.1 * k, 10),
            k * step * math.cos(direction),
            k * step * math.sin(direction),
            heading,
        ]
        for k in range(n)
    ]


def test_study_b_trajectory_drives_along_its_heading() -> None:
    """The shipped planner's trajectory (turns in place at its sharp vertices, rounded to
    0.1 mm and 0.1 mrad) keeps the rule, with room to spare."""
    cfg = platoon_env.scenarios.load_config("study_b")
    route = trajectory.trajectory_route(cfg.leader.trajectory)
    _, omega = trajectory_velocities(route)
    sideways, allowed = trajectory.sideways_slip(route, omega)
    assert np.all(sideways <= 0.5 * allowed)


@pytest.mark.parametrize(
    ("samples", "sample"),
    [
        (straight_samples(0.0, direction=math.pi / 2), 1),  # a crab: heading x, moving y
        (straight_samples(0.07), 1),  # the heading 0.07 rad off the motion all along
        # the heading drifts at 0.1 rad/s from a straight motion: segment 6 to 7 is the first
        # whose mean heading, 0.065 rad, lies beyond 0.005 + 0.05 rad (a half-turn and the
        # tolerance) of the chord
        ([[t, x, y, 0.1 * t] for t, x, y, _ in straight_samples(0.0)], 7),
    ],
    ids=["crab", "offset", "drift"],
)
def test_sliding_sideways_is_an_error_naming_the_sample(
    samples: list[list[float]], sample: int
) -> None:
    with pytest.raises(
        ScenarioError,
        match=rf"leader\.trajectory\[{sample}\]: the heading does not match the motion: from "
        rf"sample {sample - 1} to {sample} the leader moves .* m sideways of its heading",
    ):
        parse_scenario(scenario(samples))


def _sampled_unicycle(u_of_t: Any, omega: float, period: float, duration: float) -> list[Any]:
    """A unicycle with speed ``u_of_t(t)`` and turn rate ``omega``, integrated in 1 ms arcs and
    sampled every ``period`` [s] (positions and headings rounded as a log writes them)."""
    h = 1e-3
    x = y = th = 0.0
    out = [[0.0, 0.0, 0.0, 0.0]]
    every = round(period / h)
    for k in range(round(duration / h)):
        u = u_of_t(k * h)
        x += u * h * math.cos(th + 0.5 * omega * h)
        y += u * h * math.sin(th + 0.5 * omega * h)
        th += omega * h
        if (k + 1) % every == 0:
            out.append([round((k + 1) * h, 10), round(x, 4), round(y, 4), round(th, 4)])
    return out


@pytest.mark.parametrize(
    "samples",
    [
        straight_samples(0.04),  # within TRAJECTORY_HEADING_TOLERANCE of the motion
        straight_samples(0.0, direction=math.pi),  # reversing along its heading
        straight_samples(math.pi / 2, direction=-math.pi / 2),  # reversing, another heading
        # accelerating from rest through a turn, sampled coarsely: the chord leans towards the
        # later headings, but stays among the headings held
        _sampled_unicycle(lambda t: min(0.3, 0.3 * t), omega=1.0, period=0.5, duration=3.0),
        # a slow leader (1 mm per sample) whose positions are rounded to 0.1 mm
        _sampled_unicycle(lambda t: 0.01, omega=0.2, period=0.1, duration=10.0),
    ],
    ids=["tolerance", "reverse", "reverse-y", "coarse-turn", "slow-rounded"],
)
def test_driving_along_the_heading_passes(samples: list[list[float]]) -> None:
    cfg = parse_scenario(scenario(samples))
    assert cfg.leader.trajectory[-1][1:3] == tuple(samples[-1][1:3])
