"""PPC in the simulator: error dynamics (eqs. 8-9), and the paper's studies without violations."""

from __future__ import annotations

import math

import numpy as np
import pytest

import platoon_env
from baselines import PPCPolicy
from platoon_env.rollout import episode_metrics, run_episode


@pytest.mark.parametrize("seed", range(5))
def test_error_dynamics_match_finite_differences(seed: int) -> None:
    """d/dt e_d and e_beta of follower 2 in the simulator agree with eqs. 8 and 9."""
    h = 1e-5
    env = platoon_env.make("study_c", control_period=h, physics_substeps=1, terminate_on=())
    info0 = env.reset(seed=seed)[1]["follower_2"]
    rng = np.random.default_rng(seed)
    u1, w1, u2, w2 = rng.uniform(-1, 1, 4)
    before = env.poses
    _, _, _, _, infos = env.step({"follower_1": [u1, w1], "follower_2": [u2, w2]})
    info1 = infos["follower_2"]
    th1, th2 = before[1, 2], before[2, 2]
    d, beta = info0["d"], info0["beta"]
    ed_dot = -u2 * math.cos(beta) + u1 * math.cos(th2 - th1 + beta)  # eq. 8
    eb_dot = -w2 + u2 / d * math.sin(beta) - u1 / d * math.sin(th2 - th1 + beta)  # eq. 9
    assert (info1["e_d"] - info0["e_d"]) / h == pytest.approx(ed_dot, abs=1e-4)
    assert (info1["e_beta"] - info0["e_beta"]) / h == pytest.approx(eb_dot, abs=1e-3)
    assert info1["violation"] is None


@pytest.mark.parametrize("study", ["study_a", "study_b", "study_c"])
def test_ppc_completes_study_without_violation(study: str) -> None:
    """Default settings, seed 0: the leader reaches the end, no violation, no funnel exit.

    (The five-seed record is produced by ``python -m experiments.studies.paper_figures``.)
    """
    env = platoon_env.make(study)
    policy = PPCPolicy(env)
    m = episode_metrics(run_episode(env, policy, seed=0, record_signals=False))
    assert m["success"], m
    assert m["violation"] == "" and m["funnel_exits"] == 0 and m["lost_sight_steps"] == 0
    assert math.isfinite(m["peak_u"]) and math.isfinite(m["peak_omega"])


@pytest.mark.slow
@pytest.mark.parametrize("study", ["study_a", "study_b", "study_c"])
@pytest.mark.parametrize("seed", range(1, 5))
def test_ppc_more_seeds(study: str, seed: int) -> None:
    env = platoon_env.make(study)
    m = episode_metrics(run_episode(env, PPCPolicy(env), seed=seed, record_signals=False))
    assert m["success"] and m["funnel_exits"] == 0, m


def test_distance_funnel_shrinks_in_narrow_passage() -> None:
    """§3: with walls on both sides the distance bounds fall (the follower closes up)."""
    env = platoon_env.make("study_c")
    ep = run_episode(env, PPCPolicy(env), seed=0)
    both = (ep.signals["F_l"] > 0) & (ep.signals["F_r"] > 0)
    assert both.any()
    hi = ep.signals["rho_d_hi"]
    assert hi[both].mean() < hi[~both & (ep.times[1:, None] > 20)].mean()
