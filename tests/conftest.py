"""Shared fixtures: small scenarios given as dicts (the schema of docs/scenarios.md)."""

from __future__ import annotations

import copy
import os
from collections.abc import Callable, Iterator
from typing import Any

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

CORRIDOR: dict[str, Any] = {
    "name": "test_corridor",
    "workspace": {
        "bounds": [0.0, -2.0, 30.0, 2.0],
        "obstacles": [[[10.0, 0.8], [12.0, 0.8], [12.0, 2.0], [10.0, 2.0]]],
    },
    "leader": {"path": [[0.5, 0.0], [20.0, 0.0]], "speed": 0.3},
    "followers": 2,
    "robot": {"radius": 0.15},
    "camera": {"half_angle": 0.4, "range": 1.5},
    "safety": {"d_col": 0.3},
    "formation": {"d_des": 1.0},
    "ppc": {
        "lambda": 0.5,
        "rho_d_inf": 0.05,
        "rho_beta_inf": 0.1,
        "k_d": 1.0,
        "k_beta": 2.0,
        "delta": 0.5,
        "epsilon": 0.75,
    },
}


@pytest.fixture
def corridor() -> dict[str, Any]:
    """A straight 4 m wide corridor with one box obstacle, two followers (study C parameters)."""
    return copy.deepcopy(CORRIDOR)


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Training runs single-threaded (as platoon-train does); the thread count is restored
    afterwards. Test files that train use it for every test:
    ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def usage_error(capsys: pytest.CaptureFixture[str]) -> Callable[..., str]:
    """``usage_error(parse, argv)``: calls ``parse(argv)``, requires argparse's usage error
    (``SystemExit`` with code 2) and returns what it wrote to stderr."""

    def run(parse: Callable[[list[str]], object], argv: list[str]) -> str:
        with pytest.raises(SystemExit) as exit_info:
            parse(argv)
        assert exit_info.value.code == 2
        return capsys.readouterr().err

    return run
