"""Learned policies behind the shared policy interface (``docs/api.md``).

A trained model is saved as two files side by side::

    DIR/model.zip    the Stable-Baselines3 model (PPO or SAC), as ``model.save`` writes it
    DIR/model.json   everything else needed to act with it, and how it was made:

        {
          "format": "platoon_env.learned_policy", "format_version": 2,
          "algo": "ppo",                       # which SB3 class loads model.zip
          "zip_sha256": "3f1c...",             # SHA-256 of the zip beside this file
          "scenario": "study_c",               # scenario trained on, as it was given
          "scenario_fingerprint": "5d48...",   # SHA-256 of the resolved scenario config
          "scenario_config": {...},            # that resolved config (after the overrides)
          "control_period": 0.05,              # [s] period the policy was trained at
          "observation_layout": ["visible", "x_rel", ...], "action_layout": ["u", "omega"],
                                               # (13 names with task-aware observations)
          "observation_normalization": {"type": "fixed_scale", "scale": [1, 1.5, ...]},
          "action_range": {"u_low": -0.5, "u_high": 1.5, "omega_high": 2.0},
          "config": {...}, "git_commit": "...", "seed": 0, "timesteps": ..., ...
        }

The observation normalisation is fixed (not a running mean): the policy sees
``obs / scale``, with ``scale`` the upper bound of the training env's observation Box, stored
as numbers so that the same division is applied whatever env the policy is evaluated on
(``null``: the policy was trained on raw observations). The action rescaling maps the policy's
``[-1, 1]^2`` to ``[u_low, u_high] x [-omega_high, omega_high]``
(:class:`training.vec_env.ActionRange`); it is required: a ``model.json`` without a valid one
is refused, since the policy's normalised outputs would otherwise be applied as m/s and rad/s.
So ``LearnedPolicy.load("DIR/model.zip")`` needs no other file.

What :meth:`LearnedPolicy.load` checks (every refusal is a ``ValueError`` naming the file and
the reason):

* ``model.json`` must exist (``FileNotFoundError`` otherwise: without it there is no action
  range, normalisation or control period to act with) and be a ``format_version`` this code
  reads;
* ``zip_sha256`` must be the SHA-256 of the zip: a zip and a JSON from different runs (or a
  save cut off between the two files) are refused. ``format_version`` 1 files (written before
  the hash was recorded) load with a ``UserWarning``, once per file; a version 2 file without
  the hash is refused. Both shipped models (``models/``) have it (backfilled);
* ``action_range``, ``observation_normalization`` and ``control_period`` must be present and
  well-formed; the model must map 7 observations (13 with task-aware observations,
  ``observation: {task_aware: true}``: :data:`OBSERVATION_LAYOUTS`) to 2 actions, and the
  recorded ``observation_layout`` and normalisation must have that length. A model with
  ``"previous_command": true`` (``platoon-train --engine fast --previous-command``) reads two
  more values after the observation, its own previous command: its input is the layout's
  length plus 2.

:meth:`LearnedPolicy.check_env` then compares the model with the env it is about to act in:
which differences make a result meaningless (refused) and which are experiments (allowed, and
returned as notes) is listed there.

``"engine"`` says what wrote the model (absent: ``"sb3"``). A model trained by
``platoon-train --engine rllib`` (:mod:`training.rllib`) has ``"engine": "rllib"``: its
``model.zip`` is a NumPy ``.npz`` archive of the actor's layers ``W0, b0, W1, b1, ...`` (Tanh
between them; ``"actor"`` in ``model.json`` describes it), evaluated by :class:`MLPActor` with
NumPy alone, so an RLlib model evaluates without Ray installed, through the same
:class:`LearnedPolicy`. The full RLlib checkpoint (to resume or fine-tune) lies beside it in
``DIR/rllib_checkpoint/``.

Nothing :meth:`LearnedPolicy.load` reads can run code (``docs/security.md``):

* an SB3 zip is read **weights-only** (:func:`read_sb3_actor`, giving an :class:`SB3Actor`):
  its ``policy.pth`` with ``torch.load(weights_only=True)`` (tensors only), and its ``data``
  entry as plain JSON, of which only SB3's human-readable fields are used (the policy class's
  module and ``__init__``, ``policy_kwargs``, ``use_sde``, the spaces' type, shape and action
  bounds); the cloudpickled ``:serialized:`` fields SB3 stores there are never decoded. The
  actor (PPO's ``mlp_extractor.policy_net`` + ``action_net``, SAC's ``actor.latent_pi`` +
  ``actor.mu``) is refused unless it is the plain MLP those fields describe, with the
  activation ``policy_kwargs`` names (SB3 writes ``activation_fn`` there as its class name)
  or, where it names none, SB3's default for that policy class (PPO Tanh, SAC ReLU; a test
  compares them with SB3's signatures). The actions are those of the SB3 object's
  ``predict(obs, deterministic=True)`` within float32 rounding (the PPO path is the very
  :class:`~training.forward.MLPForward` the SB3 object gave, so the shipped models act to
  the bit as when they were loaded through SB3);
* an exported RLlib actor: each array's shape and dtype are read from its ``.npy`` header and
  checked (the layers chain, at most :data:`MAX_LAYER_UNITS` units per layer and
  :data:`MAX_PARAMETERS` parameters) before any data is read, then the data with
  ``allow_pickle=False``.

.. warning::
    :meth:`LearnedPolicy.load_pickled` (the full SB3 object, e.g. for its ``predict`` with
    sampling, or to compare with SB3) and SB3's own ``PPO.load`` / ``SAC.load`` (continuing a
    training run, ``platoon-train --resume``) unpickle Python objects from the zip, which can
    execute arbitrary code: use them only on model files you trust. The hash check guards
    against mixed-up files, not against an attacker, who can rewrite both.
"""

from __future__ import annotations

import io
import json
import math
import os
import pickle
import re
import tempfile
import warnings
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm

from platoon_env.observation import (
    ACT_SIZE,
    OBS_NAMES,
    OBS_NAMES_SCALE_FREE,
    OBS_NAMES_TASK,
    observation_names,
)
from platoon_env.scenarios.fingerprint import config_fingerprint, config_mapping, file_sha256
from training.algorithms import ALGORITHMS as TRAINING_ALGORITHMS
from training.experts import EXPERTS, to_normalised
from training.forward import MLPForward, sb3_forward
from training.vec_env import ActionRange

__all__ = [
    "ACTION_LAYOUT",
    "ALGORITHMS",
    "ENGINES",
    "MAX_LAYER_UNITS",
    "MAX_PARAMETERS",
    "METADATA_FORMAT",
    "OBSERVATION_LAYOUT",
    "OBSERVATION_LAYOUTS",
    "LearnedPolicy",
    "MLPActor",
    "SB3Actor",
    "adapter_metadata",
    "metadata_path",
    "parse_action_range",
    "read_sb3_actor",
    "save_exported_policy",
    "save_model",
    "scenario_differences",
    "zip_mismatch",
]

#: The SB3 classes of :attr:`training.algorithms.Algorithm.sb3_class`.
_SB3_CLASSES: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC}
#: The SB3 algorithms a learned policy can be, by the name stored in ``model.json``: the SB3
#: class that loads a model.zip of each ``algo`` (PPO-Lagrangian is SB3's PPO).
ALGORITHMS: dict[str, type[BaseAlgorithm]] = {
    a.name: _SB3_CLASSES[a.sb3_class]
    for a in TRAINING_ALGORITHMS.values()
    if not a.clone  # a clone's model.json names the algorithm that fine-tuned it
}
METADATA_FORMAT = "platoon_env.learned_policy"
#: 2: ``zip_sha256``, the resolved scenario, the observation/action layout and the training
#: segments are recorded. 1: none of them (still read; see the module doc).
METADATA_VERSION = 2
#: The default per-follower observation a policy reads, by name (``model.json``'s
#: ``observation_layout``; :mod:`platoon_env.observation`): the 7-vector.
OBSERVATION_LAYOUT: tuple[str, ...] = tuple(OBS_NAMES)
#: Every observation layout a policy can read, by its length: the 7-vector, the 13 values
#: of task-aware observations (``observation.task_aware``) and the 15 of scale-free ones
#: (``observation.scale_free``).
OBSERVATION_LAYOUTS: dict[int, tuple[str, ...]] = {
    len(OBS_NAMES): tuple(OBS_NAMES),
    len(OBS_NAMES_TASK): tuple(OBS_NAMES_TASK),
    len(OBS_NAMES_SCALE_FREE): tuple(OBS_NAMES_SCALE_FREE),
}
#: The ``observation`` option that gives each layout (what to pass to ``make()``).
_LAYOUT_OPTIONS: dict[tuple[str, ...], str] = {
    tuple(OBS_NAMES): "no observation option",
    tuple(OBS_NAMES_TASK): "observation={'task_aware': True}",
    tuple(OBS_NAMES_SCALE_FREE): "observation={'task_aware': True, 'scale_free': True}",
}
#: The per-follower action a policy outputs (``model.json``'s ``action_layout``).
ACTION_LAYOUT: tuple[str, ...] = ("u", "omega")
#: The trainers whose models ``LearnedPolicy.load`` reads (``model.json``'s ``engine``).
ENGINES = ("sb3", "rllib")
#: The most units (inputs or outputs) of one layer of an actor read from a file, and the most
#: parameters (weights and biases) of the whole actor: checked on the declared shapes before
#: any weight is read (an exported actor's ``.npy`` headers; the SB3 ``policy.pth``'s size is
#: bounded by :data:`_MAX_SB3_POLICY_BYTES` first). The shipped actors have 64 units per layer
#: and under 6,000 parameters.
MAX_LAYER_UNITS = 4096
MAX_PARAMETERS = 10_000_000
#: The largest SB3 ``policy.pth`` entry read (uncompressed): the actor and a critic of
#: :data:`MAX_PARAMETERS` float32 values each, plus 1 MiB for torch's framing.
_MAX_SB3_POLICY_BYTES = 8 * MAX_PARAMETERS + (1 << 20)
#: The largest SB3 ``data`` entry (JSON) read; the shipped ones are under 20 kB.
_MAX_SB3_DATA_BYTES = 16 << 20


class Predictor(Protocol):
    """What :class:`LearnedPolicy` calls: SB3's ``predict`` signature."""

    def predict(
        self, observation: NDArray[Any], deterministic: bool = ...
    ) -> tuple[NDArray[Any], Any]: ...


def metadata_path(model_path: str | os.PathLike[str]) -> Path:
    """The JSON beside a model zip: ``DIR/name.zip`` -> ``DIR/name.json``."""
    return Path(model_path).with_suffix(".json")


class VecAdapter(Protocol):
    """What :func:`adapter_metadata` reads from a VecEnv adapter (``PlatoonVecEnv``,
    ``BatchedPlatoonVecEnv``)."""

    obs_scale: NDArray[np.float32] | None
    action_range: ActionRange | None


def adapter_metadata(venv: VecAdapter) -> dict[str, Any]:
    """The normalisation and rescaling of ``venv``, in the ``model.json`` schema."""
    return {
        "observation_normalization": None
        if venv.obs_scale is None
        else {"type": "fixed_scale", "scale": [float(s) for s in venv.obs_scale]},
        "action_range": None if venv.action_range is None else venv.action_range.to_dict(),
    }


def _atomic_write(path: Path, write: Any) -> str:
    """Call ``write(file)`` on a temporary file beside ``path``, then rename it into place;
    returns the hex SHA-256 of the bytes written."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        digest = file_sha256(tmp)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; outputs are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return digest


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def parse_action_range(value: Any, where: str = "model.json") -> ActionRange:
    """The :class:`ActionRange` of ``model.json``'s ``action_range``; ``ValueError`` naming the
    reason for a missing (``None``), malformed or invalid one.

    A model's outputs are normalised to ``[-1, 1]^2``: without its range they would be applied
    as m/s and rad/s, silently, so there is no "no range" case.
    """
    if value is None:
        raise ValueError(
            f"{where}: action_range is null or missing: the policy's normalised [-1, 1] "
            "outputs would be applied as raw m/s and rad/s; record the range it was trained "
            'with, e.g. {"u_low": -0.5, "u_high": 1.5, "omega_high": 2.0}'
        )
    keys = ("u_low", "u_high", "omega_high")
    if not isinstance(value, Mapping) or set(value) != set(keys):
        raise ValueError(f"{where}: action_range must be a mapping with keys {keys}, got {value!r}")
    bad = [k for k in keys if not _is_number(value[k]) or not math.isfinite(value[k])]
    if bad:
        raise ValueError(
            f"{where}: action_range {', '.join(bad)} must be finite numbers: {value!r}"
        )
    try:
        return ActionRange(**{k: float(value[k]) for k in keys})
    except ValueError as e:
        raise ValueError(f"{where}: action_range: {e}") from None


def _sizes_text(size: int | None) -> str:
    return str(size) if size is not None else " or ".join(map(str, OBSERVATION_LAYOUTS))


def _parse_layout(value: Any, where: str) -> tuple[str, ...] | None:
    """``model.json``'s ``observation_layout`` (None: not recorded, an old model); a list of
    names of one of the :data:`OBSERVATION_LAYOUTS` lengths. Which names the env has is
    :meth:`LearnedPolicy.check_env`'s to compare."""
    if value is None:
        return None
    if (
        not isinstance(value, list)
        or not all(isinstance(name, str) for name in value)
        or len(value) not in OBSERVATION_LAYOUTS
    ):
        raise ValueError(
            f"{where}: observation_layout must be a list of {_sizes_text(None)} names, "
            f"got {value!r}"
        )
    return tuple(value)


def _parse_normalization(
    value: Any, where: str, size: int | None = None
) -> NDArray[np.float32] | None:
    """The observation divisor of ``observation_normalization`` (None: raw observations):
    ``size`` numbers (None: the length of one of the :data:`OBSERVATION_LAYOUTS`)."""
    if value is None:
        return None
    if not isinstance(value, Mapping) or value.get("type") != "fixed_scale":
        raise ValueError(f"{where}: unknown observation normalisation {value!r}")
    scale = value.get("scale")
    if (
        not isinstance(scale, list)
        or len(scale) not in ((size,) if size is not None else tuple(OBSERVATION_LAYOUTS))
        or not all(_is_number(x) and math.isfinite(x) and x > 0 for x in scale)
    ):
        raise ValueError(
            f"{where}: observation_normalization.scale must be {_sizes_text(size)} finite "
            f"positive numbers (one per observation), got {scale!r}"
        )
    return np.asarray(scale, dtype=np.float32)


def _parse_control_period(value: Any, where: str) -> float:
    if not _is_number(value) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{where}: control_period must be a positive number, got {value!r}")
    return float(value)


def _check_metadata(metadata: Mapping[str, Any], where: str) -> None:
    """What :func:`save_model` and :meth:`LearnedPolicy.load` both require of the metadata."""
    missing = {"algo", "control_period", "observation_normalization", "action_range"} - set(
        metadata
    )
    if missing:
        raise ValueError(f"{where}: metadata lacks {sorted(missing)}")
    if not isinstance(metadata.get("previous_command", False), bool):
        raise ValueError(
            f"{where}: previous_command must be true or false, got {metadata['previous_command']!r}"
        )
    parse_action_range(metadata["action_range"], where)
    layout = _parse_layout(metadata.get("observation_layout"), where)
    _parse_normalization(
        metadata["observation_normalization"], where, None if layout is None else len(layout)
    )
    _parse_control_period(metadata["control_period"], where)


def _document(metadata: Mapping[str, Any], digest: str) -> bytes:
    doc = {
        "format": METADATA_FORMAT,
        "format_version": METADATA_VERSION,
        **metadata,
        "zip_sha256": digest,
    }
    return json.dumps(doc, indent=2, sort_keys=False, default=str).encode()


def zip_mismatch(path: str | os.PathLike[str], metadata: Mapping[str, Any]) -> str | None:
    """Why the zip at ``path`` does not belong with ``metadata`` (its JSON), or None.

    None also when ``metadata`` records no ``zip_sha256`` (a ``format_version`` 1 file): the
    caller decides what an unchecked pair means.
    """
    recorded = metadata.get("zip_sha256")
    if recorded is None:
        return None
    actual = file_sha256(Path(path))
    if actual != recorded:
        return (
            f"{Path(path).name} has SHA-256 {actual[:16]}..., its JSON records "
            f"{str(recorded)[:16]}...: the two files are not from the same save (another run's "
            "zip, an edited file, or a save cut off between the two)"
        )
    return None


def save_model(
    model: BaseAlgorithm, path: str | os.PathLike[str], metadata: Mapping[str, Any]
) -> Path:
    """Write ``model`` to ``path`` (a ``.zip``) and ``metadata`` to the JSON beside it.

    Both files are written atomically (temporary file + ``os.replace``), the zip first, so an
    interruption leaves the previous version intact; the JSON records the zip's SHA-256
    (``zip_sha256``), so a zip and a JSON of different saves do not load as a pair.
    ``metadata`` must hold at least ``algo`` and ``control_period``, plus the keys of
    :func:`adapter_metadata`, with a valid ``action_range`` (what :meth:`LearnedPolicy.load`
    requires). Returns the zip's path.
    """
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"model path must end in .zip, got {path}")
    _check_metadata(metadata, "save_model")
    digest = _atomic_write(path, model.save)
    text = _document(metadata, digest)
    _atomic_write(metadata_path(path), lambda f: f.write(text))
    return path


def save_exported_policy(
    arrays: Mapping[str, NDArray[Any]], path: str | os.PathLike[str], metadata: Mapping[str, Any]
) -> Path:
    """Write an exported actor (``W0, b0, ...``, see :class:`MLPActor`) to ``path`` (a
    ``.zip``: an uncompressed ``.npz`` archive) and ``metadata`` to the JSON beside it, both
    atomically. ``metadata`` needs the keys :func:`save_model` needs and ``"engine"``."""
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"model path must end in .zip, got {path}")
    if "engine" not in metadata:
        raise ValueError("save_exported_policy: metadata lacks ['engine']")
    _check_metadata(metadata, "save_exported_policy")
    MLPActor.from_arrays(arrays)  # fail before writing anything if the layers do not chain
    arrays = {k: np.asarray(v, dtype=np.float32) for k, v in arrays.items()}
    digest = _atomic_write(path, lambda f: np.savez(f, allow_pickle=False, **arrays))
    text = _document(metadata, digest)
    _atomic_write(metadata_path(path), lambda f: f.write(text))
    return path


class _ActorNetwork:
    """What the actors read from a file share: their network :attr:`forward` (a
    :class:`~training.forward.MLPForward`) and its input and output lengths."""

    forward: MLPForward

    @property
    def input_dim(self) -> int:
        """Length of an observation."""
        return self.forward.input_dim

    @property
    def output_dim(self) -> int:
        """Length of an action."""
        return self.forward.output_dim


class MLPActor(_ActorNetwork):
    """A deterministic MLP actor from plain arrays: ``y = W_L tanh(... tanh(W_0 x + b_0) ...)
    + b_L`` (no activation after the last layer), with SB3's ``predict`` signature.

    This is how an RLlib-trained policy (:mod:`training.rllib`) is evaluated: the mean of its
    Gaussian, computed by :class:`training.forward.MLPForward` (no Ray, no torch, no
    unpickling; each row the same to the bit whatever the batch).
    """

    def __init__(self, layers: list[tuple[NDArray[np.float32], NDArray[np.float32]]]) -> None:
        if not layers:
            raise ValueError("an MLPActor needs at least one layer")
        last = len(layers) - 1
        #: The network (a row-invariant forward pass).
        self.forward = MLPForward(
            [(w, b, "tanh" if k < last else "identity") for k, (w, b) in enumerate(layers)]
        )
        self.layers = layers

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, NDArray[Any]]) -> MLPActor:
        """From ``{"W0": ..., "b0": ..., "W1": ...}``."""
        n = sum(1 for k in arrays if k.startswith("W"))
        try:
            layers = [
                (
                    np.asarray(arrays[f"W{k}"], dtype=np.float32),
                    np.asarray(arrays[f"b{k}"], dtype=np.float32),
                )
                for k in range(n)
            ]
        except KeyError as e:
            raise ValueError(f"exported actor lacks {e.args[0]}") from None
        return cls(layers)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> MLPActor:
        """Read the ``.npz`` archive at ``path``: ``W0.npy, b0.npy, ...`` and nothing else.

        Each array's shape and dtype are read from its ``.npy`` header first, and the archive
        is refused (``ValueError`` naming the file and the array) before any data is read if
        an array is not a float array, if the layers do not chain (``W{k}`` of shape
        ``(n_out, n_in)``, ``b{k}`` of ``(n_out,)``, ``n_in`` the previous layer's ``n_out``),
        or if they exceed :data:`MAX_LAYER_UNITS` units per layer or :data:`MAX_PARAMETERS` in
        all. The data is then read with ``allow_pickle=False``."""
        path = Path(path)
        try:
            with zipfile.ZipFile(path) as archive:
                headers = _npz_headers(archive, path)
                _check_exported_shapes(headers, path)
                arrays = {
                    name: _npz_array(archive, info, path, name)
                    for name, (info, _, _) in headers.items()
                }
        except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError) as e:
            raise ValueError(f"{path}: not a readable exported actor (.npz archive): {e}") from None
        return cls.from_arrays(arrays)

    def predict(
        self, observation: NDArray[Any], deterministic: bool = True
    ) -> tuple[NDArray[np.float32], None]:
        """The actions ``(B, output_dim)`` for observations ``(B, input_dim)`` (always greedy)."""
        return self.forward(np.asarray(observation, dtype=np.float32)), None


#: The members of an exported actor's archive: ``W0.npy``, ``b0.npy``, ``W1.npy``, ...
_EXPORTED_MEMBER = re.compile(r"([Wb])(0|[1-9][0-9]{0,5})\.npy")


def _npz_headers(
    archive: zipfile.ZipFile, path: Path
) -> dict[str, tuple[zipfile.ZipInfo, tuple[int, ...], np.dtype[Any]]]:
    """Each array of an exported actor's archive: its member, and the shape and dtype its
    ``.npy`` header declares (only the header is read)."""
    out: dict[str, tuple[zipfile.ZipInfo, tuple[int, ...], np.dtype[Any]]] = {}
    for info in archive.infolist():
        if _EXPORTED_MEMBER.fullmatch(info.filename) is None:
            raise ValueError(
                f"{path}: unexpected member {info.filename!r}: an exported actor holds only "
                "W0.npy, b0.npy, W1.npy, b1.npy, ..."
            )
        name = info.filename[: -len(".npy")]
        if name in out:
            raise ValueError(f"{path}: array {name} is stored twice")
        try:
            with archive.open(info) as f:
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                elif version == (2, 0):
                    shape, _, dtype = np.lib.format.read_array_header_2_0(f)
                else:
                    raise ValueError(f".npy format version {version} is not 1.0 or 2.0")
        except (ValueError, OSError, EOFError, SyntaxError, zipfile.BadZipFile) as e:
            raise ValueError(f"{path}: array {name}: unreadable .npy header ({e})") from None
        if dtype.kind != "f" or dtype.itemsize not in (4, 8):
            raise ValueError(
                f"{path}: array {name}: dtype {dtype} is not a float32 or float64 array"
            )
        out[name] = (info, tuple(int(n) for n in shape), dtype)
    return out


def _check_exported_shapes(
    headers: Mapping[str, tuple[zipfile.ZipInfo, tuple[int, ...], np.dtype[Any]]], path: Path
) -> None:
    """Refuse an exported actor whose declared arrays are not the layers ``W0, b0, ...`` of
    one MLP within the bounds (:func:`_check_mlp_shapes`); nothing but headers is read."""
    n = sum(1 for name in headers if name.startswith("W"))
    for name in [f"{kind}{k}" for k in range(max(n, 1)) for kind in "Wb"]:
        if name not in headers:
            raise ValueError(f"{path}: exported actor lacks {name}")
    expected = {f"{kind}{k}" for k in range(n) for kind in "Wb"}
    extra = sorted(set(headers) - expected)
    if extra:
        raise ValueError(
            f"{path}: array {extra[0]}: not a layer of the actor (W0..W{n - 1}, b0..b{n - 1})"
        )
    _check_mlp_shapes(
        [(f"W{k}", headers[f"W{k}"][1], f"b{k}", headers[f"b{k}"][1]) for k in range(n)],
        str(path),
    )


def _npz_array(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path, name: str) -> Any:
    """The data of one ``.npy`` member (its header already checked), without pickles."""
    try:
        with archive.open(info) as f:
            return np.lib.format.read_array(f, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f"{path}: array {name}: unreadable data ({e})") from None


def _check_mlp_shapes(
    layers: Sequence[tuple[str, tuple[int, ...], str, tuple[int, ...]]], where: str
) -> None:
    """Refuse (``ValueError`` naming ``where`` and the array) the declared shapes of an MLP's
    layers ``(weight name, weight shape, bias name, bias shape)``, in order, unless each
    weight is ``(n_out, n_in)`` and its bias ``(n_out,)``, each ``n_in`` is the previous
    ``n_out``, no layer has more than :data:`MAX_LAYER_UNITS` inputs or outputs and all of
    them hold at most :data:`MAX_PARAMETERS` parameters. Shapes only: checked before any
    weight is read."""
    total = 0
    for w_name, w_shape, b_name, b_shape in layers:
        for name, shape, ndim in ((w_name, w_shape, 2), (b_name, b_shape, 1)):
            if len(shape) != ndim:
                raise ValueError(
                    f"{where}: array {name}: shape {shape}, a layer's "
                    f"{'weight' if ndim == 2 else 'bias'} has {ndim} dimension(s)"
                )
            if not all(1 <= n <= MAX_LAYER_UNITS for n in shape):
                raise ValueError(
                    f"{where}: array {name}: shape {shape} is outside 1..{MAX_LAYER_UNITS} units "
                    "per layer (training.policies.MAX_LAYER_UNITS): refused before reading it"
                )
        total += w_shape[0] * w_shape[1] + b_shape[0]
        if total > MAX_PARAMETERS:
            raise ValueError(
                f"{where}: array {w_name}: the layers up to it hold {total} parameters, more "
                f"than {MAX_PARAMETERS} (training.policies.MAX_PARAMETERS): refused before "
                "reading them"
            )
    previous: str | None = None
    previous_out = 0
    for w_name, w_shape, b_name, b_shape in layers:
        if b_shape != (w_shape[0],):
            raise ValueError(
                f"{where}: array {b_name}: shape {b_shape} does not match {w_name}'s {w_shape}"
            )
        if previous is not None and w_shape[1] != previous_out:
            raise ValueError(
                f"{where}: array {w_name}: shape {w_shape} takes {w_shape[1]} inputs, "
                f"{previous} gives {previous_out}"
            )
        previous, previous_out = w_name, w_shape[0]


class SB3Actor(_ActorNetwork):
    """The deterministic actor of a Stable-Baselines3 PPO or SAC model read from its weights
    alone (:func:`read_sb3_actor`; nothing unpickled), with SB3's ``predict`` signature.

    ``predict(obs)`` is what the SB3 object's ``predict(obs, deterministic=True)`` gives,
    within float32 rounding: PPO (an ``ActorCriticPolicy``): the Gaussian's mean clipped to
    the action box; SAC (a ``SACPolicy``): ``tanh`` of the mean mapped from ``[-1, 1]`` onto
    the action box (SB3's ``unscale_action``). Always the deterministic action (as
    :class:`MLPActor`): it has no sampling. :attr:`forward` computes the network
    (:class:`~training.forward.MLPForward`; for SAC its last layer's activation is the
    ``tanh``).

    Args:
        forward: the actor's network.
        action_low, action_high: the action box.
        squash_output: SAC's squashed Gaussian (``tanh``, then the box), else PPO's clip.
        algo: ``"ppo"`` or ``"sac"``, the SB3 class the zip was saved by.
    """

    def __init__(
        self,
        forward: MLPForward,
        action_low: NDArray[Any],
        action_high: NDArray[Any],
        *,
        squash_output: bool,
        algo: str,
    ) -> None:
        self.forward = forward
        self.squash_output = squash_output
        self.algo = algo
        low = np.asarray(action_low, dtype=np.float32)
        high = np.asarray(action_high, dtype=np.float32)
        if low.shape != (forward.output_dim,) or high.shape != low.shape:
            raise ValueError(
                f"action bounds of shape {low.shape} and {high.shape} for "
                f"{forward.output_dim} outputs"
            )
        #: The action box (``Box(low, high)``) the model acts in.
        self.action_space = spaces.Box(low, high, dtype=np.float32)
        #: The observations' shape (their bounds are not read: ``-inf..inf``).
        self.observation_space = spaces.Box(
            -np.inf, np.inf, shape=(forward.input_dim,), dtype=np.float32
        )

    def predict(
        self, observation: NDArray[Any], deterministic: bool = True
    ) -> tuple[NDArray[np.float32], None]:
        """The actions ``(B, output_dim)`` for observations ``(B, input_dim)`` (always the
        deterministic one)."""
        out = self.forward(np.asarray(observation, dtype=np.float32))
        low, high = self.action_space.low, self.action_space.high
        if self.squash_output:  # SB3's BasePolicy.unscale_action, in float32 as there
            return low + (0.5 * (out + 1.0) * (high - low)), None
        return np.clip(out, low, high), None


#: What :func:`read_sb3_actor` reads of each SB3 class's policy: its class (the data entry's
#: ``policy_class.__module__`` and ``__init__`` fields), the actor's parameters (the hidden
#: layers' prefix, the head), the parameters it does not use (value network, critics), the
#: Gaussian's log-std entries, the default activation of the policy class, and whether the
#: output is squashed (SAC).
_SB3_POLICIES: dict[str, dict[str, Any]] = {
    "ppo": {
        "module": "stable_baselines3.common.policies",
        "class": "ActorCriticPolicy",
        "hidden": "mlp_extractor.policy_net",
        "head": "action_net",
        "std": {"log_std": 1},  # a state-independent diagonal Gaussian: (n_actions,)
        "unused": ("mlp_extractor.value_net.", "value_net."),
        "activation": "tanh",  # ActorCriticPolicy's activation_fn default, nn.Tanh
        "squash": False,
    },
    "sac": {
        "module": "stable_baselines3.sac.policies",
        "class": "SACPolicy",
        "hidden": "actor.latent_pi",
        "head": "actor.mu",
        "std": {"actor.log_std.weight": 2, "actor.log_std.bias": 1},
        "unused": ("critic.", "critic_target."),
        "activation": "relu",  # SACPolicy's activation_fn default, nn.ReLU
        "squash": True,
    },
}
#: ``policy_kwargs['activation_fn']`` as SB3's data entry writes it (``str`` of the class).
_SB3_ACTIVATIONS = {
    "<class 'torch.nn.modules.activation.Tanh'>": "tanh",
    "<class 'torch.nn.modules.activation.ReLU'>": "relu",
}
_FLATTEN_EXTRACTOR = "<class 'stable_baselines3.common.torch_layers.FlattenExtractor'>"
#: The ``policy_kwargs`` that do not change the deterministic actor of a flat Box observation
#: (the rest are checked: ``net_arch`` against the weights, ``activation_fn``,
#: ``features_extractor_class``, ``squash_output``, ``use_sde``).
_SB3_INERT_KWARGS = frozenset(
    {
        "log_std_init",
        "ortho_init",
        "optimizer_class",
        "optimizer_kwargs",
        "n_critics",
        "share_features_extractor",
        "normalize_images",
        "features_extractor_kwargs",
        "use_expln",
        "full_std",
        "clip_mean",
    }
)


def _zip_entry(archive: zipfile.ZipFile, name: str, limit: int, path: Path) -> bytes:
    """The bytes of the entry ``name`` (at most ``limit`` bytes, checked before reading)."""
    try:
        info = archive.getinfo(name)
    except KeyError:
        raise ValueError(f"{path}: holds no {name!r} entry: not an SB3 model zip") from None
    if info.file_size > limit:
        raise ValueError(
            f"{path}: its {name!r} entry is {info.file_size} bytes, more than the {limit} "
            "this loader reads: refused before reading it"
        )
    return archive.read(info)


def _shown(value: Any) -> str:
    """``repr(value)``, cut to 60 characters (a file's content in an error message)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _plain_fields(value: Any, key: str, path: Path) -> dict[str, Any]:
    """The readable fields of the data entry's ``key``: a JSON object as SB3 writes it
    (a plain one, or the first-level fields of a pickled object, the ``:serialized:`` pickle
    itself left out and never decoded)."""
    if not isinstance(value, Mapping):
        raise ValueError(f"{path}: the data entry's {key!r} is {_shown(value)}, not a JSON object")
    return {k: v for k, v in value.items() if k != ":serialized:"}


def _sb3_space(data: Mapping[str, Any], key: str, path: Path) -> int:
    """The length of the 1-D Box ``key`` (``observation_space``/``action_space``) of the data
    entry."""
    space = _plain_fields(data.get(key), key, path)
    shape = space.get("_shape", space.get("shape"))
    if not str(space.get(":type:", "")).endswith("spaces.box.Box'>") or not (
        isinstance(shape, list) and len(shape) == 1 and isinstance(shape[0], int)
    ):
        raise ValueError(
            f"{path}: {key} is {_shown(space.get(':type:'))} of shape {_shown(shape)}: this "
            "loader reads 1-D Box spaces"
        )
    return int(shape[0])


def _sb3_action_bounds(data: Mapping[str, Any], n: int, path: Path) -> None:
    """Refuse an action space other than ``[-1, 1]^n``, the normalised action that
    ``model.json``'s ``action_range`` maps (``training.vec_env``): its bounds are read from
    the data entry's text (``'[-1. -1.]'``), which can be exact only for such round values."""
    space = _plain_fields(data.get("action_space"), "action_space", path)
    for bound, value in (("low", -1.0), ("high", 1.0)):
        text = space.get(bound)
        numbers: list[float] = []
        if isinstance(text, str) and text.startswith("[") and text.endswith("]"):
            try:
                numbers = [float(x) for x in text[1:-1].split()]
            except ValueError:
                pass
        if numbers != [value] * n:
            raise ValueError(
                f"{path}: action_space.{bound} is {_shown(text)}, expected {[value] * n}: a "
                "learned policy acts in [-1, 1] per action (model.json's action_range maps it)"
            )


def _sb3_activation(
    kwargs: Mapping[str, Any], kind: Mapping[str, Any], algo: str, path: Path
) -> str:
    """The hidden layers' activation the data entry's ``policy_kwargs`` give (``kwargs``,
    its readable fields), after refusing any option that changes the actor beyond it."""
    for key, value in kwargs.items():
        if key in _SB3_INERT_KWARGS or key in ("net_arch", "activation_fn", ":type:"):
            continue
        if key == "features_extractor_class" and value == _FLATTEN_EXTRACTOR:
            continue
        if key in ("squash_output", "use_sde") and value is False:
            continue
        raise ValueError(
            f"{path}: policy_kwargs {_shown(key)}={_shown(value)}: not an option this loader "
            f"reads (the {algo} MLP actor on flat observations); if you trust the file, "
            "LearnedPolicy.load_pickled loads it through SB3"
        )
    if "activation_fn" not in kwargs:
        return str(kind["activation"])
    activation = _SB3_ACTIVATIONS.get(str(kwargs["activation_fn"]))
    if activation is None:
        raise ValueError(
            f"{path}: policy_kwargs activation_fn={_shown(kwargs['activation_fn'])} is not one of "
            f"{sorted(_SB3_ACTIVATIONS)}"
        )
    return activation


def _sb3_hidden_sizes(kwargs: Mapping[str, Any]) -> list[int] | None:
    """The actor's hidden sizes ``policy_kwargs['net_arch']`` records (a list, or a dict's
    ``pi``), or None where it records none in these forms."""
    arch = kwargs.get("net_arch")
    if isinstance(arch, Mapping):
        arch = arch.get("pi")
    if isinstance(arch, list) and all(isinstance(n, int) for n in arch):
        return list(arch)
    return None


def _sb3_state(archive: zipfile.ZipFile, path: Path) -> dict[str, Any]:
    """The zip's ``policy.pth`` as tensors (``torch.load(weights_only=True)``)."""
    import torch

    raw = _zip_entry(archive, "policy.pth", _MAX_SB3_POLICY_BYTES, path)
    try:
        state = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, EOFError, ValueError, pickle.UnpicklingError) as e:
        raise ValueError(f"{path}: policy.pth is not readable as weights ({e})") from None
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise ValueError(f"{path}: policy.pth is not a state dict of tensors")
    return dict(state)


def read_sb3_actor(path: str | os.PathLike[str], algo: str = "ppo") -> SB3Actor:
    """The deterministic actor of the SB3 model zip ``path`` saved by SB3's ``PPO``
    (``algo="ppo"``, also PPO-Lagrangian's zips) or ``SAC`` (``"sac"``), read without
    unpickling anything.

    Only two entries are read: ``policy.pth`` with ``torch.load(weights_only=True)`` (tensors,
    never code), and ``data`` as JSON, of which only the readable fields are used (never the
    ``:serialized:`` cloudpickles SB3 stores beside them): the policy class's ``__module__``
    and ``__init__`` (PPO's ``ActorCriticPolicy``, SAC's ``SACPolicy``), ``use_sde`` (false),
    ``policy_kwargs`` (the activation, the ``net_arch`` compared with the weights, no other
    feature extractor than a flatten), the observation and action spaces (1-D Boxes, the
    action box ``[-1, 1]^n``). The actor's parameters must be exactly an MLP (the hidden
    ``Linear`` layers at indices 0, 2, 4, ... with the activation between and after them, then
    the head) within :data:`MAX_LAYER_UNITS` and :data:`MAX_PARAMETERS`, reading the
    observation space's length. Anything else is a ``ValueError`` naming the file and what
    was found. (``policy.pth`` is read whole, after its size is checked against
    :data:`_MAX_SB3_POLICY_BYTES`; the actor's shapes are then checked before any array is
    built from it.)
    """
    path = Path(path)
    kind = _SB3_POLICIES.get(algo)
    if kind is None:
        raise ValueError(f"read_sb3_actor: algo must be one of {list(_SB3_POLICIES)}, got {algo!r}")
    try:
        with zipfile.ZipFile(path) as archive:
            raw = _zip_entry(archive, "data", _MAX_SB3_DATA_BYTES, path)
            state = _sb3_state(archive, path)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError) as e:
        raise ValueError(f"{path}: not a readable SB3 model zip: {e}") from None
    try:
        data = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: its data entry is not JSON: {e}") from None
    except RecursionError:
        raise ValueError(f"{path}: its data entry is not JSON: nested too deep") from None
    if not isinstance(data, Mapping):
        raise ValueError(f"{path}: its data entry is not a JSON object")
    policy_class = _plain_fields(data.get("policy_class"), "policy_class", path)
    init = str(policy_class.get("__init__", ""))
    if policy_class.get("__module__") != kind["module"] or not init.startswith(
        f"<function {kind['class']}.__init__ "
    ):
        raise ValueError(
            f"{path}: its policy class is not SB3's {kind['module']}.{kind['class']} (the "
            f"data entry says module {_shown(policy_class.get('__module__'))}, {_shown(init)}): "
            "this loader reads that MLP policy; if you trust the file, "
            "LearnedPolicy.load_pickled loads it through SB3"
        )
    if data.get("use_sde") is not False:
        raise ValueError(
            f"{path}: use_sde is {_shown(data.get('use_sde'))}: this loader reads the diagonal "
            "Gaussian actor (use_sde false)"
        )
    kwargs = _plain_fields(data.get("policy_kwargs", {}), "policy_kwargs", path)
    activation = _sb3_activation(kwargs, kind, algo, path)
    n_obs = _sb3_space(data, "observation_space", path)
    n_act = _sb3_space(data, "action_space", path)
    _sb3_action_bounds(data, n_act, path)
    layers = _sb3_layers(state, kind, path)
    _check_mlp_shapes(
        [(w, tuple(state[w].shape), b, tuple(state[b].shape)) for w, b in layers], str(path)
    )
    shapes = [tuple(state[w].shape) for w, _ in layers]
    hidden = [shape[0] for shape in shapes[:-1]]
    recorded = _sb3_hidden_sizes(kwargs)
    if recorded is not None and recorded != hidden:
        raise ValueError(
            f"{path}: policy_kwargs net_arch gives hidden layers {recorded}, the weights {hidden}"
        )
    if shapes[0][1] != n_obs or shapes[-1][0] != n_act:
        raise ValueError(
            f"{path}: the weights map {shapes[0][1]} -> {shapes[-1][0]}, the spaces "
            f"{n_obs} -> {n_act}"
        )
    for name, ndim in kind["std"].items():
        shape = tuple(state[name].shape)
        if len(shape) != ndim or shape[0] != n_act:
            raise ValueError(
                f"{path}: {name} has shape {shape}: not the diagonal Gaussian of {n_act} "
                "actions this loader reads"
            )
    last = len(layers) - 1
    try:
        forward = MLPForward(
            [
                (
                    _weights(state[w]),
                    _weights(state[b]),
                    activation if k < last else ("tanh" if kind["squash"] else "identity"),
                )
                for k, (w, b) in enumerate(layers)
            ]
        )
    except (TypeError, ValueError, RuntimeError) as e:
        raise ValueError(f"{path}: the actor's weights are not usable: {e}") from None
    return SB3Actor(
        forward,
        -np.ones(n_act, dtype=np.float32),
        np.ones(n_act, dtype=np.float32),
        squash_output=bool(kind["squash"]),
        algo=algo,
    )


def _sb3_layers(
    state: Mapping[str, Any], kind: Mapping[str, Any], path: Path
) -> list[tuple[str, str]]:
    """The ``(weight, bias)`` names of the actor's layers in ``state``, hidden then head;
    ``ValueError`` for a parameter that is not one of an MLP actor, its log-std or the parts
    it does not use (value network, critics)."""
    hidden_prefix = f"{kind['hidden']}."
    pattern = re.compile(re.escape(hidden_prefix) + r"(0|[1-9][0-9]{0,5})\.(?:weight|bias)")
    indices = sorted(
        {int(match.group(1)) for match in map(pattern.fullmatch, state) if match is not None}
    )
    layers = [(f"{hidden_prefix}{i}.weight", f"{hidden_prefix}{i}.bias") for i in indices]
    layers.append((f"{kind['head']}.weight", f"{kind['head']}.bias"))
    actor = {name for pair in layers for name in pair} | set(kind["std"])
    missing = sorted(actor - set(state))
    unknown = sorted(
        key for key in state if key not in actor and not key.startswith(kind["unused"])
    )
    if indices != list(range(0, 2 * len(indices), 2)) or missing or unknown:
        raise ValueError(
            f"{path}: policy.pth is not the MLP actor this loader reads ("
            + "; ".join(
                ([f"missing {missing[:4]}"] if missing else [])
                + ([f"unexpected {unknown[:4]}"] if unknown else [])
                + (
                    [f"hidden layers at {indices}, not 0, 2, 4, ..."]
                    if indices != list(range(0, 2 * len(indices), 2))
                    else []
                )
            )
            + "); if you trust the file, LearnedPolicy.load_pickled loads it through SB3"
        )
    return layers


def _weights(tensor: Any) -> NDArray[np.float32]:
    """A tensor of the state dict as float32 (what :func:`training.forward.sb3_forward` reads
    of the SB3 module's parameter: the same values)."""
    if not tensor.is_floating_point():
        raise TypeError(f"a {tensor.dtype} tensor, not floating point")
    return np.array(tensor.detach().cpu().numpy(), dtype=np.float32)


#: ``model.json`` files already warned about (a ``format_version`` 1 file has no zip hash).
_WARNED_UNCHECKED: set[Path] = set()


def _input_size(model: Any) -> int | None:
    """The observation length a model reads (SB3: its observation space; an MLPActor or an
    SB3Actor: its input), or None when it does not say."""
    if isinstance(model, _ActorNetwork):
        return model.input_dim
    shape = getattr(getattr(model, "observation_space", None), "shape", None)
    return int(shape[0]) if shape else None


def _layout_text(layout: tuple[str, ...] | None) -> str:
    """``the 7-vector`` / ``task-aware observations (13 values)`` / ``N values``."""
    if layout == OBS_NAMES_SCALE_FREE:
        return f"scale-free task-aware observations ({len(layout)} values)"
    if layout == OBS_NAMES_TASK:
        return f"task-aware observations ({len(layout)} values)"
    if layout == OBS_NAMES:
        return f"the {len(layout)}-vector"
    return "an unknown layout" if layout is None else f"{len(layout)} values"


def _observation_mismatch(
    model: tuple[str, ...], shape: tuple[int, ...], env: tuple[str, ...] | None
) -> str:
    """Why a model reading ``model`` cannot read an env's observations of ``shape`` (layout
    ``env``), with what to do about the task-aware switch."""
    text = (
        f"observations: the model reads {_layout_text(model)}, the env gives "
        f"{_layout_text(env) if env is not None else 'shape ' + str(shape)}"
    )
    option = _LAYOUT_OPTIONS.get(tuple(model))
    if option is not None and env is not None and tuple(env) != tuple(model):
        text += f" (make the env with {option}, as the model was trained)"
    return text


def _dotted(value: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping flattened to ``{"a.b.c": leaf}`` (lists are leaves)."""
    if isinstance(value, Mapping):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_dotted(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: value}


def scenario_differences(
    first: Mapping[str, Any],
    second: Mapping[str, Any],
    labels: tuple[str, str] = ("trained", "env"),
    limit: int = 8,
) -> list[str]:
    """The dotted fields in which two resolved scenario mappings differ, as ``"field: trained
    X, env Y"`` (``labels`` name the two sides; at most ``limit``, then a count of the rest).
    ``name`` and ``description`` are left out: they change nothing the robots do."""
    a, b = _dotted(first), _dotted(second)
    keys = sorted(k for k in set(a) | set(b) if k not in ("name", "description"))
    diffs = [k for k in keys if a.get(k) != b.get(k)]

    def shown(v: Any) -> str:
        text = repr(v)
        return text if len(text) <= 40 else text[:37] + "..."

    out = [
        f"{k}: {labels[0]} {shown(a.get(k))}, {labels[1]} {shown(b.get(k))}" for k in diffs[:limit]
    ]
    if len(diffs) > limit:
        out.append(f"and {len(diffs) - limit} more")
    return out


def _drawn_followers(mapping: Any) -> tuple[int, int] | None:
    """The range ``(least, most)`` a training scenario drew each episode's followers from
    (``generator.formation.followers``), or None for a fixed count."""
    gen = mapping.get("generator") if isinstance(mapping, Mapping) else None
    formation = gen.get("formation") if isinstance(gen, Mapping) else None
    drawn = formation.get("followers") if isinstance(formation, Mapping) else None
    if isinstance(drawn, list | tuple) and len(drawn) == 2:
        return int(drawn[0]), int(drawn[1])
    return None


def _family(mapping: Mapping[str, Any] | None, name: Any) -> str:
    """``procedural corridor/train layouts`` or ``fixed workspace 'study_c'``."""
    gen = (mapping or {}).get("generator")
    if isinstance(gen, Mapping):
        return f"procedural {gen.get('kind')}/{gen.get('split')} layouts"
    return f"fixed workspace {name!r}"


class FastActor:
    """A model's deterministic action computed by its :class:`~training.forward.MLPForward`
    (what :func:`fast_actor` gives), optionally clipped to the action box ``[low, high]``.

    :attr:`key` names what it computes: two fast actors with equal keys give the same actions,
    so the batched evaluator runs the copies of a chunk through one call
    (:meth:`LearnedPolicy.act_group`). Built from a torch module, it follows the module's
    weights: a parameter changed in place (more training) rebuilds the forward at the next
    call (torch's version counters say when)."""

    def __init__(
        self,
        forward: MLPForward,
        low: NDArray[np.float32] | None = None,
        high: NDArray[np.float32] | None = None,
        module: Any = None,
    ) -> None:
        self.forward = forward
        self.low = low
        self.high = high
        self._clip = "" if low is None or high is None else f"{low.tolist()}{high.tolist()}"
        self._module = module
        self._parameters = [] if module is None else list(module.parameters())
        self._versions = self._read_versions()

    def _read_versions(self) -> tuple[int, ...]:
        """The version counters of the module's parameters (as listed when built: a parameter
        replaced by another object, rather than changed in place, is not seen)."""
        return tuple(p._version for p in self._parameters)

    def _sync(self) -> MLPForward:
        """The forward of the module's current weights."""
        if self._module is not None:
            versions = self._read_versions()
            if versions != self._versions:
                self._parameters = list(self._module.parameters())
                rebuilt = sb3_forward(self._module)
                if rebuilt is not None:
                    self.forward = rebuilt
                self._versions = versions
        return self.forward

    @property
    def key(self) -> tuple[str, str]:
        """The network's digest and the clip box."""
        return (self._sync().digest, self._clip)

    def __call__(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        out = self._sync()(obs)
        if self.low is None or self.high is None:
            return out
        return np.clip(out, self.low, self.high)


def fast_actor(model: Any, clip: bool = True) -> FastActor | None:
    """The deterministic action of ``model`` as a :class:`FastActor`, or None for a model it
    cannot compute (then ``predict`` is called): an SB3 ``ActorCriticPolicy`` with a diagonal
    Gaussian head, a Box action space and a plain MLP (:func:`training.forward.sb3_forward`;
    the mean clipped to the action space as ``predict(obs, deterministic=True)`` does, or with
    ``clip=False`` the mean itself: a residual policy adds it to its law's action before
    clipping), an :class:`SB3Actor` read from a PPO zip (the same forward and clip, from the
    same weights: the same actions to the bit; a SAC one goes through its ``predict``), or an
    :class:`MLPActor` (its output, unclipped as its ``predict``).

    It agrees with ``predict`` within float32 rounding, not to the bit: it sums in float64 in a
    fixed order so that each row is the same whatever the batch (:mod:`training.forward`)."""
    if isinstance(model, MLPActor):
        return FastActor(model.forward)
    if isinstance(model, SB3Actor):
        if model.squash_output:
            return None
        if not clip:
            return FastActor(model.forward)
        box = model.action_space
        return FastActor(model.forward, box.low.astype(np.float32), box.high.astype(np.float32))
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy

    policy = getattr(model, "policy", None)
    if not isinstance(policy, ActorCriticPolicy) or policy.squash_output:
        return None
    if not isinstance(policy.action_dist, DiagGaussianDistribution):
        return None
    space = policy.action_space
    if not isinstance(space, spaces.Box) or space.shape != (ACT_SIZE,):
        return None
    forward = sb3_forward(policy)
    if forward is None or forward.output_dim != ACT_SIZE:
        return None
    if not clip:
        return FastActor(forward, module=policy)
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    return FastActor(forward, low, high, module=policy)


def _read_metadata(meta_file: Path) -> tuple[dict[str, Any], int]:
    """A model's ``model.json`` and its ``format_version``; ``FileNotFoundError`` if it is
    missing, ``ValueError`` if it is not a readable one of this code's versions."""
    if not meta_file.is_file():
        raise FileNotFoundError(
            f"{meta_file} not found: a learned policy needs the JSON written beside its zip "
            "(action range, observation normalisation, control period)"
        )
    try:
        meta = json.loads(meta_file.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{meta_file} is not valid JSON: {e}") from None
    except RecursionError:
        raise ValueError(f"{meta_file} is not valid JSON: nested too deep") from None
    if not isinstance(meta, dict) or meta.get("format") != METADATA_FORMAT:
        raise ValueError(f"{meta_file} is not a {METADATA_FORMAT} file")
    version = meta.get("format_version", 0)
    if not isinstance(version, int) or version > METADATA_VERSION:
        raise ValueError(
            f"{meta_file} has format_version {version!r}; this code reads up to {METADATA_VERSION}"
        )
    return meta, version


def _check_zip(path: Path, meta: Mapping[str, Any], version: int, meta_file: Path) -> None:
    """Refuse a zip whose SHA-256 is not the one its JSON records (``ValueError``); a
    ``format_version`` 1 JSON records none: warn once per file that it cannot be checked."""
    where = str(meta_file)
    if meta.get("zip_sha256") is not None:
        reason = zip_mismatch(path, meta)
        if reason is not None:
            raise ValueError(f"{where}: refusing to load: {reason}")
        return
    if version >= 2:
        raise ValueError(
            f"{where}: format_version {version} but no zip_sha256: cannot tell whether "
            f"{path.name} belongs to it"
        )
    key = meta_file.resolve()
    if key not in _WARNED_UNCHECKED:
        _WARNED_UNCHECKED.add(key)
        warnings.warn(
            f"{where} predates zip hashes (format_version {version}): cannot check "
            f"that {path.name} belongs to it",
            UserWarning,
            stacklevel=4,  # the caller of LearnedPolicy.load (or load_pickled)
        )


def _load_model(
    path: Path, meta: Mapping[str, Any], meta_file: Path, device: str, pickled: bool = False
) -> tuple[BaseAlgorithm | MLPActor | SB3Actor, tuple[Any, Any]]:
    """The model of ``path`` by ``meta``'s ``engine`` (SB3, or an exported RLlib actor) and
    its input and output sizes (None where a space has no shape). An SB3 zip is read
    weights-only (:func:`read_sb3_actor`) unless ``pickled``: then through SB3's loader, which
    unpickles the zip's objects (:meth:`LearnedPolicy.load_pickled`)."""
    engine = str(meta.get("engine", "sb3")).lower()
    if engine == "rllib":
        actor = meta.get("actor") or {}
        if actor.get("type", "mlp") != "mlp" or actor.get("activation", "tanh") != "tanh":
            raise ValueError(f"{meta_file}: unknown exported actor {actor!r}")
        mlp = MLPActor.load(path)
        return mlp, (mlp.input_dim, mlp.output_dim)
    if engine == "sb3":
        algo = str(meta["algo"]).lower()
        if algo not in ALGORITHMS:
            raise ValueError(
                f"{meta_file}: unknown algo {algo!r}, expected one of {list(ALGORITHMS)}"
            )
        if not pickled:
            sb3 = read_sb3_actor(path, TRAINING_ALGORITHMS[algo].sb3_class)
            return sb3, (sb3.input_dim, sb3.output_dim)
        model = ALGORITHMS[algo].load(path, device=device)  # unpickles: asked for by name
        obs_shape = getattr(model.observation_space, "shape", None) or (None,)
        act_shape = getattr(model.action_space, "shape", None) or (None,)
        return model, (obs_shape[0], act_shape[0])
    raise ValueError(f"{meta_file}: unknown engine {engine!r}, expected one of {ENGINES}")


def _input_layout(
    meta: Mapping[str, Any], dims: tuple[Any, Any], meta_file: Path
) -> tuple[int, tuple[str, ...] | None]:
    """The env observation's length a model of input and output sizes ``dims`` reads (its
    input less a previous command's two values) and the recorded observation layout (None:
    not recorded); ``ValueError`` if they are not a known layout mapped to 2 actions."""
    where = str(meta_file)
    extra = ACT_SIZE if meta.get("previous_command", False) else 0
    n_obs = None if dims[0] is None else dims[0] - extra
    if n_obs not in OBSERVATION_LAYOUTS or dims[1] != ACT_SIZE:
        read = f"{dims[0]} ({n_obs} + the previous command)" if extra else dims[0]
        raise ValueError(
            f"{meta_file}: the model maps {read} -> {dims[1]}, expected "
            f"{_sizes_text(None)}{' + 2' if extra else ''} -> {ACT_SIZE}"
        )
    layout = _parse_layout(meta.get("observation_layout"), where)
    if layout is not None and len(layout) != n_obs:
        raise ValueError(
            f"{meta_file}: observation_layout has {len(layout)} names, the model reads "
            f"{n_obs} observations"
        )
    return n_obs, layout


class LearnedPolicy:
    """A trained model (SB3, or an RLlib actor) acting for every follower (parameter sharing).

    ``act`` stacks the followers' observations, applies the training normalisation, calls the
    model's deterministic ``predict`` once for the batch and maps the actions back to physical
    ``[u, omega]``. A plain policy is stateless (an MLP). Two kinds keep state over an episode,
    so call :meth:`reset` at every episode start (after ``env.reset``), as for every policy: a
    residual policy (its law), and one that reads its own previous command
    (:attr:`previous_command`; each follower's last normalised command, the standstill after
    :meth:`reset`).

    Evaluate it at :attr:`control_period` (the period it was trained at), e.g.
    ``platoon_env.make(scenario, control_period=policy.control_period)``, unless you mean to
    test it at another one; :meth:`check_env` says whether an env suits the model.

    :meth:`load` reads a model without unpickling anything (an SB3 zip's weights only);
    :meth:`load_pickled` gives the full SB3 object and unpickles the zip: only for files you
    trust.

    Args:
        model: the SB3 model (its action space ``[-1, 1]^2`` if ``action_range`` is given), an
            :class:`SB3Actor` (an SB3 model's actor read from its weights, what :meth:`load`
            gives) or an :class:`MLPActor` (an RLlib-trained policy).
        action_range: physical range of the normalised action, or None (a model that outputs
            physical actions; :meth:`load` never gives None, see :func:`parse_action_range`).
        obs_scale: the observation divisor used in training, or None (raw observations).
        control_period: [s] the env control period the model was trained at.
        metadata: the rest of ``model.json`` (scenario, config, seed, ...), for reference.
        observation_layout: the names of the observations the model reads (one of
            :data:`OBSERVATION_LAYOUTS`); None: ``metadata``'s ``observation_layout``, else the
            layout of ``obs_scale``'s length, else of the model's input size, else the 7-vector.
    """

    def __init__(
        self,
        model: BaseAlgorithm | Predictor,
        *,
        action_range: ActionRange | None,
        obs_scale: NDArray[Any] | None,
        control_period: float,
        metadata: Mapping[str, Any] | None = None,
        observation_layout: tuple[str, ...] | list[str] | None = None,
    ) -> None:
        self.model = model
        self.action_range = action_range
        self.obs_scale = None if obs_scale is None else np.asarray(obs_scale, dtype=np.float32)
        self.control_period = float(control_period)
        self.metadata: dict[str, Any] = dict(metadata or {})
        previous = self.metadata.get("previous_command", False)
        if not isinstance(previous, bool) or (previous and action_range is None):
            raise ValueError(
                f"previous_command must be true (with an action range) or false, got {previous!r}"
            )
        #: Whether the model reads, after the observation, each follower's previous command
        #: (normalised, clipped to ``[-1, 1]``; ``model.json``'s ``previous_command``).
        self.previous_command: bool = previous
        if observation_layout is None:
            recorded = self.metadata.get("observation_layout")
            if isinstance(recorded, list | tuple):
                observation_layout = tuple(recorded)
            else:
                size = _input_size(model) if self.obs_scale is None else self.obs_scale.shape[0]
                if size is not None and self.obs_scale is None and self.previous_command:
                    size -= ACT_SIZE  # the input less the previous command's two values
                observation_layout = OBSERVATION_LAYOUTS.get(size or len(OBS_NAMES), OBS_NAMES)
        #: The names of the observations the model reads, in order.
        self.observation_layout: tuple[str, ...] = tuple(observation_layout)
        residual = self.metadata.get("residual")
        if residual is not None and (residual not in EXPERTS or action_range is None):
            raise ValueError(
                f"residual must be one of {tuple(EXPERTS)} with an action range, got {residual!r}"
            )
        #: The analytic law a residual policy adds its output to (``model.json``'s
        #: ``residual``; :mod:`training.experts`), or None for a plain policy.
        self.residual: str | None = residual
        self._standstill: NDArray[np.float32] | None = (
            None if action_range is None else to_normalised(np.zeros(2), action_range)[0]
        )
        self._sent: dict[str, NDArray[np.float32]] = {}
        self._env: Any = None
        self._law: Any = None
        self._fast: FastActor | None = None
        self._fast_checked = False
        self._group_key: tuple[Any, ...] | None = None
        n = len(self.observation_layout)
        if self.obs_scale is not None and self.obs_scale.shape != (n,):
            raise ValueError(
                f"obs_scale must have shape ({n},) (the observation layout), got "
                f"{self.obs_scale.shape}"
            )

    @property
    def observation_size(self) -> int:
        """The length of the env observation the model reads (7; task-aware 13, scale-free
        15)."""
        return len(self.observation_layout)

    @property
    def input_size(self) -> int:
        """The length of the model's input: :attr:`observation_size`, plus 2 with
        :attr:`previous_command`."""
        return self.observation_size + (ACT_SIZE if self.previous_command else 0)

    @property
    def task_aware(self) -> bool:
        """Whether the model reads task-aware observations: act in envs made with
        ``observation={"task_aware": True}`` (and, :attr:`scale_free`, ``"scale_free": True``)."""
        return self.observation_layout in (OBS_NAMES_TASK, OBS_NAMES_SCALE_FREE)

    @property
    def scale_free(self) -> bool:
        """Whether the model reads scale-free observations: act in envs made with
        ``observation={"task_aware": True, "scale_free": True}``."""
        return self.observation_layout == OBS_NAMES_SCALE_FREE

    @property
    def scenario(self) -> str | None:
        """The scenario the model was trained on, as it was given (from ``model.json``)."""
        scenario = self.metadata.get("scenario")
        return None if scenario is None else str(scenario)

    @property
    def scenario_fingerprint(self) -> str | None:
        """The SHA-256 of the resolved training scenario (None: not recorded, an old model)."""
        fp = self.metadata.get("scenario_fingerprint")
        return None if fp is None else str(fp)

    @classmethod
    def load(cls, path: str | os.PathLike[str], device: str = "cpu") -> LearnedPolicy:
        """Load ``DIR/model.zip`` (or ``DIR``) and the ``model.json`` beside it, by its
        ``engine``: an SB3 PPO or SAC model, read weights-only as an :class:`SB3Actor`, or an
        RLlib actor exported as arrays (:class:`MLPActor`). Nothing is unpickled: an SB3 zip's
        ``policy.pth`` is read with ``torch.load(weights_only=True)`` and its ``data`` entry as
        JSON whose cloudpickled fields are never decoded (:func:`read_sb3_actor`); a crafted
        zip cannot run code here. The actions are those of the SB3 object (the same
        :class:`~training.forward.MLPForward` as through SB3 for PPO, so the same to the bit).

        Refuses (``ValueError`` with the reason) a zip whose SHA-256 is not the one its JSON
        records, a missing, null or malformed ``action_range``, a malformed normalisation or
        control period, and a model that does not map 7 (task-aware: 13) observations to 2
        actions, or whose recorded layout or normalisation has another length; a missing
        ``model.json`` is a ``FileNotFoundError``. A ``format_version`` 1 file (no zip hash)
        loads with a ``UserWarning`` (once per file). An SB3 zip whose actor is not the plain
        MLP :func:`read_sb3_actor` reads (another policy class, a feature extractor, gSDE, an
        activation other than Tanh or ReLU) is refused, naming
        :meth:`load_pickled`; an exported actor whose ``.npy`` headers declare layers that do
        not chain or exceed :data:`MAX_LAYER_UNITS` / :data:`MAX_PARAMETERS` is refused before
        its data is read. See the module doc.

        ``device`` is not used (the actor computes on the CPU with NumPy); it is kept for
        callers written for SB3's loader.
        """
        return cls._load(path, device, pickled=False)

    @classmethod
    def load_pickled(cls, path: str | os.PathLike[str], device: str = "cpu") -> LearnedPolicy:
        """What :meth:`load` gives, with the full SB3 object as :attr:`model` (SB3's
        ``PPO.load``/``SAC.load`` on ``device``): for SB3's own ``predict`` (sampling
        included), its torch modules, or a model :func:`read_sb3_actor` does not read. The same
        checks as :meth:`load` (hash, metadata, shapes) come first. An exported RLlib actor
        loads as with :meth:`load` (no pickles).

        .. warning:: This unpickles Python objects from the zip (SB3's ``data`` entry is
           cloudpickled), which can execute arbitrary code: use it only on files you trust.
           Nothing in the evaluators, the leaderboard or the examples calls it.
        """
        return cls._load(path, device, pickled=True)

    @classmethod
    def _load(cls, path: str | os.PathLike[str], device: str, *, pickled: bool) -> LearnedPolicy:
        path = Path(path)
        if path.is_dir():
            path = path / "model.zip"
        meta_file = metadata_path(path)
        meta, version = _read_metadata(meta_file)
        if not path.is_file():
            raise FileNotFoundError(f"{path} not found (its JSON {meta_file.name} is there)")
        where = str(meta_file)
        _check_zip(path, meta, version, meta_file)
        _check_metadata(meta, where)
        model, dims = _load_model(path, meta, meta_file, device, pickled)
        n_obs, layout = _input_layout(meta, dims, meta_file)
        return cls(
            model,
            action_range=parse_action_range(meta["action_range"], where),
            obs_scale=_parse_normalization(meta["observation_normalization"], where, n_obs),
            control_period=_parse_control_period(meta["control_period"], where),
            metadata=meta,
            observation_layout=layout or OBSERVATION_LAYOUTS[n_obs],
        )

    def check_env(self, env: Any, *, allow_control_period: bool = False) -> list[str]:
        """Check that ``env`` is one this model can meaningfully act in; returns notes on the
        legitimate differences. ``env``: a ``PlatoonParallelEnv`` (or anything with its
        ``possible_agents``, ``observation_space(agent)``, ``action_space(agent)``,
        ``control_period`` and, to compare scenarios, ``source.config``).

        Refused (``ValueError`` listing every reason):

        * an observation or action layout other than the one the model was trained on (the
          model would read the wrong quantities or command the wrong ones: the numbers mean
          nothing), in particular a model trained on the 7-vector in an env with task-aware
          observations (13 values) and vice versa;
        * another control period, unless ``allow_control_period`` (the model would hold each
          action a different time than it learned to; almost always a forgotten
          ``control_period=policy.control_period``, but testing robustness to the period is a
          legitimate experiment, hence the switch).

        Allowed, each returned as a note (these are the experiments the benchmark is for):

        * another scenario, or another family: a model trained on procedural layouts evaluated
          on ``study_a``, on held-out layouts, with a sensor profile, other robots or camera
          (the note names the fields that differ);
        * another number of followers (one shared per-follower policy acts for each);
        * observations that can exceed the training normalisation (the policy extrapolates),
          and an action range beyond the env's actuator limits (the env clips the commands);
        * a model whose ``model.json`` does not record its training scenario's content.

        A model evaluated on its own training scenario gets no note (a procedural training
        split: a note that the layouts are not held out).
        """
        agents = list(env.possible_agents)
        obs_space = env.observation_space(agents[0])
        act_space = env.action_space(agents[0])
        source = getattr(env, "source", None)
        cfg = getattr(source, "config", None)
        refusals = self._layout_refusals(cfg, tuple(obs_space.shape), tuple(act_space.shape))
        notes: list[str] = []
        period = self._period_mismatch(float(env.control_period))
        if period is not None and allow_control_period:
            notes.append(period + " (allowed: allow_control_period)")
        elif period is not None:
            refusals.append(
                period + " (make the env with control_period=policy.control_period, or pass "
                "allow_control_period=True to test the policy at another period)"
            )
        notes += self._follower_notes(len(agents))
        scenario = self._scenario_note(source, cfg)
        if scenario is not None:
            notes.append(scenario)
        notes += self._range_notes(obs_space, act_space)
        if refusals:
            raise ValueError(
                f"model trained on {self.scenario!r} cannot act meaningfully in this env: "
                + "; ".join(refusals)
            )
        return notes

    def _layout_refusals(
        self, cfg: Any, shape: tuple[int, ...], act_shape: tuple[int, ...]
    ) -> list[str]:
        """Why an env of observation shape ``shape``, action shape ``act_shape`` and scenario
        config ``cfg`` (None: unknown) has another observation or action layout."""
        refusals: list[str] = []
        env_layout = (
            observation_names(cfg) if cfg is not None else OBSERVATION_LAYOUTS.get(shape[0])
        )
        if shape != (self.observation_size,):
            refusals.append(_observation_mismatch(self.observation_layout, shape, env_layout))
        if act_shape != (ACT_SIZE,):
            refusals.append(f"env actions have shape {act_shape}, the model outputs {ACT_SIZE}")
        for key, current in (
            ("observation_layout", env_layout if shape == (self.observation_size,) else None),
            ("action_layout", ACTION_LAYOUT),
        ):
            recorded = self.metadata.get(key)
            if recorded is not None and current is not None and tuple(recorded) != current:
                refusals.append(f"{key}: trained on {list(recorded)}, the env has {list(current)}")
        return refusals

    def _period_mismatch(self, period: float) -> str | None:
        """How an env's control period ``period`` [s] differs from the training one (None:
        it does not)."""
        if math.isclose(period, self.control_period, rel_tol=1e-9, abs_tol=0.0):
            return None
        return (
            f"control period: trained at {self.control_period:g} s, the env steps at {period:g} s"
        )

    def _follower_notes(self, n_agents: int) -> list[str]:
        """A note if an env's ``n_agents`` followers are not the training formation's."""
        trained_n = self.metadata.get("n_followers")
        drawn = _drawn_followers(self.metadata.get("scenario_config"))
        if drawn is not None and not drawn[0] <= n_agents <= drawn[1]:
            return [
                f"followers: trained with {drawn[0]}-{drawn[1]} drawn per episode, the env has "
                f"{n_agents} (allowed: one shared per-follower policy)"
            ]
        if drawn is None and trained_n is not None and int(trained_n) != n_agents:
            return [
                f"followers: trained with {trained_n}, the env has {n_agents} (allowed: one "
                "shared per-follower policy)"
            ]
        return []

    def _scenario_note(self, source: Any, cfg: Any) -> str | None:
        """How an env's scenario (``source``, its config ``cfg``) relates to the training one
        (None: it is the training scenario, not a procedural split)."""
        fingerprint = self.scenario_fingerprint
        if cfg is None:
            return "the env exposes no resolved scenario config: scenario not compared"
        if fingerprint is None:
            return (
                f"model.json records no training scenario content (only the name "
                f"{self.scenario!r}): scenario not compared"
            )
        given = config_fingerprint(cfg)
        mapping = config_mapping(cfg)
        trained_map = self.metadata.get("scenario_config")
        if given != fingerprint:
            fields = (
                scenario_differences(trained_map, mapping)
                if isinstance(trained_map, Mapping)
                else []
            )
            return (
                f"scenario: trained on {_family(trained_map, self.scenario)} "
                f"({fingerprint[:12]}), the env is {_family(mapping, cfg.name)} "
                f"({given[:12]}); allowed (an evaluation on another scenario)"
                + (f"; differs in {'; '.join(fields)}" if fields else "")
            )
        if getattr(source, "procedural", False):
            return (
                f"scenario: the env draws from the training layouts "
                f"({_family(mapping, cfg.name)}): not held out"
            )
        return None

    def _range_notes(self, obs_space: Any, act_space: Any) -> list[str]:
        """Notes if an env's observations can exceed the training normalisation, or the
        action range its actuator limits."""
        notes: list[str] = []
        if self.obs_scale is not None:
            bound = np.maximum(np.abs(obs_space.low), np.abs(obs_space.high))
            over = [
                f"{name} {b:g} > {s:g}"
                for name, b, s in zip(self.observation_layout, bound, self.obs_scale, strict=False)
                if b > s * (1 + 1e-6)
            ]
            if over:
                notes.append(
                    "observations can exceed the training normalisation ("
                    + ", ".join(over)
                    + "): the policy extrapolates there"
                )
        if self.action_range is not None:
            r = self.action_range
            high = np.asarray(act_space.high, dtype=np.float64)
            if max(r.u_high, -r.u_low) > high[0] * (1 + 1e-6) or r.omega_high > high[1] * (
                1 + 1e-6
            ):
                notes.append(
                    f"the action range (u in [{r.u_low:g}, {r.u_high:g}] m/s, |omega| <= "
                    f"{r.omega_high:g} rad/s) exceeds the env's actuator limits (|u| <= "
                    f"{high[0]:g}, |omega| <= {high[1]:g}): the env clips the commands"
                )
        return notes

    def bind(self, env: Any) -> None:
        """Give a residual policy (:attr:`residual`) the env it acts in: its law is built on
        ``env`` (the law reads the followers, the control period and the scenario at
        construction) and rebuilt at every :meth:`reset`, after ``env.reset``. A law refusing
        the env raises its ``ValueError``. Nothing to do for a plain policy."""
        if self.residual is None:
            return
        self._env = env
        self._law = EXPERTS[self.residual](env)

    def _unbound(self) -> RuntimeError:
        return RuntimeError(
            f"a residual policy on {self.residual!r} needs its env: call bind(env) first"
        )

    def reset(self, seed: int | None = None) -> None:
        """Start an episode (call after ``env.reset``). A plain policy acts deterministically
        and has nothing to restore; with :attr:`previous_command` every follower's previous
        command is the standstill again; a residual policy's law starts over on its env's
        current scenario."""
        self._sent = {}
        if self.residual is None:
            return
        if self._env is None:
            raise self._unbound()
        self._law = EXPERTS[self.residual](self._env)
        self._law.reset(seed=seed)

    def _fast_actor(self) -> FastActor | None:
        """The model's :class:`FastActor` (built on first use), or None: ``predict`` is used."""
        if not self._fast_checked:
            self._fast = fast_actor(self.model, clip=self.residual is None)
            self._fast_checked = True
            if self._fast is None and self.residual is not None:
                raise ValueError("a residual policy needs an SB3 PPO model with a Gaussian head")
        return self._fast

    def _deterministic(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        """The model's deterministic actions for a batch of (scaled) observations.

        For an SB3 actor-critic (PPO) with a Gaussian head and an MLP, and for an RLlib
        actor, the network's mean is computed by :class:`~training.forward.MLPForward` (clipped
        to the action space as ``model.predict(obs, deterministic=True)`` does, unless the
        policy is a residual): each row the same to the bit whatever the batch, within float32
        rounding of ``predict`` (tested), and without ``predict``'s per-call bookkeeping. Other
        models go through ``predict``.
        """
        fast = self._fast_actor()
        if fast is not None:
            return fast(obs)
        actions, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(actions, dtype=np.float32).reshape(len(obs), ACT_SIZE)

    def act(self, observations: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[np.float32]]:
        """Map ``{agent: observation (7,) or, task-aware, (13,)}`` to ``{agent: float32 [u,
        omega]}`` in one batch."""
        agents, inputs = self._model_input(observations)
        if not agents:
            return {}
        return self._commands(agents, observations, self._deterministic(inputs))

    @classmethod
    def act_group(
        cls,
        policies: Sequence[LearnedPolicy],
        observations: Sequence[Mapping[str, NDArray[Any]]],
    ) -> list[dict[str, NDArray[np.float32]]]:
        """What ``[p.act(o) for p, o in zip(policies, observations)]`` returns, with one
        network call for all the policies that compute the same network (equal
        :attr:`FastActor.key`, residual law, action range and previous-command input, e.g. the
        copies of one model in a chunk of the batched evaluator,
        :mod:`experiments.batched_eval`), and the element-wise steps of :meth:`_commands` (a
        residual's law added, the clip, the physical range) done once on the stacked rows; a
        residual's law itself still acts per policy (it keeps its own state). The results are
        those of each ``act`` to the bit: the forward pass does not depend on the batch
        (:mod:`training.forward`) and the rest is element-wise."""
        if len(policies) != len(observations):
            raise ValueError(
                f"act_group needs one observation dict per policy, got {len(observations)} "
                f"for {len(policies)}"
            )
        out: list[dict[str, NDArray[np.float32]] | None] = [None] * len(policies)
        groups: dict[tuple[Any, ...], list[tuple[int, list[str], NDArray[np.float32]]]] = {}
        for i, (policy, obs) in enumerate(zip(policies, observations, strict=True)):
            fast = policy._fast_actor()
            if fast is None:  # predict's path: the policy alone
                out[i] = policy.act(obs)
                continue
            agents, inputs = policy._model_input(obs)
            if not agents:
                out[i] = {}
                continue
            if policy._group_key is None:  # what else must match for one batch (fixed)
                policy._group_key = (policy.residual, policy.previous_command,
                                     repr(policy.action_range))  # fmt: skip
            key = (*fast.key, *policy._group_key)
            groups.setdefault(key, []).append((i, agents, inputs))
        for members in groups.values():
            first = policies[members[0][0]]
            fast = first._fast_actor()
            assert fast is not None  # grouped by its key
            actions = fast(np.concatenate([inputs for _, _, inputs in members]))
            laws = (
                None
                if first.residual is None  # each copy's own law; added in one batch below
                else np.concatenate([policies[i]._law_rows(agents, observations[i])
                                     for i, agents, _ in members])
            )  # fmt: skip
            actions, physical = first._finish(actions, laws)
            start = 0
            for i, agents, _ in members:
                out[i] = policies[i]._keep(agents, actions[start:], physical[start:])
                start += len(agents)
        return [o if o is not None else {} for o in out]

    def _model_input(
        self, observations: Mapping[str, NDArray[Any]]
    ) -> tuple[list[str], NDArray[np.float32]]:
        """The agents and the model's input rows: each observation checked, scaled by the
        training normalisation, followed by the agent's previous command if the model reads
        it."""
        agents = list(observations)
        if not agents:
            return agents, np.zeros((0, self.input_size), dtype=np.float32)
        obs = np.stack([np.asarray(observations[a], dtype=np.float32) for a in agents])
        n = self.observation_size
        if obs.shape != (len(agents), n):
            raise ValueError(
                f"observations must have shape ({n},) "
                f"({_layout_text(self.observation_layout)}), got {obs.shape[1:]}"
            )
        if self.obs_scale is not None:
            obs = obs / self.obs_scale
        if self.previous_command:
            assert self._standstill is not None  # checked at construction
            sent = [self._sent.get(a, self._standstill) for a in agents]
            obs = np.concatenate([obs, np.stack(sent)], axis=1, dtype=np.float32)
        return agents, obs

    def _commands(
        self,
        agents: list[str],
        observations: Mapping[str, NDArray[Any]],
        actions: NDArray[np.float32],
    ) -> dict[str, NDArray[np.float32]]:
        """The physical commands of the model's normalised ``actions`` (one row per agent):
        a residual policy's law added, the previous commands kept."""
        laws = None if self.residual is None else self._law_rows(agents, observations)
        actions, physical = self._finish(actions, laws)
        return self._keep(agents, actions, physical)

    def _law_rows(
        self, agents: list[str], observations: Mapping[str, NDArray[Any]]
    ) -> NDArray[Any]:
        """A residual policy's law's commands for ``agents`` (one row each; the law acts, so
        its state moves on)."""
        if self._law is None:
            raise self._unbound()
        law = self._law.act(observations)
        return np.stack([law[a] for a in agents])

    def _finish(
        self, actions: NDArray[np.float32], laws: NDArray[Any] | None
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """The normalised and the physical commands of the model's ``actions``, the law's rows
        ``laws`` (physical) added for a residual policy, then clipped to ``[-1, 1]``.
        Element-wise: the rows of several policies of one :meth:`act_group` batch come out as
        each policy's alone would."""
        if laws is not None:
            assert self.action_range is not None  # checked at construction
            base, _ = to_normalised(laws, self.action_range)
            actions = np.clip(actions + base, -1.0, 1.0)
        if self.action_range is None:
            return actions, actions
        return actions, self.action_range.to_physical(actions)

    def _keep(
        self, agents: list[str], actions: NDArray[np.float32], physical: NDArray[np.float32]
    ) -> dict[str, NDArray[np.float32]]:
        """``{agent: command}`` from the first ``len(agents)`` rows, remembering the normalised
        ones as the previous commands when the model reads them."""
        if self.previous_command:
            self._sent = {a: actions[i].copy() for i, a in enumerate(agents)}
        return {a: physical[i].copy() for i, a in enumerate(agents)}
