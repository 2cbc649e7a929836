"""platoon-evaluate: a smoke run with PPC and a freshly trained model; resume; summary."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from training.evaluate import CSV_COLUMNS, PolicySpec, main, summarise, wilson
from training.train import main as train_main


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("model")
    code = train_main(
        [
            "--algo",
            "ppo",
            "--scenario",
            "study_c",
            "--timesteps",
            "512",
            "--n-envs",
            "1",
            "--n-steps",
            "256",
            "--batch-size",
            "64",
            "--seed",
            "0",
            "--out",
            str(out),
            "--no-progress-bar",
            "--verbose",
            "0",
        ]
    )
    assert code == 0
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_evaluate_ppc_and_model(tiny_model: Path, tmp_path: Path) -> None:
    out = tmp_path / "eval"
    args = [
        "--policy",
        "ppc",
        "--policy",
        f"tiny={tiny_model}",
        "--scenario",
        "study_c",
        "--episodes",
        "1",
        "--workers",
        "2",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    rows = _rows(out / "results.csv")
    assert [r["policy"] for r in sorted(rows, key=lambda r: r["policy"])] == ["ppc", "tiny"]
    assert list(rows[0]) == list(CSV_COLUMNS)
    ppc = next(r for r in rows if r["policy"] == "ppc")
    assert ppc["success"] == "True" and ppc["violation"] == ""
    summary = (out / "summary.md").read_text()
    assert "| study_c | ppc | 1 | 1/1" in summary and "| study_c | tiny | 1 |" in summary
    for name in (
        "study_c_trajectories.png",
        "study_c_errors.png",
        "study_c_commands.png",
        "study_c_ppc.gif",
        "study_c_tiny.gif",
    ):
        assert (out / "plots" / name).stat().st_size > 1000
    # Re-running resumes: the finished episodes are not run again, new seeds are added.
    more = ["--policy", "ppc", "--policy", f"tiny={tiny_model}", "--scenario", "study_c"]
    assert main([*more, "--episodes", "2", "--no-plots", "--workers", "1", "--out", str(out)]) == 0
    rows = _rows(out / "results.csv")
    assert sorted((r["policy"], r["seed"]) for r in rows) == [
        ("ppc", "0"),
        ("ppc", "1"),
        ("tiny", "0"),
        ("tiny", "1"),
    ]


def test_policy_spec_errors(tmp_path: Path) -> None:
    import argparse

    with pytest.raises(argparse.ArgumentTypeError, match="no model file"):
        PolicySpec.parse(f"x={tmp_path}")
    assert PolicySpec.parse("ppc").kind == "ppc"


def test_wilson_interval() -> None:
    lo, hi = wilson(5, 5)
    assert hi == 1.0 and 0.5 < lo < 0.6
    lo, hi = wilson(0, 10)
    assert lo == 0.0 and 0.25 < hi < 0.35


def test_summary_counts_causes() -> None:
    base = {c: "0" for c in CSV_COLUMNS}
    rows = [
        {
            **base,
            "policy": "p",
            "scenario": "s",
            "success": "False",
            "violation": "occluded",
            "funnel_exits": "0",
        },
        {
            **base,
            "policy": "p",
            "scenario": "s",
            "success": "True",
            "violation": "",
            "funnel_exits": "2",
        },
    ]
    text = summarise(rows)
    assert "| s | p | 2 | 1/2" in text and "occluded 1" in text and text.rstrip().endswith("2 |")
