"""``platoon-sweep`` (``experiments.studies.sweep``): the ``platoon-train`` arguments of each run
(with ``--resume`` exactly when its directory holds a run), the shipped configurations, ``ship()``
and the command line. No training is run here."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("stable_baselines3")

from experiments.configs import CONFIGS
from experiments.studies import sweep
from experiments.studies.sweep import RESUMABLE, main, run_args, run_dir, ship
from training.train import RUN_FILES, check_scenario, make_env, parse_args, plan_run

CONFIG = CONFIGS["ppo_ta_aruco"]
SHIPPED = ("model.zip", "model.json", "progress.csv")


def mark_run(out: Path, name: str) -> None:
    """Make ``out`` hold a run through ``name`` (a directory for tb/ and rllib_checkpoint/; a
    zip with the JSON that records it, as a save writes them)."""
    out.mkdir(parents=True, exist_ok=True)
    if name in ("tb", "rllib_checkpoint"):
        (out / name).mkdir()
    elif name.endswith(".zip"):
        save_pair(out, name.removesuffix(".zip"), b"x")
    else:
        (out / name).write_text("x")


def save_pair(out: Path, name: str, data: bytes, **meta: Any) -> None:
    """``out/NAME.zip`` holding ``data`` and ``out/NAME.json`` recording its SHA-256 (and
    ``meta``)."""
    import hashlib

    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.zip").write_bytes(data)
    digest = hashlib.sha256(data).hexdigest()
    (out / f"{name}.json").write_text(json.dumps({"zip_sha256": digest, **meta}))


def value_after(args: list[str], flag: str) -> str:
    assert args.count(flag) == 1, args
    return args[args.index(flag) + 1]


# ------------------------------------------------------------------------------------------------
# run_args
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("state", ["missing", "empty", "only_train_log"])
def test_run_args_of_a_directory_without_a_run_do_not_resume(tmp_path: Path, state: str) -> None:
    out = tmp_path / "ppo_ta_aruco" / "s3"
    if state != "missing":
        out.mkdir(parents=True)
    if state == "only_train_log":
        (out / "train.log").write_text("$ python -m training.train ...\n")
    args = run_args(CONFIG, 3, out)
    assert "--resume" not in args
    assert args[: len(CONFIG.args)] == list(CONFIG.args)
    assert value_after(args, "--seed") == "3"
    assert value_after(args, "--out") == str(out)
    assert args.count("--no-progress-bar") == 1
    cfg = parse_args(args)
    assert (cfg.seed, cfg.out, cfg.progress_bar, cfg.resume) == (3, str(out), False, False)


@pytest.mark.parametrize("name", RESUMABLE)
def test_run_args_resume_when_the_directory_holds_a_run(tmp_path: Path, name: str) -> None:
    out = tmp_path / "lag_ta_aruco" / "s1"
    mark_run(out, name)
    config = CONFIGS["lag_ta_aruco"]
    args = run_args(config, 1, out)
    assert args.count("--resume") == 1
    assert args[: len(config.args)] == list(config.args)
    assert value_after(args, "--seed") == "1"
    assert value_after(args, "--out") == str(out)
    assert "--no-progress-bar" in args
    cfg = parse_args(args)
    assert cfg.resume and not cfg.force and cfg.seed == 1 and cfg.out == str(out)


@pytest.mark.parametrize("name", sorted(set(RUN_FILES) - set(RESUMABLE)))
def test_run_files_without_a_model_start_the_run_over(tmp_path: Path, name: str) -> None:
    # the logs or a description without the model or checkpoint: nothing to continue from
    assert "progress.csv" in RUN_FILES and "model.json" in RUN_FILES
    out = tmp_path / name.replace(".", "_")
    mark_run(out, name)
    args = run_args(CONFIG, 0, out)
    assert args[-1] == "--force" and "--resume" not in args
    cfg = parse_args(args)
    assert cfg.force and not cfg.resume


CUTS = {
    # a first save cut after its zip (no JSON yet)
    "zip_without_json": lambda out: (out / "model.zip").write_bytes(b"new"),
    # a later save cut after its zip: the JSON of the save before
    "zip_of_another_save": lambda out: (
        save_pair(out, "model", b"old"),
        (out / "model.zip").write_bytes(b"new"),
    ),
    # a checkpoint of the fast engine cut after its learner state
    "state_of_another_save": lambda out: (
        (out / "checkpoint.state.pt").write_bytes(b"new"),
        save_pair(out, "checkpoint", b"zip", learner_state_sha256="0" * 64),
    ),
}


@pytest.mark.parametrize("cut", sorted(CUTS))
def test_a_run_whose_only_save_was_cut_starts_over(tmp_path: Path, cut: str) -> None:
    """A save cut off between its files (kill -9, a full disk) leaves nothing to continue
    from: the sweep starts the run over (--force), where --resume would fail it on every
    re-run (platoon-train: "nothing to resume")."""
    out = tmp_path / "ppo_ta_aruco" / "s0"
    out.mkdir(parents=True)
    (out / "progress.csv").write_text("timesteps\n")
    CUTS[cut](out)
    args = run_args(CONFIG, 0, out)
    assert "--force" in args and "--resume" not in args
    (reason,) = sweep.cut_saves(out)
    assert "a save cut off" in reason or "not from the same save" in reason


def test_a_cut_model_beside_a_complete_checkpoint_resumes_from_the_checkpoint(
    tmp_path: Path,
) -> None:
    out = tmp_path / "ppo_ta_aruco" / "s0"
    save_pair(out, "checkpoint", b"checkpoint")
    save_pair(out, "model", b"old")
    (out / "model.zip").write_bytes(b"new")
    assert run_args(CONFIG, 0, out)[-1] == "--resume"
    assert [c.split(":")[0] for c in sweep.cut_saves(out)] == ["model"]


def test_the_sweep_says_why_it_starts_a_cut_run_over(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    seen: list[list[str]] = []

    class FakePopen:
        def __init__(self, cmd: list[str], **kwargs: Any) -> None:
            seen.append(cmd)

        def wait(self, timeout: float | None = None) -> int:
            return 0

    monkeypatch.setattr(sweep.subprocess, "Popen", FakePopen)
    out = tmp_path / "ppo_ta_aruco" / "s0"
    out.mkdir(parents=True)
    (out / "model.zip").write_bytes(b"new")
    assert sweep._train(CONFIG, 0, out)[1] == 0
    assert "--force" in seen[0]
    line = capsys.readouterr().out.strip()
    assert line.startswith("ppo_ta_aruco s0: nothing complete to resume (model: model.zip ")
    assert line.endswith("starting it over") and "\n" not in line
    assert line in (out / "train.log").read_text()


def test_run_dir_layout() -> None:
    assert run_dir(Path("runs/sweep"), "ppo_ta_aruco", 4) == Path("runs/sweep/ppo_ta_aruco/s4")


def test_a_run_killed_before_its_first_checkpoint_starts_over(tmp_path: Path) -> None:
    # tb/ and progress.csv exist from the start, the first checkpoint only after 100k steps:
    # with nothing to continue from, the sweep starts the run over (--force), not --resume
    out = tmp_path / "ppo_ta_aruco" / "s0"
    mark_run(out, "tb")
    (out / "progress.csv").write_text("timesteps,wall_time_s,episodes\n")
    args = run_args(CONFIG, 0, out)
    assert "--force" in args and "--resume" not in args
    cfg = parse_args(args)
    env = make_env(cfg)
    try:
        assert plan_run(cfg, env).mode == "new"  # --force: a fresh run, no error
    finally:
        env.close()


# ------------------------------------------------------------------------------------------------
# The shipped configurations
# ------------------------------------------------------------------------------------------------
def test_configs_are_named_by_their_keys() -> None:
    assert set(CONFIGS) == {
        "ppo_ta_aruco",
        "lag_ta_aruco",
        "bc_ppo_sharp",
        "bc_ppo_formations_sf",
        "bc_ppo_mixed_anchor",
        "bc_ppo_mixed_20ms",
        "residual_ppc",
        "residual_filtered_aruco",
        "residual_filtered_aruco_cmd",
        "residual_drive_aruco",
        "residual_drive_realism",
        "residual_filtered_realism",
        "lag_residual_drive_realism",
    }
    for name, config in CONFIGS.items():
        assert config.name == name and config.summary
        assert "--seed" not in config.args and "--out" not in config.args
        assert "--resume" not in config.args and "--force" not in config.args


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_every_config_parses_and_resolves(name: str) -> None:
    config = CONFIGS[name]
    cfg = parse_args([*config.args, "--seed", "0", "--out", "x"])
    assert cfg.task_aware_observations is True
    # the SB3 configurations train under aruco (30 Hz frames), the clones with ideal sensing
    # the realism configurations: aruco for the law, each episode's realism drawn
    realism = name.endswith("_realism")
    aruco = cfg.engine == "sb3" or name.endswith(("_aruco", "_aruco_cmd")) or realism
    assert cfg.sensor_profile == ("aruco" if aruco else None)
    assert cfg.realism_preset == ("ideal_to_beyond_aruco" if realism else None)
    residual = {
        "residual_ppc": "ppc",
        "residual_filtered_aruco": "filtered_ppc",
        "residual_filtered_aruco_cmd": "filtered_ppc",
        "residual_drive_aruco": "filtered_ppc_drive",
        "residual_drive_realism": "filtered_ppc_drive",
        "residual_filtered_realism": "filtered_ppc",
        "lag_residual_drive_realism": "filtered_ppc_drive",
    }
    assert cfg.residual == residual.get(name)
    assert cfg.control_period <= 1 / 30
    assert cfg.scale_free_observations == (
        name.startswith(("bc_ppo_formations", "bc_ppo_mixed", "residual", "lag_residual"))
    )
    assert (
        cfg.algo
        == {
            "ppo_ta_aruco": "ppo",
            "lag_ta_aruco": "ppo_lagrangian",
            "bc_ppo_sharp": "bc_ppo",
            "bc_ppo_formations_sf": "bc_ppo",
            "bc_ppo_mixed_anchor": "bc_ppo",
            "bc_ppo_mixed_20ms": "bc_ppo",
            "residual_ppc": "ppo",
            "residual_filtered_aruco": "ppo",
            "residual_filtered_aruco_cmd": "ppo",
            "residual_drive_aruco": "ppo",
            "residual_drive_realism": "ppo",
            "residual_filtered_realism": "ppo",
            "lag_residual_drive_realism": "ppo_lagrangian",
        }[name]
    )
    assert cfg.timesteps >= 1
    assert cfg.previous_command == name.endswith("_cmd")
    env = make_env(cfg)
    try:
        assert check_scenario(cfg, env) == []  # platoon-train would not refuse it
        assert env.control_period == pytest.approx(cfg.control_period)
        agent = env.possible_agents[0]
        # the task-aware observation (13 values), scale-free (15)
        size = 15 if cfg.scale_free_observations else 13
        assert env.observation_space(agent).shape == (size,)
    finally:
        env.close()


def test_lagrangian_config_sets_its_budget() -> None:
    cfg = parse_args([*CONFIGS["lag_ta_aruco"].args, "--seed", "0", "--out", "x"])
    assert cfg.cost_budget == pytest.approx(0.05)


# ------------------------------------------------------------------------------------------------
# ship
# ------------------------------------------------------------------------------------------------
def recorded_options(config: str, seed: int, *extra: str) -> dict[str, Any]:
    """The ``config`` block platoon-train records in model.json for a run of ``config``."""
    import dataclasses

    args = [*CONFIGS[config].args, *extra, "--seed", str(seed), "--out", "x"]
    return dataclasses.asdict(parse_args(args))


def fake_run(runs: Path, name: str, seed: int, **meta: Any) -> Path:
    """A run folder of configuration ``name`` and ``seed`` whose model.json holds ``meta`` (and,
    unless given, the options the configuration trains with)."""
    src = run_dir(runs, name, seed)
    src.mkdir(parents=True)
    meta.setdefault("config", recorded_options(name, seed))
    (src / "model.zip").write_bytes(f"zip {name} {seed}".encode())
    (src / "model.json").write_text(json.dumps(meta))
    (src / "progress.csv").write_text(f"timesteps\n{seed}\n")
    (src / "checkpoint.zip").write_bytes(b"not shipped")
    (src / "train.log").write_text("not shipped")
    return src


def test_ship_copies_finished_runs_and_skips_the_others(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs, models = tmp_path / "runs", tmp_path / "models"
    done = fake_run(runs, "ppo_ta_aruco", 0, timesteps=1000, timesteps_requested=1000)
    fake_run(runs, "ppo_ta_aruco", 1, timesteps=400, timesteps_requested=1000)
    fake_run(runs, "ppo_ta_aruco", 2, timesteps=1000, timesteps_requested=1000, interrupted=True)
    more = fake_run(
        runs, "lag_ta_aruco", 0, timesteps=1024, timesteps_requested=1000, interrupted=False
    )
    shipped = ship(runs, models, ["ppo_ta_aruco", "lag_ta_aruco"], [0, 1, 2, 3])
    assert shipped == [models / "ppo_ta_aruco_s0", models / "lag_ta_aruco_s0"]
    for src, dst in ((done, shipped[0]), (more, shipped[1])):
        assert sorted(p.name for p in dst.iterdir()) == sorted(SHIPPED)
        for f in SHIPPED:
            assert (dst / f).read_bytes() == (src / f).read_bytes()
    assert sorted(p.name for p in models.iterdir()) == ["lag_ta_aruco_s0", "ppo_ta_aruco_s0"]
    err = capsys.readouterr().err
    assert "skip ppo_ta_aruco s1: unfinished (400 of 1000)" in err
    assert "skip ppo_ta_aruco s2" in err  # interrupted
    assert "skip ppo_ta_aruco s3: no" in err  # missing
    assert "skip lag_ta_aruco s1: no" in err
    assert "ppo_ta_aruco s0" not in err and "lag_ta_aruco s0" not in err


def test_ship_skips_a_run_missing_a_file_or_its_counts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs, models = tmp_path / "runs", tmp_path / "models"
    no_curve = fake_run(runs, "ppo_ta_aruco", 0, timesteps=10, timesteps_requested=10)
    (no_curve / "progress.csv").unlink()
    fake_run(runs, "ppo_ta_aruco", 1, timesteps=10)  # no timesteps_requested
    assert ship(runs, models, ["ppo_ta_aruco"], [0, 1]) == []
    assert not models.exists() or not any(models.iterdir())  # nothing half-shipped
    err = capsys.readouterr().err
    assert "skip ppo_ta_aruco s0: no progress.csv" in err
    assert "skip ppo_ta_aruco s1: unfinished (10 of None)" in err


def test_ship_skips_a_bad_model_json_and_ships_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs, models = tmp_path / "runs", tmp_path / "models"
    for seed, text in ((0, "{not json"), (1, "[1, 2]"), (2, "\udcff")):
        bad = fake_run(runs, "ppo_ta_aruco", seed, timesteps=5, timesteps_requested=5)
        (bad / "model.json").write_text(text, errors="surrogateescape")
    bad_counts = fake_run(runs, "ppo_ta_aruco", 3, timesteps="5", timesteps_requested=5)  # text
    good = fake_run(runs, "ppo_ta_aruco", 4, timesteps=5, timesteps_requested=5)
    shipped = ship(runs, models, ["ppo_ta_aruco"], [0, 1, 2, 3, 4])
    assert shipped == [models / "ppo_ta_aruco_s4"]
    assert (shipped[0] / "model.zip").read_bytes() == (good / "model.zip").read_bytes()
    err = capsys.readouterr().err
    assert (
        f"skip ppo_ta_aruco s0: {runs / 'ppo_ta_aruco' / 's0' / 'model.json'} is not readable JSON"
        in err
    )
    assert "skip ppo_ta_aruco s1: " in err and "is not a JSON object" in err
    assert "skip ppo_ta_aruco s2: " in err and "is not readable JSON" in err
    assert "skip ppo_ta_aruco s3: unfinished (5 of 5)" in err
    assert bad_counts.is_dir()


def test_ship_refuses_a_run_trained_with_other_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run folder of one configuration holding a run of other options (another seed, the
    other algorithm, another learning rate or scenario, fewer timesteps) is not shipped as it."""
    runs, models = tmp_path / "runs", tmp_path / "models"
    done = {"timesteps": 5, "timesteps_requested": 5}
    fake_run(runs, "ppo_ta_aruco", 0, **done, config=recorded_options("ppo_ta_aruco", 1))
    fake_run(runs, "ppo_ta_aruco", 1, **done, config=recorded_options("lag_ta_aruco", 1))
    fake_run(runs, "ppo_ta_aruco", 2, **done,
             config=recorded_options("ppo_ta_aruco", 2, "--learning-rate", "0.001"))  # fmt: skip
    fake_run(runs, "ppo_ta_aruco", 3, **done,
             config=recorded_options("ppo_ta_aruco", 3, "--scenario", "study_c"))  # fmt: skip
    fake_run(runs, "ppo_ta_aruco", 4, **done,
             config=recorded_options("ppo_ta_aruco", 4, "--timesteps", "1000"))  # fmt: skip
    fake_run(runs, "ppo_ta_aruco", 5, **done, config=None)
    fake_run(runs, "ppo_ta_aruco", 6, **done)
    shipped = ship(runs, models, ["ppo_ta_aruco"], range(7))
    assert shipped == [models / "ppo_ta_aruco_s6"]
    err = capsys.readouterr().err
    assert "skip ppo_ta_aruco s0: " in err and "--seed: stored 1, given 0" in err
    assert "--algo: stored 'ppo_lagrangian', given 'ppo'" in err
    assert "--learning-rate: stored 0.001, given 0.0003" in err
    assert "--scenario: stored 'study_c', given 'procedural_medium_train'" in err
    assert "--timesteps: stored 1000, given 1500000" in err
    assert "skip ppo_ta_aruco s5: " in err and "no recorded options" in err
    assert "records other options than the configuration ppo_ta_aruco with seed 2" in err


def test_ship_replaces_an_earlier_copy(tmp_path: Path) -> None:
    runs, models = tmp_path / "runs", tmp_path / "models"
    src = fake_run(runs, "ppo_ta_aruco", 0, timesteps=10, timesteps_requested=10)
    (models / "ppo_ta_aruco_s0").mkdir(parents=True)
    (models / "ppo_ta_aruco_s0" / "model.zip").write_bytes(b"old")
    ship(runs, models, ["ppo_ta_aruco"], [0])
    assert (models / "ppo_ta_aruco_s0" / "model.zip").read_bytes() == (
        src / "model.zip"
    ).read_bytes()


def test_main_ship_exit_status(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs, models = tmp_path / "runs", tmp_path / "models"
    argv = ["--ship", "--runs", str(runs), "--models", str(models), "--seeds", "0"]
    assert main(argv) == 1  # nothing to ship
    assert not models.exists() or not any(models.iterdir())
    fake_run(runs, "lag_ta_aruco", 0, timesteps=5, timesteps_requested=5)
    assert main(argv) == 0
    assert f"shipped {models / 'lag_ta_aruco_s0'}" in capsys.readouterr().out
    assert (models / "lag_ta_aruco_s0" / "model.zip").is_file()


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def test_list_prints_every_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--list"]) == 0
    out = capsys.readouterr().out
    for name, config in CONFIGS.items():
        assert f"{name}: {config.summary}" in out
        assert "platoon-train " + " ".join(config.args) in out


@pytest.mark.parametrize(
    "argv",
    [
        ["--seeds", "1", "1"],
        ["--seeds", "0", "-1"],
        ["--jobs", "0"],
        ["--jobs", "-2", "--list"],
        ["--config", "no_such_config"],
    ],
)
def test_bad_arguments_are_argparse_errors(
    argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_training(*args: Any) -> Any:
        raise AssertionError("a refused sweep must not train")

    monkeypatch.setattr(sweep, "_train", no_training)
    with pytest.raises(SystemExit) as info:
        main([*argv, "--runs", str(tmp_path / "runs")])
    assert info.value.code == 2
    assert not (tmp_path / "runs").exists()


def test_main_trains_every_run_and_fails_if_one_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    started: list[tuple[str, int, Path]] = []

    def fake_train(config: Any, seed: int, out: Path) -> tuple[str, int, float]:
        started.append((config.name, seed, out))
        return f"{config.name} s{seed}", 3 if (config.name, seed) == ("lag_ta_aruco", 1) else 0, 6

    monkeypatch.setattr(sweep, "_train", fake_train)
    runs = tmp_path / "runs"
    assert main(["--seeds", "0", "1", "--jobs", "2", "--runs", str(runs)]) == 1
    assert sorted(started) == sorted((n, s, run_dir(runs, n, s)) for n in CONFIGS for s in (0, 1))
    out = capsys.readouterr().out
    assert f"{2 * len(CONFIGS)} runs, 2 at a time" in out
    assert "lag_ta_aruco s1: FAILED (exit 3" in out
    assert "ppo_ta_aruco s0: done in 0.1 min" in out
    started.clear()
    assert main(["--config", "ppo_ta_aruco", "--seeds", "2", "--runs", str(runs)]) == 0
    assert started == [("ppo_ta_aruco", 2, run_dir(runs, "ppo_ta_aruco", 2))]


def test_train_runs_platoon_train_with_one_torch_thread_and_logs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: dict[str, Any] = {}

    class FakePopen:
        def __init__(self, cmd: list[str], **kwargs: Any) -> None:
            seen["cmd"], seen["kwargs"] = cmd, kwargs
            kwargs["stdout"].write("trained\n")

        def wait(self, timeout: float | None = None) -> int:
            return 0

    monkeypatch.setattr(sweep.subprocess, "Popen", FakePopen)
    monkeypatch.chdir(tmp_path)
    out = Path("runs") / "ppo_ta_aruco" / "s0"  # relative: the caller's working directory
    name, rc, wall = sweep._train(CONFIG, 0, out)
    assert (name, rc) == ("ppo_ta_aruco s0", 0) and wall >= 0
    cmd = seen["cmd"]
    assert cmd[:3] == [sys.executable, "-m", "training.train"]
    assert cmd[3:-2] == run_args(CONFIG, 0, out)
    assert cmd[-2:] == ["--torch-threads", "1"]
    # the child runs where the caller does (not in the package's folder, which in a wheel
    # install is site-packages), so its --out is the folder that holds the log
    assert seen["kwargs"].get("cwd") is None
    log = (tmp_path / out / "train.log").read_text()
    assert log.startswith("$ " + " ".join(cmd) + "\n") and log.endswith("trained\n")


def fast_options(name: str, seed: int, *extra: str) -> dict[str, Any]:
    """The fast learner's options a ``model.json`` of configuration ``name`` records."""
    from training.fast_ppo import json_config
    from training.train import fast_config

    cfg = parse_args([*CONFIGS[name].args, "--seed", str(seed), "--out", "unused", *extra])
    return json_config(fast_config(cfg))


def test_ship_compares_a_fast_run_with_the_learners_own_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A fast-engine run records the learner's options (no --engine): those are compared, but
    the clone it was fine-tuned from (its own path) and the options a resume may change; an
    option recorded before it existed counts as its default; the trainer must be the cloner."""
    runs, models = tmp_path / "runs", tmp_path / "models"
    name = "bc_ppo_sharp"
    done = {"timesteps": 5, "timesteps_requested": 5, "trainer": "training.bc"}
    options = fast_options(name, 0)
    older = {k: v for k, v in fast_options(name, 1).items() if k != "realism_preset"}
    fake_run(runs, name, 0, **done, config={**options, "init_from": "/a/run/bc/model.zip"})
    fake_run(runs, name, 1, **done, config={**older, "torch_threads": 2})
    fake_run(runs, name, 2, **done, config=fast_options(name, 2, "--n-envs", "32"))
    fake_run(
        runs, name, 3, **{**done, "trainer": "training.fast_ppo"}, config=fast_options(name, 3)
    )
    shipped = ship(runs, models, [name], range(4))
    assert shipped == [models / f"{name}_s0", models / f"{name}_s1"]
    err = capsys.readouterr().err
    assert "skip bc_ppo_sharp s2: " in err and "n_envs: stored 32, given 64" in err
    assert "skip bc_ppo_sharp s3: " in err and "trainer: stored 'training.fast_ppo'" in err


# ------------------------------------------------------------------------------------------------
# Learning curves of a configuration's runs
# ------------------------------------------------------------------------------------------------
def test_curves_draws_the_runs_that_have_a_progress_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from PIL import Image

    from training.curves import PROGRESS_COLUMNS

    for seed in (0, 2):
        run = run_dir(tmp_path / "runs", "residual_ppc", seed)
        run.mkdir(parents=True)
        rows = [",".join(PROGRESS_COLUMNS)]
        for i in range(1, 6):
            rows.append(f"{i * 1000},{i},{i},{10.0 * i},{0.2 * i},0.0,")
        (run / "progress.csv").write_text("\n".join(rows) + "\n")
    png = tmp_path / "curves.png"
    argv = ["--config", "residual_ppc", "bc_ppo_sharp", "--runs", str(tmp_path / "runs")]
    assert main([*argv, "--curves", str(png)]) == 0
    assert "no progress.csv of bc_ppo_sharp" in capsys.readouterr().err
    assert "platoon-sweep" in Image.open(png).info["Description"]
    # no run of any configuration: nothing drawn, a failure
    assert main(["--config", "bc_ppo_sharp", "--runs", str(tmp_path), "--curves", str(png)]) == 1


def test_ship_checks_the_zip_and_never_writes_through_a_link(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run whose zip is not the one its model.json records is not shipped; a link at the
    destination is replaced by the shipped folder (its target untouched), and the folder
    appears whole: nothing of an earlier copy is left in it, no temporary folder beside it."""
    import hashlib

    runs, models = tmp_path / "runs", tmp_path / "models"
    digest = hashlib.sha256(b"zip ppo_ta_aruco 0").hexdigest()
    fake_run(runs, "ppo_ta_aruco", 0, timesteps=10, timesteps_requested=10, zip_sha256=digest)
    fake_run(runs, "ppo_ta_aruco", 1, timesteps=10, timesteps_requested=10, zip_sha256="0" * 64)
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "model.zip").write_bytes(b"keep")
    models.mkdir()
    (models / "ppo_ta_aruco_s0").symlink_to(outside, target_is_directory=True)
    shipped = ship(runs, models, ["ppo_ta_aruco"], [0, 1])
    assert shipped == [models / "ppo_ta_aruco_s0"]
    assert "skip ppo_ta_aruco s1: model.zip has SHA-256" in capsys.readouterr().err
    dst = models / "ppo_ta_aruco_s0"
    assert not dst.is_symlink() and sorted(p.name for p in dst.iterdir()) == sorted(SHIPPED)
    assert (outside / "model.zip").read_bytes() == b"keep"
    assert sorted(p.name for p in models.iterdir()) == ["ppo_ta_aruco_s0"]


def test_a_stopped_sweep_leaves_no_training_behind(tmp_path: Path) -> None:
    """SIGTERM to the sweep (here: its handler's KeyboardInterrupt) stops and reaps every
    running training, starts no other, and exits 130; no child outlives it."""
    import os
    import signal
    import threading

    started = tmp_path / "started"
    sleeper = [sys.executable, "-c", f"open({str(started)!r}, 'a').write('x'); "
               "import time; time.sleep(120)"]  # fmt: skip

    def fake_train(config: Any, seed: int, out: Path) -> tuple[str, int, float]:
        out.mkdir(parents=True, exist_ok=True)
        return f"{config.name} s{seed}", *sweep._run_child(sleeper, out / "train.log")

    jobs = [(CONFIG, seed, tmp_path / f"s{seed}") for seed in range(3)]
    original = sweep._train
    sweep._train = fake_train  # type: ignore[assignment]
    try:
        timer = threading.Timer(3.0, os.kill, (os.getpid(), signal.SIGTERM))
        timer.start()
        try:
            assert sweep._run_jobs(jobs, 2) == 130
        finally:
            timer.cancel()
    finally:
        sweep._train = original  # type: ignore[assignment]
    assert not sweep._CHILDREN
    assert len(started.read_text()) == 2  # two ran, the third never started
    logs = [(tmp_path / f"s{seed}" / "train.log") for seed in range(3)]
    assert not logs[2].exists() or "not started" in logs[2].read_text()
