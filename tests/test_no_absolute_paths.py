"""No absolute path of a machine in the published text; the relativising of command lines.

The scan covers what a reader sees: every text file under ``docs/`` (pages, generated tables,
the site's sources), ``README.md`` and ``CHANGELOG.md``, tracked by git or new (untracked and
not ignored). ``models/**/model.json`` is left out: every shipped ``model.json`` records the
training command with the absolute paths of the machine that trained it, and their hashes and
fingerprints are pinned by tests (``tests/test_fingerprints.py``, ``tests/test_shipped_models.py``),
so they are not rewritten here. Binary files (the PNGs) are skipped: their text fields were
written by :func:`experiments.stamp.png_metadata`, which now writes portable paths too.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from experiments.stamp import REPO_ROOT, png_metadata, portable_argv, portable_path, stamp_markdown

ROOT = Path(__file__).resolve().parents[1]

#: What the scan calls an absolute machine path: a home, temporary or work folder of Linux or
#: macOS at the start of a path (not ``docs/work/...``), or a Windows drive path.
ABSOLUTE = re.compile(
    r"(?<![\w.~-])/(?:root|home|tmp|work|Users|private/var|var/folders)/"
    r"|(?<![A-Za-z])[A-Za-z]:\\[A-Za-z]"
)

#: Known occurrences the scan lets through, by file: each is a line of a page this test does
#: not own. Remove the entry once the line is fixed (the test fails on an entry that no longer
#: matches, so the list stays true).
KNOWN: dict[str, tuple[str, ...]] = {}


def _published_files() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    listing = ["ls-files", "--cached", "--others", "--exclude-standard", "-z"]
    out = subprocess.run(
        [
            "git",
            "-C",
            str(ROOT),
            *listing,
            "--",
            "docs",
            "README.md",
            "CHANGELOG.md",
            "benchmarks/README.md",
            "models/README.md",
            "examples/README.md",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    ).stdout
    return sorted({name for name in out.split("\0") if name})


def _text(path: Path) -> str | None:
    data = path.read_bytes()
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def test_no_absolute_machine_paths_in_published_text() -> None:
    found: list[str] = []
    used: set[tuple[str, str]] = set()
    scanned = 0
    for name in _published_files():
        path = ROOT / name
        if not path.is_file():  # deleted in the working tree, not yet committed
            continue
        text = _text(path)
        if text is None:
            continue
        scanned += 1
        for number, line in enumerate(text.splitlines(), start=1):
            if not ABSOLUTE.search(line):
                continue
            known = [k for k in KNOWN.get(name, ()) if k in line]
            rest = line
            for k in known:
                used.add((name, k))
                rest = rest.replace(k, "")
            if ABSOLUTE.search(rest):
                found.append(f"{name}:{number}: {line.strip()[:160]}")
    assert scanned > 10, "the scan found almost nothing to read"
    assert not found, "absolute machine paths in published text:\n" + "\n".join(found)
    stale = [f"{name}: {k!r}" for name, ks in KNOWN.items() for k in ks if (name, k) not in used]
    assert not stale, "KNOWN entries that no longer occur (remove them):\n" + "\n".join(stale)


@pytest.mark.parametrize(
    ("arg", "expected"),
    [
        ("/x/repo/models", "models"),
        ("/x/repo/docs/leaderboard.md", "docs/leaderboard.md"),
        ("/x/repo", "."),
        ("/x/repo/", "."),
        ("--docs=/x/repo/docs", "--docs=docs"),
        ("/x/repository/models", "<outside>/models"),  # a prefix of the root is not the root
        ("/scratch/tmp/a.log", "<outside>/a.log"),
        ("/tmp/ppct/search2.log", "<tmp>/ppct/search2.log"),
        ("/tmp", "<tmp>"),
        ("/home/u/runs/store", "~/runs/store"),
        ("--out=/home/u/runs", "--out=~/runs"),
        ("/srv/data/runs/lb/store", "<outside>/store"),
        ("/srv/data/runs/lb/store/", "<outside>/store"),
        ("C:\\Users\\me\\runs\\store", "<outside>/store"),
        ("/", "<outside>"),
        # not absolute paths: unchanged
        ("runs/lb/store", "runs/lb/store"),
        ("./models", "./models"),
        ("--workers", "--workers"),
        ("-1", "-1"),
        ("mine=my_policy:MyPolicy", "mine=my_policy:MyPolicy"),
        ("a=b=c", "a=b=c"),
        ("", ""),
    ],
)
def test_portable_path(arg: str, expected: str) -> None:
    assert portable_path(arg, root="/x/repo", home="/home/u", tmp="/tmp") == expected


def test_portable_path_checkout_inside_home_and_windows_root() -> None:
    # The checkout wins over the home folder that holds it.
    assert portable_path("/home/u/repo/docs", root="/home/u/repo", home="/home/u") == "docs"
    assert portable_path("/home/u/other", root="/home/u/repo", home="/home/u") == "~/other"
    assert portable_path("C:\\src\\repo\\models", root="C:\\src\\repo", home="/h") == "models"


def test_portable_argv_gives_the_published_leaderboard_line() -> None:
    # docs/leaderboard.md's stamp as the leaderboard wrote it from the checkout /work/lbtree
    # (its store elsewhere), and the line as published now.
    argv = (
        "--models /work/lbtree/models --store /work/main/runs/lb/store --batch 20 --workers 2 "
        "--heldout-seeds 40 --docs /work/lbtree/docs --readme /work/lbtree/README.md"
    ).split()
    line = " ".join(portable_argv(argv, root="/work/lbtree"))
    assert line == (
        "--models models --store <outside>/store --batch 20 --workers 2 --heldout-seeds 40 "
        "--docs docs --readme README.md"
    )
    assert f"- arguments: `{line}`" in (ROOT / "docs" / "leaderboard.md").read_text()


def test_stamp_writers_publish_no_absolute_path() -> None:
    stamp = {
        "tool": "platoon-leaderboard",
        "argv": ["--models", str(REPO_ROOT / "models"), "--store", "/srv/x/store", "--seeds", "3"],
        "versions": {"platoon_env": "0.1.0"},
    }
    markdown = stamp_markdown(stamp)
    assert "- arguments: `--models models --store <outside>/store --seeds 3`" in markdown
    description = png_metadata(stamp)["Description"]
    assert "--models models --store <outside>/store --seeds 3" in description
    for text in (markdown, description):
        assert str(REPO_ROOT) not in text
        assert not ABSOLUTE.search(text)
