"""The first ``make()`` and step in a fresh environment, with no compiled kernel cached, and
again with the kernels cached (what every later process, venv or worker on the machine pays).

Each figure is one fresh Python process (``python -c``: import platoon_env, ``make("study_c")``,
``reset``, one ``step``) timed as a whole, with ``NUMBA_CACHE_DIR`` set to a new empty folder
for the cold run and to the same folder, now filled, for the warm one. Prints a markdown list.

    python benchmarks/cold_start.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time

SNIPPET = """
import numpy as np
import platoon_env
env = platoon_env.make("study_c")
obs, _ = env.reset(seed=0)
env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
"""


def timed(cache: str) -> float:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PLATOON_ENV_QUIET": "1"}
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", SNIPPET], env=env, check=True)
    return time.perf_counter() - start


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="platoon-cold-") as cache:
        cold = timed(cache)
        warm = timed(cache)
    print(f"- first `make()` + `reset` + `step` in a fresh process, no kernel cached: {cold:.1f} s")
    print(f"- the same with the kernels cached (a later process, venv or worker): {warm:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
