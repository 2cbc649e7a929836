"""scripts/docs_blocks.py: the generated blocks of the documentation (parsing, replacement,
commands, the repository's own blocks)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parent.parent


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "docs_blocks", REPO / "scripts" / "docs_blocks.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["docs_blocks"] = module  # dataclasses resolve their module
    spec.loader.exec_module(module)
    return module


db = _load()

DOC = """# Title

Text with 1 number by hand.

<!-- begin: python tool.py --rows 2 -->
old body
<!-- end -->

Between.

<!-- begin: python tool.py --rows 2 ; file out/result.md ; table 2 -->
| old |
<!-- end -->
tail
"""

TOOL = """import sys
from pathlib import Path
rows = int(sys.argv[sys.argv.index("--rows") + 1])
print("| a | b |\\n|---|---|")
for i in range(rows):
    print(f"| {i} | {i * i} |")
Path("out").mkdir(exist_ok=True)
made = "# made\\n\\n| x |\\n|---|\\n\\nprose\\n\\n| y |\\n|---|\\n| 7 |\\n"
Path("out/result.md").write_text(made)
"""


def _repo(tmp_path: Path, doc: str = DOC) -> Path:
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text(doc)
    (tmp_path / "tool.py").write_text(TOOL)
    return tmp_path


def test_parse_finds_blocks_with_their_clauses() -> None:
    blocks = db.parse(DOC, "README.md")
    assert [(b.line, b.command, b.file, b.select) for b in blocks] == [
        (5, "python tool.py --rows 2", None, None),
        (11, "python tool.py --rows 2", "out/result.md", ("table", 2)),
    ]
    assert blocks[0].body == "old body"
    assert blocks[1].body == "| old |"


def test_markers_in_fenced_code_are_not_blocks() -> None:
    text = "```\n<!-- begin: python x.py -->\n```\n<!-- begin: python y.py -->\nz\n<!-- end -->\n"
    assert [b.command for b in db.parse(text, "f.md")] == ["python y.py"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("<!-- begin: python a.py -->\n<!-- begin: python b.py -->\n<!-- end -->\n", "f.md:2"),
        ("a\n<!-- begin: python a.py -->\nbody\n", "f.md:2: the block is not closed"),
        ("a\n<!-- end -->\n", "f.md:2: an end marker without"),
        ("<!-- begin: python a.py ; tabel 1 -->\n<!-- end -->\n", "bad clause"),
        ("<!-- begin: python a.py ; table 0 -->\n<!-- end -->\n", "bad clause"),
        ("<!-- begin: python a.py ; file a ; file b -->\n<!-- end -->\n", "bad clause"),
        ("<!-- begin:  -->\n<!-- end -->\n", "names no command"),
    ],
)
def test_malformed_markers_are_errors_with_the_place(text: str, message: str) -> None:
    with pytest.raises(db.BlockError, match=message):
        db.parse(text, "f.md")


def test_replace_changes_only_the_bodies() -> None:
    blocks = db.parse(DOC, "README.md")
    new = db.replace(DOC, blocks, {0: "line 1\nline 2\n", 1: ""})
    assert new == DOC.replace("old body", "line 1\nline 2").replace("| old |\n", "")
    assert [b.spec for b in db.parse(new, "README.md")] == [b.spec for b in blocks]


def test_select_table_and_list() -> None:
    text = "intro\n| a |\n|---|\n\n- one\n  more\n- two\n\n| b |\n"
    assert db.select_text(text, ("table", 2), "x") == "| b |"
    assert db.select_text(text, ("list", 1), "x") == "- one\n  more\n- two"
    assert db.select_text(f"\n{text}\n\n", None, "x") == text.strip("\n")
    with pytest.raises(db.BlockError, match="2 table"):
        db.select_text(text, ("table", 3), "x")


def test_known_and_unknown_commands(tmp_path: Path) -> None:
    root = _repo(tmp_path)
    (root / "pkg").mkdir()
    (root / "pkg" / "mod.py").write_text("")
    (root / "pyproject.toml").write_text('[project.scripts]\nplatoon-x = "pkg.mod:main"\n')
    assert db.unknown_reason("python tool.py --rows 1", root) is None
    assert db.unknown_reason("python -m pkg.mod --flag", root) is None
    assert db.unknown_reason("platoon-x --y", root) is None
    assert "no module" in db.unknown_reason("python -m pkg.nothing", root)
    assert "no file" in db.unknown_reason("python missing.py", root)
    assert "console script" in db.unknown_reason("cat out/result.md", root)
    assert "-m MODULE" in db.unknown_reason("python -c 'print(1)'", root)


def test_write_runs_each_command_once_and_fills_both_blocks(tmp_path: Path) -> None:
    root = _repo(tmp_path)
    assert db.main(["--root", str(root), "--write"]) == 0
    text = (root / "README.md").read_text()
    assert "| a | b |\n|---|---|\n| 0 | 0 |\n| 1 | 1 |\n<!-- end -->" in text
    assert "table 2 -->\n| y |\n|---|\n| 7 |\n<!-- end -->\ntail\n" in text
    assert "Text with 1 number by hand." in text
    # the bodies now match their sources: --check (file blocks) and --diff (all) are clean
    assert db.main(["--root", str(root), "--check"]) == 0
    assert db.main(["--root", str(root), "--diff"]) == 0


def test_only_selects_blocks(tmp_path: Path) -> None:
    doc = DOC.replace("python tool.py --rows 2 -->", "python tool.py --rows 1 -->")
    root = _repo(tmp_path, doc)
    assert db.main(["--root", str(root), "--write", "--only", "rows 1"]) == 0
    text = (root / "README.md").read_text()
    assert "| 0 | 0 |\n<!-- end -->" in text
    assert "| old |" in text  # the other command was not run


def test_check_catches_a_hand_edit_of_a_file_block(tmp_path: Path, capsys) -> None:
    root = _repo(tmp_path)
    assert db.main(["--root", str(root), "--write"]) == 0
    readme = root / "README.md"
    readme.write_text(readme.read_text().replace("| 7 |", "| 8 |"))
    assert db.main(["--root", str(root), "--check"]) == 1
    assert "README.md:14: the body differs from out/result.md" in capsys.readouterr().err
    assert db.main(["--root", str(root), "--diff"]) == 1


def test_unknown_command_fails_check_and_write_without_running(tmp_path: Path, capsys) -> None:
    root = _repo(tmp_path, DOC + "<!-- begin: python nowhere.py -->\nx\n<!-- end -->\n")
    assert db.main(["--root", str(root), "--check"]) == 1
    assert "unknown command 'python nowhere.py'" in capsys.readouterr().err
    before = (root / "README.md").read_text()
    assert db.main(["--root", str(root), "--write"]) == 1
    assert (root / "README.md").read_text() == before
    assert not (root / "out").exists()  # nothing ran


def test_failing_command_leaves_its_blocks(tmp_path: Path) -> None:
    root = _repo(tmp_path, DOC + "<!-- begin: python bad.py -->\nkept\n<!-- end -->\n")
    (root / "bad.py").write_text("raise SystemExit(3)\n")
    assert db.main(["--root", str(root), "--write"]) == 1
    text = (root / "README.md").read_text()
    assert "<!-- begin: python bad.py -->\nkept\n<!-- end -->" in text
    assert "| 1 | 1 |" in text  # the other command's blocks were written


def test_dry_run_lists_commands_and_writes_nothing(tmp_path: Path, capsys) -> None:
    root = _repo(tmp_path)
    assert db.main(["--root", str(root), "--write", "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines() == ["python tool.py --rows 2"]
    assert (root / "README.md").read_text() == DOC


def test_the_repositorys_blocks_parse_and_name_known_commands() -> None:
    blocks, errors = db.collect(REPO)
    assert errors == []
    found = [b for bs in blocks.values() for b in bs]
    assert found, "the documentation has generated blocks"
    for b in found:
        assert db.unknown_reason(b.command, REPO) is None, b.label()
    for page, command in db.PAGES.items():
        assert db.unknown_reason(command, REPO) is None, page
        assert f"`{command}`" in (REPO / page).read_text(), page


def test_no_run_takes_files_as_they_are_and_leaves_stdout_blocks(tmp_path: Path) -> None:
    root = _repo(tmp_path)
    (root / "out").mkdir()
    (root / "out" / "result.md").write_text("| 1 |\n\n| 2 |\n| 3 |\n")
    assert db.main(["--root", str(root), "--write", "--no-run"]) == 0
    text = (root / "README.md").read_text()
    assert "table 2 -->\n| 2 |\n| 3 |\n<!-- end -->" in text
    assert "-->\nold body\n<!-- end -->" in text  # standard output: nothing ran
    assert (root / "out" / "result.md").read_text() == "| 1 |\n\n| 2 |\n| 3 |\n"


def test_the_repositorys_blocks_of_committed_files_equal_those_files() -> None:
    """A block quoting a committed output (``docs/figures/*.md``) equals it: a hand edit of the
    quote, or a regenerated output not copied into its quotes, fails. (Outputs under the
    uncommitted ``results/`` differ from machine to machine and are not compared here.)"""
    blocks, _ = db.collect(REPO)
    compared = 0
    for b in (b for bs in blocks.values() for b in bs):
        if b.file is None or b.file.startswith("results/") or not (REPO / b.file).is_file():
            continue
        assert db.source_text(b, "", REPO) == b.body.strip("\n"), b.label()
        compared += 1
    assert compared >= 2  # the README's PPC record and comparison


def test_the_readme_quick_start_prints_what_its_comment_says() -> None:
    """The one number of the README outside a generated block, the quick start's output, is
    checked here by running the snippet (``print(...)   # OUTPUT``)."""
    import contextlib
    import io
    import re

    readme = (REPO / "README.md").read_text()
    quick = readme.split("## Quick start", 1)[1]
    code = re.search(r"```python\n(.*?)```", quick, re.S)
    assert code is not None
    snippet = code.group(1)
    printed = re.search(r"^print\(.*\)\s+# (?P<out>.+)$", snippet, re.M)
    assert printed is not None, "the quick start ends with print(...)  # its output"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(snippet, "README.md quick start", "exec"), {})
    assert out.getvalue().strip() == printed.group("out").strip()
