"""What the parameter searches share: the training scenarios they may run on and their objective.

Both gain searches, the PPC law's (:mod:`experiments.studies.tune_ppc`) and the filtered PPC's
drive-aware table (:mod:`experiments.studies.tune_filtered`), tune on procedural ``train``
layouts only (:func:`check_training_scenario`) and score a trial's episodes by
:func:`objective_value`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from platoon_env.scenarios.loader import load_config
from platoon_env.scenarios.schema import ScenarioConfig

__all__ = ["TIE_BREAK", "check_training_scenario", "objective_value"]

#: Weight of the tie-break (mean time to the first violation over the horizon): below one
#: episode's share of the success rate for any budget of up to 10 episodes a trial.
TIE_BREAK = 0.1


def check_training_scenario(scenario: str) -> ScenarioConfig:
    """The config of ``scenario`` if it is a procedural ``train`` split; else a ``ValueError``.

    A fixed map (a study, or any YAML with one workspace) or a ``test`` split is refused: the
    search must never see the layouts the policies are evaluated on."""
    cfg = load_config(scenario)
    if cfg.generator is None:
        raise ValueError(
            f"refusing to tune on {scenario!r}: a fixed map (the studies are evaluation maps); "
            "give a procedural training split such as procedural_medium_train"
        )
    if cfg.generator.split != "train":
        raise ValueError(
            f"refusing to tune on {scenario!r}: its generator split is "
            f"{cfg.generator.split!r}; never tune on test layouts (use a *_train split)"
        )
    return cfg


def objective_value(metrics: Sequence[Mapping[str, Any]], horizon: float) -> float:
    """The search's objective over one trial's episodes: the fraction without a violation,
    plus :data:`TIE_BREAK` times the mean of ``min(time_to_violation, horizon) / horizon``."""
    safe = sum(m["violation"] == "" for m in metrics) / len(metrics)
    frac = sum(min(float(m["time_to_violation"]), horizon) / horizon for m in metrics)
    return safe + TIE_BREAK * frac / len(metrics)
