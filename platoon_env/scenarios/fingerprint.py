"""Content fingerprints: what identifies a resolved scenario, a set of overrides, a file.

An evaluation result or a trained model is only comparable with another when they ran on the
same thing. "The same thing" is the *resolved* scenario config (after the YAML is read, the
overrides and the sensor profile are applied), not the name or path it was given by:
``./x.yaml`` and ``x.yaml`` are one scenario, an edited ``x.yaml`` is another. The fingerprint
is the SHA-256 of the canonical JSON of :func:`~platoon_env.scenarios.schema.config_to_mapping`
(keys sorted, no whitespace, floats in Python's shortest round-trip form).

That mapping is canonical: a number where the schema's type is float is written as a float
(``accel_max=1`` and ``accel_max=1.0`` are one scenario), and a field at its default is left out
unless it is identity-bearing (:func:`platoon_env.config.identity`: the fields that were written
out at their defaults when fingerprints were first recorded). So a field added to the schema
with a default changes no stored fingerprint; it joins the fingerprint of a scenario only where
that scenario sets it to another value. ``tests/test_fingerprints.py`` pins the fingerprints of
the shipped scenarios and models.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from platoon_env.scenarios.schema import ScenarioConfig, config_to_mapping

__all__ = [
    "canonical_json",
    "config_fingerprint",
    "config_mapping",
    "file_sha256",
    "text_sha256",
]


def canonical_json(value: Any) -> str:
    """``value`` as canonical JSON: sorted keys, no whitespace, tuples as lists.

    Raises ``TypeError`` on a value JSON cannot hold (the caller's bug, not to be hashed away
    with ``str``). ``inf`` and ``nan`` are written as ``Infinity``/``NaN``, as Python's ``json``
    reads them back.
    """
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


def text_sha256(text: str) -> str:
    """The hex SHA-256 of ``text`` encoded as UTF-8."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def config_mapping(cfg: ScenarioConfig) -> dict[str, Any]:
    """The resolved config as plain data (the mapping :func:`config_fingerprint` hashes)."""
    return config_to_mapping(cfg)


def config_fingerprint(cfg: ScenarioConfig) -> str:
    """The hex SHA-256 of the canonical JSON of the resolved config ``cfg``."""
    return text_sha256(canonical_json(config_to_mapping(cfg)))


def file_sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    """The hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        while block := f.read(chunk):
            digest.update(block)
    return digest.hexdigest()
