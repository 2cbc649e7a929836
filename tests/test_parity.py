"""experiments/studies/parity.py: the tail success of a run and the verdict of the comparison."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from experiments.studies.parity import report, tail_success, train_args, wall_time
from training.curves import PROGRESS_COLUMNS


def _progress(path: Path, rates: list[str]) -> Path:
    rows = [",".join(PROGRESS_COLUMNS)]
    rows += [f"{(i + 1) * 1000},{i},1,0.0,{r},0.0," for i, r in enumerate(rates)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_tail_success_averages_the_last_windows_with_episodes(tmp_path: Path) -> None:
    p = _progress(tmp_path / "progress.csv", ["0.0", "0.2", "0.4", "", "0.6"])
    assert tail_success(p, 2) == pytest.approx(0.5)  # 0.4 and 0.6; the empty window skipped
    with pytest.raises(ValueError, match="no logged window"):
        tail_success(_progress(tmp_path / "empty.csv", ["", ""]), 2)


def _args() -> argparse.Namespace:
    return argparse.Namespace(scenario="procedural_medium_train", timesteps=1000, tail=5)


@pytest.mark.parametrize(
    ("sb3", "fast", "verdict"),
    [
        ([0.50, 0.60, 0.55], [0.52, 0.58, 0.61], "**within noise**"),
        ([0.10, 0.12, 0.11], [0.80, 0.82, 0.81], "**not within noise**"),
        ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], "no variance to test"),
    ],
)
def test_the_verdict_follows_the_interval(
    sb3: list[float], fast: list[float], verdict: str
) -> None:
    text = report({"sb3": sb3, "fast": fast}, [0, 1, 2], _args(), {"argv": []})
    assert verdict in text
    assert "| sb3 |" in text and "| fast |" in text


def test_a_run_with_a_model_resumes(tmp_path: Path) -> None:
    assert "--resume" not in train_args("fast", "study_c", 10, 0, tmp_path)
    (tmp_path / "model.zip").write_bytes(b"")
    assert "--resume" in train_args("fast", "study_c", 10, 0, tmp_path)


def test_the_sb3_schedule_variant_is_the_fast_engine_on_sb3s_update_schedule(
    tmp_path: Path,
) -> None:
    args = train_args("fast_sb3_schedule", "procedural_medium_train", 10, 0, tmp_path)
    assert args[:2] == ["--engine", "fast"]
    opts = dict(zip(args[2:12:2], args[3:12:2], strict=True))
    assert opts == {"--n-envs": "64", "--n-steps": "32", "--batch-size": "256",
                    "--n-epochs": "10", "--learning-rate": "3e-4"}  # fmt: skip
    # the same rollout as SB3's 4 copies x 512 steps: 64 x 32
    assert 64 * 32 == 4 * 512
    assert train_args("sb3", "study_c", 10, 0, tmp_path)[:3] == ["--engine", "sb3", "--algo"]


def test_each_fast_variant_gets_a_verdict() -> None:
    rates = {
        "sb3": [0.5, 0.6, 0.55],
        "fast": [0.0, 0.0, 0.01],
        "fast_sb3_schedule": [0.52, 0.58, 0.6],
    }
    text = report(rates, [0, 1, 2], _args(), {"argv": []})
    assert "- fast - sb3:" in text and "**not within noise**" in text
    assert "- fast_sb3_schedule - sb3:" in text and "**within noise**" in text
    assert "| fast_sb3_schedule |" in text


def test_wall_times_are_a_column_with_the_throughput(tmp_path: Path) -> None:
    progress = _progress(tmp_path / "progress.csv", ["0.1", "0.2", "0.3"])
    assert wall_time(progress) == 2.0  # the last window's wall time
    # a resumed run: its second segment counts from 0 again
    with progress.open("a") as f:
        f.write("4000,0.5,1,0.0,0.4,0.0,\n")
    assert wall_time(progress) == 2.5
    rates = {"sb3": [0.5, 0.6, 0.55], "fast": [0.5, 0.55, 0.6]}
    walls = {"sb3": [100.0, 200.0, 300.0], "fast": [10.0, 20.0, 40.0]}
    args = _args()
    text = report(rates, [0, 1, 2], args, {"argv": []}, walls)
    assert "median wall time [s] | transitions/s |" in text
    assert f"| 200 | {args.timesteps / 200:,.0f} |" in text  # sb3's median
    assert f"| 20 | {args.timesteps / 20:,.0f} |" in text
    assert "median wall time" not in report(rates, [0, 1, 2], args, {"argv": []})
