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


def test_graded_metrics_of_a_synthetic_episode() -> None:
    """The margins are the formulas of constraint_margins, read at their minimum; the path
    fraction is the leader's travelled distance over the path's length."""
    from dataclasses import replace

    from platoon_env.geometry.sensing import (
        SENSE_CLEARANCE,
        SENSE_D_SIGHT_LEFT,
        SENSE_D_SIGHT_RIGHT,
    )

    ep = _episode(2.0)
    ep.sensed[:, 0, SENSE_CLEARANCE] = 0.6
    ep.sensed[:, 0, SENSE_D_SIGHT_LEFT] = 0.45
    ep.sensed[:, 0, SENSE_D_SIGHT_RIGHT] = 0.9
    ep.poses[:, 0, 0] = 0.25 * np.arange(21)  # the leader drives 5 m of a 20 m path
    ep = replace(ep, d_col=0.5, d_con=2.0, beta_con=0.5, radius=0.3, path_length=20.0)
    m = episode_metrics(ep)
    # d after each step: 1.01 .. 1.2
    assert m["min_margin_distance"] == pytest.approx(min((2.0 - 1.2) / 1.0, (1.01 - 0.5) / 0.5))
    assert m["min_margin_bearing"] == pytest.approx((0.5 - 0.02) / 0.5)
    assert m["min_margin_clearance"] == pytest.approx(1.0)  # (0.6 - 0.3) / 0.3
    assert m["min_margin_sight"] == pytest.approx(1.5)  # 0.45 / 0.3
    assert m["path_fraction"] == pytest.approx(0.25)
    # Cut at a violation at step 7: the leader had travelled 8 steps' worth (poses 0..8).
    cut = replace(ep, first_violation=(7, "out_of_range", 1))
    assert episode_metrics(cut)["path_fraction"] == pytest.approx(8 * 0.25 / 20.0)
    # Arrived without a violation: the whole path.
    assert episode_metrics(replace(ep, leader_arrived=True))["path_fraction"] == 1.0
    # constraint_margins names its constraints as MARGINS does, one (T, N) array each.
    from platoon_env.rollout import MARGINS, constraint_margins

    margins = constraint_margins(ep)
    assert tuple(margins) == MARGINS and all(v.shape == (20, 1) for v in margins.values())
    # Not recorded (an Episode built without its constraints): NaN, not a number made up.
    assert np.isnan(episode_metrics(_episode(2.0))["min_margin_distance"])


@pytest.mark.parametrize("policy", ["halt", "ppc"])
def test_graded_metrics_of_real_episodes(policy: str) -> None:
    """A law that completes study C has the whole path and positive margins; followers that
    stop lose their leader part of the way, with the violated constraint's margin at or below
    zero."""
    import platoon_env
    from baselines.ppc import PPCPolicy
    from platoon_env.rollout import run_episode

    class Halt:
        def reset(self, seed: int | None = None) -> None:
            pass

        def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            return {a: np.zeros(2, dtype=np.float32) for a in obs}

    env = platoon_env.make("study_c")
    ep = run_episode(env, PPCPolicy(env) if policy == "ppc" else Halt(), seed=0)
    m = episode_metrics(ep)
    if policy == "ppc":
        assert m["success"] and m["path_fraction"] == 1.0
        assert min(m[f"min_margin_{k}"] for k in ("distance", "bearing", "sight")) > 0
    else:
        assert not m["success"] and 0.0 < m["path_fraction"] < 0.5
        bound = {"out_of_range": "distance", "out_of_fov": "bearing", "occluded": "sight"}
        assert m[f"min_margin_{bound[m['violation']]}"] <= 1e-9
