"""The policy registry: every policy an experiment can run, by name, and its fingerprint.

A :class:`PolicySpec` says which policy a grid cell runs: a display ``name``, a registered
``kind`` (:data:`REGISTRY`: the analytic laws), ``"model"`` (a model saved by
``platoon-train``) or ``"user"`` (a user's class named ``module:Class``, :func:`load_user_class`),
and the keyword arguments of its constructor (``params``). Specs are plain
data, so they pickle to worker processes; :func:`build_policy` builds the policy there, for
the env of the cell.

The **fingerprint** (:meth:`PolicySpec.fingerprint`) is what identifies the policy in the
evaluation store: for an analytic law its factory and parameters (the scenario's own PPC gains
are part of the scenario's fingerprint), for a model the SHA-256 of ``model.zip`` together with
the content of its ``model.json``, for a user's class its ``module:Class``, parameters and the
SHA-256 of its module's source file. A different model saved under the same name is another
policy; the same model under another name is the same one.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import io
import json
import math
import os
import re
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from platoon_env.provenance import REPO_ROOT
from platoon_env.scenarios.fingerprint import canonical_json, text_sha256

__all__ = [
    "MODEL",
    "REGISTRY",
    "STUDY_DRIVERS",
    "USER",
    "PolicyFileChanged",
    "PolicyKind",
    "PolicySpec",
    "UserPolicyError",
    "analytic_policies",
    "build_policy",
    "configurations",
    "default_models_dir",
    "load_model",
    "load_user_class",
    "register_policy",
    "shipped_models",
]

#: The kind of a model saved by ``platoon-train`` (``DIR/model.zip`` + ``DIR/model.json``).
MODEL = "model"
#: The kind of a user's policy class, ``module:Class`` (:meth:`PolicySpec.user`).
USER = "user"


@dataclass(frozen=True)
class PolicyKind:
    """A registered policy: ``factory`` is ``"module:callable"``, called as
    ``factory(env, **params)`` in the worker (a dotted path, so that it reaches spawned
    processes); ``signals`` says whether the policy records internal signals worth keeping
    (PPC's performance functions: the frontiers diagnose its failures from them); ``label`` is
    its name in tables and figures; ``studies`` names the drivers that run it by default
    (:data:`STUDY_DRIVERS`), so that each driver's list of policies is derived from here;
    ``privileged`` marks a policy that reads the true state (the oracle)."""

    factory: str
    description: str
    signals: bool = False
    label: str = ""
    studies: frozenset[str] = frozenset()
    #: The policy reads ground truth (the env's true state), not the followers' sensors: an
    #: upper reference (``docs/feasibility.md``), kept out of the pairwise comparisons and the
    #: goal, labelled *privileged* wherever it is shown.
    privileged: bool = False

    def __post_init__(self) -> None:
        unknown = set(self.studies) - set(STUDY_DRIVERS)
        if unknown:
            raise ValueError(
                f"unknown driver(s) {sorted(unknown)} in studies; known: {', '.join(STUDY_DRIVERS)}"
            )


#: The drivers whose default policy list is read from :data:`REGISTRY`
#: (:func:`analytic_policies`).
STUDY_DRIVERS: tuple[str, ...] = ("comparison", "frontiers", "leaderboard", "evaluate")

_ALL = frozenset(STUDY_DRIVERS)

#: Policy kinds by name. ``model`` (a trained model) is not in it: it needs a path.
REGISTRY: dict[str, PolicyKind] = {
    "ppc": PolicyKind(
        "baselines.ppc:PPCPolicy",
        "the paper's Prescribed Performance Control law",
        signals=True,
        label="PPC",
        studies=_ALL,
    ),
    "filtered_ppc": PolicyKind(
        "baselines.filtered_ppc:FilteredPPCPolicy",
        "PPC behind a constant-velocity Kalman filter with noise-tightened funnels",
        signals=True,
        label="filtered PPC",
        studies=frozenset({"frontiers", "leaderboard", "evaluate"}),
    ),
    "filtered_ppc_drive": PolicyKind(
        "baselines.filtered_ppc_drive:DriveAwareFilteredPPCPolicy",
        "the filtered PPC with a lookahead sized for a rate-limited drive, chosen on training "
        "layouts under the aruco profile (Remark 3; baselines/data/filtered_ppc_drive.yaml)",
        signals=True,
        label="drive-aware filtered PPC",
        studies=frozenset({"frontiers", "leaderboard", "evaluate"}),
    ),
    "last_seen": PolicyKind(
        "baselines.last_seen:LastSeenPolicy",
        "ref. [32] as the paper describes it: saturated tracking, drive to where the "
        "predecessor was last seen",
        label="last-seen [32]",
        studies=_ALL,
    ),
    "last_seen_fov": PolicyKind(
        "baselines.last_seen:LastSeenFOVPolicy",
        "the last-seen baseline with this project's field-of-view slow-down (not in the paper)",
        label="last-seen + FOV slow-down",
        studies=frozenset({"comparison"}),
    ),
    "ppc_tuned": PolicyKind(
        "baselines.ppc_tuned:TunedPPCPolicy",
        "the paper's PPC law with its gains tuned per formation under the aruco profile "
        "(Remark 3; baselines/data/ppc_tuned.yaml)",
        signals=True,
        label="tuned PPC",
        studies=frozenset({"frontiers", "leaderboard", "evaluate"}),
    ),
    "oracle": PolicyKind(
        "baselines.oracle:OraclePolicy",
        "PRIVILEGED: a receding-horizon planner on the true state, with the simulation itself "
        "as its exact model (every robot's pose and velocity, the leader's timed future, the "
        "free space); an upper reference of what is achievable, not a competitor",
        label="oracle (privileged)",
        privileged=True,
    ),
}


def analytic_policies(driver: str) -> dict[str, PolicyKind]:
    """The registered policies ``driver`` (one of :data:`STUDY_DRIVERS`) runs by default, in
    registry order."""
    if driver not in STUDY_DRIVERS:
        raise ValueError(f"unknown driver {driver!r}; known: {', '.join(STUDY_DRIVERS)}")
    return {name: kind for name, kind in REGISTRY.items() if driver in kind.studies}


def register_policy(name: str, kind: PolicyKind) -> None:
    """Add a policy kind (e.g. a new baseline) under ``name``; an existing name is an error."""
    if name in REGISTRY or name == MODEL:
        raise ValueError(f"policy kind {name!r} is already registered")
    if ":" not in kind.factory:
        raise ValueError(f"factory must be 'module:callable', got {kind.factory!r}")
    REGISTRY[name] = kind


class PolicyFileChanged(RuntimeError):
    """A model file read by a worker is not the one the evaluation planned (replaced or edited
    since): the cell fails (it is not a refusal), rather than storing the new file's episodes
    under the old file's fingerprint."""


def _model_description(zip_bytes: bytes, meta_bytes: bytes | None, path: Path) -> dict[str, Any]:
    """What a model's fingerprint hashes, from the bytes of its ``model.zip`` and ``model.json``
    (None: absent). The JSON is hashed as its text, read as ``Path.read_text`` reads it, so that
    the fingerprints of existing stores stay the same."""
    meta = "" if meta_bytes is None else io.TextIOWrapper(io.BytesIO(meta_bytes)).read()
    return {
        "kind": MODEL,
        "zip_sha256": hashlib.sha256(zip_bytes).hexdigest(),
        "model_json_sha256": text_sha256(meta),
        "path": str(path),
    }


def _read_model(zip_path: Path) -> tuple[bytes, bytes | None]:
    """The bytes of ``model.zip`` and of the ``model.json`` beside it (None if absent)."""
    meta_path = zip_path.with_suffix(".json")
    return zip_path.read_bytes(), meta_path.read_bytes() if meta_path.is_file() else None


def _fingerprint(description: dict[str, Any]) -> str:
    """The fingerprint of a policy description (its ``path`` left out: the same files
    elsewhere are the same model)."""
    return text_sha256(canonical_json({k: v for k, v in description.items() if k != "path"}))


def _resolve(factory: str) -> Any:
    module, _, attr = factory.partition(":")
    return getattr(importlib.import_module(module), attr)


#: What a policy's display name may hold (it names rows, files and markdown table cells).
_NAME = re.compile(r"[A-Za-z0-9_.-]{1,80}")

#: A user's policy class on the command line: ``module:Class`` (a dotted module path).
_USER_FACTORY = re.compile(r"^[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*:[A-Za-z_][\w]*$")


class UserPolicyError(ValueError):
    """A ``module:Class`` policy that cannot be used: the module does not import, it has no
    such attribute, or the attribute is not a policy class (``reset`` and ``act``)."""


def load_user_class(factory: str) -> Any:
    """The class (or factory) ``module:Class`` names, imported as ``python -m`` would: the
    working directory first on the import path (so ``my_policy.py`` beside the user works in
    every worker, which inherits the directory). It must be callable as ``Class(env)`` and its
    instances implement :class:`baselines.Policy` (``reset(seed=None)``,
    ``act(observations)``); anything else is a :class:`UserPolicyError` saying what is
    missing."""
    if not _USER_FACTORY.match(factory):
        raise UserPolicyError(f"{factory!r} is not of the form module:Class")
    module_name, _, attr = factory.partition(":")
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.insert(0, cwd)
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise UserPolicyError(
            f"{factory}: no module {exc.name!r} on the import path (the working directory "
            f"{cwd} and the installed packages); run from the folder that holds it, or set "
            "PYTHONPATH"
        ) from None
    except Exception as exc:  # the user's module raised while importing
        raise UserPolicyError(
            f"{factory}: importing {module_name} raised {type(exc).__name__}: {exc}"
        ) from None
    if not hasattr(module, attr):
        raise UserPolicyError(f"{factory}: module {module_name} has no attribute {attr!r}")
    target = getattr(module, attr)
    if not callable(target):
        raise UserPolicyError(f"{factory}: {attr} is not a class (it is {type(target).__name__})")
    if isinstance(target, type):
        missing = [m for m in ("reset", "act") if not callable(getattr(target, m, None))]
        if missing:
            raise UserPolicyError(
                f"{factory}: {attr} does not implement the Policy protocol: no "
                f"{' and no '.join(missing)} method (a policy has reset(seed=None) and "
                "act(observations) -> {agent: [u, omega]})"
            )
    return target


def _checked_metadata(meta: Any, path: Path) -> dict[str, Any]:
    """``meta`` (a model's JSON) if the fields the evaluator reads before loading the model have
    their types; else a ``ValueError`` naming ``path`` and the field."""
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: not a JSON object (got {type(meta).__name__})")
    period = meta.get("control_period")
    if period is not None and (
        isinstance(period, bool)
        or not isinstance(period, int | float)
        or not math.isfinite(period)
        or period <= 0
    ):
        raise ValueError(f"{path}: control_period must be a positive number, got {period!r}")
    config = meta.get("scenario_config")
    if config is not None and not isinstance(config, dict):
        raise ValueError(f"{path}: scenario_config must be an object, got {type(config).__name__}")
    observation = (config or {}).get("observation")
    if observation is not None and not isinstance(observation, dict):
        raise ValueError(
            f"{path}: scenario_config.observation must be an object, got "
            f"{type(observation).__name__}"
        )
    return meta


def _source_sha256(factory: str) -> str | None:
    """SHA-256 of the source file of ``factory``'s module (None: none, e.g. a built-in)."""
    module = sys.modules.get(factory.partition(":")[0])
    path = getattr(module, "__file__", None)
    if not path:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


@dataclass(frozen=True)
class PolicySpec:
    """One policy of a grid: ``name`` (display), ``kind`` (a :data:`REGISTRY` name or
    :data:`MODEL`), ``path`` (a model's ``model.zip``) and ``params`` (canonical JSON of the
    constructor's keyword arguments)."""

    name: str
    kind: str
    path: Path | None = None
    params: str = "{}"
    #: The kind's ``module:callable``, copied from :data:`REGISTRY` when the spec is made, so
    #: that a worker process (which has only the shipped registry) builds a policy registered
    #: at run time too.
    factory: str = ""
    #: What the spec read of its files, once (a model's ``model.json``, its description and
    #: fingerprint): every cell of a grid shares one reading, and the fingerprint, description
    #: and env overrides describe the same snapshot of the files.
    _memo: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind == USER:
            if not _USER_FACTORY.match(self.factory) or self.path is not None:
                raise ValueError(
                    f"a user policy needs a module:Class factory, got {self.factory!r}"
                )
            if not isinstance(json.loads(self.params), dict):
                raise ValueError(f"params must be a JSON object, got {self.params!r}")
            return
        if self.kind != MODEL and self.kind not in REGISTRY:
            raise ValueError(
                f"unknown policy kind {self.kind!r}; known: {', '.join(sorted(REGISTRY))}, {MODEL}"
            )
        if self.kind != MODEL and not self.factory:
            object.__setattr__(self, "factory", REGISTRY[self.kind].factory)
        if (self.kind == MODEL) != (self.path is not None):
            raise ValueError("a model policy needs a path, and only a model policy takes one")
        if not isinstance(json.loads(self.params), dict):
            raise ValueError(f"params must be a JSON object, got {self.params!r}")

    @classmethod
    def of(cls, kind: str, name: str | None = None, **params: Any) -> PolicySpec:
        """A registered policy with constructor ``params``, named ``name`` (default: kind)."""
        return cls(name or kind, kind, params=canonical_json(params))

    @classmethod
    def user(cls, factory: str, name: str | None = None, **params: Any) -> PolicySpec:
        """A user's policy class ``module:Class`` (:func:`load_user_class`, imported and checked
        now), built as ``Class(env, **params)`` for every episode, named ``name`` (default: the
        class's name). Its fingerprint hashes the module's source file, so an edited policy
        runs again."""
        load_user_class(factory)
        return cls(
            name or factory.partition(":")[2], USER, params=canonical_json(params), factory=factory
        )

    @classmethod
    def model(cls, path: str | Path, name: str | None = None) -> PolicySpec:
        """A saved model (``DIR`` or ``DIR/model.zip``), named ``name`` (default: ``DIR``'s
        name). A missing file is a ``ValueError``."""
        p = Path(path)
        zip_path = p if p.suffix == ".zip" else p / "model.zip"
        try:
            found = zip_path.is_file()
        except (OSError, ValueError) as exc:  # a name too long, a NUL byte
            shown = str(zip_path) if len(str(zip_path)) <= 120 else str(zip_path)[:117] + "..."
            raise ValueError(f"no model file at {shown} ({exc.__class__.__name__})") from None
        if not found:
            raise ValueError(f"no model file at {zip_path}")
        zip_path = zip_path.resolve()
        name = name or zip_path.parent.name
        if not _NAME.fullmatch(name):
            raise ValueError(
                f"the model folder's name {name!r} holds characters other than letters, "
                "digits, '_', '.' and '-': name it, NAME=PATH"
            )
        return cls(name, MODEL, zip_path)

    @classmethod
    def parse(cls, text: str) -> PolicySpec:
        """The command-line form: a registered kind (``ppc``), ``NAME=KIND``, ``NAME=PATH`` or
        a bare model PATH. Errors are ``argparse.ArgumentTypeError`` (a usage error)."""
        name, sep, rest = text.partition("=")
        if not sep:
            name, rest = "", text
        if not name and not rest:
            raise argparse.ArgumentTypeError("--policy needs a value")
        if sep and not name:
            raise argparse.ArgumentTypeError(f"--policy {text!r}: empty NAME before '='")
        if name and not _NAME.fullmatch(name):
            raise argparse.ArgumentTypeError(
                f"--policy {text!r}: NAME may hold letters, digits, '_', '.' and '-' only (it "
                "names rows, files and table cells)"
            )
        if rest in REGISTRY:
            return cls.of(rest, name or None)
        if _USER_FACTORY.match(rest) and not Path(rest).exists():
            try:
                return cls.user(rest, name or None)
            except UserPolicyError as exc:
                raise argparse.ArgumentTypeError(f"--policy {text!r}: {exc}") from None
        try:
            return cls.model(rest, name or None)
        except ValueError as exc:
            known = ", ".join(sorted(REGISTRY))
            raise argparse.ArgumentTypeError(
                f"--policy {text!r}: not a policy kind ({known}) and {exc}"
            ) from None

    @property
    def kwargs(self) -> dict[str, Any]:
        """The constructor's keyword arguments."""
        out: dict[str, Any] = json.loads(self.params)
        return out

    def model_metadata(self) -> dict[str, Any]:
        """A model's metadata: ``X.json`` beside ``X.zip`` (``model.json``, ``checkpoint.json``;
        {} if absent or not a model). A file that is not a JSON object, or whose fields the
        evaluator reads before loading the model are of the wrong type (``control_period`` a
        positive number, ``scenario_config`` and its ``observation`` objects), is a
        ``ValueError`` naming the file and the field (a usage error); the rest is checked by
        :meth:`training.LearnedPolicy.load`."""
        if self.path is None:
            return {}
        if "meta" not in self._memo:
            meta_path = self.path.with_suffix(".json")
            if not meta_path.is_file():
                self._memo["meta"] = {}
            else:
                try:
                    meta = json.loads(meta_path.read_text())
                except (OSError, ValueError, RecursionError) as exc:
                    detail = "nested too deep" if isinstance(exc, RecursionError) else exc
                    raise ValueError(f"{meta_path}: not readable JSON ({detail})") from None
                self._memo["meta"] = _checked_metadata(meta, meta_path)
        out: dict[str, Any] = self._memo["meta"]
        return out

    def env_overrides(self) -> dict[str, Any]:
        """What the policy asks of its env: a model runs at the control period it was trained
        at, and with the observation layout it was trained on (task-aware or not; its
        ``model.json``); the analytic laws at the scenario's settings."""
        if self.kind != MODEL:
            return {}
        meta = self.model_metadata()
        out: dict[str, Any] = {}
        if meta.get("control_period") is not None:
            out["control_period"] = float(meta["control_period"])
        observation = (meta.get("scenario_config") or {}).get("observation")
        if isinstance(observation, dict) and observation:
            out["observation"] = dict(observation)
        return out

    def description(self) -> dict[str, Any]:
        """What the fingerprint hashes, as data (kept in the store beside it; a model's files are
        hashed once per spec)."""
        if self.kind == USER:
            return {
                "kind": USER,
                "factory": self.factory,
                "params": self.kwargs,
                "source_sha256": _source_sha256(self.factory),
            }
        if self.kind != MODEL:
            return {"kind": self.kind, "factory": self.factory, "params": self.kwargs}
        if "description" not in self._memo:
            assert self.path is not None
            self._memo["description"] = _model_description(*_read_model(self.path), self.path)
        return dict(self._memo["description"])

    def fingerprint(self) -> str:
        """The hex SHA-256 identifying the policy (computed once per spec object)."""
        if "fingerprint" not in self._memo:
            self._memo["fingerprint"] = _fingerprint(self.description())
        out: str = self._memo["fingerprint"]
        return out

    @property
    def signals(self) -> bool:
        """Whether the policy's internal signals are worth recording."""
        kind = REGISTRY.get(self.kind)
        return kind is not None and kind.signals


def load_model(spec: PolicySpec, planned: str | None = None) -> Any:
    """The ``LearnedPolicy`` of a model spec, loaded from the files' bytes only after they are
    checked against ``planned`` (a fingerprint; default: the spec's, as first computed).

    The bytes are read once, hashed, and the policy is loaded from a private copy of exactly
    those bytes, so a file replaced at any moment gives either the planned model or a
    :class:`PolicyFileChanged` naming the file; never the new model under the old fingerprint.
    Errors of the files themselves (a malformed ``model.json``) are also ``PolicyFileChanged``'s
    kin: a ``RuntimeError``, since a ``ValueError`` of :func:`build_policy` means a refusal.
    """
    from training.policies import LearnedPolicy

    assert spec.path is not None
    planned = planned or spec.fingerprint()
    zip_bytes, meta_bytes = _read_model(spec.path)
    actual = _model_description(zip_bytes, meta_bytes, spec.path)
    if _fingerprint(actual) != planned:
        before = spec.description()
        changed = [
            f"{name} (SHA-256 planned {before[field][:12]}, read {actual[field][:12]})"
            for name, field in (("model.zip", "zip_sha256"), ("model.json", "model_json_sha256"))
            if before.get(field) != actual[field]
        ] or ["its files (the fingerprint differs)"]
        raise PolicyFileChanged(
            f"{spec.path.parent}: {', '.join(changed)} changed after the evaluation was planned; "
            "nothing of this cell was stored under the old fingerprint: re-run to evaluate the "
            "new files"
        )
    with tempfile.TemporaryDirectory(prefix="platoon-model-") as tmp:
        copy = Path(tmp) / "model.zip"
        copy.write_bytes(zip_bytes)
        if meta_bytes is not None:
            copy.with_suffix(".json").write_bytes(meta_bytes)
        try:
            return LearnedPolicy.load(copy)
        except (OSError, ValueError) as exc:
            message = str(exc).replace(str(copy.parent), str(spec.path.parent))
            raise RuntimeError(f"{spec.path}: cannot be loaded: {message}") from None


def build_policy(
    spec: PolicySpec, env: Any, planned: str | None = None, *, loaded: Any = None
) -> Any:
    """The policy of ``spec`` for ``env`` (in the process that runs the episode). A model is
    loaded by :func:`load_model` (its files checked against ``planned``), unless ``loaded``
    gives it: a fresh policy of :func:`load_model` for this spec and ``planned``, never bound
    nor acted (e.g. a copy of one loaded once for a batch of episodes,
    :mod:`experiments.batched_eval`); then checked and bound to ``env`` here. A
    ``ValueError`` from here is the policy refusing the configuration (``check_env``, a
    law's constructor)."""
    if spec.kind == MODEL:
        policy = load_model(spec, planned) if loaded is None else loaded
        check = getattr(policy, "check_env", None)
        if check is not None:
            check(env)
        bind = getattr(policy, "bind", None)
        if bind is not None:  # a residual policy builds its law on the env
            bind(env)
        return policy
    if spec.kind == USER:
        return load_user_class(spec.factory)(env, **spec.kwargs)
    return _resolve(spec.factory)(env, **spec.kwargs)


def default_models_dir() -> Path | None:
    """The folder of shipped models when none is named: the source checkout's ``models/`` (a
    clone, where the package is installed in editable mode), or None (an installed wheel:
    pass ``--models DIR``). Never the working directory's ``./models``: loading a model
    unpickles code, so nothing is loaded from a path the user did not name or the project
    does not ship."""
    if not (REPO_ROOT / ".git").exists():
        return None
    folder = REPO_ROOT / "models"
    return folder if any(folder.glob("*/model.zip")) else None


def shipped_models(models_dir: Path) -> list[PolicySpec]:
    """A spec per ``models_dir/*/model.zip`` (sorted by folder name); a ``models_dir`` that is
    not a folder is a ``ValueError`` naming it (a typo must not silently run no model)."""
    if not models_dir.is_dir():
        raise ValueError(f"models folder {models_dir} does not exist or is not a folder")
    return [PolicySpec.model(p) for p in sorted(models_dir.glob("*/model.zip"))]


#: A model named ``<configuration>_s<seed>`` (a ``platoon-sweep`` folder) is training seed
#: ``seed`` of ``configuration``.
_SEED_SUFFIX = re.compile(r"^(.+)_s(\d+)$")


def configurations(specs: Sequence[PolicySpec]) -> dict[str, tuple[str, int | None]]:
    """Each policy's configuration and training seed, by policy name: the models named
    ``<configuration>_s<seed>`` are the training seeds of ``configuration``; an analytic law,
    or a model without that suffix, is a configuration of its own (seed None). A prefix that
    is also the name of another policy given (``ppc_s0`` beside ``ppc``) is not a
    configuration: those models stay on their own, so that rows are never merged with another
    policy's."""
    names = {s.name for s in specs}
    out: dict[str, tuple[str, int | None]] = {}
    for spec in specs:
        match = _SEED_SUFFIX.match(spec.name) if spec.kind == MODEL else None
        if match is None or match.group(1) in names:
            out[spec.name] = (spec.name, None)
        else:
            out[spec.name] = (match.group(1), int(match.group(2)))
    return out
