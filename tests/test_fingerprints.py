"""Scenario fingerprints are stable: pinned for every shipped scenario and model, unchanged by a
field added with a default, and one per config whatever the number types it was built with.

A fingerprint (:mod:`platoon_env.scenarios.fingerprint`) identifies stored results and trained
models; a change of one silently splits a store and makes every shipped model refuse its
training env. The literal values below are the fingerprints as first recorded: a schema change
that alters one of them must be a deliberate, documented break.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from platoon_env.config import RobotConfig, field_key, is_identity
from platoon_env.scenarios import list_scenarios, load_config, scenario_source
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping
from platoon_env.scenarios.schema import config_to_mapping, parse_scenario
from training.train import TrainConfig, env_overrides

REPO = Path(__file__).resolve().parent.parent
MODELS = REPO / "models"

#: ``config_fingerprint(scenario_source(name).config)`` of every shipped scenario (a procedural
#: one: its template, as a procedural env resolves it).
SCENARIO_FINGERPRINTS = {
    "procedural_corridors_train": (
        "72d6961df81a1a430c8a5c17ae84acecb81607436b789967f7bea94461fd6a63"
    ),
    "procedural_easy_test": "ada3ddcdc41c6af80bf1581a05a93baed313b1d36ef8c035cd93ccc47d04115e",
    "procedural_easy_train": "7f4468f5a3760aa77bb290e9efea5e658f50329232b6aca37e51f5c7d44ea693",
    "procedural_formations_test": (
        "29b092f774456b6a90ef053672a7726718885dc61db3ae00ab4a1e70cbfb0d22"
    ),
    "procedural_formations_train": (
        "7339b91dab1a7bb0fa0632a1e541f3da731484a420df265b8bff8a4949d84b56"
    ),
    "procedural_formations_paper_test": (
        "9ddd4017da373e303e00f38408ad8c257b4f35a1bedd90318149a3a5df7087ac"
    ),
    "procedural_formations_paper_train": (
        "bb243f1b4029e0202f711966233feaba291efd0fee1e62b9825d1e4a9d688384"
    ),
    "procedural_formations_sharp_test": (
        "bfa8c4342b4c711ea3ca3c466f7d19bd9f230b55d6f390d5195933a309e0afef"
    ),
    "procedural_formations_sharp_train": (
        "ff92fa3fa6ea6a1048f6368492768118ed9db28272d6eeb8234ed469d6bb243f"
    ),
    "procedural_hard_test": "c160fad89472b718ad5f0cddd69420ac2935a8498518691aabadc053c8bbee5e",
    "procedural_hard_train": "b6d09085dcc97d1f7e5216c3b9c1ac05478ef9da3c46ad2f5f28a60118d5f140",
    "procedural_medium_test": "d2dd7406c26f74edf3df24ed0a067ad46a7a94886ce58f6adc5e7a583f525905",
    "procedural_medium_train": "f65c8665f4a69331cde8cda4b99391a7ed362a8866df64529a7ba1649d9e2694",
    "procedural_paper_test": "2ec44f51ba2ea2dee06712b1e37ffd1c7ca60147af9e7cbcb0d0290d32b82355",
    "procedural_paper_train": "4a03afa283ad726ef45436c4134d7629f36687d8b9385695b586bd48a7857355",
    "procedural_sharp_test": "1742250666ef18bfdc5d4c70ac36b284ab932efff36513423e4b1d9fb73b4d67",
    "procedural_sharp_train": "51ea651d13650166e8b17f9f01b5fcbe16a2821d85c00630b210963fb8a66c8d",
    "procedural_test": "434f9428545797413e008662a3b407792d564c031c9ce7e2130d4a10da1767c8",
    "procedural_train": "1057a32610d0530783e8ae7bd71e2732cd78ecd40fbdf609a04157486f97f90c",
    "study_a": "66e91d7dbf578c5bbbe68c335f78620595b90ae59053eaa0b4522ee9fedd45c2",
    "study_b": "e1c5a761834ef96dbf5b786e9fbb7950bacc97ccde68d19d5486365ed63ab1d8",
    "study_c": "8cb8e1a410c0c5783dc43f992aae63ade37497d048639b0b820d46d8777c9ed2",
}

#: The ``scenario_fingerprint`` recorded in every shipped ``model.json`` (by its folder under
#: ``models/``); None: not recorded (``models/legacy/ppo_procedural_s0`` says why).
_ARUCO_MEDIUM = "f4245de9689b0369e15ad162dc28048731b92a9eee7bdb846498465c3db9abbc"
MODEL_FINGERPRINTS: dict[str, str | None] = {
    **{f"{algo}_ta_aruco_s{seed}": _ARUCO_MEDIUM for algo in ("lag", "ppo") for seed in range(5)},
    "legacy/ppo_corridors_s0": "968215adc956401e25a3dfa186d9df24b798f4238b1f714ab99f8768c3714091",
    "legacy/ppo_procedural_s0": None,
    **{
        f"residual_ppc_s{seed}": (
            "c336d5c9ff82a56b0df8e47ba59a6c6151e94239d0c5aae3af0702a6e3c7a278"
        )
        for seed in range(5)
    },
    **{
        f"{config}_s{seed}": "5185ad39c27476504406bd51231793ec358984dd5981e6bac951aa08799440aa"
        for config in ("residual_filtered_aruco", "residual_drive_aruco")
        for seed in range(5)
    },
    # trained with the realism drawn per episode (--realism-preset ideal_to_beyond_aruco)
    **{
        f"{config}_s{seed}": "50e90b617867fee77fc42ec902d0dc884c129a0b0397dd619f4e5ba5ff79bcbc"
        for config in (
            "residual_drive_realism",
            "residual_filtered_realism",
            "lag_residual_drive_realism",
        )
        for seed in range(5)
    },
}


def _shipped_models() -> list[str]:
    found = [
        *MODELS.glob("*/model.json"),
        *MODELS.glob("legacy/*/model.json"),
    ]
    return sorted(str(p.parent.relative_to(MODELS)) for p in found)


def test_every_shipped_scenario_and_model_is_pinned() -> None:
    """A newly shipped scenario or model gets its fingerprint pinned here when it ships."""
    unpinned = sorted(set(list_scenarios()) - set(SCENARIO_FINGERPRINTS))
    assert not unpinned, f"pin the fingerprints of {unpinned} in SCENARIO_FINGERPRINTS"
    assert sorted(SCENARIO_FINGERPRINTS) == list_scenarios()
    unpinned = sorted(set(_shipped_models()) - set(MODEL_FINGERPRINTS))
    assert not unpinned, f"pin the recorded fingerprints of {unpinned} in MODEL_FINGERPRINTS"
    assert sorted(MODEL_FINGERPRINTS) == _shipped_models()


@pytest.mark.parametrize("name", sorted(SCENARIO_FINGERPRINTS))
def test_shipped_scenario_fingerprint(name: str) -> None:
    cfg = scenario_source(name).config
    assert cfg == load_config(name)
    assert config_fingerprint(cfg) == SCENARIO_FINGERPRINTS[name]
    assert config_fingerprint(parse_scenario(config_mapping(cfg))) == SCENARIO_FINGERPRINTS[name]


@pytest.mark.parametrize("run", sorted(MODEL_FINGERPRINTS))
def test_shipped_model_scenario_fingerprint(run: str) -> None:
    """The recorded fingerprint is the pinned one, and training's own resolution of the recorded
    run gives it again: its scenario with its env options (:func:`training.train.env_overrides`)
    resolved as ``make()`` resolves them (``env.source``, which training fingerprints), as does
    the recorded ``scenario_config``; that mapping is still the config's canonical form."""
    meta = json.loads((MODELS / run / "model.json").read_text())
    pinned = MODEL_FINGERPRINTS[run]
    assert meta["scenario_fingerprint"] == pinned
    if pinned is None:
        assert meta["scenario_config"] is None
        return
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    cfg = TrainConfig(**{k: v for k, v in meta["config"].items() if k in known})
    assert cfg.scenario == meta["scenario"]
    resolved = scenario_source(cfg.scenario, env_overrides(cfg)).config
    assert config_fingerprint(resolved) == pinned
    assert config_mapping(resolved) == meta["scenario_config"]
    assert config_fingerprint(parse_scenario(meta["scenario_config"])) == pinned


@dataclasses.dataclass(frozen=True)
class _RobotWithANewKnob(RobotConfig):
    """The robot block as it would be with a field added later, at its default."""

    new_knob: float = 0.0


def test_a_field_added_with_a_default_changes_no_fingerprint() -> None:
    cfg = load_config("study_c")
    grown = dataclasses.replace(cfg, robot=_RobotWithANewKnob(**dataclasses.asdict(cfg.robot)))
    assert config_to_mapping(grown) == config_to_mapping(cfg)
    assert config_fingerprint(grown) == config_fingerprint(cfg)
    # ... until a scenario sets it: then it is part of that scenario's identity
    turned = dataclasses.replace(grown, robot=dataclasses.replace(grown.robot, new_knob=0.5))
    assert config_to_mapping(turned)["robot"]["new_knob"] == 0.5
    assert config_fingerprint(turned) != config_fingerprint(cfg)


def _check_defaults(section: Any, mapping: dict[str, Any], where: str) -> int:
    """Every field of ``section`` at its default is in ``mapping`` exactly when it is
    identity-bearing (recursively); returns how many fields were at their default."""
    count = 0
    for f in dataclasses.fields(section):
        value, key = getattr(section, f.name), field_key(f)
        if f.default is not dataclasses.MISSING and value == f.default:
            assert (key in mapping) == is_identity(f), f"{where}.{key}"
            count += 1
        if key in mapping and dataclasses.is_dataclass(value):
            count += _check_defaults(value, mapping[key], f"{where}.{key}")
    return count


@pytest.mark.parametrize("name", ["study_a", "study_b", "procedural_train"])
def test_only_identity_bearing_fields_are_written_at_their_defaults(name: str) -> None:
    cfg = load_config(name)
    assert _check_defaults(cfg, config_to_mapping(cfg), "scenario") > 0


def test_ints_given_for_floats_are_one_config() -> None:
    """``robot={"accel_max": 1}`` and ``accel_max=1.0`` are one scenario, however the config was
    built: through the overrides (parsed) or in code (an int kept in the dataclass)."""
    base = load_config("study_a")
    as_float = scenario_source("study_a", {"robot": {"accel_max": 1.0}}).config
    assert config_fingerprint(scenario_source("study_a", {"robot": {"accel_max": 1}}).config) == (
        config_fingerprint(as_float)
    )
    in_code = dataclasses.replace(base, robot=dataclasses.replace(base.robot, accel_max=1))
    assert in_code == as_float
    assert config_fingerprint(in_code) == config_fingerprint(as_float)
    assert config_to_mapping(in_code)["robot"]["accel_max"] == 1.0
    assert isinstance(config_to_mapping(in_code)["robot"]["accel_max"], float)
    # nested floats too (a path of ints), and an int field stays an int
    path = ((0, 0), (1, 2))
    leader = dataclasses.replace(base.leader, path=path, settle_time=3)
    ints = dataclasses.replace(base, leader=leader, followers=2)
    plain = config_to_mapping(ints)
    assert plain["leader"]["path"] == [[0.0, 0.0], [1.0, 2.0]]
    assert all(isinstance(v, float) for p in plain["leader"]["path"] for v in p)
    assert isinstance(plain["leader"]["settle_time"], float)
    assert plain["followers"] == 2 and isinstance(plain["followers"], int)
    floats = dataclasses.replace(
        base,
        leader=dataclasses.replace(leader, path=((0.0, 0.0), (1.0, 2.0)), settle_time=3.0),
        followers=2,
    )
    assert config_fingerprint(ints) == config_fingerprint(floats)
