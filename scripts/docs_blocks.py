"""The documentation's generated blocks: list them, regenerate them, check them.

Every measured number in ``README.md``, ``docs/*.md``, ``benchmarks/README.md`` and
``models/README.md`` is written by a command, never by hand. It sits in a *generated block*
whose opening marker names that command::

    <!-- begin: COMMAND [; file PATH] [; table N | ; list N] -->
    ... the body: what COMMAND printed (or wrote to PATH) ...
    <!-- end -->

* ``COMMAND`` is run from the repository root without a shell (split like a shell would split
  it; ``python`` is the interpreter running this tool). It must be *known*: ``python -m
  MODULE`` of a module in the repository, ``python FILE`` or ``bash FILE`` of a file in it, or a
  console script of ``pyproject.toml``.
* The body is ``COMMAND``'s standard output; with ``; file PATH`` (relative to the repository
  root) it is the text of ``PATH`` after ``COMMAND`` ran — for drivers that write a markdown
  file and print progress. ``; table N`` keeps only the N-th markdown table of that text (from
  1), ``; list N`` the N-th bullet list.
* Markers are whole lines, outside fenced code; blocks do not nest.

Some pages are written whole by a command (the leaderboard's): they are listed in
:data:`PAGES`, and must name their command in their text.

Usage::

    python scripts/docs_blocks.py --list                 # every block and page, and its command
    python scripts/docs_blocks.py --write [--only RE]    # run the commands, rewrite the bodies
    python scripts/docs_blocks.py --write --dry-run      # what --write would run
    python scripts/docs_blocks.py --write --no-run       # file blocks from their files, as they are
    python scripts/docs_blocks.py --check                # static; runs nothing (exit 1: a problem)
    python scripts/docs_blocks.py --diff --only RE       # run the commands, show what would change

``--write`` runs each distinct command once, in the order of first appearance, then replaces
the bodies of its blocks; a command that fails leaves its blocks as they were (exit 1).
Several commands take an hour (the leaderboard, the frontiers): ``--only RE`` (a regular
expression searched in ``FILE: COMMAND``) picks some.

``--write --no-run`` runs nothing: the blocks of a file take that file as it is (after running
an hour-long command by hand, or in a clean checkout); blocks of standard output are left.

``--check`` runs no command, so it is cheap enough for the test suite. It fails (exit 1) when
a file's markers do not parse (an unclosed block, a block inside a block, an ``end`` without a
``begin``, an unknown clause), a block names an unknown command, a page in :data:`PAGES` does
not name its command, or a block whose ``file`` exists here differs from that file's (selected)
text. A block of standard output, or of a file not present here (a fresh clone has no
``results/``), is reported as not compared: ``--diff`` compares those by running them (it
writes no block, but the commands write their own outputs, and the drivers that rewrite their
own block — ``check_workspaces.py --tiers``, ``tune_ppc report``, the leaderboard — do so).

Nothing here imports the package: this tool is stdlib only.
"""

from __future__ import annotations

import argparse
import difflib
import os
import re
import shlex
import subprocess
import sys
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

#: The files whose blocks this tool manages (globs relative to the repository root).
FILES = ("README.md", "docs/*.md", "benchmarks/README.md", "models/README.md")

#: Pages written whole by a command (no markers: the command rewrites the file).
PAGES = {
    "docs/leaderboard.md": "python -m experiments.studies.leaderboard",
    "models/README.md": "python -m experiments.studies.leaderboard",
}

BEGIN = re.compile(r"^\s*<!--\s*begin:\s*(?P<spec>.*?)\s*-->\s*$")
END = re.compile(r"^\s*<!--\s*end\s*-->\s*$")
FENCE = re.compile(r"^\s*(```|~~~)")


class BlockError(ValueError):
    """A file's markers do not parse, or a block's specification is malformed."""


@dataclass(frozen=True)
class Block:
    """One generated block of a markdown file."""

    path: str  # relative to the root
    line: int  # 1-based line of the begin marker
    spec: str  # everything between "begin:" and "-->"
    command: str
    file: str | None  # take the body from this file (relative to the root) after the command
    select: tuple[str, int] | None  # ("table" | "list", N): keep the N-th of the text
    body: str  # the current body (the lines between the markers, joined)
    start: int  # 0-based index of the begin line
    stop: int  # 0-based index of the end line

    def label(self) -> str:
        return f"{self.path}:{self.line}"


def parse_spec(spec: str, where: str) -> tuple[str, str | None, tuple[str, int] | None]:
    """``COMMAND [; file PATH] [; table N | ; list N]`` -> (command, file, select)."""
    parts = [p.strip() for p in spec.split(";")]
    command, clauses = parts[0], parts[1:]
    if not command:
        raise BlockError(f"{where}: a begin marker names no command")
    file: str | None = None
    select: tuple[str, int] | None = None
    for clause in clauses:
        key, _, value = clause.partition(" ")
        value = value.strip()
        if key == "file" and value and file is None:
            file = value
        elif key in ("table", "list") and value.isdigit() and int(value) >= 1 and select is None:
            select = (key, int(value))
        else:
            raise BlockError(
                f"{where}: bad clause {clause!r} (expected 'file PATH', 'table N' or 'list N', "
                "each at most once)"
            )
    return command, file, select


def parse(text: str, path: str) -> list[Block]:
    """Every block of one file's ``text``; :class:`BlockError` names the file and line of a
    nested or unclosed block, a stray end marker or a malformed specification."""
    lines = text.split("\n")
    blocks: list[Block] = []
    open_at: int | None = None
    in_fence = False
    for i, line in enumerate(lines):
        if FENCE.match(line):
            in_fence = not in_fence
            continue
        if in_fence:
            continue
        begin = BEGIN.match(line)
        if begin:
            if open_at is not None:
                raise BlockError(
                    f"{path}:{i + 1}: a block begins inside the block of line {open_at + 1}"
                )
            open_at = i
        elif END.match(line):
            if open_at is None:
                raise BlockError(f"{path}:{i + 1}: an end marker without a begin marker")
            spec = BEGIN.match(lines[open_at]).group("spec")  # type: ignore[union-attr]
            command, file, select = parse_spec(spec, f"{path}:{open_at + 1}")
            blocks.append(
                Block(
                    path=path,
                    line=open_at + 1,
                    spec=spec,
                    command=command,
                    file=file,
                    select=select,
                    body="\n".join(lines[open_at + 1 : i]),
                    start=open_at,
                    stop=i,
                )
            )
            open_at = None
    if open_at is not None:
        raise BlockError(f"{path}:{open_at + 1}: the block is not closed (no <!-- end -->)")
    return blocks


def replace(text: str, blocks: Sequence[Block], bodies: dict[int, str]) -> str:
    """``text`` with the body of ``blocks[k]`` replaced by ``bodies[k]`` (blocks of this text,
    as :func:`parse` returned them); everything outside the bodies is kept as it was."""
    lines = text.split("\n")
    for k in sorted(bodies, key=lambda k: blocks[k].start, reverse=True):
        b = blocks[k]
        new = bodies[k].strip("\n")
        lines[b.start + 1 : b.stop] = new.split("\n") if new else []
    return "\n".join(lines)


def _runs(lines: list[str], starts: re.Pattern[str], continues: re.Pattern[str]) -> list[str]:
    runs: list[list[str]] = []
    current: list[str] | None = None
    for line in lines:
        if starts.match(line) or (current is not None and continues.match(line)):
            if current is None:
                current = []
                runs.append(current)
            current.append(line)
        else:
            current = None
    return ["\n".join(r) for r in runs]


def select_text(text: str, select: tuple[str, int] | None, where: str) -> str:
    """The part of a command's output a block keeps: all of it, the N-th table or list."""
    if select is None:
        return text.strip("\n")
    kind, n = select
    lines = text.split("\n")
    if kind == "table":
        parts = _runs(lines, re.compile(r"^\s*\|"), re.compile(r"^\s*\|"))
    else:
        parts = _runs(lines, re.compile(r"^[-*] "), re.compile(r"^\s+\S"))
    if len(parts) < n:
        raise BlockError(f"{where}: the output has {len(parts)} {kind}(s), not {n}")
    return parts[n - 1]


def console_scripts(root: Path) -> set[str]:
    pyproject = root / "pyproject.toml"
    if not pyproject.is_file():
        return set()
    data = tomllib.loads(pyproject.read_text())
    return set(data.get("project", {}).get("scripts", {}))


def unknown_reason(command: str, root: Path) -> str | None:
    """Why ``command`` is not a known command of the repository at ``root`` (None: known)."""
    try:
        argv = shlex.split(command)
    except ValueError as exc:
        return f"cannot split: {exc}"
    if not argv:
        return "empty command"
    if argv[0] in ("python", "python3"):
        if len(argv) >= 3 and argv[1] == "-m":
            parts = argv[2].split(".")
            base = root.joinpath(*parts)
            if base.with_suffix(".py").is_file() or (base / "__main__.py").is_file():
                return None
            return f"no module {argv[2]} in the repository"
        if len(argv) >= 2 and argv[1].endswith(".py"):
            return None if (root / argv[1]).is_file() else f"no file {argv[1]}"
        return "python must run '-m MODULE' or a .py file of the repository"
    if argv[0] == "bash":
        return None if len(argv) >= 2 and (root / argv[1]).is_file() else "no such bash script"
    if argv[0] in console_scripts(root):
        return None
    return f"{argv[0]} is not python, bash or a console script of pyproject.toml"


def doc_files(root: Path) -> list[Path]:
    found: dict[Path, None] = {}
    for pattern in FILES:
        for p in sorted(root.glob(pattern)):
            if p.is_file():
                found[p] = None
    return list(found)


def collect(root: Path) -> tuple[dict[str, list[Block]], list[str]]:
    """Blocks per file (relative path) and the parse errors."""
    blocks: dict[str, list[Block]] = {}
    errors: list[str] = []
    for p in doc_files(root):
        rel = p.relative_to(root).as_posix()
        try:
            blocks[rel] = parse(p.read_text(), rel)
        except BlockError as exc:
            errors.append(str(exc))
    return blocks, errors


def run_command(command: str, root: Path) -> str:
    """Run ``command`` at ``root`` (no shell); its standard output. Progress on standard error
    goes to ours. ``RuntimeError`` when it fails."""
    argv = shlex.split(command)
    if argv[0] in ("python", "python3"):
        argv[0] = sys.executable
    elif (Path(sys.executable).parent / argv[0]).is_file():  # a console script of this venv
        argv[0] = str(Path(sys.executable).parent / argv[0])
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run(argv, cwd=root, env=env, stdout=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{command!r} exited with status {done.returncode}")
    return done.stdout


def source_text(block: Block, stdout: str, root: Path) -> str:
    """What ``block``'s body should be, from its command's ``stdout`` (or its file)."""
    if block.file is not None:
        path = root / block.file
        if not path.is_file():
            raise BlockError(f"{block.label()}: {block.command!r} did not write {block.file}")
        return select_text(path.read_text(), block.select, block.label())
    return select_text(stdout, block.select, block.label())


def _matches(only: str | None, path: str, command: str) -> bool:
    return only is None or re.search(only, f"{path}: {command}") is not None


def cmd_list(root: Path) -> int:
    blocks, errors = collect(root)
    for bs in blocks.values():
        for b in bs:
            reason = unknown_reason(b.command, root)
            source = f"file {b.file}" if b.file else "stdout"
            if b.select:
                source += f", {b.select[0]} {b.select[1]}"
            known = "known" if reason is None else f"UNKNOWN ({reason})"
            print(f"{b.label()}\t{b.command}\t{source}\t{known}")
    for page, command in PAGES.items():
        if (root / page).is_file():
            reason = unknown_reason(command, root)
            known = "known" if reason is None else f"UNKNOWN ({reason})"
            print(f"{page}\t{command}\twhole page\t{known}")
    for e in errors:
        print(f"error: {e}", file=sys.stderr)
    return 1 if errors else 0


def cmd_check(root: Path) -> int:
    blocks, problems = collect(root)
    compared = uncompared = 0
    for bs in blocks.values():
        for b in bs:
            reason = unknown_reason(b.command, root)
            if reason is not None:
                problems.append(f"{b.label()}: unknown command {b.command!r}: {reason}")
                continue
            if b.file is None or not (root / b.file).is_file():
                uncompared += 1
                continue
            try:
                want = source_text(b, "", root)
            except BlockError as exc:
                problems.append(str(exc))
                continue
            compared += 1
            if want != b.body.strip("\n"):
                problems.append(
                    f"{b.label()}: the body differs from {b.file} "
                    f"(run: python scripts/docs_blocks.py --write --only '{re.escape(b.command)}')"
                )
    for page, command in PAGES.items():
        p = root / page
        if not p.is_file():
            continue
        if f"`{command}`" not in p.read_text():
            problems.append(f"{page}: a generated page that does not name `{command}`")
        if unknown_reason(command, root) is not None:
            problems.append(f"{page}: unknown command {command!r}")
    for problem in problems:
        print(f"error: {problem}", file=sys.stderr)
    n = sum(len(bs) for bs in blocks.values())
    print(
        f"{n} blocks in {len(blocks)} files: {compared} compared with their files, "
        f"{uncompared} not compared (standard output, or a file not present here); "
        f"{len(problems)} problem(s)"
    )
    return 1 if problems else 0


def regenerate(
    root: Path, only: str | None, *, write: bool, dry_run: bool = False, no_run: bool = False
) -> int:
    """``--write`` (``write=True``) or ``--diff``: run the selected blocks' commands once each
    (``no_run``: none; the blocks of a file take it as it is, the others are left)."""
    blocks, errors = collect(root)
    for e in errors:
        print(f"error: {e}", file=sys.stderr)
    if errors:
        return 1
    chosen = [b for bs in blocks.values() for b in bs if _matches(only, b.path, b.command)]
    pages = [(p, c) for p, c in PAGES.items() if _matches(only, p, c) and (root / p).is_file()]
    if no_run:
        chosen = [b for b in chosen if b.file is not None and (root / b.file).is_file()]
        pages = []
    commands = list(dict.fromkeys([b.command for b in chosen] + [c for _, c in pages]))
    status = 0
    for command in commands:
        reason = unknown_reason(command, root)
        if reason is not None:
            print(f"error: unknown command {command!r}: {reason}", file=sys.stderr)
            status = 1
    if status:
        return status
    if dry_run:
        for command in commands:
            print(command)
        return 0
    outputs: dict[str, str] = {}
    for command in commands if not no_run else []:
        print(f"== {command}", file=sys.stderr, flush=True)
        try:
            outputs[command] = run_command(command, root)
        except (RuntimeError, OSError) as exc:
            print(f"error: {exc}; its blocks are left as they were", file=sys.stderr)
            status = 1
    for path, bs in blocks.items():
        bodies: dict[int, str] = {}
        for k, b in enumerate(bs):
            if b in chosen and (no_run or b.command in outputs):
                try:
                    bodies[k] = source_text(b, outputs.get(b.command, ""), root)
                except BlockError as exc:
                    print(f"error: {exc}", file=sys.stderr)
                    status = 1
        if not bodies:
            continue
        # Re-read: the command may have rewritten this file itself (a driver that writes its
        # own block); the markers must still be where they were.
        text = (root / path).read_text()
        try:
            current = parse(text, path)
        except BlockError as exc:
            print(f"error: after the commands ran: {exc}", file=sys.stderr)
            status = 1
            continue
        if [b.spec for b in current] != [b.spec for b in bs]:
            print(f"error: {path}: its blocks changed while the commands ran", file=sys.stderr)
            status = 1
            continue
        new = replace(text, current, bodies)
        if new == text:
            continue
        if write:
            (root / path).write_text(new)
            print(f"wrote {path} ({len(bodies)} block(s))", file=sys.stderr)
        else:
            diff = difflib.unified_diff(
                text.splitlines(), new.splitlines(), f"a/{path}", f"b/{path}", lineterm=""
            )
            print("\n".join(diff))
            status = 1
    return status


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python scripts/docs_blocks.py", description=__doc__.splitlines()[0]
    )
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--list", action="store_true", help="every block: file:line, command")
    mode.add_argument("--write", action="store_true", help="run the commands, rewrite bodies")
    mode.add_argument("--check", action="store_true", help="static check; runs nothing")
    mode.add_argument("--diff", action="store_true", help="run the commands, show the changes")
    parser.add_argument("--only", metavar="RE", help="blocks whose 'FILE: COMMAND' matches RE")
    parser.add_argument("--dry-run", action="store_true", help="with --write: print the commands")
    parser.add_argument(
        "--no-run",
        action="store_true",
        help="with --write or --diff: run nothing; blocks of a file take the file as it is",
    )
    parser.add_argument("--root", type=Path, default=REPO, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    root: Path = args.root.resolve()
    if args.dry_run and not args.write:
        parser.error("--dry-run goes with --write")
    if args.no_run and not (args.write or args.diff):
        parser.error("--no-run goes with --write or --diff")
    if args.list:
        return cmd_list(root)
    if args.check:
        return cmd_check(root)
    return regenerate(root, args.only, write=args.write, dry_run=args.dry_run, no_run=args.no_run)


if __name__ == "__main__":
    sys.exit(main())
