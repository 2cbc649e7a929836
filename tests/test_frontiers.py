"""The frontiers study: the Wilson interval, the grid, resuming, diagnostics and a quick run."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from experiments.grid import resolve_cells, run_cell
from experiments.studies.frontiers import (
    AXES,
    CONTROLLERS,
    CSV_COLUMNS,
    build_grid,
    level_key,
    main,
    wilson_interval,
)


def test_wilson_interval_hand_case() -> None:
    # 8/10, z = 1.959964 (the 97.5 % normal quantile) by hand: p = 0.8, z^2 = 3.841459,
    # denom = 1 + 0.3841459 = 1.3841459, centre = (0.8 + 0.1920729) / 1.3841459 = 0.716740,
    # half = 1.959964 sqrt(0.016 + 0.0096036) / 1.3841459 = 1.959964 * 0.160011 / 1.3841459
    # = 0.226578, so [0.490162, 0.943318] (the tabulated Wilson interval of 8/10: 0.490, 0.943).
    lo, hi = wilson_interval(8, 10)
    assert lo == pytest.approx(0.490162, abs=2e-6)
    assert hi == pytest.approx(0.943318, abs=2e-6)
    # 0/10: centre = 0.1920729/1.3841459 = half, so [0, 2 * 0.138766] = [0, 0.277533].
    lo, hi = wilson_interval(0, 10)
    assert lo == pytest.approx(0.0, abs=1e-12) and hi == pytest.approx(0.277533, abs=1e-6)
    lo, hi = wilson_interval(10, 10)
    assert hi == pytest.approx(1.0, abs=1e-12) and lo == pytest.approx(1 - 0.277533, abs=1e-6)
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_grid_levels() -> None:
    assert list(AXES) == [
        "camera_noise",
        "detection",
        "latency",
        "frame_rate",
        "accel_max",
        "profile",
    ]
    assert AXES["camera_noise"].levels == (0, 0.5, 1, 2, 5, 10)
    assert AXES["detection"].levels == (1, 0.95, 0.8, 0.5)
    assert AXES["latency"].levels == (0, 10, 30, 50, 100)
    assert AXES["frame_rate"].levels == (None, 30, 15)
    assert AXES["accel_max"].levels == (None, 2, 1, 0.5)
    assert AXES["profile"].levels == ("aruco",)
    assert sum(len(a.levels) for a in AXES.values()) == 23
    for axis in AXES.values():
        assert len(axis.quick) == min(2, len(axis.levels))
        assert set(axis.quick) <= set(axis.levels)
    # Units: cm -> m, ms -> s; the ideal level of each axis overrides nothing.
    assert AXES["camera_noise"].overrides(2) == {"camera": {"noise": {"position": 0.02}}}
    assert AXES["latency"].overrides(30) == {"camera": {"latency": 0.03}}
    assert AXES["detection"].overrides(0.8) == {"camera": {"detection": 0.8}}
    assert AXES["frame_rate"].overrides(15) == {"camera": {"frame_rate": 15}}
    assert AXES["accel_max"].overrides(0.5) == {"robot": {"accel_max": 0.5}}
    for name in ("camera_noise", "detection", "latency", "frame_rate", "accel_max"):
        assert AXES[name].overrides(AXES[name].levels[0]) == {}
    assert [level_key(v) for v in (None, 0.0, 0.5, 10.0, "aruco")] == [
        "none",
        "0",
        "0.5",
        "10",
        "aruco",
    ]
    assert AXES["frame_rate"].show(None) == "every step"
    assert {"ppc", "last_seen"} <= set(CONTROLLERS)


def test_build_grid_shares_the_ideal_point() -> None:
    axes = ["camera_noise", "latency", "accel_max"]
    grid, notes = build_grid(["study_b"], ["ppc"], axes, 2)
    assert notes == []
    assert len(grid) == 2 * (6 + 5 + 4)
    keys = [k for k, _ in grid]
    assert len(set(keys)) == len(keys)
    # The three ideal levels are one configuration: one episode (one store key) per seed.
    resolved = resolve_cells([cell for _, cell in grid], unique=False)
    assert len({rc.key for rc in resolved}) == 2 * (1 + 5 + 4 + 3)
    ideal = {rc.key for (k, _), rc in zip(grid, resolved, strict=True) if k[3] in ("0", "none")}
    assert len(ideal) == 2
    assert len(resolve_cells(cell for _, cell in grid)) == 2 * (1 + 5 + 4 + 3)


def test_ppc_failure_diagnostics() -> None:
    # 100 ms of camera latency on study C: the bearing loop oscillates out of the field of
    # view within seconds.
    ((_, cell),) = [
        (k, c) for k, c in build_grid(["study_c"], ["ppc"], ["latency"], 1)[0] if k[3] == "100"
    ]
    result = run_cell(resolve_cells([cell])[0])
    assert result.status == "done", result.error
    row = result.metrics
    assert row["success"] is False and row["violation"] == "out_of_fov"
    assert row["first_saturation"] in ("beta_lo", "beta_hi")
    assert row["first_saturation_time"] <= row["violation_time"]
    assert math.isfinite(row["xi_beta"]) and math.isfinite(row["xi_beta_true"])
    assert abs(row["xi_beta_true"]) >= 1.0  # truly out of the bearing funnel
    assert row["omega_flips_1s"] >= 2 and row["seen_steps_ago"] >= 0


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_quick_run_writes_csv_md_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fr"
    args = ["--quick", "--seeds", "1", "--study", "study_a", "--max-episode-steps", "15"]
    args += ["--axis", "latency", "--axis", "accel_max", "--out", str(out), "--workers", "1"]
    assert main(args) == 0
    rows = _csv(out / "frontiers.csv")
    assert list(rows[0]) == list(CSV_COLUMNS)
    assert len(rows) == len(CONTROLLERS) * 4  # two axes x two levels x one seed
    assert {(r["axis"], r["level"]) for r in rows} == {
        ("latency", "0"),
        ("latency", "50"),
        ("accel_max", "none"),
        ("accel_max", "0.5"),
    }
    assert all(r["success"] == "True" and r["steps"] == "15" for r in rows)
    md = (out / "frontiers.md").read_text()
    assert "## study_a" in md and "| latency | 50 | 1/1 [0.21, 1.00] |" in md
    assert (out / "frontier_study_a.png").stat().st_size > 5000
    assert "- rows: " in md and "- code: " in md  # the provenance of the rows
    # A re-run has nothing left to do (the three ideal levels were one episode each).
    capsys.readouterr()
    assert main(args) == 0
    assert "0 episode(s) run, " + str(len(CONTROLLERS) * 3) + " already in the store" in (
        capsys.readouterr().out
    )
    assert _csv(out / "frontiers.csv") == rows
    # Other settings in the same folder are other episodes, never mixed with these.
    other = [a if a != "15" else "16" for a in args]
    assert main(other) == 0
    rows16 = _csv(out / "frontiers.csv")
    assert len(rows16) == len(rows) and all(r["steps"] == "16" for r in rows16)


@pytest.mark.slow
def test_worker_pool(tmp_path: Path) -> None:
    """The spawn pool path (slow: each worker imports the package and loads its kernels)."""
    out = tmp_path / "pool"
    args = ["--quick", "--seeds", "2", "--study", "study_b", "--max-episode-steps", "10"]
    assert main([*args, "--axis", "detection", "--workers", "2", "--out", str(out)]) == 0
    rows = _csv(out / "frontiers.csv")
    assert len(rows) == len(CONTROLLERS) * 2 * 2
    assert {r["seed"] for r in rows} == {"0", "1"}


def test_robot_contact_is_diagnosed_on_the_rear_robot() -> None:
    import numpy as np

    from experiments.robustness import diagnosed_follower, failure_diagnostics
    from platoon_env.geometry.sensing import SENSE_BETA, SENSE_D
    from platoon_env.rollout import Episode

    # Leader at x = 2, follower 1 at x = 1, follower 2 at x = 0.75 (touching follower 1): both
    # followers are flagged, the first violation names follower 1.
    poses = np.zeros((2, 3, 3))
    poses[:, :, 0] = [2.0, 1.0, 0.75]
    sensed = np.zeros((2, 2, 9))
    sensed[:, :, SENSE_D] = [1.0, 0.25]
    sensed[:, :, SENSE_BETA] = [0.0, 0.1]
    ep = Episode(
        scenario="s", seed=0, control_period=0.01, d_des=0.8, times=np.array([0.0, 0.01]),
        poses=poses, sensed=sensed, actions=np.array([[[0.1, 0.2], [0.5, -0.3]]]),
        violations=np.array([[1, 1]]), terminated=True, truncated=False, leader_arrived=False,
        first_violation=(0, "collision_robot", 1),
    )  # fmt: skip
    assert diagnosed_follower(ep) == (2, "1-2")
    diag = failure_diagnostics(ep)
    assert diag["d_true"] == 0.25 and diag["beta_true"] == pytest.approx(0.1)
    assert diag["u_peak_1s"] == 0.5 and diag["omega_peak_1s"] == pytest.approx(0.3)
    other = Episode(**{**ep.__dict__, "first_violation": (0, "out_of_fov", 1)})
    assert diagnosed_follower(other) == (1, "")
