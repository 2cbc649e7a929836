"""experiments/studies/parity.py: the tail success of a run and the verdict of the comparison."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from experiments.studies.parity import report, tail_success, train_args
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
