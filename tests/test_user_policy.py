"""A researcher's own policy class on the command line (``--policy NAME=module:Class``) and the
default scope of ``platoon-evaluate`` (a configuration's training seeds share the episodes)."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from experiments.policies import USER, PolicySpec, UserPolicyError, load_user_class
from experiments.published import (
    FORMAT,
    PublishedError,
    load_published,
    mcnemar_exact,
    write_published,
)
from experiments.studies.evaluate import episode_seeds, main

POLICY = '''
import numpy as np


class Straight:
    """Drive at a constant speed, turning towards the predecessor's bearing."""

    def __init__(self, env, speed=0.3):
        self.speed = speed

    def reset(self, seed=None):
        pass

    def act(self, observations):
        return {
            a: np.array([self.speed, 2.0 * float(o[1])], dtype=np.float32)
            for a, o in observations.items()
        }


class NoAct:
    def reset(self, seed=None):
        pass


VALUE = 3
'''


@pytest.fixture
def user_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A fresh module ``user_policy_<n>`` in the working directory (as a user's file)."""
    name = f"user_policy_{abs(hash(tmp_path)) % 10**8}"
    (tmp_path / f"{name}.py").write_text(POLICY)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    yield name
    sys.modules.pop(name, None)


def test_a_user_class_is_a_policy_spec(user_module: str) -> None:
    spec = PolicySpec.parse(f"mine={user_module}:Straight")
    assert (spec.name, spec.kind, spec.factory) == ("mine", USER, f"{user_module}:Straight")
    assert spec.description()["source_sha256"]
    assert PolicySpec.parse(f"{user_module}:Straight").name == "Straight"
    faster = PolicySpec.user(f"{user_module}:Straight", speed=0.5)
    assert faster.fingerprint() != spec.fingerprint()


def test_an_edited_module_is_another_policy(user_module: str, tmp_path: Path) -> None:
    before = PolicySpec.parse(f"{user_module}:Straight").fingerprint()
    path = tmp_path / f"{user_module}.py"
    path.write_text(POLICY.replace("2.0 * float", "2.5 * float"))
    after = PolicySpec.parse(f"{user_module}:Straight").fingerprint()
    assert before != after


@pytest.mark.parametrize(
    ("attr", "match"),
    [
        ("NoAct", "does not implement the Policy protocol: no act"),
        ("Missing", "has no attribute 'Missing'"),
        ("VALUE", "is not a class"),
    ],
)
def test_what_is_not_a_policy_is_refused(user_module: str, attr: str, match: str) -> None:
    with pytest.raises(UserPolicyError, match=match):
        load_user_class(f"{user_module}:{attr}")
    with pytest.raises(argparse.ArgumentTypeError, match=match):
        PolicySpec.parse(f"x={user_module}:{attr}")


def test_a_missing_module_names_the_import_path(user_module: str) -> None:
    with pytest.raises(UserPolicyError, match="no module 'no_such_module_here' on the import"):
        load_user_class("no_such_module_here:Policy")


def test_evaluate_runs_a_user_policy_beside_a_law(
    user_module: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = ["--policy", f"mine={user_module}:Straight", "--policy", "ppc"]
    argv += ["--scenario", "study_c", "--episodes", "2", "--no-plots", "--workers", "1"]
    argv += ["--set", "max_episode_steps=50", "--out", str(out)]
    assert main(argv) == 0
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["policy"], r["seed"]) for r in rows) == [
        ("mine", "0"),
        ("mine", "1"),
        ("ppc", "0"),
        ("ppc", "1"),
    ]
    with pytest.raises(SystemExit):
        main(["--policy", f"{user_module}:NoAct", "--out", str(out)])
    assert "no act" in capsys.readouterr().err


def test_a_configurations_seeds_share_the_episodes() -> None:
    configs = {
        "ppc": ("ppc", None),
        "a_s2": ("a", 2),
        "a_s0": ("a", 0),
        "a_s1": ("a", 1),
        "b": ("b", None),
    }
    played = episode_seeds(configs, range(10, 20))
    assert played["ppc"] == range(10, 20) and played["b"] == range(10, 20)
    assert [list(played[f"a_s{k}"]) for k in range(3)] == [
        [10, 11, 12],
        [13, 14, 15],
        [16, 17, 18, 19],
    ]
    every = episode_seeds(configs, range(10, 20), every_seed=True)
    assert all(every[name] == range(10, 20) for name in configs)
    few = episode_seeds(configs, range(2))
    assert [list(few[f"a_s{k}"]) for k in range(3)] == [[0], [1], [0]]


def test_mcnemar_exact() -> None:
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(5, 0) == pytest.approx(2 / 32)
    assert mcnemar_exact(0, 10) == pytest.approx(2 / 1024)
    assert mcnemar_exact(3, 3) == 1.0
    with pytest.raises(ValueError):
        mcnemar_exact(-1, 2)


def test_a_user_policy_ranks_against_published_rows(
    user_module: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Rows of two laws written as a published file; the user's policy alone is run on their
    scenario and seeds and ranked, without the laws running again; a file of other code, and
    options the rows do not have, are refused."""
    base = ["--scenario", "study_c", "--episodes", "3", "--no-plots", "--workers", "1"]
    assert (
        main(["--policy", "ppc", "--policy", "last_seen", *base, "--out", str(tmp_path / "a")]) == 0
    )
    with (tmp_path / "a" / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    published = write_published(rows, tmp_path / "pub.json", {"commit": "test"})
    assert sorted(load_published(published).entries()) == ["last_seen", "ppc"]

    out = tmp_path / "b"
    argv = ["--policy", f"mine={user_module}:Straight", "--compare-to", str(published)]
    capsys.readouterr()
    assert main([*argv, "--no-plots", "--workers", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "mine: rank 2 against the published benchmark" in printed  # below ppc, tied last
    with (out / "results.csv").open() as f:
        ran = list(csv.DictReader(f))
    assert {r["policy"] for r in ran} == {"mine"} and len(ran) == 3  # the laws did not run
    text = (out / "comparison.md").read_text()
    assert "| study_c | ppc | 0/3" in text and "| 1 | ppc | 1.000 |" in text

    document = json.loads(published.read_text())
    document["code"] = "0" * 64
    other = tmp_path / "other.json"
    other.write_text(json.dumps(document))
    with pytest.raises(SystemExit):
        main([*argv[:2], "--compare-to", str(other), "--out", str(tmp_path / "c")])
    assert "made by other code" in capsys.readouterr().err
    for extra in (["--sensor-profile", "aruco"], ["--scenario", "study_a"]):
        with pytest.raises(SystemExit):
            main([*argv, *extra, "--out", str(tmp_path / "d")])
    with pytest.raises(SystemExit):
        main(["--compare-to", str(published), "--out", str(tmp_path / "e")])
    assert "give --policy" in capsys.readouterr().err
    assert not (tmp_path / "c").exists() and not (tmp_path / "e").exists()


def test_malformed_published_files_are_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    for text, match in (
        ("not json", "not a readable"),
        ('{"format": "x"}', "not a published-rows file"),
        (json.dumps({"format": FORMAT, "version": 1, "rows": []}), "non-empty list"),
        (json.dumps({"format": FORMAT, "version": 1, "rows": [{"seed": 1}]}), "row 0 lacks"),
    ):
        bad.write_text(text)
        with pytest.raises(PublishedError, match=match):
            load_published(bad)
