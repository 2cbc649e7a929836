"""platoon-evaluate: a smoke run with PPC and a freshly trained model; resume; summary."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from experiments.policies import analytic_policies
from experiments.studies.evaluate import CSV_COLUMNS, PolicySpec, main, summarise, wilson
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
    assert "| study_c | ppc | – | 1 | 0 | 1/1" in summary
    assert "| study_c | tiny | – | 1 | 0 |" in summary
    assert (ppc["configuration"], ppc["training_seed"]) == ("ppc", "")
    for name in (
        "trajectories.png",
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
    base = {c: "0" for c in CSV_COLUMNS} | {"status": "done", "configuration": "p"}
    base["training_seed"] = ""
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
    assert "| s | p | – | 2 | 0 | 1/2" in text and "occluded 1" in text
    assert text.rstrip().endswith("2 |")
    rows[0] |= {"command_rate_u": "1.0", "command_rate_omega": "30"}
    rows[1] |= {"command_rate_u": "3.0", "command_rate_omega": "50"}
    assert "| 2.00 | 40.00 | 2 |" in summarise(rows)
    # rows stored before the command rates existed have no value: the column says so
    for row in rows:
        row["command_rate_u"] = row["command_rate_omega"] = ""
    assert "| – | – | 2 |" in summarise(rows)


def _png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels, from the PNG's IHDR chunk."""
    import struct

    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    width, height = struct.unpack(">II", head[16:24])
    return width, height


def test_configurations_group_training_seeds() -> None:
    from experiments.policies import MODEL, configurations

    def model(name: str) -> PolicySpec:
        return PolicySpec(name, MODEL, Path(f"/nowhere/{name}/model.zip"))

    specs = [PolicySpec.of("ppc"), model("a_s1"), model("a_s0"), model("b"), model("ppc_s0")]
    assert configurations(specs) == {
        "ppc": ("ppc", None),
        "a_s1": ("a", 1),
        "a_s0": ("a", 0),
        "b": ("b", None),
        "ppc_s0": ("ppc_s0", None),  # never merged with the analytic law of that name
    }
    # an analytic law named like a seed is not a training seed
    assert configurations([PolicySpec.of("ppc", "x_s3")]) == {"x_s3": ("x_s3", None)}


def test_summary_one_line_per_configuration() -> None:
    from experiments.significance import mean_success
    from experiments.studies.evaluate import _representatives

    base = {c: "0" for c in CSV_COLUMNS} | {"status": "done", "scenario": "s", "violation": ""}
    wins = {0: [True, True], 1: [True, False], 2: [False, False]}
    rows = [
        {**base, "policy": f"c_s{k}", "configuration": "c", "training_seed": str(k),
         "seed": str(e), "success": str(ok)}
        for k, oks in wins.items() for e, ok in enumerate(oks)
    ]  # fmt: skip
    rows += [
        {**base, "policy": "ppc", "configuration": "ppc", "training_seed": "", "seed": str(e),
         "success": "True"}
        for e in range(2)
    ]  # fmt: skip
    table = summarise(rows).splitlines()
    assert len(table) == 4  # header, rule, c, ppc
    expected = mean_success([[(2, 2)], [(1, 2)], [(0, 2)]])
    assert table[2].startswith(
        f"| s | c | 0..2 | 6 | 0..1 | 3/6 [{expected.low:.2f}, {expected.high:.2f}] | "
        "2, 1, 0 of 2 |"
    )
    lo, hi = wilson(2, 2)
    assert table[3].startswith(f"| s | ppc | – | 2 | 0..1 | 2/2 [{lo:.2f}, {hi:.2f}] | – |")
    assert _representatives({"ppc": ("ppc", None), "c_s1": ("c", 1), "c_s0": ("c", 0)}) == [
        "ppc",
        "c_s0",
    ]


def test_trajectory_grid_columns() -> None:
    from experiments.studies.evaluate import _grid_columns

    # eleven panels of a square-ish workspace: a landscape grid, not one column of eleven
    cols = _grid_columns(11, 0.93)
    assert 3 <= cols <= 5 and -(-11 // cols) * 0.93 < cols
    assert _grid_columns(1, 0.5) == 1
    assert _grid_columns(4, 1.6) == 4  # tall workspaces side by side


def test_default_benchmark_groups_seeds_and_notes(
    tiny_model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Models ``<configuration>_s<seed>`` found by --models: one summary line and one console
    note line per configuration and scenario, per-seed rows in results.csv, the notes in full
    in summary.md, the wall time in its header, and a landscape overview figure."""
    import shutil

    models = tmp_path / "models"
    for seed in (0, 1):
        # the same weights with another model.json: another policy (fingerprint) to the store
        run = shutil.copytree(tiny_model, models / f"tiny_s{seed}")
        meta = json.loads((run / "model.json").read_text())
        (run / "model.json").write_text(json.dumps({**meta, "seed": seed}))
    out = tmp_path / "eval"
    args = ["--models", str(models), "--scenario", "study_c", "--scenario", "study_a"]
    args += ["--episodes", "1", "--set", "max_episode_steps=60", "--workers", "1"]
    capsys.readouterr()
    assert main([*args, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    notes = [line for line in printed.splitlines() if line.startswith("note: ")]
    assert sorted(line.split(":")[1] for line in notes) == [" tiny on study_a", " tiny on study_c"]
    (on_a,) = (line for line in notes if "on study_a" in line)
    assert "2 seeds trained on study_c; followers trained with 2, the env has 7 (allowed)" in on_a
    assert "wall time: " in printed.splitlines()[-1]

    rows = _rows(out / "results.csv")
    assert list(rows[0]) == list(CSV_COLUMNS)
    laws = list(analytic_policies("evaluate"))
    assert "ppc" in laws and len(laws) >= 4  # PPC and the other laws
    assert sorted((r["scenario"], r["policy"], r["configuration"], r["training_seed"])
                  for r in rows) == sorted(
        (s, p, c, k)
        for s in ("study_a", "study_c")
        for p, c, k in (*((law, law, "") for law in laws), ("tiny_s0", "tiny", "0"),
                        ("tiny_s1", "tiny", "1"))
    )  # fmt: skip
    summary = (out / "summary.md").read_text()
    table = [line for line in summary.splitlines() if line.startswith("| study_")]
    assert [line.split(" | ")[:3] for line in table] == [
        [f"| {s}", p, k] for s in ("study_a", "study_c")
        for p, k in sorted([*((law, "–") for law in laws), ("tiny", "0..1")])
    ]  # fmt: skip
    assert summary.splitlines()[3].startswith("- wall time of this run: ")
    assert "## Notes on the learned models" in summary
    assert "  - seeds 0..1: followers: trained with 2, the env has 7" in summary
    assert "tiny_s0" not in "\n".join(notes)  # the console names configurations, not runs

    width, height = _png_size(out / "plots" / "trajectories.png")  # a row per law and config
    assert width / height > 2 / (len(laws) + 1) * 0.8  # 2 scenario columns
    width, height = _png_size(out / "plots" / "study_c_trajectories.png")  # 3 panels
    assert height < 1.5 * width


def test_realism_flag_parsing() -> None:
    import argparse

    from experiments.studies.evaluate import nest_assignments, parse_args, parse_assignment

    assert parse_assignment("noise.position=0.01") == (("noise", "position"), 0.01)
    assert parse_assignment("frame_rate=null") == (("frame_rate",), None)
    assert parse_assignment("accel_max = 1") == (("accel_max",), 1)
    for bad, match in (
        ("latency", "expected KEY=VALUE"),
        ("=1", "bad key"),
        ("noise..position=1", "bad key"),
        ("9lives=1", "bad key"),
        ("latency=[1", "not YAML"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=match):
            parse_assignment(bad)
    nested = nest_assignments(
        [(("noise", "position"), 0.01), (("latency",), 0.05), (("noise", "bearing"), 0.02)],
        "--camera",
    )
    assert nested == {"noise": {"position": 0.01, "bearing": 0.02}, "latency": 0.05}
    with pytest.raises(ValueError, match="both a value and sub-keys"):
        nest_assignments([(("noise",), 0), (("noise", "position"), 0.01)], "--camera")

    args = parse_args(
        [
            "--policy", "ppc", "--scenario", "study_a", "--sensor-profile", "aruco",
            "--camera", "noise.position=0.01", "--camera", "latency=0.02",
            "--robot", "accel_max=1", "--proximity", "noise=0.02",
        ]
    )  # fmt: skip
    assert args.realism.overrides() == {
        "sensor_profile": "aruco",
        "camera": {"noise": {"position": 0.01}, "latency": 0.02},
        "robot": {"accel_max": 1},
        "proximity": {"noise": 0.02},
    }
    assert args.realism.label == (
        "profile aruco; camera.noise.position=0.01; camera.latency=0.02; "
        "proximity.noise=0.02; robot.accel_max=1"
    )
    ((key, text),) = args.resolved.items()
    assert key == ("study_a", args.realism.label)
    resolved = json.loads(text)
    assert resolved["camera"]["noise"] == {
        "position": 0.01,
        "position_per_m": 0.01,
        "bearing": 0.01,
    }
    assert resolved["camera"]["latency"] == 0.02 and resolved["camera"]["frame_rate"] == 30.0
    assert resolved["robot"]["accel_max"] == 1 and resolved["proximity"]["noise"] == 0.02


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--camera", "latency"], "argument --camera: 'latency': expected KEY=VALUE"),
        (["--robot", "accel_max=[1"], "is not YAML"),
        (["--camera", "noise=0", "--camera", "noise.position=1"], "both a value and sub-keys"),
        (["--camera", "nosie=1"], "camera.nosie: unknown key"),
        (["--camera", "latency=0.015"], "whole number of control periods"),
        (["--robot", "accel_max=-1"], "robot.accel_max: must be > 0"),
        (["--sensor-profile", "no_such_profile"], "no_such_profile"),
    ],
)
def test_realism_flag_errors(
    flags: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from experiments.studies.evaluate import parse_args

    with pytest.raises(SystemExit) as exc:
        parse_args(["--policy", "ppc", "--scenario", "study_a", *flags])
    assert exc.value.code == 2  # an argparse usage error, not a traceback
    err = capsys.readouterr().err
    assert "usage: platoon-evaluate" in err and message in err and "Traceback" not in err


def test_rows_carry_the_realism(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "eval"
    base = ["--policy", "ppc", "--scenario", "study_c", "--episodes", "1", "--no-plots"]
    base += ["--workers", "1", "--out", str(out)]
    # 100 ms of latency: PPC loses its predecessor within seconds (a short episode).
    assert main([*base, "--camera", "latency=0.1"]) == 0
    (row,) = _rows(out / "results.csv")
    assert row["realism_label"] == "camera.latency=0.1" and row["sensor_profile"] == ""
    assert json.loads(row["realism"])["camera"]["latency"] == 0.1
    assert row["success"] == "False" and row["violation"] == "out_of_fov"
    first_fp = row["scenario_fingerprint"]
    # Other realism, same folder: a new episode, not a resumed one; the exports are this grid's.
    capsys.readouterr()
    assert main([*base, "--camera", "latency=0.05", "--camera", "frame_rate=15"]) == 0
    assert "1 episode(s) run, 0 already in the store" in capsys.readouterr().out
    (row,) = _rows(out / "results.csv")
    assert row["scenario_fingerprint"] != first_fp
    summary = (out / "summary.md").read_text()
    assert "realism flags: camera.latency=0.05; camera.frame_rate=15" in summary
    assert summary.count("| study_c | ppc | – | 1 |") == 1
    # The same realism again resumes: nothing to run.
    assert main([*base, "--camera", "latency=0.1"]) == 0
    assert "0 episode(s) run, 1 already in the store" in capsys.readouterr().out
    # Mixed rows are summarised per realism, never together.
    rows = [{**row, "realism_label": label, "scenario": "s"} for label in ("a", "b")]
    text = summarise(rows)
    assert text.count("### realism:") == 2 and text.count("| s | ppc | – | 1 |") == 2


def test_old_csv_folder_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A folder of the CSV-era platoon-evaluate: its rows cannot be matched to fingerprints, so
    they are neither resumed nor overwritten."""
    out = tmp_path / "old"
    out.mkdir()
    (out / "results.csv").write_text("policy,scenario,seed\nppc,study_a,0\n")
    args = ["--policy", "ppc", "--scenario", "study_a", "--episodes", "1", "--no-plots"]
    assert main([*args, "--out", str(out)]) == 2
    assert "written by an older platoon-evaluate" in capsys.readouterr().err
    assert (out / "results.csv").read_text() == "policy,scenario,seed\nppc,study_a,0\n"
    assert not (out / "results.sqlite").exists()


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--scenario", "no_such_scenario"], "no_such_scenario"),
        (["--workers", "0"], "argument --workers: must be >= 1, got 0"),
        (["--seed", "-1"], "argument --seed: must be >= 0, got -1"),
        (["--episodes", "0"], "argument --episodes: must be >= 1, got 0"),
        (["--episodes", "x"], "argument --episodes: 'x' is not an integer"),
        (["--policy", "=ppc"], "empty NAME"),
        (["--policy", "nope"], "not a policy kind"),
        (["--set", "max_episode_steps=-3"], "max_episode_steps"),
        (["--set", "nonsense=1"], "unexpected keyword argument 'nonsense'"),
        (["--set", "render_mode=human"], "not an option of an evaluation episode"),
        (["--set", "camera.latency=0.1"], "use the realism flag (--camera)"),
    ],
)
def test_cli_errors_are_usage_errors(
    flags: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "ppc", "--scenario", "study_c", *flags, "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "usage: platoon-evaluate" in err and message in err and "Traceback" not in err
    assert not out.exists()  # nothing written


def test_file_as_out_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "a_file"
    path.write_text("x")
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "ppc", "--scenario", "study_c", "--out", str(path)])
    assert exc.value.code == 2 and "exists and is not a folder" in capsys.readouterr().err
    assert path.read_text() == "x"


def test_duplicate_scenarios_run_once_and_headers_count_rows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--scenario study_c`` twice, or a name and a path to the same content, is one scenario;
    plots of a scenario given by an absolute path go to OUT/plots, never beside the YAML."""
    import yaml

    from platoon_env.scenarios.loader import load_config
    from platoon_env.scenarios.schema import config_to_mapping

    yaml_dir = tmp_path / "yaml"
    yaml_dir.mkdir()
    copy = yaml_dir / "my_c.yaml"
    copy.write_text(yaml.safe_dump(config_to_mapping(load_config("study_c"))))
    out = tmp_path / "eval"
    args = ["--policy", "ppc", "--scenario", str(copy), "--scenario", "study_c"]
    args += ["--scenario", str(copy), "--episodes", "2", "--workers", "1", "--out", str(out)]
    assert main([*args, "--set", "max_episode_steps=200"]) == 0
    assert "has the content of another one given: run once" in capsys.readouterr().out
    rows = _rows(out / "results.csv")
    assert sorted((r["scenario"], r["seed"]) for r in rows) == [(str(copy), "0"), (str(copy), "1")]
    summary = (out / "summary.md").read_text()
    assert "2 episodes summarised (seeds 0..1)" in summary
    meta = json.loads((out / "results.csv.meta.json").read_text())
    assert {r["run_id"] for r in rows} == {str(k) for k in meta["runs"]}
    assert meta["runs"][rows[0]["run_id"]]["stamp"]["tool"] == "platoon-evaluate"
    assert "| " + str(copy) + " | ppc | – | 2 | 0..1 |" in summary
    assert sorted(p.name for p in yaml_dir.iterdir()) == ["my_c.yaml"]
    assert (out / "plots" / "my_c_trajectories.png").is_file()


def test_suites() -> None:
    from experiments.suites import SUITES, suite

    paper = suite("paper")
    assert paper.scenarios == ("study_a", "study_b", "study_c") and paper.seeds >= 20
    assert [c.label for c in paper.conditions] == ["ideal", "aruco"]
    heldout = suite("heldout")
    assert heldout.scenarios == (
        "procedural_easy_test",
        "procedural_medium_test",
        "procedural_hard_test",
        "procedural_sharp_test",
        "procedural_paper_test",
    )
    assert heldout.seeds >= 200
    robust = suite("robustness")
    labels = [c.label for c in robust.conditions]
    assert labels[0] == "ideal" and "latency=50" in labels and "profile=aruco" in labels
    assert len(labels) == len(set(labels)) and all(c.overrides for c in robust.conditions[1:])
    assert set(SUITES) == {"paper", "heldout", "robustness"}
    with pytest.raises(KeyError, match="no suite"):
        suite("nope")


def test_suite_run_labels_rows_by_condition(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "eval"
    args = ["--suite", "paper", "--policy", "ppc", "--episodes", "1", "--no-plots"]
    args += ["--workers", "1", "--set", "max_episode_steps=30", "--out", str(out)]
    assert main(args) == 0
    rows = _rows(out / "results.csv")
    assert sorted((r["scenario"], r["realism_label"], r["sensor_profile"]) for r in rows) == [
        (s, label, "aruco" if label == "aruco" else "")
        for s in ("study_a", "study_b", "study_c")
        for label in ("aruco", "ideal")
    ]
    summary = (out / "summary.md").read_text()
    assert "### realism: aruco" in summary and "### realism: ideal" in summary
    assert "suite paper: conditions ideal, aruco" in summary
    for flags in (
        ["--scenario", "study_a"],
        ["--sensor-profile", "aruco"],
        ["--camera", "latency=0.1"],
    ):
        with pytest.raises(SystemExit) as exc:
            main([*args, *flags])
        assert exc.value.code == 2
        assert "--suite paper sets the scenarios and conditions" in capsys.readouterr().err
