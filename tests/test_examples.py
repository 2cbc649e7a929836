"""The scripts of examples/, each run as a user runs it (``python examples/X.py ...``, a
subprocess) on tiny settings, checking what it prints and writes.

``test_rllib_example`` needs Ray: it runs in the RLlib job (``scripts/test_rllib.sh``), and is
skipped in the main venv, where ``test_rllib_example_without_ray`` checks the script's message.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from experiments.published import load_published, write_published
from experiments.studies.evaluate import main as evaluate_main

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"


def run_example(script: str, *args: str, cwd: Path = REPO, timeout: float = 300) -> str:
    """Run ``examples/<script>`` with ``args`` from ``cwd``; require exit status 0 and return
    its standard output."""
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}  # never join a cluster
    env["MPLBACKEND"] = "Agg"
    res = subprocess.run(
        [sys.executable, str(EXAMPLES / script), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert res.returncode == 0, f"{script} exited {res.returncode}:\n{res.stderr[-3000:]}"
    return res.stdout


def test_examples_readme_lists_every_script() -> None:
    readme = (EXAMPLES / "README.md").read_text()
    scripts = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert len(scripts) == 5
    for name in scripts:
        assert f"examples/{name}" in readme, name


def test_ppc_rollout() -> None:
    out = run_example("ppc_rollout.py")  # a whole study C episode: about a second
    assert "scenario study_c, seed 0: 2 followers" in out
    assert "success: True" in out and "first violation: none" in out
    cut = run_example("ppc_rollout.py", "--scenario", "study_b", "--seed", "2", "--max-steps", "50")
    assert "scenario study_b, seed 2: 2 followers" in cut and "steps: 50 (0.50 s" in cut
    assert "success: False" in cut and "stopped before the leader reached" in cut


def test_custom_scenario(tmp_path: Path) -> None:
    out = run_example("custom_scenario.py", cwd=tmp_path)  # corridor.yaml beside the script
    assert "scenario 'corridor'" in out and "2 obstacles, 2 followers" in out
    assert "success: True" in out and "first violation: none" in out
    # an edited copy: a leader far too fast for its followers
    scenario = yaml.safe_load((EXAMPLES / "corridor.yaml").read_text())
    scenario["name"] = "corridor_fast"
    scenario["leader"]["speed"] = 4.0
    path = tmp_path / "fast.yaml"
    path.write_text(yaml.safe_dump(scenario))
    fast = run_example("custom_scenario.py", "--scenario", str(path), "--max-steps", "2000")
    assert "scenario 'corridor_fast'" in fast and "success: False" in fast
    assert re.search(r"^first violation: (?!none)\w+$", fast, re.MULTILINE), fast


def test_train_small(tmp_path: Path) -> None:
    run = tmp_path / "run"
    argv = ["--timesteps", "512", "--out", str(run), "--max-steps", "50"]
    out = run_example("train_small.py", *argv)
    assert f"trained 512 transitions: {run / 'model.zip'}" in out
    assert re.search(r"evaluation on study_c at 0\.05 s: \d+ steps, success False", out), out
    meta = json.loads((run / "model.json").read_text())
    assert meta["trainer"] == "training.fast_ppo" and (run / "progress.csv").is_file()


def test_my_policy_ranks_against_published_rows(tmp_path: Path) -> None:
    """A tiny published file (PPC and last-seen on study C, 2 episodes) made as the
    maintainers' --publish makes the shipped one; the script ranks MyPolicy against it, run
    from another folder (``my_policy`` imports from the script's own)."""
    base = tmp_path / "published_run"
    argv = ["--policy", "ppc", "--policy", "last_seen", "--scenario", "study_c"]
    assert evaluate_main([*argv, "--episodes", "2", "--no-plots", "--workers", "1", "--out",
                          str(base)]) == 0  # fmt: skip
    with (base / "results.csv").open() as f:
        published = write_published(list(csv.DictReader(f)), tmp_path / "pub.json")
    assert sorted(load_published(published).entries()) == ["last_seen", "ppc"]

    out_dir = tmp_path / "mine"
    out = run_example("my_policy.py", "--published", str(published), "--out", str(out_dir),
                      cwd=tmp_path)  # fmt: skip
    assert f"--compare-to {published}" in out and "running --policy ppc" not in out
    assert re.search(r"^mine: rank \d+ against the published benchmark", out, re.MULTILINE), out
    assert (out_dir / "comparison.md").is_file()
    with (out_dir / "results.csv").open() as f:
        assert {r["policy"] for r in csv.DictReader(f)} == {"mine"}  # the laws did not run


def test_my_policy_falls_back_to_ppc_beside_it(tmp_path: Path) -> None:
    out_dir = tmp_path / "mine"
    missing = tmp_path / "no_such_file.json"
    argv = ["--published", str(missing), "--episodes", "1", "--max-steps", "50"]
    out = run_example("my_policy.py", *argv, "--out", str(out_dir), cwd=tmp_path)
    assert "cannot compare to" in out and "running --policy ppc beside mine instead" in out
    assert "| study_c | mine |" in out and "| study_c | ppc |" in out
    assert not (out_dir / "comparison.md").exists()


def test_rllib_example_without_ray() -> None:
    if importlib.util.find_spec("ray") is not None:
        pytest.skip("ray is installed: test_rllib_example runs the script")
    out = run_example("rllib_local_cluster.py")
    assert out.startswith("skipped: ray is not installed (pip install -e '.[rllib]'")


def test_rllib_example(tmp_path: Path) -> None:
    """Run in the RLlib job (scripts/test_rllib.sh): one env runner, two PPO iterations."""
    pytest.importorskip("ray")
    pytest.importorskip("ray.rllib")
    run = tmp_path / "run"
    argv = ["--env-runners", "1", "--timesteps", "256", "--max-steps", "50", "--out", str(run)]
    out = run_example("rllib_local_cluster.py", *argv, timeout=900)
    assert re.search(r"^trained \d+ transitions with 1 env runner\(s\)", out, re.MULTILINE), out
    assert f"model {run / 'model.zip'}:" in out and "steps on study_c" in out
    meta = json.loads((run / "model.json").read_text())
    assert meta["engine"] == "rllib" and meta["timesteps"] >= 256
