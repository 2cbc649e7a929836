"""The seeds of a training run's envs: one independent stream per env and per segment.

A run seeded ``seed`` draws every env's random stream (its procedural layouts, start
perturbations, leader speed factors, sensor noise) from ``numpy.random.SeedSequence(seed)``:

* env ``j`` of training segment ``s`` is reset with :func:`env_seeds`'s
  ``SeedSequence(seed, spawn_key=(s, j)).generate_state(1, uint64)``, which is the sequence
  ``SeedSequence(seed).spawn(s + 1)[s].spawn(n_envs)[j]``;
* a *segment* is one invocation of ``platoon-train`` for the run: 0 for a new run, then one
  more for each ``--resume`` (the number of segments already recorded in the
  ``model.json``/``checkpoint.json`` it continues from). A resumed run therefore continues
  with fresh streams instead of replaying the first segment's episodes, without storing any
  RNG state in the checkpoint;
* RLlib's sub-env ``j`` of env runner ``w`` draws from
  ``SeedSequence(seed, spawn_key=(s, w, j, evaluation))`` (:func:`training.rllib.derived_seed`).

Every stream is distinct from every other run's: seeds 0 and 1 no longer share envs. Until
this rule, env ``j`` was seeded ``seed + j``, so training seeds 0 and 1 shared 3 of their 4 env
streams, and a resumed run restarted them. The rule changes which layouts and starts a *new*
training run sees (models trained before it were trained on the old streams); evaluation
seeds its envs itself and is unchanged.
"""

from __future__ import annotations

import numpy as np

__all__ = ["env_seeds", "process_seed", "stream_seed"]


def stream_seed(seed: int, *key: int, bits: int = 64) -> int:
    """The ``bits``-bit int seed of ``SeedSequence(seed, spawn_key=key)`` (its first word)."""
    if bits not in (32, 64):
        raise ValueError(f"bits must be 32 or 64, got {bits}")
    dtype = np.uint64 if bits == 64 else np.uint32
    sequence = np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key))
    return int(sequence.generate_state(1, dtype=dtype)[0])


def env_seeds(seed: int, n_envs: int, *, segment: int = 0) -> list[int]:
    """The reset seeds of envs ``0 .. n_envs - 1`` of segment ``segment`` of run ``seed``:
    ``SeedSequence(seed).spawn(segment + 1)[segment].spawn(n_envs)``, one int each."""
    return [stream_seed(seed, segment, j) for j in range(n_envs)]


def process_seed(seed: int, segment: int = 0) -> int:
    """The python/numpy/torch seed of segment ``segment`` (the policy's initialisation and
    action noise): ``seed`` itself for a new run, so its model is what it always was; a
    32-bit draw of ``SeedSequence(seed, spawn_key=(segment,))`` for a resumed one, so it does
    not replay the first segment's action noise either."""
    return int(seed) if segment == 0 else stream_seed(seed, segment, bits=32)
