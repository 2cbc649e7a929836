"""The console commands on an install without the optional extras (experiments/studies/launch.py): a
command that needs a missing extra says so in one line with exit code 2, and
``platoon-evaluate`` runs the analytic laws with none of them.

Each case runs the command's entry point in a fresh interpreter (``python -S``, no site
directories) whose path holds the checkout and a folder of links to every entry of this venv's
site-packages but the extras' modules: as on a plain ``pip install platoon-env``, they are not
found (``import`` raises ``ModuleNotFoundError``, ``importlib.util.find_spec`` is None).
"""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TRAIN = ("torch", "stable_baselines3")
PLOT = ("matplotlib", "imageio")
STATS = ("rliable", "pandas")


def _site_without(blocked: tuple[str, ...], root: Path) -> Path:
    """A folder of links to the entries of this venv's site-packages, those of ``blocked``'s
    distributions left out (the package, its ``.libs`` and metadata)."""
    site = root / ("site-" + "-".join(blocked))
    if site.is_dir():
        return site
    site.mkdir()
    prefixes = tuple(name.lower() for name in blocked)
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        stem = entry.name.lower().replace("-", "_").split(".")[0]
        if stem in prefixes or stem.startswith(tuple(p + "_" for p in prefixes)):
            continue
        (site / entry.name).symlink_to(entry)
    return site


def _run(
    entry: str, argv: list[str], blocked: tuple[str, ...], cwd: Path
) -> subprocess.CompletedProcess[str]:
    site = _site_without(blocked, cwd.parent)
    code = textwrap.dedent(
        f"""
        import sys
        from experiments.studies import launch
        sys.argv = {["platoon-" + entry, *argv]!r}
        raise SystemExit(launch.{entry}())
        """
    )
    return subprocess.run(
        [sys.executable, "-S", "-c", code],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
        env={"PYTHONPATH": f"{REPO}:{site}", "MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"},
    )


@pytest.mark.parametrize(
    ("entry", "argv", "blocked", "extra"),
    [
        ("train", ["--help"], TRAIN, "[train]"),
        ("leaderboard", ["--help"], TRAIN, "[train]"),
        ("leaderboard", ["--help"], STATS, "[stats]"),
        ("leaderboard", ["--help"], PLOT, "[plot]"),
        ("sweep", ["--config", "residual_ppc"], TRAIN, "[train]"),
        ("sweep", ["--ship", "--runs", "r", "--models", "m"], TRAIN, "[train]"),
        ("sweep", ["--curves", "c.png", "--config", "residual_ppc"], PLOT, "[plot]"),
    ],
)
def test_a_missing_extra_is_one_line_naming_it(
    entry: str, argv: list[str], blocked: tuple[str, ...], extra: str, tmp_path: Path
) -> None:
    done = _run(entry, argv, blocked, tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1, done.stderr
    assert f"the optional {extra} extra" in errors[0]
    assert f"platoon-env{extra}" in errors[0]  # the install command
    assert not any(tmp_path.iterdir())  # nothing was started


def test_sweep_help_and_list_need_no_extra(tmp_path: Path) -> None:
    done = _run("sweep", ["--help"], TRAIN + PLOT + STATS, tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: platoon-sweep")
    done = _run("sweep", ["--list"], TRAIN + PLOT + STATS, tmp_path)
    assert done.returncode == 0, done.stderr
    assert "residual_ppc:" in done.stdout


def test_evaluate_runs_the_analytic_laws_without_any_extra(tmp_path: Path) -> None:
    """PPC alone on a plain install: episodes, tables and CSV; the plots are skipped with a
    note naming the [plot] extra; nothing of [train] is imported (it would raise)."""
    out = tmp_path / "out"
    argv = ["--policy", "ppc", "--scenario", "study_c", "--episodes", "1"]
    argv += ["--workers", "1", "--out", str(out)]
    done = _run("evaluate", argv, TRAIN + PLOT + STATS, tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    notes = [line for line in done.stderr.splitlines() if "[plot] extra" in line]
    assert len(notes) == 1 and notes[0].startswith("note: "), done.stderr
    assert "no plots (the [plot] extra is not installed)" in done.stdout
    rows = (out / "results.csv").read_text().splitlines()
    assert len(rows) == 2 and ",ppc," in rows[1]
    assert not (out / "plots").exists()


def test_evaluate_refuses_a_model_without_train(tmp_path: Path) -> None:
    model = REPO / "models" / "residual_ppc_s0" / "model.zip"
    argv = ["--policy", str(model), "--scenario", "study_c", "--out", str(tmp_path / "o")]
    done = _run("evaluate", argv, TRAIN, tmp_path)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert "the optional [train] extra" in done.stderr.splitlines()[-1]
