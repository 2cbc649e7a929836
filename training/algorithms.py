"""The training algorithms of ``platoon-train --algo``: one table every other list derives from.

Each :class:`Algorithm` says which engines train it (``--engine``), which Stable-Baselines3
class its ``model.zip`` is saved as (what :class:`training.policies.LearnedPolicy` loads it
with), whether it holds a Lagrange multiplier on ``info["cost"]`` (:mod:`training.lagrangian`)
and whether it is a **clone**: the PPC law cloned with DAgger (:mod:`training.bc`), then
fine-tuned by another algorithm of the table (:attr:`Algorithm.finetune`). The command line's
choices, the engines' checks, the SB3 option tables and the model loader all read
:data:`ALGORITHMS`; a new algorithm is one row here.

This module imports nothing of the project (and no torch), so any layer may read it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "ALGORITHMS",
    "Algorithm",
    "clones",
    "finetune_algo",
    "has_multiplier",
    "is_clone",
    "trained_by",
]


@dataclass(frozen=True)
class Algorithm:
    """One ``--algo`` value.

    ``engines``: the ``--engine`` values that train it. ``sb3_class``: the SB3 class
    (``"ppo"`` or ``"sac"``) its ``model.zip`` is saved as. ``lagrangian``: PPO on rewards
    penalised by a Lagrange multiplier on ``info["cost"]`` (for a clone: its fine-tuning).
    ``finetune``: for a clone, the algorithm that fine-tunes it (None: not a clone).
    ``label``: what it is, in a few words.
    """

    name: str
    engines: tuple[str, ...]
    sb3_class: str
    label: str
    lagrangian: bool = False
    finetune: str | None = None

    @property
    def clone(self) -> bool:
        """Whether it clones the PPC law first (:mod:`training.bc`; ``--algo bc_*``)."""
        return self.finetune is not None


#: Every ``--algo``, by name, in the order ``platoon-train --help`` lists them.
ALGORITHMS: dict[str, Algorithm] = {
    a.name: a
    for a in (
        Algorithm("ppo", ("sb3", "rllib", "fast"), "ppo", "PPO"),
        Algorithm("sac", ("sb3",), "sac", "SAC"),
        Algorithm(
            "ppo_lagrangian",
            ("sb3", "rllib", "fast"),
            "ppo",
            "PPO with a Lagrange multiplier on info['cost']",
            lagrangian=True,
        ),
        Algorithm(
            "bc_ppo",
            ("fast",),
            "ppo",
            "the PPC law cloned with DAgger, then fine-tuned by PPO",
            finetune="ppo",
        ),
        Algorithm(
            "bc_ppo_lagrangian",
            ("fast",),
            "ppo",
            "the PPC law cloned with DAgger, then fine-tuned by PPO-Lagrangian",
            lagrangian=True,
            finetune="ppo_lagrangian",
        ),
    )
}


def trained_by(engine: str, *, clones: bool = True) -> tuple[str, ...]:
    """The names of the algorithms ``engine`` trains (``clones=False``: its own learners only,
    not the ``bc_*`` ones), in table order."""
    return tuple(
        a.name for a in ALGORITHMS.values() if engine in a.engines and (clones or not a.clone)
    )


def clones() -> tuple[str, ...]:
    """The names of the clone algorithms (``bc_*``), in table order."""
    return tuple(a.name for a in ALGORITHMS.values() if a.clone)


def is_clone(name: str) -> bool:
    """Whether ``name`` is a clone algorithm (an unknown name is not)."""
    algo = ALGORITHMS.get(name)
    return algo is not None and algo.clone


def has_multiplier(name: str) -> bool:
    """Whether ``name`` trains with a Lagrange multiplier (an unknown name does not)."""
    algo = ALGORITHMS.get(name)
    return algo is not None and algo.lagrangian


def finetune_algo(name: str) -> str:
    """The algorithm the fast learner runs for ``name``: a clone's fine-tuning, else ``name``."""
    algo = ALGORITHMS.get(name)
    return algo.finetune if algo is not None and algo.finetune is not None else name
