"""Learning curves (``training.curves``): what ``platoon-train`` writes to ``DIR/progress.csv``
(a tiny real run), the team-success rule and the resume rule of ``LearningCurveCallback``
(driven by hand), reading the file back, the common grid of several runs and the figure."""

from __future__ import annotations

import csv
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
from stable_baselines3.common.vec_env import VecMonitor

from training.curves import (
    PROGRESS_COLUMNS,
    PROGRESS_FILE,
    LearningCurveCallback,
    _slot_teams,
    curve_on_grid,
    plot_learning_curves,
    read_progress,
    read_rows,
)
from training.lagrangian import LagrangeMultiplier, LagrangianVecEnv
from training.train import RUN_FILES, build_vec_env, main, parse_args

#: A PPO run of 4 slots (2 copies x 2 followers), a rollout of 1024 follower transitions, short
#: episodes (40 env steps at most) so that every logged window has ended episodes.
TINY = [
    "--scenario",
    "study_c",
    "--seed",
    "0",
    "--n-envs",
    "2",
    "--n-steps",
    "256",
    "--batch-size",
    "256",
    "--n-epochs",
    "1",
    "--net-arch",
    "16",
    "16",
    "--max-episode-steps",
    "40",
    "--log-every",
    "1024",
    "--no-progress-bar",
]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def run(out: Path, algo: str, timesteps: int, *extra: str) -> int:
    argv = [*TINY, "--algo", algo, "--timesteps", str(timesteps), "--out", str(out), *extra]
    return main(argv)


def read_json(path: Path) -> dict[str, Any]:
    return dict(json.loads(path.read_text()))


def header(path: Path) -> tuple[str, ...]:
    with path.open(newline="") as f:
        return tuple(next(csv.reader(f)))


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ppo") / "run"
    assert run(out, "ppo", 4096, "--checkpoint-every", "0") == 0
    return out


@pytest.fixture(scope="module")
def lagrangian_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("lag") / "run"
    assert run(out, "ppo_lagrangian", 4096, "--checkpoint-every", "0") == 0
    return out


def check_rows(rows: list[dict[str, str]]) -> None:
    """The invariants of every row of a two-follower run."""
    steps = [int(r["timesteps"]) for r in rows]
    assert steps == sorted(set(steps))  # strictly increasing
    for r in rows:
        assert float(r["wall_time_s"]) >= 0
        episodes = int(r["episodes"])
        if episodes == 0:
            assert r["return_mean"] == r["success_rate"] == r["cost_mean"] == ""
            continue
        # every follower of a copy ends together: whole teams of two in each window
        assert episodes % 2 == 0
        success, cost = float(r["success_rate"]), float(r["cost_mean"])
        assert 0.0 <= success <= 1.0
        assert 0.0 <= cost <= 1.0
        assert math.isfinite(float(r["return_mean"]))
        # a failed team has 1 or 2 followers with cost 1 (a violation ends the episode), a
        # successful one none: cost_mean in [failed / 2, failed] with failed = 1 - success
        failed = 1.0 - success
        assert failed / 2 - 1e-5 <= cost <= failed + 1e-5


# ------------------------------------------------------------------------------------------------
# A tiny real run
# ------------------------------------------------------------------------------------------------
def test_ppo_run_writes_the_learning_curve(ppo_run: Path) -> None:
    path = ppo_run / PROGRESS_FILE
    assert PROGRESS_FILE == "progress.csv" and PROGRESS_FILE in RUN_FILES
    assert header(path) == PROGRESS_COLUMNS
    rows = read_rows(path)
    assert [int(r["timesteps"]) for r in rows] == [1024, 2048, 3072, 4096]
    check_rows(rows)
    assert all(int(r["episodes"]) > 0 for r in rows)  # 40-step episodes end in every window
    assert all(r["lambda"] == "" for r in rows)  # ppo has no multiplier
    data = read_progress(path)
    assert set(data) == set(PROGRESS_COLUMNS)
    assert np.all(np.isnan(data["lambda"]))
    assert np.array_equal(data["timesteps"], [1024, 2048, 3072, 4096])


def test_ppo_lagrangian_run_logs_the_multiplier(lagrangian_run: Path) -> None:
    rows = read_rows(lagrangian_run / PROGRESS_FILE)
    assert [int(r["timesteps"]) for r in rows] == [1024, 2048, 3072, 4096]
    check_rows(rows)
    lam = [float(r["lambda"]) for r in rows]  # every cell filled
    assert all(v >= 0 for v in lam)
    # the violation rate is far above the budget (0.05): the multiplier only grows
    assert all(float(r["cost_mean"]) > 0.05 for r in rows)
    assert all(b > a for a, b in itertools.pairwise(lam))
    assert read_json(lagrangian_run / "model.json")["lagrange_multiplier"] >= lam[-1]


def test_an_out_with_only_a_progress_file_holds_a_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / PROGRESS_FILE).write_text("left over\n")
    with pytest.raises(SystemExit) as info:
        run(out, "ppo", 256)
    assert info.value.code == 2
    assert "progress.csv" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [PROGRESS_FILE]
    assert (out / PROGRESS_FILE).read_text() == "left over\n"


def test_a_resumed_run_drops_the_rows_after_its_checkpoint(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert run(out, "ppo", 4096, "--checkpoint-every", "3000") == 0
    first = read_rows(out / PROGRESS_FILE)
    ckpt = int(read_json(out / "checkpoint.json")["timesteps"])
    assert 3000 <= ckpt < 4096
    # continue from the checkpoint, not from the (newer) final model
    (out / "model.zip").unlink()
    (out / "model.json").unlink()
    assert run(out, "ppo", 5000, "--checkpoint-every", "3000", "--resume") == 0
    rows = read_rows(out / PROGRESS_FILE)
    kept = [r for r in first if int(r["timesteps"]) <= ckpt]
    assert [int(r["timesteps"]) for r in kept] == [1024, 2048]
    assert rows[: len(kept)] == kept  # byte for byte the earlier rows
    new = [int(r["timesteps"]) for r in rows[len(kept) :]]
    assert new == [ckpt + 1024, ckpt + 2048]  # one row per rollout from the checkpoint on
    check_rows(rows)


def test_log_every_zero_is_an_argparse_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as info:
        main([*TINY, "--timesteps", "256", "--out", str(out), "--log-every", "0"])
    assert info.value.code == 2
    assert "--log-every" in capsys.readouterr().err
    assert not out.exists()


def test_callback_refuses_a_non_positive_period(tmp_path: Path) -> None:
    for every in (0, -5):
        with pytest.raises(ValueError, match="every"):
            LearningCurveCallback(tmp_path / PROGRESS_FILE, every)


# ------------------------------------------------------------------------------------------------
# The team-success rule, driven by hand
# ------------------------------------------------------------------------------------------------
class SlotEnv:
    """The base of a platoon vector env: ``n_envs`` copies of ``followers`` slots each."""

    def __init__(self, n_envs: int, followers: int) -> None:
        self.n_envs = n_envs
        self.followers = followers
        self.num_envs = n_envs * followers

    def env_slots(self, j: int) -> range:
        return range(j * self.followers, (j + 1) * self.followers)


class Wrapper:
    """An SB3-style wrapper: ``num_envs`` and the wrapped env as ``.venv`` (no forwarding)."""

    def __init__(self, venv: Any) -> None:
        self.venv = venv
        self.num_envs = venv.num_envs


class PlainVecEnv:
    """A vector env without ``env_slots``: each slot its own team."""

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs


class FakeModel:
    def __init__(self, env: Any) -> None:
        self.env = env
        self.num_timesteps = 0

    def get_env(self) -> Any:
        return self.env


class Driver:
    """Drives a :class:`LearningCurveCallback` as SB3's rollout loop does."""

    def __init__(self, callback: LearningCurveCallback, env: Any) -> None:
        self.callback = callback
        self.model = FakeModel(env)
        self.num_envs = env.num_envs
        self.locals: dict[str, Any] = {}
        callback.init_callback(self.model)  # type: ignore[arg-type]
        callback.on_training_start(self.locals, {})

    def step(
        self,
        costs: dict[int, float] | None = None,
        done: tuple[int, ...] = (),
        returns: dict[int, float] | None = None,
    ) -> None:
        costs, returns = costs or {}, returns or {}
        dones = np.zeros(self.num_envs, dtype=bool)
        dones[list(done)] = True
        infos: list[dict[str, Any]] = []
        for k in range(self.num_envs):
            info: dict[str, Any] = {"cost": costs.get(k, 0.0)}
            if dones[k]:
                info["episode"] = {"r": returns.get(k, 0.0), "l": 3}
            infos.append(info)
        self.model.num_timesteps += self.num_envs
        self.callback.update_locals({"dones": dones, "infos": infos})
        assert self.callback.on_step()

    def end(self) -> None:
        self.callback.on_training_end()


def rows_of(path: Path) -> list[dict[str, str]]:
    return read_rows(path)


def test_a_team_with_one_violating_follower_is_a_failure(tmp_path: Path) -> None:
    path = tmp_path / PROGRESS_FILE
    env = Wrapper(Wrapper(SlotEnv(n_envs=2, followers=2)))
    d = Driver(LearningCurveCallback(path, every=8, multiplier=lambda: 0.25), env)
    assert rows_of(path) == []  # the header only
    # copy 0: follower 0 violates (cost 1), follower 1 does not; both end at the next step
    d.step(costs={0: 1.0})
    d.step(done=(0, 1), returns={0: 1.0, 1: 3.0})  # t = 8: a row
    # copy 1: both followers end without a violation
    d.step()
    d.step(done=(2, 3), returns={2: -2.0, 3: -4.0})  # t = 16: a row
    # copy 0 again, clean this time (its earlier cost was reset at its episode end), and
    # copy 1 with both followers violating
    d.step(costs={2: 1.0, 3: 1.0})
    d.step(done=(0, 1, 2, 3))  # t = 24: a row
    d.step()  # t = 28: nothing ended
    d.step()  # t = 32: a row without episodes
    d.step(costs={1: 1.0})  # t = 36: pending cost, no episode ended yet
    d.end()  # a last row for the timesteps after the last one
    rows = rows_of(path)
    assert [r["timesteps"] for r in rows] == ["8", "16", "24", "32", "36"]
    first, second, third, empty, last = rows
    assert first["episodes"] == "2"
    assert float(first["success_rate"]) == 0.0  # the team failed: not 0.5 (per follower)
    assert float(first["cost_mean"]) == 0.5
    assert float(first["return_mean"]) == 2.0
    assert first["lambda"] == "0.25"
    assert (second["episodes"], float(second["success_rate"])) == ("2", 1.0)
    assert float(second["cost_mean"]) == 0.0 and float(second["return_mean"]) == -3.0
    assert third["episodes"] == "4"
    assert float(third["success_rate"]) == 0.5  # copy 0 succeeded, copy 1 failed
    assert float(third["cost_mean"]) == 0.5
    for r in (empty, last):
        assert r["episodes"] == "0"
        assert r["return_mean"] == r["success_rate"] == r["cost_mean"] == ""
        assert r["lambda"] == "0.25"


def test_without_env_slots_each_slot_is_its_own_team(tmp_path: Path) -> None:
    path = tmp_path / PROGRESS_FILE
    d = Driver(LearningCurveCallback(path, every=100), Wrapper(PlainVecEnv(2)))
    d.step(costs={0: 1.0}, done=(0, 1))
    d.end()
    (row,) = rows_of(path)
    assert row["episodes"] == "2"
    assert float(row["success_rate"]) == 0.5  # two teams of one: one failed
    assert float(row["cost_mean"]) == 0.5
    assert row["lambda"] == ""


def test_slot_teams() -> None:
    assert np.array_equal(_slot_teams(PlainVecEnv(3)), [0, 1, 2])
    assert np.array_equal(_slot_teams(Wrapper(Wrapper(PlainVecEnv(3)))), [0, 1, 2])
    assert np.array_equal(_slot_teams(SlotEnv(2, 3)), [0, 0, 0, 1, 1, 1])
    assert np.array_equal(_slot_teams(Wrapper(Wrapper(SlotEnv(3, 2)))), [0, 0, 1, 1, 2, 2])
    assert _slot_teams(PlainVecEnv(3)).dtype == np.int64


def test_slot_teams_of_the_real_training_env() -> None:
    venv = build_vec_env(parse_args([*TINY, "--out", "unused"]))
    try:
        assert venv.num_envs == 4
        monitored = VecMonitor(venv)
        assert np.array_equal(_slot_teams(monitored), [0, 0, 1, 1])
        penalised = LagrangianVecEnv(monitored, LagrangeMultiplier(budget=0.05, lr=0.05))
        assert np.array_equal(_slot_teams(penalised), [0, 0, 1, 1])
    finally:
        venv.close()


# ------------------------------------------------------------------------------------------------
# Resume
# ------------------------------------------------------------------------------------------------
def write_progress(path: Path, steps: list[int]) -> list[dict[str, str]]:
    rows = [
        {
            "timesteps": str(t),
            "wall_time_s": f"{t / 100:.1f}",
            "episodes": "4",
            "return_mean": f"{-t / 10:g}",
            "success_rate": "0.5",
            "cost_mean": "0.25",
            "lambda": "",
        }
        for t in steps
    ]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=PROGRESS_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return rows


@pytest.mark.parametrize(
    ("resume_from", "kept"),
    [(200, [100, 200]), (250, [100, 200]), (99, []), (10_000, [100, 200, 300]), (None, [])],
)
def test_resume_keeps_the_rows_up_to_its_timesteps(
    tmp_path: Path, resume_from: int | None, kept: list[int]
) -> None:
    path = tmp_path / PROGRESS_FILE
    before = write_progress(path, [100, 200, 300])
    callback = LearningCurveCallback(path, every=1000, resume_from=resume_from)
    d = Driver(callback, SlotEnv(1, 2))
    rows = rows_of(path)
    assert rows == [r for r in before if int(r["timesteps"]) in kept]
    # a resumed run counts on from its restored timesteps: the next row is `every` later
    d.model.num_timesteps = resume_from or 0
    d.callback.on_training_start(d.locals, {})
    d.step(done=(0, 1))
    d.end()
    after = rows_of(path)
    assert after[:-1] == rows
    assert int(after[-1]["timesteps"]) == (resume_from or 0) + 2


def test_resume_without_a_file_starts_one(tmp_path: Path) -> None:
    path = tmp_path / PROGRESS_FILE
    Driver(LearningCurveCallback(path, every=10, resume_from=500), SlotEnv(1, 2))
    assert header(path) == PROGRESS_COLUMNS and rows_of(path) == []


def test_resume_refuses_a_file_with_other_columns(tmp_path: Path) -> None:
    path = tmp_path / PROGRESS_FILE
    path.write_text("step,reward\n1,2\n")
    callback = LearningCurveCallback(path, every=10, resume_from=500)
    with pytest.raises(ValueError, match="columns"):
        Driver(callback, SlotEnv(1, 2))
    assert path.read_text() == "step,reward\n1,2\n"  # left as it was


# ------------------------------------------------------------------------------------------------
# Reading back, the common grid, the figure
# ------------------------------------------------------------------------------------------------
def test_read_rows_refuses_other_columns(tmp_path: Path) -> None:
    path = tmp_path / "other.csv"
    path.write_text("timesteps,reward,cost\n1,2,3\n")
    with pytest.raises(ValueError, match=r"timesteps.*reward.*cost") as info:
        read_rows(path)
    assert "expected" in str(info.value) and "success_rate" in str(info.value)
    reordered = tmp_path / "reordered.csv"
    reordered.write_text(",".join(reversed(PROGRESS_COLUMNS)) + "\n")
    with pytest.raises(ValueError, match="columns"):
        read_rows(reordered)


def test_read_progress_refuses_an_empty_file(tmp_path: Path) -> None:
    header_only = tmp_path / "header.csv"
    write_progress(header_only, [])
    assert read_rows(header_only) == []
    with pytest.raises(ValueError, match="no rows"):
        read_progress(header_only)
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(ValueError):
        read_progress(empty)


def test_read_progress_gives_floats_and_nan_for_empty_cells(tmp_path: Path) -> None:
    path = tmp_path / PROGRESS_FILE
    write_progress(path, [100, 200])
    data = read_progress(path)
    assert np.array_equal(data["timesteps"], [100.0, 200.0])
    assert np.array_equal(data["return_mean"], [-10.0, -20.0])
    assert data["success_rate"].dtype == np.float64
    assert np.all(np.isnan(data["lambda"]))


def hand_run(steps: list[float], values: list[float]) -> dict[str, np.ndarray]:
    return {"timesteps": np.array(steps, dtype=float), "v": np.array(values, dtype=float)}


def test_curve_on_grid_interpolates_on_the_overlap() -> None:
    a = hand_run([0, 10, 20, 30], [0.0, 1.0, math.nan, 3.0])  # the NaN window is skipped
    b = hand_run([5, 15, 25, 35], [1.0, 1.0, 2.0, 2.0])
    grid, values = curve_on_grid([a, b], "v", points=6)
    assert np.allclose(grid, [5, 10, 15, 20, 25, 30])  # largest first row .. smallest last
    assert values.shape == (2, 6)
    assert np.allclose(values[0], [0.5, 1.0, 1.5, 2.0, 2.5, 3.0])
    assert np.allclose(values[1], [1.0, 1.0, 1.0, 1.5, 2.0, 2.0])
    # a run without a single value gives a NaN row
    c = hand_run([0, 40], [math.nan, math.nan])
    grid, values = curve_on_grid([a, c], "v", points=4)
    assert np.allclose(grid, [0, 10, 20, 30])
    assert np.allclose(values[0], [0, 1, 2, 3]) and np.all(np.isnan(values[1]))


def test_curve_on_grid_refuses_no_runs_and_disjoint_runs() -> None:
    with pytest.raises(ValueError, match="no runs"):
        curve_on_grid([], "v")
    with pytest.raises(ValueError, match="overlap"):
        curve_on_grid([hand_run([0, 10], [1, 2]), hand_run([20, 30], [1, 2])], "v")


def test_plot_learning_curves_writes_a_png(tmp_path: Path) -> None:
    files: dict[str, list[Path]] = {}
    for name, scale in (("ppo", 1.0), ("lag", 0.5)):
        for seed in (0, 1):
            path = tmp_path / name / f"s{seed}" / PROGRESS_FILE
            path.parent.mkdir(parents=True)
            steps = list(range(1000, 11_000 + 1000 * seed, 1000))
            write_progress(path, steps)
            rows = read_rows(path)
            for i, r in enumerate(rows):
                r["return_mean"] = f"{scale * i:g}"
                r["success_rate"] = "" if i == 2 else f"{min(1.0, 0.1 * i):g}"
                r["lambda"] = "" if name == "ppo" else "0.1"
            with path.open("w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=PROGRESS_COLUMNS)
                writer.writeheader()
                writer.writerows(rows)
            files.setdefault(name, []).append(path)
    out = tmp_path / "figures" / "curves.png"
    written = plot_learning_curves(files, out, metadata={"Source": "test_curves"})
    assert written == out and out.is_file()
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"Source" in data and b"test_curves" in data
    assert len(data) > 10_000
