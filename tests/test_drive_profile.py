"""A profile that names its robot carries its whole drive, and the leader is one of its robots.

* ``turtlebot3_waffle_pi`` extends ``aruco`` with the robot's velocity box: commands beyond it
  are clipped, the applied velocity never exceeds it.
* ``leader.drive``: ``"check"`` refuses a leader beyond the robots' drive naming the field,
  ``"retime"`` slows it (a trajectory stretched in time, a path's speed and turn rate lowered;
  a pure pursuit is rate-limited); ``"free"`` (the default) keeps every shipped scenario as it
  was.
* The old ``aruco`` results stay distinguishable: its fingerprints are unchanged
  (``tests/test_fingerprints.py``) and differ from the new profile's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import platoon_env
from platoon_env import ScenarioError
from platoon_env.scenarios import load_config
from platoon_env.scenarios.fingerprint import config_fingerprint
from platoon_env.scenarios.options import apply_overrides
from platoon_env.scenarios.profiles import load_profile
from platoon_env.scenarios.trajectory import (
    fit_leader_to_drive,
    leader_drive_excess,
    trajectory_rates,
)

PROFILE = "turtlebot3_waffle_pi"


def test_the_profile_carries_the_robot_s_whole_drive() -> None:
    blocks = load_profile(PROFILE)
    aruco = load_profile("aruco")
    # the sensing and the rate limits are aruco's, the velocity box and the leader rule its own
    assert blocks["camera"] == aruco["camera"] and blocks["proximity"] == aruco["proximity"]
    assert {k: blocks["robot"][k] for k in aruco["robot"]} == aruco["robot"]
    assert blocks["robot"]["u_max"] == 0.26 and blocks["robot"]["omega_max"] == 1.82
    assert blocks["leader"] == {"drive": "retime"}


def test_commands_beyond_the_velocity_box_are_clipped() -> None:
    env = platoon_env.make("study_b", sensor_profile=PROFILE, terminate_on=[])
    space = env.action_space(env.possible_agents[0])
    np.testing.assert_allclose(space.high, [0.26, 1.82], rtol=1e-6)
    env.reset(seed=0)
    peak = np.zeros(2)
    for _ in range(200):
        env.step({a: np.array([5.0, 5.0], dtype=np.float32) for a in env.agents})
        peak = np.maximum(peak, np.abs(env.applied_velocities).max(axis=0))
    # reached the box (through the rate limits), never beyond it
    np.testing.assert_allclose(peak, [0.26, 1.82], rtol=1e-6)


def test_study_b_s_leader_already_fits_the_drive() -> None:
    base = load_config("study_b")
    cfg = apply_overrides(base, {"sensor_profile": PROFILE})
    assert cfg.leader.trajectory == base.leader.trajectory
    assert leader_drive_excess(cfg) == []


@pytest.mark.parametrize("scenario", ["study_a", "study_c"])
def test_a_pure_pursuit_leader_keeps_the_drive_by_construction(scenario: str) -> None:
    """Under the profile a path leader is slowed to the velocity box and its pure pursuit is
    rate-limited (it ramps up, turns and brakes within accel_max and alpha_max)."""
    env = platoon_env.make(scenario, sensor_profile=PROFILE, terminate_on=[])
    lead = env.scenario.config.leader
    assert lead.speed * (1 + lead.speed_variation) <= 0.26 + 1e-12
    assert lead.max_turn_rate == 1.5  # already within omega_max
    env.reset(seed=0)
    velocities = [env.leader_velocity]
    for _ in range(3000):
        env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
        velocities.append(env.leader_velocity)
    v = np.array(velocities)
    dt = env.control_period
    assert np.abs(v[:, 0]).max() <= 0.26 and np.abs(v[:, 1]).max() <= 1.5 + 1e-12
    assert np.abs(np.diff(v[:, 0])).max() <= 2.5 * dt + 1e-12
    assert np.abs(np.diff(v[:, 1])).max() <= 3.2 * dt + 1e-12
    assert np.abs(np.diff(v[:, 1])).max() > 0  # it did turn
    # the same scenario without the profile's drive rule: pure pursuit as before (a jump)
    free = platoon_env.make(scenario, terminate_on=[])
    free.reset(seed=0)
    free.step({a: np.zeros(2, dtype=np.float32) for a in free.agents})
    assert free.leader_velocity[0] > 2.5 * dt


def test_retime_lowers_a_path_leader_to_the_box() -> None:
    cfg = apply_overrides(
        load_config("study_a"),
        {"robot": {"u_max": 0.26, "omega_max": 1.0}, "leader": {"drive": "retime"}},
    )
    lead = cfg.leader
    assert lead.speed * (1 + lead.speed_variation) <= 0.26 + 1e-12
    assert lead.max_turn_rate <= 1.0
    assert leader_drive_excess(cfg) == []
    with pytest.raises(ScenarioError, match=r"leader\.speed: the leader's speed"):
        apply_overrides(
            load_config("study_a"), {"robot": {"u_max": 0.26}, "leader": {"drive": "check"}}
        )


def _slow_box() -> dict[str, object]:
    """A velocity box study B's leader exceeds (0.2 m/s * 1.2 > 0.15)."""
    return {"robot": {"u_max": 0.15, "omega_max": 0.8, "accel_max": 0.5, "alpha_max": 1.0}}


def test_check_refuses_a_trajectory_beyond_the_drive_naming_the_field() -> None:
    overrides = {**_slow_box(), "leader": {"drive": "check"}}
    with pytest.raises(ScenarioError) as err:
        apply_overrides(load_config("study_b"), overrides)
    message = str(err.value)
    assert "leader.trajectory[" in message and "above robot." in message
    assert "leader.drive: retime" in message


def test_retime_stretches_the_trajectory_until_it_fits() -> None:
    base = load_config("study_b")
    cfg = apply_overrides(base, {**_slow_box(), "leader": {"drive": "retime"}})
    old, new = np.array(base.leader.trajectory), np.array(cfg.leader.trajectory)
    # the same samples in space, later in time by one factor
    np.testing.assert_array_equal(old[:, 1:], new[:, 1:])
    stretch = (new[-1, 0] - new[0, 0]) / (old[-1, 0] - old[0, 0])
    assert stretch > 1.0
    np.testing.assert_allclose(new[1:, 0] - new[0, 0], (old[1:, 0] - old[0, 0]) * stretch)
    assert cfg.leader.speed == pytest.approx(base.leader.speed / stretch)
    assert leader_drive_excess(cfg) == []
    # within the bounds, and one of them binding (the smallest stretch that fits)
    f = 1 + cfg.leader.speed_variation
    u, omega, a, alpha = trajectory_rates(cfg.leader.trajectory)
    usage = [
        f * np.abs(u).max() / 0.15,
        f * np.abs(omega).max() / 0.8,
        f**2 * np.abs(a).max() / 0.5,
        f**2 * np.abs(alpha).max() / 1.0,
    ]
    assert max(usage) <= 1.0 and max(usage) > 1.0 - 1e-6
    # idempotent (the drive rule passes it as it is); the free rule refuses the unslowed leader
    assert fit_leader_to_drive(cfg) is cfg
    with pytest.raises(ScenarioError, match=r"above robot\.u_max"):
        apply_overrides(base, _slow_box())
    env = platoon_env.make("study_b", **_slow_box(), leader={"drive": "retime"})
    assert env.scenario.config.leader.trajectory == cfg.leader.trajectory


def test_free_keeps_every_leader_as_it_was() -> None:
    cfg = apply_overrides(load_config("study_c"), {"u_max": 0.1, "omega_max": 0.2})
    assert cfg.leader == load_config("study_c").leader
    assert leader_drive_excess(cfg)  # it does exceed the box, and nothing checks it


def test_aruco_and_the_robot_profile_are_different_scenarios() -> None:
    base = load_config("study_b")
    aruco = apply_overrides(base, {"sensor_profile": "aruco"})
    robot = apply_overrides(base, {"sensor_profile": PROFILE})
    assert config_fingerprint(aruco) != config_fingerprint(robot)


def test_a_bad_drive_mode_and_a_bad_extends_are_named(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"leader\.drive: must be one of free, check, retime"):
        apply_overrides(load_config("study_c"), {"leader": {"drive": "fast"}})
    path = tmp_path / "p.yaml"
    path.write_text("extends: nosuch\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="extends: must name a shipped profile"):
        load_profile(path)
    path.write_text("leader: {speed: 3.0}\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"leader\.speed: unknown key \(expected one of drive"):
        load_profile(path)
    path.write_text("extends: aruco\ncamera: {noise: {bearing: 0.02}}\n", encoding="utf-8")
    merged = load_profile(path)
    assert merged["camera"]["noise"] == {
        **load_profile("aruco")["camera"]["noise"],
        "bearing": 0.02,
    }
