"""Learned policies behind the shared policy interface (``docs/api.md``).

A trained model is saved as two files side by side::

    DIR/model.zip    the Stable-Baselines3 model (PPO or SAC), as ``model.save`` writes it
    DIR/model.json   everything else needed to act with it, and how it was made:

        {
          "format": "platoon_env.learned_policy", "format_version": 1,
          "algo": "ppo",                       # which SB3 class loads model.zip
          "scenario": "study_c",               # scenario trained on
          "control_period": 0.05,              # [s] period the policy was trained at
          "observation_normalization": {"type": "fixed_scale", "scale": [1, 1.5, ...]},
          "action_range": {"u_low": -0.5, "u_high": 1.5, "omega_high": 2.0},
          "config": {...}, "git_commit": "...", "seed": 0, "timesteps": ..., ...
        }

The observation normalisation is fixed (not a running mean): the policy sees
``obs / scale``, with ``scale`` the upper bound of the training env's observation Box, stored
as numbers so that the same division is applied whatever env the policy is evaluated on. The
action rescaling maps the policy's ``[-1, 1]^2`` to ``[u_low, u_high] x [-omega_high,
omega_high]`` (:class:`training.vec_env.ActionRange`). ``null`` for either means none was used.
So ``LearnedPolicy.load("DIR/model.zip")`` needs no other file.

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
    ``allow_pickle=False``.)
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm

from platoon_env.observation import ACT_SIZE, OBS_SIZE
from training.vec_env import ActionRange

__all__ = [
    "ALGORITHMS",
    "ENGINES",
    "METADATA_FORMAT",
    "LearnedPolicy",
    "MLPActor",
    "adapter_metadata",
    "metadata_path",
    "save_exported_policy",
    "save_model",
]

#: The SB3 algorithms a learned policy can be, by the name stored in ``model.json``.
ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC}
METADATA_FORMAT = "platoon_env.learned_policy"
METADATA_VERSION = 1
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


def _atomic_write(path: Path, write: Any) -> None:
    """Call ``write(file)`` on a temporary file beside ``path``, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; outputs are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_model(
    model: BaseAlgorithm, path: str | os.PathLike[str], metadata: Mapping[str, Any]
) -> Path:
    """Write ``model`` to ``path`` (a ``.zip``) and ``metadata`` to the JSON beside it.

    Both files are written atomically (temporary file + ``os.replace``), so an interruption
    leaves the previous version intact. ``metadata`` must hold at least ``algo`` and
    ``control_period``, plus the keys of :func:`adapter_metadata`. Returns the zip's path.
    """
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"model path must end in .zip, got {path}")
    missing = {"algo", "control_period", "observation_normalization", "action_range"} - set(
        metadata
    )
    if missing:
        raise ValueError(f"metadata lacks {sorted(missing)}")
    doc = {"format": METADATA_FORMAT, "format_version": METADATA_VERSION, **metadata}
    text = json.dumps(doc, indent=2, sort_keys=False, default=str).encode()
    _atomic_write(path, model.save)
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
    missing = {
        "engine",
        "algo",
        "control_period",
        "observation_normalization",
        "action_range",
    } - set(metadata)
    if missing:
        raise ValueError(f"metadata lacks {sorted(missing)}")
    MLPActor.from_arrays(arrays)  # fail before writing anything if the layers do not chain
    doc = {"format": METADATA_FORMAT, "format_version": METADATA_VERSION, **metadata}
    text = json.dumps(doc, indent=2, sort_keys=False, default=str).encode()
    arrays = {k: np.asarray(v, dtype=np.float32) for k, v in arrays.items()}
    _atomic_write(path, lambda f: np.savez(f, allow_pickle=False, **arrays))
    _atomic_write(metadata_path(path), lambda f: f.write(text))
    return path


class MLPActor:
    """A deterministic MLP actor from plain arrays: ``y = W_L tanh(... tanh(W_0 x + b_0) ...)
    + b_L`` (no activation after the last layer), with SB3's ``predict`` signature.

    This is how an RLlib-trained policy (:mod:`training.rllib`) is evaluated: the mean of its
    Gaussian, computed with NumPy (no Ray, no torch, no unpickling).
    """

    def __init__(self, layers: list[tuple[NDArray[np.float32], NDArray[np.float32]]]) -> None:
        if not layers:
            raise ValueError("an MLPActor needs at least one layer")
        for k, (w, b) in enumerate(layers):
            if w.ndim != 2 or b.shape != (w.shape[0],):
                raise ValueError(f"layer {k}: weight {w.shape} and bias {b.shape} do not match")
            if k and w.shape[1] != layers[k - 1][0].shape[0]:
                raise ValueError(
                    f"layer {k} takes {w.shape[1]} inputs, layer {k - 1} gives "
                    f"{layers[k - 1][0].shape[0]}"
                )
        self.layers = layers

    @property
    def input_dim(self) -> int:
        """Length of an observation."""
        return int(self.layers[0][0].shape[1])

    @property
    def output_dim(self) -> int:
        """Length of an action."""
        return int(self.layers[-1][0].shape[0])

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
        x = np.asarray(observation, dtype=np.float32)
        last = len(self.layers) - 1
        for k, (w, b) in enumerate(self.layers):
            x = x @ w.T + b
            if k < last:
                x = np.tanh(x)
        return x.astype(np.float32), None


class LearnedPolicy:
    """A trained model (SB3, or an RLlib actor) acting for every follower (parameter sharing).

    ``act`` stacks the followers' observations, applies the training normalisation, calls the
    model's deterministic ``predict`` once for the batch and maps the actions back to physical
    ``[u, omega]``. The policy is stateless (an MLP), so :meth:`reset` does nothing.

    Evaluate it at :attr:`control_period` (the period it was trained at), e.g.
    ``platoon_env.make(scenario, control_period=policy.control_period)``, unless you mean to
    test it at another one.

    .. warning::
        :meth:`load` unpickles code from the model zip: load only files you trust.

    Args:
        model: the SB3 model (its action space ``[-1, 1]^2`` if ``action_range`` is given), or
            an :class:`MLPActor` (an RLlib-trained policy).
        action_range: physical range of the normalised action, or None (physical actions).
        obs_scale: the observation divisor used in training, or None (raw observations).
        control_period: [s] the env control period the model was trained at.
        metadata: the rest of ``model.json`` (scenario, config, seed, ...), for reference.
    """

    def __init__(
        self,
        model: BaseAlgorithm | Predictor,
        *,
        action_range: ActionRange | None,
        obs_scale: NDArray[Any] | None,
        control_period: float,
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        self.model = model
        self.action_range = action_range
        self.obs_scale = None if obs_scale is None else np.asarray(obs_scale, dtype=np.float32)
        if self.obs_scale is not None and self.obs_scale.shape != (OBS_SIZE,):
            raise ValueError(f"obs_scale must have shape ({OBS_SIZE},), got {self.obs_scale.shape}")
        self.control_period = float(control_period)
        self.metadata: dict[str, Any] = dict(metadata or {})

    @property
    def scenario(self) -> str | None:
        """The scenario the model was trained on (from ``model.json``), if recorded."""
        scenario = self.metadata.get("scenario")
        return None if scenario is None else str(scenario)

    @classmethod
    def load(cls, path: str | os.PathLike[str], device: str = "cpu") -> LearnedPolicy:
        """Load ``DIR/model.zip`` (or ``DIR``) and the ``model.json`` beside it, by its
        ``engine``: an SB3 model, or an RLlib actor exported as arrays (:class:`MLPActor`).

        .. warning:: For SB3 this unpickles code from the zip: load only files you trust.
        """
        path = Path(path)
        if path.is_dir():
            path = path / "model.zip"
        meta_file = metadata_path(path)
        if not meta_file.is_file():
            raise FileNotFoundError(
                f"{meta_file} not found: a learned policy needs the JSON written beside its zip"
            )
        meta = json.loads(meta_file.read_text())
        if meta.get("format") != METADATA_FORMAT:
            raise ValueError(f"{meta_file} is not a {METADATA_FORMAT} file")
        if int(meta.get("format_version", 0)) > METADATA_VERSION:
            raise ValueError(
                f"{meta_file} has format_version {meta['format_version']}; this code reads "
                f"up to {METADATA_VERSION}"
            )
        engine = str(meta.get("engine", "sb3")).lower()
        model: BaseAlgorithm | MLPActor
        if engine == "rllib":
            actor = meta.get("actor") or {}
            if actor.get("type", "mlp") != "mlp" or actor.get("activation", "tanh") != "tanh":
                raise ValueError(f"{meta_file}: unknown exported actor {actor!r}")
            model = MLPActor.load(path)
            if model.input_dim != OBS_SIZE or model.output_dim != ACT_SIZE:
                raise ValueError(
                    f"{meta_file}: the actor maps {model.input_dim} -> {model.output_dim}, "
                    f"expected {OBS_SIZE} -> {ACT_SIZE}"
                )
        elif engine == "sb3":
            algo = str(meta["algo"]).lower()
            if algo not in ALGORITHMS:
                raise ValueError(
                    f"{meta_file}: unknown algo {algo!r}, expected one of {list(ALGORITHMS)}"
                )
            model = ALGORITHMS[algo].load(path, device=device)
        else:
            raise ValueError(f"{meta_file}: unknown engine {engine!r}, expected one of {ENGINES}")
        norm = meta.get("observation_normalization")
        if norm is not None and norm.get("type") != "fixed_scale":
            raise ValueError(f"{meta_file}: unknown observation normalisation {norm!r}")
        act = meta.get("action_range")
        return cls(
            model,
            action_range=None if act is None else ActionRange(**act),
            obs_scale=None if norm is None else np.asarray(norm["scale"], dtype=np.float32),
            control_period=float(meta["control_period"]),
            metadata=meta,
        )

    def reset(self, seed: int | None = None) -> None:
        """Nothing to restore: the policy is stateless and acts deterministically."""

    def act(self, observations: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[np.float32]]:
        """Map ``{agent: observation (7,)}`` to ``{agent: float32 [u, omega]}`` in one batch."""
        agents = list(observations)
        if not agents:
            return {}
        obs = np.stack([np.asarray(observations[a], dtype=np.float32) for a in agents])
        if obs.shape != (len(agents), OBS_SIZE):
            raise ValueError(f"observations must have shape ({OBS_SIZE},), got {obs.shape[1:]}")
        if self.obs_scale is not None:
            obs = obs / self.obs_scale
        actions, _ = self.model.predict(obs, deterministic=True)
        actions = np.asarray(actions, dtype=np.float32).reshape(len(agents), ACT_SIZE)
        if self.action_range is not None:
            actions = self.action_range.to_physical(actions)
        return {a: actions[i].copy() for i, a in enumerate(agents)}
