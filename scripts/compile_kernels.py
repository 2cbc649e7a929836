"""Compile (and cache) the numba kernels the default benchmark calls, as the last step of set-up.

numba compiles a kernel at its first call and caches it on disk, keyed on the source version
(``platoon_env/_numba_cache.py``): without this step the first ``platoon-evaluate`` of a fresh
clone spends a minute or two compiling before its first episode. This runs three steps of every
analytic law of the default benchmark on each paper study, one episode alone and a chunk of two
on the batched core, and one learned model's forward pass, so every kernel they call is
compiled once here. A warm cache makes it a few seconds.

    python scripts/compile_kernels.py
"""

from __future__ import annotations

import sys
import time


def main() -> int:
    start = time.perf_counter()
    from experiments.batched_eval import run_cells
    from experiments.grid import Cell, resolve_cells
    from experiments.policies import PolicySpec, analytic_policies, default_models_dir
    from experiments.studies.evaluate import DEFAULT_SCENARIOS

    specs = [PolicySpec.of(name) for name in analytic_policies("evaluate")]
    models = default_models_dir()
    try:
        import stable_baselines3  # noqa: F401  (the [train] extra: learned models)
    except ImportError:
        models = None
    if models is not None:
        first = sorted(models.glob("residual*/model.zip"))[:1]
        specs += [PolicySpec.model(p) for p in first]
    overrides = (("max_episode_steps", 3),)
    for spec in specs:
        for scenario in DEFAULT_SCENARIOS:
            cells = resolve_cells([Cell.of(spec, scenario, s, overrides) for s in range(3)])
            results = run_cells(cells[:1]) + run_cells(cells[1:])
            bad = [r for r in results if r.status != "done"]
            if bad:
                print(
                    f"{spec.name} on {scenario}: {bad[0].status}: {bad[0].error}", file=sys.stderr
                )
                return 1
    print(f"compile_kernels: kernels compiled or loaded in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
