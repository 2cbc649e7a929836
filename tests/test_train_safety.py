"""Training runs that cannot be mixed up (``platoon-train --out/--resume/--force``), what
``model.json`` records, what ``LearnedPolicy.load``/``check_env`` refuse, and every option's
range check (an ``argparse`` error, nothing written)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("stable_baselines3")
import torch

import platoon_env
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping, file_sha256
from training import LearnedPolicy
from training.policies import OBSERVATION_LAYOUT, save_model
from training.run import LOCK_FILE, hold_run, holds_run, read_holder, run_status
from training.train import (
    TrainConfig,
    build_model,
    build_vec_env,
    cli_args,
    main,
    run_metadata,
)

REPO = Path(__file__).resolve().parents[1]
#: A PPO run whose rollout is 256 follower transitions (1 env x 2 followers x 128 steps).
TINY = cli_args(
    algo="ppo",
    scenario="study_c",
    seed=0,
    n_envs=1,
    n_steps=128,
    batch_size=64,
    n_epochs=1,
    net_arch=[16, 16],
    checkpoint_every=256,
    progress_bar=False,
)
#: Long enough for the tests that stop a run from outside to find it running.
FOREVER = ["--timesteps", "10000000"]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def train(out: Path, timesteps: int, *extra: str) -> int:
    return main([*TINY, "--timesteps", str(timesteps), "--out", str(out), *extra])


def snapshot(out: Path) -> dict[str, bytes]:
    """Every file under ``out`` and its bytes (``{}`` for a missing directory)."""
    if not out.exists():
        return {}
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def meta(out: Path, name: str = "model") -> dict[str, Any]:
    return dict(json.loads((out / f"{name}.json").read_text()))


def refused(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """``main(argv)`` exits with status 2; returns its stderr."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    return capsys.readouterr().err


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 256-timestep run (model + checkpoint at 256); copy it before changing it."""
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("finished") / "run"
    assert train(out, 256) == 0
    return out


@pytest.fixture
def run(finished_run: Path, tmp_path: Path) -> Path:
    """A private copy of :func:`finished_run`."""
    out = tmp_path / "run"
    shutil.copytree(finished_run, out)
    return out


# ------------------------------------------------------------------------------------------------
# --out, --force, --resume
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("marker", ["model.json", "checkpoint.json", "model.zip", "tb"])
def test_out_holding_a_run_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], marker: str
) -> None:
    out = tmp_path / "run"
    out.mkdir()
    if marker == "tb":
        (out / "tb").mkdir()
        (out / "tb" / "events.out.tfevents.1").write_bytes(b"x")
    else:
        (out / marker).write_bytes(b"an earlier run's file")
    before = snapshot(out)
    err = refused(capsys, [*TINY, "--timesteps", "256", "--out", str(out)])
    assert "argument --out" in err and "already holds a run" in err and marker in err
    assert "--resume" in err and "--force" in err
    assert snapshot(out) == before


def test_trained_out_is_refused_and_force_starts_over(
    run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = snapshot(run)
    err = refused(capsys, [*TINY, "--timesteps", "256", "--seed", "1", "--out", str(run)])
    assert "already holds a run" in err
    assert snapshot(run) == before

    assert train(run, 256, "--seed", "1", "--checkpoint-every", "0", "--force") == 0
    err = capsys.readouterr().err
    assert "--force" in err and "starting over" in err
    m = meta(run)
    assert m["seed"] == 1 and m["timesteps"] == 256
    assert [s["timesteps_start"] for s in m["segments"]] == [0]
    assert m["zip_sha256"] == file_sha256(run / "model.zip")
    # the earlier run's checkpoint is gone (no new one with --checkpoint-every 0)
    assert not (run / "checkpoint.zip").exists() and not (run / "checkpoint.json").exists()


def test_empty_out_is_a_new_run(tmp_path: Path) -> None:
    out = tmp_path / "empty"
    out.mkdir()
    assert train(out, 256, "--checkpoint-every", "0") == 0
    assert meta(out)["timesteps"] == 256


def test_resume_with_other_options_names_every_field(
    run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = snapshot(run)
    base = [*TINY, "--timesteps", "512", "--out", str(run), "--resume"]
    err = refused(capsys, [*base, "--gamma", "0.9", "--seed", "4", "--net-arch", "32", "32"])
    assert "--gamma: stored 0.99, given 0.9" in err
    assert "--seed: stored 0, given 4" in err
    assert "--net-arch: stored [16, 16], given [32, 32]" in err
    err = refused(capsys, [*base, "--control-period", "0.02"])
    assert "resolved scenario" in err and "fingerprint" in err
    assert "simulation.control_period: stored 0.05, given 0.02" in err
    err = refused(capsys, [*base, "--scenario", "study_b"])
    assert "resolved scenario" in err and "--scenario 'study_b'" in err
    err = refused(capsys, [*base, "--algo", "sac", "--batch-size", "64"])
    assert "--algo: stored 'ppo', given 'sac'" in err
    assert snapshot(run) == before


def test_resume_of_a_finished_run_changes_nothing(
    run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = snapshot(run)
    assert train(run, 256, "--resume") == 0
    assert "nothing to do" in capsys.readouterr().out
    # the same run given differently: the shipped file by path, the default sub-steps
    # stated, a lower total and a change of what does not define the run
    same = [
        "--scenario",
        str(REPO / "platoon_env" / "scenarios" / "data" / "study_c.yaml"),
        "--physics-substeps",
        "2",
        "--checkpoint-every",
        "100",
        "--resume",
    ]
    assert train(run, 128, *same) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert snapshot(run) == before


@pytest.mark.parametrize("exists", [False, True])
def test_resume_with_nothing_to_resume_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], exists: bool
) -> None:
    out = tmp_path / "run"
    if exists:
        (out / "tb").mkdir(parents=True)  # a run that died before its first checkpoint
    before = snapshot(out)
    err = refused(capsys, [*TINY, "--timesteps", "256", "--out", str(out), "--resume"])
    assert "nothing to resume" in err and "no checkpoint and no model" in err
    assert snapshot(out) == before and out.exists() == exists


def test_resume_sums_wall_time_over_segments(run: Path) -> None:
    first = meta(run)
    assert len(first["segments"]) == 1 and first["wall_time_s"] > 0
    assert train(run, 512, "--resume") == 0
    resumed = meta(run)
    segments = resumed["segments"]
    assert len(segments) == 2 and segments[0] == first["segments"][0]
    assert segments[1]["resumed_from"] == "model.zip"
    assert segments[1]["timesteps_start"] == 256 and segments[1]["timesteps_end"] == 512
    total = sum(s["wall_time_s"] for s in segments)
    assert resumed["wall_time_s"] == pytest.approx(total, abs=2e-3)
    assert resumed["wall_time_s"] > first["wall_time_s"]
    assert resumed["started_at"] == first["started_at"] and resumed["timesteps"] == 512
    assert resumed["timesteps_per_s"] == pytest.approx(512 / total, rel=1e-2)


def test_resume_continues_from_the_newer_of_checkpoint_and_model(run: Path) -> None:
    """A Ctrl-C model older than the checkpoint: the checkpoint wins (a tie: the model, as in
    test_resume_sums_wall_time_over_segments)."""
    early = {name: (run / name).read_bytes() for name in ("model.zip", "model.json")}
    assert train(run, 768, "--resume") == 0  # checkpoints at 512 and 768
    for name, data in early.items():  # put back the model of 256 timesteps, as interrupted
        (run / name).write_bytes(data)
    m = meta(run)
    m["interrupted"] = True
    (run / "model.json").write_text(json.dumps(m))
    # a resumed run checkpoints every 256 timesteps after its restored 256
    assert meta(run, "checkpoint")["timesteps"] == 768
    assert train(run, 1024, "--resume") == 0
    last = meta(run)["segments"][-1]
    assert last["resumed_from"] == "checkpoint.zip" and last["timesteps_start"] == 768
    assert meta(run)["timesteps"] == 1024
    assert [s["timesteps_start"] for s in meta(run)["segments"]] == [0, 256, 768]


@pytest.mark.parametrize("checkpoint", ["complete", "cut"])
def test_a_run_whose_last_save_was_cut_is_continued_by_the_sweep(
    run: Path, capsys: pytest.CaptureFixture[str], checkpoint: str
) -> None:
    """A save cut off between model.zip and model.json (kill -9 between the two renames): the
    sweep's re-run continues the run from the complete checkpoint, or with none starts it
    over, instead of failing it ("nothing to resume") on every re-run."""
    from experiments.configs import Config
    from experiments.studies.sweep import cut_saves, run_args

    (run / "model.json").unlink()  # a new model.zip, its JSON not yet in place
    (run / "model.zip").write_bytes((run / "model.zip").read_bytes() + b"\0")
    if checkpoint == "cut":  # the checkpoint's zip of a later save beside its JSON
        (run / "checkpoint.zip").write_bytes((run / "checkpoint.zip").read_bytes() + b"\0")
    assert len(cut_saves(run)) == (1 if checkpoint == "complete" else 2)
    config = Config("tiny", "the tiny run", (*TINY, "--timesteps", "512"))
    args = run_args(config, 0, run)
    assert main(args) == 0
    err = capsys.readouterr().err
    m = meta(run)
    assert m["timesteps"] == 512 and m["zip_sha256"] == file_sha256(run / "model.zip")
    if checkpoint == "complete":
        assert "--resume" in args and "left out: model.zip (no model.json" in err
        assert [s["resumed_from"] for s in m["segments"]] == [None, "checkpoint.zip"]
    else:
        assert "--force" in args and "starting over" in err
        assert [s["resumed_from"] for s in m["segments"]] == [None]
    assert cut_saves(run) == []
    LearnedPolicy.load(run / "model.zip")


def test_a_saved_point_appears_whole(tmp_path: Path) -> None:
    """save_point: a save that fails after its zip (a full disk) leaves the previous point as
    it was; a SIGTERM that arrives mid-save is delivered once every file is in place; no
    temporary folder is left either way."""
    import errno
    import hashlib

    from training.run import incomplete_point, save_point

    def writer(data: bytes, fail: bool = False, signal_mid_save: bool = False) -> Any:
        def save(path: Path) -> None:
            path.write_bytes(data)
            if signal_mid_save:
                os.kill(os.getpid(), signal.SIGTERM)
            if fail:
                raise OSError(errno.ENOSPC, "No space left on device")
            digest = hashlib.sha256(data).hexdigest()
            path.with_suffix(".json").write_text(json.dumps({"zip_sha256": digest}))

        return save

    out = tmp_path / "run"
    save_point(out / "model.zip", writer(b"first"))
    with pytest.raises(OSError, match="No space left"):
        save_point(out / "model.zip", writer(b"second", fail=True))
    assert (out / "model.zip").read_bytes() == b"first" and incomplete_point(out, "model") is None

    class Stopped(Exception):
        pass

    def stopped(signum: int, frame: Any) -> None:
        raise Stopped

    previous = signal.signal(signal.SIGTERM, stopped)
    try:
        with pytest.raises(Stopped):
            save_point(out / "model.zip", writer(b"third", signal_mid_save=True))
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert (out / "model.zip").read_bytes() == b"third" and incomplete_point(out, "model") is None
    assert sorted(p.name for p in out.iterdir()) == ["model.json", "model.zip"]


# ------------------------------------------------------------------------------------------------
# One owner per folder
# ------------------------------------------------------------------------------------------------
def train_cmd(out: Path, *extra: str) -> list[str]:
    """The command of ``platoon-train`` (the tiny run, ``extra`` appended) into ``out``."""
    return [sys.executable, "-m", "training.train", *TINY, "--out", str(out), *extra]


def start_training(out: Path, *extra: str) -> subprocess.Popen[str]:
    """:func:`train_cmd` in a child process."""
    return subprocess.Popen(
        train_cmd(out, *extra),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # pytest-xdist workers ignore SIGINT and children inherit that: restore the default so
        # that Ctrl-C (SIGINT) reaches the trainer as KeyboardInterrupt.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def wait_for(proc: subprocess.Popen[str], ready: Callable[[], bool]) -> None:
    """Wait until ``ready()`` while ``proc`` runs (generous: a fresh clone compiles the numba
    kernels on first use)."""
    deadline = time.monotonic() + 900
    while not ready():
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        assert time.monotonic() < deadline, "the run never got there"
        time.sleep(0.2)


def stop(proc: subprocess.Popen[str], sig: int) -> str:
    """Send ``sig`` to ``proc``, wait for it; returns its stderr."""
    try:
        os.kill(proc.pid, sig)
        return proc.communicate(timeout=120)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_second_run_into_a_folder_in_use_is_refused(tmp_path: Path) -> None:
    """Two processes, one folder: the second (even with --force, which would discard the
    first's files) is refused with the holder's name and how to release it; the first runs on
    and finishes its own model."""
    out = tmp_path / "run"
    first = start_training(out, *FOREVER)
    try:
        # training (its first checkpoint written), not still starting up
        wait_for(first, lambda: (out / "checkpoint.json").is_file())
        assert getattr(read_holder(out / LOCK_FILE), "pid", 0) == first.pid
        assert run_status(out).state == "running"
        second = subprocess.run(
            train_cmd(out, "--timesteps", "256", "--force"),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=900,  # generous: a loaded machine, maybe compiling the numba kernels
        )
        assert second.returncode == 2, second.stderr[-2000:]
        err = second.stderr
        assert "argument --out" in err and "in use by another platoon-train run" in err
        assert f"pid {first.pid} on " in err and str(out / LOCK_FILE) in err
        assert f"kill -INT {first.pid}" in err and "Traceback" not in err
        assert first.poll() is None  # untouched
    finally:
        stderr = stop(first, signal.SIGINT)
    assert first.returncode == 130, stderr[-2000:]
    m = meta(out)
    assert m["interrupted"] is True and len(m["segments"]) == 1
    assert m["segments"][0]["command"][-len(FOREVER) :] == FOREVER
    assert not (out / LOCK_FILE).exists() and run_status(out).state == "interrupted"


def test_a_killed_run_is_reported_killed_and_resumed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``kill -9`` leaves the lock file but not the lock: the folder is reported killed (not
    running), and the next run takes it over, saying so."""
    out = tmp_path / "run"
    victim = start_training(out, *FOREVER)
    try:
        wait_for(victim, lambda: (out / "checkpoint.json").is_file())
    finally:
        stop(victim, signal.SIGKILL)
    status = run_status(out)
    assert status.state == "killed", status
    assert status.holder is not None and status.holder.pid == victim.pid
    assert status.timesteps is not None and status.timesteps >= 256
    assert train(out, status.timesteps + 256, "--resume") == 0
    err = capsys.readouterr().err
    assert f"pid {victim.pid}" in err and "was killed" in err
    assert run_status(out).state == "finished" and not (out / LOCK_FILE).exists()


def test_holding_a_folder_is_reentrant_and_a_refused_run_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "new" / "run"
    with hold_run(out):
        assert holds_run(out) and read_holder(out / LOCK_FILE) is not None
        assert read_holder(out / LOCK_FILE).pid == os.getpid()  # type: ignore[union-attr]
        assert train(out, 256, "--checkpoint-every", "0") == 0  # main takes it again
        assert holds_run(out)
    assert not holds_run(out) and not (out / LOCK_FILE).exists()
    assert meta(out)["timesteps"] == 256
    with hold_run(tmp_path / "other" / "run"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new"]


def test_an_empty_out_is_an_argparse_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)  # Path("") is the working directory
    err = refused(capsys, [*TINY, "--timesteps", "256", "--out", ""])
    assert "argument --out: must name a directory, got ''" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("where", ["under a file", "read-only folder"])
def test_an_unwritable_out_is_an_argparse_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    if where == "under a file":
        (tmp_path / "file").write_text("not a folder")
        out = tmp_path / "file" / "run"
    else:
        if os.geteuid() == 0:
            pytest.skip("root writes into read-only folders")
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        out = locked / "run"
    before = snapshot(tmp_path)
    err = refused(capsys, [*TINY, "--timesteps", "256", "--out", str(out)])
    assert f"argument --out: cannot write to {out}" in err and "Traceback" not in err
    assert snapshot(tmp_path) == before and not out.exists()


# ------------------------------------------------------------------------------------------------
# model.json
# ------------------------------------------------------------------------------------------------
def test_model_json_records_the_resolved_scenario_and_the_zip_hash(finished_run: Path) -> None:
    m = meta(finished_run)
    env = platoon_env.make("study_c", control_period=0.05)
    assert m["scenario"] == "study_c"
    assert m["scenario_fingerprint"] == config_fingerprint(env.source.config)
    assert m["scenario_config"] == json.loads(json.dumps(config_mapping(env.source.config)))
    assert m["scenario_config"]["simulation"]["control_period"] == 0.05  # after the override
    assert m["zip_sha256"] == file_sha256(finished_run / "model.zip")
    ckpt = meta(finished_run, "checkpoint")
    assert ckpt["zip_sha256"] == file_sha256(finished_run / "checkpoint.zip")
    assert m["observation_layout"] == list(OBSERVATION_LAYOUT)
    assert m["action_layout"] == ["u", "omega"] and m["format_version"] == 2


# ------------------------------------------------------------------------------------------------
# LearnedPolicy.load and check_env
# ------------------------------------------------------------------------------------------------
def _saved(path: Path, seed: int = 0) -> Path:
    """An untrained tiny model saved as a platoon-train model (no learning needed)."""
    cfg = TrainConfig(n_envs=1, n_steps=128, batch_size=64, net_arch=[8], seed=seed)
    venv = build_vec_env(cfg)
    model = build_model(cfg, venv)
    return save_model(model, path / "model.zip", run_metadata(cfg, venv, model))


def test_load_refuses_a_zip_from_another_save(tmp_path: Path) -> None:
    a = _saved(tmp_path / "a", seed=0)
    b = _saved(tmp_path / "b", seed=1)
    LearnedPolicy.load(b)
    shutil.copyfile(a, b)
    with pytest.raises(ValueError, match=r"SHA-256.*not from the same save"):
        LearnedPolicy.load(b)


@pytest.mark.parametrize(
    "action_range",
    [
        None,
        "missing",
        [-0.5, 1.5, 2.0],
        {"u_low": -0.5, "u_high": 1.5},
        {"u_low": "slow", "u_high": 1.5, "omega_high": 2.0},
        {"u_low": -0.5, "u_high": float("inf"), "omega_high": 2.0},
        {"u_low": 1.5, "u_high": -0.5, "omega_high": 2.0},
        {"u_low": -0.5, "u_high": 1.5, "omega_high": 0.0},
    ],
)
def test_load_refuses_a_missing_or_malformed_action_range(
    tmp_path: Path, action_range: Any
) -> None:
    path = _saved(tmp_path)
    m = meta(tmp_path)
    if action_range == "missing":
        del m["action_range"]
    else:
        m["action_range"] = action_range
    (tmp_path / "model.json").write_text(json.dumps(m))
    with pytest.raises(ValueError, match="action_range"):
        LearnedPolicy.load(path)


def test_save_refuses_a_null_action_range(tmp_path: Path) -> None:
    cfg = TrainConfig(n_envs=1, n_steps=128, batch_size=64, net_arch=[8])
    venv = build_vec_env(cfg)
    model = build_model(cfg, venv)
    with pytest.raises(ValueError, match="action_range is null"):
        save_model(
            model, tmp_path / "model.zip", {**run_metadata(cfg, venv, model), "action_range": None}
        )
    assert not (tmp_path / "model.zip").exists()


def test_old_format_without_hash_warns_once_new_format_refuses(tmp_path: Path) -> None:
    path = _saved(tmp_path)
    m = meta(tmp_path)
    del m["zip_sha256"]
    (tmp_path / "model.json").write_text(json.dumps(m))
    with pytest.raises(ValueError, match="no zip_sha256"):
        LearnedPolicy.load(path)
    (tmp_path / "model.json").write_text(json.dumps({**m, "format_version": 1}))
    with pytest.warns(UserWarning, match="predates zip hashes"):
        LearnedPolicy.load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        LearnedPolicy.load(path)  # once per file


def test_check_env_refuses_meaningless_envs_and_notes_experiments(tmp_path: Path) -> None:
    policy = LearnedPolicy.load(_saved(tmp_path))
    assert policy.check_env(platoon_env.make("study_c", control_period=0.05)) == []
    with pytest.raises(ValueError, match=r"control period: trained at 0\.05 s.*0\.01 s"):
        policy.check_env(platoon_env.make("study_c"))
    notes = policy.check_env(platoon_env.make("study_c"), allow_control_period=True)
    assert any("control period" in n for n in notes)
    notes = policy.check_env(platoon_env.make("study_c", control_period=0.05, followers=3))
    assert any("followers: trained with 2, the env has 3" in n for n in notes)
    # a formation drawn per episode: a count in its range is no note, one outside it is
    policy.metadata["scenario_config"] = {"generator": {"formation": {"followers": [1, 3]}}}
    notes = policy.check_env(platoon_env.make("study_c", control_period=0.05, followers=3))
    assert not any(n.startswith("followers") for n in notes)
    notes = policy.check_env(platoon_env.make("study_c", control_period=0.05, followers=4))
    assert any("followers: trained with 1-3 drawn per episode, the env has 4" in n for n in notes)
    del policy.metadata["scenario_config"]
    notes = policy.check_env(platoon_env.make("study_a", control_period=0.05))
    assert any(n.startswith("scenario: trained on fixed workspace 'study_c'") for n in notes)
    policy.metadata["observation_layout"] = ["visible", "x_rel", "y_rel", "range"]
    with pytest.raises(ValueError, match="observation_layout"):
        policy.check_env(platoon_env.make("study_c", control_period=0.05))


def test_shipped_models_load_and_pass_the_checks() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # both carry zip_sha256 (backfilled): no warning
        corridors = LearnedPolicy.load(REPO / "models" / "legacy" / "ppo_corridors_s0")
        procedural = LearnedPolicy.load(REPO / "models" / "legacy" / "ppo_procedural_s0")
    period = corridors.control_period
    train_env = platoon_env.make("procedural_corridors_train", control_period=period)
    assert corridors.scenario_fingerprint == config_fingerprint(train_env.source.config)
    notes = corridors.check_env(train_env)
    assert len(notes) == 1 and "not held out" in notes[0]
    notes = corridors.check_env(platoon_env.make("study_a", control_period=period))
    assert any("procedural corridor/train layouts" in n and "study_a" in n for n in notes)
    with pytest.raises(ValueError, match="control period"):
        corridors.check_env(platoon_env.make("study_a"))
    assert procedural.scenario_fingerprint is None  # not backfilled: see its model.json
    notes = procedural.check_env(platoon_env.make("procedural_test", control_period=period))
    assert notes == [
        "model.json records no training scenario content (only the name "
        "'procedural_train'): scenario not compared"
    ]


# ------------------------------------------------------------------------------------------------
# Option ranges
# ------------------------------------------------------------------------------------------------
BAD_OPTIONS = [
    (["--timesteps", "-5"], "--timesteps"),
    (["--timesteps", "0"], "--timesteps"),
    (["--timesteps", "2.5e0"], "--timesteps"),  # not an integer
    (["--gamma", "5"], "--gamma"),
    (["--gamma", "-0.1"], "--gamma"),
    (["--gamma", "nan"], "--gamma"),
    (["--seed", "-1"], "--seed"),
    (["--seed", str(2**32)], "--seed"),
    (["--n-envs", "0"], "--n-envs"),
    (["--n-envs", "-3"], "--n-envs"),
    (["--env-threads", "0"], "--env-threads"),
    (["--num-env-runners", "-1"], "--num-env-runners"),
    (["--num-learners", "-1"], "--num-learners"),
    (["--control-period", "0"], "--control-period"),
    (["--control-period", "-0.05"], "--control-period"),
    (["--control-period", "2"], "--control-period"),
    (["--control-period", "inf"], "--control-period"),
    (["--physics-substeps", "0"], "--physics-substeps"),
    (["--max-episode-steps", "0"], "--max-episode-steps"),
    (["--u-low", "1", "--u-high", "0.5"], "--u-high"),
    (["--u-high", "20"], "--u-high"),
    (["--u-low", "-20"], "--u-low"),
    (["--omega-high", "0"], "--omega-high"),
    (["--omega-high", "100"], "--omega-high"),
    (["--learning-rate", "0"], "--learning-rate"),
    (["--learning-rate", "-0.001"], "--learning-rate"),
    (["--learning-rate", "3"], "--learning-rate"),
    (["--batch-size", "0"], "--batch-size"),
    (["--batch-size", "1"], "--batch-size"),  # PPO
    (["--batch-size", "512"], "--batch-size"),  # > the 256-transition rollout
    (["--net-arch", "0", "16"], "--net-arch"),
    (["--n-steps", "0"], "--n-steps"),
    (["--n-epochs", "0"], "--n-epochs"),
    (["--gae-lambda", "1.5"], "--gae-lambda"),
    (["--clip-range", "0"], "--clip-range"),
    (["--ent-coef", "-0.1"], "--ent-coef"),
    (["--vf-coef", "-1"], "--vf-coef"),
    (["--max-grad-norm", "0"], "--max-grad-norm"),
    (["--algo", "sac", "--buffer-size", "0"], "--buffer-size"),
    (["--algo", "sac", "--buffer-size", "32"], "--batch-size"),  # batch 64 > buffer
    (["--algo", "sac", "--learning-starts", "-1"], "--learning-starts"),
    (["--algo", "sac", "--tau", "0"], "--tau"),
    (["--algo", "sac", "--tau", "1.5"], "--tau"),
    (["--algo", "sac", "--train-freq", "0"], "--train-freq"),
    (["--algo", "sac", "--gradient-steps", "0"], "--gradient-steps"),
    (["--algo", "sac", "--gradient-steps", "-2"], "--gradient-steps"),
    (["--checkpoint-every", "-1"], "--checkpoint-every"),
    (["--torch-threads", "0"], "--torch-threads"),
    (["--device", "cuda"], "--device"),
    (["--device", "cuda:7"], "--device"),
    (["--device", "toaster"], "--device"),
    (["--verbose", "3"], "--verbose"),
    (["--scenario", "no_such_scenario"], "--scenario"),
    (["--sensor-profile", "no_such_profile"], "--sensor-profile"),
    (["--sensor-profile", "aruco", "--control-period", "0.03"], "--sensor-profile"),  # latency
    (["--resume", "--force"], "--force"),
    (["--engine", "rllib", "--algo", "sac"], "--algo"),
]


@pytest.mark.parametrize(
    ("options", "flag"), BAD_OPTIONS, ids=[" ".join(o) for o, _ in BAD_OPTIONS]
)
def test_bad_option_is_an_argparse_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], options: list[str], flag: str
) -> None:
    if options[:2] == ["--device", "cuda"] and torch.cuda.is_available():
        pytest.skip("a CUDA device is available")
    out = tmp_path / "out"
    err = refused(capsys, [*TINY, "--timesteps", "256", "--out", str(out), *options])
    assert f"argument {flag}" in err, err
    assert "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_out_that_is_a_file_is_an_argparse_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    out.write_text("not a directory")
    err = refused(capsys, [*TINY, "--out", str(out)])
    assert "argument --out" in err and "not a directory" in err
    assert out.read_text() == "not a directory"


def test_a_zombie_holds_no_run() -> None:
    """A killed process its parent has not reaped yet (a zombie) runs no more: a run it held is
    not "running" (the sweep's killed trainings, until someone reaps them)."""
    import socket

    from training.run import Holder

    child = subprocess.Popen([sys.executable, "-c", "pass"])
    deadline = time.monotonic() + 30
    while Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
        assert time.monotonic() < deadline, "the child never became a zombie"
        time.sleep(0.05)
    try:
        assert Holder(socket.gethostname(), child.pid, "t", ()).alive() is False
        assert Holder(socket.gethostname(), os.getpid(), "t", ()).alive() is True
    finally:
        child.wait()
