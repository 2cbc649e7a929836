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

.. warning::
    Loading an SB3 model unpickles Python objects from the zip, which can execute arbitrary
    code. Load only model files you trust. (An exported RLlib actor is read with
    ``allow_pickle=False``.) The hash check guards against mixed-up files, not against an
    attacker, who can rewrite both.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import warnings
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
    "METADATA_FORMAT",
    "OBSERVATION_LAYOUT",
    "OBSERVATION_LAYOUTS",
    "LearnedPolicy",
    "MLPActor",
    "adapter_metadata",
    "metadata_path",
    "parse_action_range",
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


class MLPActor:
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

    @property
    def input_dim(self) -> int:
        """Length of an observation."""
        return self.forward.input_dim

    @property
    def output_dim(self) -> int:
        """Length of an action."""
        return self.forward.output_dim

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
        """Read the ``.npz`` archive at ``path`` (``allow_pickle=False``)."""
        with np.load(path, allow_pickle=False) as data:
            return cls.from_arrays({k: data[k] for k in data.files})

    def predict(
        self, observation: NDArray[Any], deterministic: bool = True
    ) -> tuple[NDArray[np.float32], None]:
        """The actions ``(B, output_dim)`` for observations ``(B, input_dim)`` (always greedy)."""
        return self.forward(np.asarray(observation, dtype=np.float32)), None


#: ``model.json`` files already warned about (a ``format_version`` 1 file has no zip hash).
_WARNED_UNCHECKED: set[Path] = set()


def _input_size(model: Any) -> int | None:
    """The observation length a model reads (SB3: its observation space; an MLPActor: its
    input), or None when it does not say."""
    if isinstance(model, MLPActor):
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
    clipping), or an :class:`MLPActor` (its output, unclipped as its ``predict``).

    It agrees with ``predict`` within float32 rounding, not to the bit: it sums in float64 in a
    fixed order so that each row is the same whatever the batch (:mod:`training.forward`)."""
    if isinstance(model, MLPActor):
        return FastActor(model.forward)
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
            stacklevel=3,  # the caller of LearnedPolicy.load
        )


def _load_model(
    path: Path, meta: Mapping[str, Any], meta_file: Path, device: str
) -> tuple[BaseAlgorithm | MLPActor, tuple[Any, Any]]:
    """The model of ``path`` by ``meta``'s ``engine`` (SB3, or an exported RLlib actor) and
    its input and output sizes (None where a space has no shape)."""
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
        model = ALGORITHMS[algo].load(path, device=device)
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

    .. warning::
        :meth:`load` unpickles code from the model zip: load only files you trust.

    Args:
        model: the SB3 model (its action space ``[-1, 1]^2`` if ``action_range`` is given), or
            an :class:`MLPActor` (an RLlib-trained policy).
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
        ``engine``: an SB3 model, or an RLlib actor exported as arrays (:class:`MLPActor`).

        Refuses (``ValueError`` with the reason) a zip whose SHA-256 is not the one its JSON
        records, a missing, null or malformed ``action_range``, a malformed normalisation or
        control period, and a model that does not map 7 (task-aware: 13) observations to 2
        actions, or whose recorded layout or normalisation has another length; a missing
        ``model.json`` is a ``FileNotFoundError``. A ``format_version`` 1 file (no zip hash)
        loads with a ``UserWarning`` (once per file). See the module doc.

        .. warning:: For SB3 this unpickles code from the zip: load only files you trust.
        """
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
        model, dims = _load_model(path, meta, meta_file, device)
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
