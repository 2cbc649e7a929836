"""The versioning policy (docs/versioning.md): every Gymnasium id carries the current env
version, an older id is refused naming the current one, the history starts with the current
version, and the package's version is the same in every place that states it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import gymnasium
import pytest

import platoon_env
from platoon_env.gym_env import ENV_VERSION, GYM_IDS, VERSION_HISTORY

ROOT = Path(__file__).resolve().parents[1]


def test_every_id_carries_the_current_version() -> None:
    assert GYM_IDS and all(i.endswith(f"-{ENV_VERSION}") for i in GYM_IDS)
    assert VERSION_HISTORY[0][0] == ENV_VERSION
    assert VERSION_HISTORY[0][1] == platoon_env.__version__


@pytest.mark.filterwarnings("ignore:.*out of date:DeprecationWarning")
def test_an_older_id_is_refused_naming_the_current_one() -> None:
    old = int(ENV_VERSION[1:]) - 1
    if old < 0:
        pytest.skip("no older version")
    current = "platoon_env/SingleFollower-StudyC-" + ENV_VERSION
    with pytest.raises(gymnasium.error.DeprecatedEnv, match=re.escape(current)):
        gymnasium.make(f"platoon_env/SingleFollower-StudyC-v{old}")


def test_the_package_version_is_stated_once_everywhere() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["version"] == platoon_env.__version__
    cff = (ROOT / "CITATION.cff").read_text()
    assert f"version: {platoon_env.__version__}" in cff
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert f"## {platoon_env.__version__}" in changelog


def test_the_module_id_form_registers_the_ids_itself() -> None:
    """CleanRL's and RL Zoo's ``--env-id platoon_env:platoon_env/...``: Gymnasium imports the
    module before it looks the id up (checked in a fresh process, where nothing imported
    platoon_env before)."""
    code = (
        "import gymnasium\n"
        f"env = gymnasium.make('platoon_env:platoon_env/SingleFollower-StudyC-{ENV_VERSION}')\n"
        "print(env.spec.id, env.spec.max_episode_steps)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
        env={**os.environ, "PLATOON_ENV_QUIET": "1"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"platoon_env/SingleFollower-StudyC-{ENV_VERSION} ")
