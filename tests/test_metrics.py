"""``episode_metrics``: the error statistics cover the steps after the transient, or the whole
episode when it ends before the transient is over (``docs/metrics.md``)."""

from __future__ import annotations

import numpy as np
import pytest

from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D, SENSE_VISIBLE
from platoon_env.rollout import Episode, episode_metrics


def _episode(duration: float, dt: float = 0.1, d_des: float = 1.0) -> Episode:
    """A synthetic one-follower episode whose distance error at step k is k * 0.01 m and whose
    bearing is -k * 0.001 rad (always visible)."""
    steps = round(duration / dt)
    times = np.arange(steps + 1) * dt
    sensed = np.zeros((steps + 1, 1, 9))
    k = np.arange(steps + 1, dtype=float)
    sensed[:, 0, SENSE_D] = d_des + 0.01 * k
    sensed[:, 0, SENSE_BETA] = -0.001 * k
    sensed[:, 0, SENSE_VISIBLE] = 1.0
    return Episode(
        scenario="synthetic",
        seed=0,
        control_period=dt,
        d_des=d_des,
        times=times,
        poses=np.stack([np.zeros((steps + 1, 3)), np.ones((steps + 1, 3))], axis=1),
        sensed=sensed,
        actions=np.zeros((steps, 1, 2)),
        violations=np.zeros((steps, 1), dtype=np.int64),
        terminated=True,
        truncated=False,
        leader_arrived=False,
        first_violation=None,
    )


def test_short_episode_is_scored_over_all_its_steps() -> None:
    """A 2 s episode with a 5 s transient: every step after the first counts (before the fix
    only the last step did, which overstated the error)."""
    ep = _episode(2.0)
    e_d = 0.01 * np.arange(1, 21)
    m = episode_metrics(ep, transient=5.0)
    assert m["rms_e_d"] == pytest.approx(float(np.sqrt(np.mean(e_d**2))))
    assert m["max_abs_e_d"] == pytest.approx(0.2)
    assert m["rms_e_beta"] == pytest.approx(float(np.sqrt(np.mean((0.1 * e_d) ** 2))))


def test_long_episode_is_scored_after_the_transient() -> None:
    ep = _episode(8.0)
    k = np.arange(50, 81)  # t = 5.0 ... 8.0 s
    m = episode_metrics(ep, transient=5.0)
    assert m["rms_e_d"] == pytest.approx(float(np.sqrt(np.mean((0.01 * k) ** 2))))
    assert m["max_abs_e_d"] == pytest.approx(0.8)


def test_command_rates_measure_how_fast_the_commands_change() -> None:
    """Chatter (u and omega switching between bounds every step) against a smooth ramp, and
    the rates' units: per second of the control period."""
    ep = _episode(1.0, dt=0.025)
    steps = ep.actions.shape[0]
    sign = np.where(np.arange(steps) % 2 == 0, 1.0, -1.0)
    ep.actions[:, 0, 0] = 0.5 + sign  # -0.5 <-> 1.5 m/s
    ep.actions[:, 0, 1] = 2.0 * sign  # -2 <-> 2 rad/s
    m = episode_metrics(ep)
    assert m["command_rate_u"] == pytest.approx(2.0 / 0.025)
    assert m["command_rate_omega"] == pytest.approx(4.0 / 0.025)
    ep.actions[:, 0, 0] = 0.1 * np.arange(steps)  # +0.1 m/s per step
    ep.actions[:, 0, 1] = 0.3
    m = episode_metrics(ep)
    assert m["command_rate_u"] == pytest.approx(0.1 / 0.025)
    assert m["command_rate_omega"] == 0.0


def test_command_rates_of_a_one_step_episode_are_zero() -> None:
    m = episode_metrics(_episode(0.1))
    assert m["command_rate_u"] == 0.0 and m["command_rate_omega"] == 0.0
