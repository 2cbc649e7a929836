"""What breaks whom: the profile taken apart, the conditions, the failure places, a quick run."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from experiments.axes import AXES
from experiments.studies.breaks import (
    CSV_COLUMNS,
    PROFILE_AXES,
    Condition,
    _nest,
    axis_values,
    build_grid,
    condition_overrides,
    conditions,
    failure_place,
    main,
    place_of,
)
from platoon_env.geometry.sensing import SENSE_D_WALL_LEFT, SENSE_D_WALL_RIGHT
from platoon_env.rollout import Episode
from platoon_env.scenarios.fingerprint import config_fingerprint
from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.options import apply_overrides
from platoon_env.scenarios.profiles import load_profile


def _flat(block: dict, prefix: tuple[str, ...] = ()) -> dict[tuple[str, ...], object]:
    out: dict[tuple[str, ...], object] = {}
    for k, v in block.items():
        out.update(_flat(v, (*prefix, k)) if isinstance(v, dict) else {(*prefix, k): v})
    return out


def test_every_profile_field_belongs_to_one_axis() -> None:
    values = axis_values("aruco")
    assert list(values) == [a for a in PROFILE_AXES if a in values]
    merged = {p: v for per_axis in values.values() for p, v in per_axis.items()}
    assert merged == _flat(load_profile("aruco"))
    assert values["latency"] == {("camera", "latency"): 0.05}
    assert values["accel_limits"] == {("robot", "accel_max"): 2.5, ("robot", "alpha_max"): 3.2}
    # The profile's lag is the studies' own 0: the axis is skipped, with a note.
    conds, notes = conditions("study_a", "aruco")
    assert not any(c.axis == "actuator_lag" for c in conds)
    assert len(notes) == 1 and "actuator_lag" in notes[0]
    active = [a for a in PROFILE_AXES if a != "actuator_lag"]
    assert conds == [
        Condition("ideal"),
        Condition("profile"),
        *(Condition("without", a) for a in active),
        *(Condition("alone", a) for a in active),
    ]


def test_a_profile_field_no_axis_holds_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "odd.yaml"
    path.write_text("camera: {latency: 0.02, half_angle: 0.5}\n")
    with pytest.raises(ValueError, match=r"camera\.half_angle belongs to no axis"):
        axis_values(str(path))


@pytest.mark.parametrize("study", ["study_a", "study_b", "study_c"])
def test_removed_axis_is_the_profile_minus_that_axis(study: str) -> None:
    cfg = load_config(study)
    profile = _flat(load_profile("aruco"))

    def fp(overrides: dict) -> str:
        return config_fingerprint(apply_overrides(cfg, overrides))

    conds, _ = conditions(study, "aruco")
    whole = fp(condition_overrides(study, Condition("profile"), "aruco"))
    # the whole profile is the frontiers' profile level, and all its fields as block options
    frontier_level = AXES["profile"].overrides("aruco")
    assert condition_overrides(study, Condition("profile"), "aruco") == frontier_level
    assert whole == fp(_nest(profile))
    assert fp(condition_overrides(study, Condition("ideal"), "aruco")) == config_fingerprint(cfg)
    for cond in conds:
        if cond.kind not in ("without", "alone"):
            continue
        fields = PROFILE_AXES[cond.axis].fields
        got = fp(condition_overrides(study, cond, "aruco"))
        if cond.kind == "without":
            rest = {p: v for p, v in profile.items() if p not in fields}
            assert got == fp(_nest(rest)), cond
            assert got != whole, cond
        else:
            alone = {p: v for p, v in profile.items() if p in fields}
            assert got == fp(_nest(alone)), cond
            assert got != config_fingerprint(cfg), cond


def test_grid_keys_and_bad_input() -> None:
    grid, conds, notes = build_grid(["study_b"], ["ppc", "last_seen"], 2)
    assert len(grid) == 2 * 2 * len(conds["study_b"])
    keys = [k for k, _ in grid]
    assert len(set(keys)) == len(keys)
    assert ("ppc", "study_b", "without", "latency", "1") in keys
    assert ("last_seen", "study_b", "profile", "", "0") in keys
    assert notes
    with pytest.raises(ValueError, match="unknown controller"):
        build_grid(["study_b"], ["nope"], 1)
    with pytest.raises(ValueError):
        Condition("without")
    with pytest.raises(ValueError):
        Condition("alone", "colour")
    with pytest.raises(ValueError):
        Condition("profile", "latency")


def test_place_of() -> None:
    # r = 0.2, delta = 0.5: a side is near when d_W - r < 0.5, i.e. d_W < 0.7
    row = {"fail_d_W_l": "0.6", "fail_d_W_r": "0.65"}
    assert place_of(row, 0.2, 0.5) == "narrow"
    assert place_of({**row, "fail_d_W_r": "0.75"}, 0.2, 0.5) == "wall"
    assert place_of({"fail_d_W_l": "3", "fail_d_W_r": "4"}, 0.2, 0.5) == "open"
    assert place_of({"fail_d_W_l": "", "fail_d_W_r": ""}, 0.2, 0.5) == ""


def test_failure_place_is_the_rear_robot_of_a_contact() -> None:
    poses = np.zeros((2, 3, 3))
    poses[0, :, 0] = [2.0, 1.0, 0.6]
    poses[1, :, 0] = [2.0, 1.0, 0.75]  # after the step: follower 2 touches follower 1
    poses[1, :, 1] = [0.0, 0.1, 0.2]
    sensed = np.zeros((2, 2, 9))
    sensed[1, :, SENSE_D_WALL_LEFT] = [1.0, 0.4]
    sensed[1, :, SENSE_D_WALL_RIGHT] = [2.0, 0.5]
    ep = Episode(
        scenario="s", seed=0, control_period=0.01, d_des=0.8, times=np.array([0.0, 0.01]),
        poses=poses, sensed=sensed, actions=np.zeros((1, 2, 2)),
        violations=np.array([[1, 1]]), terminated=True, truncated=False, leader_arrived=False,
        first_violation=(0, "collision_robot", 1),
    )  # fmt: skip
    assert failure_place(ep) == {
        "fail_x": 0.75,
        "fail_y": 0.2,
        "fail_d_W_l": 0.4,
        "fail_d_W_r": 0.5,
    }
    ok = Episode(**{**ep.__dict__, "first_violation": None, "truncated": True})
    assert set(failure_place(ok).values()) == {""}


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_quick_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Study A's PPC under the aruco profile fails within its first 3 s (300 steps).
    out, figs = tmp_path / "br", tmp_path / "figs"
    args = ["--quick", "--seeds", "1", "--study", "study_a", "--controller", "ppc"]
    args += ["--max-episode-steps", "300", "--out", str(out), "--figures", str(figs)]
    assert main([*args, "--workers", "1"]) == 0
    rows = _csv(out / "breaks.csv")
    assert list(rows[0]) == list(CSV_COLUMNS)
    conds, _ = conditions("study_a", "aruco")
    assert {(r["condition"], r["axis"]) for r in rows} == {(c.kind, c.axis) for c in conds}
    assert len(rows) == len(conds)
    profile = next(r for r in rows if r["condition"] == "profile")
    assert profile["success"] == "False"
    failed = [r for r in rows if r["success"] == "False"]
    for r in failed:
        assert 0 < float(r["violation_time"]) <= 3.0
        assert math.isfinite(float(r["fail_x"])) and math.isfinite(float(r["fail_y"]))
        assert float(r["fail_d_W_l"]) >= 0 and float(r["fail_d_W_r"]) >= 0
    for r in rows:
        if r["success"] == "True":
            assert r["fail_x"] == "" and r["steps"] == "300"
    md = (out / "breaks.md").read_text()
    assert "### study_a" in md and "| aruco (the whole profile) | 0/1 [0.00, 0.79] |" in md
    assert "| aruco without latency |" in md and "| accel_limits alone |" in md
    assert "### The start-up question" in md and "study_a, PPC: " in md
    assert "- code: " in md
    for name in ("breaks_study_a.png", "breaks_times.png"):
        assert (figs / name).stat().st_size > 5000
    # a re-run has nothing left to do
    capsys.readouterr()
    assert main([*args, "--workers", "1"]) == 0
    assert f"0 episode(s) run, {len(conds)} already in the store" in capsys.readouterr().out
    assert _csv(out / "breaks.csv") == rows
