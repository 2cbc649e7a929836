"""TorchRL's wrappers on the env (issue 25): ``PettingZooWrapper`` on the numeric info view and
``GymEnv`` on the Gymnasium ids, each passing ``check_env_specs`` (docs/ecosystem.md).

Skipped unless TorchRL is installed: ``bash scripts/test_torchrl.sh`` makes ``.venv-torchrl``
(the ``torchrl`` extra) and runs this file in it. The BenchMARL recipe's test also needs
BenchMARL, which pins an older TorchRL (``torchrl<0.12``): it runs in a BenchMARL venv
(docs/ecosystem.md says how to make one), and is skipped in ``.venv-torchrl``.
"""

from __future__ import annotations

import importlib
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torchrl")

import torch
from torchrl.data import Unbounded
from torchrl.envs import GymEnv, PettingZooWrapper
from torchrl.envs.libs.gym import default_info_dict_reader
from torchrl.envs.utils import check_env_specs

import platoon_env
from platoon_env.violations import VIOLATION_CAUSES, VIOLATION_CODE_NAMES, violation_code

STUDY_C_ID = "platoon_env/SingleFollower-StudyC-v1"


def _wrapped(scenario: str = "study_c", **kwargs: Any) -> PettingZooWrapper:
    return PettingZooWrapper(
        env=platoon_env.make(scenario, info_view="numeric", **kwargs), return_state=True, seed=0
    )


@pytest.mark.parametrize("diagnostics", [True, False])
@pytest.mark.parametrize("scenario", ["study_a", "study_c"])
def test_pettingzoo_wrapper_passes_check_env_specs(scenario: str, diagnostics: bool) -> None:
    env = _wrapped(scenario, diagnostics=diagnostics)
    check_env_specs(env, seed=0)
    group = env.group_map["follower"]
    assert group == platoon_env.make(scenario).possible_agents
    info_keys = set(env.observation_spec["follower", "info"].keys())
    assert {"violation", "violation_mask", "cost"} <= info_keys
    assert ("d" in info_keys) == diagnostics


def test_the_rich_view_is_what_torchrl_cannot_read() -> None:
    # The reason for the numeric view: the default infos hold None, names and a nested dict.
    with pytest.raises((RuntimeError, TypeError, ValueError)):
        PettingZooWrapper(env=platoon_env.make("study_c"))


def test_rollout_reports_the_violation_code_that_ended_the_episode() -> None:
    env = _wrapped("study_c")

    def spin(td: Any) -> Any:  # every follower turns on the spot: out of its camera's FOV
        action = torch.zeros(env.full_action_spec["follower", "action"].shape)
        action[..., 1] = 2.0
        td.set(("follower", "action"), action)
        return td

    td = env.rollout(400, policy=spin, break_when_any_done=True)
    done = td["next", "done"].squeeze(-1)
    assert bool(done[-1]) and not bool(done[:-1].any())
    codes = td["next", "follower", "info", "violation"][-1]
    assert any(int(c) == violation_code("out_of_fov") for c in codes)
    assert bool(td["next", "follower", "terminated"][-1].all())
    # Before the last step: no violation, cost 0.
    assert not td["next", "follower", "info", "violation"][:-1].any()
    assert not td["next", "follower", "info", "cost"][:-1].any()
    assert "state" in td.keys()


def test_random_rollouts_match_the_env_step_by_step() -> None:
    env = _wrapped("study_c")
    # The wrapper's reset passes its seed on (the start's perturbation, the leader's speed).
    start = env.reset(seed=5)
    td = env.rollout(200, tensordict=start, auto_reset=False, break_when_any_done=True)
    mirror = platoon_env.make("study_c", info_view="numeric")
    _, infos = mirror.reset(seed=5)
    actions = td["follower", "action"].numpy()
    for t in range(td.shape[0]):
        *_, infos = mirror.step(
            {a: actions[t, i].astype(np.float64) for i, a in enumerate(mirror.possible_agents)}
        )
        for i, agent in enumerate(mirror.possible_agents):
            for key, value in infos[agent].items():
                got = float(td["next", "follower", "info", key][t, i])
                assert got == pytest.approx(value, rel=1e-6, abs=1e-6), (t, agent, key)
    final = [int(c) for c in td["next", "follower", "info", "violation"][-1]]
    assert all(0 <= c < len(VIOLATION_CODE_NAMES) for c in final)
    if bool(td["next", "follower", "terminated"][-1].any()):
        assert any(VIOLATION_CODE_NAMES[c] in VIOLATION_CAUSES for c in final)


def test_gymenv_builds_the_gymnasium_id_and_passes_check_env_specs() -> None:
    # GymEnv passes frameskip=...: make() must word the refusal as Python does for GymEnv to
    # drop it (and frame-skip in the wrapper instead).
    env = GymEnv(STUDY_C_ID)
    check_env_specs(env, seed=0)
    assert env.observation_spec["observation"].shape == (7,)


def test_gymenv_reads_the_numeric_infos() -> None:
    # Without keys, the reader takes every key and its dtype from the reset's info.
    env = GymEnv(STUDY_C_ID, info_view="numeric")
    env.set_info_dict_reader(default_info_dict_reader())
    check_env_specs(env, seed=0)
    td = env.rollout(50)
    assert td["next", "violation"].dtype == torch.int64
    assert td["next", "d"].dtype == torch.float64
    assert {"violation_mask", "cost", "visible", "reward_distance"} <= set(td["next"].keys())
    # A violation ends the episode: every step but the last has code 0 and the camera's d.
    codes = td["next", "violation"]
    assert not codes[:-1].any()
    d = td["next", "d"][:-1]
    assert bool(((d > 0) & (d < 1.5)).all())


def test_gymenv_reads_chosen_numeric_infos_with_their_specs() -> None:
    # With keys, TorchRL assumes float32 unless told: the integer entries need their spec.
    env = GymEnv(STUDY_C_ID, info_view="numeric")
    specs = {
        "violation": Unbounded((), dtype=torch.int64),
        "cost": Unbounded((), dtype=torch.int64),
        "d": Unbounded((), dtype=torch.float64),
    }
    env.set_info_dict_reader(default_info_dict_reader(list(specs), spec=specs))
    check_env_specs(env, seed=0)
    assert set(env.rollout(5)["next"].keys()) >= set(specs)


def test_gymenv_frame_skip_is_done_by_the_wrapper() -> None:
    env = GymEnv(STUDY_C_ID, frame_skip=2)
    assert env.wrapper_frame_skip == 2
    check_env_specs(env, seed=0)


def test_the_benchmarl_recipe_in_the_docs_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("benchmarl")
    text = (Path(__file__).parents[1] / "docs" / "ecosystem.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    recipe = next(block for block in blocks if "class PlatoonClass" in block)
    # A module file, as a user saves it: BenchMARL pickles the task class by its module.
    (tmp_path / "benchmarl_recipe.py").write_text(recipe, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("benchmarl_recipe")
    out = tmp_path / "runs"
    out.mkdir()
    module.run("mappo", str(out), frames=1_000)  # one collection, one update
    (written,) = out.glob("*/*.json")  # the marl-eval file
    results = json.loads(written.read_text())
    assert list(results) == ["platoon"] and list(results["platoon"]) == ["study_c"]
    assert "seed_0" in results["platoon"]["study_c"]["mappo"]
