"""Property-based families (hypothesis) for the files a run reads (hardening round 4, item 7):
a ``model.json`` of any shape goes through the validation ``LearnedPolicy.load`` applies and is
accepted or refused with a ``ValueError``/``FileNotFoundError`` naming the file, never another
exception; an evaluation store's rows of any content are read back or refused with one
:class:`~experiments.store.StoreError` naming the store, never a crash. (The command-line
numbers' family is in ``tests/test_properties.py``.)"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import shutil
import sqlite3
import uuid
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

pytest.importorskip("stable_baselines3")

from experiments.store import (
    EPISODE_METRICS,
    EPISODE_METRICS_LATER,
    RUN_STATUSES,
    STATUSES,
    EpisodeKey,
    Store,
    StoreError,
)
from training.policies import (
    METADATA_FORMAT,
    METADATA_VERSION,
    _check_metadata,
    _check_zip,
    _read_metadata,
)

REPO = Path(__file__).resolve().parents[1]
#: Each example writes a file (and for the store copies a database): fewer than the in-memory
#: families of test_properties.py, a few seconds per test.
SETTINGS = settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)

#: Any JSON value, the awkward ones included: huge integers, non-finite floats (json writes
#: them as NaN/Infinity, which Python's reader accepts), their spellings as strings, deep-ish
#: nesting, empty and odd keys.
JSON_SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.floats(),
    st.sampled_from(["NaN", "nan", "inf", "-inf", "Infinity", "1e400", "", "0", "true", "null"]),
    st.text(max_size=20),
)
JSON_VALUES = st.recursive(
    JSON_SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=10), inner, max_size=5)
    ),
    max_leaves=20,
)


# ----------------------------------------------------------------------------------------------
# model.json
# ----------------------------------------------------------------------------------------------
#: A shipped model's description (an SB3 model), the base the documents below are made from.
BASE_META: dict[str, Any] = json.loads((REPO / "models/lag_ta_aruco_s0/model.json").read_text())
ZIP_BYTES = b"a model zip"
ZIP_SHA256 = hashlib.sha256(ZIP_BYTES).hexdigest()
#: The fields LearnedPolicy.load reads (and some it only carries), to replace or remove.
FIELDS = sorted(
    {
        "format",
        "format_version",
        "algo",
        "engine",
        "zip_sha256",
        "control_period",
        "observation_layout",
        "observation_normalization",
        "action_range",
        "previous_command",
        "scenario_config",
        "config",
        "segments",
    }
)


def _valid_meta() -> dict[str, Any]:
    meta = copy.deepcopy(BASE_META)
    meta["zip_sha256"] = ZIP_SHA256
    return meta


def _replace(meta: dict[str, Any], path: tuple[str, ...], value: Any) -> dict[str, Any]:
    node = meta
    for part in path[:-1]:
        child = node.get(part)
        if not isinstance(child, dict):
            child = node[part] = {}
        node = child
    if value is _REMOVE:
        node.pop(path[-1], None)
    else:
        node[path[-1]] = value
    return meta


_REMOVE = object()
#: A path into the document: a top-level field, or one inside action_range/normalisation.
PATHS = st.one_of(
    st.sampled_from(FIELDS).map(lambda f: (f,)),
    st.sampled_from(["u_low", "u_high", "omega_high", "extra"]).map(lambda k: ("action_range", k)),
    st.sampled_from(["type", "scale"]).map(lambda k: ("observation_normalization", k)),
)
#: Documents: the valid one with fields replaced or removed, any JSON value at all, and text
#: that is not JSON (deep nesting, NaN spellings, bytes that are not UTF-8).
DOCUMENTS = st.one_of(
    st.lists(
        st.tuples(PATHS, st.one_of(JSON_VALUES, st.just(_REMOVE))), min_size=1, max_size=3
    ).map(lambda edits: json.dumps(_apply(edits))),
    JSON_VALUES.map(json.dumps),
    st.dictionaries(st.sampled_from(FIELDS), JSON_VALUES, max_size=6).map(
        lambda d: json.dumps({"format": METADATA_FORMAT, "format_version": METADATA_VERSION, **d})
    ),
    st.integers(1, 200_000).map(lambda n: "[" * n + "]" * n),
    st.integers(1, 200_000).map(lambda n: '{"a":' * n + "1" + "}" * n),
    st.text(max_size=200),
    st.binary(max_size=200),
)


def _apply(edits: Sequence[tuple[tuple[str, ...], Any]]) -> dict[str, Any]:
    meta = _valid_meta()
    for path, value in edits:
        meta = _replace(meta, path, value)
    return meta


def _validate(meta_file: Path) -> None:
    """What LearnedPolicy.load checks of ``model.json`` before it loads the zip beside it."""
    meta, version = _read_metadata(meta_file)
    zip_path = meta_file.with_suffix(".zip")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # a format_version 1 file: not checkable
        _check_zip(zip_path, meta, version, meta_file)
    _check_metadata(meta, str(meta_file))


def test_the_shipped_description_is_valid(tmp_path: Path) -> None:
    meta_file = tmp_path / "model.json"
    meta_file.write_text(json.dumps(_valid_meta()))
    (tmp_path / "model.zip").write_bytes(ZIP_BYTES)
    _validate(meta_file)


@SETTINGS
@given(DOCUMENTS)
# the cases of the adversarial pass: 200,000 deep, fields of the wrong type or shape
@example("[" * 200_000 + "]" * 200_000)
@example(json.dumps(_apply([(("control_period",), "abc")])))
@example(json.dumps(_apply([(("control_period",), math.nan)])))
@example(json.dumps(_apply([(("action_range",), [1])])))
@example(json.dumps(_apply([(("action_range", "u_high"), "1.5")])))
@example(json.dumps(_apply([(("observation_normalization", "scale"), [1e400])])))
@example(json.dumps(_apply([(("format_version",), 10**400)])))
@example(json.dumps(_apply([(("previous_command",), "yes")])))
@example(json.dumps(_apply([(("zip_sha256",), ["a"])])))
@example(json.dumps(_apply([(("action_range",), _REMOVE)])))
def test_any_model_json_is_valid_or_refused_naming_the_file(
    tmp_path_factory: pytest.TempPathFactory, document: str | bytes
) -> None:
    folder = tmp_path_factory.mktemp("model")
    meta_file = folder / "model.json"
    if isinstance(document, bytes):
        meta_file.write_bytes(document)
    else:
        meta_file.write_text(document, encoding="utf-8", errors="surrogatepass")
    (folder / "model.zip").write_bytes(ZIP_BYTES)
    try:
        _validate(meta_file)
    except (ValueError, FileNotFoundError) as exc:
        assert str(meta_file) in str(exc), str(exc)[:300]
        assert "Traceback" not in str(exc)


def test_a_missing_model_json_is_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"model\.json not found"):
        _validate(tmp_path / "model.json")


# ----------------------------------------------------------------------------------------------
# Store rows
# ----------------------------------------------------------------------------------------------
MEASURE = "platoon_env.rollout:episode_metrics"
KEY = EpisodeKey("a" * 64, "b" * 64, "c" * 64, 3, MEASURE)
GOOD: dict[str, Any] = {
    **{field: 1.5 for field, kind in EPISODE_METRICS.items() if kind == "number"},
    **{field: 2 for field, kind in EPISODE_METRICS.items() if kind == "count"},
    "success": True,
    "leader_arrived": True,
    "violation": "",
    "time_to_violation": math.inf,
}
INT64 = st.integers(min_value=-(2**63), max_value=2**63 - 1)
#: What an SQLite column can hold (of any declared type: SQLite does not enforce them).
SQL_VALUES = st.one_of(
    st.none(),
    INT64,
    st.sampled_from([0, 1, -1, 2**31 - 1, 2**31, 2**63 - 1, -(2**63)]),
    st.floats(),
    st.text(st.characters(codec="utf-8"), max_size=40),
    st.sampled_from(list(STATUSES) + list(RUN_STATUSES) + ["", "DONE", "done ", "\x1b[31m"]),
    st.binary(max_size=20),
)
#: The metrics column: the good metrics with fields replaced or removed, any JSON, any text.
METRICS = st.one_of(
    st.dictionaries(st.sampled_from(sorted(EPISODE_METRICS)), JSON_VALUES, max_size=4).map(
        lambda d: json.dumps({**{k: v for k, v in GOOD.items() if k not in d}, **d})
    ),
    st.sampled_from(sorted(EPISODE_METRICS)).map(
        lambda f: json.dumps({k: v for k, v in GOOD.items() if k != f})
    ),
    JSON_VALUES.map(json.dumps),
    st.text(max_size=60),
    st.integers(1, 50_000).map(lambda n: "[" * n + "]" * n),
)
EPISODE_COLUMNS = (
    "policy",
    "scenario",
    "overrides",
    "seed",
    "measure",
    "status",
    "run_id",
    "policy_name",
    "scenario_name",
    "updated",
    "wall_time",
    "error",
)
RUN_COLUMNS = ("tool", "started", "finished", "status", "pid", "host", "proc_start", "stamp")


@pytest.fixture(scope="module")
def base_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store with one finished episode (``KEY``) of one finished run."""
    path = tmp_path_factory.mktemp("store") / "s.sqlite"
    with Store(path) as store:
        store.register({KEY.policy: ("ppc", {})}, {KEY.scenario: {}}, {KEY.overrides: {}})
        run = store.begin_run("platoon-evaluate", {"tool": "test", "commit": "0" * 40})
        store.claim([KEY], run, {KEY: ("ppc", "study_c")})
        store.record(KEY, run, "done", metrics=GOOD, names=("ppc", "study_c"))
        store.finish_run(run, "finished")
    return path


def _edited(base: Path, table: str, values: dict[str, Any]) -> Path | None:
    """A copy of ``base`` with its one ``table`` row's columns set to ``values`` (None: SQLite
    itself refuses the values: a NOT NULL or CHECK constraint)."""
    path = base.with_name(f"{uuid.uuid4().hex}.sqlite")
    shutil.copyfile(base, path)
    db = sqlite3.connect(path)
    try:
        sets = ", ".join(f"{column} = ?" for column in values)
        db.execute(f"UPDATE {table} SET {sets}", list(values.values()))
        db.commit()
    except sqlite3.IntegrityError:
        return None
    finally:
        db.close()
    return path


def _read_back(path: Path) -> Any:
    """Every row of the store at ``path``, as the evaluators read it; a refusal must be one
    StoreError naming the file."""
    try:
        with Store(path) as store:
            return store.runs(), store.episodes()
    except StoreError as exc:
        assert str(path) in str(exc), str(exc)[:300]
        assert "Traceback" not in str(exc)
        return None
    finally:
        path.unlink(missing_ok=True)


@SETTINGS
@given(
    st.dictionaries(st.sampled_from(EPISODE_COLUMNS), SQL_VALUES, min_size=1, max_size=3),
    st.one_of(st.none(), METRICS),
)
@example({"seed": "3"}, json.dumps(GOOD))
@example({"run_id": 0, "status": "DONE"}, None)
@example({"policy_name": "\x1b[2J", "updated": math.inf}, "{}")
def test_any_episode_row_is_read_or_refused_with_a_store_error(
    base_store: Path, columns: dict[str, Any], metrics: str | None
) -> None:
    path = _edited(base_store, "episodes", {**columns, "metrics": metrics})
    if path is None:
        return
    read = _read_back(path)
    if read is not None:  # accepted: every field of the documented type
        _, episodes = read
        for key, record in episodes.items():
            assert isinstance(key.seed, int) and record.status in STATUSES
            assert isinstance(record.metrics, dict) and isinstance(record.error, str)
            assert isinstance(record.run_id, int) and record.run_id > 0


@SETTINGS
@given(METRICS)
# the cases of the adversarial pass: {}, a string where a number belongs, Infinity (not JSON)
@example("{}")
@example(json.dumps({**GOOD, next(f for f, k in EPISODE_METRICS.items() if k == "number"): "1"}))
@example(json.dumps({**GOOD, "time_to_violation": math.inf}))
@example("[" * 50_000 + "]" * 50_000)
def test_any_metrics_of_a_done_episode_are_complete_or_refused(
    base_store: Path, metrics: str
) -> None:
    path = _edited(base_store, "episodes", {"metrics": metrics})
    assert path is not None
    read = _read_back(path)
    if read is not None:
        (record,) = read[1].values()
        # every field but those added after stores held rows (a row may predate them)
        assert set(EPISODE_METRICS) - set(EPISODE_METRICS_LATER) <= set(record.metrics)


@SETTINGS
@given(
    st.dictionaries(
        st.sampled_from(RUN_COLUMNS),
        st.one_of(SQL_VALUES, JSON_VALUES.map(json.dumps)),
        min_size=1,
        max_size=3,
    )
)
@example({"stamp": "[1, 2]"})
@example({"pid": 2**40})
@example({"pid": "1234"})
@example({"stamp": '{"a": Infinity}', "started": -1.0})
def test_any_run_row_is_read_or_refused_with_a_store_error(
    base_store: Path, columns: dict[str, Any]
) -> None:
    path = _edited(base_store, "runs", columns)
    if path is None:
        return
    read = _read_back(path)
    if read is not None:
        (run,) = read[0]
        assert isinstance(run["stamp"], dict) and run["status"] in RUN_STATUSES
        assert isinstance(run["pid"], int) and isinstance(run["state"], str)
