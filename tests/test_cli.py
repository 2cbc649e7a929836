"""experiments.cli: the drivers' shared parser and their one rule for a store that fails (one line
``TOOL: error: ...``, exit 2 before any work, exit 1 during the run; never a traceback)."""

from __future__ import annotations

import hashlib
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from experiments.cli import new_parser, open_store
from experiments.store import ClaimTimeout


def _foreign_sqlite(path: Path) -> str:
    """A SQLite file that is not an evaluation store; returns its hash."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE users (name TEXT)")
    db.close()
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_new_parser_names_the_tool_and_adds_out() -> None:
    parser = new_parser("python -m tool", "The tool.\n\n    kept   as written", out=Path("o"))
    assert parser.prog == "python -m tool"
    assert "    kept   as written" in parser.format_help()
    assert parser.parse_args([]).out == Path("o")
    assert parser.parse_args(["--out", "x"]).out == Path("x")
    assert not hasattr(new_parser("t", None).parse_args([]), "out")


def test_a_store_that_is_not_ours_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "results.sqlite"
    _foreign_sqlite(path)
    with pytest.raises(SystemExit) as exc, open_store("tool", path):
        raise AssertionError("never entered")
    assert exc.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"tool: error: {path}: not an evaluation store")


def test_a_store_error_during_the_run_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc, open_store("tool", tmp_path / "s.sqlite") as store:
        assert store.path == tmp_path / "s.sqlite"
        raise ClaimTimeout("cells held by run 3")
    assert exc.value.code == 1
    assert capsys.readouterr().err == "tool: error: cells held by run 3\n"


def _comparison(store: Path, out: Path) -> Any:
    from experiments.studies.comparison import main

    return main(["--store", str(store), "--out", str(out), "--seeds", "1"])


def _paper_figures(store: Path, out: Path) -> Any:
    from experiments.studies.paper_figures import main

    return main(["--store", str(store), "--out", str(out), "--seeds", "1", "--study", "study_c"])


def _frontiers(store: Path, out: Path) -> Any:
    from experiments.studies.frontiers import main

    args = ["--quick", "--seeds", "1", "--study", "study_c", "--controller", "ppc"]
    return main([*args, "--axis", "detection", "--out", str(out)])


@pytest.mark.parametrize(
    ("tool", "run"),
    [
        ("comparison", _comparison),
        ("paper_figures", _paper_figures),
        ("frontiers", _frontiers),
    ],
)
def test_drivers_refuse_a_foreign_store_before_any_work(
    tool: str,
    run: Callable[[Path, Path], Any],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "out"
    store = out / "results.sqlite" if tool == "frontiers" else tmp_path / "other.sqlite"
    before = _foreign_sqlite(store)
    with pytest.raises(SystemExit) as exc:
        run(store, out)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"python -m experiments.studies.{tool}: error: {store}: not an evaluation store" in err
    assert "Traceback" not in err
    assert hashlib.sha256(store.read_bytes()).hexdigest() == before
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert written == [store.relative_to(tmp_path)]  # nothing but the refused file


def test_a_driver_exits_1_naming_its_failed_episodes(capsys: pytest.CaptureFixture[str]) -> None:
    from types import SimpleNamespace

    from experiments.cli import failed_episodes

    assert failed_episodes(SimpleNamespace(failed=[])) == 0  # type: ignore[arg-type]
    assert capsys.readouterr().err == ""
    assert failed_episodes(SimpleNamespace(failed=[object(), object()])) == 1  # type: ignore[arg-type]
    assert capsys.readouterr().err == "2 episode(s) failed; re-run to retry them\n"
