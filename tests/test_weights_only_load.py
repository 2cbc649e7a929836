"""Loading a model runs no code from it (issue 44, items 1 and 4): ``LearnedPolicy.load`` reads
an SB3 zip's weights only (``policy.pth`` with ``torch.load(weights_only=True)``, the ``data``
entry as JSON whose cloudpickled fields are never decoded), and an exported RLlib actor's array
shapes from their ``.npy`` headers before any data. ``docs/security.md`` lists these tests."""

from __future__ import annotations

import base64
import inspect
import io
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import cloudpickle
import torch
from gymnasium import spaces
from stable_baselines3 import PPO, SAC
from torch import nn

from platoon_env.scenarios.fingerprint import file_sha256
from training import LearnedPolicy
from training.forward import sb3_forward
from training.policies import (
    _SB3_POLICIES,
    MAX_LAYER_UNITS,
    MAX_PARAMETERS,
    MLPActor,
    SB3Actor,
    save_exported_policy,
    save_model,
)

REPO = Path(__file__).resolve().parents[1]
ACTION_RANGE = {"u_low": -0.5, "u_high": 1.5, "omega_high": 2.0}
META = {
    "algo": "ppo",
    "control_period": 0.05,
    "observation_normalization": None,
    "action_range": ACTION_RANGE,
}

pytestmark = pytest.mark.usefixtures("one_torch_thread")


class BoxEnv(gym.Env[np.ndarray, np.ndarray]):
    """A do-nothing env with the 7-vector observation and the normalised 2-value action."""

    observation_space = spaces.Box(-1.0, 1.0, shape=(7,), dtype=np.float32)
    action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        return np.zeros(7, dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        return np.zeros(7, dtype=np.float32), 0.0, False, True, {}


class _WritesMarker:
    """Unpickled, it writes ``marker`` (what a crafted model would do, harmlessly)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return (Path.write_text, (self.marker, "the payload ran"))


def _ppo(**policy_kwargs: Any) -> PPO:
    model = PPO(
        "MlpPolicy",
        BoxEnv(),
        n_steps=16,
        batch_size=16,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [16, 16], **policy_kwargs},
    )
    with torch.no_grad():  # means outside [-1, 1]: the clip matters
        model.policy.action_net.weight.mul_(100.0)
    return model


def _saved(model: Any, folder: Path, **meta: Any) -> Path:
    return save_model(model, folder / "model.zip", {**META, **meta})


def _rewrite(zip_path: Path, entries: dict[str, bytes]) -> None:
    """Replace entries of the zip (and the hash its ``model.json`` records, so that the hash
    check passes: the crafted pair is consistent, as an attacker's would be)."""
    with zipfile.ZipFile(zip_path) as archive:
        kept = {n: archive.read(n) for n in archive.namelist() if n not in entries}
    with zipfile.ZipFile(zip_path, "w") as archive:
        for name, raw in {**kept, **entries}.items():
            archive.writestr(name, raw)
    meta_file = zip_path.with_suffix(".json")
    meta = json.loads(meta_file.read_text())
    meta["zip_sha256"] = file_sha256(zip_path)
    meta_file.write_text(json.dumps(meta))


def _obs(n: int, size: int = 7, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(scale=3.0, size=(n, size)).astype(np.float32)


# ------------------------------------------------------------------------------------------------
# SB3 zips: weights only
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("field", ["surprise", "policy_class"])
def test_a_pickled_payload_in_the_data_entry_never_runs(tmp_path: Path, field: str) -> None:
    """A model.zip whose ``data`` entry carries a cloudpickled payload (in a field of its own,
    or as the policy class SB3 unpickles) loads and acts through ``LearnedPolicy.load`` without
    the payload running, and acts as the clean model did; ``load_pickled`` (SB3's loader) does
    run it: the payload is live, only the weights-only path never touches it."""
    path = _saved(_ppo(), tmp_path / "m")
    clean = LearnedPolicy.load(path)
    marker = tmp_path / "marker.txt"
    payload = base64.b64encode(cloudpickle.dumps(_WritesMarker(marker))).decode()
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    if field == "policy_class":
        data["policy_class"][":serialized:"] = payload
    else:
        data[field] = {":type:": "<class 'object'>", ":serialized:": payload}
    _rewrite(path, {"data": json.dumps(data).encode()})

    policy = LearnedPolicy.load(path)
    assert isinstance(policy.model, SB3Actor)
    obs = {f"follower_{i}": row for i, row in enumerate(_obs(3))}
    actions = policy.act(obs)
    assert not marker.exists()
    expected = clean.act(obs)
    assert all(np.array_equal(actions[a], expected[a]) for a in obs)

    try:  # SB3's loader unpickles it (the policy class: then fails on the int it got)
        LearnedPolicy.load_pickled(path)
    except TypeError:
        assert field == "policy_class"
    assert marker.read_text() == "the payload ran"


def test_a_pickled_payload_in_the_weights_is_refused_unrun(tmp_path: Path) -> None:
    path = _saved(_ppo(), tmp_path / "m")
    marker = tmp_path / "marker.txt"
    _rewrite(path, {"policy.pth": pickle.dumps({"x": _WritesMarker(marker)}, protocol=2)})
    with pytest.raises(ValueError, match=r"model\.zip: policy\.pth is not readable as weights"):
        LearnedPolicy.load(path)
    assert not marker.exists()


@pytest.mark.parametrize(
    "name", ["ppo_ta_aruco_s0", "residual_drive_aruco_s0", "legacy/ppo_corridors_s0"]
)
def test_shipped_models_read_the_network_sb3_builds_to_the_bit(name: str) -> None:
    path = REPO / "models" / name / "model.zip"
    if not path.is_file():
        pytest.skip(f"{name} is not in models/")
    weights_only = LearnedPolicy.load(path)
    sb3 = LearnedPolicy.load_pickled(path)
    forward = sb3_forward(sb3.model.policy)
    assert forward is not None and isinstance(weights_only.model, SB3Actor)
    assert weights_only.model.forward.digest == forward.digest
    fast, reference = weights_only._fast_actor(), sb3._fast_actor()
    assert fast is not None and reference is not None and fast.key == reference.key
    obs = _obs(9, weights_only.input_size, seed=3) * 10
    assert np.array_equal(fast(obs), reference(obs))
    assert weights_only.observation_layout == sb3.observation_layout
    assert np.array_equal(weights_only.obs_scale, sb3.obs_scale)  # type: ignore[arg-type]


def test_the_default_activations_are_sb3s() -> None:
    """Where ``policy_kwargs`` names no ``activation_fn`` the loader takes the policy class's
    default: it must be SB3's own (checked here, not assumed)."""
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.sac.policies import SACPolicy

    names = {nn.Tanh: "tanh", nn.ReLU: "relu"}
    for algo, cls in (("ppo", ActorCriticPolicy), ("sac", SACPolicy)):
        default = inspect.signature(cls.__init__).parameters["activation_fn"].default
        assert names[default] == _SB3_POLICIES[algo]["activation"]
        assert _SB3_POLICIES[algo]["class"] == cls.__name__
        assert _SB3_POLICIES[algo]["module"] == cls.__module__


@pytest.mark.parametrize("activation", [None, nn.ReLU, nn.Tanh])
def test_a_ppo_acts_as_sb3s_predict_with_its_recorded_activation(
    tmp_path: Path, activation: Any
) -> None:
    kwargs = {} if activation is None else {"activation_fn": activation}
    model = _ppo(**kwargs)
    policy = LearnedPolicy.load(_saved(model, tmp_path / "m"))
    assert isinstance(policy.model, SB3Actor)
    reference = sb3_forward(model.policy)
    assert reference is not None and policy.model.forward.digest == reference.digest
    obs = _obs(20)
    expected, _ = model.predict(obs, deterministic=True)
    out = policy._deterministic(obs)
    np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-5)
    assert np.any(np.abs(out) == 1.0)  # clipped to the box as predict clips


def test_a_sac_acts_as_sb3s_predict(tmp_path: Path) -> None:
    model = SAC(
        "MlpPolicy", BoxEnv(), buffer_size=100, policy_kwargs={"net_arch": [8, 8]}, device="cpu"
    )
    policy = LearnedPolicy.load(_saved(model, tmp_path / "m", algo="sac"))
    assert isinstance(policy.model, SB3Actor) and policy.model.squash_output
    obs = _obs(20)
    expected, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy._deterministic(obs), expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    ("policy_kwargs", "message"),
    [
        ({"activation_fn": nn.ELU}, "activation_fn="),
        ({"squash_output": True, "use_sde": True}, "use_sde"),
        (
            {
                "ortho_init": False,
                "features_extractor_kwargs": {},
                "share_features_extractor": False,
            },
            None,
        ),
    ],
)
def test_an_actor_the_loader_cannot_read_exactly_is_refused(
    tmp_path: Path, policy_kwargs: dict[str, Any], message: str | None
) -> None:
    use_sde = bool(policy_kwargs.pop("use_sde", False))
    model = PPO(
        "MlpPolicy",
        BoxEnv(),
        n_steps=16,
        batch_size=16,
        device="cpu",
        use_sde=use_sde,
        policy_kwargs=policy_kwargs,
    )
    path = _saved(model, tmp_path / "m")
    if message is None:  # options that leave the actor as it is: read, and the same network
        reference = sb3_forward(model.policy)
        assert reference is not None
        assert LearnedPolicy.load(path).model.forward.digest == reference.digest  # type: ignore[union-attr]
        return
    with pytest.raises(ValueError, match=rf"model\.zip: .*{message}"):
        LearnedPolicy.load(path)


def test_a_policy_class_or_parameters_it_does_not_know_are_refused(tmp_path: Path) -> None:
    path = _saved(_ppo(), tmp_path / "m")
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
        state = torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    other = json.loads(json.dumps(data))
    other["policy_class"]["__init__"] = "<function MyPolicy.__init__ at 0x0>"
    _rewrite(path, {"data": json.dumps(other).encode()})
    with pytest.raises(ValueError, match=r"policy class is not SB3's.*load_pickled"):
        LearnedPolicy.load(path)
    buffer = io.BytesIO()
    torch.save({**state, "features_extractor.cnn.0.weight": torch.zeros(3, 3)}, buffer)
    _rewrite(path, {"data": json.dumps(data).encode(), "policy.pth": buffer.getvalue()})
    with pytest.raises(ValueError, match=r"not the MLP actor .*unexpected.*features_extractor"):
        LearnedPolicy.load(path)


def test_the_hash_check_comes_before_anything_is_read(tmp_path: Path) -> None:
    path = _saved(_ppo(), tmp_path / "m")
    with zipfile.ZipFile(path, "a") as archive:
        archive.writestr("extra", b"x")
    with pytest.raises(ValueError, match="not from the same save"):
        LearnedPolicy.load(path)


# ------------------------------------------------------------------------------------------------
# Exported (RLlib) actors: shapes from the .npy headers, before any data
# ------------------------------------------------------------------------------------------------
def _npy(shape: tuple[int, ...], data: bytes | None = None, dtype: str = "<f4") -> bytes:
    """A ``.npy`` member declaring ``shape``: its header, then ``data`` (None: the real zeros;
    bytes: e.g. a truncated few)."""
    out = io.BytesIO()
    header = {"descr": dtype, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(out, header)
    if data is None:
        data = np.zeros(shape, dtype=dtype).tobytes()
    return out.getvalue() + data


def _exported(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    arrays = {
        "W0": rng.normal(size=(8, 7)),
        "b0": rng.normal(size=8),
        "W1": rng.normal(size=(2, 8)),
        "b1": rng.normal(size=2),
    }
    return save_exported_policy(arrays, tmp_path / "m" / "model.zip", {**META, "engine": "rllib"})


def _replace_exported(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        for name, raw in members.items():
            archive.writestr(name, raw)
    meta = json.loads(path.with_suffix(".json").read_text())
    meta["zip_sha256"] = file_sha256(path)
    path.with_suffix(".json").write_text(json.dumps(meta))


def test_an_exported_actor_loads_and_acts(tmp_path: Path) -> None:
    policy = LearnedPolicy.load(_exported(tmp_path))
    assert isinstance(policy.model, MLPActor) and policy.model.input_dim == 7
    actions = policy.act({"follower_0": _obs(1)[0]})
    assert actions["follower_0"].shape == (2,)


@pytest.mark.parametrize(
    ("members", "message"),
    [
        (  # 1.6 GB declared, 16 bytes stored: refused on the header, never read
            {"W0.npy": _npy((20000, 20000), b"\0" * 16), "b0.npy": _npy((20000,), b"")},
            r"array W0: shape \(20000, 20000\) is outside 1\.\.4096 units",
        ),
        (
            {
                "W0.npy": _npy((4096, 7)),
                "b0.npy": _npy((4096,)),
                "W1.npy": _npy((4096, 4096), b""),
                "b1.npy": _npy((4096,), b""),
            },
            r"array W1: the layers up to it hold \d+ parameters, more than 10000000",
        ),
        (
            {
                "W0.npy": _npy((8, 7), b""),
                "b0.npy": _npy((8,), b""),
                "W1.npy": _npy((2, 9), b""),
                "b1.npy": _npy((2,), b""),
            },
            r"array W1: shape \(2, 9\) takes 9 inputs, W0 gives 8",
        ),
        (
            {"W0.npy": _npy((2, 7), b""), "b0.npy": _npy((3,), b"")},
            r"array b0: shape \(3,\) does not match",
        ),
        ({"W0.npy": _npy((2, 7), b"")}, "exported actor lacks b0"),
        (
            {"W0.npy": _npy((2, 7)), "b0.npy": _npy((2,)), "b1.npy": _npy((2,))},
            "array b1: not a layer",
        ),
        (
            {"W0.npy": _npy((2, 7)), "b0.npy": _npy((2,)), "x.pkl": b"\x80\x04."},
            "unexpected member 'x.pkl'",
        ),
        ({"W0.npy": _npy((2, 7), b"", dtype="|O"), "b0.npy": _npy((2,))}, "array W0: dtype object"),
        ({"W0.npy": b"not a npy", "b0.npy": _npy((2,))}, "array W0: unreadable .npy header"),
    ],
)
def test_an_exported_actor_is_refused_on_its_headers_before_its_data(
    tmp_path: Path, members: dict[str, bytes], message: str
) -> None:
    path = _exported(tmp_path)
    _replace_exported(path, members)
    with pytest.raises(ValueError, match=rf"model\.zip: {message}"):
        LearnedPolicy.load(path)
    with pytest.raises(ValueError, match=message):
        MLPActor.load(path)


def test_a_truncated_member_within_the_bounds_is_one_error_naming_it(tmp_path: Path) -> None:
    path = _exported(tmp_path)
    _replace_exported(path, {"W0.npy": _npy((2, 7), b"\0" * 8), "b0.npy": _npy((2,))})
    with pytest.raises(ValueError, match=r"model\.zip: array W0: unreadable data"):
        LearnedPolicy.load(path)


def test_the_bounds_leave_room_for_the_shipped_models() -> None:
    shipped = sorted(REPO.glob("models/**/model.zip"))
    if not shipped:
        pytest.skip("no shipped models")
    for path in shipped:
        model = LearnedPolicy.load(path).model
        assert isinstance(model, SB3Actor)
        dims = [model.input_dim, *(int(s[0]) for s in model.forward._shapes)]
        assert max(dims) * 8 <= MAX_LAYER_UNITS, path
        assert model.forward._params.size * 100 <= MAX_PARAMETERS, path
