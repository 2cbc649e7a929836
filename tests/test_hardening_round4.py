"""Hardening, round 4 (nothing runs that was not asked for): a store file carrying a schema
object the store does not create is refused untouched, and no model is loaded from the working
directory's ``./models`` unless it is named."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import pytest

from experiments import policies
from experiments.store import Store, StoreError


def _store(tmp_path: Path) -> Path:
    path = tmp_path / "results.sqlite"
    with Store(path):
        pass
    return path


@pytest.mark.parametrize(
    "sql",
    [
        "CREATE TRIGGER t AFTER INSERT ON episodes BEGIN UPDATE episodes SET status = 'done'; END",
        "CREATE VIEW v AS SELECT * FROM episodes",
        "CREATE INDEX i ON episodes (seed)",
        "ALTER TABLE episodes ADD COLUMN extra TEXT DEFAULT 'x'",
    ],
)
def test_a_store_with_a_foreign_schema_object_is_refused_untouched(
    tmp_path: Path, sql: str
) -> None:
    path = _store(tmp_path)
    db = sqlite3.connect(path)
    db.execute(sql)
    db.commit()
    db.close()
    before = path.read_bytes()
    with pytest.raises(StoreError, match="not an evaluation store as this code writes it"):
        Store(path)
    assert path.read_bytes() == before


def test_a_clean_store_still_opens(tmp_path: Path) -> None:
    path = _store(tmp_path)
    with Store(path) as store:
        assert store.path == path


def test_models_are_never_read_from_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``./models/x/model.zip`` in the working directory is not a default: outside a source
    checkout there is no default folder at all."""
    (tmp_path / "models" / "x").mkdir(parents=True)
    (tmp_path / "models" / "x" / "model.zip").write_bytes(b"PK")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(policies, "REPO_ROOT", tmp_path / "not_a_checkout")
    assert policies.default_models_dir() is None
    monkeypatch.setattr(policies, "REPO_ROOT", Path(__file__).resolve().parents[1])
    found = policies.default_models_dir()
    assert found is None or found.resolve() != (tmp_path / "models").resolve()


class _Payload:
    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (print, ("pwned",))


def test_init_from_reads_weights_without_unpickling_code(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--init-from`` reads the zip's ``policy.pth`` as tensors only: a pickled object there is
    a ``ValueError`` naming the file, and its code never runs; the ``data`` entry (SB3's
    cloudpickled objects) is not read at all."""
    import pickle
    import zipfile

    pytest.importorskip("torch")
    from training.fast_ppo import initial_weights

    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(bad, "w") as archive:
        archive.writestr("data", pickle.dumps(_Payload()).hex())
        archive.writestr("policy.pth", pickle.dumps({"x": _Payload()}, protocol=2))
    with pytest.raises(ValueError, match=r"init_from: .*bad\.zip"):
        initial_weights(bad, None)  # type: ignore[arg-type]
    assert "pwned" not in capsys.readouterr().out
    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as archive:
        archive.writestr("data", "{}")
    with pytest.raises(ValueError, match="holds no SB3 policy parameters"):
        initial_weights(empty, None)  # type: ignore[arg-type]


def test_atomic_writes_replace_links_and_leave_nothing_half_written(tmp_path: Path) -> None:
    """Every file the drivers write for the user goes through ``atomic_file``: a symbolic link
    at the destination is replaced (its target untouched), a failure mid-write leaves the old
    file whole and no temporary file behind."""
    from experiments.report import atomic_file, write_text_atomic

    target = tmp_path / "outside.txt"
    target.write_text("keep me")
    link = tmp_path / "README.md"
    link.symlink_to(target)
    write_text_atomic(link, "new")
    assert not link.is_symlink() and link.read_text() == "new"
    assert target.read_text() == "keep me"

    with pytest.raises(RuntimeError, match="disk full"), atomic_file(link) as f:
        f.write("half")
        raise RuntimeError("disk full")
    assert link.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "outside.txt"]


def test_counts_are_integers_never_floats_and_stay_in_int64() -> None:
    import argparse

    from experiments.cli import INT64_MAX, count

    parse = count(0, "seed")
    assert parse("9007199254740993") == 9007199254740993  # 2**53 + 1: not through a float
    assert parse("2e1") == 20 and parse("1_000") == 1000
    assert parse(str(INT64_MAX)) == INT64_MAX
    for bad, match in (
        (str(INT64_MAX + 1), "must be <="),
        ("1e300", "write integers this large in digits"),
        ("²", "not an integer"),
        ("2.5", "not a whole number"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=match):
            parse(bad)


def test_a_grid_too_large_to_plan_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from experiments.studies.evaluate import main

    with pytest.raises(SystemExit) as exc:
        main(["--policy", "ppc", "--episodes", "1e9", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert "more than the 1,000,000 one run plans" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "camera",
    [
        {"noise": {"position": 5.0}},
        {"noise": {"position": 1e300}},
        {"noise": {"bearing": 1e3}},
        {"noise": {"position_per_m": 10.0}, "latency": 0.05, "frame_rate": 30.0},
    ],
)
def test_noisy_observations_stay_inside_their_space(camera: dict) -> None:
    """A noisy reading is clipped to the camera's reach (x~ in [0, d_con], y~ in [-d_con,
    d_con]): every observation lies in the observation space, scale-free ones too."""
    import numpy as np

    import platoon_env

    for scale_free in (False, True):
        env = platoon_env.make(
            "study_c",
            camera=camera,
            terminate_on=(),
            observation={"task_aware": scale_free, "scale_free": scale_free},
        )
        obs, _ = env.reset(seed=0)
        space = env.observation_space("follower_1")
        for _ in range(100):
            assert all(space.contains(o) for o in obs.values())
            obs, *_ = env.step({a: np.zeros(2, np.float32) for a in env.agents})


def test_a_range_beyond_float32_is_refused() -> None:
    import platoon_env
    from platoon_env.scenarios import ScenarioError

    with pytest.raises(ScenarioError, match=r"camera.range: d_con must be <= 1e\+06 m"):
        platoon_env.make("study_c", camera={"range": 1e300})
    with pytest.raises(ScenarioError, match=r"proximity.range"):
        platoon_env.make("study_c", proximity={"range": 1e300})


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('{"a":' * 100_000 + "1" + "}" * 100_000, "nested too deep"),
        ("[1, 2]", "not a JSON object"),
        ('{"control_period": "abc"}', "control_period must be a positive number"),
        ('{"control_period": 0.025, "scenario_config": [1]}', "scenario_config must be an obj"),
    ],
)
def test_a_malformed_model_json_is_one_usage_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, match: str
) -> None:
    import shutil

    from experiments.studies.evaluate import main

    shipped = Path(__file__).resolve().parents[1] / "models" / "ppo_ta_aruco_s0"
    if not shipped.is_dir():
        pytest.skip("no shipped model")
    model = shutil.copytree(shipped, tmp_path / "m")
    (model / "model.json").write_text(text)
    with pytest.raises(SystemExit) as exc:
        main(["--policy", str(model), "--scenario", "study_c", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err


@pytest.mark.parametrize("name", ["a|b", "a\nb", "\x1b[31mred", "", "x" * 81])
def test_policy_names_that_break_tables_are_refused(name: str) -> None:
    import argparse

    from experiments.policies import PolicySpec

    with pytest.raises(argparse.ArgumentTypeError):
        PolicySpec.parse(f"{name}=ppc")


def test_a_whole_float_and_its_integer_are_one_episode(tmp_path: Path) -> None:
    """``--robot accel_max=1`` and ``accel_max=1.0`` resolve to one cell: one key, one episode
    in the store."""
    from experiments.cells import Cell
    from experiments.grid import resolve_cells

    spec = policies.PolicySpec.of("ppc")
    one = resolve_cells([Cell.of(spec, "study_c", 0, {"robot": {"accel_max": 1}})])[0]
    other = resolve_cells([Cell.of(spec, "study_c", 0, {"robot": {"accel_max": 1.0}})])[0]
    assert one.key == other.key
    half = resolve_cells([Cell.of(spec, "study_c", 0, {"robot": {"accel_max": 1.5}})])[0]
    assert half.key != one.key


def test_store_metrics_are_json_and_keep_inf_and_nan(tmp_path: Path) -> None:
    """A metric that is not a finite number is stored as a string JSON can hold (``"inf"``),
    which SQLite's ``json_extract`` reads, and comes back as the float; a row written as
    before (``Infinity``) still reads."""
    import json
    import math

    from experiments.store import EpisodeKey

    path = tmp_path / "s.sqlite"
    key = EpisodeKey("p", "s", "o", 0, "m")
    old = EpisodeKey("p", "s", "o", 1, "m")
    with Store(path) as store:
        store.register({"p": ("ppc", {})}, {"s": {}}, {"o": {}})
        run = store.begin_run("t", {"tool": "test"})
        names = {key: ("p", "s"), old: ("p", "s")}
        store.claim(list(names), run, names)
        metrics = {"time_to_violation": math.inf, "low": -math.inf, "x": math.nan, "y": 1.5}
        assert store.record(key, run, "done", metrics=metrics, names=("p", "s"))
        assert store.record(old, run, "done", metrics={"y": 2.0}, names=("p", "s"))
    db = sqlite3.connect(path)
    raw = db.execute("SELECT metrics FROM episodes WHERE seed = 0").fetchone()[0]
    json.loads(raw, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    extracted = db.execute(
        "SELECT json_extract(metrics, '$.time_to_violation') FROM episodes WHERE seed = 0"
    ).fetchone()[0]
    assert extracted == "inf"
    db.execute("UPDATE episodes SET metrics = ? WHERE seed = 1", ('{"t": Infinity}',))
    db.commit()
    db.close()
    with Store(path) as store:
        got = store.episodes()
    m = got[key].metrics
    assert m["time_to_violation"] == math.inf and m["low"] == -math.inf and math.isnan(m["x"])
    assert m["y"] == 1.5 and got[old].metrics == {"t": math.inf}


# --- scenario files: bounded before the expensive work, parsed once ----------------------------


def test_a_scenario_file_over_its_limit_is_refused_before_parsing(
    tmp_path: Path, corridor: dict
) -> None:
    """A valid scenario padded with comments just past MAX_SCENARIO_BYTES (1 MiB; it used to be
    parsed, about 10 s per MiB) is refused at once, naming the limit."""
    import time

    import yaml

    from platoon_env.scenarios import ScenarioError, load_config, loader

    path = tmp_path / "padded.yaml"
    text = yaml.safe_dump(corridor)
    line = "#" + "x" * 1022 + "\n"
    path.write_text(text + line * ((loader.MAX_SCENARIO_BYTES - len(text)) // len(line) + 1))
    assert loader.MAX_SCENARIO_BYTES < path.stat().st_size < loader.MAX_YAML_BYTES
    start = time.perf_counter()
    with pytest.raises(ScenarioError) as exc:
        load_config(path)
    assert time.perf_counter() - start < 1.0
    assert str(exc.value).startswith(f"{path}: the file is ")
    assert f"limit of {loader.MAX_SCENARIO_BYTES} bytes (MAX_SCENARIO_BYTES)" in str(exc.value)


def _squares(n: int, vertices: int = 4) -> list:
    """``n`` small polygons of ``vertices`` vertices each, inside the corridor fixture."""
    import math

    return [
        [
            [round(20.0 + 0.001 * i + 0.0004 * math.cos(2 * math.pi * k / vertices), 6),
             round(1.5 + 0.0004 * math.sin(2 * math.pi * k / vertices), 6)]
            for k in range(vertices)
        ]
        for i in range(n)
    ]  # fmt: skip


#: Scenarios past a count limit: (block, key, value, the error past "scenario.").
PAST_A_LIMIT = {
    "obstacles": ("workspace", "obstacles", lambda: _squares(1001),
                  r"workspace\.obstacles: 1001 polygons.*MAX_OBSTACLES"),
    "polygon": ("workspace", "obstacles", lambda: _squares(1, 10_001),
                r"workspace\.obstacles\[0\]: 10001 vertices.*MAX_POLYGON_VERTICES"),
    "workspace": ("workspace", "obstacles", lambda: _squares(3, 7_000),
                  r"workspace: more than 20000 vertices.*MAX_WORKSPACE_VERTICES"),
    "path": ("leader", "path", lambda: [[0.5 + 1e-3 * i, 0.0] for i in range(10_001)],
             r"leader\.path: 10001 points.*MAX_PATH_POINTS"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(PAST_A_LIMIT))
def test_a_scenario_past_a_count_limit_is_refused_before_the_schema(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, corridor: dict, case: str
) -> None:
    """Obstacles, vertices and path points are counted before the schema parses them (its checks
    and the geometry grow with them): a file or a mapping past a limit names the field and the
    limit; the schema is never called."""
    import yaml

    from platoon_env.scenarios import ScenarioError, load_config, loader

    block, key, value, match = PAST_A_LIMIT[case]
    corridor[block][key] = value()
    path = tmp_path / "big.yaml"
    path.write_text(yaml.dump(corridor, Dumper=yaml.CSafeDumper, default_flow_style=True))
    assert path.stat().st_size < loader.MAX_SCENARIO_BYTES  # the count is what is refused

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("the schema parsed a scenario past a limit")

    monkeypatch.setattr(loader, "parse_scenario", never)
    with pytest.raises(ScenarioError, match=rf"^{path}: scenario\.{match}"):
        load_config(path)
    with pytest.raises(ScenarioError, match=rf"^scenario\.{match}"):
        load_config(corridor)


def test_the_count_limits_leave_wide_headroom_for_shipped_and_procedural_scenarios() -> None:
    """Every shipped scenario file, and the layouts the procedural families draw, lie at least
    ten times inside each limit (measured: 6.7 kB, 26 obstacles, 171 vertices, 133 path
    points)."""
    from importlib import resources

    from platoon_env.scenarios import list_scenarios, load_config, loader
    from platoon_env.scenarios.source import ProceduralSource

    def counts(cfg: Any) -> tuple[int, int, int, int]:
        ws = cfg.workspace
        polygons = list(ws.obstacles)
        if ws.free_space is not None:
            polygons += [ws.free_space.exterior, *ws.free_space.holes]
        sizes = [len(p) for p in polygons]
        return len(polygons), max(sizes, default=0), sum(sizes), len(cfg.leader.path)

    limits = (loader.MAX_OBSTACLES, loader.MAX_POLYGON_VERTICES, loader.MAX_WORKSPACE_VERTICES,
              loader.MAX_PATH_POINTS)  # fmt: skip
    for name in list_scenarios():
        text = resources.files(loader._DATA).joinpath(f"{name}.yaml").read_bytes()
        assert 10 * len(text) < loader.MAX_SCENARIO_BYTES, name
        cfg = load_config(name)
        layouts = [cfg] if cfg.generator is None else [
            ProceduralSource(cfg).layout(i).config for i in (0, 1, 2)
        ]  # fmt: skip
        for layout in layouts:
            assert all(10 * n < limit for n, limit in zip(counts(layout), limits, strict=True)), (
                name, counts(layout))  # fmt: skip


def test_a_scenario_file_is_parsed_once_per_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """make() twice and the single-follower env (which looked at the file first) parse a file
    once (each episode of a run used to parse it again); an edited scenario or trajectory file
    is parsed again."""
    import shutil

    import platoon_env
    from platoon_env.gym_env import SingleFollowerEnv
    from platoon_env.scenarios import ScenarioError, load_config, loader

    data = Path(loader.__file__).parent / "data"
    path = shutil.copy(data / "study_b.yaml", tmp_path / "b.yaml")
    shutil.copytree(data / "trajectories", tmp_path / "trajectories")
    parsed: list[str] = []
    read_yaml = loader.read_yaml

    def counting(text: str, source: str) -> Any:
        parsed.append(source)
        return read_yaml(text, source)

    monkeypatch.setattr(loader, "read_yaml", counting)
    first = load_config(path)
    assert len(parsed) == 2  # the scenario and its trajectory file
    platoon_env.make(path)
    platoon_env.make(path)
    SingleFollowerEnv(path)
    assert load_config(path) is first and len(parsed) == 2
    assert load_config("study_b") == first  # the shipped file: the same config
    # An edited trajectory file, then an edited scenario file: parsed again.
    trajectory = tmp_path / "trajectories" / "study_b_trajectory.yaml"
    trajectory.write_text("[[0, 0, 0, 0]]\n")
    with pytest.raises(ScenarioError, match=r"leader\.trajectory"):
        load_config(path)
    shutil.copy(data / "trajectories" / "study_b_trajectory.yaml", trajectory)
    Path(path).write_text(Path(path).read_text().replace("followers: 2", "followers: 3"))
    assert load_config(path).followers == 3
